"""The search's settings: one frozen dataclass, validated in one place.

Works on plain numbers: the rotation grid's level, the modes of each stage, how many
translations each rotation keeps, the clustering radius, the refinement depth, the seed.
"""

from __future__ import annotations

from dataclasses import dataclass

from engine.backend import check_choice
from engine.search.rotations import MAX_LEVEL, level_angle, level_size


@dataclass(frozen=True)
class SearchSettings:
    """What one search does; the same settings and seed give the same result.

    Attributes
    ----------
    level : int
        Level of the Hopf rotation grid scanned (``72 * 8^level`` rotations, about
        ``60 / 2^level`` degrees apart; 1: 576 at 30 degrees, 2: 4,608 at 15).
    scan_modes : int
        Modes per axis of the scan's landscapes (the coarse stage).
    modes : int or None
        Modes per axis of the refinement and the local minimisation (None: the
        correlator's own).
    lattice : int or None
        Translation samples per axis of the scan's landscapes (None: the smallest even
        size above ``2 scan_modes``, a step of ``N h / lattice``).
    per_rotation : int
        Best translations each rotation keeps (separate local minima of its landscape).
    keep : int
        Candidates kept over all rotations before clustering (the lowest energies).
    cluster_radius : float
        Two poses belong to one cluster when part 2's surface points lie within this
        fraction of part 2's size of each other (mean nearest distance, both ways).
    clusters : int
        Clusters refined (the best by energy); the rest are reported unrefined.
    refine_levels : int
        Rotation-grid levels the refinement descends through children before the local
        minimisation.
    top : int
        Fits returned.
    seed : int or None
        Turns the rotation grid as a whole by a random rotation drawn from it (None: the
        plain grid).
    chunk : int
        Rotations per unit of work (what a Dask task or a progress step covers).
    backend : str
        Where the scan's landscapes are computed: "numpy" (scipy's transforms, one thread
        a block), "opencl" (:mod:`engine.search.opencl_scan`, a block per launch) or
        "auto" (OpenCL on a GPU, else numpy: ``engine.backend.CAPABILITIES["scan"]``).
    """

    level: int = 1
    scan_modes: int = 16
    modes: int | None = None
    lattice: int | None = None
    per_rotation: int = 2
    keep: int = 600
    cluster_radius: float = 0.1
    clusters: int = 8
    refine_levels: int = 1
    top: int = 5
    seed: int | None = 0
    chunk: int = 64
    backend: str = "auto"

    def __post_init__(self) -> None:
        checks = [
            (0 <= self.level <= MAX_LEVEL, f"level must be 0 to {MAX_LEVEL}"),
            (self.scan_modes >= 2, "scan_modes must be at least 2"),
            (self.modes is None or self.modes >= 2, "modes must be at least 2"),
            (self.lattice is None or (self.lattice >= 4 and self.lattice % 2 == 0),
             "lattice must be an even number of at least 4"),
            (self.per_rotation >= 1, "per_rotation must be at least 1"),
            (self.keep >= 1, "keep must be at least 1"),
            (0.0 < self.cluster_radius < 10.0, "cluster_radius must be in (0, 10)"),
            (self.clusters >= 1, "clusters must be at least 1"),
            (self.refine_levels >= 0, "refine_levels must be at least 0"),
            (self.top >= 1, "top must be at least 1"),
            (self.chunk >= 1, "chunk must be at least 1"),
        ]
        try:
            check_choice("scan", self.backend)
        except ValueError as exc:
            checks.append((False, str(exc)))
        for ok, message in checks:
            if not ok:
                raise ValueError(f"search settings: {message}")

    @property
    def rotations(self) -> int:
        """Rotations the scan evaluates."""
        return level_size(self.level)

    @property
    def angle(self) -> float:
        """The scan grid's nominal spacing in degrees."""
        return level_angle(self.level)

    def scan_lattice(self) -> int:
        """Translation samples per axis of the scan (even, above twice the widest mode)."""
        if self.lattice is not None:
            return self.lattice
        return max(2 * (self.scan_modes // 2) + 2, _even_at_least(2 * self.scan_modes))


def _even_at_least(value: int) -> int:
    """The smallest even number not below ``value``."""
    return value + (value % 2)
