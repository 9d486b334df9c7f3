"""Where the fine level goes and how fine it is: grids over the fit, chosen from the parts.

Works on a scene's two loaded parts (:class:`engine.loading.Part`, the scene's unit), their
descriptors on the scene's grid (:class:`engine.descriptor.Descriptor`, one spacing ``h``)
and the assembled pose (6,). The numerics of the level are
:mod:`engine.correlation.near`; this module decides its extent:

- part 1's fine grid covers the box where the parts meet at the seat
  (:func:`engine.sim.auto.measure_fit`), grown by :data:`BOX_CELLS` coarse cells (a blind
  bore's floor, which a flush end leaves out of the measure) and then by a taper of
  :data:`TAPER_CELLS` cells over which the window falls to zero;
- its spacing is ``h / r``, the largest ``r`` (at most :data:`MAX_RATIO`) for which the box
  holds at most :data:`SAMPLES_BUDGET` samples: finer for a small fit in a large part;
- part 2's fine grid covers the region of part 2 that lies in that box at the seat, grown
  by the protocol's misaim and the taper, aligned with part 2's own grid and clipped to it.

Both fine descriptors come from the descriptor store (cached on disk like the coarse ones),
and so does part 1's signed distance on the finest grid: the walls' distance map
(:func:`wall_shell`), and the shell about part 1's surface that the level's window keeps
to (:data:`SURFACE_CELLS`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from engine.correlation.near import NearLevel, SurfaceShell, cylinder_box, smooth_window, trilinear
from engine.correlation.walls import WallShell, shell_points
from engine.grid import Grid
from engine.pose import rotation_matrix

if TYPE_CHECKING:
    from engine.descriptor import Descriptor
    from engine.loading import Part
    from engine.scene import Scene
    from engine.sim.auto import FitMeasure

#: The fit's box grows by this many coarse cells before the taper (a blind bore's floor).
BOX_CELLS = 2.0
#: The window's shape: "cylinder" about the insertion axis, around the fit's points
#: (:attr:`engine.sim.auto.FitMeasure.cylinder`), or "box", the box of the grid's planes
#: around them. A box cuts part 1's surfaces near the fit where the grid's planes happen to
#: lie: the level pushed a centred rectangular peg sideways 12 mm above its pocket with
#: 7.9e3, twice the coupling's force at 1 mm off (a pair turned at random in its files);
#: the cylinder, 16. Goes with the guidance's smooth band (docs/fine_level.md).
WINDOW_SHAPE = "cylinder"
#: The window falls from 1 to 0 over this many coarse cells.
TAPER_CELLS = 2.0
#: Part 2's fine region reaches this many coarse cells beyond the box's pre-image (a part
#: misaimed by a few per cent of its width, or tilted by a few degrees).
MOVING_MARGIN_CELLS = 3.0
#: Largest fine samples over part 1's box (all three axes): the level's setup costs two
#: descriptors of up to about this many samples. At 64^3 the 20 mm shaft and the
#: thin-walled sleeve of assets/real got no finer level (r = 1) and ended 1.1 and 1.2
#: degrees tilted; at 80^3 (r = 2) the sleeve seats and the shaft ends 0.3 degree tilted.
#: At 80^3 a fit whose box is large in the descriptor's cells (a wide hub, or any fit whose
#: axis runs obliquely through part 1's grid, whose box is then the bounding box of a
#: tilted cylinder) still got r = 1, where the unsmoothed descriptor samples leave wells a
#: cell or two deep along the way in: such pairs failed 4 times in 8 on an unseen set
#: against 3 in 31 at r = 2. At 100^3, on the six pairs of a new set whose level it makes
#: finer, 5 seat against 3 (docs/measurements/seating_generated.md, seed 57203), for two to
#: four times the level's setup.
SAMPLES_BUDGET = 100 ** 3
#: The finest level: ``h / MAX_RATIO``. Every level is smoothed over its own cell
#: (:func:`engine.correlation.near.binomial_smooth`), a smaller share of a descriptor cell
#: at each step: the 12 mm rectangular Factory peg seated within 0.04 % of its width at
#: r = 2 and ended 3.9 % off at r = 3 (unsmoothed at r = 4: 4 %, 3.3 degrees). Unsmoothed,
#: the energy ripples with the fine grid (at r = 2 that peg rested half a cell off its seat,
#: 5.5 degrees tilted; smoothed, within 0.1 degree). At r = 1 smoothing blurs a whole
#: descriptor cell, and it was left off there after two pairs of assets/real, then at
#: r = 1, ended 0.8 mm past a collar and 1 mm short of a floor smoothed. Every pair of
#: assets/real now has r = 2; of five generated pairs still at r = 1, smoothed, a dovetail
#: seats (1.20 % of its width, against 8.36 %) and the other four do as they did
#: (docs/measurements/seating_generated.md).
MAX_RATIO = 2
#: Part 1's faces that stop part 2 (outward normal within 60 degrees of against the
#: insertion axis, where the walls push part 2's leading faces back) are set back into part
#: 1 by this many fine cells in the level's density (:func:`set_back_stops`). The level
#: blurs every face by about a fine cell on each side (the trilinear interpolant and the
#: ``[1, 2, 1] / 4`` smoothing of both parts), and where part 2's inside meets part 1's the
#: penalty's slope is several times the fit's pull: the blurred penalty balanced that pull
#: about 1.5 fine cells short of contact, so a hub rested 0.52 mm short of its collar and a
#: T-slot slide or a dovetail short of its stop. Set back, the level's own pull reaches the
#: face and the walls, exact there, hold it. A level at ``r = 1`` (no finer tier) is the
#: descriptors' own samples and is not set back.
STOP_CELLS = 1.5
#: Only the faces part 2 rests on at the seat are set back: within this many fine cells of
#: its leading points there. Part 1's other faces against the axis (a through hole's rim,
#: a plate's top) keep theirs: with every such face set back, the 12 mm rectangular Factory
#: peg, which enters its hole over the rim, jammed 4.09 degrees tilted at the mouth.
STOP_REACH_CELLS = 3.0
#: The level's window reaches this many coarse cells out of part 1's surface, then falls to
#: zero over :data:`SURFACE_TAPER_CELLS` more; inside part 1 it is whole
#: (:class:`engine.correlation.near.SurfaceShell`). Over the whole box, the sharpened medial
#: peaks of a counterbore's open space drew a stepped peg (seed 24683, pair 13) 1.4 mm off
#: the axis at its bore's mouth with 5.1 N against the band's 1.8 N back (at 3 % of its
#: width off; 4.7 N of it from part 1's outside samples, 3.4 N from those more than a cell
#: out), and it wedged 6 degrees tilted; a dovetail slide (pair 7) was pushed sideways at its
#: way's mouth with ten times the band's pull back. With the shell both seat. Its reach is a
#: compromise: at one cell two keyed hubs of seed 19477 (pairs 11 and 17) stopped 1.6 and
#: 1.4 mm short of their collars, where the band's blur of the collar, no longer corrected
#: out there, held them; at two they seat. A shell on both sides of the surface let the
#: 50 mm spigot of assets/real drift 4.8 mm sideways onto its rim (9.2 % of its width): part
#: 1's inside samples centre it.
SURFACE_CELLS = 2.0
#: The shell's taper, in coarse cells (:data:`SURFACE_CELLS`).
SURFACE_TAPER_CELLS = 1.0


def _aligned_grid(lo: np.ndarray, hi: np.ndarray, coarse: Grid, ratio: int,
                  clip: bool) -> Grid | None:
    """Grid of spacing ``coarse.spacing / ratio`` over ``[lo, hi]``, on the coarse nodes.

    ``clip``: within the coarse grid's box. None where nothing is left.
    """
    h = coarse.spacing
    origin = np.asarray(coarse.origin)
    a = np.floor((lo - origin) / h)
    b = np.ceil((hi - origin) / h)
    if clip:
        a = np.maximum(a, 0.0)
        b = np.minimum(b, np.asarray(coarse.shape) - 1.0)
    if np.any(b <= a):
        return None
    nx, ny, nz = (int(n) * ratio + 1 for n in (b - a))
    x0, y0, z0 = (float(v) for v in origin + a * h)
    return Grid((x0, y0, z0), h / ratio, (nx, ny, nz))


def fine_ratio(box_lo: np.ndarray, box_hi: np.ndarray, spacing: float) -> int:
    """The largest ``r <= MAX_RATIO`` whose fine grid over the box fits the budget (>= 1)."""
    cells = np.maximum(np.asarray(box_hi) - np.asarray(box_lo), spacing) / spacing
    r = (SAMPLES_BUDGET / float(np.prod(cells + 1.0))) ** (1.0 / 3.0)
    return int(max(1, min(MAX_RATIO, math.floor(r))))


def level_grids(fixed_grid: Grid, moving_grid: Grid, box_lo: np.ndarray,
                box_hi: np.ndarray, assembled_pose: np.ndarray,
                cylinder: tuple[np.ndarray, np.ndarray, float, float] | None = None
                ) -> tuple[Grid, int, np.ndarray, np.ndarray, Grid, np.ndarray, np.ndarray] | None:
    """(part 1's box nodes, r, window lo, hi, part 2's fine grid, its window lo, hi), or None.

    The window boxes are where each window is 1 (the taper lies outside them). With the
    fit's ``cylinder`` (grown by :data:`BOX_CELLS` cells), part 1's box is the cylinder's.
    """
    h = fixed_grid.spacing
    if cylinder is not None:
        centre, axis, radius, half = grown_cylinder(cylinder, h)
        inner_lo, inner_hi = cylinder_box(centre, axis, radius, half)
    else:
        inner_lo = np.asarray(box_lo, float) - BOX_CELLS * h
        inner_hi = np.asarray(box_hi, float) + BOX_CELLS * h
    taper = TAPER_CELLS * h
    ratio = fine_ratio(inner_lo - taper, inner_hi + taper, h)
    nodes = _aligned_grid(inner_lo - taper, inner_hi + taper, fixed_grid, 1, clip=False)
    if nodes is None:
        return None
    # the box's corners in part 2's frame at the seat
    pose = np.asarray(assembled_pose, float).reshape(6)
    rot = rotation_matrix(pose[3:])
    corners = np.array([[x, y, z] for x in (nodes.origin[0], nodes.upper[0])
                        for y in (nodes.origin[1], nodes.upper[1])
                        for z in (nodes.origin[2], nodes.upper[2])])
    local = (corners - pose[:3]) @ rot
    m_lo = local.min(axis=0) - MOVING_MARGIN_CELLS * h
    m_hi = local.max(axis=0) + MOVING_MARGIN_CELLS * h
    moving = _aligned_grid(m_lo - taper, m_hi + taper, moving_grid, ratio, clip=True)
    if moving is None:
        return None
    return nodes, ratio, inner_lo, inner_hi, moving, m_lo, m_hi


def grown_cylinder(cylinder: tuple[np.ndarray, np.ndarray, float, float], spacing: float
                   ) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The fit's cylinder grown by :data:`BOX_CELLS` cells of ``spacing`` all round."""
    centre, axis, radius, half = cylinder
    grow = BOX_CELLS * spacing
    return (np.asarray(centre, float), np.asarray(axis, float), float(radius) + grow,
            float(half) + grow)


