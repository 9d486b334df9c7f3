"""Quadrature constants of the skeletal density: every number both kernels use.

Lengths are in *local units* (grid cells; see :mod:`engine.descriptor.compute`). The numba
kernels receive these values as arguments (:func:`kernel_constants`), never as globals, so
that a changed constant cannot be served from numba's on-disk cache of an old compile; the
OpenCL kernel receives them as build options and arguments. Each value is explained where
it is used (docs/descriptor.md gives the whole method).
"""

from __future__ import annotations

from typing import NamedTuple

#: Floor on |xi| and the normal push distance, in grid cells.
EPS_FLOOR = 1e-3
#: Largest piece radius / distance (and / sigma |xi|) before a piece is split. A piece is
#: flat, so its lumped term has no second-order error (numba_kernels._radial): at 0.7 the
#: brute-force sum is within 1.1e-4 of a converged one (docs/descriptor.md).
THETA = 0.7
#: Largest cluster radius / distance (and / sigma |xi|) for a lumped cluster. Clusters are
#: curved, and their error (mostly far from the part, where they are large) is what this
#: trades against time (with NODE_BEND: docs/descriptor.md).
THETA_NODE = 0.6
#: A cluster is opened when its bend (1 - |N| / A, its summed area vector against its
#: area; about a^2 / 4 for a spherical cap of angular radius a) times (radius / distance)^2
#: exceeds this. A lumped cluster's third moment is taken as N Q, which curvature breaks:
#: with large clusters far from a small part (a pin 2 to 3 cells across on a coarse grid)
#: the error reached 2e-3 to 3.5e-3 without this test.
NODE_BEND = 0.002
#: The Gaussian size test uses min(sigma, SIGMA_RESOLUTION): a wide Gaussian still gets
#: pieces no coarser than at the default sigma (the 1/r^2-like kernel needs them anyway).
SIGMA_RESOLUTION = 0.5
#: Barnes-Hut opening ratio for the winding number.
THETA_WINDING = 0.35
#: Pieces and clusters beyond (1 + GAUSS_CUTOFF * sigma) |xi| are skipped.
GAUSS_CUTOFF = 6.0
#: Distances within TIE (grid cells) count as equal when picking the nearest triangle.
TIE = 1e-4
#: Most distinct face normals summed into the boundary normal at an edge or corner.
MAX_NORMALS = 8
#: Deepest subdivision of one triangle (bisections; a piece's area is 2^-level of it).
MAX_LEVEL = 90
#: Explicit stack sizes (pieces: one per level + 1; nodes: tree depth + 1).
PIECE_STACK = 96
NODE_STACK = 64

#: Slivers are cut across their length (engine.descriptor.tree.split_slivers) into pieces
#: no longer than SPLIT_WIDTH times their width, but no shorter than SPLIT_FLOOR grid
#: cells; at most SPLIT_BUDGET pieces (past it the floor grows). Well-shaped triangles
#: (longest edge under SPLIT_WIDTH times the altitude onto it) are never cut.
SPLIT_WIDTH = 3.0
SPLIT_FLOOR = 0.1
SPLIT_BUDGET = 1_000_000

#: Adaptive sampling (engine.descriptor.adaptive): coarse levels below the grid, the
#: largest estimated trilinear error of an interpolated sample (a fraction of the RMS of
#: rho), and the clearance from the surface of an interpolated cube (in cube sides).
ADAPTIVE_LEVELS = 2
ADAPTIVE_TOLERANCE = 3e-3
ADAPTIVE_CLEARANCE = 1.0
#: A tricubic stencil must not span the medial axis: second differences of the signed
#: distance within ADAPTIVE_KINK times the spacing (engine.descriptor.adaptive._no_kink).
ADAPTIVE_KINK = 0.25

#: Evaluation methods: the hierarchy with adaptive sampling of grids (exact where the
#: field is rough, interpolated elsewhere), the hierarchy at every point, or every
#: triangle at every point (the reference).
METHODS = ("adaptive", "tree", "brute")
#: Points evaluated between progress reports / cancel checks.
CHUNK_POINTS = 32768


class KernelConstants(NamedTuple):
    """The constants as one value the numba kernels take as an argument."""

    theta: float
    theta_node: float
    theta_winding: float
    eps: float
    gauss_cutoff: float
    sigma_resolution: float
    tie: float
    max_normals: int
    max_level: int
    piece_stack: int
    node_stack: int
    node_bend: float


def kernel_constants() -> KernelConstants:
    """The current module values (read at call time, so a test may patch one)."""
    return KernelConstants(
        float(THETA), float(THETA_NODE), float(THETA_WINDING), float(EPS_FLOOR),
        float(GAUSS_CUTOFF), float(SIGMA_RESOLUTION), float(TIE), int(MAX_NORMALS),
        int(MAX_LEVEL), int(PIECE_STACK), int(NODE_STACK), float(NODE_BEND),
    )  # fmt: skip


def as_dict() -> dict[str, float | int | str | tuple[str, ...]]:
    """Every constant by name (part of the descriptor cache key)."""
    return {k: v for k, v in sorted(globals().items())
            if k.isupper() and isinstance(v, (int, float, str, tuple))}  # fmt: skip
