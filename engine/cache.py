"""On-disk cache of computed arrays (descriptors, spectra), keyed by content.

Entries are ``.npz`` files named by the SHA-256 of everything that determines them:
the mesh bytes, the grid, the parameters, a format version and a digest of the code that
computes them (:func:`code_digest`). The cache lives in ``SKELASM_CACHE`` or
``~/.cache/skelasm`` and is kept under ``SKELASM_CACHE_MAX_GB`` (default 2 GiB) by deleting
entries after each store: those cheapest to compute again per byte first (each entry
records how long it took), the least recently used first among equals.

Layout: ``<cache>/<kind>/<64 hex digits>.npz`` plus a ``CACHEDIR.TAG``; only files of that
layout are entries (:func:`entries`), so eviction never touches anything else in the
folder. Entries are written whole (temporary file, fsync, rename), entries that cannot be
read are deleted and recomputed, results with non-finite values and entries larger than the
cap are never stored, and a cache that cannot be written (read-only, another user's) is
read as usual and skipped for writing with one warning. Warnings go to the
``engine.cache`` logger.
"""

from __future__ import annotations

import ast
import contextlib
import hashlib
import json
import logging
import math
import os
import re
import time
import zipfile
import zlib
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from engine.files import (
    atomic_write,
    disk_space_error,
    human_size,
    write_text,
)

#: The folder holding the ``engine`` package (module names are resolved under it).
SOURCE_ROOT = Path(__file__).resolve().parent.parent


def _module_file(name: str, root: Path) -> Path | None:
    """The source file of module ``name`` under ``root`` (a package: its ``__init__.py``)."""
    base = root.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def _engine_imports(path: Path, name: str, root: Path) -> set[str]:
    """Modules of the ``engine`` package that ``path`` (module ``name``) imports.

    Every import counts, in a function or not. ``from a import b`` names ``a.b`` when that
    is a module, else ``a``; a name that has no file is returned all the same, so that the
    caller reports it rather than skipping it.
    """
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if _module_file(sub, root) is not None else base)
    return {m for m in found if m == "engine" or m.startswith("engine.")}


def code_files(module: str, *, root: Path | None = None) -> list[Path]:
    """The source files whose code shapes what ``module`` computes, sorted.

    Every ``.py`` file in the folder of ``module``'s package (whatever their names, new
    files included) and, transitively, every module of the ``engine`` package that
    ``module`` imports (in functions too), wherever it lives.

    Parameters
    ----------
    module : str
        Dotted name, e.g. ``"engine.descriptor.compute"``.
    root : Path, optional
        The folder holding the ``engine`` package (default: this installation's).

    Raises
    ------
    FileNotFoundError
        ``module`` or a module it imports has no source file under ``root``: a digest that
        silently skipped it could serve results of code that has changed.
    """
    root = SOURCE_ROOT if root is None else Path(root)
    start = _module_file(module, root)
    if start is None:
        raise FileNotFoundError(f"no source file for {module} under {root}: the cache's code "
                                "digest cannot cover it")  # fmt: skip
    files = set(start.parent.rglob("*.py"))
    todo = [module]
    seen: set[str] = set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        path = _module_file(name, root)
        if path is None:
            raise FileNotFoundError(f"no source file for {name} (imported by the code of "
                                    f"{module}) under {root}")  # fmt: skip
        files.add(path)
        todo.extend(_engine_imports(path, name, root) - seen)
    return sorted(files, key=lambda p: p.relative_to(root).as_posix())


