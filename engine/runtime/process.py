"""The engine loop in its own process: out of reach of the GUI's interpreter lock.

Data crossing the process boundary, all through channels this module owns:

- frames: packed rows (``engine.runtime.frames``) in a :class:`FrameRing` in shared memory,
  written by the child's loop thread, read by the parent without locks;
- commands: pickled frozen commands through a one-way pipe, parent to child;
- events: pickled frozen events through a one-way pipe, child to parent, with protocol 5
  out-of-band buffers, so descriptors and landscapes (megabytes of arrays) are written to
  the pipe from their own memory with the interpreter lock released, never copied into one
  large pickle while the loop thread waits for the lock.

No queue or lock of ``multiprocessing`` is used (no semaphores to leak). The child ends with
its parent, however the parent ends (:class:`ParentGuard`): a parent-death signal on Linux,
end-of-file on the command pipe, and a watchdog comparing ``os.getppid()``; it then drops
real-time scheduling at once, stops the loop, and unlinks the shared memory itself. It
ignores Ctrl+C (SIGINT reaches the whole foreground process group): its parent decides. A
parent that exits normally (Ctrl+C included) stops its engines first thing at exit
(:meth:`ProcessEngine.stop`, registered with ``atexit``), so their real-time loops no longer
spin while the interpreter winds down, instead of being terminated last by
``multiprocessing``'s own exit handler.
"""

from __future__ import annotations

import atexit
import ctypes
import multiprocessing as mp
import os
import pickle
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing import shared_memory
from multiprocessing.connection import Connection

import numpy as np

from engine.devices import Device, DeviceError, MouseDevice, TrajectoryDevice, open_device
from engine.runtime.benchmark import AnalyticWell, bench_trajectory
from engine.runtime.frames import SLOTS, FrameRing
from engine.runtime.loop import EngineLoop
from engine.runtime.messages import (
    COMMAND_TYPES,
    Command,
    DeviceEvent,
    ErrorEvent,
    Event,
    Frame,
    ReadyEvent,
    Stop,
    StoppedEvent,
    describe_error,
)
from engine.runtime.pacing import WAIT_WORDS, drop_realtime_priority
from engine.runtime.scene_handle import SceneHandle
from engine.sim import Simulation, build_simulation, evaluator_name

__all__ = ["EngineOptions", "LoopResult", "ParentGuard", "ProcessEngine", "recv_message",
           "send_message"]

#: Frame rows kept in shared memory.
RING_ROWS = 64
#: The switch interval while the job worker runs: the loop thread gets the interpreter lock
#: back from the busy worker within this (otherwise Python's 5 ms, see start_engine).
JOB_SWITCH_INTERVAL = 5e-4
#: Seconds between the child's looks for events to send (each look takes the interpreter
#: lock from the loop thread for a moment, so not more often than needed).
EVENT_POLL = 0.05
#: Seconds between the watchdog's looks at the parent.
WATCH_PERIOD = 0.2
#: Seconds the child gives its loop to end after losing its parent before it exits anyway.
ORPHAN_GRACE = 2.0
#: Seconds a parent at exit gives its engine to stop before terminating it.
EXIT_GRACE = 1.0


@dataclass(frozen=True)
class EngineOptions:
    """How the child builds and runs its engine (see ``engine.runtime.start_engine``)."""

    modes: int | None = None
    backend: str = "auto"
    rate_hz: float | None = None
    realtime: bool = True
    switch_interval: float | None = None  # Python's 5 ms (see start_engine)
    raise_priority: bool = False
    analytic: bool = False  # benchmarks: an analytic field instead of the correlator
    keep_periods: bool = False  # benchmarks: return every period at the end
    job_process: bool | None = None  # see EngineLoop (None: job_process.wanted decides)


@dataclass(frozen=True)
class LoopResult:
    """What an engine process measured (``EngineOptions(keep_periods=True)``).

    Attributes
    ----------
    periods : (n,) float64
        Every loop period in seconds.
    ends : (n,) float64
        ``perf_counter`` at the end of each period (the clock is shared between processes
        on Linux: :meth:`engine.runtime.pacing.PeriodWindow.ends`).
    eval_us : float
        Median evaluation time in microseconds.
    described : str
        The field and the loop thread's scheduling, in words.
    collections : (m, 3) float64
        The engine process's garbage collections while the loop ran
        (:meth:`engine.runtime.pacing.CollectionLog.table`).
    """

    periods: np.ndarray
    ends: np.ndarray
    eval_us: float
    described: str
    collections: np.ndarray


