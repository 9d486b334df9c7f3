"""`skelasm scene new`: a scene for two part files that opens at rest."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine.scene import load_scene

trimesh = pytest.importorskip("trimesh")


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


@pytest.fixture
def parts(tmp_path):
    cup = trimesh.creation.box(extents=(8, 8, 4))
    cup.export(tmp_path / "cup.stl")
    peg = trimesh.creation.box(extents=(3, 3, 6))
    peg.apply_translation((0, 0, 3))
    peg.export(tmp_path / "peg.stl")
    return tmp_path / "cup.stl", tmp_path / "peg.stl"


def test_scene_new_starts_out_of_reach_and_pushes_to_the_seat(parts, tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "fit.toml"
    assert main(["scene", "new", str(parts[0]), str(parts[1]), "-o", str(out), "--grid", "12",
                 "--modes", "6", "--assembled", "0", "0", "-1", "0", "0", "0"]) == 0
    scene = load_scene(out)
    assert scene.descriptor.grid == 12 and scene.modes == 6
    np.testing.assert_allclose(scene.assembled_pose, [0, 0, -1, 0, 0, 0])
    start = np.asarray(scene.parts[1].pose)
    assert start[2] > 2.0 and np.allclose(start[[0, 1, 3, 4, 5]], 0.0)
    capsys.readouterr()
    # at the start the descriptors do not reach each other: no energy, no force
    assert main(["evaluate", str(out), "--pose", *map(str, start), "--about", "origin",
                 "--json", "--repeat", "1", "--backend", "numpy"]) == 0
    at_start = json.loads(capsys.readouterr().out)
    assert at_start["energy"] == 0.0 and not any(at_start["force"])
    # closer, and they do
    closer = start.copy()
    closer[2] -= 2 * load_scene(out).descriptor.padding  # well inside the reach
    assert main(["evaluate", str(out), "--pose", *map(str, closer), "--about", "origin",
                 "--json", "--repeat", "1", "--backend", "numpy"]) == 0
    assert json.loads(capsys.readouterr().out)["energy"] != 0.0
    push = (tmp_path / "fit_push.csv").read_text().splitlines()
    assert push[0] == "t,tx,ty,tz,rx,ry,rz" and len(push) == 3
    np.testing.assert_allclose([float(v) for v in push[1].split(",")[1:]], start)
    np.testing.assert_allclose([float(v) for v in push[2].split(",")[1:]], [0, 0, -1, 0, 0, 0])


def test_scene_new_never_replaces_without_force(parts, tmp_path, capsys):
    from app.cli import main

    out = tmp_path / "fit.toml"
    out.write_text("mine")
    assert main(["scene", "new", str(parts[0]), str(parts[1]), "-o", str(out)]) == 2
    assert out.read_text() == "mine"
    assert "--force" in capsys.readouterr().err
    assert main(["scene", "new", str(parts[0]), str(tmp_path / "nothing.stl"), "-o",
                 str(tmp_path / "b.toml")]) == 2
    assert "no such part file" in capsys.readouterr().err
