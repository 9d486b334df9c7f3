"""OpenCL kernels of the skeletal density descriptor (pyopencl; any device).

Works on the packed triangle and hierarchy arrays of :mod:`engine.descriptor.tree` (sent
as float32 in local units: grid cells about the grid centre) and query points ``(k, 3)``
in the same units. One work-item evaluates one point: winding number, exact nearest
distance, then the boundary sum, with the same rules, constants and traversal order as
the numba reference in :mod:`engine.descriptor.numba_kernels`, so both agree to float32
precision. Accumulators are double where the device has ``cl_khr_fp64`` (PoCL does; many
GPUs do not), else float. Subdivision and traversal use explicit private stacks (no
recursion in OpenCL C).
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np

import engine.descriptor.constants as _c
from engine.backend import Backend, BackendError
from engine.descriptor.tree import TriangleTree

#: Work items per work-group of the evaluation kernel. With the size left to the driver,
#: PoCL ran a whole chunk (thousands of points) as one work-group, on one CPU core.
LOCAL_SIZE = 64

KERNEL_SOURCE = r"""
#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double acc_t;
#else
typedef float acc_t;
#endif

#define TS 16   /* floats per triangle */
#define NS 32   /* floats per node */

inline float3 seg_closest(float3 p, float3 a, float3 b)
{
    float3 u = b - a;
    float uu = dot(u, u);
    float t = 0.0f;
    if (uu > 0.0f) {
        t = dot(p - a, u) / uu;
        t = fmin(fmax(t, 0.0f), 1.0f);
    }
    return a + t * u;
}

/* Closest point of a triangle to p (Ericson's regions; degenerate-safe). */
float3 tri_closest(float3 p, __global const float *t)
{
    float3 a = (float3)(t[0], t[1], t[2]);
    float3 ab = (float3)(t[3], t[4], t[5]);
    float3 ac = (float3)(t[6], t[7], t[8]);
    float3 n = (float3)(t[9], t[10], t[11]);
    float ab2 = dot(ab, ab);
    float ac2 = dot(ac, ac);
    float n2 = dot(n, n);
    if (4.0f * n2 <= 1e-12f * ab2 * ac2) {
        float3 b = a + ab;
        float3 c = a + ac;
        float3 q = seg_closest(p, a, b);
        float best = dot(p - q, p - q);
        float3 s = seg_closest(p, a, c);
        float d = dot(p - s, p - s);
        if (d < best) { best = d; q = s; }
        s = seg_closest(p, b, c);
        d = dot(p - s, p - s);
        if (d < best) { q = s; }
        return q;
    }
    float3 ap = p - a;
    float d1 = dot(ab, ap);
    float d2 = dot(ac, ap);
    float3 q = a;
    if (!(d1 <= 0.0f && d2 <= 0.0f)) {
        float3 bp = ap - ab;
        float d3 = dot(ab, bp);
        float d4 = dot(ac, bp);
        float3 cp = ap - ac;
        float d5 = dot(ab, cp);
        float d6 = dot(ac, cp);
        float vc = d1 * d4 - d3 * d2;
        float vb = d5 * d2 - d1 * d6;
        float va = d3 * d6 - d5 * d4;
        if (d3 >= 0.0f && d4 <= d3) {
            q = a + ab;
        } else if (vc <= 0.0f && d1 >= 0.0f && d3 <= 0.0f) {
            q = a + (d1 / (d1 - d3)) * ab;
        } else if (d6 >= 0.0f && d5 <= d6) {
            q = a + ac;
        } else if (vb <= 0.0f && d2 >= 0.0f && d6 <= 0.0f) {
            q = a + (d2 / (d2 - d6)) * ac;
        } else if (va <= 0.0f && (d4 - d3) >= 0.0f && (d5 - d6) >= 0.0f) {
            float w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
            q = a + ab + w * (ac - ab);
        } else {
            float denom = 1.0f / (va + vb + vc);
            q = a + (vb * denom) * ab + (vc * denom) * ac;
        }
    }
    return q;
}

inline float tri_dist2(float3 p, __global const float *t)
{
    float3 d = p - tri_closest(p, t);
    return dot(d, d);
}