def _window_cylinder(fit: FitMeasure) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """The fit's cylinder where the level's window is one (:data:`WINDOW_SHAPE`), else None."""
    return fit.cylinder if WINDOW_SHAPE == "cylinder" else None


def fine_nodes(nodes: Grid, ratio: int) -> Grid:
    """Part 1's fine grid: ``nodes`` (its box at the descriptor's spacing) ``ratio`` times finer."""
    nx, ny, nz = ((n - 1) * ratio + 1 for n in nodes.shape)
    return Grid(nodes.origin, nodes.spacing / ratio, (nx, ny, nz))


def fine_rungs(fixed: Part, moving: Part, fixed_grid: Grid, moving_grid: Grid,
               assembled_pose: np.ndarray, fit: FitMeasure) -> list[tuple[Part, Grid]]:
    """The (part, grid) of each descriptor :func:`build_level` computes for a pair.

    Part 1's and part 2's fine grids where the level is finer than the descriptors (none
    at ``r = 1``, nor where the parts do not meet): they depend on the meshes, the seat
    and the descriptors' grids, not on sigma, so a sigma ladder on them serves the level
    at a new sigma.
    """
    if fit.points < 8:
        return []
    grids = level_grids(fixed_grid, moving_grid, fit.box_lo, fit.box_hi, assembled_pose,
                        _window_cylinder(fit))
    if grids is None or grids[1] <= 1:
        return []
    return [(fixed, fine_nodes(grids[0], grids[1])), (moving, grids[4])]


