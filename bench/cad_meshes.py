"""Closed triangle meshes tessellated the way CAD exporters do, and well-shaped counterparts.

Each function returns ``vertices (n, 3) float64`` and ``faces (m, 3) int64`` (outward,
counter-clockwise seen from outside), in millimetres. A CAD exporter (a STEP or STL writer
over a B-rep) triangulates each face from its boundary alone: a cylinder's side becomes
strips of two triangles running its full length, a flat face with a circular edge becomes
a fan of long thin triangles from one boundary vertex. Such meshes have slivers whose
aspect ratio (longest edge over the altitude onto it) reaches the hundreds; the
benchmark (``skelasm bench descriptor``) and the descriptor's accuracy tests use them
beside well-shaped meshes of about the same triangle count.
"""

from __future__ import annotations

import numpy as np


def _ring(radius: float, segments: int, z: float, phase: float = 0.0) -> np.ndarray:
    """(segments, 3) points on a circle about the z axis at height z."""
    a = phase + 2.0 * np.pi * np.arange(segments) / segments
    return np.stack([radius * np.cos(a), radius * np.sin(a), np.full(segments, z)], axis=1)


def _fan(loop: np.ndarray, *, flip: bool) -> np.ndarray:
    """Fan triangles (k - 2, 3) over a closed polygon of vertex indices, from its first one."""
    f = np.stack([np.full(len(loop) - 2, loop[0]), loop[1:-1], loop[2:]], axis=1)
    return f[:, ::-1] if flip else f


