"""Rigid body of the moving part: constant properties, mutable state, integrator pieces.

Works on one rigid body in part 1's frame ("world" below): centre-of-mass position (3,),
orientation as a unit quaternion (w, x, y, z) (4,), linear velocity of the centre of mass
(3,) and angular velocity in world axes (3,), all float64. Forces and torques come in at
the part's *origin* (the convention of the correlation engine and of poses: torque about
world axes through part 2's origin) and are moved to the centre of mass here.

Integrator pieces: :func:`kick` changes the velocities by an impulse, :func:`drift` moves
the body at its velocities, orientation by the exact exponential of the angular step
(``q <- exp(omega dt / 2) q``), renormalised; the gyroscopic term ``omega x (I omega)`` is
carried by the drift (torque-free motion at fixed angular momentum, midpoint rule), not by an
explicit term. :func:`step` is symplectic Euler (kick, then drift); the simulation composes them
as velocity Verlet (half kick, drift, new forces, half kick: second order, one field
evaluation per step). For a conservative field with damping off the energy error stays
bounded (no drift) for a step well inside the stability limit ``omega_max dt < 2``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.pose import quaternion_to_matrix, quaternion_to_rotvec, rotvec_to_quaternion


@dataclass(frozen=True)
class RigidBody:
    """Constant properties of the moving part.

    Attributes
    ----------
    mass : float
    inertia : (3, 3) float64
        About the centre of mass, in the part's own frame.
    centre : (3,) float64
        Centre of mass in the part's own frame.
    """

    mass: float
    inertia: np.ndarray
    centre: np.ndarray

    def __post_init__(self) -> None:
        inertia = np.array(self.inertia, dtype=np.float64).reshape(3, 3)
        centre = np.array(self.centre, dtype=np.float64).reshape(3)
        if not (self.mass > 0 and math.isfinite(self.mass)):
            raise ValueError(f"mass must be positive and finite, got {self.mass!r}")
        if np.any(np.linalg.eigvalsh(0.5 * (inertia + inertia.T)) <= 0):
            raise ValueError("inertia must be symmetric positive definite")
        inertia.setflags(write=False)
        centre.setflags(write=False)
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "centre", centre)
        inv = np.linalg.inv(inertia)
        inv.setflags(write=False)
        object.__setattr__(self, "_inv_inertia", inv)

    @property
    def inv_inertia(self) -> np.ndarray:
        """(3, 3) float64 inverse inertia in the body frame."""
        return self._inv_inertia  # type: ignore[attr-defined]


class BodyState:
    """The mutable state of the body (MuJoCo's "data"); owned by the engine thread.

    Attributes
    ----------
    com : (3,) float64
        Centre-of-mass position.
    quat : (4,) float64
        Orientation (w, x, y, z), body to world.
    velocity : (3,) float64
        Centre-of-mass velocity.
    omega : (3,) float64
        Angular velocity, world axes.
    """

    __slots__ = ("com", "quat", "velocity", "omega", "_R")

    def __init__(
        self,
        com: np.ndarray,
        quat: np.ndarray,
        velocity: np.ndarray | None = None,
        omega: np.ndarray | None = None,
    ):
        self.com = np.array(com, dtype=np.float64).reshape(3)
        self.quat = np.array(quat, dtype=np.float64).reshape(4)
        self.quat /= np.linalg.norm(self.quat)
        self.velocity = np.zeros(3) if velocity is None else np.array(velocity, float).reshape(3)
        self.omega = np.zeros(3) if omega is None else np.array(omega, float).reshape(3)
        self._R = quaternion_to_matrix(self.quat)

    @classmethod
    def at_pose(cls, body: RigidBody, pose: np.ndarray) -> BodyState:
        """A body at rest whose origin is at ``pose`` (6,)."""
        p = np.asarray(pose, dtype=np.float64).reshape(6)
        q = rotvec_to_quaternion(p[3:])
        R = quaternion_to_matrix(q)
        return cls(p[:3] + R @ body.centre, q)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) float64 rotation matrix (cached, updated by :func:`step`)."""
        return self._R

    def orient(self, quat: np.ndarray) -> None:
        """Set the orientation to the unit quaternion ``quat`` (4,) (the position kept)."""
        self.quat = np.asarray(quat, np.float64).reshape(4)
        self._R = quaternion_to_matrix(self.quat)

    def origin(self, body: RigidBody) -> np.ndarray:
        """(3,) position of the part's origin."""
        return self.com - self._R @ body.centre

    def pose(self, body: RigidBody) -> np.ndarray:
        """(6,) pose of the part's origin (translation, rotation vector)."""
        return np.concatenate([self.origin(body), quaternion_to_rotvec(self.quat)])

    def origin_velocity(self, body: RigidBody) -> np.ndarray:
        """(3,) velocity of the part's origin."""
        return self.velocity - cross3(self.omega, self._R @ body.centre)

    def copy(self) -> BodyState:
        """An independent copy of the state."""
        return BodyState(self.com.copy(), self.quat.copy(), self.velocity.copy(), self.omega.copy())


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(3,) cross product of two (3,) vectors (np.cross costs ~20x more on 3-vectors)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def rotvec_between(q_to: np.ndarray, q_from: np.ndarray) -> np.ndarray:
    """(3,) rotation vector of ``R_to R_from^T`` from two unit quaternions (w, x, y, z)."""
    w1, x1, y1, z1 = (float(v) for v in q_to)
    w2, x2, y2, z2 = (float(v) for v in q_from)
    # q_to * conj(q_from)
    w = w1 * w2 + x1 * x2 + y1 * y2 + z1 * z2
    x = -w1 * x2 + x1 * w2 - y1 * z2 + z1 * y2
    y = -w1 * y2 + x1 * z2 + y1 * w2 - z1 * x2
    z = -w1 * z2 - x1 * y2 + y1 * x2 + z1 * w2
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-12:
        return np.array([2.0 * x, 2.0 * y, 2.0 * z])
    k = 2.0 * math.atan2(s, w) / s
    return np.array([k * x, k * y, k * z])


def kinetic_energy(body: RigidBody, state: BodyState) -> float:
    """Translational plus rotational kinetic energy."""
    R = state.rotation
    i_world = R @ body.inertia @ R.T
    return float(
        0.5 * body.mass * state.velocity @ state.velocity
        + 0.5 * state.omega @ i_world @ state.omega
    )


def shed(body: RigidBody, state: BodyState, energy: float) -> float:
    """Take up to ``energy`` out of the part's kinetic energy in place; returns what was taken.

    Velocity and angular velocity are scaled by one factor (directions kept), never below rest.
    """
    if not energy > 0.0:
        return 0.0
    have = kinetic_energy(body, state)
    if not have > 0.0:
        return 0.0
    take = min(energy, have)
    scale = math.sqrt(max(0.0, 1.0 - take / have))
    state.velocity = state.velocity * scale
    state.omega = state.omega * scale
    return take


def quaternion_step(quat: np.ndarray, omega: np.ndarray, dt: float) -> np.ndarray:
    """(4,) orientation after turning at world angular velocity ``omega`` for ``dt``."""
    angle = float(math.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)) * dt
    if angle < 1e-15:
        return quat
    half = 0.5 * angle
    s = math.sin(half) / angle * dt
    w1, x1, y1, z1 = math.cos(half), s * omega[0], s * omega[1], s * omega[2]
    w2, x2, y2, z2 = quat
    q = np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )
    return q / math.sqrt(float(q @ q))


