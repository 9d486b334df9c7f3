"""Writing output files safely: checked before the work, written whole or not at all.

Data: paths of output files (descriptors, recordings, reports, images, cache entries) and
of the input files they must never replace.

- :func:`check_output` runs before any work: the folder exists and takes new files, the
  file is not one of the inputs (never, whatever ``force`` says), an existing file is
  replaced only with ``force`` and only when it is a writable regular file.
- :func:`atomic_write` writes to a hidden temporary file in the same folder, flushes and
  fsyncs it, then renames it over the target: a reader, a crash (``kill -9``) or a full disk
  sees the old file or the new one, never a part of one. Errors name the file.
- :func:`disk_space_error` estimates whether a file of a given size fits before writing it.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from engine.errors import InputError

#: Prefix and suffix of the temporary files :func:`atomic_write` leaves only when killed.
TEMP_PREFIX = ".skelasm-"
TEMP_SUFFIX = ".partial"


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (links and ``..`` resolved); False if either is absent."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # a loop of links (RuntimeError in Python 3.11)
        return False


def check_output(
    path: str | os.PathLike,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "output file",
) -> Path:
    """Check, before any work, that ``path`` can be written; return it as a Path.

    Parameters
    ----------
    path : path-like
        The file to be written.
    force : bool
        Replace an existing file (never an input file, never a folder or a read-only file).
    inputs : iterable of path-like
        The files the command reads (scene, parts, trajectory): none of them is ever
        replaced.
    what : str
        What the file is, for the messages (``"log"``, ``"descriptor"``, ...).

    Raises
    ------
    InputError
        The path is an input, a folder, an existing file without ``force``, a read-only
        file, or its folder is missing or does not take new files. The message names the
        path and the fix.
    """
    p = Path(path)
    for source in inputs:
        if _same_file(p, Path(source)):
            raise InputError(f"{p}: this is an input file of the command; the {what} would "
                             "replace it: choose another name")
    if p.is_dir():
        raise InputError(f"{p}: is a folder; give the {what} a file name")
    folder = p.parent
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder for the {what} {p.name}; create it first "
                         "or choose another path")
    if p.exists() or p.is_symlink():
        if not force:
            raise InputError(f"{p}: the file exists; add --force to replace it, or choose "
                             "another name")
        if not p.is_file():
            raise InputError(f"{p}: not a regular file; choose another path for the {what}")
        if not os.stat(p).st_mode & 0o222 or not os.access(p, os.W_OK):
            raise InputError(f"{p}: the file is read-only; make it writable or choose "
                             "another name")
    _check_folder_takes_files(folder, p, what)
    remove_stale_temporaries(p)
    return p


def check_output_folder(path: str | os.PathLike, *, create: bool = False,
                        what: str = "output folder") -> Path:  # fmt: skip
    """Check that ``path`` is a folder that takes new files (created if ``create``)."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(f"{p}: not a folder; give the {what} a folder's path")
    if not p.exists():
        if not create:
            raise InputError(f"{p}: no such folder; create it first or choose another")
        if not p.parent.is_dir():
            raise InputError(f"{p.parent}: no such folder for the {what} {p.name}; create it "
                             "first or choose another path")
        _check_folder_takes_files(p.parent, p, what)
        return p
    _check_folder_takes_files(p, p, what)
    return p


def _check_folder_takes_files(folder: Path, target: Path, what: str) -> None:
    """Create and remove a probe file in ``folder`` (permission bits lie to root and NFS)."""
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=TEMP_PREFIX, suffix=TEMP_SUFFIX)
    except OSError as exc:
        raise InputError(f"{folder}: cannot create files in this folder ({exc.strerror}); "
                         f"the {what} {target.name} needs another place") from None
    os.close(fd)
    os.unlink(probe)


def disk_space_error(path: str | os.PathLike, nbytes: int, *, what: str) -> str | None:
    """A message when ``nbytes`` will not fit in the free space of ``path``'s folder, else None."""
    p = Path(path)
    folder = p if p.is_dir() else p.parent
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return None
    if int(nbytes) <= free:
        return None
    return (f"{p}: the {what} needs about {human_size(nbytes)} but its folder has "
            f"{human_size(free)} free; free some space or choose another folder")


