"""A pair's spectral work in a process of its own: the truncations and landscapes of a K.

Why: the loop steps every millisecond in one interpreter, and a thread there computing a new
K's table or a landscape (hundreds of short numpy calls) keeps taking the interpreter lock
back; the loop then waits for it, and a K change lengthened its periods past
2 ms (docs/runtime.md, "K changes"). In a process of its own that work holds no lock the loop
needs; the loop's process only maps the arrays that come back.

Data crossing the boundary, all through channels this module owns:

- requests and replies: small pickled tuples over one socket pair (``(op, id, ...)`` and
  ``(kind, id, ...)``), replies matched to the waiting caller by id;
- arrays: the sender pickles the object (a :class:`~engine.correlation.Spectra`, a
  :class:`~engine.correlation.ModeTable`, a :class:`~engine.correlation.Landscape`) with
  protocol 5 out-of-band buffers and writes the buffers into a file of
  its own in a private folder (in ``/dev/shm`` where there is one); the receiver reads the
  file into one new array and unlinks it, and the arrays are views of that array. Nothing
  is copied while the interpreter lock is held (file reads and writes release it), and the
  arrays are writable C arrays, the types the compiled kernels were compiled for.

Rotation caches stay in the loop's process: their build is a compiled kernel with the lock
released, asked for every few milliradians while the part turns, and one that came back
late through the child left the full per-pose path serving (measured: docs/runtime.md).

The child computes with the very functions the loop's process would
(:func:`engine.correlation.tables.truncate`, :func:`engine.correlation.compute_landscape`)
on the same spectra, so the results are the same arrays. It serves two requests at once (a
new request need not wait for a cancelled one to notice), leaves one core to the loop in
each, runs at a lower
priority than the loop's process (:data:`JOB_NICE`), and ends with its parent: on
end-of-file on its socket, however the parent ended. It starts in a session of its own, so
Ctrl+C in a terminal does not reach it; its parent decides.

Where the child cannot be started or has gone, :class:`RemoteSpectral` computes in the
calling process instead (the same results; only the lock is shared again), and says so in
:attr:`JobProcess.problem`.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import os
import pickle
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import weakref
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import TYPE_CHECKING

import numpy as np

from engine.backend import cpu_cores, spare_cores
from engine.errors import Cancelled

if TYPE_CHECKING:
    from engine.correlation import Landscape, ModeTable, Spectra

_log = logging.getLogger(__name__)

__all__ = ["JobProcess", "JobProcessGone", "RemoteSpectral", "read_arrays", "write_arrays"]

#: Cores from which a loop thread at normal priority gets a job process too. On 2 cores such
#: a loop lost its CPU to the job process and measured worse with it; on 16 (real-time
#: scheduling refused) the job process took a K change's landscapes off the loop's
#: interpreter lock: changes followed by a period over 2 ms fell from 20 of 20 to 3 and 5
#: (docs/measurements/loop.md, "K changes on a machine with more cores"). Between the two
#: nothing was measured; 4 leaves the loop, the worker and the job process a core each.
CORES_WITHOUT_REALTIME = 4


def wanted(paced: bool, realtime_thread: bool, cores: int | None = None) -> bool:
    """Whether a loop's truncations and landscapes go to a job process (the default rule).

    A paced loop whose thread runs real-time, or one at normal priority on a machine of
    :data:`CORES_WITHOUT_REALTIME` cores or more; never an unpaced (headless) one.
    """
    cores = cpu_cores() if cores is None else cores
    return bool(paced and (realtime_thread or cores >= CORES_WITHOUT_REALTIME))


#: Buffers start at multiples of this many bytes in a transfer file (aligned arrays).
ALIGN = 64
#: How often (seconds) a caller waiting for a reply looks at its cancel callback.
POLL = 0.02
#: Tables the child keeps per pair (the K values asked for last).
TABLES_KEPT = 4
#: Free bytes ``/dev/shm`` must have to hold the transfer files.
SHM_FREE = 2 << 30
#: Seconds :meth:`JobProcess.close` waits for the child before killing it. Its work is
#: disposable once closed (nothing waits for a reply, the folder goes); a child still
#: importing its modules reads "stop" only when they are in, a second or more after it
#: was started, and an engine that waited for that ended as late (a Ctrl+C'd parent).
CLOSE_WAIT = 0.2


#: The child's niceness: below the loop's process, so that a transform never keeps the loop
#: waiting for a CPU. (In the loop's own process a lower priority made things worse: a
#: thread waiting for a CPU there held the interpreter lock. A process of its own holds
#: nothing the loop needs.)
JOB_NICE = 10

#: The child's program: :func:`main` with the socket's descriptor and the folder.
_CHILD = "import sys; from engine.runtime.job_process import main; main(sys.argv[1:])"


class JobProcessGone(RuntimeError):
    """The job process could not be started, or has ended."""


# ---------------------------------------------------------------------------------------------
# arrays through files


def transfer_folder() -> str:
    """A new private folder for transfer files.

    In ``/dev/shm`` where there is one with :data:`SHM_FREE` bytes free (containers often
    give it 64 MiB), else in the system's temporary folder.
    """
    base = None
    with contextlib.suppress(OSError):
        if os.access("/dev/shm", os.W_OK) and shutil.disk_usage("/dev/shm").free >= SHM_FREE:
            base = "/dev/shm"
    return tempfile.mkdtemp(prefix="skelasm-jobs-", dir=base)


def write_arrays(obj: object, path: str) -> tuple[bytes, list[tuple[int, int]]]:
    """Pickle ``obj`` with its contiguous arrays written to ``path``.

    Returns the pickle's head and where each buffer lies in the file, ``(offset, bytes)``;
    no file is written when there is no buffer. The writes release the interpreter lock.
    """
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    layout: list[tuple[int, int]] = []
    raws = []
    offset = 0
    for b in buffers:
        raw = b.raw()
        layout.append((offset, raw.nbytes))
        raws.append(raw)
        offset += -(-raw.nbytes // ALIGN) * ALIGN
    if layout:
        with open(path, "wb") as f:
            for (start, _), raw in zip(layout, raws, strict=True):
                f.seek(start)
                f.write(raw)
    return head, layout


def read_arrays(path: str, head: bytes, layout: list[tuple[int, int]]) -> object:
    """The object :func:`write_arrays` wrote; ``path`` is read and unlinked.

    The file is read into one new array with a single ``readinto`` (the lock released, the
    new pages touched by the kernel in this thread), and the object's arrays are views of
    it: writable, aligned C arrays. (Mapping the file instead was measured slower for the
    loop: docs/runtime.md.)
    """
    if not layout:
        return pickle.loads(head)
    with open(path, "rb", buffering=0) as f:
        size = os.fstat(f.fileno()).st_size
        block = np.empty(size, dtype=np.uint8)
        view = block.data
        done = 0
        while done < size:
            n = f.readinto(view[done:])
            if not n:
                raise EOFError(f"{path} ended after {done} of {size} bytes")
            done += n
    os.unlink(path)
    return pickle.loads(head, buffers=[view[start:start + n] for start, n in layout])


def _picklable(exc: BaseException) -> BaseException:
    """``exc`` if it survives pickling, else a RuntimeError with its message."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


