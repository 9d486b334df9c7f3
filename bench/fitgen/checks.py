"""Checks of a generated fit's truth: how deep two meshes interpenetrate at a pose.

Data: two triangle meshes, ``vertices (n, 3) float64`` and ``faces (m, 3) int64``, each in
its own file's frame and the scene's unit, and part 2's pose ``(6,)`` in part 1's frame.
"""

from __future__ import annotations

import numpy as np


def _depth_into(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> float:
    """Deepest of ``points`` (k, 3) inside the (nearly) closed mesh.

    The winding number says inside (above 0.5; T-junctions change it by a sliver's worth
    only), the exact distance to the triangles how deep.
    """
    import trimesh

    from engine.descriptor import winding_number

    inside = winding_number(vertices, faces, points) > 0.5
    if not inside.any():
        return 0.0
    mesh = trimesh.Trimesh(np.asarray(vertices), np.asarray(faces), process=False)
    _, distance, _ = trimesh.proximity.closest_point(mesh, np.asarray(points)[inside])
    return float(distance.max())


def _surface_points(vertices: np.ndarray, faces: np.ndarray, count: int,
                    seed: int) -> np.ndarray:
    """(n + count, 3) the vertices and ``count`` points spread by area over the surface."""
    rng = np.random.default_rng(seed)
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (m, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(tri), size=count, p=area / area.sum())
    u, v = rng.uniform(size=(2, count))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    samples = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    return np.vstack([vertices, samples])


def interference(fixed: tuple[np.ndarray, np.ndarray], moving: tuple[np.ndarray, np.ndarray],
                 pose: np.ndarray, *, samples: int = 20000) -> float:
    """Deepest interpenetration of part 2 at ``pose`` (6,) relative to part 1 (scene units).

    Points of either surface (its vertices and ``samples`` random points) that lie inside
    the other part, and how far inside. Touching faces give rounding-sized depths.

    The meshes are measured scaled to about a hundred units across: trimesh's closest-point
    search has absolute tolerances, and on a part in metres it gave distances of 0.1 mm
    for points touching the surface.
    """
    from engine.pose import pose_to_matrix

    fv, mv = np.asarray(fixed[0], np.float64), np.asarray(moving[0], np.float64)
    scale = 100.0 / float(np.linalg.norm(np.ptp(fv, axis=0)))
    fixed, moving = (fv * scale, fixed[1]), (mv * scale, moving[1])
    m = pose_to_matrix(np.asarray(pose, float))
    rot, shift = m[:3, :3], m[:3, 3] * scale
    pm = _surface_points(*moving, samples, 1) @ rot.T + shift   # part 2's points, frame 1
    pf = (_surface_points(*fixed, samples, 2) - shift) @ rot     # part 1's points, frame 2
    return max(_depth_into(*fixed, pm), _depth_into(*moving, pf)) / scale
