"""Grouping poses that put part 2 in the same place, whatever its symmetries.

Works on poses of part 2 ((3, 3) float64 rotations, (3,) translations) and on points of
part 2's surface in its own frame ((n, 3) float64). Two poses are alike when the point sets
they produce lie close as *sets* (each point's nearest point of the other set, both ways,
read at the 90th percentile):
a round peg turned about its axis, or a square one by a quarter turn, puts its surface where
it was, and the two poses are one fit. A distance between rotations and translations alone
would count them as many.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


def surface_spread(points: np.ndarray) -> float:
    """The diagonal of the points' bounding box (the size distances are measured against)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 1.0


def placed(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """(n, 3) ``points`` moved by ``(rotation, translation)``."""
    return np.asarray(points) @ np.asarray(rotation).T + np.asarray(translation)


#: The share of points whose nearest distance :func:`set_distance` reads: a key on a shaft
#: (a fifth of its surface) turned to the wrong side must count, where a mean would drown it
#: in the shaft's points that still lie on the shaft.
QUANTILE = 0.9


def set_distance(a: np.ndarray, b: np.ndarray, tree_b: cKDTree | None = None) -> float:
    """How far point sets ``a`` and ``b`` lie apart.

    The :data:`QUANTILE` of the points' nearest distances to the other set, the larger of
    both ways.
    """
    tb = tree_b if tree_b is not None else cKDTree(b)
    ab = float(np.quantile(tb.query(a)[0], QUANTILE))
    ba = float(np.quantile(cKDTree(a).query(b)[0], QUANTILE))
    return max(ab, ba)


@dataclass(frozen=True)
class Clusters:
    """Groups of poses, each led by its lowest-energy member.

    Attributes
    ----------
    leaders : (c,) int64
        Row of each cluster's leader, lowest energy first.
    members : tuple of (m,) int64
        Rows of each cluster's members (the leader first).
    """

    leaders: np.ndarray
    members: tuple[np.ndarray, ...]

    def sizes(self) -> np.ndarray:
        """(c,) int64 members per cluster."""
        return np.array([len(m) for m in self.members], dtype=np.int64)


def cluster_poses(rotations: np.ndarray, translations: np.ndarray, energies: np.ndarray,
                  points: np.ndarray, radius: float) -> Clusters:
    """Greedy clustering, as ClusPro's: the lowest pose left leads a cluster.

    Every pose left within ``radius`` of the leader joins its cluster.

    Parameters
    ----------
    rotations : (n, 3, 3) float64
    translations : (n, 3) float64
    energies : (n,) float64
    points : (p, 3) float64
        Part 2's surface points in its own frame.
    radius : float
        Set distance (scene unit) within which two poses are one fit.

    Returns
    -------
    Clusters
    """
    n = len(energies)
    order = np.lexsort((np.arange(n), energies))
    pts = np.asarray(points, dtype=np.float64)
    centre = pts.mean(axis=0)
    centres = np.einsum("nij,j->ni", rotations, centre) + translations  # (n, 3)
    # a symmetric part's centroid stays put under its symmetries, so poses whose centroids
    # lie far apart cannot give the same surface: the set distance is needed only near
    reach = 2.0 * radius + 1e-9
    # every pose's points, placed once: (n, p, 3)
    moved = np.matmul(pts[None], np.transpose(rotations, (0, 2, 1))) + translations[:, None, :]
    left = np.ones(n, dtype=bool)
    leaders: list[int] = []
    members: list[np.ndarray] = []
    for row in order:
        if not left[row]:
            continue
        left[row] = False
        near = np.flatnonzero(left & (np.linalg.norm(centres - centres[row], axis=1) < reach))
        near = near[np.lexsort((near, energies[near]))]  # members lowest first
        group = [int(row)]
        for other in near[_within(moved[row], moved[near], radius)]:
            group.append(int(other))
            left[other] = False
        leaders.append(int(row))
        members.append(np.array(group, dtype=np.int64))
    return Clusters(np.array(leaders, dtype=np.int64), tuple(members))


#: Points of each pose :func:`_within` tries first, in stages: enough far ones among them
#: settle it.
FIRST_POINTS = (48, 64, 96, 128)


def _within(lead: np.ndarray, moved: np.ndarray, radius: float) -> np.ndarray:
    """(m,) bool: which point sets ``moved`` (m, p, 3) lie within ``radius`` of ``lead``.

    ``set_distance(moved[i], lead) <= radius`` for each, exactly, with most settled
    cheaply. The distance is the larger of two quantiles. First, the first
    :data:`FIRST_POINTS` points of each set (48, then 64, 96 and 128, each stage for the
    sets left) are looked up in ``lead``'s tree: a set with enough of them farther than
    ``radius`` is out, its quantile above ``radius`` whatever the other points do. The sets
    left get the quantile of all their points to ``lead`` (one query for all), and the
    other way (a tree per set) only where that one is within ``radius``.
    """
    m, p = moved.shape[:2]
    out = np.zeros(m, dtype=bool)
    if m == 0:
        return out
    tree = cKDTree(lead)
    # the quantile interpolates sorted distances f and f + 1: with more than p - f - 1
    # distances above radius, both lie above it
    far_enough = p - int(np.floor(QUANTILE * (p - 1)))
    hopeful = np.arange(m)
    far = np.zeros(m, dtype=np.int64)
    done = 0
    for first in FIRST_POINTS:
        first = min(first, p)
        if first <= done or first < far_enough:
            continue
        part = moved[hopeful, done:first].reshape(-1, 3)
        dist = tree.query(part, distance_upper_bound=radius)[0].reshape(len(hopeful), -1)
        far[hopeful] += np.sum(dist > radius, axis=1)
        hopeful = hopeful[far[hopeful] < far_enough]
        done = first
        if len(hopeful) == 0:
            return out
    ab = np.quantile(tree.query(moved[hopeful].reshape(-1, 3))[0]
                     .reshape(len(hopeful), p), QUANTILE, axis=1)
    for i, d in zip(hopeful, ab, strict=True):
        if d <= radius:
            ba = float(np.quantile(cKDTree(moved[i]).query(lead)[0], QUANTILE))
            out[i] = max(float(d), ba) <= radius
    return out
