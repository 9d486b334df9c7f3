"""Correlation: spectral sums against brute force, closed forms and finite differences.

The backbone is sums of isotropic complex Gaussians: their correlation, its gradient in
``t`` and its derivative under rotations of part 2 are known in closed form, so the
energy, force and torque of :class:`engine.correlation.Correlator` are checked against
exact answers, not against themselves.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from engine.correlation import Correlator, required_fft_size
from engine.grid import Grid
from engine.pose import rotation_matrix

H = 0.5
BLOBS1 = [(1 + 2j, (0.3, -0.2, 0.1), 1.0), (-0.5j, (1.0, 0.5, -0.5), 0.8)]
BLOBS2 = [(0.5 - 1j, (0.2, 0.1, -0.3), 0.9), (1j, (-0.7, 0.4, 0.2), 0.8)]
GRID1 = Grid((-5.0, -5.0, -5.0), H, (21, 21, 21))
GRID2 = Grid((-4.0, -4.5, -4.0), H, (17, 19, 17))


def gaussian_field(grid: Grid, blobs, motion=None) -> np.ndarray:
    """(nx, ny, nz) complex64 samples of ``sum a exp(-|p - mu|^2 / (2 s^2))``.

    ``motion = (Q, b)`` moves every blob centre to ``Q mu + b`` (isotropic blobs, so this is
    the field moved rigidly).
    """
    p = grid.points()
    out = np.zeros(grid.shape, dtype=complex)
    for a, mu, s in blobs:
        mu = np.asarray(mu, dtype=float)
        if motion is not None:
            mu = motion[0] @ mu + motion[1]
        out += a * np.exp(-np.sum((p - mu) ** 2, axis=-1) / (2 * s * s))
    return out.astype(np.complex64)


def closed_form(blobs1, blobs2, rot, t):
    """Exact ``f``, ``df/dt`` and ``df/dtheta`` for two Gaussian sums (complex)."""
    f = 0j
    df_dt = np.zeros(3, dtype=complex)
    df_dtheta = np.zeros(3, dtype=complex)
    for a, mu, s1 in blobs1:
        for b, nu, s2 in blobs2:
            var = s1 * s1 + s2 * s2
            rnu = rot @ np.asarray(nu)
            d = np.asarray(mu) - t - rnu
            term = a * b * (2 * np.pi * s1 * s1 * s2 * s2 / var) ** 1.5 * np.exp(-d @ d / (2 * var))
            f += term
            df_dt += term * d / var
            df_dtheta += np.cross(rnu, term * d / var)
    return f, df_dt, df_dtheta


def descriptor(rho, grid):
    return types.SimpleNamespace(rho=rho, grid=grid)


@pytest.fixture(scope="module")
def fields():
    return gaussian_field(GRID1, BLOBS1), gaussian_field(GRID2, BLOBS2)


@pytest.fixture(scope="module")
def full(fields):
    """Numpy reference at full modes."""
    r1, r2 = fields
    return Correlator(
        descriptor(r1, GRID1), descriptor(r2, GRID2), modes=10_000, backend="numpy",
        use_cache=False,
    )


@pytest.fixture(scope="module")
def fast(fields):
    r1, r2 = fields
    return Correlator(
        descriptor(r1, GRID1), descriptor(r2, GRID2), modes=16, backend="numba", use_cache=False
    )


def brute_force(r1, g1, r2, g2, shift):
    """``h^3 sum_b rho1[b + m] rho2[b]`` for part 2 moved by whole cells ``m``."""
    n1 = np.array(r1.shape)
    total = 0j
    for i in range(r2.shape[0]):
        for j in range(r2.shape[1]):
            a, b = i + shift[0], j + shift[1]
            if not (0 <= a < n1[0] and 0 <= b < n1[1]):
                continue
            k = np.arange(r2.shape[2])
            kk = k + shift[2]
            ok = (kk >= 0) & (kk < n1[2])
            total += np.sum(r1[a, b, kk[ok]].astype(complex) * r2[i, j, k[ok]])
    return total * g1.spacing**3


@pytest.mark.parametrize("shift", [(3, -2, 1), (0, 0, 0), (-14, 5, 18), (19, 0, -3)])
@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_full_modes_identity_equals_spatial_sum(fields, full, shift, backend):
    r1, r2 = fields
    full.use_backend(backend)
    t = np.asarray(GRID1.origin) - np.asarray(GRID2.origin) + H * np.asarray(shift)
    expected = -brute_force(r1, GRID1, r2, GRID2, shift).real
    got = full.evaluate(np.eye(3), t).energy
    assert got == pytest.approx(expected, rel=1e-5, abs=1e-6 * float(np.abs(r1).max()) ** 2)
    full.use_backend("numpy")


def test_identity_matches_closed_form(full):
    t = np.array([0.7, -0.4, 0.25])
    ev = full.evaluate(np.eye(3), t)
    f, df_dt, df_dth = closed_form(BLOBS1, BLOBS2, np.eye(3), t)
    assert ev.energy == pytest.approx(-f.real, rel=1e-5)
    np.testing.assert_allclose(ev.force, df_dt.real, rtol=1e-4, atol=1e-5)
    # the torque is the derivative of the interpolated rotated energy; at R = I every mode
    # sits on a lattice node, where the cubic Hermite interpolant's gradient is the node's
    # own moment spectrum: the closed form to 1e-7 (the earlier interpolant: 0.7 %)
    assert np.linalg.norm(ev.torque - df_dth.real) < 1e-5 * np.linalg.norm(df_dth.real)


@pytest.mark.parametrize(
    "rotvec",
    [(0.4, -0.3, 0.8), (np.pi, 0, 0), (0, np.pi, 0), (np.pi / np.sqrt(2), np.pi / np.sqrt(2), 0),
     (1e-9, -2e-9, 0), (0.0, 0.0, 2.0)],
)
def test_rotated_matches_closed_form(full, rotvec):
    """Interpolated rotated spectrum: energy, force and torque within the measured error."""
    rot = rotation_matrix(np.asarray(rotvec))
    t = np.array([0.3, 0.2, -0.4])
    ev = full.evaluate(rot, t)
    f, df_dt, df_dth = closed_form(BLOBS1, BLOBS2, rot, t)
    scale_e = abs(f)
    scale_f = np.linalg.norm(df_dt) + 1e-12
    scale_t = np.linalg.norm(df_dth) + 1e-12
    assert abs(ev.energy + f.real) < 0.01 * scale_e
    assert np.linalg.norm(ev.force - df_dt.real) < 0.02 * scale_f
    assert np.linalg.norm(ev.torque - df_dth.real) < 0.02 * scale_t


def test_force_is_central_difference_of_energy(fast):
    rot = rotation_matrix(np.array([0.3, 0.5, -0.2]))
    t = np.array([0.4, -0.3, 0.6])
    ev = fast.evaluate(rot, t)
    eps = 1e-4
    fd = np.empty(3)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        fd[a] = -(fast.evaluate(rot, t + d).energy - fast.evaluate(rot, t - d).energy) / (2 * eps)
    np.testing.assert_allclose(ev.force, fd, rtol=1e-5, atol=1e-6 * np.linalg.norm(fd))


def _rotation_difference(corr, rot, t, eps):
    """``-dE/dtheta`` by central differences under ``R -> exp([theta]x) R``."""
    fd = np.empty(3)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        plus = corr.evaluate(rotation_matrix(d) @ rot, t).energy
        minus = corr.evaluate(rotation_matrix(-d) @ rot, t).energy
        fd[a] = -(plus - minus) / (2 * eps)
    return fd


@pytest.mark.parametrize("which", ["full", "fast"])
@pytest.mark.parametrize("rotvec", [(0.3, 0.5, -0.2), (0.0, 0.0, 0.0), (0.01, 0.0, 0.0)])
def test_torque_is_central_difference_of_energy(request, which, rotvec):
    """T = -dE/dtheta (R -> exp([theta]x) R) of the energy the correlator reports, to the
    precision of the central difference: the torque differentiates the interpolant the
    energy uses, so the field is conservative (and a free part keeps its energy).
    """
    corr = request.getfixturevalue(which)
    rot = rotation_matrix(np.array(rotvec))
    t = np.array([0.4, -0.3, 0.6])
    ev = corr.evaluate(rot, t)
    fd = _rotation_difference(corr, rot, t, 1e-4)
    # the compiled kernel reads float32 tables but interpolates in float64. At the
    # identity every mode sits on a lattice node, where the cubic Hermite interpolant takes
    # the node's own gradient from every side; near it (0.01 rad about x) the modes stay on
    # lattice faces, across which the normal derivative keeps a third-order jump.
    tol = 2e-6 if which == "full" else 1e-5
    if np.linalg.norm(rotvec) < 0.1:
        tol = 1e-4
    assert np.linalg.norm(ev.torque - fd) < tol * np.linalg.norm(fd)
    # and the exact torque of the Gaussians lies close (the interpolation error)
    _, _, df_dth = closed_form(BLOBS1, BLOBS2, rot, t)
    if which == "full":
        assert np.linalg.norm(fd - df_dth.real) < 0.02 * np.linalg.norm(fd)


def test_invariant_under_moving_both_parts(full):
    """Move both parts' geometry by one rigid motion: the same relative pose, same energy."""
    q = rotation_matrix(np.array([0.7, -0.2, 0.4]))
    b = np.array([3.1, -1.7, 0.45])
    # the moved parts are sampled on new grids (new origins, same spacing)
    g1 = Grid(tuple(np.asarray(GRID1.origin) + b + 0.13), H, GRID1.shape)
    g2 = Grid(tuple(np.asarray(GRID2.origin) - 0.21), H, GRID2.shape)
    # part 1 moved by (q, b) in its frame; part 2 likewise in its own frame
    moved = Correlator(
        descriptor(gaussian_field(g1, BLOBS1, (q, b)), g1),
        descriptor(gaussian_field(g2, BLOBS2, (np.eye(3), np.zeros(3))), g2),
        modes=10_000, backend="numpy", use_cache=False,
    )
    rot = rotation_matrix(np.array([0.2, -0.4, 0.1]))
    t = np.array([0.3, 0.2, -0.4])
    before = full.evaluate(rot, t)
    after = moved.evaluate(q @ rot, q @ t + b)
    assert after.energy == pytest.approx(before.energy, rel=0.01)
    np.testing.assert_allclose(after.force, q @ before.force,
                               atol=0.02 * np.linalg.norm(before.force))


