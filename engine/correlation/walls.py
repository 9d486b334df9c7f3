"""The walls: part 2's surface points against part 1's signed distance where the parts meet.

The skeletal energy sees the parts through a band of modes and the fine level's grid: its
walls are soft. At a blind bore's floor its minimum lies one or two fine cells past the
floor (0.19 mm for a 3.4 mm peg, 5 % of its width, with the fine level; 0.45 mm without),
so a part pushed home rests inside the floor, and a part turned in its bore can turn into
the wall. The walls are a contact term at the resolution of the fine level: a point shell
of part 2 against a distance map of part 1 (Voxmap PointShell, McNeely, Puterbaugh and
Troy 1999), each point inside part 1 pushed out along the distance's gradient::

    E_w = 1/2 k sum_i d_i^2                over the points with d_i < 0
    F_w = -k sum_i d_i grad d(x_i)
    T_w = sum_i (x_i - o) x f_i            (about part 2's origin o, world axes)

``x_i = R p_i + t`` the shell's points at the pose, ``d`` part 1's signed distance (+
outside) interpolated trilinearly on the fine grid, and ``grad d`` that interpolant's own
gradient, so the force is the energy's exact derivative. Points outside the grid feel
nothing (the grid covers the fit's box and its margin).

The stiffness ``k`` (per point) is the most an explicit step integrates: all ``n`` points
in contact at once give ``n k = WALL_STEPS m / dt^2``, an angular frequency of
``sqrt(WALL_STEPS) / dt``, within the velocity Verlet's limit of ``2 / dt``; a face
holding a tenth of the points is a tenth as stiff. It follows the part's mass and the
step, so the same pair in metres and in millimetres, at any rate, is held the same.

A stiff penalty integrated in fixed steps makes energy: a point's force starts in the
middle of a step and the trapezoid the integrator applies overshoots the energy it stored
(the bundled peg dropped free into its hole drifted by 62 % of its largest kinetic
energy).
So the walls keep a passivity observer (Hannaford and Ryu 2002): at each step the work
their force did on the part, by the trapezoid rule over the step's motion, against the
energy they gave up; the difference is energy they made, reported as
``Evaluation.switched``, which the simulation takes back from the part's motion as it does
every change of model's (``engine.sim.Simulation``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numba
import numpy as np

from engine.correlation.finishing import Evaluation
from engine.grid import Grid

#: ``n k = WALL_STEPS m / dt^2``: all points touching at once oscillate at ``1 / dt``,
#: half the explicit step's limit, which leaves room for the skeletal energy's own
#: stiffness where the two add up. At 3 a peg dropped free onto its floor, its whole
#: shell on the floor (:data:`LEADING`), was thrown out of the bore.
WALL_STEPS = 1.0
#: With an insertion axis, the shell is part 2's faces whose outward normal is within
#: arccos(LEADING) = 60 degrees of it: the faces that lead along it (a peg's end, a
#: shoulder, a bolt's head, a hub's face on its collar), which floors, steps and stops
#: hold. The sides are the guidance's: with every face in the shell, the 60 mm dovetail
#: slide of assets/real and a generated T-slot slide (seed 51822) stuck at their ways'
#: mouths; leading faces only, the dovetail seats (0.60 %), and so do the blind shaft and
#: the pocketed peg of assets/real (0.59 and 0.60 %). None: every face.
LEADING: float | None = 0.5
#: The walls push a point only this many cells of their grid inside part 1. At 0.5 (every
#: face in the shell) a generated T-slot still stuck at its way's mouth (26 % off) and a
#: 3.4 mm blind peg ended 1.9 % of its width past its floor (0.8 % at 0).
SKIN_CELLS = 0.0
#: Most shell points: the sum's cost per pose grows with them (20,000 take about 0.2 ms on
#: one core); fewer, the shell's spacing grows past the fine cell on a large part.
MAX_POINTS = 20_000
#: A move longer than this many cells of the grid between two poses evaluated is a jump (a
#: reset, a pose typed or set; the simulation also discards what the first evaluation after
#: a reset reports), for which the observer books no work. At one cell it missed the very
#: steps where the walls make energy: a peg dropped onto its floor crosses two fine cells in
#: a step as it hits, and, its floor set back (:data:`engine.sim.fine.STOP_CELLS`), it
#: gained 25 % of its largest kinetic energy in 2 s.
JUMP_CELLS = 4.0
#: Points drawn on part 2's surface before those outside the fit's region are left out.
DRAWN = 200_000


def surface_points(vertices: np.ndarray, faces: np.ndarray, count: int,
                   seed: int = 0) -> np.ndarray:
    """(count, 3) float64: points uniform over the mesh's area (deterministic per seed)."""
    return surface_samples(vertices, faces, count, seed)[0]


