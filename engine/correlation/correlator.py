"""The Correlator: energy, force and torque of part 2 against part 1 at any pose.

Works on two descriptor fields (``.rho`` (nx, ny, nz) complex64 on ``.grid``, one shared
spacing ``h``): part 1 fixed, part 2 moved by ``(R, t)`` (a point ``q`` of part 2 goes to
``R q + t`` in part 1's frame). With ``^`` the continuous Fourier transform and
``v2(q) = q rho2(q)``::

    f(R, t)   = sum_w rho1^(w) rho2^(-R^T w) exp(2 pi i w.t) dw
    E = -kappa Re f,   F = -dE/dt,   T = -dE/dtheta   (R -> exp([theta]x) R)

The pieces, each in its own module of :mod:`engine.correlation`:

* :mod:`~engine.correlation.spectrum` and :mod:`~engine.correlation.tables`: the spectra,
  computed once (:class:`~engine.correlation.tables.Spectra`), and per mode count ``K`` a
  frozen :class:`~engine.correlation.tables.ModeTable`;
* :mod:`~engine.correlation.interpolation`: part 2's spectrum at rotated frequencies;
* :mod:`~engine.correlation.finishing`: energy, force and torque from the raw sums;
* :mod:`~engine.correlation.reference` (numpy), :mod:`~engine.correlation.numba_kernels`
  and :mod:`~engine.correlation.opencl_kernels`: the per-pose sums;
* :mod:`~engine.correlation.per_pose`: which of them runs (the registry's "auto");
* :mod:`~engine.correlation.landscape`: every translation at once.

Threads: the spectra never change after construction, and the current table is replaced,
never changed. :meth:`Correlator.with_modes` and :meth:`Correlator.landscape` only read
them, so a worker thread may call them while another thread evaluates poses; the caller
swaps the new correlator (or the new landscape) in. Correlators made by ``with_modes`` share
the compiled kernels, and two threads may evaluate poses at once (the worker warms a new
field while the loop uses the old one): a kernel keeps what it prepared per table
(:class:`~engine.correlation.tables.PerTable`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

import engine.correlation.per_pose as per_pose
import engine.correlation.reference as reference
from engine.backend import check_choice
from engine.correlation.finishing import Evaluation, boxes_overlap
from engine.correlation.landscape import Landscape, compute_landscape
from engine.correlation.spectrum import band_named, fast_size
from engine.correlation.tables import (
    ModeTable,
    PairGeometry,
    Spectra,
    build_spectra,
    truncate,
)
from engine.grid import Grid
from engine.params import CorrelationParams

if TYPE_CHECKING:
    from engine.correlation.rotation_cache import RotationCache


class SampledField(Protocol):
    """What a Correlator reads of a descriptor: its samples and their grid."""

    @property
    def rho(self) -> np.ndarray:
        """(nx, ny, nz) complex64 samples."""
        ...

    @property
    def grid(self) -> Grid:
        """Where the samples sit (one spacing shared by both parts)."""
        ...


class SpectralWork(Protocol):
    """Computes a pair's truncations and landscapes from its spectra (:attr:`Correlator.spectral`).

    Each method returns what the in-process function returns for the same arguments
    (:func:`~engine.correlation.tables.truncate`,
    :func:`~engine.correlation.landscape.compute_landscape`): :class:`LocalSpectral` calls
    them; the runtime's job process (``engine.runtime.job_process.RemoteSpectral``) runs
    them in a process of its own.
    """

    def truncate(self, modes: int) -> ModeTable:
        """The table keeping ``modes`` per axis."""
        ...

    def landscape(self, rotation: np.ndarray, modes: int, *, forces: bool,
                  table: ModeTable | None, progress: Callable[[float], None] | None,
                  cancel: Callable[[], bool] | None) -> Landscape:
        """The landscape at ``rotation`` with ``modes`` per axis."""
        ...


class LocalSpectral:
    """A pair's truncations and landscapes computed here, by the calling thread (the default)."""

    def __init__(self, spectra: Spectra):
        self.spectra = spectra

    def truncate(self, modes: int) -> ModeTable:
        """:func:`~engine.correlation.tables.truncate` of the spectra."""
        return truncate(self.spectra, modes)

    def landscape(self, rotation: np.ndarray, modes: int, *, forces: bool,
                  table: ModeTable | None, progress: Callable[[float], None] | None,
                  cancel: Callable[[], bool] | None) -> Landscape:
        """:func:`~engine.correlation.landscape.compute_landscape` of the spectra."""
        return compute_landscape(self.spectra, rotation, modes, forces=forces, table=table,
                                 progress=progress, cancel=cancel)


