"""Virtual coupling and the coupled system: input proxy -- spring-damper -- rigid part, with
the geometric force field of the correlation engine acting on the part.

Data: poses (6,) float64 relative to part 1, forces and torques (3,) float64 in part 1's
frame, torques about world axes through part 2's origin (the correlation convention).

The coupling is a six-axis spring-damper between the proxy frame and the part's frame,
attached at the part's origin::

    F_c = k (t_proxy - t) - c v_origin
    T_c = k_r rotvec(R_proxy R^T) - c_r omega

(damping against the world: robust to jerky mouse input, which has no clean velocity).
The device renders the reaction ``-F_c, -T_c`` scaled by ``force_scale`` and clamped in
norm to ``max_force`` / ``max_torque``. The part itself feels the unclamped coupling.

Geometric fields: :class:`CorrelatorField` (full modal sum, torque only if rotation is
free), :class:`LandscapeField` (rotation locked: the translational landscape at the locked
rotation, computed once and looked up per step, no modal sum), :class:`NullField`
(guidance off: nothing is computed).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from engine.dynamics import (
    BodyState,
    RigidBody,
    cross3,
    drift,
    kick,
    kinetic_energy,
    rotvec_between,
)
from engine.pose import quaternion_to_matrix, rotation_vector, rotvec_to_quaternion
from engine.simconfig import Effects, Physics

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


@dataclass(frozen=True)
class CouplingGains:
    """Spring-damper gains: force/length, force*s/length, torque/rad, torque*s/rad."""

    k_lin: float
    c_lin: float
    k_rot: float
    c_rot: float

    @classmethod
    def from_physics(cls, physics: Physics) -> CouplingGains:
        return cls(physics.k_lin, physics.c_lin, physics.k_rot, physics.c_rot)


@dataclass(frozen=True)
class HapticLimits:
    """Rendering of the reaction on the device: scale, then clamp the norms."""

    force_scale: float = 1.0
    max_force: float = math.inf
    max_torque: float = math.inf


def coupling_wrench(
    gains: CouplingGains,
    origin: np.ndarray,
    rotation: np.ndarray,
    origin_velocity: np.ndarray,
    omega: np.ndarray,
    proxy_translation: np.ndarray,
    proxy_rotation: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Force and torque the coupling applies at the part's origin.

    Parameters
    ----------
    gains : CouplingGains
    origin : (3,) float64
        Part origin position.
    rotation : (3, 3) float64
        Part orientation.
    origin_velocity, omega : (3,) float64
        Velocity of the part's origin and angular velocity (world axes).
    proxy_translation : (3,) float64
    proxy_rotation : (3, 3) float64

    Returns
    -------
    force, torque : (3,) float64
    """
    force = gains.k_lin * (proxy_translation - origin) - gains.c_lin * origin_velocity
    torque = gains.k_rot * rotation_vector(proxy_rotation @ rotation.T) - gains.c_rot * omega
    return force, torque


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


# ---------------------------------------------------------------------------------------------
# geometric fields


class FieldSample:
    """One evaluation of a geometric field, already scaled by kappa.

    Attributes: ``energy`` float, ``force`` (3,) float64, ``torque`` (3,) float64 (zeros
    when not computed), ``microseconds`` float (time in the evaluator).
    """

    __slots__ = ("energy", "force", "torque", "microseconds")

    def __init__(self, energy=0.0, force=_ZERO3, torque=_ZERO3, microseconds=0.0):
        self.energy = energy
        self.force = force
        self.torque = torque
        self.microseconds = microseconds


class GeometricField(Protocol):
    """What the simulation needs from the correlation engine."""

    rotation: bool
    modes: int

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> FieldSample: ...

    def set_modes(self, modes: int) -> None: ...


class NullField:
    """Guidance off: no geometric force, nothing computed."""

    rotation = False
    modes = 0

    def __init__(self) -> None:
        self._sample = FieldSample()

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> FieldSample:
        return self._sample

    def set_modes(self, modes: int) -> None:
        self.modes = int(modes)


class CorrelatorField:
    """The per-pose modal sum of an ``engine.correlation.Correlator``, times kappa.

    The correlator should be built with ``kappa=1``; this field scales by its own ``kappa``
    so that the gain can change live. With ``rotation=False`` on the correlator no torque is
    computed and the torque is reported as zeros.
    """

    def __init__(self, correlator: Any, kappa: float):
        self.correlator = correlator
        self.kappa = float(kappa)
        self.rotation = bool(getattr(correlator, "rotation", True))
        self.modes = int(getattr(correlator, "modes", 0))

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> FieldSample:
        ev = self.correlator.evaluate(rotation, translation)
        torque = _ZERO3 if ev.torque is None else self.kappa * np.asarray(ev.torque, float)
        return FieldSample(
            self.kappa * float(ev.energy),
            self.kappa * np.asarray(ev.force, float),
            torque,
            float(ev.microseconds),
        )

    def set_modes(self, modes: int) -> None:
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)


