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


def _engine_copy(tmp_path):
    """A copy of the engine's sources (only .py files) under tmp_path; returns its root."""
    import shutil

    root = tmp_path / "src"
    shutil.copytree(cache.SOURCE_ROOT / "engine", root / "engine",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))  # fmt: skip
    return root


def test_descriptor_code_files_cover_the_package_and_what_it_imports():
    names = {p.relative_to(cache.SOURCE_ROOT).as_posix()
             for p in cache.code_files("engine.descriptor.compute")}  # fmt: skip
    package = {f"engine/descriptor/{p.name}"
               for p in (cache.SOURCE_ROOT / "engine" / "descriptor").glob("*.py")}  # fmt: skip
    assert package <= names  # every file of the folder, whatever its name
    assert {"engine/grid.py", "engine/params.py"} <= names  # flat modules the kernels read


def test_code_digest_follows_every_kernel_file(tmp_path):
    root = _engine_copy(tmp_path)
    digest = cache.code_digest("engine.descriptor.compute", root=root)
    # A copy elsewhere has the same digest (paths are relative, content decides).
    assert digest == cache.code_digest("engine.descriptor.compute")
    changes = {
        "kernel": root / "engine" / "descriptor" / "numba_kernels.py",
        "opencl": root / "engine" / "descriptor" / "opencl_kernels.py",
        "grid": root / "engine" / "grid.py",
    }
    seen = {digest}
    for path in changes.values():
        original = path.read_bytes()
        path.write_bytes(original + b"\n# changed\n")
        changed = cache.code_digest("engine.descriptor.compute", root=root)
        assert changed not in seen, path
        seen.add(changed)
        path.write_bytes(original)
    assert cache.code_digest("engine.descriptor.compute", root=root) == digest
    # A new file in the package counts too.
    (root / "engine" / "descriptor" / "new_rule.py").write_text("X = 1\n")
    assert cache.code_digest("engine.descriptor.compute", root=root) not in seen


def test_code_digest_never_skips_a_missing_file(tmp_path):
    import pytest

    root = _engine_copy(tmp_path)
    (root / "engine" / "grid.py").unlink()
    with pytest.raises(FileNotFoundError, match="engine.grid"):
        cache.code_digest("engine.descriptor.compute", root=root)
    with pytest.raises(FileNotFoundError, match="engine.nowhere"):
        cache.code_digest("engine.nowhere", root=root)
