"""engine.sim.joints: free axes found from the energy around a pose."""

import numpy as np
import pytest

from engine.pose import rotation_vector
from engine.sim.joints import FREE_THRESHOLD, find_free_axes

CENTRE = np.array([0.0, 0.0, 5.0])


def well(stiff_t, stiff_r, *, stop_z=None):
    """Energy of a part near the identity pose: quadratic in its centre's displacement and
    its rotation vector, plus an optional one-sided floor along z. Rotational stiffness 25
    matches translational 1 for the steps used (0.1 rad against 0.5).
    """
    kt, kr = np.asarray(stiff_t, float), np.asarray(stiff_r, float)

    def energy(rotation, translation):
        r = rotation_vector(rotation)
        # the part's centre moves by the translation plus the turn about the file's origin
        c = rotation @ CENTRE + translation - CENTRE
        e = float(kt @ c**2 + kr @ r**2)
        if stop_z is not None and c[2] < 0:
            e += stop_z * c[2] ** 2
        return e

    return energy


def test_a_cylindrical_joint_leaves_its_axis_and_spin_free():
    found = find_free_axes(well([5, 5, 0], [100, 100, 0]), np.zeros(6), CENTRE, 10.0, 0.5)
    assert found.free == ("z", "rz")
    assert found.curvature["z"] == pytest.approx(0.0, abs=1e-12)
    assert found.curvature["x"] == pytest.approx(2 * 5 * 0.25, rel=1e-9)
    assert found.angle == pytest.approx(0.5 / 5.0)


def test_a_one_sided_floor_locks_its_axis():
    found = find_free_axes(well([5, 5, 0], [100, 100, 100], stop_z=50), np.zeros(6), CENTRE, 10.0,
                           0.5)
    assert "z" not in found.free and found.free == ()


def test_rotations_turn_about_the_centre_not_the_origin():
    # only the centre's position costs energy: a turn about the centre costs nothing, so all
    # rotations are free although the centre is 5 from the origin
    found = find_free_axes(well([5, 5, 5], [0, 0, 0]), np.zeros(6), CENTRE, 10.0, 0.5)
    assert found.free == ("rx", "ry", "rz")


def test_threshold_is_relative_within_each_kind():
    weak = FREE_THRESHOLD * 0.5
    found = find_free_axes(well([1, weak, 1], [25, 25, 25]), np.zeros(6), CENTRE, 10.0, 0.5)
    assert found.free == ("y",)
    strong = FREE_THRESHOLD * 2
    assert find_free_axes(well([1, strong, 1], [25, 25, 25]), np.zeros(6), CENTRE, 10.0,
                          0.5).free == ()


def test_a_steady_slope_along_a_free_axis_stays_free():
    # through a through hole the energy keeps falling as the peg slides on: a slope, no wall
    base = well([5, 5, 0], [25, 25, 0])

    def sloped(rotation, translation):
        return base(rotation, translation) + 40.0 * translation[2]

    found = find_free_axes(sloped, np.zeros(6), CENTRE, 10.0, 0.5)
    assert found.free == ("z", "rz")


def test_no_contact_means_everything_is_free():
    found = find_free_axes(lambda r, t: 0.0, np.zeros(6), CENTRE, 10.0, 0.5)
    assert found.free == ("x", "y", "z", "rx", "ry", "rz")


def test_a_stiff_floor_does_not_make_the_tilts_free():
    # a seated peg: the floor's rise dwarfs the tilts', which must still count as locked
    found = find_free_axes(well([5, 5, 0], [0.5, 0.5, 0], stop_z=20), np.zeros(6), CENTRE, 10.0,
                           0.5)
    assert found.curvature["z"] > 400 * found.curvature["rx"] > 0
    assert found.free == ("rz",)
