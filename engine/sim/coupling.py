"""Virtual coupling between the input proxy and the moving part.

Also the reaction a device renders.

Data: positions (3,) float64 and orientations as unit quaternions (w, x, y, z) (4,) float64
in part 1's frame; forces and torques (3,) float64 in part 1's frame, torques about world
axes through part 2's origin (the correlation convention).

The coupling is a six-axis spring-damper between the proxy frame and the part's frame,
attached at the part's centre of mass ``x = t + R c`` (``c`` the centre in the part's own
frame), which the proxy places at ``x_proxy = t_proxy + R_proxy c``::

    F_c = k (x_proxy - x) - c v
    T_c = k_r rotvec(R_proxy R^T) - c_r omega

up to the angle ``rot_play`` between the two; past it the spring stiffens to ``k_r'`` (the
torque ``k_r play + k_r' (angle - play)`` along the same axis) and the damping to ``c_r'``.
Near a fit the soft spring lets the fit's torque turn the part into line within the hand's
play; beyond it the hand holds the part, so a torque at a hole's mouth cannot throw it over
(``engine.sim.build.resolve_physics`` chooses the three). The play is the hand's only near
the fit: away from it (:func:`near_fit`, the fine level's closeness to the seat) it
closes, and the stiff spring holds the part's orientation from the first degree. However
hard a fit pulls, the part turns no further than the play from the proxy: the wrist's stop
(:func:`wrist_stop`, applied by the simulation after each drift).

(damping against the world: robust to jerky mouse input, which has no clean velocity).
Holding the part at its centre of mass, not at its file's origin, keeps the lever of the
geometric force against the rotational spring independent of where the file puts the origin.
The device renders the reaction ``-F_c, -T_c`` scaled by ``force_scale`` and clamped in
norm to ``max_force`` / ``max_torque``. The part itself feels the unclamped coupling.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from engine.params import HapticLimits, Physics
from engine.sim.body import BodyState, RigidBody, cross3, quaternion_step, rotvec_between


def coupling_wrench(
    gains: Physics,
    point: np.ndarray,
    quat: np.ndarray,
    point_velocity: np.ndarray,
    omega: np.ndarray,
    proxy_point: np.ndarray,
    proxy_quat: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Force and torque the coupling applies at its attachment point on the part.

    Parameters
    ----------
    gains : Physics
        Reads ``k_lin``, ``c_lin``, ``k_rot``, ``c_rot``.
    point : (3,) float64
        Position of the attachment point (the simulation's: the centre of mass).
    quat : (4,) float64
        Part orientation (w, x, y, z).
    point_velocity, omega : (3,) float64
        Velocity of the attachment point and angular velocity (world axes).
    proxy_point : (3,) float64
        Where the proxy places the attachment point.
    proxy_quat : (4,) float64
        Proxy orientation (w, x, y, z).

    Returns
    -------
    force, torque : (3,) float64
    """
    force = gains.k_lin * (proxy_point - point) - gains.c_lin * point_velocity
    r = rotvec_between(proxy_quat, quat)
    angle = math.sqrt(float(r @ r))
    play = gains.rot_play
    if gains.k_rot_hard > gains.k_rot and angle > play:
        # past the hand's play the spring stiffens: the part follows the proxy's turn
        spring = (gains.k_rot * play + gains.k_rot_hard * (angle - play)) / angle
        return force, spring * r - gains.c_rot_hard * omega
    torque = gains.k_rot * r - gains.c_rot * omega
    return force, torque


#: How stiff the hand is past its play: its natural frequency about the part's weakest
#: principal axis times the time step (the integrator is stable below 2; 1 is about four
#: hundred times the mass-based spring of a compact part at 1 kHz). At 0.5 generated pairs
#: turned up to 0.84 degree past the misaim and their play (seed 61523), at 1 up to 0.15
#: (seed 77291).
HAND_OMEGA_DT = 1.0
#: Its damping ratio about that axis: the damping term's share of a step, ``c dt / I``, is
#: ``2 ratio omega dt`` = 1, well inside the explicit step's limit of 2.
HAND_DAMPING_RATIO = 0.5


def weakest_inertia(inertia: np.ndarray) -> float:
    """The smallest principal moment of an inertia tensor (3, 3), at least 0."""
    return max(float(np.min(np.linalg.eigvalsh(np.asarray(inertia, np.float64)))), 0.0)


