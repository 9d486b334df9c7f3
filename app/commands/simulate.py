"""`skelasm simulate SCENE`: run a scene headless and report where the part ended up."""

from __future__ import annotations

import argparse
import json
import sys

from app.commands.arguments import check_rotation_vector, finite_float, positive_float
from app.commands.poses import add_about_argument, typed_pose
from engine.backend import choices


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm simulate`` (a headless run with a scripted proxy) to ``sub``."""
    p = sub.add_parser(
        "simulate",
        help="run a scene headless (scripted proxy) and report the final pose and timing",
        description="Step a scene's simulation without a GUI. The proxy follows --trajectory "
        "(CSV t,tx,ty,tz,rx,ry,rz relative to part 1) or stays at the start pose.",
    )
    p.add_argument("scene", help="scene file (TOML)")
    p.add_argument("--trajectory", metavar="IN.csv", help="proxy trajectory CSV")
    p.add_argument("--seconds", type=positive_float, default=None,
                   help="simulated seconds (default: the trajectory's length + 1 s, else the "
                   "scene's [simulation] seconds)")
    p.add_argument("--log", metavar="OUT.csv", help="record every step (CSV, or .npz), "
                   "streamed to the file: Ctrl+C keeps the steps recorded so far")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --log file (never an input file)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--realtime", dest="realtime", action="store_true",
                      help="hold the scene's rate on the wall clock")
    mode.add_argument("--as-fast-as-possible", dest="realtime", action="store_false",
                      help="step as fast as possible (default)")
    p.set_defaults(realtime=False)
    p.add_argument("--guidance", choices=("skeletal", "collision", "none"),
                   help="override the scene's [effects] guidance")
    p.add_argument("--modes", type=int, help="override the scene's [correlation] modes")
    p.add_argument("--backend", default="auto", choices=choices("per_pose"),
                   help="per-pose evaluator of the correlator")
    p.add_argument("--start", type=finite_float, nargs=6,
                   metavar=("TX", "TY", "TZ", "RX", "RY", "RZ"),
                   help="start pose of part 2 relative to part 1, turning about its centre "
                   "(see --about; default: the scene's start)")
    add_about_argument(p, "--start")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Step the scene's simulation headless and print the final pose and timing.

    Returns the exit status.
    """
    from dataclasses import replace

    import numpy as np

    from engine.devices import DeviceError, MouseDevice, TrajectoryDevice, open_device
    from engine.errors import InputError
    from engine.files import check_output, disk_space_error, files_digest
    from engine.params import QuantityUnits
    from engine.pose import relative_pose
    from engine.recording import CSV_ROW_BYTES, NPZ_ROW_BYTES, RecordingWriter, recording_scene
    from engine.runtime import EngineLoop, open_scene, period_stats
    from engine.runtime.frames import RECORDING_INDEX
    from engine.seat import seat_state
    from engine.sim import build_simulation, evaluator_name

    if args.modes is not None:  # 0 would be taken for "the scene's"
        from engine.params import check_modes

        check_modes(args.modes, "--modes")
    if args.start is not None:
        check_rotation_vector(args.start[3:], "--start")
    if args.trajectory:  # a device, a FIFO or a folder is refused before the scene's work
        from engine.files import MAX_TRAJECTORY_BYTES, input_problem

        problem = input_problem(args.trajectory, what="trajectory file",
                                limit=MAX_TRAJECTORY_BYTES)
        if problem:
            raise InputError(problem)
    handle = open_scene(args.scene)
    inputs = [handle.path, *(spec.file for spec in handle.scene.parts)]
    if args.log:  # before any work: a bad path costs nothing, an input is never replaced
        check_output(args.log, force=args.force, what="log",
                     inputs=inputs + ([args.trajectory] if args.trajectory else []))
    scene_tag = files_digest(inputs)
    if args.guidance:
        effects = replace(handle.config.effects, guidance=args.guidance)
        handle = replace(handle, config=replace(handle.config, effects=effects))
    if args.start is not None:
        handle = replace(handle, start_pose=typed_pose(handle, args.start, args.about))
    # Before any work: the run's length, its step count and the trajectory's poses.
    trajectory = TrajectoryDevice(args.trajectory) if args.trajectory else None
    seconds, steps = _duration(args, trajectory, handle)
    sim, model = build_simulation(handle, modes=args.modes, backend=args.backend, prepare=True)

    notes = [f"{w}" for part in handle.parts for w in part.warnings]
    field_modes = getattr(sim.field, "modes", None)
    if args.modes is not None and field_modes is not None and int(field_modes) < args.modes:
        notes.append(f"--modes {args.modes} is more than this scene's FFT holds per axis: "
                     f"K = {int(field_modes)} used (a finer grid holds more)")
    if trajectory is not None:
        device = trajectory
        recorded_with = recording_scene(args.trajectory)
        if recorded_with is not None and recorded_with != scene_tag:
            notes.append(f"{args.trajectory} was recorded with another scene (or other part "
                         f"files) than {handle.path}: replaying it here does not reproduce "
                         "the recorded motion")
    else:
        cfg = handle.config.device
        try:
            device = open_device(cfg.kind, sim.proxy_pose, dict(cfg.options), handle.path.parent)
        except DeviceError as exc:
            notes.append(f"{exc}")
            device = MouseDevice(sim.proxy_pose)

    recorder = None
    if args.log:
        per_row = NPZ_ROW_BYTES if str(args.log).lower().endswith(".npz") else CSV_ROW_BYTES
        room = disk_space_error(args.log, steps * per_row, what=f"log of {steps} steps")
        if room is not None:
            raise InputError(f"{room} (or record fewer --seconds)")
        recorder = RecordingWriter(args.log, index=RECORDING_INDEX, scene=scene_tag)
    loop = EngineLoop(
        sim,
        model=model,
        device=device,
        realtime=args.realtime,
        keep_periods=True,
        on_frame=_with_progress(recorder.on_frame if recorder else None, steps, sim.dt),
    )
    import time

    t0 = time.perf_counter()
    try:
        taken = loop.run(max_steps=steps)
    except BaseException:
        if recorder is not None:  # Ctrl+C or a failure: keep every step recorded so far
            recorder.close()
            print(f"log: kept {recorder.count} steps in {args.log}", file=sys.stderr)
        raise
    wall = time.perf_counter() - t0
    device.disconnect()
    device_stats = device.stats()  # the UDP bridge: packets in, replies, drops by reason
    if device_stats.get("dropped"):
        reasons = ", ".join(f"{k} {n}" for k, n in device_stats["dropped_by_reason"].items())
        notes.append(f"{device.name}: dropped {device_stats['dropped']} packet(s) ({reasons})")
    for event in loop.poll_events():
        msg = getattr(event, "message", "")
        if msg and type(event).__name__ in ("DeviceEvent", "ErrorEvent"):
            notes.append(msg)
    if recorder is not None:
        recorder.close()

    final = sim.part_pose()
    target = np.asarray(handle.assembled_pose, float)
    error_pose = relative_pose(target, final)
    moving = handle.parts[-1]
    seat = seat_state(final, target, sim.physics.centre, handle.scene.seat,
                      float(np.linalg.norm(np.ptp(moving.vertices, axis=0))))
    units = QuantityUnits.of(handle.scene.units)
    stats = period_stats(np.asarray(loop.periods))
    frames = loop.poll_frames()
    eval_us = [f.eval_us for f in frames]
    result = {
        "scene": str(handle.path),
        "guidance": sim.effects.guidance,
        "axes": list(sim.effects.axes),
        "backend": evaluator_name(sim.field),
        "modes": int(getattr(sim.field, "modes", 0)),
        "final_pose": [float(v) for v in final],
        "assembled_pose": [float(v) for v in target],
        "distance_to_assembled": float(np.linalg.norm(error_pose[:3])),
        "angle_to_assembled_deg": float(np.degrees(np.linalg.norm(error_pose[3:]))),
        "seat": {"seated": seat.seated, "distance": seat.distance, "angle_deg": seat.angle_deg,
                 "free_travel": seat.free_travel, "free_axes": seat.free_axes,
                 "tolerance": [seat.distance_tolerance, seat.angle_tolerance_deg]},
        "steps": int(taken),
        "simulated_seconds": float(sim.time),
        "wall_seconds": float(wall),
        "realtime": bool(args.realtime),
        "rate_hz": float(taken / wall) if wall > 0 else 0.0,
        "period_us": {
            "median": stats.median_us,
            "p1": stats.p1_us,
            "p99": stats.p99_us,
            "max": stats.max_us,
        },
        "eval_us_median_last": float(np.median(eval_us)) if eval_us else 0.0,
        "final_energy": float(sim.sample.energy),
        "kappa": float(sim.physics.kappa),
        "units": {"length": units.length, "energy": units.energy, "force": units.force,
                  "torque": units.torque, "kappa": units.kappa},
        "haptic_force": [float(v) for v in sim.haptic_force],
        "device": {"name": device.name, **device_stats},
        "notes": notes,
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        from engine.scene.parts import say_notes

        for line in say_notes(notes):
            print(line, file=sys.stderr)
        f = result["final_pose"]
        mode = "realtime" if args.realtime else "as fast as possible"
        print(f"{result['scene']}: {taken} steps ({sim.time:.3f} s simulated) in {wall:.2f} s "
              f"wall, {result['rate_hz']:.0f} steps/s ({mode})")
        print(f"guidance {result['guidance']}, evaluator {result['backend']}, "
              f"K = {result['modes']}")
        print("final pose  t = (" + ", ".join(f"{v:.4g}" for v in f[:3]) + "), r = ("
              + ", ".join(f"{v:.4g}" for v in f[3:]) + ")")
        print(f"to assembled: {result['distance_to_assembled']:.4g} {handle.scene.units}, "
              f"{result['angle_to_assembled_deg']:.3g} deg")
        free = (", ".join(seat.free_axes) or "none") if seat.free_axes is not None else "unknown"
        print(f"seat: {'SEATED' if seat.seated else 'not seated'} ({seat.distance:.4g} "
              f"{units.length} and {seat.angle_deg:.3g} deg from the seat along the locked axes; "
              f"tolerance {seat.distance_tolerance:.3g} {units.length}, "
              f"{seat.angle_tolerance_deg:.3g} deg; free axes: {free})")
        print(f"energy: {result['final_energy']:.6g} {units.energy} (kappa = "
              f"{sim.physics.kappa:.6g} {units.kappa})")
        p = result["period_us"]
        print(f"period us: median {p['median']:.1f}, p1 {p['p1']:.1f}, p99 {p['p99']:.1f}, "
              f"max {p['max']:.1f}")
        if args.log:
            print(f"log: {args.log}")
    return 0


def _duration(args: argparse.Namespace, trajectory, handle) -> tuple[float, int]:
    """Simulated seconds and steps of the run, checked before any work (InputError)."""
    import numpy as np

    from engine.errors import InputError
    from engine.params import check_steps
    from engine.sim.guard import check_proxy_pose

    rate = handle.config.simulation.rate_hz
    if trajectory is not None:
        times = trajectory.times
        if times[0] < 0 or not np.all(np.isfinite(times)):
            raise InputError(f"{args.trajectory}: its times run from {times[0]:g} to "
                             f"{times[-1]:g} s; they are seconds from the start of the run, "
                             "from 0 on (shift them so the first row is at 0)")
        length = float(np.max(handle.parts[-1].extent))
        for row, pose in enumerate(trajectory.poses, start=2):
            check_proxy_pose(pose, length, f"{args.trajectory}: row {row}: the pose")
    if args.seconds is not None:
        seconds, what = args.seconds, "--seconds"
    elif trajectory is not None:
        seconds, what = trajectory.duration + 1.0, f"{args.trajectory}: its last time + 1 s"
    else:
        seconds, what = handle.config.simulation.seconds, "[simulation] seconds"
    return seconds, check_steps(seconds, rate, what)


def _with_progress(on_frame, steps: int, dt: float):
    """``on_frame`` that also reports progress on stderr every 5 s of a long run."""
    import time

    started = time.monotonic()
    state = {"count": 0, "next": started + 5.0}

    def frame(f) -> None:
        if on_frame is not None:
            on_frame(f)
        state["count"] += 1
        if state["count"] % 1000:
            return
        now = time.monotonic()
        if now < state["next"]:
            return
        state["next"] = now + 5.0
        done = state["count"] / steps
        left = (now - started) * (1.0 / max(done, 1e-9) - 1.0)
        print(f"simulate: {state['count'] * dt:.1f} of {steps * dt:.1f} s simulated "
              f"({100 * done:.0f} %), about {left:.0f} s left", file=sys.stderr, flush=True)

    return frame
