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

from engine.backend import thread_budget


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
    left = np.ones(n, dtype=bool)
    leaders: list[int] = []
    members: list[np.ndarray] = []
    for row in order:
        if not left[row]:
            continue
        left[row] = False
        lead = placed(pts, rotations[row], translations[row])
        near = np.flatnonzero(left & (np.linalg.norm(centres - centres[row], axis=1) < reach))
        near = near[np.lexsort((near, energies[near]))]  # members lowest first
        group = [int(row)]
        for other in near[_within(lead, pts, rotations[near], translations[near], radius)]:
            group.append(int(other))
            left[other] = False
        leaders.append(int(row))
        members.append(np.array(group, dtype=np.int64))
    return Clusters(np.array(leaders, dtype=np.int64), tuple(members))


#: Points of each pose :func:`_within` tries first: enough far ones among them settle it.
FIRST_POINTS = 64


def _within(lead: np.ndarray, points: np.ndarray, rotations: np.ndarray,
            translations: np.ndarray, radius: float) -> np.ndarray:
    """(m,) bool: which poses put ``points`` within ``radius`` of ``lead`` (set distance).

    ``set_distance(placed(points, R, t), lead) <= radius`` for each pose, exactly, with
    most poses settled cheaply. The distance is the larger of two quantiles; the one from
    the pose's points to ``lead`` is taken for all poses in one query of ``lead``'s tree,
    the other (a tree per pose) only where the first is within ``radius``. Before that, the
    first :data:`FIRST_POINTS` points alone rule a pose out when enough of them lie farther
    than ``radius``: the quantile then exceeds ``radius`` whatever the other points do.
    """
    m, p = len(rotations), len(points)
    out = np.zeros(m, dtype=bool)
    if m == 0:
        return out
    tree = cKDTree(lead)
    workers = thread_budget()
    moved = np.einsum("pj,nij->npi", points, rotations) + translations[:, None, :]
    # the quantile interpolates sorted distances f and f + 1: with more than p - f - 1
    # distances above radius, both lie above it
    far_enough = p - int(np.floor(QUANTILE * (p - 1)))
    first = min(FIRST_POINTS, p)
    head = tree.query(moved[:, :first].reshape(-1, 3), distance_upper_bound=radius,
                      workers=workers)[0].reshape(m, first)
    hopeful = np.flatnonzero(np.sum(head > radius, axis=1) < far_enough)
    if len(hopeful) == 0:
        return out
    ab = np.quantile(tree.query(moved[hopeful].reshape(-1, 3), workers=workers)[0]
                     .reshape(len(hopeful), p), QUANTILE, axis=1)
    for i, d in zip(hopeful, ab, strict=True):
        if d <= radius:
            ba = float(np.quantile(cKDTree(moved[i]).query(lead)[0], QUANTILE))
            out[i] = max(float(d), ba) <= radius
    return out
