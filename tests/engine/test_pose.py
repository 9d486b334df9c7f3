import numpy as np
import pytest

from engine import pose


def _random_rotvecs(n, seed=0):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(0, np.pi, size=n)
    return axes * angles[:, None]


def test_rotation_matrix_is_orthonormal_and_matches_axis_angle():
    r = np.array([0.0, 0.0, np.pi / 2])
    m = pose.rotation_matrix(r)
    np.testing.assert_allclose(m @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    for rv in _random_rotvecs(20):
        m = pose.rotation_matrix(rv)
        np.testing.assert_allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) == pytest.approx(1.0)
        np.testing.assert_allclose(m @ rv, rv, atol=1e-12)  # the axis is fixed


@pytest.mark.parametrize("angle", [0.0, 1e-10, 1e-5, 1.0, np.pi - 1e-7, np.pi])
def test_rotvec_roundtrip_including_near_zero_and_half_turn(angle):
    axis = np.array([0.3, -0.5, 0.8])
    axis /= np.linalg.norm(axis)
    rv = axis * angle
    back = pose.rotation_vector(pose.rotation_matrix(rv))
    # at exactly pi, r and -r are the same rotation
    same = np.allclose(back, rv, atol=1e-7) or (angle > 3 and np.allclose(back, -rv, atol=1e-7))
    assert same, (rv, back)


def test_quaternion_and_matrix_agree():
    for rv in _random_rotvecs(20, seed=1):
        q = pose.rotvec_to_quaternion(rv)
        np.testing.assert_allclose(
            pose.quaternion_to_matrix(q), pose.rotation_matrix(rv), atol=1e-12
        )
        np.testing.assert_allclose(pose.quaternion_to_rotvec(q), rv, atol=1e-9)


def test_quaternion_product_composes_rotations():
    a, b = _random_rotvecs(2, seed=2)
    qa, qb = pose.rotvec_to_quaternion(a), pose.rotvec_to_quaternion(b)
    np.testing.assert_allclose(
        pose.quaternion_to_matrix(pose.quaternion_multiply(qa, qb)),
        pose.rotation_matrix(a) @ pose.rotation_matrix(b),
        atol=1e-12,
    )


def test_relative_pose_maps_moving_frame_into_fixed_frame():
    fixed = np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3])
    moving = np.array([-4.0, 0.5, 2.0, 0.7, 0.1, -0.4])
    rel = pose.relative_pose(fixed, moving)
    q = np.array([0.3, -1.2, 2.5, 1.0])
    world_via_moving = pose.pose_to_matrix(moving) @ q
    world_via_rel = pose.pose_to_matrix(fixed) @ (pose.pose_to_matrix(rel) @ q)
    np.testing.assert_allclose(world_via_rel, world_via_moving, atol=1e-12)
    np.testing.assert_allclose(pose.compose(fixed, rel), moving, atol=1e-9)


# --------------------------------------------------------------------------- pivot poses
def test_a_typed_tilt_turns_the_part_about_its_centre_not_the_file_origin():
    """A body of an assembly file sits 75 mm from the file's origin; a 2 degree tilt typed
    by a user must leave its centre where it was (about the origin it would move 2.6 mm).
    """
    centre = np.array([75.0, 0.0, 0.0])
    tilt = np.array([0.0, 0.0, 0.0, 0.0, np.radians(2.0), 0.0])
    about_origin = pose.pose_to_matrix(tilt)[:3] @ np.append(centre, 1.0)
    assert np.linalg.norm(about_origin - centre) == pytest.approx(75.0 * np.radians(2.0),
                                                                  rel=1e-3)  # 2.6 mm
    placed = pose.pivot_to_origin(tilt, centre)
    np.testing.assert_allclose(pose.pose_to_matrix(placed)[:3] @ np.append(centre, 1.0),
                               centre, atol=1e-12)
    np.testing.assert_allclose(placed[3:], tilt[3:])  # the rotation itself is unchanged
    # a typed translation moves the centre by exactly that much
    moved = pose.pivot_to_origin(tilt + [1.0, -2.0, 0.5, 0, 0, 0], centre)
    np.testing.assert_allclose(pose.pose_to_matrix(moved)[:3] @ np.append(centre, 1.0),
                               centre + [1.0, -2.0, 0.5], atol=1e-12)


def test_pivot_and_origin_readings_convert_both_ways():
    rng = np.random.default_rng(3)
    for rv in _random_rotvecs(10, seed=4):
        p = np.concatenate([rng.normal(size=3) * 10, rv])
        c = rng.normal(size=3) * 50
        np.testing.assert_allclose(pose.origin_to_pivot(pose.pivot_to_origin(p, c), c), p,
                                   atol=1e-9)
        # every point q goes to R (q - c) + c + t
        q = rng.normal(size=3)
        expected = pose.rotation_matrix(rv) @ (q - c) + c + p[:3]
        np.testing.assert_allclose(
            pose.pose_to_matrix(pose.pivot_to_origin(p, c))[:3] @ np.append(q, 1.0), expected,
            atol=1e-9)
    np.testing.assert_allclose(pose.pivot_to_origin(p, np.zeros(3)), p)  # origin pivot


def test_rotate_about_keeps_the_centre_and_composes_the_rotation():
    start = np.array([5.0, -3.0, 2.0, 0.1, 0.2, -0.3])
    centre_local = np.array([10.0, 0.0, 4.0])
    centre = pose.pose_to_matrix(start)[:3] @ np.append(centre_local, 1.0)
    turn = np.array([0.0, 0.3, 0.1])
    after = pose.rotate_about(start, turn, centre)
    np.testing.assert_allclose(pose.pose_to_matrix(after)[:3] @ np.append(centre_local, 1.0),
                               centre, atol=1e-12)
    np.testing.assert_allclose(pose.rotation_matrix(after[3:]),
                               pose.rotation_matrix(turn) @ pose.rotation_matrix(start[3:]),
                               atol=1e-12)
