"""What crosses the engine boundary: frozen commands in, immutable frames and events out.

Data: poses are (6,) float64 ``(tx, ty, tz, rx, ry, rz)`` of part 2 relative to part 1
(``engine.pose``); forces and torques (3,) float64 in part 1's frame. Arrays inside frames
and events are read-only, so no mutable state is shared between the engine and its reader.
Every type here pickles (the process transport sends events through a pipe).
"""

from __future__ import annotations

import math
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from engine.params import CouplingParams, DescriptorParams, Effects

if TYPE_CHECKING:
    from engine.correlation import Landscape
    from engine.descriptor import Descriptor

__all__ = [
    "CancelRecompute",
    "Command",
    "COMMAND_TYPES",
    "DescriptorsSwapped",
    "DeviceEvent",
    "ErrorEvent",
    "Event",
    "Frame",
    "LandscapeFailed",
    "LandscapeReady",
    "Pause",
    "PeriodStats",
    "ProgressEvent",
    "ReadyEvent",
    "RequestLandscape",
    "Reset",
    "SetCoupling",
    "SetDescriptorParams",
    "SetDevice",
    "SetEffects",
    "SetKappa",
    "SetModes",
    "SetProxyPose",
    "Stop",
    "StoppedEvent",
    "describe_error",
]


# ---------------------------------------------------------------------------------------------
# frames


@dataclass(frozen=True)
class PeriodStats:
    """Loop period statistics over the last ``window`` steps (microseconds).

    ``rate_hz`` is steps per wall-clock second over that window; in as-fast-as-possible mode
    it is the raw stepping rate.
    """

    rate_hz: float = 0.0
    median_us: float = 0.0
    p1_us: float = 0.0
    p99_us: float = 0.0
    max_us: float = 0.0
    window: int = 0


@dataclass(frozen=True)
class Frame:
    """An immutable snapshot of the simulation after one loop iteration.

    Both transports deliver the same fields (``engine.runtime.frames`` packs and unpacks
    them in one place); frames keep coming while the engine is paused.

    Attributes
    ----------
    time : float
        Simulated time in seconds (``step * dt``).
    step : int
    proxy_pose : (6,) float64, read-only
        The input proxy (the ghost), relative to part 1.
    part_pose : (6,) float64, read-only
        The moving part, relative to part 1.
    energy : float
        Geometric energy ``E = -kappa Re f`` (0 when guidance is off).
    force, torque : (3,) float64, read-only
        Geometric force and torque on the part (part 1's frame; torque about the part's
        origin). Torque is zeros when rotation is locked (and was not computed).
    coupling_force, coupling_torque : (3,) float64, read-only
        Virtual coupling's pull on the part.
    haptic_force, haptic_torque : (3,) float64, read-only
        What the device renders: the reaction on the proxy, scaled and clamped.
    eval_us : float
        Microseconds spent in the correlator this step.
    step_us : float
        Microseconds of the whole iteration (input, correlator, integration, output).
    period : PeriodStats
        Loop timing over the recent window (refreshed every ~100 steps).
    modes : int
        Current K (m' = K^3).
    paused : bool
    recompute : float or None
        Fraction done of a background descriptor recompute, None when none runs.
    device : str
        Name of the device driving the proxy (at most 16 ASCII characters are kept).
    """

    time: float
    step: int
    proxy_pose: np.ndarray
    part_pose: np.ndarray
    energy: float
    force: np.ndarray
    torque: np.ndarray
    coupling_force: np.ndarray
    coupling_torque: np.ndarray
    haptic_force: np.ndarray
    haptic_torque: np.ndarray
    eval_us: float
    step_us: float
    period: PeriodStats
    modes: int
    paused: bool = False
    recompute: float | None = None
    device: str = "mouse"


# ---------------------------------------------------------------------------------------------
# commands (GUI -> engine)


@dataclass(frozen=True)
class SetProxyPose:
    """Move the input proxy (mouse drags); ``pose`` (6,) relative to part 1."""

    pose: tuple[float, ...]

    def __post_init__(self) -> None:
        p = tuple(float(v) for v in np.asarray(self.pose, dtype=float).reshape(6))
        if not all(math.isfinite(v) for v in p):
            raise ValueError(f"proxy pose must be six finite numbers, got {self.pose!r}")
        object.__setattr__(self, "pose", p)


@dataclass(frozen=True)
class SetModes:
    """Change the number of retained modes per axis K (m' = K^3).

    The field for the new K is built by the engine's job worker, never on the loop thread;
    the loop keeps the old K until it is ready (``Frame.modes`` says which is in use).
    """

    modes: int

    def __post_init__(self) -> None:
        if int(self.modes) < 1:
            raise ValueError(f"modes must be a positive integer, got {self.modes!r}")
        object.__setattr__(self, "modes", int(self.modes))


@dataclass(frozen=True, kw_only=True)
class SetDescriptorParams:
    """Recompute descriptors with these parameters in the background.

    ``params`` replaces the scene's ``[descriptor]`` whole: the window's panel builds it
    from the scene's (``dataclasses.replace(scene.descriptor, sigma=...)``), and the same
    object reaches the descriptor kernels. The old descriptors stay in use until the new
    ones are ready; progress arrives as :class:`ProgressEvent` (task ``"descriptors"``) and
    in ``Frame.recompute``; the swap as :class:`DescriptorsSwapped`. A newer request
    supersedes (cancels) a running one.
    """

    params: DescriptorParams