def test_far_apart_is_exactly_zero(fast, full):
    rot = rotation_matrix(np.array([0.1, 0.2, 0.3]))
    for corr in (fast, full):
        ev = corr.evaluate(rot, np.array([40.0, 0.0, 0.0]))
        assert ev.energy == 0.0
        assert not np.any(ev.force)
        assert not np.any(ev.torque)


def test_barely_overlapping_is_small_and_finite(full):
    """Just inside the overlap cut-off the truncated-box fields barely touch: energy ~ 0."""
    t = np.array([GRID1.upper[0] - GRID2.origin[0] + 0.5 * H, 0.0, 0.0])
    assert full.boxes_overlap(np.eye(3), t)
    ev = full.evaluate(np.eye(3), t)
    inside = full.evaluate(np.eye(3), np.zeros(3))
    assert np.isfinite(ev.energy)
    assert abs(ev.energy) < 1e-3 * abs(inside.energy)
    assert np.linalg.norm(ev.force) < 1e-3 * np.linalg.norm(inside.force) + 1e-9


def test_rotation_near_identity_is_continuous(fast):
    t = np.array([0.3, -0.2, 0.5])
    at_identity = fast.evaluate(np.eye(3), t)
    for angle in (1e-12, 1e-9, 1e-6):
        ev = fast.evaluate(rotation_matrix(np.array([angle, -angle, angle])), t)
        assert ev.energy == pytest.approx(at_identity.energy, rel=1e-5)
        # modes on lattice nodes fall into a neighbouring cell, whose gradient at the node
        # is the node's own: the torque changes only as much as the rotation does
        scale = np.linalg.norm(at_identity.torque)
        assert np.linalg.norm(ev.torque - at_identity.torque) < 1e-5 * scale