def code_digest(module: str, *, root: Path | None = None) -> str:
    """SHA-256 of :func:`code_files` of ``module``: paths relative to ``root`` and bytes.

    A copy of the tree elsewhere has the same digest; any change to one of the files, a
    file added to or removed from the package folder, changes it.
    """
    root = SOURCE_ROOT if root is None else Path(root)
    h = hashlib.sha256()
    for path in code_files(module, root=root):
        h.update(path.relative_to(root).as_posix().encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def cache_dir() -> Path:
    """The cache folder (created on first store)."""
    root = os.environ.get("SKELASM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "skelasm"
    )
    return Path(root)


#: Default cap on the cache's size, in GiB (spectra of a 160^3 FFT are ~60 MB each).
DEFAULT_MAX_GB = 2.0
#: The member of an entry's ``.npz`` that records how long its computation took (seconds);
#: eviction reads it, :func:`load` never returns it.
SECONDS_MEMBER = "__compute_seconds__"
#: Below this a computation's measured time is the scheduler's and the collector's, not its
#: own: such entries are all alike to eviction, whatever the timer read.
TIMING_FLOOR_SECONDS = 0.05
#: What reading an entry that is not a whole ``.npz`` raises (truncated, a flipped bit).
_UNREADABLE = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)
#: An entry's file name: the 64 hex digits of its key. Nothing else is ever evicted.
ENTRY_NAME = re.compile(r"^[0-9a-f]{64}\.npz$")
#: An entry kind, the sub-folder it lives in (``descriptor``, ``spectrum``, ...).
KIND_NAME = re.compile(r"^[a-z][a-z0-9-]{0,63}$")
#: Marks the folder as a cache for backup tools (https://bford.info/cachedir/).
TAG_NAME = "CACHEDIR.TAG"
_TAG = ("Signature: 8a477f597d28d172789f06886806bc55\n"
        "# This file is a cache tag created by skelasm; its entries can be recomputed.\n")
#: Largest cap taken as given (a zettabyte); a larger ``SKELASM_CACHE_MAX_GB`` is this.
MAX_CAP_GB = 2.0**40
#: The cache's own temporary files: ``.skelasm-<entry>.<random>.partial`` as
#: :func:`engine.files.atomic_write` names them for an entry, and older versions' ``tmp``
#: files. Nothing else is removed, however it is named.
TEMP_NAME = re.compile(r"^(\.skelasm-[0-9a-f]{64}\.npz\.(\d+\.)?[a-z0-9_]+\.partial"
                       r"|tmp[a-z0-9_]{8}\.tmp\.npz)$")
#: Temporary files of interrupted writes older than this (seconds) are removed on eviction.
STALE_SECONDS = 3600.0

_log = logging.getLogger(__name__)
_warned: set[tuple[str, str]] = set()


def _warn_once(folder: Path, what: str, message: str) -> None:
    """Log ``message`` once per process for this folder and kind of problem."""
    token = (str(folder), what)
    if token not in _warned:
        _warned.add(token)
        _log.warning(message)


def max_bytes() -> int:
    """The cache's size cap from ``SKELASM_CACHE_MAX_GB`` (default 2 GiB)."""
    raw = os.environ.get("SKELASM_CACHE_MAX_GB")
    try:
        gb = float(raw) if raw else DEFAULT_MAX_GB
    except ValueError as exc:
        raise ValueError(f"SKELASM_CACHE_MAX_GB must be a number of GiB, got {raw!r}") from exc
    if not (math.isfinite(gb) and gb >= 0):
        raise ValueError(f"SKELASM_CACHE_MAX_GB must be zero (no cache) or a positive number "
                         f"of GiB, got {raw!r}")
    # a cap past what any disk holds is no cap: 1e300 GiB is no integer number of bytes
    return int(min(gb, MAX_CAP_GB) * 2**30)


def entry_path(kind: str, key: str) -> Path:
    """Where the entry ``key`` of ``kind`` lives: ``<cache>/<kind>/<key>.npz``."""
    if not KIND_NAME.match(kind):
        raise ValueError(f"cache kind must match {KIND_NAME.pattern}, got {kind!r}")
    name = f"{key}.npz"
    if not ENTRY_NAME.match(name):
        raise ValueError(f"cache key must be 64 hex digits, got {key!r}")
    return cache_dir() / kind / name


def entries() -> list[Path]:
    """Every entry the cache wrote: ``<kind>/<64 hex digits>.npz`` files, no links.

    Other files under the cache folder (a user's own results, if it points at a project
    folder) are never listed, so never evicted.
    """
    found: list[Path] = []
    for folder in _kind_folders(cache_dir()):
        try:
            found.extend(f for f in folder.iterdir() if ENTRY_NAME.match(f.name)
                         and not f.is_symlink() and f.is_file())  # fmt: skip
        except OSError:
            continue
    return found


