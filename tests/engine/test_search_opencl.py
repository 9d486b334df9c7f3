"""The search's scan on OpenCL: the CPU path's landscapes and minima, a block per launch.

Runs on any OpenCL device (PoCL on a machine without a GPU) and skips, saying why, where
there is none.
"""

import numpy as np
import pytest
from gaussian_pair import pair
from search_pairs import through_round

from engine.backend import BackendError, get_backend
from engine.correlation import Correlator, compute_landscape, correlator_for_scene
from engine.errors import Cancelled
from engine.search import SearchSettings, find_fits
from engine.search.driver import scan_backend
from engine.search.rotations import RotationGrid
from engine.search.scan import ScanBlock, lowest_minima
from engine.search.work import Shared


@pytest.fixture(scope="module")
def opencl():
    try:
        return get_backend("opencl")
    except BackendError as exc:
        pytest.skip(f"no OpenCL device here: {exc}")


@pytest.fixture(scope="module")
def spectra():
    fixed, moving = pair()
    return Correlator(fixed, moving, modes=8, backend="numpy", use_cache=False,
                      rotation=False).spectra


def _scan(spectra, modes, lattice, backend):
    from engine.search.opencl_scan import OpenCLScan

    return OpenCLScan(spectra, modes, lattice, backend, batch=5)


@pytest.mark.parametrize(("modes", "lattice"), [(8, 12), (7, 10), (6, 26)])
def test_the_opencl_landscapes_are_the_cpu_ones(opencl, spectra, modes, lattice):
    # even and odd K (an even band's end modes at half weight), lattices coarse and fine;
    # 12 rotations in batches of 5: a batch's last rows and a partial batch
    rotations = RotationGrid.from_seed(3).matrices(0, np.arange(0, 72, 6))
    got = _scan(spectra, modes, lattice, opencl).landscapes(rotations)
    for rot, land in zip(rotations, got, strict=True):
        want = compute_landscape(spectra, rot, modes, forces=False, lattice=lattice,
                                 real=True).energy
        scale = float(np.abs(want).max())
        assert scale > 0
        np.testing.assert_allclose(land, want, atol=2e-5 * scale)
        assert np.array_equal(land == 0, want == 0)  # where the grid boxes cannot meet


def test_the_opencl_minima_are_the_cpu_ones(opencl, spectra):
    # four per rotation: the argmin rounds away from the kept ones are the greedy choice
    rotations = RotationGrid.from_seed(5).matrices(1, np.arange(0, 576, 8))
    scan = _scan(spectra, 8, 12, opencl)
    index, energy = scan.minima(rotations, 4)
    kept = 0
    for r, rot in enumerate(rotations):
        land = compute_landscape(spectra, rot, 8, forces=False, lattice=12, real=True)
        want = lowest_minima(land.energy, 4, separation=1)
        got = index[r][index[r] >= 0]
        assert list(got) == list(want), r
        np.testing.assert_allclose(energy[r][: len(got)], land.energy.ravel()[want],
                                   rtol=1e-4)
        kept += len(got)
    assert kept > 2 * len(rotations)  # the rounds after the first found something


def test_an_opencl_block_gives_the_numpy_blocks_candidates(opencl, spectra):
    grid = RotationGrid.from_seed(1)
    shared = Shared("spectra", spectra)
    cpu = ScanBlock(shared, grid, 1, np.arange(100, 164), 8, 12, 2)()
    gpu = ScanBlock(shared, grid, 1, np.arange(100, 164), 8, 12, 2, backend="opencl")()
    assert gpu.rotations == cpu.rotations == 64 and len(cpu.candidates) > 64
    assert np.array_equal(gpu.candidates.rotation_index, cpu.candidates.rotation_index)
    np.testing.assert_allclose(gpu.candidates.translation, cpu.candidates.translation,
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(gpu.candidates.energy, cpu.candidates.energy, rtol=1e-4)


def test_the_opencl_scan_stops_when_cancelled(opencl, spectra):
    rotations = RotationGrid().matrices(0, np.arange(20))
    with pytest.raises(Cancelled):
        _scan(spectra, 8, 12, opencl).minima(rotations, 2, cancelled=lambda: True)


def test_a_search_on_opencl_finds_the_numpy_searchs_fits(opencl, tmp_path):
    path = through_round(tmp_path)[0]
    corr = correlator_for_scene(path)
    scan = correlator_for_scene(path, rotation=False).spectra
    fits = {}
    for backend in ("numpy", "opencl"):
        result = find_fits(corr, SearchSettings(level=0, scan_modes=12, top=2, clusters=2,
                                                backend=backend), scan=scan)
        assert result.scan_backend == backend
        fits[backend] = result.fits
    assert len(fits["opencl"]) == len(fits["numpy"]) >= 1
    for a, b in zip(fits["opencl"], fits["numpy"], strict=True):
        np.testing.assert_allclose(a.pose, b.pose, atol=1e-3)
        assert a.energy == pytest.approx(b.energy, rel=1e-4)
        assert a.joint.kind == b.joint.kind


def test_a_named_opencl_scan_that_cannot_run_says_why(opencl):
    fixed, moving = pair()
    with_moments = Correlator(fixed, moving, modes=8, backend="numpy", use_cache=False).spectra
    settings = SearchSettings(level=0, scan_modes=8, backend="opencl")
    with pytest.raises(ValueError, match="trilinearly.*rotation=False"):
        scan_backend(with_moments, settings, 12)
    # "auto" passes over it to the CPU's transforms
    assert scan_backend(with_moments, SearchSettings(level=0, scan_modes=8), 12) == "numpy"


def test_auto_takes_the_opencl_scan_only_on_a_gpu(opencl, spectra):
    chosen = scan_backend(spectra, SearchSettings(level=0, scan_modes=8), 12)
    assert chosen == ("opencl" if opencl.is_gpu else "numpy")


def test_an_unknown_scan_backend_is_refused_with_the_choices():
    with pytest.raises(ValueError, match="no backend 'cuda'.*numpy, opencl, auto"):
        SearchSettings(backend="cuda")


def test_the_descent_on_opencl_lands_where_the_cpus_does(opencl, spectra):
    from engine.search.opencl_scan import OpenCLScan
    from engine.search.refine import descend

    grid = RotationGrid.from_seed(2)
    gpu = OpenCLScan(spectra, 8, 18, opencl).landscapes_and_axes
    levels = []
    for index in (3, 17, 40):
        rot = grid.matrix(0, index)
        land = compute_landscape(spectra, rot, 8, forces=False, lattice=18, real=True)
        start = np.array([ax[len(ax) // 2] for ax in land.translations])
        kw = dict(levels=2, lattice=18, reach=2.0)
        cpu_end = descend(spectra, 8, grid, 0, index, start, **kw)
        gpu_end = descend(spectra, 8, grid, 0, index, start, landscapes=gpu, **kw)
        assert cpu_end[:2] == gpu_end[:2]
        levels.append(cpu_end[0])
        np.testing.assert_allclose(gpu_end[2], cpu_end[2], atol=1e-12)
        assert gpu_end[3] == pytest.approx(cpu_end[3], rel=1e-4)
    assert max(levels) == 2  # children were compared and chosen
