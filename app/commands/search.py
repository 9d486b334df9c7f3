"""`skelasm search SCENE`: where part 2 fits on part 1 and what joint each fit is."""

from __future__ import annotations

import argparse
import sys
import time

from app.commands.arguments import int_in_range, positive_float
from engine.backend import choices, describe_auto


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm search`` (the fits over all rotations, ranked) to ``sub``."""
    parser = sub.add_parser(
        "search",
        help="find where part 2 fits on part 1, and the joint of each fit",
        description="Search all rotations of part 2 (a uniform grid) and all translations "
        "(one inverse FFT per rotation) for the poses of lowest energy; cluster, refine and "
        "rank them, and classify each fit's joint (rigid, revolute, prismatic, cylindrical, "
        "planar, other). The scene's assembled_pose is not needed.",
    )
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument("--top", type=int_in_range(1, 100),
                        help="fits to report (default: the search's own)")
    grid = parser.add_mutually_exclusive_group()
    grid.add_argument("--rotations", type=int_in_range(1, 2_359_296),
                      help="rotations to scan at least (72 * 8^l: 72, 576, 4608, 36864, ...; "
                      "default: the search's own grid)")
    grid.add_argument("--angle", type=positive_float,
                      help="rotation grid spacing in degrees at most (60, 30, 15, 7.5, ...)")
    parser.add_argument("--modes", type=int, help="modes per axis K of the refinement "
                        "(default: the scene's)")
    parser.add_argument("--scan-modes", type=int_in_range(2, 64),
                        help="modes per axis of the scan (default: the search's own)")
    parser.add_argument("--seed", type=int_in_range(0, 2**31 - 1),
                        help="turns the rotation grid by a random rotation (default: the "
                        "search's own)")
    parser.add_argument("--workers", type=int_in_range(1, 1024),
                        help="run the scan on a local Dask cluster of N processes")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run the scan on the Dask scheduler at ADDRESS (tcp://host:8786)")
    parser.add_argument("--backend", choices=choices("scan"),
                        help="where the scan's landscapes are computed (default auto: "
                        f"{describe_auto('scan')})")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("-o", "--output", help="write the result as JSON to this file")
    parser.add_argument("--force", action="store_true", help="replace an existing --output")
    parser.set_defaults(run=run)


class _Progress:
    """Progress with the time left, on stderr.

    One updated line on a terminal, else a line per tenth.
    """

    def __init__(self) -> None:
        self.tty = sys.stderr.isatty()
        self.shown = -1

    def __call__(self, fraction: float, left: float | None) -> None:
        tenth = int(fraction * 10)
        if not self.tty and tenth == self.shown:
            return
        self.shown = tenth
        rest = f", about {left:.0f} s left" if left is not None else ""
        line = f"search {100 * fraction:5.1f} %{rest}"
        if self.tty:
            print(f"\r{line:<40}", end="", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.tty:
            print(file=sys.stderr, flush=True)


def result_json(result, scene, scale, where: str) -> dict:
    """The search's result as plain JSON types."""
    s = result.settings
    fits = []
    for f in result.fits:
        fits.append({
            "rank": f.rank, "pose": [round(float(v), 6) for v in f.pose],
            "energy": f.energy, "scan_energy": f.scan_energy, "cluster_size": f.cluster_size,
            "joint": {
                "kind": f.joint.kind, "confidence": round(f.joint.confidence, 4),
                "free_translations": [[round(float(v), 6) for v in d] for d in f.joint.slides],
                "free_rotations": [{"axis": [round(float(v), 6) for v in a],
                                    "point": [round(float(v), 6) for v in p]}
                                   for a, p in f.joint.turns],
            },
            "contact": None if f.contact is None else {
                "touching": round(f.contact.touching, 4), "inside": round(f.contact.inside, 4),
                "depth": round(f.contact.depth, 6)},
            "seconds": round(f.seconds, 4),
        })
    return {
        "scene": str(scene.path), "units": scene.units, "energy_unit": scale.units.energy,
        "rotations": s.rotations, "angle_degrees": s.angle, "level": s.level,
        "scan_modes": s.scan_modes, "modes": result.modes, "lattice": result.lattice,
        "lattice_step": result.step, "seed": s.seed, "run_on": where,
        "scan_backend": result.scan_backend,
        "candidates": result.candidates, "clusters": result.clusters,
        "scan_seconds": round(result.scan_seconds, 3),
        "seconds_per_rotation": round(result.seconds_per_rotation, 6),
        "seconds": round(result.seconds, 3), "fits": fits,
    }


