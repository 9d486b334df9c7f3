"""A nested uniform grid of rotations: the Hopf fibration (Yershova et al. 2010).

Works on rotations as unit quaternions ``(w, x, y, z)`` and (3, 3) float64 matrices.
SO(3) is a circle bundle over the sphere: a rotation is a point ``(theta, phi)`` of the
sphere (where it sends an axis) and an angle ``psi`` about it. The grid at level ``l``
takes HEALPix's ``12 * 4^l`` equal-area pixel centres (nested numbering) on the sphere and
``6 * 2^l`` evenly spaced angles on the circle::

    q = (cos(theta/2) cos(psi/2), cos(theta/2) sin(psi/2),
         sin(theta/2) cos(phi + psi/2), sin(theta/2) sin(phi + psi/2))

which is ``72 * 8^l`` rotations (72, 576, 4,608, 36,864, ...), about ``60 / 2^l`` degrees
apart. The levels nest: pixel ``p`` at level ``l`` has the children ``4p .. 4p + 3`` and
angle ``k`` the children ``2k, 2k + 1``, so rotation ``(p, k)`` has eight children at
level ``l + 1`` around it (the search refines a fit through them). Every cell has the same
volume, and the covering radius halves with each level (tests/engine/test_search_rotations.py
measures it).

A grid may be turned as a whole by a fixed rotation (:class:`RotationGrid`'s ``offset``,
drawn from the search's seed), so that no grid rotation coincides with a part's own axes
by construction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from engine.pose import quaternion_to_matrix

#: HEALPix's face layout: the ring row and the longitude of each of the 12 base pixels.
_FACE_ROW = np.array([2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4])
_FACE_COLUMN = np.array([1, 3, 5, 7, 0, 2, 4, 6, 1, 3, 5, 7])

#: Deepest level offered (36,864 * 8 rotations at level 4; level 5 would be 2.4 million).
MAX_LEVEL = 5


def level_size(level: int) -> int:
    """Rotations at ``level``: ``72 * 8^level``."""
    return 72 * 8 ** int(level)


def level_angle(level: int) -> float:
    """Nominal spacing in degrees at ``level``: 60 / 2^level."""
    return 60.0 / 2 ** int(level)


def level_for(*, rotations: int | None = None, angle: float | None = None) -> int:
    """The coarsest level with at least ``rotations`` rotations or at most ``angle`` degrees.

    Raises
    ------
    ValueError
        Neither or both given, a value out of range, or beyond :data:`MAX_LEVEL`.
    """
    if (rotations is None) == (angle is None):
        raise ValueError("give either a number of rotations or an angle, not both")
    for level in range(MAX_LEVEL + 1):
        if rotations is not None and level_size(level) >= rotations:
            return level
        if angle is not None and level_angle(level) <= angle:
            return level
    what = (f"{rotations} rotations" if rotations is not None else f"{angle:g} degrees")
    raise ValueError(f"{what} is finer than the deepest grid ({level_size(MAX_LEVEL)} "
                     f"rotations, {level_angle(MAX_LEVEL):g} degrees): ask for fewer")


def _compress_bits(v: np.ndarray) -> np.ndarray:
    """The even bits of ``v`` packed together (HEALPix's nested index to x or y)."""
    out = np.zeros_like(v)
    for bit in range(31):
        out |= ((v >> (2 * bit)) & 1) << bit
    return out


def healpix_nested(level: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colatitude and longitude (radians) of HEALPix pixel centres, nested numbering.

    Parameters
    ----------
    level : int
        ``nside = 2^level``; ``12 * 4^level`` pixels.
    pixels : (n,) int64
        Nested pixel numbers.

    Returns
    -------
    theta, phi : (n,) float64
    """
    nside = 1 << int(level)
    npface = nside * nside
    pix = np.asarray(pixels, dtype=np.int64)
    face = pix // npface
    within = pix % npface
    ix = _compress_bits(within)
    iy = _compress_bits(within >> 1)
    jr = _FACE_ROW[face] * nside - ix - iy - 1
    npix = 12 * npface
    fact2 = 4.0 / npix
    fact1 = 2 * nside * fact2
    north = jr < nside
    south = jr > 3 * nside
    nr = np.where(north, jr, np.where(south, 4 * nside - jr, nside))
    z = np.where(north, 1.0 - nr * nr * fact2,
                 np.where(south, nr * nr * fact2 - 1.0, (2 * nside - jr) * fact1))
    tmp = _FACE_COLUMN[face] * nr + ix - iy
    tmp = np.where(tmp < 0, tmp + 8 * nr, np.where(tmp >= 8 * nr, tmp - 8 * nr, tmp))
    phi = np.where(nr == nside, 0.75 * (math.pi / 2) * tmp * fact1,
                   0.5 * (math.pi / 2) * tmp / np.maximum(nr, 1))
    return np.arccos(np.clip(z, -1.0, 1.0)), phi


def hopf_quaternions(level: int, indices: np.ndarray) -> np.ndarray:
    """(n, 4) float64 unit quaternions of grid rotations ``indices`` at ``level``.

    Index ``i`` is pixel ``i // m`` and circle angle ``i % m``, ``m = 6 * 2^level``.
    """
    m = 6 * 2 ** int(level)
    idx = np.asarray(indices, dtype=np.int64)
    theta, phi = healpix_nested(level, idx // m)
    psi = (idx % m + 0.5) * (2.0 * math.pi / m)
    ct, st = np.cos(theta / 2), np.sin(theta / 2)
    return np.stack([ct * np.cos(psi / 2), ct * np.sin(psi / 2),
                     st * np.cos(phi + psi / 2), st * np.sin(phi + psi / 2)], axis=1)


def children(level: int, index: int) -> np.ndarray:
    """(8,) int64 indices at ``level + 1`` of the children of rotation ``index``."""
    m = 6 * 2 ** int(level)
    pixel, angle = divmod(int(index), m)
    return np.array([(4 * pixel + a) * (2 * m) + 2 * angle + b
                     for a in range(4) for b in range(2)], dtype=np.int64)


def _quaternion_matrices(quats: np.ndarray) -> np.ndarray:
    return np.stack([quaternion_to_matrix(q) for q in quats]) if len(quats) else np.zeros((0, 3, 3))


@dataclass(frozen=True)
class RotationGrid:
    """The Hopf grid turned as a whole by ``offset``.

    Rotation ``(level, i)`` is ``offset @ hopf(level, i)``.

    Attributes
    ----------
    offset : (3, 3) float64
        The grid's turn (identity: the plain grid).
    """

    offset: np.ndarray = field(default_factory=lambda: np.eye(3))

    @classmethod
    def from_seed(cls, seed: int | None) -> RotationGrid:
        """The grid turned by a uniformly random rotation drawn from ``seed`` (None: plain)."""
        if seed is None:
            return cls()
        q = np.random.default_rng(int(seed)).normal(size=4)
        return cls(offset=quaternion_to_matrix(q / np.linalg.norm(q)))

    def matrices(self, level: int, indices: np.ndarray) -> np.ndarray:
        """(n, 3, 3) float64 rotation matrices of grid rotations ``indices`` at ``level``."""
        return np.einsum("ij,njk->nik", self.offset,
                         _quaternion_matrices(hopf_quaternions(level, indices)))

    def matrix(self, level: int, index: int) -> np.ndarray:
        """(3, 3) float64 matrix of one grid rotation."""
        return self.matrices(level, np.array([index]))[0]


def rotation_angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in radians of the rotation taking (3, 3) ``b`` to (3, 3) ``a``."""
    c = (float(np.trace(np.asarray(a) @ np.asarray(b).T)) - 1.0) / 2.0
    return math.acos(min(1.0, max(-1.0, c)))