def _stale_temporaries(now: float) -> list[Path]:
    """Temporary files of the cache's own interrupted writes, older than STALE_SECONDS.

    Its own: ``.skelasm-<entry>.<random>.partial`` (and ``tmp*.tmp.npz`` of older versions)
    in a kind folder.
    """
    out = []
    for folder in _kind_folders(cache_dir()):
        try:
            for f in folder.iterdir():
                ours = TEMP_NAME.match(f.name) is not None
                if ours and not f.is_symlink() and now - f.stat().st_mtime > STALE_SECONDS:
                    out.append(f)
        except OSError:
            continue
    return out


def _kind_folders(root: Path) -> set[Path]:
    """The kind sub-folders of ``root`` (no links)."""
    try:
        return {d for d in root.iterdir()
                if KIND_NAME.match(d.name) and d.is_dir() and not d.is_symlink()}
    except OSError:
        return set()


def recompute_seconds(path: Path) -> float | None:
    """How long the entry at ``path`` took to compute, as :func:`store` recorded it.

    None when it was not recorded (an entry of an older version) or cannot be read.
    """
    try:
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            if SECONDS_MEMBER not in data.files:
                return None
            value = float(data[SECONDS_MEMBER])
    except _UNREADABLE:
        return None
    return value if math.isfinite(value) and value >= 0.0 else None


def cost_class(seconds: float | None, nbytes: int) -> int:
    """The decade of an entry's recompute seconds per MiB (unknown: that of 1 s per MiB).

    :func:`evict` deletes the lower classes first: a spectrum table of 400 MiB that an FFT
    rebuilds in 5 s (class -2) goes before a 1.4 MiB descriptor that took 20 s (class 1).
    Times under :data:`TIMING_FLOOR_SECONDS` count as that floor: they measure the machine's
    noise, which must not order entries that are equally cheap.
    """
    if seconds is None:
        return 0
    per_mib = max(seconds, TIMING_FLOOR_SECONDS) / max(nbytes / 2**20, 1e-6)
    return math.floor(math.log10(per_mib))


def evict(limit: int | None = None, *, keep: Path | None = None) -> int:
    """Delete entries until the cache holds at most ``limit`` bytes, cheapest first.

    Entries go in order of :func:`cost_class` (what takes less time per byte to compute
    again goes first: spectra and tables before descriptors), and within a class the
    least recently used first. Only the cache's own entries count and go (:func:`entries`);
    ``keep`` (the entry just written) is never deleted. Temporary files of writes killed
    more than an hour ago go too. Returns the bytes freed.
    """
    limit = max_bytes() if limit is None else limit
    listed = []
    for path in entries():
        try:
            st = path.stat()
        except OSError:
            continue
        listed.append((max(st.st_atime, st.st_mtime), st.st_size, path))
    total = sum(size for _, size, _ in listed)
    freed = 0
    for path in _stale_temporaries(time.time()):
        with contextlib.suppress(OSError):
            path.unlink()
    if total > limit:  # read what each entry cost only when something must go
        order = sorted((cost_class(recompute_seconds(path), size), used, size, path)
                       for used, size, path in listed)
    else:
        order = []
    for _, _, size, path in order:
        if total - freed <= limit:
            break
        if keep is not None and path == keep:
            continue
        try:
            path.unlink()
            freed += size
        except FileNotFoundError:
            freed += size  # another process evicted it first
        except OSError:
            pass
    return freed


def content_key(kind: str, parts: Mapping[str, object]) -> str:
    """Hex SHA-256 of ``kind`` and ``parts``: arrays by dtype, shape and bytes, the rest as JSON."""
    h = hashlib.sha256(kind.encode())
    for name in sorted(parts):
        value = parts[name]
        h.update(name.encode())
        if isinstance(value, np.ndarray):
            arr = np.ascontiguousarray(value)
            h.update(f"{arr.dtype.str}{arr.shape}".encode())
            h.update(arr.tobytes())
        else:
            h.update(json.dumps(value, sort_keys=True, default=str).encode())
    return h.hexdigest()


def _non_finite(arrays: Mapping[str, np.ndarray]) -> list[str]:
    """Names of the float or complex arrays that hold NaN or infinity."""
    bad = []
    for name, value in arrays.items():
        arr = np.asarray(value)
        if arr.dtype.kind in "fc" and not np.isfinite(arr).all():
            bad.append(name)
    return bad