def surface_samples(vertices: np.ndarray, faces: np.ndarray, count: int,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(points (count, 3), unit normals (count, 3)): uniform over the mesh's area."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                axis=1)
    total = float(area.sum())
    if not total > 0 or count < 1:
        return np.zeros((0, 3)), np.zeros((0, 3))
    rng = np.random.default_rng(seed)
    which = rng.choice(len(tri), size=count, p=area / total)
    u = rng.random((count, 2))
    flip = u.sum(axis=1) > 1.0
    u[flip] = 1.0 - u[flip]
    t = tri[which]
    normal = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    return t[:, 0] + u[:, :1] * (t[:, 1] - t[:, 0]) + u[:, 1:] * (t[:, 2] - t[:, 0]), normal


@dataclass(frozen=True)
class WallShell:
    """What the walls sum: part 1's distance map and part 2's shell.

    Attributes
    ----------
    grid : Grid
        The distance map's nodes (part 1's frame).
    distance : (nx, ny, nz) float32
        Part 1's signed distance at the nodes, + outside.
    points : (n, 3) float64
        Part 2's shell, in part 2's own frame.
    """

    grid: Grid
    distance: np.ndarray
    points: np.ndarray

    @classmethod
    def on(cls, grid: Grid, distance: np.ndarray, moving_vertices: np.ndarray,
           moving_faces: np.ndarray, region: tuple[np.ndarray, np.ndarray],
           lead: np.ndarray | None = None) -> WallShell:
        """The shell of part 2 within ``region`` (lo, hi in its own frame), on ``grid``.

        ``lead`` (3,): the insertion axis in part 2's frame (:func:`shell_points`).
        """
        return cls(grid=grid, distance=np.ascontiguousarray(distance, np.float32),
                   points=shell_points(moving_vertices, moving_faces, region, lead))


def shell_points(vertices: np.ndarray, faces: np.ndarray,
                 region: tuple[np.ndarray, np.ndarray],
                 lead: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) float64: part 2's shell within ``region`` (lo, hi in its own frame).

    With ``lead`` (the insertion axis in part 2's frame) the faces that lead along it
    (:data:`LEADING`), else all of them; at most :data:`MAX_POINTS`.
    """
    drawn, normal = surface_samples(vertices, faces, DRAWN)
    lo, hi = (np.asarray(b, float) for b in region)
    keep = np.all((drawn >= lo) & (drawn <= hi), axis=1)
    if lead is not None and LEADING is not None:
        a = np.asarray(lead, float) / np.linalg.norm(lead)
        keep &= normal @ a > LEADING
    inside = drawn[keep][:MAX_POINTS]  # the draw is already random
    return np.ascontiguousarray(inside, np.float64)


class Walls:
    """Energy, force and torque of the walls at a pose (see the module).

    ``stiffness`` is the whole shell's, ``n k`` (0: the walls add nothing):
    :meth:`for_body` sets it from the part's mass and the step.
    """

    def __init__(self, shell: WallShell, stiffness: float = 0.0):
        self.shell = shell
        self.stiffness = float(stiffness)
        g = shell.grid
        self._grid = (np.asarray(g.origin, np.float64), 1.0 / g.spacing)
        #: A step longer than this is a jump (a reset, a new pose): no work booked.
        self._step_reach = JUMP_CELLS * float(g.spacing)
        self._skin = SKIN_CELLS * float(g.spacing)
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (R, t, raw)

    def for_body(self, mass: float, dt: float) -> None:
        """The stiffness an explicit step of ``dt`` integrates for a part of ``mass``."""
        self.stiffness = WALL_STEPS * float(mass) / float(dt) ** 2

    @property
    def terms(self) -> int:
        """Shell points summed per pose."""
        return len(self.shell.points)

    def raw(self, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """(7,) float64: energy, force (3), torque about part 2's origin (3)."""
        n = len(self.shell.points)
        if n == 0 or not self.stiffness > 0:
            return np.zeros(7)
        origin, inv_h = self._grid
        return _wall_sum(np.ascontiguousarray(rotation, np.float64),
                         np.ascontiguousarray(translation, np.float64), self.shell.points,
                         self.shell.distance, origin, inv_h, self.stiffness / n, self._skin)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The walls' energy, force and torque at ``(R, t)``.

        ``switched``: the energy the walls made since the last pose evaluated (the work
        their force did over the move, trapezoid rule, less the energy they gave up); 0
        after a jump of more than :data:`JUMP_CELLS` cells or a turn of more than a tenth
        of a radian.
        """
        start = time.perf_counter()
        rot = np.asarray(rotation, np.float64)
        t = np.asarray(translation, np.float64)
        s = self.raw(rot, t)
        made = 0.0
        if self._last is not None:
            rot0, t0, s0 = self._last
            move = t - t0
            turn = _rotvec(rot @ rot0.T)
            if (float(np.linalg.norm(move)) <= self._step_reach
                    and float(np.linalg.norm(turn)) <= 0.1):
                work = 0.5 * (float((s0[1:4] + s[1:4]) @ move)
                              + float((s0[4:7] + s[4:7]) @ turn))
                made = work + float(s[0] - s0[0])
        self._last = (rot.copy(), t.copy(), s)
        return Evaluation(float(s[0]), s[1:4].copy(), s[4:7].copy(),
                          (time.perf_counter() - start) * 1e6, 0, made)


def _rotvec(m: np.ndarray) -> np.ndarray:
    """(3,) rotation vector of a rotation matrix (small angles; exact below pi)."""
    c = max(-1.0, min(1.0, 0.5 * (float(np.trace(m)) - 1.0)))
    angle = math.acos(c)
    v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    s = math.sin(angle)
    return 0.5 * v if s < 1e-9 else v * (0.5 * angle / s)


@numba.njit(cache=True, fastmath=True, nogil=True, parallel=True)
def _wall_sum(rot, t, points, dist, origin, inv_h, k, skin):  # pragma: no cover - compiled
    nx, ny, nz = dist.shape
    n = points.shape[0]
    chunks = 2
    part = np.zeros((chunks, 7))
    size = (n + chunks - 1) // chunks
    for c in numba.prange(chunks):
        e = 0.0
        f0 = 0.0
        f1 = 0.0
        f2 = 0.0
        t0 = 0.0
        t1 = 0.0
        t2 = 0.0
        for i in range(c * size, min(n, (c + 1) * size)):
            px, py, pz = points[i, 0], points[i, 1], points[i, 2]
            rx = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz
            ry = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz
            rz = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz
            gx = (rx + t[0] - origin[0]) * inv_h
            gy = (ry + t[1] - origin[1]) * inv_h
            gz = (rz + t[2] - origin[2]) * inv_h
            if not (gx >= 0.0 and gy >= 0.0 and gz >= 0.0
                    and gx < nx - 1 and gy < ny - 1 and gz < nz - 1):
                continue
            ix = int(gx)
            iy = int(gy)
            iz = int(gz)
            ux = gx - ix
            uy = gy - iy
            uz = gz - iz
            c000 = dist[ix, iy, iz]
            c100 = dist[ix + 1, iy, iz]
            c010 = dist[ix, iy + 1, iz]
            c110 = dist[ix + 1, iy + 1, iz]
            c001 = dist[ix, iy, iz + 1]
            c101 = dist[ix + 1, iy, iz + 1]
            c011 = dist[ix, iy + 1, iz + 1]
            c111 = dist[ix + 1, iy + 1, iz + 1]
            c00 = c000 + (c100 - c000) * ux
            c10 = c010 + (c110 - c010) * ux
            c01 = c001 + (c101 - c001) * ux
            c11 = c011 + (c111 - c011) * ux
            c0 = c00 + (c10 - c00) * uy
            c1 = c01 + (c11 - c01) * uy
            d = c0 + (c1 - c0) * uz + skin
            if not d < 0.0:
                continue
            # the interpolant's own gradient, so the force is the energy's derivative
            dx = (((c100 - c000) * (1.0 - uy) + (c110 - c010) * uy) * (1.0 - uz)
                  + ((c101 - c001) * (1.0 - uy) + (c111 - c011) * uy) * uz) * inv_h
            dy = ((c10 - c00) * (1.0 - uz) + (c11 - c01) * uz) * inv_h
            dz = (c1 - c0) * inv_h
            e += 0.5 * k * d * d
            ax = -k * d * dx
            ay = -k * d * dy
            az = -k * d * dz
            f0 += ax
            f1 += ay
            f2 += az
            t0 += ry * az - rz * ay
            t1 += rz * ax - rx * az
            t2 += rx * ay - ry * ax
        part[c, 0] = e
        part[c, 1] = f0
        part[c, 2] = f1
        part[c, 3] = f2
        part[c, 4] = t0
        part[c, 5] = t1
        part[c, 6] = t2
    out = np.zeros(7)
    for c in range(chunks):
        for j in range(7):
            out[j] += part[c, j]
    return out
