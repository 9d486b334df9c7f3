"""The per-pose sums as one fused OpenCL kernel.

Works on the same :class:`~engine.correlation.tables.ModeTable` as the numba kernels: part
1's kept coefficients ``(K, K, K)`` complex64, part 2's interleaved table ``(B^3, C)``
float32 and the kept frequency indices. These are uploaded once per table and stay on the
device between calls; a call passes the pose as one ``float16`` kernel argument (rotation,
and the phase offset ``(t + R c2 - c1) / (N h)``) and reads back the seven raw sums, which
:func:`engine.correlation.finishing.finish` turns into energy, force and torque, as for
every other path. The reduction over work-groups happens in the same kernel (the last
group to finish sums the group partials), so there is one launch per pose.

The interpolation and the per-mode terms are C functions generated from their Python
definition (:func:`kernel_source`, :mod:`engine.correlation.to_opencl`); only the loop over
the modes, the phases and the reduction are written in C here.

On a CPU-only machine (PoCL) a launch plus read-back costs a few hundred microseconds
whatever the kernel does, so "auto" takes this path only on a GPU
(``engine.backend.CAPABILITIES["per_pose"].gpu_only``).
"""

from __future__ import annotations

import functools
import threading

import numpy as np
import pyopencl as cl

import engine.correlation.interpolation as interpolation
from engine.backend import Backend, BackendError, get_backend
from engine.correlation.finishing import boxes_overlap, finish, phase_offset
from engine.correlation.tables import ModeTable, PerTable
from engine.correlation.to_opencl import translate