def prepare_ladders(scene: Scene, parts: list[Part], assembled_pose: np.ndarray,
                    fit: FitMeasure | None, *,
                    progress: Callable[[float], None] | None = None,
                    cancel: Callable[[], bool] | None = None) -> None:
    """Compute the nodes missing from the scene's sigma ladders, then its fine level's.

    The scene's grids first (the first 60 % of the progress: a new sigma's field), then the
    fine level's grids (:func:`fine_rungs`; none without ``fit``): the level at a new sigma,
    which took 24 to 65 s afresh on the bundled pairs, is then read from them.
    """
    from engine.descriptor import grid_for_part, scene_spacing
    from engine.descriptor.ladder import prepare_ladders as prepare_rungs
    from engine.descriptor.ladder import prepare_scene_ladder

    def stage(lo: float, hi: float) -> Callable[[float], None] | None:
        return None if progress is None else (lambda f: progress(lo + (hi - lo) * f))

    prepare_scene_ladder(scene, parts, progress=stage(0.0, 0.6), cancel=cancel)
    if fit is not None and len(parts) > 1:
        spacing = scene_spacing(scene, parts)
        g1, g2 = (grid_for_part(p, spacing=spacing, padding=scene.descriptor.padding)
                  for p in parts[:2])
        prepare_rungs(fine_rungs(parts[0], parts[1], g1, g2, assembled_pose, fit),
                      scene.descriptor, progress=stage(0.6, 1.0), cancel=cancel)
    if progress is not None:
        progress(1.0)