class LandscapeField:
    """Rotation locked: the translational energy landscape at the locked rotation, computed
    once (an inverse FFT over all translations) and looked up per step.

    ``landscape.lookup(t)`` may return an object with ``energy`` and ``force`` or a tuple
    ``(energy, force)``; both are accepted (kappa-free, scaled here).
    """

    rotation = False

    def __init__(self, correlator: Any, locked_rotation: np.ndarray, kappa: float):
        self.correlator = correlator
        self.locked_rotation = np.array(locked_rotation, float)
        self.kappa = float(kappa)
        self.modes = int(getattr(correlator, "modes", 0))
        self.landscape = correlator.landscape(self.locked_rotation)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> FieldSample:
        t0 = time.perf_counter()
        res = self.landscape.lookup(np.asarray(translation, float))
        if hasattr(res, "energy"):
            energy, force = res.energy, res.force
        else:
            energy, force = res[0], res[1]
        us = (time.perf_counter() - t0) * 1e6
        return FieldSample(
            self.kappa * float(energy), self.kappa * np.asarray(force, float), _ZERO3, us
        )

    def set_modes(self, modes: int) -> None:
        # the landscape depends on the modes kept: recompute it (an FFT, tens of ms)
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)
        self.landscape = self.correlator.landscape(self.locked_rotation)


# ---------------------------------------------------------------------------------------------
# the coupled system


