"""The sigma ladder: descriptors at a few sigma nodes, from which any sigma between is read.

Data: a part (``engine.loading.Part``) on a grid (:class:`engine.grid.Grid`); the ladder is
its descriptors at :func:`ladder_sigmas` (``rho (nx, ny, nz) complex64`` each), computed and
cached one by one through :func:`engine.descriptor.store.descriptor_for_part`. The density at
a sample is a smooth function of sigma, so ``sigma * rho`` is interpolated in ``log sigma``
(Lagrange, on Chebyshev nodes) and divided by sigma: a new sigma inside
:data:`LADDER_SPAN` takes a second or so instead of computing the density afresh.

What is interpolated is the cached, penalty-free ``unit = rho / c`` (``c``: ``lambda_in``
inside, ``-lambda_out`` outside); the side comes from the winding number and is the same at
every sigma, and the requested penalty's ``c`` is applied after. The result is a
:class:`Descriptor` whose ``method`` is ``"ladder"`` and whose ``ladder`` names the nodes, so
it is never taken for a direct computation. docs/descriptor.md, "Sigma ladder".
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from engine import cache
from engine.descriptor.compute import BackendLike
from engine.descriptor.store import (
    CACHE_KIND,
    Descriptor,
    cache_key_parts,
    descriptor_cached,
    descriptor_for_part,
    grid_for_part,
    scene_spacing,
)
from engine.grid import Grid
from engine.loading import Part
from engine.params import DescriptorParams
from engine.scene import Scene

__all__ = [
    "LADDER_NODES",
    "LADDER_SPAN",
    "LadderIncomplete",
    "in_span",
    "interpolated_descriptor",
    "descriptor_preferring_ladder",
    "ladder_cached",
    "ladder_descriptors_for_scene",
    "ladder_for_part",
    "ladder_sigmas",
    "prepare_ladders",
    "prepare_scene_ladder",
    "scene_ladder_cached",
]

#: The sigmas a ladder serves, ends included. Measured on the peg-in-hole block (its scene
#: grid, 69 x 69 x 41, adaptive method) against direct computations: RMS error over RMS(rho)
#: 2.5e-3 at sigma 0.3, 2.3e-3 at 0.4, 9.8e-4 at 0.5, 1.8e-3 at 0.7, 6.4e-4 at 1.0, 1.4e-4 at
#: 1.5 (largest error 0.9 to 1.7 % of RMS): about the adaptive sampling's own tolerance
#: (3e-3 of RMS). Below 0.25 the cost of every sigma grows like 1/sigma^2; above 2 the
#: density flattens and each node costs more (37.5 s at 1.93 against 8 s at 0.26 there).
LADDER_SPAN: tuple[float, float] = (0.25, 2.0)
#: Chebyshev nodes in log sigma over the span (6: the accuracy above).
LADDER_NODES = 6


class LadderIncomplete(LookupError):
    """A node of the ladder is not in the cache: nothing to interpolate from."""


def ladder_sigmas(span: tuple[float, float] = LADDER_SPAN,
                  nodes: int = LADDER_NODES) -> np.ndarray:  # fmt: skip
    """The ladder's sigmas: ``(nodes,) float64``, ascending, Chebyshev nodes in log sigma.

    Chebyshev points (of the first kind) keep the Lagrange interpolant's error near its
    minimax value; log sigma because the density's dependence on sigma is much the same
    over each factor of sigma (the Gaussian acts on ``eta / |xi|``, in units of sigma).
    """
    lo, hi = np.log(float(span[0])), np.log(float(span[1]))
    k = np.arange(nodes)
    t = -np.cos((2 * k + 1) * np.pi / (2 * nodes))  # ascending in (-1, 1)
    return np.exp(0.5 * (lo + hi) + 0.5 * (hi - lo) * t)


def in_span(sigma: float, span: tuple[float, float] = LADDER_SPAN) -> bool:
    """Whether a ladder over ``span`` serves ``sigma`` (the ends included)."""
    return bool(span[0] <= float(sigma) <= span[1])


def _weights(sigma: float, nodes: np.ndarray) -> np.ndarray:
    """Lagrange weights ``(n,) float64`` of the nodes at ``sigma``, in log sigma."""
    x, xs = np.log(float(sigma)), np.log(nodes)
    w = np.ones(len(xs))
    for i in range(len(xs)):
        for j in range(len(xs)):
            if j != i:
                w[i] *= (x - xs[j]) / (xs[i] - xs[j])
    return w


def _node_key(part: Part, grid: Grid, params: DescriptorParams, sigma: float,
              method: str) -> str:  # fmt: skip
    return cache.content_key(CACHE_KIND, cache_key_parts(
        part, grid, replace(params, sigma=float(sigma)), method))


def ladder_cached(part: Part, grid: Grid, params: DescriptorParams | None = None, *,
                  method: str = "adaptive", span: tuple[float, float] = LADDER_SPAN,
                  nodes: int = LADDER_NODES) -> bool:  # fmt: skip
    """Whether every node of the part's ladder is in the cache (nothing is computed)."""
    params = DescriptorParams() if params is None else params
    return all(cache.entry_path(CACHE_KIND, _node_key(part, grid, params, s, method)).is_file()
               for s in ladder_sigmas(span, nodes))


