"""Holding the loop's rate on the wall clock, measuring it, and asking the OS for priority.

Data: periods are float seconds between the starts of two loop iterations (``perf_counter``);
statistics are :class:`engine.runtime.messages.PeriodStats` in microseconds.

Pacing (:class:`Pacer`): the loop targets deadlines ``next += dt`` and waits for each in one
of two ways (:data:`WAITS`):

- ``"sleep"``: sleep until :data:`SPIN_MARGIN` before the deadline (Python's sleep overshoots
  by 60-100 us), then spin the rest. For a real-time (``SCHED_FIFO``) loop thread, whose
  wake-up preempts ordinary work at once and which must not keep a core from it.
- ``"yield"``: spin until the deadline with the interpreter lock released, yielding the CPU
  to any thread that is ready at each turn (:func:`yield_until`). For a loop thread at
  normal priority: its CPU never goes idle, so waking it costs nothing. A sleeping thread's
  wake-up waits for its CPU to come out of idle, which on a virtual machine whose idle CPUs
  halt (``cpuidle`` haltpoll, no guest polling) is the host's scheduling latency: a bare
  1 kHz loop that sleeps missed 2 ms in most 3-second windows there, one that spins held it.

Catch-up policy: after a short overrun the next deadlines are already due, so the loop
runs them back to back and catches up (simulated time stays locked to the wall clock); after
an overrun of more than :data:`RESYNC_PERIODS` periods it re-anchors the deadline at now
instead of racing through the backlog (the simulation then lags the wall clock by the gap).
"""

from __future__ import annotations

import functools
import gc
import os
import sys
import threading
import time
from array import array
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager, nullcontext
from typing import cast

import numpy as np

from engine.runtime.messages import PeriodStats

__all__ = [
    "LANE_PRIORITY",
    "REALTIME_PRIORITY",
    "RESYNC_PERIODS",
    "SPIN_MARGIN",
    "WAITS",
    "WAIT_WORDS",
    "CollectionLog",
    "Pacer",
    "PeriodWindow",
    "drop_realtime_priority",
    "period_stats",
    "raise_thread_priority",
    "switch_interval",
    "yield_until",
]

#: Seconds before a deadline at which the loop stops sleeping and spins.
SPIN_MARGIN = 0.0003
#: An overrun longer than this many periods re-anchors the deadline (no racing to catch up).
RESYNC_PERIODS = 5
#: Steps between refreshes of the period statistics in frames.
STATS_EVERY = 100
#: Periods kept for the statistics window.
STATS_WINDOW = 1000
#: Real-time priority asked for by :func:`raise_thread_priority` (1-99; low, so that the
#: kernel's own real-time threads still come first).
REALTIME_PRIORITY = 10
#: Real-time priority of the refresh lane while a real-time loop waits for its cache: below
#: the loop's, so that the waking loop preempts it, and above every ordinary thread (the
#: window's, the job worker's), so that the cache is not held up behind them.
LANE_PRIORITY = 5
#: How :class:`Pacer` waits for a deadline (see the module's docstring).
WAITS = ("sleep", "yield")
#: :attr:`Pacer.waiting` in words (an unpaced pacer does not wait: ``"none"``).
WAIT_WORDS = {"sleep": "sleeping", "yield": "spinning (yielding the CPU)",
              "none": "not waiting (unpaced)"}


def period_stats(periods_s: np.ndarray) -> PeriodStats:
    """:class:`PeriodStats` of an array of periods in seconds."""
    p = np.asarray(periods_s, dtype=np.float64)
    if len(p) == 0:
        return PeriodStats()
    us = p * 1e6
    q = np.percentile(us, [50, 1, 99])
    total = float(p.sum())
    return PeriodStats(
        rate_hz=float(len(p) / total) if total > 0 else 0.0,
        median_us=float(q[0]),
        p1_us=float(q[1]),
        p99_us=float(q[2]),
        max_us=float(us.max()),
        window=int(len(p)),
    )