# ---------------------------------------------------------------------------------------------
# parent side


@dataclass
class _Call:
    progress: Callable[[float], None] | None
    done: threading.Event = field(default_factory=threading.Event)
    reply: tuple[object, ...] = ()


class JobProcess:
    """The child process and the calls to it (any thread; calls block until answered).

    Parameters
    ----------
    command : list of str, optional
        The child's command line (tests); default: this interpreter running this module.
    """

    def __init__(self, command: list[str] | None = None) -> None:
        self.folder = transfer_folder()
        self._ids = itertools.count(1)
        self._pairs = itertools.count(1)
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._waiting: dict[int, _Call] = {}
        #: Why the child is not serving (None while it is).
        self.problem: str | None = None
        parent, child = socket.socketpair()
        try:
            argv = (command or [sys.executable, "-c", _CHILD]) + [
                str(child.fileno()), self.folder]
            self._proc: subprocess.Popen[bytes] | None = subprocess.Popen(
                argv, pass_fds=(child.fileno(),), stdin=subprocess.DEVNULL,
                start_new_session=True)
        except OSError as exc:
            parent.close()
            self._proc = None
            self.problem = f"the job process could not be started: {exc}"
        finally:
            child.close()
        self._conn = Connection(parent.detach()) if self._proc is not None else None
        self._reader = threading.Thread(target=self._read, name="skelasm-job-replies",
                                        daemon=True)
        if self._conn is not None:
            self._reader.start()

    @property
    def pid(self) -> int | None:
        """The child's process id (None: not started)."""
        return None if self._proc is None else self._proc.pid

    @property
    def alive(self) -> bool:
        """True while the child serves."""
        return self.problem is None

    # -- the channel ------------------------------------------------------------------------
    def _send(self, message: tuple[object, ...]) -> None:
        if self.problem is not None or self._conn is None:
            raise JobProcessGone(self.problem or "the job process is closed")
        try:
            with self._send_lock:
                self._conn.send(message)
        except (OSError, ValueError) as exc:
            self._lost(f"the job process ended ({exc})")
            raise JobProcessGone(self.problem) from exc

    def _read(self) -> None:
        assert self._conn is not None
        while True:
            try:
                message = self._conn.recv()
            except (EOFError, OSError):
                self._lost("the job process ended")
                return
            kind, rid = message[0], int(message[1])
            with self._lock:
                call = self._waiting.get(rid)
                if kind != "progress":
                    self._waiting.pop(rid, None)
            if kind == "progress":
                if call is not None and call.progress is not None:
                    call.progress(float(message[2]))
                continue
            if call is None:  # abandoned (cancelled): drop its file
                if kind == "ok" and message[4]:
                    with contextlib.suppress(OSError):
                        os.unlink(str(message[2]))
                continue
            call.reply = tuple(message)
            call.done.set()

    def _lost(self, why: str) -> None:
        with self._lock:
            if self.problem is None:
                self.problem = why
            waiting, self._waiting = self._waiting, {}
        for call in waiting.values():
            call.reply = ("gone", 0)
            call.done.set()

    def call(self, op: str, *args: object, progress: Callable[[float], None] | None = None,
             cancel: Callable[[], bool] | None = None) -> object:
        """Run ``op`` in the child and return its result (blocks; any thread).

        Raises
        ------
        Cancelled
            ``cancel()`` turned True first (the child is told to stop).
        JobProcessGone
            The child is not serving.
        Exception
            What the child's computation raised.
        """
        if cancel is not None and cancel():
            raise Cancelled("superseded")
        rid = next(self._ids)
        pending = _Call(progress)
        with self._lock:
            self._waiting[rid] = pending
        try:
            self._send((op, rid, *args))
        except JobProcessGone:
            with self._lock:
                self._waiting.pop(rid, None)
            raise
        while not pending.done.wait(POLL):
            if cancel is not None and cancel():
                with self._lock:
                    self._waiting.pop(rid, None)
                with contextlib.suppress(JobProcessGone):
                    self._send(("cancel", rid))
                raise Cancelled("superseded")
        reply = pending.reply
        if reply[0] == "ok" and cancel is not None and cancel():  # too late to stop it
            if reply[4]:
                with contextlib.suppress(OSError):
                    os.unlink(str(reply[2]))
            raise Cancelled("superseded")
        if reply[0] == "ok":
            path, head, layout = reply[2:5]
            assert isinstance(path, str) and isinstance(head, bytes)
            assert isinstance(layout, list)
            return read_arrays(path, head, layout)
        if reply[0] == "cancelled":
            raise Cancelled("superseded")
        if reply[0] == "error" and isinstance(reply[2], BaseException):
            raise reply[2]
        raise JobProcessGone(self.problem or "the job process ended")

    # -- pairs ------------------------------------------------------------------------------
    def spectral(self, spectra: Spectra) -> RemoteSpectral:
        """Send ``spectra`` to the child; what computes from them there.

        Raises JobProcessGone when the child is not serving.
        """
        pair = next(self._pairs)
        path = os.path.join(self.folder, f"pair{pair}")
        head, layout = write_arrays(spectra, path)
        try:
            self.call("register", pair, path, head, layout)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(path)
            raise
        return RemoteSpectral(self, spectra, pair)

    def forget(self, pair: int) -> None:
        """The child drops ``pair``'s spectra and tables (nothing if it is gone)."""
        with contextlib.suppress(JobProcessGone):
            self._send(("forget", 0, pair))

    def close(self) -> None:
        """Stop the child (killed after :data:`CLOSE_WAIT` seconds) and remove the folder."""
        if self._conn is not None:
            with contextlib.suppress(JobProcessGone):
                self._send(("stop", 0))
            self._lost("the job process is closed")
            with contextlib.suppress(OSError):
                self._conn.close()
        if self._proc is not None:
            try:
                self._proc.wait(CLOSE_WAIT)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        shutil.rmtree(self.folder, ignore_errors=True)


