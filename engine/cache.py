"""On-disk cache of computed arrays (descriptors, spectra), keyed by content.

Entries are ``.npz`` files named by the SHA-256 of everything that determines them:
the mesh bytes, the grid, the parameters and a format version. The cache lives in
``SKELASM_CACHE`` or ``~/.cache/skelasm`` and is kept under ``SKELASM_CACHE_MAX_GB``
(default 2 GiB) by deleting the least recently used entries after each store.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np


def cache_dir() -> Path:
    """The cache folder (created on first use)."""
    root = os.environ.get("SKELASM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "skelasm"
    )
    return Path(root)


#: Default cap on the cache's size, in GiB (spectra of a 160^3 FFT are ~60 MB each).
DEFAULT_MAX_GB = 2.0


def max_bytes() -> int:
    """The cache's size cap from ``SKELASM_CACHE_MAX_GB`` (default 2 GiB)."""
    raw = os.environ.get("SKELASM_CACHE_MAX_GB")
    try:
        gb = float(raw) if raw else DEFAULT_MAX_GB
    except ValueError as exc:
        raise ValueError(f"SKELASM_CACHE_MAX_GB must be a number of GiB, got {raw!r}") from exc
    return int(gb * 2**30)


def evict(limit: int | None = None, *, keep: Path | None = None) -> int:
    """Delete least recently used entries until the cache holds at most ``limit`` bytes.

    ``keep`` (the entry just written) is never deleted. Returns the bytes freed.
    """
    limit = max_bytes() if limit is None else limit
    entries = []
    for path in cache_dir().glob("*/*.npz"):
        try:
            st = path.stat()
        except OSError:
            continue
        entries.append((max(st.st_atime, st.st_mtime), st.st_size, path))
    total = sum(size for _, size, _ in entries)
    freed = 0
    for _, size, path in sorted(entries):
        if total - freed <= limit:
            break
        if keep is not None and path == keep:
            continue
        try:
            path.unlink()
            freed += size
        except OSError:
            pass
    return freed


def content_key(kind: str, parts: Mapping[str, Any]) -> str:
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


def load(kind: str, key: str) -> dict[str, np.ndarray] | None:
    """The cached arrays, or None when absent or unreadable (a damaged entry is dropped)."""
    path = cache_dir() / kind / f"{key}.npz"
    if not path.exists():
        return None
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        os.utime(path)  # mark as recently used, whatever the file system's atime policy
        return arrays
    except (OSError, ValueError, EOFError):
        path.unlink(missing_ok=True)
        return None


def store(kind: str, key: str, arrays: Mapping[str, np.ndarray]) -> Path:
    """Write arrays atomically (temporary file, then rename) and return the path."""
    folder = cache_dir() / kind
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}.npz"
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp.npz")
    os.close(fd)
    try:
        np.savez(tmp, **dict(arrays))  # type: ignore[arg-type]  # numpy's stub types **kwds as bool
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def load_or_compute(
    kind: str,
    parts: Mapping[str, Any],
    compute: Callable[[], Mapping[str, np.ndarray]],
    *,
    use_cache: bool = True,
) -> tuple[dict[str, np.ndarray], bool]:
    """Cached arrays for ``parts``, computing and storing them when missing.

    Returns the arrays and whether they came from the cache.
    """
    key = content_key(kind, parts)
    if use_cache:
        hit = load(kind, key)
        if hit is not None:
            return hit, True
    arrays = dict(compute())
    if use_cache:
        try:
            evict(keep=store(kind, key, arrays))
        except OSError:
            pass  # a read-only or full disk costs a recompute next time, nothing more
    return arrays, False
