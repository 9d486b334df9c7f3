"""The skeletal density descriptor of a part: mathematics, kernels, tree, store and cache.

Works on closed triangle meshes (``vertices (n, 3) float64``, ``faces (m, 3) int64``) and
regular grids (:class:`engine.grid.Grid`); produces ``rho (nx, ny, nz) complex64``.

Modules, bottom to top:

- :mod:`~engine.descriptor.constants`: the quadrature constants both kernels use;
- :mod:`~engine.descriptor.tree`: packed triangles and their bounding-volume hierarchy;
- :mod:`~engine.descriptor.numba_kernels` and :mod:`~engine.descriptor.opencl_kernels`:
  the per-point evaluation on the "numba" and "opencl" backends;
- :mod:`~engine.descriptor.compute`: the public functions (mesh checks, local units,
  backend choice, progress and cancel);
- :mod:`~engine.descriptor.store`: :class:`Descriptor` (samples plus provenance), ``.npz``
  files and the content-keyed cache;
- :mod:`~engine.descriptor.collision`: the collision-only density (the paper's baseline).

docs/descriptor.md gives the mathematics and the measurements.
"""

from engine.descriptor.collision import collision_density, collision_descriptor
from engine.descriptor.compute import (
    BackendLike,
    compute_descriptor,
    descriptor_at_points,
    descriptor_slice,
    resolve_backend,
    signed_distance,
    winding_number,
)
from engine.descriptor.constants import METHODS
from engine.descriptor.store import (
    Descriptor,
    descriptor_for_part,
    descriptors_for_scene,
    grid_for_part,
    scene_spacing,
)
from engine.descriptor.tree import TriangleTree, build_tree

__all__ = [
    "METHODS",
    "BackendLike",
    "Descriptor",
    "TriangleTree",
    "build_tree",
    "collision_density",
    "collision_descriptor",
    "compute_descriptor",
    "descriptor_at_points",
    "descriptor_slice",
    "descriptor_for_part",
    "descriptors_for_scene",
    "grid_for_part",
    "resolve_backend",
    "scene_spacing",
    "signed_distance",
    "winding_number",
]
