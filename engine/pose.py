"""Rigid poses: rotation vectors, rotation matrices, unit quaternions.

A pose is six numbers ``(tx, ty, tz, rx, ry, rz)``: a translation, then a rotation vector
in radians (axis times angle). It maps a point ``q`` of the moved part's frame to
``R q + t``: the rotation turns about the origin of the part's file. Quaternions are
``(w, x, y, z)``.

A *pivot pose* is the same six numbers read about a pivot ``c`` of the part (a point of
its own frame, usually its centre): rotate by ``R`` about ``c``, then move ``c`` by ``t``,
so ``q -> R (q - c) + c + t``. That is how a person types or drags a pose: a "2 degree
tilt" of a part drawn far from its file's origin then tilts it in place instead of
swinging it across the scene. :func:`pivot_to_origin` and :func:`origin_to_pivot` convert
between the two readings; stored poses (scene files, frames) use the origin reading.
"""

from __future__ import annotations

import numpy as np


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """(3, 3) float64 rotation matrix of a (3,) rotation vector (Rodrigues)."""
    r = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(r))
    k = np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])
    if theta < 1e-8:
        # second-order series: exact to rounding for tiny angles, no 0/0
        return np.eye(3) + k + 0.5 * (k @ k)
    a = np.sin(theta) / theta
    b = (1.0 - np.cos(theta)) / theta**2
    return np.eye(3) + a * k + b * (k @ k)


def rotation_vector(matrix: np.ndarray) -> np.ndarray:
    """(3,) float64 rotation vector of a (3, 3) rotation matrix, angle in [0, pi]."""
    return quaternion_to_rotvec(matrix_to_quaternion(matrix))


def matrix_to_quaternion(matrix: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w, x, y, z) of a rotation matrix; stable near 180 degrees."""
    m = np.asarray(matrix, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    # Shepperd's method: pick the largest diagonal term to divide by.
    cand = np.array([tr, m[0, 0], m[1, 1], m[2, 2]])
    i = int(np.argmax(cand))
    if i == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 0.0))
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif i == 1:
        s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif i == 2:
        s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    unit = np.asarray(q, dtype=np.float64)
    unit /= np.linalg.norm(unit)
    return unit if unit[0] >= 0 else -unit


def quaternion_to_matrix(quat: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix of a quaternion (w, x, y, z); normalises it first."""
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotvec_to_quaternion(rotvec: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion of a rotation vector."""
    r = np.asarray(rotvec, dtype=np.float64).reshape(3)
    theta = float(np.linalg.norm(r))
    if theta < 1e-12:
        return np.array([1.0, 0.5 * r[0], 0.5 * r[1], 0.5 * r[2]]) / np.sqrt(
            1.0 + 0.25 * theta**2
        )
    return np.concatenate([[np.cos(theta / 2)], np.sin(theta / 2) * r / theta])


def quaternion_to_rotvec(quat: np.ndarray) -> np.ndarray:
    """(3,) rotation vector of a quaternion, angle in [0, pi]."""
    q = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    if q[0] < 0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-12:
        return 2.0 * q[1:]
    return 2.0 * np.arctan2(s, q[0]) * q[1:] / s


def quaternion_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(4,) Hamilton product ``a * b`` (apply b, then a)."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def pose_to_matrix(pose: np.ndarray) -> np.ndarray:
    """(4, 4) homogeneous transform of a six-number pose."""
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    m = np.eye(4)
    m[:3, :3] = rotation_matrix(p[3:])
    m[:3, 3] = p[:3]
    return m


def matrix_to_pose(matrix: np.ndarray) -> np.ndarray:
    """(6,) pose of a (4, 4) homogeneous rigid transform."""
    m = np.asarray(matrix, dtype=np.float64)
    return np.concatenate([m[:3, 3], rotation_vector(m[:3, :3])])


def relative_pose(pose_fixed: np.ndarray, pose_moving: np.ndarray) -> np.ndarray:
    """(6,) pose of the moving part in the fixed part's frame, from both world poses."""
    return matrix_to_pose(np.linalg.inv(pose_to_matrix(pose_fixed)) @ pose_to_matrix(pose_moving))


def compose(pose_a: np.ndarray, pose_b: np.ndarray) -> np.ndarray:
    """(6,) pose of ``a`` after ``b``: ``x -> A (B x)``."""
    return matrix_to_pose(pose_to_matrix(pose_a) @ pose_to_matrix(pose_b))


def pivot_to_origin(pose: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(6,) origin pose of a pivot pose: ``t_origin = t + c - R c``, rotation unchanged.

    Parameters
    ----------
    pose : (6,) float
        Rotation ``r`` about ``pivot``, then translation ``t`` of the pivot.
    pivot : (3,) float
        The pivot ``c`` in the moved part's own frame.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    c = np.asarray(pivot, dtype=np.float64).reshape(3)
    return np.concatenate([p[:3] + c - rotation_matrix(p[3:]) @ c, p[3:]])


def origin_to_pivot(pose: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """(6,) pivot pose of an origin pose: ``t = t_origin - c + R c``.

    The inverse of :func:`pivot_to_origin`.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    c = np.asarray(pivot, dtype=np.float64).reshape(3)
    return np.concatenate([p[:3] - c + rotation_matrix(p[3:]) @ c, p[3:]])


def rotate_about(pose: np.ndarray, rotvec: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(6,) origin pose after turning a placed part by ``rotvec`` about the point ``centre``.

    ``rotvec`` (3,) and ``centre`` (3,) are in the frame the pose maps into (world, or part
    1's frame for a relative pose): the rotation a drag applies about the part's centre.
    """
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    r = rotation_matrix(rotvec)
    turned = r @ rotation_matrix(p[3:])
    return np.concatenate([r @ (p[:3] - c) + c, rotation_vector(turned)])