def kick(
    body: RigidBody,
    state: BodyState,
    force: np.ndarray,
    torque: np.ndarray,
    dt: float,
    *,
    translation_mask: np.ndarray | None = None,
    rotation_mask: np.ndarray | None = None,
) -> None:
    """Change the velocities in place by ``dt`` of ``force`` and ``torque`` (positions kept).

    Parameters
    ----------
    body : RigidBody
    state : BodyState
        Updated in place.
    force : (3,) float64
        Total force (gravity included), applied at the part's origin.
    torque : (3,) float64
        Total torque about world axes through the part's origin.
    dt : float
        Duration of the impulse in seconds.
    translation_mask, rotation_mask : (3,) float64, optional
        1 for free axes, 0 for locked ones (part 1's frame); locked components of the
        velocity and angular velocity are zeroed.
    """
    R = state.rotation
    arm = R @ body.centre  # (3,) origin -> centre of mass
    # torque about the centre of mass of a force applied at the origin
    torque_com = torque - cross3(arm, force)
    state.velocity = state.velocity + (dt / body.mass) * force
    if translation_mask is not None:
        state.velocity = state.velocity * translation_mask
    # the impulse changes the angular momentum L = I_world omega by dt torque; the body does
    # not turn during a kick, so no gyroscopic term here (the drift carries it, see there)
    inv_world = R @ body.inv_inertia @ R.T
    state.omega = state.omega + dt * (inv_world @ torque_com)
    if rotation_mask is not None:
        state.omega = state.omega * rotation_mask


