"""The search's scan: landscapes on a coarse lattice, real transforms, lowest minima, blocks."""

import numpy as np
import pytest
from gaussian_pair import pair

from engine.correlation import Correlator, LandscapeError, compute_landscape
from engine.pose import rotation_matrix
from engine.search.rotations import RotationGrid
from engine.search.scan import Candidates, ScanBlock, lowest_minima
from engine.search.work import Shared


@pytest.fixture(scope="module")
def corr():
    fixed, moving = pair()
    return Correlator(fixed, moving, modes=8, backend="numpy", use_cache=False)


def test_a_coarser_lattice_samples_the_same_landscape(corr):
    rot = rotation_matrix(np.array([0.3, -0.5, 0.2]))
    n = corr.size
    full = compute_landscape(corr.spectra, rot, 8, forces=True)
    half = compute_landscape(corr.spectra, rot, 8, forces=True, lattice=n // 2)
    assert half.energy.shape == (n // 2,) * 3
    assert half.spacing == pytest.approx(2 * full.spacing)
    np.testing.assert_allclose(half.translations[1], full.translations[1][::2])
    scale = float(np.abs(full.energy).max())
    np.testing.assert_allclose(half.energy, full.energy[::2, ::2, ::2], atol=1e-5 * scale)
    np.testing.assert_allclose(half.force, full.force[:, ::2, ::2, ::2],
                               atol=1e-5 * float(np.abs(full.force).max()))


def test_real_transforms_give_the_complex_ones_result(corr):
    rot = rotation_matrix(np.array([-0.7, 0.1, 0.4]))
    a = compute_landscape(corr.spectra, rot, 8, forces=True)
    b = compute_landscape(corr.spectra, rot, 8, forces=True, real=True)
    np.testing.assert_allclose(b.energy, a.energy, atol=1e-5 * float(np.abs(a.energy).max()))
    np.testing.assert_allclose(b.force, a.force, atol=1e-5 * float(np.abs(a.force).max()))


@pytest.mark.parametrize("lattice", [7, 8, 4])
def test_a_lattice_too_coarse_for_the_modes_is_refused(corr, lattice):
    # K = 8 keeps |k| <= 4: at least 10 samples; odd sizes never
    with pytest.raises(LandscapeError, match="even size from 10"):
        compute_landscape(corr.spectra, np.eye(3), 8, forces=False, lattice=lattice)


def test_lowest_minima_are_separate_and_lowest_first():
    energy = np.zeros((8, 8, 8), np.float32)
    energy[2, 2, 2], energy[2, 2, 3], energy[6, 5, 1], energy[4, 4, 4] = -5, -4, -3, 1
    found = lowest_minima(energy, 3, separation=1)
    cells = [tuple(int(v) for v in np.unravel_index(i, energy.shape)) for i in found]
    assert cells == [(2, 2, 2), (6, 5, 1)]  # the neighbour of the best is left out


def test_candidates_best_orders_by_energy_then_rotation():
    c = Candidates(np.array([3, 1, 2]), np.zeros((3, 3)), np.array([-1.0, -2.0, -1.0]))
    best = c.best(2)
    assert list(best.rotation_index) == [1, 2]


def test_a_block_is_the_same_wherever_it_is_split(corr):
    grid = RotationGrid.from_seed(1)
    shared = Shared("spectra", corr.spectra)
    whole = ScanBlock(shared, grid, 0, np.arange(10), 8, 12, 2)()
    parts = [ScanBlock(shared, grid, 0, np.arange(i, i + 5), 8, 12, 2)() for i in (0, 5)]
    joined = Candidates.join([p.candidates for p in parts])
    assert whole.rotations == 10 and len(whole.candidates) > 0
    assert np.array_equal(joined.energy, whole.candidates.energy)
    assert np.array_equal(joined.translation, whole.candidates.translation)
    assert set(whole.candidates.rotation_index) <= set(range(10))


def test_a_block_stops_when_cancelled(corr):
    from engine.errors import Cancelled

    block = ScanBlock(Shared("s", corr.spectra), RotationGrid(), 0, np.arange(5), 8, 12, 1)
    with pytest.raises(Cancelled):
        block(lambda: True)