def send_message(conn: Connection, obj: object) -> None:
    """Pickle ``obj`` (protocol 5) and write it with its large buffers sent out of band."""
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    conn.send_bytes(len(buffers).to_bytes(4, "little") + head)
    for b in buffers:
        conn.send_bytes(b.raw())


def recv_message(conn: Connection) -> object:
    """Read one object written by :func:`send_message`."""
    data = conn.recv_bytes()
    count = int.from_bytes(data[:4], "little")
    buffers = [conn.recv_bytes() for _ in range(count)]
    return pickle.loads(memoryview(data)[4:], buffers=buffers)


# ---------------------------------------------------------------------------------------------
# parent side


class ProcessEngine:
    """The engine loop in a child process.

    Same reader interface as :class:`engine.runtime.loop.EngineLoop` (``send``,
    ``poll_frames``, ``poll_events``, ``is_alive``, ``stop``).

    Start it from a thread that lives as long as the engine (the GUI's main thread): on Linux
    the child's parent-death signal follows the thread that started it.

    Parameters
    ----------
    handle : SceneHandle
        The loaded scene (sent to the child once, so it runs on exactly this scene and
        does not load the meshes again).
    options : EngineOptions
    """

    def __init__(self, handle: SceneHandle, options: EngineOptions | None = None):
        ctx = mp.get_context("spawn")
        self._shm = shared_memory.SharedMemory(create=True, size=8 * FrameRing.size(RING_ROWS))
        self._ring = FrameRing(RING_ROWS, np.ndarray((FrameRing.size(RING_ROWS),),
                                                     dtype=np.float64, buffer=self._shm.buf))
        self._ring.buffer[:] = 0.0
        cmd_read, self._commands = ctx.Pipe(duplex=False)
        self._events, event_write = ctx.Pipe(duplex=False)
        self._send_lock = threading.Lock()
        self._pending: list[Event] = []
        self._said_stopped = False  # a StoppedEvent was delivered (real or made here)
        self._result: LoopResult | None = None
        self._proc = ctx.Process(
            target=_child_main,
            args=(handle, self._shm.name, cmd_read, event_write,
                  options or EngineOptions(), os.getpid()),
            name="skelasm-engine-process",
            daemon=True,
        )
        self._child_ends = (cmd_read, event_write)
        self._closed = False

    @property
    def shared_memory_name(self) -> str:
        """Name of the shared-memory block holding the frames."""
        return self._shm.name

    @property
    def pid(self) -> int | None:
        """The child's process id once started."""
        return self._proc.pid

    def start(self) -> None:
        """Start the child process.

        The child ignores Ctrl+C from its first instruction, not only once its imports are
        done: SIGINT ignored while it is spawned stays ignored across ``exec`` (Ctrl+C
        reaches the whole terminal group, and the parent decides when the engine stops).
        """
        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
        try:
            self._proc.start()
        finally:
            if main:
                signal.signal(signal.SIGINT,
                              previous if previous is not None else signal.default_int_handler)
        for end in self._child_ends:
            end.close()  # the child has its own copies; EOF then means it is gone
        atexit.register(self._stop_at_exit)

    def _stop_at_exit(self) -> None:
        self.stop(timeout=EXIT_GRACE)

    def is_alive(self) -> bool:
        """True while the child runs."""
        return self._proc.is_alive()

    def send(self, command: Command) -> None:
        """Queue a command for the child's loop."""
        if not isinstance(command, COMMAND_TYPES):
            raise TypeError(f"not an engine command: {command!r}")
        with self._send_lock:
            try:
                self._commands.send(command)
            except (BrokenPipeError, OSError):
                pass  # the child is gone; its StoppedEvent or ErrorEvent says why

    def poll_frames(self, max_frames: int | None = None) -> list[Frame]:
        """Frames the child published since the last call, oldest first."""
        if self._closed:
            return []
        return self._ring.read_frames(max_frames)

    def _drain(self) -> None:
        while not self._events.closed:
            try:
                if not self._events.poll():
                    return
                message = recv_message(self._events)
            except (EOFError, OSError):
                self._events.close()
                return
            if isinstance(message, LoopResult):
                self._result = message
            else:
                self._pending.append(message)  # type: ignore[arg-type]  # only events come

    def poll_events(self) -> list[Event]:
        """Events since the last call, oldest first.

        A child that ended without saying so (killed, or crashed before its loop started)
        gets a fatal ErrorEvent and a StoppedEvent here, so no caller waits for it forever.
        """
        self._drain()
        if (not self._closed and not self._said_stopped and self._events.closed
                and not self._proc.is_alive()):
            self._proc.join(0.1)
            code = self._proc.exitcode
            how = (f"was killed by signal {-code}" if code is not None and code < 0
                   else f"exited with status {code}")
            self._pending += [
                ErrorEvent(f"the engine process {how} before it reported why; its output "
                           "(stderr of this program) has the details", "EngineProcessDied",
                           fatal=True),
                StoppedEvent(0, "engine process died"),
            ]
        if any(isinstance(e, StoppedEvent) for e in self._pending):
            self._said_stopped = True
        out, self._pending = self._pending, []
        return out

    def wait_ready(self, timeout: float = 600.0) -> bool:
        """Block until the child's ReadyEvent (or a fatal error); True when ready."""
        end = time.monotonic() + timeout
        while time.monotonic() < end and self._proc.is_alive():
            self._drain()
            for e in self._pending:
                if isinstance(e, ReadyEvent):
                    return True
                if isinstance(e, ErrorEvent) and e.fatal:
                    return False
            time.sleep(0.01)
        return False

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the child and free the shared memory.

        Sends Stop, then terminates the child if it is still alive after ``timeout`` seconds.
        """
        if self._closed:
            return
        atexit.unregister(self._stop_at_exit)
        self.send(_STOP)
        end = time.monotonic() + timeout
        while self._proc.is_alive() and time.monotonic() < end:
            self._drain()  # a child blocked on a full event pipe must be able to finish
            self._proc.join(0.01)
        self._drain()
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(1.0)
        self._closed = True
        self._commands.close()
        self._events.close()
        self._ring = FrameRing(RING_ROWS)  # drop the view of the shared block before closing
        self._shm.close()
        try:
            self._shm.unlink()
        except FileNotFoundError:
            pass  # the child unlinked it (it lost us once)

    def stop_and_collect(self) -> LoopResult:
        """Stop; return what the engine process measured."""
        self.stop()
        if self._result is None:
            errors = [e.message for e in self._pending if isinstance(e, ErrorEvent)]
            raise RuntimeError("the engine process returned no result: " + "; ".join(errors))
        return self._result


_STOP = Stop()


# ---------------------------------------------------------------------------------------------
# child side


_PR_SET_PDEATHSIG = 1


class ParentGuard:
    """Ends this process's engine when its parent process is gone.

    Three ways to notice, whichever comes first: the kernel's parent-death signal (Linux
    ``prctl(PR_SET_PDEATHSIG, SIGTERM)``, set here through ctypes), end-of-file on the
    command pipe (the caller calls :meth:`lost`), and a watchdog thread comparing
    ``os.getppid()`` with the parent's pid every :data:`WATCH_PERIOD` seconds. On the first,
    ``on_lost`` runs (drop real-time priority, stop the loop); if the process still lives
    :data:`ORPHAN_GRACE` seconds later it exits at once.

    The SIGTERM handler only notes the signal; the watchdog acts on it at its next look. A
    handler runs in the main thread between two bytecodes, possibly inside a lock that
    thread holds, and a second SIGTERM can arrive inside the first handler: a handler that
    called :meth:`lost` itself deadlocked on the :class:`threading.Event`'s lock, and the
    orphaned engine stepped on, real-time, until killed.
    """

    def __init__(self, parent_pid: int, on_lost: Callable[[], None]):
        self.parent_pid = parent_pid
        self.on_lost = on_lost
        self.gone = threading.Event()
        self._once = threading.Lock()
        self._signal: str | None = None  # set by the handler, read by the watchdog
        self.signalled = _set_parent_death_signal(signal.SIGTERM)
        signal.signal(signal.SIGTERM, self._note_signal)
        threading.Thread(target=self._watch, name="skelasm-parent-watch", daemon=True).start()

    def _note_signal(self, signum: int, frame: object) -> None:
        self._signal = signal.Signals(signum).name  # no lock, no call: see the class

    def _watch(self) -> None:
        while not self.gone.is_set():
            if self._signal is not None:
                self.lost(self._signal)
            elif os.getppid() != self.parent_pid:
                self.lost("parent process gone")
            self.gone.wait(WATCH_PERIOD)
        time.sleep(ORPHAN_GRACE)
        os._exit(1)

    def lost(self, why: str) -> None:
        """The parent is gone (or asked us to end): run ``on_lost`` once, whichever thread asks."""
        if not self._once.acquire(blocking=False):
            return
        self.gone.set()
        self.on_lost()


def _set_parent_death_signal(signum: int) -> bool:
    """Ask Linux to send ``signum`` when the parent dies; False where it cannot."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(signum), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _child_device(handle: SceneHandle, sim: Simulation, options: EngineOptions,
                  notices: list[Event]) -> Device:
    if options.keep_periods:
        return TrajectoryDevice(bench_trajectory(sim, 3600.0)[:200000])
    cfg = handle.config.device
    try:
        return open_device(cfg.kind, sim.proxy_pose, dict(cfg.options), handle.path.parent)
    except DeviceError as exc:
        notices.append(DeviceEvent(cfg.kind, False, str(exc), fallback="mouse"))
        return MouseDevice(sim.proxy_pose)


