"""Poses typed on the command line turn about the moving part's centre.

A scene stores part 2's pose relative to part 1 turning about the origin of part 2's file
(``engine.pose``); a part drawn far from its file's origin then swings across the scene for
a small tilt. What a person types (``evaluate --pose``, ``simulate --start``) is read about
the part's centre instead: the scene's ``pivot`` for the part, else its centre of mass. The
translation is then where the part's file origin would sit without the rotation, so
``0 0 -15 0.05 0 0`` is the seat at ``t = (0, 0, -15)`` tilted 0.05 rad in place.
``--about origin`` reads the numbers as the scene does.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from engine.runtime import SceneHandle

ABOUT = ("centre", "origin")


def add_about_argument(parser: argparse.ArgumentParser, option: str) -> None:
    """Add ``--about {centre,origin}`` explaining how ``option``'s rotation is read."""
    parser.add_argument(
        "--about", choices=ABOUT, default="centre",
        help=f"what {option}'s rotation turns about: the moving part's centre (default: the "
        "scene's pivot for the part, else its centre of mass) or the origin of its file (the "
        "scene file's convention)")


def typed_pose(handle: SceneHandle, values: list[float], about: str) -> np.ndarray:
    """The scene-convention (origin) pose of six typed numbers read ``about`` a point."""
    from engine.pose import pivot_to_origin
    from engine.sim import part_pivot

    pose = np.asarray(values, dtype=np.float64).reshape(6)
    if about == "origin":
        return pose
    return pivot_to_origin(pose, part_pivot(handle))
