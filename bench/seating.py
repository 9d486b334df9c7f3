"""`skelasm bench seating`: whether each real pair seats from a misaimed push.

For each pair of the real-fit suite (``assets/real/*/scene.toml``): the proxy is aimed 3 %
of the moving part's width sideways and tilted 3 degrees, then pushed along the insertion
axis to the assembled depth in 2 s and held (5 simulated seconds in all by default), the
simulation stepped headless at the scene's rate. The final pose is compared with the
assembled pose in the axes the fit constrains (:data:`FITS`: a through hole leaves the
translation along its axis free, a round fit the rotation about it): the position error in
% of the moving part's width along the aim's direction, and the tilt in degrees. Guided
(skeletal) beside collision-only. Prints a markdown table, writes a PNG (both errors per
pair, guided and collision-only) and shows progress with the time left on a terminal.

Seated means within :data:`SEAT_FRACTION` of the width and :data:`SEAT_DEGREES` of tilt.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "assets" / "real"

#: Seated: constrained position error within this fraction of the width ...
SEAT_FRACTION = 0.02
#: ... and constrained tilt within this many degrees.
SEAT_DEGREES = 0.5
#: The misaim: sideways offset (fraction of the width) and tilt (degrees) of the proxy.
OFFSET_FRACTION, TILT_DEGREES = 0.03, 3.0
#: The push to the assembled depth takes this long (s); the rest of the run holds it there.
PUSH_SECONDS = 2.0

_AXES = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True)
class Fit:
    """What a pair's fit leaves free, in part 1's frame.

    Attributes
    ----------
    free : tuple of str
        Free axes among ``tx ty tz rx ry rz``.
    lateral : (3,) tuple or None
        Direction the proxy is aimed off (None: the protocol's default, the insertion axis
        crossed with the coordinate axis least aligned with it).
    misfit : (6,) tuple
        A small misalignment from the assembled pose that makes the parts interpenetrate
        (used by the tests: beyond the clearance in a constrained axis).
    """

    free: tuple[str, ...]
    lateral: tuple[float, float, float] | None = None
    misfit: tuple[float, ...] = (0.1, 0.0, 0.0, 0.0, 0.0, 0.0)


#: The fits of the suite, by folder of assets/real.
FITS: dict[str, Fit] = {
    "iso_pin_5_H7h6_through": Fit(("tz", "rz")),
    "iso_shaft_20_H7g6_blind": Fit(("rz",)),
    "iso_spigot_50_H7h6": Fit(("rz",)),
    "iso_sleeve_30_H7g6_thinwall": Fit(("tz", "rz")),
    "keyed_hub_20": Fit(()),
    "spline_6x23x26": Fit(("tz",)),
    "rect_peg_10x16_H7g6": Fit(()),
    "dovetail_60_slide": Fit(("ty",), lateral=(1.0, 0.0, 0.0)),
    "factory_round_peg_8mm_loose": Fit(("tz", "rz")),
    "factory_round_peg_16mm_tight": Fit(("tz", "rz"), misfit=(0.3, 0, 0, 0, 0, 0)),
    "factory_rect_peg_8mm_loose": Fit(("tz",), misfit=(0.15, 0, 0, 0, 0, 0)),
    "factory_rect_peg_12mm_tight": Fit(("tz",), misfit=(0.15, 0, 0, 0, 0, 0)),
}


@dataclass(frozen=True)
class SeatingResult:
    """One run's outcome; lengths in the scene's unit, angles in degrees."""

    pair: str
    guidance: str
    width: float            # moving part's extent along the aim's direction
    position_error: float   # norm over the constrained translation axes
    lateral_error: float    # its part across the insertion axis
    axial_error: float      # signed, along the insertion axis (0 when that axis is free)
    tilt_deg: float         # rotation error in the constrained rotation axes
    final_pose: tuple[float, ...]
    modes: int
    seconds: float          # simulated
    wall_seconds: float

    @property
    def position_percent(self) -> float:
        """Position error in % of the width."""
        return 100.0 * self.position_error / self.width

    @property
    def seated(self) -> bool:
        """Within :data:`SEAT_FRACTION` of the width and :data:`SEAT_DEGREES`."""
        return (self.position_error <= SEAT_FRACTION * self.width
                and self.tilt_deg <= SEAT_DEGREES)


def pair_names() -> list[str]:
    """Folders of assets/real that hold a scene, sorted."""
    return sorted(p.parent.name for p in REAL.glob("*/scene.toml"))


def misaim(axis: np.ndarray, lateral: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """(lateral, tilt_axis) unit vectors of the protocol for an insertion ``axis`` (3,)."""
    axis = axis / np.linalg.norm(axis)
    if lateral is None:
        helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
        lateral = np.cross(axis, helper)
    lateral = np.asarray(lateral, float)
    lateral = lateral / np.linalg.norm(lateral)
    tilt_axis = np.cross(axis, lateral)
    return lateral, tilt_axis / np.linalg.norm(tilt_axis)


def constrained_errors(error: np.ndarray, axis: np.ndarray, free: tuple[str, ...]
                       ) -> tuple[float, float, float, float]:
    """(position, lateral, axial, tilt_deg) of a pose error (6,) in the target's frame.

    Free translation axes are dropped from the position error. The tilt is the whole
    rotation angle when no rotation is free, the angle the part's free rotation axis has
    turned when one is, and 0 when all are.
    """
    from scipy.spatial.transform import Rotation

    t = np.array(error[:3], float)
    for i, name in enumerate(_AXES[:3]):
        if name in free:
            t[i] = 0.0
    axis = axis / np.linalg.norm(axis)
    axial = float(t @ axis)
    lateral = float(np.linalg.norm(t - axial * axis))
    rot = Rotation.from_rotvec(np.array(error[3:], float))
    free_rot = [i for i, name in enumerate(_AXES[3:]) if name in free]
    if not free_rot:
        tilt = float(np.linalg.norm(error[3:]))
    elif len(free_rot) == 1:
        a = np.eye(3)[free_rot[0]]
        tilt = float(np.arccos(np.clip(rot.apply(a) @ a, -1.0, 1.0)))
    else:
        tilt = 0.0
    return float(np.linalg.norm(t)), lateral, axial, math.degrees(tilt)


def seating_run(name: str, guidance: str = "skeletal", *, seconds: float = 5.0,
                modes: int | None = None, backend: str = "auto",
                progress=None) -> SeatingResult:
    """Run the misaim protocol on one pair of assets/real (see the module docstring).

    ``progress(fraction)`` is called as the simulation advances.
    """
    from engine.devices import TrajectoryDevice
    from engine.pose import relative_pose
    from engine.runtime import EngineLoop, open_scene
    from engine.sim import build_simulation

    fit = FITS[name]
    handle = open_scene(REAL / name / "scene.toml")
    cfg = handle.config
    handle = replace(handle, config=replace(cfg, effects=replace(cfg.effects,
                                                                 guidance=guidance)))
    axis = np.array(handle.scene.insertion_axis, float)
    axis /= np.linalg.norm(axis)
    lateral, tilt_axis = misaim(axis, None if fit.lateral is None else np.array(fit.lateral))
    width = float(np.ptp(handle.parts[1].vertices @ lateral))
    start = np.array(handle.start_pose, float)
    start[:3] += OFFSET_FRACTION * width * lateral
    start[3:] += math.radians(TILT_DEGREES) * tilt_axis
    handle = replace(handle, start_pose=start)
    k = int(modes if modes is not None else handle.scene.modes)
    sim, model = build_simulation(handle, prepare=True, backend=backend, modes=k)
    target = np.array(handle.assembled_pose, float)
    end = start.copy()
    end[:3] += axis * float((target[:3] - start[:3]) @ axis)
    device = TrajectoryDevice(np.array([[0.0, *start], [PUSH_SECONDS, *end]]))
    loop = EngineLoop(sim, model=model, device=device, realtime=False)
    total = int(round(seconds / sim.dt))
    chunk = max(1, int(round(0.1 / sim.dt)))
    done = 0
    t0 = time.perf_counter()
    while done < total:
        done += loop.run(max_steps=min(chunk, total - done))
        loop.poll_frames()
        loop.poll_events()
        if progress is not None:
            progress(done / total)
    wall = time.perf_counter() - t0
    final = np.asarray(sim.part_pose(), float)
    error = relative_pose(target, final)
    position, lat, axial, tilt = constrained_errors(error, axis, fit.free)
    return SeatingResult(pair=name, guidance=guidance, width=width, position_error=position,
                         lateral_error=lat, axial_error=axial, tilt_deg=tilt,
                         final_pose=tuple(float(x) for x in final), modes=k,
                         seconds=done * sim.dt, wall_seconds=wall)


# ---------------------------------------------------------------------------- command
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``skelasm bench seating``."""
    parser.add_argument("--pairs", nargs="*", default=None, metavar="NAME",
                        help="folders of assets/real (default: every pair)")
    parser.add_argument("--guidance", choices=("skeletal", "collision", "both"),
                        default="both", help="guided, collision-only, or both (default)")
    parser.add_argument("--seconds", type=float, default=5.0,
                        help="simulated seconds per run (the push takes the first 2)")
    parser.add_argument("--modes", type=int, default=None,
                        help="modes per axis K (default: each scene's)")
    parser.add_argument("--backend", default="auto", help="per-pose backend")
    parser.add_argument("-o", "--output", default="bench_seating.png", help="plot (PNG)")


