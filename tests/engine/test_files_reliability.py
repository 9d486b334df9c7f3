"""Files in and out, end to end: no user file replaced, outputs whole, the cache healing itself.

Each command-line case asserts the message, the exit status (2 for bad input) and that no
file changed (hashes before and after). The scene is the peg in hole at grid 16, K = 8.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from engine.files import TEMP_PREFIX, atomic_write, check_output
from engine.recording import COLUMNS, load_recording

ROOT = Path(__file__).resolve().parents[2]
PEG = ROOT / "assets" / "peg_in_hole"
SCENE = """name = "Peg in hole, small"
units = "mm"
assembled_pose = [0, 0, -15, 0, 0, 0]
insertion_axis = [0, 0, -1]
[descriptor]
grid = 16
padding = 6
[correlation]
modes = 8
[[part]]
name = "block"
file = "block.step"
fixed = true
[[part]]
name = "peg"
file = "peg.step"
pose = [0, 0, 5, 0, 0, 0]
"""


def digest(*paths: Path) -> dict[str, str | None]:
    """SHA-256 of each file (None when absent), to show that nothing changed."""
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() if p.exists() else None
            for p in paths}


def cache_entries(folder: Path) -> list[Path]:
    return sorted(folder.glob("*/*.npz"))


@pytest.fixture
def scene(tmp_path, monkeypatch):
    """A copy of the small scene in its own folder, with an empty private cache."""
    folder = tmp_path / "scene"
    folder.mkdir()
    for name in ("block.step", "peg.step"):
        shutil.copy(PEG / name, folder / name)
    (folder / "base.toml").write_text(SCENE)
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(folder)
    return folder / "base.toml"


def run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


# --------------------------------------------------------------------------- outputs
@pytest.mark.parametrize("target", ["peg.step", "base.toml"])
def test_log_never_replaces_an_input_even_with_force(scene, capsys, target):
    files = [scene, scene.parent / "peg.step", scene.parent / "block.step"]
    before = digest(*files)
    for extra in ([], ["--force"]):
        code, err = run(capsys, "simulate", scene, "--seconds", "0.01", "--log",
                        scene.parent / target, *extra)
        assert code == 2
        assert f"{target}: this is an input file of the command" in err
    assert digest(*files) == before
    assert cache_entries(scene.parent.parent / "cache") == []  # refused before any work


def test_log_into_a_missing_folder_is_refused_before_the_run(scene, capsys):
    code, err = run(capsys, "simulate", scene, "--seconds", "5", "--log", "nowhere/out.csv")
    assert code == 2 and "nowhere: no such folder for the log out.csv" in err
    assert cache_entries(scene.parent.parent / "cache") == []  # no descriptor computed


def test_log_onto_an_existing_file_needs_force(scene, capsys):
    old = scene.parent / "old.csv"
    old.write_text("mine\n")
    before = digest(old)
    code, err = run(capsys, "simulate", scene, "--guidance", "none", "--seconds", "0.01",
                    "--log", old)
    assert code == 2 and "old.csv: the file exists; add --force to replace it" in err
    assert digest(old) == before
    code, _ = run(capsys, "simulate", scene, "--guidance", "none", "--seconds", "0.01",
                  "--log", old, "--force")
    assert code == 0 and load_recording(old).shape == (10, len(COLUMNS))


def test_read_only_log_is_refused_even_with_force(scene, capsys):
    locked = scene.parent / "locked.csv"
    locked.write_text("mine\n")
    locked.chmod(0o444)
    before = digest(locked)
    code, err = run(capsys, "simulate", scene, "--seconds", "0.01", "--log", locked, "--force")
    assert code == 2 and "locked.csv: the file is read-only" in err
    assert digest(locked) == before


def test_landscape_into_a_missing_folder_is_refused_before_the_compute(scene, capsys):
    code, err = run(capsys, "landscape", scene, "-o", "nowhere/l.png")
    assert code == 2 and "nowhere: no such folder for the image l.png" in err
    assert cache_entries(scene.parent.parent / "cache") == []
    code, err = run(capsys, "landscape", scene, "-o", "l.txt")
    assert code == 2 and "l.txt: cannot write images of type 'txt'" in err
    assert not (scene.parent / "l.txt").exists()


def test_report_does_not_overwrite_its_files_without_force(scene, capsys):
    out = scene.parent / "rep"
    out.mkdir()
    mine = out / "report.md"
    mine.write_text("my notes\n")
    before = digest(mine)
    code, err = run(capsys, "report", scene, "-o", out)
    assert code == 2 and "report.md: the file exists; add --force" in err
    assert digest(mine) == before
    assert cache_entries(scene.parent.parent / "cache") == []  # checked before the work


def test_precompute_output_needs_force(scene, capsys):
    peg = scene.parent / "peg.step"
    mine = scene.parent / "mine.npz"
    mine.write_bytes(b"keep")
    before = digest(mine, peg)
    code, err = run(capsys, "precompute", peg, "--grid", "8", "-o", mine)
    assert code == 2 and "mine.npz: the file exists; add --force" in err
    assert digest(mine, peg) == before
    code, _ = run(capsys, "precompute", peg, "--grid", "8", "-o", mine, "--force")
    assert code == 0 and mine.read_bytes()[:2] == b"PK"


def test_precompute_onto_a_full_disk_keeps_the_old_file_and_names_it(scene, capsys,
                                                                     monkeypatch):
    peg = scene.parent / "peg.step"
    out = scene.parent / "peg.npz"
    assert run(capsys, "precompute", peg, "--grid", "8")[0] == 0
    before = digest(out)

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", full)
    code, err = run(capsys, "precompute", peg, "--grid", "8", "--force")
    assert code == 2
    assert f"{out}: cannot write the descriptor (No space left on device)" in err
    assert digest(out) == before
    assert not [p for p in out.parent.iterdir() if p.name.startswith(TEMP_PREFIX)]


def test_kill_during_a_write_leaves_the_old_file(tmp_path):
    """``kill -9`` in the middle of atomic_write: the old file is whole, the new one absent."""
    target = tmp_path / "result.npz"
    target.write_bytes(b"old result")
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import sys, time\n"
         "from engine.files import atomic_write\n"
         f"with atomic_write({str(target)!r}) as fh:\n"
         "    fh.write(b'x' * 100000); fh.flush()\n"
         "    print('writing', flush=True); time.sleep(60)\n"],
        stdout=subprocess.PIPE, cwd=ROOT)
    assert child.stdout is not None and child.stdout.readline().strip() == b"writing"
    child.send_signal(signal.SIGKILL)
    child.communicate(timeout=10)
    assert child.returncode == -signal.SIGKILL
    assert target.read_bytes() == b"old result"
    partial = [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]
    assert len(partial) == 1 and partial[0].stat().st_size == 100000


def test_atomic_write_failure_leaves_nothing(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_write(target, "w") as fh:
        fh.write("new")
        raise RuntimeError("boom")
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]


def test_check_output_messages(tmp_path):
    (tmp_path / "dir").mkdir()
    with pytest.raises(ValueError, match="dir: is a folder"):
        check_output(tmp_path / "dir")
    with pytest.raises(ValueError, match="no such folder"):
        check_output(tmp_path / "a" / "b.csv")
    link = tmp_path / "link.step"
    real = tmp_path / "real.step"
    real.write_text("x")
    link.symlink_to(real)
    with pytest.raises(ValueError, match="input file"):
        check_output(link, force=True, inputs=[real])
    assert check_output(tmp_path / "new.csv") == tmp_path / "new.csv"


# --------------------------------------------------------------------------- the log
def test_ctrl_c_keeps_the_recorded_steps(scene):
    """SIGINT during ``simulate --realtime --log``: exit 130 and a readable log of the steps."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    log = scene.parent / "int.csv"
    child = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "simulate", str(scene), "--guidance", "none",
         "--realtime", "--seconds", "60", "--log", str(log)],
        cwd=scene.parent, env=env, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    partial: list[Path] = []
    while time.monotonic() < deadline:  # wait until some steps are on disk
        partial = [p for p in scene.parent.iterdir() if p.name.startswith(TEMP_PREFIX + "int")]
        if partial and partial[0].stat().st_size > 20000:
            break
        time.sleep(0.1)
    assert partial, "the log was not streamed"
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=30)
    assert child.returncode == 130, err
    assert "log: kept" in err and "int.csv" in err
    rows = load_recording(log)
    assert len(rows) >= 256 and np.all(np.diff(rows[:, 0]) > 0)


