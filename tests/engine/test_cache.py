import os

import numpy as np
import pytest

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
    for n in range(3):  # equally cheap, so only their use orders them
        cache.store("spectrum", cache.content_key("spectrum", {"n": n}), {"x": one},
                    seconds=1e-3)
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


def test_eviction_keeps_what_is_costly_to_recompute(tmp_path, monkeypatch):
    # a suite of real pairs filled a 2 GiB cache with spectrum tables (hundreds of MiB,
    # rebuilt in seconds) and evicted the descriptors (a few MiB, 20 to 60 s each): every
    # run recomputed them. Entries now go cheapest per byte first
    import time

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    small = np.zeros(1 << 14, dtype=np.float64)  # 128 KiB: a descriptor
    big = np.zeros(1 << 16, dtype=np.float64)  # 512 KiB: a spectrum table
    monkeypatch.setenv("SKELASM_CACHE_MAX_GB", str(2.5 * big.nbytes / 2**30))
    key = {n: cache.content_key("k", {"n": n}) for n in range(4)}
    path = {n: tmp_path / "k" / f"{key[n]}.npz" for n in range(4)}
    cache.store("k", key[0], {"x": small}, seconds=30.0)  # the oldest, but costly
    old = time.time() - 100
    os.utime(path[0], (old, old))
    for n in (1, 2, 3):
        cache.store("k", key[n], {"x": big}, seconds=0.5)
        os.utime(path[n], (old + 10 * n, old + 10 * n))
        cache.evict(keep=path[n])
    left = {n for n in range(4) if path[n].exists()}
    assert left == {0, 2, 3}  # plain least-recently-used would have dropped 0 first
    total = sum(p.stat().st_size for p in tmp_path.glob("*/*.npz"))
    assert total <= 2.5 * big.nbytes
    assert cache.recompute_seconds(path[0]) == pytest.approx(30.0)
    assert set(cache.load("k", key[0])) == {"x"}  # the record is not handed back


def test_an_entry_records_how_long_it_took_and_unrecorded_ones_rank_as_one_second_a_mib(
        tmp_path, monkeypatch):
    import time
    from types import SimpleNamespace

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    # The cache's clock, faked so that the computation takes 0.75 s exactly: what is
    # recorded is the computation's time, not whatever the machine's load adds to a sleep.
    clock = SimpleNamespace(now=1000.0)
    monkeypatch.setattr(cache, "time", SimpleNamespace(
        perf_counter=lambda: clock.now, time=time.time, sleep=time.sleep))

    def slow():
        clock.now += 0.75
        return {"x": np.ones(4)}

    arrays, hit = cache.load_or_compute("k", {"n": 1}, slow)
    assert not hit and set(arrays) == {"x"}
    written = tmp_path / "k" / f"{cache.content_key('k', {'n': 1})}.npz"
    assert cache.recompute_seconds(written) == pytest.approx(0.75)
    cache.store("k", "0" * 64, {"x": np.ones(4)})  # as older versions wrote
    assert cache.recompute_seconds(tmp_path / "k" / f"{'0' * 64}.npz") is None
    mib = 2**20
    assert cache.cost_class(None, mib) == 0
    assert cache.cost_class(20.0, int(1.4 * mib)) == 1
    assert cache.cost_class(5.0, 400 * mib) == -2
    # the timer's noise on a quick computation does not set entries apart
    assert cache.cost_class(2e-6, mib // 2) == cache.cost_class(3e-2, mib // 2) == -1


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


# --------------------------------------------------------------------------- reliability
def _key(n):
    return cache.content_key("descriptor", {"n": n})


def test_eviction_touches_only_the_cache_s_own_entries(tmp_path, monkeypatch):
    """A cache pointed at a project folder: the user's .npz files survive any cap."""
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    user = [tmp_path / "results" / "a.npz", tmp_path / "descriptor" / "mine.npz",
            tmp_path / "My Results" / f"{'0' * 64}.npz", tmp_path / "top.npz"]
    for path in user:
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"user data" * 1000)
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(10)})
    cache.load_or_compute("descriptor", {"n": 2}, lambda: {"x": np.ones(10)})
    assert len(cache.entries()) == 2
    cache.evict(0)  # a cap of 0 bytes: every entry of the cache's own goes
    assert all(p.read_bytes() == b"user data" * 1000 for p in user)
    assert cache.entries() == []
    assert (tmp_path / "CACHEDIR.TAG").read_text().startswith("Signature: 8a477f597d28d172")


