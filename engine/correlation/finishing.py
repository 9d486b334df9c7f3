"""The per-pose finishing: energy, force and torque from the raw modal sums.

Every per-pose path (the numpy reference, the numba kernels, the OpenCL kernel) sums the
same seven raw numbers over the kept modes and hands them to :func:`finish`; the box
overlap test that decides whether there is anything to sum is :func:`boxes_overlap`. So
the force and torque formulas, their signs and scales, are written once, here.

The raw sums, over kept integer frequency indices ``k`` (``w = k / (N h)``)::

    c = rho1c^(w) dw exp(2 pi i w.(t + R c2 - c1))     part 1's coefficient and the phase
    G = rho2c^(-R^T w)                                 part 2's spectrum, interpolated
    sums = [Re sum c G,                                 (the score f)
            Im sum c G k  (3),                          (S_k)
            sum Re(c dG/du) x R^T k  (3)]               (S_u, lattice derivatives)

and with ``a`` lattice steps per unit of frequency (:func:`torque_scale`), the moment
term ``S_m = (a / 2 pi) S_u`` is ``Im sum c M x R^T k`` with ``M`` the moment spectrum the
interpolant implies. Then (``n_h = N h``)::

    E = -kappa Re f
    F = -dE/dt     = -(2 pi kappa / n_h) S_k
    T = -dE/dtheta = -(2 pi kappa / n_h) R (S_m + c2 x R^T S_k)

The functions are plain Python on scalars and small arrays, so the numba kernels compile
these very functions and the other paths call them as they are.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Evaluation:
    """Energy, force and torque on part 2 at one pose: the per-pose result.

    Attributes
    ----------
    energy : float
        ``E = -kappa Re f``.
    force : (3,) float64
        ``-dE/dt`` in part 1's frame.
    torque : (3,) float64 or None
        ``-dE/dtheta`` about part 2's origin, world axes; None when rotation is off.
    microseconds : float
        Wall time of the evaluation.
    modes : int
        Modes per axis used (``m' = modes^3``).
    switched : float
        Where the evaluator switched models at this pose (a rotation cache refreshed, or
        the full path took over from it): the energy the part, stepped through its poses,
        gained over the old model's stretch (``engine.sim.fields.RotationCacheField``),
        which the simulation takes back. 0 otherwise.
    """

    energy: float
    force: np.ndarray
    torque: np.ndarray | None
    microseconds: float
    modes: int
    switched: float = 0.0




def add_evaluations(a: Evaluation, b: Evaluation) -> Evaluation:
    """The sum of two models' samples at one pose (``a``'s modes, both switches).

    A torque missing from one of them counts as zero; missing from both, it stays None.
    """
    if a.torque is None:
        torque = b.torque
    else:
        torque = a.torque if b.torque is None else a.torque + b.torque
    return Evaluation(a.energy + b.energy, a.force + b.force, torque,
                      a.microseconds + b.microseconds, a.modes, a.switched + b.switched)


def overlap_bounds(rot, c1, c2, half1, half2, h):
    """Where the grid boxes can meet: ``(offset, reach)``, two (3,) float64.

    Part 2's box, rotated by ``rot`` and with one cell ``h`` of margin, meets part 1's exactly
    when ``|t_a + offset_a| < reach_a`` on every axis ``a``, with ``offset = R c2 - c1`` and
    ``reach = half1 + |R| half2 + h``. Where the boxes do not meet, the energy, force and
    torque are exactly zero.

    rot (3, 3); c1, c2 (grid centres), half1, half2 (half extents) (3,) float64.
    """
    offset = np.empty(3)
    reach = np.empty(3)
    for a in range(3):
        offset[a] = rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2] - c1[a]
        reach[a] = (half1[a] + abs(rot[a, 0]) * half2[0] + abs(rot[a, 1]) * half2[1]
                    + abs(rot[a, 2]) * half2[2] + h)
    return offset, reach


def overlap_bounds_many(rots, c1, c2, half1, half2, h):
    """:func:`overlap_bounds` for a stack of rotations ``rots`` (B, 3, 3): two (B, 3) arrays.

    The same formula over numpy arrays, for the search's blocks of rotations (the scalar
    form above is the one the numba kernels compile).
    """
    rots = np.asarray(rots, dtype=np.float64)
    offset = rots @ np.asarray(c2, np.float64) - np.asarray(c1, np.float64)
    reach = np.asarray(half1, np.float64) + np.abs(rots) @ np.asarray(half2, np.float64) + h
    return offset, reach


def boxes_overlap(rot, t, c1, c2, half1, half2, h):
    """Whether the grid boxes meet at the pose ``(rot, t)`` (see :func:`overlap_bounds`)."""
    offset, reach = overlap_bounds(rot, c1, c2, half1, half2, h)
    for a in range(3):
        if abs(t[a] + offset[a]) >= reach[a]:
            return False
    return True


def phase_offset(rot, t, c1, c2):
    """(3,) ``t + R c2 - c1``: the offset the separable phase factors refer to."""
    out = np.empty(3)
    for a in range(3):
        out[a] = t[a] + rot[a, 0] * c2[0] + rot[a, 1] * c2[1] + rot[a, 2] * c2[2] - c1[a]
    return out


def torque_scale(scale, n_h):
    """The factor ``a / (2 pi)`` from the lattice-derivative sums ``S_u`` to the moment sums.

    ``a = scale N h`` is the number of lattice steps per unit of frequency; the moment sums
    are ``S_m``.
    """
    return scale * n_h / (2.0 * np.pi)


def finish(sums, rot, c2, kappa, n_h, scale, moments):
    """(7,) float64 ``[E, F (3), T (3)]`` from the seven raw sums (module docstring).

    Parameters
    ----------
    sums : (7,) float64
        ``[Re f, S_k (3), S_u (3)]``; ``S_u`` ignored when ``moments`` is False.
    rot : (3, 3) float64
    c2 : (3,) float64
        Centre of part 2's grid (its frame).
    kappa, n_h, scale : float
        Energy scale, ``N h``, and lattice steps per unit of ``k`` of the table read.
    moments : bool
        Whether the torque is wanted (zeros otherwise).
    """
    out = np.zeros(7)
    factor = 2.0 * np.pi * kappa / n_h
    out[0] = -kappa * sums[0]
    for a in range(3):
        out[1 + a] = -factor * sums[1 + a]
    if moments:
        to_moment = torque_scale(scale, n_h)
        # R^T S_k, then local = S_m + c2 x R^T S_k
        r0 = rot[0, 0] * sums[1] + rot[1, 0] * sums[2] + rot[2, 0] * sums[3]
        r1 = rot[0, 1] * sums[1] + rot[1, 1] * sums[2] + rot[2, 1] * sums[3]
        r2 = rot[0, 2] * sums[1] + rot[1, 2] * sums[2] + rot[2, 2] * sums[3]
        l0 = to_moment * sums[4] + c2[1] * r2 - c2[2] * r1
        l1 = to_moment * sums[5] + c2[2] * r0 - c2[0] * r2
        l2 = to_moment * sums[6] + c2[0] * r1 - c2[1] * r0
        for a in range(3):
            out[4 + a] = -factor * (rot[a, 0] * l0 + rot[a, 1] * l1 + rot[a, 2] * l2)
    return out


#: The functions the numba kernels compile (callees of the kernels).
FUNCTIONS = (overlap_bounds, boxes_overlap, phase_offset, torque_scale, finish)
