"""The engine loop: one thread owns the simulation and steps it at a fixed rate.

Data crossing threads: frozen commands in (``engine.api``), immutable :class:`engine.api.Frame`
snapshots and frozen events out. Channels:

- commands: ``queue.SimpleQueue`` (unbounded, none dropped), drained between steps;
- frames: ``collections.deque(maxlen=N)``: appending drops the oldest frame when the reader is
  slow (stale poses are worthless to a viewer), appends and pops are atomic in CPython;
- events: ``collections.deque`` (unbounded: progress, ready, errors are never dropped).

Timing: the loop targets ``next += dt`` on ``time.perf_counter`` and waits by sleeping until
about 0.3 ms before the deadline (Python's sleep overshoots by 60-100 us) and spinning the rest.
After an overrun of more than 5 periods it re-anchors rather than racing to catch up. With
``realtime=False`` it steps as fast as it can (simulated time still advances by ``dt``).

Background work: descriptor (re)computation and landscapes run in a worker thread; the loop
keeps using the old field until the worker hands over a new one, which is swapped in between
two steps.
"""

from __future__ import annotations

import collections
import os
import queue
import sys
import threading
import time
import traceback
from array import array
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from engine import api
from engine.devices import Device, DeviceError, MouseDevice, open_device
from engine.errors import Cancelled
from engine.params import Physics
from engine.pose import rotation_matrix
from engine.sim import CorrelatorField, SceneModel, Simulation, build_simulation

#: Seconds before a deadline at which the loop stops sleeping and spins.
SPIN_MARGIN = 0.0003
#: Steps between refreshes of the period statistics in frames.
STATS_EVERY = 100
#: Periods kept for the statistics window.
STATS_WINDOW = 1000


def _ro(values: Any) -> np.ndarray:
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


def period_stats(periods_s: np.ndarray) -> api.PeriodStats:
    """:class:`engine.api.PeriodStats` of an array of periods in seconds."""
    p = np.asarray(periods_s, dtype=np.float64)
    if len(p) == 0:
        return api.PeriodStats()
    us = p * 1e6
    q = np.percentile(us, [50, 1, 99])
    return api.PeriodStats(
        rate_hz=float(len(p) / p.sum()) if p.sum() > 0 else 0.0,
        median_us=float(q[0]),
        p1_us=float(q[1]),
        p99_us=float(q[2]),
        max_us=float(us.max()),
        window=int(len(p)),
    )


# ---------------------------------------------------------------------------------------------
# the loop