class Pacer:
    """Deadlines every ``dt`` seconds on ``perf_counter`` (see the module's catch-up policy).

    Parameters
    ----------
    dt : float
        Target period in seconds.
    realtime : bool
        False: :meth:`wait` returns at once (as fast as possible).
    wait : {"sleep", "yield"}
        How to wait for a deadline (:data:`WAITS`). ``"yield"`` where :func:`yield_until`
        is not available here falls back to ``"sleep"``; :attr:`waiting` says which is used.
        An unpaced pacer (``realtime=False``) builds nothing.
    """

    def __init__(self, dt: float, *, realtime: bool = True, wait: str = "sleep"):
        if wait not in WAITS:
            raise ValueError(f"wait must be one of {WAITS}, got {wait!r}")
        self.dt = float(dt)
        self.realtime = realtime
        self.overruns = 0  # times the deadline was re-anchored
        self._yield = _yield_kernel() if wait == "yield" and realtime else None
        #: The way this pacer waits: ``"sleep"``, ``"yield"``, or ``"none"`` (unpaced).
        self.waiting = ("none" if not realtime
                        else "yield" if self._yield is not None else "sleep")
        self._clock = np.zeros(2, dtype=np.int64)  # the yield kernel's timespec
        self.deadline = time.perf_counter() + self.dt

    def wait(self) -> None:
        """Wait until the current deadline (sleep then spin, or yield); then move it on."""
        if not self.realtime:
            return
        perf = time.perf_counter
        deadline = self.deadline
        if self._yield is not None:
            self._yield(int(deadline * 1e9), self._clock)
        else:
            remaining = deadline - perf()
            if remaining > SPIN_MARGIN:
                time.sleep(remaining - SPIN_MARGIN)
            while perf() < deadline:
                pass
        now = perf()
        if now - deadline > RESYNC_PERIODS * self.dt:
            self.overruns += 1
            deadline = now
        self.deadline = deadline + self.dt


def yield_until(deadline_ns: int) -> bool:
    """Spin until ``perf_counter_ns() >= deadline_ns``, interpreter lock released, yielding.

    Each turn reads the clock and calls ``sched_yield``, so any thread that is ready runs
    first; the calling thread keeps its CPU busy and is never woken from idle. Returns False
    (without waiting) where this is not available: not Linux, ``perf_counter`` not on
    ``CLOCK_MONOTONIC``, or the kernel not compiled.
    """
    kernel = _yield_kernel()
    if kernel is None:
        return False
    kernel(int(deadline_ns), np.zeros(2, dtype=np.int64))
    return True


@functools.cache
def _yield_kernel() -> Callable[[int, np.ndarray], None] | None:
    """The compiled spin of :func:`yield_until` (numba, nogil), or None where unavailable.

    It calls libc's ``clock_gettime(CLOCK_MONOTONIC)`` and ``sched_yield`` through ctypes,
    so numba cannot cache it on disk: it is compiled once per process (about 0.5 s).
    """
    if not sys.platform.startswith("linux"):
        return None
    if time.get_clock_info("perf_counter").implementation != "clock_gettime(CLOCK_MONOTONIC)":
        return None
    try:
        import ctypes

        import numba

        libc = ctypes.CDLL(None)
        clock_gettime = libc.clock_gettime
        clock_gettime.argtypes = [ctypes.c_int, ctypes.c_void_p]
        clock_gettime.restype = ctypes.c_int
        sched_yield = libc.sched_yield
        sched_yield.argtypes = []
        sched_yield.restype = ctypes.c_int
        monotonic = int(time.CLOCK_MONOTONIC)

        @numba.njit(nogil=True)
        def spin(deadline_ns: int, timespec: np.ndarray) -> None:  # pragma: no cover (numba)
            while True:
                clock_gettime(monotonic, timespec.ctypes.data)
                if timespec[0] * 1_000_000_000 + timespec[1] >= deadline_ns:
                    return
                sched_yield()

        spin(0, np.zeros(2, dtype=np.int64))  # compile now, not in the loop's first period
    except Exception:  # noqa: BLE001 -- no compiler or no libc symbol: the pacer sleeps
        return None
    return cast("Callable[[int, np.ndarray], None]", spin)


class CollectionLog:
    """Python's cyclic garbage collections while a loop runs: when, how long, which generation.

    A collection holds the interpreter lock from start to end, in whichever thread
    triggered it, so a loop sharing the interpreter waits it out. In a thread engine that
    interpreter is the caller's: a full collection of a test process's 165,000 objects took
    50 to 90 ms there (docs/runtime.md, "The garbage collector": a thread engine shares its
    caller's). Benchmarks keep this log beside the periods (``keep_periods``) and place
    each collection against the K changes.

    The callback (``gc.callbacks``) runs in the collecting thread with the lock held, and
    collections never overlap, so :meth:`table` may be read from any thread.
    """

    def __init__(self) -> None:
        self._rows = array("d")  # start (perf_counter), seconds, generation; flat
        self._started = 0.0

    def _callback(self, phase: str, info: dict[str, int]) -> None:
        now = time.perf_counter()
        if phase == "start":
            self._started = now
        else:
            self._rows.extend((self._started, now - self._started, float(info["generation"])))

    @contextmanager
    def watching(self) -> Iterator[None]:
        """Log the collections inside the block."""
        gc.callbacks.append(self._callback)
        try:
            yield
        finally:
            gc.callbacks.remove(self._callback)

    def table(self) -> np.ndarray:
        """(n, 3) float64: each collection's ``perf_counter`` start, seconds, generation."""
        return np.asarray(self._rows, dtype=np.float64).reshape(-1, 3)


