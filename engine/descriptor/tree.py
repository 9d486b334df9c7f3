"""Packed triangle data and a bounding-volume hierarchy over a triangle soup.

Works on triangles in ``(m, 3, 3)`` float form (vertex coordinates, usually already in the
descriptor's local units: relative to the grid centre, divided by the spacing). Everything
is packed into flat arrays so that the numba reference and the OpenCL kernels read exactly
the same layout:

- ``tri`` ``(m, 16)``: ``a`` (3), ``e1 = b - a`` (3), ``e2 = c - a`` (3), the area vector
  ``N = (e1 x e2) / 2`` (3, outward for counter-clockwise faces seen from outside), the
  radius of the triangle about its centroid (1), three unused.
- ``node`` ``(n, 32)``: bounding box ``lo`` (3), ``hi`` (3), the area-weighted centroid ``c``
  (3), the summed area vector (3), a radius about ``c`` that bounds every vertex below the
  node (1), total area (1), the bend ``1 - |N| / A`` (1: 0 for a flat cluster), one unused,
  then the first moment
  ``S[a, b] = sum_i N_i[a] (g_i - c)[b]`` (9, row-major; ``g_i`` the triangle centroids),
  which lets a lumped cluster be integrated to second order (see engine.descriptor.compute),
  then the area-normalised second moment of the cluster about ``c``
  ``Q = (1/A) sum_i integral (q - c)(q - c)^T dA`` as xx, yy, zz, xy, xz, yz (6), one unused.
- ``node_index`` ``(n, 4)`` int32: left child, right child (``-1`` for a leaf), first
  triangle, number of triangles. Children always have larger indices than their parent.

The tree is built top-down by median split along the longest axis of the triangle
centroids' bounding box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

#: Triangles per leaf.
LEAF_SIZE = 4


@dataclass(frozen=True)
class TriangleTree:
    """Packed triangles and their hierarchy.

    Attributes
    ----------
    tri : (m, 16) float64
        Packed triangles in tree order (see module docstring).
    node : (n, 32) float64
        Packed node geometry.
    node_index : (n, 4) int32
        Children and triangle ranges.
    order : (m,) int64
        ``order[k]`` is the input index of the triangle stored at ``k``.
    depth : int
        Depth of the tree (root alone = 1).
    """

    tri: np.ndarray
    node: np.ndarray
    node_index: np.ndarray
    order: np.ndarray
    depth: int

    @property
    def n_triangles(self) -> int:
        """Number of triangles."""
        return int(self.tri.shape[0])


def pack_triangles(triangles: np.ndarray) -> np.ndarray:
    """Pack triangles for the kernels.

    Parameters
    ----------
    triangles : (m, 3, 3) float
        Vertex coordinates.

    Returns
    -------
    (m, 16) float64
    """
    t = np.asarray(triangles, dtype=np.float64)
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    e1 = b - a
    e2 = c - a
    area_vector = 0.5 * np.cross(e1, e2)
    centroid = (a + b + c) / 3.0
    radius = np.sqrt(np.max(np.sum((t - centroid[:, None, :]) ** 2, axis=2), axis=1))
    packed = np.zeros((t.shape[0], 16))
    packed[:, 0:3] = a
    packed[:, 3:6] = e1
    packed[:, 6:9] = e2
    packed[:, 9:12] = area_vector
    packed[:, 12] = radius
    return packed


@numba.njit(cache=True)
def _split(centroids, leaf_size):  # pragma: no cover - compiled
    m = centroids.shape[0]
    order = np.arange(m)
    max_nodes = 2 * m + 1
    index = np.full((max_nodes, 4), -1, dtype=np.int32)
    depth_of = np.zeros(max_nodes, dtype=np.int64)
    stack = np.empty(256, dtype=np.int64)
    index[0, 2] = 0
    index[0, 3] = m
    depth_of[0] = 1
    n_nodes = 1
    sp = 0
    stack[sp] = 0
    sp += 1
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        start = index[nd, 2]
        count = index[nd, 3]
        if count <= leaf_size:
            continue
        idx = order[start : start + count].copy()
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for k in range(count):
            for d in range(3):
                v = centroids[idx[k], d]
                lo[d] = min(lo[d], v)
                hi[d] = max(hi[d], v)
        axis = 0
        for d in range(1, 3):
            if hi[d] - lo[d] > hi[axis] - lo[axis]:
                axis = d
        keys = np.empty(count)
        for k in range(count):
            keys[k] = centroids[idx[k], axis]
        perm = np.argsort(keys, kind="mergesort")
        for k in range(count):
            order[start + k] = idx[perm[k]]
        half = count // 2
        left = n_nodes
        right = n_nodes + 1
        n_nodes += 2
        index[nd, 0] = left
        index[nd, 1] = right
        index[left, 2] = start
        index[left, 3] = half
        index[right, 2] = start + half
        index[right, 3] = count - half
        depth_of[left] = depth_of[nd] + 1
        depth_of[right] = depth_of[nd] + 1
        stack[sp] = left
        stack[sp + 1] = right
        sp += 2
    return order, index[:n_nodes], depth_of[:n_nodes].max()


@numba.njit(cache=True)
def _node_geometry(tri, index):  # pragma: no cover - compiled
    n = index.shape[0]
    node = np.zeros((n, 32))
    for nd in range(n - 1, -1, -1):
        left = index[nd, 0]
        right = index[nd, 1]
        if left < 0:
            start = index[nd, 2]
            count = index[nd, 3]
            lo = np.full(3, np.inf)
            hi = np.full(3, -np.inf)
            area_vec = np.zeros(3)
            weighted = np.zeros(3)
            area_sum = 0.0
            for k in range(start, start + count):
                area = np.sqrt(tri[k, 9] ** 2 + tri[k, 10] ** 2 + tri[k, 11] ** 2)
                for d in range(3):
                    a = tri[k, d]
                    b = a + tri[k, 3 + d]
                    c = a + tri[k, 6 + d]
                    lo[d] = min(lo[d], a, b, c)
                    hi[d] = max(hi[d], a, b, c)
                    area_vec[d] += tri[k, 9 + d]
                    weighted[d] += area * (a + (tri[k, 3 + d] + tri[k, 6 + d]) / 3.0)
                area_sum += area
            if area_sum > 0.0:
                centre = weighted / area_sum
            else:
                centre = 0.5 * (lo + hi)
            moment = np.zeros((3, 3))
            for k in range(start, start + count):
                for a in range(3):
                    for b in range(3):
                        g = tri[k, b] + (tri[k, 3 + b] + tri[k, 6 + b]) / 3.0
                        moment[a, b] += tri[k, 9 + a] * (g - centre[b])
            second = np.zeros((3, 3))
            if area_sum > 0.0:
                for k in range(start, start + count):
                    area = np.sqrt(tri[k, 9] ** 2 + tri[k, 10] ** 2 + tri[k, 11] ** 2)
                    g = np.empty(3)
                    for b in range(3):
                        g[b] = tri[k, b] + (tri[k, 3 + b] + tri[k, 6 + b]) / 3.0
                    for corner in range(3):
                        dv = np.empty(3)
                        for b in range(3):
                            v = tri[k, b]
                            if corner == 1:
                                v += tri[k, 3 + b]
                            elif corner == 2:
                                v += tri[k, 6 + b]
                            dv[b] = v - g[b]
                        # Covariance of a triangle: (1/12) sum over corners of d d^T.
                        for a in range(3):
                            for b in range(3):
                                second[a, b] += area * dv[a] * dv[b] / 12.0
                    for a in range(3):
                        for b in range(3):
                            second[a, b] += area * (g[a] - centre[a]) * (g[b] - centre[b])
                second /= area_sum
            radius = 0.0
            for k in range(start, start + count):
                for corner in range(3):
                    r2 = 0.0
                    for d in range(3):
                        v = tri[k, d]
                        if corner == 1:
                            v += tri[k, 3 + d]
                        elif corner == 2:
                            v += tri[k, 6 + d]
                        r2 += (v - centre[d]) ** 2
                    radius = max(radius, np.sqrt(r2))
        else:
            lo = np.minimum(node[left, 0:3], node[right, 0:3])
            hi = np.maximum(node[left, 3:6], node[right, 3:6])
            area_vec = node[left, 9:12] + node[right, 9:12]
            al = node[left, 13]
            ar = node[right, 13]
            area_sum = al + ar
            if area_sum > 0.0:
                centre = (al * node[left, 6:9] + ar * node[right, 6:9]) / area_sum
            else:
                centre = 0.5 * (lo + hi)
            # A bound, not the tightest sphere: child sphere pushed out by the offset.
            rl = np.sqrt(np.sum((node[left, 6:9] - centre) ** 2)) + node[left, 12]
            rr = np.sqrt(np.sum((node[right, 6:9] - centre) ** 2)) + node[right, 12]
            radius = max(rl, rr)
            # The box gives another bound; keep the smaller.
            far = np.maximum(np.abs(hi - centre), np.abs(lo - centre))
            radius = min(radius, np.sqrt(np.sum(far**2)))
            second = np.zeros((3, 3))
            if area_sum > 0.0:
                for child in (left, right):
                    wgt = node[child, 13] / area_sum
                    q = node[child, 25:31]
                    qc = np.array([[q[0], q[3], q[4]], [q[3], q[1], q[5]], [q[4], q[5], q[2]]])
                    off = node[child, 6:9] - centre
                    for a in range(3):
                        for b in range(3):
                            second[a, b] += wgt * (qc[a, b] + off[a] * off[b])
            moment = np.zeros((3, 3))
            for child in (left, right):
                for a in range(3):
                    for b in range(3):
                        moment[a, b] += node[child, 16 + 3 * a + b] + node[child, 9 + a] * (
                            node[child, 6 + b] - centre[b]
                        )
        node[nd, 0:3] = lo
        node[nd, 3:6] = hi
        node[nd, 6:9] = centre
        node[nd, 9:12] = area_vec
        node[nd, 12] = radius
        node[nd, 13] = area_sum
        for a in range(3):
            for b in range(3):
                node[nd, 16 + 3 * a + b] = moment[a, b]
        node[nd, 25] = second[0, 0]
        node[nd, 26] = second[1, 1]
        node[nd, 27] = second[2, 2]
        node[nd, 28] = second[0, 1]
        node[nd, 29] = second[0, 2]
        node[nd, 30] = second[1, 2]
    return node


def split_slivers(triangles: np.ndarray, *, floor: float, width_factor: float,
                  budget: int) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Cut long thin triangles across their length into short pieces.

    A sliver (a CAD exporter's full-length strip or fan) spans far more space than its
    area fills: every cluster of the hierarchy that holds one is as long as the sliver, so
    no cluster near it can be lumped and every query point opens every sliver (measured on
    a CAD peg: 888 of 1,148 triangles opened per point, against 110 for a well-shaped
    mesh). Cut into pieces no longer than ``max(floor, width_factor * w)`` (``w`` the
    triangle's altitude onto its longest edge), the slivers cluster side by side into
    compact patches, as a well-shaped mesh does.

    A triangle ``(o, p, q)`` whose shortest edge is ``pq`` is cut by ``n - 1`` lines
    parallel to ``pq`` at equal steps from ``o``: a small triangle at ``o`` and ``n - 1``
    strips of two triangles each, all with the triangle's orientation. The pieces tile
    the triangle exactly, so the surface, its integral, winding number and distances are
    unchanged (T-junctions between pieces change none of them). Triangles no longer than
    ``width_factor * w`` (well-shaped ones, whatever their size) are not cut.

    Parameters
    ----------
    triangles : (m, 3, 3) float64
        Vertex coordinates, in local units (grid cells).
    floor : float
        Pieces are never cut shorter than this (grid cells).
    width_factor : float
        Longest piece, in multiples of its triangle's width.
    budget : int
        Most pieces (at least ``m``); past it the floor is doubled until the pieces fit.

    Returns
    -------
    pieces : (k, 3, 3) float64
    source : (k,) int64
        Index in ``triangles`` of each piece's triangle.
    """
    t = np.asarray(triangles, dtype=np.float64)
    m = t.shape[0]
    if not floor > 0:
        raise ValueError(f"floor must be positive, got {floor!r}")
    budget = max(int(budget), m)
    # Edge j runs from corner j to corner j + 1 and is opposite corner j + 2.
    edges = np.stack([t[:, 1] - t[:, 0], t[:, 2] - t[:, 1], t[:, 0] - t[:, 2]], axis=1)
    lengths = np.sqrt((edges**2).sum(axis=2))  # (m, 3)
    longest = lengths.max(axis=1)
    area2 = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
    width = area2 / np.where(longest > 0, longest, 1.0)
    while True:
        target = np.maximum(floor, width_factor * width)
        n = np.maximum(1, np.ceil(longest / target - 1e-9)).astype(np.int64)
        if int(np.sum(2 * n - 1)) <= budget:
            break
        floor *= 2.0
    cut = np.nonzero(n > 1)[0]
    keep = np.nonzero(n == 1)[0]
    if cut.size == 0:
        return t, np.arange(m, dtype=np.int64)
    short = np.argmin(lengths[cut], axis=1)
    rows = cut
    p = t[rows, short]
    q = t[rows, (short + 1) % 3]
    o = t[rows, (short + 2) % 3]
    # Corners in the order (o, p, q) are a cyclic shift of the original: same orientation.
    counts = n[cut]
    tri_of = np.repeat(np.arange(cut.size), counts)  # (total strips,)
    first = np.cumsum(counts) - counts
    k = np.arange(tri_of.size) - first[tri_of]
    t0 = (k / counts[tri_of])[:, None]
    t1 = ((k + 1) / counts[tri_of])[:, None]
    oo, pp, qq = o[tri_of], p[tri_of], q[tri_of]
    p0, p1 = oo + t0 * (pp - oo), oo + t1 * (pp - oo)
    q0, q1 = oo + t0 * (qq - oo), oo + t1 * (qq - oo)
    lower = np.stack([p0, p1, q1], axis=1)  # at k = 0 this is (o, p1, q1)
    upper_rows = k > 0  # at k = 0 the second triangle (o, q1, o) is empty
    upper = np.stack([p0, q1, q0], axis=1)[upper_rows]
    pieces = np.concatenate([t[keep], lower, upper])
    source = np.concatenate([keep, cut[tri_of], cut[tri_of[upper_rows]]]).astype(np.int64)
    return pieces, source


def build_tree(triangles: np.ndarray, *, leaf_size: int = LEAF_SIZE) -> TriangleTree:
    """Build the hierarchy.

    Parameters
    ----------
    triangles : (m, 3, 3) float
        Vertex coordinates, ``m >= 1``.
    leaf_size : int
        Largest number of triangles in a leaf (leaves of triangles with coincident
        centroids may hold more).

    Returns
    -------
    TriangleTree
    """
    t = np.asarray(triangles, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (3, 3) or t.shape[0] < 1:
        raise ValueError(f"triangles must have shape (m, 3, 3) with m >= 1, got {t.shape}")
    centroids = t.mean(axis=1)
    order, index, depth = _split(centroids, int(leaf_size))
    tri = pack_triangles(t[order])
    node = _node_geometry(tri, index)
    # how far a cluster is from flat: 0 for a plane patch, 1 for a closed surface
    node[:, 14] = 1.0 - np.linalg.norm(node[:, 9:12], axis=1) / np.maximum(node[:, 13], 1e-300)
    return TriangleTree(tri, node, np.ascontiguousarray(index, dtype=np.int32), order, int(depth))