def cad_peg(diameter: float = 8.0, length: float = 24.0,
            segments: int = 288) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A cylindrical peg as CAD exports it: full-length side strips, fans on the end caps.

    With the defaults (an 8 mm peg 24 mm long, 288 segments: 1,148 triangles) the side
    triangles are 24 mm long and 0.087 mm wide (aspect ratio about 275) and each cap is a
    fan of 286 triangles from one rim vertex.

    Returns
    -------
    vertices : (2 * segments, 3) float64
    faces : (4 * segments - 4, 3) int64
    """
    r = 0.5 * diameter
    n = int(segments)
    v = np.vstack([_ring(r, n, 0.0), _ring(r, n, length)])
    i = np.arange(n)
    j = (i + 1) % n
    side = np.vstack([np.stack([i, j, n + j], axis=1), np.stack([i, n + j, n + i], axis=1)])
    bottom = _fan(i, flip=True)
    top = _fan(n + i, flip=False)
    return v, np.vstack([side, bottom, top]).astype(np.int64)


def cad_plate_with_hole(size: float = 20.0, thickness: float = 6.0, hole: float = 8.0,
                        segments: int = 96) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """A square plate with a round through hole, as CAD exports it.

    The hole's wall is full-length strips; each flat face joins every hole vertex to the
    plate corner of its quadrant (long fans of slivers, the way a B-rep face with an inner
    loop is triangulated from its boundary alone); the four outer sides are two triangles
    each.

    Returns
    -------
    vertices : (2 * segments + 8, 3) float64
    faces : (4 * segments + 16, 3) int64
    """
    n = int(segments)
    if n % 4:
        raise ValueError(f"segments must be a multiple of 4, got {segments}")
    h = 0.5 * size
    r = 0.5 * hole
    # Hole vertices start half a step off the diagonals so each quadrant holds n/4 of them.
    ring_b = _ring(r, n, 0.0, phase=np.pi / n)
    ring_t = _ring(r, n, thickness, phase=np.pi / n)
    corners = np.array([(h, h), (-h, h), (-h, -h), (h, -h)], float)  # quadrants 0..3
    cb = np.column_stack([corners, np.zeros(4)])
    ct = np.column_stack([corners, np.full(4, thickness)])
    v = np.vstack([ring_b, ring_t, cb, ct])
    hb, ht, kb, kt = 0, n, 2 * n, 2 * n + 4
    faces = []
    i = np.arange(n)
    j = (i + 1) % n
    # Hole wall: its normals point into the hole (towards the axis), out of the solid.
    faces.append(np.stack([hb + i, ht + j, hb + j], axis=1))
    faces.append(np.stack([hb + i, ht + i, ht + j], axis=1))
    q = n // 4
    mid = q // 2
    for face_ring, corner, z_sign in ((hb, kb, -1.0), (ht, kt, 1.0)):
        tris = []
        for c in range(4):
            # Plate edge c runs from corner c (at 45 + 90 c degrees) to corner c + 1; hole
            # vertex k lies at (2 k + 1) 180 / n degrees, so edge c faces vertices
            # c q + q / 2 ... c q + q / 2 + q - 1. A fan from corner c over the first half of
            # them, one triangle to corner c + 1, a fan from corner c + 1 over the rest, and
            # one triangle across the diagonal to the next edge's first vertex.
            idx = face_ring + (c * q + mid + np.arange(q + 1)) % n
            a, b = corner + c, corner + (c + 1) % 4
            tris += [(idx[k], idx[k + 1], a) for k in range(mid)]
            tris.append((idx[mid], a, b))
            tris += [(idx[k], idx[k + 1], b) for k in range(mid, q)]
        t = np.asarray(tris)
        p = v[t]
        nz = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
        flip = nz * z_sign < 0
        t[flip] = t[flip][:, ::-1]
        faces.append(t)
    # Outer sides.
    for c in range(4):
        a, b = c, (c + 1) % 4
        faces.append(np.array([(kb + a, kb + b, kt + b), (kb + a, kt + b, kt + a)]))
    return v, np.vstack(faces).astype(np.int64)


def torus(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A well-shaped torus (major radius 10 mm, minor 3.5 mm) with about ``triangles``."""
    import trimesh

    minor = max(3, int(round(np.sqrt(triangles / 5.0))))
    major = max(3, int(round(triangles / (2.0 * minor))))
    m = trimesh.creation.torus(10.0, 3.5, major_sections=major, minor_sections=minor)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def well_shaped_peg(diameter: float = 8.0, length: float = 24.0,
                    triangles: int = 1150) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The peg of :func:`cad_peg` with nearly equilateral triangles (about ``triangles``).

    Side: rings spaced about one chord apart, alternate rings rotated half a step; caps:
    concentric rings down to the centre.
    """
    import trimesh
    from scipy.spatial import Delaunay

    r = 0.5 * diameter
    # Solve for the segment count n: side ~ 2 n rows, caps ~ n^2 / (2 pi) each.
    area = np.pi * diameter * length + 2 * np.pi * r * r
    edge = np.sqrt(4.0 * area / (np.sqrt(3.0) * triangles))
    n = max(8, int(round(2 * np.pi * r / edge)))
    rows = max(1, int(round(length / (edge * np.sqrt(3.0) / 2.0))))
    pts = []
    for k in range(rows + 1):
        pts.append(_ring(r, n, length * k / rows, phase=np.pi * (k % 2) / n))
    side_v = np.vstack(pts)
    faces = []
    for k in range(rows):
        a = k * n + np.arange(n)
        b = (k + 1) * n + np.arange(n)
        a1 = k * n + (np.arange(n) + 1) % n
        b1 = (k + 1) * n + (np.arange(n) + 1) % n
        if k % 2 == 0:
            faces.append(np.stack([a, a1, b], axis=1))
            faces.append(np.stack([a1, b1, b], axis=1))
        else:
            faces.append(np.stack([a, b1, b], axis=1))
            faces.append(np.stack([a, a1, b1], axis=1))
    # Caps: a disc of points (rings of decreasing count), Delaunay in the plane.
    disc = [np.zeros((1, 2))]
    n_rings = max(1, int(round(r / edge)))
    for k in range(1, n_rings):
        rk = r * k / n_rings
        m = max(6, int(round(2 * np.pi * rk / edge)))
        a = 2 * np.pi * np.arange(m) / m
        disc.append(np.stack([rk * np.cos(a), rk * np.sin(a)], axis=1))
    inner = np.vstack(disc)
    v = [side_v]
    offset = side_v.shape[0]
    for ring_start, z, up in ((0, 0.0, False), (rows * n, length, True)):
        rim = side_v[ring_start : ring_start + n, :2]
        flat = np.vstack([rim, inner])
        tri = Delaunay(flat).simplices
        index = np.concatenate([ring_start + np.arange(n), offset + np.arange(len(inner))])
        cap = index[tri]
        # Orient: normal +z on top, -z at the bottom.
        p = flat[tri]
        cross = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (
            p[:, 1, 1] - p[:, 0, 1]
        ) * (p[:, 2, 0] - p[:, 0, 0])
        flip = (cross < 0) if up else (cross > 0)
        cap[flip] = cap[flip][:, ::-1]
        faces.append(cap)
        v.append(np.column_stack([inner, np.full(len(inner), z)]))
        offset += len(inner)
    mesh = trimesh.Trimesh(np.vstack(v), np.vstack(faces), process=True)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)


def aspect_ratios(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) longest edge over the altitude onto it (about 1.15 for an equilateral)."""
    t = vertices[faces]
    edges = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 1], t[:, 0] - t[:, 2]], axis=1)
    longest = np.sqrt((edges**2).sum(axis=2)).max(axis=1)
    area2 = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
    return longest**2 / np.maximum(area2, 1e-300)