def _child_main(handle: SceneHandle, shm_name: str, commands: Connection, events: Connection,
                options: EngineOptions, parent_pid: int) -> None:
    """Entry point of the engine process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    shm = shared_memory.SharedMemory(name=shm_name)
    ring = FrameRing(RING_ROWS, np.ndarray((FrameRing.size(RING_ROWS),), dtype=np.float64,
                                           buffer=shm.buf))
    holder: list[EngineLoop] = []
    orphaned = threading.Event()

    def on_lost() -> None:
        orphaned.set()
        if holder:
            loop = holder[0]
            if loop.native_id is not None:
                drop_realtime_priority(loop.native_id)
            loop.stop(timeout=0.0)

    guard = ParentGuard(parent_pid, on_lost)
    eval_log: list[float] = []
    try:
        blocking = options.keep_periods and not options.analytic  # benchmarks measure ready
        sim, model = build_simulation(handle, modes=options.modes, backend=options.backend,
                                      rate_hz=options.rate_hz, prepare=blocking)
        if options.analytic:
            sim.set_field(AnalyticWell(sim.physics.kappa))
        notices: list[Event] = []
        device = _child_device(handle, sim, options, notices)
        eval_slot = SLOTS["eval_us"].start

        def on_frame(row: np.ndarray) -> None:
            if len(eval_log) < 1_000_000:
                eval_log.append(float(row[eval_slot]))

        loop = EngineLoop(
            sim, model=model, device=device, realtime=options.realtime, frames=ring,
            prepare=not (blocking or options.analytic),
            on_frame=on_frame if options.keep_periods else None,
            keep_periods=options.keep_periods, switch_interval=options.switch_interval,
            job_switch_interval=JOB_SWITCH_INTERVAL,
            raise_priority=options.raise_priority, base_dir=handle.path.parent,
            job_process=options.job_process,
        )
        loop.events.extend(notices)
        holder.append(loop)

        def forward_commands() -> None:
            while True:
                try:
                    command = commands.recv()
                except (EOFError, OSError):
                    guard.lost("command pipe closed")
                    return
                loop.send(command)

        threading.Thread(target=forward_commands, name="skelasm-commands", daemon=True).start()
        if orphaned.is_set():
            return
        loop.start()
        while loop.is_alive() or loop.events:
            for event in loop.poll_events():
                send_message(events, event)
            loop.join(EVENT_POLL)
        if options.keep_periods:
            eval_us = float(np.median(eval_log)) if eval_log else float("nan")
            described = (f"{evaluator_name(sim.field)}; engine thread scheduling: "
                         f"{loop.scheduling}, waiting by {WAIT_WORDS[loop.waiting]}; "
                         f"refresh lane: {loop.guidance.refresh_lane.describe()}")
            send_message(events, LoopResult(loop.periods, loop.window.ends(), eval_us,
                                            described, loop.window.collections.table()))
    except (BrokenPipeError, EOFError):
        guard.lost("event pipe closed")
    except Exception as exc:  # noqa: BLE001 -- reported to the parent
        try:
            send_message(events, ErrorEvent(describe_error(exc), type(exc).__name__,
                                            fatal=True))
            send_message(events, StoppedEvent(0, "error"))
        except OSError:
            pass
    finally:
        ring = FrameRing(RING_ROWS)  # drop the view of the shared block before closing it
        shm.close()
        if orphaned.is_set():
            try:
                shm.unlink()  # nobody else will
            except FileNotFoundError:
                pass
        guard.gone.set()