class RemoteSpectral:
    """A pair's truncations and landscapes done by a :class:`JobProcess` (a ``SpectralWork``).

    Where the child is not serving, each call computes here instead, with the same function
    on the same spectra (counted in :attr:`here`).
    """

    def __init__(self, jobs: JobProcess, spectra: Spectra, pair: int):
        from engine.correlation import LocalSpectral

        self.jobs = jobs
        self.local = LocalSpectral(spectra)  # where the child is gone
        self.pair = pair
        self.here = 0  # calls computed in this process because the child was gone
        weakref.finalize(self, jobs.forget, pair)

    def _here(self) -> None:
        if not self.here:
            _log.warning("truncations and landscapes run in the loop's process: %s",
                         self.jobs.problem or "the job process could not pass them back")
        self.here += 1

    def truncate(self, modes: int) -> ModeTable:
        """The table keeping ``modes`` per axis, from the child."""
        try:
            return self.jobs.call("truncate", self.pair, int(modes))  # type: ignore[return-value]
        except (JobProcessGone, OSError):  # no child, or no room for the transfer files
            self._here()
            return self.local.truncate(modes)

    def landscape(self, rotation: np.ndarray, modes: int, *, forces: bool,
                  table: ModeTable | None, progress: Callable[[float], None] | None,
                  cancel: Callable[[], bool] | None) -> Landscape:
        """The landscape at ``rotation``, from the child (progress and cancel pass through)."""
        rot = np.array(rotation, dtype=np.float64)
        try:
            return self.jobs.call(  # type: ignore[return-value]
                "landscape", self.pair, rot, int(modes), bool(forces),
                progress=progress, cancel=cancel)
        except (JobProcessGone, OSError):  # no child, or no room for the transfer files
            self._here()
            return self.local.landscape(rot, modes, forces=forces, table=table,
                                        progress=progress, cancel=cancel)


