"""Where a second part opened beside a first one starts: where its file draws it.

Two parts exported from one CAD assembly share its frame: each file draws its part where it
sits in the product, so the second part is placed at the first part's pose and the pair
appears as drawn. Files drawn each about its own origin (two centred meshes) put the parts
inside each other; there the part is parked clear of the first one instead, and the reason
says so.
"""

from __future__ import annotations

import numpy as np

from engine.loading import Part
from engine.pose import pose_to_matrix

#: Surface points of the moving part tested for lying inside the fixed part.
SAMPLES = 400
#: A point counts as inside when it lies deeper than this fraction of the moving part's
#: box diagonal (the faceting of a fit with no clearance stays below it).
DEPTH_FRACTION = 0.01
#: The parts interpenetrate where more than this share of the points lies inside.
INSIDE_SHARE = 0.02
#: Parked: the gap above the fixed part, in its heights.
PARK_GAP = 0.75


def interpenetration(fixed: Part, moving: Part, relative: np.ndarray) -> float:
    """Share of the moving part's surface (area-weighted samples) inside the fixed part.

    ``relative`` (6,) is the moving part's pose relative to the fixed part. A point counts
    where it lies deeper than :data:`DEPTH_FRACTION` of the moving part's box diagonal
    (trimesh's signed distance, positive inside). The samples are the same for the same
    mesh (a fixed seed).
    """
    import trimesh

    mesh1 = trimesh.Trimesh(fixed.vertices, fixed.faces, process=False)
    mesh2 = trimesh.Trimesh(moving.vertices, moving.faces, process=False)
    if len(mesh1.faces) == 0 or len(mesh2.faces) == 0:
        return 0.0
    points, _ = trimesh.sample.sample_surface(mesh2, SAMPLES, seed=0)
    m = pose_to_matrix(np.asarray(relative, np.float64))
    points = points @ m[:3, :3].T + m[:3, 3]
    depth = trimesh.proximity.signed_distance(mesh1, points)
    diagonal = float(np.linalg.norm(np.ptp(moving.vertices, axis=0)))
    return float(np.mean(depth > DEPTH_FRACTION * diagonal))


def parked_pose(fixed: Part, moving: Part, first_pose: np.ndarray) -> np.ndarray:
    """(6,) world pose that puts the moving part above the fixed one (+z), clear of it."""
    v1, v2 = fixed.vertices, moving.vertices
    height = float(np.ptp(v1[:, 2])) if len(v1) else 1.0
    pose = np.array(first_pose, dtype=np.float64).reshape(6)
    # the moving part's lowest point a gap above the fixed part's highest (both unrotated)
    pose[2] += float(v1[:, 2].max() - v2[:, 2].min()) + PARK_GAP * height
    return pose


def place_second(fixed: Part, moving: Part, first_pose: np.ndarray
                 ) -> tuple[np.ndarray, str]:
    """(world pose (6,), reason) for a second part opened beside ``fixed``.

    Where its file draws it (the first part's pose, so the two files' frames coincide),
    unless the parts interpenetrate there (:func:`interpenetration` over
    :data:`INSIDE_SHARE`); then :func:`parked_pose`.
    """
    first_pose = np.asarray(first_pose, np.float64).reshape(6)
    share = interpenetration(fixed, moving, np.zeros(6))
    if share > INSIDE_SHARE:
        return parked_pose(fixed, moving, first_pose), (
            f"{moving.name}: its file draws it inside {fixed.name} ({share:.0%} of its "
            f"surface), so it starts above it; Edit > Set up the fit or Find fits sets its "
            "seat")
    return first_pose.copy(), (f"{moving.name}: placed where its file draws it beside "
                               f"{fixed.name}, its seat there until Edit > Set up the fit or "
                               "Find fits sets another")
