"""Fakes of the correlation engine for simulation tests: an analytic conservative field.

``SpringCorrelator``: springs joining body points p_i (part 2's frame) to anchors x_i
(part 1's frame), E = sum a_i / 2 |R p_i + t - x_i|^2. Force and torque (about the part's
origin, world axes) are exact, so energy conservation can be tested. It counts the work it
does, so tests can check that switched-off work is not done.
"""

from __future__ import annotations

import threading

import numpy as np

from engine.correlation import Evaluation


class FakeLandscape:
    """The spring field at one locked rotation, looked up per translation."""

    def __init__(self, owner, rotation):
        self.owner = owner
        self.rotation = np.array(rotation)

    def lookup(self, t):
        self.owner.lookups += 1
        e, f, _ = self.owner._field(self.rotation, np.asarray(t, float), torque=False)
        return Evaluation(e, f, None, 1.0, self.owner.modes)


class SpringCorrelator:
    def __init__(self, points, anchors, stiffness, *, rotation=True, modes=16, delay_s=0.0):
        self.points = np.asarray(points, float).reshape(-1, 3)
        self.anchors = np.asarray(anchors, float).reshape(-1, 3)
        self.a = np.broadcast_to(np.asarray(stiffness, float), (len(self.points),)).copy()
        self.rotation = rotation
        self.modes = modes
        self.kappa = 1.0  # its energy scale, as Correlator.kappa
        self.delay_s = delay_s
        self.evaluations = 0
        self.torque_sums = 0
        self.landscapes = 0
        self.lookups = 0
        self.threads: set[str] = set()

    def _field(self, R, t, torque):
        arms = self.points @ np.asarray(R).T  # (n, 3)
        d = arms + t - self.anchors
        e = 0.5 * float(np.sum(self.a * np.sum(d * d, axis=1)))
        f_each = -self.a[:, None] * d
        tq = np.sum(np.cross(arms, f_each), axis=0) if torque else None
        return e, f_each.sum(axis=0), tq

    def evaluate(self, R, t):
        self.evaluations += 1
        self.threads.add(threading.current_thread().name)
        if self.delay_s:
            import time

            end = time.perf_counter() + self.delay_s
            while time.perf_counter() < end:
                pass
        want_torque = self.rotation
        if want_torque:
            self.torque_sums += 1
        e, f, tq = self._field(np.asarray(R, float), np.asarray(t, float), want_torque)
        return Evaluation(e, f, tq, 1.0, self.modes)

    def set_modes(self, k):
        self.modes = int(k)

    def landscape(self, R):
        self.landscapes += 1
        return FakeLandscape(self, R)


def well(centre=(0.0, 0.0, 0.0), size=1.0, stiffness=50.0, **kw):
    """Three non-collinear springs: a full 6-DOF well at pose (centre, identity)."""
    pts = size * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, -1.0, 0.0]])
    return SpringCorrelator(pts, pts + np.asarray(centre), stiffness, **kw)


class UniformPull:
    """A constant force ``F`` on the part's centre of mass ``c`` (part frame): the field of a
    uniform pull, ``E = -F . (R c + t)``; force ``F`` and torque ``(R c) x F`` about the
    part's origin (exact, conservative).
    """

    rotation = True
    modes = 0

    def __init__(self, force, centre):
        self.force = np.asarray(force, float).reshape(3)
        self.centre = np.asarray(centre, float).reshape(3)

    def evaluate(self, R, t):
        arm = np.asarray(R, float) @ self.centre
        energy = -float(self.force @ (arm + np.asarray(t, float)))
        return Evaluation(energy, self.force.copy(), np.cross(arm, self.force), 1.0, 0)

    def set_modes(self, k):
        self.modes = int(k)
