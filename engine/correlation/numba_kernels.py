"""The per-pose sums compiled in process with numba: the fast path on CPUs.

Works on one :class:`~engine.correlation.tables.ModeTable` (part 1's kept coefficients
``(K, K, K)`` complex64 or a mode list, part 2's interleaved table ``(B^3, C)`` float32)
and one pose; returns ``[E, F (3), T (3)]`` as (7,) float64. The interpolation
(:mod:`engine.correlation.interpolation`) and the finishing and overlap test
(:mod:`engine.correlation.finishing`) are those modules' own Python functions, compiled
here; only the loop over the modes is written in this module.

Over the kept cube the phase factors are separable (three tables of ``K`` values per
pose); a mode list (selection "largest") needs one sine and cosine per mode.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import types
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba
import numpy as np

import engine.correlation.finishing as finishing
import engine.correlation.interpolation as interpolation
from engine.backend import env_count
from engine.correlation.tables import ModeTable, PerTable

# The functions below call the interpolation and finishing helpers by these names; numba
# resolves them, compiled, from the namespace :func:`_compiled` gives each function.
cell = interpolation.cell
mode_terms = interpolation.mode_terms
boxes_overlap = finishing.boxes_overlap
finish = finishing.finish
prange = numba.prange


def _pose_cube(
    rot, t, fixed_kept, table, radius, kept, c1, c2, half1, half2, h, n_h, q, kappa, moments,
):
    """Energy, force and torque at one pose over the kept cube: (7,) float64.

    fixed_kept (K, K, K) complex64; table (B^3, C) float32 interleaved (C = 8 or 2); kept
    (K,) float64. The partial sums are kept per kx plane, so that the kx loop can run in
    parallel without a shared accumulator and the result does not depend on the threads.
    """
    if not boxes_overlap(rot, t, c1, c2, half1, half2, h):
        return np.zeros(7)
    nk = kept.shape[0]
    side = 2 * radius + 2
    px = np.empty(nk, dtype=np.complex128)
    py = np.empty(nk, dtype=np.complex128)
    pz = np.empty(nk, dtype=np.complex128)
    scale = 2.0 * np.pi / n_h
    s = np.empty(3)
    for a in range(3):
        s[a] = t[a] + rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2] - c1[a]
    for i in range(nk):
        px[i] = np.exp(1j * (scale * kept[i] * s[0]))
        py[i] = np.exp(1j * (scale * kept[i] * s[1]))
        pz[i] = np.exp(1j * (scale * kept[i] * s[2]))
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    partial = np.zeros((nk, 7))
    for ix in prange(nk):
        kx = kept[ix]
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        s6 = 0.0
        for iy in range(nk):
            ky = kept[iy]
            pxy = px[ix] * py[iy]
            # R^T k = kx R[0,:] + ky R[1,:] + kz R[2,:]; lattice index u = -q R^T k
            a0 = kx * r00 + ky * r10
            a1 = kx * r01 + ky * r11
            a2 = kx * r02 + ky * r12
            row_im = 0.0
            for iz in range(nk):
                kz = kept[iz]
                rk0 = a0 + kz * r20
                rk1 = a1 + kz * r21
                rk2 = a2 + kz * r22
                at = cell(-q * rk0, -q * rk1, -q * rk2, radius, side)
                c = fixed_kept[ix, iy, iz] * pxy * pz[iz]
                cg_re, cg_im, d4, d5, d6 = mode_terms(
                    table, at, c.real, c.imag, rk0, rk1, rk2, moments
                )
                s0 += cg_re
                row_im += cg_im
                s3 += cg_im * kz
                s4 += d4
                s5 += d5
                s6 += d6
            s1 += row_im * kx
            s2 += row_im * ky
        partial[ix, 0] = s0
        partial[ix, 1] = s1
        partial[ix, 2] = s2
        partial[ix, 3] = s3
        partial[ix, 4] = s4
        partial[ix, 5] = s5
        partial[ix, 6] = s6
    return finish(_sum_rows(partial), rot, c2, kappa, n_h, q, moments)


def _pose_list(rot, t, kvec, coeff, table, radius, c1, c2, half1, half2, h, n_h, q, kappa,
               moments):
    """As :func:`_pose_cube` for any list of modes (selection "largest").

    kvec (m', 3) float64 signed frequency indices; coeff (m',) complex64 ``rho1c^(w) dw``.
    """
    if not boxes_overlap(rot, t, c1, c2, half1, half2, h):
        return np.zeros(7)
    side = 2 * radius + 2
    scale = 2.0 * np.pi / n_h
    s = np.empty(3)
    for a in range(3):
        s[a] = scale * (t[a] + rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2]
                        - c1[a])
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    nm = kvec.shape[0]
    nchunk = max(1, min(64, nm // 512))
    chunk = (nm + nchunk - 1) // nchunk
    partial = np.zeros((nchunk, 7))
    for ci in prange(nchunk):
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        s3 = 0.0
        s4 = 0.0
        s5 = 0.0
        s6 = 0.0
        for m in range(ci * chunk, min(nm, (ci + 1) * chunk)):
            kx = kvec[m, 0]
            ky = kvec[m, 1]
            kz = kvec[m, 2]
            rk0 = kx * r00 + ky * r10 + kz * r20
            rk1 = kx * r01 + ky * r11 + kz * r21
            rk2 = kx * r02 + ky * r12 + kz * r22
            at = cell(-q * rk0, -q * rk1, -q * rk2, radius, side)
            ph = kx * s[0] + ky * s[1] + kz * s[2]
            c = coeff[m] * (np.cos(ph) + 1j * np.sin(ph))
            cg_re, cg_im, d4, d5, d6 = mode_terms(
                table, at, c.real, c.imag, rk0, rk1, rk2, moments
            )
            s0 += cg_re
            s1 += cg_im * kx
            s2 += cg_im * ky
            s3 += cg_im * kz
            s4 += d4
            s5 += d5
            s6 += d6
        partial[ci, 0] = s0
        partial[ci, 1] = s1
        partial[ci, 2] = s2
        partial[ci, 3] = s3
        partial[ci, 4] = s4
        partial[ci, 5] = s5
        partial[ci, 6] = s6
    return finish(_sum_rows(partial), rot, c2, kappa, n_h, q, moments)


def _sum_rows(partial):
    """(7,) float64: the partial sums added up in a fixed order (thread-count independent)."""
    sums = np.zeros(7)
    for i in range(partial.shape[0]):
        for j in range(7):
            sums[j] += partial[i, j]
    return sums


_NAMESPACE: dict[str, Any] = {}
_KERNELS: dict[tuple[str, bool], Callable[..., Any]] = {}


def _compiled(func: Callable[..., Any], **options: Any) -> Any:
    """``func`` compiled, as a copy whose globals are the shared compiled namespace.

    The helpers it calls by name are then the compiled ones.
    """
    copy = types.FunctionType(func.__code__, _NAMESPACE, func.__name__)
    copy.__qualname__ = func.__qualname__
    copy.__doc__ = func.__doc__
    return numba.njit(fastmath=True, cache=True, nogil=True, **options)(copy)


def compiled_helpers() -> dict[str, Any]:
    """The namespace of the compiled interpolation and finishing helpers (built once)."""
    if not _NAMESPACE:
        _NAMESPACE.update({"__name__": __name__, "np": np, "prange": numba.prange})
        inlined: tuple[Callable[..., Any], ...] = interpolation.FUNCTIONS
        for helper in inlined:
            _NAMESPACE[helper.__name__] = _compiled(helper, inline="always")
        called: tuple[Callable[..., Any], ...] = (*finishing.FUNCTIONS, _sum_rows)
        for helper in called:
            _NAMESPACE[helper.__name__] = _compiled(helper)
    return _NAMESPACE


@functools.lru_cache(maxsize=1)
def helpers_digest() -> str:
    """Short digest of the helpers' source (interpolation and finishing modules).

    numba's on-disk cache checks only the file that defines a function, not the files of
    the functions it inlines: a kernel compiled before a change to the interpolation would
    be loaded again unchanged. The digest in the kernel's name gives every version of the
    helpers its own cache entry.
    """
    digest = hashlib.sha256()
    for module in (interpolation, finishing):
        digest.update(Path(inspect.getfile(module)).read_bytes())
    return digest.hexdigest()[:12]


def compile_with_helpers(source: Callable[..., Any], name: str, *, parallel: bool = False
                         ) -> Callable[..., Any]:
    """``source`` compiled under ``name``, with its own entry in numba's on-disk cache.

    The variant calls the compiled helpers of :func:`compiled_helpers` by their names; the
    cache entry is keyed by :func:`helpers_digest` as well.
    """
    namespace = compiled_helpers()
    name = f"{name}_{helpers_digest()}"
    variant = types.FunctionType(source.__code__.replace(co_name=name), namespace, name)
    variant.__qualname__ = name
    variant.__doc__ = source.__doc__
    return numba.njit(fastmath=True, cache=True, nogil=True, parallel=parallel)(variant)


def kernel_function(kind: str, parallel: bool) -> Callable[..., Any]:
    """The compiled sum over the cube (``kind`` "cube") or a mode list ("list")."""
    key = (kind, parallel)
    if key not in _KERNELS:
        source = _pose_cube if kind == "cube" else _pose_list
        name = f"{source.__name__}_{'parallel' if parallel else 'serial'}"
        _KERNELS[key] = compile_with_helpers(source, name, parallel=parallel)
    return _KERNELS[key]


def compile_now(kind: str) -> None:
    """Compile (or load from numba's disk cache) the serial kernel of ``kind``.

    Calls it once with arguments of the real types at a pose whose boxes are apart (it
    returns at once). Lets a caller start the compilation early, on a worker thread.
    """
    kernel_function(kind, False)(*warm_arguments(kind))


def warm_arguments(kind: str) -> tuple[Any, ...]:
    """Arguments of the real types for ``kind``'s kernel, at a pose whose boxes are apart.

    The types must be those :meth:`NumbaKernel.pose` passes (numba compiles one variant
    per argument type).
    """
    far = np.array([1e9, 0.0, 0.0])
    zero, one = np.zeros(3), np.ones(3)
    table = np.zeros((8, 8), dtype=np.float32)
    if kind == "cube":
        modes: tuple[Any, ...] = (np.zeros((1, 1, 1), dtype=np.complex64), table, 0,
                                  np.zeros(1))
    else:
        modes = (np.zeros((1, 3)), np.zeros(1, dtype=np.complex64), table, 0)
    return (np.eye(3), far, *modes, zero, zero, one, one, 1.0, 10.0, 1.0, 1.0, True)


class NumbaKernel:
    """Per-pose sums compiled with numba; one thread unless asked for more.

    ``SKELASM_CORRELATION_THREADS`` asks for more threads; a parallel variant is then
    compiled too, and ``engine.correlation.per_pose._tune_threads`` keeps it only where it
    measures clearly faster. On a shared 2-core machine a parallel region whose second
    thread is not scheduled stalls for a whole time slice (a benchmark saw medians of 36 ms
    instead of 80 us), which a 1 kHz loop cannot take, hence one thread by default.
    """

    name = "numba"

    def __init__(self, selection: str) -> None:
        wanted = env_count("SKELASM_CORRELATION_THREADS", 1)
        self.threads = max(1, min(wanted, numba.get_num_threads()))
        self.kind = "cube" if selection == "cube" else "list"
        self._serial = kernel_function(self.kind, False)
        self._parallel = kernel_function(self.kind, True) if self.threads > 1 else None
        if self._parallel is not None:
            numba.set_num_threads(self.threads)
        self.parallel = False
        #: Each table's kernel arguments, made on its first use (safe across threads).
        self.per_table: PerTable[tuple[Any, ...]] = PerTable(_arguments)

    @property
    def can_parallel(self) -> bool:
        """Whether a parallel variant exists (more than one thread asked for)."""
        return self._parallel is not None

    def describe(self) -> str:
        """Name and thread count."""
        return f"numba ({self.threads} threads)" if self.parallel else "numba (1 thread)"

    def supports(self, table: ModeTable) -> bool:
        """Whether this kernel can sum ``table`` (its interleaved table exists)."""
        return table.moving is not None

    def pose(self, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 ``[E, F (3), T (3)]`` at one pose."""
        args = self.per_table.get(table)
        rot = _plain(rot)
        t = _plain(t)
        if self.parallel and self._parallel is not None:
            return self._parallel(rot, t, *args)
        return self._serial(rot, t, *args)


def _plain(a: np.ndarray) -> np.ndarray:
    """``a`` as a writable C-ordered float64 array (a copy only when it is not one).

    numba compiles one variant per argument type, and a read-only array (a scene's pose,
    a view of a cached file) or a transposed one is another type: the kernel compiled
    ahead of time by :func:`compile_now` would then be compiled a second time, seconds
    more, on the first pose.
    """
    if a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=np.float64, order="C")


def _arguments(table: ModeTable) -> tuple[Any, ...]:
    """The kernel's arguments after the pose, from a table."""
    g = table.geometry
    w = _writable
    radius = int(table.radius)
    if table.kept is not None:
        modes: tuple[Any, ...] = (w(table.fixed_kept), w(table.moving), radius, w(table.kept))
    else:
        modes = (w(table.mode_k), w(table.mode_a), w(table.moving), radius)
    # Plain Python scalars and writable C arrays: the types compile_now compiled for.
    return (*modes, _plain(g.centre_fixed), _plain(g.centre_moving), _plain(g.half_fixed),
            _plain(g.half_moving), float(g.spacing), float(g.n_h), float(table.scale),
            float(g.kappa), bool(g.rotation))


def _writable(a: Any) -> Any:
    """A writable C-ordered array of ``a``'s dtype (a copy only when ``a`` is not one)."""
    if a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, order="C")
