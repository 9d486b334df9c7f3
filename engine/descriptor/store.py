"""Descriptors on disk and in the cache: a part's skeletal density on its grid, with provenance.

A :class:`Descriptor` is ``rho (nx, ny, nz) complex64`` sampled on a :class:`engine.grid.Grid`
in the part's own frame, plus the parameters it was computed with. ``Descriptor.save`` writes
an ``.npz`` with (at least) ``rho``, ``origin`` (3 floats: where grid index (0, 0, 0) lies in
the part's frame), ``spacing``, ``shape``, ``sigma``, ``penalty`` and ``lambda_out``.

:func:`descriptor_for_part` goes through ``engine.cache.load_or_compute``, keyed by the mesh's
bytes, the grid, the parameters, the method, the quadrature constants, a
digest of the descriptor's source files and :data:`FORMAT_VERSION`; a second call with the
same inputs loads the stored array. The key does not include the backend: the numba and
OpenCL paths agree to float32 precision, so either one's result serves both.

All parts of a scene share one grid spacing (so that the correlation needs no resampling at
R = I): :func:`scene_spacing` picks it, :func:`descriptors_for_scene` computes both.
"""

from __future__ import annotations

import os
import time
import zipfile
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import engine.descriptor.constants as _c
from engine.cache import code_digest, content_key, entry_path, load_or_compute
from engine.descriptor.compute import BackendLike, descriptor_and_side, resolve_backend
from engine.errors import InputError
from engine.files import atomic_write
from engine.grid import Grid, grid_for_bounds
from engine.loading import Part
from engine.params import DescriptorParams
from engine.scene import Scene, load_scene_parts

#: Bumped whenever the stored layout or the meaning of a stored descriptor changes.
FORMAT_VERSION = 1
#: Cache kind (sub-folder of the cache directory).
CACHE_KIND = "descriptor"


