"""The README's "Your own parts" walkthrough runs as written and seats the peg."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def walkthrough_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"<!-- walkthrough -->\s*```sh\n(.*?)```\s*<!-- /walkthrough -->", text,
                      re.S)
    assert block, "README.md lost its walkthrough block"
    return [line for line in block.group(1).splitlines() if line.strip()]


def test_the_walkthrough_is_in_the_readme():
    commands = walkthrough_commands()
    assert commands[1].startswith("skelasm scene new") and commands[-1].startswith("skelasm gui")


@pytest.mark.slow
def test_the_walkthrough_runs_as_written_and_seats(tmp_path):
    (tmp_path / "assets").symlink_to(ROOT / "assets")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
               SKELASM_CACHE=str(tmp_path / "cache"))
    outputs = []
    for command in walkthrough_commands():
        if command.startswith("skelasm gui"):  # the window is tested in tests/app
            continue
        run = subprocess.run(command, shell=True, cwd=tmp_path, env=env, capture_output=True,
                             text=True, timeout=1800)
        assert run.returncode == 0, f"{command}\n{run.stdout}\n{run.stderr}"
        outputs.append(run.stdout)
    assert "free axes" in outputs[-2]
    assert "seat: SEATED" in outputs[-1], outputs[-1]
    assert (tmp_path / "my_fit" / "scene.toml").is_file()