@dataclass(frozen=True)
class CancelRecompute:
    """Cancel a running background recompute (the old descriptors stay)."""


@dataclass(frozen=True)
class SetEffects:
    """Switch effects live (guidance kind, free axes, damping, gravity).

    Changing guidance or locking/freeing rotation rebuilds the field in the background like
    :class:`SetDescriptorParams`.
    """

    effects: Effects


@dataclass(frozen=True)
class SetCoupling:
    """New coupling gains (applied at the next step)."""

    coupling: CouplingParams


@dataclass(frozen=True)
class SetKappa:
    """New geometric force gain (None: back to the scale-invariant default)."""

    kappa: float | None


@dataclass(frozen=True)
class SetDevice:
    """Switch the input device.

    ``kind`` is ``"mouse"``, ``"spacemouse"``, ``"openhaptics"``, ``"udp"`` or
    ``"trajectory"``, ``options`` its settings as ``(name, value)`` pairs; on failure a
    :class:`DeviceEvent` says why and the old one stays.
    """

    kind: str
    options: tuple[tuple[str, str | float | int | bool], ...] = ()


@dataclass(frozen=True)
class RequestLandscape:
    """Ask for the translational energy landscape at the part's current rotation (or ``rotvec``).

    Answered off the loop by :class:`LandscapeReady` or :class:`LandscapeFailed`. A newer
    request supersedes an unanswered one.
    """

    rotvec: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Pause:
    """Pause (True) or resume (False) stepping; frames keep coming while paused."""

    paused: bool = True


@dataclass(frozen=True)
class Reset:
    """Put part and proxy back at the scene's start pose (or ``pose``) at rest."""

    pose: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Stop:
    """End the engine."""


Command = (
    SetProxyPose
    | SetModes
    | SetDescriptorParams
    | CancelRecompute
    | SetEffects
    | SetCoupling
    | SetKappa
    | SetDevice
    | RequestLandscape
    | Pause
    | Reset
    | Stop
)

#: The command classes, for ``isinstance`` checks at the boundary.
COMMAND_TYPES: tuple[type, ...] = Command.__args__  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------------------------
# events (engine -> GUI)


@dataclass(frozen=True)
class ProgressEvent:
    """Progress of a background task.

    ``task`` is "correlator" while preparing after start, "descriptors" for a recompute,
    "ladder" for the sigma ladders (:mod:`engine.runtime.ladder_jobs`; its messages are
    "done", "paused" and "failed: ..."); ``message`` is "cancelled" when it was.
    """

    task: str
    fraction: float
    message: str = ""


@dataclass(frozen=True)
class ReadyEvent:
    """The engine has its field and steps.

    ``descriptors`` for slice views (read-only descriptors of part 1 and part 2, empty when
    guidance is off), ``backend`` names the per-pose evaluator picked, ``message`` the loop
    thread's scheduling. ``coarse_grid``: the field is a coarse first one on this grid while
    the scene's own descriptors are computed (progress task "descriptors", then
    DescriptorsSwapped); None when it is the scene's own.
    """

    descriptors: tuple[Descriptor, ...] = ()
    backend: str = ""
    message: str = ""
    coarse_grid: int | None = None


@dataclass(frozen=True)
class DescriptorsSwapped:
    """New descriptors are in use (after SetDescriptorParams / SetEffects).

    ``coarse_grid``: they are a coarse first field's at the new parameters (a new sigma),
    on this grid; the scene's own grid follows (progress task "descriptors", then another
    DescriptorsSwapped). None: the scene's own grid.
    """

    descriptors: tuple[Descriptor, ...] = ()
    sigma: float = 0.0
    penalty: float = 0.0
    seconds: float = 0.0
    coarse_grid: int | None = None


@dataclass(frozen=True)
class LandscapeReady:
    """Answer to :class:`RequestLandscape`: the landscape at ``rotvec``."""

    landscape: Landscape
    rotvec: tuple[float, ...] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class LandscapeFailed:
    """A :class:`RequestLandscape` could not be answered (guidance off, or it failed)."""

    message: str
    kind: str = "Error"


@dataclass(frozen=True)
class DeviceEvent:
    """A device connected, failed or was lost; ``fallback`` is the device now in use."""

    device: str
    connected: bool
    message: str
    fallback: str = "mouse"


@dataclass(frozen=True)
class ErrorEvent:
    """Something failed in the engine (recompute, command, step).

    The session goes on when ``fatal`` is False. ``kind`` is the exception class name.
    """

    message: str
    kind: str = "Error"
    fatal: bool = False


@dataclass(frozen=True)
class StoppedEvent:
    """The engine ended (after Stop, or a fatal error, or its parent process died)."""

    steps: int = 0
    reason: str = "stopped"


Event = (
    ProgressEvent
    | ReadyEvent
    | DescriptorsSwapped
    | LandscapeReady
    | LandscapeFailed
    | DeviceEvent
    | ErrorEvent
    | StoppedEvent
)


def describe_error(exc: BaseException) -> str:
    """The message of an :class:`ErrorEvent` for ``exc``.

    Its text, and for an unexpected error (not a ValueError or OSError, whose messages name
    the problem) where it arose.
    """
    text = str(exc) or type(exc).__name__
    if not isinstance(exc, (ValueError, OSError)):
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            text += f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})"
    return text
