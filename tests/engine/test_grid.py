import numpy as np
import pytest

from engine.grid import Grid, grid_for_bounds


def test_points_follow_origin_and_spacing():
    grid = Grid((1.0, -2.0, 0.5), 0.25, (3, 4, 5))
    pts = grid.points()
    assert pts.shape == (3, 4, 5, 3)
    np.testing.assert_allclose(pts[0, 0, 0], grid.origin)
    np.testing.assert_allclose(pts[2, 3, 4], np.array(grid.origin) + 0.25 * np.array([2, 3, 4]))
    np.testing.assert_allclose(grid.upper, pts[-1, -1, -1])


def test_grid_for_bounds_covers_box_with_padding():
    lower, upper = np.array([-1.0, 0.0, 2.0]), np.array([3.0, 1.0, 2.5])
    grid = grid_for_bounds(lower, upper, samples=40, padding=3)
    assert grid.spacing == pytest.approx(4.0 / 40)
    # at least three free cells on every side, and the grid is centred on the box
    assert np.all(np.asarray(grid.origin) <= lower - 3 * grid.spacing + 1e-9)
    assert np.all(grid.upper >= upper + 3 * grid.spacing - 1e-9)
    np.testing.assert_allclose(grid.centre, 0.5 * (lower + upper))


def test_grid_for_bounds_by_spacing_matches_samples():
    lower, upper = np.zeros(3), np.array([2.0, 1.0, 1.0])
    a = grid_for_bounds(lower, upper, samples=20, padding=0)
    b = grid_for_bounds(lower, upper, spacing=0.1, padding=0)
    assert a == b


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(),
        dict(samples=10, spacing=0.1),
        dict(samples=1),
        dict(spacing=-1.0),
        dict(spacing=np.nan),
    ],
)
def test_grid_for_bounds_rejects_bad_options(kwargs):
    with pytest.raises(ValueError):
        grid_for_bounds(np.zeros(3), np.ones(3), **kwargs)


def test_grid_rejects_bad_values():
    with pytest.raises(ValueError, match="spacing"):
        Grid((0, 0, 0), 0.0, (2, 2, 2))
    with pytest.raises(ValueError, match="shape"):
        Grid((0, 0, 0), 1.0, (2, 0, 2))
    with pytest.raises(ValueError, match="origin"):
        Grid((0, np.nan, 0), 1.0, (2, 2, 2))