float tri_solid_angle(float3 p, __global const float *t)
{
    float3 a = (float3)(t[0], t[1], t[2]) - p;
    float3 b = a + (float3)(t[3], t[4], t[5]);
    float3 c = a + (float3)(t[6], t[7], t[8]);
    float la = length(a);
    float lb = length(b);
    float lc = length(c);
    float num = dot(a, cross(b, c));
    float den = la * lb * lc + dot(a, b) * lc + dot(a, c) * lb + dot(b, c) * la;
    return 2.0f * atan2(num, den);
}

/* Nearest triangle: (distance, index); ties within TIE go to the lowest index. */
void nearest(float3 p, __global const float *tri, int m, __global const float *node,
             __global const int *nidx, int use_tree, float *out_d, int *out_k)
{
    float best = INFINITY;
    int best_k = 1 << 30;
    if (!use_tree) {
        for (int k = 0; k < m; ++k) {
            float d = sqrt(tri_dist2(p, tri + TS * k));
            if (d < best - TIE || (d <= best + TIE && k < best_k)) {
                if (d < best || k < best_k) best_k = k;
            }
            best = fmin(best, d);
        }
        *out_d = best;
        *out_k = best_k;
        return;
    }
    int stack[NODE_STACK];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int nd = stack[--sp];
        __global const float *nb = node + NS * nd;
        float3 lo = (float3)(nb[0], nb[1], nb[2]);
        float3 hi = (float3)(nb[3], nb[4], nb[5]);
        float3 e = fmax(lo - p, (float3)(0.0f)) + fmax(p - hi, (float3)(0.0f));
        float bd = dot(e, e);
        if (bd > (best + TIE) * (best + TIE)) continue;
        int left = nidx[4 * nd];
        if (left < 0) {
            int k0 = nidx[4 * nd + 2];
            int k1 = k0 + nidx[4 * nd + 3];
            for (int k = k0; k < k1; ++k) {
                float d = sqrt(tri_dist2(p, tri + TS * k));
                if (d < best - TIE || (d <= best + TIE && k < best_k)) {
                    if (d < best || k < best_k) best_k = k;
                }
                best = fmin(best, d);
            }
        } else {
            int right = nidx[4 * nd + 1];
            __global const float *nl = node + NS * left;
            __global const float *nr = node + NS * right;
            float3 cl = (float3)(nl[6], nl[7], nl[8]) - p;
            float3 cr = (float3)(nr[6], nr[7], nr[8]) - p;
            if (dot(cl, cl) < dot(cr, cr)) {
                stack[sp] = right;
                stack[sp + 1] = left;
            } else {
                stack[sp] = left;
                stack[sp + 1] = right;
            }
            sp += 2;
        }
    }
    *out_d = best;
    *out_k = best_k;
}

/* Sum of the distinct unit normals of the triangles within TIE of the nearest distance. */
float3 boundary_normal(float3 p, __global const float *tri, int m, __global const float *node,
                       __global const int *nidx, int use_tree, float best)
{
    float3 normals[MAX_NORMALS];
    int count = 0;
    float lim = best + TIE;
    int stack[NODE_STACK];
    int sp = 0;
    stack[sp++] = 0;
    int k_lo = 0;
    int k_hi = m;
    while (sp > 0) {
        int nd = stack[--sp];
        if (use_tree) {
            __global const float *nb = node + NS * nd;
            float3 lo = (float3)(nb[0], nb[1], nb[2]);
            float3 hi = (float3)(nb[3], nb[4], nb[5]);
            float3 e = fmax(lo - p, (float3)(0.0f)) + fmax(p - hi, (float3)(0.0f));
            if (dot(e, e) > lim * lim) continue;
            if (nidx[4 * nd] >= 0) {
                stack[sp] = nidx[4 * nd];
                stack[sp + 1] = nidx[4 * nd + 1];
                sp += 2;
                continue;
            }
            k_lo = nidx[4 * nd + 2];
            k_hi = k_lo + nidx[4 * nd + 3];
        }
        for (int k = k_lo; k < k_hi; ++k) {
            __global const float *t = tri + TS * k;
            float3 n = (float3)(t[9], t[10], t[11]);
            float nn = length(n);
            if (nn <= 0.0f || sqrt(tri_dist2(p, t)) > lim) continue;
            n /= nn;
            int seen = 0;
            for (int j = 0; j < count; ++j)
                if (dot(n, normals[j]) > 1.0f - 1e-4f) seen = 1;
            if (!seen && count < MAX_NORMALS) normals[count++] = n;
        }
    }
    float3 sum = (float3)(0.0f);
    for (int j = 0; j < count; ++j) sum += normals[j];
    return sum;
}