def build_level(fixed: Part, moving: Part, fixed_desc: Descriptor, moving_desc: Descriptor,
                assembled_pose: np.ndarray, axis: np.ndarray | None, *,
                fit: FitMeasure | None = None,
                progress: Callable[[float], None] | None = None,
                cancel: Callable[[], bool] | None = None) -> NearLevel | None:
    """The fine level of a pair at its seat, or None where the parts do not meet there.

    The descriptors' parameters (sigma, penalty) are the coarse ones', so the levels are
    one density sampled twice. At ``r = 1`` no descriptor is computed: the level is the
    descriptors' own samples in the box. ``fit``: the pair's measure at that pose, where
    the caller keeps it (it depends on the meshes alone; seconds on a part of many
    triangles, which a new sigma or penalty would pay again).
    """
    from engine.descriptor.ladder import descriptor_preferring_ladder
    from engine.descriptor.store import distance_for_part
    from engine.sim.auto import measure_fit

    if fit is None:
        fit = measure_fit(fixed, moving, assembled_pose, axis)
    if fit.points < 8:
        return None
    cylinder = _window_cylinder(fit)
    grids = level_grids(fixed_desc.grid, moving_desc.grid, fit.box_lo, fit.box_hi,
                        assembled_pose, cylinder)
    if grids is None:
        return None
    nodes, ratio, lo1, hi1, g2, lo2, hi2 = grids
    pose = np.asarray(assembled_pose, float).reshape(6)
    seat = rotation_matrix(pose[3:])  # part 2's frame to part 1's at the seat
    h = fixed_desc.grid.spacing
    taper = TAPER_CELLS * h

    def stage(a: float, b: float) -> Callable[[float], None] | None:
        return None if progress is None else (lambda f: progress(a + (b - a) * float(f)))

    node_rho = trilinear(np.asarray(fixed_desc.rho, np.complex128), fixed_desc.grid,
                         nodes.points().reshape(-1, 3)).reshape(nodes.shape)
    g1 = rho1 = None
    if ratio > 1:  # from the cache, or the sigma ladder (SceneModel.prepare_ladder)
        g1 = fine_nodes(nodes, ratio)
        rho1 = descriptor_preferring_ladder(fixed, g1, fixed_desc.params,
                                            progress=stage(0.0, 0.4), cancel=cancel).rho
        rho2 = descriptor_preferring_ladder(moving, g2, moving_desc.params,
                                            progress=stage(0.4, 0.8), cancel=cancel).rho
    else:
        rho2 = trilinear(np.asarray(moving_desc.rho, np.complex128), moving_desc.grid,
                         g2.points().reshape(-1, 3)).reshape(g2.shape)
    lead = None if axis is None else seat.T @ np.asarray(axis, float)
    finest = g1 if g1 is not None else nodes
    distance = np.ascontiguousarray(
        distance_for_part(fixed, finest, progress=stage(0.8, 1.0), cancel=cancel), np.float32)
    walls = wall_shell(moving, finest, distance, g2, lead=lead)
    if walls is not None and g1 is not None and rho1 is not None and axis is not None:
        rho1 = set_back_stops(rho1, g1, walls.distance, np.asarray(axis, float),
                              STOP_CELLS * g1.spacing, walls.points @ seat.T + pose[:3])
    return NearLevel.from_samples(
        nodes, node_rho, (lo1, hi1, taper), g1, rho1,
        g2, rho2, smooth_window(g2, lo2, hi2, taper),
        moving_desc.grid, moving_desc.rho, walls=walls,
        anchor=(0.5 * (lo1 + hi1) - pose[:3]) @ seat,
        cylinder=None if cylinder is None else grown_cylinder(cylinder, h),
        surface=SurfaceShell(finest, distance, SURFACE_CELLS * h, SURFACE_TAPER_CELLS * h))


