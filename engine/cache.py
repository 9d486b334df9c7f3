"""On-disk cache of computed arrays (descriptors, spectra), keyed by content.

Entries are ``.npz`` files named by the SHA-256 of everything that determines them:
the mesh bytes, the grid, the parameters, a format version and a digest of the code that
computes them (:func:`code_digest`). The cache lives in ``SKELASM_CACHE`` or
``~/.cache/skelasm`` and is kept under ``SKELASM_CACHE_MAX_GB`` (default 2 GiB) by deleting
the least recently used entries after each store.
"""

from __future__ import annotations

import ast
import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

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