def well_shaped_plate_with_hole(size: float = 20.0, thickness: float = 6.0, hole: float = 8.0,
                                triangles: int = 400) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The plate of :func:`cad_plate_with_hole` with nearly equilateral triangles.

    Flat faces: a Delaunay triangulation of the square's and the hole's boundary points and
    a hexagonal lattice between them; walls and sides: rows of points about one edge apart.
    """
    import trimesh
    from scipy.spatial import Delaunay

    h = 0.5 * size
    r = 0.5 * hole
    area = 2 * (size * size - np.pi * r * r) + 2 * np.pi * r * thickness + 4 * size * thickness
    edge = np.sqrt(4.0 * area / (np.sqrt(3.0) * triangles))
    n_hole = max(8, int(round(2 * np.pi * r / edge)))
    n_side = max(2, int(round(size / edge)))
    rows = max(1, int(round(thickness / edge)))
    s = np.linspace(-h, h, n_side + 1)[:-1]
    square = np.vstack([np.column_stack([s, np.full_like(s, -h)]),
                        np.column_stack([np.full_like(s, h), s]),
                        np.column_stack([-s, np.full_like(s, h)]),
                        np.column_stack([np.full_like(s, -h), -s])])  # fmt: skip
    a = 2 * np.pi * np.arange(n_hole) / n_hole
    ring = np.column_stack([r * np.cos(a), r * np.sin(a)])
    lattice = []
    dy = edge * np.sqrt(3.0) / 2.0
    for j, y in enumerate(np.arange(-h, h + 1e-9, dy)):
        xs = np.arange(-h + (0.5 * edge if j % 2 else 0.0), h + 1e-9, edge)
        lattice += [(x, y) for x in xs]
    lat = np.asarray(lattice)
    rr = np.hypot(lat[:, 0], lat[:, 1])
    ok = (rr > r + 0.6 * edge) & (np.abs(lat).max(axis=1) < h - 0.6 * edge)
    flat = np.vstack([square, ring, lat[ok]])
    tri = Delaunay(flat).simplices
    centre = flat[tri].mean(axis=1)
    tri = tri[np.hypot(centre[:, 0], centre[:, 1]) > r]
    verts = [np.column_stack([flat, np.zeros(len(flat))]),
             np.column_stack([flat, np.full(len(flat), thickness)])]  # fmt: skip
    faces = [tri, tri + len(flat)]
    offset = 2 * len(flat)
    # Walls (hole and outer sides): rows of the boundary loops, quads cut in two.
    for loop in (ring, square):
        k = len(loop)
        for row in range(rows + 1):
            verts.append(np.column_stack([loop, np.full(k, thickness * row / rows)]))
        i = np.arange(k)
        j = (i + 1) % k
        for row in range(rows):
            lo, hi = offset + row * k, offset + (row + 1) * k
            faces.append(np.stack([lo + i, lo + j, hi + j], axis=1))
            faces.append(np.stack([lo + i, hi + j, hi + i], axis=1))
        offset += (rows + 1) * k
    v = np.vstack(verts)
    f = np.vstack(faces)
    # Orient outward: the flat faces along -z / +z, the hole wall towards the axis, the
    # outer sides away from it.
    t = v[f]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    c = t.mean(axis=1)
    radial = np.column_stack([c[:, 0], c[:, 1], np.zeros(len(c))])
    on_flat = np.abs(normal[:, 2]) > 0.5 * np.linalg.norm(normal, axis=1)
    in_hole = np.hypot(c[:, 0], c[:, 1]) < r + 1e-6
    want = np.where(on_flat[:, None], np.column_stack([np.zeros((len(c), 2)),
                                                       c[:, 2] - 0.5 * thickness]),
                    np.where(in_hole[:, None], -radial, radial))  # fmt: skip
    flip = (normal * want).sum(axis=1) < 0
    f[flip] = f[flip][:, ::-1]
    mesh = trimesh.Trimesh(v, f, process=True)
    return np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
