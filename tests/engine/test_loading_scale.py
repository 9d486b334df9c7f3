"""Loading meshes with fans and duplicates: welding in linear memory, counted not timed."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from bench.loading import fan_cylinder, write_stl
from engine import loading
from engine.loading import _weld, load_part


def test_a_fan_of_8000_copies_of_one_vertex_welds_in_bounded_work_and_memory(tmp_path):
    """The issue's cylinder: each cap's centre stored 8,000 times (query_pairs: 32M pairs)."""
    path = tmp_path / "fan.stl"
    write_stl(path, fan_cylinder(32_000))
    tracemalloc.start()
    try:
        part = load_part(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    stats = loading.WELD_STATS
    assert stats["pairs"] <= 13 * stats["cells"]
    assert stats["cells"] == len(part.vertices)
    assert part.volume == pytest.approx(np.pi * 100 * 20, rel=1e-3)
    # the old weld's pair list alone was 8000^2 / 2 pairs x 16 bytes = 512 MB per cap
    assert peak < 150e6, f"peak {peak / 1e6:.0f} MB"


def test_weld_of_10000_copies_examines_one_cell_not_50_million_pairs():
    rng = np.random.default_rng(0)
    v = np.zeros((10_000, 3)) + rng.uniform(-1e-8, 1e-8, (10_000, 3))
    f = np.arange(9_999).reshape(-1, 3)
    v2, f2 = _weld(v, f, 1e-6)
    assert len(v2) == 1 and not f2.any()
    assert loading.WELD_STATS["cells"] <= 8
    assert loading.WELD_STATS["pairs"] <= 13 * loading.WELD_STATS["cells"]


def test_copies_straddling_a_cell_boundary_are_welded():
    tol = 1e-3
    base = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    # copies of vertex 1 a quarter tolerance apart across every cell edge near it
    jitter = np.array([[tol * k / 4, -tol * k / 8, tol * k / 5] for k in range(-3, 4)])
    v = np.concatenate([base, base[1] + jitter])
    f = np.array([[0, 1, 2]] + [[0, 3 + k, 2] for k in range(len(jitter))])
    v2, f2 = _weld(v, f, tol)
    assert len(v2) == 3
    assert (f2 == [0, 1, 2]).all()


def test_distinct_vertices_farther_than_the_tolerance_stay_apart():
    rng = np.random.default_rng(1)
    v = rng.uniform(0, 1, (5000, 3))
    f = np.arange(4998).reshape(-1, 3)
    v2, _ = _weld(v, f, 1e-9)
    assert len(v2) == len(v)


def test_weld_agrees_with_the_pairwise_definition_on_random_clusters():
    """Every pair closer than tol ends in one vertex; none joined beyond (1 + 2 sqrt 3) tol."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(2)
    centres = rng.uniform(0, 1, (300, 3))
    tol = 1e-4
    v = np.repeat(centres, 5, axis=0) + rng.uniform(-tol / 4, tol / 4, (1500, 3))
    f = np.arange(1500).reshape(-1, 3)
    v2, f2 = _weld(v, f, tol)
    assert len(v2) == 300
    merged = v2[f2.ravel()]
    assert np.abs(merged - v[f.ravel()]).max() < (1 + 2 * 3**0.5) * tol
    assert len(cKDTree(v2).query_pairs(tol)) == 0


def test_ten_thousand_copies_of_one_triangle_load_as_one_with_a_word(tmp_path):
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], dtype=np.float32)
    path = tmp_path / "copies.stl"
    write_stl(path, np.repeat(tri, 10_000, axis=0))
    part = load_part(path)
    assert part.triangles == 1
    assert any("9999 duplicate" in w for w in part.warnings)
