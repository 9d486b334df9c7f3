"""Settings chosen from the parts, where a scene does not set them.

Works on a scene (:class:`engine.scene.Scene`) and its two loaded parts
(:class:`engine.loading.Part`, vertices ``(n, 3) float64`` in the scene's unit). A user
knows the files, their unit, the assembled pose and the insertion axis; the grid, the mode
count K, the STEP chord tolerance and the rest follow from the parts:

1. :func:`measure_fit` places part 2 at its assembled pose and measures, from points on its
   surface, the distance to part 1's surface: the points within reach of part 1 are the fit
   (a box where the parts meet), the median of their gaps (flush faces left out) is the
   fit's clearance, the smallest its tightest gap, and the fit's width is the smaller
   extent of those points across the insertion axis (a peg's diameter, a key's hub).
2. :func:`choose_settings` turns the measure into settings, each with a one-line reason:

   - the STEP chord tolerance: a third of the tightest gap (a tessellated bore is an
     inscribed polygon, smaller than the bore by up to the tolerance: at the loader's
     default, 1/1000 of the diagonal, it cuts into a shaft with a 24 micrometre play);
   - the grid spacing ``h``: a twelfth of the fit's width (the band's shortest wavelength,
     :data:`WAVELENGTH_PER_WIDTH` of the width, spans five cells), within
     :data:`GRID_RANGE` samples along the longest side;
   - K: the odd count whose band reaches that wavelength on the pair's FFT lattice, at most
     the machine's budget (:func:`modes_budget`): the loop's rate with the per-pose sum of
     ``K^3`` modes on the CPU at hand, more on a GPU. Where the budget's band would only
     half-resolve the fit (its shortest wavelength between :data:`NEAR_WAVELENGTHS` and
     :data:`OUTLINE_WAVELENGTHS` of the fit's width), K is lowered until that wavelength is
     :data:`OUTLINE_WAVELENGTHS` widths: the part is drawn in by its outline;
   - sigma, the padding and the penalty keep the engine's values, which no size changes
     (:func:`scale_free_choices` says why for each), and the coupling holds the part at the
     middle of the fit (``engine.sim.build.hold_point``), its springs and damping from the
     part's mass and inertia, the step and the fit's stiffness (``resolve_physics``).

3. :func:`complete_scene` applies the choices the scene does not make itself (a value the
   file sets always wins), reloading STEP parts at the chosen tolerance, and records each
   choice and its reason in ``Scene.chosen``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from engine.params import LENGTH_UNITS, MAX_MODES, DescriptorParams
from engine.pose import rotation_matrix

if TYPE_CHECKING:
    from engine.loading import Part
    from engine.scene import Scene

#: Points sampled on part 2's surface to measure the fit (deterministic).
SAMPLES = 6000
#: Part 2's surface points farther than this fraction of its smallest box side from part 1
#: are not in the fit.
REACH_FRACTION = 0.2
#: Then only gaps within this many times the median gap of those points are the fit's:
#: a hub's face beside the collar it rests on is not.
GAP_REACH = 4.0
#: Gaps below this fraction of the parts' size are flush faces (a shoulder on its seat, a
#: peg's end flush with a plate), not clearance.
FLUSH_FRACTION = 1e-5
#: The band's shortest wavelength, as a fraction of the fit's width: 2.5 wavelengths across
#: the fit. The hand-tuned real pairs seated with 2.1 (the 5 mm pin) to 6.4 (the 20 mm
#: shaft) across.
WAVELENGTH_PER_WIDTH = 0.4
#: Where the budget's band would half-resolve the fit, its shortest wavelength is kept at
#: this many times the fit's width. On the real pairs made into scenes by `scene new`,
#: K = 17 (1.5 to 1.6 widths on the Factory 12 mm rectangular and 8 mm round pegs) seated
#: them; K = 25 (1.0 to 1.1 widths there) left them 2 to 6 degrees tilted; the 16 mm peg
#: seated at both (0.5 and 0.8 widths), the bundled peg at K = 25 (0.87 widths) and not at
#: K = 13 (1.5).
OUTLINE_WAVELENGTHS = 1.5
#: A band whose shortest wavelength is within this many widths of the fit is near enough
#: to resolving it: the budget's K is kept.
NEAR_WAVELENGTHS = 0.9
#: Cells per shortest wavelength: the descriptor is sampled finely enough for the band.
CELLS_PER_WAVELENGTH = 5.0
#: Samples along the longest side of the largest part: a floor that keeps the part's shape,
#: and a ceiling on the descriptor's cost (its time grows with the cube: a minute or two for
#: both parts at 96 on two cores). Below 48 the descriptor aliases a part's edges into the
#: band.
GRID_RANGE = (48, 96)
#: The chord tolerance is this fraction of the tightest gap.
TOLERANCE_PER_GAP = 1.0 / 3.0
#: Never finer than this fraction of the parts' size: the bundled zero-clearance peg
#: tessellated at 2e-5 of it (0.0008 mm, 25 times the triangles, fans of slivers on the
#: caps) ended 1.1 degrees tilted (14.6 with the lowered coupling alone), at 1e-4
#: (0.004 mm, what the real pairs' scenes had by hand) 0.1.
TOLERANCE_FLOOR = 1e-4
#: Odd mode counts the loop affords at 1 kHz: per-pose sums of K^3 modes took 0.2 ms at
#: K = 17 and 0.57 ms at K = 25 on one core of a 2-core x86 host (numba); a GPU sums
#: 49^3 in well under a period.
MODES_BUDGET_CPU, MODES_BUDGET_GPU = 25, 49
#: The least K chosen (the band must hold the parts' outline).
MIN_MODES = 9


@dataclass(frozen=True)
class FitMeasure:
    """What :func:`measure_fit` finds at the assembled pose (lengths in the scene's unit).

    Attributes
    ----------
    size : float
        Longest box side of the larger part.
    box_lo, box_hi : (3,) float64
        Where the parts meet: the box of part 2's surface points within reach of part 1,
        part 1's frame. Equal to part 2's box when nothing is within reach.
    width : float
        The fit's smaller extent across the insertion axis (part 2's extent when nothing
        is within reach).
    clearance : float or None
        Median gap of the fit's points that are not flush; None when every point is flush
        or none is within reach.
    tightest : float or None
        The 10th percentile of those gaps.
    points : int
        Part 2's surface points within reach of part 1.
    cylinder : (centre (3,), axis (3,), radius, half_length) or None
        The same points' cylinder about the insertion axis (part 1's frame): the centre of
        their extents along the axis and across it, their largest distance from the axis
        line and half their extent along it. None without an axis. Unlike the box, it
        turns with the parts: a fit symmetric about a plane through its axis is symmetric
        in it, whatever the planes of part 1's grid.
    """

    size: float
    box_lo: np.ndarray
    box_hi: np.ndarray
    width: float
    clearance: float | None
    tightest: float | None
    points: int
    cylinder: tuple[np.ndarray, np.ndarray, float, float] | None = None


def _surface_points(part: Part, count: int) -> np.ndarray:
    """(count, 3) points on a part's surface, area-weighted, the same for the same mesh."""
    from engine.correlation.walls import surface_points

    points = surface_points(part.vertices, part.faces, count)
    return points if len(points) else np.asarray(part.vertices, np.float64).copy()