float winding(float3 p, __global const float *tri, int m, __global const float *node,
              __global const int *nidx, int use_tree, float theta_w)
{
    acc_t total = 0;
    if (!use_tree) {
        for (int k = 0; k < m; ++k) total += tri_solid_angle(p, tri + TS * k);
        return (float)total / (4.0f * M_PI_F);
    }
    int stack[NODE_STACK];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
        int nd = stack[--sp];
        __global const float *nb = node + NS * nd;
        float3 d = (float3)(nb[6], nb[7], nb[8]) - p;
        float dc = length(d);
        if (nb[12] < theta_w * dc) {
            total += dot((float3)(nb[9], nb[10], nb[11]), d) / (dc * dc * dc);
        } else if (nidx[4 * nd] < 0) {
            int k0 = nidx[4 * nd + 2];
            int k1 = k0 + nidx[4 * nd + 3];
            for (int k = k0; k < k1; ++k) total += tri_solid_angle(p, tri + TS * k);
        } else {
            stack[sp] = nidx[4 * nd];
            stack[sp + 1] = nidx[4 * nd + 1];
            sp += 2;
        }
    }
    return (float)total / (4.0f * M_PI_F);
}

/* Complex second-order factor of a lumped piece (engine.descriptor._radial). */
inline float2 radial(float xi, float eta, float x, float axi, float inv2s2, float quq,
                     float trq)
{
    float den = xi * xi + eta * eta;
    float inv_s2 = 2.0f * inv2s2;
    float hr = -x * inv_s2 / axi - 2.0f * eta / den;
    float hi = -2.0f * xi / den;
    float b = -inv_s2 / (axi * axi);
    float den2 = den * den;
    float inv_eta = 1.0f / eta;
    float cr = 0.5f * quq * (-2.0f * (xi * xi - eta * eta) / den2 + b + hr * hr - hi * hi)
               - hr * quq * inv_eta - 0.5f * (trq - 3.0f * quq) * inv_eta * inv_eta;
    float ci = 0.5f * quq * (4.0f * xi * eta / den2 + 2.0f * hr * hi) - hi * quq * inv_eta;
    float mag = sqrt(cr * cr + ci * ci);
    if (mag > 0.5f) {
        cr *= 0.5f / mag;
        ci *= 0.5f / mag;
    }
    return (float2)(1.0f + cr, ci);
}