def load(kind: str, key: str) -> dict[str, np.ndarray] | None:
    """The cached arrays, or None when absent.

    An entry that cannot be read whole (truncated, a flipped bit caught by the zip CRC,
    not an ``.npz``) or that holds non-finite values is deleted, with a warning, and None
    is returned: the caller recomputes it.
    """
    path = entry_path(kind, key)
    try:  # the file is opened here: np.load leaks its handle when the zip is bad
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files if k != SECONDS_MEMBER}
    except FileNotFoundError:
        return None
    except _UNREADABLE as exc:
        _drop(path, f"cannot be read ({type(exc).__name__}: {exc})")
        return None
    bad = _non_finite(arrays)
    if bad:
        _drop(path, f"holds non-finite values (in {', '.join(bad)})")
        return None
    with contextlib.suppress(OSError):  # a read-only cache can still be read
        os.utime(path)  # mark as recently used, whatever the file system's atime policy
    return arrays


def _drop(path: Path, why: str) -> None:
    """Delete a damaged entry, saying so; a read-only cache keeps it and says that."""
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError as exc:
        _warn_once(path, "drop", f"cache: entry {path} {why} and cannot be deleted "
                   f"({exc.strerror}); it is recomputed each time: delete it or fix the "
                   "folder's permissions")
        return
    _log.warning(f"cache: entry {path} {why}; deleted, it is computed again")


def store(kind: str, key: str, arrays: Mapping[str, np.ndarray], *,
          seconds: float | None = None) -> Path | None:
    """Write an entry atomically and return its path; None when it is not stored.

    ``seconds``, how long the computation took, is kept in the entry (``SECONDS_MEMBER``)
    for :func:`evict`, which lets entries that are cheap to compute again go first.

    Not stored (each with one warning): non-finite values, an entry larger than the cap
    (:func:`max_bytes`) or than the disk's free space, a cache folder that does not take
    files (read-only, another user's). The file is written under a temporary name in the
    entry's folder and renamed into place, so concurrent writers and readers see a whole
    entry or none.
    """
    path = entry_path(kind, key)
    bad = _non_finite(arrays)
    if bad:
        _log.warning(f"cache: not storing a {kind} with non-finite values (in "
                     f"{', '.join(bad)}); the parameters give no usable result")
        return None
    nbytes = sum(np.asarray(a).nbytes for a in arrays.values()) + 1024 * (len(arrays) + 1)
    cap = max_bytes()
    if nbytes > cap:
        _warn_once(path.parent, "cap", f"cache: a {kind} entry of {human_size(nbytes)} is "
                   f"larger than the cache's cap ({human_size(cap)}, "
                   "SKELASM_CACHE_MAX_GB); not stored, it is computed each time: raise the cap "
                   "to keep it")
        return None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tag = cache_dir() / TAG_NAME
        if not tag.exists():
            write_text(tag, _TAG, what="cache tag")
        room = disk_space_error(path, nbytes, what=f"{kind} cache entry")
        if room is not None:
            _warn_once(path.parent, "space", f"cache: {room}; not stored")
            return None
        members = dict(arrays)
        if seconds is not None:
            members[SECONDS_MEMBER] = np.asarray(float(seconds), dtype=np.float64)
        with atomic_write(path, what=f"{kind} cache entry") as fh:
            np.savez(fh, **members)  # type: ignore[arg-type]  # numpy's stub: **kwds bool
    except OSError as exc:
        _warn_once(cache_dir(), "write", f"cache: cannot write to {cache_dir()} ({exc}); "
                   "results are not cached (set SKELASM_CACHE to a folder you can write)")
        return None
    return path


def load_or_compute(
    kind: str,
    parts: Mapping[str, object],
    compute: Callable[[], Mapping[str, np.ndarray]],
    *,
    use_cache: bool = True,
) -> tuple[dict[str, np.ndarray], bool]:
    """Cached arrays for ``parts``, computing and storing them when missing.

    Returns the arrays and whether they came from the cache. A damaged entry is dropped
    and recomputed; a result with non-finite values is returned but never stored.
    """
    key = content_key(kind, parts)
    if use_cache:
        hit = load(kind, key)
        if hit is not None:
            return hit, True
    start = time.perf_counter()
    arrays = dict(compute())
    seconds = time.perf_counter() - start
    if use_cache:
        written = store(kind, key, arrays, seconds=seconds)
        if written is not None:
            evict(keep=written)
    return arrays, False
