"""The engine loop: one thread owns the simulation and steps it at a fixed rate.

Data crossing threads: frozen commands in (``engine.runtime.messages``), packed frame rows
out through a :class:`engine.runtime.frames.FrameRing` (read back as immutable
:class:`~engine.runtime.messages.Frame` snapshots), frozen events out. Channels:

- commands: ``queue.SimpleQueue`` (unbounded, none dropped), drained between steps;
- frames: the ring keeps the newest N rows; a slow reader loses the older ones (stale poses
  are worthless to a viewer); one row per iteration, also while paused;
- events: ``collections.deque`` (unbounded: progress, ready, errors are never dropped).

Each iteration: apply commands, take finished background jobs, resolve the physics if
either changed it, read the device, step
(unless paused), render the force, pack the frame, wait for the next deadline
(:class:`engine.runtime.pacing.Pacer`, which also states the catch-up policy). Everything
that costs more than a step runs in the job worker (:mod:`engine.runtime.guidance`).
"""

from __future__ import annotations

import collections
import queue
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine.devices import Device
from engine.runtime.frames import FRAME_WIDTH, FrameRing, pack_frame
from engine.runtime.guidance import Guidance
from engine.runtime.inputs import DeviceSlot
from engine.runtime.job_process import wanted as wanted_job_process
from engine.runtime.jobs import FieldModel
from engine.runtime.messages import (
    COMMAND_TYPES,
    CancelRecompute,
    Command,
    ErrorEvent,
    Event,
    Frame,
    Pause,
    ReadyEvent,
    RequestLandscape,
    Reset,
    SetCoupling,
    SetDescriptorParams,
    SetDevice,
    SetEffects,
    SetKappa,
    SetModes,
    SetProxyPose,
    Stop,
    StoppedEvent,
    describe_error,
)
from engine.runtime.pacing import (
    LANE_PRIORITY,
    WAIT_WORDS,
    WAITS,
    Pacer,
    PeriodWindow,
    current_native_id,
    drop_realtime_priority,
    raise_thread_priority,
    switch_interval,
)
from engine.sim import Simulation, evaluator_name

__all__ = ["EngineLoop"]