@pytest.mark.parametrize("scale", [1e-4, 1e4])
def test_tiny_and_huge_scales(scale):
    """Scaling lengths by s scales E by s^3, F by s^2, T by s^3 (unit amplitudes)."""
    def scaled(blobs):
        return [(a, tuple(scale * np.asarray(mu)), scale * s) for a, mu, s in blobs]

    g1 = Grid(tuple(scale * np.asarray(GRID1.origin)), scale * H, GRID1.shape)
    g2 = Grid(tuple(scale * np.asarray(GRID2.origin)), scale * H, GRID2.shape)
    big = Correlator(
        descriptor(gaussian_field(g1, scaled(BLOBS1)), g1),
        descriptor(gaussian_field(g2, scaled(BLOBS2)), g2),
        modes=12, backend="numba", use_cache=False,
    )
    unit = Correlator(
        descriptor(gaussian_field(GRID1, BLOBS1), GRID1),
        descriptor(gaussian_field(GRID2, BLOBS2), GRID2),
        modes=12, backend="numba", use_cache=False,
    )
    rot = rotation_matrix(np.array([0.5, 0.1, -0.3]))
    t = np.array([0.3, 0.2, -0.4])
    ev_big = big.evaluate(rot, scale * t)
    ev_unit = unit.evaluate(rot, t)
    assert np.isfinite(ev_big.energy) and np.all(np.isfinite(ev_big.torque))
    assert ev_big.energy / scale**3 == pytest.approx(ev_unit.energy, rel=1e-4)
    np.testing.assert_allclose(ev_big.force / scale**2, ev_unit.force, rtol=1e-3,
                               atol=1e-4 * np.linalg.norm(ev_unit.force))
    np.testing.assert_allclose(ev_big.torque / scale**3, ev_unit.torque, rtol=1e-3,
                               atol=1e-4 * np.linalg.norm(ev_unit.torque))


