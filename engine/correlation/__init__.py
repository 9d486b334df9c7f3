"""Fourier correlation of two descriptors: energy, force and torque at any pose.

Works on two skeletal-density descriptors (``rho (nx, ny, nz) complex64`` on grids of one
spacing): part 1 fixed, part 2 moved by ``(R, t)``. Modules, bottom to top:

- :mod:`~engine.correlation.spectrum`: centred, zero-padded spectra and refined tables;
- :mod:`~engine.correlation.tables`: the frozen inputs of the sums, the spectra of a pair
  and the table of one mode count;
- :mod:`~engine.correlation.interpolation`: part 2's spectrum at rotated frequencies (the
  one definition; :mod:`~engine.correlation.to_opencl` turns it into OpenCL C);
- :mod:`~engine.correlation.finishing`: energy, force, torque from the raw sums, the box
  overlap test, and :class:`Evaluation`, the per-pose result;
- :mod:`~engine.correlation.reference`, :mod:`~engine.correlation.numba_kernels`,
  :mod:`~engine.correlation.opencl_kernels`: the per-pose sums (numpy, numba, OpenCL);
- :mod:`~engine.correlation.per_pose`: which per-pose path runs;
- :mod:`~engine.correlation.landscape`: the energy over every translation at once;
- :mod:`~engine.correlation.rotation_cache`: per-pose sums from products kept at a
  reference rotation (only translation phases per pose);
- :mod:`~engine.correlation.correlator`: :class:`Correlator`, which ties them together;
- :mod:`~engine.correlation.from_scene`: a Correlator for a scene's two parts.

docs/correlation.md gives the mathematics, the checks and the measurements.
"""

from engine.correlation.correlator import (
    Correlator,
    LocalSpectral,
    SpectralWork,
    required_fft_size,
)
from engine.correlation.finishing import Evaluation, add_evaluations
from engine.correlation.from_scene import correlator_for_scene
from engine.correlation.landscape import Landscape, LandscapeError, compute_landscape
from engine.correlation.spectrum import Spectrum, compute_spectrum
from engine.correlation.tables import ModeTable, Spectra

__all__ = [
    "Correlator",
    "Evaluation",
    "add_evaluations",
    "Landscape",
    "LandscapeError",
    "LocalSpectral",
    "ModeTable",
    "Spectra",
    "SpectralWork",
    "Spectrum",
    "compute_landscape",
    "compute_spectrum",
    "correlator_for_scene",
    "required_fft_size",
]