def required_fft_size(shape1: tuple[int, ...], shape2: tuple[int, ...]) -> int:
    """Smallest FFT size for which no periodic image interferes at any pose.

    ``N >= n1 - 1 + 2 r2 / h + 3`` along every axis, with ``r2 / h`` the half-diagonal of
    part 2's grid box in cells (its largest extent under any rotation) and one cell of
    margin on each side for the overlap test.
    """
    half_diag = 0.5 * float(np.linalg.norm(np.asarray(shape2) - 1))
    need = max(shape1) - 1 + 2.0 * half_diag + 3.0
    return fast_size(int(math.ceil(need)))


class Correlator:
    """Energy, force and torque between a fixed and a moving descriptor.

    Parameters
    ----------
    fixed, moving : descriptor
        Objects with ``.rho`` ((nx, ny, nz) complex64) and ``.grid``
        (:class:`engine.grid.Grid`); both grids must share one spacing.
    params : CorrelationParams, optional
        Modes ``K``, oversampling, refined table, selection (defaults from
        :mod:`engine.params`). ``modes``, ``oversample``, ``refine``, ``fine_modes``,
        ``selection`` and ``band`` given as keywords override its fields (``band``: "box",
        the plain truncation, unless told; the guidance's is "smooth",
        :data:`engine.params.GUIDANCE_BAND`).
    rotation : bool
        Compute the torque (moment spectra). When False, :meth:`evaluate` returns
        ``torque=None``.
    backend : {"auto", "numpy", "numba", "opencl"}
        Per-pose backend (:mod:`engine.correlation.per_pose`).
    kappa : float
        Energy scale, ``E = -kappa Re f``.
    fft_size : int, optional
        Override the padded size ``N`` (at least :func:`required_fft_size` to be free of
        periodic images; smaller values are accepted for tests and experiments).
    use_cache : bool
        Use the on-disk spectrum cache.
    progress, cancel
        Progress fractions 0..1 while the spectra are built and the backend is chosen;
        a cancel returning True raises :class:`engine.errors.Cancelled`.

    Attributes
    ----------
    spectra : Spectra
        The pair's spectra (immutable).
    table : ModeTable
        The current truncation (replaced by :meth:`set_modes`, never changed).
    stats : dict
        Counters: ``spectra``, ``moment_spectra``, ``evaluations``, ``torque_sums``,
        ``truncations``, ``reference_fallbacks`` (evaluations run on numpy because the
        compiled kernels' table for K would be too large).
    backend_name : str
        The per-pose backend in use and why.
    """

    def __init__(
        self,
        fixed: SampledField,
        moving: SampledField,
        params: CorrelationParams | None = None,
        *,
        modes: int | None = None,
        oversample: float | None = None,
        refine: int | None = None,
        fine_modes: int | None = None,
        selection: str | None = None,
        band: str | None = None,
        rotation: bool = True,
        backend: str = "auto",
        kappa: float = 1.0,
        fft_size: int | None = None,
        use_cache: bool = True,
        progress: Callable[[float], None] | None = None,
        cancel: Callable[[], bool] | None = None,
    ) -> None:
        given: dict[str, Any] = {"modes": modes, "oversample": oversample, "refine": refine,
                                 "fine_modes": fine_modes, "selection": selection, "band": band}
        params = dataclasses.replace(params or CorrelationParams(),
                                     **{k: v for k, v in given.items() if v is not None})
        backend = check_choice("per_pose", backend)
        for name, obj in (("fixed", fixed), ("moving", moving)):
            if not hasattr(obj, "rho") or not hasattr(obj, "grid"):
                raise TypeError(f"{name} must have .rho and .grid (a descriptor)")
        g1, g2 = fixed.grid, moving.grid
        if not math.isclose(g1.spacing, g2.spacing, rel_tol=1e-9, abs_tol=0.0):
            raise ValueError(
                f"the two descriptors have different grid spacings ({g1.spacing:g} and "
                f"{g2.spacing:g}): compute them with one shared spacing "
                "(descriptors_for_scene does)")
        if not (math.isfinite(kappa) and kappa > 0):
            raise ValueError(f"kappa must be a positive finite number, got {kappa!r}")
        size = int(fft_size) if fft_size is not None else required_fft_size(g1.shape, g2.shape)
        if size < max(max(g1.shape), max(g2.shape)) or size % 2:
            raise ValueError(f"fft_size must be even and cover both grids, got {size}")
        h = g1.spacing
        geometry = PairGeometry(
            centre_fixed=np.asarray(g1.centre, dtype=np.float64),
            centre_moving=np.asarray(g2.centre, dtype=np.float64),
            half_fixed=0.5 * h * (np.asarray(g1.shape, dtype=np.float64) - 1),
            half_moving=0.5 * h * (np.asarray(g2.shape, dtype=np.float64) - 1),
            spacing=h, size=size, kappa=float(kappa), rotation=bool(rotation))

        def stage(lo: float, hi: float) -> Callable[[float], None] | None:
            return None if progress is None else (lambda f: progress(lo + (hi - lo) * f))

        per_pose.warm_up(backend, params.selection)  # compiles while the spectra are built
        self.params = params
        self.fixed_grid: Grid = g1
        self.moving_grid: Grid = g2
        self.spectra: Spectra = build_spectra(
            fixed.rho, g1, moving.rho, g2, geometry, oversample=params.oversample,
            refine=params.refine, fine_modes=params.fine_modes, selection=params.selection,
            use_cache=use_cache, band=band_named(params.band), progress=stage(0.0, 0.7),
            cancel=cancel)
        self.stats: dict[str, int] = {
            "spectra": 2 + (1 if self.spectra.fine_table is not None else 0),
            "moment_spectra": 3 if rotation else 0, "evaluations": 0, "torque_sums": 0,
            "truncations": 1, "reference_fallbacks": 0}
        self.table: ModeTable = truncate(self.spectra, params.modes)
        kernels, active, why = per_pose.choose(backend, self.table, params.selection,
                                               bool(rotation), progress=stage(0.7, 1.0))
        #: Where truncations and landscapes are computed; the same results wherever (the
        #: runtime may give a process of its own). Correlators made by :meth:`with_modes`
        #: share it.
        self.spectral: SpectralWork = LocalSpectral(self.spectra)
        self._kernels: dict[str, per_pose.Kernel] = kernels
        self._active: tuple[str, per_pose.Kernel | None] = (active, kernels.get(active))
        self.backend_name = why
        if progress is not None:
            progress(1.0)

    # ------------------------------------------------------------------ truncation
    def truncate(self, modes: int) -> ModeTable:
        """A new table keeping ``modes`` per axis (by :attr:`spectral`; any thread)."""
        return self.spectral.truncate(int(modes))

    def with_modes(self, modes: int) -> Correlator:
        """A new Correlator with ``modes`` per axis, sharing the spectra and the kernels.

        Pure: nothing of this one changes, so a worker may build it while this one
        evaluates poses, and the caller swaps it in.
        """
        other = object.__new__(Correlator)
        other.__dict__.update(self.__dict__)
        other.stats = dict(self.stats, truncations=self.stats["truncations"] + 1)
        other.table = self.truncate(modes)
        other.params = dataclasses.replace(self.params, modes=other.table.modes)
        return other

    def set_modes(self, modes: int) -> None:
        """Keep the cube of the ``modes`` lowest frequencies per axis (``m' = K^3``).

        Builds the new table first, then swaps it in with one assignment: a pose being
        evaluated meanwhile finishes with the old table. Nothing is transformed again.
        """
        if int(modes) < 1:
            raise ValueError(f"modes per axis must be at least 1, got {modes}")
        if min(int(modes), self.size) == self.table.modes:
            return
        self.table = self.truncate(modes)
        self.stats["truncations"] += 1

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy, force and torque at one relative pose.

        Parameters
        ----------
        rotation : (3, 3) float
            Rotation of part 2 relative to part 1.
        translation : (3,) float
            Translation of part 2 relative to part 1 (part 1's frame).
        """
        start = time.perf_counter()
        rot = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
        t = np.ascontiguousarray(translation, dtype=np.float64).reshape(3)
        if not math.isfinite(float(rot.sum()) + float(t.sum())):
            raise ValueError("pose contains NaN or infinite values")
        table = self.table  # one read: a set_modes meanwhile swaps in a new table
        name, kernel = self._active
        self.stats["evaluations"] += 1
        if table.geometry.rotation:
            self.stats["torque_sums"] += 1
        if kernel is not None and kernel.supports(table):
            out = kernel.pose(table, rot, t)
        else:
            if kernel is not None:
                self.stats["reference_fallbacks"] += 1
            out = reference.pose(self.spectra, table, rot, t)
        return Evaluation(
            energy=float(out[0]), force=out[1:4],
            torque=out[4:7] if table.geometry.rotation else None,
            microseconds=(time.perf_counter() - start) * 1e6, modes=table.modes)

    def boxes_overlap(self, rotation: np.ndarray, translation: np.ndarray) -> bool:
        """Whether part 2's grid box (rotated, one cell of margin) can meet part 1's."""
        g = self.spectra.geometry
        return bool(boxes_overlap(np.asarray(rotation, dtype=np.float64),
                                  np.asarray(translation, dtype=np.float64),
                                  g.centre_fixed, g.centre_moving, g.half_fixed,
                                  g.half_moving, g.spacing))

    def landscape(
        self, rotation: np.ndarray, *, modes: int | None = None, forces: bool = True,
        progress: Callable[[float], None] | None = None,
        cancel: Callable[[], bool] | None = None,
    ) -> Landscape:
        """Energy (and force) over every lattice translation at one rotation (any thread).

        See :func:`engine.correlation.landscape.compute_landscape`; ``modes`` defaults to
        the current :attr:`modes`. Computed by :attr:`spectral`.
        """
        table = self.table
        return self.spectral.landscape(
            rotation, table.modes if modes is None else int(modes), forces=forces,
            table=table, progress=progress, cancel=cancel)

    def rotation_cache(self, rotation: np.ndarray, *,
                       table: ModeTable | None = None) -> RotationCache:
        """Products kept at ``rotation`` for :meth:`evaluate_cached` (numba; any thread).

        ``table``: the truncation to build them for (default: the current one). Always
        here, never by :attr:`spectral`: asked for every few milliradians, needed at once.
        """
        from engine.correlation.rotation_cache import build_rotation_cache  # needs numba

        return build_rotation_cache(self.table if table is None else table, rotation)

    def evaluate_cached(self, cache: RotationCache, rotation: np.ndarray,
                        translation: np.ndarray) -> Evaluation:
        """As :meth:`evaluate`, from a rotation cache.

        First order in the rotation since the cache was built; force and torque are the exact
        derivatives of the energy returned.
        """
        from engine.correlation.rotation_cache import cached_pose

        start = time.perf_counter()
        rot = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
        out = cached_pose(cache, rot, np.ascontiguousarray(translation, dtype=np.float64))
        return Evaluation(energy=float(out[0]), force=out[1:4], torque=out[4:7],
                          microseconds=(time.perf_counter() - start) * 1e6,
                          modes=cache.table.modes)

    # ------------------------------------------------------------------ backends
    @property
    def backend(self) -> str:
        """Short name of the per-pose backend in use."""
        return self._active[0]

    def use_backend(self, name: str) -> None:
        """Switch the per-pose backend (building its kernel if needed)."""
        name = check_choice("per_pose", name)
        if name == "auto":
            raise ValueError("use_backend needs a backend name: numpy, numba or opencl")
        if name != "numpy" and name not in self._kernels:
            self._kernels[name] = per_pose.make_kernel(name, self.selection, self.rotation)
        self._active = (name, self._kernels.get(name))

    # ------------------------------------------------------------------ read-only views
    @property
    def modes(self) -> int:
        """Modes per axis of the current table."""
        return self.table.modes

    @property
    def size(self) -> int:
        """FFT size ``N``."""
        return self.spectra.geometry.size

    @property
    def spacing(self) -> float:
        """Grid spacing ``h``."""
        return self.spectra.geometry.spacing

    @property
    def kappa(self) -> float:
        """Energy scale."""
        return self.spectra.geometry.kappa

    @property
    def rotation(self) -> bool:
        """Whether torques are computed."""
        return self.spectra.geometry.rotation

    @property
    def selection(self) -> str:
        """"cube" or "largest"."""
        return self.spectra.selection

    @property
    def centre_fixed(self) -> np.ndarray:
        """(3,) centre of part 1's grid."""
        return self.spectra.geometry.centre_fixed

    @property
    def centre_moving(self) -> np.ndarray:
        """(3,) centre of part 2's grid (its frame)."""
        return self.spectra.geometry.centre_moving

    @property
    def half_fixed(self) -> np.ndarray:
        """(3,) half extent of part 1's grid box."""
        return self.spectra.geometry.half_fixed

    @property
    def half_moving(self) -> np.ndarray:
        """(3,) half extent of part 2's grid box."""
        return self.spectra.geometry.half_moving
