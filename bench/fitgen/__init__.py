"""A generator of unseen fits: random pairs of the families real products have, as scenes.

Models pairs with gmsh's OpenCASCADE kernel (a development dependency: ``pip install -e
".[assets]"``), writes them as CAD exporters do (STEP, STL, OBJ; mm or m; origins anywhere,
insertion axes in any direction), makes each a scene only through ``skelasm scene new``, and
records the fit's ground truth beside it (``fit.json``). See docs/generated_fits.md.

Modules: :mod:`~bench.fitgen.families` (the designs), :mod:`~bench.fitgen.kernel` (the CAD
kernel), :mod:`~bench.fitgen.export` (tessellation and files), :mod:`~bench.fitgen.scenes`
(``scene new``), :mod:`~bench.fitgen.truth` (the ground truth), :mod:`~bench.fitgen.checks`
(interference of two meshes), :mod:`~bench.fitgen.generate` (a seeded set).
"""

from bench.fitgen.families import FAMILIES, FitDesign
from bench.fitgen.generate import GeneratedPair, family_of, generate
from bench.fitgen.kernel import INSTALL_HINT, KernelMissing, require_gmsh
from bench.fitgen.truth import FitTruth, read_truth

__all__ = ["FAMILIES", "INSTALL_HINT", "FitDesign", "FitTruth", "GeneratedPair",
           "KernelMissing", "family_of", "generate", "read_truth", "require_gmsh"]
