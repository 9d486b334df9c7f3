"""The search for a scene's two parts: descriptors from the store, part 2's surface points.

Works on a scene (:class:`engine.scene.Scene` or its TOML file); its ``assembled_pose`` is
not read.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from engine.correlation import correlator_for_scene
from engine.correlation.walls import surface_points
from engine.scene import Scene, load_scene
from engine.scene.parts import load_scene_parts
from engine.search.driver import Progress, SearchResult, find_fits
from engine.search.settings import SearchSettings
from engine.search.work import BlockWork

#: Points of part 2's surface the clustering compares poses by.
SURFACE_POINTS = 256


def search_scene(scene: Scene | str | Path, settings: SearchSettings | None = None, *,
                 modes: int | None = None, kappa: float = 1.0,
                 work: BlockWork | None = None,
                 progress: Progress | None = None,
                 cancel: Callable[[], bool] | None = None) -> SearchResult:
    """:func:`~engine.search.driver.find_fits` for a scene's two parts.

    ``modes``: the refinement's modes (default the scene's ``[correlation] modes``);
    ``kappa``: the energy scale (:class:`~engine.correlation.Correlator`).
    Progress: the preparation (descriptors, spectra) is the first tenth.
    """
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    parts = load_scene_parts(scene)
    if len(parts) < 2:
        raise ValueError(f"{scene.path}: the search needs two parts; add a second [[part]]")

    def prepared(fraction: float) -> None:
        if progress is not None:
            progress(0.1 * fraction, None)

    correlator = correlator_for_scene(scene, parts=parts, modes=modes, kappa=kappa,
                                      progress=prepared, cancel=cancel)
    points = surface_points(parts[1].vertices, parts[1].faces, SURFACE_POINTS, seed=0)

    def searching(fraction: float, left: float | None) -> None:
        if progress is not None:
            progress(0.1 + 0.9 * fraction, left)

    return find_fits(correlator, settings, points=points, work=work, progress=searching,
                     cancel=cancel)