def test_all_mode_counts_finite_and_converging(fast, full):
    rot = rotation_matrix(np.array([0.4, -0.3, 0.8]))
    t = np.array([0.3, 0.2, -0.4])
    exact = -closed_form(BLOBS1, BLOBS2, rot, t)[0].real
    errors = []
    for k in list(range(2, 33, 2)) + [full.size]:
        fast.set_modes(k)
        ev = fast.evaluate(rot, t)
        assert np.isfinite(ev.energy) and np.all(np.isfinite(ev.force))
        assert np.all(np.isfinite(ev.torque))
        errors.append(abs(ev.energy - exact))
    fast.set_modes(16)
    # full modes: only the interpolation error of the q lattice is left (about 1e-5)
    assert errors[-1] < 1e-4 * abs(exact)
    assert abs(fast.evaluate(rot, t).energy - full.evaluate(rot, t).energy) > 0
    assert errors[0] > errors[7] > errors[11] > errors[-1]


def test_interpolation_error_falls_with_refinement_and_gradients(fields):
    """Rotated spectrum: the refined table and the cubic Hermite interpolant (rotation on)
    each cut the interpolation error; measured against a 4x refined table, so that the
    closed form's own discretisation error (about 1e-5 here) does not hide it. The band is
    kept untapered: the Gaussians' spectra lie within K = 32, so the box band's sum is the
    closed form's (the correlator's band unless told).
    """
    r1, r2 = fields
    rot = rotation_matrix(np.array([0.4, -0.3, 0.8]))
    t = np.array([0.3, 0.2, -0.4])
    energy = {}
    for rotation in (False, True):
        for refine in (1, 2, 4):
            corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=32,
                              rotation=rotation, backend="numpy", refine=refine,
                              fine_modes=32, use_cache=False)
            energy[rotation, refine] = corr.evaluate(rot, t).energy
    exact = -closed_form(BLOBS1, BLOBS2, rot, t)[0].real
    assert energy[True, 4] == pytest.approx(exact, rel=1e-4)
    err = {key: abs(value - energy[True, 4]) for key, value in energy.items()}
    # trilinear: second order (measured 7.9e-3, 2.0e-3); cubic Hermite with the moment
    # spectra's gradients: fourth order or better (9.6e-6, 6.9e-7)
    assert err[False, 2] < 0.4 * err[False, 1]
    assert err[True, 2] < 0.2 * err[True, 1]
    assert err[True, 1] < 0.01 * err[False, 1]
    assert err[True, 2] < 0.01 * err[False, 2]


