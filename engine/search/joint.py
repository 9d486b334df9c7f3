"""What kind of joint a fit is, from the energy's second derivatives and the energy around it.

Works on a fitted pose of part 2 ((3, 3) float64 rotation, (3,) translation, part 1's
frame), the energy there and its gradient (a Correlator's energy, force and torque).

1. The 6 x 6 matrix of second derivatives (the stiffness) by central differences of the
   force and the torque, in the variables ``(s, L phi)``: a translation ``s`` and a turn
   ``phi`` about part 2's grid centre, scaled by ``L`` (half part 2's size) so that both
   move part 2's far points alike.
2. Its principal motions: the eigenvectors of the translational block (slides), and of the
   rotational block with the translations relaxed (its Schur complement: a turn about an
   axis that misses the centre is a turn and a slide together; the slide that goes with a
   free turn places its axis).
3. A probe along each: the mean energy rise of a slide of ``REACH L`` and of a turn of
   ``ANGLE`` each way. A motion whose rise is under :data:`FREE_FRACTION` of the largest
   rise of its kind is free. The curvature alone does not tell: a faceted round peg's turn
   about its axis has a tenth of a tilt's curvature at the seat, but the energy it meets
   levels off within a few degrees (the facets) while a tilt's keeps growing (about 150
   against 7,400 at 30 degrees on the bundled peg).
4. The kind: nothing free rigid; one turn revolute; one slide prismatic; a slide along a
   turn's axis cylindrical; two slides and a turn about their normal planar; else other.

Rises are compared within their kind, as :mod:`engine.sim.joints` does: a blind bore's floor
is far stiffer than its walls, and one scale for both would call the walls free. The
confidence is how far the ratios lie from the threshold, on a log scale: 1 when every one
differs from it by the threshold's own factor or more, 0 when one sits on it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from engine.pose import rotation_matrix

#: A direction is free when its probe's energy rise is under this fraction of the largest
#: rise of its kind.
FREE_FRACTION = 0.1

#: The slide probes move part 2 by this fraction of ``L`` each way.
REACH = 0.25

#: The turn probes turn part 2 by this angle (radians) each way.
ANGLE = 1.0

#: Two directions count as parallel within this angle (degrees).
PARALLEL_DEGREES = 25.0

KINDS = ("rigid", "revolute", "prismatic", "cylindrical", "planar", "other")

#: The energy at a pose (rotation (3, 3), translation (3,)).
Energy = Callable[[np.ndarray, np.ndarray], float]

#: (force (3,), torque about part 2's origin (3,)) at a pose (rotation, translation).
Gradient = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Joint:
    """The joint a fit leaves (see the module docstring).

    Attributes
    ----------
    kind : str
        One of :data:`KINDS`.
    slides : tuple of (3,) float64
        Unit directions of the free translations (part 1's frame).
    turns : tuple of ((3,) float64, (3,) float64)
        Free rotations: a unit axis and a point on it (part 1's frame).
    confidence : float
        0 to 1.
    stiffness : (6, 6) float64
        The energy's second derivatives in ``(s, L phi)`` (energy per length squared).
    rises : (6,) float64
        The probes' mean energy rise along the three principal slides, then the three
        principal turns.
    """

    kind: str
    slides: tuple[np.ndarray, ...]
    turns: tuple[tuple[np.ndarray, np.ndarray], ...]
    confidence: float
    stiffness: np.ndarray
    rises: np.ndarray


def stiffness(gradient: Gradient, rotation: np.ndarray, translation: np.ndarray,
              centre: np.ndarray, *, step: float, length: float) -> np.ndarray:
    """(6, 6) float64 second derivatives of the energy in ``(s, L phi)`` at the pose.

    Parameters
    ----------
    gradient : callable
        Force and torque (about part 2's origin) at a pose.
    rotation : (3, 3), translation : (3,)
        The pose.
    centre : (3,)
        Part 2's centre in its own frame (the turns' pivot).
    step : float
        The difference step in ``s`` and ``L phi`` (a descriptor cell suits: finer steps see
        only the interpolation of the sampled field).
    length : float
        ``L``.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    pivot = rot @ np.asarray(centre, dtype=np.float64) + t
    columns = []
    for j in range(6):
        sides = []
        for sign in (1.0, -1.0):
            x = np.zeros(6)
            x[j] = sign * step
            turn = rotation_matrix(x[3:] / length)
            r, tt = turn @ rot, turn @ (t - pivot) + pivot + x[:3]
            force, torque = gradient(r, tt)
            about = torque + np.cross(tt - (pivot + x[:3]), force)
            sides.append(np.concatenate([-force, -about / length]))
        columns.append((sides[0] - sides[1]) / (2.0 * step))
    h = np.stack(columns, axis=1)
    return 0.5 * (h + h.T)


def _split(values: np.ndarray, fraction: float) -> tuple[np.ndarray, float]:
    """Which of ``values`` are free, and the margin of that call (0..1)."""
    top = float(values.max())
    if top <= 0.0:
        return np.ones(len(values), dtype=bool), 1.0
    ratio = values / top
    free = ratio < fraction
    scale = math.log(1.0 / fraction)
    margins = [1.0 if r <= 0 else min(1.0, abs(math.log(r / fraction)) / scale) for r in ratio]
    return free, float(min(margins))


def principal_motions(matrix: np.ndarray, pivot: np.ndarray, length: float
                      ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """The stiffness's principal slides and turns.

    Returns
    -------
    slides : (3, 3) float64
        Rows: unit eigenvectors of the translational block.
    turns : list of ((3,) axis, (3,) point)
        The eigenvectors of the rotational block with the translations relaxed (its Schur
        complement), each placed where the translation that goes with it puts its axis.
    """
    h = 0.5 * (matrix + matrix.T)
    htt, htr, hrr = h[:3, :3], h[:3, 3:], h[3:, 3:]
    t_values, t_vectors = np.linalg.eigh(htt)
    top = max(float(t_values.max()), 0.0)
    keep = t_values > 1e-3 * top if top > 0 else np.zeros(3, dtype=bool)
    inverse = (t_vectors[:, keep] / t_values[keep]) @ t_vectors[:, keep].T
    schur = hrr - htr.T @ inverse @ htr
    _, r_vectors = np.linalg.eigh(0.5 * (schur + schur.T))
    turns = []
    for i in range(3):
        axis = _canonical(r_vectors[:, i])
        # a turn phi = axis / L about the pivot with the slide s = shift that goes with it
        # is a turn about the point pivot + (phi x s) / |phi|^2
        shift = -inverse @ htr @ axis
        point = pivot + length * np.cross(axis, shift)
        # the axis's point nearest the pivot
        turns.append((axis, point - axis * float(axis @ (point - pivot))))
    return np.stack([_canonical(t_vectors[:, i]) for i in range(3)]), turns


def find_joint(energy: Energy, gradient: Gradient, rotation: np.ndarray,
               translation: np.ndarray, centre: np.ndarray, *, step: float, length: float,
               reach: float = REACH, angle: float = ANGLE,
               fraction: float = FREE_FRACTION) -> Joint:
    """The joint at a fit (see the module docstring).

    Parameters
    ----------
    energy : callable(rotation, translation) -> float
    gradient : callable(rotation, translation) -> (force, torque about part 2's origin)
    rotation : (3, 3), translation : (3,)
        The fit.
    centre : (3,)
        Part 2's centre in its own frame.
    step : float
        The stiffness's difference step (a descriptor cell).
    length : float
        ``L``: half part 2's size.
    reach, angle : float
        The probes' slide (a fraction of ``L``) and turn (radians).
    fraction : float
        See :data:`FREE_FRACTION`.
    """
    rot = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    pivot = rot @ np.asarray(centre, dtype=np.float64) + t
    matrix = stiffness(gradient, rot, t, centre, step=step, length=length)
    slides, turns = principal_motions(matrix, pivot, length)
    e0 = float(energy(rot, t))
    rises = []
    for v in slides:
        sides = [energy(rot, t + sign * reach * length * v) for sign in (1.0, -1.0)]
        rises.append(0.5 * (sides[0] + sides[1]) - e0)
    for axis, point in turns:
        sides = []
        for sign in (1.0, -1.0):
            turn = rotation_matrix(sign * angle * axis)
            sides.append(energy(turn @ rot, turn @ (t - point) + point))
        rises.append(0.5 * (sides[0] + sides[1]) - e0)
    rise = np.array(rises)
    t_free, t_margin = _split(rise[:3], fraction)
    r_free, r_margin = _split(rise[3:], fraction)
    free_slides = tuple(slides[i] for i in np.flatnonzero(t_free))
    free_turns = tuple(turns[i] for i in np.flatnonzero(r_free))
    return Joint(kind=_kind(free_slides, [a for a, _ in free_turns]), slides=free_slides,
                 turns=free_turns, confidence=min(t_margin, r_margin), stiffness=matrix,
                 rises=rise)


def _canonical(vector: np.ndarray) -> np.ndarray:
    """A unit vector with its largest component positive (eigenvectors have no sign)."""
    v = vector / np.linalg.norm(vector)
    return v if v[int(np.argmax(np.abs(v)))] > 0 else -v


def _kind(slides: tuple[np.ndarray, ...], axes: list[np.ndarray]) -> str:
    parallel = math.cos(math.radians(PARALLEL_DEGREES))
    ns, nr = len(slides), len(axes)
    if ns == 0 and nr == 0:
        return "rigid"
    if ns == 0 and nr == 1:
        return "revolute"
    if ns == 1 and nr == 0:
        return "prismatic"
    if ns == 1 and nr == 1 and abs(float(slides[0] @ axes[0])) >= parallel:
        return "cylindrical"
    if ns == 2 and nr == 1:
        normal = np.cross(slides[0], slides[1])
        if abs(float(normal @ axes[0])) >= parallel * np.linalg.norm(normal):
            return "planar"
    return "other"
