"""The coupled system: input proxy -- spring-damper -- rigid part.

The geometric force field of the correlation engine acts on the part, and the system is
stepped at a fixed time step.

Data: poses (6,) float64 relative to part 1 (translation, rotation vector), forces and
torques (3,) float64 in part 1's frame, torques about world axes through part 2's origin.
The simulation owns its time step ``dt``: nothing else sets it, and changing the physics,
the effects or the field keeps it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np

from engine.correlation import Evaluation, add_evaluations
from engine.params import Effects, HapticLimits, Physics, SimulationParams
from engine.pose import quaternion_to_matrix, rotvec_to_quaternion
from engine.sim.body import BodyState, RigidBody, cross3, drift, kick, kinetic_energy, shed
from engine.sim.coupling import (
    coupling_energy,
    coupling_wrench,
    for_step,
    haptic_reaction,
    near_fit,
    wrist_stop,
)
from engine.sim.fields import ZERO_EVALUATION, GeometricField, field_correlator

if TYPE_CHECKING:
    from engine.correlation.near import NearField
from engine.sim.guard import check_motion, check_proxy_pose

#: Take the energy the field releases out of the part's motion each step (damping on):
#: a part drawn into a seat is led, not flung. False keeps it as speed (for comparisons).
SHED_RELEASE = True
#: The wrist's stop lies this fraction of the hand's play past it, so a part held at the stop
#: is past the play for the coupling's choice of spring and damping whatever the round-off
#: (exactly at the play, the choice flipped from step to step with the last bit).
STOP_PAST_PLAY = 1e-6
_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)


def _wrist(sim: Simulation) -> None:
    """The hand's wrist stops the part at its play from the proxy (``wrist_stop``).

    Where a hand is modelled (a stiffer spring past its play), the part is coupled, the
    effects dissipate (the stop is inelastic) and every axis is free (turning about the hold
    point moves the origin).
    """
    p = sim.physics
    if (sim.coupled and sim.effects.damping and sim._rmask is None and sim._tmask is None
            and p.k_rot_hard > p.k_rot and p.rot_play < math.pi):
        wrist_stop(sim.body, sim.state, sim.hold, sim._proxy_q,
                   p.rot_play * (1.0 + STOP_PAST_PLAY))


class HoldRule(Protocol):
    """Where the coupling holds the part for a pose (``engine.sim.build.FitHold``)."""

    def at(self, rotation: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """(3,) the hold point in the part's own frame, the part at ``rotation``, ``origin``."""
        ...


