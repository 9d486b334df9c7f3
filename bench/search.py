"""`skelasm bench search`: the search on pairs whose fit is known, against that fit.

Data: scenes with an ``assembled_pose`` and ``free_axes`` (the bundled pairs, the pairs of
assets/real). For each, :func:`engine.search.search_scene` runs without being told the
pose; the table gives the seconds (the scan's and the whole search's, descriptors from the
store not counted), the rotations scanned, the rank of the first fit within 5 % of the
assembled pose, the top fit's errors and its joint kind against the one ``free_axes``
declares. Errors, all blind to part 2's symmetries and, along the translations that
``free_axes`` declares, to where the fit lies (a peg in a through bore fits anywhere along
it):

- geometry: the mean distance from part 2's surface points at the fit to the surface at
  the assembled pose (a dense sample), in % of part 2's size (its bounding-box diagonal);
- centre: how far the fit puts part 2's surface centroid (which its symmetries keep), in %
  of that size;
- axes: the largest angle between the fit's and the assembled pose's principal axes of
  part 2's surface, each taken as a line, over the axes whose moments differ from the
  others' by 10 % or more (a round peg's one axis; none of a sphere's).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from engine.backend import choices, describe_auto

ROOT = Path(__file__).resolve().parents[1]
BUNDLED = ("peg_in_hole", "boss_pins", "bracket_slot", "dovetail")

#: A fit within this geometry error (% of part 2's size) is the assembled pose.
FOUND_PERCENT = 5.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench search`` to ``parser``."""
    parser.add_argument("--pairs", choices=("bundled", "real", "all"), default="bundled",
                        help="which scenes (default: the bundled pairs)")
    parser.add_argument("--scene", nargs="+", help="these scenes instead (a generated "
                        "pair's, with its fit.json beside it, judged by that truth)")
    parser.add_argument("--generated", type=int, metavar="N",
                        help="N unseen pairs of bench.fitgen instead (with --seed), judged "
                        "against their ground truth (fit.json)")
    parser.add_argument("--seed", type=int, help="the seed of --generated")
    parser.add_argument("--keep", metavar="DIR", help="with --generated: write the pairs "
                        "into DIR and keep them (a DIR holding this seed and count already is "
                        "reused; default: a temporary folder)")
    parser.add_argument("--angle", type=float, nargs="+", default=[30.0],
                        help="rotation grid spacings in degrees (default 30)")
    parser.add_argument("--scan-modes", type=int, default=16, help="scan modes (default 16)")
    parser.add_argument("--top", type=int, default=5, help="fits kept (default 5)")
    parser.add_argument("--workers", type=int, help="a local Dask cluster of N processes")
    parser.add_argument("--backend", nargs="+", choices=choices("scan"), default=["auto"],
                        help="where the scan runs; several: each in turn, in one run "
                        f"(default auto: {describe_auto('scan')})")
    parser.add_argument("-o", "--output", default="search_bench.json",
                        help="JSON of every row (default search_bench.json)")


def expected_kind(free_axes) -> str:
    """The joint kind a scene's ``free_axes`` declares."""
    axes = set(free_axes or ())
    t = {a for a in axes if a in ("x", "y", "z")}
    r = {a[1] for a in axes if a in ("rx", "ry", "rz")}
    if not t and not r:
        return "rigid"
    if not t and len(r) == 1:
        return "revolute"
    if len(t) == 1 and not r:
        return "prismatic"
    if len(t) == 1 and r == t:
        return "cylindrical"
    if len(t) == 2 and len(r) == 1 and not (r & t):
        return "planar"
    return "other"


def _principal_lines(points: np.ndarray) -> list[np.ndarray]:
    """Unit principal axes of ``points`` whose moments stand apart from the others' by 10 %."""
    centred = points - points.mean(axis=0)
    values, vectors = np.linalg.eigh(centred.T @ centred / len(points))
    lines = []
    for i in range(3):
        others = [values[j] for j in range(3) if j != i]
        if all(abs(values[i] - o) > 0.1 * max(values[i], o) for o in others):
            lines.append(vectors[:, i])
    return lines


def errors(fit_rotation, fit_translation, pose, points, dense, free_axes=()) -> dict:
    """Geometry, centre (% of size) and axes (degrees) errors of a fit (module docstring).

    ``free_axes``: the scene's declared free axes; the fit is first slid along the free
    translations (part 1's x, y, z, or unit vectors: a generated fit's) to the assembled
    pose's centroid.
    """
    from scipy.spatial import cKDTree

    from engine.pose import pose_to_matrix
    from engine.search.cluster import placed, surface_spread

    size = surface_spread(points)
    m = pose_to_matrix(np.asarray(pose, float))
    want = placed(dense, m[:3, :3], m[:3, 3])
    gap = want.mean(axis=0) - placed(dense, fit_rotation, fit_translation).mean(axis=0)
    slide = np.zeros(3)
    for axis in free_axes or ():
        if isinstance(axis, str):
            if axis in ("x", "y", "z"):
                index = "xyz".index(axis)
                slide[index] = gap[index]
        else:  # a unit direction
            v = np.asarray(axis, float)
            slide += v * float(gap @ v)
    fit_translation = np.asarray(fit_translation, float) + slide
    got = placed(points, fit_rotation, fit_translation)
    geometry = 100.0 * float(np.mean(cKDTree(want).query(got)[0])) / size
    # the dense sample's centroid and axes: a few hundred points' wander by percents
    centre = 100.0 * float(np.linalg.norm(want.mean(axis=0) - placed(
        dense, fit_rotation, fit_translation).mean(axis=0))) / size
    angles = [math.degrees(math.acos(min(1.0, abs(float((m[:3, :3] @ v) @ (fit_rotation @ v))))))
              for v in _principal_lines(dense)]
    return {"geometry_percent": geometry, "centre_percent": centre,
            "axes_degrees": max(angles) if angles else 0.0}