def hand_stiffness(inertia: np.ndarray, dt: float) -> float:
    """The stiffest spring past the hand's play that a step of ``dt`` integrates stably.

    ``(HAND_OMEGA_DT / dt)^2 I_min`` for the part's inertia tensor ``inertia`` (3, 3).
    """
    return (HAND_OMEGA_DT / dt) ** 2 * weakest_inertia(inertia)


def for_step(gains: Physics, dt: float) -> Physics:
    """``gains`` with the spring past the hand's play no stiffer than a step of ``dt`` allows.

    The gains are resolved for the scene's rate; a loop run at a lower rate (a longer step)
    would integrate them unstably, so the spring and its damping come down to the step.
    """
    cap = hand_stiffness(gains.inertia, dt)
    if gains.k_rot_hard <= cap or gains.k_rot_hard <= gains.k_rot:
        return gains
    from dataclasses import replace

    k = max(cap, gains.k_rot)
    # the damping keeps its ratio: it scales with the square root of the stiffness
    damping = gains.c_rot_hard * math.sqrt(k / gains.k_rot_hard)
    return replace(gains, k_rot_hard=k if k > gains.k_rot else 0.0, c_rot_hard=damping)


def near_fit(gains: Physics, near: Any, rotation: np.ndarray, origin: np.ndarray) -> Physics:
    """``gains`` with the hand's play opened as the part at ``(rotation, origin)`` nears its fit.

    ``near`` is the fine level (:class:`engine.correlation.near.NearField`; None: no fit
    known, the play everywhere): its closeness scales the play, 0 away from the fit and 1
    in it. Away from the fit the hand holds the part's orientation with its stiff spring
    from the first degree, so the band's stray torque on the way cannot turn it; near the
    fit the play lets the fit turn the part into line.
    """
    if near is None or gains.k_rot_hard <= gains.k_rot:
        return gains
    closeness = near.closeness(rotation, origin)
    if closeness >= 1.0:
        return gains
    return gains.with_play(gains.rot_play * max(closeness, 0.0))


def wrist_stop(body: RigidBody, state: BodyState, hold: np.ndarray, proxy_quat: np.ndarray,
               stop: float) -> bool:
    """Turn the part back to ``stop`` (rad) from the proxy if it is further; True if it was.

    The hand's wrist has a range: however hard the field pulls, the part held in it turns
    no further than ``stop`` from how the hand holds it (the proxy ``proxy_quat``, (4,)).
    The part is turned about the hold point ``hold`` (part's own frame, (3,)) along the
    shortest way back onto the range's edge, and the part of its angular velocity that
    turns it outward is taken away (an inelastic stop; the hold point keeps its velocity).
    The stiff spring past the play (:func:`coupling_wrench`) is as stiff as an explicit
    step allows, which still let a fit's torque at a hole's mouth overshoot the bore's axis
    by up to 0.85 degree past the play (seed 70919); a stop has no such limit.
    ``state`` is changed in place.
    """
    r = rotvec_between(state.quat, proxy_quat)  # proxy -> part
    angle = math.sqrt(float(r @ r))
    if not angle > stop:
        return False
    arm = np.asarray(hold, np.float64) - body.centre  # com -> hold, the part's own frame
    lever = state.rotation @ arm
    at = state.com + lever
    hold_velocity = state.velocity + cross3(state.omega, lever)
    # back along r by (angle - stop): a turn of -(angle - stop) r / angle on the part
    state.orient(quaternion_step(state.quat, r * (-(angle - stop) / angle), 1.0))
    outward = r / angle
    rate = float(state.omega @ outward)
    if rate > 0.0:
        state.omega = state.omega - rate * outward
    lever = state.rotation @ arm
    state.com = at - lever
    state.velocity = hold_velocity - cross3(state.omega, lever)
    return True


def coupling_energy(
    gains: Physics,
    point: np.ndarray,
    quat: np.ndarray,
    proxy_point: np.ndarray,
    proxy_quat: np.ndarray,
) -> float:
    """Potential energy of the coupling's springs, ``k |d|^2 / 2 + k_r |r|^2 / 2``."""
    d = proxy_point - point
    r = rotvec_between(proxy_quat, quat)
    linear = 0.5 * gains.k_lin * float(d @ d)
    angle = math.sqrt(float(r @ r))
    play = gains.rot_play
    if gains.k_rot_hard > gains.k_rot and angle > play:
        past = angle - play
        return linear + gains.k_rot * play * (0.5 * play + past) + 0.5 * gains.k_rot_hard * past**2
    return linear + 0.5 * gains.k_rot * angle**2


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
