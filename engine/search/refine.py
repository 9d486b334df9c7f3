"""Refining a cluster's best pose: down the rotation grid, then a local minimisation.

Works on a :class:`~engine.correlation.Correlator` (the refinement's modes, torque on) and
one pose of part 2 ((3, 3) float64 rotation, (3,) translation). :func:`descend` compares the
pose's grid rotation with its eight children one level finer by their landscapes (the
translations near the pose only), keeps the best, and repeats; :func:`minimise` then follows
the energy's gradient (the force and the torque, per pose) with L-BFGS to the local minimum,
turning part 2 about its grid centre.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from engine.correlation import Correlator, Spectra
from engine.correlation.landscape import compute_landscape
from engine.errors import Cancelled
from engine.pose import rotation_matrix
from engine.search.rotations import RotationGrid, children


@dataclass(frozen=True)
class Refined:
    """A pose after refinement.

    Attributes
    ----------
    rotation : (3, 3) float64
    translation : (3,) float64
    energy : float
        At the refinement's modes, per pose.
    level, index : int
        The grid rotation the descent ended at.
    evaluations : int
        Per-pose evaluations the minimisation spent.
    """

    rotation: np.ndarray
    translation: np.ndarray
    energy: float
    level: int
    index: int
    evaluations: int


#: landscapes(rotations (B, 3, 3)) -> (energy (B, M, M, M), translation axes (B, 3, M)).
Landscapes = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def cpu_landscapes(spectra: Spectra, modes: int, lattice: int) -> Landscapes:
    """:data:`Landscapes` by :func:`~engine.correlation.landscape.compute_landscape`."""
    def run(rotations: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lands = [compute_landscape(spectra, r, modes, forces=False, lattice=lattice,
                                   real=True) for r in rotations]
        return (np.stack([land.energy for land in lands]),
                np.stack([np.stack(land.translations) for land in lands]))
    return run


def descend(spectra: Spectra, modes: int, grid: RotationGrid, level: int, index: int,
            translation: np.ndarray, *, levels: int, lattice: int, reach: float,
            cancel: Callable[[], bool] | None = None,
            landscapes: Landscapes | None = None) -> tuple[int, int, np.ndarray, float]:
    """Follow the best child down ``levels`` levels of the grid.

    At each level the current rotation and its eight children are compared by the lowest
    landscape energy within ``reach`` of the current translation (``lattice`` samples per
    axis, ``modes`` per axis of ``spectra``: the scan's trilinear ones suffice to choose a
    rotation); the best becomes current. ``landscapes`` computes them (default
    :func:`cpu_landscapes`; the OpenCL scan's on a GPU), the eight children at once.

    Returns
    -------
    level, index : int
        The grid rotation reached.
    translation : (3,) float64
    energy : float
        Its landscape energy.
    """
    here = (int(level), int(index), np.asarray(translation, dtype=np.float64))
    compute = landscapes or cpu_landscapes(spectra, modes, lattice)

    def measure(lev: int, indices: np.ndarray, t: np.ndarray) -> list[tuple[float, np.ndarray]]:
        if cancel is not None and cancel():
            raise Cancelled("the search was cancelled")
        energies, all_axes = compute(grid.matrices(lev, np.asarray(indices, np.int64)))
        found = []
        for energy, axes in zip(energies, all_axes, strict=True):
            near = [np.abs(axes[a] - t[a]) <= reach for a in range(3)]
            window = energy[np.ix_(*near)]
            if window.size == 0:
                found.append((np.inf, t))
                continue
            k = np.unravel_index(int(np.argmin(window)), window.shape)
            found.append((float(window[k]),
                          np.array([axes[a][near[a]][k[a]] for a in range(3)])))
        return found

    best, t_best = measure(here[0], np.array([here[1]]), here[2])[0]
    here = (here[0], here[1], t_best)
    for _ in range(levels):
        lev, idx, t = here
        step = None
        kids = np.asarray(children(lev, idx), dtype=np.int64)
        for child, (energy, t_child) in zip(kids, measure(lev + 1, kids, t), strict=True):
            if energy < best:
                best, step = energy, (lev + 1, int(child), t_child)
        if step is None:
            break  # no child beats the rotation it came from: the minimisation goes on
        here = step
    return here[0], here[1], here[2], best


def minimise(correlator: Correlator, rotation: np.ndarray, translation: np.ndarray, *,
             length: float, rounds: int = 3,
             iterations: int = 40) -> tuple[np.ndarray, np.ndarray, float, int]:
    """Local minimum of the per-pose energy from ``(rotation, translation)``.

    The variables are a translation ``s`` and a turn ``phi`` about part 2's grid centre,
    scaled by ``length`` (``length * phi``: a turn that moves a point at ``length`` by as
    much as ``s`` moves it, so both kinds weigh alike); the gradient is minus the force and
    minus the torque about that centre over ``length``. Each round restarts about the pose
    reached (the torque is the derivative at no turn).

    Returns
    -------
    rotation (3, 3), translation (3,), energy, evaluations
    """
    rot = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    centre_moving = correlator.centre_moving
    count = 0
    energy = float(correlator.evaluate(rot, t).energy)
    for _ in range(rounds):
        pivot = rot @ centre_moving + t

        def pose(x: np.ndarray, rot0: np.ndarray = rot, t0: np.ndarray = t,
                 pivot: np.ndarray = pivot) -> tuple[np.ndarray, np.ndarray]:
            turn = rotation_matrix(x[3:] / length)
            return turn @ rot0, turn @ (t0 - pivot) + pivot + x[:3]

        def objective(x: np.ndarray, pivot: np.ndarray = pivot) -> tuple[float, np.ndarray]:
            nonlocal count
            count += 1
            r, tt = pose(x)
            ev = correlator.evaluate(r, tt)
            torque = ev.torque if ev.torque is not None else np.zeros(3)
            about = torque + np.cross(tt - pivot, ev.force)  # the torque about the pivot
            return float(ev.energy), np.concatenate([-ev.force, -about / length])

        result = minimize(objective, np.zeros(6), jac=True, method="L-BFGS-B",
                          options={"maxiter": iterations})
        if float(result.fun) >= energy - 1e-9 * abs(energy):
            break
        rot, t = pose(result.x)
        energy = float(result.fun)
    return rot, t, energy, count
