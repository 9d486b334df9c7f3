import numpy as np

from engine import cache


def test_key_changes_with_any_input():
    v = np.arange(9, dtype=np.float64).reshape(3, 3)
    k = cache.content_key("descriptor", {"vertices": v, "sigma": 0.5})
    assert k == cache.content_key("descriptor", {"vertices": v.copy(), "sigma": 0.5})
    assert k != cache.content_key("descriptor", {"vertices": v, "sigma": 0.6})
    assert k != cache.content_key("descriptor", {"vertices": v.astype(np.float32), "sigma": 0.5})
    v2 = v.copy()
    v2[1, 1] += 1e-12
    assert k != cache.content_key("descriptor", {"vertices": v2, "sigma": 0.5})
    assert k != cache.content_key("spectrum", {"vertices": v, "sigma": 0.5})


def test_load_or_compute_stores_then_hits(tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return {"rho": np.full((2, 2, 2), 1 + 2j, dtype=np.complex64)}

    a, hit_a = cache.load_or_compute("descriptor", {"n": 1}, compute)
    b, hit_b = cache.load_or_compute("descriptor", {"n": 1}, compute)
    c, hit_c = cache.load_or_compute("descriptor", {"n": 2}, compute)
    assert (hit_a, hit_b, hit_c) == (False, True, False)
    assert len(calls) == 2
    np.testing.assert_array_equal(a["rho"], b["rho"])
    assert b["rho"].dtype == np.complex64


def test_damaged_entry_is_recomputed(tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    key = cache.content_key("descriptor", {"n": 1})
    (tmp_path / "descriptor").mkdir()
    (tmp_path / "descriptor" / f"{key}.npz").write_bytes(b"not a zip file")
    arrays, hit = cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
    assert not hit
    np.testing.assert_array_equal(arrays["x"], np.ones(3))


def test_cache_stays_under_its_cap_dropping_least_recently_used(tmp_path, monkeypatch):
    import os
    import time

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    one = np.zeros(1 << 16, dtype=np.float64)  # 512 KiB per entry
    monkeypatch.setenv("SKELASM_CACHE_MAX_GB", str(3.5 * one.nbytes / 2**30))
    for n in range(3):
        cache.load_or_compute("spectrum", {"n": n}, lambda: {"x": one})
    # entry 0 is used again, so entry 1 is now the least recently used
    old = time.time() - 100
    for n, age in ((0, 0), (1, 10), (2, 50)):
        path = tmp_path / "spectrum" / f"{cache.content_key('spectrum', {'n': n})}.npz"
        os.utime(path, (old + age, old + age))
    assert cache.load("spectrum", cache.content_key("spectrum", {"n": 0})) is not None
    cache.load_or_compute("spectrum", {"n": 3}, lambda: {"x": one})
    left = {n for n in range(4)
            if (tmp_path / "spectrum" / f"{cache.content_key('spectrum', {'n': n})}.npz").exists()}
    assert left == {0, 2, 3}
    total = sum(p.stat().st_size for p in tmp_path.glob("*/*.npz"))
    assert total <= 3.5 * one.nbytes


def test_bad_cap_is_reported(monkeypatch):
    import pytest

    monkeypatch.setenv("SKELASM_CACHE_MAX_GB", "lots")
    with pytest.raises(ValueError, match="SKELASM_CACHE_MAX_GB"):
        cache.max_bytes()
