"""The search's second ranking by how the parts meet on their meshes (engine.search.rescore).

A box in a box-shaped pocket: at its seat it touches the pocket and is not in it; lifted
clear of the block it touches nothing; pushed sideways through the pocket's wall a share of
its samples lies inside the block, as deep as the push. The ranking puts touching fits
before apart ones, fits through a wall after those that are not (judged against the least
share of all fits), and otherwise keeps the energy's order.
"""

from __future__ import annotations

import numpy as np
import pytest

from engine.search.joint import Surfaces
from engine.search.rescore import DEPTH_SLACK, NEAR, Contact, contact, rerank


@pytest.fixture(scope="module")
def box_in_pocket():
    trimesh = pytest.importorskip("trimesh")
    block = trimesh.creation.box((40.0, 40.0, 20.0))
    block.apply_translation((0.0, 0.0, -10.0))
    pocket = trimesh.creation.box((20.2, 20.2, 10.0))
    pocket.apply_translation((0.0, 0.0, -5.0 + 1e-3))
    block = block.difference(pocket)
    peg = trimesh.creation.box((20.0, 20.0, 16.0))
    peg.apply_translation((0.0, 0.0, 8.0))
    return Surfaces.of(block.vertices, block.faces, peg.vertices, peg.faces, count=2000)


SIZE = float(np.linalg.norm([20.0, 20.0, 16.0]))


def test_contact_tells_a_seat_from_parts_apart_and_from_a_wall_gone_through(box_in_pocket):
    eye = np.eye(3)
    seat = contact(box_in_pocket, eye, np.array([0.0, 0.0, -10.0]), SIZE)
    apart = contact(box_in_pocket, eye, np.array([0.0, 0.0, 30.0]), SIZE)
    through = contact(box_in_pocket, eye, np.array([4.0, 0.0, -10.0]), SIZE)
    # at the seat: its bottom on the floor and its sides a tenth of a mm from the walls
    assert seat.touches and seat.touching > 0.3
    assert seat.inside == 0.0 and seat.depth < NEAR
    assert not apart.touches and apart.touching == 0.0 and apart.inside == 0.0
    # 4 mm through the wall (less the 0.1 mm play): the depth is the push's
    assert through.inside > 0.05
    assert through.depth * SIZE == pytest.approx(3.9, abs=0.05)


def test_rerank_puts_touching_first_then_not_through_a_wall_then_energy():
    seat = Contact(touching=0.4, inside=0.02, depth=0.01)
    deeper = Contact(touching=0.4, inside=0.02 + 0.5 * DEPTH_SLACK, depth=0.02)
    wall = Contact(touching=0.2, inside=0.02 + 2 * DEPTH_SLACK, depth=0.1)
    apart = Contact(touching=0.0, inside=0.0, depth=0.0)
    # energies: the wall lowest, then apart, then the two seats
    order = rerank([wall, apart, deeper, seat], [-10.0, -9.0, -8.0, -7.0])
    # apart goes last; the slack is judged against the least share of the touching fits
    # (0.02, not the apart fit's 0), so both seats pass and the wall does not
    assert order == [2, 3, 0, 1]
    # a true fit a little deep (a blind floor's overshoot: 13 % of the samples) is not
    # demoted for it by a fit apart, which has none inside
    floor = Contact(touching=0.3, inside=0.13, depth=0.05)
    tilted = Contact(touching=0.1, inside=0.13 + 2 * DEPTH_SLACK, depth=0.14)
    assert rerank([tilted, apart, floor], [-3.0, -2.0, -1.0]) == [2, 0, 1]
    # the energy's order where the contacts do not differ
    assert rerank([seat, seat, seat], [-1.0, -3.0, -2.0]) == [1, 2, 0]
    assert rerank([], []) == []


@pytest.mark.parametrize("start, turn", [
    ((1.5, 0.0, -10.0), (0.0, 0.0, 0.0)),       # 1.4 mm through the pocket's wall
    ((0.0, 0.0, -11.0), (0.0, 0.0, 0.0)),       # 1 mm past the pocket's floor
    ((0.0, 0.0, -9.0), (0.0, 0.06, 0.04)),      # turned 4 degrees through two walls
])
def test_the_polish_moves_a_part_out_of_the_walls_to_its_seat(box_in_pocket, start, turn):
    from engine.pose import rotation_matrix, rotation_vector
    from engine.search.rescore import polish

    rot0, t0 = rotation_matrix(np.array(turn)), np.array(start)
    before = contact(box_in_pocket, rot0, t0, SIZE)
    assert before.inside > 0.01
    rot, t = polish(box_in_pocket, rot0, t0, SIZE)
    after = contact(box_in_pocket, rot, t, SIZE)
    assert after.inside < 0.1 * before.inside and after.depth < 2 * NEAR
    assert after.touches
    # in the pocket, square to it, within the fit's play and the polish's tolerance
    assert np.degrees(np.linalg.norm(rotation_vector(rot))) < 1.0
    assert np.all(np.abs(t[:2]) < 0.1 + NEAR * SIZE)
    assert -10.0 - NEAR * SIZE <= t[2] < -8.0


def test_the_polish_leaves_a_part_that_is_not_in_a_wall_where_it_is(box_in_pocket):
    from engine.search.rescore import polish

    t0 = np.array([0.05, -0.05, -9.5])
    rot, t = polish(box_in_pocket, np.eye(3), t0, SIZE)
    np.testing.assert_array_equal(rot, np.eye(3))
    np.testing.assert_array_equal(t, t0)
