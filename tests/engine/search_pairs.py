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


def _turned(mesh: trimesh.Trimesh, rotation: np.ndarray) -> trimesh.Trimesh:
    moved = mesh.copy()
    matrix = np.eye(4)
    matrix[:3, :3] = rotation
    moved.apply_transform(matrix)
    return moved


def box_in_pocket(folder: Path, rotation: np.ndarray, *, grid: int = 32,
                  modes: int = 16) -> tuple[Path, np.ndarray]:
    """A 10 x 6 x 8 box in a blind pocket of its shape in a 24 x 20 x 14 block (rigid).

    The pocket opens on the block's top face (z = 7) and is 6 deep; the box stands 2 proud.
    Both parts are turned by ``rotation`` about the origin (so the fit lies along no frame
    axis). Returns the scene and the seated pose of the box: its own frame has its centre at
    the origin, and seated it sits at ``rotation @ (0, 0, 5)``.
    """
    from engine.pose import rotation_vector

    block = trimesh.creation.box((24.0, 20.0, 14.0))
    pocket = trimesh.creation.box((10.0, 6.0, 6.0))
    pocket.apply_translation((0.0, 0.0, 4.0 + 0.01))  # 6 deep from z = 7, open at the top
    cut = block.difference(pocket, engine="manifold")
    box = trimesh.creation.box((10.0, 6.0, 8.0))
    seated = np.concatenate([rotation @ np.array([0.0, 0.0, 5.0]), rotation_vector(rotation)])
    return _write(folder, "box in pocket", _turned(cut, rotation), box, grid, modes), seated


def keyed_through(folder: Path, *, grid: int = 36, modes: int = 16) -> tuple[Path, np.ndarray]:
    """A radius-4 shaft with a 2 x 2 key along it, through a 20 x 20 x 16 hub (prismatic).

    The hub's bore and keyway run through along z; the shaft, 30 long, is centred in it.
    The seated pose is the identity.
    """
    hub = trimesh.creation.box((20.0, 20.0, 16.0))
    bore = trimesh.creation.cylinder(radius=4.0, height=40.0, sections=48)
    keyway = trimesh.creation.box((2.0, 4.0, 40.0))
    keyway.apply_translation((0.0, 4.5, 0.0))
    cut = hub.difference(trimesh.boolean.union([bore, keyway], engine="manifold"),
                         engine="manifold")
    shaft = trimesh.creation.cylinder(radius=4.0, height=30.0, sections=48)
    key = trimesh.creation.box((2.0, 3.0, 30.0))
    key.apply_translation((0.0, 5.0, 0.0))
    keyed = trimesh.boolean.union([shaft, key], engine="manifold")
    return _write(folder, "keyed through", cut, keyed, grid, modes), np.zeros(6)
