"""Poses typed on the command line turn about part 2's centre (issue 11, point 6)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from engine.pose import pose_to_matrix

trimesh = pytest.importorskip("trimesh")

SCENE = """
name = "Offset box"
units = "mm"
assembled_pose = [0, 0, 0, 0, 0, 0]
[descriptor]
grid = 10
padding = 3
[correlation]
modes = 4
[[part]]
file = "cup.stl"
fixed = true
[[part]]
file = "box.stl"
{pivot}
"""


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def scene(folder, pivot=""):
    folder.mkdir()
    trimesh.creation.box(extents=(6, 6, 4)).export(folder / "cup.stl")
    box = trimesh.creation.box(extents=(2, 2, 2))
    box.apply_translation((0, 0, 20))  # drawn 20 mm above its file's origin
    box.export(folder / "box.stl")
    (folder / "scene.toml").write_text(SCENE.format(pivot=pivot))
    return folder / "scene.toml"


def evaluated_pose(capsys, path, *extra):
    from app.cli import main

    assert main(["evaluate", str(path), "--pose", "1", "0", "-18", "0.2", "0", "0", "--json",
                 "--repeat", "1", "--backend", "numpy", *extra]) == 0
    return np.asarray(json.loads(capsys.readouterr().out)["pose"])


def where_centre_goes(pose, centre=(0, 0, 20)):
    return (pose_to_matrix(pose) @ np.r_[centre, 1.0])[:3]


def test_a_typed_tilt_turns_about_the_centre(tmp_path, capsys):
    pose = evaluated_pose(capsys, scene(tmp_path / "a"))
    # the centre only moves by the typed translation; the tilt happens in place
    np.testing.assert_allclose(where_centre_goes(pose), [1, 0, 2], atol=1e-9)
    np.testing.assert_allclose(pose[3:], [0.2, 0, 0])


def test_about_origin_reads_the_numbers_as_the_scene_does(tmp_path, capsys):
    pose = evaluated_pose(capsys, scene(tmp_path / "b"), "--about", "origin")
    np.testing.assert_allclose(pose, [1, 0, -18, 0.2, 0, 0])
    # the 0.2 rad tilt about the file's origin swings the centre 4 mm sideways
    assert abs(where_centre_goes(pose)[1]) > 3.9


def test_the_scene_pivot_wins_over_the_centre_of_mass(tmp_path, capsys):
    pose = evaluated_pose(capsys, scene(tmp_path / "c", pivot="pivot = [0, 0, 21]"))
    np.testing.assert_allclose(where_centre_goes(pose, (0, 0, 21)), [1, 0, 3], atol=1e-9)
