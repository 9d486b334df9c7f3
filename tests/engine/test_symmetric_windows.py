"""Windows that turn with the parts, not with their grids (options: docs/fine_level.md).

- The fine level's cylinder window (``engine.correlation.near.cylinder_window``) is the same
  under every turn about its axis and every mirror through it, 1 within the cylinder and 0
  past its taper; its box of the grid's planes holds it.
- The descriptor's support window (``engine.correlation.support``) of a box turned in its
  own frame is 1 over the box, 0 on the grid's sides, and the same at mirror points of the
  box: where the tail ends depends on the part, not on how its grid lies.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from engine.correlation.near import cylinder_box, cylinder_window
from engine.correlation.support import hull_distance, support_window
from engine.grid import Grid

TURN = Rotation.from_rotvec([0.3, -0.5, 0.7]).as_matrix()  # no plane of the grid survives it


def test_the_cylinder_window_turns_and_mirrors_with_its_axis():
    grid = Grid((-10.0, -10.0, -10.0), 0.5, (41, 41, 41))
    centre, axis = np.array([0.5, -0.3, 0.2]), TURN[:, 2]
    radius, half, taper = 3.0, 4.0, 1.5
    w = cylinder_window(grid, centre, axis, radius, half, taper).reshape(-1)
    p = grid.points().reshape(-1, 3)
    assert w.min() == 0.0 and w.max() == 1.0
    s = (p - centre) @ axis
    r = np.linalg.norm(p - centre - np.outer(s, axis), axis=1)
    assert np.all(w[(r <= radius) & (np.abs(s) <= half)] == 1.0)
    assert np.all(w[(r >= radius + taper) | (np.abs(s) >= half + taper)] == 0.0)
    # its value at points turned about the axis, or mirrored through a plane holding it
    rng = np.random.default_rng(5)
    q = centre + rng.uniform(-7, 7, size=(500, 3))
    small = Grid((0.0, 0.0, 0.0), 1.0, (1, 1, 1))

    def at(points: np.ndarray) -> np.ndarray:
        out = []
        for x in points:
            g = Grid(tuple(x), small.spacing, small.shape)
            out.append(cylinder_window(g, centre, axis, radius, half, taper).item())
        return np.array(out)

    turn = Rotation.from_rotvec(1.1 * axis).as_matrix()
    normal = np.cross(axis, TURN[:, 0])
    normal /= np.linalg.norm(normal)
    mirror = np.eye(3) - 2.0 * np.outer(normal, normal)
    base = at(q)
    np.testing.assert_allclose(at(centre + (q - centre) @ turn.T), base, atol=1e-12)
    np.testing.assert_allclose(at(centre + (q - centre) @ mirror.T), base, atol=1e-12)
    # the box of the grid's planes holds everything the window is 1 on
    lo, hi = cylinder_box(centre, axis, radius, half)
    inside = p[w == 1.0]
    assert np.all(inside >= lo - 1e-9) and np.all(inside <= hi + 1e-9)


def _turned_box(half: np.ndarray) -> tuple[Grid, np.ndarray, np.ndarray]:
    """A box of half-sides ``half`` turned by TURN, sampled on its grid (6 cells padding)."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    placed = corners @ TURN.T
    h = 0.5
    lo = placed.min(axis=0) - 6 * h
    shape = tuple(int(n) for n in np.ceil((placed.max(axis=0) + 6 * h - lo) / h) + 1)
    grid = Grid(tuple(lo), h, shape)
    local = grid.points().reshape(-1, 3) @ TURN  # the box's own frame
    inside = np.all(np.abs(local) <= half, axis=1).reshape(shape)
    rho = np.where(inside, 3.0j, -1.0j).astype(np.complex64)  # as a density's sides
    return grid, rho, local


def test_the_support_window_ends_the_tail_at_one_distance_from_a_turned_part():
    half = np.array([4.0, 2.5, 1.5])
    grid, rho, local = _turned_box(half)
    w = support_window(rho, grid)
    assert w is not None and w.shape == grid.shape
    w = w.reshape(-1)
    assert np.all((w >= 0) & (w <= 1))
    assert np.all(w[np.all(np.abs(local) <= half, axis=1)] == 1.0)  # nothing inside changes
    sides = np.zeros(grid.shape, bool)
    sides[[0, -1], :, :] = sides[:, [0, -1], :] = sides[:, :, [0, -1]] = True
    assert np.all(w[sides.reshape(-1)] == 0.0)  # the tail ends within the grid
    # the same at points mirrored through the box's planes (read trilinearly)
    from engine.correlation.near import trilinear

    field = w.reshape(grid.shape).astype(np.complex128)
    rng = np.random.default_rng(11)
    pts = rng.uniform(-1, 1, size=(400, 3)) * (half + 3.0)  # box frame, near the taper
    base = trilinear(field, grid, pts @ TURN.T).real
    cut = np.ones(grid.shape, np.complex128)  # the grid's own cut: 1 within it, 0 beyond
    cut_base = trilinear(cut, grid, pts @ TURN.T).real
    for axis in range(3):
        flip = pts.copy()
        flip[:, axis] *= -1
        mirrored = trilinear(field, grid, flip @ TURN.T).real
        cut_mirrored = trilinear(cut, grid, flip @ TURN.T).real
        # the hull is of samples: a cell off at most, a third of the taper's 3 cells
        assert np.sqrt(np.mean((mirrored - base) ** 2)) < 0.08, axis
        assert np.max(np.abs(mirrored - base)) < 0.4, axis
        # where the grid's planes cut the turned box's tail, mirror points differ more
        assert np.max(np.abs(cut_mirrored - cut_base)) > 0.5, axis


def test_no_window_where_there_is_no_room_or_no_volume():
    grid = Grid((0.0, 0.0, 0.0), 1.0, (8, 8, 8))
    rho = np.full(grid.shape, -1.0j, np.complex64)
    assert support_window(rho, grid) is None  # nothing inside
    rho[1:7, 1:7, 1:7] = 3.0j  # one cell from the sides: no tail to shape
    assert support_window(rho, grid) is None
    flat = np.zeros(grid.shape, bool)
    flat[2:6, 2:6, 4] = True
    assert hull_distance(flat) is None  # a plane spans no volume
    with pytest.raises(ValueError, match="shape"):
        support_window(rho[:-1], grid)


@pytest.mark.parametrize("shape", [(24, 20, 17), (25, 21, 16)])
def test_the_support_window_of_a_mirror_symmetric_part_is_mirror_symmetric(shape):
    """A box centred on its grid, even and odd sample counts: the window is the same at
    every sample and its mirror images through the grid's mid-planes (its lattice of hull
    distances is spread evenly over the grid, not every second sample from the first).
    """
    grid = Grid((0.0, 0.0, 0.0), 1.0, shape)
    n = np.array(shape)
    inside = np.zeros(shape, bool)
    inside[tuple(slice(k // 2 - k // 4, k - (k // 2 - k // 4)) for k in n)] = True
    assert all(np.array_equal(inside, np.flip(inside, axis=a)) for a in range(3))
    rho = np.where(inside, 3.0j, -1.0j).astype(np.complex64)
    w = support_window(rho, grid)
    assert w is not None and w.min() == 0.0 and w.max() == 1.0
    assert np.count_nonzero((w > 0.0) & (w < 1.0)) > 100  # a taper between
    for axis in range(3):
        np.testing.assert_allclose(w, np.flip(w, axis=axis), atol=1e-6)
