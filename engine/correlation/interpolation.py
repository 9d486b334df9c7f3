"""Interpolation of part 2's spectrum at rotated frequencies: the one definition.

The functions here read a table of interleaved float32 rows, ``(B^3, C)``: for each lattice
node the real and imaginary part of the centred spectrum ``G`` and, when ``C = 8``, of its
lattice derivatives ``dG/du`` along x, y and z (from the moment spectra). A lattice *cell*
is given by the row of its lower corner ``b00``, its +y neighbour ``b01``, +x neighbour
``b10`` and +x+y neighbour ``b11`` (the +z neighbour of each is the next row), and the
fractional position ``(tx, ty, tz)`` in the cell.

These plain Python functions are the only definition of the interpolation:

* the numpy reference (:mod:`engine.correlation.reference`) calls them on index and position
  arrays;
* the numba kernels (:mod:`engine.correlation.numba_kernels`) compile them, inlined;
* the OpenCL kernel's C functions are generated from their source
  (:func:`engine.correlation.to_opencl.translate`), not retyped.

So they are written in the small subset of Python all three accept: scalar arithmetic,
tuple returns, ``table[row, column]`` reads, ``np.floor`` and ``int``, and ``if`` on a
flag. :data:`SIGNATURES` gives their C types.
"""

from __future__ import annotations

import numpy as np


def cell(ux, uy, uz, radius, side):
    """Lattice cell of the point ``(ux, uy, uz)``: ``(b00, b01, b10, b11, tx, ty, tz)``.

    The table has ``side^3`` rows and its index 0 lies at ``radius``. ``bij`` are the row
    indices of the cell's corners, ``t*`` the fractional position inside it.
    """
    fx = np.floor(ux)
    fy = np.floor(uy)
    fz = np.floor(uz)
    b00 = ((int(fx) + radius) * side + int(fy) + radius) * side + int(fz) + radius
    return (b00, b00 + side, b00 + side * side, b00 + side * side + side,
            ux - fx, uy - fy, uz - fz)


def bilinear(d00, d01, d10, d11, u, v):
    """Bilinear interpolation at ``(u, v)`` and its two derivatives: ``(value, d/du, d/dv)``.

    Interpolates the four corner values ``d[i][j]`` (``i`` along ``u``, ``j`` along ``v``).
    """
    l0 = d00 + v * (d01 - d00)
    l1 = d10 + v * (d11 - d10)
    return l0 + u * (l1 - l0), l1 - l0, (d01 - d00) + u * ((d11 - d10) - (d01 - d00))


def lerp(table, col, cell):
    """Column ``col`` of the table, interpolated trilinearly in ``cell``."""
    b00, b01, b10, b11, tx, ty, tz = cell
    a00 = table[b00, col] + tz * (table[b00 + 1, col] - table[b00, col])
    a01 = table[b01, col] + tz * (table[b01 + 1, col] - table[b01, col])
    a10 = table[b10, col] + tz * (table[b10 + 1, col] - table[b10, col])
    a11 = table[b11, col] + tz * (table[b11 + 1, col] - table[b11, col])
    value = bilinear(a00, a01, a10, a11, tx, ty)[0]
    return value