class EngineLoop:
    """Fixed-rate stepping of a :class:`Simulation` in its own thread (or the caller's).

    Parameters
    ----------
    sim : Simulation
    model : FieldModel, optional
        ``engine.sim.SceneModel`` of the scene: needed for commands that rebuild things
        (K, descriptor parameters, effects, coupling) and to prepare the field in the
        background when ``prepare`` is True.
    device : Device, optional
        Drives the proxy (default: a MouseDevice at the start pose).
    rate_hz : float, optional
        Default ``1 / sim.dt``; setting it sets the simulation's step to ``1 / rate_hz``.
    realtime : bool
        Hold the rate on the wall clock; False: as fast as possible.
    frames : FrameRing, optional
        Where frame rows go (the process transport passes one in shared memory).
    frame_queue : int
        Rows kept by a ring made here (older ones are dropped).
    publish_every : int
        Publish a frame every this many iterations.
    prepare : bool
        Build the model's field in the background on start (ReadyEvent when done); False:
        the field handed in is the one to use (ReadyEvent at once).
    on_frame : callable((FRAME_WIDTH,) float64), optional
        Called with every stepped iteration's row in the loop thread (recording).
    keep_periods : bool
        Keep every period (seconds) and garbage collection in :attr:`window` (benchmarks).
    switch_interval : float, optional
        If given, ``sys.setswitchinterval`` while the loop runs; restored at the end.
    job_switch_interval : float, optional
        If given, the switch interval while a background job runs (the worker then
        competes with the loop thread for the interpreter lock and gives it back this
        soon); ``switch_interval`` again when the worker is idle.
    raise_priority : bool
        Ask the OS to run the loop thread ahead of other work
        (:func:`engine.runtime.pacing.raise_thread_priority`); what was granted is in
        :attr:`scheduling`.
    wait : {"sleep", "yield"}, optional
        How the loop waits for its deadlines (:class:`engine.runtime.pacing.Pacer`). None:
        ``"sleep"`` when the loop thread got real-time scheduling, ``"yield"`` otherwise;
        what is used is in :attr:`waiting` once the loop runs (``"none"``: unpaced).
    base_dir : Path, optional
        Where relative device files are found (the scene's folder).
    job_process : bool, optional
        Compute a field's truncations and landscapes in a process of their own
        (:mod:`engine.runtime.job_process`). None: decided as the loop starts by
        :func:`engine.runtime.job_process.wanted`: when paced in real time, with the loop
        thread granted real-time scheduling or on a machine of 4 cores or more (on 2, a loop
        at normal priority lost its CPU to that process; docs/runtime.md, "K changes").
    """

    def __init__(
        self,
        sim: Simulation,
        *,
        model: FieldModel | None = None,
        device: Device | None = None,
        rate_hz: float | None = None,
        realtime: bool = True,
        frames: FrameRing | None = None,
        frame_queue: int = 64,
        publish_every: int = 1,
        prepare: bool = False,
        on_frame: Callable[[np.ndarray], None] | None = None,
        keep_periods: bool = False,
        switch_interval: float | None = None,
        job_switch_interval: float | None = None,
        raise_priority: bool = False,
        wait: str | None = None,
        base_dir: Path | None = None,
        job_process: bool | None = None,
    ):
        self.sim = sim
        self.model = model
        if rate_hz is not None:
            sim.dt = 1.0 / float(rate_hz)
        self.realtime = realtime
        self.events: collections.deque[Event] = collections.deque()
        self.commands: queue.SimpleQueue[Command] = queue.SimpleQueue()
        self.frames = frames if frames is not None else FrameRing(frame_queue)
        self.inputs = DeviceSlot(sim, device, self.events, base_dir)
        self.guidance = Guidance(sim, model, self.events)
        # paced: rotation caches refresh in their own lane, never in the step
        self.guidance.background_refresh = bool(realtime)
        self.job_process = job_process
        self.guidance.job_process = bool(job_process)  # None: decided in run()
        self.guidance.attach(sim.field)
        if model is not None:
            self.guidance.coupling = model.config.coupling
        self.publish_every = max(1, int(publish_every))
        self.prepare = prepare
        self.on_frame = on_frame
        self.window = PeriodWindow(keep=keep_periods)
        self.switch_interval = switch_interval
        self.job_switch_interval = job_switch_interval
        self._jobs_running = False
        self._base_interval = sys.getswitchinterval()
        self.raise_priority = raise_priority
        self.scheduling = "normal (not asked for)"
        if wait is not None and wait not in WAITS:
            raise ValueError(f"wait must be one of {WAITS} or None, got {wait!r}")
        self.wait = wait
        self.waiting = ""  # how the running loop waits ("sleep", "yield" or "none")
        self.started = threading.Event()  # set once the loop runs (scheduling is known)
        self.native_id: int | None = None  # the loop thread's OS id once it runs
        self.overruns = 0
        self.paused = False
        self._row = np.zeros(FRAME_WIDTH)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._announced = False

    # -- reader side (any thread) ---------------------------------------------------------------
    @property
    def device(self) -> Device:
        """The device in use."""
        return self.inputs.device

    @property
    def periods(self) -> np.ndarray:
        """Every period in seconds so far (with ``keep_periods``)."""
        return np.asarray(self.window.periods)

    @property
    def frames_published(self) -> int:
        """Frames written to the ring so far."""
        return self.frames.written

    def send(self, command: Command) -> None:
        """Queue a command; applied between steps, in order."""
        if not isinstance(command, COMMAND_TYPES):
            raise TypeError(f"not an engine command: {command!r}")
        self.commands.put(command)

    def poll_frames(self, max_frames: int | None = None) -> list[Frame]:
        """Frames published since the last call that are still in the ring, oldest first."""
        return self.frames.read_frames(max_frames)

    def poll_events(self) -> list[Event]:
        """Events since the last call, oldest first."""
        out: list[Event] = []
        while self.events:
            out.append(self.events.popleft())
        return out

    def start(self) -> None:
        """Run the loop in a new daemon thread."""
        self._thread = threading.Thread(target=self._thread_main, name="skelasm-engine",
                                        daemon=True)
        self._thread.start()

    def is_alive(self) -> bool:
        """True while the loop thread runs."""
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the loop thread to end."""
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the loop and its job worker, and wait for them."""
        self._stop.set()
        self.join(timeout)
        self.guidance.close()

    def _thread_main(self) -> None:
        try:
            self.run()
        except Exception as exc:  # deliver, never raise into another thread
            self.events.append(ErrorEvent(describe_error(exc), type(exc).__name__,
                                              fatal=True))
            self.events.append(StoppedEvent(self.sim.steps, "error"))
        finally:
            self.guidance.close()

    # -- the loop (runs in the calling thread) --------------------------------------------------
    def run(self, max_steps: int | None = None) -> int:
        """Iterate until Stop (or ``max_steps`` iterations); returns the iterations run."""
        self.native_id = current_native_id()
        if self.raise_priority:
            self.scheduling = raise_thread_priority()
        granted = self.scheduling.startswith("real-time")
        # while the loop waits for the lane's cache, beside a real-time loop the lane runs
        # ahead of ordinary threads too, below the loop (Guidance.take_responses)
        self.guidance.refresh_lane.priority = LANE_PRIORITY if granted else None
        wait = self.wait or ("sleep" if granted else "yield")
        if self.job_process is None:
            self.guidance.job_process = wanted_job_process(self.realtime, granted)
        pacer = Pacer(self.sim.dt, realtime=self.realtime, wait=wait)
        self.waiting = pacer.waiting
        self.guidance.ready_message = (f"engine ready; its loop thread: {self.scheduling}, "
                                       f"waiting by {WAIT_WORDS[self.waiting]}")
        self.started.set()
        if self.prepare and self.model is not None:
            self.prepare = False  # once, not at every run
            self.guidance.prepare(self.model.modes)
        elif not self._announced:
            self.guidance.offload(self.sim.field)  # a field built before the loop
            self.events.append(ReadyEvent(self.guidance.descriptors,
                                              evaluator_name(self.sim.field),
                                              self.guidance.ready_message))
        self._announced = True
        reason = "stopped"
        steps = 0
        pacer.deadline = time.perf_counter() + self.sim.dt
        self._base_interval = sys.getswitchinterval()
        self.window.restart()
        try:
            with switch_interval(self.switch_interval), self.window.watching():
                while not self._stop.is_set():
                    self._iterate()
                    steps += 1
                    if max_steps is not None and steps >= max_steps:
                        reason = "done"
                        break
                    pacer.wait()
                    self.window.tick()
        finally:
            if self.raise_priority:
                drop_realtime_priority()  # the calling thread may live on (run() called directly)
            self.guidance.refresh_lane.hurry(False)  # nobody waits for it now
            self.overruns += pacer.overruns
            if self._jobs_running:
                self._jobs_running = False
                sys.setswitchinterval(self._base_interval)
            self.inputs.release()
            self.events.append(StoppedEvent(self.sim.steps, reason))
        return steps

    def _iterate(self) -> None:
        t0 = time.perf_counter()
        sim = self.sim
        if not self.commands.empty():
            self._apply_commands()
        self.guidance.take_responses()
        self.guidance.apply_physics()  # once per iteration, after commands and a new field
        if self.job_switch_interval is not None and self.guidance.worker.busy != self._jobs_running:
            self._jobs_running = not self._jobs_running
            interval = self.job_switch_interval if self._jobs_running else self.switch_interval
            sys.setswitchinterval(interval if interval is not None else self._base_interval)
        self.inputs.read()
        stepped = not self.paused and not self._stop.is_set()
        if stepped:
            sim.step()
            self.inputs.write()
        row = self._row
        pack_frame(
            row, sim, modes=int(sim.field.modes), step_us=(time.perf_counter() - t0) * 1e6,
            period=self.window.stats, paused=self.paused, recompute=self.guidance.recompute,
            device=self.inputs.name_code,
        )
        if stepped and self.on_frame is not None:
            self.on_frame(row)
        if sim.steps % self.publish_every == 0 or self.paused:
            self.frames.write(row)

    # -- commands -------------------------------------------------------------------------------
    def _apply_commands(self) -> None:
        while True:
            try:
                cmd = self.commands.get_nowait()
            except queue.Empty:
                break
            try:
                self._apply(cmd)
            except Exception as exc:  # noqa: BLE001 -- a failed command is reported
                self.events.append(ErrorEvent(describe_error(exc), type(exc).__name__))

    def _apply(self, cmd: Command) -> None:
        g = self.guidance
        if isinstance(cmd, SetProxyPose):
            self.inputs.set_proxy(cmd.pose)
        elif isinstance(cmd, SetModes):
            g.set_modes(cmd.modes)
        elif isinstance(cmd, Pause):
            self.paused = bool(cmd.paused)
        elif isinstance(cmd, Reset):
            self.sim.reset(None if cmd.pose is None else np.asarray(cmd.pose, float))
            self.inputs.reset()
        elif isinstance(cmd, Stop):
            self._stop.set()
        elif isinstance(cmd, SetKappa):
            g.set_kappa(cmd.kappa)
        elif isinstance(cmd, SetCoupling):
            g.set_coupling(cmd.coupling)
        elif isinstance(cmd, SetEffects):
            g.set_effects(cmd.effects)
        elif isinstance(cmd, SetDescriptorParams):
            g.set_descriptor_params(cmd.params)
        elif isinstance(cmd, CancelRecompute):
            g.cancel_recompute()
        elif isinstance(cmd, SetDevice):
            self.inputs.switch(cmd)
        elif isinstance(cmd, RequestLandscape):
            g.request_landscape(cmd.rotvec)
        else:
            raise TypeError(f"unknown command {cmd!r}")