def _distances(part: Part, points: np.ndarray) -> np.ndarray:
    """(k,) unsigned distance of each point to a part's surface (exact, per triangle).

    Through the descriptors' own triangle tree on the CPU (the same numbers on every
    machine): about ten times faster than trimesh's closest-point query on a CAD part of
    17,000 triangles, which cost a bundled scene 5 s at every open.
    """
    from engine.descriptor.compute import signed_distance

    distance = signed_distance(np.asarray(part.vertices, np.float64),
                               np.asarray(part.faces, np.int64),
                               np.asarray(points, np.float64), backend="numba")
    return np.abs(distance)


#: Fits measured in this process, by the meshes, the pose and the axis (the newest last).
_FITS: dict[str, FitMeasure] = {}
#: How many :data:`_FITS` keeps.
FITS_KEPT = 16
#: The fine level measures on the engine's background thread while a scene may open.
_FITS_LOCK = threading.Lock()


def measure_fit(fixed: Part, moving: Part, assembled_pose: np.ndarray,
                axis: np.ndarray | None) -> FitMeasure:
    """Measure the fit of ``moving`` in ``fixed`` at ``assembled_pose`` (see the module).

    Kept in this process by the meshes, the pose and the axis: opening a scene whose K is
    chosen measures the fit, and so does its fine level, a second or two each on parts of
    many triangles. Not on disk: a command refused after the scene opens leaves nothing in
    the cache.
    """
    from engine.cache import content_key

    pose = np.asarray(assembled_pose, np.float64).reshape(6)
    key = content_key("fit", {
        "fixed_vertices": np.asarray(fixed.vertices, np.float64),
        "fixed_faces": np.asarray(fixed.faces, np.int64),
        "moving_vertices": np.asarray(moving.vertices, np.float64),
        "moving_faces": np.asarray(moving.faces, np.int64),
        "pose": pose, "axis": None if axis is None else np.asarray(axis, np.float64)})
    with _FITS_LOCK:
        fit = _FITS.pop(key, None)
    if fit is None:
        fit = _measure_fit(fixed, moving, pose, axis)
    with _FITS_LOCK:
        _FITS[key] = fit
        while len(_FITS) > FITS_KEPT:
            _FITS.pop(next(iter(_FITS)))
    return replace(fit, box_lo=fit.box_lo.copy(), box_hi=fit.box_hi.copy())


