"""Small two-part scenes with known fits for the search's tests, made with trimesh.

Each function writes a block with a bore (through or blind) and a peg into ``folder`` as
STL files with a scene.toml beside them, the peg away from its seat, and returns the scene's
path and the seated pose (part 2 in part 1's frame) the search must find without being told.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

SCENE = """name = "{name}"
units = "mm"
assembled_pose = [0, 0, 0, 0, 0, 0]

[descriptor]
sigma = 0.5
grid = {grid}
padding = 4

[correlation]
modes = {modes}

[[part]]
name = "block"
file = "block.stl"
pose = [0, 0, 0, 0, 0, 0]
fixed = true

[[part]]
name = "peg"
file = "peg.stl"
pose = [0, 0, 40, 0, 0, 0]
"""


def _write(folder: Path, name: str, block: trimesh.Trimesh, peg: trimesh.Trimesh, grid: int,
           modes: int) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    block.export(folder / "block.stl")
    peg.export(folder / "peg.stl")
    path = folder / "scene.toml"
    path.write_text(SCENE.format(name=name, grid=grid, modes=modes))
    return path


def through_round(folder: Path, *, grid: int = 32, modes: int = 16) -> tuple[Path, np.ndarray]:
    """A 24 x 24 x 12 block bored through by a radius-4 hole along z, and a peg.

    The radius-4 peg, 24 long, sits centred in it (a cylindrical joint along z). The seated
    pose is the identity.
    """
    block = trimesh.creation.box((24.0, 24.0, 12.0))
    bore = trimesh.creation.cylinder(radius=4.0, height=40.0, sections=48)
    holed = block.difference(bore, engine="manifold")
    peg = trimesh.creation.cylinder(radius=4.0, height=24.0, sections=48)
    return _write(folder, "through round", holed, peg, grid, modes), np.zeros(6)
