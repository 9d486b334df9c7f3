"""The search for where part 2 fits on part 1: scan, cluster, refine, classify.

Works on a :class:`~engine.correlation.Correlator` of the pair (part 1 fixed, part 2
moving; its spectra are read, never changed) and :class:`SearchSettings`. Stages, coarse to
fine:

1. scan: every rotation of the Hopf grid at ``settings.level``, one landscape each at
   ``scan_modes`` on a lattice of about ``2 scan_modes`` translations per axis, the
   ``per_rotation`` lowest separate minima kept (:mod:`engine.search.scan`), in blocks that
   run here or on Dask (:mod:`engine.search.work`);
2. the ``keep`` lowest candidates, clustered by where they put part 2's surface
   (:mod:`engine.search.cluster`), ranked by their best energy;
3. each of the best ``clusters`` clusters' leader refined: down the rotation grid's
   children at the refinement's modes, then a local minimisation by force and torque
   (:mod:`engine.search.refine`); refined fits that meet merge;
4. with the parts' meshes, each fit moved out of part 1's walls by the least rigid motion
   and the fits ranked again by how the parts meet there: touching first, then not
   through a wall, then by energy (:mod:`engine.search.rescore`);
5. the joint kind of each fit (:mod:`engine.search.joint`).

The same settings and seed give the same fits, wherever the blocks run.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from engine.correlation import Correlator, Spectra
from engine.errors import Cancelled
from engine.pose import rotation_vector
from engine.search.cluster import cluster_poses, surface_spread
from engine.search.joint import Joint, Surfaces, find_joint, motion_joint
from engine.search.opencl_scan import scan_for, supports
from engine.search.refine import Landscapes, descend, minimise
from engine.search.rescore import Contact, contact, polish, rerank
from engine.search.rotations import RotationGrid
from engine.search.scan import BlockResult, Candidates, ScanBlock
from engine.search.settings import SearchSettings
from engine.search.work import BlockWork, Shared

#: progress(fraction done, seconds left (None until it can be estimated)).
Progress = Callable[[float, float | None], None]

#: Share of the whole the scan stands for in the progress fraction.
SCAN_SHARE = 0.85


@dataclass(frozen=True)
class Fit:
    """One fit found, part 2 in part 1's frame.

    Attributes
    ----------
    rank : int
        1 for the best: the lowest energy, or where the search had the parts' meshes the
        lowest of the fits that touch without going through a wall.
    rotation : (3, 3) float64
    translation : (3,) float64
    energy : float
        Per pose at the refinement's modes.
    scan_energy : float
        The cluster leader's energy in the scan.
    cluster_size : int
        Scan candidates in its cluster (clusters that refined to this fit added).
    joint : Joint
    seconds : float
        Time its refinement and classification took.
    contact : Contact or None
        How the parts meet there, on the meshes (:mod:`engine.search.rescore`); None where
        the search had no surfaces (then the rank is the energy's alone).
    """

    rank: int
    rotation: np.ndarray
    translation: np.ndarray
    energy: float
    scan_energy: float
    cluster_size: int
    joint: Joint
    seconds: float
    contact: Contact | None = None

    @property
    def pose(self) -> np.ndarray:
        """(6,) float64 ``(tx, ty, tz, rx, ry, rz)``."""
        return np.concatenate([self.translation, rotation_vector(self.rotation)])


@dataclass(frozen=True)
class SearchResult:
    """The ranked fits and what the search did to find them.

    Attributes
    ----------
    fits : tuple of Fit
    settings : SearchSettings
    modes : int
        The refinement's modes.
    lattice : int
        The scan's translation samples per axis; ``step`` their spacing (scene unit).
    step : float
    candidates, clusters : int
        Candidates kept from the scan; clusters they formed.
    scan_seconds, seconds : float
        The scan's time and the whole search's.
    scan_backend : str
        Where the scan ran: "numpy" or "opencl" (:func:`scan_backend`).
    """

    fits: tuple[Fit, ...]
    settings: SearchSettings
    modes: int
    lattice: int
    step: float
    candidates: int
    clusters: int
    scan_seconds: float
    seconds: float
    scan_backend: str = "numpy"

    @property
    def seconds_per_rotation(self) -> float:
        """The scan's time per rotation."""
        return self.scan_seconds / max(1, self.settings.rotations)


def default_points(correlator: Correlator) -> np.ndarray:
    """(9, 3) part 2's grid box corners and centre, its frame (no symmetry seen by them)."""
    c, half = correlator.centre_moving, correlator.half_moving
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return np.vstack([c + signs * half, c])


def find_fits(correlator: Correlator, settings: SearchSettings | None = None, *,
              points: np.ndarray | None = None, scan: Spectra | None = None,
              work: BlockWork | None = None, surfaces: Surfaces | None = None,
              progress: Progress | None = None,
              cancel: Callable[[], bool] | None = None) -> SearchResult:
    """The ``settings.top`` lowest-energy fits of part 2 on part 1 (see the module docstring).

    Parameters
    ----------
    correlator : Correlator
        The pair; its modes are the refinement's unless ``settings.modes`` says otherwise.
    settings : SearchSettings, optional
    points : (n, 3) float64, optional
        Points of part 2's surface in its own frame, for clustering alike poses (its
        symmetries); default: its grid box's corners (no symmetry).
    scan : Spectra, optional
        The pair's spectra for the scan and the descent through the grid's children
        (default: the correlator's). Spectra made without the torque
        (``Correlator(..., rotation=False)``) interpolate trilinearly: about 7 times faster
        per rotation than the torque's cubic Hermite interpolant, the energy within about
        1 % (the minimisation and the joints use the correlator, per pose).
    work : BlockWork, optional
        Where the scan's blocks run (:class:`~engine.search.distributed.DaskWork`);
        default: here, in order.
    surfaces : Surfaces, optional
        The parts' surfaces: each fit's joint is then the one the parts' motions allow
        (:func:`~engine.search.joint.motion_joint`), the energy's (:func:`find_joint`)
        where they do not meet; without them, the energy's.
    progress : callable(fraction, seconds_left), optional
    cancel : callable() -> bool, optional
        Raises :class:`engine.errors.Cancelled` once it returns True.
    """
    s = settings or SearchSettings()
    start = time.perf_counter()
    fine = correlator if s.modes is None else correlator.with_modes(s.modes)
    pts = default_points(correlator) if points is None else np.asarray(points, float)
    size = surface_spread(pts)
    grid = RotationGrid.from_seed(s.seed)

    def report(fraction: float) -> None:
        if cancel is not None and cancel():
            raise Cancelled("the search was cancelled")
        if progress is not None:
            spent = time.perf_counter() - start
            left = spent * (1.0 - fraction) / fraction if fraction > 0.02 else None
            progress(min(1.0, fraction), left)

    report(0.0)
    lattice = s.scan_lattice()
    scan_spectra = correlator.spectra if scan is None else scan
    found, backend = _scan(scan_spectra, grid, s, lattice, work,
                           lambda f: report(SCAN_SHARE * f), cancel)
    scan_seconds = time.perf_counter() - start
    kept = found.best(s.keep)
    rotations = grid.matrices(s.level, kept.rotation_index)
    groups = cluster_poses(rotations, kept.translation, kept.energy, pts,
                           s.cluster_radius * size)
    fits: list[tuple[float, np.ndarray, np.ndarray, float, int, float]] = []
    count = min(len(groups.leaders), max(s.clusters, s.top))
    for i in range(count):
        began = time.perf_counter()
        row = int(groups.leaders[i])
        lev, idx, t, _ = descend(
            scan_spectra, fine.modes, grid, s.level, int(kept.rotation_index[row]),
            kept.translation[row],
            levels=s.refine_levels, lattice=_even_above(2 * fine.modes),
            reach=s.cluster_radius * size, cancel=cancel,
            landscapes=_descent_landscapes(scan_spectra, fine.modes, backend))
        rot, t, energy, _ = minimise(fine, grid.matrix(lev, idx), t, length=0.5 * size)
        fits.append((energy, rot, t, float(kept.energy[row]), len(groups.members[i]),
                     time.perf_counter() - began))
        report(SCAN_SHARE + (0.97 - SCAN_SHARE) * (i + 1) / count)
    merged = _merge(fits, pts, s.cluster_radius * size)
    contacts: list[Contact | None] = [None] * len(merged)
    if surfaces is not None:  # out of the walls, then ranked again by how the parts meet
        merged = [_polished(fine, surfaces, f, size) for f in merged]
        measured = [contact(surfaces, f[1], f[2], size) for f in merged]
        order = rerank(measured, [f[0] for f in merged])
        merged, contacts = [merged[i] for i in order], [measured[i] for i in order]
    out = []
    for rank, (energy, rot, t, scan_energy, members, seconds) in enumerate(merged[:s.top],
                                                                           start=1):
        began = time.perf_counter()
        joint = _joint(fine, rot, t, 0.5 * size, surfaces)
        out.append(Fit(rank, rot, t, energy, scan_energy, members, joint,
                       seconds + time.perf_counter() - began, contacts[rank - 1]))
    report(1.0)
    return SearchResult(
        fits=tuple(out), settings=s, modes=fine.modes, lattice=lattice,
        step=fine.size * fine.spacing / lattice, candidates=len(kept),
        clusters=len(groups.leaders), scan_seconds=scan_seconds,
        seconds=time.perf_counter() - start, scan_backend=backend)


def _polished(fine: Correlator, surfaces: Surfaces,
              fit: tuple[float, np.ndarray, np.ndarray, float, int, float], size: float
              ) -> tuple[float, np.ndarray, np.ndarray, float, int, float]:
    """A refined fit moved out of part 1's walls (:func:`polish`), its energy there."""
    began = time.perf_counter()
    energy, rot, t, scan_energy, members, seconds = fit
    new_rot, new_t = polish(surfaces, rot, t, size)
    if not (np.array_equal(new_rot, rot) and np.array_equal(new_t, t)):
        energy = float(fine.evaluate(new_rot, new_t).energy)
    return (energy, new_rot, new_t, scan_energy, members,
            seconds + time.perf_counter() - began)


def _even_above(value: int) -> int:
    return value + 2 - value % 2


def _descent_landscapes(spectra: Spectra, modes: int, backend: str) -> Landscapes | None:
    """The descent's landscapes on the scan's OpenCL device, where that is a GPU.

    On a CPU device (PoCL) nine landscapes at the refinement's modes cost about twice
    scipy's transforms (2.3 against 1.1 s for the bundled peg's eight clusters), so the
    descent stays there.
    """
    lattice = _even_above(2 * modes)
    if backend != "opencl" or supports(spectra, modes, lattice, 1) is not None:
        return None  # the CPU's
    from engine.backend import get_backend

    device = get_backend("opencl")
    if not device.is_gpu:
        return None
    return scan_for(spectra, modes, lattice, device).landscapes_and_axes


def _joint(fine: Correlator, rot: np.ndarray, t: np.ndarray, length: float,
           surfaces: Surfaces | None = None) -> Joint:
    def gradient(r: np.ndarray, tt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ev = fine.evaluate(r, tt)
        return ev.force, (ev.torque if ev.torque is not None else np.zeros(3))

    def energy(r: np.ndarray, tt: np.ndarray) -> float:
        return float(fine.evaluate(r, tt).energy)

    by_energy = find_joint(energy, gradient, rot, t, fine.centre_moving, step=fine.spacing,
                           length=length)
    moved = None if surfaces is None else motion_joint(surfaces, rot, t, length=length)
    # the energy's stiffness stays with the joint either way
    return by_energy if moved is None else replace(moved, stiffness=by_energy.stiffness)


def _merge(fits: list[tuple[float, np.ndarray, np.ndarray, float, int, float]],
           points: np.ndarray, radius: float
           ) -> list[tuple[float, np.ndarray, np.ndarray, float, int, float]]:
    """Refined fits that ended alike, as one (the lowest; cluster sizes added)."""
    if not fits:
        return []
    groups = cluster_poses(np.stack([f[1] for f in fits]), np.stack([f[2] for f in fits]),
                           np.array([f[0] for f in fits]), points, radius)
    merged = []
    for leader, members in zip(groups.leaders, groups.members, strict=True):
        best = fits[int(leader)]
        merged.append(best[:4] + (sum(fits[int(m)][4] for m in members),
                                  sum(fits[int(m)][5] for m in members)))
    return merged


def scan_backend(spectra: Spectra, s: SearchSettings, lattice: int) -> str:
    """The backend the scan's blocks run on: ``s.backend``, "auto" resolved here.

    "auto" takes OpenCL on a GPU where the scan's kernels build and these settings suit
    them (:func:`engine.search.opencl_scan.supports`), else numpy. A named "opencl" that
    cannot scan these spectra raises ValueError with the reason.
    """
    from engine.backend import resolve
    from engine.search.opencl_scan import builds, supports

    problem = supports(spectra, s.scan_modes, lattice, s.per_rotation)
    if s.backend == "opencl" and problem is not None:
        raise ValueError(f"search on opencl: {problem}")
    chosen = resolve("scan", s.backend,
                     usable=lambda made: problem is None and builds(made))
    return chosen.name


def _scan(spectra: Spectra, grid: RotationGrid, s: SearchSettings, lattice: int,
          work: BlockWork | None, report: Callable[[float], None],
          cancel: Callable[[], bool] | None) -> tuple[Candidates, str]:
    """The scan's candidates and the backend they ran on.

    Block after block, joined in block order wherever they ran.
    """
    total = s.rotations
    indices = np.arange(total, dtype=np.int64)
    shared: Shared = Shared("spectra", spectra) if work is None else work.share(spectra)
    backend = scan_backend(spectra, s, lattice)
    blocks = [ScanBlock(shared, grid, s.level, indices[i:i + s.chunk], s.scan_modes, lattice,
                        s.per_rotation, number=n, backend=backend)
              for n, i in enumerate(range(0, total, s.chunk))]
    results: dict[int, BlockResult] = {}
    done = 0
    if work is None:
        for block in blocks:
            result = block(cancel)
            results[result.number] = result
            done += result.rotations
            report(done / total)
    else:
        kinds = [f"search block {b.number}" for b in blocks]
        for kind, block in zip(kinds, blocks, strict=True):
            work.submit(kind, block)
        try:
            while len(results) < len(blocks):
                work.wait_until_idle(0.2)
                for result in work.responses():
                    results[result.number] = result
                    done += result.rotations
                report(done / total)
        except BaseException:
            for kind in kinds:
                work.cancel(kind)
            raise
    return Candidates.join([results[n].candidates for n in sorted(results)]), backend
