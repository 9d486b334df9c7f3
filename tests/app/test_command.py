"""`skelasm gui` from the command line: timed screenshot and quit, bad input."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def _skelasm(*args, timeout=120):
    return subprocess.run([sys.executable, "-m", "app", "gui", *map(str, args)], cwd=ROOT,
                          env=dict(os.environ), capture_output=True, text=True,
                          timeout=timeout)


def test_screenshot_and_quit_after(small_scene, tmp_path):
    from PySide6 import QtGui

    out = tmp_path / "shot.png"
    r = _skelasm(small_scene, "--screenshot", out, "--quit-after", "3")
    assert r.returncode == 0, r.stderr
    assert f"saved {out}" in r.stdout
    img = QtGui.QImage(str(out))
    assert img.width() >= 800 and img.height() >= 500
    # the picture shows a window, not one flat colour
    ptr = img.convertToFormat(QtGui.QImage.Format_RGB888)
    arr = np.frombuffer(ptr.constBits(), np.uint8, ptr.sizeInBytes())
    assert arr.std() > 20


def test_bad_scene_exits_with_the_message(tmp_path):
    bad = tmp_path / "nothing.toml"
    bad.write_text("this is not toml = = =")
    r = _skelasm(bad, "--quit-after", "0.5")
    assert r.returncode == 2
    assert "nothing.toml" in r.stderr


def test_negative_quit_after_is_refused_before_qt_starts():
    from app.cli import main

    assert main(["gui", "--quit-after", "-1"]) == 2


@pytest.mark.parametrize("flag", ["--help"])
def test_help_lists_the_options(flag, capsys):
    from app.cli import main

    with pytest.raises(SystemExit):
        main(["gui", flag])
    text = capsys.readouterr().out
    for option in ("--screenshot", "--quit-after", "--engine"):
        assert option in text