def _measure_fit(fixed: Part, moving: Part, pose: np.ndarray,
                 axis: np.ndarray | None) -> FitMeasure:
    """The measure itself (see :func:`measure_fit`)."""
    rot = rotation_matrix(pose[3:])
    placed = _surface_points(moving, SAMPLES) @ rot.T + pose[:3]  # part 1's frame
    v2 = np.asarray(moving.vertices, np.float64) @ rot.T + pose[:3]
    size = max(float(np.max(np.ptp(np.asarray(fixed.vertices), axis=0))),
               float(np.max(np.ptp(v2, axis=0))))
    reach = REACH_FRACTION * float(np.min(np.ptp(v2, axis=0)))
    gap = _distances(fixed, placed)
    near = gap < reach
    fitting = near & (gap > FLUSH_FRACTION * size)  # flush faces rest, they do not fit
    for _ in range(2):  # narrow the reach to the fit's own gaps: a few times their median
        if fitting.sum() >= 8:
            tighter = fitting & (gap < GAP_REACH * float(np.median(gap[fitting])))
            if tighter.sum() >= 8:
                fitting = tighter
    zone = placed[fitting] if fitting.sum() >= 8 else placed[near] if near.sum() >= 8 else v2
    a = None if axis is None else np.asarray(axis, np.float64) / np.linalg.norm(axis)
    cylinder = None
    if a is None:
        width = float(np.min(np.ptp(zone, axis=0)))
    else:
        across = zone - np.outer(zone @ a, a)  # projected on the plane across the axis
        centred = across - across.mean(axis=0)
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        spread = centred @ vt[:2].T
        extents = np.ptp(spread, axis=0)
        width = float(np.min(extents))
        mid = across.mean(axis=0) + (0.5 * (spread.min(axis=0) + spread.max(axis=0))) @ vt[:2]
        along = zone @ a
        centre = mid + a * 0.5 * float(along.min() + along.max())
        radius = float(np.max(np.linalg.norm(across - mid, axis=1)))
        cylinder = (centre, a, radius, 0.5 * float(np.ptp(along)))
    open_gaps = gap[fitting]
    clearance = float(np.median(open_gaps)) if len(open_gaps) else None
    tightest = float(np.percentile(open_gaps, 10)) if len(open_gaps) else None
    return FitMeasure(size=size, box_lo=zone.min(axis=0), box_hi=zone.max(axis=0),
                      width=max(width, 1e-9 * size), clearance=clearance, tightest=tightest,
                      points=int(near.sum()), cylinder=cylinder)


def _odd_at_most(k: int) -> int:
    return k if k % 2 else k - 1


def modes_budget(rate_hz: float = 1000.0) -> tuple[int, str]:
    """The largest odd K the loop affords at ``rate_hz`` on this machine, and why.

    A GPU OpenCL device affords :data:`MODES_BUDGET_GPU`, the CPU
    :data:`MODES_BUDGET_CPU`, at 1 kHz; the per-pose sum scales with ``K^3``, so a slower
    loop affords ``(1000 / rate)^(1/3)`` times more.
    """
    gpu = False
    try:
        from engine.backend import get_backend

        gpu = bool(getattr(get_backend("opencl"), "is_gpu", False))
    except Exception:  # noqa: BLE001  (no OpenCL at all: the CPU's budget)
        gpu = False
    base = MODES_BUDGET_GPU if gpu else MODES_BUDGET_CPU
    k = _odd_at_most(int(base * (1000.0 / max(rate_hz, 1.0)) ** (1.0 / 3.0)))
    k = max(MIN_MODES, min(k, MAX_MODES - 1))
    where = "a GPU" if gpu else "the CPU"
    return k, f"the most the loop affords at {rate_hz:g} Hz on {where}"


@dataclass(frozen=True)
class Settings:
    """Settings chosen from the parts, each with its reason (lengths in the scene's unit)."""

    spacing: float
    modes: int
    tolerance: float | None
    reasons: dict[str, str]
    fit: FitMeasure


