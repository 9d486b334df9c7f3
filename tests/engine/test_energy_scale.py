"""One energy scale: evaluate, simulate and the simulation's own field report the same E."""

from __future__ import annotations

import json

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

SCENE = """
name = "Box in a cup"
units = "{units}"
assembled_pose = [0, 0, 1, 0, 0, 0]
{kappa}
[descriptor]
grid = 10
padding = 3

[correlation]
modes = 6

[[part]]
name = "cup"
file = "cup.stl"
pose = [0, 0, 0, 0, 0, 0]

[[part]]
name = "box"
file = "box.stl"
pose = [0, 0, 6, 0, 0, 0]
"""
POSE = ["0.2", "0", "1.5", "0.1", "0", "0"]


@pytest.fixture(autouse=True)
def private_cache(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path_factory.getbasetemp() / "cache"))


def scene(folder, *, units="mm", kappa=""):
    folder.mkdir(parents=True, exist_ok=True)
    trimesh.creation.box(extents=(6, 6, 4)).export(folder / "cup.stl")
    trimesh.creation.box(extents=(3, 3, 2)).export(folder / "box.stl")
    path = folder / "scene.toml"
    path.write_text(SCENE.format(units=units, kappa=kappa))
    return path


def evaluate(capsys, path):
    from app.cli import main

    assert main(["evaluate", str(path), "--pose", *POSE, "--about", "origin", "--json",
                 "--repeat", "1", "--backend", "numpy"]) == 0
    return json.loads(capsys.readouterr().out)


def test_evaluate_reports_the_simulations_energy(tmp_path, capsys):
    import engine.runtime as rt
    from engine.pose import rotation_matrix
    from engine.sim import build_simulation

    path = scene(tmp_path / "a")
    out = evaluate(capsys, path)
    assert out["units"] == {"length": "mm", "energy": "µJ", "force": "mN", "torque": "mN·mm",
                            "kappa": "kg/(mm·s²)"}
    assert out["kappa_source"] == "default"
    sim, _ = build_simulation(rt.open_scene(path), prepare=True, backend="numpy")
    assert out["kappa"] == pytest.approx(sim.physics.kappa, rel=1e-12)
    pose = np.array([float(v) for v in POSE])
    sim.reset(pose)  # the part's origin at the pose: the field and the fine level there
    ev = sim.evaluate_field()
    assert sim.near is not None and out["fine_level"]["terms"] == sim.near.terms
    alone = sim.field.evaluate(rotation_matrix(pose[3:]), pose[:3])
    assert ev.energy != 0.0 and ev.energy != pytest.approx(alone.energy, rel=1e-6)
    assert out["energy"] == pytest.approx(ev.energy, rel=1e-9)
    np.testing.assert_allclose(out["force"], ev.force, rtol=1e-9, atol=1e-12)
    # where the simulation's coupling holds the part, and why
    assert out["hold"]["source"] == "fit"
    np.testing.assert_allclose(out["hold"]["point"], sim.hold, atol=1e-12)


def test_evaluate_reports_a_hold_point_the_scene_names(tmp_path, capsys):
    path = scene(tmp_path / "a")
    path.write_text(path.read_text() + "hold = [0, 0, 0.5]\n")
    out = evaluate(capsys, path)
    assert out["hold"] == {"point": [0.0, 0.0, 0.5], "source": "scene"}


def test_a_scene_kappa_scales_every_reported_quantity(tmp_path, capsys):
    base = evaluate(capsys, scene(tmp_path / "a"))
    fixed = evaluate(capsys, scene(tmp_path / "b", kappa="[simulation]\nkappa = 2.5\n"))
    assert fixed["kappa"] == 2.5 and fixed["kappa_source"] == "scene"
    ratio = 2.5 / base["kappa"]
    # the walls' contact term is as stiff as the part's mass and the step make it, not
    # kappa (the box sits in the cup's solid here, so they push): the rest scales
    walls = base["fine_level"]["walls"]
    assert walls == fixed["fine_level"]["walls"] and walls["energy"] > 0
    assert fixed["energy"] - walls["energy"] == pytest.approx(
        ratio * (base["energy"] - walls["energy"]), rel=1e-9)
    np.testing.assert_allclose(np.subtract(fixed["torque"], walls["torque"]),
                               ratio * np.subtract(base["torque"], walls["torque"]),
                               rtol=1e-9, atol=1e-9 * np.abs(base["torque"]).max())


def test_units_follow_the_scene_unit(tmp_path, capsys):
    out = evaluate(capsys, scene(tmp_path / "m", units="m"))
    assert (out["units"]["energy"], out["units"]["force"], out["units"]["torque"]) == (
        "J", "N", "N·m")
