"""Descriptor store: npz round trip, cache hits and misses, one spacing per scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import engine.descriptor.store as store_module
from engine.descriptor import (
    Descriptor,
    descriptor_for_part,
    descriptors_for_scene,
    grid_for_part,
    scene_spacing,
)
from engine.errors import InputError
from engine.grid import Grid
from engine.loading import load_part, part_from_mesh
from engine.params import DescriptorParams
from engine.scene import load_scene, load_scene_parts

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("SKELASM_CACHE", str(folder))
    return folder


@pytest.fixture
def fake_compute(monkeypatch):
    """Replace the descriptor kernel by a cheap function of its inputs, counting calls."""
    calls = []

    def compute(vertices, faces, grid, params, *, backend=None, method="tree", progress=None,
                cancel=None):
        calls.append((grid, params, method))
        pts = grid.points()
        value = params.sigma * pts[..., 0] + 1j * (params.penalty + vertices[0, 0] + pts[..., 2])
        if progress is not None:
            progress(0.5)
            progress(1.0)
        return value.astype(np.complex64), pts[..., 2] < 0

    monkeypatch.setattr(store_module, "descriptor_and_side", compute)
    return calls


def box_part(size=2.0, shift=0.0):
    h = size / 2
    v = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)]) + shift
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return part_from_mesh(v, f, name="box")


def test_cache_hit_and_miss(fake_compute, private_cache):
    part = box_part()
    grid = grid_for_part(part, samples=8, padding=2)
    first = descriptor_for_part(part, grid, DescriptorParams(), backend="numba")
    assert not first.from_cache and len(fake_compute) == 1
    assert first.backend == "numba" and first.triangles == 12 and first.name == "box"
    assert list(private_cache.rglob("*.npz"))
    second = descriptor_for_part(part, grid, DescriptorParams(), backend="numba")
    assert second.from_cache and len(fake_compute) == 1
    np.testing.assert_array_equal(second.rho, first.rho)
    assert second.rho.dtype == np.complex64 and second.grid == grid
    # the hit carries the first computation's time, not a new one
    assert second.compute_seconds == first.compute_seconds
    # any changed input recomputes
    descriptor_for_part(part, grid, DescriptorParams(sigma=0.6), backend="numba")
    descriptor_for_part(part, grid_for_part(part, samples=9, padding=2), backend="numba")
    descriptor_for_part(box_part(shift=1e-9), grid, backend="numba")
    descriptor_for_part(part, grid, method="brute", backend="numba")
    assert len(fake_compute) == 5
    # but not the weights: a new penalty or lambda_out rescales the entry on each side
    other = descriptor_for_part(part, grid, DescriptorParams(penalty=2.0, lambda_out=0.5),
                                backend="numba")
    assert other.from_cache and len(fake_compute) == 5
    assert other.params == DescriptorParams(penalty=2.0, lambda_out=0.5)
    inside = grid.points()[..., 2] < 0
    np.testing.assert_allclose(other.rho[inside], first.rho[inside] * (1.0 / 3.0), rtol=1e-6)
    np.testing.assert_allclose(other.rho[~inside], first.rho[~inside] * 0.5, rtol=1e-6)
    # and the originals still hit
    assert descriptor_for_part(part, grid, DescriptorParams(), backend="numba").from_cache


def test_no_cache(fake_compute, private_cache):
    part = box_part()
    grid = grid_for_part(part, samples=6, padding=1)
    a = descriptor_for_part(part, grid, use_cache=False, backend="numba")
    b = descriptor_for_part(part, grid, use_cache=False, backend="numba")
    assert not a.from_cache and not b.from_cache and len(fake_compute) == 2
    assert not private_cache.exists() or not list(private_cache.rglob("*.npz"))


def test_bad_method(fake_compute):
    part = box_part()
    with pytest.raises(ValueError, match="unknown method 'fast'; valid: adaptive, tree, brute"):
        descriptor_for_part(part, grid_for_part(part, samples=6, padding=1), method="fast")


def test_save_and_load_round_trip(tmp_path):
    grid = Grid((1.0, -2.0, 0.5), 0.25, (3, 4, 5))
    rho = (np.arange(60).reshape(3, 4, 5) * (1 - 2j)).astype(np.complex64)
    params = DescriptorParams(sigma=0.7, penalty=2.5, lambda_out=1.5)
    d = Descriptor(rho=rho, grid=grid, params=params, triangles=12, backend="numba",
                   seconds=1.0, name="peg", compute_seconds=1.0)
    path = d.save(tmp_path / "peg")
    assert path.name == "peg.npz"
    with np.load(path) as raw:
        np.testing.assert_array_equal(raw["rho"], rho)
        np.testing.assert_array_equal(raw["origin"], [1.0, -2.0, 0.5])
        assert float(raw["spacing"]) == 0.25
        assert raw["shape"].tolist() == [3, 4, 5]
        assert (float(raw["sigma"]), float(raw["penalty"]), float(raw["lambda_out"])) == (
            0.7, 2.5, 1.5)
    back = Descriptor.load(path)
    np.testing.assert_array_equal(back.rho, rho)
    assert back.grid == grid and back.params == d.params
    assert back.triangles == 12 and back.backend == "numba" and back.name == "peg"


def test_load_errors(tmp_path):
    with pytest.raises(InputError, match="no such descriptor file"):
        Descriptor.load(tmp_path / "absent.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(InputError, match="junk.npz: not a readable descriptor file"):
        Descriptor.load(junk)
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    with pytest.raises(InputError, match="missing rho"):
        Descriptor.load(other)


def test_rho_shape_must_match_grid():
    with pytest.raises(ValueError, match="shape"):
        Descriptor(rho=np.zeros((2, 2, 2), np.complex64), grid=Grid((0, 0, 0), 1.0, (2, 2, 3)),
                   params=DescriptorParams(), triangles=0, backend="numba", seconds=0.0)


def test_scene_spacing_and_grids(fake_compute):
    scene = load_scene(ROOT / "assets" / "peg_in_hole" / "scene.toml")
    parts = load_scene_parts(scene)
    # the block is 40 mm wide, the peg 30 mm long: h = 40 / grid
    assert scene_spacing(scene, parts) == pytest.approx(40.0 / scene.descriptor.grid)
    seen = []
    out = descriptors_for_scene(scene, parts=parts, backend="numba", progress=seen.append)
    assert [d.name for d in out] == ["block", "peg"]
    h = 40.0 / scene.descriptor.grid
    for d, part in zip(out, parts, strict=True):
        assert d.grid.spacing == pytest.approx(h)
        pad = scene.descriptor.padding * h
        assert np.all(np.asarray(d.grid.origin) <= part.bounds[0] - pad + 1e-5)
        assert np.all(d.grid.upper >= part.bounds[1] + pad - 1e-5)
        assert np.all(d.grid.upper - d.grid.origin <= part.extent + 2 * pad + 2 * h)
    assert seen == sorted(seen) and seen[-1] == pytest.approx(1.0)


def test_scene_spacing_from_the_scene(tmp_path):
    text = (ROOT / "assets" / "peg_in_hole" / "scene.toml").read_text()
    text = text.replace("grid = 56", "spacing = 0.8")
    for name in ("block.step", "peg.step"):
        (tmp_path / name).write_bytes((ROOT / "assets" / "peg_in_hole" / name).read_bytes())
    (tmp_path / "scene.toml").write_text(text.replace("grid = 56 ", "spacing = 0.8 "))
    scene = load_scene(tmp_path / "scene.toml")
    assert scene.descriptor.spacing == 0.8
    assert scene_spacing(scene, load_scene_parts(scene)) == 0.8


def test_real_descriptor_is_cached_and_loads_fast(private_cache, monkeypatch):
    """The real kernel on a coarse grid: +i inside, -i outside, and a second load from disk."""
    part = load_part(ROOT / "assets" / "dovetail" / "slide.step")
    grid = grid_for_part(part, samples=8, padding=1)
    first = descriptor_for_part(part, grid, backend="numba")
    assert not first.from_cache and first.rho.shape == grid.shape
    assert np.all(np.isfinite(first.rho))
    # the slide's cap, a 20 x 30 x 5 slab, holds the point (0, -15, 2.5)
    index = tuple(np.round((np.array([0.0, -15.0, 2.5]) - grid.origin) / grid.spacing).astype(int))
    assert first.rho[index].imag > 0
    assert first.rho[0, 0, 0].imag < 0  # a corner of the padded box is outside
    # the second load runs no kernel (no wall-clock bound: the machine may be busy)
    def no_kernel(*args, **kwargs):
        raise AssertionError("the descriptor was computed again")

    monkeypatch.setattr(store_module, "descriptor_and_side", no_kernel)
    second = descriptor_for_part(part, grid, backend="numba")
    assert second.from_cache
    np.testing.assert_array_equal(second.rho, first.rho)


@pytest.mark.parametrize("method", ["tree", "adaptive"])
def test_a_new_penalty_rescales_the_cached_descriptor_as_the_kernel_computes_it(
        private_cache, monkeypatch, method):
    # rho is c(p) times a sum that neither weight touches: the cache keeps the sum and each
    # sample's side, so the window's penalty slider costs no kernel run. Against the
    # kernel run afresh at the new weights: every sample where each is evaluated (tree);
    # within the sampler's interpolation where it decides again which samples it
    # interpolates (adaptive)
    part = load_part(ROOT / "assets" / "dovetail" / "slide.step")
    grid = grid_for_part(part, samples=10, padding=2)
    descriptor_for_part(part, grid, DescriptorParams(penalty=3.0), backend="numba",
                        method=method)
    new = DescriptorParams(penalty=7.5, lambda_out=0.8)
    fresh = descriptor_for_part(part, grid, new, backend="numba", method=method,
                                use_cache=False)

    def no_kernel(*args, **kwargs):
        raise AssertionError("the descriptor was computed again for a new penalty")

    monkeypatch.setattr(store_module, "descriptor_and_side", no_kernel)
    rescaled = descriptor_for_part(part, grid, new, backend="numba", method=method)
    assert rescaled.from_cache and rescaled.params == new
    both = (fresh.rho.imag > 0) == (rescaled.rho.imag > 0)
    assert both.mean() > 0.999  # the same side, so c(p) picked the same weight
    err = np.linalg.norm(rescaled.rho - fresh.rho) / np.linalg.norm(fresh.rho)
    assert err < (1e-6 if method == "tree" else 2e-3), err


def test_changed_descriptor_code_recomputes(fake_compute, monkeypatch):
    store = store_module
    part = box_part()
    grid = grid_for_part(part, samples=6, padding=1)
    descriptor_for_part(part, grid, backend="numba")
    assert descriptor_for_part(part, grid, backend="numba").from_cache
    monkeypatch.setattr(store, "_CODE_DIGEST", "a different kernel")
    assert not descriptor_for_part(part, grid, backend="numba").from_cache
    assert len(fake_compute) == 2


def test_edited_kernel_file_recomputes(fake_compute, monkeypatch, tmp_path):
    """The cache key follows the files themselves: an edited kernel misses the cache."""
    import shutil

    import engine.cache as cache

    root = tmp_path / "src"
    shutil.copytree(cache.SOURCE_ROOT / "engine", root / "engine",
                    ignore=shutil.ignore_patterns("__pycache__"))  # fmt: skip
    monkeypatch.setattr(cache, "SOURCE_ROOT", root)
    monkeypatch.setattr(store_module, "_CODE_DIGEST", None)
    part = box_part()
    grid = grid_for_part(part, samples=6, padding=1)
    descriptor_for_part(part, grid, backend="numba")
    assert descriptor_for_part(part, grid, backend="numba").from_cache
    kernel = root / "engine" / "descriptor" / "numba_kernels.py"
    kernel.write_text(kernel.read_text() + "\n# a changed quadrature rule\n")
    monkeypatch.setattr(store_module, "_CODE_DIGEST", None)  # a new process
    assert not descriptor_for_part(part, grid, backend="numba").from_cache
    assert len(fake_compute) == 2


# --------------------------------------------------------------------------- reliability
def _saved(tmp_path):
    grid = Grid((0.0, 0.0, 0.0), 0.5, (20, 20, 20))
    rho = (np.arange(8000).reshape(20, 20, 20) * (1 + 1j)).astype(np.complex64)
    d = Descriptor(rho=rho, grid=grid, params=DescriptorParams(), triangles=12,
                   backend="numba", seconds=1.0, name="peg")
    return d, d.save(tmp_path / "peg.npz")


@pytest.mark.parametrize("damage", ["half", "flip"])
def test_load_of_a_damaged_file_names_it(tmp_path, damage):
    """A half-written or bit-flipped file: the project's error with the file and the fix."""
    _, path = _saved(tmp_path)
    data = bytearray(path.read_bytes())
    if damage == "half":
        data = data[: len(data) // 2]
    else:
        data[len(data) // 3] ^= 0x10
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"peg.npz: not a readable descriptor file \(BadZip"
                                         r"File: .*compute it again with `skelasm precompute`"):
        Descriptor.load(path)


def test_load_refuses_non_finite_rho(tmp_path):
    d, path = _saved(tmp_path)
    arrays = d.arrays()
    arrays["rho"] = np.full_like(arrays["rho"], np.nan)
    np.savez(path, **arrays)
    with pytest.raises(InputError, match="peg.npz: rho holds non-finite values"):
        Descriptor.load(path)


def test_save_is_atomic_and_keeps_the_old_file_on_failure(tmp_path, monkeypatch):
    d, path = _saved(tmp_path)
    before = path.read_bytes()

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", full)
    with pytest.raises(OSError, match=r"peg.npz: cannot write the descriptor \(No space left"):
        d.save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["peg.npz"]
    with pytest.raises(InputError, match="no such folder for the descriptor"):
        d.save(tmp_path / "absent" / "x.npz")


def test_a_non_finite_descriptor_is_refused_and_not_cached(monkeypatch, private_cache):
    def nan_compute(vertices, faces, grid, params, **kwargs):
        return np.full(grid.shape, np.nan, dtype=np.complex64), np.zeros(grid.shape, bool)

    monkeypatch.setattr(store_module, "descriptor_and_side", nan_compute)
    part = box_part()
    grid = grid_for_part(part, samples=8, padding=1)
    with pytest.raises(InputError, match=r"box: the descriptor has 1331 of 1331 non-finite "
                                         r"samples .* sigma = 0.5"):
        descriptor_for_part(part, grid)
    assert list(private_cache.glob("*/*.npz")) == []
