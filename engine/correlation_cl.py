"""One fused OpenCL kernel for the per-pose sums of :mod:`engine.correlation`.

Works on the same arrays as the numba path: part 1's kept spectrum ``(K, K, K)`` complex64
(times ``dw``), part 2's interleaved spectrum table ``(B^3, C)`` float32 (``C = 8``: the
centred spectrum and its lattice derivatives from the moment spectra, interpolated by the
gradient-enhanced scheme of :func:`engine.correlation._hermite`; ``C = 2`` without torque,
trilinear) and the kept
frequency indices. These stay on the device between calls; a call passes the pose as one
``float16`` kernel argument (rotation, and the phase offset ``(t + R c2 - c1) / (N h)``)
and reads back seven numbers. The reduction over work-groups happens in the same kernel
(the last group to finish sums the group partials), so there is one launch per pose.

On a CPU-only machine (PoCL) a launch plus read-back costs a few hundred microseconds
whatever the kernel does (DESIGN.md section 4), so :class:`engine.correlation.Correlator`
measures this path against numba at start-up and keeps the faster.
"""

from __future__ import annotations

from typing import Any

import numpy as np

KERNEL_SOURCE = r"""
#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double acc_t;
#else
typedef float acc_t;
#endif

#define NSUM 7

#if CHANNELS == 8
/* Bilinear interpolation of d[i][j] (i along u, j along v) at (u, v); *du, *dv get its
   derivatives (engine.correlation._bilinear). */
inline float2 bilinear(const float2 d00, const float2 d01, const float2 d10, const float2 d11,
                       const float u, const float v, float2 *du, float2 *dv)
{
    const float2 l0 = d00 + v * (d01 - d00), l1 = d10 + v * (d11 - d10);
    *du = l1 - l0;
    *dv = (d01 - d00) + u * ((d11 - d10) - (d01 - d00));
    return l0 + u * (l1 - l0);
}

/* Gradient-enhanced interpolation (engine.correlation._hermite), real and imaginary parts
   together. Table row: value, then dG/du along x, y, z (float2 each). out: value, d/dx,
   d/dy, d/dz. */
inline void hermite(__global const float *table, const int b00, const int b01,
                    const int b10, const int b11, const float tx, const float ty,
                    const float tz, float2 *out)
{
    const float8 c000 = vload8(b00, table), c001 = vload8(b00 + 1, table);
    const float8 c010 = vload8(b01, table), c011 = vload8(b01 + 1, table);
    const float8 c100 = vload8(b10, table), c101 = vload8(b10 + 1, table);
    const float8 c110 = vload8(b11, table), c111 = vload8(b11 + 1, table);
    const float2 e00 = c001.s01 - c000.s01, e01 = c011.s01 - c010.s01;
    const float2 e10 = c101.s01 - c100.s01, e11 = c111.s01 - c110.s01;
    float2 gx, gy, gz, unused, da, db, b;
    float p;
    float2 g = bilinear(c000.s01 + tz * e00, c010.s01 + tz * e01, c100.s01 + tz * e10,
                        c110.s01 + tz * e11, tx, ty, &gx, &gy);
    gz = bilinear(e00, e01, e10, e11, tx, ty, &unused, &unused);
    /* x: drop X(0, y, z) - X(1, y, z), bilinear over (y, z) */
    b = bilinear(c000.s23 - c100.s23, c001.s23 - c101.s23, c010.s23 - c110.s23,
                 c011.s23 - c111.s23, ty, tz, &da, &db);
    p = 0.5f * tx * (1.0f - tx);
    g += p * b;  gx += (0.5f - tx) * b;  gy += p * da;  gz += p * db;
    /* y: drop Y(x, 0, z) - Y(x, 1, z), bilinear over (x, z) */
    b = bilinear(c000.s45 - c010.s45, c001.s45 - c011.s45, c100.s45 - c110.s45,
                 c101.s45 - c111.s45, tx, tz, &da, &db);
    p = 0.5f * ty * (1.0f - ty);
    g += p * b;  gy += (0.5f - ty) * b;  gx += p * da;  gz += p * db;
    /* z: drop Z(x, y, 0) - Z(x, y, 1), bilinear over (x, y) */
    b = bilinear(c000.s67 - c001.s67, c010.s67 - c011.s67, c100.s67 - c101.s67,
                 c110.s67 - c111.s67, tx, ty, &da, &db);
    p = 0.5f * tz * (1.0f - tz);
    g += p * b;  gz += (0.5f - tz) * b;  gx += p * da;  gy += p * db;
    out[0] = g;  out[1] = gx;  out[2] = gy;  out[3] = gz;
}
#endif

__kernel void pose_sums(
    __global const float2 *fixed,      /* (K^3) rho1c^(w) dw                     */
    __global const float *table,       /* (side^3 * CHANNELS) interleaved          */
    __global const float *kept,        /* (K) signed frequency indices             */
    const int nk, const int side, const int radius, const float q,
    const float16 pose,                /* R row-major s0..s8, shift/(N h) s9..sb   */
    __global volatile acc_t *partials, /* (groups * 8)                             */
    __global volatile int *counter,    /* (1), zero between calls                  */
    __global acc_t *out,               /* (8)                                      */
    __local acc_t *scratch)            /* (local size * NSUM)                      */
{
    const int lid = get_local_id(0);
    const int lsize = get_local_size(0);
    const int total = nk * nk * nk;
    acc_t s[NSUM];
    for (int j = 0; j < NSUM; ++j) s[j] = 0;
    const float r00 = pose.s0, r01 = pose.s1, r02 = pose.s2;
    const float r10 = pose.s3, r11 = pose.s4, r12 = pose.s5;
    const float r20 = pose.s6, r21 = pose.s7, r22 = pose.s8;
    for (int m = get_global_id(0); m < total; m += get_global_size(0)) {
        const int ix = m / (nk * nk);
        const int iy = (m / nk) % nk;
        const int iz = m % nk;
        const float kx = kept[ix], ky = kept[iy], kz = kept[iz];
        const float rk0 = kx * r00 + ky * r10 + kz * r20;
        const float rk1 = kx * r01 + ky * r11 + kz * r21;
        const float rk2 = kx * r02 + ky * r12 + kz * r22;
        const float ux = -q * rk0, uy = -q * rk1, uz = -q * rk2;
        const float fx = floor(ux), fy = floor(uy), fz = floor(uz);
        const float tx = ux - fx, ty = uy - fy, tz = uz - fz;
        const float sx = 1.0f - tx, sy = 1.0f - ty, sz = 1.0f - tz;
        const int b00 = (((int)fx + radius) * side + (int)fy + radius) * side + (int)fz + radius;
        const int b01 = b00 + side, b10 = b00 + side * side, b11 = b10 + side;
#if CHANNELS == 8
        float2 hv[4];
        hermite(table, b00, b01, b10, b11, tx, ty, tz, hv);
        const float g_re = hv[0].x, g_im = hv[0].y;
#else
        const float2 v = sx * sy * sz * vload2(b00, table) + sx * sy * tz * vload2(b00 + 1, table)
                       + sx * ty * sz * vload2(b01, table) + sx * ty * tz * vload2(b01 + 1, table)
                       + tx * sy * sz * vload2(b10, table) + tx * sy * tz * vload2(b10 + 1, table)
                       + tx * ty * sz * vload2(b11, table) + tx * ty * tz * vload2(b11 + 1, table);
        const float g_re = v.s0, g_im = v.s1;
#endif
        /* phase exp(2 pi i k.shift/(N h)) in turns, each axis reduced before summing */
        float px = kx * pose.s9;  px -= rint(px);
        float py = ky * pose.sa;  py -= rint(py);
        float pz = kz * pose.sb;  pz -= rint(pz);
        float cs;
        const float sn = sincos(6.283185307179586f * (px + py + pz), &cs);
        const float2 a = fixed[m];
        const float c_re = a.x * cs - a.y * sn;
        const float c_im = a.x * sn + a.y * cs;
        const float cg_re = c_re * g_re - c_im * g_im;
        const float cg_im = c_re * g_im + c_im * g_re;
        s[0] += cg_re;
        s[1] += cg_im * kx;
        s[2] += cg_im * ky;
        s[3] += cg_im * kz;
#if CHANNELS == 8
        /* Re(c dG/du) x R^T k; scaled to Im(c M) x R^T k on the host */
        const float r0 = c_re * hv[1].x - c_im * hv[1].y;
        const float r1 = c_re * hv[2].x - c_im * hv[2].y;
        const float r2 = c_re * hv[3].x - c_im * hv[3].y;
        s[4] += r1 * rk2 - r2 * rk1;
        s[5] += r2 * rk0 - r0 * rk2;
        s[6] += r0 * rk1 - r1 * rk0;
#endif
    }
    for (int j = 0; j < NSUM; ++j) scratch[lid * NSUM + j] = s[j];
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int stride = lsize / 2; stride > 0; stride /= 2) {
        if (lid < stride)
            for (int j = 0; j < NSUM; ++j)
                scratch[lid * NSUM + j] += scratch[(lid + stride) * NSUM + j];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    __local int is_last;
    if (lid == 0) {
        const int group = get_group_id(0);
        for (int j = 0; j < NSUM; ++j) partials[group * 8 + j] = scratch[j];
        mem_fence(CLK_GLOBAL_MEM_FENCE);
        is_last = (atomic_inc(counter) == (int)get_num_groups(0) - 1);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    if (is_last && lid == 0) {
        mem_fence(CLK_GLOBAL_MEM_FENCE);
        for (int j = 0; j < NSUM; ++j) {
            acc_t acc = 0;
            for (int g = 0; g < (int)get_num_groups(0); ++g) acc += partials[g * 8 + j];
            out[j] = acc;
        }
        *counter = 0;
    }
}
"""


