"""What the readouts say, in plain words and the scene's units.

Data: poses (6,) float64 of part 2 relative to part 1 (``engine.pose``), energies, forces and
torques as the engine's frames carry them (``E = -kappa Re f`` with the physics kappa, in the
units of :class:`engine.params.QuantityUnits`). Pure functions and small value types, no Qt:
the window and the tests call them alike.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from engine import pose as posemath
from engine.params import CouplingParams, Effects, QuantityUnits
from engine.seat import SeatState, seat_state


@dataclass(frozen=True)
class MovingPart:
    """What the readouts and drags need of part 2, in its own frame and the scene's unit.

    ``centre`` (3,) float64 is its centre of mass (whose distance to its seat the readout
    gives); ``pivot`` (3,) float64 the point drags and typed poses turn about: the scene's
    ``pivot`` for the part, else its centre of mass, as the command line's typed poses
    (``evaluate --pose``, ``simulate --start``); ``size`` the diagonal of its bounding box.
    """

    centre: np.ndarray
    pivot: np.ndarray
    size: float


def moving_part(handle) -> MovingPart:
    """:class:`MovingPart` of a scene handle's part 2 (part 1 alone: its own centre)."""
    from engine.sim import mass_properties, part_pivot

    index = 1 if len(handle.parts) > 1 else 0
    part = handle.parts[index]
    v = np.asarray(part.vertices, float)
    _, _, centre = mass_properties(v, np.asarray(part.faces), handle.config.mass_spec(index),
                                   handle.scene.units)
    size = float(np.linalg.norm(np.ptp(v, axis=0))) if len(v) else 1.0
    pivot = part_pivot(handle, index)
    return MovingPart(np.asarray(centre, float), np.asarray(pivot, float),
                      size if size > 0 else 1.0)


def physics_kappa(handle, *, coupling: CouplingParams | None = None,
                  kappa: float | None = None, effects: Effects | None = None) -> float:
    """The kappa the engine uses for ``handle``'s scene (``E = -kappa Re f``).

    Resolved by the engine's own scene model (``engine.sim.SceneModel.physics``, as the
    engine and the command line's ``energy_scale`` do): the scene's or the user's kappa, else
    the scale-free default from the coupling stiffness and the part's size; so it changes
    with the coupling frequency unless a kappa is set.
    """
    from engine.sim import SceneModel

    model = SceneModel(handle)
    return float(model.physics(effects or handle.config.effects, coupling, kappa).kappa)


def units_of(handle) -> QuantityUnits:
    """The units of E, F, T and kappa in ``handle``'s scene."""
    return QuantityUnits.of(handle.scene.units)


def seat_of(handle, part: MovingPart, pose: np.ndarray) -> SeatState:
    """Part 2's distance and angle to its seat at ``pose`` (relative to part 1)."""
    return seat_state(np.asarray(pose, float), handle.assembled_pose, part.centre,
                      handle.scene.seat, part.size)


def number(value: float, digits: int = 4) -> str:
    """``value`` with ``digits`` significant digits, a true minus sign and no ``e+00``."""
    if not math.isfinite(value):
        return "–"
    text = f"{value:.{digits}g}"
    if "e" in text:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}×10^{int(exponent)}"
    return text.replace("-", "−")


def pose_text(pose: np.ndarray, unit: str, pivot: np.ndarray | None = None) -> str:
    """Part 2's pose relative to part 1 in words: where it is and its rotation (axis, angle).

    With ``pivot`` (3,) (part 2's own frame) it is the pose about the pivot
    (``engine.pose.origin_to_pivot``: the pivot's displacement, and the rotation about it;
    the origin pose when not turned), else the origin pose.
    """
    p = np.asarray(pose, float)
    if pivot is not None:
        p = posemath.origin_to_pivot(p, pivot)
    angle = float(np.degrees(np.linalg.norm(p[3:])))
    where = ", ".join(f"{v:.3f}" for v in p[:3])
    if angle < 1e-3:
        return f"at ({where}) {unit}, not turned"
    axis = p[3:] / np.linalg.norm(p[3:])
    return (f"at ({where}) {unit}, turned {angle:.2f}° about "
            f"({axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f})")


def free_axes_text(free_axes: tuple[str, ...] | None) -> str:
    """The fit's free axes in words (part 1's frame)."""
    if free_axes is None:
        return "not given by the scene (every axis counts)"
    if not free_axes:
        return "none (the fit locks every axis)"
    names = {"x": "slides along x", "y": "slides along y", "z": "slides along z",
             "rx": "turns about x", "ry": "turns about y", "rz": "turns about z"}
    return ", ".join(names[a] for a in free_axes)


def seat_text(state: SeatState, unit: str) -> tuple[str, str]:
    """(headline, detail) for the seat readout.

    The headline says "SEATED" or how far part 2 is from its seat; the detail gives the
    tolerances applied.
    """
    if state.seated:
        head = "SEATED"
    else:
        head = f"not seated: {state.distance:.3g} {unit} and {state.angle_deg:.2f}° from the seat"
    detail = (f"seated within {state.distance_tolerance:.3g} {unit} and "
              f"{state.angle_tolerance_deg:.3g}°")
    if state.free_axes:
        detail += f"; travel along the free axes {state.free_travel:.3g} {unit}"
    return head, detail


def duration_text(seconds: float) -> str:
    """A duration for people: "45 s", "3 min 20 s", "1 h 5 min"."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s // 3600} h {(s % 3600) // 60} min"


class ProgressClock:
    """Time left of a task from its fraction done, by the rate seen since it started.

    The estimate is linear in the fraction (the engine's descriptor and table builds advance
    in chunks of similar cost); none is given before one second has passed or 2 % is done.
    """

    MIN_SECONDS = 1.0
    MIN_FRACTION = 0.02

    def __init__(self, clock=time.perf_counter):
        self._clock = clock
        self.started = clock()
        self.fraction: float | None = None
        self._first: tuple[float, float] | None = None  # (time, fraction) of the first report

    def update(self, fraction: float) -> None:
        """Record the fraction done now (0..1)."""
        now = self._clock()
        f = min(max(float(fraction), 0.0), 1.0)
        if self._first is None:
            self._first = (now, f)
        self.fraction = f

    @property
    def elapsed(self) -> float:
        """Seconds since the task started."""
        return self._clock() - self.started

    def seconds_left(self) -> float | None:
        """Estimated seconds to go, or None while there is too little to go by."""
        if self.fraction is None or self._first is None:
            return None
        t0, f0 = self._first
        now = self._clock()
        if now - self.started < self.MIN_SECONDS or self.fraction - f0 < self.MIN_FRACTION:
            return None
        rate = (self.fraction - f0) / max(now - t0, 1e-9)
        return (1.0 - self.fraction) / rate

    def text(self) -> str:
        """"42 %, about 1 min 10 s left" or, without a fraction, the time spent so far."""
        if self.fraction is None:
            return f"{duration_text(self.elapsed)} so far"
        left = self.seconds_left()
        done = f"{100 * self.fraction:.0f} %"
        if left is None:
            return f"{done}, estimating the time left"
        return f"{done}, about {duration_text(left)} left"