def test_energy_smooth_along_a_path(fast):
    """No jumps: second differences along a line stay at the level of the curvature."""
    rot = rotation_matrix(np.array([0.2, 0.3, 0.1]))
    fast.set_modes(8)
    ts = np.linspace(-2.0, 2.0, 81)
    energy = np.array([fast.evaluate(rot, np.array([x, 0.1, -0.2])).energy for x in ts])
    fast.set_modes(16)
    second = np.abs(np.diff(energy, 2))
    assert second.max() < 5 * np.median(second) + 1e-9


def test_set_modes_only_truncates(fields, monkeypatch):
    import scipy.fft

    r1, r2 = fields
    calls = {"fft": 0}
    original = scipy.fft.fftn

    def counting(*args, **kwargs):
        calls["fft"] += 1
        return original(*args, **kwargs)

    monkeypatch.setattr(scipy.fft, "fftn", counting)
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8, backend="numpy",
                      use_cache=False)
    after_init = calls["fft"]
    # part 1's spectrum only: part 2's refined table is a separable Fourier sum, and its
    # spectrum on the q lattice is computed when a K beyond the refined table needs it
    assert after_init == 1
    spectra = corr.stats["spectra"]
    for k in (4, 12, 20, 8):
        corr.set_modes(k)
        corr.evaluate(np.eye(3), np.zeros(3))
    assert calls["fft"] == after_init
    assert corr.stats["spectra"] == spectra
    assert corr.stats["truncations"] == 5
    for k in (30, 40, 30, 8):  # beyond the refined table: part 2 and 3 moments, once
        corr.set_modes(k)
        corr.evaluate(np.eye(3), np.zeros(3))
    assert calls["fft"] == after_init + 4


def test_rotation_off_computes_no_moments(fields):
    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8, rotation=False,
                      backend="numba", use_cache=False)
    assert corr.stats["moment_spectra"] == 0
    assert corr.spectra.moving.moments is None
    assert corr.table.moving.shape[-1] == 2
    ev = corr.evaluate(rotation_matrix(np.array([0.1, 0.2, 0.3])), np.array([0.1, 0.0, 0.2]))
    assert ev.torque is None
    assert corr.stats["torque_sums"] == 0
    with_torque = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8,
                             backend="numba", use_cache=False)
    ev2 = with_torque.evaluate(rotation_matrix(np.array([0.1, 0.2, 0.3])),
                               np.array([0.1, 0.0, 0.2]))
    # rotation off interpolates trilinearly (no moment spectra), rotation on with the
    # gradients: equal up to the trilinear error, and exactly equal at R = I
    assert ev.energy == pytest.approx(ev2.energy, rel=1e-2)
    t0 = np.array([0.1, 0.0, 0.2])
    at_identity = corr.evaluate(np.eye(3), t0), with_torque.evaluate(np.eye(3), t0)
    assert at_identity[0].energy == pytest.approx(at_identity[1].energy, rel=1e-6)
    np.testing.assert_allclose(at_identity[0].force, at_identity[1].force, rtol=1e-6)
    np.testing.assert_allclose(ev.force, ev2.force, rtol=1e-2)
    assert with_torque.stats["moment_spectra"] == 3
    assert with_torque.stats["torque_sums"] == 2


