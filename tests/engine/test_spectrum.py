"""Spectra: centred zero-padded FFTs against direct Fourier sums and Gaussian transforms."""

from __future__ import annotations

import numpy as np
import pytest

from engine.correlation.spectrum import (
    compute_spectrum,
    cube_weights,
    fast_size,
    kept_indices,
    kept_weights,
)
from engine.grid import Grid


def _smooth(n: int) -> bool:
    for p in (2, 3, 5, 7):
        while n % p == 0:
            n //= p
    return n == 1


@pytest.mark.parametrize("target", [1, 7, 33, 97, 131, 211])
def test_fast_size_is_smallest_even_smooth(target):
    n = fast_size(target)
    assert n >= target and n % 2 == 0 and _smooth(n)
    assert not any(m % 2 == 0 and _smooth(m) for m in range(max(target, 2), n))


def test_values_and_moments_equal_direct_sums():
    rng = np.random.default_rng(0)
    grid = Grid((0.3, -1.2, 2.0), 0.25, (5, 6, 4))
    rho = (rng.normal(size=grid.shape) + 1j * rng.normal(size=grid.shape)).astype(np.complex64)
    size = 8
    spec = compute_spectrum(rho, grid, size, moments=True, use_cache=False)
    points = grid.points().reshape(-1, 3)
    centre = grid.centre
    h = grid.spacing
    for k in [(0, 0, 0), (1, -2, 3), (-4, 3, -1), (2, 2, 2)]:
        w = np.asarray(k) / (size * h)
        phase = np.exp(-2j * np.pi * (points - centre) @ w)
        expected = h**3 * np.sum(rho.ravel() * phase)
        idx = tuple(np.mod(k, size))
        assert spec.values[idx] == pytest.approx(expected, rel=1e-5, abs=1e-6)
        for a in range(3):
            moment = h**3 * np.sum((points[:, a] - centre[a]) * rho.ravel() * phase)
            assert spec.moments[(a,) + idx] == pytest.approx(moment, rel=1e-5, abs=1e-6)


def test_gaussian_has_its_closed_form_transform():
    """FT of exp(-|p - mu|^2 / 2 s^2) about c:

    (2 pi s^2)^1.5 exp(-2 pi^2 s^2 w^2 - 2 pi i w.(mu - c)).
    """
    grid = Grid((-4.0, -4.0, -4.0), 0.4, (21, 21, 21))
    mu = np.array([0.3, -0.5, 0.2])
    s = 0.9
    p = grid.points()
    rho = np.exp(-np.sum((p - mu) ** 2, axis=-1) / (2 * s * s)).astype(np.complex64)
    spec = compute_spectrum(rho, grid, 32, use_cache=False)
    k = np.fft.fftfreq(32, 1 / 32)
    kx, ky, kz = np.meshgrid(k, k, k, indexing="ij")
    w = np.stack([kx, ky, kz], -1) / (32 * grid.spacing)
    expected = (2 * np.pi * s * s) ** 1.5 * np.exp(
        -2 * np.pi**2 * s * s * np.sum(w * w, -1) - 2j * np.pi * w @ (mu - grid.centre)
    )
    assert np.abs(spec.values - expected).max() < 1e-4 * np.abs(expected).max()


def test_spectra_are_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    grid = Grid((0, 0, 0), 1.0, (4, 4, 4))
    rho = np.ones(grid.shape, dtype=np.complex64)
    first = compute_spectrum(rho, grid, 8, moments=True)
    second = compute_spectrum(rho, grid, 8, moments=True)
    assert not first.from_cache and second.from_cache
    np.testing.assert_array_equal(first.values, second.values)
    np.testing.assert_array_equal(first.moments, second.moments)
    other = compute_spectrum(rho, grid, 8, moments=False)  # a different entry
    assert not other.from_cache and other.moments is None


def test_bad_inputs_are_rejected():
    grid = Grid((0, 0, 0), 1.0, (4, 4, 4))
    with pytest.raises(ValueError, match="grid shape"):
        compute_spectrum(np.zeros((3, 4, 4), np.complex64), grid, 8, use_cache=False)
    with pytest.raises(ValueError, match="smaller"):
        compute_spectrum(np.zeros((4, 4, 4), np.complex64), grid, 2, use_cache=False)
    bad = np.zeros((4, 4, 4), np.complex64)
    bad[1, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        compute_spectrum(bad, grid, 8, use_cache=False)


def test_kept_band_is_symmetric_with_half_weights_at_an_even_bands_ends():
    np.testing.assert_array_equal(kept_indices(4, 16), [-2, -1, 0, 1, 2])
    np.testing.assert_array_equal(kept_weights(4, taper="none"), [0.5, 1, 1, 1, 0.5])
    np.testing.assert_array_equal(kept_indices(3, 16), [-1, 0, 1])
    np.testing.assert_array_equal(kept_weights(3, taper="none"), [1, 1, 1])
    np.testing.assert_array_equal(kept_indices(1, 16), [0])
    for k in range(1, 17):
        band = kept_indices(k, 16)
        np.testing.assert_array_equal(band, -band[::-1])  # symmetric about zero
        # K modes' worth per axis before the taper (tests/engine/test_band_taper.py)
        assert kept_weights(k, taper="none").sum() == pytest.approx(k)
    # the whole even lattice: both ends wrap onto the Nyquist index, half each
    wrapped = np.mod(kept_indices(16, 16), 16)
    per_index = np.bincount(wrapped, weights=kept_weights(16, 16), minlength=16)
    np.testing.assert_array_equal(per_index, np.ones(16))
    w = cube_weights(4, 4)
    assert w.shape == (5, 5, 5) and w[0, 0, 0] == 0.125 and w[2, 2, 2] == 1.0
    with pytest.raises(ValueError):
        kept_indices(17, 16)


def test_refined_table_equals_direct_sums_at_fractional_frequencies():
    from engine.correlation.spectrum import refined_table

    rng = np.random.default_rng(4)
    grid = Grid((0.1, 0.7, -0.4), 0.3, (5, 4, 6))
    rho = (rng.normal(size=grid.shape) + 1j * rng.normal(size=grid.shape)).astype(np.complex64)
    size, refine, radius = 8, 3, 7
    table = refined_table(rho, grid, size, refine, radius, moments=True, use_cache=False)
    assert table.shape == (2 * radius + 2,) * 3 + (8,)
    values = table.view(np.complex64)  # (B, B, B, 4)
    points = grid.points().reshape(-1, 3)
    centre = grid.centre
    h = grid.spacing
    coarse = compute_spectrum(rho, grid, size, use_cache=False)
    for j in [(0, 0, 0), (1, -2, 3), (-7, 5, 8), (4, 4, -1), (3, 0, 0)]:
        w = np.asarray(j) / (refine * size * h)
        phase = np.exp(-2j * np.pi * (points - centre) @ w)
        expected = h**3 * np.sum(rho.ravel() * phase)
        pos = tuple(np.asarray(j) + radius)
        assert values[pos + (0,)] == pytest.approx(expected, rel=1e-4, abs=1e-5)
        moment = h**3 * np.sum((points[:, 1] - centre[1]) * rho.ravel() * phase)
        assert values[pos + (2,)] == pytest.approx(moment, rel=1e-4, abs=1e-5)
        if all(x % refine == 0 for x in j):  # on the coarse lattice: the plain FFT values
            k = tuple(np.mod(np.asarray(j) // refine, size))
            assert values[pos + (0,)] == pytest.approx(coarse.values[k], rel=1e-5, abs=1e-6)
