"""The translational scan: per rotation, the energy over every translation, the best kept.

Works on a pair's :class:`~engine.correlation.tables.Spectra` and a block of rotations of
the Hopf grid: for each rotation one landscape from
:func:`engine.correlation.landscape.compute_landscape` (energy only, real transforms, on a
translation lattice of about ``2 K`` samples per axis: the kept modes are band-limited, so
the coarse lattice samples the same function), of which the few lowest separate minima are
kept. A block is one unit of work (:class:`ScanBlock`): frozen, callable with a
``cancelled()`` callable, so it runs here, on a worker thread or as a Dask task, and gives
the same numbers wherever it runs.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from engine.correlation.landscape import compute_landscape
from engine.correlation.tables import Spectra
from engine.errors import Cancelled
from engine.search.rotations import RotationGrid
from engine.search.work import Shared


@dataclass(frozen=True)
class Candidates:
    """Poses the scan found, one row each.

    Attributes
    ----------
    rotation_index : (n,) int64
        Index of the rotation in the grid at the scan's level.
    translation : (n, 3) float64
        Part 2 relative to part 1 (part 1's frame).
    energy : (n,) float64
        The scan's energy there (its modes, its lattice).
    """

    rotation_index: np.ndarray
    translation: np.ndarray
    energy: np.ndarray

    def __len__(self) -> int:
        return int(self.energy.shape[0])

    @staticmethod
    def empty() -> Candidates:
        """No candidates."""
        return Candidates(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))

    @staticmethod
    def join(parts: list[Candidates]) -> Candidates:
        """The rows of ``parts`` in order."""
        if not parts:
            return Candidates.empty()
        return Candidates(np.concatenate([p.rotation_index for p in parts]),
                          np.concatenate([p.translation for p in parts]),
                          np.concatenate([p.energy for p in parts]))

    def best(self, count: int) -> Candidates:
        """The ``count`` rows of lowest energy, lowest first (ties by rotation, then row)."""
        order = np.lexsort((np.arange(len(self)), self.rotation_index, self.energy))[:count]
        return Candidates(self.rotation_index[order], self.translation[order],
                          self.energy[order])


def lowest_minima(energy: np.ndarray, count: int, separation: int) -> np.ndarray:
    """Flat indices of up to ``count`` lowest samples of ``energy``, ``separation`` apart.

    Parameters
    ----------
    energy : (M, M, M) float32
        A landscape's energy.
    count : int
        How many to keep.
    separation : int
        Two kept samples differ by more than this many lattice steps along some axis.

    Returns
    -------
    (k,) int64, k <= count
        Lowest first; only samples of negative energy (the parts overlap to advantage).
    """
    flat = energy.ravel()
    pool = min(flat.size, max(64, 32 * count))
    chosen = np.argpartition(flat, pool - 1)[:pool]
    chosen = chosen[np.lexsort((chosen, flat[chosen]))]
    where = np.stack(np.unravel_index(chosen, energy.shape), axis=1)  # (pool, 3)
    kept: list[int] = []
    for i, index in enumerate(chosen):
        if flat[index] >= 0.0 or len(kept) == count:
            break
        if all(np.abs(where[i] - where[j]).max() > separation for j in kept):
            kept.append(i)
    return chosen[kept].astype(np.int64)


@dataclass(frozen=True)
class ScanBlock:
    """One block of the scan: rotations ``indices`` of the grid at ``level``.

    Called with a ``cancelled()`` callable, returns :class:`BlockResult`; raises
    :class:`engine.errors.Cancelled` once ``cancelled()`` turns True. ``backend`` "opencl"
    computes the block's landscapes and minima on the OpenCL device of
    ``engine.backend.get_backend("opencl")`` (:mod:`engine.search.opencl_scan`), "numpy"
    one landscape at a time with scipy's transforms.
    """

    spectra: Shared[Spectra]
    grid: RotationGrid
    level: int
    indices: np.ndarray
    modes: int
    lattice: int
    per_rotation: int
    number: int = 0
    backend: str = "numpy"

    def __call__(self, cancelled: Callable[[], bool] | None = None) -> BlockResult:
        """Scan the block."""
        start = time.perf_counter()
        spectra = self.spectra.get()
        rotations = self.grid.matrices(self.level, self.indices)
        if self.backend == "opencl":
            return BlockResult(self.number, self._on_opencl(spectra, rotations, cancelled),
                               len(self.indices), time.perf_counter() - start)
        found: list[Candidates] = []
        for index, rot in zip(self.indices, rotations, strict=True):
            if cancelled is not None and cancelled():
                raise Cancelled("the search was cancelled")
            land = compute_landscape(spectra, rot, self.modes, forces=False,
                                     lattice=self.lattice, real=True)
            best = lowest_minima(land.energy, self.per_rotation, separation=1)
            cells = np.unravel_index(best, land.energy.shape)
            translation = np.stack([land.translations[a][cells[a]] for a in range(3)], axis=1)
            found.append(Candidates(np.full(len(best), int(index), np.int64),
                                    translation.astype(np.float64),
                                    land.energy.ravel()[best].astype(np.float64)))
        return BlockResult(self.number, Candidates.join(found), len(self.indices),
                           time.perf_counter() - start)

    def _on_opencl(self, spectra: Spectra, rotations: np.ndarray,
                   cancelled: Callable[[], bool] | None) -> Candidates:
        """The block's candidates from the OpenCL scan (rows in the numpy path's order)."""
        from engine.backend import get_backend
        from engine.search.opencl_scan import scan_for

        scan = scan_for(spectra, self.modes, self.lattice, get_backend("opencl"))
        index, energy = scan.minima(rotations, self.per_rotation, separation=1,
                                    cancelled=cancelled)
        axes = scan.axes(rotations)  # (B, 3, M)
        row, slot = np.nonzero(index >= 0)  # row-major: by rotation, then lowest first
        cells = np.unravel_index(index[row, slot], (self.lattice,) * 3)
        translation = np.stack([axes[row, a, cells[a]] for a in range(3)], axis=1)
        return Candidates(self.indices[row].astype(np.int64), translation,
                          energy[row, slot].astype(np.float64))


@dataclass(frozen=True)
class BlockResult:
    """What one :class:`ScanBlock` found, with its number and its cost."""

    number: int
    candidates: Candidates
    rotations: int
    seconds: float
