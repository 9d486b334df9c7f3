"""`skelasm warm`: the engine's start path on a coarse grid, leaving no descriptors behind."""

from __future__ import annotations

import os
from pathlib import Path

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_warm_runs_the_start_path_and_keeps_nothing_in_the_users_cache(tmp_path, monkeypatch,
                                                                        capfd):
    # a fresh install compiled the start's kernels during the window's first launch (the
    # part draggable after 44 s instead of 15); `skelasm warm` runs that path once, in a
    # cache of its own
    cache = tmp_path / "cache"
    monkeypatch.setenv("SKELASM_CACHE", str(cache))
    seen = []
    import engine.runtime.warm as warm

    real = warm._warm

    def spy(scene, stages, progress):
        seen.append(os.environ["SKELASM_CACHE"])
        return real(scene, stages, progress)

    monkeypatch.setattr(warm, "_warm", spy)
    assert main(["warm", str(ROOT / "assets" / "peg_in_hole" / "scene.toml")]) == 0
    out, err = capfd.readouterr()
    for stage in ("loading the parts", "descriptors, correlation tables and the per-pose "
                  "evaluator", "the fine level and its walls", "the loop's steps",
                  "the slice preview, beside"):
        assert stage in out, out
    assert "skelasm warm: the fine level and its walls" in err  # each stage as it starts
    assert seen and seen[0] != str(cache) and not Path(seen[0]).exists()  # removed after
    assert os.environ["SKELASM_CACHE"] == str(cache)
    assert not cache.exists() or not any(cache.rglob("*.npz"))


def test_warm_names_a_missing_scene(tmp_path, capfd):
    assert main(["warm", str(tmp_path / "none.toml")]) == 2
    _, err = capfd.readouterr()
    assert "none.toml" in err
