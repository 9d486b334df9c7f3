"""Landscapes: one inverse FFT against per-pose evaluation and brute-force sums."""

from __future__ import annotations

import numpy as np
import pytest
from gaussian_pair import GRID1, GRID2, H, gaussian, pair

from engine.correlation import Correlator
from engine.pose import rotation_matrix


@pytest.fixture(scope="module")
def corr():
    fixed, moving = pair()
    return Correlator(fixed, moving, modes=10_000, backend="numpy", use_cache=False)


def test_identity_full_modes_equals_brute_force(corr):
    land = corr.landscape(np.eye(3))
    rho1 = gaussian(GRID1, (0.2, -0.1, 0.3), 0.8, 1 + 1j) + gaussian(GRID1, (-1, 0.5, 0), 0.7, -1j)
    rho2 = gaussian(GRID2, (0.3, 0.2, -0.2), 0.7, 2 - 1j)
    rng = np.random.default_rng(1)
    for _ in range(6):
        idx = rng.integers(0, land.energy.shape[0], size=3)
        t = np.array([ax[i] for ax, i in zip(land.translations, idx, strict=True)])
        shift = np.rint((t + np.asarray(GRID2.origin) - np.asarray(GRID1.origin)) / H).astype(int)
        total = 0j
        for i in range(rho2.shape[0]):
            for j in range(rho2.shape[1]):
                for k in range(rho2.shape[2]):
                    a, b, c = i + shift[0], j + shift[1], k + shift[2]
                    if 0 <= a < 13 and 0 <= b < 13 and 0 <= c < 13:
                        total += complex(rho1[a, b, c]) * complex(rho2[i, j, k])
        expected = -(total * H**3).real
        scale = float(np.abs(land.energy).max())
        assert land.energy[tuple(idx)] == pytest.approx(expected, abs=1e-5 * scale)


def test_matches_per_pose_evaluation(corr):
    rot = rotation_matrix(np.array([0.3, -0.6, 0.2]))
    corr.set_modes(8)
    land = corr.landscape(rot)
    assert land.modes == 8
    rng = np.random.default_rng(2)
    n = land.energy.shape[0]
    for _ in range(5):
        idx = rng.integers(n // 4, 3 * n // 4, size=3)
        t = np.array([ax[i] for ax, i in zip(land.translations, idx, strict=True)])
        ev = corr.evaluate(rot, t)
        scale = float(np.abs(land.energy).max())
        assert land.energy[tuple(idx)] == pytest.approx(ev.energy, abs=1e-5 * scale)
        np.testing.assert_allclose(land.force[(slice(None),) + tuple(idx)], ev.force,
                                   atol=1e-5 * np.abs(land.force).max())
        looked = land.lookup(t)
        assert looked.energy == pytest.approx(ev.energy, abs=1e-5 * scale)
        assert looked.torque is None
    corr.set_modes(10_000)


def test_lookup_interpolates_and_is_zero_outside(corr):
    land = corr.landscape(np.eye(3), forces=False)
    x, y, z = land.translations
    n = len(x)
    i, j, k = n // 2, n // 2 + 1, n // 2 - 1
    t = np.array([0.5 * (x[i] + x[i + 1]), y[j], z[k]])
    expected = 0.5 * (land.energy[i, j, k] + land.energy[i + 1, j, k])
    assert land.lookup(t).energy == pytest.approx(expected, rel=1e-6)
    far = land.lookup(np.array([x[-1] + 10 * H, 0, 0]))
    assert far.energy == 0.0 and not np.any(far.force)


def test_lookup_force_is_minus_the_gradient_of_the_looked_up_energy(corr):
    """With forces, the lookup interpolates gradient-enhanced: its force is -dE/dt of its
    own energy (a conservative field for locked-rotation scenes), and between lattice points
    it is closer to the exact per-pose value than trilinear interpolation.
    """
    land = corr.landscape(np.eye(3))
    x, y, z = land.translations
    n = len(x)
    rng = np.random.default_rng(4)
    for _ in range(5):
        t = np.array([ax[n // 2] for ax in (x, y, z)]) + rng.uniform(-2, 2, 3) * H
        looked = land.lookup(t)
        eps = 1e-5
        fd = np.array([-(land.lookup(t + d).energy - land.lookup(t - d).energy) / (2 * eps)
                       for d in np.eye(3) * eps])
        np.testing.assert_allclose(looked.force, fd, atol=1e-4 * np.abs(land.force).max())
        exact = corr.evaluate(np.eye(3), t)
        trilinear = land_energy_trilinear(land, t)
        assert abs(looked.energy - exact.energy) < 0.5 * abs(trilinear - exact.energy) + 1e-9


def land_energy_trilinear(land, t):
    origin = np.array([ax[0] for ax in land.translations])
    pos = (t - origin) / land.spacing
    i0 = np.floor(pos).astype(int)
    fr = pos - i0
    total = 0.0
    for c in np.ndindex(2, 2, 2):
        w = np.prod([fr[a] if c[a] else 1 - fr[a] for a in range(3)])
        total += w * land.energy[tuple(i0 + np.array(c))]
    return total


def test_section_and_minimum(corr):
    land = corr.landscape(np.eye(3), forces=False)
    t_min, e_min = land.minimum()
    assert e_min == pytest.approx(land.energy.min())
    section, u, v = land.section("xy", t_min[2])
    assert section.shape == (len(u), len(v))
    assert section.min() == pytest.approx(e_min, rel=1e-6)
    section_xz, _, _ = land.section("xz", t_min[1])
    assert section_xz.min() == pytest.approx(e_min, rel=1e-6)
    with pytest.raises(ValueError, match="valid: xy, xz, yz"):
        land.section("xx", 0.0)
    with pytest.raises(ValueError, match="outside"):
        land.section("xy", 1e6)


def test_far_from_overlap_is_zero(corr):
    rot = rotation_matrix(np.array([0.2, 0.1, 0.4]))
    land = corr.landscape(rot, forces=False)
    x, y, z = land.translations
    for idx in [(0, 0, 0), (len(x) - 1, 0, len(z) // 2)]:
        t = np.array([x[idx[0]], y[idx[1]], z[idx[2]]])
        if not corr.boxes_overlap(rot, t):
            assert land.energy[idx] == 0.0


def test_transforms_use_the_calling_threads_budget(corr, monkeypatch):
    """Inside ``spare_cores`` (the runtime's job worker) the landscape's inverse FFTs leave
    a core free; elsewhere they use every core.
    """
    import engine.backend as backend
    import engine.correlation.landscape as landscape_module

    monkeypatch.setattr(backend, "cpu_cores", lambda: 4)
    seen: list[int] = []
    real = landscape_module.scipy.fft.ifftn
    monkeypatch.setattr(landscape_module.scipy.fft, "ifftn",
                        lambda x, workers=None, **kw: seen.append(workers)
                        or real(x, workers=1, **kw))
    corr.landscape(np.eye(3))
    assert seen and set(seen) == {4}
    seen.clear()
    with backend.spare_cores(1) as threads:
        corr.landscape(np.eye(3))
    assert threads == 3 and seen and set(seen) == {3}
    with backend.spare_cores(8):
        assert backend.thread_budget() == 1  # never fewer than one
    assert backend.thread_budget() == 4
