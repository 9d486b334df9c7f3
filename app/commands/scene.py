"""`skelasm scene new FIXED MOVING -o SCENE.toml`: a scene for two part files, ready to run.

The two parts are taken as drawn in one assembly (CAD programs export the parts of an
assembly in their assembled places), so by default part 2's assembled pose relative to part
1 is zero; ``--assembled`` gives another. Part 2 starts backed off against the insertion axis
just far enough that the two parts' descriptor grids do not overlap: nothing pulls it before
the user moves it. The file is written with the one scene writer and read back before it
replaces anything.
"""

from __future__ import annotations

import argparse
import os

from app.commands.arguments import finite_float
from engine.params import DEFAULT_UNIT

#: Seconds the written push trajectory takes from the start pose to the seat.
PUSH_SECONDS = 3.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm scene new`` (write a scene for two part files) to ``sub``."""
    parser = sub.add_parser("scene", help="write a scene file for two parts",
                            description="Write scene files.")
    which = parser.add_subparsers(dest="action", metavar="ACTION")
    which.required = True
    new = which.add_parser(
        "new", help="a scene for a fixed and a moving part file",
        description="Write a scene for two part files (STEP, STL, OBJ, PLY, OFF): the first "
        "fixed, the second moving. The parts are taken as drawn in one assembly (part 2's "
        "assembled pose relative to part 1 is zero unless --assembled says otherwise); part "
        "2 starts backed off against the insertion axis, clear of part 1's reach.")
    new.add_argument("fixed", help="part 1, the fixed part")
    new.add_argument("moving", help="part 2, the part you move")
    new.add_argument("-o", "--output", required=True, help="scene file to write (.toml)")
    new.add_argument("--unit", default=DEFAULT_UNIT, help="the scene's length unit (default "
                     f"{DEFAULT_UNIT}); mesh "
                     "files are read in it, STEP files in their header's unit, converted")
    new.add_argument("--assembled", nargs=6, type=finite_float, default=None,
                     metavar=("TX", "TY", "TZ", "RX", "RY", "RZ"),
                     help="part 2 relative to part 1 when assembled (default: as drawn)")
    new.add_argument("--insertion-axis", nargs=3, type=finite_float, default=(0.0, 0.0, -1.0),
                     metavar=("X", "Y", "Z"), help="direction part 2 travels to seat, part 1's "
                     "frame (default: %(default)s, down)")
    new.add_argument("--grid", type=int, default=None,
                     help="descriptor samples along the largest part's longest side (default: "
                     "chosen from the fit's width; the descriptor's cost grows with its cube)")
    new.add_argument("--modes", type=int, default=None,
                     help="Fourier modes per axis K (default: chosen from the fit's width, "
                     "within what the loop affords on this machine)")
    new.add_argument("--force", action="store_true", help="replace an existing scene file")
    new.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Write the scene; print where part 2 starts and what to run next. Returns 0."""
    from dataclasses import replace
    from pathlib import Path

    import numpy as np

    from engine.errors import InputError
    from engine.files import check_output, input_problem, write_text
    from engine.params import LENGTH_UNITS, CorrelationParams, DescriptorParams
    from engine.scene import PartSpec, Scene
    from engine.scene.writer import save_scene
    from engine.sim.auto import complete_scene

    if args.unit not in LENGTH_UNITS:
        raise InputError(f"--unit {args.unit!r} is not a known unit; use one of "
                         f"{', '.join(LENGTH_UNITS)}")
    for given in (args.fixed, args.moving):
        problem = input_problem(given, what="part file")
        if problem is not None and not os.path.lexists(given):
            raise InputError(f"{given}: no such part file; give the path of a STEP, STL, OBJ, "
                             "PLY or OFF file")
        if problem is not None:  # a folder, FIFO, device or loop of links, said as such
            raise InputError(problem)
    files = [Path(args.fixed).resolve(), Path(args.moving).resolve()]
    out = Path(args.output)
    if out.suffix.lower() != ".toml":  # never a name the user did not write
        raise InputError(f"{out}: a scene file ends in .toml; give -o a name such as "
                         f"{out.with_suffix('.toml').name}")
    check_output(out, force=args.force, inputs=files, what="scene")
    push = out.with_name(out.stem + "_push.csv")
    check_output(push, force=args.force, inputs=files, what="trajectory")
    axis = np.asarray(args.insertion_axis, dtype=np.float64)
    if not np.linalg.norm(axis) > 0:
        raise InputError("--insertion-axis must not be zero; give the direction part 2 "
                         "travels to seat, e.g. 0 0 -1")
    axis = axis / np.linalg.norm(axis)
    assembled = np.zeros(6) if args.assembled is None else np.asarray(args.assembled, float)
    descriptor = DescriptorParams() if args.grid is None else DescriptorParams(grid=args.grid)
    correlation = (CorrelationParams() if args.modes is None
                   else CorrelationParams(modes=args.modes))
    # what the user gave; the rest is chosen from the parts
    given = frozenset(key for key, value in (("descriptor.grid", args.grid),
                                             ("correlation.modes", args.modes))
                      if value is not None)
    parts = (PartSpec(name=files[0].stem, file=files[0], pose=np.zeros(6), fixed=True),
             PartSpec(name=files[1].stem, file=files[1], pose=assembled, fixed=False))
    draft = Scene(path=out.resolve(), name=f"{files[1].stem} into {files[0].stem}",
                  parts=parts, assembled_pose=assembled, units=args.unit,
                  insertion_axis=axis, descriptor=descriptor, correlation=correlation,
                  given=given)
    draft, _ = complete_scene(draft)
    back = clear_distance(draft, axis)
    start = assembled.copy()
    start[:3] -= back * axis
    moving = replace(draft.parts[1], pose=start)
    written = save_scene(replace(draft, parts=(draft.parts[0], moving)), out)
    rows = ["t,tx,ty,tz,rx,ry,rz", "0," + ",".join(f"{v:.9g}" for v in start),
            f"{PUSH_SECONDS:g}," + ",".join(f"{v:.9g}" for v in assembled)]
    write_text(push, "\n".join(rows) + "\n", what="trajectory")
    print(f"wrote      {written}")
    for key, value, reason in draft.chosen:
        print(f"chose      {key} = {value}: {reason}")
    print(f"start      part 2 {back:.4g} {args.unit} back from its seat along the insertion "
          "axis, out of part 1's reach (at rest until you move it)")
    print(f"push       {push}: the proxy from the start to the seat in {PUSH_SECONDS:g} s")
    print(f"next       skelasm precompute {written}   (descriptors; cached)")
    print(f"           skelasm evaluate {written}     (E, F, T and the free axes at the seat)")
    print(f"           skelasm simulate {written} --trajectory {push}")
    print(f"           skelasm gui {written}")
    return 0


def clear_distance(scene, axis) -> float:
    """How far back along ``axis`` part 2 must start so its descriptor grid clears part 1's.

    Both grids are boxes in their parts' frames (the parts plus ``padding`` cells); the
    correlation is exactly zero while they do not overlap. One cell more is added.
    """
    import numpy as np

    from engine.descriptor import grid_for_part, scene_spacing
    from engine.pose import pose_to_matrix
    from engine.scene import load_scene_parts

    parts = load_scene_parts(scene)
    h = scene_spacing(scene, parts)
    grids = [grid_for_part(p, spacing=h, padding=scene.descriptor.padding) for p in parts]

    def corners(grid, pose) -> np.ndarray:
        lo = np.asarray(grid.origin, float)
        hi = lo + h * (np.asarray(grid.shape, float) - 1)
        box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
        m = pose_to_matrix(pose)
        return box @ m[:3, :3].T + m[:3, 3]

    fixed = corners(grids[0], np.zeros(6)) @ axis
    moving = corners(grids[1], scene.assembled_pose) @ axis
    return float(max(moving.max() - fixed.min(), 0.0) + h)
