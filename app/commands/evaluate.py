"""`skelasm evaluate SCENE --pose ...`: energy, force and torque of one relative pose."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable

from app.commands.arguments import (
    add_band_argument,
    check_rotation_vector,
    finite_float,
    int_in_range,
)
from app.commands.poses import add_about_argument, typed_pose
from engine.backend import choices, describe_auto

#: Most evaluations --repeat times (100,000 of the slowest, 10 ms each, take 17 minutes).
MAX_REPEAT = 100_000


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm evaluate`` (energy, force and torque at one pose) to ``sub``."""
    parser = sub.add_parser(
        "evaluate",
        help="energy, force and torque of part 2 at one pose relative to part 1",
        description="Evaluate the Fourier-correlation energy E = -kappa Re f, the force "
        "-dE/dt and the torque -dE/dtheta on the moving part at one pose (part 2 relative "
        "to part 1, the convention of the scene's assembled_pose). kappa is the one the "
        "simulation and the window use (the scene's [simulation] kappa or its scale-free "
        "default); masses are in kg, so a millimetre scene's E is in µJ, F in mN, T in mN·mm.",
    )
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument(
        "--pose", nargs=6, type=finite_float, metavar=("TX", "TY", "TZ", "RX", "RY", "RZ"),
        help="translation (scene units) and rotation vector (radians) of part 2 relative to "
        "part 1, turning about its centre (see --about); default: the scene's assembled pose",
    )
    add_about_argument(parser, "--pose")
    parser.add_argument("--modes", type=int, help="modes per axis K (m' = K^3); default: the "
                        "scene's [correlation] modes")
    parser.add_argument("--backend", default="auto", choices=choices("per_pose"),
                        help=f"per-pose backend (auto: {describe_auto('per_pose')})")
    parser.add_argument("--repeat", type=int_in_range(1, MAX_REPEAT, "each is one evaluation "
                                                      "of up to milliseconds"),
                        default=100, metavar="N",
                        help="evaluations to time, 1 to 100,000; the reported microseconds "
                        "are their median")
    add_band_argument(parser)
    parser.add_argument("--no-fine", action="store_true",
                        help="the modal sum alone, without the fine level where the parts "
                        "meet (docs/fine_level.md)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Evaluate energy, force and torque at the pose asked for and print them.

    Prints JSON with ``--json``. Returns the exit status.
    """
    import json

    import numpy as np

    from app.commands.scale import energy_scale
    from engine.correlation import add_evaluations, correlator_for_scene
    from engine.params import GUIDANCE_BAND
    from engine.pose import rotation_matrix
    from engine.runtime import open_scene
    from engine.search.joint import MOTION_ANGLE, REACH, Surfaces, axis_names, motion_joint
    from engine.sim import mass_properties
    from engine.sim.build import hold_point
    from engine.sim.joints import find_free_axes

    if args.modes is not None:
        from engine.params import check_modes

        check_modes(args.modes, "--modes")
    if args.pose is not None:
        check_rotation_vector(args.pose[3:], "--pose")
    band = args.band or GUIDANCE_BAND  # what the part feels, unless told
    handle = open_scene(args.scene)  # the scene and its parts, read once
    scene = handle.scene
    pose = (typed_pose(handle, args.pose, args.about) if args.pose is not None
            else np.asarray(scene.assembled_pose, dtype=float))
    scale = energy_scale(scene, handle)
    update, close = progress_bar("preparing", enabled=not args.json)
    try:
        corr = correlator_for_scene(scene, parts=handle.parts, modes=args.modes,
                                    backend=args.backend, band=band,
                                    kappa=scale.kappa, progress=update)
    finally:
        close()
    near = None
    if len(handle.parts) > 1 and not args.no_fine:
        from engine.correlation.near import NearField
        from engine.descriptor import descriptors_for_scene
        from engine.sim.fine import build_level

        d1, d2 = descriptors_for_scene(scene, parts=list(handle.parts))[:2]  # cached
        level = build_level(handle.parts[0], handle.parts[1], d1, d2,
                            np.asarray(scene.assembled_pose, float), scene.insertion_axis)
        if level is not None:
            near = NearField(level, kappa=scale.kappa)
            if not near.follow(corr.table):
                near = None
            elif near.walls is not None:  # as stiff as the simulation makes them
                spec = handle.config.mass_spec(len(handle.parts) - 1)
                mass, _, _ = mass_properties(handle.parts[-1].vertices, handle.parts[-1].faces,
                                             spec, scene.units)
                near.walls.for_body(mass, 1.0 / handle.config.simulation.rate_hz)

    def evaluate(rot, t):  # the modal sum, and the fine level where the parts meet
        ev = corr.evaluate(rot, t)
        return ev if near is None else add_evaluations(ev, near.evaluate(rot, t))

    rot = rotation_matrix(pose[3:])
    t = pose[:3]
    result = evaluate(rot, t)
    walls = None if near is None or near.walls is None else near.walls.evaluate(rot, t)
    times = [evaluate(rot, t).microseconds for _ in range(args.repeat)]
    micro = float(np.median(times))
    moving = handle.parts[-1]
    spec = handle.config.mass_spec(len(handle.parts) - 1)
    _, _, centre = mass_properties(moving.vertices, moving.faces, spec, scene.units)
    # the joint from the motions the parts allow there; where they do not meet, the
    # energy's curvature one cell each way (engine.sim.joints)
    length = 0.5 * float(np.max(np.ptp(moving.vertices, axis=0)))
    motion = motion_joint(Surfaces.of(handle.parts[0].vertices, handle.parts[0].faces,
                                      moving.vertices, moving.faces),
                          rot, t, length=length) if len(handle.parts) > 1 else None
    joint = find_free_axes(lambda r, tr: evaluate(r, tr).energy, pose, centre,
                           float(np.linalg.norm(np.ptp(moving.vertices, axis=0))), corr.spacing)
    found, unnamed = axis_names(motion) if motion is not None else (joint.free, ())
    held = hold_point(handle)  # where the simulation's coupling holds the part
    coupling = _coupling(handle, corr, scale.kappa)
    if scene.parts[-1].hold is not None:
        hold_source = "scene"
    elif held is not None:
        hold_source = "fit"
    else:
        held, hold_source = np.asarray(centre, dtype=float), "centre of mass"
    out = {
        "scene": str(scene.path),
        "pose": [float(x) for x in pose],
        "energy": result.energy,
        "force": [float(x) for x in result.force],
        "torque": [float(x) for x in result.torque] if result.torque is not None else None,
        "modes": result.modes,
        "band": band,
        "microseconds": micro,
        "backend": corr.backend,
        "backend_detail": corr.backend_name,
        "fft_size": corr.size,
        "fine_level": None if near is None else {
            "ratio": near.level.ratio, "terms": near.terms,
            "spacing": near.level.fixed_nodes.spacing / near.level.ratio,
            "walls": None if walls is None else {
                "points": near.walls.terms, "stiffness": near.walls.stiffness,
                # their share of the energy, force and torque above (not scaled by kappa)
                "energy": walls.energy, "force": [float(x) for x in walls.force],
                "torque": [float(x) for x in walls.torque]}},
        **scale.as_json(),
        "free_axes": {"found": list(found),
                      "declared": (None if scene.seat.free_axes is None
                                   else list(scene.seat.free_axes)),
                      "from": "motions" if motion is not None else "energy",
                      "unnamed": [[float(x) for x in d] for d in unnamed],
                      "curvature": joint.curvature, "step": joint.step,
                      "angle_deg": float(np.degrees(joint.angle))},
        "joint": None if motion is None else {
            "kind": motion.kind, "confidence": motion.confidence,
            "slides": [[float(x) for x in d] for d in motion.slides],
            "turns": [{"axis": [float(x) for x in a], "point": [float(x) for x in p]}
                      for a, p in motion.turns]},
        "hold": {"point": [float(x) for x in held], "source": hold_source},
        # the settings the scene leaves open, chosen from the parts, and why
        "chosen": [{"key": key, "value": value, "reason": reason}
                   for key, value, reason in scene.chosen],
        # the coupling's gains the simulation would use, and why
        "coupling": [{"key": key, "value": value, "reason": reason}
                     for key, value, reason in coupling],
        # the repairs made to the parts (duplicates dropped, holes): what was evaluated
        "notes": [str(w) for part in handle.parts for w in part.warnings],
    }
    from engine.scene.parts import say_notes

    for line in say_notes(out["notes"]):
        print(line, file=sys.stderr)
    if args.json:
        print(json.dumps(out))
        return 0
    units = scale.units
    print(f"scene      {scene.name} ({scene.path})")
    print(f"pose       t = {pose[:3].tolist()} {units.length}, rotation vector = "
          f"{pose[3:].tolist()} rad")
    print(f"energy     {result.energy:.6g} {units.energy}")
    print(f"force      {np.array2string(result.force, precision=5)} {units.force}  (|F| = "
          f"{np.linalg.norm(result.force):.5g})")
    if result.torque is not None:
        print(f"torque     {np.array2string(result.torque, precision=5)} {units.torque}")
    print(f"scale      {scale.describe()}")
    declared = ("" if scene.seat.free_axes is None
                else f" (the scene declares: {', '.join(scene.seat.free_axes) or 'none'})")
    if motion is not None:
        extra = "".join(f", and along {np.array2string(d, precision=3)}" for d in unnamed)
        which = ("only these keep" if found or unnamed else "none keeps")
        print(f"free axes  {', '.join(found) or 'none'}{extra} at this pose{declared}: a "
              f"{motion.kind} joint (confidence {motion.confidence:.2f}); of slides by "
              f"{REACH * length:.3g} {units.length} and turns by "
              f"{np.degrees(MOTION_ANGLE):.0f} deg each way along and about the contact's "
              f"principal directions, {which} part 2 out of part 1")
    else:
        print(f"free axes  {', '.join(joint.free) or 'none'} at this pose{declared}: the "
              f"parts do not meet here; along them the energy's curvature over one cell "
              f"({joint.step:.3g} {units.length}, or {np.degrees(joint.angle):.2g} deg) is "
              "under 5 % of the largest of their kind")
    where = {"scene": "named by the scene", "fit": "the middle of the fit",
             "centre of mass": "its centre of mass"}[hold_source]
    print(f"held at    {np.array2string(held, precision=4)} {units.length} in part 2's frame "
          f"({where})")
    print(f"modes      K = {result.modes} (m' = {result.modes ** 3}), {corr.params.band} band, "
          f"FFT size {corr.size}")
    if near is not None:
        lv = near.level
        print(f"fine level spacing {lv.fixed_nodes.spacing / lv.ratio:.4g} {units.length} "
              f"({lv.ratio} per descriptor cell) where the parts meet, {near.terms} terms")
        if walls is not None:
            print(f"walls      {near.walls.terms} points of part 2 against part 1's distance "
                  f"(docs/fine_level.md): energy {walls.energy:.6g} {units.energy}, force "
                  f"{np.array2string(walls.force, precision=5)} {units.force} of the above")
    print(f"time       {micro:.1f} us median over {len(times)} evaluations")
    print(f"backend    {corr.backend_name}")
    for key, value, reason in scene.chosen:
        print(f"chosen     {key} = {value}: {reason}")
    for key, value, reason in coupling:
        print(f"coupling   {key} = {value:.4g}: {reason}")
    return 0


def _coupling(handle, corr, kappa: float) -> list[tuple[str, float, str]]:
    """The coupling's gains the simulation resolves for the moving part, with reasons."""
    from engine.sim.build import coupling_choices, resolve_physics, rotational_stiffness
    from engine.sim.fields import CorrelatorField

    if len(handle.parts) < 2:
        return []
    moving = handle.parts[-1]
    fit = (rotational_stiffness(CorrelatorField(corr, kappa), handle.scene.assembled_pose)
           if corr.rotation and kappa > 0 else None)
    physics = resolve_physics(handle.config, moving.vertices, moving.faces, kappa=kappa,
                              geometric_rotation=fit)
    return coupling_choices(handle.config, physics, fit)


def progress_bar(
    label: str, *, enabled: bool = True
) -> tuple[Callable[[float], None] | None, Callable[[], None]]:
    """A tqdm bar on stderr fed with fractions 0..1, when stderr is a terminal.

    Returns the ``progress`` callback (None when there is no bar) and a function that
    closes the bar.
    """
    if not enabled or not sys.stderr.isatty():
        return None, lambda: None
    from tqdm import tqdm

    bar = tqdm(total=1000, desc=label, unit="", file=sys.stderr, leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")

    def update(fraction: float) -> None:
        bar.n = int(round(1000 * min(max(fraction, 0.0), 1.0)))
        bar.refresh()

    return update, bar.close
