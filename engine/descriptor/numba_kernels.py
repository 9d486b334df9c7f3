"""Numba kernels of the skeletal density (the "numba" backend; float64).

Work on the packed triangles and hierarchy of :mod:`engine.descriptor.tree` in local units
(grid cells about the grid centre) and query points ``(k, 3) float64`` in the same units.
One call of :func:`evaluate` fills, per point, the winding number, the signed distance and
the boundary sum of the skeletal density (docs/descriptor.md gives the mathematics). The
OpenCL source in :mod:`engine.descriptor.opencl_kernels` mirrors these functions line by
line. Every quadrature constant arrives in a :class:`engine.descriptor.constants.KernelConstants`
argument ``kc``: numba freezes globals into its on-disk cache, arguments it cannot.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def _seg_closest(px, py, pz, ax, ay, az, bx, by, bz):  # pragma: no cover - compiled
    ux = bx - ax
    uy = by - ay
    uz = bz - az
    uu = ux * ux + uy * uy + uz * uz
    t = 0.0
    if uu > 0.0:
        t = ((px - ax) * ux + (py - ay) * uy + (pz - az) * uz) / uu
        t = min(max(t, 0.0), 1.0)
    return ax + t * ux, ay + t * uy, az + t * uz


@numba.njit(cache=True)
def _tri_closest(px, py, pz, tri, k):  # pragma: no cover - compiled
    """Closest point of triangle k to p (Ericson's regions; degenerate-safe)."""
    ax = tri[k, 0]
    ay = tri[k, 1]
    az = tri[k, 2]
    abx = tri[k, 3]
    aby = tri[k, 4]
    abz = tri[k, 5]
    acx = tri[k, 6]
    acy = tri[k, 7]
    acz = tri[k, 8]
    nx = tri[k, 9]
    ny = tri[k, 10]
    nz = tri[k, 11]
    ab2 = abx * abx + aby * aby + abz * abz
    ac2 = acx * acx + acy * acy + acz * acz
    n2 = nx * nx + ny * ny + nz * nz
    if 4.0 * n2 <= 1e-12 * ab2 * ac2:
        # Degenerate (zero-area) triangle: the nearest of its three edges.
        bx = ax + abx
        by = ay + aby
        bz = az + abz
        cx = ax + acx
        cy = ay + acy
        cz = az + acz
        qx, qy, qz = _seg_closest(px, py, pz, ax, ay, az, bx, by, bz)
        best = (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2
        sx, sy, sz = _seg_closest(px, py, pz, ax, ay, az, cx, cy, cz)
        d = (px - sx) ** 2 + (py - sy) ** 2 + (pz - sz) ** 2
        if d < best:
            best = d
            qx, qy, qz = sx, sy, sz
        sx, sy, sz = _seg_closest(px, py, pz, bx, by, bz, cx, cy, cz)
        d = (px - sx) ** 2 + (py - sy) ** 2 + (pz - sz) ** 2
        if d < best:
            qx, qy, qz = sx, sy, sz
        return qx, qy, qz
    apx = px - ax
    apy = py - ay
    apz = pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    qx = ax
    qy = ay
    qz = az
    if d1 <= 0.0 and d2 <= 0.0:
        pass
    else:
        bpx = apx - abx
        bpy = apy - aby
        bpz = apz - abz
        d3 = abx * bpx + aby * bpy + abz * bpz
        d4 = acx * bpx + acy * bpy + acz * bpz
        cpx = apx - acx
        cpy = apy - acy
        cpz = apz - acz
        d5 = abx * cpx + aby * cpy + abz * cpz
        d6 = acx * cpx + acy * cpy + acz * cpz
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            qx = ax + abx
            qy = ay + aby
            qz = az + abz
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            v = d1 / (d1 - d3)
            qx = ax + v * abx
            qy = ay + v * aby
            qz = az + v * abz
        elif d6 >= 0.0 and d5 <= d6:
            qx = ax + acx
            qy = ay + acy
            qz = az + acz
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            w = d2 / (d2 - d6)
            qx = ax + w * acx
            qy = ay + w * acy
            qz = az + w * acz
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
            qx = ax + abx + w * (acx - abx)
            qy = ay + aby + w * (acy - aby)
            qz = az + abz + w * (acz - abz)
        else:
            denom = 1.0 / (va + vb + vc)
            v = vb * denom
            w = vc * denom
            qx = ax + v * abx + w * acx
            qy = ay + v * aby + w * acy
            qz = az + v * abz + w * acz
    return qx, qy, qz


@numba.njit(cache=True)
def _tri_dist2(px, py, pz, tri, k):  # pragma: no cover - compiled
    """Squared distance from p to triangle k."""
    qx, qy, qz = _tri_closest(px, py, pz, tri, k)
    return (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2


@numba.njit(cache=True)
def _tri_solid_angle(px, py, pz, tri, k):  # pragma: no cover - compiled
    """Signed solid angle of triangle k seen from p (Van Oosterom and Strackee)."""
    ax = tri[k, 0] - px
    ay = tri[k, 1] - py
    az = tri[k, 2] - pz
    bx = ax + tri[k, 3]
    by = ay + tri[k, 4]
    bz = az + tri[k, 5]
    cx = ax + tri[k, 6]
    cy = ay + tri[k, 7]
    cz = az + tri[k, 8]
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    lc = math.sqrt(cx * cx + cy * cy + cz * cz)
    num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    den = (
        la * lb * lc
        + (ax * bx + ay * by + az * bz) * lc
        + (ax * cx + ay * cy + az * cz) * lb
        + (bx * cx + by * cy + bz * cz) * la
    )
    return 2.0 * math.atan2(num, den)


@numba.njit(cache=True)
def _nearest(px, py, pz, tri, node, nidx, use_tree, tie, stack, bound):  # pragma: no cover
    """(distance, triangle index) of the nearest triangle.

    Triangles within TIE of the best distance count as tied and the lowest index wins, so
    float32 and float64 pick the same triangle on edges and corners; the distance returned
    is the least one whichever triangle is picked. ``bound`` is an upper
    bound on the distance known beforehand (``inf`` if none): the search then skips every
    box farther than it. Returns index ``1 << 30`` when no triangle lies within it.
    """
    best = bound
    best_k = 1 << 30
    if not use_tree:
        for k in range(tri.shape[0]):
            d = math.sqrt(_tri_dist2(px, py, pz, tri, k))
            if d < best - tie or (d <= best + tie and k < best_k):
                if d < best or k < best_k:
                    best_k = k
            best = min(best, d)
        return best, best_k
    sp = 0
    stack[sp] = 0
    sp += 1
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        # Squared distance from p to the node's box.
        bd = 0.0
        for d in range(3):
            v = (px, py, pz)[d]
            lo = node[nd, d]
            hi = node[nd, 3 + d]
            if v < lo:
                bd += (lo - v) ** 2
            elif v > hi:
                bd += (v - hi) ** 2
        if bd > (best + tie) * (best + tie):
            continue
        left = nidx[nd, 0]
        if left < 0:
            for k in range(nidx[nd, 2], nidx[nd, 2] + nidx[nd, 3]):
                d = math.sqrt(_tri_dist2(px, py, pz, tri, k))
                if d < best - tie or (d <= best + tie and k < best_k):
                    if d < best or k < best_k:
                        best_k = k
                best = min(best, d)  # the least distance, whichever triangle is picked
        else:
            right = nidx[nd, 1]
            # Visit the child whose centre is nearer first (push it last).
            dl = (node[left, 6] - px) ** 2 + (node[left, 7] - py) ** 2 + (node[left, 8] - pz) ** 2
            dr = (
                (node[right, 6] - px) ** 2 + (node[right, 7] - py) ** 2 + (node[right, 8] - pz) ** 2
            )
            if dl < dr:
                stack[sp] = right
                stack[sp + 1] = left
            else:
                stack[sp] = left
                stack[sp + 1] = right
            sp += 2
    return best, best_k


@numba.njit(cache=True)
def _boundary_normal(px, py, pz, tri, node, nidx, use_tree, best, tie, max_normals,
                     stack):  # pragma: no cover  # fmt: skip
    """Sum of the distinct unit normals of the triangles within TIE of the nearest distance.

    At a face this is the face normal; on an edge or a corner it points between the faces
    that meet there, whichever way they are triangulated (equal normals count once).
    """
    normals = np.zeros((max_normals, 3))
    count = 0
    lim = best + tie
    sp = 0
    stack[0] = 0
    sp = 1
    k_lo = 0
    k_hi = tri.shape[0]
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        if use_tree:
            bd = 0.0
            for d in range(3):
                v = (px, py, pz)[d]
                if v < node[nd, d]:
                    bd += (node[nd, d] - v) ** 2
                elif v > node[nd, 3 + d]:
                    bd += (v - node[nd, 3 + d]) ** 2
            if bd > lim * lim:
                continue
            if nidx[nd, 0] >= 0:
                stack[sp] = nidx[nd, 0]
                stack[sp + 1] = nidx[nd, 1]
                sp += 2
                continue
            k_lo = nidx[nd, 2]
            k_hi = k_lo + nidx[nd, 3]
        for k in range(k_lo, k_hi):
            nx = tri[k, 9]
            ny = tri[k, 10]
            nz = tri[k, 11]
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nn <= 0.0 or math.sqrt(_tri_dist2(px, py, pz, tri, k)) > lim:
                continue
            nx /= nn
            ny /= nn
            nz /= nn
            seen = False
            for j in range(count):
                if nx * normals[j, 0] + ny * normals[j, 1] + nz * normals[j, 2] > 1.0 - 1e-4:
                    seen = True
            if not seen and count < max_normals:
                normals[count, 0] = nx
                normals[count, 1] = ny
                normals[count, 2] = nz
                count += 1
    sx = 0.0
    sy = 0.0
    sz = 0.0
    for j in range(count):
        sx += normals[j, 0]
        sy += normals[j, 1]
        sz += normals[j, 2]
    return sx, sy, sz


@numba.njit(cache=True)
def _winding(px, py, pz, tri, node, nidx, use_tree, theta_w, stack):  # pragma: no cover
    """Winding number of the surface about p."""
    total = 0.0
    if not use_tree:
        for k in range(tri.shape[0]):
            total += _tri_solid_angle(px, py, pz, tri, k)
        return total / (4.0 * math.pi)
    sp = 0
    stack[sp] = 0
    sp += 1
    while sp > 0:
        sp -= 1
        nd = stack[sp]
        dx = node[nd, 6] - px
        dy = node[nd, 7] - py
        dz = node[nd, 8] - pz
        dc = math.sqrt(dx * dx + dy * dy + dz * dz)
        if node[nd, 12] < theta_w * dc:
            total += (node[nd, 9] * dx + node[nd, 10] * dy + node[nd, 11] * dz) / (dc * dc * dc)
        elif nidx[nd, 0] < 0:
            for k in range(nidx[nd, 2], nidx[nd, 2] + nidx[nd, 3]):
                total += _tri_solid_angle(px, py, pz, tri, k)
        else:
            stack[sp] = nidx[nd, 0]
            stack[sp + 1] = nidx[nd, 1]
            sp += 2
    return total / (4.0 * math.pi)


@numba.njit(cache=True, inline="always")
def _radial(xi, eta, x, axi, inv2s2, quq, trq):  # pragma: no cover - compiled
    """Complex second-order factor of a flat piece lumped at its centroid.

    The integrand is ``w(eta) n.u`` with ``u = (q - p)/eta``; over a piece with
    area-normalised second moment ``Q`` about its centroid (``u.Q.u`` the variance of eta
    across it, ``tr Q`` its whole spread) the second-order terms of its Taylor expansion are,
    relative to the centroid value (eta already shifted to its mean, see _term):
    ``(w''/w) u.Q.u / 2`` (w along the ray), ``-(w'/w) u.Q.u / eta`` (w times the change of
    the projection ``n.u``) and ``-(tr Q - 3 u.Q.u) / (2 eta^2)`` (the second derivative of
    ``u`` itself), using ``n.Q = 0`` for a flat piece. With ``h = log w``: ``w'/w = h' =
    -2i/zeta - x/(sigma^2 |xi|)``, ``h'' = -2/zeta^2 - 1/(sigma |xi|)^2``, ``w''/w = h'' +
    h'^2``. The centroid rule's error is then of third order in the piece's size over its
    distance (a triangle's third moment about its centroid does not vanish; second order
    with the first term alone). The correction is scaled down to at
    most 0.5 in modulus: in the Gaussian's far tail pieces may be coarse (see _tail) and the
    expansion no longer holds, but there the term is negligible anyway.
    """
    den = xi * xi + eta * eta
    inv_s2 = 2.0 * inv2s2
    hr = -x * inv_s2 / axi - 2.0 * eta / den
    hi = -2.0 * xi / den
    b = -inv_s2 / (axi * axi)
    den2 = den * den
    inv_eta = 1.0 / eta
    cr = (0.5 * quq * (-2.0 * (xi * xi - eta * eta) / den2 + b + hr * hr - hi * hi)
          - hr * quq * inv_eta - 0.5 * (trq - 3.0 * quq) * inv_eta * inv_eta)
    ci = 0.5 * quq * (4.0 * xi * eta / den2 + 2.0 * hr * hi) - hi * quq * inv_eta
    mag = math.sqrt(cr * cr + ci * ci)
    if mag > 0.5:
        cr *= 0.5 / mag
        ci *= 0.5 / mag
    return 1.0 + cr, ci


@numba.njit(cache=True, inline="always")
def _term(px, py, pz, cx, cy, cz, nx, ny, nz, xi, inv_axi, inv2s2, trq, quq):  # pragma: no cover
    """(re, im) of zeta^-2 g dA_perp for area vector N lumped at centroid c.

    ``trq`` and ``quq`` are the trace and radial component of the piece's second moment:
    eta is taken at its mean over the piece, ``|c - p| + (tr Q - u.Q.u) / (2 |c - p|)``
    (a curved or tilted piece lies farther on average than its centroid), and the
    second-order factor of _radial. g is without its constant.
    """
    dx = cx - px
    dy = cy - py
    dz = cz - pz
    eta2 = dx * dx + dy * dy + dz * dz
    if eta2 <= 0.0:
        return 0.0, 0.0
    eta = math.sqrt(eta2)
    nu = (nx * dx + ny * dy + nz * dz) / eta
    eta = eta + (trq - quq) / (2.0 * eta)
    eta2 = eta * eta
    x = eta * inv_axi - 1.0
    f = math.exp(-x * x * inv2s2) * nu
    den = xi * xi + eta2
    f = f / (den * den)
    tr = f * (xi * xi - eta2)
    ti = f * (-2.0 * xi * eta)
    kr, ki = _radial(xi, eta, x, 1.0 / inv_axi, inv2s2, quq, trq)
    return tr * kr - ti * ki, tr * ki + ti * kr


@numba.njit(cache=True)
def _node_term(px, py, pz, node, nd, xi, inv_axi, inv2s2):  # pragma: no cover - compiled
    """(re, im) of a lumped cluster, to second order in its size.

    The centroid term ``w(eta) N.u`` (eta at its mean, the factor of _radial, as in
    _term) plus the first-order correction ``sum_ab J_ab S_ab`` with ``J`` the Jacobian of
    ``V(q) = w(eta) (q - p)/eta`` and ``S`` the cluster's first moment (see tree.py), which
    removes the O(r/d) error of clusters whose normals differ (edges, corners, thin walls):
    ``J_ab = (w' - w/eta) u_a u_b + (w/eta) delta_ab``, ``w'/w = -2i/zeta - x/(sigma^2 |xi|)``.
    The second-order terms take the cluster's third moment as ``N Q`` (exact for a flat
    cluster): _radial's factor, and ``(w'/w - 1/eta) N.Q.u / eta``, which a curved cluster's
    ``N.Q`` (its bulge along its mean normal) makes non-zero.
    """
    dx = node[nd, 6] - px
    dy = node[nd, 7] - py
    dz = node[nd, 8] - pz
    eta2 = dx * dx + dy * dy + dz * dz
    if eta2 <= 0.0:
        return 0.0, 0.0
    eta = math.sqrt(eta2)
    ux = dx / eta
    uy = dy / eta
    uz = dz / eta
    quq = (
        node[nd, 25] * ux * ux
        + node[nd, 26] * uy * uy
        + node[nd, 27] * uz * uz
        + 2.0 * (node[nd, 28] * ux * uy + node[nd, 29] * ux * uz + node[nd, 30] * uy * uz)
    )
    trq = node[nd, 25] + node[nd, 26] + node[nd, 27]
    eta = eta + (trq - quq) / (2.0 * eta)
    eta2 = eta * eta
    x = eta * inv_axi - 1.0
    g = math.exp(-x * x * inv2s2)
    den = xi * xi + eta2
    g = g / (den * den)
    wr = g * (xi * xi - eta2)
    wi = g * (-2.0 * xi * eta)
    nu = node[nd, 9] * ux + node[nd, 10] * uy + node[nd, 11] * uz
    usu = (
        ux * (node[nd, 16] * ux + node[nd, 17] * uy + node[nd, 18] * uz)
        + uy * (node[nd, 19] * ux + node[nd, 20] * uy + node[nd, 21] * uz)
        + uz * (node[nd, 22] * ux + node[nd, 23] * uy + node[nd, 24] * uz)
    )
    trs = node[nd, 16] + node[nd, 20] + node[nd, 24]
    hr = -2.0 * eta / den - 2.0 * x * inv2s2 * inv_axi
    hi = -2.0 * xi / den
    qx = node[nd, 25] * ux + node[nd, 28] * uy + node[nd, 29] * uz
    qy = node[nd, 28] * ux + node[nd, 26] * uy + node[nd, 30] * uz
    qz = node[nd, 29] * ux + node[nd, 30] * uy + node[nd, 27] * uz
    nqu = node[nd, 9] * qx + node[nd, 10] * qy + node[nd, 11] * qz
    inv_eta = 1.0 / eta
    fr = nu + (hr - inv_eta) * usu + trs * inv_eta + (hr - inv_eta) * inv_eta * nqu
    fi = hi * usu + hi * inv_eta * nqu
    tr = wr * fr - wi * fi
    ti = wr * fi + wi * fr
    kr, ki = _radial(xi, eta, x, 1.0 / inv_axi, inv2s2, quq, trq)
    return tr * kr - ti * ki, tr * ki + ti * kr


@numba.njit(cache=True, inline="always")
def _tail(dc, r, axi, inv_axi, inv2s2, inv_sigma):  # pragma: no cover - compiled
    """How much coarser than at the Gaussian's peak a piece may be where g is smaller.

    The centroid rule's error over a piece scales like g * max(1, x/sigma)^2 * (r/(sigma
    |xi|))^2 (g and its curvature); keeping it at the peak's level lets the size grow by
    exp(x^2/(4 sigma^2)) / max(1, x/sigma), x taken at the piece's nearest possible point.
    (Derived for a second-order rule. With _radial's terms the error is of higher order,
    which would allow only about exp(x^2/(8 sigma^2)); that version, measured on the headline
    torus, gave a smaller error at the same THETA_NODE but a worse error for the time.)
    """
    x = max(dc - r - axi, 0.0) * inv_axi
    return math.exp(0.5 * x * x * inv2s2) / max(1.0, x * inv_sigma)


@numba.njit(cache=True)
def _tri_rho(px, py, pz, tri, k, xi, inv_axi, inv2s2, cut, theta, gauss_size, eps, max_level,
            stack):  # fmt: skip
    """(re, im) of one triangle's contribution with per-point adaptive subdivision.

    A piece is split in two at the midpoint of its longest edge, so slivers are cut
    along their length only. Pieces are kept as the barycentric (u, v) of their three
    corners in the triangle plus their level (area = 2^-level of the triangle's).
    """  # pragma: no cover - compiled
    ax = tri[k, 0]
    ay = tri[k, 1]
    az = tri[k, 2]
    e1x = tri[k, 3]
    e1y = tri[k, 4]
    e1z = tri[k, 5]
    e2x = tri[k, 6]
    e2y = tri[k, 7]
    e2z = tri[k, 8]
    nx = tri[k, 9]
    ny = tri[k, 10]
    nz = tri[k, 11]
    if nx == 0.0 and ny == 0.0 and nz == 0.0:
        return 0.0, 0.0
    re = 0.0
    im = 0.0
    axi = 1.0 / inv_axi
    inv_sigma = math.sqrt(2.0 * inv2s2)
    corner = np.empty((3, 3))
    stack[0, 0] = 0.0
    stack[0, 1] = 0.0
    stack[0, 2] = 1.0
    stack[0, 3] = 0.0
    stack[0, 4] = 0.0
    stack[0, 5] = 1.0
    stack[0, 6] = 0.0
    sp = 1
    while sp > 0:
        sp -= 1
        for j in range(3):
            u = stack[sp, 2 * j]
            v = stack[sp, 2 * j + 1]
            corner[j, 0] = ax + u * e1x + v * e2x
            corner[j, 1] = ay + u * e1y + v * e2y
            corner[j, 2] = az + u * e1z + v * e2z
        level = stack[sp, 6]
        cx = (corner[0, 0] + corner[1, 0] + corner[2, 0]) / 3.0
        cy = (corner[0, 1] + corner[1, 1] + corner[2, 1]) / 3.0
        cz = (corner[0, 2] + corner[1, 2] + corner[2, 2]) / 3.0
        r2 = 0.0
        for j in range(3):
            r2 = max(r2, (corner[j, 0] - cx) ** 2 + (corner[j, 1] - cy) ** 2
                     + (corner[j, 2] - cz) ** 2)  # fmt: skip
        r = math.sqrt(r2)
        dx = cx - px
        dy = cy - py
        dz = cz - pz
        dc = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dc - r > cut:
            continue
        if (
            (
                r > theta * max(dc, eps)
                or r > gauss_size * _tail(dc, r, axi, inv_axi, inv2s2, inv_sigma)
            )
            and level < max_level
            and sp + 2 <= stack.shape[0]
        ):
            # Longest edge (i, j), opposite corner o.
            best = -1.0
            i0 = 0
            for j in range(3):
                jn = (j + 1) % 3
                l2 = ((corner[j, 0] - corner[jn, 0]) ** 2 + (corner[j, 1] - corner[jn, 1]) ** 2
                      + (corner[j, 2] - corner[jn, 2]) ** 2)  # fmt: skip
                if l2 > best:
                    best = l2
                    i0 = j
            i1 = (i0 + 1) % 3
            o = (i0 + 2) % 3
            ui = stack[sp, 2 * i0]
            vi = stack[sp, 2 * i0 + 1]
            uj = stack[sp, 2 * i1]
            vj = stack[sp, 2 * i1 + 1]
            uo = stack[sp, 2 * o]
            vo = stack[sp, 2 * o + 1]
            um = 0.5 * (ui + uj)
            vm = 0.5 * (vi + vj)
            child = level + 1.0
            stack[sp, 0] = ui
            stack[sp, 1] = vi
            stack[sp, 2] = um
            stack[sp, 3] = vm
            stack[sp, 4] = uo
            stack[sp, 5] = vo
            stack[sp, 6] = child
            stack[sp + 1, 0] = um
            stack[sp + 1, 1] = vm
            stack[sp + 1, 2] = uj
            stack[sp + 1, 3] = vj
            stack[sp + 1, 4] = uo
            stack[sp + 1, 5] = vo
            stack[sp + 1, 6] = child
            sp += 2
            continue
        frac = 2.0 ** (-level)
        # Second moment of the piece about its centroid: (1/12) sum over corners of d d^T.
        quq = 0.0
        trq = 0.0
        for j in range(3):
            ddx = corner[j, 0] - cx
            ddy = corner[j, 1] - cy
            ddz = corner[j, 2] - cz
            ud = (ddx * dx + ddy * dy + ddz * dz) / max(dc, 1e-30)
            quq += ud * ud
            trq += ddx * ddx + ddy * ddy + ddz * ddz
        tr, ti = _term(px, py, pz, cx, cy, cz, nx * frac, ny * frac, nz * frac, xi, inv_axi,
                       inv2s2, trq / 12.0, quq / 12.0)  # fmt: skip
        re += tr
        im += ti
    return re, im


@numba.njit(cache=True)
def _rho_sum(px, py, pz, xi, tri, node, nidx, use_tree, sigma, kc, nstack, pstack):
    """(re, im) of the boundary sum (without c(p) and the Gaussian's constant)."""  # noqa: D401
    theta = kc.theta
    theta_node = kc.theta_node
    node_bend = kc.node_bend
    eps = kc.eps
    max_level = kc.max_level
    axi = abs(xi)
    inv_axi = 1.0 / axi
    inv2s2 = 1.0 / (2.0 * sigma * sigma)
    cut = (1.0 + kc.gauss_cutoff * sigma) * axi
    sig_res = min(sigma, kc.sigma_resolution)
    gauss_piece = theta * sig_res * axi
    gauss_node = theta_node * sig_res * axi
    re = 0.0
    im = 0.0
    if not use_tree:
        for k in range(tri.shape[0]):
            tr, ti = _tri_rho(px, py, pz, tri, k, xi, inv_axi, inv2s2, cut, theta, gauss_piece,
                              eps, max_level, pstack)  # fmt: skip
            re += tr
            im += ti
        return re, im
    sp = 0
    nstack[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        nd = nstack[sp]
        cx = node[nd, 6]
        cy = node[nd, 7]
        cz = node[nd, 8]
        r = node[nd, 12]
        dx = cx - px
        dy = cy - py
        dz = cz - pz
        dc = math.sqrt(dx * dx + dy * dy + dz * dz)
        if dc - r > cut:
            continue
        if not (
            r > theta_node * max(dc, eps)
            or r > gauss_node * _tail(dc, r, axi, inv_axi, inv2s2, 1.0 / sigma)
            or node[nd, 14] * r * r > node_bend * dc * dc
        ):
            tr, ti = _node_term(px, py, pz, node, nd, xi, inv_axi, inv2s2)
            re += tr
            im += ti
        elif nidx[nd, 0] < 0:
            for k in range(nidx[nd, 2], nidx[nd, 2] + nidx[nd, 3]):
                tr, ti = _tri_rho(px, py, pz, tri, k, xi, inv_axi, inv2s2, cut, theta,
                                  gauss_piece, eps, max_level, pstack)  # fmt: skip
                re += tr
                im += ti
        else:
            nstack[sp] = nidx[nd, 0]
            nstack[sp + 1] = nidx[nd, 1]
            sp += 2
    return re, im


@numba.njit(cache=True, parallel=True)
def evaluate(points, tri, node, nidx, dtri, dnode, dnidx, use_tree, mode, sigma, lam_in,
             lam_out, kc, hints, out):  # fmt: skip
    """Fill out (n, 4) float64 with (Re rho, Im rho, xi, winding) per point.

    Parameters
    ----------
    points : (n, 3) float64
        Query points in local units.
    tri, node, nidx : arrays of :class:`engine.descriptor.tree.TriangleTree`
        Packed triangles and hierarchy (any ``node``/``nidx`` when ``use_tree`` is False):
        what the winding number and the boundary sum run over (slivers cut into pieces).
    dtri, dnode, dnidx : arrays of a TriangleTree
        The same surface for the nearest distance, with slivers left whole: the distance
        to a sliver is as cheap as to any triangle, while its pieces (a hundred to a
        faceted cylinder's strip) all lie at about the same distance from a point near the
        axis and would all be visited. The same arrays as ``tri``, ``node``, ``nidx``
        when nothing was cut.
    use_tree : bool
        The hierarchy, or every triangle (brute force, the reference).
    mode : int
        0: winding only; 1: winding and signed distance; 2: everything.
    sigma, lam_in, lam_out : float
        The descriptor's parameters.
    kc : KernelConstants
        The quadrature constants.
    out : (n, 4) float64
        Filled with (Re rho, Im rho, xi, winding).
    hints : (n, 2) float64
        Per point, what is known beforehand (from a neighbouring sample ``d`` away whose
        signed distance is ``x``): an upper bound on the distance, ``|x| + d`` (``inf`` if
        none), and the side, ``+1`` outside or ``-1`` inside when ``|x| > d + 2 eps`` (no
        surface lies within ``|x|`` of the neighbour), else 0. A known side skips the winding
        number (``out[i, 3]`` is then 1 or 0); the bound prunes the distance search. Both
        are exact: rho and xi are those computed without hints.
    """  # pragma: no cover - compiled
    n = points.shape[0]
    norm = 1.0 / (math.sqrt(2.0 * math.pi) * sigma)
    eps = kc.eps
    tie = kc.tie
    for i in numba.prange(n):
        nstack = np.empty(kc.node_stack, dtype=np.int64)
        pstack = np.empty((kc.piece_stack, 7))
        px = points[i, 0]
        py = points[i, 1]
        pz = points[i, 2]
        side = hints[i, 1] if mode != 0 else 0.0
        if side != 0.0:
            w = 1.0 if side < 0.0 else 0.0
        else:
            w = _winding(px, py, pz, tri, node, nidx, use_tree, kc.theta_winding, nstack)
        out[i, 3] = w
        out[i, 0] = 0.0
        out[i, 1] = 0.0
        out[i, 2] = 0.0
        if mode == 0:
            continue
        inside = w > 0.5
        dist, kn = _nearest(px, py, pz, dtri, dnode, dnidx, use_tree, tie, nstack,
                            hints[i, 0])  # fmt: skip
        if kn == 1 << 30 or (dist < eps and hints[i, 0] < np.inf):
            # The bound was too tight (rounding), or p is on the surface, where the tied
            # triangle picked decides the normal: search as without hints.
            dist, kn = _nearest(px, py, pz, dtri, dnode, dnidx, use_tree, tie, nstack, np.inf)
        push = False
        if dist < eps:
            nx, ny, nz = _boundary_normal(px, py, pz, dtri, dnode, dnidx, use_tree, dist, tie,
                                          kc.max_normals, nstack)  # fmt: skip
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nn > 1e-3:
                # Within a hair of the boundary the winding number is about 0.5 and its
                # rounding would pick the side: take it from the height above the nearest
                # point along the boundary normal instead, the boundary counting as inside.
                nx /= nn
                ny /= nn
                nz /= nn
                qx, qy, qz = _tri_closest(px, py, pz, dtri, kn)
                off = (px - qx) * nx + (py - qy) * ny + (pz - qz) * nz
                inside = off < tie
                push = True
        out[i, 2] = -dist if inside else dist
        if mode == 1:
            continue
        sgn = -1.0 if inside else 1.0
        if push:
            # Evaluate at height eps above the nearest point, on p's side: on a face this is
            # the one-sided limit of the smooth formula.
            px = qx + sgn * eps * nx
            py = qy + sgn * eps * ny
            pz = qz + sgn * eps * nz
        xi = sgn * max(dist, eps)
        re, im = _rho_sum(px, py, pz, xi, tri, node, nidx, use_tree, sigma, kc, nstack, pstack)
        c = lam_in if inside else -lam_out
        out[i, 0] = c * norm * re
        out[i, 1] = c * norm * im
