"""Geometric force fields acting on the moving part.

What the simulation asks of the correlation engine at one pose.

Data: the part's rotation (3, 3) float64 and origin (3,) float64 relative to part 1; each
field returns an :class:`engine.correlation.Evaluation` already scaled by its gain
``kappa`` (energy float, force (3,) float64, torque (3,) float64 about world axes through
the part's origin, zeros where no torque is computed).

- :class:`CorrelatorField`: the per-pose modal sum of a Correlator (torque only if its
  rotation is on);
- :class:`LandscapeField`: rotation locked, the translational energy landscape at the locked
  rotation, computed once and looked up per step (no modal sum);
- :class:`NullField`: guidance off, nothing computed.

:func:`field_for_effects` picks the cheapest of the three that gives what the effects ask for.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import numpy as np

from engine.correlation import Evaluation

if TYPE_CHECKING:
    from engine.correlation import Correlator, Landscape
    from engine.params import Effects

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)

#: The sample of a field that computes nothing.
ZERO_EVALUATION = Evaluation(0.0, _ZERO3, _ZERO3, 0.0, 0)


class GeometricField(Protocol):
    """What the simulation needs from the correlation engine."""

    rotation: bool
    modes: int
    kappa: float

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy, force and torque at one pose, scaled by ``kappa``."""
        ...

    def set_modes(self, modes: int) -> None:
        """Keep ``modes`` modes per axis from now on."""
        ...


class NullField:
    """Guidance off: no geometric force, nothing computed."""

    rotation = False

    def __init__(self) -> None:
        self.modes = 0
        self.kappa = 0.0

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The zero sample."""
        return ZERO_EVALUATION

    def set_modes(self, modes: int) -> None:
        """Remember ``modes`` (nothing depends on it)."""
        self.modes = int(modes)


def _scaled(ev: Evaluation, kappa: float, microseconds: float | None = None) -> Evaluation:
    """``ev`` times ``kappa``; a missing torque becomes zeros."""
    torque = _ZERO3 if ev.torque is None else kappa * np.asarray(ev.torque, np.float64)
    return Evaluation(
        kappa * float(ev.energy),
        kappa * np.asarray(ev.force, np.float64),
        torque,
        float(ev.microseconds if microseconds is None else microseconds),
        int(ev.modes),
    )


class CorrelatorField:
    """The per-pose modal sum of a Correlator, times ``kappa``.

    The correlator is built with ``kappa=1``; this field scales by its own ``kappa`` so that
    the gain can change live. With ``rotation=False`` on the correlator no torque is
    computed and the torque is reported as zeros.
    """

    def __init__(self, correlator: Correlator, kappa: float):
        self.correlator = correlator
        self.kappa = float(kappa)
        self.rotation = bool(correlator.rotation)
        self.modes = int(correlator.modes)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The correlator's evaluation at ``(rotation, translation)``, times kappa."""
        return _scaled(self.correlator.evaluate(rotation, translation), self.kappa)

    def set_modes(self, modes: int) -> None:
        """Change the correlator's modes per axis."""
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)


class LandscapeField:
    """Rotation locked: the translational energy landscape at the locked rotation.

    Computed once (an inverse FFT over all translations) and looked up per step, times
    ``kappa``.
    """

    rotation = False

    def __init__(self, correlator: Correlator, locked_rotation: np.ndarray, kappa: float):
        self.correlator = correlator
        self.locked_rotation = np.array(locked_rotation, np.float64).reshape(3, 3)
        self.kappa = float(kappa)
        self.modes = int(correlator.modes)
        self.landscape: Landscape = correlator.landscape(self.locked_rotation)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The landscape's value at ``translation`` (``rotation`` is the locked one)."""
        return _scaled(self.landscape.lookup(np.asarray(translation, np.float64)), self.kappa)

    def set_modes(self, modes: int) -> None:
        """Change the modes and recompute the landscape (an FFT, tens of ms)."""
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)
        self.landscape = self.correlator.landscape(self.locked_rotation)


def field_for_effects(
    effects: Effects,
    make_correlator: Callable[[bool], Correlator] | None,
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