def test_a_log_too_large_for_the_disk_is_refused_before_the_run(scene, capsys):
    late = scene.parent / "late.csv"
    late.write_text("t,tx,ty,tz,rx,ry,rz\n0,0,0,5,0,0,0\n1e9,0,0,0,0,0,0\n")
    code, err = run(capsys, "simulate", scene, "--guidance", "none", "--trajectory", late,
                    "--log", "late_log.csv")
    assert code == 2 and "MemoryError" not in err
    assert "late_log.csv: the log of" in err or "seconds" in err
    assert not (scene.parent / "late_log.csv").exists()


def test_replaying_a_recording_of_another_scene_says_so(scene, capsys):
    import json

    assert run(capsys, "simulate", scene, "--guidance", "none", "--seconds", "0.02",
               "--log", "rec.csv")[0] == 0
    same = main(["simulate", str(scene), "--guidance", "none", "--trajectory", "rec.csv",
                 "--json"])
    assert same == 0 and json.loads(capsys.readouterr().out)["notes"] == []
    other = scene.parent / "other.toml"
    other.write_text(SCENE.replace("padding = 6", "padding = 4"))
    code = main(["simulate", str(other), "--guidance", "none", "--trajectory", "rec.csv",
                 "--json"])
    notes = json.loads(capsys.readouterr().out)["notes"]
    assert code == 0
    assert any("rec.csv was recorded with another scene" in n for n in notes)


# --------------------------------------------------------------------------- the cache
def _descriptor_entries(scene: Path) -> list[Path]:
    return cache_entries(scene.parent.parent / "cache")


@pytest.mark.parametrize("damage", ["truncate", "flip"])
def test_damaged_cache_entries_are_dropped_and_recomputed(scene, capsys, caplog, damage):
    """Once broken, an entry gave a BadZipFile traceback in every later command."""
    argv = ("precompute", scene, "--grid", "8", "--force")
    assert run(capsys, *argv)[0] == 0
    entries = _descriptor_entries(scene)
    assert len(entries) == 2
    for path in entries:
        data = bytearray(path.read_bytes())
        if damage == "truncate":
            data = data[: len(data) // 2]
        else:
            data[len(data) // 2] ^= 0xFF
        path.write_bytes(bytes(data))
    code, err = run(capsys, *argv)
    assert code == 0 and "Traceback" not in err
    assert sum("cannot be read" in r.getMessage() and "deleted" in r.getMessage()
               for r in caplog.records) == 2
    caplog.clear()
    assert run(capsys, *argv)[0] == 0
    assert not [r for r in caplog.records if "cannot be read" in r.getMessage()]  # healed
