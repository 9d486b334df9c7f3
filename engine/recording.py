"""Record and replay a session.

Per step, a recording holds the input (proxy) trajectory, the part's pose and the forces.

Data: one row per step, float64 columns :data:`COLUMNS`: ``t`` (simulated seconds at
the start of the step), the proxy pose used by the step (``tx..rz``: the columns a
trajectory CSV needs, so a recording is itself a trajectory), the part's pose after the
step (``part_*``), energy, geometric force and torque, haptic force and torque.

Files: ``.csv`` (header line, numbers written with 17 significant digits so that replay
is bit-exact) or ``.npz`` (``columns`` and ``rows`` arrays). A recording may name the scene
it was made with: a last header field ``scene=<16 hex digits>`` in a CSV (trajectory
readers ignore columns they do not know), a ``scene`` array in an ``.npz``.

Recording: ``engine.runtime.Recorder`` takes these columns from the loop's frame rows into
memory; :class:`RecordingWriter` streams them to the file as they come (memory bounded
whatever the length, and an interrupted run keeps every step recorded so far).
Replay: :func:`replay_device` turns a recording into a
:class:`engine.devices.TrajectoryDevice`; stepping the same scene with it at the same
rate feeds the exact recorded proxy pose to every step and so reproduces the motion.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import zipfile
from pathlib import Path
from types import TracebackType

import numpy as np

from engine.devices import TrajectoryDevice
from engine.errors import InputError
from engine.files import (
    MAX_TRAJECTORY_BYTES,
    atomic_write,
    decode_text,
    input_problem,
    make_temporary,
    move_into_place,
    read_input,
    write_error,
)

COLUMNS = (
    "t", "tx", "ty", "tz", "rx", "ry", "rz",
    "part_tx", "part_ty", "part_tz", "part_rx", "part_ry", "part_rz",
    "energy", "fx", "fy", "fz", "mx", "my", "mz",
    "haptic_fx", "haptic_fy", "haptic_fz", "haptic_mx", "haptic_my", "haptic_mz",
)
#: Bytes a CSV row takes at most: 26 numbers of up to 24 characters, commas, newline.
CSV_ROW_BYTES = len(COLUMNS) * 25
#: Bytes an ``.npz`` row takes (float64, uncompressed while recording).
NPZ_ROW_BYTES = len(COLUMNS) * 8
#: Rows kept in memory between writes to the file (about 50 KB).
FLUSH_ROWS = 256

_SCENE_FIELD = re.compile(r"^scene=([0-9a-f]{16})$")


def _header(scene: str | None) -> str:
    fields = list(COLUMNS) + ([f"scene={scene}"] if scene else [])
    return ",".join(fields)


def _check_scene(scene: str | None) -> None:
    if scene is not None and not re.fullmatch(r"[0-9a-f]{16}", scene):
        raise ValueError(f"scene must be 16 hex digits, got {scene!r}")


def save_recording(path: str | Path, rows: np.ndarray, *, scene: str | None = None) -> Path:
    """Write rows (n, 26) to ``.csv`` or ``.npz`` (by suffix), whole or not at all.

    ``scene`` (16 hex digits, e.g. a digest of the scene's files) is stored with the rows
    so that a replay can tell a recording of another scene. The file is replaced
    atomically: check the path (``engine.files.check_output``) before the work.
    """
    path = Path(path)
    _check_scene(scene)
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(COLUMNS))
    if path.suffix.lower() == ".npz":
        extra = {"scene": np.array(scene)} if scene else {}
        with atomic_write(path, what="recording") as fh:
            np.savez_compressed(fh, columns=np.array(COLUMNS), rows=rows,
                                **extra)  # type: ignore[arg-type]  # numpy's stub: **kwds bool
    else:
        with atomic_write(path, "w", what="recording", encoding="utf-8") as fh:
            np.savetxt(fh, rows, delimiter=",", header=_header(scene), comments="",
                       fmt="%.17g")
    return path


class RecordingWriter:
    """Streams recording rows to a file as they come; the file appears when it is closed.

    Rows go to a temporary file next to the target, flushed every :data:`FLUSH_ROWS`
    rows, so memory stays bounded whatever the run's length. :meth:`close` (also on
    leaving a ``with`` block, an exception or Ctrl+C included) renames it into place:
    an interrupted run keeps every row recorded. :meth:`discard` drops it.

    Parameters
    ----------
    path : path-like
        ``.csv`` or ``.npz`` (by suffix). Check it (``engine.files.check_output``) first:
        it is replaced on close.
    index : (26,) int array, optional
        Columns to take from each row given to :meth:`on_frame` (the loop's frame rows,
        ``engine.runtime.frames.RECORDING_INDEX``); None: rows are recording rows.
    scene : str, optional
        16 hex digits naming the scene (see :func:`save_recording`).
    """

    def __init__(self, path: str | os.PathLike, *, index: np.ndarray | None = None,
                 scene: str | None = None) -> None:  # fmt: skip
        _check_scene(scene)
        self.path = Path(path)
        self.scene = scene
        self.count = 0
        self._index = None if index is None else np.asarray(index, dtype=np.intp)
        self._npz = self.path.suffix.lower() == ".npz"
        self._buffer = np.empty((FLUSH_ROWS, len(COLUMNS)), dtype=np.float64)
        self._filled = 0
        self._closed = False
        try:
            fd, self._tmp = make_temporary(self.path)
        except OSError as exc:
            raise write_error(self.path, exc, what="recording") from exc
        # unbuffered: every write is one whole chunk of rows, and ``_good`` counts the bytes
        # of the chunks written whole, so a signal that stops a write leaves no torn row
        self._fh = os.fdopen(fd, "wb", buffering=0)
        self._good = 0
        if not self._npz:
            self._write((_header(scene) + "\n").encode())

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        try:
            while view:
                done = self._fh.write(view)
                view = view[done or 0:]
        except OSError as exc:
            self.discard()
            raise write_error(self.path, exc, what="recording") from exc
        finally:
            if view and not self._closed:  # stopped part-way by a signal: back to whole rows
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fh.fileno(), self._good)
                    os.lseek(self._fh.fileno(), self._good, os.SEEK_SET)
        self._good += len(data)

    def on_frame(self, row: np.ndarray) -> None:
        """Record one row (a frame row when ``index`` was given, else a recording row)."""
        self._add(row if self._index is None else row[self._index])

    def append(self, rows: np.ndarray) -> None:
        """Record recording rows (n, 26) (``index`` does not apply)."""
        for row in np.asarray(rows, dtype=np.float64).reshape(-1, len(COLUMNS)):
            self._add(row)

    def _add(self, values: np.ndarray) -> None:
        if self._closed:
            raise ValueError(f"{self.path}: the recording is closed")
        self._buffer[self._filled] = values
        self._filled += 1
        self.count += 1
        if self._filled == FLUSH_ROWS:
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows to the temporary file."""
        if self._filled == 0 or self._closed:
            return
        rows = self._buffer[: self._filled]
        if self._npz:
            chunk = rows.tobytes()
        else:
            text = io.BytesIO()
            np.savetxt(text, rows, delimiter=",", fmt="%.17g")
            chunk = text.getvalue()
        self._write(chunk)  # the rows stay buffered until they are written whole
        self._filled = 0

    def close(self) -> Path:
        """Write what is buffered, fsync, and rename the file into place; return its path."""
        if self._closed:
            return self.path
        self.flush()
        try:
            self._fh.flush()
            os.fsync(self._fh.fileno())
            self._fh.close()
            if self._npz:
                self._finish_npz()
            else:
                move_into_place(self._tmp, self.path)
        except OSError as exc:
            self.discard()
            raise write_error(self.path, exc, what="recording") from exc
        self._closed = True
        return self.path

    def _finish_npz(self) -> None:
        """The raw float64 rows, streamed into the ``.npz`` (numpy writes it in chunks)."""
        try:
            rows: np.ndarray
            if self.count:
                rows = np.memmap(self._tmp, dtype=np.float64, mode="r",
                                 shape=(self.count, len(COLUMNS)))
            else:
                rows = np.zeros((0, len(COLUMNS)))
            extra = {"scene": np.array(self.scene)} if self.scene else {}
            with atomic_write(self.path, what="recording") as fh:
                np.savez_compressed(fh, columns=np.array(COLUMNS), rows=rows,
                                    **extra)  # type: ignore[arg-type]  # numpy's stub: bool
            del rows
        finally:
            with contextlib.suppress(OSError):
                os.unlink(self._tmp)

    def discard(self) -> None:
        """Drop the temporary file; the target is left as it was."""
        self._closed = True
        with contextlib.suppress(OSError):
            self._fh.close()
        with contextlib.suppress(OSError):
            os.unlink(self._tmp)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.close()