class OpenCLKernel:
    """Per-pose sums in one OpenCL launch; device buffers kept between calls.

    Parameters
    ----------
    correlator : engine.correlation.Correlator
        Supplies the kept spectra (rebound after ``set_modes``).
    backend : engine.backend.Backend, optional
        An OpenCL backend; default :func:`engine.backend.get_backend` ``("opencl")``.
    """

    def __init__(self, correlator: Any, backend: Any = None) -> None:
        import pyopencl as cl

        from engine.backend import get_backend

        self._cl = cl
        self.backend = backend if backend is not None else get_backend("opencl")
        if self.backend.name != "opencl":
            raise RuntimeError("OpenCL backend is not available")
        ctx = self.backend.context
        device = ctx.devices[0]
        self.double = "cl_khr_fp64" in device.extensions
        if correlator.selection != "cube":
            raise RuntimeError(
                "the OpenCL kernel sums the cube of lowest modes only; "
                "use numba or numpy for selection='largest'"
            )
        self.channels = 8 if correlator.rotation else 2
        options = [f"-DCHANNELS={self.channels}", "-cl-fast-relaxed-math"]
        if self.double:
            options.append("-DUSE_DOUBLE")
        self.program = cl.Program(ctx, KERNEL_SOURCE).build(options=options)
        self.kernel = cl.Kernel(self.program, "pose_sums")
        self.acc_dtype = np.float64 if self.double else np.float32
        self.local_size = 64 if not self.backend.is_gpu else 256
        self.local_size = min(self.local_size, device.max_work_group_size)
        self.max_groups = 4 * device.max_compute_units if not self.backend.is_gpu else 512
        self._pose = np.zeros(16, dtype=np.float32)
        self._result = np.zeros(8, dtype=self.acc_dtype)
        self._modes = -1
        self.prepare(correlator)

    def describe(self) -> str:
        return f"opencl ({self.backend.device_name}, {'GPU' if self.backend.is_gpu else 'CPU'})"

    def set_modes(self, correlator: Any) -> None:
        self._modes = -1  # rebind lazily: the table is rebuilt on first use

    def prepare(self, correlator: Any) -> None:
        """Upload the current truncation's arrays and bind the constant kernel arguments."""
        cl = self._cl
        ctx = self.backend.context
        mf = cl.mem_flags
        table, radius, scale = correlator.moving_table()
        fixed = np.ascontiguousarray(correlator._fixed_kept.ravel())
        kept = correlator._kept.astype(np.float32)
        nk = len(kept)
        total = nk**3
        groups = max(1, min(self.max_groups, -(-total // self.local_size)))
        self.global_size = groups * self.local_size
        self._buffers = {
            "fixed": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=fixed),
            "table": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=table.ravel()),
            "kept": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=kept),
            "partials": cl.Buffer(ctx, mf.READ_WRITE, size=groups * 8 * self._result.itemsize),
            "counter": cl.Buffer(
                ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.zeros(1, dtype=np.int32)
            ),
            "out": cl.Buffer(ctx, mf.WRITE_ONLY, size=8 * self._result.itemsize),
        }
        b = self._buffers
        k = self.kernel
        k.set_arg(0, b["fixed"])
        k.set_arg(1, b["table"])
        k.set_arg(2, b["kept"])
        k.set_arg(3, np.int32(nk))
        k.set_arg(4, np.int32(table.shape[0]))
        k.set_arg(5, np.int32(radius))
        k.set_arg(6, np.float32(scale))
        k.set_arg(8, b["partials"])
        k.set_arg(9, b["counter"])
        k.set_arg(10, b["out"])
        k.set_arg(11, cl.LocalMemory(self.local_size * 7 * self._result.itemsize))
        # torque sums arrive as Re(c dG/du) x R^T k: times a / (2 pi) gives Im(c M) x R^T k
        self._torque_scale = scale * correlator.size * correlator.spacing / (2.0 * np.pi)
        self._modes = correlator.modes

    def sums(self, correlator: Any, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) ``[Re f, Im S_k (3), Im S_m (3)]`` at one pose (see ``Correlator._sums_numpy``)."""
        cl = self._cl
        if self._modes != correlator.modes:
            self.prepare(correlator)
        self._pose[:9] = rot.ravel()
        self._pose[9:12] = correlator._shift(rot, t) / (correlator.size * correlator.spacing)
        self.kernel.set_arg(7, self._pose.view(cl.cltypes.float16)[0])
        queue = self.backend.queue
        cl.enqueue_nd_range_kernel(queue, self.kernel, (self.global_size,), (self.local_size,))
        cl.enqueue_copy(queue, self._result, self._buffers["out"], is_blocking=True)
        sums = self._result[:7].astype(np.float64)
        sums[4:7] *= self._torque_scale
        return sums

    def pose(self, correlator: Any, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 ``[E, F (3), T (3)]`` at one pose (zeros where the boxes are apart)."""
        if not correlator.boxes_overlap(rot, t):
            return np.zeros(7)
        energy, force, torque = correlator._finish(self.sums(correlator, rot, t), rot)
        out = np.zeros(7)
        out[0] = energy
        out[1:4] = force
        if torque is not None:
            out[4:7] = torque
        return out
