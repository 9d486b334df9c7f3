"""Starting the engine, and the handle the GUI drives it through.

Data crossing the boundary: frozen commands in, frozen :class:`Frame` snapshots and frozen
events out (``engine.runtime.messages``). The engine runs either in a thread of the caller's
process (:class:`engine.runtime.loop.EngineLoop`) or in a process of its own
(:class:`engine.runtime.process.ProcessEngine`); both honour one contract, and the handle
cannot tell them apart: frames keep coming while paused and carry every field, progress
arrives while the field is prepared, descriptors come with ReadyEvent and
DescriptorsSwapped, landscapes are answered by the engine.

Typical use from a GUI (all calls return at once; none raises into the GUI thread once the
engine runs -- failures arrive as events)::

    handle = open_scene("assets/peg_in_hole/scene.toml")   # parse + load meshes (~100 ms)
    engine = start_engine(handle)                           # field prepared in the background
    engine.send(SetProxyPose(pose))                         # from a mouse drag
    engine.send(SetModes(24))                               # built off the loop, then swapped
    for frame in engine.poll_frames(): ...                  # on a QTimer, newest last
    for event in engine.poll_events(): ...                  # progress, ready, errors
    engine.stop()
"""

from __future__ import annotations

from typing import Protocol

from engine.devices import Device, DeviceError, MouseDevice, open_device
from engine.runtime.loop import EngineLoop
from engine.runtime.messages import Command, DeviceEvent, Event, Frame
from engine.runtime.process import EngineOptions, ProcessEngine
from engine.runtime.scene_handle import SceneHandle
from engine.sim import build_simulation

__all__ = ["DEFAULT_SWITCH_INTERVAL", "EngineHandle", "Transport", "start_engine"]

#: Thread engine: how long another thread may hold the interpreter lock before the loop
#: thread gets it back (Python's default is 5 ms); see docs/runtime.md for the measurements.
DEFAULT_SWITCH_INTERVAL = 5e-4


class Transport(Protocol):
    """What a running engine offers its handle (the thread loop and the process engine)."""

    def send(self, command: Command) -> None:
        """Queue a command."""
        ...

    def poll_frames(self, max_frames: int | None = None) -> list[Frame]:
        """New frames, oldest first."""
        ...

    def poll_events(self) -> list[Event]:
        """New events, oldest first."""
        ...

    def is_alive(self) -> bool:
        """True while the engine runs."""
        ...

    def stop(self, timeout: float = 2.0) -> None:
        """End the engine and wait for it."""
        ...


class EngineHandle:
    """The running engine as the GUI sees it: a command channel in, frames and events out.

    Methods never block for long and never raise because of the engine's own failures
    (those arrive as events); ``send`` raises TypeError only for a value that is not a
    command.
    """

    def __init__(self, transport: Transport):
        self.transport = transport

    @property
    def process(self) -> bool:
        """True when the engine runs in a process of its own."""
        return isinstance(self.transport, ProcessEngine)

    def send(self, command: Command) -> None:
        """Queue a command; applied between steps, in order."""
        self.transport.send(command)

    def poll_frames(self, max_frames: int | None = None) -> list[Frame]:
        """Frames published since the last call, oldest first (stale ones were dropped)."""
        return self.transport.poll_frames(max_frames)

    def latest_frame(self) -> Frame | None:
        """The newest frame (draining older ones), or None if none came yet."""
        frames = self.transport.poll_frames(None)
        return frames[-1] if frames else None

    def poll_events(self) -> list[Event]:
        """Events since the last call, oldest first (none dropped)."""
        return self.transport.poll_events()

    @property
    def running(self) -> bool:
        """True while the engine lives."""
        return self.transport.is_alive()

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the engine and wait for it (at most ``timeout`` seconds)."""
        self.transport.stop(timeout)


def start_engine(
    handle: SceneHandle,
    *,
    rate_hz: float | None = None,
    realtime: bool = True,
    device: Device | None = None,
    modes: int | None = None,
    backend: str = "auto",
    frame_queue: int = 64,
    process: bool | None = None,
    switch_interval: float | None = DEFAULT_SWITCH_INTERVAL,
) -> EngineHandle:
    """Start the engine on a scene; returns at once.

    The field (descriptors, correlator) is prepared by the engine's job worker (progress as
    ProgressEvent task "correlator", then ReadyEvent with the descriptors); until then frames
    come with the coupling alone and zero geometric force.

    Parameters
    ----------
    handle : SceneHandle
    rate_hz : float, optional
        Overrides ``[simulation] rate_hz``: the loop's period and the simulation's step.
    realtime : bool
        Hold the rate on the wall clock (``engine.runtime.pacing``: a loop thread at normal
        priority spins, yielding the CPU; a real-time one sleeps, then spins); False steps
        as fast as possible.
        A process engine also asks the OS to run its loop thread ahead of other work
        (``SCHED_FIFO``; ``SKELASM_REALTIME=0`` turns the request off). A thread engine does
        not: sharing the interpreter with the caller (a window), a real-time loop thread
        made the window's own thread 1.5 to 5 times slower (docs/runtime.md).
    device : engine.devices.Device, optional
        Input device (thread engine only); default: the scene's ``[device]`` (falling back to
        the mouse, with a DeviceEvent, when it is absent).
    modes : int, optional
        Overrides the scene's ``[correlation] modes``.
    backend : str
        Per-pose evaluator passed to the correlator ("auto", "numba", "numpy", "opencl").
    frame_queue : int
        Frames kept for the reader of a thread engine; older ones are dropped.
    process : bool or None
        True: run the loop in its own process, out of reach of the GUI's interpreter lock,
        asking for real-time scheduling when ``realtime``; it opens the scene's device
        itself. None (default): a process when the scene's device renders force
        (``openhaptics``, ``udp``), else a thread.
    switch_interval : float or None
        Thread engine: ``sys.setswitchinterval`` while the loop runs (None: leave Python's
        5 ms). The process engine keeps Python's 5 ms: there a shorter interval hands the
        lock to the process's idle helper threads while the real-time loop thread spins,
        and a helper preempted by other programs then stalls the loop for tens of
        milliseconds (measured in docs/runtime.md).
    """
    if process is None:
        process = device is None and handle.config.device.kind in ("openhaptics", "udp")
    if process:
        if device is not None:
            raise ValueError("a process engine opens the scene's device itself; pass "
                             "process=False to drive it with a device object")
        options = EngineOptions(modes=modes, backend=backend, rate_hz=rate_hz,
                                realtime=realtime, raise_priority=realtime)
        engine = ProcessEngine(handle, options)
        engine.start()
        return EngineHandle(engine)
    sim, model = build_simulation(handle, modes=modes, backend=backend, rate_hz=rate_hz,
                                  prepare=False)
    notice = None
    if device is None:
        cfg = handle.config.device
        try:
            device = open_device(cfg.kind, sim.proxy_pose, dict(cfg.options), handle.path.parent)
        except DeviceError as exc:
            device = MouseDevice(sim.proxy_pose)
            notice = DeviceEvent(cfg.kind, False, str(exc), fallback="mouse")
    loop = EngineLoop(sim, model=model, device=device, realtime=realtime,
                      frame_queue=frame_queue, prepare=True, switch_interval=switch_interval,
                      base_dir=handle.path.parent)
    if notice is not None:
        loop.events.append(notice)
    loop.start()
    return EngineHandle(loop)
