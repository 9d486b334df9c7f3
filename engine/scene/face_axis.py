"""The axis of a picked face: a bore's or a shaft's axis, or a flat face's normal.

Setting up a fit, a user points at a hole's wall (or a peg's side) instead of typing its
axis. From the picked triangle the face is grown over neighbours that meet it smoothly
(:data:`SMOOTH_DEGREES` between normals: a tessellated cylinder's facets, not the sharp
edge where a bore meets a flat face). Its area-weighted normals give the axis: a round face's
normals all lie across its axis, so the axis is the direction of least normal scatter
(the scatter ``sum a n n^T`` has one eigenvalue near 0 and two near 1/2); a flat face's
normals all agree (one eigenvalue near 1), and its normal is the axis. A round face's axis
line and radius come from a least-squares fit of ``p = c + r n`` across the axis (``r < 0``
for a hole, whose normals point at its axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Neighbouring triangles whose normals differ by less than this belong to one face.
SMOOTH_DEGREES = 40.0
#: A round face: the least scatter below this share, the middle one above FLAT_SCATTER.
ROUND_SCATTER = 0.06
#: A flat face: the largest scatter above this share (all normals within about 18 deg).
FLAT_SCATTER = 0.9
#: Faces of a round patch whose normals turn further than this from across the axis (a
#: fillet's flat end, a chamfer) are left out of the second estimate.
ACROSS_DEGREES = 20.0


class FaceAxisError(ValueError):
    """The picked face has no clear axis (a cone, a sphere, a free-form patch)."""


@dataclass(frozen=True)
class FaceAxis:
    """The axis of a picked face, in the mesh's frame.

    Attributes
    ----------
    kind : str
        ``"hole"`` (a round face whose normals point at its axis), ``"shaft"`` (outwards), or
        ``"flat"``.
    direction : (3,) float64
        Unit vector along the axis (a flat face: its outward normal, unless oriented).
    point : (3,) float64
        A point on the axis (a flat face: its area-weighted centre).
    radius : float
        The round face's radius; 0 for a flat one.
    faces : (m,) int64
        The triangles taken as the face.
    """

    kind: str
    direction: np.ndarray
    point: np.ndarray
    radius: float
    faces: np.ndarray


def smooth_region(vertices: np.ndarray, faces: np.ndarray, start: int,
                  degrees: float = SMOOTH_DEGREES) -> np.ndarray:
    """Triangles reached from ``start`` across edges where the normals turn by < ``degrees``."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    normals = mesh.face_normals
    pairs = mesh.face_adjacency
    smooth = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) > np.cos(
        np.radians(degrees))
    keep = pairs[smooth]
    neighbours: list[list[int]] = [[] for _ in range(len(faces))]
    for a, b in keep:
        neighbours[a].append(int(b))
        neighbours[b].append(int(a))
    seen = np.zeros(len(faces), bool)
    seen[start] = True
    stack = [int(start)]
    while stack:
        for n in neighbours[stack.pop()]:
            if not seen[n]:
                seen[n] = True
                stack.append(n)
    return np.flatnonzero(seen)


def face_axis(vertices: np.ndarray, faces: np.ndarray, picked: int,
              towards: np.ndarray | None = None) -> FaceAxis:
    """The axis of the face the triangle ``picked`` lies on (see the module docstring).

    ``towards`` (3,), where given, orients the direction: it points from that point to the
    face (a moving part's centre, so the axis is the way the part travels to a hole).

    Raises
    ------
    FaceAxisError
        The face is neither round nor flat (the message says what was found and what to do).
    """
    import trimesh

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if not 0 <= picked < len(faces):
        raise FaceAxisError(f"triangle {picked} is not on the part ({len(faces)} triangles)")
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    region = smooth_region(vertices, faces, picked)
    normals = mesh.face_normals[region]
    areas = mesh.area_faces[region]
    centres = mesh.triangles_center[region]
    scatter, basis = _scatter(normals, areas)
    if scatter[2] > FLAT_SCATTER:
        direction = basis[:, 2] * np.sign(basis[:, 2] @ (normals.T @ areas) or 1.0)
        point = areas @ centres / areas.sum()
        return _oriented(FaceAxis("flat", direction, point, 0.0, region), towards)
    if not (scatter[0] < ROUND_SCATTER and scatter[1] > 0.5 * (1.0 - FLAT_SCATTER)):
        raise FaceAxisError(
            f"the picked face ({len(region)} triangles) is neither round nor flat (its "
            f"normals' spread {scatter[0]:.2f}, {scatter[1]:.2f}, {scatter[2]:.2f}): pick a "
            "bore's wall, a shaft's side or a flat face, or type the axis")
    axis = basis[:, 0]
    across = np.abs(normals @ axis) < np.sin(np.radians(ACROSS_DEGREES))
    if across.sum() >= 3 and not across.all():  # a fillet or chamfer taken in: drop it
        region, normals, areas, centres = (region[across], normals[across], areas[across],
                                           centres[across])
        axis = _scatter(normals, areas)[1][:, 0]
    u = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    # p = c + r n across the axis: unknowns c_u, c_v, r (area-weighted least squares)
    a = np.zeros((2 * len(region), 3))
    a[0::2, 0], a[1::2, 1] = 1.0, 1.0
    a[0::2, 2], a[1::2, 2] = normals @ u, normals @ v
    b = np.empty(2 * len(region))
    b[0::2], b[1::2] = centres @ u, centres @ v
    w = np.sqrt(np.repeat(areas, 2))
    (cu, cv, r), *_ = np.linalg.lstsq(a * w[:, None], b * w, rcond=None)
    along = float(areas @ (centres @ axis) / areas.sum())
    point = cu * u + cv * v + along * axis
    kind = "hole" if r < 0 else "shaft"
    return _oriented(FaceAxis(kind, axis, point, float(abs(r)), region), towards)


def _scatter(normals: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors (columns) of the area-weighted scatter."""
    m = (normals * areas[:, None]).T @ normals / areas.sum()
    return np.linalg.eigh(m)


def _oriented(found: FaceAxis, towards: np.ndarray | None) -> FaceAxis:
    d = np.asarray(found.direction, np.float64)
    d = d / np.linalg.norm(d)
    if towards is not None and float((found.point - np.asarray(towards, float)) @ d) < 0:
        d = -d
    return FaceAxis(found.kind, d, np.asarray(found.point, np.float64), found.radius,
                    np.asarray(found.faces, np.int64))
