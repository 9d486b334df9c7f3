"""Public functions of the skeletal density descriptor: mesh in, samples out.

Works on a mesh given as ``vertices (n, 3) float64`` and ``faces (m, 3) int64`` (outward
oriented) and a :class:`engine.grid.Grid`. For a query point ``p`` (docs/descriptor.md)::

    rho(p) = c(p) * sum over the boundary of  zeta^-2 * g_sigma(eta/|xi| - 1) * dA_perp

with ``xi`` the exact signed closest-point distance (+ outside), ``eta = |q - p|``,
``zeta = xi + i eta``, ``dA_perp = n.(q - p)/eta dA``, ``g_sigma`` the normal density and
``c = +lambda_in`` inside, ``-lambda_out`` outside. Membership is the winding number
thresholded at 0.5.

How it is computed
------------------
All geometry is moved to *local units*: coordinates relative to the grid centre divided by
the spacing ``h``. ``rho`` and the winding number are scale-free, so nothing else changes,
and float32 is then accurate for parts at 1e4 mm or 1e-3 mm alike.

Quadrature. The surface integral is a sum over pieces of triangles, each lumped at its
centroid (area vector at the centroid) with every second-order term of the integrand's
Taylor expansion over the piece (``Q`` its second moment about the centroid): eta at its
mean over the piece, ``w(eta) = zeta^-2 g`` varying along the ray (``(w''/w) u.Q.u / 2``),
the projection ``n.u`` changing across it (``-(w'/w) u.Q.u / eta``) and the direction ``u``
itself (``-(tr Q - 3 u.Q.u) / (2 eta^2)``); the error left is of third order. A piece of
radius ``r`` (about its centroid) at centroid distance ``d`` is cut in two at the
midpoint of its longest edge (so slivers are cut along their length only) while::

    r > THETA * max(d, EPS_FLOOR)   or   r > THETA * min(sigma, 0.5) * |xi| * tail(x)

The first test keeps the solid angle of every piece small; the second resolves the
Gaussian, which varies over a piece through ``eta/|xi|``, and is relaxed in its tail
(``tail(x) = exp(x^2/(4 sigma^2)) / max(1, x/sigma)`` at the piece's nearest possible
point, which keeps the expected error at the level of the peak's). The refinement is per
query point, so only pieces near ``p`` are split: the cost grows like
``log(size / |xi|)``. Pieces whose nearest possible point is farther than
``(1 + GAUSS_CUTOFF * sigma) |xi|`` are skipped: there
``g < exp(-GAUSS_CUTOFF^2 / 2) g(0) = 1.5e-8 g(0)``. With THETA = 0.7 the box values of
docs/descriptor.md are reproduced within 0.8% (the reference itself is good to about 0.5%),
and brute force is within 1.1e-4 (relative L2) of its own limit at THETA = 0.06.

Acceleration (``method="tree"``). A bounding-volume hierarchy over the triangles
(:mod:`engine.descriptor.tree`) serves three traversals per point: the exact nearest distance (box
pruning; over the triangles as given, in a second hierarchy when slivers were cut for the
other two), the winding number (Barnes-Hut: a cluster with radius below ``THETA_WINDING``
times its distance counts as a dipole, near triangles get their exact Van
Oosterom-Strackee solid angle) and the ``rho`` sum, where a whole cluster is skipped
beyond the Gaussian cut-off, lumped into one term when it passes the same two size tests
as a piece (``THETA_NODE`` in place of ``THETA``) and its bend ``1 - |N| / A`` times
``(r / d)^2`` is under ``NODE_BEND``, and otherwise opened; its triangles
then get the adaptive quadrature above. A lumped cluster uses its summed area vector at
its area-weighted centroid, its first moment ``S = sum N_i (g_i - c)^T`` (which removes
the first-order error of clusters whose normals differ: edges, corners, thin walls) and
its second moment (the same correction as a piece). ``method="brute"`` runs the same
quadrature on every triangle with no clusters: the reference the tree is tested against
(relative L2 difference below 1e-3; 3e-4 to 6e-4 measured on spheres and tori).

Regularisation. Let ``eps = EPS_FLOOR * h`` (1e-3 of a grid cell). A query point closer
than ``eps`` to the boundary (on it, or within a hair) takes its side from its height
above the nearest boundary point along the *boundary normal* (the sum of the distinct unit
normals of the triangles within ``TIE`` of the nearest distance: the face normal on a
face, the bisector on an edge or corner, whatever the triangulation), a point on the
boundary counting as inside; it is then evaluated at distance ``eps`` from its nearest
boundary point along that normal, on its side, and ``|xi|`` is floored at ``eps``. So
``zeta`` never vanishes, refinement stops at pieces of size ``THETA * eps``, the value on
a face is the one-sided limit the smooth formula has there, and on an edge a bounded
value between the faces' limits. Pieces are capped at ``MAX_LEVEL`` bisections, which the
floor never reaches for triangles smaller than about ``2^(MAX_LEVEL/2) * THETA * eps``.
Degenerate triangles have a zero area vector and contribute nothing (they still count
for the distance). Thin walls need nothing special: the distance and the quadrature are
exact per point and the tree's clusters carry their first moment.

Numbers used by both implementations (:mod:`engine.descriptor.numba_kernels` and
:mod:`engine.descriptor.opencl_kernels`) live in :mod:`engine.descriptor.constants`, so
they agree to float32 precision.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

import engine.descriptor.constants as _c
from engine.backend import Backend, choices, resolve
from engine.descriptor.adaptive import sample_grid
from engine.descriptor.numba_kernels import evaluate as _evaluate_numba
from engine.descriptor.opencl_kernels import OpenCLDescriptor, kernel_builds
from engine.descriptor.tree import TriangleTree, build_tree, pack_triangles, split_slivers
from engine.errors import Cancelled, InputError
from engine.grid import DESCRIPTOR_BYTES_PER_SAMPLE, Grid, check_memory
from engine.interrupt import call_interruptibly
from engine.params import SIGMA_GRID_MAX, SIGMA_RANGE, DescriptorParams

_log = logging.getLogger(__name__)

#: What ``backend=`` accepts.
BackendLike = Backend | str | None

#: Chunks of points are sized to take about this many seconds: cancel and Ctrl+C are
#: honoured between chunks. They start at FIRST_CHUNK_POINTS, grow at most fourfold per
#: chunk, and stay between MIN_CHUNK_POINTS and ``constants.CHUNK_POINTS``. (Kept here,
#: not in ``constants``: those are part of the descriptor's cache key, and chunking does
#: not change a single value.)
CHUNK_SECONDS = 0.02
#: The same for the OpenCL kernel. A launch there costs a fixed latency whatever the chunk
#: holds (1 to 20 ms on a GPU, launch, slowest work-item and read-back), and a chunk sized
#: by the rate of a small one stays small: on an H100 the 20 mm CAD plate's 32^3 grid ran
#: as 808 chunks of about 70 points, 20 ms each, 16 s, while its kernel did 32,768 points
#: in 35 ms. A quarter second still honours cancel well inside a second.
OPENCL_CHUNK_SECONDS = 0.25
#: Points a thread takes at a time within a chunk (numba's dynamic schedule). (Chunks of
#: 0.2 s cost 1.4 to 2 times the CPU of chunks of 0.02 s in one measurement, one thread
#: or two, a 48^3 grid of the 2e5-triangle torus: kept at 0.02 s. Batches of 8 cost 10 to
#: 40 % more CPU than 64 on the CAD peg at grid 24, three rounds: kept at 64.)
PARALLEL_BATCH = 64
FIRST_CHUNK_POINTS = 256
MIN_CHUNK_POINTS = 4
#: Triangles at which the first chunk is FIRST_CHUNK_POINTS; a larger mesh starts smaller,
#: in proportion. A point's cost grows with the triangles near it: on a 10^6-triangle STL
#: cylinder with fan caps a point took about a second (the caps' slivers all meet at their
#: centres, and no box of the tree separates them), so a first chunk of 256 points kept
#: Ctrl+C waiting for minutes; it starts at 4 points there.
FIRST_CHUNK_TRIANGLES = 20_000


def first_chunk_points(triangles: int) -> int:
    """Points in the first chunk for a mesh of ``triangles`` (later ones are sized by time)."""
    scaled = FIRST_CHUNK_POINTS * FIRST_CHUNK_TRIANGLES // max(int(triangles), 1)
    return max(MIN_CHUNK_POINTS, min(FIRST_CHUNK_POINTS, scaled))


# --------------------------------------------------------------------------------------
# Public interface


def _triangles(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Check a mesh and return its triangles, (m, 3, 3) float64."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"vertices must have shape (n, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InputError(f"faces must have shape (m, 3), got {f.shape}")
    if f.shape[0] == 0 or v.shape[0] == 0:
        raise InputError("the mesh is empty (no triangles): load a closed surface mesh")
    if not np.issubdtype(f.dtype, np.integer):
        raise InputError(f"faces must be integer vertex indices, got {f.dtype}")
    if f.min() < 0 or f.max() >= v.shape[0]:
        raise InputError(
            f"faces index vertices 0..{v.shape[0] - 1} but hold {int(f.min())}..{int(f.max())}"
        )
    used = v[np.unique(f)]
    if not np.all(np.isfinite(used)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(used), axis=1)))
        raise InputError(
            f"{bad} mesh vertices have non-finite (NaN or inf) coordinates: repair the mesh"
        )
    return v[f]


def _check_memory(n_points: int, what: str) -> None:
    check_memory(int(n_points) * DESCRIPTOR_BYTES_PER_SAMPLE, what,
                 "use a coarser grid (smaller --grid or larger --spacing)")


def check_grid_sigma(sigma: float) -> None:
    """Refuse a sigma above ``SIGMA_GRID_MAX`` for a grid (InputError): hours of work."""
    if sigma > SIGMA_GRID_MAX:
        raise InputError(
            f"sigma = {sigma:g} is above {SIGMA_GRID_MAX:g}, the most a descriptor on a grid "
            "allows: each sample near the surface then costs 50 ms or more (a 32-sample grid "
            "took 10 minutes at 50) while the density only scales as 1/sigma; use sigma from "
            f"{SIGMA_RANGE[0]:g} to {SIGMA_GRID_MAX:g}")


def _kernel_builds(backend: Backend) -> bool:
    """For "auto": whether the descriptor kernel compiles on ``backend`` (logged if not)."""
    if backend.name != "opencl" or kernel_builds(backend):
        return True
    _log.warning("OpenCL device %s cannot compile the descriptor kernel; using numba",
                 backend.device_name)
    return False


def resolve_backend(backend: BackendLike = None, device: str | None = None) -> Backend:
    """The backend that computes a descriptor: ``engine.backend.resolve("descriptor", ...)``.

    None or "auto" take the registry's choice for the descriptor (OpenCL where a device
    compiles its kernel, else numba, its reference); a name or a Backend is used as given
    and fails with its own error. ``device`` picks the OpenCL device (``SKELASM_DEVICE``
    by default).

    Raises
    ------
    ValueError
        A name or backend the descriptor has no kernels for.
    BackendError
        A backend asked for by name is unusable here.
    """
    if not (backend is None or isinstance(backend, (str, Backend))):
        raise ValueError(f"backend must be None, a Backend or one of "
                         f"{', '.join(choices('descriptor'))}; got {backend!r}")
    return resolve("descriptor", backend, device, usable=_kernel_builds)


@dataclass(frozen=True)
class _Local:
    """Triangles in local units and what maps points there."""

    centre: np.ndarray  # (3,)
    scale: float  # local = (x - centre) / scale
    tree: TriangleTree | None
    tri: np.ndarray  # (m, 16) packed, tree order if tree
    surface: TriangleTree | None = None  # the uncut triangles, for distances (None: tree)


def _localise(triangles: np.ndarray, centre: np.ndarray, scale: float, use_tree: bool) -> _Local:
    """Move triangles to local units; the tree gets slivers cut into short pieces.

    Brute force, the reference, sums over the triangles as given (no tree, no cutting).
    """
    local = (triangles - centre) / scale
    if not use_tree:
        return _Local(centre, scale, None, pack_triangles(local))
    pieces, _ = split_slivers(local, floor=_c.SPLIT_FLOOR, width_factor=_c.SPLIT_WIDTH,
                              budget=_c.SPLIT_BUDGET)  # fmt: skip
    tree = build_tree(pieces)
    # the nearest distance runs over the triangles as given (numba_kernels.evaluate)
    surface = tree if pieces.shape[0] == local.shape[0] else build_tree(local)
    return _Local(centre, scale, tree, tree.tri, surface)


def _run(
    local: _Local,
    points_local: np.ndarray,
    mode: int,
    params: DescriptorParams,
    backend: Backend,
    *,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    hints: np.ndarray | None = None,
) -> np.ndarray:
    """Evaluate points (n, 3) in local units; returns (n, 4) float64 (re, im, xi, w).

    ``hints`` (n, 2): a distance bound and a known side per point (see
    :func:`engine.descriptor.numba_kernels.evaluate`); the numba kernels use them, the
    OpenCL kernel computes without.
    """
    n = points_local.shape[0]
    out = np.empty((n, 4))
    if hints is None:
        hints = np.empty((n, 2))
        hints[:, 0] = np.inf
        hints[:, 1] = 0.0
    if backend.name == "opencl":
        runner = OpenCLDescriptor.for_backend(backend)
        evaluate = runner.prepare(local.tri, local.tree, params.sigma, params.lambda_in,
                                  params.lambda_out, surface=local.surface)

        def chunk(lo: int, hi: int) -> None:
            out[lo:hi] = evaluate(points_local[lo:hi], mode)
    else:
        if local.tree is not None:
            node, nidx = local.tree.node, local.tree.node_index
        else:
            node, nidx = np.zeros((1, 32)), np.full((1, 4), -1, dtype=np.int32)
        surface = local.surface
        if surface is None or local.tree is None:
            dtri, dnode, dnidx = local.tri, node, nidx
        else:
            dtri, dnode, dnidx = surface.tri, surface.node, surface.node_index
        kc = _c.kernel_constants()

        def chunk(lo: int, hi: int) -> None:
            # Points cost very different amounts (near the surface vs deep inside):
            # hand them to the threads in small batches rather than one half each.
            previous = numba.set_parallel_chunksize(PARALLEL_BATCH)
            try:
                _evaluate_numba(
                    np.ascontiguousarray(points_local[lo:hi]), local.tri, node, nidx,
                    dtri, dnode, dnidx, local.tree is not None, mode, params.sigma,
                    params.lambda_in, params.lambda_out, kc,
                    np.ascontiguousarray(hints[lo:hi]), out[lo:hi],
                )  # fmt: skip
            finally:
                numba.set_parallel_chunksize(previous)

    # Chunks are sized by time, not by count: a point's cost varies a hundredfold (sigma,
    # distance to the surface), and cancel and Ctrl+C (Python runs its signal handler only
    # between chunks) must be honoured within a second. Start small and grow towards
    # CHUNK_SECONDS per chunk (OPENCL_CHUNK_SECONDS on OpenCL).
    step = min(_c.CHUNK_POINTS, first_chunk_points(local.tri.shape[0]))
    seconds = OPENCL_CHUNK_SECONDS if backend.name == "opencl" else CHUNK_SECONDS
    lo = 0
    while lo < n:
        if cancel is not None and cancel():
            raise Cancelled("descriptor computation cancelled")
        hi = min(n, lo + step)
        started = time.perf_counter()
        # on a worker: Ctrl+C acts mid-chunk, however long a chunk of points takes
        call_interruptibly(chunk, lo, hi)
        took = time.perf_counter() - started
        if progress is not None:
            progress(hi / n)
        rate = (hi - lo) / max(took, 1e-6)
        step = int(max(MIN_CHUNK_POINTS, min(rate * seconds, 4 * (hi - lo),
                                             _c.CHUNK_POINTS)))
        lo = hi
    return out


def _method(method: str) -> bool:
    """Whether ``method`` uses the tree (``ValueError`` for an unknown one)."""
    if method not in _c.METHODS:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(_c.METHODS)}")
    return method != "brute"


def compute_descriptor(
    vertices: np.ndarray,
    faces: np.ndarray,
    grid: Grid,
    params: DescriptorParams = DescriptorParams(),  # noqa: B008 - frozen, so shared safely
    *,
    backend: BackendLike = None,
    method: str = "adaptive",
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> np.ndarray:
    """Skeletal density of a closed mesh on a grid (:func:`descriptor_and_side`'s rho)."""
    rho, _ = descriptor_and_side(vertices, faces, grid, params, backend=backend, method=method,
                                 progress=progress, cancel=cancel)
    return rho


def descriptor_and_side(
    vertices: np.ndarray,
    faces: np.ndarray,
    grid: Grid,
    params: DescriptorParams = DescriptorParams(),  # noqa: B008 - frozen, so shared safely
    *,
    backend: BackendLike = None,
    method: str = "adaptive",
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Skeletal density of a closed mesh on a grid, and which samples lie inside.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex coordinates in the part's frame.
    faces : (m, 3) int64
        Triangles, counter-clockwise seen from outside.
    grid : Grid
        Where to sample.
    params : DescriptorParams
        sigma, penalty and lambda_out.
    backend : None, Backend or {"numba", "opencl", "auto"}
        Compute backend; None picks as :func:`resolve_backend`.
    method : {"adaptive", "tree", "brute"}
        The hierarchy with adaptive sampling (exact where the field is rough, interpolated
        with a bounded error elsewhere; :mod:`engine.descriptor.adaptive`), the hierarchy
        at every grid point, or every triangle at every point (the reference).
    progress : callable(float), optional
        Called with the fraction done after each chunk of points.
    cancel : callable() -> bool, optional
        Polled between chunks; True raises :class:`engine.errors.Cancelled`.

    Returns
    -------
    rho : (nx, ny, nz) complex64
        The descriptor. Points within ``1e-3 * grid.spacing`` of the boundary are evaluated
        at that distance on their own side (see the module docstring, "Regularisation").
    inside : (nx, ny, nz) bool
        The side each sample took, whose factor ``c`` (``lambda_in`` or ``-lambda_out``)
        multiplies it: the sign of its signed distance. ``rho`` is linear in ``c``, so
        another penalty is ``rho`` rescaled on each side (``engine.descriptor.store``).

    Raises
    ------
    InputError
        Empty mesh, bad shapes or non-finite vertices.
    ResourceError
        The grid does not fit in memory.
    Cancelled
        ``cancel()`` returned True.
    """
    use_tree = _method(method)
    check_grid_sigma(params.sigma)
    triangles = _triangles(vertices, faces)
    _check_memory(grid.size, f"a {grid.shape[0]}x{grid.shape[1]}x{grid.shape[2]} grid")
    be = resolve_backend(backend)
    centre = grid.centre
    local = _localise(triangles, centre, grid.spacing, use_tree)
    if method == "adaptive":

        def evaluate(points: np.ndarray, part: Callable[[float], None] | None,
                     hints: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
            return _run(local, points, 2, params, be, progress=part, cancel=cancel,
                        hints=hints)

        xs, ys, zs = ((a - c) / grid.spacing for a, c in zip(grid.axes(), centre, strict=True))
        sampled, xi, _ = sample_grid(xs, ys, zs, evaluate, progress=progress)
        return sampled.astype(np.complex64), np.signbit(xi)
    points = ((grid.points().reshape(-1, 3) - centre) / grid.spacing).astype(np.float64)
    out = _run(local, points, 2, params, be, progress=progress, cancel=cancel)
    rho = (out[:, 0] + 1j * out[:, 1]).astype(np.complex64)
    # the kernel writes -dist inside (-0.0 on the boundary itself): the sign bit is the side
    return rho.reshape(grid.shape), np.signbit(out[:, 2]).reshape(grid.shape)


def _local_points(triangles: np.ndarray,
                  points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError("query points must be finite")
    lo = triangles.reshape(-1, 3).min(axis=0)
    hi = triangles.reshape(-1, 3).max(axis=0)
    centre = 0.5 * (lo + hi)
    scale = float(np.max(hi - lo))
    if not scale > 0:
        scale = 1.0
    return p, centre, scale


def _query(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, mode: int,
           backend: BackendLike, *, progress: Callable[[float], None] | None = None,
           cancel: Callable[[], bool] | None = None) -> tuple[np.ndarray, float]:
    """Point query ``mode`` (0 winding number, 1 signed distance) through the tree.

    Runs in the mesh's normalised frame; returns the (k, 4) float64 kernel output and the
    scale that normalised lengths.
    """
    triangles = _triangles(vertices, faces)
    p, centre, scale = _local_points(triangles, points)
    if p.shape[0] == 0:
        return np.zeros((0, 4)), scale
    local = _localise(triangles, centre, scale, True)
    out = _run(local, (p - centre) / scale, mode, DescriptorParams(), resolve_backend(backend),
               progress=progress, cancel=cancel)
    return out, scale


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, *,
                   backend: BackendLike = None) -> np.ndarray:  # fmt: skip
    """Generalised winding number of the mesh about each point.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    points : (k, 3) float64
    backend : None, Backend or {"numba", "opencl", "auto"}

    Returns
    -------
    (k,) float64
        1 inside, 0 outside (about 0.5 on the surface); threshold at 0.5 for membership.
        Uses the tree (Barnes-Hut with exact near triangles).
    """
    out, _ = _query(vertices, faces, points, 0, backend)
    return out[:, 3].copy()


def signed_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray, *,
                    backend: BackendLike = None,
                    progress: Callable[[float], None] | None = None,
                    cancel: Callable[[], bool] | None = None) -> np.ndarray:  # fmt: skip
    """Exact signed distance to the triangles, + outside, - inside (winding number > 0.5).

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    points : (k, 3) float64
    backend : None, Backend or {"numba", "opencl", "auto"}
    progress, cancel : callables, optional
        As :func:`compute_descriptor`'s.

    Returns
    -------
    (k,) float64
    """
    out, scale = _query(vertices, faces, points, 1, backend, progress=progress, cancel=cancel)
    return out[:, 2] * scale


def descriptor_at_points(
    vertices: np.ndarray,
    faces: np.ndarray,
    points: np.ndarray,
    params: DescriptorParams = DescriptorParams(),  # noqa: B008
    *,
    spacing: float,
    backend: BackendLike = None,
    method: str = "tree",
) -> np.ndarray:
    """Skeletal density at arbitrary points, as :func:`compute_descriptor` computes it.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    points : (k, 3) float64
    params : DescriptorParams
    spacing : float
        The grid spacing ``h`` the regularisation refers to (floor ``1e-3 h``).
    backend : None, Backend or {"numba", "opencl", "auto"}
    method : {"tree", "brute", "adaptive"}
        ``"adaptive"`` samples grids only: here it means ``"tree"`` (every point exact).

    Returns
    -------
    (k,) complex128
    """
    use_tree = _method(method)
    if not (math.isfinite(spacing) and spacing > 0):
        raise InputError(f"spacing must be a positive finite number, got {spacing!r}")
    triangles = _triangles(vertices, faces)
    p, centre, _ = _local_points(triangles, points)
    if p.shape[0] == 0:
        return np.zeros(0, dtype=np.complex128)
    local = _localise(triangles, centre, spacing, use_tree)
    out = _run(local, (p - centre) / spacing, 2, params, resolve_backend(backend))
    return out[:, 0] + 1j * out[:, 1]



def descriptor_slice(
    vertices: np.ndarray,
    faces: np.ndarray,
    grid: Grid,
    axis: int,
    index: int,
    params: DescriptorParams = DescriptorParams(),  # noqa: B008
    *,
    backend: BackendLike = None,
) -> np.ndarray:
    """One plane of the descriptor on ``grid`` at other parameters, every sample exact.

    The plane ``index`` along ``axis`` (0, 1, 2) of what :func:`compute_descriptor` would
    give with ``method="tree"``: a few thousand points, a fraction of a second, so the
    window previews a new sigma or penalty while its slider is held.

    Returns
    -------
    (nu, nv) complex64
        The plane; (u, v) the two remaining axes in increasing order.
    """
    if axis not in (0, 1, 2) or not 0 <= index < grid.shape[axis]:
        raise ValueError(f"no plane {index} along axis {axis} of a grid of shape {grid.shape}")
    axes = list(grid.axes())
    axes[axis] = axes[axis][index:index + 1]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    rho = descriptor_at_points(vertices, faces, points, params, spacing=grid.spacing,
                               backend=backend)
    return rho.reshape([len(a) for a in axes]).take(0, axis=axis).astype(np.complex64)
