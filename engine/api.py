"""The small typed interface the GUI (and scripts) use to drive the engine.

Data crossing the boundary: frozen command dataclasses going in, frozen :class:`Frame`
snapshots and frozen event dataclasses coming out. Arrays inside frames and events are
read-only copies, so no mutable state is shared between the engine thread and the GUI.

Typical use from a GUI (all calls return at once; none raises into the GUI thread once the
engine runs -- failures arrive as :class:`ErrorEvent`)::

    handle = open_scene("assets/peg_in_hole/scene.toml")   # parse + load meshes (~100 ms)
    engine = start_engine(handle)                           # descriptors in the background
    ...
    engine.send(SetProxyPose(pose))                         # from a mouse drag
    engine.send(SetModes(24))                               # instant
    engine.send(SetDescriptorParams(sigma=0.8))             # background recompute
    for frame in engine.poll_frames(): ...                  # on a QTimer, newest last
    for event in engine.poll_events(): ...                  # progress, ready, errors
    engine.stop()

Poses are six numbers ``(tx, ty, tz, rx, ry, rz)`` of part 2 *relative to part 1* (part 1's
frame), the convention of ``engine.pose``; ``SceneHandle.world_pose`` maps them to world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from engine.params import CouplingParams, Effects, SimConfig

__all__ = [
    "SceneHandle",
    "EngineHandle",
    "open_scene",
    "start_engine",
    "Frame",
    "PeriodStats",
    "SetProxyPose",
    "SetModes",
    "SetDescriptorParams",
    "CancelRecompute",
    "SetEffects",
    "SetCoupling",
    "SetKappa",
    "SetDevice",
    "RequestLandscape",
    "Pause",
    "Reset",
    "Stop",
    "Command",
    "ProgressEvent",
    "ReadyEvent",
    "DescriptorsSwapped",
    "LandscapeReady",
    "DeviceEvent",
    "ErrorEvent",
    "StoppedEvent",
    "Event",
]


def _frozen_array(values: Any, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.array(values, dtype=np.float64).reshape(shape)
    arr.setflags(write=False)
    return arr


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
    """An immutable snapshot of the simulation after one step.

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
        Microseconds of the whole step (input, correlator, integration, publish).
    period : PeriodStats
        Loop timing over the recent window (refreshed every ~100 steps).
    modes : int
        Current K (m' = K^3).
    paused : bool
    recompute : float or None
        Fraction done of a background descriptor recompute, None when none runs.
    device : str
        Name of the device driving the proxy.
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
    """Change the number of retained modes per axis K (m' = K^3); applies at the next step."""

    modes: int

    def __post_init__(self) -> None:
        if int(self.modes) < 1:
            raise ValueError(f"modes must be a positive integer, got {self.modes!r}")
        object.__setattr__(self, "modes", int(self.modes))


@dataclass(frozen=True)
class SetDescriptorParams:
    """Recompute descriptors with new sigma and/or penalty in the background.

    The old descriptors stay in use until the new ones are ready; progress arrives as
    :class:`ProgressEvent` (task ``"descriptors"``) and in ``Frame.recompute``; the swap as
    :class:`DescriptorsSwapped`. A newer request supersedes (cancels) a running one.
    """

    sigma: float | None = None
    penalty: float | None = None


@dataclass(frozen=True)
class CancelRecompute:
    """Cancel a running background recompute (the old descriptors stay)."""


@dataclass(frozen=True)
class SetEffects:
    """Switch effects live (guidance kind, free axes, damping, gravity).

    Changing guidance between skeletal and collision rebuilds the correlator in the
    background like :class:`SetDescriptorParams`.
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
    """Switch the input device (``"mouse"``, ``"spacemouse"``, ``"openhaptics"``, ``"udp"``,
    ``"trajectory"``); on failure a :class:`DeviceEvent` says why and the mouse stays."""

    kind: str
    options: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class RequestLandscape:
    """Ask for the translational energy landscape at the part's current rotation (or
    ``rotvec``); answered off the loop by :class:`LandscapeReady`."""

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
    """End the engine thread."""


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


# ---------------------------------------------------------------------------------------------
# events (engine -> GUI)


@dataclass(frozen=True)
class ProgressEvent:
    """Progress of a background task (``task``: "descriptors", "correlator", "landscape")."""

    task: str
    fraction: float
    message: str = ""


@dataclass(frozen=True)
class ReadyEvent:
    """The engine has its correlator and steps; ``descriptors`` for slice views (read-only
    ``engine.store.Descriptor`` objects of part 1 and part 2, empty when guidance is off),
    ``backend`` names the per-pose evaluator picked."""

    descriptors: tuple[Any, ...] = ()
    backend: str = ""
    message: str = ""


@dataclass(frozen=True)
class DescriptorsSwapped:
    """New descriptors are in use (after SetDescriptorParams / SetEffects)."""

    descriptors: tuple[Any, ...] = ()
    sigma: float = 0.0
    penalty: float = 0.0
    seconds: float = 0.0


@dataclass(frozen=True)
class LandscapeReady:
    """Answer to :class:`RequestLandscape`: an ``engine.correlation.Landscape``."""

    landscape: Any
    rotvec: tuple[float, ...] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class DeviceEvent:
    """A device connected, failed or was lost; ``fallback`` is the device now in use."""

    device: str
    connected: bool
    message: str
    fallback: str = "mouse"


@dataclass(frozen=True)
class ErrorEvent:
    """Something failed in the engine (recompute, command, step); the session goes on when
    ``fatal`` is False. ``kind`` is the exception class name."""

    message: str
    kind: str = "Error"
    fatal: bool = False


@dataclass(frozen=True)
class StoppedEvent:
    """The engine thread ended (after Stop, or a fatal error)."""

    steps: int = 0
    reason: str = "stopped"


Event = (
    ProgressEvent
    | ReadyEvent
    | DescriptorsSwapped
    | LandscapeReady
    | DeviceEvent
    | ErrorEvent
    | StoppedEvent
)


# ---------------------------------------------------------------------------------------------
# handles


@dataclass(frozen=True)
class SceneHandle:
    """A loaded scene: parsed file, validated simulation settings and part meshes.

    Attributes
    ----------
    scene : engine.scene.Scene
    config : SimConfig
    parts : tuple of engine.loading.Part
        One mesh per ``[[part]]`` (vertices (n, 3) float64, faces (m, 3) int64, own frame).
    start_pose : (6,) float64, read-only
        Part 2 relative to part 1 at the start (from the scene's part poses).
    assembled_pose : (6,) float64, read-only
    """

    scene: Any
    config: SimConfig
    parts: tuple[Any, ...]
    start_pose: np.ndarray
    assembled_pose: np.ndarray
    path: Path = field(default=Path("."))

    @property
    def part1_world_pose(self) -> np.ndarray:
        """(6,) world pose of the fixed part."""
        return np.asarray(self.scene.parts[0].pose, dtype=float)

    def world_pose(self, relative: np.ndarray) -> np.ndarray:
        """(6,) world pose of part 2 from its pose relative to part 1."""
        from engine.pose import compose

        return compose(self.part1_world_pose, np.asarray(relative, float))

    def relative_pose(self, world: np.ndarray) -> np.ndarray:
        """(6,) pose relative to part 1 of a world pose of part 2."""
        from engine.pose import relative_pose

        return relative_pose(self.part1_world_pose, np.asarray(world, float))


def open_scene(path: str | Path) -> SceneHandle:
    """Parse a scene file, validate its simulation tables and load its parts' meshes.

    Fast (no descriptors): call it from the GUI thread or a worker.

    Raises
    ------
    engine.scene.SceneError, engine.loading.PartError
        ValueError subclasses with the file, the line and the fix.
    """
    from engine.scene import load_scene, load_scene_parts, relative_start_pose

    scene = load_scene(path)
    config = scene.config
    parts = tuple(load_scene_parts(scene))
    start = relative_start_pose(scene) if len(scene.parts) >= 2 else np.zeros(6)
    return SceneHandle(
        scene=scene,
        config=config,
        parts=parts,
        start_pose=_frozen_array(start, (6,)),
        assembled_pose=_frozen_array(scene.assembled_pose, (6,)),
        path=Path(scene.path),
    )


class EngineHandle:
    """The running engine as the GUI sees it: a command channel in, frames and events out.

    Methods never block for long and never raise because of the engine's own failures
    (those arrive as :class:`ErrorEvent`); ``send`` raises TypeError only for a value that
    is not a command.
    """

    def __init__(self, loop: Any):
        self._loop = loop

    def send(self, command: Command) -> None:
        """Queue a command; applied between steps, in order."""
        self._loop.send(command)

    def poll_frames(self, max_frames: int | None = None) -> list[Frame]:
        """Frames published since the last call, oldest first (stale ones were dropped)."""
        return self._loop.poll_frames(max_frames)

    def latest_frame(self) -> Frame | None:
        """The newest frame (draining older ones), or None if none came yet."""
        frames = self._loop.poll_frames(None)
        return frames[-1] if frames else None

    def poll_events(self) -> list[Event]:
        """Events since the last call, oldest first (none dropped)."""
        return self._loop.poll_events()

    @property
    def running(self) -> bool:
        """True while the engine thread lives."""
        return self._loop.is_alive()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the engine thread and wait for it (at most ``timeout`` seconds)."""
        self._loop.stop(timeout)


def start_engine(
    handle: SceneHandle,
    *,
    rate_hz: float | None = None,
    realtime: bool = True,
    device: Any = None,
    modes: int | None = None,
    backend: str = "auto",
    frame_queue: int = 64,
    process: bool | None = None,
    switch_interval: float | None = 5e-4,
) -> EngineHandle:
    """Start the engine thread on a scene; returns at once.

    Descriptors and the correlator are prepared in the engine's background worker (progress
    as :class:`ProgressEvent`, then :class:`ReadyEvent`); until then frames come with the
    coupling alone and zero geometric force.

    Parameters
    ----------
    handle : SceneHandle
    rate_hz : float, optional
        Overrides ``[simulation] rate_hz``.
    realtime : bool
        Hold the rate on the wall clock (sleep-then-spin); False steps as fast as possible.
    device : engine.devices.Device, optional
        Input device; default: the scene's ``[device]`` (falling back to the mouse, with a
        :class:`DeviceEvent`, when it is absent).
    modes : int, optional
        Overrides the scene's ``[correlation] modes``.
    backend : str
        Per-pose evaluator passed to the correlator ("auto", "numba", "numpy", "opencl").
    frame_queue : int
        Frames kept for the GUI; older ones are dropped.
    switch_interval : float or None
        ``sys.setswitchinterval`` while the engine thread runs (None: leave Python's 5 ms).
    process : bool or None
        None (default): a process when the scene's device renders force (``openhaptics``,
        ``udp``), where the period's tail matters, else a thread (see the measurements in
        README.md, "Simulation"). True: run the loop in its own process
        (``engine.loop.ProcessEngine``: frames through shared memory, only the newest kept;
        commands through a queue), out of reach of the GUI's GIL. The process opens the
        scene's device itself; ReadyEvent carries no descriptors (load them with
        ``engine.store`` for slice views) and RequestLandscape is not answered.
    """
    if process is None:
        process = device is None and handle.config.device.kind in ("openhaptics", "udp")
    if process:
        from engine.loop import ProcessEngine

        # the process's loop thread asks for real-time scheduling where the OS allows it:
        # beside a software-rendered window it otherwise waits for the render threads
        options = {"modes": modes, "backend": backend, "rate_hz": rate_hz,
                   "realtime": realtime, "switch_interval": None, "raise_priority": realtime}
        engine = ProcessEngine(str(handle.path), options=options)
        engine.start()
        return EngineHandle(engine)
    from engine.devices import DeviceError, MouseDevice, open_device
    from engine.loop import EngineLoop, build_simulation

    sim, model = build_simulation(handle, modes=modes, backend=backend, prepare=False)
    notice = None
    if device is None:
        cfg = handle.config.device
        try:
            device = open_device(cfg.kind, sim.proxy_pose, dict(cfg.options), handle.path.parent)
        except DeviceError as exc:
            device = MouseDevice(sim.proxy_pose)
            notice = DeviceEvent(cfg.kind, False, str(exc), fallback="mouse")
    loop = EngineLoop(
        sim,
        model=model,
        device=device,
        rate_hz=rate_hz,
        realtime=realtime,
        frame_queue=frame_queue,
        prepare=True,
        # another thread may hold the GIL this long before the loop gets it back (Python's
        # default is 5 ms); measured in README.md, "Simulation"
        switch_interval=switch_interval,
    )
    if notice is not None:
        loop.events.append(notice)
    loop.start()
    return EngineHandle(loop)