def test_non_finite_results_are_never_cached(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    calls = []

    def compute():
        calls.append(1)
        return {"rho": np.full(4, np.nan + 0j, dtype=np.complex64)}

    for _ in range(2):
        arrays, hit = cache.load_or_compute("descriptor", {"n": 1}, compute)
        assert not hit and np.isnan(arrays["rho"]).all()
    assert len(calls) == 2 and cache.entries() == []
    assert "not storing a descriptor with non-finite values (in rho)" in caplog.text


def test_a_non_finite_entry_on_disk_is_dropped(tmp_path, monkeypatch, caplog):
    """An entry written by an older version with NaN in it is not served."""
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    path = tmp_path / "descriptor" / f"{_key(1)}.npz"
    path.parent.mkdir()
    np.savez(path, x=np.array([1.0, np.inf]))
    arrays, hit = cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(2)})
    assert not hit and np.array_equal(arrays["x"], np.ones(2))
    assert "holds non-finite values (in x); deleted" in caplog.text
    assert np.array_equal(np.load(path)["x"], np.ones(2))


@pytest.mark.parametrize("damage", ["truncate", "flip", "empty"])
def test_unreadable_entries_are_dropped_with_a_warning(tmp_path, monkeypatch, caplog, damage):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    value = np.arange(20000, dtype=np.float64)
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": value})
    path = tmp_path / "descriptor" / f"{_key(1)}.npz"
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "flip":
        data[len(data) // 2] ^= 0x01  # inside the array: the zip CRC catches it
    else:
        data = bytearray()
    path.write_bytes(bytes(data))
    arrays, hit = cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": value + 1})
    assert not hit and np.array_equal(arrays["x"], value + 1)
    assert f"entry {path} cannot be read" in caplog.text and "deleted" in caplog.text
    again, hit = cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": value})
    assert hit and np.array_equal(again["x"], value + 1)  # healed: the recomputed entry


def test_the_cap_holds_for_an_entry_larger_than_the_cap(tmp_path, monkeypatch, caplog):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    monkeypatch.setenv("SKELASM_CACHE_MAX_GB", str(100_000 / 2**30))
    small = np.zeros(1000)
    cache.load_or_compute("spectrum", {"n": 1}, lambda: {"x": small})
    big = np.zeros(50_000)  # 400 KB, four times the cap
    for _ in range(2):
        cache.load_or_compute("spectrum-table", {"n": 2}, lambda: {"x": big})
    sizes = sum(p.stat().st_size for p in cache.entries())
    assert sizes <= cache.max_bytes()
    assert [p.parent.name for p in cache.entries()] == ["spectrum"]
    assert caplog.text.count("larger than the cache's cap") == 1  # said once


def test_concurrent_writers_leave_one_whole_entry(tmp_path, monkeypatch):
    import threading

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    value = np.arange(200_000, dtype=np.float64)
    key = _key(1)
    errors = []

    def writer():
        try:
            for _ in range(5):
                cache.store("descriptor", key, {"x": value})
                got = cache.load("descriptor", key)
                assert got is not None and np.array_equal(got["x"], value)
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [p.name for p in (tmp_path / "descriptor").iterdir()] == [f"{key}.npz"]


def test_read_only_cache_is_read_and_skipped_for_writing(tmp_path, monkeypatch, caplog):
    """Another user's cache: entries load, stores are skipped with one warning."""
    import engine.cache as module

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
    monkeypatch.setattr(module, "_warned", set())

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(module.os, "utime", denied)
    monkeypatch.setattr(module, "atomic_write", denied)
    arrays, hit = cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.zeros(3)})
    assert hit and np.array_equal(arrays["x"], np.ones(3))
    for n in (2, 3):
        arrays, hit = cache.load_or_compute("descriptor", {"n": n}, lambda: {"x": np.zeros(3)})
        assert not hit
    assert caplog.text.count("cannot write to") == 1
    assert "results are not cached" in caplog.text


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions")
def test_read_only_cache_folder_for_real(tmp_path, monkeypatch):  # pragma: no cover - not root
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
    for folder in (tmp_path / "descriptor", tmp_path):
        folder.chmod(0o555)
    try:
        assert cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.zeros(3)})[1]
        assert not cache.load_or_compute("descriptor", {"n": 2}, lambda: {"x": np.zeros(3)})[1]
    finally:
        for folder in (tmp_path, tmp_path / "descriptor"):
            folder.chmod(0o755)


def test_stale_temporaries_of_killed_writes_are_cleaned(tmp_path, monkeypatch):
    import time

    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
    folder = tmp_path / "descriptor"
    old = folder / f".skelasm-{_key(2)}.npz.abc.partial"
    fresh = folder / f".skelasm-{_key(3)}.npz.def.partial"
    user = folder / "notes.partial"
    for path in (old, fresh, user):
        path.write_bytes(b"x")
    past = time.time() - 2 * cache.STALE_SECONDS
    os.utime(old, (past, past))
    os.utime(user, (past, past))
    cache.evict()
    assert not old.exists() and fresh.exists() and user.exists()