class EngineLoop:
    """Fixed-rate stepping of a :class:`Simulation` in its own thread (or the caller's).

    Parameters
    ----------
    sim : Simulation
    model : SceneModel, optional
        Needed for commands that rebuild things (descriptor params, effects, coupling) and to
        prepare the field in the background when ``prepare`` is True.
    device : Device, optional
        Drives the proxy (default: a MouseDevice at the start pose).
    rate_hz : float, optional
        Default ``1 / sim.dt``; setting it changes the step.
    realtime : bool
        Hold the rate on the wall clock; False: as fast as possible.
    frame_queue : int
        Frames kept for readers (older dropped).
    publish_every : int
        Publish a frame every this many steps.
    prepare : bool
        Build the model's field in the background on start (ReadyEvent when done).
    on_step : callable(sim, proxy_pose), optional
        Called after each step in the loop thread (recording).
    keep_periods : bool
        Keep every period (seconds) in ``periods`` (benchmarks).
    switch_interval : float, optional
        If given, ``sys.setswitchinterval`` while the loop runs (how long another thread may
        hold the GIL before the loop gets it back); restored at the end.
    raise_priority : bool
        Ask the OS to run the loop thread ahead of other work (:func:`raise_thread_priority`:
        real-time FIFO scheduling where allowed). What was granted is in
        :attr:`scheduling`.
    """

    def __init__(
        self,
        sim: Simulation,
        *,
        model: SceneModel | None = None,
        device: Device | None = None,
        rate_hz: float | None = None,
        realtime: bool = True,
        frame_queue: int = 64,
        publish_every: int = 1,
        prepare: bool = False,
        on_step: Callable[[Simulation, np.ndarray], None] | None = None,
        keep_periods: bool = False,
        switch_interval: float | None = None,
        raise_priority: bool = False,
    ):
        self.sim = sim
        self.model = model
        if rate_hz is not None:
            sim.dt = 1.0 / float(rate_hz)
        self.dt = sim.dt
        self.realtime = realtime
        self.device = device or MouseDevice(sim.proxy_pose)
        self.mouse = self.device if isinstance(self.device, MouseDevice) else None
        self._apply_device_limits()
        self.frames: collections.deque[api.Frame] = collections.deque(maxlen=int(frame_queue))
        self.events: collections.deque[Any] = collections.deque()
        self.commands: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.publish_every = max(1, int(publish_every))
        self.prepare = prepare
        self.on_step = on_step
        self.keep_periods = keep_periods
        self.periods = array("d")
        self.switch_interval = switch_interval
        self.raise_priority = raise_priority
        self.scheduling = "normal (not asked for)"
        self.started = threading.Event()  # set once the loop runs (scheduling is known)
        self.frames_published = 0
        self.overruns = 0
        self.paused = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._worker: threading.Thread | None = None
        self._worker_cancel = threading.Event()
        self._handover: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._recompute: float | None = None
        self._effects = sim.effects
        self._coupling = model.config.coupling if model is not None else None
        self._kappa: float | None = None
        self._params: dict[str, float] = {}
        self._stats = api.PeriodStats()
        self._window = np.zeros(STATS_WINDOW)
        self._window_n = 0
        self.thread_name = ""

    # -- channel API (any thread) --------------------------------------------------------------
    def send(self, command: Any) -> None:
        if not isinstance(command, api.Command.__args__):  # type: ignore[attr-defined]
            raise TypeError(f"not an engine command: {command!r}")
        self.commands.put(command)

    def poll_frames(self, max_frames: int | None = None) -> list[api.Frame]:
        out: list[api.Frame] = []
        pop = self.frames.popleft
        while self.frames and (max_frames is None or len(out) < max_frames):
            try:
                out.append(pop())
            except IndexError:
                break
        return out

    def poll_events(self) -> list[Any]:
        out: list[Any] = []
        while self.events:
            try:
                out.append(self.events.popleft())
            except IndexError:
                break
        return out

    def start(self) -> None:
        """Run the loop in a new daemon thread."""
        self._thread = threading.Thread(
            target=self._thread_main, name="skelasm-engine", daemon=True
        )
        self._thread.start()

    def is_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        self._worker_cancel.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def _thread_main(self) -> None:
        try:
            self.run()
        except Exception as exc:  # deliver, never raise into another thread
            self.events.append(api.ErrorEvent(_message(exc), type(exc).__name__, fatal=True))
            self.events.append(api.StoppedEvent(self.sim.steps, "error"))

    # -- the loop (runs in the calling thread) ------------------------------------------------
    def run(self, max_steps: int | None = None) -> int:
        """Step until Stop (or ``max_steps`` steps); returns the steps taken."""
        self.thread_name = threading.current_thread().name
        if self.raise_priority:
            self.scheduling = raise_thread_priority()
        self.started.set()
        old_switch = sys.getswitchinterval()
        if self.switch_interval is not None:
            sys.setswitchinterval(self.switch_interval)
        if self.prepare and self.model is not None:
            self._start_worker("correlator", self._prepare_job())
        sim = self.sim
        dt = self.dt
        perf = time.perf_counter
        sleep = time.sleep
        steps = 0
        last = perf()
        deadline = last + dt
        reason = "stopped"
        try:
            while not self._stop.is_set():
                t_step = perf()
                if not self.commands.empty():
                    self._apply_commands()
                    if self._stop.is_set():
                        break
                if not self._handover.empty():
                    self._take_handover()
                self._read_device()
                if not self.paused:
                    sim.step()
                    self._write_device()
                    if self.on_step is not None:
                        self.on_step(sim, sim.proxy_pose)
                steps += 1
                step_us = (perf() - t_step) * 1e6
                if steps % self.publish_every == 0:
                    self._publish(step_us)
                if max_steps is not None and steps >= max_steps:
                    reason = "done"
                    break
                if self.realtime:
                    now = perf()
                    remaining = deadline - now
                    if remaining > SPIN_MARGIN:
                        sleep(remaining - SPIN_MARGIN)
                    while perf() < deadline:
                        pass
                    now = perf()
                    if now - deadline > 5 * dt:
                        self.overruns += 1
                        deadline = now
                    deadline += dt
                now = perf()
                self._record_period(now - last)
                last = now
        finally:
            if self.switch_interval is not None:
                sys.setswitchinterval(old_switch)
            self._worker_cancel.set()
            try:
                self.device.write_force(np.zeros(3), np.zeros(3))
            except Exception:
                pass
            self.events.append(api.StoppedEvent(sim.steps, reason))
        return steps

    # -- pieces of a step -----------------------------------------------------------------------
    def _record_period(self, period: float) -> None:
        self._window[self._window_n % STATS_WINDOW] = period
        self._window_n += 1
        if self.keep_periods:
            self.periods.append(period)
        if self._window_n % STATS_EVERY == 0:
            n = min(self._window_n, STATS_WINDOW)
            self._stats = period_stats(self._window[:n])

    def _read_device(self) -> None:
        try:
            pose = self.device.read_pose(self.sim.time)
        except DeviceError as exc:
            self._fallback_to_mouse(str(exc))
            return
        except Exception as exc:
            self._fallback_to_mouse(f"{self.device.name}: {exc}")
            return
        if pose is not None:
            self.sim.set_proxy(pose)

    def _write_device(self) -> None:
        if not self.device.capabilities.force_feedback:
            return
        try:
            self.device.write_force(self.sim.haptic_force, self.sim.haptic_torque)
        except Exception as exc:
            self._fallback_to_mouse(str(exc))

    def _apply_device_limits(self) -> None:
        """Clamp the rendered force to the device's maximum unless the scene set a lower one."""
        caps = self.device.capabilities
        lim = self.sim.limits
        self.sim.limits = replace(
            lim,
            max_force=min(lim.max_force, caps.max_force),
            max_torque=min(lim.max_torque, caps.max_torque),
        )

    def _fallback_to_mouse(self, message: str) -> None:
        lost = self.device.name
        try:
            self.device.disconnect()
        except Exception:
            pass
        self.mouse = MouseDevice()
        self.device = self.mouse
        self.events.append(api.DeviceEvent(lost, False, message, fallback="mouse"))

    def _publish(self, step_us: float) -> None:
        sim = self.sim
        s = sim.sample
        frame = api.Frame(
            time=sim.time,
            step=sim.steps,
            proxy_pose=_ro(sim.proxy_pose),
            part_pose=_ro(sim.part_pose()),
            energy=float(s.energy),
            force=_ro(s.force),
            torque=_ro(s.torque),
            coupling_force=_ro(sim.coupling_force),
            coupling_torque=_ro(sim.coupling_torque),
            haptic_force=_ro(sim.haptic_force),
            haptic_torque=_ro(sim.haptic_torque),
            eval_us=float(s.microseconds),
            step_us=step_us,
            period=self._stats,
            modes=int(getattr(sim.field, "modes", 0)),
            paused=self.paused,
            recompute=self._recompute,
            device=self.device.name,
        )
        self.frames.append(frame)
        self.frames_published += 1

    # -- commands -------------------------------------------------------------------------------
    def _apply_commands(self) -> None:
        while True:
            try:
                cmd = self.commands.get_nowait()
            except queue.Empty:
                return
            try:
                self._apply(cmd)
            except Exception as exc:
                self.events.append(api.ErrorEvent(_message(exc), type(exc).__name__))

    def _apply(self, cmd: Any) -> None:
        sim = self.sim
        if isinstance(cmd, api.SetProxyPose):
            if self.mouse is not None and self.device is self.mouse:
                self.mouse.set_pose(cmd.pose)
            else:
                sim.set_proxy(np.asarray(cmd.pose))
        elif isinstance(cmd, api.SetModes):
            sim.field.set_modes(cmd.modes)
            sim.field_changed()
        elif isinstance(cmd, api.Pause):
            self.paused = bool(cmd.paused)
        elif isinstance(cmd, api.Reset):
            sim.reset(None if cmd.pose is None else np.asarray(cmd.pose, float))
            if self.mouse is not None:
                self.mouse.set_pose(sim.proxy_pose)
        elif isinstance(cmd, api.Stop):
            self._stop.set()
        elif isinstance(cmd, api.SetKappa):
            self._kappa = cmd.kappa
            self._resolve_physics()
        elif isinstance(cmd, api.SetCoupling):
            self._coupling = cmd.coupling
            self._resolve_physics()
        elif isinstance(cmd, api.SetEffects):
            old = self._effects
            self._effects = cmd.effects
            rebuild = (
                old.guidance != cmd.effects.guidance or old.rotation != cmd.effects.rotation
            )
            if rebuild:
                self._start_recompute()
            else:
                sim.set_effects(cmd.effects, self._physics())
        elif isinstance(cmd, api.SetDescriptorParams):
            if cmd.sigma is not None:
                self._params["sigma"] = float(cmd.sigma)
            if cmd.penalty is not None:
                self._params["penalty"] = float(cmd.penalty)
            self._start_recompute()
        elif isinstance(cmd, api.CancelRecompute):
            self._worker_cancel.set()
        elif isinstance(cmd, api.SetDevice):
            self._switch_device(cmd)
        elif isinstance(cmd, api.RequestLandscape):
            self._request_landscape(cmd)
        else:
            raise TypeError(f"unknown command {cmd!r}")

    def _physics(self) -> Physics:
        if self.model is None:
            return replace(self.sim.physics, kappa=self._kappa or self.sim.physics.kappa)
        return self.model.physics(self._effects, self._coupling, self._kappa)

    def _resolve_physics(self) -> None:
        self.sim.set_effects(self._effects, self._physics())

    def _switch_device(self, cmd: Any) -> None:
        base = None
        if self.model is not None:
            base = Path(getattr(self.model.scene, "path", ".")).parent
        try:
            dev = open_device(cmd.kind, self.sim.proxy_pose, dict(cmd.options), base)
        except DeviceError as exc:
            self.events.append(
                api.DeviceEvent(cmd.kind, False, str(exc), fallback=self.device.name)
            )
            return
        try:
            self.device.disconnect()
        except Exception:
            pass
        self.device = dev
        self.mouse = dev if isinstance(dev, MouseDevice) else None
        self._apply_device_limits()
        self.events.append(api.DeviceEvent(cmd.kind, True, f"{cmd.kind} connected", cmd.kind))

    # -- background work ------------------------------------------------------------------------
    def _start_worker(self, task: str, job: Callable[..., Any]) -> None:
        if self._worker is not None and self._worker.is_alive():
            self._worker_cancel.set()  # superseded: the old one stops at its next check
        cancel_flag = threading.Event()
        self._worker_cancel = cancel_flag
        self._recompute = 0.0

        def progress(fraction: float) -> None:
            self._recompute = float(fraction)
            self.events.append(api.ProgressEvent(task, float(fraction)))

        def body() -> None:
            try:
                result = job(progress, cancel_flag.is_set)
            except Cancelled:
                self._handover.put(("cancelled", task, cancel_flag))
                return
            except Exception as exc:
                self._handover.put(("error", exc, cancel_flag))
                return
            self._handover.put(("done", result, cancel_flag))

        self._worker = threading.Thread(target=body, name=f"skelasm-{task}", daemon=True)
        self._worker.start()

    def _prepare_job(self) -> Callable[..., Any]:
        model = self.model
        assert model is not None
        effects = self._effects
        physics = self.sim.physics
        rot = self.sim.state.rotation.copy()

        def job(progress: Callable[[float], None], cancel: Callable[[], bool]) -> Any:
            field, descs = model.field(
                effects, physics.kappa, rot, progress=progress, cancel=cancel
            )
            return ("ready", field, descs, effects)

        return job

    def _start_recompute(self) -> None:
        if self.model is None:
            raise RuntimeError("this engine has no scene model to recompute from")
        model = self.model
        effects = self._effects
        params = dict(self._params)
        modes = int(getattr(self.sim.field, "modes", 0)) or None
        kappa = self._physics().kappa
        rot = self.sim.state.rotation.copy()

        def job(progress: Callable[[float], None], cancel: Callable[[], bool]) -> Any:
            t0 = time.perf_counter()
            field, descs = model.field(
                effects, kappa, rot, sigma=params.get("sigma"), penalty=params.get("penalty"),
                modes=modes, progress=progress, cancel=cancel,
            )
            return ("swap", field, descs, effects, params, time.perf_counter() - t0)

        self._start_worker("descriptors", job)

    def _request_landscape(self, cmd: Any) -> None:
        field = self.sim.field
        correlator = getattr(field, "correlator", None)
        if correlator is None:
            self.events.append(api.ErrorEvent("no landscape: guidance is off", "ValueError"))
            return
        rotvec = cmd.rotvec if cmd.rotvec is not None else tuple(self.sim.part_pose()[3:])
        rot = rotation_matrix(np.asarray(rotvec, float))

        def run() -> None:
            try:
                land = correlator.landscape(rot)
                rv = tuple(float(v) for v in rotvec)
                self.events.append(api.LandscapeReady(land, rv))
            except Exception as exc:
                self.events.append(api.ErrorEvent(_message(exc), type(exc).__name__))

        # correlator.landscape reads only constant spectra: safe beside evaluate()
        threading.Thread(target=run, name="skelasm-landscape", daemon=True).start()

    def _take_handover(self) -> None:
        while True:
            try:
                kind, payload, flag = self._handover.get_nowait()
            except queue.Empty:
                return
            current = flag is self._worker_cancel
            if current:
                self._recompute = None
            if kind == "cancelled":
                if current:
                    self.events.append(api.ProgressEvent(str(payload), 1.0, "cancelled"))
                continue
            if kind == "error":
                self.events.append(api.ErrorEvent(_message(payload), type(payload).__name__))
                continue
            if not current or flag.is_set():
                continue  # superseded result: drop it
            tag = payload[0]
            field, descs, effects = payload[1], payload[2], payload[3]
            if effects != self._effects:
                continue  # effects changed meanwhile; a newer job is on its way
            modes = int(getattr(self.sim.field, "modes", 0))
            if modes and getattr(field, "modes", 0) not in (0, modes):
                field.set_modes(modes)  # keep the K the user picked meanwhile
            self.sim.set_effects(effects, self._physics())
            self.sim.set_field(field)
            if tag == "ready":
                self.events.append(api.ReadyEvent(tuple(descs), _backend_name(field)))
            else:
                params = payload[4]
                d = descs[0] if descs else None
                dp = getattr(d, "params", None)
                self.events.append(
                    api.DescriptorsSwapped(
                        tuple(descs),
                        float(getattr(dp, "sigma", params.get("sigma", 0.0)) or 0.0),
                        float(getattr(dp, "penalty", params.get("penalty", 0.0)) or 0.0),
                        float(payload[5]),
                    )
                )