def recording_scene(path: str | Path) -> str | None:
    """The scene tag a recording was made with, or None (a plain trajectory, an old file)."""
    path = Path(path)
    if input_problem(path, what="recording", limit=MAX_TRAJECTORY_BYTES):
        return None
    try:
        if path.suffix.lower() == ".npz":
            with open(path, "rb") as raw, np.load(raw, allow_pickle=False) as data:
                return str(data["scene"]) if "scene" in data.files else None
        with open(path, encoding="utf-8-sig", errors="replace") as text:
            last = text.readline(1 << 16).rstrip("\r\n").split(",")[-1].strip()
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
        return None
    m = _SCENE_FIELD.match(last)
    return m.group(1) if m else None


def load_recording(path: str | Path) -> np.ndarray:
    """(n, 26) float64 rows of a recording (``.csv`` or ``.npz``)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npz":
            problem = input_problem(path, what="recording", limit=MAX_TRAJECTORY_BYTES)
            if problem:
                raise InputError(problem)
            with open(path, "rb") as raw, np.load(raw, allow_pickle=False) as data:
                columns = tuple(str(c) for c in data["columns"])
                rows = data["rows"]
        else:
            raw_text = read_input(path, what="recording", limit=MAX_TRAJECTORY_BYTES)
            # -sig: a byte-order mark is no column
            with io.StringIO(decode_text(raw_text, path, what="recording")) as text:
                del raw_text
                columns = tuple(c.strip() for c in text.readline().split(","))
                if columns and _SCENE_FIELD.match(columns[-1]):
                    columns = columns[:-1]
                rows = np.loadtxt(text, delimiter=",", ndmin=2)
    except InputError:
        raise
    except OSError as exc:
        raise InputError(f"{path}: cannot read the recording ({exc})") from exc
    except (ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a skelasm recording ({exc})") from exc
    if columns != COLUMNS:
        raise InputError(f"{path}: unexpected columns; a recording has {','.join(COLUMNS)}")
    rows = np.asarray(rows, dtype=np.float64)
    if rows.size == 0:
        rows = rows.reshape(0, len(COLUMNS))
    if rows.ndim != 2 or rows.shape[1] != len(COLUMNS):
        raise InputError(f"{path}: rows have {rows.shape[-1]} values; a recording has "
                         f"{len(COLUMNS)} per row")
    return rows


def replay_device(path_or_rows: str | Path | np.ndarray) -> TrajectoryDevice:
    """A trajectory device that feeds the recorded proxy poses back, step by step."""
    rows = (
        load_recording(path_or_rows)
        if isinstance(path_or_rows, (str, Path))
        else np.asarray(path_or_rows, float)
    )
    return TrajectoryDevice(rows[:, :7])
