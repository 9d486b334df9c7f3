"""`skelasm precompute` end to end: JSON output, the .npz it writes, the cache, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]
SLIDE = ROOT / "assets" / "dovetail" / "slide.step"  # 28 triangles: fast
SMALL = ["--grid", "8", "--padding", "1", "--backend", "numba"]


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)


def run_json(capfd, *argv):
    code = main(["precompute", *map(str, argv), "--json"])
    out, err = capfd.readouterr()
    assert code == 0, err
    return json.loads(out)  # stdout is exactly one JSON object


def test_json_and_output_file(tmp_path, capfd):
    out = tmp_path / "slide.npz"
    rec = run_json(capfd, SLIDE, *SMALL, "-o", out)
    for key in ("grid", "spacing", "triangles", "seconds", "backend", "output"):
        assert key in rec
    assert rec["output"] == str(out) and out.is_file()
    assert rec["triangles"] == 28 and rec["backend"] == "numba" and rec["unit"] == "mm"
    assert rec["from_cache"] is False
    # --grid 8: 8 samples along the longest side (30 mm), one cell of padding each side
    assert rec["spacing"] == pytest.approx(30 / 8)
    with np.load(out) as data:
        rho = data["rho"]
        assert rho.dtype == np.complex64 and list(rho.shape) == rec["grid"]
        origin, h = data["origin"], float(data["spacing"])
        assert h == pytest.approx(rec["spacing"])
        np.testing.assert_allclose(origin, rec["origin"])
        assert (float(data["sigma"]), float(data["penalty"]), float(data["lambda_out"])) == (
            0.5, 3.0, 1.0)
    # origin is where index (0, 0, 0) lies in the part's frame: the grid covers the part
    upper = origin + h * (np.array(rho.shape) - 1)
    assert np.all(origin < [-10, -30, -8]) and np.all(upper > [10, 0, 5])
    centre = np.round((np.array([0.0, -15.0, 2.5]) - origin) / h).astype(int)
    assert rho[tuple(centre)].imag > 0 > rho[0, 0, 0].imag  # inside ~ +i, outside ~ -i


def test_second_run_hits_the_cache_and_parameters_recompute(capfd):
    first = run_json(capfd, SLIDE, *SMALL)
    assert first["output"] == str(Path.cwd() / "slide.npz")  # default: current directory
    second = run_json(capfd, SLIDE, *SMALL, "--force")  # replaces the first run's file
    assert second["from_cache"] is True
    assert second["compute_seconds"] == first["compute_seconds"]  # the stored computation's
    third = run_json(capfd, SLIDE, *SMALL, "--sigma", "0.7", "--force")
    assert third["from_cache"] is False and third["sigma"] == 0.7
    fourth = run_json(capfd, SLIDE, *SMALL, "--no-cache", "--force")
    assert fourth["from_cache"] is False


def test_text_output(capfd):
    assert main(["precompute", str(SLIDE), *SMALL]) == 0
    out, _ = capfd.readouterr()
    assert "slide: 28 triangles, grid" in out and "slide.npz" in out


def test_multibody_needs_body(capfd, tmp_path):
    data = ROOT / "tests" / "data" / "two_bodies.step"
    assert main(["precompute", str(data), *SMALL]) == 2
    out, err = capfd.readouterr()
    assert out == ""
    assert "skelasm precompute: error:" in err and "'block', 'peg'" in err and "--body" in err
    rec = run_json(capfd, data, "--body", "peg", *SMALL)
    assert rec["name"] == "peg" and rec["output"] == str(tmp_path / "two_bodies-peg.npz")


def test_corrupt_step_is_a_clean_error(capfd):
    assert main(["precompute", str(ROOT / "tests" / "data" / "corrupt.step"), "--json"]) == 2
    out, err = capfd.readouterr()
    record = json.loads(out)  # --json: a script reads the error as an object too
    assert set(record) == {"error", "file", "line"} and record["file"].endswith("corrupt.step")
    assert record["error"] in err
    assert err.startswith("skelasm precompute: error: ") and "corrupt.step" in err
    assert "Traceback" not in err


def test_missing_file_and_bad_output_folder(capfd, tmp_path):
    assert main(["precompute", str(tmp_path / "none.step")]) == 2
    assert "no such file" in capfd.readouterr().err
    assert main(["precompute", str(SLIDE), *SMALL, "-o", str(tmp_path / "no" / "x.npz")]) == 2
    assert "no such folder" in capfd.readouterr().err


@pytest.mark.parametrize(
    "argv",
    [["--grid", "1"], ["--grid", "8", "--spacing", "1"], ["--sigma", "-1"], ["--padding", "x"],
     ["--backend", "cuda"]],
)
def test_bad_options_exit_2(argv, capfd):
    with pytest.raises(SystemExit) as info:
        main(["precompute", str(SLIDE), *argv])
    assert info.value.code == 2
    assert "precompute" in capfd.readouterr().err


def test_scene_computes_both_parts_with_one_spacing(capfd, tmp_path):
    scene = ROOT / "assets" / "dovetail" / "scene.toml"
    out = tmp_path / "descriptors"
    out.mkdir()
    rec = run_json(capfd, scene, *SMALL, "-o", out)
    assert [p["name"] for p in rec["parts"]] == ["block", "slide"]
    # the block's 40 mm side sets the spacing for both
    assert rec["spacing"] == pytest.approx(40 / 8)
    for part in rec["parts"]:
        assert part["spacing"] == pytest.approx(rec["spacing"])
        assert Path(part["output"]) == out / f"dovetail-{part['name']}.npz"
        assert Path(part["output"]).is_file()


def test_a_scene_without_o_only_fills_the_cache(capfd, tmp_path):
    scene = ROOT / "assets" / "dovetail" / "scene.toml"
    rec = run_json(capfd, scene, *SMALL)  # the current folder is tmp_path
    assert [p["output"] for p in rec["parts"]] == [None, None]
    assert not list(tmp_path.glob("*.npz"))  # nothing written beside the user's files
    assert all(not p["from_cache"] for p in rec["parts"])
    again = run_json(capfd, scene, *SMALL)  # the cache it filled
    assert all(p["from_cache"] for p in again["parts"])
    assert main(["precompute", str(scene), *SMALL]) == 0
    assert capfd.readouterr().out.count("-> the cache") == 2
    # computing into nothing is refused with the fix
    assert main(["precompute", str(scene), *SMALL, "--no-cache"]) == 2
    assert "add -o FOLDER" in capfd.readouterr().err
    assert not list(tmp_path.glob("*.npz"))


def test_progress_bar_on_a_terminal(capfd, monkeypatch):
    import sys

    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert main(["precompute", str(SLIDE), *SMALL, "--no-cache"]) == 0
    out, err = capfd.readouterr()
    assert "100%|" in err  # tqdm's bar, on stderr
    assert "%|" not in out


# ------------------------------------------------------------------------ a parts library
def _library(tmp_path):
    """Three small part files (a copy of the slide under another name among them)."""
    import shutil

    folder = tmp_path / "library"
    folder.mkdir()
    for name in ("slide", "block"):
        shutil.copy(ROOT / "assets" / "dovetail" / f"{name}.step", folder / f"{name}.step")
    shutil.copy(SLIDE, folder / "copy.step")
    return sorted(folder.glob("*.step"))


def test_a_library_runs_a_task_per_part_resumably_into_a_folder(capfd, tmp_path):
    parts = _library(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    first = run_json(capfd, *parts, *SMALL, "-o", out)
    assert first["failed"] == 0 and len(first["parts"]) == 3
    assert sorted(Path(r["output"]).name for r in first["parts"]) == [
        "block.npz", "copy.npz", "slide.npz"]
    # the copy is the same bytes: the cache serves it
    by_name = {Path(r["part"]).stem: r for r in first["parts"]}
    assert by_name["copy"]["from_cache"] != by_name["slide"]["from_cache"]
    # a second run keeps what is there; --force computes again (from the cache)
    again = run_json(capfd, *parts, *SMALL, "-o", out)
    assert all(r.get("kept") for r in again["parts"])
    forced = run_json(capfd, *parts, *SMALL, "-o", out, "--force")
    assert all(r["from_cache"] for r in forced["parts"])


def test_a_bad_part_in_a_library_fails_alone(capfd, tmp_path):
    parts = _library(tmp_path)
    bad = tmp_path / "library" / "bad.step"
    bad.write_text("ISO-10303-21;\nnot a step file\n")
    code = main(["precompute", *map(str, [*parts, bad]), *SMALL, "--json"])
    out, err = capfd.readouterr()
    assert code == 2
    rec = json.loads(out)
    assert rec["failed"] == 1 and len(rec["parts"]) == 4
    (failed,) = [r for r in rec["parts"] if "error" in r]
    assert "bad.step" in failed["error"] and "Traceback" not in err


def test_a_library_on_dask_gives_the_same_descriptors(capfd, tmp_path):
    pytest.importorskip("distributed")
    parts = _library(tmp_path)[:2]
    serial, dask = tmp_path / "serial", tmp_path / "dask"
    serial.mkdir()
    dask.mkdir()
    run_json(capfd, *parts, *SMALL, "--no-cache", "-o", serial)
    rec = run_json(capfd, *parts, *SMALL, "--no-cache", "-o", dask, "--workers", "2")
    assert rec["failed"] == 0
    for name in ("block.npz", "copy.npz"):
        with np.load(serial / name) as a, np.load(dask / name) as b:
            assert np.array_equal(a["rho"], b["rho"])  # bit for bit
            np.testing.assert_array_equal(a["origin"], b["origin"])


def test_library_options_that_do_not_fit_say_so(capfd, tmp_path):
    parts = _library(tmp_path)
    for argv, words in (
        ([parts[0], "--workers", "2"], "several parts"),
        ([*parts, "--workers", "2", "--scheduler", "tcp://x:1"], "give one"),
        ([*parts, "-o", tmp_path / "nowhere"], "no such folder"),
        ([*parts, "--body", "x"], "one by one"),
    ):
        code = main(["precompute", *map(str, argv), *SMALL])
        _, err = capfd.readouterr()
        assert code == 2 and words in err and "Traceback" not in err, err
