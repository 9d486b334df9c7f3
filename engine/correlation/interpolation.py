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
    """Cubic Hermite interpolation of one real component: ``(G, dG/dux, dG/duy, dG/duz)``.

    ``col`` picks the component (0: real part, 1: imaginary part); ``cell`` is the lattice
    cell from :func:`cell`.

    Columns ``col`` (value ``v``) and ``col + 2``, ``col + 4``, ``col + 6`` (the lattice
    derivatives ``D_x``, ``D_y``, ``D_z``, from the moment spectra) give

        G = trilinear(v) + sum_a [w0(t_a) P_a - w1(t_a) Q_a],
        w0(t) = t (1 - t)^2,   w1(t) = t^2 (1 - t),

    ``P_a`` (``Q_a``) the bilinear interpolation, over the other two axes, of ``D_a`` on the
    cell's lower (upper) ``a``-face minus the value's difference along the edge ``a``.
    Along each lattice line this is the cubic Hermite interpolant of the values and
    derivatives at its ends; it reproduces every polynomial of degree 3, is continuous
    across cell faces, and *takes the node's own derivatives at every node*: its gradient
    is single-valued there, seen from any of the eight cells around it. That matters
    because rotations that map the lattice onto itself (``R = I``, a seated part, and the
    half turns) put every mode exactly on a node, and a pose a hair away puts it in any of
    the neighbouring cells; with an interpolant whose one-sided gradients differed at the
    nodes, the torque jumped there (the energy did not). Its gradient, differentiated
    exactly, is what the torque sums use, so the torque is the derivative of the energy
    that is reported.
    """
    b00, b01, b10, b11, tx, ty, tz = cell
    # corner values v[x][y][z]. "1.0 *" promotes a float32 entry to the precision of the
    # arithmetic (float64 in numba): the edge differences below are then exact, so the
    # eight cells around a node agree there to rounding of float64, not of float32 (a
    # float32 energy step of 3e-8 at a node reads as a 1 % torque in a central difference)
    v000 = 1.0 * table[b00, col]
    v001 = 1.0 * table[b00 + 1, col]
    v010 = 1.0 * table[b01, col]
    v011 = 1.0 * table[b01 + 1, col]
    v100 = 1.0 * table[b10, col]
    v101 = 1.0 * table[b10 + 1, col]
    v110 = 1.0 * table[b11, col]
    v111 = 1.0 * table[b11 + 1, col]
    # trilinear part: along z first, then bilinear over (x, y); its z-derivative is the
    # bilinear interpolation of the z differences
    e00 = v001 - v000
    e01 = v011 - v010
    e10 = v101 - v100
    e11 = v111 - v110
    g, gx, gy = bilinear(v000 + tz * e00, v010 + tz * e01, v100 + tz * e10, v110 + tz * e11,
                         tx, ty)
    gz = bilinear(e00, e01, e10, e11, tx, ty)[0]
    # x: derivative minus edge difference on the faces x = 0 (p) and x = 1 (q), over (y, z)
    c = col + 2
    d00 = v100 - v000
    d01 = v101 - v001
    d10 = v110 - v010
    d11 = v111 - v011
    p, py, pz = bilinear(table[b00, c] - d00, table[b00 + 1, c] - d01,
                         table[b01, c] - d10, table[b01 + 1, c] - d11, ty, tz)
    q, qy, qz = bilinear(table[b10, c] - d00, table[b10 + 1, c] - d01,
                         table[b11, c] - d10, table[b11 + 1, c] - d11, ty, tz)
    s = 1.0 - tx
    w0 = tx * s * s
    w1 = tx * tx * s
    g += w0 * p - w1 * q
    gx += s * (1.0 - 3.0 * tx) * p - tx * (2.0 - 3.0 * tx) * q
    gy += w0 * py - w1 * qy
    gz += w0 * pz - w1 * qz
    # y: faces y = 0 and y = 1, over (x, z)
    c = col + 4
    d00 = v010 - v000
    d01 = v011 - v001
    d10 = v110 - v100
    d11 = v111 - v101
    p, px, pz = bilinear(table[b00, c] - d00, table[b00 + 1, c] - d01,
                         table[b10, c] - d10, table[b10 + 1, c] - d11, tx, tz)
    q, qx, qz = bilinear(table[b01, c] - d00, table[b01 + 1, c] - d01,
                         table[b11, c] - d10, table[b11 + 1, c] - d11, tx, tz)
    s = 1.0 - ty
    w0 = ty * s * s
    w1 = ty * ty * s
    g += w0 * p - w1 * q
    gy += s * (1.0 - 3.0 * ty) * p - ty * (2.0 - 3.0 * ty) * q
    gx += w0 * px - w1 * qx
    gz += w0 * pz - w1 * qz
    # z: faces z = 0 and z = 1, over (x, y); the edge differences are e
    c = col + 6
    p, px, py = bilinear(table[b00, c] - e00, table[b01, c] - e01,
                         table[b10, c] - e10, table[b11, c] - e11, tx, ty)
    q, qx, qy = bilinear(table[b00 + 1, c] - e00, table[b01 + 1, c] - e01,
                         table[b10 + 1, c] - e10, table[b11 + 1, c] - e11, tx, ty)
    s = 1.0 - tz
    w0 = tz * s * s
    w1 = tz * tz * s
    g += w0 * p - w1 * q
    gz += s * (1.0 - 3.0 * tz) * p - tz * (2.0 - 3.0 * tz) * q
    gx += w0 * px - w1 * qx
    gy += w0 * py - w1 * qy
    return g, gx, gy, gz


def mode_terms(table, cell, c_re, c_im, rk0, rk1, rk2, moments):
    """One mode's contributions to the raw sums.

    These are ``Re(c G)``, ``Im(c G)`` and, with ``moments``, the torque terms
    ``Re(c dG/du) x R^T k`` (zeros without).

    ``c`` is the mode's coefficient (part 1's spectrum times the phase), ``G`` part 2's
    interpolated spectrum at the cell (cubic Hermite with ``moments``, trilinear
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