def _fft_size(parts: list[Part], spacing: float, padding: float) -> int:
    from engine.correlation.correlator import required_fft_size
    from engine.descriptor.store import grid_for_part

    shapes = [grid_for_part(p, spacing=spacing, padding=padding).shape for p in parts]
    return required_fft_size(tuple(shapes[0]), tuple(shapes[1]))


def choose_settings(scene: Scene, parts: list[Part], *, fit: FitMeasure | None = None,
                    budget: tuple[int, str] | None = None) -> Settings:
    """The grid spacing, K and STEP chord tolerance for a scene's two parts (see the module)."""
    if fit is None:
        fit = measure_fit(parts[0], parts[1], scene.assembled_pose, scene.insertion_axis)
    unit = scene.units
    reasons: dict[str, str] = {}
    wavelength = WAVELENGTH_PER_WIDTH * fit.width
    longest = max(float(np.max(np.ptp(np.asarray(p.vertices), axis=0))) for p in parts)
    lo, hi = GRID_RANGE
    spacing = wavelength / CELLS_PER_WAVELENGTH
    samples = longest / spacing
    if samples > hi:
        spacing = longest / hi
        why = (f"{hi} samples along the {longest:.4g} {unit} part, the most the descriptor "
               f"affords (a fifth of the fit's shortest wavelength, {wavelength:.3g} {unit}, "
               "would need more)")
    elif samples < lo:
        spacing = longest / lo
        why = f"{lo} samples along the {longest:.4g} {unit} part, the fewest that keep its shape"
    else:
        why = (f"five cells per shortest wavelength of the band, {WAVELENGTH_PER_WIDTH:g} of "
               f"the fit's width {fit.width:.4g} {unit}")
    spacing = float(f"{spacing:.4g}")  # as written into the scene: K follows from it
    if scene.gives("descriptor.spacing") and scene.descriptor.spacing is not None:
        spacing, why = float(scene.descriptor.spacing), "the scene's"  # K follows the scene's
    reasons["descriptor.spacing"] = why
    padding = scene.descriptor.padding
    size = _fft_size(parts, spacing, padding)
    half = math.ceil(size * spacing / wavelength)  # |k| reaching the wavelength
    need = 2 * half + 1
    k_max, budget_why = budget if budget is not None else modes_budget(
        scene.config.simulation.rate_hz)
    k_max = min(k_max, _odd_at_most(size))
    modes = max(MIN_MODES, min(need, k_max))
    shortest = size * spacing / max(1, k_max // 2)  # the budget's shortest wavelength
    if need > k_max and NEAR_WAVELENGTHS * fit.width < shortest < OUTLINE_WAVELENGTHS * fit.width:
        # the budget's band would half-resolve the fit: keep it smooth at the fit's scale,
        # so the part is drawn in by its outline (a band whose shortest wavelength is near
        # the fit's width rings there and can hold the part tilted)
        half_outline = max(1, math.floor(size * spacing / (OUTLINE_WAVELENGTHS * fit.width)))
        modes = max(MIN_MODES, min(2 * half_outline + 1, k_max))
        reasons["correlation.modes"] = (
            f"the fit's width {fit.width:.4g} {unit} asks for {need}, more than {k_max} "
            f"({budget_why}), whose band would half-resolve it: the shortest wavelength is "
            f"kept at {OUTLINE_WAVELENGTHS:g} times the fit's width, so the part is drawn in "
            "by its outline")
    elif need > k_max:
        reasons["correlation.modes"] = (
            f"{budget_why}; the fit's width {fit.width:.4g} {unit} asks for {need}, so the "
            "fit is resolved coarsely")
    else:
        reasons["correlation.modes"] = (
            f"the band reaches a wavelength of {wavelength:.3g} {unit}, 2.5 across the fit's "
            f"width {fit.width:.4g} {unit} (odd: a band symmetric about zero)")
    tolerance = None
    if fit.tightest is not None:
        third, floor = TOLERANCE_PER_GAP * fit.tightest, TOLERANCE_FLOOR * fit.size
        tolerance = max(third, floor)
        reasons["part.tolerance"] = (
            f"a third of the fit's tightest gap ({fit.tightest:.3g} {unit}; median clearance "
            f"{fit.clearance:.3g} {unit}): the tessellated parts stay apart" if third >= floor
            else f"{TOLERANCE_FLOOR:g} of the parts' size {fit.size:.4g} {unit}, the finest "
            f"kept (a third of the fit's tightest gap, {fit.tightest:.3g} {unit}, would "
            "tessellate curved faces into fans of slivers)")
    tolerance = None if tolerance is None else float(f"{tolerance:.3g}")
    return Settings(spacing=float(spacing), modes=int(modes), tolerance=tolerance,
                    reasons=reasons, fit=fit)


def _is_step(path: object) -> bool:
    return str(path).lower().endswith((".step", ".stp"))


def complete_scene(scene: Scene, *, budget: tuple[int, str] | None = None
                   ) -> tuple[Scene, list[Part]]:
    """Load a scene's parts and choose every setting the scene does not give from them.

    Returns the completed scene (its choices and their reasons in ``Scene.chosen``) and
    its parts. A scene of one part, or one that gives every setting chosen here, comes back
    as it is. ``budget`` is the largest K and why (default: :func:`modes_budget`). STEP
    parts without a ``tolerance`` are loaded again at the chosen one, and the fit measured
    again on them.
    """
    from engine.scene.parts import load_scene_parts_and_units

    parts, file_units = load_scene_parts_and_units(scene)
    if len(parts) < 2:
        return scene, parts
    wants = [key for key in ("descriptor.grid", "correlation.modes")
             if not (scene.gives(key) or (key == "descriptor.grid"
                                          and scene.gives("descriptor.spacing")))]
    steps = [i for i, spec in enumerate(scene.parts)
             if spec.tolerance is None and _is_step(spec.file) and scene.given is not None]
    if not wants and not steps:
        return scene, parts
    settings = choose_settings(scene, parts, budget=budget)
    chosen: list[tuple[str, str, str]] = []
    if steps and settings.tolerance is not None:
        specs = list(scene.parts)
        for i in steps:
            factor = LENGTH_UNITS[scene.units] / LENGTH_UNITS[file_units[i]]
            specs[i] = replace(specs[i], tolerance=settings.tolerance * factor)
            chosen.append((f"part.{i}.tolerance",
                           f"{settings.tolerance:.3g} {scene.units}",
                           settings.reasons["part.tolerance"]
                           + f"; written in the file's unit, {file_units[i]}"))
        scene = replace(scene, parts=tuple(specs))
        parts, _ = load_scene_parts_and_units(scene)
        settings = choose_settings(scene, parts, budget=budget)
    descriptor, correlation = scene.descriptor, scene.correlation
    if "descriptor.grid" in wants:
        descriptor = DescriptorParams(sigma=descriptor.sigma, penalty=descriptor.penalty,
                                      lambda_out=descriptor.lambda_out, grid=None,
                                      spacing=settings.spacing, padding=descriptor.padding)
        chosen.append(("descriptor.spacing", f"{settings.spacing:.4g} {scene.units}",
                       settings.reasons["descriptor.spacing"]))
    if "correlation.modes" in wants:
        correlation = replace(correlation, modes=settings.modes)
        chosen.append(("correlation.modes", str(settings.modes),
                       settings.reasons["correlation.modes"]))
    chosen += [entry for entry in scale_free_choices(descriptor)
               if not scene.gives(entry[0])]
    return (replace(scene, descriptor=descriptor, correlation=correlation,
                    chosen=scene.chosen + tuple(chosen)), parts)


def scale_free_choices(descriptor: DescriptorParams) -> list[tuple[str, str, str]]:
    """``(key, value, reason)`` for the descriptor's settings that no part's size changes.

    sigma, the penalty and the padding are measured in the parts' own terms (a fraction of
    the distance to the surface, a ratio of weights, cells of the grid chosen from the fit),
    so the engine's values hold on any pair; each is said with why.
    """
    return [
        ("descriptor.sigma", f"{descriptor.sigma:g}",
         "the skeletal density's width relative to the distance to the surface, so the same "
         "on a part of any size; the grid, chosen from the fit, sets how finely it is seen"),
        ("descriptor.penalty", f"{descriptor.penalty:g}",
         "an overlap weighs this many times a gap, a ratio of weights that no size changes; "
         "floors and stops are held by the walls (docs/fine_level.md), so it stays moderate "
         "(10 drew dovetails and T-slots off their ways)"),
        ("descriptor.padding", f"{descriptor.padding:g} cells",
         "the descriptor's outside tail fades within a few cells, so the periodic images of "
         "the two parts stay apart over the landscape's range"),
    ]


__all__ = ["FitMeasure", "Settings", "choose_settings", "complete_scene", "measure_fit",
           "modes_budget", "scale_free_choices"]
