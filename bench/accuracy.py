"""`skelasm bench accuracy`: what accuracy costs in time, for every dial.

For each scene (by default one CAD-tessellated pair from ``assets/real`` and one bundled
pair) and each dial, the dial is varied around the scene's setting with everything else
held, and the bench measures the time the dial costs (descriptor seconds, spectra seconds,
microseconds per full 6-DOF evaluation, as applies) and the error of energy, force and
torque at a few poses near the seat and in the approach against a reference setting:

- ``modes``: K, the Fourier modes kept per axis. Reference: the whole FFT lattice
  (``K = N``, nothing truncated; the numpy reference sum).
  Also printed: the share of the correlation spectrum's weight ``|rho1^| |rho2^|`` outside
  the kept cube, and of ``|k| |rho1^| |rho2^|`` for the force
  (:func:`engine.correlation.truncation.truncation_profile`), the indicator the window
  shows beside K, so it can be read against the measured errors.
- ``grid``: samples along the largest part (the grid spacing). Reference: the finest.
- ``sigma``: the skeletal density's width. A different sigma is a different energy, not a
  less accurate one: its rows give the time and the *change* against the scene's sigma
  (marked), and the seat shift, which is what a modelling choice should not move.
- ``quadrature``: the descriptor's quadrature tolerance. There is no public knob: the
  bench sets the opening ratio ``THETA`` (and ``THETA_NODE``) of
  :mod:`engine.descriptor.constants`, which the kernels read at each call, for the time of
  one computation (method "tree", every point evaluated), plus the adaptive sampler's
  tolerance ``ADAPTIVE_TOLERANCE`` (method "adaptive", the default). Reference: the
  smallest THETA of the sweep. Errors are given for part 2's descriptor (relative L2) and,
  downstream, for energy, force and torque.
- ``interpolation``: the rotated spectrum's lattice, ``refine`` (the refined table's
  factor) and ``oversample`` (part 2's lattice). Reference: the finest of the sweep.
- ``backend``: per pose numpy, numba, opencl (reference: numpy, the reference
  implementation), and per descriptor numba and opencl (reference: numba).

Errors are ``max over poses |q - q_ref| / max over poses |q_ref|`` (q = energy, force
vector, torque vector), the force direction error in degrees (largest over poses whose
reference force is at least a tenth of the largest), and the seat shift: the distance, in
grid cells, from the assembled pose to the energy's minimum along the insertion axis
(sampled every quarter cell within 3 cells, "> 3" when the
minimum lies at the window's edge; a free axis along the insertion makes it
ill-defined, so it is left out for such scenes).

Prints one markdown table per scene and dial and writes one PNG (error against time,
log-log, a panel per dial). On a terminal a line shows progress and the time left.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from engine.backend import choices

DIALS = ("modes", "grid", "sigma", "quadrature", "interpolation", "backend")
DEFAULT_SCENES = ("real/iso_pin_5_H7h6_through", "peg_in_hole")
ASSETS = Path(__file__).resolve().parents[1] / "assets"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench accuracy`` to ``parser``."""
    parser.add_argument("--scenes", nargs="*", default=None,
                        help="scene files (default: assets/real/iso_pin_5_H7h6_through and "
                             "assets/peg_in_hole)")
    parser.add_argument("--dials", nargs="*", default=list(DIALS), choices=DIALS,
                        help="dials to sweep (default: all)")
    parser.add_argument("--grid", type=int, default=16,
                        help="base samples along the largest part (the scenes' own are "
                             "finer; 16 keeps the run to minutes on two cores)")
    parser.add_argument("--modes", type=int, default=16, help="base K (modes per axis)")
    parser.add_argument("--mode-sweep", type=int, nargs="*", default=[4, 8, 12, 16, 24, 32])
    parser.add_argument("--grid-sweep", type=int, nargs="*", default=[10, 13, 16, 20])
    parser.add_argument("--sigma-sweep", type=float, nargs="*", default=[0.25, 0.5, 1.0])
    parser.add_argument("--theta-sweep", type=float, nargs="*", default=[0.7, 0.5, 0.35, 0.2],
                        help="quadrature opening ratios THETA (the smallest is the reference)")
    parser.add_argument("--adaptive-tolerances", type=float, nargs="*", default=[1e-2, 3e-3],
                        help="adaptive sampler tolerances (fractions of rms rho)")
    parser.add_argument("--interpolation-sweep", nargs="*",
                        default=["1:1", "1:2", "2:2", "4:2"],
                        help="REFINE:OVERSAMPLE pairs (the last is the reference; 4:3 adds "
                             "part 2's lattice at q = 2, half a minute of spectra here)")
    parser.add_argument("--poses", type=int, default=200,
                        help="evaluations timed per row (median)")
    parser.add_argument("-o", "--output", default="bench_accuracy.png", help="plot (PNG)")


