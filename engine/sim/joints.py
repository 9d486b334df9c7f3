"""Which axes a fit leaves free, measured from the energy around the seat.

A peg in a through hole can slide along and turn about its axis: a cylindrical joint. The
energy tells which degrees of freedom a fit constrains without being told: along a
constrained axis, moving either way out of the seat costs energy (a wall, a floor, a key);
along a free one it does not, or only by as much as the descriptor's faceting and the
attraction that draws the part on along a through hole.

:func:`find_free_axes` moves part 2 out of the pose by one step each way along each of the
six axes of part 1's frame (translations by ``step``, rotations about part 2's centre by the
angle that moves its farthest point by ``step``) and takes, per axis, the second difference
``E(+h) + E(-h) - 2 E(0)``: the energy's curvature, which a wall on either side raises (a
one-sided stop, such as the floor of a blind bore, counts: one way is blocked) and a steady
slope does not (along a through hole the energy keeps falling as the peg slides on: the
larger one-sided rise there is the largest of all, the curvature about zero). Curvatures
are compared within their kind (translations with translations, rotations with rotations; a
floor makes the axial one of a seated peg far larger than any tilt's, so one scale for both
would call the tilts free): an axis whose curvature is below ``threshold`` times the largest
of its kind is free. A kind whose largest curvature is not positive, or negligible (under
:data:`NEGLIGIBLE` of the other kind's), is free as a whole: no wall anywhere.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from engine.params import AXES
from engine.pose import compose, rotate_about, rotation_matrix

#: An axis is free when the energy's curvature along it is under this fraction of the largest
#: curvature among the axes of its kind.
FREE_THRESHOLD = 0.05

#: A kind of axes whose largest curvature is under this fraction of the other kind's is free.
NEGLIGIBLE = 1e-6

Energy = Callable[[np.ndarray, np.ndarray], float]


@dataclass(frozen=True)
class FreeAxes:
    """The measured freedom of a fit (see the module docstring).

    Attributes
    ----------
    free : tuple of str
        Names from :data:`engine.params.AXES` of the axes found free, part 1's frame.
    curvature : dict of str to float
        ``E(+h) + E(-h) - 2 E(0)`` per axis (scaled as the energy function).
    step, angle : float
        The translation step (scene unit) and the rotation step (radians).
    """

    free: tuple[str, ...]
    curvature: dict[str, float]
    step: float
    angle: float


def find_free_axes(energy: Energy, pose: np.ndarray, centre: np.ndarray, size: float,
                   step: float, *, threshold: float = FREE_THRESHOLD) -> FreeAxes:
    """Measure which axes leave the energy flat at ``pose``.

    Parameters
    ----------
    energy : callable(rotation (3, 3), translation (3,)) -> float
        The energy of part 2 at a pose relative to part 1 (e.g. a Correlator's
        ``evaluate(...).energy``).
    pose : (6,) array_like
        Part 2 in part 1's frame (usually the assembled pose).
    centre : (3,) array_like
        Part 2's centre in its own frame; rotations turn about it.
    size : float
        Part 2's bounding-box diagonal: the rotation step moves a point at half of it by
        ``step``.
    step : float
        Translation step (a descriptor cell is the natural choice: finer steps see only the
        interpolation of the sampled field).
    threshold : float
        See :data:`FREE_THRESHOLD`.

    Returns
    -------
    FreeAxes
    """
    p = np.asarray(pose, dtype=np.float64).reshape(6)
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    angle = float(step) / max(0.5 * float(size), 1e-12)
    centre_world = compose(p, np.r_[c, 0.0, 0.0, 0.0])[:3]

    def at(q: np.ndarray) -> float:
        return float(energy(rotation_matrix(q[3:]), q[:3]))

    e0 = at(p)
    curvature: dict[str, float] = {}
    for i, name in enumerate(AXES):
        ups = []
        for sign in (1.0, -1.0):
            if i < 3:
                q = p.copy()
                q[i] += sign * step
            else:
                rotvec = np.zeros(3)
                rotvec[i - 3] = sign * angle
                q = rotate_about(p, rotvec, centre_world)
            ups.append(at(q) - e0)
        curvature[name] = ups[0] + ups[1]
    overall = max(curvature.values())
    free: list[str] = []
    for kind in (AXES[:3], AXES[3:]):
        top = max(curvature[a] for a in kind)
        if top <= NEGLIGIBLE * overall or top <= 0:
            free += kind
        else:
            free += [a for a in kind if curvature[a] < threshold * top]
    return FreeAxes(free=tuple(free), curvature=curvature, step=float(step), angle=angle)
