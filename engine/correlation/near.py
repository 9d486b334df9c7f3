"""The fine level where the parts meet: the correlation summed in space over the fit's box.

The modal sum keeps ``K`` modes per axis: it sees part 1's density low-passed,
``P_K rho1``, and a fit whose walls are a fraction of the band's shortest wavelength apart
is blurred away. This level adds back, over a box around the fit, what the band drops::

    f(R, t) = f_K(R, t) + integral w(p) (rho1 - P_K rho1)(p) rho2(R^T (p - t)) dp

``w`` is a smooth window, 1 over the fit's box and 0 beyond its margin, and (where the
level has part 1's distance, :class:`SurfaceShell`) 1 only inside part 1 and within a few
cells outside it, 0 in the open space of a wide bore. With ``w = 1``
everywhere the sum is the full correlation, whatever ``K``; with the window it is the
correlation of ``P_K rho1 + w (rho1 - P_K rho1)``: part 1's density at full resolution in
the box and band-limited outside, a field of its own, so the energy stays one function of
the pose and the force and torque are its exact derivatives.

The integral is a sum over part 1's samples in the box, each a mass, against part 2's
density interpolated at ``q_j = R^T (p_j - t)``: a point shell against a voxel map, as
Voxmap PointShell is, with the shell on the fixed part (it never moves, so nothing is
transformed but the ``J`` points per pose). The masses come in two tiers
(:class:`NearLevel`): ``h^3 w (rho1 - P_K rho1)`` at the descriptor's own nodes (smooth on
its cells; they change with K), and ``(h / r)^3 w (rho1_fine - I rho1)`` at nodes ``r``
times finer, what the fine samples add to the descriptor's trilinear interpolant ``I``
(near part 1's surface and medial peaks; only the largest are kept). Part 2's density
comes from a fine grid over the region that lands in the box at the seat, blended into its
descriptor's own grid at the region's edge (the two grids are aligned, so the blend is
continuous), and is zero beyond its descriptor's grid, as the spectrum's zero padding has
it. Its cost grows with the box, not the parts.

With ``E = -kappa Re f`` and ``g = grad rho2`` in part 2's frame::

    E_near = -kappa Re sum_j m_j rho2(q_j)
    F_near = -kappa R Re sum_j m_j g(q_j)
    T_near = -kappa R Re sum_j m_j q_j x g(q_j)      (about part 2's origin, world axes)

(from ``dq_j/dt = -R^T`` and ``dq_j/dtheta = -R^T [p_j - t]x``; docs/fine_level.md).
``P_K rho1`` is the band the per-pose sum keeps (:func:`band_field`, from the table's own
coefficients), so the two levels never count a mode twice; a new ``K`` needs new node
masses (:meth:`NearField.follow`, milliseconds). Where the level is finer than the
descriptors, both parts' fine samples are smoothed over a cell (:func:`binomial_smooth`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba
import numpy as np

from engine.correlation.finishing import Evaluation, add_evaluations
from engine.correlation.walls import Walls, WallShell
from engine.grid import Grid

if TYPE_CHECKING:
    from engine.correlation.tables import ModeTable
    from engine.params import Physics

#: Of part 1's finer tier, the largest masses carrying this share of the total magnitude
#: are summed (the rest: :attr:`NearField.dropped`). On the 20 mm shaft's bore 95 % of it
#: lay in a fifth of the fine samples, near the bore's surface.
FINE_SHARE = 0.95


def cylinder_window(grid: Grid, centre: np.ndarray, axis: np.ndarray, radius: float,
                    half_length: float, taper: float) -> np.ndarray:
    """(nx, ny, nz) float64: 1 in the cylinder, 0 beyond ``taper`` of it.

    The cylinder of ``radius`` about the line through ``centre`` along the unit ``axis``,
    ``half_length`` either side of ``centre``; a product of raised-cosine ramps in the
    distance from the axis and along it. It is the same under every turn about its axis
    and every mirror through it, which a box of the grid's planes is not.
    """
    p = grid.points().reshape(-1, 3) - np.asarray(centre, float)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    s = p @ a
    r = np.linalg.norm(p - np.outer(s, a), axis=1)
    d_r = np.clip((r - radius) / taper, 0.0, 1.0)
    d_s = np.clip((np.abs(s) - half_length) / taper, 0.0, 1.0)
    w = 0.25 * (1.0 + np.cos(math.pi * d_r)) * (1.0 + np.cos(math.pi * d_s))
    return w.reshape(grid.shape)


def cylinder_box(centre: np.ndarray, axis: np.ndarray, radius: float,
                 half_length: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) each: the smallest box of the grid's planes around the cylinder."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    e = np.abs(a) * half_length + radius * np.sqrt(np.maximum(0.0, 1.0 - a * a))
    c = np.asarray(centre, float)
    return c - e, c + e


def smooth_window(grid: Grid, lo: np.ndarray, hi: np.ndarray, taper: float) -> np.ndarray:
    """(nx, ny, nz) float64: 1 inside the box ``[lo, hi]``, 0 beyond ``taper`` of it.

    A separable product of raised-cosine ramps, so the window and its first derivative are
    continuous.
    """
    out = np.ones(grid.shape)
    for axis, coords in enumerate(grid.axes()):
        below = np.clip((lo[axis] - coords) / taper, 0.0, 1.0)
        above = np.clip((coords - hi[axis]) / taper, 0.0, 1.0)
        d = np.maximum(below, above)
        ramp = 0.5 * (1.0 + np.cos(math.pi * d))
        shape = [1, 1, 1]
        shape[axis] = -1
        out = out * ramp.reshape(shape)
    return out


@dataclass(frozen=True)
class SurfaceShell:
    """How far the level's window reaches out of part 1: a shell of its signed distance.

    ``w`` is 1 inside part 1 and out to ``reach`` from its surface, and falls by a raised
    cosine to 0 at ``reach + taper`` out: the level resolves the clearance of a fit, the
    faces that stop a part and part 1's inside (where an overlap costs), and leaves the
    open space of a wider bore to the band. Resolved there, the medial peaks of a
    counterbore's open space drew a stepped peg's pin off the axis at its bore's mouth,
    where it wedged 6 degrees tilted (docs/fine_level.md).

    Attributes
    ----------
    grid : Grid
        Where ``distance`` is sampled (the level's finest grid over the box).
    distance : (nx, ny, nz) float32
        Part 1's signed distance there (+ outside).
    reach, taper : float
        Lengths in the scene's unit.
    """

    grid: Grid
    distance: np.ndarray
    reach: float
    taper: float

    def weight(self, points: np.ndarray) -> np.ndarray:
        """(n,) float64: the shell's factor of ``w`` at ``points`` (n, 3)."""
        d = trilinear(np.asarray(self.distance, np.float64), self.grid, points)
        x = np.clip((d - self.reach) / max(self.taper, 1e-300), 0.0, 1.0)
        return 0.5 * (1.0 + np.cos(math.pi * x))


def band_field(fixed_kept: np.ndarray, kept: np.ndarray, centre: np.ndarray, n_h: float,
               grid: Grid) -> np.ndarray:
    """(nx, ny, nz) complex128: ``P_K rho1`` on ``grid``, the band the modal sum keeps.

    ``P_K rho1(p) = sum_k fixed_kept[k] exp(2 pi i k.(p - c1) / (N h))`` over the kept
    cube (``fixed_kept`` holds ``rho1c^(w) dw`` and the band's weights), summed one axis at
    a time: ``O(L n^3)`` for an ``n^3`` grid and ``L`` kept modes per axis.
    """
    phases = [np.exp(2j * np.pi * np.outer(ax - c, kept) / n_h)  # (n_axis, L)
              for ax, c in zip(grid.axes(), np.asarray(centre, np.float64), strict=True)]
    a = np.asarray(fixed_kept, np.complex128)
    a = np.einsum("ijk,ck->ijc", a, phases[2], optimize=True)
    a = np.einsum("ijc,bj->ibc", a, phases[1], optimize=True)
    return np.einsum("ibc,ai->abc", a, phases[0], optimize=True)


def trilinear(values: np.ndarray, grid: Grid, points: np.ndarray) -> np.ndarray:
    """``values`` (nx, ny, nz) interpolated trilinearly at ``points`` (k, 3); 0 beyond."""
    u = (np.asarray(points, np.float64) - np.asarray(grid.origin)) / grid.spacing
    i0 = np.floor(u).astype(np.int64)
    f = u - i0
    out = np.zeros(len(u), dtype=np.result_type(values.dtype, np.float64))
    shape = np.asarray(grid.shape)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                idx = i0 + (dx, dy, dz)
                ok = np.all((idx >= 0) & (idx < shape), axis=1)
                wgt = ((f[:, 0] if dx else 1 - f[:, 0]) * (f[:, 1] if dy else 1 - f[:, 1])
                       * (f[:, 2] if dz else 1 - f[:, 2]))
                out[ok] += wgt[ok] * values[idx[ok, 0], idx[ok, 1], idx[ok, 2]]
    return out


def binomial_smooth(values: np.ndarray) -> np.ndarray:
    """``values`` (nx, ny, nz) filtered by ``[1, 2, 1] / 4`` along each axis (edges held).

    The fine level's samples are smoothed so over about a cell: trilinear interpolation of
    sharp samples (a medial peak a cell wide) makes the energy ripple with the grid, and on
    a tight rectangular peg the ripple's wells, half a cell off the seat, held the peg
    there.
    """
    out = np.asarray(values)
    for axis in range(3):
        lo = np.take(out, [0], axis=axis)
        hi = np.take(out, [out.shape[axis] - 1], axis=axis)
        padded = np.concatenate([lo, out, hi], axis=axis)
        n = out.shape[axis]
        a = np.take(padded, range(0, n), axis=axis)
        b = np.take(padded, range(1, n + 1), axis=axis)
        c = np.take(padded, range(2, n + 2), axis=axis)
        out = 0.25 * a + 0.5 * b + 0.25 * c
    return out


def _pairs(rho: np.ndarray) -> np.ndarray:
    """(nx, ny, nz, 2) float32: real and imaginary parts side by side."""
    rho = np.asarray(rho)
    return np.ascontiguousarray(np.stack([rho.real, rho.imag], axis=-1), dtype=np.float32)


@dataclass(frozen=True, eq=False)
class NearLevel:
    """The fine level's samples (immutable; lengths in the scene's unit).

    Part 1's density in the box comes in two tiers: its descriptor samples at the box's
    descriptor nodes (``fixed_nodes``, spacing ``h``), less the band the modal sum keeps
    (their masses change with K), and, where a finer level exists, what its fine samples
    add to the descriptor's trilinear interpolant (``fixed_fine``, spacing ``h / r``: near
    part 1's surface and medial peaks, and nearly nothing elsewhere, so only the largest
    are kept). Both tiers are one measure: in the box, part 1's density is
    ``P_K rho1 + w (rho1_h - P_K rho1) + w (rho1_fine - I rho1_h)``.

    Attributes
    ----------
    fixed_nodes : Grid
        Part 1's descriptor nodes over the fit's box and its margin (part 1's frame).
    fixed_node_rho : (nx, ny, nz) complex64
        Part 1's descriptor samples there (zero beyond its descriptor grid).
    window_box : (lo (3,), hi (3,), taper float)
        ``w``: 1 over ``[lo, hi]``, 0 beyond ``taper`` of it (:func:`smooth_window`).
    fixed_grid : Grid or None
        Part 1's fine grid over the same box (None: no finer level, ``r = 1``).
    fixed_rho : (fx, fy, fz) complex64 or None
        Part 1's density there.
    moving_grid : Grid
        Part 2's fine grid (part 2's frame), aligned with ``coarse_grid``.
    moving : (mx, my, mz, 2) float32
        Part 2's density there, blended into the coarse samples at the region's edge.
    coarse_grid : Grid
        Part 2's descriptor grid.
    coarse : (cx, cy, cz, 2) float32
        Part 2's descriptor samples.
    ratio : int
        ``r``: the descriptor spacing over the fine one.
    smooth : bool
        Whether the fine samples of both parts are smoothed over a cell
        (:func:`binomial_smooth`).
    walls : WallShell or None
        Part 1's distance map and part 2's point shell over the same box
        (:mod:`engine.correlation.walls`); None: no walls.
    anchor : (3,) or None
        The point of part 2 (its frame) that lies at the centre of the box at the seat:
        how far it is from the box says how near the part is to its fit
        (:meth:`NearField.closeness`). None: unknown, the part counts as near.
    cylinder : (centre (3,), axis (3,), radius, half_length) or None
        Where ``w`` is 1 when given (:func:`cylinder_window`, the same ``taper``), the box
        ``window_box`` then being the cylinder's box of the grid's planes; None: the box.
    surface : SurfaceShell or None
        ``w`` is also held to a shell about part 1's surface; None: the whole box.
    """

    fixed_nodes: Grid
    fixed_node_rho: np.ndarray
    window_box: tuple[np.ndarray, np.ndarray, float]
    fixed_grid: Grid | None
    fixed_rho: np.ndarray | None
    moving_grid: Grid
    moving: np.ndarray
    coarse_grid: Grid
    coarse: np.ndarray
    ratio: int
    smooth: bool = True
    walls: WallShell | None = None
    anchor: np.ndarray | None = None
    cylinder: tuple[np.ndarray, np.ndarray, float, float] | None = None
    surface: SurfaceShell | None = None

    @classmethod
    def from_samples(cls, fixed_nodes: Grid, fixed_node_rho: np.ndarray,
                     window_box: tuple[np.ndarray, np.ndarray, float],
                     fixed_grid: Grid | None, fixed_rho: np.ndarray | None,
                     moving_grid: Grid, moving_rho: np.ndarray, moving_window: np.ndarray,
                     coarse_grid: Grid, coarse_rho: np.ndarray, *,
                     smooth: bool = True, walls: WallShell | None = None,
                     anchor: np.ndarray | None = None,
                     cylinder: tuple[np.ndarray, np.ndarray, float, float] | None = None,
                     surface: SurfaceShell | None = None) -> NearLevel:
        """Assemble a level; part 2's fine samples are blended into its coarse ones.

        ``moving_window`` (1 inside part 2's fine region, 0 at its edge) blends
        ``moving_rho`` into the coarse samples interpolated at the fine nodes, so the
        interpolant of part 2's density is continuous where the fine region ends.
        """
        ratio = coarse_grid.spacing / moving_grid.spacing
        r = int(round(ratio))
        offset = (np.asarray(moving_grid.origin) - np.asarray(coarse_grid.origin)) \
            / coarse_grid.spacing
        if abs(ratio - r) > 1e-6 * r or np.max(np.abs(offset - np.round(offset))) > 1e-6:
            raise ValueError("part 2's fine grid must be aligned with its coarse grid "
                             f"(spacing ratio {ratio:.6g}, origin offset {offset} cells)")
        if abs(fixed_nodes.spacing - coarse_grid.spacing) > 1e-9 * coarse_grid.spacing:
            raise ValueError("part 1's nodes must have the descriptors' spacing")
        coarse_at = trilinear(np.asarray(coarse_rho), coarse_grid,
                              moving_grid.points().reshape(-1, 3)).reshape(moving_grid.shape)
        fine = np.asarray(moving_rho)
        if smooth:
            fine = binomial_smooth(fine)
        blended = coarse_at + moving_window * (fine - coarse_at)
        lo, hi, taper = window_box
        return cls(fixed_nodes=fixed_nodes,
                   fixed_node_rho=np.asarray(fixed_node_rho, np.complex64),
                   window_box=(np.asarray(lo, float), np.asarray(hi, float), float(taper)),
                   fixed_grid=fixed_grid,
                   fixed_rho=None if fixed_rho is None else np.asarray(fixed_rho, np.complex64),
                   moving_grid=moving_grid, moving=_pairs(blended),
                   coarse_grid=coarse_grid, coarse=_pairs(coarse_rho), ratio=r,
                   smooth=smooth, walls=walls,
                   anchor=None if anchor is None else np.asarray(anchor, float).reshape(3),
                   cylinder=cylinder, surface=surface)

    def window(self, grid: Grid) -> np.ndarray:
        """``w`` on ``grid``: the cylinder's (where there is one) or the box's, in the shell.

        The shell is :attr:`surface`, where there is one.
        """
        lo, hi, taper = self.window_box
        if self.cylinder is not None:
            centre, axis, radius, half = self.cylinder
            w = cylinder_window(grid, centre, axis, radius, half, taper)
        else:
            w = smooth_window(grid, lo, hi, taper)
        if self.surface is not None:
            w = w * self.surface.weight(grid.points().reshape(-1, 3)).reshape(grid.shape)
        return w


def _fine_masses(level: NearLevel) -> tuple[np.ndarray, np.ndarray, float]:
    """(points (k, 3), masses (k,) complex128, dropped) of part 1's finer tier.

    ``(h / r)^3 w (S rho1_fine - I rho1_h)`` at the fine nodes (``S`` the smoothing where
    the level has it, ``I`` trilinear interpolation of the descriptor nodes); the largest
    carrying :data:`FINE_SHARE` of the total magnitude are kept, ``dropped`` the rest's
    share.
    """
    g = level.fixed_grid
    if g is None or level.fixed_rho is None:
        return np.zeros((0, 3)), np.zeros(0, np.complex128), 0.0
    fine = np.asarray(level.fixed_rho, np.complex128)
    if level.smooth:
        fine = binomial_smooth(fine)
    points = g.points().reshape(-1, 3)
    nodes = trilinear(np.asarray(level.fixed_node_rho, np.complex128), level.fixed_nodes,
                      points)
    m = g.spacing ** 3 * (level.window(g).reshape(-1) * (fine.reshape(-1) - nodes))
    mag = np.abs(m)
    total = float(mag.sum())
    if not total > 0:
        return np.zeros((0, 3)), np.zeros(0, np.complex128), 0.0
    order = np.argsort(mag)[::-1]
    cum = np.cumsum(mag[order])
    n = int(np.searchsorted(cum, FINE_SHARE * total)) + 1
    keep = np.sort(order[:n])
    return points[keep], m[keep], 1.0 - float(cum[n - 1]) / total


class NearField:
    """Energy, force and torque of the fine level at a pose (see the module).

    Parameters
    ----------
    level : NearLevel
    kappa : float
        Energy scale (the simulation sets it with the coarse field's, :meth:`attach`).

    The level's walls (:attr:`walls`) add their contact term to :meth:`evaluate` once
    :meth:`attach` has given them the part's mass and the step; :meth:`raw` is the
    correlation alone.
    """

    def __init__(self, level: NearLevel, kappa: float = 1.0):
        self.level = level
        self.kappa = float(kappa)
        #: The contact term where the parts meet (None where the level has no walls).
        self.walls = None if level.walls is None else Walls(level.walls)
        self.modes = 0
        self._key: object = None
        self._points = np.zeros((0, 3))
        self._masses = np.zeros((0, 2), np.float32)
        lv = level
        fine_points, fine_masses, dropped = _fine_masses(lv)
        self._fine_points, self._fine_masses = fine_points, fine_masses
        #: Share of the finer tier's total magnitude left out (:data:`FINE_SHARE`).
        self.dropped = dropped
        self._node_points = lv.fixed_nodes.points().reshape(-1, 3)
        self._node_window = lv.window(lv.fixed_nodes).reshape(-1)
        self._fine = (np.asarray(lv.moving_grid.origin), 1.0 / lv.moving_grid.spacing,
                      np.asarray(lv.moving_grid.shape, np.int64), lv.moving.reshape(-1))
        self._coarse = (np.asarray(lv.coarse_grid.origin), 1.0 / lv.coarse_grid.spacing,
                        np.asarray(lv.coarse_grid.shape, np.int64), lv.coarse)
        reach = 0.5 * float(np.linalg.norm(lv.coarse_grid.upper - lv.coarse_grid.origin))
        self._moving_centre = lv.coarse_grid.centre
        self._moving_reach = reach + lv.coarse_grid.spacing
        g = lv.fixed_nodes
        self._box = (np.asarray(g.origin), g.upper)

    @property
    def terms(self) -> int:
        """Samples summed per pose."""
        return len(self._masses)

    def attach(self, physics: Physics, dt: float) -> None:
        """The simulation's kappa, and the walls' stiffness for its part and step."""
        self.kappa = float(physics.kappa)
        if self.walls is not None:
            self.walls.for_body(physics.mass, dt)

    def prepare(self, key: object, band: np.ndarray | None, modes: int) -> None:
        """Masses for a band: ``band`` is ``P_K rho1`` at part 1's box nodes (None: zero).

        ``key`` names the band (the mode table it came from); the same key keeps the masses.
        """
        if key is self._key and self._key is not None:
            return
        lv = self.level
        resid = np.asarray(lv.fixed_node_rho, np.complex128).reshape(-1)
        if band is not None:
            resid = resid - np.asarray(band).reshape(-1)
        m = lv.fixed_nodes.spacing ** 3 * self._node_window * resid
        keep = self._node_window > 0
        points = np.concatenate([self._node_points[keep], self._fine_points])
        masses = np.concatenate([m[keep], self._fine_masses])
        self._points = np.ascontiguousarray(points, np.float64)
        self._masses = np.ascontiguousarray(
            np.stack([masses.real, masses.imag], axis=-1), np.float32)
        self._key = key
        self.modes = int(modes)

    def follow(self, table: ModeTable | None) -> bool:
        """Masses for the band of ``table`` (the coarse level's current truncation).

        Returns whether the level serves it: a table without a kept cube (the "largest"
        selection) or none at all (guidance off) is not served, and the level adds nothing.
        """
        if table is None or table.fixed_kept is None or table.kept is None:
            return False
        if table is not self._key:
            g = table.geometry
            band = band_field(table.fixed_kept, table.kept, g.centre_fixed, g.n_h,
                              self.level.fixed_nodes)
            self.prepare(table, band, table.modes)
        return True

    def closeness(self, rotation: np.ndarray, translation: np.ndarray) -> float:
        """1 where part 2 at ``(rotation, translation)`` is in its fit, 0 a box away.

        Measured at the level's anchor (part 2's point at the box's centre at the seat)
        against the box where the window is 1; it falls by a raised cosine over the box's
        largest half-extent beyond it, so the play opens before a tight part reaches its
        fit's mouth (opened over the window's taper alone, a tight 12 mm rectangular peg
        entered its hole at the misaim and ended 1.56 degrees tilted).
        """
        if self.level.anchor is None:
            return 1.0
        lo, hi, _ = self.level.window_box
        point = np.asarray(rotation) @ self.level.anchor + np.asarray(translation)
        reach = 0.5 * float(np.max(hi - lo))
        d = float(np.linalg.norm(np.maximum(0.0, np.maximum(lo - point, point - hi))))
        if d >= reach:
            return 0.0
        return 0.5 * (1.0 + math.cos(math.pi * d / reach))

    def raw(self, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
        """(7,) float64 ``Re sum m rho2``, ``Re sum m g`` (3), ``Re sum m q x g`` (3)."""
        rot = np.ascontiguousarray(rotation, np.float64)
        t = np.ascontiguousarray(translation, np.float64)
        # part 2's descriptor box, as a sphere, against the fine box: nothing to sum apart
        lo, hi = self._box
        centre = rot @ self._moving_centre + t
        if np.linalg.norm(np.maximum(0.0, np.maximum(lo - centre, centre - hi))) \
                > self._moving_reach:
            return np.zeros(7)
        fo, fi, fs, fv = self._fine
        co, ci, cs, cv = self._coarse
        return _near_sum(self._points, self._masses, rot, t, fo, fi, fs, fv, co, ci, cs, cv)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The fine level's energy, force and torque at ``(R, t)``, scaled by ``kappa``."""
        start = time.perf_counter()
        s = self.raw(rotation, translation)
        rot = np.asarray(rotation, np.float64)
        k = self.kappa
        out = Evaluation(-k * float(s[0]), -k * (rot @ s[1:4]), -k * (rot @ s[4:7]),
                         (time.perf_counter() - start) * 1e6, self.modes)
        if self.walls is not None and self.walls.stiffness > 0:
            out = add_evaluations(out, self.walls.evaluate(rotation, translation))
        return out


@numba.njit(cache=True, fastmath=True, nogil=True)
def _sample(v, o0, o1, o2, inv_h, shape, q0, q1, q2, out):  # pragma: no cover
    """Trilinear value and gradient of ``v`` (nx, ny, nz, 2) at q into ``out`` (8,).

    Nodes beyond the grid count as zero (the spectrum's zero padding); False: the value is 0.
    """
    u0 = (q0 - o0) * inv_h
    u1 = (q1 - o1) * inv_h
    u2 = (q2 - o2) * inv_h
    n0, n1, n2 = shape[0], shape[1], shape[2]
    if not (-1.0 < u0 < n0 and -1.0 < u1 < n1 and -1.0 < u2 < n2):
        return False
    i0 = int(math.floor(u0))
    i1 = int(math.floor(u1))
    i2 = int(math.floor(u2))
    f0 = u0 - i0
    f1 = u1 - i1
    f2 = u2 - i2
    for c in range(8):
        out[c] = 0.0
    for dx in range(2):
        a = i0 + dx
        if a < 0 or a >= n0:
            continue
        wx = f0 if dx else 1.0 - f0
        gx = 1.0 if dx else -1.0
        for dy in range(2):
            b = i1 + dy
            if b < 0 or b >= n1:
                continue
            wy = f1 if dy else 1.0 - f1
            gy = 1.0 if dy else -1.0
            for dz in range(2):
                c = i2 + dz
                if c < 0 or c >= n2:
                    continue
                wz = f2 if dz else 1.0 - f2
                gz = 1.0 if dz else -1.0
                re = v[a, b, c, 0]
                im = v[a, b, c, 1]
                w = wx * wy * wz
                out[0] += w * re
                out[1] += w * im
                d0 = gx * wy * wz * inv_h
                d1 = wx * gy * wz * inv_h
                d2 = wx * wy * gz * inv_h
                out[2] += d0 * re
                out[3] += d0 * im
                out[4] += d1 * re
                out[5] += d1 * im
                out[6] += d2 * re
                out[7] += d2 * im
    return True


@numba.njit(cache=True, fastmath=True, nogil=True, inline="always")
def _inner(v, o0, o1, o2, inv_h, n0, n1, n2, q0, q1, q2, out):  # pragma: no cover
    """Trilinear value and gradient within ``v``'s box (no node beyond it); False outside.

    ``v`` is the (n0, n1, n2, 2) array flattened (C order).
    """
    u0 = (q0 - o0) * inv_h
    u1 = (q1 - o1) * inv_h
    u2 = (q2 - o2) * inv_h
    if not (0.0 <= u0 < n0 - 1 and 0.0 <= u1 < n1 - 1 and 0.0 <= u2 < n2 - 1):
        return False
    a = int(u0)
    b = int(u1)
    c = int(u2)
    f0 = u0 - a
    f1 = u1 - b
    f2 = u2 - c
    e0 = 1.0 - f0
    e1 = 1.0 - f1
    e2 = 1.0 - f2
    sz = 2
    sy = 2 * n2
    sx = sy * n1
    base = a * sx + b * sy + c * sz
    for k in range(2):  # real, imaginary
        i = base + k
        c000 = v[i]
        c001 = v[i + sz]
        c010 = v[i + sy]
        c011 = v[i + sy + sz]
        c100 = v[i + sx]
        c101 = v[i + sx + sz]
        c110 = v[i + sx + sy]
        c111 = v[i + sx + sy + sz]
        x00 = e0 * c000 + f0 * c100
        x01 = e0 * c001 + f0 * c101
        x10 = e0 * c010 + f0 * c110
        x11 = e0 * c011 + f0 * c111
        y0 = e1 * x00 + f1 * x10
        y1 = e1 * x01 + f1 * x11
        out[k] = e2 * y0 + f2 * y1
        out[6 + k] = (y1 - y0) * inv_h
        z0 = e2 * x00 + f2 * x01
        z1 = e2 * x10 + f2 * x11
        out[4 + k] = (z1 - z0) * inv_h
        d00 = c100 - c000
        d01 = c101 - c001
        d10 = c110 - c010
        d11 = c111 - c011
        out[2 + k] = (e1 * (e2 * d00 + f2 * d01) + f1 * (e2 * d10 + f2 * d11)) * inv_h
    return True


@numba.njit(cache=True, fastmath=True, nogil=True)
def _near_range(points, masses, rot, t, fo, fi, fs, fv, co, ci, cs, cv, lo, hi,
                out):  # pragma: no cover - compiled
    """The seven raw sums over terms ``lo .. hi - 1``, into ``out`` (7,)."""
    s = np.zeros(8)
    e = a0 = a1 = a2 = b0 = b1 = b2 = 0.0
    r00, r01, r02 = rot[0, 0], rot[0, 1], rot[0, 2]
    r10, r11, r12 = rot[1, 0], rot[1, 1], rot[1, 2]
    r20, r21, r22 = rot[2, 0], rot[2, 1], rot[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    fo0, fo1, fo2 = fo[0], fo[1], fo[2]
    n0, n1, n2 = fs[0], fs[1], fs[2]
    for j in range(lo, hi):
        d0 = points[j, 0] - t0
        d1 = points[j, 1] - t1
        d2 = points[j, 2] - t2
        q0 = r00 * d0 + r10 * d1 + r20 * d2
        q1 = r01 * d0 + r11 * d1 + r21 * d2
        q2 = r02 * d0 + r12 * d1 + r22 * d2
        if not _inner(fv, fo0, fo1, fo2, fi, n0, n1, n2, q0, q1, q2, s):
            if not _sample(cv, co[0], co[1], co[2], ci, cs, q0, q1, q2, s):
                continue
        mr = masses[j, 0]
        mi = masses[j, 1]
        e += mr * s[0] - mi * s[1]
        g0 = mr * s[2] - mi * s[3]
        g1 = mr * s[4] - mi * s[5]
        g2 = mr * s[6] - mi * s[7]
        a0 += g0
        a1 += g1
        a2 += g2
        b0 += q1 * g2 - q2 * g1
        b1 += q2 * g0 - q0 * g2
        b2 += q0 * g1 - q1 * g0
    out[0] = e
    out[1] = a0
    out[2] = a1
    out[3] = a2
    out[4] = b0
    out[5] = b1
    out[6] = b2


@numba.njit(cache=True, fastmath=True, nogil=True, parallel=True)
def _near_sum(points, masses, rot, t, fo, fi, fs, fv, co, ci, cs, cv):  # pragma: no cover
    """The seven raw sums of :meth:`NearField.raw` (compiled, in two halves at once)."""
    chunks = 2
    parts = np.zeros((chunks, 7))
    n = points.shape[0]
    for ch in numba.prange(chunks):
        _near_range(points, masses, rot, t, fo, fi, fs, fv, co, ci, cs, cv,
                    ch * n // chunks, (ch + 1) * n // chunks, parts[ch])
    return parts.sum(axis=0)
