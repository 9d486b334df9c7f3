"""Per-pose evaluation from products kept at a reference rotation: no gathers per pose.

Works on one :class:`~engine.correlation.tables.ModeTable` (kept cube, rotation on) and a
reference rotation ``R0``. :func:`build_rotation_cache` interpolates part 2's spectrum
once at ``u0 = -q R0^T k`` for every kept mode (value ``G0`` and lattice gradient ``g0``,
cubic Hermite) and keeps, with part 1's coefficients ``c1`` folded in,

    A(k) = c1 (G0 - g0 . u0),     B(k) = c1 g0          (8 float32 per mode)

so that ``c1 G(u) ~ A + B . u`` to first order around ``u0``. Per pose (:func:`cached_pose`)
``u = -q R^T k`` and the phases ``exp(2 pi i k.(t + R c2 - c1) / (N h))`` are separable, so
the sums contract the cube axis by axis: the ``K^3`` work is eleven complex accumulations
per mode over contiguous memory (the z axis), the rest is ``K^2`` work; no table is
gathered. The raw sums of this model energy are finished by
:func:`engine.correlation.finishing.finish` as for every other path, so force and torque
are the exact derivatives of the energy reported from the cache.

The model differs from the full interpolation by second-order terms in the rotation since
``R0``: measured on the peg at K = 32, energy 1.5e-6 and force 4e-6 relative at 1 mrad,
torque 0.9 % (its first-order term); so a caller refreshes the cache (a worker calls
:func:`build_rotation_cache` again, it only reads the table) when the rotation has moved
by about a milliradian, and swaps the new cache in.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# the kernels below call these by name; numba resolves them compiled (see numba_kernels)
from engine.correlation.finishing import boxes_overlap, finish
from engine.correlation.interpolation import cell, hermite
from engine.correlation.numba_kernels import compile_with_helpers
from engine.correlation.tables import ModeTable


@dataclass(frozen=True, eq=False)
class RotationCache:
    """The kept products at one reference rotation (immutable).

    Attributes
    ----------
    table : ModeTable
        The truncation the products belong to.
    rotation : (3, 3) float64
        The reference rotation ``R0``.
    products : (8, K, K, K) float32
        ``A`` real, ``A`` imaginary, then ``B`` along x, y, z (real, imaginary).
    """

    table: ModeTable
    rotation: np.ndarray
    products: np.ndarray


def _refresh(rot, fixed_kept, table, radius, kept, q, out):
    """Fill ``out`` (8, K, K, K) with A and B at rotation ``rot`` (see module docstring)."""
    nk = kept.shape[0]
    side = 2 * radius + 2
    for ix in range(nk):
        for iy in range(nk):
            for iz in range(nk):
                rk0 = kept[ix] * rot[0, 0] + kept[iy] * rot[1, 0] + kept[iz] * rot[2, 0]
                rk1 = kept[ix] * rot[0, 1] + kept[iy] * rot[1, 1] + kept[iz] * rot[2, 1]
                rk2 = kept[ix] * rot[0, 2] + kept[iy] * rot[1, 2] + kept[iz] * rot[2, 2]
                u0 = -q * rk0
                u1 = -q * rk1
                u2 = -q * rk2
                at = cell(u0, u1, u2, radius, side)
                g_re, gx_re, gy_re, gz_re = hermite(table, 0, at)
                g_im, gx_im, gy_im, gz_im = hermite(table, 1, at)
                c = fixed_kept[ix, iy, iz]
                a = c * ((g_re + 1j * g_im) - (gx_re + 1j * gx_im) * u0
                         - (gy_re + 1j * gy_im) * u1 - (gz_re + 1j * gz_im) * u2)
                bx = c * (gx_re + 1j * gx_im)
                by = c * (gy_re + 1j * gy_im)
                bz = c * (gz_re + 1j * gz_im)
                out[0, ix, iy, iz] = a.real
                out[1, ix, iy, iz] = a.imag
                out[2, ix, iy, iz] = bx.real
                out[3, ix, iy, iz] = bx.imag
                out[4, ix, iy, iz] = by.real
                out[5, ix, iy, iz] = by.imag
                out[6, ix, iy, iz] = bz.real
                out[7, ix, iy, iz] = bz.imag


def _pose(rot, t, products, kept, c1, c2, half1, half2, h, n_h, q, kappa):
    """(7,) ``[E, F (3), T (3)]`` of the model at one pose (zeros where boxes are apart)."""
    if not boxes_overlap(rot, t, c1, c2, half1, half2, h):
        return np.zeros(7)
    nk = kept.shape[0]
    w = 2.0 * np.pi / n_h
    s = np.empty(3)
    for a in range(3):
        s[a] = t[a] + rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2] - c1[a]
    px = np.exp(1j * w * kept * s[0])
    py = np.exp(1j * w * kept * s[1])
    pzr = np.cos(w * kept * s[2]).astype(np.float32)
    pzi = np.sin(w * kept * s[2]).astype(np.float32)
    kz1 = kept.astype(np.float32)
    kz2 = kz1 * kz1
    acc = np.zeros((3, 3, 2))  # per B axis: sums of pz B, pz B kz, pz B kz^2 (re, im)
    sums = np.zeros(7)
    for ix in range(nk):
        kx = kept[ix]
        for iy in range(nk):
            ky = kept[iy]
            # the z contraction: eleven complex sums, contiguous float32
            ar = products[0, ix, iy]
            ai = products[1, ix, iy]
            za_r = np.float32(0.0)
            za_i = np.float32(0.0)
            za1_r = np.float32(0.0)
            za1_i = np.float32(0.0)
            for iz in range(nk):
                cr = pzr[iz] * ar[iz] - pzi[iz] * ai[iz]
                ci = pzr[iz] * ai[iz] + pzi[iz] * ar[iz]
                za_r += cr
                za_i += ci
                za1_r += cr * kz1[iz]
                za1_i += ci * kz1[iz]
            for b in range(3):
                br = products[2 + 2 * b, ix, iy]
                bi = products[3 + 2 * b, ix, iy]
                r0 = np.float32(0.0)
                i0 = np.float32(0.0)
                r1 = np.float32(0.0)
                i1 = np.float32(0.0)
                r2 = np.float32(0.0)
                i2 = np.float32(0.0)
                for iz in range(nk):
                    cr = pzr[iz] * br[iz] - pzi[iz] * bi[iz]
                    ci = pzr[iz] * bi[iz] + pzi[iz] * br[iz]
                    r0 += cr
                    i0 += ci
                    r1 += cr * kz1[iz]
                    i1 += ci * kz1[iz]
                    r2 += cr * kz2[iz]
                    i2 += ci * kz2[iz]
                acc[b, 0, 0] = r0
                acc[b, 0, 1] = i0
                acc[b, 1, 0] = r1
                acc[b, 1, 1] = i1
                acc[b, 2, 0] = r2
                acc[b, 2, 1] = i2
            # R^T k = (a_c + kz R[2, c]); u = -q R^T k; sum_z pz (A + B.u) [kz]
            z0 = za_r + 1j * za_i
            z1 = za1_r + 1j * za1_i
            pxy = px[ix] * py[iy]
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            for c in range(3):
                a_c = kx * rot[0, c] + ky * rot[1, c]
                y0 = acc[c, 0, 0] + 1j * acc[c, 0, 1]
                y1 = acc[c, 1, 0] + 1j * acc[c, 1, 1]
                y2 = acc[c, 2, 0] + 1j * acc[c, 2, 1]
                z0 -= q * (a_c * y0 + rot[2, c] * y1)
                z1 -= q * (a_c * y1 + rot[2, c] * y2)
            # torque sums: sum Re(phase B_b) (R^T k)_c = Re(pxy (y0_b a_c + y1_b R[2, c]))
            p = np.empty((3, 3))
            for b in range(3):
                y0 = acc[b, 0, 0] + 1j * acc[b, 0, 1]
                y1 = acc[b, 1, 0] + 1j * acc[b, 1, 1]
                for c in range(3):
                    a_c = kx * rot[0, c] + ky * rot[1, c]
                    p[b, c] = (pxy * (y0 * a_c + y1 * rot[2, c])).real
            t0 = p[1, 2] - p[2, 1]
            t1 = p[2, 0] - p[0, 2]
            t2 = p[0, 1] - p[1, 0]
            f0 = pxy * z0
            f1 = pxy * z1
            sums[0] += f0.real
            sums[1] += f0.imag * kx
            sums[2] += f0.imag * ky
            sums[3] += f1.imag
            sums[4] += t0
            sums[5] += t1
            sums[6] += t2
    return finish(sums, rot, c2, kappa, n_h, q, True)


_COMPILED: dict[str, Any] = {}


def _kernel(name: str) -> Any:
    if name not in _COMPILED:
        source = _refresh if name == "refresh" else _pose
        _COMPILED[name] = compile_with_helpers(source, f"rotation_cache{source.__name__}")
    return _COMPILED[name]


def build_rotation_cache(table: ModeTable, rotation: np.ndarray) -> RotationCache:
    """The products of ``table``'s kept cube at ``rotation`` (reads only; any thread).

    Raises
    ------
    ValueError
        The table is not a cube with moment spectra and an interleaved table.
    """
    if (table.kept is None or table.fixed_kept is None or table.moving is None
            or not table.geometry.rotation):
        raise ValueError("a rotation cache needs the kept cube with rotation on and a "
                         "table the compiled kernels can read")
    rot = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
    k = len(table.kept)
    products = np.empty((8, k, k, k), dtype=np.float32)
    _kernel("refresh")(rot, table.fixed_kept, table.moving, table.radius, table.kept,
                       float(table.scale), products)
    products.setflags(write=False)
    return RotationCache(table=table, rotation=rot, products=products)


def cached_pose(cache: RotationCache, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(7,) float64 ``[E, F (3), T (3)]`` of the cached model at one pose."""
    table = cache.table
    g = table.geometry
    assert table.kept is not None
    return _kernel("pose")(rot, t, cache.products, table.kept, g.centre_fixed,
                           g.centre_moving, g.half_fixed, g.half_moving, g.spacing, g.n_h,
                           float(table.scale), g.kappa)
