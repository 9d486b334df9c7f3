"""Saving the open scene: its TOML tables with the current pose and parameters written in.

The original scene file is the starting point, so tables the window does not edit
(``[simulation]``, ``[device]``, masses, ...) are kept as they were. Part file paths are
rewritten relative to the new location.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import tomli_w
import tomllib


def write_scene(handle, path: Path, *, moving_relative_pose: np.ndarray | None = None,
                sigma: float | None = None, penalty: float | None = None,
                modes: int | None = None) -> Path:
    """Write ``handle``'s scene to ``path`` (TOML) and return the path written.

    Parameters
    ----------
    handle : engine.api.SceneHandle
    path : Path
        Destination; ``.toml`` is appended when missing.
    moving_relative_pose : (6,) float, optional
        Part 2 relative to part 1 now; stored as part 2's world pose.
    sigma, penalty, modes : optional
        Current descriptor and accuracy settings.
    """
    if handle is None:
        raise ValueError("there is no scene to save")
    path = Path(path)
    if path.suffix.lower() != ".toml":
        path = path.with_suffix(".toml")
    source = Path(handle.path)
    spec = tomllib.loads(source.read_text()) if source.exists() else {}
    parts = spec.get("part") or []
    spec_parts = handle.scene.parts
    base_old = source.parent
    base_new = path.parent.resolve()
    out_parts = []
    for i, scene_part in enumerate(spec_parts):
        entry = dict(parts[i]) if i < len(parts) else {"name": scene_part.name}
        file = Path(str(entry.get("file", scene_part.file)))
        absolute = file if file.is_absolute() else (base_old / file).resolve()
        try:
            entry["file"] = os.path.relpath(absolute, base_new)
        except ValueError:  # another drive on Windows
            entry["file"] = str(absolute)
        entry["pose"] = [float(x) for x in scene_part.pose]
        out_parts.append(entry)
    if moving_relative_pose is not None and len(out_parts) >= 2:
        out_parts[1]["pose"] = [float(x) for x in handle.world_pose(moving_relative_pose)]
    spec["part"] = out_parts
    if sigma is not None or penalty is not None:
        desc = dict(spec.get("descriptor", {}))
        if sigma is not None:
            desc["sigma"] = float(sigma)
        if penalty is not None:
            desc["penalty"] = float(penalty)
        spec["descriptor"] = desc
    if modes is not None:
        spec["correlation"] = {**spec.get("correlation", {}), "modes": int(modes)}
    spec.setdefault("name", getattr(handle.scene, "name", path.stem))
    text = tomli_w.dumps(spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".toml.part")
    tmp.write_text(text)
    os.replace(tmp, path)  # never leave a half-written scene behind
    return path