def set_back_stops(rho: np.ndarray, grid: Grid, distance: np.ndarray, axis: np.ndarray,
                   depth: float, seated: np.ndarray | None = None) -> np.ndarray:
    """``rho`` on ``grid`` with part 1's stop faces set back by ``depth`` (see :data:`STOP_CELLS`).

    A sample inside part 1 (``distance`` < 0, part 1's signed distance on ``grid``) within
    ``depth`` of a face whose outward normal (the distance's gradient) points against
    ``axis`` (part 2's direction of travel, part 1's frame) by less than 60 degrees, and
    (with ``seated``, part 2's leading points at the seat in part 1's frame) whose nearest
    point on that face lies within :data:`STOP_REACH_CELLS` cells of one of them, takes
    the density outside that face, as far out as the sample is in (at least a cell out,
    where the interpolant reads no sample inside). Other samples keep theirs. Returns a new
    array (``rho`` unchanged).
    """
    d = np.asarray(distance, np.float64)
    out = np.array(rho, copy=True)
    if depth <= 0:
        return out
    grad = np.stack(list(np.gradient(d, grid.spacing)), axis=-1)
    norm = np.linalg.norm(grad, axis=-1)
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    stop = (d < 0) & (d > -depth) & (norm > 0) & ((grad @ a) < -0.5 * norm)
    points = grid.points()
    if stop.any() and seated is not None:  # the faces part 2 rests on, not a hole's rim
        where = np.argwhere(stop)
        face = points[stop] - d[stop][:, None] * grad[stop] / norm[stop][:, None]
        near = cKDTree(np.asarray(seated, np.float64)).query(
            face, distance_upper_bound=STOP_REACH_CELLS * grid.spacing)[0] < np.inf
        stop[tuple(where[~near].T)] = False
    if stop.any():
        outward = grad[stop] / norm[stop][:, None]
        # as far out as the sample is in, and at least a cell, where no sample inside
        # reaches the interpolant
        out_by = np.maximum(-d[stop], grid.spacing) - d[stop]
        mirror = points[stop] + out_by[:, None] * outward
        out[stop] = trilinear(np.asarray(rho), grid, mirror)
    return out


def wall_shell(moving: Part, grid: Grid, distance: np.ndarray, region: Grid, *,
               lead: np.ndarray | None = None) -> WallShell | None:
    """The walls over the level (:mod:`engine.correlation.walls`).

    Part 1's signed ``distance`` on ``grid`` (the level's finest over the fit's box) and
    part 2's shell within ``region`` (its fine grid: what can reach the box). None where no
    face of part 2 there leads along ``lead``.
    """
    points = shell_points(moving.vertices, moving.faces,
                          (np.asarray(region.origin), np.asarray(region.upper)), lead)
    if len(points) == 0:  # nothing leads into the box (a through fit's end is past it)
        return None
    return WallShell(grid=grid, distance=np.asarray(distance, np.float32), points=points)