class Simulation:
    """Proxy, coupling, rigid part and geometric field, stepped at a fixed ``dt``.

    Owned by one thread (the engine loop); other threads see only the frames it publishes.

    Parameters
    ----------
    body : RigidBody
    physics : Physics
        Resolved gains, kappa, gravity and step.
    effects : Effects
    field : GeometricField
    start_pose : (6,) float64
        Part and proxy start here, at rest.
    limits : HapticLimits
    coupled : bool
        False: no proxy, no coupling (free body in the field; for energy tests).
    """

    def __init__(
        self,
        body: RigidBody,
        physics: Physics,
        effects: Effects,
        field: GeometricField,
        start_pose: np.ndarray,
        *,
        limits: HapticLimits | None = None,
        coupled: bool = True,
    ):
        self.body = body
        self.effects = effects
        self.field = field
        self.limits = limits or HapticLimits()
        self.coupled = coupled
        self.start_pose = np.array(start_pose, float).reshape(6)
        self.set_physics(physics)
        self.reset()

    # -- parameters ---------------------------------------------------------------------------
    def set_physics(self, physics: Physics) -> None:
        self.physics = physics
        self.dt = physics.dt
        self.gains = CouplingGains.from_physics(physics)
        self._gravity_force = physics.mass * np.asarray(physics.gravity, float)
        if isinstance(self.field, (CorrelatorField, LandscapeField)):
            self.field.kappa = physics.kappa
        self._tmask = self.effects.translation_mask
        self._rmask = self.effects.rotation_mask
        self._tmask_opt = None if self._tmask.all() else self._tmask
        self._rmask_opt = None if self._rmask.all() else self._rmask
        self._sample_fresh = False  # kappa may have changed

    def set_field(self, field: GeometricField) -> None:
        if isinstance(field, (CorrelatorField, LandscapeField)):
            field.kappa = self.physics.kappa
        self.field = field
        self.field_changed()

    def field_changed(self) -> None:
        """Say that the field changed (new modes, new descriptors): the next step evaluates it
        afresh instead of reusing the sample from the end of the last step."""
        self._sample_fresh = False

    def set_effects(self, effects: Effects, physics: Physics) -> None:
        self.effects = effects
        self.set_physics(physics)

    # -- state ----------------------------------------------------------------------------------
    def reset(self, pose: np.ndarray | None = None) -> None:
        pose = self.start_pose if pose is None else np.asarray(pose, float).reshape(6)
        self.state = BodyState.at_pose(self.body, pose)
        self.time = 0.0
        self.step_time = 0.0
        self.steps = 0
        self.set_proxy(pose)
        self.sample = FieldSample()
        self._sample_fresh = False  # the field at the current pose is yet to be evaluated
        self.coupling_force = _ZERO3
        self.coupling_torque = _ZERO3
        self.haptic_force = _ZERO3
        self.haptic_torque = _ZERO3

    def set_proxy(self, pose: np.ndarray) -> None:
        p = np.asarray(pose, float).reshape(6)
        self.proxy_pose = p.copy()
        self._proxy_t = p[:3].copy()
        self._proxy_q = rotvec_to_quaternion(p[3:])
        self._proxy_R = quaternion_to_matrix(self._proxy_q)

    def part_pose(self) -> np.ndarray:
        """(6,) current pose of the part relative to part 1."""
        return self.state.pose(self.body)

    def total_energy(self) -> float:
        """Kinetic plus geometric plus gravity (plus coupling spring) energy."""
        e = kinetic_energy(self.body, self.state) + self.sample.energy
        e -= float(self._gravity_force @ self.state.com)
        if self.coupled:
            origin = self.state.origin(self.body)
            d = self._proxy_t - origin
            r = rotation_vector(self._proxy_R @ self.state.rotation.T)
            e += 0.5 * self.gains.k_lin * float(d @ d) + 0.5 * self.gains.k_rot * float(r @ r)
        return e

    def evaluate_field(self) -> FieldSample:
        """Evaluate the geometric field at the current pose (stores it in ``sample``)."""
        R = self.state.rotation
        self.sample = self.field.evaluate(R, self.state.origin(self.body))
        return self.sample

    # -- stepping -------------------------------------------------------------------------------
    def _total_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """Force and torque on the part at its current state: the stored field sample,
        gravity, the coupling to the proxy (sets the coupling and haptic outputs) and body
        damping."""
        state, body, sample = self.state, self.body, self.sample
        force = sample.force + self._gravity_force
        torque = sample.torque
        if self.coupled:
            R = state.rotation
            origin = state.com - R @ body.center
            v_origin = state.velocity - cross3(state.omega, R @ body.center)
            g = self.gains
            fc = g.k_lin * (self._proxy_t - origin) - g.c_lin * v_origin
            tc = g.k_rot * rotvec_between(self._proxy_q, state.quat) - g.c_rot * state.omega
            self.coupling_force, self.coupling_torque = fc, tc
            self.haptic_force, self.haptic_torque = haptic_reaction(fc, tc, self.limits)
            force = force + fc
            torque = torque + tc
        p = self.physics
        if p.body_c_lin:
            force = force - p.body_c_lin * state.velocity
        if p.body_c_rot:
            torque = torque - p.body_c_rot * state.omega
        return force, torque

    def step(self) -> FieldSample:
        """One fixed step, velocity Verlet: half a kick with the forces at the current pose
        (the field sample from the end of the last step, the coupling to the proxy as it is
        now), a drift, the field at the new pose, half a kick with the new forces. One field
        evaluation per step; second order, so a free part keeps its energy far better than
        with symplectic Euler at the same step. Returns the field sample at the new pose
        (also in :attr:`sample`)."""
        state, body = self.state, self.body
        if not self._sample_fresh:
            self.evaluate_field()
            self._sample_fresh = True
        half = 0.5 * self.dt
        masks = {"translation_mask": self._tmask_opt, "rotation_mask": self._rmask_opt}
        force, torque = self._total_forces()
        kick(body, state, force, torque, half, **masks)
        drift(body, state, self.dt, **masks)
        sample = self.evaluate_field()
        force, torque = self._total_forces()
        kick(body, state, force, torque, half, **masks)
        self.step_time = self.time
        self.time += self.dt
        self.steps += 1
        return sample

    def run(self, steps: int) -> None:
        """Step ``steps`` times (no proxy input)."""
        for _ in range(steps):
            self.step()


def field_for_effects(
    effects: Effects,
    make_correlator: Any,
    *,
    kappa: float,
    locked_rotation: np.ndarray,
) -> GeometricField:
    """The cheapest field that provides what ``effects`` asks for.

    Parameters
    ----------
    effects : Effects
    make_correlator : callable(rotation: bool) -> Correlator, or None
        Builds the correlator; called with ``rotation=False`` when rotation is locked so
        that no torque spectra or sums are computed. Not called when guidance is off or no
        moving part exists (None).
    kappa : float
    locked_rotation : (3, 3) float64
        The part's rotation, used when rotation is locked.

    Returns
    -------
    NullField, LandscapeField (rotation locked) or CorrelatorField.
    """
    if effects.guidance == "none" or make_correlator is None:
        return NullField()
    if not effects.rotation:
        return LandscapeField(make_correlator(False), locked_rotation, kappa)
    return CorrelatorField(make_correlator(True), kappa)