def _backend_name(field: Any) -> str:
    c = getattr(field, "correlator", None)
    return str(getattr(c, "backend_name", "") or type(field).__name__)


def _message(exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    if not isinstance(exc, (ValueError, OSError)):
        tb = traceback.extract_tb(exc.__traceback__)
        if tb:
            text += f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})"
    return text


# ---------------------------------------------------------------------------------------------
# benchmark helpers (also used by the engine process when it benchmarks)


class AnalyticWell:
    """A quadratic well (energy, force, torque in closed form): the loop without the sum."""

    rotation = True
    modes = 0

    def evaluate(self, R: np.ndarray, t: np.ndarray) -> Any:
        from engine.correlation import Evaluation

        t = np.asarray(t, float)
        return Evaluation(0.5 * float(t @ t), -t, -0.5 * (R - R.T)[[2, 0, 1], [1, 2, 0]], 0.0, 0)

    def set_modes(self, k: int) -> None:
        pass


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



# ---------------------------------------------------------------------------------------------
# the loop in its own process


#: Layout of the shared-memory frame block (float64 slots); slot 0 is the seqlock counter.
_SLOTS = {
    "seq": 0, "time": 1, "step": 2, "proxy": 3, "part": 9, "energy": 15, "force": 16,
    "torque": 19, "cforce": 22, "ctorque": 25, "hforce": 28, "htorque": 31, "eval_us": 34,
    "step_us": 35, "modes": 36, "paused": 37, "rate": 38, "median": 39, "p1": 40, "p99": 41,
    "max": 42, "window": 43,
}
_NSLOTS = 48


