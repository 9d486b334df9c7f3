"""A loaded scene as the engine takes it: the parsed file, its settings and its part meshes.

Data: part meshes (vertices (n, 3) float64, faces (m, 3) int64, in each part's own frame);
poses (6,) float64, part 2 relative to part 1 unless said otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from engine.loading import Part
from engine.params import SimConfig
from engine.pose import compose, relative_pose
from engine.scene import Scene, load_scene, relative_start_pose, require_assembled
from engine.sim.auto import complete_scene

__all__ = ["SceneHandle", "open_scene"]


def _frozen_array(values: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    arr = np.array(values, dtype=np.float64).reshape(shape)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class SceneHandle:
    """A loaded scene: parsed file, validated simulation settings and part meshes.

    Attributes
    ----------
    scene : engine.scene.Scene
    config : SimConfig
        The scene's simulation settings (replace it to run with other effects).
    parts : tuple of engine.loading.Part
        One mesh per ``[[part]]`` (vertices (n, 3) float64, faces (m, 3) int64, own frame).
    start_pose : (6,) float64, read-only
        Part 2 relative to part 1 at the start (from the scene's part poses).
    assembled_pose : (6,) float64, read-only
    path : Path
        The scene file.
    """

    scene: Scene
    config: SimConfig
    parts: tuple[Part, ...]
    start_pose: np.ndarray
    assembled_pose: np.ndarray
    path: Path = field(default=Path("."))

    @property
    def part1_world_pose(self) -> np.ndarray:
        """(6,) world pose of the fixed part."""
        return np.asarray(self.scene.parts[0].pose, dtype=float)

    def world_pose(self, relative: np.ndarray) -> np.ndarray:
        """(6,) world pose of part 2 from its pose relative to part 1."""
        return compose(self.part1_world_pose, np.asarray(relative, float))

    def relative_pose(self, world: np.ndarray) -> np.ndarray:
        """(6,) pose relative to part 1 of a world pose of part 2."""
        return relative_pose(self.part1_world_pose, np.asarray(world, float))


def open_scene(path: str | Path) -> SceneHandle:
    """Parse a scene file, validate its tables and load its parts' meshes.

    Fast (no descriptors): call it from the GUI thread or a worker.

    Raises
    ------
    engine.scene.SceneError, engine.loading.PartError
        ValueError subclasses with the file, the line and the fix.
    """
    scene = load_scene(path)
    # the fit's measurements choose the settings and judge the seat
    require_assembled(scene, "the simulation (evaluate, simulate, the window)")
    scene, loaded = complete_scene(scene)
    parts = tuple(loaded)
    start = relative_start_pose(scene) if len(scene.parts) >= 2 else np.zeros(6)
    return SceneHandle(
        scene=scene,
        config=scene.config,
        parts=parts,
        start_pose=_frozen_array(start, (6,)),
        assembled_pose=_frozen_array(scene.assembled_pose, (6,)),
        path=Path(scene.path),
    )
