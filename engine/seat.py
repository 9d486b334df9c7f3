"""How far part 2 is from its seat, and whether it is seated.

A scene gives the assembled pose of part 2 in part 1's frame, and may say which axes the fit
leaves free (``free_axes``: a peg in a through hole may slide along and turn about its axis)
and how close counts as seated (``seat_tolerance``). :func:`seat_state` compares a pose with
the seat the way a person checks a fit:

- **distance**: how far part 2's centre is from where it sits when assembled, in part 1's
  frame, ignoring the components along free translation axes;
- **angle**: the angle of the rotation that takes the seated orientation to the current one,
  ignoring the twist about free rotation axes (swing-twist decomposition);
- **seated**: both within the tolerance, and the travel along free translation axes within
  half of part 2's size (a peg in a through hole is seated anywhere along the bore, but not
  above it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from engine.params import DEFAULT_SEAT_DISTANCE_FRACTION, SeatSpec
from engine.pose import (
    matrix_to_quaternion,
    quaternion_multiply,
    rotation_matrix,
)

#: Travel along a free translation axis that still counts as seated, as a fraction of part 2's
#: bounding-box diagonal.
FREE_TRAVEL_FRACTION = 0.5

_UNIT = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class SeatState:
    """Part 2's offset from its seat (see the module docstring).

    Attributes
    ----------
    distance : float
        Distance of part 2's centre from the seat along the locked axes (scene unit).
    angle_deg : float
        Angle from the seated orientation about the locked axes (degrees).
    offset : (3,) float64
        Part 2's centre minus its seated position, part 1's frame, free axes included.
    free_travel : float
        Distance along the free translation axes (0 when none is free).
    seated : bool
        Within ``distance_tolerance`` and ``angle_tolerance_deg``, free travel within
        :data:`FREE_TRAVEL_FRACTION` of part 2's size.
    distance_tolerance, angle_tolerance_deg : float
        The tolerances applied.
    free_axes : tuple of str or None
        The free axes used (None: the scene does not say; every axis then counts).
    """

    distance: float
    angle_deg: float
    offset: np.ndarray
    free_travel: float
    seated: bool
    distance_tolerance: float
    angle_tolerance_deg: float
    free_axes: tuple[str, ...] | None


def seat_state(pose: np.ndarray, assembled_pose: np.ndarray, centre: np.ndarray,
               spec: SeatSpec, size: float) -> SeatState:
    """Compare part 2's ``pose`` in part 1's frame with its ``assembled_pose``.

    Parameters
    ----------
    pose, assembled_pose : (6,) array_like
        Part 2 in part 1's frame now, and when assembled.
    centre : (3,) array_like
        Part 2's centre (e.g. its centre of mass) in its own frame.
    spec : SeatSpec
        The scene's free axes and tolerance.
    size : float
        Part 2's bounding-box diagonal (sets the default distance tolerance and the free
        travel allowed).

    Returns
    -------
    SeatState
    """
    pose = np.asarray(pose, dtype=np.float64).reshape(6)
    seat = np.asarray(assembled_pose, dtype=np.float64).reshape(6)
    c = np.asarray(centre, dtype=np.float64).reshape(3)
    r_now, r_seat = rotation_matrix(pose[3:]), rotation_matrix(seat[3:])
    offset = (r_now @ c + pose[:3]) - (r_seat @ c + seat[:3])
    free = spec.free_axes or ()
    locked = offset.copy()
    for axis in free:
        if axis in _UNIT:
            locked[_UNIT[axis]] = 0.0
    free_travel = float(np.linalg.norm(offset - locked))
    # rotation from the seated orientation to the current one, in part 1's frame
    q = matrix_to_quaternion(r_now @ r_seat.T)
    for axis in free:
        if axis.startswith("r"):
            q = _remove_twist(q, _UNIT[axis[1]])
    angle = math.degrees(2.0 * math.atan2(float(np.linalg.norm(q[1:])), abs(float(q[0]))))
    tolerance = (spec.distance if spec.distance is not None
                 else DEFAULT_SEAT_DISTANCE_FRACTION * float(size))
    distance = float(np.linalg.norm(locked))
    seated = (distance <= tolerance and angle <= spec.angle_deg
              and free_travel <= FREE_TRAVEL_FRACTION * float(size))
    return SeatState(distance=distance, angle_deg=angle, offset=offset, free_travel=free_travel,
                     seated=bool(seated), distance_tolerance=float(tolerance),
                     angle_tolerance_deg=spec.angle_deg, free_axes=spec.free_axes)


def _remove_twist(quat: np.ndarray, axis: int) -> np.ndarray:
    """The swing of unit quaternion ``quat`` once its twist about coordinate ``axis`` goes."""
    w, v = float(quat[0]), float(quat[1 + axis])
    norm = math.hypot(w, v)
    if norm < 1e-12:  # a half turn about an axis perpendicular to ``axis``: no twist
        return quat
    twist_inverse = np.zeros(4)
    twist_inverse[0] = w / norm
    twist_inverse[1 + axis] = -v / norm
    return quaternion_multiply(quat, twist_inverse)
