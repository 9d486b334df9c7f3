"""The search's clustering: the greedy grouping by set distance, computed cheaply, exactly."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from engine.pose import rotation_matrix
from engine.search.cluster import cluster_poses, placed, set_distance


def _greedy(rotations, translations, energies, points, radius):
    """The definition: the lowest pose left leads; every pose left within radius joins."""
    n = len(energies)
    left = np.ones(n, dtype=bool)
    leaders, members = [], []
    for row in np.lexsort((np.arange(n), energies)):
        if not left[row]:
            continue
        left[row] = False
        lead = placed(points, rotations[row], translations[row])
        group = [int(row)]
        others = np.flatnonzero(left)
        for other in others[np.lexsort((others, energies[others]))]:
            moved = placed(points, rotations[other], translations[other])
            if set_distance(moved, lead, cKDTree(lead)) <= radius:
                group.append(int(other))
                left[other] = False
        leaders.append(int(row))
        members.append(group)
    return leaders, members


def _key_on_a_shaft(rng, count=300):
    """Points of a round shaft (its turns about z keep it) with an arm on one side."""
    z = rng.uniform(-10, 10, count)
    a = rng.uniform(0, 2 * np.pi, count)
    shaft = np.stack([3 * np.cos(a), 3 * np.sin(a), z], axis=1)
    k = count // 5  # a sixth of the points: the set distance's quantile must see it
    arm = np.stack([rng.uniform(3, 9, k), rng.uniform(-0.5, 0.5, k), rng.uniform(-4, 4, k)],
                   axis=1)
    return np.vstack([shaft, arm])


@pytest.mark.parametrize("seed", [0, 1])
def test_the_clusters_are_the_greedy_definitions(seed):
    rng = np.random.default_rng(seed)
    points = _key_on_a_shaft(rng)
    # poses around three places, turned about the shaft (a symmetry but for the key),
    # tilted a little or a lot, energies in no particular order
    rotations, translations = [], []
    for _ in range(120):
        spin = rotation_matrix(np.array([0, 0, rng.uniform(-np.pi, np.pi)]))
        tilt = rotation_matrix(rng.normal(scale=rng.choice([0.02, 0.3]), size=3))
        rotations.append(tilt @ spin)
        translations.append(rng.choice([-6.0, 0.0, 6.0], size=3) * [1, 0, 1]
                            + rng.normal(scale=0.4, size=3))
    rotations, translations = np.array(rotations), np.array(translations)
    energies = rng.normal(size=120)
    radius = 2.0
    got = cluster_poses(rotations, translations, energies, points, radius)
    leaders, members = _greedy(rotations, translations, energies, points, radius)
    assert list(got.leaders) == leaders
    assert [list(m) for m in got.members] == members
    sizes = got.sizes()
    assert sizes.max() > 3 and (sizes == 1).any()  # groups and loners both


def test_a_turned_round_shaft_is_one_fit_and_a_turned_arm_is_not():
    rng = np.random.default_rng(5)
    points = _key_on_a_shaft(rng, count=2000)
    turn = rotation_matrix(np.array([0, 0, np.pi]))
    rotations = np.stack([np.eye(3), turn])
    t = np.zeros((2, 3))
    e = np.array([0.0, 1.0])
    assert len(cluster_poses(rotations, t, e, points[:2000], 1.0).leaders) == 1
    assert len(cluster_poses(rotations, t, e, points, 1.0).leaders) == 2


@pytest.mark.parametrize(("arm", "fits"), [(25, 1), (26, 2)])
def test_a_pose_is_ruled_out_early_only_when_its_quantile_must_exceed_the_radius(arm, fits):
    # 256 points, as the search takes; the arm's points come first, where the early test
    # reads: 25 far points of 256 leave the 90 % quantile among the near ones, 26 do not
    rng = np.random.default_rng(9)
    a = rng.uniform(0, 2 * np.pi, 256 - arm)
    shaft = np.stack([3 * np.cos(a), 3 * np.sin(a), rng.uniform(-10, 10, 256 - arm)], axis=1)
    tip = np.stack([rng.uniform(6, 9, arm), rng.uniform(-0.5, 0.5, arm),
                    rng.uniform(-4, 4, arm)], axis=1)
    points = np.vstack([tip, shaft])
    rotations = np.stack([np.eye(3), rotation_matrix(np.array([0, 0, np.pi]))])
    t, e = np.zeros((2, 3)), np.array([0.0, 1.0])
    within = set_distance(placed(points, rotations[1], t[1]), points) <= 2.0
    assert within == (fits == 1)
    assert len(cluster_poses(rotations, t, e, points, 2.0).leaders) == fits
