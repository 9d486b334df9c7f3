"""Every way a run ends keeps its outputs: SIGTERM, SIGHUP, Ctrl+C, a killed writer.

A log holds every step written and no torn row; no hidden ``.partial`` file outlives its
run; an interrupted report leaves its folder as it was; cache eviction removes only the
cache's own temporary files.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from app.cli import main
from engine import cache
from engine.files import TEMP_PREFIX, check_output, make_temporary
from engine.recording import COLUMNS, RecordingWriter, load_recording

trimesh = pytest.importorskip("trimesh")
ROOT = Path(__file__).resolve().parents[2]

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


@pytest.fixture
def scene(tmp_path, monkeypatch):
    folder = tmp_path / "scene"
    folder.mkdir()
    trimesh.creation.box(extents=(6, 6, 4)).export(folder / "cup.stl")
    trimesh.creation.box(extents=(3, 3, 2)).export(folder / "box.stl")
    (folder / "scene.toml").write_text(SCENE)
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(folder)
    return folder / "scene.toml"


def partials(folder: Path) -> list[Path]:
    return [p for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX)]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_keep_the_log_whole_and_leave_no_partial(scene, signum):
    """Before: exit 143, no log, an 8.8 MB hidden .partial with a torn last row."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    log = scene.parent / "run.csv"
    child = subprocess.Popen(
        [sys.executable, "-m", "app.cli", "simulate", str(scene), "--guidance", "none",
         "--realtime", "--seconds", "120", "--log", str(log)],
        cwd=scene.parent, env=env, stderr=subprocess.PIPE, text=True,
        # as from a terminal: a run started under nohup (SIGHUP ignored) rightly goes on
        preexec_fn=lambda: signal.signal(signum, signal.SIG_DFL))
    deadline = time.monotonic() + 120  # a hang guard, not a timing
    found: list[Path] = []
    try:
        while time.monotonic() < deadline:
            found = [p for p in partials(scene.parent) if "run.csv" in p.name]
            if found and found[0].stat().st_size > 20000:
                break
            time.sleep(0.1)
        assert found, "the log was not streamed"
        child.send_signal(signum)
        _, err = child.communicate(timeout=60)
    finally:
        if child.poll() is None:
            child.kill()
    assert child.returncode == 128 + signum, err
    assert "log: kept" in err and signal.Signals(signum).name in err
    rows = load_recording(log)  # every row whole: 26 numbers
    assert len(rows) >= 256 and np.all(np.diff(rows[:, 0]) > 0)
    assert partials(scene.parent) == []


class _StopHalfway:
    """A raw file whose next write stores half the bytes, then raises (a signal's exception)."""

    def __init__(self, fh):
        self.fh = fh
        self.armed = True

    def write(self, data):
        if self.armed:
            self.armed = False
            self.fh.write(bytes(data[: len(data) // 2]))
            raise KeyboardInterrupt
        return self.fh.write(data)

    def __getattr__(self, name):
        return getattr(self.fh, name)


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_a_write_stopped_halfway_leaves_whole_rows_and_no_duplicates(tmp_path, suffix):
    path = tmp_path / f"log{suffix}"
    writer = RecordingWriter(path)
    rows = np.arange(300 * len(COLUMNS), dtype=float).reshape(300, len(COLUMNS))
    rows[:, 0] = np.arange(300)
    writer.append(rows[:100])
    writer._fh = _StopHalfway(writer._fh)
    with pytest.raises(KeyboardInterrupt):
        writer.append(rows[100:])
    writer.close()
    kept = load_recording(path)
    assert len(kept) == writer.count
    np.testing.assert_array_equal(kept, rows[:writer.count])
    assert partials(tmp_path) == []


def test_the_temporary_file_of_a_killed_writer_is_removed_by_the_next_run(tmp_path):
    target = tmp_path / "out.csv"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    stale = tmp_path / f"{TEMP_PREFIX}out.csv.{pid}.abcd1234.partial"
    stale.write_text("torn")
    fd, mine = make_temporary(target)  # this process's own: alive, kept
    os.close(fd)
    other = tmp_path / f"{TEMP_PREFIX}other.csv.{pid}.abcd1234.partial"
    other.write_text("another file's")
    check_output(target)
    assert not stale.exists()
    assert Path(mine).exists() and other.exists()


def test_eviction_never_removes_a_users_file_named_like_a_temporary(tmp_path, monkeypatch):
    monkeypatch.setenv("SKELASM_CACHE", str(tmp_path))
    cache.load_or_compute("descriptor", {"n": 1}, lambda: {"x": np.ones(3)})
    folder = tmp_path / "descriptor"
    user = [folder / ".skelasm-notes.partial", folder / ".skelasm-thesis.tex.x.partial",
            folder / "tmpmydata.tmp.npz.bak"]
    ours = folder / f".skelasm-{'a' * 64}.npz.12345.abcdefgh.partial"
    past = time.time() - 2 * cache.STALE_SECONDS
    for path in [*user, ours]:
        path.write_bytes(b"x")
        os.utime(path, (past, past))
    cache.evict()
    assert all(p.exists() for p in user)
    assert not ours.exists()


def test_ctrl_c_during_report_leaves_the_folder_as_it_was(scene, capsys, monkeypatch):
    """Before: two PNGs and no report.md, and the rerun needed --force."""
    import app.commands.landscape as landscape

    real = landscape.write_section_png

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    out = scene.parent / "rep"
    monkeypatch.setattr(landscape, "write_section_png", interrupted)
    assert main(["report", str(scene), "-o", str(out), "--backend", "numba"]) == 130
    assert sorted(p.name for p in out.iterdir()) == []
    monkeypatch.setattr(landscape, "write_section_png", real)
    assert main(["report", str(scene), "-o", str(out), "--backend", "numba"]) == 0
    assert (out / "report.md").exists() and partials(out) == []


@pytest.mark.parametrize("value", ["1e300", "1e30", "inf", "nan", "-1", "abc"])
def test_cache_cap_values_never_end_in_a_traceback(scene, capsys, monkeypatch, value):
    """Before: SKELASM_CACHE_MAX_GB=1e300 ended in OverflowError after the computation."""
    monkeypatch.setenv("SKELASM_CACHE_MAX_GB", value)
    code = main(["evaluate", str(scene), "--json"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "OverflowError" not in err
    if value in ("1e300", "1e30"):
        assert code == 0
    else:
        assert code == 2 and "SKELASM_CACHE_MAX_GB" in err
