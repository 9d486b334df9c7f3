"""The axis of a picked face: a bore's or a shaft's axis, or a flat face's normal.

Setting up a fit, a user points at a hole's wall (or a peg's side) instead of typing its
axis. From the picked triangle the face is grown over neighbours that meet it smoothly
(:data:`SMOOTH_DEGREES` between normals: a tessellated cylinder's facets, not the sharp
edge where a bore meets a flat face) whose normals lie across one axis: a round face's
normals all do, and the axis is then their direction of least scatter (the area-weighted
``sum a n n^T`` has one eigenvalue near 0). A chamfer between a bore and a flat face meets
both smoothly enough to be taken for one surface, but its normals are at 45 degrees to the
axis, so it is left out. A flat face's normals all agree, and its normal is the axis. A
round face's axis line and radius come from a least-squares fit of ``p = c + r n`` across
the axis (``r < 0`` for a hole, whose normals point at its axis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Neighbouring triangles whose normals differ by less than this may belong to one face (a
#: tessellated cylinder's facets: 45 degrees apart on an 8-sided bore).
SMOOTH_DEGREES = 50.0
#: A round face's triangles: normals within this of square to its axis. A tessellated
#: cylinder's facets need not lie along its rulings (the bundled block's bore: up to 4.4
#: degrees off); a chamfer's normals, at 45 degrees, and a flat end's are far beyond.
ACROSS_DEGREES = 10.0
#: Most of a round face's area has normals within this of square to its axis (a ruled
#: wall, :func:`_ruled`).
RULED_DEGREES = 2.5
#: The largest root-mean-square distance of a round face's facets from its cylinder, in
#: radii (an inscribed polygon's facet centres lie on one: r cos(pi / n)).
CYLINDER_MISFIT = 0.05
#: A round face's picked facet, with those coplanar with it, holds less than this share of
#: it (an 8-sided bore: an eighth). A flat end picked beside a fillet makes a region, across
#: an axis along the end, of the end and two strips of the side that one circle touches.
SEED_PLANE_SHARE = 0.25
#: A flat face's triangles: normals within this of the picked one (a CAD face's facets agree
#: exactly; a fine sphere's neighbours turn by a degree or more).
FLAT_DEGREES = 0.5
#: A round face spans at least this angle around its axis (its normals' largest spread).
ROUND_SPAN_DEGREES = 20.0


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


def face_axis(vertices: np.ndarray, faces: np.ndarray, picked: int,
              towards: np.ndarray | None = None) -> FaceAxis:
    """The axis of the face the triangle ``picked`` lies on (see the module docstring).

    Each neighbour the picked triangle meets smoothly (its normal turned by
    :data:`FLAT_DEGREES` to :data:`SMOOTH_DEGREES`) proposes an axis, the two normals'
    cross product; from the picked triangle the region of smoothly joined triangles whose
    normals lie across that axis (within :data:`ACROSS_DEGREES`) is grown, and the proposal
    with the largest region wins, its axis then fitted to the region and the region grown
    again. A chamfer or a flat end beside a bore is never taken in, since its normals do not
    lie across the axis. The face is round where that region spans
    :data:`ROUND_SPAN_DEGREES` around its axis and the coplanar region (normals within
    :data:`FLAT_DEGREES` of the picked one) covers less than half of it (a flat face beside
    a fillet is flat); else flat, where at least two triangles are coplanar or the picked
    one meets no other smoothly.

    ``towards`` (3,), where given, orients the direction: it points from that point to the
    face (a moving part's centre, so the axis is the way the part travels to a hole).

    Raises
    ------
    FaceAxisError
        The face is neither round nor flat (the message says so and what to do).
    """
    import trimesh

    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if not 0 <= picked < len(faces):
        raise FaceAxisError(f"triangle {picked} is not on the part ({len(faces)} triangles)")
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    # coincident vertices joined (an STL's triangles each have their own), so that facets
    # meeting along an edge are neighbours; the triangles keep their order
    mesh.merge_vertices()
    if len(mesh.faces) != len(faces):
        raise FaceAxisError("the part's triangles changed when its vertices were joined")
    normals, areas = mesh.face_normals, mesh.area_faces
    neighbours = _smooth_neighbours(mesh)
    seed = normals[picked]
    across = np.sin(np.radians(ACROSS_DEGREES))
    flat = _grow(neighbours, picked, normals @ seed > np.cos(np.radians(FLAT_DEGREES)))
    best: FaceAxis | None = None
    proposed = False
    for j in neighbours.indices[neighbours.indptr[picked]:neighbours.indptr[picked + 1]]:
        axis = np.cross(seed, normals[j])
        if np.linalg.norm(axis) < np.sin(np.radians(FLAT_DEGREES)):
            continue  # coplanar: no axis from this pair
        proposed = True
        axis /= np.linalg.norm(axis)
        region = _grow(neighbours, picked, np.abs(normals @ axis) < across)
        axis = _scatter(normals[region], areas[region])[1][:, 0]
        region = _grow(neighbours, picked, np.abs(normals @ axis) < across)
        if (_spread_degrees(normals[region]) < ROUND_SPAN_DEGREES
                or _largest_plane(region, normals, areas) >= 0.5 * areas[region].sum()
                or areas[flat].sum() >= SEED_PLANE_SHARE * areas[region].sum()
                or not _ruled(region, np.abs(normals @ axis), areas)):
            continue
        found = _round(mesh, region, _scatter(normals[region], areas[region])[1][:, 0])
        if found is not None and (best is None
                                  or areas[region].sum() > areas[best.faces].sum()):
            best = found
    if best is not None:
        return _oriented(best, towards)
    if proposed and len(flat) < 2:
        raise FaceAxisError(
            "the picked face is neither round nor flat (its triangles turn, but not about "
            "one axis: a sphere, a cone, a free-form patch): pick a bore's wall, a shaft's "
            "side or a flat face, or type the axis")
    point = areas[flat] @ mesh.triangles_center[flat] / areas[flat].sum()
    return _oriented(FaceAxis("flat", seed.copy(), point, 0.0, flat), towards)


def _smooth_neighbours(mesh):
    """(n, n) sparse graph: triangles sharing a vertex and turned < SMOOTH_DEGREES.

    A shared vertex, not a shared edge: an exported mesh's T-junctions (a vertex in the
    middle of a neighbour's edge) leave facets of one wall without a common edge, but never
    without a common vertex.
    """
    from scipy import sparse

    faces = np.asarray(mesh.faces)
    n = len(faces)
    incidence = sparse.csr_matrix(
        (np.ones(faces.size), (np.repeat(np.arange(n), 3), faces.ravel())),
        shape=(n, len(mesh.vertices)))
    shared = (incidence @ incidence.T).tocoo()
    normals = mesh.face_normals
    keep = (shared.row != shared.col) & (np.einsum(
        "ij,ij->i", normals[shared.row], normals[shared.col]) > np.cos(
        np.radians(SMOOTH_DEGREES)))
    return sparse.csr_matrix((np.ones(int(keep.sum()), np.int8),
                              (shared.row[keep], shared.col[keep])), shape=(n, n))


def _ruled(region: np.ndarray, off: np.ndarray, areas: np.ndarray) -> bool:
    """Whether most of a round region's area lies exactly across its axis.

    ``off`` holds each triangle's ``|n . axis|``. A cylinder's wall is ruled: its facets'
    normals lie square to the axis (a fillet's first rows beside it do not, and may still
    be taken in); a sphere's band across the same axis spreads its normals evenly over
    :data:`ACROSS_DEGREES` either way, so only about a quarter of it lies within
    :data:`RULED_DEGREES`.
    """
    exact = off[region] < np.sin(np.radians(RULED_DEGREES))
    return bool(areas[region][exact].sum() >= 0.5 * areas[region].sum())


def _grow(graph, start: int, allowed: np.ndarray) -> np.ndarray:
    """Triangles reached from ``start`` through smooth neighbours that are ``allowed``."""
    from scipy.sparse.csgraph import connected_components

    allowed = allowed.copy()
    allowed[start] = True
    index = np.flatnonzero(allowed)
    _, labels = connected_components(graph[index][:, index], directed=False)
    return index[labels == labels[int(np.searchsorted(index, start))]]


def _spread_degrees(normals: np.ndarray) -> float:
    """The largest angle between any normal and the region's mean direction, doubled."""
    mean = normals.mean(axis=0)
    n = float(np.linalg.norm(mean))
    if n < 1e-9:
        return 180.0
    return 2.0 * float(np.degrees(np.arccos(np.clip(np.min(normals @ (mean / n)), -1, 1))))


def _largest_plane(region: np.ndarray, normals: np.ndarray, areas: np.ndarray) -> float:
    """Area of the region's triangles coplanar (within FLAT_DEGREES) with its largest one.

    A round face has no plane holding half of it (a 48-sided bore: a 48th); a region that
    took in a flat face beside a chamfer and a wall does.
    """
    big = region[int(np.argmax(areas[region]))]
    same = normals[region] @ normals[big] > np.cos(np.radians(FLAT_DEGREES))
    return float(areas[region][same].sum())


def _round(mesh, region: np.ndarray, axis: np.ndarray) -> FaceAxis | None:
    """A round face's axis line and radius, or None where its facets share no cylinder.

    Each facet is a plane tangent to a cylinder of radius ``r`` about the line through
    ``c``: ``n . c + r = n . p`` across ``axis`` (``p`` the facet's centre, ``r < 0`` for a
    hole), solved by area-weighted least squares over the ruled facets (those square to the
    axis, :data:`RULED_DEGREES`). An inscribed polygon's facets fit it exactly, at ``r
    cos(pi / n)``. None where they miss it by more than :data:`CYLINDER_MISFIT` of ``r``
    (root mean square).
    """
    normals, areas = mesh.face_normals[region], mesh.area_faces[region]
    centres = mesh.triangles_center[region]
    ruled = np.abs(normals @ axis) < np.sin(np.radians(RULED_DEGREES))
    u = np.cross(axis, np.eye(3)[int(np.argmin(np.abs(axis)))])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    a = np.column_stack([normals @ u, normals @ v, np.ones(len(region))])[ruled]
    b = np.einsum("ij,ij->i", normals, centres)[ruled]
    w = np.sqrt(areas[ruled])
    (cu, cv, r), *_ = np.linalg.lstsq(a * w[:, None], b * w, rcond=None)
    misfit = (a @ np.array([cu, cv, r]) - b) * w
    if not float(np.sqrt(misfit @ misfit / areas[ruled].sum())) < CYLINDER_MISFIT * abs(r):
        return None
    along = float(areas @ (centres @ axis) / areas.sum())
    point = cu * u + cv * v + along * axis
    # the radius the CAD model has: its ruled facets' corners lie on the cylinder
    corners = mesh.vertices[np.unique(mesh.faces[region[ruled]])] - point
    radius = float(np.mean(np.linalg.norm(corners - np.outer(corners @ axis, axis), axis=1)))
    # outward normals point away from a shaft's axis: n . (p - c) = r > 0
    return FaceAxis("shaft" if r > 0 else "hole", axis, point, radius, region)


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