class ProcessEngine:
    """The engine loop in a child process; frames through shared memory, commands through a
    ``multiprocessing`` queue. Same reader interface as :class:`EngineLoop` (``send``,
    ``poll_frames``, ``poll_events``, ``is_alive``, ``stop``), so ``engine.api.EngineHandle``
    can wrap either.

    The child writes the newest frame into a small float64 block guarded by a sequence counter
    (odd while writing: a seqlock), so the reader never blocks the loop and never sees a torn
    frame; only the newest frame is kept (the GUI wants no other). Events (progress, ready,
    errors) are pickled through a second queue; descriptors are not sent back (they would be
    large): the GUI loads them itself when it needs slices.

    Parameters
    ----------
    scene_path : str
    options : dict
        ``modes``, ``backend``, ``rate_hz``, ``realtime``, ``translation_only``, ``fake``,
        ``switch_interval``, ``raise_priority`` (see :func:`raise_thread_priority`).
    keep_periods : bool
        The child returns every period at the end (:meth:`stop_and_collect`).
    """

    def __init__(self, scene_path: str, *, options: dict | None = None,
                 keep_periods: bool = False):
        import multiprocessing as mp
        from multiprocessing import shared_memory

        self._ctx = mp.get_context("spawn")
        self._shm = shared_memory.SharedMemory(create=True, size=8 * _NSLOTS)
        self._block = np.ndarray((_NSLOTS,), dtype=np.float64, buffer=self._shm.buf)
        self._block[:] = 0.0
        self._commands = self._ctx.Queue()
        self._events = self._ctx.Queue()
        self._last_seq = 0.0
        self._pending: list[Any] = []
        self._result: Any = None
        self._proc = self._ctx.Process(
            target=_process_main,
            args=(str(scene_path), self._shm.name, self._commands, self._events,
                  dict(options or {}), keep_periods),
            name="skelasm-engine-process",
            daemon=True,
        )

    def start(self) -> None:
        self._proc.start()

    def is_alive(self) -> bool:
        return self._proc.is_alive()

    def send(self, command: Any) -> None:
        if not isinstance(command, api.Command.__args__):  # type: ignore[attr-defined]
            raise TypeError(f"not an engine command: {command!r}")
        self._commands.put(command)

    def poll_frames(self, max_frames: int | None = None) -> list[api.Frame]:
        b = self._block
        for _ in range(100):
            seq = float(b[0])
            if seq % 2:
                continue  # the writer is mid-frame
            snap = b.copy()
            if float(b[0]) == seq:
                break
        else:
            return []
        if seq == self._last_seq or seq == 0:
            return []
        self._last_seq = seq
        s = _SLOTS
        return [
            api.Frame(
                time=float(snap[s["time"]]), step=int(snap[s["step"]]),
                proxy_pose=_ro(snap[3:9]), part_pose=_ro(snap[9:15]),
                energy=float(snap[15]), force=_ro(snap[16:19]), torque=_ro(snap[19:22]),
                coupling_force=_ro(snap[22:25]), coupling_torque=_ro(snap[25:28]),
                haptic_force=_ro(snap[28:31]), haptic_torque=_ro(snap[31:34]),
                eval_us=float(snap[34]), step_us=float(snap[35]),
                period=api.PeriodStats(float(snap[38]), float(snap[39]), float(snap[40]),
                                       float(snap[41]), float(snap[42]), int(snap[43])),
                modes=int(snap[36]), paused=bool(snap[37]),
            )
        ]

    def _drain_events(self) -> None:
        while True:
            try:
                event = self._events.get_nowait()
            except queue.Empty:
                return
            if isinstance(event, tuple) and event and event[0] == "result":
                self._result = event[1]
            else:
                self._pending.append(event)

    def poll_events(self) -> list[Any]:
        self._drain_events()
        out, self._pending = self._pending, []
        return out

    def wait_ready(self, timeout: float = 600.0) -> bool:
        """Block until the child's ReadyEvent (or an error); True when ready."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and self._proc.is_alive():
            self._drain_events()
            for e in self._pending:
                if isinstance(e, api.ReadyEvent):
                    return True
                if isinstance(e, api.ErrorEvent) and e.fatal:
                    return False
            time.sleep(0.01)
        return False

    def stop(self, timeout: float = 5.0) -> None:
        if self._proc.is_alive():
            self._commands.put(api.Stop())
        end = time.monotonic() + timeout
        while self._proc.is_alive() and time.monotonic() < end:
            self._drain_events()
            time.sleep(0.01)
        self._drain_events()
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(1.0)
        try:
            self._shm.close()
            self._shm.unlink()
        except (FileNotFoundError, BufferError):
            pass

    def stop_and_collect(self) -> tuple[np.ndarray, float, str]:
        """Stop; return (periods in seconds, median eval microseconds, field name)."""
        self.stop()
        if self._result is None:
            errors = [e.message for e in self._pending if isinstance(e, api.ErrorEvent)]
            raise RuntimeError("the engine process returned no result: " + "; ".join(errors))
        return self._result


#: Real-time priority asked for by :func:`raise_thread_priority` (1-99; low, so that the
#: kernel's own real-time threads still come first).
REALTIME_PRIORITY = 10


def raise_thread_priority() -> str:
    """Run the calling thread ahead of ordinary work, as far as the OS allows.

    Tries ``SCHED_FIFO`` at :data:`REALTIME_PRIORITY` (Linux: root, ``CAP_SYS_NICE`` or an
    ``rtprio`` limit in ``/etc/security/limits.conf``); a woken FIFO thread preempts the
    GUI's render threads at once instead of waiting for its turn. The loop sleeps most of
    each period and the kernel caps real-time threads at 95 % of a CPU, so the rest of the
    machine keeps running. ``SKELASM_REALTIME=0`` turns this off. Returns what was granted,
    in words.
    """
    if os.environ.get("SKELASM_REALTIME", "1").strip() in ("0", "no", "off", "false"):
        return "normal (SKELASM_REALTIME=0)"
    if not hasattr(os, "sched_setscheduler"):
        return "normal (no real-time scheduling on this OS)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(REALTIME_PRIORITY))
    except OSError as exc:
        return (f"normal (real-time scheduling refused: {exc.strerror or exc}; allow it with "
                "an rtprio limit or CAP_SYS_NICE)")
    return f"real-time (SCHED_FIFO {REALTIME_PRIORITY})"


def _process_main(scene_path: str, shm_name: str, commands: Any, events: Any, options: dict,
                  keep_periods: bool) -> None:
    """Entry point of the engine process."""
    from multiprocessing import shared_memory

    shm = shared_memory.SharedMemory(name=shm_name)
    block = np.ndarray((_NSLOTS,), dtype=np.float64, buffer=shm.buf)
    try:
        from engine.api import open_scene

        handle = open_scene(scene_path)
        effects = handle.config.effects
        if options.get("translation_only"):
            effects = replace(effects, axes=("x", "y", "z"))
        handle = replace(handle, config=replace(handle.config, effects=effects))
        fake = bool(options.get("fake"))
        sim, model = build_simulation(
            handle, modes=options.get("modes"), backend=options.get("backend", "auto"),
            prepare=not fake,
        )
        if fake:
            sim.set_field(CorrelatorField(AnalyticWell(), sim.physics.kappa))
        field_name = _backend_name(sim.field)
        eval_log: list[float] = []

        def on_step(sim: Simulation, proxy: np.ndarray) -> None:
            block[0] += 1.0  # odd: writing
            block[1] = sim.time
            block[2] = sim.steps
            block[3:9] = proxy
            block[9:15] = sim.part_pose()
            s = sim.sample
            block[15] = s.energy
            block[16:19] = s.force
            block[19:22] = s.torque
            block[22:25] = sim.coupling_force
            block[25:28] = sim.coupling_torque
            block[28:31] = sim.haptic_force
            block[31:34] = sim.haptic_torque
            block[34] = s.microseconds
            block[36] = getattr(sim.field, "modes", 0)
            st = loop._stats
            block[38:44] = (st.rate_hz, st.median_us, st.p1_us, st.p99_us, st.max_us, st.window)
            block[0] += 1.0  # even: complete
            if keep_periods and len(eval_log) < 1_000_000:
                eval_log.append(s.microseconds)

        from engine.devices import MouseDevice, TrajectoryDevice

        device: Any = None
        if not keep_periods:
            # the scene's device, opened here in the engine process; the mouse if it fails
            cfg = handle.config.device
            try:
                device = open_device(cfg.kind, sim.proxy_pose, dict(cfg.options),
                                     handle.path.parent)
            except DeviceError as exc:
                device = MouseDevice(sim.proxy_pose)
                events.put(api.DeviceEvent(cfg.kind, False, str(exc), fallback="mouse"))
        elif options.get("bench_motion", True):
            pose_at = bench_proxy_motion(sim)
            ts = np.arange(0.0, 3600.0, 0.01)[:200000]
            device = TrajectoryDevice(np.column_stack([ts, np.array([pose_at(t) for t in ts])]))
        loop = EngineLoop(
            sim, model=model, device=device, rate_hz=options.get("rate_hz"),
            realtime=bool(options.get("realtime", True)), publish_every=1_000_000_000,
            on_step=on_step, keep_periods=keep_periods,
            switch_interval=options.get("switch_interval"),
            raise_priority=bool(options.get("raise_priority", False)),
        )

        def forward_commands() -> None:
            while True:
                cmd = commands.get()
                loop.send(cmd)
                if isinstance(cmd, api.Stop):
                    return

        def forward_events() -> None:
            while loop.is_alive() or loop.events:
                for e in loop.poll_events():
                    if isinstance(e, (api.ReadyEvent, api.DescriptorsSwapped)):
                        e = replace(e, descriptors=())
                    if isinstance(e, api.LandscapeReady):
                        continue
                    events.put(e)
                time.sleep(0.01)

        threading.Thread(target=forward_commands, daemon=True).start()
        loop.start()
        loop.started.wait(5.0)
        events.put(api.ReadyEvent((), field_name,
                                  f"engine ready; its loop thread: {loop.scheduling}"))
        fwd = threading.Thread(target=forward_events, daemon=True)
        fwd.start()
        while loop.is_alive():
            loop._thread.join(0.1)  # type: ignore[union-attr]
        fwd.join(1.0)
        eval_us = float(np.median(eval_log)) if eval_log else float("nan")
        described = f"{field_name}; engine thread scheduling: {loop.scheduling}"
        events.put(("result", (np.asarray(loop.periods), eval_us, described)))
    except Exception as exc:
        events.put(api.ErrorEvent(_message(exc), type(exc).__name__, fatal=True))
    finally:
        block = None  # type: ignore[assignment]  # drop the view so the block can close
        shm.close()
