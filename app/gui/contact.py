"""How deep part 2 sits inside part 1: the overlap the window shows.

The engine's fit is soft: a part pushed past a blind bore's floor goes into it (the peg
dragged 100 pixels past its seat sat 12 mm into the floor) and nothing else says so. The
window measures the overlap from the meshes: part 1's signed distance (+ outside) on a grid
(:func:`engine.descriptor.store.distance_for_part`, cached like the descriptors), read by
trilinear interpolation at a point sample of part 2's surface (its vertices and face
centres) placed at the pose. The depth is the deepest point's distance inside part 1.

The grid's interpolation errs by up to about a cell where the surface bends, and a part at
rest on a floor sits a little inside it (the walls' contact, ``engine.correlation.walls``:
0.2 mm for the bundled peg), so :attr:`OverlapMap.threshold` (one cell) separates contact
from an overshoot.

:class:`OverlapMap` has no Qt; :class:`OverlapGauge` builds one off the GUI thread.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore
from scipy import ndimage

from engine import pose as posemath
from engine.runtime import JobWorker

#: Grid samples along part 1's longest side, and the most points of part 2 sampled.
SAMPLES = 48
MAX_POINTS = 20_000


class OverlapMap:
    """Part 1's signed distance on a grid and a point sample of part 2's surface.

    Parameters
    ----------
    grid : engine.grid.Grid
        Where ``distance`` is sampled (part 1's frame).
    distance : grid.shape float32
        Part 1's signed distance, + outside.
    points : (k, 3) float64
        Points of part 2's surface in part 2's own frame.
    """

    def __init__(self, grid, distance: np.ndarray, points: np.ndarray):
        self.grid = grid
        self.distance = np.asarray(distance, np.float64)
        self.points = np.asarray(points, np.float64)
        #: Depths up to one cell count as contact, deeper as an overshoot.
        self.threshold = float(grid.spacing)

    @classmethod
    def of(cls, part1, part2, *, samples: int = SAMPLES, cancel=None) -> OverlapMap:
        """The map of parts ``part1`` (fixed) and ``part2`` (moving): ``vertices``, ``faces``."""
        from engine.descriptor.store import distance_for_part
        from engine.grid import grid_for_bounds

        v1 = np.asarray(part1.vertices, float)
        grid = grid_for_bounds(v1.min(0), v1.max(0), samples=samples, padding=2)
        distance = distance_for_part(part1, grid, cancel=cancel)
        return cls(grid, distance, surface_points(part2.vertices, part2.faces))

    def depth(self, pose: np.ndarray) -> float:
        """The depth inside part 1 of part 2's deepest point at ``pose`` (0: none inside).

        ``pose``: part 2 relative to part 1, (6,).
        """
        m = posemath.pose_to_matrix(np.asarray(pose, float))
        x = self.points @ m[:3, :3].T + m[:3, 3]
        index = (x - np.asarray(self.grid.origin)) / self.grid.spacing
        # outside the grid is outside part 1 (the grid covers it with cells to spare)
        d = ndimage.map_coordinates(self.distance, index.T, order=1, mode="constant",
                                    cval=np.inf)
        return float(max(0.0, -float(d.min()))) if d.size else 0.0


def surface_points(vertices: np.ndarray, faces: np.ndarray,
                   limit: int = MAX_POINTS) -> np.ndarray:
    """(k, 3) float64: a mesh's vertices and face centres, at most ``limit`` (evenly picked)."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    points = np.concatenate([v, v[f].mean(axis=1)]) if len(f) else v
    if len(points) > limit:
        points = points[np.linspace(0, len(points) - 1, limit).astype(np.int64)]
    return points


class OverlapGauge(QtCore.QObject):
    """Builds the :class:`OverlapMap` of a scene's pair off the GUI thread.

    Signals
    -------
    ready(object)
        The map, or None when it could not be made (the readout then says so).
    """

    ready = QtCore.Signal(object)
    _built = QtCore.Signal(int, object)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._worker = JobWorker(name="skelasm-overlap")
        self._request = 0
        self.map: OverlapMap | None = None
        self.error: str | None = None
        self._built.connect(self._deliver, QtCore.Qt.QueuedConnection)

    def submit(self, part1, part2) -> None:
        """Start building the map of ``part1`` and ``part2``; the old one is dropped."""
        self._request += 1
        request = self._request
        self.map, self.error = None, None

        def work(cancelled) -> None:
            try:
                result: object = OverlapMap.of(part1, part2, cancel=cancelled)
            except Exception as exc:  # noqa: BLE001 - shown in the readout, never raised
                result = f"{type(exc).__name__}: {exc}"
            if not cancelled():
                self._built.emit(request, result)

        self._worker.submit("overlap", work)

    def wait_until_idle(self, timeout: float = 60.0) -> bool:
        """Wait until the last request has been built (tests); True when it has."""
        return self._worker.wait_until_idle(timeout)

    def shutdown(self) -> None:
        """Drop what is queued and stop the worker (the window closes)."""
        self._request += 1
        self._worker.shutdown(timeout=0.0)

    def _deliver(self, request: int, result) -> None:
        if request != self._request:
            return
        if isinstance(result, OverlapMap):
            self.map = result
        else:
            self.error = str(result)
        self.ready.emit(self.map)