@pytest.mark.parametrize("k", [2, 5, 16, 33])
def test_numba_agrees_with_numpy(fields, k):
    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=k, backend="numba",
                      use_cache=False)
    rng = np.random.default_rng(k)
    for _ in range(4):
        rot = rotation_matrix(rng.normal(size=3))
        t = rng.normal(scale=1.5, size=3)
        corr.use_backend("numba")
        got = corr.evaluate(rot, t)
        corr.use_backend("numpy")
        ref = corr.evaluate(rot, t)
        scale = abs(ref.energy) + 1e-9
        assert got.energy == pytest.approx(ref.energy, abs=1e-5 * scale)
        np.testing.assert_allclose(got.force, ref.force,
                                   atol=1e-5 * (np.linalg.norm(ref.force) + 1))
        np.testing.assert_allclose(got.torque, ref.torque,
                                   atol=1e-5 * (np.linalg.norm(ref.torque) + 1))


def test_opencl_agrees_with_numpy(fields):
    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=12, backend="numpy",
                      use_cache=False)
    try:
        corr.use_backend("opencl")
    except Exception as exc:  # noqa: BLE001 - no usable OpenCL device here
        pytest.skip(f"OpenCL kernel cannot run here: {str(exc).splitlines()[0]}")
    rng = np.random.default_rng(3)
    for _ in range(4):
        rot = rotation_matrix(rng.normal(size=3))
        t = rng.normal(scale=1.5, size=3)
        corr.use_backend("opencl")
        got = corr.evaluate(rot, t)
        corr.use_backend("numpy")
        ref = corr.evaluate(rot, t)
        assert got.energy == pytest.approx(ref.energy, rel=1e-4, abs=1e-5)
        np.testing.assert_allclose(got.force, ref.force, atol=1e-4 * np.linalg.norm(ref.force))
        np.testing.assert_allclose(got.torque, ref.torque, atol=1e-4 * np.linalg.norm(ref.torque))


def _compiled_kernel(name):
    from engine.backend import BackendError
    from engine.correlation.per_pose import make_kernel

    try:
        return make_kernel(name, "cube", True)
    except BackendError as exc:
        pytest.skip(f"the {name} kernel cannot run here: {str(exc).splitlines()[0]}")


def _two_tables(fields):
    """A correlator's table and the one ``with_modes`` builds for a new K (as the worker does)."""
    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=12, backend="numpy",
                      use_cache=False)
    return corr, (corr.table, corr.with_modes(8).table)


def _poses(corr, count, seed):
    rng = np.random.default_rng(seed)
    g = corr.table.geometry
    out = []
    for _ in range(count):
        rot = rotation_matrix(rng.normal(scale=0.5, size=3))
        out.append((rot, g.centre_fixed - rot @ g.centre_moving + rng.normal(scale=1.0, size=3)))
    return out


@pytest.mark.parametrize("name", ["numba", "opencl"])
def test_kernel_prepares_each_table_once_when_two_take_turns(fields, name):
    # the worker warms and times a new K's field while the loop evaluates the old one, with
    # the same kernel: a kernel that kept only its last table prepared (copied, uploaded)
    # each table again at every turn
    kernel = _compiled_kernel(name)
    corr, tables = _two_tables(fields)
    (rot, t), = _poses(corr, 1, 5)
    for _ in range(5):
        for table in tables:
            kernel.pose(table, rot, t)
    assert kernel.per_table.prepared == 2


@pytest.mark.parametrize("name", ["numba", "opencl"])
def test_two_threads_on_two_tables_each_get_their_own_sums(fields, name):
    # the same kernel, one table per thread, the interpreter switching threads as often as
    # it can: every pose must come out as the numpy reference gives it for its own table
    import sys
    import threading

    from engine.correlation import reference

    kernel = _compiled_kernel(name)
    corr, tables = _two_tables(fields)
    poses = _poses(corr, 6, 11)
    expected = [[reference.pose(corr.spectra, table, rot, t) for rot, t in poses]
                for table in tables]
    wrong: list[str] = []

    def run(which):
        table = tables[which]
        for rep in range(40):
            for i, (rot, t) in enumerate(poses):
                got = kernel.pose(table, rot, t)
                ref = expected[which][i]
                if not np.allclose(got, ref, rtol=1e-3, atol=1e-4 * np.abs(ref).max()):
                    wrong.append(f"table {which}, pose {i}, round {rep}: {got} != {ref}")

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=run, args=(which,)) for which in (0, 1)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
    finally:
        sys.setswitchinterval(interval)
    assert not wrong, f"{len(wrong)} poses wrong, first: {wrong[0]}"


