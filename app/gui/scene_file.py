"""Saving the open scene with the window's current pose and parameters written in.

The scene is written by the engine's one scene writer (``engine.scene.save_scene``), which
reads the text back before it replaces the file: every table the window does not edit is
kept, part file paths are rewritten relative to the new location, and what is saved loads
back the same.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from engine.params import CouplingParams, DescriptorParams, Effects, SeatSpec
from engine.scene import save_scene


@dataclass(frozen=True)
class FitSetup:
    """The fit as the window's Fit dialog sets it up (part 1's frame, the scene's unit).

    ``insertion_axis`` None: the scene gives none; ``seat_distance`` None: the default
    share of part 2's size.
    """

    assembled_pose: tuple[float, ...]
    insertion_axis: tuple[float, float, float] | None
    free_axes: tuple[str, ...]
    seat_distance: float | None
    seat_degrees: float


#: ``kappa=KEEP``: the scene's own ``[simulation] kappa`` is written as it was.
KEEP = object()
#: The descriptor's parameters the window may change (the grid is the scene's).
DESCRIPTOR_KEYS = ("sigma", "penalty", "lambda_out", "padding")


def write_scene(handle: Any, path: Path, *, moving_relative_pose: np.ndarray | None = None,
                descriptor: DescriptorParams | None = None,
                modes: int | None = None, effects: Effects | None = None,
                coupling: CouplingParams | None = None, kappa: Any = KEEP,
                fit: FitSetup | None = None) -> Path:
    """Write ``handle``'s scene to ``path`` (TOML) and return the path written.

    Parameters
    ----------
    handle : engine.runtime.SceneHandle
    path : Path
        Destination; ``.toml`` is appended when missing.
    moving_relative_pose : (6,) float, optional
        Part 2 relative to part 1 now; stored as part 2's world pose.
    descriptor : DescriptorParams, optional
        The descriptor's parameters now (the object the panel sends to the engine).
    modes : int, optional
        The mode count K now.
    effects, coupling : optional
        Current simulation settings (``[effects]``, ``[coupling]``).
    kappa : float or None, optional
        ``[simulation] kappa``: a value, or None for the scale-free default; by default
        (:data:`KEEP`) the scene's own.
    fit : FitSetup, optional
        The fit as set up in the window (assembled pose, insertion axis, free axes, seat
        tolerance), replacing the scene's.

    Raises
    ------
    engine.scene.SceneError
        The scene cannot be written (or would not load back).
    """
    if handle is None:
        raise ValueError("there is no scene to save; open one first")
    scene = handle.scene
    parts = list(scene.parts)
    if moving_relative_pose is not None and len(parts) >= 2:
        parts[1] = replace(parts[1], pose=handle.world_pose(moving_relative_pose))
    changes = ({} if descriptor is None else
               {k: getattr(descriptor, k) for k in DESCRIPTOR_KEYS
                if getattr(descriptor, k) != getattr(scene.descriptor, k)})
    config = scene.config
    if effects is not None:
        config = replace(config, effects=effects)
    if coupling is not None:
        config = replace(config, coupling=coupling)
    if kappa is not KEEP:
        config = replace(config, simulation=replace(
            config.simulation, kappa=None if kappa is None else float(kappa)))
    if fit is not None:
        scene = replace(scene, assembled_pose=np.asarray(fit.assembled_pose, float),
                        assembled_known=True, insertion_axis=fit.insertion_axis,
                        seat=SeatSpec(free_axes=tuple(fit.free_axes),
                                      distance=fit.seat_distance,
                                      angle_deg=float(fit.seat_degrees)))
    scene = replace(
        scene,
        parts=tuple(parts),
        descriptor=replace(scene.descriptor, **changes),
        correlation=(scene.correlation if modes is None
                     else replace(scene.correlation, modes=int(modes))),
        config=config,
        given=_given_after(handle.scene, changes, modes),
    )
    return save_scene(scene, path)


def _given_after(scene, changes: dict[str, object], modes: int | None) -> frozenset[str] | None:
    """The scene's given keys, plus those the window changed (they are the user's now)."""
    if scene.given is None:
        return None
    changed = {f"descriptor.{k}" for k, v in changes.items() if getattr(scene.descriptor, k) != v}
    if modes is not None and int(modes) != scene.correlation.modes:
        changed.add("correlation.modes")
    return frozenset(scene.given) | changed
