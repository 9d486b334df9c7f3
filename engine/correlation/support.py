"""Where a descriptor's outside tail ends: a window that follows the part, not its grid.

A part's skeletal density has an outside tail that fades slowly (about ``-i lambda_out``
at the surface, a few tenths of it a part's width away). The descriptor samples it on a
box-shaped grid, axis-aligned in the part's own frame, a few cells (the scene's
``padding``) beyond the part's bounds, and the correlation takes the density to be zero
beyond. Where the box cuts the tail depends on how the part lies in its frame: a part
turned in its file is cut nearer on one side than on the other, and the correlation then
pushes a part that sits on a symmetric fit towards one side. On a generated rectangular
peg 3 mm above its blind pocket (both parts turned at random in their files, grid 2.3 mm,
K = 25) the band pushed the centred peg sideways with 1.4e4, 3.5 times the coupling's
force at 1 mm off; with this window (and the ball band: the "smooth" band of
``engine.correlation.spectrum.BANDS``, which windows the densities)
2.0e3.

The window is 1 within part's convex hull (of its inside samples) and out to half the
room the grid leaves around that hull, then falls smoothly to 0 where the nearest side of
the grid is: a function of the part's shape alone, so the tail ends at the same distance
in every direction and turns with the part. Inside the hull (pockets, holes, the gap of a
fit) nothing changes.
"""

from __future__ import annotations

import numpy as np

from engine.grid import Grid

#: The window falls from 1 to 0 between these fractions of the room the grid leaves around
#: the part's hull (the least distance, in cells, from the hull to the grid's sides).
SUPPORT_TAPER = (0.5, 1.0)
#: Below this room (cells) the grid leaves no tail to shape: the window is not applied.
MIN_ROOM = 2.0
_CHUNK = 16384


def hull_distance(inside: np.ndarray) -> np.ndarray | None:
    """(nx, ny, nz) float64: distance in cells outside the hull of the ``inside`` samples.

    The largest signed distance to the hull's facet planes: 0 or less within the hull, the
    exact distance where the nearest point of the hull is on a facet, and a little less
    near its edges and corners (a smooth, convex function either way). None when the inside
    samples span no volume (fewer than four, or all in a plane).
    """
    from scipy.spatial import ConvexHull, QhullError

    idx = np.argwhere(inside)
    if len(idx) < 4:
        return None
    # the hull's vertices lie among the samples on the inside set's outer faces: thin the
    # set to those whose six neighbours are not all inside before calling qhull
    padded = np.pad(inside, 1)
    core = padded[1:-1, 1:-1, 1:-1].copy()
    for axis in range(3):
        for step in (-1, 1):
            core &= np.roll(padded, step, axis=axis)[1:-1, 1:-1, 1:-1]
    rim = np.argwhere(inside & ~core).astype(np.float64)
    try:
        planes = ConvexHull(rim).equations  # (f, 4): unit normal, offset; inside <= 0
    except (QhullError, ValueError):
        return None
    # on a lattice of about half the samples along each axis, read in between linearly:
    # the distance is Lipschitz and convex, and its taper spans cells. The lattice is
    # spread evenly from the first sample to the last, so it is as symmetric as the grid
    # (every second sample from the first is not, on an even count, and a mirror-symmetric
    # pair then felt a force across its plane)
    axes = [np.linspace(0.0, n - 1.0, max(2, (n + 1) // 2 + 1)) for n in inside.shape]
    points = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    best = np.empty(len(points))
    for start in range(0, len(points), _CHUNK):  # (chunk, f) plane distances at a time
        block = points[start:start + _CHUNK] @ planes[:, :3].T + planes[:, 3]
        best[start:start + _CHUNK] = block.max(axis=1)
    coarse = best.reshape(tuple(len(a) for a in axes))
    out = coarse
    for axis, (a, n) in enumerate(zip(axes, inside.shape, strict=True)):  # linear reads
        full = np.arange(n, dtype=np.float64)
        i = np.clip(np.searchsorted(a, full, side="right") - 1, 0, len(a) - 2)
        f = (full - a[i]) / (a[i + 1] - a[i])
        shape = [1, 1, 1]
        shape[axis] = n
        f = f.reshape(shape)
        out = np.take(out, i, axis=axis) * (1.0 - f) + np.take(out, i + 1, axis=axis) * f
    return out


def support_window(rho: np.ndarray, grid: Grid) -> np.ndarray | None:
    """(nx, ny, nz) float32 window for ``rho`` on ``grid`` (None: leave it as it is).

    The inside samples are those of positive imaginary part (the density is about ``+i
    lambda_in`` inside and ``-i lambda_out`` outside); the window is 1 to
    ``SUPPORT_TAPER[0]`` of the room around their hull and 0 from ``SUPPORT_TAPER[1]`` of
    it, a smoothstep between.
    """
    rho = np.asarray(rho)
    if rho.ndim != 3 or tuple(rho.shape) != tuple(grid.shape):
        raise ValueError(f"descriptor shape {rho.shape} does not match its grid {grid.shape}")
    distance = hull_distance(rho.imag > 0)
    if distance is None:
        return None
    faces = [distance[0], distance[-1], distance[:, 0], distance[:, -1],
             distance[:, :, 0], distance[:, :, -1]]
    room = float(min(f.min() for f in faces))
    if not room >= MIN_ROOM:
        return None
    lo, hi = SUPPORT_TAPER[0] * room, SUPPORT_TAPER[1] * room
    z = np.clip((distance - lo) / (hi - lo), 0.0, 1.0)
    return (1.0 - z * z * (3.0 - 2.0 * z)).astype(np.float32)


def supported(rho: np.ndarray, grid: Grid) -> np.ndarray:
    """``rho`` times its :func:`support_window` (``rho`` itself where there is none)."""
    window = support_window(rho, grid)
    if window is None:
        return rho
    return (np.asarray(rho) * window).astype(np.complex64)