@dataclass(frozen=True, eq=False)
class Descriptor:
    """A part's skeletal density on a grid.

    Attributes
    ----------
    rho : (nx, ny, nz) complex64
        Samples; ``rho[i, j, k]`` at ``grid.origin + grid.spacing * (i, j, k)`` (read-only).
    grid : Grid
        Where the samples lie, in the part's own frame.
    params : DescriptorParams
        sigma, penalty, lambda_out.
    triangles : int
        Triangles of the mesh it was computed from.
    backend : str
        Backend that computed it (``"numba"``, ``"opencl"``), as stored.
    seconds : float
        Wall time of the call that produced this object (a cache load when ``from_cache``).
    from_cache : bool
        Whether it was loaded from the cache.
    name : str
        The part's name.
    method : str
        ``"adaptive"``, ``"tree"`` or ``"brute"`` (see ``compute_descriptor``), or
        ``"ladder"``: interpolated from other sigmas (:mod:`engine.descriptor.ladder`).
    compute_seconds : float
        Wall time the computation itself took (when it was computed, even if now cached).
    ladder : tuple of float
        The sigmas of the ladder nodes it was interpolated from (``method == "ladder"``,
        :mod:`engine.descriptor.ladder`); empty: computed directly.
    """

    rho: np.ndarray
    grid: Grid
    params: DescriptorParams
    triangles: int
    backend: str
    seconds: float
    from_cache: bool = False
    name: str = ""
    method: str = "tree"
    compute_seconds: float = float("nan")
    ladder: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        rho = np.asarray(self.rho)
        if rho.shape != tuple(self.grid.shape):
            raise ValueError(f"rho has shape {rho.shape} but the grid is {self.grid.shape}")
        rho = np.ascontiguousarray(rho, dtype=np.complex64)
        rho.setflags(write=False)
        object.__setattr__(self, "rho", rho)

    def arrays(self) -> dict[str, np.ndarray]:
        """The ``.npz`` contents: rho, origin, spacing, shape, parameters and provenance."""
        return {
            "rho": np.asarray(self.rho),
            "origin": np.asarray(self.grid.origin, dtype=np.float64),
            "spacing": np.asarray(self.grid.spacing, dtype=np.float64),
            "shape": np.asarray(self.grid.shape, dtype=np.int64),
            "sigma": np.asarray(self.params.sigma, dtype=np.float64),
            "penalty": np.asarray(self.params.penalty, dtype=np.float64),
            "lambda_out": np.asarray(self.params.lambda_out, dtype=np.float64),
            "triangles": np.asarray(self.triangles, dtype=np.int64),
            "backend": np.asarray(self.backend),
            "method": np.asarray(self.method),
            "name": np.asarray(self.name),
            "compute_seconds": np.asarray(self.compute_seconds, dtype=np.float64),
            "ladder": np.asarray(self.ladder, dtype=np.float64),
            "format_version": np.asarray(FORMAT_VERSION, dtype=np.int64),
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write an ``.npz`` (suffix added if missing) and return its path.

        The file is written whole or not at all (``engine.files.atomic_write``): a crash or
        a full disk leaves any earlier file at ``path`` as it was. It replaces an existing
        file: check the path with ``engine.files.check_output`` before the work.

        Raises
        ------
        InputError
            The folder does not exist.
        OSError
            The write failed; the message names the file.
        """
        p = Path(path)
        if p.suffix != ".npz":
            p = p.with_name(p.name + ".npz")
        if not p.parent.is_dir():
            raise InputError(f"{p.parent}: no such folder for the descriptor {p.name}")
        with atomic_write(p, what="descriptor") as fh:
            np.savez(fh, **self.arrays())  # type: ignore[arg-type]
        return p

    @classmethod
    def load(cls, path: str | os.PathLike) -> Descriptor:
        """Read a descriptor written by :meth:`save` (or ``skelasm precompute``)."""
        p = Path(path)
        t0 = time.perf_counter()
        try:
            with open(p, "rb") as fh, np.load(fh, allow_pickle=False) as data:
                arrays = {k: data[k] for k in data.files}
        except FileNotFoundError:
            raise InputError(f"{p}: no such descriptor file") from None
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
            raise InputError(f"{p}: not a readable descriptor file ({type(exc).__name__}: "
                             f"{exc}); the file is damaged or incomplete: compute it again "
                             "with `skelasm precompute`") from exc
        return cls._from_arrays(arrays, source=str(p), seconds=time.perf_counter() - t0,
                                from_cache=False)

    @classmethod
    def _from_arrays(cls, arrays: dict[str, np.ndarray], *, source: str, seconds: float,
                     from_cache: bool) -> Descriptor:
        missing = [k for k in ("rho", "origin", "spacing", "sigma", "penalty", "lambda_out")
                   if k not in arrays]
        if missing:
            raise InputError(f"{source}: not a descriptor file (missing {', '.join(missing)})")
        version = int(arrays.get("format_version", FORMAT_VERSION))
        if version > FORMAT_VERSION:
            raise InputError(f"{source}: descriptor format {version} is newer than this "
                             f"program's ({FORMAT_VERSION}); update skelasm")
        rho = arrays["rho"]
        if rho.dtype.kind not in "fc":
            raise InputError(f"{source}: rho holds {rho.dtype} values, not numbers; compute "
                             "it again with `skelasm precompute`")
        if not np.isfinite(rho).all():
            raise InputError(f"{source}: rho holds non-finite values (NaN or infinity); "
                             "compute it again with `skelasm precompute` and valid parameters")
        if rho.ndim != 3 or np.asarray(arrays["origin"]).size != 3:
            raise InputError(f"{source}: rho must be 3D and origin 3 numbers, got shapes "
                             f"{rho.shape} and {np.asarray(arrays['origin']).shape}")
        o = np.asarray(arrays["origin"], dtype=np.float64).reshape(3)
        nx, ny, nz = (int(n) for n in rho.shape)
        grid = Grid((float(o[0]), float(o[1]), float(o[2])), float(arrays["spacing"]),
                    (nx, ny, nz))
        params = DescriptorParams(sigma=float(arrays["sigma"]), penalty=float(arrays["penalty"]),
                                  lambda_out=float(arrays["lambda_out"]))
        return cls(
            rho=rho, grid=grid, params=params,
            triangles=int(arrays.get("triangles", -1)),
            backend=str(arrays.get("backend", "unknown")),
            seconds=seconds, from_cache=from_cache,
            name=str(arrays.get("name", "")),
            method=str(arrays.get("method", "tree")),
            compute_seconds=float(arrays.get("compute_seconds", np.nan)),
            ladder=tuple(float(s) for s in np.asarray(arrays.get("ladder", ())).reshape(-1)),
        )


# --------------------------------------------------------------------------- grids
def grid_for_part(part: Part, *, samples: int | None = None, spacing: float | None = None,
                  padding: float) -> Grid:
    """The grid of a part (``engine.loading.Part``): its bounds plus ``padding`` cells."""
    lower, upper = part.bounds
    return grid_for_bounds(lower, upper, samples=samples, spacing=spacing, padding=padding)


def scene_spacing(scene: Scene, parts: Sequence[Part]) -> float:
    """The one grid spacing of a scene.

    The scene's ``[descriptor] spacing`` if given, else the longest side of the largest part
    (the largest bounding-box side of all parts) divided by ``[descriptor] grid``.
    """
    settings = scene.descriptor
    if settings.spacing is not None:
        return float(settings.spacing)
    assert settings.grid is not None  # DescriptorParams holds one of grid and spacing
    longest = max(float(np.max(p.extent)) for p in parts)
    if not longest > 0:
        raise InputError(f"{scene.path}: the parts have zero extent; cannot derive a grid")
    return longest / settings.grid


# --------------------------------------------------------------------------- compute / cache
_CODE_DIGEST: str | None = None


def descriptor_code_digest() -> str:
    """Digest of the code that shapes a cached descriptor (once per process).

    :func:`engine.cache.code_digest` of :mod:`engine.descriptor.compute`: every file of this
    package and every engine module the computation imports (engine/grid.py,
    engine/params.py, ...). An installed program never changes them, so users keep their
    cache, while a developer's edit recomputes instead of serving stale values.
    """
    global _CODE_DIGEST
    if _CODE_DIGEST is None:
        _CODE_DIGEST = code_digest("engine.descriptor.compute")
    return _CODE_DIGEST


def cache_key_parts(part: Part, grid: Grid, params: DescriptorParams,
                    method: str) -> dict[str, object]:  # fmt: skip
    """Everything the cached descriptor of ``part`` depends on (for ``engine.cache``)."""
    return {
        "vertices": np.ascontiguousarray(part.vertices, dtype=np.float64),
        "faces": np.ascontiguousarray(part.faces, dtype=np.int64),
        "origin": list(grid.origin),
        "spacing": grid.spacing,
        "shape": list(grid.shape),
        # not the penalty nor lambda_out: the entry holds rho / c and the side of each
        # sample, so any weights are a rescale of it (descriptor_for_part)
        "sigma": params.sigma,
        "method": method,
        "format": FORMAT_VERSION,
        "constants": _c.as_dict(),
        "code": descriptor_code_digest(),
    }


def _side_factor(inside: np.ndarray, params: DescriptorParams) -> np.ndarray:
    """``c`` per sample: ``lambda_in`` inside, ``-lambda_out`` outside (float32)."""
    return np.where(inside, np.float32(params.lambda_in), np.float32(-params.lambda_out))


def descriptor_for_part(
    part: Part,
    grid: Grid,
    params: DescriptorParams | None = None,
    *,
    backend: BackendLike = None,
    method: str = "adaptive",
    use_cache: bool = True,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> Descriptor:
    """The descriptor of ``part`` on ``grid``, from the cache when the same inputs were seen.

    Parameters
    ----------
    part : engine.loading.Part
        Mesh in its own frame (``vertices (n, 3) float64``, ``faces (m, 3) int64``).
    grid : Grid
        Where to sample, in the part's frame.
    params : DescriptorParams, optional
        Default ``DescriptorParams()``.
    backend : None, str or engine.backend.Backend
        As :func:`engine.descriptor.compute.resolve_backend`; not part of the cache key.
    method : {"adaptive", "tree", "brute"}
    use_cache : bool
        False computes and stores nothing.
    progress, cancel : callables, optional
        As ``compute_descriptor``; ``progress(1.0)`` is also called on a cache hit.

    Returns
    -------
    Descriptor
    """
    if params is None:
        params = DescriptorParams()
    if method not in _c.METHODS:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(_c.METHODS)}")
    t0 = time.perf_counter()
    used: dict[str, str] = {}

    def compute() -> dict[str, np.ndarray]:
        resolved = resolve_backend(backend)
        used["backend"] = resolved.name
        start = time.perf_counter()
        rho, inside = descriptor_and_side(part.vertices, part.faces, grid, params,
                                          backend=resolved, method=method, progress=progress,
                                          cancel=cancel)
        seconds = time.perf_counter() - start
        return {
            "unit": np.ascontiguousarray(rho / _side_factor(inside, params), np.complex64),
            "inside": np.packbits(inside, axis=None),
            "backend": np.asarray(used["backend"]),
            "compute_seconds": np.asarray(seconds, dtype=np.float64),
        }

    arrays, hit = load_or_compute(CACHE_KIND, cache_key_parts(part, grid, params, method),
                                  compute, use_cache=use_cache)
    inside = np.unpackbits(arrays["inside"], count=grid.size).reshape(grid.shape).view(bool)
    rho = (arrays["unit"] * _side_factor(inside, params)).astype(np.complex64)
    bad = int(np.count_nonzero(~np.isfinite(rho)))
    if bad:  # never cached (engine.cache refuses it); never handed on either
        raise InputError(
            f"{part.source or part.name}: the descriptor has {bad} of {rho.size} "
            f"non-finite samples (NaN or infinity) with sigma = {params.sigma:g}, penalty = "
            f"{params.penalty:g}, lambda_out = {params.lambda_out:g} on a grid of spacing "
            f"{grid.spacing:.4g}; use parameters nearer the defaults (sigma 0.5, penalty 3)"
        )
    if hit and progress is not None:
        progress(1.0)
    return Descriptor(
        rho=rho, grid=grid, params=params, triangles=int(len(part.faces)),
        backend=str(arrays.get("backend", used.get("backend", "unknown"))),
        seconds=time.perf_counter() - t0, from_cache=hit, name=str(getattr(part, "name", "")),
        method=method, compute_seconds=float(arrays.get("compute_seconds", np.nan)),
    )


def distance_for_part(part: Part, grid: Grid, *, use_cache: bool = True,
                      progress: Callable[[float], None] | None = None,
                      cancel: Callable[[], bool] | None = None) -> np.ndarray:
    """Part's signed distance (+ outside) at ``grid``'s nodes: ``grid.shape`` float32, cached.

    The walls' distance map (:mod:`engine.correlation.walls`), content-keyed like the
    descriptors (the mesh, the grid, the kernel's code).
    """
    from engine.descriptor.compute import signed_distance

    def compute() -> dict[str, np.ndarray]:
        d = signed_distance(part.vertices, part.faces, grid.points().reshape(-1, 3),
                            progress=progress, cancel=cancel)
        return {"distance": np.ascontiguousarray(d.reshape(grid.shape), np.float32)}

    key = {"vertices": np.ascontiguousarray(part.vertices, dtype=np.float64),
           "faces": np.ascontiguousarray(part.faces, dtype=np.int64),
           "origin": list(grid.origin), "spacing": grid.spacing, "shape": list(grid.shape),
           "format": FORMAT_VERSION, "code": descriptor_code_digest()}
    arrays, hit = load_or_compute("distance", key, compute, use_cache=use_cache)
    if hit and progress is not None:
        progress(1.0)
    return arrays["distance"]


def descriptor_cached(part: Part, grid: Grid, params: DescriptorParams, *,
                      method: str = "adaptive") -> bool:
    """Whether the part's descriptor on ``grid`` at ``params`` is in the cache."""
    key = content_key(CACHE_KIND, cache_key_parts(part, grid, params, method))
    return entry_path(CACHE_KIND, key).is_file()


def descriptors_cached(scene: Scene, parts: Sequence[Part], *,
                       method: str = "adaptive") -> bool:
    """Whether every descriptor of the scene is in the cache (nothing to compute)."""
    spacing = scene_spacing(scene, parts)
    return all(descriptor_cached(part, grid_for_part(part, spacing=spacing,
                                                     padding=scene.descriptor.padding),
                                 scene.descriptor, method=method) for part in parts)


def descriptors_for_scene(
    scene: Scene,
    *,
    parts: Sequence[Part] | None = None,
    backend: BackendLike = None,
    method: str = "adaptive",
    use_cache: bool = True,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> list[Descriptor]:
    """Descriptors of every part of a scene, each on its own grid in its own frame.

    All grids share :func:`scene_spacing`; each covers its part's bounds plus the scene's
    ``[descriptor] padding`` cells.

    Parameters
    ----------
    scene : engine.scene.Scene
    parts : sequence of engine.loading.Part, optional
        Already loaded parts (default: ``engine.scene.load_scene_parts(scene)``).
    backend, method, use_cache, progress, cancel
        As :func:`descriptor_for_part`; progress runs 0..1 over all parts, weighted by
        grid size.
    """
    if parts is None:
        parts = load_scene_parts(scene)
    spacing = scene_spacing(scene, parts)
    grids = [grid_for_part(p, spacing=spacing, padding=scene.descriptor.padding) for p in parts]
    params = scene.descriptor
    total = float(sum(g.size for g in grids)) or 1.0
    done = 0.0
    out = []
    for part, grid in zip(parts, grids, strict=True):
        sub = None
        if progress is not None:
            base, weight = done, grid.size / total

            def sub(fraction: float, base: float = base, weight: float = weight) -> None:
                progress(min(1.0, base + weight * fraction))

        out.append(descriptor_for_part(part, grid, params, backend=backend, method=method,
                                       use_cache=use_cache, progress=sub, cancel=cancel))
        done += grid.size / total
    return out
