"""Holding the loop's rate on the wall clock, measuring it, and asking the OS for priority.

Data: periods are float seconds between the starts of two loop iterations (``perf_counter``);
statistics are :class:`engine.runtime.messages.PeriodStats` in microseconds.

Pacing (:class:`Pacer`): the loop targets deadlines ``next += dt``; it sleeps until
:data:`SPIN_MARGIN` before a deadline (Python's sleep overshoots by 60-100 us) and spins the
rest. Catch-up policy: after a short overrun the next deadlines are already due, so the loop
runs them back to back and catches up (simulated time stays locked to the wall clock); after
an overrun of more than :data:`RESYNC_PERIODS` periods it re-anchors the deadline at now
instead of racing through the backlog (the simulation then lags the wall clock by the gap).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from array import array
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from engine.runtime.messages import PeriodStats

__all__ = [
    "REALTIME_PRIORITY",
    "RESYNC_PERIODS",
    "SPIN_MARGIN",
    "Pacer",
    "PeriodWindow",
    "drop_realtime_priority",
    "period_stats",
    "raise_thread_priority",
    "switch_interval",
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
    """

    def __init__(self, dt: float, *, realtime: bool = True):
        self.dt = float(dt)
        self.realtime = realtime
        self.overruns = 0  # times the deadline was re-anchored
        self.deadline = time.perf_counter() + self.dt

    def wait(self) -> None:
        """Sleep, then spin, until the current deadline; then move it on by ``dt``."""
        if not self.realtime:
            return
        perf = time.perf_counter
        deadline = self.deadline
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


class PeriodWindow:
    """The last :data:`STATS_WINDOW` periods and their statistics.

    For benchmarks, it also keeps every period (``keep``).

    Parameters
    ----------
    keep : bool
        Also keep every period in :attr:`periods`.
    """

    def __init__(self, *, keep: bool = False):
        self.keep = keep
        self.periods = array("d")
        self.stats = PeriodStats()
        self._window = np.zeros(STATS_WINDOW)
        self._n = 0
        self._last = time.perf_counter()

    def restart(self) -> None:
        """The next period starts now (the loop begins)."""
        self._last = time.perf_counter()

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
