"""`skelasm evaluate` and `skelasm landscape` on a small generated scene (a box in a slot)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

SCENE = """
name = "Box in a cup"
units = "mm"
assembled_pose = [0, 0, 1, 0, 0, 0]

[descriptor]
grid = 10
padding = 3

[correlation]
modes = 8

[[part]]
name = "cup"
file = "cup.stl"
pose = [0, 0, 0, 0, 0, 0]

[[part]]
name = "box"
file = "box.stl"
pose = [0, 0, 6, 0, 0, 0]
"""


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("scene")
    outer = trimesh.creation.box(extents=(6, 6, 4))
    hole = trimesh.creation.box(extents=(3, 3, 4))
    hole.apply_translation((0, 0, 1.01))
    try:
        cup = outer.difference(hole)
    except BaseException:  # no boolean engine: a plain block still exercises the command
        cup = outer
    cup.export(folder / "cup.stl")
    trimesh.creation.box(extents=(3, 3, 2)).export(folder / "box.stl")
    path = folder / "scene.toml"
    path.write_text(SCENE)
    return path


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def test_evaluate_json(scene_file, capsys):
    from app.cli import main

    code = main(["evaluate", str(scene_file), "--pose", "0.2", "0", "1.5", "0.1", "0", "0",
                 "--modes", "6", "--json", "--repeat", "3", "--backend", "numba"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    for key in ("energy", "force", "torque", "modes", "microseconds", "backend"):
        assert key in out
    assert out["modes"] == 6 and out["backend"] == "numba"
    assert len(out["force"]) == 3 and len(out["torque"]) == 3
    assert np.isfinite(out["energy"]) and out["microseconds"] > 0

    # the numpy reference gives the same numbers
    main(["evaluate", str(scene_file), "--pose", "0.2", "0", "1.5", "0.1", "0", "0",
          "--modes", "6", "--json", "--repeat", "1", "--backend", "numpy"])
    ref = json.loads(capsys.readouterr().out)
    assert out["energy"] == pytest.approx(ref["energy"], rel=1e-5, abs=1e-9)
    np.testing.assert_allclose(out["force"], ref["force"], rtol=1e-4,
                               atol=1e-5 * np.linalg.norm(ref["force"]) + 1e-12)


def test_evaluate_adds_the_fine_level_where_the_parts_meet(scene_file, capsys):
    from app.cli import main
    from engine.correlation import correlator_for_scene
    from engine.params import GUIDANCE_BAND
    from engine.pose import rotation_matrix
    from engine.scene import load_scene

    pose = ["0.2", "0", "1.5", "0.1", "0", "0"]
    args = ["evaluate", str(scene_file), "--pose", *pose, "--modes", "6", "--json",
            "--repeat", "1", "--backend", "numpy"]
    assert main(args) == 0
    fine = json.loads(capsys.readouterr().out)
    assert main([*args, "--no-fine"]) == 0
    alone = json.loads(capsys.readouterr().out)
    assert alone["fine_level"] is None
    level = fine["fine_level"]
    assert level["terms"] > 0 and level["ratio"] >= 1
    # without the level: the modal sum itself, as the correlator gives it, in the band
    # that guides a part (the one evaluate reports)
    assert fine["band"] == alone["band"] == GUIDANCE_BAND
    corr = correlator_for_scene(load_scene(scene_file), modes=6, backend="numpy",
                                kappa=alone["kappa"], band=alone["band"])
    p = np.array([float(v) for v in pose])
    ev = corr.evaluate(rotation_matrix(p[3:]), p[:3])
    assert alone["energy"] == pytest.approx(ev.energy, rel=1e-6)
    # with it: something added, in energy and force
    assert fine["energy"] != pytest.approx(alone["energy"], rel=1e-3)
    assert not np.allclose(fine["force"], alone["force"], rtol=1e-3)


def test_evaluate_reads_each_part_file_once(scene_file, capsys, monkeypatch):
    import engine.scene.parts as scene_parts
    from app.cli import main

    read = []
    real = scene_parts.load_part

    def counting(path, *args, **kwargs):
        read.append(str(path))
        return real(path, *args, **kwargs)

    monkeypatch.setattr(scene_parts, "load_part", counting)
    assert main(["evaluate", str(scene_file), "--modes", "6", "--json"]) == 0
    json.loads(capsys.readouterr().out)
    assert sorted(read) == sorted({str(scene_file.parent / n) for n in ("cup.stl", "box.stl")})


def test_evaluate_text_defaults_to_scene(scene_file, capsys):
    from app.cli import main

    assert main(["evaluate", str(scene_file), "--repeat", "2"]) == 0
    text = capsys.readouterr().out
    assert "energy" in text and "K = 8" in text and "backend" in text


def test_landscape_writes_png(scene_file, tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "land.png"
    assert main(["landscape", str(scene_file), "--plane", "xz", "--offset", "0",
                 "--rotation", "0", "0", "0", "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "fitted" in capsys.readouterr().out


def test_bad_modes_is_a_user_error(scene_file, capsys):
    from app.cli import main

    assert main(["evaluate", str(scene_file), "--modes", "0"]) == 2
    assert "modes" in capsys.readouterr().err


def test_report_writes_markdown_with_its_images(scene_file, tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "report"
    assert main(["report", str(scene_file), "-o", str(out), "--backend", "numba"]) == 0
    text = (out / "report.md").read_text()
    for heading in ("## Parts", "## Descriptors", "## Energy, force and torque",
                    "## What the mode count costs", "## Energy landscape"):
        assert heading in text
    # every image the report links to was written and is a PNG
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert {"slice_cup.png", "slice_box.png", "landscape_xy.png", "landscape_xz.png"} <= set(images)
    for name in images:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the separated pose is far out of reach: exactly zero energy, as the correlation promises
    row = next(line for line in text.splitlines() if line.startswith("| separated"))
    assert row.split("|")[4].strip() == "0"


def test_evaluate_shows_progress_on_a_terminal(scene_file, monkeypatch, capsys):
    """On a terminal the preparation (descriptors, spectra, tables, kernels) shows a bar
    that reaches 100 %; without one (a pipe, --json) nothing is drawn.
    """
    import io
    import sys

    from app.cli import main

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    assert main(["evaluate", str(scene_file), "--repeat", "1", "--modes", "6"]) == 0
    drawn = terminal.getvalue()
    assert "preparing" in drawn and "100%" in drawn
    quiet = Terminal()
    monkeypatch.setattr(sys, "stderr", quiet)
    assert main(["evaluate", str(scene_file), "--repeat", "1", "--json"]) == 0
    assert "preparing" not in quiet.getvalue()