def human_size(nbytes: int | float) -> str:
    """``nbytes`` in bytes, KB, MB, GB or TB (powers of 1000)."""
    value = float(nbytes)
    for unit in ("bytes", "KB", "MB", "GB", "TB"):
        if value < 1000 or unit == "TB":
            return f"{value:.0f} {unit}" if unit == "bytes" else f"{value:.1f} {unit}"
        value /= 1000
    return f"{value:.1f} PB"  # pragma: no cover


def write_error(path: str | os.PathLike, exc: OSError, *, what: str = "file") -> OSError:
    """An OSError for a failed write whose message names the file, the problem and the fix."""
    p = Path(path)
    reason = exc.strerror or str(exc)
    fix = ("free some space or choose another folder" if exc.errno in (28, 122)
           else "check the folder's permissions and space, or choose another path")
    err = OSError(f"{p}: cannot write the {what} ({reason}); {fix}; any earlier file there "
                  "is unchanged")
    err.errno = exc.errno  # one-argument form: str(err) is the message alone
    return err


def _fsync_folder(folder: Path) -> None:
    """Make a rename durable (a no-op where folders cannot be opened, e.g. Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, mode: str = "wb", *, what: str = "file",
                 encoding: str | None = None) -> Iterator[IO[Any]]:  # fmt: skip
    """Write ``path`` through a temporary file in its folder, renamed into place on success.

    Yields the open temporary file (``mode`` ``"wb"`` or ``"w"``). When the block ends
    normally the file is flushed, fsynced and renamed over ``path`` (atomic on POSIX); when
    it raises, the temporary file is removed and ``path`` is left as it was. Check the path
    with :func:`check_output` first: this function replaces whatever is there.

    Raises
    ------
    OSError
        The write failed (full disk, permissions): the message names ``path``.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"mode must be 'wb' or 'w', got {mode!r}")
    p = Path(path)
    try:
        fd, tmp = make_temporary(p)
    except OSError as exc:
        raise write_error(p, exc, what=what) from exc
    try:
        try:
            fh = os.fdopen(fd, mode, encoding=encoding if mode == "w" else None)
        except BaseException:
            os.close(fd)
            raise
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        move_into_place(tmp, p)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise write_error(p, exc, what=what) from exc
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def make_temporary(path: Path) -> tuple[int, str]:
    """Create ``.skelasm-<name>.<pid>.<random>.partial`` beside ``path``: (fd, its path).

    The process id in the name lets a later run tell a temporary file whose writer was
    killed (``kill -9``, a power cut) from one still being written: see
    :func:`remove_stale_temporaries`.
    """
    return tempfile.mkstemp(dir=path.parent, prefix=f"{TEMP_PREFIX}{path.name}.{os.getpid()}.",
                            suffix=TEMP_SUFFIX)


def staged_path(path: str | os.PathLike) -> Path:
    """A hidden name beside ``path`` for a file moved into place once a whole set is done.

    Named like :func:`make_temporary`'s files (``.skelasm-<name>.<pid>.staged__.partial``),
    so :func:`remove_stale_temporaries` removes it when its process was killed.
    """
    p = Path(path)
    return p.parent / f"{TEMP_PREFIX}{p.name}.{os.getpid()}.staged__{TEMP_SUFFIX}"


def remove_stale_temporaries(path: str | os.PathLike) -> int:
    """Remove the temporary files of writes of ``path`` whose writing process is gone.

    Only names :func:`make_temporary` gives for this very file count, and only when the
    process id they carry no longer exists on this machine. Returns how many were removed.
    """
    p = Path(path)
    pattern = re.compile(re.escape(f"{TEMP_PREFIX}{p.name}.") + r"(\d+)\.[a-z0-9_]{8}"
                         + re.escape(TEMP_SUFFIX) + "$")
    removed = 0
    try:
        names = os.listdir(p.parent)
    except OSError:
        return 0
    for name in names:
        m = pattern.match(name)
        if not m or _alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            os.unlink(p.parent / name)
            removed += 1
    return removed