#: (part, grid) pairs of one ladder, with the scene's parameters (any penalty: not in the key)
_Rung = tuple[Part, Grid]


def _cost(grid: Grid, sigma: float) -> float:
    """A node's expected cost, relative: samples times ``1 + sigma^2``.

    Measured on the peg's block: 8 s at sigma 0.26, 9 s at 0.54, 13.6 s at 0.93, 23.7 s at
    1.48, 37.5 s at 1.93 (within 6 % of 8 s times ``1 + 0.94 sigma^2``).
    """
    return float(grid.size) * (1.0 + float(sigma) ** 2)


def _compute_missing(rungs: Sequence[_Rung], params: DescriptorParams, *, backend: BackendLike,
                     method: str, span: tuple[float, float], nodes: int,
                     progress: Callable[[float], None] | None,
                     cancel: Callable[[], bool] | None) -> None:  # fmt: skip
    """Compute the nodes not in the cache, cheapest sigma first, each cached as it ends.

    Progress runs over the whole ladders (nodes already cached count as done), weighted by
    :func:`_cost`; a cancel loses only the node being computed.
    """
    sigmas = ladder_sigmas(span, nodes)
    todo = [(part, grid, s) for s in sigmas for part, grid in rungs]  # small sigmas first
    total = sum(_cost(g, s) for _, g, s in todo) or 1.0
    done = 0.0
    for part, grid, s in todo:
        cost = _cost(grid, s)
        if cache.entry_path(CACHE_KIND, _node_key(part, grid, params, s, method)).is_file():
            done += cost
            continue
        sub = None
        if progress is not None:
            progress(done / total)

            def sub(f: float, base: float = done, weight: float = cost) -> None:
                progress(min(1.0, (base + weight * float(f)) / total))

        descriptor_for_part(part, grid, replace(params, sigma=float(s)), backend=backend,
                            method=method, progress=sub, cancel=cancel)
        done += cost
    if progress is not None:
        progress(1.0)


def ladder_for_part(part: Part, grid: Grid, params: DescriptorParams | None = None, *,
                    backend: BackendLike = None, method: str = "adaptive",
                    span: tuple[float, float] = LADDER_SPAN, nodes: int = LADDER_NODES,
                    progress: Callable[[float], None] | None = None,
                    cancel: Callable[[], bool] | None = None) -> list[Descriptor]:  # fmt: skip
    """The part's ladder on ``grid``: its node descriptors (``params``' penalty), ascending.

    Nodes in the cache are loaded, the others computed and cached one by one (progress and
    cancel as :func:`engine.descriptor.store.descriptor_for_part`).
    """
    params = DescriptorParams() if params is None else params
    _compute_missing([(part, grid)], params, backend=backend, method=method, span=span,
                     nodes=nodes, progress=progress, cancel=cancel)
    return [descriptor_for_part(part, grid, replace(params, sigma=float(s)), method=method)
            for s in ladder_sigmas(span, nodes)]


