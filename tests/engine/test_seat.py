"""engine.seat: distance and angle to the seat, free axes, the seated test."""

import math

import numpy as np
import pytest

from engine.params import SeatSpec
from engine.pose import compose, rotate_about
from engine.scene import parse_scene
from engine.scene.writer import save_scene
from engine.seat import FREE_TRAVEL_FRACTION, seat_state

SEAT = np.array([1.0, 2.0, -15.0, 0.0, 0.0, 0.3])
CENTRE = np.array([0.5, -0.2, 10.0])


def test_at_the_seat_everything_is_zero_and_seated():
    s = seat_state(SEAT, SEAT, CENTRE, SeatSpec(), size=20.0)
    assert s.distance == pytest.approx(0.0, abs=1e-12)
    assert s.angle_deg == pytest.approx(0.0, abs=1e-6)
    assert s.seated


def test_distance_is_the_centres_displacement_and_angle_the_relative_rotation():
    # tilt 3 degrees about x through the part's centre, then move 0.3 along y
    tilted = rotate_about(SEAT, np.array([math.radians(3.0), 0, 0]),
                          _centre_in_parent(SEAT))
    moved = tilted + np.array([0.0, 0.3, 0.0, 0, 0, 0])
    s = seat_state(moved, SEAT, CENTRE, SeatSpec(), size=20.0)
    assert s.distance == pytest.approx(0.3, rel=1e-9)
    assert s.angle_deg == pytest.approx(3.0, rel=1e-9)
    assert not s.seated  # 3 degrees > the default 1 degree


def test_free_axes_are_left_out():
    spin = rotate_about(SEAT, np.array([0, 0, 1.0]), _centre_in_parent(SEAT))
    slide = spin + np.array([0, 0, -4.0, 0, 0, 0])
    locked = seat_state(slide, SEAT, CENTRE, SeatSpec(), size=20.0)
    free = seat_state(slide, SEAT, CENTRE, SeatSpec(free_axes=("z", "rz")), size=20.0)
    assert locked.distance == pytest.approx(4.0) and locked.angle_deg == pytest.approx(
        math.degrees(1.0))
    assert free.distance == pytest.approx(0.0, abs=1e-9)
    assert free.angle_deg == pytest.approx(0.0, abs=1e-6)
    assert free.free_travel == pytest.approx(4.0)
    assert free.seated
    # a tilt is not a twist: it still counts with rz free
    tilt = rotate_about(SEAT, np.array([0.05, 0, 0]), _centre_in_parent(SEAT))
    assert seat_state(tilt, SEAT, CENTRE, SeatSpec(free_axes=("rz",)), 20.0).angle_deg == \
        pytest.approx(math.degrees(0.05), rel=1e-9)


def test_free_travel_beyond_half_the_part_is_not_seated():
    far = SEAT + np.array([0, 0, FREE_TRAVEL_FRACTION * 20.0 + 0.1, 0, 0, 0])
    assert not seat_state(far, SEAT, CENTRE, SeatSpec(free_axes=("z",)), 20.0).seated


def test_tolerance_from_the_scene_and_default():
    near = SEAT + np.array([0.25, 0, 0, 0, 0, 0])
    assert not seat_state(near, SEAT, CENTRE, SeatSpec(distance=0.2), 20.0).seated
    assert seat_state(near, SEAT, CENTRE, SeatSpec(distance=0.3), 20.0).seated
    # default: 2 % of the size
    assert seat_state(near, SEAT, CENTRE, SeatSpec(), 20.0).seated
    assert not seat_state(near, SEAT, CENTRE, SeatSpec(), 10.0).seated


def test_scene_keys_round_trip(tmp_path):
    text = """name = "t"
assembled_pose = [0, 0, -15, 0, 0, 0]
free_axes = ["z", "rz"]
seat_tolerance = [0.05, 0.5]
[[part]]
file = "a.stl"
fixed = true
[[part]]
file = "b.stl"
"""
    for name in ("a.stl", "b.stl"):
        (tmp_path / name).write_text("solid x\nendsolid x\n")
    scene = parse_scene(text, tmp_path / "scene.toml")
    assert scene.seat == SeatSpec(free_axes=("z", "rz"), distance=0.05, angle_deg=0.5)
    with pytest.raises(Exception, match=r"scene.toml:3: .*unknown axis 'w'"):
        parse_scene(text.replace('"rz"]', '"w"]'), tmp_path / "scene.toml")
    with pytest.raises(Exception, match=r"scene.toml:4: .*angle"):
        parse_scene(text.replace("0.5]", "400]"), tmp_path / "scene.toml")
    assert parse_scene(text.replace("[0.05, 0.5]", "[0, 0.5]"),
                       tmp_path / "scene.toml").seat.distance is None
    saved = tmp_path / "saved.toml"
    save_scene(scene, saved)
    assert parse_scene(saved.read_text(), saved).seat == scene.seat


def _centre_in_parent(pose):
    return compose(pose, np.r_[CENTRE, 0, 0, 0])[:3]