class PeriodWindow:
    """The last :data:`STATS_WINDOW` periods and their statistics.

    For benchmarks, it also keeps every period and the garbage collections (``keep``).

    Parameters
    ----------
    keep : bool
        Also keep every period in :attr:`periods`, and the collections inside
        :meth:`watching` in :attr:`collections`.
    """

    def __init__(self, *, keep: bool = False):
        self.keep = keep
        self.periods = array("d")
        self.collections = CollectionLog()
        self.stats = PeriodStats()
        self._window = np.zeros(STATS_WINDOW)
        self._n = 0
        self._last = time.perf_counter()
        #: ``perf_counter`` when the first kept period began (:meth:`ends`).
        self.started = self._last

    def restart(self) -> None:
        """The next period starts now (the loop begins)."""
        self._last = time.perf_counter()
        if not self.periods:
            self.started = self._last

    def ends(self) -> np.ndarray:
        """``perf_counter`` at the end of each kept period (with ``keep``).

        ``perf_counter`` is ``CLOCK_MONOTONIC`` on Linux, one clock for every process, so a
        parent can place a child's periods against its own times.
        """
        return self.started + np.cumsum(np.asarray(self.periods))

    def watching(self) -> AbstractContextManager[None]:
        """A block inside which collections are logged (with ``keep``; else nothing)."""
        return self.collections.watching() if self.keep else nullcontext()

    def tick(self) -> None:
        """Record the period ending now."""
        now = time.perf_counter()
        period = now - self._last
        self._last = now
        self._window[self._n % STATS_WINDOW] = period
        self._n += 1
        if self.keep:
            self.periods.append(period)
        if self._n % STATS_EVERY == 0:
            self.stats = period_stats(self._window[: min(self._n, STATS_WINDOW)])


@contextmanager
def switch_interval(seconds: float | None) -> Iterator[None]:
    """``sys.setswitchinterval(seconds)`` inside the block (None: leave it), restored after.

    It is how long another thread may hold the GIL before the loop thread gets it back
    (Python's default is 5 ms).
    """
    old = sys.getswitchinterval()
    if seconds is not None:
        sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        if seconds is not None:
            sys.setswitchinterval(old)


def raise_thread_priority(priority: int = REALTIME_PRIORITY,
                          native_thread_id: int | None = None) -> str:
    """Run a thread (default: the calling one) ahead of ordinary work, as far as the OS allows.

    Tries ``SCHED_FIFO`` at ``priority`` (default :data:`REALTIME_PRIORITY`; Linux: root,
    ``CAP_SYS_NICE`` or an ``rtprio`` limit in ``/etc/security/limits.conf``); a woken FIFO
    thread preempts the GUI's render threads at once instead of waiting for its turn. The
    loop sleeps most of each period and the kernel caps real-time threads at 95 % of a CPU,
    so the rest of the machine keeps running. ``SKELASM_REALTIME=0`` turns this off.
    Returns what was granted, in words.

    The request carries ``SCHED_RESET_ON_FORK``: a thread the loop thread starts (the job
    worker, the refresh lane, a transform's helper threads) runs at ordinary priority.
    Without it Linux hands the policy down, and a job thread in ``SCHED_FIFO`` at the
    loop's own priority cannot be preempted by the waking loop: the loop waited out
    whole transforms. The refresh lane is raised to its own, lower priority
    (:data:`LANE_PRIORITY`) only while the loop waits for it.
    """
    if os.environ.get("SKELASM_REALTIME", "1").strip() in ("0", "no", "off", "false"):
        return "normal (SKELASM_REALTIME=0)"
    if not hasattr(os, "sched_setscheduler"):
        return "normal (no real-time scheduling on this OS)"
    try:
        policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
        tid = 0 if native_thread_id is None else int(native_thread_id)
        os.sched_setscheduler(tid, policy, os.sched_param(priority))
    except OSError as exc:
        return (f"normal (real-time scheduling refused: {exc.strerror or exc}; allow it with "
                "an rtprio limit or CAP_SYS_NICE)")
    return f"real-time (SCHED_FIFO {priority})"


def drop_realtime_priority(native_thread_id: int | None = None) -> None:
    """Put a thread (default: the calling one) back to ordinary scheduling.

    On Linux a thread id is a scheduling target of its own, so another thread (the engine
    process's watchdog) can demote the loop thread when the process loses its parent.
    """
    if not hasattr(os, "sched_setscheduler"):
        return
    tid = 0 if native_thread_id is None else int(native_thread_id)
    try:
        if os.sched_getscheduler(tid) != os.SCHED_OTHER:
            os.sched_setscheduler(tid, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pass  # the thread has ended


def current_native_id() -> int:
    """The calling thread's OS id (for :func:`drop_realtime_priority`)."""
    return threading.get_native_id()
