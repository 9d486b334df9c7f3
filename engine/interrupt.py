"""Long compiled calls that a signal still interrupts at once.

Python runs a signal's handler (Ctrl+C's ``KeyboardInterrupt``, the command line's SIGTERM
and SIGHUP) in the main thread, between bytecodes. While the main thread is inside one
compiled call (a numba kernel, a wait on an OpenCL queue) nothing acts until the call
returns: on a finely tessellated mesh one chunk of the descriptor's points took 2 to 6 s.
:func:`call_interruptibly` makes such a call on a worker thread and waits for it in the main
thread, where a wait is interrupted by a signal: the handler runs within
:data:`WAIT_SLICE_S`, and its exception leaves from here. The worker finishes the call it
is in (its result is dropped) and takes the next; it is a daemon, so a process ended by the
signal does not wait for it.

Only the command line turns this on (:func:`enable`, for the console script): there the
process ends with the signal. Elsewhere, and off the main thread (the window's jobs, the
engine's processes, a script), a call runs where it is, as it always did: cancel is polled
between calls. One worker serves every caller, so compiled code never runs on two threads
at once from here; a forked child starts with the routing off and no worker.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")

#: The longest the main thread waits before looking again (its wait is interrupted by a
#: signal in any case; this bounds the latency where a platform's wait is not).
WAIT_SLICE_S = 0.05

_lock = threading.Lock()
_enabled = False  # enable(): the command line's console script
_running = threading.Event()  # set while the worker is inside a call
_jobs: queue.SimpleQueue[tuple[Callable[..., Any], tuple[Any, ...], list[Any],
                               threading.Event]] | None = None


def _serve(jobs: queue.SimpleQueue) -> None:  # type: ignore[type-arg]
    while True:
        fn, args, box, done = jobs.get()
        _running.set()
        try:
            box.append((True, fn(*args)))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller, re-raised there
            box.append((False, exc))
        finally:
            _running.clear()
            done.set()


def _worker() -> queue.SimpleQueue:  # type: ignore[type-arg]
    global _jobs
    with _lock:
        if _jobs is None:
            jobs: queue.SimpleQueue = queue.SimpleQueue()  # type: ignore[type-arg]
            # not named "skelasm-...": the window waits for those at its end, and this one
            # idles for the process's life
            threading.Thread(target=_serve, args=(jobs,), name="interruptible-calls",
                             daemon=True).start()
            _jobs = jobs
        return _jobs


def enable() -> None:
    """Run the main thread's compiled calls on the worker from now on (the command line)."""
    global _enabled
    _enabled = True


def _forked() -> None:
    """Reset the routing in a forked child, with new locks.

    The parent's worker thread is not there, and a lock held at the fork stays held.
    """
    global _enabled, _jobs, _lock, _running
    _enabled = False
    _jobs = None
    _lock = threading.Lock()
    _running = threading.Event()


os.register_at_fork(after_in_child=_forked)


def call_interruptibly(fn: Callable[..., T], *args: Any) -> T:
    """``fn(*args)``, with a signal acting within :data:`WAIT_SLICE_S` while it runs.

    Once enabled (:func:`enable`), on the main thread the call runs on the worker, and an
    exception a signal handler raises here (``KeyboardInterrupt``, the command line's
    ``Terminated``) propagates at once while the abandoned call runs to its end on the
    worker. ``fn``'s own exceptions are re-raised here. Otherwise a plain call.
    """
    if not _enabled or threading.current_thread() is not threading.main_thread():
        return fn(*args)
    box: list[tuple[bool, Any]] = []
    done = threading.Event()
    _worker().put((fn, args, box, done))
    while not done.wait(WAIT_SLICE_S):
        pass
    ok, value = box[0]
    if not ok:
        raise value
    return value  # type: ignore[no-any-return]


def in_flight() -> bool:
    """Whether the worker is still inside a call (one a signal made its caller abandon).

    A process ending then must not finalise the runtime the call uses: PoCL's threads
    aborted the interpreter's exit (``terminate called without an active exception``,
    SIGABRT) while an abandoned OpenCL chunk ran. The command line ends with ``os._exit``
    after its own clean-up instead.
    """
    return _running.is_set()