# ---------------------------------------------------------------------------- rows
@dataclass
class Row:
    """One setting of one dial: its times and its errors against the dial's reference.

    ``None`` where a quantity does not apply (a dial that does not change the descriptors
    has no descriptor seconds). ``reference`` marks the reference row (errors 0).
    """

    scene: str
    dial: str
    setting: str
    descriptor_s: float | None = None
    spectra_s: float | None = None
    pose_us: float | None = None
    energy: float | None = None
    force: float | None = None
    torque: float | None = None
    direction_deg: float | None = None
    seat_cells: float | None = None
    rho_l2: float | None = None
    outside: float | None = None
    outside_force: float | None = None
    reference: bool = False
    note: str = ""


@dataclass
class Pair:
    """A scene's parts at one descriptor setting, and what they took."""

    fixed: Any
    moving: Any
    seconds: float


@dataclass
class Case:
    """A scene loaded for the bench: parts, poses, the base grid's cell, the seat line."""

    name: str
    scene: Any
    parts: list
    longest: float
    poses: list[tuple[np.ndarray, np.ndarray]]
    line: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    line_step: float = 0.0
    cell: float = 1.0


def load_case(path: str, grid: int) -> Case:
    """Read a scene and place the error poses: seat, near it, entering, approach."""
    from engine.pose import rotation_matrix
    from engine.scene import load_scene, load_scene_parts

    scene = load_scene(path)
    parts = load_scene_parts(scene)
    longest = max(float(np.max(p.extent)) for p in parts)
    seat = np.asarray(scene.assembled_pose, dtype=float)
    axis = (np.asarray(scene.insertion_axis, dtype=float) if scene.insertion_axis is not None
            else np.array([0.0, 0.0, -1.0]))
    axis = axis / np.linalg.norm(axis)
    side = np.cross(axis, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 0.1:
        side = np.cross(axis, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    h = longest / grid
    span = float(np.max(parts[1].extent))
    base = rotation_matrix(seat[3:])
    poses = []
    # seat; half a cell aside, turned a little; a quarter and half the part's length back
    for back, aside, turn in ((0.0, 0.0, 0.0), (0.0, 0.5 * h, 0.03),
                              (0.25 * span, 0.3 * h, 0.05), (0.5 * span, 0.0, 0.1)):
        rot = rotation_matrix(turn * side) @ base
        poses.append((rot, seat[:3] - back * axis + aside * side))
    name = os.path.basename(os.path.dirname(os.path.abspath(path)))
    case = Case(name=name, scene=scene, parts=parts, longest=longest, poses=poses, cell=h)
    free = {str(a).lower() for a in (scene.seat.free_axes or ())}
    dominant = "xyz"[int(np.argmax(np.abs(axis)))]
    if dominant not in free:
        case.line_step = 0.25 * h
        case.line = [(base, seat[:3] + s * case.line_step * axis) for s in range(-12, 13)]
    return case


def warm_up(case: Case, method: str, backend: str = "numba") -> None:
    """Compile the descriptor kernels for ``method`` on a 2^3 grid, so no timing holds it."""
    from engine.descriptor import descriptor_for_part
    from engine.grid import Grid

    part = case.parts[1]
    grid = Grid(tuple(np.asarray(part.bounds[0], dtype=float)), case.longest / 4, (2, 2, 2))
    descriptor_for_part(part, grid, case.scene.descriptor, backend=backend, method=method,
                        use_cache=False)


def descriptors(case: Case, grid: int, *, sigma: float | None = None, backend: str = "numba",
                method: str = "adaptive", use_cache: bool = True) -> Pair:
    """Both parts' descriptors at ``grid`` samples along the largest part (seconds: both)."""
    from engine.descriptor import descriptor_for_part, grid_for_part

    params = case.scene.descriptor
    if sigma is not None:
        params = replace(params, sigma=sigma)
    h = case.longest / grid
    start = time.perf_counter()
    out = [descriptor_for_part(p, grid_for_part(p, spacing=h, padding=params.padding), params,
                               backend=backend, method=method, use_cache=use_cache)
           for p in case.parts[:2]]
    return Pair(out[0], out[1], time.perf_counter() - start)


def correlator(pair: Pair, modes: int, *, refine: int = 2, oversample: float = 2.0,
               backend: str = "numba") -> tuple[Any, float]:
    """A Correlator built without the spectrum cache, and the seconds it took."""
    from engine.correlation import Correlator

    start = time.perf_counter()
    corr = Correlator(pair.fixed, pair.moving, modes=modes, refine=refine,
                      oversample=oversample, fine_modes=max(24, modes), backend=backend,
                      use_cache=False)
    return corr, time.perf_counter() - start


def evaluate(corr, poses) -> np.ndarray:
    """(n, 7) float64: energy, force, torque at each pose."""
    out = []
    for rot, t in poses:
        e = corr.evaluate(rot, t)
        torque = e.torque if e.torque is not None else np.zeros(3)
        out.append(np.concatenate([[e.energy], e.force, torque]))
    return np.asarray(out, dtype=np.float64)


def pose_cost(corr, case: Case, count: int, *, warm: bool = True) -> float:
    """Median microseconds per evaluation over ``count`` poses jittered about the error poses."""
    rng = np.random.default_rng(0)
    poses = [(rot, t + rng.normal(scale=0.3 * case.cell, size=3))
             for rot, t in (case.poses * (count // len(case.poses) + 1))[:count]]
    if warm:
        evaluate(corr, poses[:5])
    return float(np.median([corr.evaluate(rot, t).microseconds for rot, t in poses]))


def errors(values: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Energy, force and torque errors of (n, 7) ``values`` against ``reference``."""
    out = {}
    for key, cols in (("energy", slice(0, 1)), ("force", slice(1, 4)),
                      ("torque", slice(4, 7))):
        ref = np.linalg.norm(reference[:, cols], axis=1)
        diff = np.linalg.norm(values[:, cols] - reference[:, cols], axis=1)
        scale = float(np.max(ref))
        out[key] = float(np.max(diff) / scale) if scale > 0 else float("nan")
    f, f_ref = values[:, 1:4], reference[:, 1:4]
    mag, mag_ref = np.linalg.norm(f, axis=1), np.linalg.norm(f_ref, axis=1)
    strong = mag_ref >= 0.1 * np.max(mag_ref) if np.max(mag_ref) > 0 else mag_ref > 0
    cos = np.sum(f * f_ref, 1) / np.maximum(mag * mag_ref, 1e-300)
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    out["direction_deg"] = float(np.max(angle[strong])) if np.any(strong) else float("nan")
    return out


def seat_shift(corr, case: Case) -> float | None:
    """Cells from the seat to the energy's minimum along the insertion axis.

    None when the insertion axis is free; ``inf`` when the minimum lies at the sampled
    window's edge (farther than the window reaches).
    """
    if not case.line:
        return None
    energy = evaluate(corr, case.line)[:, 0]
    lowest = int(np.argmin(energy))
    if lowest in (0, len(case.line) - 1):
        return math.inf
    return abs(lowest - len(case.line) // 2) * case.line_step / case.cell


def rho_error(rho: np.ndarray, reference: np.ndarray) -> float:
    """Relative L2 difference of two descriptors on one grid."""
    return float(np.linalg.norm(rho - reference) / np.linalg.norm(reference))


def _fill(row: Row, values: np.ndarray, reference: np.ndarray) -> Row:
    for key, value in errors(values, reference).items():
        setattr(row, key, value)
    return row


# ---------------------------------------------------------------------------- dials
def sweep_modes(case: Case, base: Pair, args) -> list[Row]:
    """K around the scene's: per-pose microseconds, errors against every mode of the lattice.

    The reference is the full FFT lattice (``K = N``, the numpy reference sum: nothing
    truncated), so the error is the truncation error itself.
    """
    from engine.correlation.truncation import truncation_profile

    sweep = sorted(set(args.mode_sweep))
    corr, spectra_s = correlator(base, max(sweep))
    profile = truncation_profile(base.fixed, base.moving, corr.size)
    profile_force = truncation_profile(base.fixed, base.moving, corr.size, quantity="force")
    corr.use_backend("numpy")
    corr.set_modes(corr.size)
    reference = evaluate(corr, case.poses)
    full = Row(case.name, "modes", f"K = {corr.size} (full lattice, numpy)",
               spectra_s=spectra_s, pose_us=pose_cost(corr, case, 2, warm=False), outside=0.0,
               outside_force=0.0, reference=True, note="seat shift not run: a second per pose")
    corr.use_backend("numba")
    rows = []
    for k in sweep:
        if k >= corr.size:
            continue
        corr.set_modes(k)
        row = Row(case.name, "modes", f"K = {k}", spectra_s=spectra_s,
                  pose_us=pose_cost(corr, case, args.poses), seat_cells=seat_shift(corr, case),
                  outside=float(profile[k]), outside_force=float(profile_force[k]))
        rows.append(_fill(row, evaluate(corr, case.poses), reference))
    return [*rows, _fill(full, reference, reference)]


def sweep_grid(case: Case, args) -> list[Row]:
    """Samples along the largest part: descriptor and spectra seconds, errors vs the finest."""
    sweep = sorted(set(args.grid_sweep))
    results = []
    for g in sweep:
        pair = descriptors(case, g, use_cache=False)
        corr, spectra_s = correlator(pair, args.modes)
        results.append((g, pair, spectra_s, pose_cost(corr, case, args.poses),
                        evaluate(corr, case.poses), seat_shift(corr, case)))
    reference = results[-1][4]
    return [_fill(Row(case.name, "grid", f"{g} (h = {case.longest / g:.3g})",
                      descriptor_s=pair.seconds, spectra_s=s, pose_us=us, seat_cells=seat,
                      reference=g == sweep[-1]), values, reference)
            for g, pair, s, us, values, seat in results]


def sweep_sigma(case: Case, args) -> list[Row]:
    """sigma: descriptor seconds, the change against the scene's sigma, the seat shift."""
    own = float(case.scene.descriptor.sigma)
    sweep = sorted(set(args.sigma_sweep) | {own})
    results = {}
    for s in sweep:
        pair = descriptors(case, args.grid, sigma=s, use_cache=False)
        corr, spectra_s = correlator(pair, args.modes)
        results[s] = (pair.seconds, spectra_s, pose_cost(corr, case, args.poses),
                      evaluate(corr, case.poses), seat_shift(corr, case))
    reference = results[own][3]
    return [_fill(Row(case.name, "sigma", f"sigma = {s:g}", descriptor_s=d, spectra_s=sp,
                      pose_us=us, seat_cells=seat, reference=s == own,
                      note="change, not error"), values, reference)
            for s, (d, sp, us, values, seat) in results.items()]


@contextlib.contextmanager
def quadrature(theta: float | None = None, tolerance: float | None = None):
    """Set the descriptor's quadrature constants for one computation (restored after)."""
    from engine.descriptor import constants

    saved = (constants.THETA, constants.THETA_NODE, constants.ADAPTIVE_TOLERANCE)
    try:
        if theta is not None:
            constants.THETA = constants.THETA_NODE = theta
        if tolerance is not None:
            constants.ADAPTIVE_TOLERANCE = tolerance
        yield
    finally:
        constants.THETA, constants.THETA_NODE, constants.ADAPTIVE_TOLERANCE = saved


def sweep_quadrature(case: Case, base: Pair, args) -> list[Row]:
    """THETA (method tree) and the adaptive tolerance: part 2's seconds, errors vs the finest."""
    from engine.descriptor import descriptor_for_part

    grid = base.moving.grid
    part = case.parts[1]
    settings = [(f"tree, THETA = {t:g}", "tree", t, None)
                for t in sorted(set(args.theta_sweep), reverse=True)]
    settings += [(f"adaptive, tol = {a:g}", "adaptive", None, a)
                 for a in sorted(set(args.adaptive_tolerances), reverse=True)]
    finest = min(args.theta_sweep)
    warm_up(case, "tree")
    results = {}
    for label, method, theta, tol in settings:
        with quadrature(theta, tol):
            start = time.perf_counter()
            moving = descriptor_for_part(part, grid, case.scene.descriptor, backend="numba",
                                         method=method, use_cache=False)
            seconds = time.perf_counter() - start
        corr, _ = correlator(Pair(base.fixed, moving, 0.0), args.modes)
        results[label] = (seconds, moving.rho, evaluate(corr, case.poses))
    ref_label = f"tree, THETA = {finest:g}"
    ref_rho, reference = results[ref_label][1], results[ref_label][2]
    return [_fill(Row(case.name, "quadrature", label, descriptor_s=s,
                      rho_l2=rho_error(rho, ref_rho), reference=label == ref_label,
                      note="part 2 only"), values, reference)
            for label, (s, rho, values) in results.items()]


def sweep_interpolation(case: Case, base: Pair, args) -> list[Row]:
    """refine:oversample: spectra seconds and per-pose microseconds, errors vs the finest."""
    results = []
    for text in args.interpolation_sweep:
        refine, oversample = text.split(":")
        corr, spectra_s = correlator(base, args.modes, refine=int(refine),
                                     oversample=float(oversample))
        label = (f"refine {int(refine)}, oversample {float(oversample):g} "
                 f"(q = {corr.spectra.oversample_factor})")
        results.append((label, spectra_s, pose_cost(corr, case, args.poses),
                        evaluate(corr, case.poses)))
    reference = results[-1][3]
    return [_fill(Row(case.name, "interpolation", label, spectra_s=s, pose_us=us,
                      reference=i == len(results) - 1), values, reference)
            for i, (label, s, us, values) in enumerate(results)]


def sweep_backend(case: Case, base: Pair, args) -> list[Row]:
    """Per pose numpy/numba/opencl (vs numpy) and descriptors numba/opencl (vs numba)."""
    corr, spectra_s = correlator(base, args.modes, backend="numpy")
    reference = evaluate(corr, case.poses)
    rows = []
    for name in choices("per_pose")[:-1]:  # every per-pose backend, the reference first
        try:
            corr.use_backend(name)
        except Exception as exc:  # noqa: BLE001 - an absent backend is reported, not fatal
            rows.append(Row(case.name, "backend", f"per pose: {name}",
                            note=f"not measured: {str(exc).splitlines()[0][:60]}"))
            continue
        count = max(5, args.poses // 20) if name == "numpy" else args.poses
        row = Row(case.name, "backend", f"per pose: {name}", pose_us=pose_cost(corr, case, count),
                  reference=name == "numpy")
        rows.append(_fill(row, evaluate(corr, case.poses), reference))
    pairs = {}
    for name in choices("descriptor")[:-1]:
        try:
            warm_up(case, "adaptive", name)
            pairs[name] = descriptors(case, args.grid, backend=name, use_cache=False)
        except Exception as exc:  # noqa: BLE001
            rows.append(Row(case.name, "backend", f"descriptor: {name}",
                            note=f"not measured: {str(exc).splitlines()[0][:60]}"))
    for name, pair in pairs.items():
        c, _ = correlator(pair, args.modes)
        row = Row(case.name, "backend", f"descriptor: {name}", descriptor_s=pair.seconds,
                  rho_l2=rho_error(pair.moving.rho, pairs["numba"].moving.rho),
                  reference=name == "numba")
        rows.append(_fill(row, evaluate(c, case.poses), evaluate(
            correlator(pairs["numba"], args.modes)[0], case.poses)))
    return rows


# ---------------------------------------------------------------------------- output
COLUMNS = ("setting", "descriptor s", "spectra s", "per pose us", "energy err", "force err",
           "torque err", "F dir (deg)", "seat shift (cells)", "rho rel L2", "E weight outside",
           "F weight outside")


def _cell(value: float | None, fmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and math.isnan(value):
        return "n/a"
    if value == math.inf:
        return "> 3"
    return format(value, fmt)


def table(rows: list[Row]) -> str:
    """A markdown table of one scene's dial (reference rows marked "(ref)")."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|---|" + "---:|" * (len(COLUMNS) - 1)]
    for r in rows:
        setting = r.setting + (" (ref)" if r.reference else "") + (
            f" [{r.note}]" if r.note else "")
        cells = [setting, _cell(r.descriptor_s, ".2f"), _cell(r.spectra_s, ".2f"),
                 _cell(r.pose_us, ".1f"), _cell(r.energy, ".2e"), _cell(r.force, ".2e"),
                 _cell(r.torque, ".2e"), _cell(r.direction_deg, ".2f"),
                 _cell(r.seat_cells, ".2f"), _cell(r.rho_l2, ".2e"), _cell(r.outside, ".2e"),
                 _cell(r.outside_force, ".2e")]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def cost_of(row: Row) -> tuple[float | None, str]:
    """The time a row's dial costs, and its axis label (what the plot puts on x)."""
    if row.dial == "modes" or (row.dial == "backend" and row.setting.startswith("per pose")):
        return row.pose_us, "us per pose"
    if row.dial == "interpolation":  # a finer table costs its build; per pose it barely shows
        return row.spectra_s, "spectra s (Correlator set-up)"
    if row.dial == "backend":
        return None, ""
    return row.descriptor_s, "descriptor s"


def _series(row: Row) -> str:
    """The curve a row belongs to within its dial (quadrature: tree or adaptive)."""
    if row.dial == "quadrature":
        return row.setting.split(",")[0]
    return ""


def plot(rows: list[Row], path: str) -> None:
    """Force error (solid) and energy error (dashed) against time, a panel per dial.

    Points are joined in the order of the sweep (not of the time, which is noisy), one
    curve per scene (and per method for the quadrature); reference rows (error 0) are left
    out.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    dials = [d for d in DIALS if any(r.dial == d for r in rows)]
    cols = min(3, len(dials))
    nrows = math.ceil(len(dials) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(4.6 * cols, 3.8 * nrows), dpi=110,
                             squeeze=False)
    scenes = list(dict.fromkeys(r.scene for r in rows))
    for ax, dial in zip(axes.ravel(), dials, strict=False):
        xlabel = ""
        curves: dict[tuple[str, str], list[tuple[float, float, float, str]]] = {}
        for r in rows:
            x, label = cost_of(r)
            if r.dial != dial or x is None or r.reference or not r.force:
                continue
            if not (r.force > 0 and math.isfinite(r.force)):
                continue
            curves.setdefault((r.scene, _series(r)), []).append(
                (x, r.force, max(r.energy or 0.0, 1e-12), r.setting))
            xlabel = label
        for (scene, series), points in curves.items():
            colour = f"C{scenes.index(scene)}"
            style = ":" if series == "adaptive" else "-"
            name = f"{scene} {series}".strip()
            ax.plot([p[0] for p in points], [p[1] for p in points], "o" + style, color=colour,
                    label=f"{name}: force")
            ax.plot([p[0] for p in points], [p[2] for p in points], "s--", color=colour,
                    alpha=0.5, label=f"{name}: energy")
            for x, y, _e, text in points:
                short = (text.split(" (")[0].replace("per pose: ", "").replace("tree, ", "")
                         .replace("adaptive, ", "").replace("oversample", "q"))
                ax.annotate(short, (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_title(dial + (" (change against the scene's sigma)" if dial == "sigma" else ""),
                     fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        ax.set_ylabel("change" if dial == "sigma" else "error against the reference",
                      fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=5)
    for ax in axes.ravel()[len(dials):]:
        ax.axis("off")
    fig.suptitle("What accuracy costs in time (solid: force, dashed: energy; the reference "
                 "rows, error 0, are not drawn)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


class Progress:
    """One line on a terminal: the task, how many are done, the time left (from the mean)."""

    def __init__(self, total: int, stream=None) -> None:
        self.total, self.done, self.start = total, 0, time.perf_counter()
        self.stream = stream or sys.stderr
        self.live = bool(getattr(self.stream, "isatty", lambda: False)())

    def begin(self, what: str) -> None:
        """Show that ``what`` starts, with the time so far and the time left."""
        if not self.live:
            return
        elapsed = time.perf_counter() - self.start
        left = (f", about {elapsed / self.done * (self.total - self.done):.0f} s left"
                if self.done else "")
        self.stream.write(f"\r\033[K[{self.done}/{self.total}] {what} ({elapsed:.0f} s"
                          f"{left})")
        self.stream.flush()

    def end(self) -> None:
        """Count one task done (the line is cleared after the last)."""
        self.done += 1
        if self.live and self.done == self.total:
            self.stream.write("\r\033[K")
            self.stream.flush()


def measure(path: str, args, progress: Progress | None = None) -> list[Row]:
    """Every asked dial of one scene (rows in dial order)."""
    case = load_case(path, args.grid)
    base = descriptors(case, args.grid)
    warm_up(case, "adaptive")  # base may have come from the cache
    rows: list[Row] = []
    sweeps = {
        "modes": lambda: sweep_modes(case, base, args),
        "grid": lambda: sweep_grid(case, args),
        "sigma": lambda: sweep_sigma(case, args),
        "quadrature": lambda: sweep_quadrature(case, base, args),
        "interpolation": lambda: sweep_interpolation(case, base, args),
        "backend": lambda: sweep_backend(case, base, args),
    }
    for dial in DIALS:
        if dial not in args.dials:
            continue
        if progress is not None:
            progress.begin(f"{case.name}: {dial}")
        rows += sweeps[dial]()
        if progress is not None:
            progress.end()
    return rows


def run(args: argparse.Namespace) -> int:
    """Sweep every dial of every scene; print the tables, write the plot. Returns 0."""
    from engine.errors import InputError

    folder = os.path.dirname(os.path.abspath(args.output))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise InputError(f"{args.output}: the folder {folder} is missing or not writable; "
                         "pass -o with a writable folder")
    if args.modes not in args.mode_sweep:
        args.mode_sweep = [*args.mode_sweep, args.modes]
    paths = args.scenes or [str(ASSETS / s / "scene.toml") for s in DEFAULT_SCENES]
    progress = Progress(len(paths) * len(args.dials))
    rows: list[Row] = []
    for path in paths:
        rows += measure(path, args, progress)
    print(f"Base: grid {args.grid} samples along the largest part, K = {args.modes}, numba "
          "unless a row says otherwise. Errors: largest over the poses (seat, near it, "
          "entering, approach) of |q - q_ref| / largest |q_ref|.")
    for scene in dict.fromkeys(r.scene for r in rows):
        for dial in DIALS:
            chosen = [r for r in rows if r.scene == scene and r.dial == dial]
            if chosen:
                print(f"\n### {scene}: {dial}\n")
                print(table(chosen))
    plot(rows, args.output)
    print(f"\nwrote {args.output}")
    return 0
