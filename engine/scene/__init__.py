"""Scene files: two parts, their poses, the assembled answer and every parameter table.

A scene is a TOML file (the full format is in docs/scenes.md)::

    name = "Peg in hole"
    units = "mm"
    assembled_pose = [0, 0, -15, 0, 0, 0]   # optional: part 2 in part 1's frame when seated
    insertion_axis = [0, 0, -1]             # optional, part 1's frame

    [descriptor]      # sigma, penalty, lambda_out, grid | spacing, padding
    [correlation]     # modes
    [simulation]      # rate_hz, kappa, guidance_gain, body_damping_ratio, seconds
    [coupling]        # frequency_hz, damping_ratio, stiffness, ... (absolute gains)
    [effects]         # guidance, axes, damping, gravity, gravity_direction
    [device]          # kind, max_force, force_scale, per-kind options
    [[part]]          # first: fixed.  name, file, pose, fixed, body, tolerance, unit, pivot
    [[part]]          # second: moving (plus hold, mass, density, inertia, center_of_mass)

:func:`load_scene` reads it (once, every table validated into the frozen types of
``engine.params``); :func:`save_scene` writes one that reads back the same;
:func:`load_scene_parts` loads the part meshes in the scene's unit. Errors are
:class:`SceneError` (a ``ValueError``) and read ``FILE:LINE: problem; fix``.
"""

from engine.scene.model import (
    PartSpec,
    Scene,
    SceneError,
    relative_start_pose,
    require_assembled,
)
from engine.scene.parts import load_scene_parts, unit_mismatch
from engine.scene.reader import key_line, load_scene, parse_scene
from engine.scene.writer import save_scene, scene_to_toml

__all__ = [
    "PartSpec",
    "Scene",
    "SceneError",
    "key_line",
    "load_scene",
    "load_scene_parts",
    "parse_scene",
    "relative_start_pose",
    "require_assembled",
    "save_scene",
    "scene_to_toml",
    "unit_mismatch",
]
