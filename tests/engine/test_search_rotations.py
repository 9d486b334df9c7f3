"""engine.search.rotations: the Hopf grid is uniform, nested, and covers SO(3)."""

import numpy as np
import pytest

from engine.search.rotations import (
    RotationGrid,
    children,
    healpix_nested,
    hopf_quaternions,
    level_angle,
    level_for,
    level_size,
)


def _random_quaternions(count, seed):
    q = np.random.default_rng(seed).normal(size=(count, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _angles_to_nearest(queries, grid):
    """Degrees from each query rotation to the nearest grid rotation (q and -q alike)."""
    dots = np.clip(np.abs(queries @ grid.T).max(axis=1), -1.0, 1.0)
    return 2.0 * np.degrees(np.arccos(dots))


def test_healpix_pixels_are_equal_area_centres():
    theta, phi = healpix_nested(2, np.arange(192))
    centres = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi),
                        np.cos(theta)], axis=1)
    assert abs(centres[:, 2].mean()) < 1e-12
    # equal areas: random directions fall about evenly to the nearest centres
    points = np.random.default_rng(0).normal(size=(60_000, 3))
    points /= np.linalg.norm(points, axis=1, keepdims=True)
    counts = np.bincount(np.argmax(points @ centres.T, axis=1), minlength=192)
    assert counts.std() / counts.mean() < 0.15
    assert len({(round(a, 9), round(b, 9)) for a, b in zip(theta, phi, strict=True)}) == 192


@pytest.mark.parametrize("level", [0, 1, 2])
def test_covering_radius_halves_with_each_level(level):
    grid = hopf_quaternions(level, np.arange(level_size(level)))
    np.testing.assert_allclose(np.linalg.norm(grid, axis=1), 1.0, atol=1e-12)
    nearest = _angles_to_nearest(_random_quaternions(20_000, level), grid)
    # the covering radius is about the nominal spacing (60 / 2^level degrees), never more
    assert nearest.max() < level_angle(level)
    assert nearest.max() > 0.35 * level_angle(level)
    # uniform: no rotation is much nearer the grid than the average says
    assert nearest.mean() == pytest.approx(0.47 * level_angle(level), rel=0.15)


def test_no_two_grid_rotations_coincide():
    grid = hopf_quaternions(1, np.arange(level_size(1)))
    dots = np.abs(grid @ grid.T)
    np.fill_diagonal(dots, 0.0)
    assert 2 * np.degrees(np.arccos(dots.max())) > 0.8 * level_angle(1)


def test_children_are_the_next_levels_rotations_near_their_parent():
    level = 1
    parents = hopf_quaternions(level, np.arange(level_size(level)))
    every_child = np.concatenate([children(level, i) for i in range(level_size(level))])
    # the children of all parents are every rotation of the next level, once
    assert np.array_equal(np.sort(every_child), np.arange(level_size(level + 1)))
    for index in (0, 77, 400):
        kids = hopf_quaternions(level + 1, children(level, index))
        angles = 2 * np.degrees(np.arccos(np.clip(np.abs(kids @ parents[index]), 0, 1)))
        assert angles.max() < 1.1 * level_angle(level)


def test_level_for_rotations_and_angle():
    assert level_for(rotations=4608) == 2
    assert level_for(rotations=4609) == 3
    assert level_for(angle=15) == 2
    assert level_for(angle=20) == 2
    assert level_for(angle=60) == 0
    with pytest.raises(ValueError, match="either"):
        level_for(rotations=10, angle=10)
    with pytest.raises(ValueError, match="finer than the deepest"):
        level_for(angle=0.1)


def test_a_seed_turns_the_whole_grid_the_same_way_each_time():
    a = RotationGrid.from_seed(3).matrices(0, np.arange(72))
    b = RotationGrid.from_seed(3).matrices(0, np.arange(72))
    c = RotationGrid.from_seed(4).matrices(0, np.arange(72))
    assert np.array_equal(a, b)
    assert not np.allclose(a, c)
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", a, a), np.broadcast_to(np.eye(3),
                               a.shape), atol=1e-12)
