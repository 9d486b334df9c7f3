"""A generated pair becomes a scene only the way a user makes one: ``skelasm scene new``.

The command gets the two files, the scene's unit, the assembled pose and the insertion axis,
and nothing else: every other setting (grid, modes, tolerances, hold point, free axes) is
whatever ``scene new`` chooses, so a benchmark of generated pairs measures what a user gets.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import numpy as np


class SceneNewFailed(RuntimeError):
    """``skelasm scene new`` refused a generated pair (its one-line message is kept)."""


def scene_new(fixed: Path, moving: Path, out: Path, *, unit: str, assembled: np.ndarray,
              insertion_axis: np.ndarray) -> Path:
    """Run ``skelasm scene new FIXED MOVING -o OUT --unit U --assembled .. --insertion-axis ..``.

    Runs the command in this process (its parser and ``run``, as the console script does);
    its printed lines are swallowed, its errors kept. Returns the scene file written.

    Raises
    ------
    SceneNewFailed
        The command exited with an error, or the scene it wrote does not hold the assembled
        pose that was given (``--assembled`` read in another convention).
    """
    from app.cli import main
    from engine.scene import load_scene

    argv = ["scene", "new", str(fixed), str(moving), "-o", str(out), "--unit", unit,
            "--assembled", *(repr(float(x)) for x in assembled),
            "--insertion-axis", *(repr(float(x)) for x in insertion_axis)]
    said, errors = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(errors):
        code = main(argv)
    if code != 0:
        text = errors.getvalue().strip().splitlines() or said.getvalue().strip().splitlines()
        raise SceneNewFailed(f"skelasm {' '.join(argv)}: exit {code}: "
                             f"{text[-1] if text else 'no message'}")
    scene = load_scene(out)
    if not np.allclose(scene.assembled_pose, assembled, rtol=1e-9, atol=1e-9):
        raise SceneNewFailed(
            f"{out}: scene new wrote assembled_pose {list(scene.assembled_pose)} for "
            f"--assembled {list(assembled)}: the generator gives the pose as the scene file "
            "stores it (turning about part 2's file origin); update bench/fitgen/scenes.py")
    return out