def interpolated_descriptor(part: Part, grid: Grid, params: DescriptorParams, *,
                            method: str = "adaptive", span: tuple[float, float] = LADDER_SPAN,
                            nodes: int = LADDER_NODES) -> Descriptor:  # fmt: skip
    """The part's descriptor at ``params.sigma``, interpolated from its cached ladder.

    Returns
    -------
    Descriptor
        ``rho (nx, ny, nz) complex64`` at ``params`` (sigma, penalty, lambda_out), with
        ``method = "ladder"`` and ``ladder`` the node sigmas.

    Raises
    ------
    ValueError
        ``params.sigma`` is outside ``span``: compute it directly.
    LadderIncomplete
        A node is not in the cache (:func:`ladder_cached` says so without loading).
    """
    sigma = float(params.sigma)
    if not in_span(sigma, span):
        raise ValueError(f"sigma {sigma:g} is outside the ladder's span {span[0]:g} to "
                         f"{span[1]:g}; compute it directly")
    t0 = time.perf_counter()
    sigmas = ladder_sigmas(span, nodes)
    weights = _weights(sigma, sigmas)
    acc = np.zeros(grid.shape, np.complex128)
    votes = np.zeros(grid.shape, np.int32)
    backend = "unknown"
    for s, w in zip(sigmas, weights, strict=True):
        arrays = cache.load(CACHE_KIND, _node_key(part, grid, params, s, method))
        if arrays is None:
            raise LadderIncomplete(f"{part.name or part.source}: the ladder's node at sigma "
                                   f"{s:.4g} is not in the cache")
        acc += (w * s) * arrays["unit"]
        votes += np.unpackbits(arrays["inside"], count=grid.size).reshape(grid.shape)
        backend = str(arrays.get("backend", backend))
    # the side is the winding number's, the same at every node; a vote guards against a
    # sample whose side one node's adaptive sampling settled differently
    inside = 2 * votes > len(sigmas)
    c = np.where(inside, np.float32(params.lambda_in), np.float32(-params.lambda_out))
    rho = (acc / sigma * c).astype(np.complex64)
    seconds = time.perf_counter() - t0
    return Descriptor(rho=rho, grid=grid, params=params, triangles=int(len(part.faces)),
                      backend=backend, seconds=seconds, from_cache=False,
                      name=str(getattr(part, "name", "")), method="ladder",
                      compute_seconds=seconds, ladder=tuple(float(s) for s in sigmas))


def descriptor_preferring_ladder(part: Part, grid: Grid, params: DescriptorParams, *,
                                 method: str = "adaptive",
                                 progress: Callable[[float], None] | None = None,
                                 cancel: Callable[[], bool] | None = None) -> Descriptor:
    """The part's descriptor on ``grid``: cached, else from its cached ladder, else computed.

    A direct computation in the cache is exact and as quick; a ladder serves a sigma inside
    :data:`LADDER_SPAN` in about a second where the direct computation takes tens.
    """
    if (in_span(float(params.sigma)) and not descriptor_cached(part, grid, params, method=method)
            and ladder_cached(part, grid, params, method=method)):
        try:
            return interpolated_descriptor(part, grid, params, method=method)
        except LadderIncomplete:  # a node evicted since: computed as usual
            pass
    return descriptor_for_part(part, grid, params, method=method, progress=progress,
                               cancel=cancel)


def prepare_ladders(rungs: Sequence[tuple[Part, Grid]], params: DescriptorParams, *,
                    backend: BackendLike = None, method: str = "adaptive",
                    progress: Callable[[float], None] | None = None,
                    cancel: Callable[[], bool] | None = None) -> None:  # fmt: skip
    """Compute and cache the nodes missing from the ladders of ``(part, grid)`` pairs.

    As :func:`prepare_scene_ladder`, for any grids (the fine level's, for instance).
    """
    _compute_missing(list(rungs), params, backend=backend, method=method, span=LADDER_SPAN,
                     nodes=LADDER_NODES, progress=progress, cancel=cancel)


# --------------------------------------------------------------------------- scenes
def _scene_rungs(scene: Scene, parts: Sequence[Part]) -> list[_Rung]:
    spacing = scene_spacing(scene, parts)
    return [(p, grid_for_part(p, spacing=spacing, padding=scene.descriptor.padding))
            for p in parts]


def scene_ladder_cached(scene: Scene, parts: Sequence[Part], *,
                        method: str = "adaptive") -> bool:  # fmt: skip
    """Whether the ladder of every part of the scene, on the scene's grids, is cached."""
    return all(ladder_cached(p, g, scene.descriptor, method=method)
               for p, g in _scene_rungs(scene, parts))


def prepare_scene_ladder(scene: Scene, parts: Sequence[Part], *, backend: BackendLike = None,
                         method: str = "adaptive",
                         progress: Callable[[float], None] | None = None,
                         cancel: Callable[[], bool] | None = None) -> None:  # fmt: skip
    """Compute and cache the nodes missing from the scene's ladders (nothing is loaded).

    Progress runs 0..1 over both ladders, nodes already cached counted as done; a cancel
    (``engine.errors.Cancelled``) keeps every node finished before it.
    """
    _compute_missing(_scene_rungs(scene, parts), scene.descriptor, backend=backend,
                     method=method, span=LADDER_SPAN, nodes=LADDER_NODES, progress=progress,
                     cancel=cancel)


def ladder_descriptors_for_scene(scene: Scene, parts: Sequence[Part], *,
                                 method: str = "adaptive") -> list[Descriptor]:  # fmt: skip
    """Every part's descriptor at the scene's ``[descriptor]``, interpolated from its ladder.

    Raises as :func:`interpolated_descriptor` (outside the span, a node not cached).
    """
    return [interpolated_descriptor(p, g, scene.descriptor, method=method)
            for p, g in _scene_rungs(scene, parts)]