inline float2 cmul(float2 a, float2 b)
{
    return (float2)(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

/* zeta^-2 g dA_perp for area vector n lumped at c, eta at its mean over the piece
   (engine.descriptor._term); g without its constant. */
inline float2 term(float3 p, float3 c, float3 n, float xi, float inv_axi, float inv2s2,
                   float trq, float quq)
{
    float3 d = c - p;
    float eta2 = dot(d, d);
    if (eta2 <= 0.0f) return (float2)(0.0f, 0.0f);
    float eta = sqrt(eta2);
    float nu = dot(n, d) / eta;
    eta = eta + (trq - quq) / (2.0f * eta);
    eta2 = eta * eta;
    float x = eta * inv_axi - 1.0f;
    float f = exp(-x * x * inv2s2) * nu;
    float den = xi * xi + eta2;
    f = f / (den * den);
    float2 tv = (float2)(f * (xi * xi - eta2), f * (-2.0f * xi * eta));
    return cmul(tv, radial(xi, eta, x, 1.0f / inv_axi, inv2s2, quq, trq));
}

/* A lumped cluster to second order (engine.descriptor._node_term). */
float2 node_term(float3 p, __global const float *nb, float xi, float inv_axi, float inv2s2)
{
    float3 d = (float3)(nb[6], nb[7], nb[8]) - p;
    float eta2 = dot(d, d);
    if (eta2 <= 0.0f) return (float2)(0.0f, 0.0f);
    float eta = sqrt(eta2);
    float3 u = d / eta;
    float quq = nb[25] * u.x * u.x + nb[26] * u.y * u.y + nb[27] * u.z * u.z
              + 2.0f * (nb[28] * u.x * u.y + nb[29] * u.x * u.z + nb[30] * u.y * u.z);
    float trq = nb[25] + nb[26] + nb[27];
    eta = eta + (trq - quq) / (2.0f * eta);
    eta2 = eta * eta;
    float x = eta * inv_axi - 1.0f;
    float g = exp(-x * x * inv2s2);
    float den = xi * xi + eta2;
    g = g / (den * den);
    float wr = g * (xi * xi - eta2);
    float wi = g * (-2.0f * xi * eta);
    float nu = dot((float3)(nb[9], nb[10], nb[11]), u);
    float usu = u.x * (nb[16] * u.x + nb[17] * u.y + nb[18] * u.z)
              + u.y * (nb[19] * u.x + nb[20] * u.y + nb[21] * u.z)
              + u.z * (nb[22] * u.x + nb[23] * u.y + nb[24] * u.z);
    float trs = nb[16] + nb[20] + nb[24];
    float hr = -2.0f * eta / den - 2.0f * x * inv2s2 * inv_axi;
    float hi = -2.0f * xi / den;
    float3 qu = (float3)(nb[25] * u.x + nb[28] * u.y + nb[29] * u.z,
                         nb[28] * u.x + nb[26] * u.y + nb[30] * u.z,
                         nb[29] * u.x + nb[30] * u.y + nb[27] * u.z);
    float nqu = dot((float3)(nb[9], nb[10], nb[11]), qu);
    float inv_eta = 1.0f / eta;
    float fr = nu + (hr - inv_eta) * usu + trs * inv_eta + (hr - inv_eta) * inv_eta * nqu;
    float fi = hi * usu + hi * inv_eta * nqu;
    float2 tv = (float2)(wr * fr - wi * fi, wr * fi + wi * fr);
    return cmul(tv, radial(xi, eta, x, 1.0f / inv_axi, inv2s2, quq, trq));
}

/* How much coarser than at the Gaussian's peak a piece may be (engine.descriptor._tail). */
inline float tail(float dc, float r, float axi, float inv_axi, float inv2s2, float inv_sigma)
{
    float x = fmax(dc - r - axi, 0.0f) * inv_axi;
    return exp(0.5f * x * x * inv2s2) / fmax(1.0f, x * inv_sigma);
}

/* One triangle with per-point adaptive subdivision: longest-edge bisection, pieces kept as
   the barycentric (u, v) of their corners and their level (area 2^-level). */
void tri_rho(float3 p, __global const float *t, float xi, float inv_axi, float inv2s2,
             float cut, float theta, float gauss_size, float eps, acc_t *re, acc_t *im)
{
    float3 a = (float3)(t[0], t[1], t[2]);
    float3 e1 = (float3)(t[3], t[4], t[5]);
    float3 e2 = (float3)(t[6], t[7], t[8]);
    float3 n = (float3)(t[9], t[10], t[11]);
    if (n.x == 0.0f && n.y == 0.0f && n.z == 0.0f) return;
    const float axi = 1.0f / inv_axi;
    const float inv_sigma = sqrt(2.0f * inv2s2);
    float stack[7 * PIECE_STACK];
    stack[0] = 0.0f; stack[1] = 0.0f;
    stack[2] = 1.0f; stack[3] = 0.0f;
    stack[4] = 0.0f; stack[5] = 1.0f;
    stack[6] = 0.0f;
    int sp = 1;
    while (sp > 0) {
        --sp;
        float *e = stack + 7 * sp;
        float3 c0 = a + e[0] * e1 + e[1] * e2;
        float3 c1 = a + e[2] * e1 + e[3] * e2;
        float3 c2 = a + e[4] * e1 + e[5] * e2;
        float level = e[6];
        float3 c = (c0 + c1 + c2) / 3.0f;
        float r2 = fmax(fmax(dot(c0 - c, c0 - c), dot(c1 - c, c1 - c)), dot(c2 - c, c2 - c));
        float r = sqrt(r2);
        float dc = length(c - p);
        if (dc - r > cut) continue;
        if ((r > theta * fmax(dc, eps)
             || r > gauss_size * tail(dc, r, axi, inv_axi, inv2s2, inv_sigma)) && level < MAX_LEVEL
            && sp + 2 <= PIECE_STACK) {
            float l0 = dot(c0 - c1, c0 - c1);
            float l1 = dot(c1 - c2, c1 - c2);
            float l2 = dot(c2 - c0, c2 - c0);
            int i0 = 0;
            float best = l0;
            if (l1 > best) { best = l1; i0 = 1; }
            if (l2 > best) { i0 = 2; }
            int i1 = (i0 + 1) % 3;
            int o = (i0 + 2) % 3;
            float ui = e[2 * i0], vi = e[2 * i0 + 1];
            float uj = e[2 * i1], vj = e[2 * i1 + 1];
            float uo = e[2 * o], vo = e[2 * o + 1];
            float um = 0.5f * (ui + uj), vm = 0.5f * (vi + vj);
            float child = level + 1.0f;
            e[0] = ui; e[1] = vi; e[2] = um; e[3] = vm; e[4] = uo; e[5] = vo; e[6] = child;
            e[7] = um; e[8] = vm; e[9] = uj; e[10] = vj; e[11] = uo; e[12] = vo; e[13] = child;
            sp += 2;
            continue;
        }
        float frac = exp2(-level);
        float3 u = (c - p) / fmax(dc, 1e-30f);
        float3 d0 = c0 - c, d1 = c1 - c, d2 = c2 - c;
        float ud0 = dot(d0, u), ud1 = dot(d1, u), ud2 = dot(d2, u);
        float quq = (ud0 * ud0 + ud1 * ud1 + ud2 * ud2) / 12.0f;
        float trq = (dot(d0, d0) + dot(d1, d1) + dot(d2, d2)) / 12.0f;
        float2 tv = term(p, c, n * frac, xi, inv_axi, inv2s2, trq, quq);
        *re += tv.x;
        *im += tv.y;
    }
}

__kernel void skeletal(__global const float *pts, int npts,
                       __global const float *tri, int m,
                       __global const float *node, __global const int *nidx,
                       __global const float *dtri, int dm,
                       __global const float *dnode, __global const int *dnidx,
                       int use_tree, int mode,
                       float sigma, float lam_in, float lam_out,
                       float theta, float theta_node, float theta_w, float eps, float cut_k,
                       float sigma_res, float node_bend, __global float *out)
{
    int i = get_global_id(0);
    if (i >= npts) return;
    float3 p = (float3)(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]);
    float w = winding(p, tri, m, node, nidx, use_tree, theta_w);
    out[4 * i + 3] = w;
    out[4 * i] = 0.0f;
    out[4 * i + 1] = 0.0f;
    out[4 * i + 2] = 0.0f;
    if (mode == 0) return;
    int inside = w > 0.5f;
    float dist;
    int kn;
    nearest(p, dtri, dm, dnode, dnidx, use_tree, &dist, &kn);  /* slivers whole */
    int push = 0;
    float3 nrm = (float3)(0.0f);
    float3 q = p;
    if (dist < eps) {
        nrm = boundary_normal(p, dtri, dm, dnode, dnidx, use_tree, dist);
        float nn = length(nrm);
        if (nn > 1e-3f) {
            nrm /= nn;
            q = tri_closest(p, dtri + TS * kn);
            inside = dot(p - q, nrm) < TIE;
            push = 1;
        }
    }
    out[4 * i + 2] = inside ? -dist : dist;
    if (mode == 1) return;
    float sgn = inside ? -1.0f : 1.0f;
    if (push) p = q + (sgn * eps) * nrm;
    float xi = sgn * fmax(dist, eps);
    float axi = fabs(xi);
    float inv_axi = 1.0f / axi;
    float inv2s2 = 1.0f / (2.0f * sigma * sigma);
    float cut = (1.0f + cut_k * sigma) * axi;
    float sig_res = fmin(sigma, sigma_res);
    float gauss_piece = theta * sig_res * axi;
    float gauss_node = theta_node * sig_res * axi;
    acc_t re = 0, im = 0;
    if (!use_tree) {
        for (int k = 0; k < m; ++k)
            tri_rho(p, tri + TS * k, xi, inv_axi, inv2s2, cut, theta, gauss_piece, eps, &re, &im);
    } else {
        int stack[NODE_STACK];
        int sp = 0;
        stack[sp++] = 0;
        while (sp > 0) {
            int nd = stack[--sp];
            __global const float *nb = node + NS * nd;
            float r = nb[12];
            float dc = length((float3)(nb[6], nb[7], nb[8]) - p);
            if (dc - r > cut) continue;
            if (!(r > theta_node * fmax(dc, eps)
                  || r > gauss_node * tail(dc, r, axi, inv_axi, inv2s2, 1.0f / sigma)
                  || nb[14] * r * r > node_bend * dc * dc)) {
                float2 tv = node_term(p, nb, xi, inv_axi, inv2s2);
                re += tv.x;
                im += tv.y;
            } else if (nidx[4 * nd] < 0) {
                int k0 = nidx[4 * nd + 2];
                int k1 = k0 + nidx[4 * nd + 3];
                for (int k = k0; k < k1; ++k)
                    tri_rho(p, tri + TS * k, xi, inv_axi, inv2s2, cut, theta, gauss_piece, eps,
                            &re, &im);
            } else {
                stack[sp] = nidx[4 * nd];
                stack[sp + 1] = nidx[4 * nd + 1];
                sp += 2;
            }
        }
    }
    float c = inside ? lam_in : -lam_out;
    float norm = c / (sqrt(2.0f * M_PI_F) * sigma);
    out[4 * i] = (float)(norm * re);
    out[4 * i + 1] = (float)(norm * im);
}
"""

_programs: weakref.WeakKeyDictionary[Any, dict[bool, Any]] = weakref.WeakKeyDictionary()
_lock = threading.Lock()


def _has_fp64(device: Any) -> bool:
    return "cl_khr_fp64" in device.extensions


def build_program(context: Any, *, double: bool | None = None) -> Any:
    """Compile (once per context and accumulator type) and return the program.

    ``double``: accumulate in double (default: when the device has ``cl_khr_fp64``).
    """
    import pyopencl as cl

    dev = context.devices[0]
    if double is None:
        double = _has_fp64(dev)
    with _lock:
        prog = _programs.setdefault(context, {}).get(double)
        if prog is None:
            options = [
                f"-DPIECE_STACK={_c.PIECE_STACK}",
                f"-DNODE_STACK={_c.NODE_STACK}",
                f"-DMAX_LEVEL={_c.MAX_LEVEL}",
                f"-DTIE={_c.TIE!r}f",
                f"-DMAX_NORMALS={_c.MAX_NORMALS}",
            ]
            if double:
                options.append("-DUSE_DOUBLE")
            try:
                prog = cl.Program(context, KERNEL_SOURCE).build(options=options)
            except (cl.Error, RuntimeError) as exc:
                lines = [ln.strip() for ln in str(exc).splitlines() if "error" in ln.lower()]
                why = lines[-1] if lines else str(exc).splitlines()[0]
                raise BackendError(
                    f"the OpenCL device {dev.name.strip()} ({dev.platform.name.strip()}) cannot "
                    f"compile the descriptor kernel ({why}); use --backend numba, or pick "
                    "another device with --device / SKELASM_DEVICE"
                ) from exc
            _programs[context][double] = prog
        return prog


def kernel_builds(backend: Backend) -> bool:
    """Whether the descriptor kernel compiles on this OpenCL backend."""
    try:
        build_program(backend.context)
    except BackendError:
        return False
    return True


class OpenCLDescriptor:
    """The compiled kernel on one backend (context and queue)."""

    def __init__(self, backend: Backend, *, double: bool | None = None) -> None:
        import pyopencl as cl

        self.backend = backend
        self.program = build_program(backend.context, double=double)
        # A kernel object of its own: the program is shared per context, and pyopencl warns
        # (an error under the tests' filters) when ``program.skeletal`` is read twice.
        self.kernel = cl.Kernel(self.program, "skeletal")
        #: Work items per group: LOCAL_SIZE, or less where the device cannot run that many
        #: of this kernel at once (its registers or private memory per item).
        try:
            most = int(self.kernel.get_work_group_info(
                cl.kernel_work_group_info.WORK_GROUP_SIZE, backend.device))
        except cl.Error:  # a driver that cannot say: the size every device here ran
            most = LOCAL_SIZE
        self.local_size = max(1, min(LOCAL_SIZE, most))

    _instances: dict[int, OpenCLDescriptor] = {}

    @classmethod
    def for_backend(cls, backend: Backend) -> OpenCLDescriptor:
        """Shared instance per backend."""
        key = id(backend.context)
        inst = cls._instances.get(key)
        if inst is None or inst.backend.context is not backend.context:
            inst = cls(backend)
            cls._instances[key] = inst
        return inst

    def prepare(self, tri: np.ndarray, tree: TriangleTree | None, sigma: float,
                lambda_in: float, lambda_out: float, *,
                surface: TriangleTree | None = None) -> Callable[[np.ndarray, int], np.ndarray]:
        """Upload one mesh; returns ``evaluate(points (k, 3) float, mode) -> (k, 4) float64``.

        Parameters
        ----------
        tri : (m, 16) float64
            Packed triangles (tree order).
        tree : TriangleTree or None
            None for brute force.
        sigma, lambda_in, lambda_out : float
            The descriptor's parameters.
        surface : TriangleTree, optional
            The uncut triangles' tree for the nearest distance (default: ``tree``; see
            :func:`engine.descriptor.numba_kernels.evaluate`).
        """
        import pyopencl as cl

        ctx = self.backend.context
        queue = self.backend.queue
        mf = cl.mem_flags
        tri32 = np.ascontiguousarray(tri, dtype=np.float32)
        if tree is not None:
            node32 = np.ascontiguousarray(tree.node, dtype=np.float32)
            nidx = np.ascontiguousarray(tree.node_index, dtype=np.int32)
            use_tree = 1
        else:
            node32 = np.zeros((1, 32), np.float32)
            nidx = np.full((1, 4), -1, np.int32)
            use_tree = 0
        tri_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=tri32)
        node_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=node32)
        nidx_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=nidx)
        m = np.int32(tri32.shape[0])
        if tree is not None and surface is not None and surface is not tree:
            dtri32 = np.ascontiguousarray(surface.tri, dtype=np.float32)
            dtri_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=dtri32)
            dnode_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                  hostbuf=np.ascontiguousarray(surface.node, dtype=np.float32))
            dnidx_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                  hostbuf=np.ascontiguousarray(surface.node_index, np.int32))
            dm = np.int32(dtri32.shape[0])
        else:
            dtri_buf, dnode_buf, dnidx_buf, dm = tri_buf, node_buf, nidx_buf, m
        scalars = [
            np.float32(sigma),
            np.float32(lambda_in),
            np.float32(lambda_out),
            np.float32(_c.THETA),
            np.float32(_c.THETA_NODE),
            np.float32(_c.THETA_WINDING),
            np.float32(_c.EPS_FLOOR),
            np.float32(_c.GAUSS_CUTOFF),
            np.float32(_c.SIGMA_RESOLUTION),
            np.float32(_c.NODE_BEND),
        ]
        kernel = self.kernel
        group = self.local_size

        def evaluate(points: np.ndarray, mode: int) -> np.ndarray:
            k = points.shape[0]
            pts = np.ascontiguousarray(points, dtype=np.float32)
            out = np.empty((k, 4), np.float32)
            pts_buf = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=pts)
            out_buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
            kernel(
                queue, (-(-k // group) * group,), (group,), pts_buf, np.int32(k),
                tri_buf, m, node_buf, nidx_buf, dtri_buf, dm, dnode_buf, dnidx_buf,
                np.int32(use_tree), np.int32(mode), *scalars, out_buf,
            )  # fmt: skip
            cl.enqueue_copy(queue, out, out_buf)
            queue.finish()
            return out.astype(np.float64)

        return evaluate