def run(args: argparse.Namespace) -> int:
    """Search, print the ranked fits (or JSON), write ``-o``. Returns the exit status."""
    import json
    from dataclasses import replace

    from app.commands.scale import EnergyScale, energy_scale
    from engine.errors import InputError
    from engine.files import check_output, write_text
    from engine.params import QuantityUnits
    from engine.scene import load_scene
    from engine.search import SearchSettings, level_for, search_scene
    from engine.sim.auto import complete_scene

    if args.modes is not None:  # the options first: a bad one costs nothing
        from engine.params import check_modes

        check_modes(args.modes, "--modes")
    if args.workers is not None and args.scheduler is not None:
        raise InputError("--workers and --scheduler: give one (a local cluster, or an address)")
    base = SearchSettings()  # the one place the defaults are written
    try:
        level = (level_for(angle=args.angle) if args.angle is not None
                 else level_for(rotations=args.rotations) if args.rotations is not None
                 else base.level)
    except ValueError as exc:
        raise InputError(f"--rotations/--angle: {exc}") from None
    if args.output:
        check_output(args.output, force=args.force, inputs=[args.scene], what="result")
    scene = load_scene(args.scene)
    if scene.assembled_known:  # settings chosen at a fit, and the simulation's kappa, need one
        scene, _ = complete_scene(scene)
        scale = energy_scale(scene)
    else:
        scale = EnergyScale(float(scene.config.simulation.kappa or 1.0),
                            QuantityUnits.of(scene.units), "scene" if
                            scene.config.simulation.kappa is not None else "unit")
    top = base.top if args.top is None else args.top
    settings = replace(base, level=level, top=top, clusters=max(base.clusters, top),
                       scan_modes=base.scan_modes if args.scan_modes is None
                       else args.scan_modes,
                       seed=base.seed if args.seed is None else args.seed,
                       backend=base.backend if args.backend is None else args.backend)
    work = None
    where = "in-process"
    if args.workers is not None or args.scheduler is not None:
        from engine.search.distributed import DaskWork

        work = DaskWork.connect(args.scheduler, workers=args.workers or 2)
        where = (f"Dask scheduler {args.scheduler}" if args.scheduler
                 else f"local Dask cluster of {args.workers} processes")
    progress = _Progress()
    start = time.perf_counter()
    try:
        result = search_scene(scene, settings, modes=args.modes, kappa=scale.kappa, work=work,
                              progress=progress)
    finally:
        progress.close()
        if work is not None:
            work.shutdown()
    out = result_json(result, scene, scale, where)
    out["seconds_with_preparation"] = round(time.perf_counter() - start, 3)
    if args.output:
        write_text(args.output, json.dumps(out, indent=1) + "\n", what="result")
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"scan       {settings.rotations} rotations ({settings.angle:g} degrees) x "
          f"{result.lattice}^3 translations at K = {settings.scan_modes}, {where}, "
          f"{result.scan_backend}: "
          f"{result.scan_seconds:.1f} s ({1000 * result.seconds_per_rotation:.1f} ms a rotation)")
    print(f"refined    {min(result.clusters, settings.clusters)} of {result.clusters} clusters "
          f"at K = {result.modes}; search {result.seconds:.1f} s")
    for f in result.fits:
        pose = " ".join(f"{v:.4g}" for v in f.pose)
        axes = [f"slide {_vec(d)}" for d in f.joint.slides] + [
            f"turn {_vec(a)} through {_vec(p)}" for a, p in f.joint.turns]
        print(f"fit {f.rank}      pose {pose}  E = {f.energy:.5g} {scale.units.energy}  "
              f"cluster {f.cluster_size}  {f.joint.kind} ({f.joint.confidence:.2f})"
              + (f": {'; '.join(axes)}" if axes else "")
              + ("" if f.contact is None else
                 f"  touching {100 * f.contact.touching:.0f} %, "
                 f"inside {100 * f.contact.inside:.0f} %"))
    if args.output:
        print(f"wrote      {args.output}")
    return 0


def _vec(v) -> str:
    return "(" + ", ".join(f"{float(x):.3g}" for x in v) + ")"
