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
    kz : (K,) float32
        The kept frequency indices along one axis.
    geometry : (15,) float64
        ``c1, c2, half1, half2`` (3 each), ``h``, ``N h``, ``q``: what a pose reads of the
        pair's geometry, in one array (one argument for the compiled kernel).
    """

    table: ModeTable
    rotation: np.ndarray
    products: np.ndarray
    kz: np.ndarray
    geometry: np.ndarray


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


def _pose(rot, rot0, t, products, kz, geo, kappa):
    """(8,) ``[E, F (3), T (3), angle]`` of the model at one pose.

    ``geo`` packs ``c1, c2, half1, half2`` (3 each), ``h``, ``N h``, ``q`` (see
    :func:`_geometry`); ``kz`` is the kept cube's index as float32. The last entry is the
    angle of ``rot`` from the cache's rotation ``rot0`` (radians); E, F and T are zeros where
    the boxes are apart.
    """
    # ||R - R0||_F = 2 sqrt(2) sin(angle / 2)
    d2 = 0.0
    for a in range(3):
        for b in range(3):
            d = rot[a, b] - rot0[a, b]
            d2 += d * d
    half = np.sqrt(d2) / (2.0 * np.sqrt(2.0))
    angle = 2.0 * np.arcsin(min(half, 1.0))
    c1 = geo[0:3]
    c2 = geo[3:6]
    n_h = geo[13]
    q = geo[14]
    if not boxes_overlap(rot, t, c1, c2, geo[6:9], geo[9:12], geo[12]):
        out = np.zeros(8)
        out[7] = angle
        return out
    nk = kz.shape[0]
    w = 2.0 * np.pi / n_h
    s0 = t[0] + rot[0, 0] * c2[0] + rot[0, 1] * c2[1] + rot[0, 2] * c2[2] - c1[0]
    s1 = t[1] + rot[1, 0] * c2[0] + rot[1, 1] * c2[1] + rot[1, 2] * c2[2] - c1[1]
    s2 = t[2] + rot[2, 0] * c2[0] + rot[2, 1] * c2[1] + rot[2, 2] * c2[2] - c1[2]
    # phases along y and z (float64 angles, float32 z factors for the contraction)
    pyr = np.empty(nk)
    pyi = np.empty(nk)
    pzr = np.empty(nk, dtype=np.float32)
    pzi = np.empty(nk, dtype=np.float32)
    kz2 = np.empty(nk, dtype=np.float32)
    for i in range(nk):
        k = np.float64(kz[i])
        pyr[i] = np.cos(w * k * s1)
        pyi[i] = np.sin(w * k * s1)
        pzr[i] = np.cos(w * k * s2)
        pzi[i] = np.sin(w * k * s2)
        kz2[i] = kz[i] * kz[i]
    r20 = rot[2, 0]
    r21 = rot[2, 1]
    r22 = rot[2, 2]
    e_sum = 0.0
    sk0 = 0.0
    sk1 = 0.0
    sk2 = 0.0
    su0 = 0.0
    su1 = 0.0
    su2 = 0.0
    for ix in range(nk):
        kx = np.float64(kz[ix])
        pxr = np.cos(w * kx * s0)
        pxi = np.sin(w * kx * s0)
        for iy in range(nk):
            ky = np.float64(kz[iy])
            ar = products[0, ix, iy]
            ai = products[1, ix, iy]
            bxr = products[2, ix, iy]
            bxi = products[3, ix, iy]
            byr = products[4, ix, iy]
            byi = products[5, ix, iy]
            bzr = products[6, ix, iy]
            bzi = products[7, ix, iy]
            # the z contraction, one pass over contiguous float32 rows: sums of pz A,
            # pz A kz and, per B axis, of pz B, pz B kz, pz B kz^2 (re, im)
            a0r = np.float32(0.0)
            a0i = np.float32(0.0)
            a1r = np.float32(0.0)
            a1i = np.float32(0.0)
            x0r = np.float32(0.0)
            x0i = np.float32(0.0)
            x1r = np.float32(0.0)
            x1i = np.float32(0.0)
            x2r = np.float32(0.0)
            x2i = np.float32(0.0)
            y0r = np.float32(0.0)
            y0i = np.float32(0.0)
            y1r = np.float32(0.0)
            y1i = np.float32(0.0)
            y2r = np.float32(0.0)
            y2i = np.float32(0.0)
            z0r = np.float32(0.0)
            z0i = np.float32(0.0)
            z1r = np.float32(0.0)
            z1i = np.float32(0.0)
            z2r = np.float32(0.0)
            z2i = np.float32(0.0)
            for iz in range(nk):
                pr = pzr[iz]
                pi = pzi[iz]
                k1 = kz[iz]
                k2 = kz2[iz]
                cr = pr * ar[iz] - pi * ai[iz]
                ci = pr * ai[iz] + pi * ar[iz]
                a0r += cr
                a0i += ci
                a1r += cr * k1
                a1i += ci * k1
                cr = pr * bxr[iz] - pi * bxi[iz]
                ci = pr * bxi[iz] + pi * bxr[iz]
                x0r += cr
                x0i += ci
                x1r += cr * k1
                x1i += ci * k1
                x2r += cr * k2
                x2i += ci * k2
                cr = pr * byr[iz] - pi * byi[iz]
                ci = pr * byi[iz] + pi * byr[iz]
                y0r += cr
                y0i += ci
                y1r += cr * k1
                y1i += ci * k1
                y2r += cr * k2
                y2i += ci * k2
                cr = pr * bzr[iz] - pi * bzi[iz]
                ci = pr * bzi[iz] + pi * bzr[iz]
                z0r += cr
                z0i += ci
                z1r += cr * k1
                z1i += ci * k1
                z2r += cr * k2
                z2i += ci * k2
            # R^T k = (a_c + kz R[2, c]) with a_c = kx R[0, c] + ky R[1, c]
            ac0 = kx * rot[0, 0] + ky * rot[1, 0]
            ac1 = kx * rot[0, 1] + ky * rot[1, 1]
            ac2 = kx * rot[0, 2] + ky * rot[1, 2]
            xb0 = np.float64(x0r) + 1j * np.float64(x0i)
            xb1 = np.float64(x1r) + 1j * np.float64(x1i)
            xb2 = np.float64(x2r) + 1j * np.float64(x2i)
            yb0 = np.float64(y0r) + 1j * np.float64(y0i)
            yb1 = np.float64(y1r) + 1j * np.float64(y1i)
            yb2 = np.float64(y2r) + 1j * np.float64(y2i)
            zb0 = np.float64(z0r) + 1j * np.float64(z0i)
            zb1 = np.float64(z1r) + 1j * np.float64(z1i)
            zb2 = np.float64(z2r) + 1j * np.float64(z2i)
            # sum_z pz (A + B.u) [kz], u = -q R^T k
            f0 = (np.float64(a0r) + 1j * np.float64(a0i)
                  - q * (ac0 * xb0 + r20 * xb1 + ac1 * yb0 + r21 * yb1 + ac2 * zb0 + r22 * zb1))
            f1 = (np.float64(a1r) + 1j * np.float64(a1i)
                  - q * (ac0 * xb1 + r20 * xb2 + ac1 * yb1 + r21 * yb2 + ac2 * zb1 + r22 * zb2))
            pxy = (pxr + 1j * pxi) * (pyr[iy] + 1j * pyi[iy])
            # torque sums: p[b, c] = Re(pxy (y0_b a_c + y1_b R[2, c])); T = p[b, c] - p[c, b]
            pxz = (pxy * (xb0 * ac2 + xb1 * r22)).real
            pzx = (pxy * (zb0 * ac0 + zb1 * r20)).real
            pyz = (pxy * (yb0 * ac2 + yb1 * r22)).real
            pzy = (pxy * (zb0 * ac1 + zb1 * r21)).real
            pxy_ = (pxy * (xb0 * ac1 + xb1 * r21)).real
            pyx = (pxy * (yb0 * ac0 + yb1 * r20)).real
            g0 = pxy * f0
            g1 = pxy * f1
            e_sum += g0.real
            sk0 += g0.imag * kx
            sk1 += g0.imag * ky
            sk2 += g1.imag
            su0 += pyz - pzy
            su1 += pzx - pxz
            su2 += pxy_ - pyx
    sums = np.empty(7)
    sums[0] = e_sum
    sums[1] = sk0
    sums[2] = sk1
    sums[3] = sk2
    sums[4] = su0
    sums[5] = su1
    sums[6] = su2
    done = finish(sums, rot, c2, kappa, n_h, q, True)
    out = np.empty(8)
    for i in range(7):
        out[i] = done[i]
    out[7] = angle
    return out


_COMPILED: dict[str, Any] = {}


def _kernel(name: str) -> Any:
    if name not in _COMPILED:
        source = _refresh if name == "refresh" else _pose
        _COMPILED[name] = compile_with_helpers(source, f"rotation_cache{source.__name__}")
    return _COMPILED[name]


def _geometry(table: ModeTable) -> np.ndarray:
    g = table.geometry
    out = np.concatenate([g.centre_fixed, g.centre_moving, g.half_fixed, g.half_moving,
                          [g.spacing, g.n_h, float(table.scale)]]).astype(np.float64)
    out.setflags(write=False)
    return out


def build_rotation_cache(table: ModeTable, rotation: np.ndarray) -> RotationCache:
    """The products of ``table``'s kept cube at ``rotation`` (reads only; any thread).

    The compiled refresh releases the interpreter lock, so a worker thread building a cache
    does not hold up a thread evaluating poses.

    Raises
    ------
    ValueError
        The table is not a cube with moment spectra and an interleaved table.
    """
    if not serves(table):
        raise ValueError("a rotation cache needs the kept cube with rotation on and a "
                         "table the compiled kernels can read")
    assert table.kept is not None
    rot = np.array(rotation, dtype=np.float64).reshape(3, 3)
    rot.setflags(write=False)
    k = len(table.kept)
    products = np.empty((8, k, k, k), dtype=np.float32)
    _kernel("refresh")(rot, table.fixed_kept, table.moving, table.radius, table.kept,
                       float(table.scale), products)
    products.setflags(write=False)
    kz = np.asarray(table.kept, dtype=np.float32).copy()
    kz.setflags(write=False)
    return RotationCache(table=table, rotation=rot, products=products, kz=kz,
                         geometry=_geometry(table))


def serves(table: ModeTable) -> bool:
    """Whether a rotation cache can be built from ``table``.

    The kept cube, rotation on (moment spectra), and part 2's interleaved table present.
    """
    return (table.kept is not None and table.fixed_kept is not None
            and table.moving is not None and bool(table.geometry.rotation))


def cached_pose(cache: RotationCache, rot: np.ndarray, t: np.ndarray,
                kappa: float | None = None) -> np.ndarray:
    """(8,) float64 ``[E, F (3), T (3), angle]`` of the cached model at one pose.

    ``rot`` (3, 3) and ``t`` (3,) contiguous float64; ``kappa`` the energy scale (default:
    the pair's); ``angle`` (radians) is how far ``rot`` is from the cache's rotation.
    """
    k = cache.table.geometry.kappa if kappa is None else kappa
    return _kernel("pose")(rot, cache.rotation, t, cache.products, cache.kz, cache.geometry,
                           float(k))
