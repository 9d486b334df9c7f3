"""A Correlator for a scene's two parts, from the descriptor store.

Works on a scene (:class:`engine.scene.Scene` or its TOML file): its first part is fixed,
its second moves; their descriptors come from the store (computed and cached on a miss).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from engine.correlation.correlator import Correlator
from engine.correlation.per_pose import warm_up
from engine.descriptor import descriptors_for_scene
from engine.scene import Scene, load_scene

if TYPE_CHECKING:
    from engine.loading import Part


def correlator_for_scene(
    scene: Scene | str | Path,
    *,
    parts: Sequence[Part] | None = None,
    modes: int | None = None,
    backend: str = "auto",
    rotation: bool = True,
    kappa: float = 1.0,
    band: str | None = None,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> Correlator:
    """A :class:`Correlator` for a scene's two parts (descriptors from the store, cached).

    Parameters
    ----------
    scene : Scene or path
        The scene (or its TOML file).
    parts : sequence of engine.loading.Part, optional
        The scene's parts, already loaded (as ``engine.runtime.open_scene`` does); default:
        loaded here.
    modes : int, optional
        Modes per axis (default: the scene's ``[correlation] modes``).
    backend, rotation, kappa, band
        As :class:`Correlator` (``band``: "box" unless told; the guidance's is "smooth").
    progress : callable(float), optional
        Fractions 0..1 over the whole preparation: the descriptors (the first 60 %, or
        nothing when cached), then the spectra, tables and kernels.
    cancel : callable() -> bool, optional
        Raises :class:`engine.errors.Cancelled` when it returns True.
    """
    warm_up(backend, "cube")  # the kernel compiles while the descriptors load
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    if len(scene.parts) < 2:
        raise ValueError(f"{scene.path}: the scene needs two parts to correlate")

    def stage(lo: float, hi: float) -> Callable[[float], None] | None:
        return None if progress is None else (lambda f: progress(lo + (hi - lo) * f))

    descriptors = descriptors_for_scene(scene, parts=parts, progress=stage(0.0, 0.6),
                                        cancel=cancel)
    return Correlator(
        descriptors[0], descriptors[1],
        modes=int(modes if modes is not None else scene.modes),
        rotation=rotation, backend=backend, kappa=kappa, band=band,
        progress=stage(0.6, 1.0), cancel=cancel,
    )
