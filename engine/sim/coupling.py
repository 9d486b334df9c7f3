"""Virtual coupling between the input proxy and the moving part, and the reaction a device
renders.

Data: positions (3,) float64 and orientations as unit quaternions (w, x, y, z) (4,) float64
in part 1's frame; forces and torques (3,) float64 in part 1's frame, torques about world
axes through part 2's origin (the correlation convention).

The coupling is a six-axis spring-damper between the proxy frame and the part's frame,
attached at the part's origin::

    F_c = k (t_proxy - t) - c v_origin
    T_c = k_r rotvec(R_proxy R^T) - c_r omega

(damping against the world: robust to jerky mouse input, which has no clean velocity).
The device renders the reaction ``-F_c, -T_c`` scaled by ``force_scale`` and clamped in
norm to ``max_force`` / ``max_torque``. The part itself feels the unclamped coupling.
"""

from __future__ import annotations

import math

import numpy as np

from engine.params import HapticLimits, Physics
from engine.sim.body import rotvec_between


def coupling_wrench(
    gains: Physics,
    origin: np.ndarray,
    quat: np.ndarray,
    origin_velocity: np.ndarray,
    omega: np.ndarray,
    proxy_translation: np.ndarray,
    proxy_quat: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Force and torque the coupling applies at the part's origin.

    Parameters
    ----------
    gains : Physics
        Reads ``k_lin``, ``c_lin``, ``k_rot``, ``c_rot``.
    origin : (3,) float64
        Part origin position.
    quat : (4,) float64
        Part orientation (w, x, y, z).
    origin_velocity, omega : (3,) float64
        Velocity of the part's origin and angular velocity (world axes).
    proxy_translation : (3,) float64
    proxy_quat : (4,) float64
        Proxy orientation (w, x, y, z).

    Returns
    -------
    force, torque : (3,) float64
    """
    force = gains.k_lin * (proxy_translation - origin) - gains.c_lin * origin_velocity
    torque = gains.k_rot * rotvec_between(proxy_quat, quat) - gains.c_rot * omega
    return force, torque


def coupling_energy(
    gains: Physics,
    origin: np.ndarray,
    quat: np.ndarray,
    proxy_translation: np.ndarray,
    proxy_quat: np.ndarray,
) -> float:
    """Potential energy of the coupling's springs, ``k |d|^2 / 2 + k_r |r|^2 / 2``."""
    d = proxy_translation - origin
    r = rotvec_between(proxy_quat, quat)
    return 0.5 * gains.k_lin * float(d @ d) + 0.5 * gains.k_rot * float(r @ r)


def clamp_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    """(3,) vector scaled down to norm ``limit`` if longer."""
    n = float(math.sqrt(vector @ vector))
    if n > limit:
        return vector * (limit / n)
    return vector


def haptic_reaction(
    force: np.ndarray, torque: np.ndarray, limits: HapticLimits
) -> tuple[np.ndarray, np.ndarray]:
    """The (force, torque) a device renders for coupling wrench (force, torque) on the part."""
    return (
        clamp_norm(-limits.force_scale * force, limits.max_force),
        clamp_norm(-limits.force_scale * torque, limits.max_torque),
    )
