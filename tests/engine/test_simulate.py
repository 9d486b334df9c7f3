"""`skelasm simulate`: headless runs, JSON, logs, messages for bad scenes and devices."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]
PEG = ROOT / "assets" / "peg_in_hole" / "scene.toml"


def copy_scene(tmp_path, extra=""):
    for f in PEG.parent.glob("*.step"):
        shutil.copy(f, tmp_path / f.name)
    text = PEG.read_text()
    head, sep, tail = text.partition("[[part]]")
    (tmp_path / "scene.toml").write_text(head + extra + "\n" + sep + tail)
    return tmp_path / "scene.toml"


def run_json(capsys, *argv):
    assert main(["simulate", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_trajectory_moves_part_and_log_replays(tmp_path, capsys):
    traj = tmp_path / "in.csv"
    traj.write_text("t,tx,ty,tz,rx,ry,rz\n0,0,0,5,0,0,0\n0.5,1,0,-5,0,0,0.1\n")
    log = tmp_path / "out.csv"
    out = run_json(capsys, PEG, "--guidance", "none", "--trajectory", traj, "--log", log)
    assert out["steps"] == 1500  # trajectory length + 1 s at 1 kHz
    # the coupling settles on the held last row
    np.testing.assert_allclose(out["final_pose"], [1, 0, -5, 0, 0, 0.1], atol=1e-3)
    assert set(out["period_us"]) == {"median", "p1", "p99", "max"} and out["rate_hz"] > 0
    # the log is itself a trajectory: replaying it gives the same final pose
    again = run_json(capsys, PEG, "--guidance", "none", "--trajectory", log, "--seconds", 1.5)
    np.testing.assert_array_equal(again["final_pose"], out["final_pose"])


def test_no_trajectory_keeps_proxy_at_start(capsys):
    out = run_json(capsys, PEG, "--guidance", "none", "--seconds", 0.2)
    np.testing.assert_allclose(out["final_pose"], [0, 0, 5, 0, 0, 0], atol=1e-9)
    assert out["steps"] == 200


def test_realtime_holds_rate(capsys):
    out = run_json(capsys, PEG, "--guidance", "none", "--seconds", 0.5, "--realtime")
    assert out["period_us"]["median"] == pytest.approx(1000.0, rel=0.05)
    assert out["wall_seconds"] >= 0.49


def test_bad_scene_names_the_line(tmp_path, capsys):
    scene = copy_scene(tmp_path, "[coupling]\nfrequency_hz = -3\n")
    assert main(["simulate", str(scene), "--guidance", "none"]) == 2
    err = capsys.readouterr().err
    line = next(i for i, l in enumerate(scene.read_text().splitlines(), 1) if "frequency_hz" in l)
    assert f"scene.toml:{line}: [coupling] frequency_hz: must be positive" in err


def test_missing_device_falls_back_to_mouse(tmp_path, capsys):
    scene = copy_scene(tmp_path, '[device]\nkind = "spacemouse"\n')
    out = run_json(capsys, scene, "--guidance", "none", "--seconds", 0.1)
    assert out["steps"] == 100
    assert any(n.startswith("spacemouse:") for n in out["notes"])


def test_missing_trajectory_file(tmp_path, capsys):
    assert main(["simulate", str(PEG), "--trajectory", str(tmp_path / "no.csv"),
                 "--guidance", "none"]) == 2
    assert "no.csv: cannot open the trajectory file" in capsys.readouterr().err