def test_auto_names_the_backend(fields):
    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8, use_cache=False)
    assert corr.backend in ("numba", "opencl")
    assert "auto" in corr.backend_name and corr.backend in corr.backend_name


def test_input_validation(fields):
    r1, r2 = fields
    other = Grid(GRID2.origin, 0.6, GRID2.shape)
    with pytest.raises(ValueError, match="spacing"):
        Correlator(descriptor(r1, GRID1), descriptor(r2, other), use_cache=False)
    with pytest.raises(ValueError, match="valid: numpy, numba, opencl, auto"):
        Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), backend="cuda", use_cache=False)
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=4, backend="numpy",
                      use_cache=False)
    with pytest.raises(ValueError, match="NaN"):
        corr.evaluate(np.eye(3), np.array([np.nan, 0, 0]))
    with pytest.raises(ValueError):
        corr.set_modes(0)


def test_fft_size_covers_any_rotation():
    n = required_fft_size((21, 21, 21), (17, 19, 17))
    half_diag = 0.5 * np.linalg.norm([16, 18, 16])
    assert n % 2 == 0 and n >= 20 + 2 * half_diag + 3


def test_full_modes_on_compiled_backend_fall_back_to_reference(fields, monkeypatch):
    import engine.correlation.tables as tables

    r1, r2 = fields
    corr = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8, backend="numba",
                      use_cache=False)
    monkeypatch.setattr(tables, "MAX_TABLE_BYTES", 1 << 20)
    corr.set_modes(corr.size)
    rot = rotation_matrix(np.array([0.2, 0.1, 0.3]))
    got = corr.evaluate(rot, np.zeros(3))
    assert corr.stats["reference_fallbacks"] == 1
    corr.use_backend("numpy")
    assert got.energy == corr.evaluate(rot, np.zeros(3)).energy


def test_largest_selection(fields):
    """K^3 largest modes: numba = numpy, all modes = the full cube, better than the cube."""
    r1, r2 = fields
    rot = rotation_matrix(np.array([0.3, -0.2, 0.6]))
    t = np.array([0.4, 0.1, -0.3])
    largest = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=8,
                         selection="largest", backend="numba", use_cache=False)
    assert largest.table.mode_k.shape == (512, 3)
    got = largest.evaluate(rot, t)
    largest.use_backend("numpy")
    ref = largest.evaluate(rot, t)
    assert got.energy == pytest.approx(ref.energy, rel=1e-5)
    np.testing.assert_allclose(got.force, ref.force, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(got.torque, ref.torque, rtol=1e-4, atol=1e-6)
    land = largest.landscape(rot, forces=False)
    i = land.energy.shape[0] // 2
    t_grid = np.array([ax[i] for ax in land.translations])
    assert land.energy[i, i, i] == pytest.approx(largest.evaluate(rot, t_grid).energy, rel=1e-4)
    # every mode kept: the same sum as the full cube
    largest.set_modes(largest.size)
    cube = Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), modes=largest.size,
                      backend="numpy", use_cache=False)
    assert largest.evaluate(rot, t).energy == pytest.approx(cube.evaluate(rot, t).energy, rel=1e-6)
    # the Gaussians' spectra peak at w = 0, so the 8^3 largest sit close to the 8^3 cube:
    # the same order of accuracy
    exact = -closed_form(BLOBS1, BLOBS2, rot, t)[0].real
    cube.set_modes(8)
    largest.set_modes(8)
    error_largest = abs(largest.evaluate(rot, t).energy - exact)
    assert error_largest < 1.5 * abs(cube.evaluate(rot, t).energy - exact)
    with pytest.raises(RuntimeError, match="cube"):
        largest.use_backend("opencl")
    with pytest.raises(ValueError, match="cube, largest"):
        Correlator(descriptor(r1, GRID1), descriptor(r2, GRID2), selection="random",
                   use_cache=False)
