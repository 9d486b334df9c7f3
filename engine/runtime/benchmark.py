"""Stand-ins for measuring the loop itself: an analytic field and a scripted proxy motion.

Data: rotations (3, 3) float64, translations and poses relative to part 1 as elsewhere; the
analytic well's energy is ``|t|^2 / 2`` with a rotational spring, so a step costs what the
loop costs without the correlator's modal sum.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from engine.correlation import Evaluation
from engine.sim import Simulation

__all__ = ["AnalyticWell", "bench_proxy_motion", "bench_trajectory"]


class AnalyticWell:
    """A geometric field in closed form: the loop without the modal sum.

    A quadratic well and a rotational spring, times ``kappa``.
    """

    rotation = True

    def __init__(self, kappa: float = 1.0):
        self.kappa = float(kappa)
        self.modes = 0

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy ``kappa |t|^2 / 2``, force ``-kappa t`` and a rotational spring's torque."""
        k = self.kappa
        t = np.asarray(translation, float)
        r = np.asarray(rotation, float)
        return Evaluation(0.5 * k * float(t @ t), -k * t,
                          -0.5 * k * (r - r.T)[[2, 0, 1], [1, 2, 0]], 0.0, 0)

    def set_modes(self, modes: int) -> None:
        """Remember ``modes`` (nothing depends on it)."""
        self.modes = int(modes)


def bench_proxy_motion(sim: Simulation) -> Callable[[float], np.ndarray]:
    """A slow circle of the proxy around the start pose, so the part keeps moving."""
    start = np.array(sim.start_pose)
    length = sim.physics.length

    def pose_at(t: float) -> np.ndarray:
        p = start.copy()
        p[0] += 0.05 * length * np.sin(2 * np.pi * 0.5 * t)
        p[1] += 0.05 * length * np.cos(2 * np.pi * 0.5 * t)
        p[2] -= 0.2 * length * (0.5 - 0.5 * np.cos(2 * np.pi * 0.25 * t))
        return p

    return pose_at


def bench_trajectory(sim: Simulation, seconds: float) -> np.ndarray:
    """(n, 7) float64 rows ``t, pose`` of :func:`bench_proxy_motion` every 10 ms."""
    pose_at = bench_proxy_motion(sim)
    ts = np.arange(0.0, seconds, 0.01)
    return np.column_stack([ts, np.array([pose_at(t) for t in ts])])