KERNEL_LOOP = r"""
#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double acc_t;
#else
typedef float acc_t;
#endif

#define NSUM 7
#define MOMENTS (CHANNELS == 8)

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
        const cell_t at = cell(-q * rk0, -q * rk1, -q * rk2, radius, side);
        /* phase exp(2 pi i k.shift/(N h)) in turns, each axis reduced before summing */
        float px = kx * pose.s9;  px -= rint(px);
        float py = ky * pose.sa;  py -= rint(py);
        float pz = kz * pose.sb;  pz -= rint(pz);
        float cs;
        const float sn = sincos(6.283185307179586f * (px + py + pz), &cs);
        const float2 a = fixed[m];
        float cg_re, cg_im, d4, d5, d6;
        mode_terms(table, at, a.x * cs - a.y * sn, a.x * sn + a.y * cs, rk0, rk1, rk2,
                   MOMENTS, &cg_re, &cg_im, &d4, &d5, &d6);
        s[0] += cg_re;
        s[1] += cg_im * kx;
        s[2] += cg_im * ky;
        s[3] += cg_im * kz;
        s[4] += d4;
        s[5] += d5;
        s[6] += d6;
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


@functools.lru_cache(maxsize=1)
def kernel_source() -> str:
    """The OpenCL program: the generated interpolation functions, then the mode loop."""
    generated = translate(interpolation.FUNCTIONS, interpolation.SIGNATURES)
    return ("/* generated from engine/correlation/interpolation.py */\n" + generated
            + KERNEL_LOOP)


class OpenCLKernel:
    """Per-pose sums in one OpenCL launch; a table's buffers are uploaded on its first use.

    Threads: the runtime's worker times and warms a new field while the loop evaluates the
    field in use, and the two share this kernel. Each table gets its own :class:`_Launch`
    (kernel arguments, device buffers, host arrays, a lock), uploaded once
    (:class:`~engine.correlation.tables.PerTable`), and each thread its own command queue,
    so neither thread changes what the other's launch reads or waits behind its work.

    Parameters
    ----------
    selection : {"cube"}
        Only the cube of lowest modes is summed here (separable phases).
    rotation : bool
        Whether the tables carry the moment columns (``C = 8``) and torques are summed.
    backend : engine.backend.Backend, optional
        An OpenCL backend; default ``get_backend("opencl")``.
    """

    name = "opencl"

    def __init__(self, selection: str, rotation: bool, backend: Backend | None = None) -> None:
        self.backend = backend if backend is not None else get_backend("opencl")
        if self.backend.name != "opencl":
            raise BackendError(f"the OpenCL kernel needs an OpenCL backend, got "
                               f"{self.backend.name!r}")
        if selection != "cube":
            raise BackendError("the OpenCL kernel sums the cube of lowest modes only; "
                               "use numba or numpy for selection='largest'")
        ctx = self.backend.context
        device = ctx.devices[0]
        self.double = "cl_khr_fp64" in device.extensions
        self.channels = 8 if rotation else 2
        options = [f"-DCHANNELS={self.channels}", "-cl-fast-relaxed-math"]
        if self.double:
            options.append("-DUSE_DOUBLE")
        self.program = cl.Program(ctx, kernel_source()).build(options=options)
        self.acc_dtype = np.float64 if self.double else np.float32
        self.local_size = 64 if not self.backend.is_gpu else 256
        self.local_size = min(self.local_size, device.max_work_group_size)
        self.max_groups = 4 * device.max_compute_units if not self.backend.is_gpu else 512
        #: Each table's launch, uploaded on its first use (``per_table.prepared`` counts).
        self.per_table: PerTable[_Launch] = PerTable(lambda table: _Launch(self, table))
        self._queues = threading.local()

    def describe(self) -> str:
        """Name and device."""
        return f"opencl ({self.backend.device_name}, {'GPU' if self.backend.is_gpu else 'CPU'})"

    def supports(self, table: ModeTable) -> bool:
        """Whether this kernel can sum ``table`` (a cube with its interleaved table)."""
        return table.moving is not None and table.kept is not None

    def _queue(self) -> cl.CommandQueue:
        """The calling thread's command queue for this kernel (made on its first pose)."""
        queue = getattr(self._queues, "queue", None)
        if queue is None:
            queue = self._queues.queue = cl.CommandQueue(self.backend.context)
        return queue

    def raw_sums(self, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 raw sums at one pose (see :mod:`engine.correlation.finishing`)."""
        launch = self.per_table.get(table)
        g = table.geometry
        offset = phase_offset(rot, t, g.centre_fixed, g.centre_moving) / g.n_h
        return launch.run(self._queue(), rot, offset)

    def pose(self, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 ``[E, F (3), T (3)]`` at one pose (zeros where the boxes are apart)."""
        g = table.geometry
        if not boxes_overlap(rot, t, g.centre_fixed, g.centre_moving, g.half_fixed,
                             g.half_moving, g.spacing):
            return np.zeros(7)
        return finish(self.raw_sums(table, rot, t), rot, g.centre_moving, g.kappa, g.n_h,
                      table.scale, g.rotation)


class _Launch:
    """One table on the device: its buffers, a kernel bound to them, and its host arrays.

    A lock makes one launch run one pose at a time (two threads on the same table take
    turns); launches of different tables run side by side.
    """

    def __init__(self, owner: OpenCLKernel, table: ModeTable) -> None:
        assert table.moving is not None and table.kept is not None
        assert table.fixed_kept is not None
        ctx = owner.backend.context
        mf = cl.mem_flags
        fixed = np.ascontiguousarray(table.fixed_kept.ravel())
        kept = table.kept.astype(np.float32)
        nk = len(kept)
        self.local_size = owner.local_size
        groups = max(1, min(owner.max_groups, -(-nk**3 // owner.local_size)))
        self.global_size = groups * owner.local_size
        self.pose = np.zeros(16, dtype=np.float32)
        self.result = np.zeros(8, dtype=owner.acc_dtype)
        self.lock = threading.Lock()
        item = self.result.itemsize
        self.buffers = {
            "fixed": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=fixed),
            "table": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                               hostbuf=np.ascontiguousarray(table.moving.ravel())),
            "kept": cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=kept),
            "partials": cl.Buffer(ctx, mf.READ_WRITE, size=groups * 8 * item),
            "counter": cl.Buffer(
                ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=np.zeros(1, dtype=np.int32)
            ),
            "out": cl.Buffer(ctx, mf.WRITE_ONLY, size=8 * item),
        }
        b = self.buffers
        k = self.kernel = cl.Kernel(owner.program, "pose_sums")
        k.set_arg(0, b["fixed"])
        k.set_arg(1, b["table"])
        k.set_arg(2, b["kept"])
        k.set_arg(3, np.int32(nk))
        k.set_arg(4, np.int32(table.side))
        k.set_arg(5, np.int32(table.radius))
        k.set_arg(6, np.float32(table.scale))
        k.set_arg(8, b["partials"])
        k.set_arg(9, b["counter"])
        k.set_arg(10, b["out"])
        scratch = cl.LocalMemory(owner.local_size * 7 * item)
        k.set_arg(11, scratch)  # type: ignore[arg-type]  # the stub omits LocalMemory

    def run(self, queue: cl.CommandQueue, rot: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """(7,) float64 raw sums at the pose ``rot`` with phase offset ``offset``."""
        with self.lock:
            self.pose[:9] = rot.ravel()
            self.pose[9:12] = offset
            self.kernel.set_arg(7, self.pose.view(cl.cltypes.float16)[0])
            cl.enqueue_nd_range_kernel(queue, self.kernel, (self.global_size,),
                                       (self.local_size,))
            cl.enqueue_copy(queue, self.result, self.buffers["out"], is_blocking=True)
            return self.result[:7].astype(np.float64)