def hermite(table, col, cell):
    """Gradient-enhanced interpolation of one real component: ``(G, dG/dux, dG/duy, dG/duz)``.

    ``col`` picks the component (0: real part, 1: imaginary part); ``cell`` is the lattice
    cell from :func:`cell`.

    Columns ``col`` (value ``v``) and ``col + 2``, ``col + 4``, ``col + 6`` (the lattice
    derivatives along x, y, z, from the moment spectra) give

        G = trilinear(v) + 1/2 sum_a t_a (1 - t_a) B_a,

    ``B_a`` the bilinear interpolation, over the other two axes, of the drop of the
    ``a``-derivative across the cell (lower face minus upper face). This is exact for
    quadratics (trilinear alone only for linear functions) and continuous across cell
    faces; its gradient, differentiated exactly, is what the torque sums use, so the torque
    is the derivative of the energy that is reported.
    """
    b00, b01, b10, b11, tx, ty, tz = cell
    # trilinear part: along z first, then bilinear over (x, y); its z-derivative is the
    # bilinear interpolation of the z differences
    v000 = table[b00, col]
    v010 = table[b01, col]
    v100 = table[b10, col]
    v110 = table[b11, col]
    e00 = table[b00 + 1, col] - v000
    e01 = table[b01 + 1, col] - v010
    e10 = table[b10 + 1, col] - v100
    e11 = table[b11 + 1, col] - v110
    g, gx, gy = bilinear(v000 + tz * e00, v010 + tz * e01, v100 + tz * e10, v110 + tz * e11,
                         tx, ty)
    gz = bilinear(e00, e01, e10, e11, tx, ty)[0]
    # x: drop X(0, y, z) - X(1, y, z), bilinear over (y, z)
    c = col + 2
    b, by, bz = bilinear(table[b00, c] - table[b10, c], table[b00 + 1, c] - table[b10 + 1, c],
                         table[b01, c] - table[b11, c], table[b01 + 1, c] - table[b11 + 1, c],
                         ty, tz)
    p = 0.5 * tx * (1.0 - tx)
    g += p * b
    gx += (0.5 - tx) * b
    gy += p * by
    gz += p * bz
    # y: drop Y(x, 0, z) - Y(x, 1, z), bilinear over (x, z)
    c = col + 4
    b, bx, bz = bilinear(table[b00, c] - table[b01, c], table[b00 + 1, c] - table[b01 + 1, c],
                         table[b10, c] - table[b11, c], table[b10 + 1, c] - table[b11 + 1, c],
                         tx, tz)
    p = 0.5 * ty * (1.0 - ty)
    g += p * b
    gy += (0.5 - ty) * b
    gx += p * bx
    gz += p * bz
    # z: drop Z(x, y, 0) - Z(x, y, 1), bilinear over (x, y)
    c = col + 6
    b, bx, by = bilinear(table[b00, c] - table[b00 + 1, c], table[b01, c] - table[b01 + 1, c],
                         table[b10, c] - table[b10 + 1, c], table[b11, c] - table[b11 + 1, c],
                         tx, ty)
    p = 0.5 * tz * (1.0 - tz)
    g += p * b
    gz += (0.5 - tz) * b
    gx += p * bx
    gy += p * by
    return g, gx, gy, gz


def mode_terms(table, cell, c_re, c_im, rk0, rk1, rk2, moments):
    """One mode's contributions to the raw sums.

    These are ``Re(c G)``, ``Im(c G)`` and, with ``moments``, the torque terms
    ``Re(c dG/du) x R^T k`` (zeros without).

    ``c`` is the mode's coefficient (part 1's spectrum times the phase), ``G`` part 2's
    interpolated spectrum at the cell (gradient-enhanced with ``moments``, trilinear
    without) and ``R^T k = (rk0, rk1, rk2)``.
    """
    if moments:
        g_re, gx_re, gy_re, gz_re = hermite(table, 0, cell)
        g_im, gx_im, gy_im, gz_im = hermite(table, 1, cell)
        r0 = c_re * gx_re - c_im * gx_im
        r1 = c_re * gy_re - c_im * gy_im
        r2 = c_re * gz_re - c_im * gz_im
        t0 = r1 * rk2 - r2 * rk1
        t1 = r2 * rk0 - r0 * rk2
        t2 = r0 * rk1 - r1 * rk0
    else:
        g_re = lerp(table, 0, cell)
        g_im = lerp(table, 1, cell)
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
    return c_re * g_re - c_im * g_im, c_re * g_im + c_im * g_re, t0, t1, t2


#: The C types of the functions above, for the OpenCL translation: argument types in order,
#: and the result (one type, or a tuple of types returned through pointers). ``cell_t`` is
#: the struct ``{int b00, b01, b10, b11; float tx, ty, tz}``; ``table`` is the interleaved
#: table in global memory with ``CHANNELS`` floats per row.
SIGNATURES: dict[str, tuple[tuple[str, ...], str | tuple[str, ...]]] = {
    "cell": (("float", "float", "float", "int", "int"), "cell_t"),
    "bilinear": (("float",) * 6, ("float", "float", "float")),
    "lerp": (("table", "int", "cell_t"), "float"),
    "hermite": (("table", "int", "cell_t"), ("float",) * 4),
    "mode_terms": (("table", "cell_t") + ("float",) * 5 + ("int",), ("float",) * 5),
}

#: The functions in an order in which each one's callees come first.
FUNCTIONS = (cell, bilinear, lerp, hermite, mode_terms)