class _Progress:
    """One line on a terminal: run i of n, its fraction, and the time left (estimated)."""

    def __init__(self, runs: int, stream=sys.stderr):
        self.runs, self.stream = runs, stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.start = time.perf_counter()
        self.index, self.label = 0, ""

    def begin(self, index: int, label: str) -> None:
        self.index, self.label = index, label
        self(0.0)

    def __call__(self, fraction: float) -> None:
        if not self.tty:
            return
        done = self.index + fraction
        elapsed = time.perf_counter() - self.start
        left = elapsed / done * (self.runs - done) if done > 0 else float("nan")
        text = "?" if math.isnan(left) else f"{left:4.0f} s"
        self.stream.write(f"\r[{self.index + 1}/{self.runs}] {self.label:<45} "
                          f"{100 * fraction:3.0f} %  time left {text}   ")
        self.stream.flush()

    def end(self) -> None:
        if self.tty:
            self.stream.write("\r" + " " * 90 + "\r")
            self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Run the benchmark: table on stdout, plot to ``args.output``."""
    names = args.pairs or pair_names()
    unknown = [n for n in names if n not in FITS]
    if unknown:
        print(f"unknown pair(s) {', '.join(unknown)}; choose from {', '.join(FITS)}",
              file=sys.stderr)
        return 2
    guidances = ("skeletal", "collision") if args.guidance == "both" else (args.guidance,)
    jobs = [(n, g) for n in names for g in guidances]
    bar = _Progress(len(jobs))
    results: list[SeatingResult] = []
    for i, (name, guidance) in enumerate(jobs):
        bar.begin(i, f"{name} ({guidance})")
        r = seating_run(name, guidance, seconds=args.seconds, modes=args.modes,
                        backend=args.backend, progress=bar)
        results.append(r)
        bar.end()
        print(f"{name} ({guidance}): position {r.position_percent:.2f} % of the width, tilt "
              f"{r.tilt_deg:.2f} deg, {'seated' if r.seated else 'not seated'} "
              f"({r.wall_seconds:.0f} s)", file=sys.stderr, flush=True)
    print(table(results))
    _plot(results, args.output)
    print(f"\nplot: {args.output}")
    return 0


def table(results: list[SeatingResult]) -> str:
    """Markdown table of the runs."""
    lines = [f"Misaim {100 * OFFSET_FRACTION:g} % of the width sideways and "
             f"{TILT_DEGREES:g} degrees; seated: within {100 * SEAT_FRACTION:g} % and "
             f"{SEAT_DEGREES:g} degrees in the constrained axes.", "",
             "| pair | free | guidance | K | width | position error (% width) | lateral | "
             "axial | tilt (deg) | seated | wall s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        free = " ".join(FITS[r.pair].free) or "none"
        lines.append(
            f"| {r.pair} | {free} | {r.guidance} | {r.modes} | {r.width:.2f} | "
            f"{r.position_percent:.2f} | {r.lateral_error:.3f} | {r.axial_error:+.3f} | "
            f"{r.tilt_deg:.2f} | {'yes' if r.seated else 'no'} | {r.wall_seconds:.0f} |")
    return "\n".join(lines)


def _plot(results: list[SeatingResult], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    names = sorted({r.pair for r in results}, key=[r.pair for r in results].index)
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(names) + 2), dpi=110,
                             sharey=True)
    y = np.arange(len(names))
    for j, guidance in enumerate(("skeletal", "collision")):
        rows = {r.pair: r for r in results if r.guidance == guidance}
        if not rows:
            continue
        off = (j - 0.5) * 0.38
        pos = [rows[n].position_percent if n in rows else np.nan for n in names]
        tilt = [rows[n].tilt_deg if n in rows else np.nan for n in names]
        label = "guided" if guidance == "skeletal" else "collision only"
        axes[0].barh(y + off, pos, height=0.36, label=label)
        axes[1].barh(y + off, tilt, height=0.36, label=label)
    axes[0].axvline(100 * SEAT_FRACTION, color="k", ls="--", lw=1)
    axes[1].axvline(SEAT_DEGREES, color="k", ls="--", lw=1)
    for ax, values in zip(axes, ([r.position_percent for r in results],
                                 [r.tilt_deg for r in results]), strict=True):
        # errors span from thousandths to hundreds: start the axis below the smallest
        ax.set_xscale("log")
        small = [v for v in values if v > 0]
        ax.set_xlim(left=min(0.01, 0.5 * min(small)) if small else 0.01)
        ax.xaxis.set_minor_formatter(NullFormatter())  # labels at the decades only
    axes[0].set_xlabel("position error, % of width (constrained axes; log)")
    axes[1].set_xlabel("tilt, degrees (constrained axes; log)")
    axes[0].set_yticks(y, names)
    axes[0].invert_yaxis()
    axes[0].legend(loc="lower right")
    fig.suptitle("Seating from a misaimed push (dashed: the seating criterion)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
