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


# ------------------------------------------------------------------ the motions the parts allow

#: Part 2's surface samples the motion test moves.
MOTION_SAMPLES = 3000

#: The turns of the motion test (radians each way): a faceted bore's facets, a key or a
#: spline's teeth all stop a turn this large, while a round fit's lets it through.
MOTION_ANGLE = 0.5

#: A motion is stopped when it drives part 2's surface deeper into part 1 than at the fit
#: by more than this fraction of how far the motion moves the fit's surface.
STOP_FRACTION = 0.05


@dataclass(frozen=True)
class Surfaces:
    """The parts' surfaces for :func:`motion_joint`.

    Attributes
    ----------
    fixed_vertices : (n, 3) float64, fixed_faces : (m, 3) int64
        Part 1's mesh (its frame).
    points, normals : (k, 3) float64
        Samples of part 2's surface and their outward unit normals, part 2's frame.
    """

    fixed_vertices: np.ndarray
    fixed_faces: np.ndarray
    points: np.ndarray
    normals: np.ndarray

    @classmethod
    def of(cls, fixed_vertices: np.ndarray, fixed_faces: np.ndarray,
           moving_vertices: np.ndarray, moving_faces: np.ndarray,
           count: int = MOTION_SAMPLES) -> Surfaces:
        """Part 1's mesh and ``count`` area-uniform samples of part 2's (the same per mesh)."""
        from engine.correlation.walls import surface_samples

        points, normals = surface_samples(moving_vertices, moving_faces, count, 0)
        return cls(np.asarray(fixed_vertices, np.float64), np.asarray(fixed_faces, np.int64),
                   points, normals)


def motion_joint(surfaces: Surfaces, rotation: np.ndarray, translation: np.ndarray, *,
                 length: float, axes: np.ndarray | None = None, reach: float = REACH,
                 angle: float = MOTION_ANGLE, stop: float = STOP_FRACTION) -> Joint | None:
    """The joint at a fit from the motions the parts allow, or None where they do not meet.

    Where part 2 touches part 1 (its samples within a few times the fit's median gap of
    part 1's surface), the contact's normals give the candidate directions: the eigenvectors
    of their scatter matrix (a round bore's axis is the one its normals leave out, a flat
    seat's normal the one they share), with ``axes`` added (say the stiffness's principal
    slides). Part 2 is then slid ``reach * length`` each way along each, and turned
    ``angle`` each way about each through the contact's centre; a motion is free when in
    both directions no sample of part 2 goes deeper into part 1 than at the fit by more than
    ``stop`` of how far the motion carries the contact. The free slides and turns are
    reduced to their span (two slides in a plane are one plane, whatever the candidates),
    and the kind follows as in :func:`find_joint`. The confidence is how far the stopped
    motions' depths and the free ones' lie from the threshold (log scale, as there).

    The result's ``stiffness`` holds zeros (the search puts the energy's there) and its
    ``rises`` the ratios of extra depth to the threshold of the first three candidates'
    slides, then their turns (over 1: stopped).
    """
    from engine.descriptor.compute import signed_distance

    rot = np.asarray(rotation, np.float64)
    t = np.asarray(translation, np.float64)
    placed = surfaces.points @ rot.T + t
    normals = surfaces.normals @ rot.T
    d0 = signed_distance(surfaces.fixed_vertices, surfaces.fixed_faces, placed)
    gap = np.abs(d0)
    reach_gap = 0.1 * length
    near = gap < reach_gap
    if near.sum() < 8:
        return None
    median = float(np.median(gap[near]))
    contact = near & (gap <= max(4.0 * median, 1e-6 * length))
    if contact.sum() < 8:
        contact = near
    centre = placed[contact].mean(axis=0)
    n = normals[contact]
    _, vectors = np.linalg.eigh(n.T @ n / len(n))
    candidates = [vectors[:, i] for i in range(3)]
    for extra in (np.zeros((0, 3)) if axes is None else np.asarray(axes, np.float64)):
        if all(abs(float(extra @ c)) < math.cos(math.radians(PARALLEL_DEGREES)) for c in
               candidates):
            candidates.append(extra / np.linalg.norm(extra))
    depth0 = float(max(0.0, -d0.min()))
    arm = float(np.sqrt(np.mean(np.sum((placed[contact] - centre) ** 2, axis=1))))
    moved, carries = [], []
    for a in candidates:
        for sign in (1.0, -1.0):
            moved.append(placed + sign * reach * length * a)
        carries.append(reach * length)
    for a in candidates:
        for sign in (1.0, -1.0):
            turn = rotation_matrix(sign * angle * a)
            moved.append((placed - centre) @ turn.T + centre)
        # how far the turn carries the contact: its points' mean distance from the axis
        off = placed[contact] - centre
        across = off - np.outer(off @ a, a)
        carries.append(angle * max(float(np.sqrt(np.mean(np.sum(across ** 2, axis=1)))),
                                   1e-3 * arm, 1e-9))
    d = signed_distance(surfaces.fixed_vertices, surfaces.fixed_faces, np.concatenate(moved))
    depth = np.maximum(0.0, -d.reshape(len(moved), -1).min(axis=1)) - depth0
    k = len(candidates)
    both = np.maximum(depth[0::2], depth[1::2])  # a free motion is free both ways
    ratio = both / (stop * np.array(carries))
    free = ratio < 1.0
    free_slides = _span([candidates[i] for i in range(k) if free[i]])
    free_axes = _span([candidates[i] for i in range(k) if free[k + i]])
    turns = tuple((a, centre - a * float(a @ centre)) for a in free_axes)
    scale = math.log(1.0 / stop)
    margins = [1.0 if r <= 0 else min(1.0, abs(math.log(r)) / scale) for r in ratio]
    return Joint(kind=_kind(free_slides, list(free_axes)), slides=free_slides, turns=turns,
                 confidence=float(min(margins)), stiffness=np.zeros((6, 6)),
                 rises=np.asarray(ratio[:3].tolist() + ratio[k:k + 3].tolist()))


def _span(directions: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """An orthonormal basis of the directions' span (canonical signs)."""
    if not directions:
        return ()
    _, s, vt = np.linalg.svd(np.stack(directions), full_matrices=False)
    rank = int(np.sum(s > 0.5 * s[0]))
    return tuple(_canonical(vt[i]) for i in range(rank))


def axis_names(joint: Joint) -> tuple[tuple[str, ...], tuple[np.ndarray, ...]]:
    """The joint's free directions as names of part 1's axes (x, y, z, rx, ry, rz).

    Returns the names of the free slides and turns that lie within
    :data:`PARALLEL_DEGREES` of an axis, and the unit directions of those that do not
    (slides first), which no name describes.
    """
    parallel = math.cos(math.radians(PARALLEL_DEGREES))
    names: list[str] = []
    others: list[np.ndarray] = []
    for prefix, directions in (("", joint.slides), ("r", [a for a, _ in joint.turns])):
        for d in directions:
            i = int(np.argmax(np.abs(d)))
            if abs(float(d[i])) >= parallel:
                names.append(prefix + "xyz"[i])
            else:
                others.append(np.asarray(d, np.float64))
    order = ("x", "y", "z", "rx", "ry", "rz")
    return tuple(sorted(set(names), key=order.index)), tuple(others)
