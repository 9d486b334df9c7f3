"""Keeping a simulation finite: proxy poses within reach, divergence detected and explained.

Works on the moving body's state (centre of mass (3,), quaternion (4,), velocity (3,),
angular velocity (3,), float64) and on proxy poses (6,) float64 in part 1's frame.

A fixed-step integrator that is pushed beyond its stability limit (a gain too stiff for the
step, an inertia far too small, a force of 1e300) does not fail by itself: its state grows
geometrically until a sine of an infinite angle raises "math domain error" or a NaN
reaches a pose. :func:`check_motion` catches that growth while every number is still
finite, from a bound on the kinetic energy: a part that moves more than its own length, or
turns more than a radian, in one step is no longer integrated (the field it moves in
changes over a grid cell). :func:`explain` then names the likely cause from the forces and
gains at that step.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np

from engine.correlation import Evaluation
from engine.errors import Diverged, InputError
from engine.params import MAX_ROTATION_VECTOR, Physics
from engine.sim.body import BodyState, RigidBody


class Simulation(Protocol):
    """What the guard reads of an :class:`engine.sim.Simulation` (no import of it here)."""

    state: BodyState
    physics: Physics
    body: RigidBody
    time: float
    steps: int
    sample: Evaluation
    coupling_force: np.ndarray
    proxy_pose: np.ndarray

    @property
    def dt(self) -> float:
        """Fixed time step in seconds."""

#: Most part lengths the body may travel in one step.
MAX_STEP_LENGTHS = 1.0
#: Most radians the body may turn in one step.
MAX_STEP_RADIANS = 1.0
#: A proxy farther than this many part lengths from part 1's origin is out of reach (the
#: coupling's force on the part would be that many lengths times its stiffness).
MAX_PROXY_LENGTHS = 1000.0


def check_proxy_pose(pose: np.ndarray, length: float, what: str = "proxy pose") -> np.ndarray:
    """``pose`` (6,) float64 when finite and within reach of part 1, else an InputError.

    Parameters
    ----------
    pose : (6,) float
        Translation then rotation vector, part 1's frame.
    length : float
        The moving part's length (largest side), the scale of the reach.
    what : str
        Names the pose in the message (a file and row, say).
    """
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    if not np.all(np.isfinite(p)):
        raise InputError(f"{what} {p.tolist()} is not finite (NaN or infinity): give six "
                         "finite numbers")
    reach = MAX_PROXY_LENGTHS * length
    distance = math.hypot(*p[:3])  # no overflow for 1e300
    if distance > reach:
        raise InputError(
            f"{what} puts part 2 {distance:.3g} from part 1, more than {MAX_PROXY_LENGTHS:g} "
            f"times its size ({reach:.3g}): the coupling would throw it there in one step; "
            "check the numbers and their unit")
    angle = math.hypot(*p[3:])
    if angle > MAX_ROTATION_VECTOR:
        raise InputError(
            f"{what} has a rotation vector of {angle:.3g} rad, above {MAX_ROTATION_VECTOR:g}: "
            "rotations are rotation vectors in radians (reduce it modulo 2 pi)")
    return p


#: Most a device may move the proxy the coupling sees in one step: this share of the part's
#: length and this many radians (at 1 kHz, 20 lengths and 20 rad a second: faster than a
#: hand assembles). A packet that jumps farther is followed at that pace, so the part
#: chases a proxy that moves at most this fast and its speed stays far below the length a
#: step that :func:`check_motion` refuses. Before, two legal UDP poses 1,980 mm apart
#: ended the run as "diverged" and blamed the coupling's gains.
MAX_PROXY_STEP_LENGTHS = 0.02
MAX_PROXY_STEP_RADIANS = 0.02


def limit_proxy_step(current: np.ndarray, target: np.ndarray, length: float
                     ) -> tuple[np.ndarray, bool]:  # fmt: skip
    """The proxy pose (6,) one step from ``current`` towards ``target``, and whether short.

    The translation moves at most ``MAX_PROXY_STEP_LENGTHS * length`` along the straight
    line, the rotation at most ``MAX_PROXY_STEP_RADIANS`` about the axis of the relative
    rotation. Returns ``(target, False)`` when it is within both.
    """
    from engine.pose import rotation_matrix, rotation_vector

    a = np.asarray(current, dtype=np.float64).reshape(6)
    b = np.asarray(target, dtype=np.float64).reshape(6)
    reach = MAX_PROXY_STEP_LENGTHS * length
    move = b[:3] - a[:3]
    distance = math.hypot(*move)
    r_a = rotation_matrix(a[3:])
    turn = rotation_vector(rotation_matrix(b[3:]) @ r_a.T)  # (3,) relative rotation
    angle = math.hypot(*turn)
    if distance <= reach and angle <= MAX_PROXY_STEP_RADIANS:
        return b, False
    out = b.copy()
    if distance > reach:
        out[:3] = a[:3] + move * (reach / distance)
    if angle > MAX_PROXY_STEP_RADIANS:
        out[3:] = rotation_vector(rotation_matrix(turn * (MAX_PROXY_STEP_RADIANS / angle)) @ r_a)
    return out, True


def check_motion(sim: Simulation) -> None:
    """Raise :class:`Diverged` when the body's state is not finite or moves too fast.

    Costs about a microsecond: three dot products.
    """
    s, dt = sim.state, sim.dt
    v2 = float(s.velocity @ s.velocity)
    w2 = float(s.omega @ s.omega)
    c2 = float(s.com @ s.com) + float(s.quat @ s.quat)
    reach = MAX_STEP_LENGTHS * sim.physics.length / dt
    if v2 <= reach * reach and w2 * dt * dt <= MAX_STEP_RADIANS**2 and math.isfinite(c2):
        return
    raise Diverged(explain(sim))


def explain(sim: Simulation) -> str:
    """What diverged, when, and the likely cause (the message of :class:`Diverged`)."""
    s, p, dt = sim.state, sim.physics, sim.dt
    speed = float(np.linalg.norm(s.velocity))
    spin = float(np.linalg.norm(s.omega))
    if not (math.isfinite(speed) and math.isfinite(spin)
            and np.all(np.isfinite(s.com)) and np.all(np.isfinite(s.quat))):
        what = "its state is no longer finite"
    elif speed * dt > MAX_STEP_LENGTHS * p.length:
        what = (f"the part moves {speed * dt / p.length:.3g} of its lengths per step "
                f"(speed {speed:.3g})")
    else:
        what = f"the part turns {spin * dt:.3g} rad per step"
    causes = _causes(sim)
    cause = causes[0] if causes else (
        "the forces and gains look sound; the input may have jumped (a proxy pose far away)")
    return (f"the simulation diverged at t = {sim.time:.4g} s (step {sim.steps}): {what}. "
            f"Likely cause: {cause}")


def _causes(sim: Simulation) -> list[str]:
    """Candidate causes, the most likely first."""
    p, dt, body = sim.physics, sim.dt, sim.body
    out: list[str] = []
    proxy = np.asarray(sim.proxy_pose, np.float64)
    if not np.all(np.isfinite(proxy)) or (
            np.linalg.norm(proxy[:3]) > MAX_PROXY_LENGTHS * p.length):
        out.append(f"the proxy pose {proxy.tolist()} is out of reach")
    w_lin = math.sqrt(p.k_lin / p.mass) * dt
    if w_lin > 2.0:
        out.append(f"the coupling stiffness {p.k_lin:.3g} for mass {p.mass:.3g} is too stiff "
                   f"for the {dt:.3g} s step (sqrt(k/m) dt = {w_lin:.3g} > 2): lower "
                   "[coupling] stiffness or frequency_hz, or raise [simulation] rate_hz")
    i_min = float(np.min(np.linalg.eigvalsh(body.inertia)))
    k_rot = max(p.k_rot, p.k_rot_hard)
    w_rot = math.sqrt(k_rot / i_min) * dt if i_min > 0 else math.inf
    if w_rot > 2.0:
        out.append(f"the rotational coupling {k_rot:.3g} is too stiff for the smallest "
                   f"principal inertia {i_min:.3g} at the {dt:.3g} s step (sqrt(k/I) dt = "
                   f"{w_rot:.3g} > 2): check the part's inertia (and its unit) or lower "
                   "[coupling] angular_stiffness")
    forces = {
        "the geometric force": float(np.linalg.norm(sim.sample.force)),
        "gravity": float(np.linalg.norm(p.gravity)) * p.mass,
        "the coupling": float(np.linalg.norm(sim.coupling_force)),
    }
    strongest = max(forces, key=lambda k: forces[k] if math.isfinite(forces[k]) else math.inf)
    size = forces[strongest]
    if strongest == "the geometric force":
        out.append(f"the geometric force ({size:.3g}, kappa = {p.kappa:.3g}) dwarfs the "
                   "coupling: lower [simulation] kappa (or write \"auto\")")
    elif strongest == "gravity":
        out.append(f"gravity ({size:.3g} on mass {p.mass:.3g}) dwarfs the other forces: "
                   "check [effects] gravity and its unit")
    else:
        out.append(f"the coupling's force ({size:.3g}) grew without bound: check the "
                   "[coupling] gains and the part's mass and inertia")
    return out