def run(args: argparse.Namespace) -> int:
    """Run the search on every scene, print the table, write the JSON."""
    from engine.correlation.walls import surface_points
    from engine.scene import load_scene
    from engine.scene.parts import load_scene_parts
    from engine.search import SearchSettings, level_for, search_scene
    from engine.sim.auto import complete_scene

    truths: dict[Path, object] = {}
    if args.generated:
        import tempfile

        from bench.fitgen.generate import generate
        from bench.fitgen.truth import TRUTH_FILE, read_truth

        if args.seed is None:
            raise ValueError("--generated needs --seed")
        folder = (Path(args.keep) if getattr(args, "keep", None)
                  else Path(tempfile.mkdtemp(prefix=f"skelasm-search-{args.seed}-")))
        generate(args.generated, args.seed, folder)
        scenes = sorted(folder.glob("*/scene.toml"))
        truths = {p: read_truth(p.parent / TRUTH_FILE) for p in scenes}
    elif args.scene:
        from bench.fitgen.truth import TRUTH_FILE, read_truth

        scenes = [Path(s) for s in args.scene]
        # a generated pair kept in its folder (bench seating --keep) is judged by its truth
        truths = {p: read_truth(p.parent / TRUTH_FILE) for p in scenes
                  if (p.parent / TRUTH_FILE).is_file()}
    else:
        scenes = []
        if args.pairs in ("bundled", "all"):
            scenes += [ROOT / "assets" / name / "scene.toml" for name in BUNDLED]
        if args.pairs in ("real", "all"):
            scenes += sorted((ROOT / "assets" / "real").glob("*/scene.toml"))
    work = None
    if args.workers:
        from engine.search.distributed import DaskWork

        work = DaskWork.connect(workers=args.workers)
    rows = []
    print(f"{'scene':34} {'deg':>4} {'rot':>6} {'scan on':>7} {'scan s':>7} {'ms/rot':>6} "
          f"{'total s':>7} {'rank':>4} {'geom %':>6} {'centre %':>8} {'axes deg':>8} {'joint':>11} "
          f"{'at seat':>11} {'expected':>11}")
    try:
        for path in scenes:
            scene, _ = complete_scene(load_scene(path))
            part = load_scene_parts(scene)[1]
            points = surface_points(part.vertices, part.faces, 256, seed=0)
            dense = surface_points(part.vertices, part.faces, 8192, seed=1)
            for angle, backend in [(a, b) for a in args.angle for b in args.backend]:
                settings = SearchSettings(level=level_for(angle=angle),
                                          scan_modes=args.scan_modes, top=args.top,
                                          backend=backend)
                start = time.perf_counter()
                result = search_scene(scene, settings, work=work)
                wall = time.perf_counter() - start
                truth = truths.get(path)
                free = (scene.seat.free_axes if truth is None
                        else truth.free_translations)  # type: ignore[attr-defined]
                errs = [errors(f.rotation, f.translation, scene.assembled_pose, points, dense,
                               free) for f in result.fits]
                rank = next((i + 1 for i, e in enumerate(errs)
                             if e["geometry_percent"] < FOUND_PERCENT), None)
                top = result.fits[0] if result.fits else None
                seat = result.fits[rank - 1] if rank else None
                if truth is None:
                    expected = expected_kind(scene.seat.free_axes)
                else:
                    from engine.search.joint import _kind

                    expected = _kind(tuple(np.asarray(v) for v in truth.free_translations),
                                     [np.asarray(v) for v in truth.free_rotations])
                row = {"scene": str(path.relative_to(ROOT) if path.is_relative_to(ROOT)
                                    else path),
                       "angle": settings.angle, "rotations": settings.rotations,
                       "scan_backend": result.scan_backend,
                       "scan_seconds": result.scan_seconds, "seconds": result.seconds,
                       "seconds_with_preparation": wall,
                       "ms_per_rotation": 1000 * result.seconds_per_rotation,
                       "rank": rank, **(errs[0] if errs else {}),
                       "joint": top.joint.kind if top else None,
                       "confidence": top.joint.confidence if top else None,
                       "joint_at_seat": seat.joint.kind if seat else None,
                       "family": getattr(truth, "family", None),
                       "expected": expected}
                rows.append(row)
                print(f"{path.parent.name:34} {settings.angle:4g} {settings.rotations:6d} "
                      f"{result.scan_backend:>7} "
                      f"{result.scan_seconds:7.1f} {row['ms_per_rotation']:6.1f} "
                      f"{result.seconds:7.1f} {rank or '-':>4} "
                      f"{row.get('geometry_percent', float('nan')):6.2f} "
                      f"{row.get('centre_percent', float('nan')):8.2f} "
                      f"{row.get('axes_degrees', float('nan')):8.2f} "
                      f"{row['joint'] or '-':>11} {row['joint_at_seat'] or '-':>11} "
                      f"{row['expected']:>11}", flush=True)
    finally:
        if work is not None:
            work.shutdown()
    if rows:
        found = [r for r in rows if r["rank"]]
        print(f"seat found (within {FOUND_PERCENT:g} %) in {len(found)} of {len(rows)}; "
              f"joint kind right at the top fit in "
              f"{sum(r['joint'] == r['expected'] for r in rows)} of {len(rows)}, at the seat "
              f"where found in {sum(r['joint_at_seat'] == r['expected'] for r in found)} of "
              f"{len(found)}")
    Path(args.output).write_text(json.dumps(rows, indent=1) + "\n")
    print(f"wrote {args.output}")
    return 0