def drift(
    body: RigidBody,
    state: BodyState,
    dt: float,
    *,
    translation_mask: np.ndarray | None = None,
    rotation_mask: np.ndarray | None = None,
) -> None:
    """Move the body in place for ``dt`` free of forces.

    The centre of mass moves at its velocity. The rotation is the torque-free motion: the
    world angular momentum ``L = I_world omega`` stays fixed while ``I_world`` turns with the
    body, integrated by the midpoint rule (turn half a step at the starting ``omega``,
    take ``omega = I_world^-1 L`` there, turn the whole step at it from the start, and end
    with ``omega = I_world^-1 L``): second order, ``L`` exact, and the gyroscopic effect is
    carried without an explicit ``omega x I omega`` term (an explicit one made the step first
    order). A locked translation axis (``translation_mask`` 0) holds the part's *origin*
    coordinate (rotation about an offset centre of mass would otherwise move it); locked
    rotation axes (``rotation_mask`` 0) keep a zero angular velocity component.
    """
    locked_origin = None
    if translation_mask is not None and not translation_mask.all():
        locked_origin = state.com - state.rotation @ body.centre
    state.com = state.com + dt * state.velocity
    omega = state.omega
    if omega[0] != 0.0 or omega[1] != 0.0 or omega[2] != 0.0:
        R0 = state.rotation
        momentum = R0 @ (body.inertia @ (R0.T @ omega))
        half = quaternion_to_matrix(quaternion_step(state.quat, omega, 0.5 * dt))
        mid = half @ (body.inv_inertia @ (half.T @ momentum))
        if rotation_mask is not None:
            mid = mid * rotation_mask
        state.quat = quaternion_step(state.quat, mid, dt)
        state._R = quaternion_to_matrix(state.quat)
        R1 = state._R
        omega = R1 @ (body.inv_inertia @ (R1.T @ momentum))
        if rotation_mask is not None:
            omega = omega * rotation_mask
        state.omega = omega
    if locked_origin is not None:
        assert translation_mask is not None
        origin = state.com - state._R @ body.centre
        keep = translation_mask == 0
        origin[keep] = locked_origin[keep]
        state.com = origin + state._R @ body.centre


def step(
    body: RigidBody,
    state: BodyState,
    force: np.ndarray,
    torque: np.ndarray,
    dt: float,
    *,
    translation_mask: np.ndarray | None = None,
    rotation_mask: np.ndarray | None = None,
) -> None:
    """Advance ``state`` in place by one symplectic Euler step.

    :func:`kick` by ``dt``, then :func:`drift` by ``dt`` (arguments as there). The simulation
    composes the two as velocity Verlet instead (:meth:`engine.sim.Simulation.step`).
    """
    kick(body, state, force, torque, dt, translation_mask=translation_mask,
         rotation_mask=rotation_mask)
    drift(body, state, dt, translation_mask=translation_mask, rotation_mask=rotation_mask)