# ---------------------------------------------------------------------------------------------
# child side


class _Pair:
    """One pair's spectra and the tables last asked for."""

    def __init__(self, spectra: Spectra):
        self.spectra = spectra
        self.tables: dict[int, ModeTable] = {}
        self.lock = threading.Lock()

    def table(self, modes: int) -> ModeTable:
        from engine.correlation.tables import truncate

        with self.lock:
            table = self.tables.pop(modes, None)
            if table is None:
                table = truncate(self.spectra, modes)
            self.tables[modes] = table  # newest last
            while len(self.tables) > TABLES_KEPT:
                self.tables.pop(next(iter(self.tables)))
            return table


def _truncation(entry: _Pair, modes: int) -> Callable[[Callable[[], bool]], object]:
    return lambda cancelled: entry.table(modes)


def _landscape(entry: _Pair, rotation: np.ndarray, modes: int, forces: bool,
               progress: Callable[[float], None]) -> Callable[[Callable[[], bool]], object]:
    from engine.correlation.landscape import compute_landscape

    def compute(cancelled: Callable[[], bool]) -> object:
        return compute_landscape(entry.spectra, rotation, modes, forces=forces,
                                 table=entry.tables.get(modes), progress=progress,
                                 cancel=cancelled)

    return compute


def _serve(conn: Connection, folder: str) -> None:
    """Answer requests until end-of-file or "stop"."""
    pairs: dict[int, _Pair] = {}
    cancelled: set[int] = set()
    send_lock = threading.Lock()
    pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="skelasm-job")

    def reply(message: tuple[object, ...]) -> None:
        with send_lock:
            conn.send(message)

    def run(rid: int, compute: Callable[[Callable[[], bool]], object]) -> None:
        try:
            with spare_cores(1):  # the loop's process steps on the core left
                result = compute(lambda: rid in cancelled)
            path = os.path.join(folder, f"reply{rid}")
            head, layout = write_arrays(result, path)
        except Cancelled:
            reply(("cancelled", rid))
        except BaseException as exc:  # delivered to the caller, never lost here
            reply(("error", rid, _picklable(exc)))
        else:
            reply(("ok", rid, path, head, layout))
        finally:
            cancelled.discard(rid)

    def progress(rid: int) -> Callable[[float], None]:
        return lambda fraction: reply(("progress", rid, float(fraction)))

    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return
        op, rid = str(message[0]), int(message[1])
        if op == "stop":
            return
        if op == "cancel":
            cancelled.add(rid)
        elif op == "forget":
            pairs.pop(int(message[2]), None)
        elif op == "register":
            pair, path, head, layout = message[2:6]
            try:
                pairs[int(pair)] = _Pair(read_arrays(path, head, layout))  # type: ignore[arg-type]
            except BaseException as exc:
                reply(("error", rid, _picklable(exc)))
            else:
                reply(("ok", rid, "", pickle.dumps(None), []))
        elif int(message[2]) not in pairs:
            reply(("error", rid, KeyError(f"no pair {message[2]} in the job process")))
        else:
            entry = pairs[int(message[2])]
            if op == "truncate":
                pool.submit(run, rid, _truncation(entry, int(message[3])))
            elif op == "landscape":
                rot, k, forces = np.asarray(message[3]), int(message[4]), bool(message[5])
                pool.submit(run, rid, _landscape(entry, rot, k, forces, progress(rid)))
            else:
                reply(("error", rid, ValueError(f"unknown job {op!r}")))


def main(argv: list[str]) -> int:
    """The child: serve on the socket whose descriptor is ``argv[0]``; files in ``argv[1]``."""
    fd, folder = int(argv[0]), argv[1]
    with contextlib.suppress(OSError):
        os.nice(JOB_NICE)
    conn = Connection(fd)
    try:
        _serve(conn, folder)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
        # worker threads may be mid-computation for a parent that is gone: end now
        os._exit(0)

