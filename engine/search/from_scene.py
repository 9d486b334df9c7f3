"""The search for a scene's two parts: descriptors from the store, part 2's surface points.

Works on a scene (:class:`engine.scene.Scene` or its TOML file); its ``assembled_pose`` is
not read.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from engine.correlation import Correlator
from engine.correlation.walls import surface_points
from engine.descriptor import descriptors_for_scene
from engine.scene import Scene, load_scene
from engine.scene.parts import load_scene_parts
from engine.search.driver import Progress, SearchResult, find_fits
from engine.search.joint import Surfaces
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

    descriptors = descriptors_for_scene(scene, parts=parts, cancel=cancel,
                                        progress=lambda f: prepared(0.6 * f))
    correlator = Correlator(descriptors[0], descriptors[1],
                            modes=int(modes if modes is not None else scene.modes), kappa=kappa,
                            progress=lambda f: prepared(0.6 + 0.3 * f), cancel=cancel)
    # the scan's spectra without the torque's moments: trilinear, about 7 times faster
    scan = Correlator(descriptors[0], descriptors[1], modes=correlator.modes, kappa=kappa,
                      rotation=False, progress=lambda f: prepared(0.9 + 0.1 * f),
                      cancel=cancel).spectra
    points = surface_points(parts[1].vertices, parts[1].faces, SURFACE_POINTS, seed=0)

    def searching(fraction: float, left: float | None) -> None:
        if progress is not None:
            progress(0.1 + 0.9 * fraction, left)

    surfaces = Surfaces.of(parts[0].vertices, parts[0].faces, parts[1].vertices,
                           parts[1].faces)
    return find_fits(correlator, settings, points=points, scan=scan, work=work,
                     surfaces=surfaces, progress=searching, cancel=cancel)
