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
