"""On-disk cache of computed arrays (descriptors, spectra), keyed by content.

Entries are ``.npz`` files named by the SHA-256 of everything that determines them:
the mesh bytes, the grid, the parameters and a format version. The cache lives in
``SKELASM_CACHE`` or ``~/.cache/skelasm``.
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
            return {k: data[k] for k in data.files}
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
        np.savez(tmp, **arrays)
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
            store(kind, key, arrays)
        except OSError:
            pass  # a read-only or full disk costs a recompute next time, nothing more
    return arrays, False
