"""The correlation package's pieces: generated OpenCL, finishing, immutability, progress.

The OpenCL interpolation is generated from the Python one: these tests run the generated C
on random tables and compare it with the Python functions. The Correlator's K changes and
landscapes must be computable on a worker while poses are evaluated: these tests check
that nothing the per-pose path reads changes.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from gaussian_pair import pair

from engine.correlation import Correlator, LandscapeError, interpolation
from engine.correlation.finishing import boxes_overlap, finish, overlap_bounds, overlap_bounds_many
from engine.correlation.to_opencl import TranslationError, translate
from engine.errors import Cancelled
from engine.pose import rotation_matrix

# ------------------------------------------------------------------ generated OpenCL
PROBE = r"""
__kernel void probe(__global const float *table, __global const float *points,
                    const int radius, const int side, __global float *out)
{
    const int i = get_global_id(0);
    const cell_t at = cell(points[3 * i], points[3 * i + 1], points[3 * i + 2], radius, side);
    float g, gx, gy, gz;
    hermite(table, 1, at, &g, &gx, &gy, &gz);
    out[6 * i] = g;  out[6 * i + 1] = gx;  out[6 * i + 2] = gy;  out[6 * i + 3] = gz;
    out[6 * i + 4] = lerp(table, 0, at);
    float a, b, c, d, e;
    mode_terms(table, at, 0.3f, -0.7f, 1.5f, -2.0f, 0.25f, 1, &a, &b, &c, &d, &e);
    out[6 * i + 5] = a + 2.0f * b + 3.0f * c - d + 0.5f * e;
}
"""


def test_generated_opencl_interpolation_equals_the_python_definition(opencl_backend):
    """The C the kernel runs is generated from interpolation.py and computes the same."""
    cl = pytest.importorskip("pyopencl")
    rng = np.random.default_rng(5)
    radius, side = 3, 8
    table = rng.normal(size=(side**3, 8)).astype(np.float32)
    points = rng.uniform(-radius + 0.01, radius - 0.01, size=(64, 3)).astype(np.float32)
    source = "#define CHANNELS 8\n" + translate(interpolation.FUNCTIONS,
                                                interpolation.SIGNATURES) + PROBE
    ctx, queue = opencl_backend.context, opencl_backend.queue
    program = cl.Program(ctx, source).build()
    mf = cl.mem_flags
    out = np.empty((64, 6), dtype=np.float32)
    out_buf = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    program.probe(queue, (64,), None,
                  cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=table),
                  cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=points),
                  np.int32(radius), np.int32(side), out_buf)
    cl.enqueue_copy(queue, out, out_buf)
    table64 = table.astype(np.float64)
    for i, (x, y, z) in enumerate(points.astype(np.float64)):
        at = interpolation.cell(x, y, z, radius, side)
        expected = list(interpolation.hermite(table64, 1, at))
        expected.append(interpolation.lerp(table64, 0, at))
        a, b, c, d, e = interpolation.mode_terms(table64, at, 0.3, -0.7, 1.5, -2.0, 0.25, True)
        expected.append(a + 2 * b + 3 * c - d + 0.5 * e)
        np.testing.assert_allclose(out[i], expected, rtol=1e-4, atol=1e-4)


def test_kernel_source_contains_the_generated_functions():
    from engine.correlation.opencl_kernels import kernel_source

    source = kernel_source()
    for name in ("cell", "bilinear", "lerp", "hermite", "mode_terms"):
        assert f" {name}(" in source
    assert "generated from engine/correlation/interpolation.py" in source


def test_translation_refuses_what_it_cannot_follow():
    def uses_division(a, b):
        return a / b

    def uses_loop(a, b):
        for _ in range(3):
            a += b
        return a

    for func in (uses_division, uses_loop):
        with pytest.raises(TranslationError, match="cannot translate"):
            translate([func], {func.__name__: (("float", "float"), "float")})


# ------------------------------------------------------------------ finishing
def test_boxes_overlap_against_the_box_geometry():
    rng = np.random.default_rng(2)
    c1, c2 = np.array([0.1, 0.2, -0.3]), np.array([0.5, -0.4, 0.2])
    half1, half2 = np.array([3.0, 2.0, 2.5]), np.array([1.0, 1.5, 0.5])
    for _ in range(200):
        rot = rotation_matrix(rng.normal(size=3))
        t = rng.normal(scale=4.0, size=3)
        gap = np.abs(rot @ c2 + t - c1) - (half1 + np.abs(rot) @ half2 + 0.1)
        assert boxes_overlap(rot, t, c1, c2, half1, half2, 0.1) == bool(np.all(gap < 0))


def test_the_batched_overlap_bounds_are_the_scalar_ones():
    rng = np.random.default_rng(5)
    c1, c2 = rng.normal(size=3), rng.normal(size=3)
    half1, half2 = rng.uniform(1, 3, size=3), rng.uniform(0.5, 2, size=3)
    rots = np.stack([rotation_matrix(rng.normal(size=3)) for _ in range(20)])
    offset, reach = overlap_bounds_many(rots, c1, c2, half1, half2, 0.1)
    for r, o, w in zip(rots, offset, reach, strict=True):
        one = overlap_bounds(r, c1, c2, half1, half2, 0.1)
        np.testing.assert_allclose(o, one[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(w, one[1], rtol=0, atol=1e-12)


def test_finish_signs_and_scales():
    """E = -kappa Re f; F = -(2 pi kappa / N h) S_k; T from S_u and c2 x R^T S_k."""
    rng = np.random.default_rng(3)
    sums = rng.normal(size=7)
    rot = rotation_matrix(rng.normal(size=3))
    c2 = rng.normal(size=3)
    kappa, n_h, scale = 2.5, 40.0, 2.0
    out = finish(sums, rot, c2, kappa, n_h, scale, True)
    factor = 2 * np.pi * kappa / n_h
    assert out[0] == pytest.approx(-kappa * sums[0])
    np.testing.assert_allclose(out[1:4], -factor * sums[1:4])
    local = scale * n_h / (2 * np.pi) * sums[4:7] + np.cross(c2, rot.T @ sums[1:4])
    np.testing.assert_allclose(out[4:7], -factor * rot @ local)
    assert not np.any(finish(sums, rot, c2, kappa, n_h, scale, False)[4:7])


# ------------------------------------------------------------------ immutability and threads
def test_with_modes_is_pure_and_shares_the_spectra():
    d1, d2 = pair()
    corr = Correlator(d1, d2, modes=8, backend="numba", use_cache=False)
    rot = rotation_matrix(np.array([0.3, -0.2, 0.4]))
    t = np.array([0.4, 0.1, -0.2])
    before = corr.evaluate(rot, t)
    table = corr.table
    other = corr.with_modes(12)
    assert corr.table is table and corr.modes == 8 and other.modes == 12
    assert other.spectra is corr.spectra
    after = corr.evaluate(rot, t)
    assert after.energy == before.energy
    np.testing.assert_array_equal(after.torque, before.torque)
    reference = Correlator(d1, d2, modes=12, backend="numba", use_cache=False)
    assert other.evaluate(rot, t).energy == pytest.approx(reference.evaluate(rot, t).energy,
                                                          rel=1e-12)


def test_k_changes_and_landscapes_on_a_worker_leave_the_pose_path_alone():
    """A worker builds new tables and landscapes while the main thread evaluates: every
    evaluation equals the one before the worker started (nothing it reads changed).
    """
    d1, d2 = pair()
    corr = Correlator(d1, d2, modes=8, backend="numba", use_cache=False)
    rot = rotation_matrix(np.array([0.1, 0.5, -0.3]))
    t = np.array([0.2, -0.3, 0.1])
    expected = corr.evaluate(rot, t)
    results: list[object] = []
    done = threading.Event()

    def work() -> None:
        try:
            for k in (4, 10, 14, 6):
                results.append(corr.with_modes(k))
                results.append(corr.landscape(rot, modes=k, forces=False))
        finally:
            done.set()

    worker = threading.Thread(target=work)
    worker.start()
    while not done.is_set():
        ev = corr.evaluate(rot, t)
        assert ev.energy == expected.energy
        np.testing.assert_array_equal(ev.force, expected.force)
    worker.join()
    assert len(results) == 8 and corr.modes == 8


# ------------------------------------------------------------------ errors and progress
def test_landscape_failures_are_typed():
    d1, d2 = pair()
    corr = Correlator(d1, d2, modes=6, backend="numpy", use_cache=False)
    with pytest.raises(LandscapeError, match="rotation"):
        corr.landscape(np.full((3, 3), np.nan))
    with pytest.raises(LandscapeError, match="rotation"):
        corr.landscape(2.0 * np.eye(3))
    with pytest.raises(Cancelled):
        corr.landscape(np.eye(3), cancel=lambda: True)


def test_progress_is_reported_and_ends_at_one():
    d1, d2 = pair()
    seen: list[float] = []
    Correlator(d1, d2, modes=6, backend="auto", use_cache=False, progress=seen.append)
    assert seen and seen[-1] == 1.0
    assert all(0.0 <= f <= 1.0 for f in seen)
    assert seen == sorted(seen)
    with pytest.raises(Cancelled):
        Correlator(d1, d2, modes=6, backend="numpy", use_cache=False, cancel=lambda: True)


# ------------------------------------------------------------------ rotation cache
@pytest.fixture(scope="module")
def cached():
    pytest.importorskip("numba")
    d1, d2 = pair()
    corr = Correlator(d1, d2, modes=12, backend="numba", use_cache=False)
    r0 = rotation_matrix(np.array([0.3, -0.2, 0.5]))
    return corr, r0, corr.rotation_cache(r0)


def test_rotation_cache_equals_the_full_path_at_its_rotation(cached):
    corr, r0, cache = cached
    for t in (np.array([0.2, -0.3, 0.1]), np.array([-0.6, 0.4, 0.3])):
        full = corr.evaluate(r0, t)
        fast = corr.evaluate_cached(cache, r0, t)
        assert fast.energy == pytest.approx(full.energy, rel=1e-5)
        np.testing.assert_allclose(fast.force, full.force, atol=1e-5 * np.linalg.norm(full.force))
        np.testing.assert_allclose(fast.torque, full.torque,
                                   atol=1e-5 * np.linalg.norm(full.torque))
    far = corr.evaluate_cached(cache, r0, np.array([50.0, 0.0, 0.0]))
    assert far.energy == 0.0 and not np.any(far.force) and not np.any(far.torque)


def test_rotation_cache_error_is_second_order_in_the_rotation(cached):
    corr, r0, cache = cached
    t = np.array([0.2, -0.3, 0.1])
    axis = np.array([0.6, 0.0, 0.8])
    errors = []
    for angle in (2e-3, 4e-3, 8e-3):
        rot = rotation_matrix(angle * axis) @ r0
        errors.append(abs(corr.evaluate_cached(cache, rot, t).energy
                          - corr.evaluate(rot, t).energy))
    assert errors[1] > 2.5 * errors[0] and errors[2] > 2.5 * errors[1]
    assert errors[0] < 1e-4 * abs(corr.evaluate(r0, t).energy)


def test_rotation_cache_force_and_torque_are_derivatives_of_its_energy(cached):
    """The cached model is conservative: F and T are -dE/dt and -dE/dtheta of the energy it
    reports, also away from the cache's rotation.
    """
    corr, r0, cache = cached
    rot = rotation_matrix(np.array([4e-3, -2e-3, 3e-3])) @ r0
    t = np.array([0.2, -0.3, 0.1])
    ev = corr.evaluate_cached(cache, rot, t)
    eps = 1e-4
    fd_t = np.empty(3)
    fd_f = np.empty(3)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        plus = corr.evaluate_cached(cache, rotation_matrix(d) @ rot, t).energy
        minus = corr.evaluate_cached(cache, rotation_matrix(-d) @ rot, t).energy
        fd_t[a] = -(plus - minus) / (2 * eps)
        fd_f[a] = -(corr.evaluate_cached(cache, rot, t + d).energy
                    - corr.evaluate_cached(cache, rot, t - d).energy) / (2 * eps)
    assert np.linalg.norm(ev.torque - fd_t) < 1e-3 * np.linalg.norm(fd_t)
    assert np.linalg.norm(ev.force - fd_f) < 1e-3 * np.linalg.norm(fd_f)
