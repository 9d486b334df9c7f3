"""Geometry the views need: mesh/plane cross-sections and arcball rotations.

Meshes are ``vertices (n, 3) float64`` and ``faces (m, 3) int64``; planes are axis-aligned
(axis 0, 1 or 2 at an offset) in the part's own frame.
"""

from __future__ import annotations

import numpy as np

AXES = ("x", "y", "z")


def axis_index(axis: str | int) -> int:
    """0, 1 or 2 for "x", "y", "z" (or the integer itself)."""
    if isinstance(axis, int | np.integer) and 0 <= int(axis) <= 2:
        return int(axis)
    if axis in AXES:
        return AXES.index(axis)
    raise ValueError(f"unknown axis {axis!r}; valid: x, y, z")


def section_segments(
    vertices: np.ndarray, faces: np.ndarray, axis: str | int, offset: float
) -> np.ndarray:
    """Cross-section of a triangle mesh with the plane ``x[axis] = offset``.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    axis : "x", "y", "z" or 0..2
    offset : float

    Returns
    -------
    (k, 2, 3) float64
        One segment (two end points) per triangle that the plane crosses.
    """
    a = axis_index(axis)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    d = v[:, a] - offset  # (n,) signed distance to the plane
    # Nudge vertices lying exactly on the plane so every crossing has two distinct edges.
    d = np.where(d == 0.0, 1e-12, d)
    df = d[f]  # (m, 3)
    crosses = (df.min(axis=1) < 0) & (df.max(axis=1) > 0)
    if not np.any(crosses):
        return np.zeros((0, 2, 3))
    f = f[crosses]
    df = df[crosses]
    pts = v[f]  # (k, 3, 3)
    segs = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        di, dj = df[:, i], df[:, j]
        hit = (di < 0) != (dj < 0)
        t = np.where(hit, di / np.where(hit, di - dj, 1.0), 0.0)
        p = pts[:, i] + t[:, None] * (pts[:, j] - pts[:, i])
        segs.append((hit, p))
    out = np.empty((len(f), 2, 3))
    # Exactly two of the three edges cross: take them in edge order.
    count = np.zeros(len(f), dtype=np.intp)
    for hit, p in segs:
        sel = hit & (count < 2)
        out[sel, count[sel]] = p[sel]
        count += sel
    return out[count == 2]


def arcball_vector(x: float, y: float, cx: float, cy: float, radius: float) -> np.ndarray:
    """(3,) unit vector on Shoemake's arcball for a screen point (y up, z towards the viewer)."""
    px = (x - cx) / radius
    py = (y - cy) / radius
    r2 = px * px + py * py
    if r2 > 1.0:
        s = 1.0 / np.sqrt(r2)
        return np.array([px * s, py * s, 0.0])
    return np.array([px, py, np.sqrt(1.0 - r2)])


def arcball_rotation(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """(3,) rotation vector turning unit vector ``v0`` into ``v1`` (shortest arc)."""
    axis = np.cross(v0, v1)
    s = float(np.linalg.norm(axis))
    c = float(np.clip(np.dot(v0, v1), -1.0, 1.0))
    if s < 1e-12:
        return np.zeros(3)
    return axis / s * float(np.arctan2(s, c))