def _alive(pid: int) -> bool:
    """Whether a process with this id exists (one we may not signal counts as alive)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    return True


def move_into_place(tmp: str | os.PathLike, path: str | os.PathLike) -> None:
    """Rename a finished, fsynced temporary file over ``path`` and make the rename durable.

    The new file takes the permissions of the file it replaces, or the usual ones for a new
    file (0666 less the umask; temporary files are created 0600).
    """
    p = Path(path)
    if p.exists():  # keep the permissions the user gave the file being replaced
        with contextlib.suppress(OSError):
            shutil.copymode(p, tmp)
    else:
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, p)
    _fsync_folder(p.parent)


def _umask() -> int:
    """The process's umask, read without changing it (``os.umask`` would race other threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    return 0o022


def write_text(path: str | os.PathLike, text: str, *, what: str = "file") -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; return the path."""
    with atomic_write(path, "w", what=what, encoding="utf-8") as fh:
        fh.write(text)
    return Path(path)


def files_digest(paths: Iterable[str | os.PathLike], *, length: int = 16) -> str:
    """Hex SHA-256 (first ``length`` digits) of the files' bytes, in the order given.

    Names a set of inputs (a scene file and its parts) so that an output made from them
    (a recording) can be matched to them later.
    """
    h = hashlib.sha256()
    for path in paths:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        h.update(b"\0")
    return h.hexdigest()[:length]


# --------------------------------------------------------------------------- inputs
#: Largest input files read, in bytes. A scene is a page of TOML; a trajectory or replayed
#: log of 256 MiB is a million rows of a log (17 minutes at 1 kHz) and a minute of
#: parsing; a part file of 1 GiB is a binary STL of 20 million triangles, far past what a
#: descriptor resolves.
MAX_SCENE_BYTES = 16 * 2**20
MAX_TRAJECTORY_BYTES = 256 * 2**20
MAX_PART_BYTES = 2**30


def input_problem(path: str | os.PathLike, *, what: str, limit: int | None = None
                  ) -> str | None:  # fmt: skip
    """Why ``path`` cannot be read as a ``what`` (a message naming it and the fix), or None.

    Refused: a missing file or a link to one, a loop of symbolic links, a folder, a device,
    FIFO or socket (``/dev/zero`` never ends, a FIFO blocks), an unreadable file, and a
    file larger than ``limit`` bytes.
    """
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        if os.path.islink(p):
            return f"{p}: a symbolic link to a missing file; check where it points"
        return f"{p}: no such {what}; check the path"
    except NotADirectoryError:
        return f"{p}: no such {what} (a part of the path is a file, not a folder); check the path"
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            return (f"{p}: a loop of symbolic links (a link that leads back to itself); "
                    "point the link at the real file")
        return f"{p}: cannot read the {what} ({exc.strerror}); check the path and permissions"
    if stat.S_ISDIR(st.st_mode):
        return f"{p}: is a folder, not a {what}; give the file inside it"
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else
                "a socket" if stat.S_ISSOCK(st.st_mode) else "a device")
        return (f"{p}: is {kind}, not a regular file; a {what} is read from a file: save "
                "it to one first")
    if limit is not None and st.st_size > limit:
        return (f"{p}: the {what} is {human_size(st.st_size)}, more than the "
                f"{human_size(limit)} a {what} may be; check that this is the right file")
    if not os.access(p, os.R_OK):
        return f"{p}: cannot read the {what} (permission denied); check its permissions"
    return None


def read_input(path: str | os.PathLike, *, what: str, limit: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them.

    The file is opened without blocking (a FIFO put in its place between the check and the
    open is refused, not waited on) and read up to ``limit`` + 1 bytes, so a file that
    grows past the limit while it is read is refused too.

    Raises
    ------
    InputError
        See :func:`input_problem`; the message names the file, the problem and the fix.
    """
    problem = input_problem(path, what=what, limit=limit)
    if problem:
        raise InputError(problem)
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise InputError(f"{p}: cannot read the {what} ({exc.strerror}); check the path and "
                         "permissions") from None
    with os.fdopen(fd, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            raise InputError(f"{p}: not a regular file; a {what} is read from a file")
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise InputError(f"{p}: the {what} is more than the {human_size(limit)} a {what} may "
                         "be; check that this is the right file")
    return data


def decode_text(data: bytes, path: str | os.PathLike, *, what: str) -> str:
    """UTF-8 text of an input (a byte-order mark dropped); InputError naming the file if not."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise InputError(f"{path}:{line}: the {what} is not UTF-8 text (byte "
                         f"{data[exc.start]:#04x} at offset {exc.start}); is it the right "
                         "file? save it as UTF-8 text") from None