class Simulation:
    """Proxy, coupling, rigid part and geometric field, stepped at a fixed ``dt``.

    Owned by one thread (the engine loop); other threads see only the frames it publishes.

    Parameters
    ----------
    body : RigidBody
    physics : Physics
        Resolved gains, kappa and gravity (its ``dt`` is not read: the step is ``dt``).
    effects : Effects
    field : GeometricField
    start_pose : (6,) float64
        Part and proxy start here, at rest.
    dt : float, optional
        Fixed time step in seconds (default: that of the default rate). Only :attr:`dt`
        changes it later.
    limits : HapticLimits
    coupled : bool
        False: no proxy, no coupling (free body in the field; for energy tests).
    hold : (3,) float64, optional
        Where the coupling holds the part, in the part's own frame (default: its centre of
        mass). ``engine.sim.build`` holds it at the middle of the fit (``hold_point``).
    follow : optional
        Moves the hold point with the part: ``follow.at(rotation, origin)`` gives it, in the
        part's own frame, at the start of every step (``engine.sim.build.FitHold``: at the
        fit, as far in as the part is). None: ``hold`` throughout.
    """

    def __init__(
        self,
        body: RigidBody,
        physics: Physics,
        effects: Effects,
        field: GeometricField,
        start_pose: np.ndarray,
        *,
        dt: float | None = None,
        limits: HapticLimits | None = None,
        coupled: bool = True,
        hold: np.ndarray | None = None,
        follow: HoldRule | None = None,
    ):
        self.body = body
        #: The coupling's attachment point in the part's own frame.
        self.hold = np.array(body.centre if hold is None else hold, np.float64).reshape(3)
        self.follow = follow
        self.effects = effects
        self.field = field
        self.near: NearField | None = None  # the fine level where the parts meet (set_near)
        self.limits = limits or HapticLimits()
        self.coupled = coupled
        self.start_pose = np.array(start_pose, np.float64).reshape(6)
        self.dt = SimulationParams().dt if dt is None else dt
        self.set_effects(effects, physics)
        self.reset()

    # -- parameters ---------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Fixed time step in seconds; the one place it is kept."""
        return self._dt

    @dt.setter
    def dt(self, value: float) -> None:
        value = float(value)
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(f"the time step must be positive and finite, got {value!r}")
        self._dt = value
        if hasattr(self, "_resolved"):  # a new step: the hand's spring and the walls follow
            self.set_physics(self._resolved)

    def set_physics(self, physics: Physics) -> None:
        """New gains, kappa and gravity (the time step is kept).

        The coupling's spring past the hand's play comes down to what the step integrates
        stably (:func:`engine.sim.coupling.for_step`).
        """
        self._resolved = physics
        self.physics = for_step(physics, self._dt)
        self._gravity_force = self.body.mass * np.asarray(physics.gravity, np.float64)
        self.field.kappa = physics.kappa
        if self.near is not None:
            self.near.attach(self.physics, self._dt)
        self._sample_fresh = False  # kappa may have changed

    def set_effects(self, effects: Effects, physics: Physics | None = None) -> None:
        """New effects (free axes, damping, gravity) and their physics; the step is kept."""
        self.effects = effects
        tmask = effects.translation_mask
        rmask = effects.rotation_mask
        self._tmask = None if tmask.all() else tmask
        self._rmask = None if rmask.all() else rmask
        self.set_physics(self.physics if physics is None else physics)

    def set_field(self, field: GeometricField) -> None:
        """Swap in a new geometric field (scaled by the current kappa)."""
        field.kappa = self.physics.kappa
        self.field = field
        self.field_changed()

    def field_changed(self) -> None:
        """Say that the field changed (new modes, new descriptors).

        The next step evaluates it afresh instead of reusing the sample from the end of the last
        step.
        """
        self._sample_fresh = False

    # -- state ----------------------------------------------------------------------------------
    def reset(self, pose: np.ndarray | None = None) -> None:
        """Part and proxy at ``pose`` (default: the start pose), at rest; time zero."""
        pose = self.start_pose if pose is None else np.asarray(pose, np.float64).reshape(6)
        self.state = BodyState.at_pose(self.body, pose)
        self.time = 0.0
        self.step_time = 0.0
        self.steps = 0
        #: Energy taken back from the part's motion at changes of model (:meth:`_take_back`).
        self.taken_back = 0.0
        #: Energy the field released into motion and the step took out (:meth:`step`).
        self.released = 0.0
        self._ledger = 0.0  # energy the changes of model gave, net, not yet taken back
        self.set_proxy(pose)
        self.sample: Evaluation = ZERO_EVALUATION
        self._sample_fresh = False  # the field at the current pose is yet to be evaluated
        self.coupling_force = _ZERO3
        self.coupling_torque = _ZERO3
        self.haptic_force = _ZERO3
        self.haptic_torque = _ZERO3

    def set_proxy(self, pose: np.ndarray) -> None:
        """Move the proxy to ``pose`` (6,): finite and within reach (else an InputError)."""
        p = check_proxy_pose(pose, self.physics.length)
        self.proxy_pose = p.copy()
        self._proxy_t = p[:3].copy()
        self._proxy_q = rotvec_to_quaternion(p[3:])
        self._proxy_R = quaternion_to_matrix(self._proxy_q)
        # where the proxy wants the hold point: the coupling holds the part there
        self._proxy_hold = self._proxy_t + self._proxy_R @ self.hold

    def _take_back(self, jump: float) -> None:
        """Take back from the part's motion the energy a change of model gave it.

        Two things the step changes between poses are models of the energy, and a change
        of either can give the part energy that no force did work for:

        - the field's rotation cache, first order in the rotation since its anchor: over a
          stretch of ``n`` steps of ``s`` the part gains ``1/2 K s^2 (n^2 - n)`` (``K`` the
          curvature the model lacks), which the field reports at the switch
          (``Evaluation.switched``). Near a stiff fit these gains kept a peg oscillating
          0.3 degree in its hole;
        - the hold point, moved along the fit (:meth:`_follow_fit`): the coupling's energy
          at the part's pose changes with it. Unchecked, an undamped part at a 4 ms step
          gained energy from it until it diverged.

        The jumps are booked in a ledger, positive ones as energy given, negative ones as
        energy lost (a model's curvature need not have one sign: a part rattling in a hole
        meets both). While the ledger holds a net gain it is removed from the kinetic energy
        (velocity and angular velocity scaled by one factor, directions kept), never more
        than there is, and the rest waits for the next step. So the sum of kinetic and model
        energy runs on through every change as with a fixed model, drifting neither up nor
        (unlike removing only the gains) down: the passivity observer and controller of
        haptic rendering (Hannaford and Ryu 2002: measure the energy a discrete element
        generates, dissipate it when the net is a gain).
        """
        self._ledger += jump
        if not self._ledger > 0.0:
            return
        take = shed(self.body, self.state, self._ledger)
        self._ledger -= take
        self.taken_back += take

    def _follow_fit(self) -> None:
        """Move the hold point where ``follow`` puts it for the part's current pose.

        The coupling's energy change at this pose is booked with the other changes of model
        (:meth:`_take_back`).
        """
        if self.follow is None or not self.coupled:
            return
        state = self.state
        rot = state.rotation
        origin = state.origin(self.body)
        hold = np.asarray(self.follow.at(rot, origin), np.float64)
        if np.array_equal(hold, self.hold):
            return
        before = self._proxy_hold - (origin + rot @ self.hold)
        proxy_hold = self._proxy_t + self._proxy_R @ hold
        after = proxy_hold - (origin + rot @ hold)
        self.hold, self._proxy_hold = hold, proxy_hold
        self._take_back(0.5 * self.physics.k_lin * float(after @ after - before @ before))

    def part_pose(self) -> np.ndarray:
        """(6,) current pose of the part relative to part 1."""
        return self.state.pose(self.body)

    def total_energy(self) -> float:
        """Kinetic plus geometric plus gravity (plus coupling spring) energy."""
        e = kinetic_energy(self.body, self.state) + self.sample.energy
        e -= float(self._gravity_force @ self.state.com)
        if self.coupled:
            lever = self.state.rotation @ (self.hold - self.body.centre)
            gains = near_fit(self.physics, self.near, self.state.rotation,
                             self.state.origin(self.body))
            e += coupling_energy(gains, self.state.com + lever, self.state.quat,
                                 self._proxy_hold, self._proxy_q)
        return e

    def set_near(self, near: NearField | None) -> None:
        """Add the fine level where the parts meet, at the field's band and kappa (or None)."""
        self.near = near
        if near is not None:
            near.attach(self.physics, self._dt)
        self._sample_fresh = False

    def evaluate_field(self) -> Evaluation:
        """The field at the current pose, the fine level's added (stored in ``sample``)."""
        rot, origin = self.state.rotation, self.state.origin(self.body)
        sample = self.field.evaluate(rot, origin)
        if self.near is not None:
            corr = field_correlator(self.field)
            if self.near.follow(None if corr is None else corr.table):
                sample = add_evaluations(sample, self.near.evaluate(rot, origin))
        self.sample = sample
        return sample

    # -- stepping -------------------------------------------------------------------------------
    def _total_forces(self) -> tuple[np.ndarray, np.ndarray]:
        """Force at the part's origin and torque about it, on the part at its current state.

        Sums the stored field sample (given at the origin), gravity and body damping (at the
        centre of mass) and the coupling to the proxy (at the hold point). Sets the coupling
        outputs (about the part's origin) and the haptic ones (the reaction about the proxy's
        origin, scaled and clamped).
        """
        state, body, sample, p = self.state, self.body, self.sample, self.physics
        arm = state.rotation @ body.centre  # (3,) origin -> centre of mass
        at_com = self._gravity_force  # (3,) forces acting at the centre of mass
        torque = sample.torque if sample.torque is not None else _ZERO3
        if self.coupled:
            lever = state.rotation @ (self.hold - body.centre)  # centre of mass -> hold
            fc, tc = coupling_wrench(
                near_fit(p, self.near, state.rotation, state.origin(body)), state.com + lever,
                state.quat, state.velocity + cross3(state.omega, lever), state.omega,
                self._proxy_hold, self._proxy_q)
            self.coupling_force = fc
            self.coupling_torque = tc + cross3(arm + lever, fc)
            self.haptic_force, self.haptic_torque = haptic_reaction(
                fc, tc + cross3(self._proxy_hold - self._proxy_t, fc), self.limits
            )
            at_com = at_com + fc
            torque = torque + tc + cross3(lever, fc)
        if p.body_c_lin:
            at_com = at_com - p.body_c_lin * state.velocity
        if p.body_c_rot:
            torque = torque - p.body_c_rot * state.omega
        # moved to the origin, where kick takes them: torque + (com - origin) x force
        return sample.force + at_com, torque + cross3(arm, at_com)

    def step(self) -> Evaluation:
        """One fixed step, velocity Verlet; returns the field sample at the new pose.

        Half a kick with the forces at the current pose (the field sample from the end of the last
        step, the coupling to the proxy as it is now), a drift, the field at the new pose, half a
        kick with the new forces. One field evaluation per step; second order, so a free part
        keeps its energy far better than with symplectic Euler at the same step (the sample is
        also in :attr:`sample`). Damped: the field's release is shed, the wrist stops the part.
        """
        state, body, dt = self.state, self.body, self._dt
        if not self._sample_fresh:
            # after a reset, a new field or new gains the last pose the field saw was not
            # this step's: a switch it reports here measured nothing the part gained
            self.evaluate_field()
            self._sample_fresh = True
        self._follow_fit()
        tmask, rmask = self._tmask, self._rmask
        force, torque = self._total_forces()
        kick(body, state, force, torque, 0.5 * dt, translation_mask=tmask, rotation_mask=rmask)
        check_motion(self)  # before the drift takes a sine of a diverged angle
        drift(body, state, dt, translation_mask=tmask, rotation_mask=rmask)
        _wrist(self)
        before = self.sample.energy
        sample = self.evaluate_field()
        self._take_back(sample.switched)
        if SHED_RELEASE and self.effects.damping and self.coupled:  # led, not flung
            self.released += shed(body, state, before - sample.energy)
        force, torque = self._total_forces()
        kick(body, state, force, torque, 0.5 * dt, translation_mask=tmask, rotation_mask=rmask)
        check_motion(self)
        self.step_time = self.time
        self.time += dt
        self.steps += 1
        return sample

    def run(self, steps: int) -> None:
        """Step ``steps`` times (no proxy input)."""
        for _ in range(steps):
            self.step()
