"""`skelasm bench loop`: achieved engine rate and period distribution.

Runs the engine loop in real time for ``--seconds`` on a scene (default the peg in hole,
m' = K^3 modes, rotation on) and prints the achieved rate and the period distribution
(median, 1st and 99th percentile, longest), optionally while something else competes for the
interpreter:

- ``--load python``: a thread doing pure-Python work (the worst case for the GIL: it never
  releases it by itself; stands in for GUI code building meshes, painting, event handling);
- ``--load numpy``: a thread doing large numpy operations (releases the GIL inside);
- ``--load vtk``: a thread rendering an off-screen pyvista scene and reading it back (does
  VTK hold the GIL while it renders?);
- ``--gui``: the real application window rendering beside the loop (``app.gui``, imported
  only then; without a screen a private Xvfb is started), with the engine in its own process
  as ``skelasm gui`` runs it, or in a thread of the window's process with ``--thread``;
- ``--process``: the loop in its own process (``engine.runtime.ProcessEngine``) while the load
  runs in this one;
- ``--switch-interval S``: ``sys.setswitchinterval`` while the loop runs (Python's default
  5 ms lets another thread hold the GIL for that long);
- ``--wait sleep|yield``: how the loop waits for its deadlines (default: ``yield`` at normal
  priority, ``sleep`` in real time; ``engine.runtime.pacing``);
- ``--modes-sweep K1,K2,...``: change K every ``--sweep-period`` seconds while measuring
  (the K slider): the new field is built by the engine's job worker; a second table counts
  the periods over 2 ms that end within 100 ms after a change against those between
  changes (the host's own stalls), which tells whether the loop felt the changes;
- ``--sweep-control``: the same marks every ``--sweep-period`` seconds with no command sent
  (the control for that table: the same windows, no K change).

Writes ``bench_loop.png`` (period histogram) unless ``--no-plot``.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

from engine.backend import choices, describe_auto

DEFAULT_SCENE = Path(__file__).resolve().parents[1] / "assets" / "peg_in_hole" / "scene.toml"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench loop`` to ``parser``."""
    parser.add_argument("--seconds", type=float, default=10.0, help="measured seconds (>= 10 "
                        "for the reported figures)")
    parser.add_argument("--modes", type=int, default=16, help="K, modes per axis (m' = K^3)")
    parser.add_argument("--scene", default=str(DEFAULT_SCENE), help="scene file")
    parser.add_argument("--rate", type=float, default=1000.0, help="target rate in Hz")
    parser.add_argument("--translation-only", action="store_true",
                        help="lock rotation (landscape lookup instead of the modal sum)")
    parser.add_argument("--backend", default="auto", choices=choices("per_pose"),
                        help=f"per-pose evaluator (auto: {describe_auto('per_pose')})")
    parser.add_argument("--load", choices=("none", "python", "numpy", "vtk"), default="none",
                        help="a competing thread in this process")
    parser.add_argument("--switch-interval", type=float, default=None,
                        help="sys.setswitchinterval while the loop runs (seconds; default as "
                             "start_engine: 0.5 ms for the thread engine, Python's 5 ms for "
                             "the process engine, 0.5 ms there while a job runs)")
    parser.add_argument("--process", action="store_true", help="run the loop in its own process")
    parser.add_argument("--fake", action="store_true",
                        help="an analytic field instead of the correlator (measures the loop "
                        "alone)")
    parser.add_argument("--gui", action="store_true",
                        help="run the GUI beside the loop, with the engine in its own process "
                             "as `skelasm gui` runs it")
    parser.add_argument("--thread", action="store_true",
                        help="with --gui: the engine in a thread of the window's process "
                             "(`skelasm gui --engine thread`)")
    parser.add_argument("--modes-sweep", default="",
                        help="comma-separated K values to cycle through while measuring")
    parser.add_argument("--sweep-period", type=float, default=0.5,
                        help="seconds between K changes of --modes-sweep")
    parser.add_argument("--sweep-control", action="store_true",
                        help="with --modes-sweep: mark the changes' times but send nothing "
                             "(the same windows with no K change)")
    parser.add_argument("--realtime-priority", action="store_true",
                        help="thread engine: ask for real-time scheduling of the loop thread "
                             "(the process engine always asks)")
    parser.add_argument("--wait", choices=("sleep", "yield"), default=None,
                        help="thread engine: how the loop waits for its deadlines (default: "
                             "yield at normal priority, sleep in real time)")
    parser.add_argument("--jobs", choices=("auto", "here", "process"), default="auto",
                        help="where a K change's truncations and landscapes are computed: "
                             "'auto' as the engine decides (a job process of their own when "
                             "the loop thread runs real-time or the machine has 4 cores or "
                             "more), 'here' in the loop's process, "
                             "'process' in a job process (docs/runtime.md, K changes)")
    parser.add_argument("--plot", default="bench_loop.png", help="histogram PNG ('' for none)")
    parser.add_argument("--full-path", action="store_true",
                        help="thread engine, rotation free: the full per-pose path every step "
                             "instead of the rotation cache")


def _python_load(stop: threading.Event, counter: list[int]) -> None:
    while not stop.is_set():
        total = 0
        for i in range(2000):
            total += i * i
        counter[0] += 1


def _numpy_load(stop: threading.Event, counter: list[int]) -> None:
    a = np.random.default_rng(0).random((600, 600))
    while not stop.is_set():
        a = np.tanh(a @ a.T * 1e-3)
        counter[0] += 1


def _vtk_load(stop: threading.Event, counter: list[int]) -> None:
    import pyvista as pv

    plotter = pv.Plotter(off_screen=True, window_size=(800, 600))
    plotter.add_mesh(pv.Sphere(theta_resolution=120, phi_resolution=120))
    while not stop.is_set():
        plotter.camera.azimuth += 2.0
        plotter.screenshot(return_img=True)  # a full render and read-back
        counter[0] += 1
    plotter.close()


def job_process(args: argparse.Namespace) -> bool | None:
    """``EngineLoop(job_process=)`` for ``--jobs``: None (the engine decides), False, True."""
    return {"auto": None, "here": False, "process": True}[args.jobs]


def switch_interval(args: argparse.Namespace) -> float | None:
    """The loop's switch interval: ``--switch-interval``, else the engine's own default.

    ``start_engine`` gives a thread engine :data:`engine.runtime.DEFAULT_SWITCH_INTERVAL`;
    a process engine keeps Python's (None) and shortens it only while a job runs.
    """
    if args.switch_interval is not None:
        return float(args.switch_interval)
    if args.process or (args.gui and not args.thread):
        return None
    from engine.runtime import DEFAULT_SWITCH_INTERVAL

    return DEFAULT_SWITCH_INTERVAL


def sweep_modes(args: argparse.Namespace) -> list[int]:
    """The K values of ``--modes-sweep``."""
    return [int(k) for k in args.modes_sweep.split(",") if k.strip()]


#: Seconds after a K change in which a period counts as the change's (``--modes-sweep``).
AFTER_CHANGE_S = 0.1


def _sweeper(args: argparse.Namespace, send, stop: threading.Event,
             sent: list[float]) -> threading.Thread:
    """A thread sending SetModes through ``send`` every ``--sweep-period`` seconds.

    Appends the ``perf_counter`` of each send to ``sent``; with ``--sweep-control`` it
    appends the times and sends nothing.
    """
    from engine.runtime import SetModes

    ks = sweep_modes(args)

    def body() -> None:
        i = 0
        while not stop.wait(args.sweep_period):
            sent.append(time.perf_counter())
            if not args.sweep_control:
                send(SetModes(ks[i % len(ks)]))
            i += 1

    return threading.Thread(target=body, name="bench-modes-sweep", daemon=True)


def after_changes(periods: np.ndarray, ends: np.ndarray, sent: list[float],
                  within: float = AFTER_CHANGE_S, late: float = 2e-3) -> dict[str, float]:
    """Periods right after each K change against those between changes.

    Parameters
    ----------
    periods, ends : (n,) float
        Periods in seconds and the ``perf_counter`` at which each ended.
    sent : list of float
        ``perf_counter`` of each SetModes; those outside the measured periods are left out.
    within : float
        A period ending within this many seconds after a change is the change's.
    late : float
        Periods longer than this (seconds) are counted.

    Returns
    -------
    dict
        ``changes``; ``changes_late`` (changes followed by a late period); ``after_n``,
        ``after_late``, ``after_max_us`` (the periods after changes); ``between_n``,
        ``between_late``, ``between_max_us`` (the others, from the first change on).
    """
    periods, ends = np.asarray(periods, float), np.asarray(ends, float)
    if len(ends):
        sent = [t for t in sent if ends[0] - periods[0] <= t <= ends[-1]]
    after = np.zeros(len(periods), bool)
    changes_late = 0
    for t in sent:
        mine = (ends > t) & (ends <= t + within)
        after |= mine
        changes_late += int(bool(np.any(periods[mine] > late)))
    between = ~after & (ends > (sent[0] if sent else np.inf))

    def stats(mask: np.ndarray) -> tuple[int, int, float]:
        p = periods[mask]
        return len(p), int((p > late).sum()), float(p.max() * 1e6) if len(p) else float("nan")

    a, b = stats(after), stats(between)
    return {"changes": len(sent), "changes_late": changes_late,
            "after_n": a[0], "after_late": a[1], "after_max_us": a[2],
            "between_n": b[0], "between_late": b[1], "between_max_us": b[2]}


#: A garbage collection longer than this (seconds) is counted in the report.
LONG_COLLECTION_S = 1e-3


def collections_report(table: np.ndarray, begin: float, sent: list[float],
                       within: float = AFTER_CHANGE_S) -> dict[str, float]:
    """The garbage collections of the measured time, and the long ones after K changes.

    Parameters
    ----------
    table : (m, 3) float
        ``perf_counter`` start, seconds and generation of each collection
        (:meth:`engine.runtime.pacing.CollectionLog.table`).
    begin : float
        ``perf_counter`` at which the measured periods begin; earlier collections are left
        out.
    sent : list of float
        ``perf_counter`` of each K change (or control mark).

    Returns
    -------
    dict
        ``n`` collections, ``full`` of them of the oldest generation (2), ``long`` (over
        :data:`LONG_COLLECTION_S`), ``longest_ms`` and ``longest_generation``, and
        ``long_after`` (long ones starting within ``within`` seconds after a change).
    """
    t = np.asarray(table, float).reshape(-1, 3)
    t = t[t[:, 0] >= begin]
    long = t[t[:, 1] > LONG_COLLECTION_S]
    after = sum(1 for start in long[:, 0]
                if any(0.0 <= start - mark <= within for mark in sent))
    top = int(np.argmax(t[:, 1])) if len(t) else -1
    return {"n": len(t), "full": int(np.count_nonzero(t[:, 2] == 2)), "long": len(long),
            "longest_ms": float(t[top, 1] * 1e3) if top >= 0 else 0.0,
            "longest_generation": int(t[top, 2]) if top >= 0 else -1,
            "long_after": after}


def run(args: argparse.Namespace) -> int:
    """Run the engine loop as the options ask (thread, process or beside the GUI) and report it.

    Prints the period statistics as a markdown table and whether the rate goal was met, and
    writes the period histogram unless ``--no-plot``. Returns the exit status (1 when no step
    was measured).
    """
    from engine.runtime import period_stats

    stop = threading.Event()
    counter = [0]
    load = None
    if args.load != "none":
        target = {"python": _python_load, "numpy": _numpy_load, "vtk": _vtk_load}[args.load]
        load = threading.Thread(target=target, args=(stop, counter), name="bench-load",
                                daemon=True)

    if args.wait is not None and (args.process or args.gui):
        print("--wait applies to the thread engine (the process engine chooses by its "
              "scheduling)", file=sys.stderr)
        return 2
    if args.gui and args.thread and args.process:
        print("--thread and --process exclude each other", file=sys.stderr)
        return 2
    if args.gui and not args.thread:
        args.process = True  # what `skelasm gui` does
    if args.gui:
        periods, info = _run_gui(args, load)  # a process engine, or a thread with --thread
    elif args.process:
        periods, info = _run_process(args, load)
    else:
        periods, info = _run_thread(args, load)
    stop.set()

    periods = np.asarray(periods)
    if len(periods) == 0 and info.get("engine_rate_hz") is not None:
        return _report_from_frames(args, info)
    if len(periods) == 0:
        print("no steps were measured", file=sys.stderr)
        return 1
    stats = period_stats(periods)
    late = float(np.mean(periods > 1.2e-3 * 1000.0 / args.rate)) * 100
    print(f"engine loop: {info['what']}, K = {args.modes} (m' = {args.modes ** 3}), "
          f"{info['field']}")
    interval = switch_interval(args)
    print(f"mode: {'process' if args.process else 'thread'}, load: {args.load}, "
          f"switch interval: {interval or sys.getswitchinterval()} s"
          + (", GUI running" if args.gui else "")
          + (f", K swept over {args.modes_sweep} every {args.sweep_period} s"
             + (" (control: marked, not sent)" if args.sweep_control else "")
             if sweep_modes(args) else "")
          + f", spectral jobs: {args.jobs}")
    if info.get("scheduling"):
        print(f"loop thread scheduling: {info['scheduling']}")
    if info.get("paths"):
        print(f"rotation cache, poses per path and refreshes: {info['paths']}")
    if info.get("handover") and sweep_modes(args):
        print(f"new fields held back until a cache served the part: {info['handover']}")
    print()
    print("| steps | seconds | rate (Hz) | median (us) | p1 (us) | p99 (us) | max (us) "
          "| > 1.2 periods | over 2 ms | eval median (us) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {len(periods)} | {periods.sum():.2f} | {stats.rate_hz:.1f} | {stats.median_us:.1f} "
          f"| {stats.p1_us:.1f} | {stats.p99_us:.1f} | {stats.max_us:.1f} | {late:.2f} % "
          f"| {int(np.count_nonzero(periods > 2e-3))} "
          f"| {info.get('eval_us', float('nan')):.1f} |")
    if info.get("sent"):
        c = after_changes(periods, info["ends"], info["sent"])
        what = "marks (control: no K change sent)" if args.sweep_control else "K changes"
        print(f"\n{what}: periods over 2 ms ending within {AFTER_CHANGE_S * 1e3:.0f} ms after "
              "a change, and between changes\n")
        print("| changes | changes followed by one | after: periods | over 2 ms | longest (us) "
              "| between: periods | over 2 ms | longest (us) |")
        print("|---|---|---|---|---|---|---|---|")
        print(f"| {c['changes']} | {c['changes_late']} | {c['after_n']} | {c['after_late']} "
              f"| {c['after_max_us']:.1f} | {c['between_n']} | {c['between_late']} "
              f"| {c['between_max_us']:.1f} |")
    if "collections" in info:
        ends = np.asarray(info["ends"], float)
        g = collections_report(info["collections"], float(ends[0] - periods[0]),
                               list(info.get("sent", [])))
        print(f"\ngarbage collections in the loop's process: {g['n']} ({g['full']} full), "
              f"{g['long']} over {LONG_COLLECTION_S * 1e3:.0f} ms"
              + (f" ({g['long_after']} within {AFTER_CHANGE_S * 1e3:.0f} ms after a change)"
                 if info.get("sent") else "")
              + (f", the longest {g['longest_ms']:.2f} ms (generation "
                 f"{g['longest_generation']})" if g["n"] else ""))
    if load is not None:
        print(f"\nload thread iterations: {counter[0]}")
    for key in ("gui_fps", "gui_latency_ms"):
        if key in info:
            print(f"{key}: {info[key]}")
    if args.plot:
        _plot(periods, args, stats, Path(args.plot))
        print(f"\nwrote {args.plot}")
    goal = stats.rate_hz >= 0.99 * args.rate and stats.p99_us <= 1200.0 * 1000.0 / args.rate
    print(f"goal (rate >= {0.99 * args.rate:.0f} Hz, p99 <= {1.2e6 / args.rate:.0f} us): "
          f"{'met' if goal else 'NOT met'}")
    return 0


def _handle(args: argparse.Namespace):
    """The scene, rotation locked with ``--translation-only``."""
    from dataclasses import replace

    from engine.runtime import open_scene

    handle = open_scene(args.scene)
    if args.translation_only:
        effects = replace(handle.config.effects, axes=("x", "y", "z"))
        handle = replace(handle, config=replace(handle.config, effects=effects))
    return handle


def _run_thread(args, load):
    from engine.devices import TrajectoryDevice
    from engine.runtime import AnalyticWell, EngineLoop, bench_trajectory
    from engine.runtime.pacing import WAIT_WORDS
    from engine.sim import CorrelatorField, RotationCacheField, build_simulation, evaluator_name

    handle = _handle(args)
    sim, model = build_simulation(handle, modes=args.modes, backend=args.backend,
                                  rate_hz=args.rate, prepare=not args.fake)
    if args.fake:
        sim.set_field(AnalyticWell(sim.physics.kappa))
    elif args.full_path and isinstance(sim.field, RotationCacheField):
        sim.set_field(CorrelatorField(sim.field.correlator, sim.physics.kappa))
    traj = TrajectoryDevice(bench_trajectory(sim, args.seconds + 2.0))
    loop = EngineLoop(sim, model=model, device=traj, realtime=True, keep_periods=True,
                      switch_interval=switch_interval(args),
                      raise_priority=args.realtime_priority, wait=args.wait,
                      job_process=job_process(args))
    if load is not None:
        load.start()
    stop = threading.Event()
    sent: list[float] = []
    if sweep_modes(args):
        _sweeper(args, loop.send, stop, sent).start()
    warm = int(0.5 * args.rate)
    try:
        loop.run(max_steps=warm + int(args.seconds * args.rate))
    finally:
        stop.set()
        loop.guidance.close()
    frames = loop.poll_frames()
    eval_us = float(np.median([f.eval_us for f in frames])) if frames else float("nan")
    counts = getattr(sim.field, "counts", None)
    return np.asarray(loop.periods)[warm:], {
        "ends": loop.window.ends()[warm:],
        "sent": sent,
        "what": f"{handle.scene.name} ({Path(args.scene).name})",
        "field": evaluator_name(sim.field),
        "paths": "" if counts is None else ", ".join(f"{k} {v}" for k, v in counts.items()),
        "handover": ", ".join(f"{k} {v}" for k, v in loop.guidance.handover.counts.items()),
        "eval_us": eval_us,
        "collections": loop.window.collections.table(),
        "scheduling": (f"{loop.scheduling}, waiting by {WAIT_WORDS[loop.waiting]}; "
                       f"refresh lane: {loop.guidance.refresh_lane.describe()}"),
    }


def _report_from_frames(args, info) -> int:
    """Print the report for the GUI with the engine in its own process.

    Shows the engine's own period statistics, as its frames carried them (medians over the
    measured time), beside the window's figures.
    """
    rate, p99 = float(info["engine_rate_hz"]), float(info["engine_p99_us"])
    print(f"engine loop: {info['what']}, K = {args.modes} (m' = {args.modes ** 3}), "
          f"{info['field']}")
    print("mode: process, GUI running (figures from the engine's frames)")
    if info.get("engine_note"):
        print(info["engine_note"])
    print()
    print("| rate (Hz) | p99 (us) | eval median (us) | GUI fps | GUI latency p50/p99/max (ms) |")
    print("|---|---|---|---|---|")
    lat = info["gui_latency_ms"]
    print(f"| {rate:.1f} | {p99:.1f} | {info.get('eval_us', float('nan')):.1f} | "
          f"{info['gui_fps']} | {lat['p50']} / {lat['p99']} / {lat['max']} |")
    goal = rate >= 0.99 * args.rate and p99 <= 1200.0 * 1000.0 / args.rate
    print(f"goal (rate >= {0.99 * args.rate:.0f} Hz, p99 <= {1.2e6 / args.rate:.0f} us): "
          f"{'met' if goal else 'NOT met'}")
    return 0


def _run_process(args, load):
    from engine.runtime import EngineOptions, ProcessEngine

    options = EngineOptions(
        modes=args.modes,
        backend=args.backend,
        analytic=args.fake,
        rate_hz=args.rate,
        switch_interval=args.switch_interval,
        raise_priority=True,  # as the GUI's engine process (SKELASM_REALTIME=0: off)
        keep_periods=True,
        job_process=job_process(args),
    )
    engine = ProcessEngine(_handle(args), options)
    engine.start()
    ready = engine.wait_ready(timeout=1800)
    if load is not None:
        load.start()
    stop = threading.Event()
    sent: list[float] = []
    if sweep_modes(args):
        _sweeper(args, engine.send, stop, sent).start()
    time.sleep(args.seconds + 0.5)
    stop.set()
    result = engine.stop_and_collect()
    if not ready:
        raise RuntimeError("the engine process did not get ready")
    warm = int(0.5 * args.rate)
    return result.periods[warm:], {
        "ends": result.ends[warm:],
        "sent": sent,
        "what": Path(args.scene).name,
        "field": result.described,
        "eval_us": result.eval_us,
        "collections": result.collections,
    }


def _run_gui(args, load):
    try:
        from app.gui import bench_hooks  # type: ignore[attr-defined]
    except ImportError as exc:
        raise RuntimeError(
            f"--gui needs the application's benchmark hooks (app.gui.bench_hooks): {exc}"
        ) from exc
    return bench_hooks.run_loop_benchmark(args, load)


def _plot(periods: np.ndarray, args, stats, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    us = periods * 1e6
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.hist(np.clip(us, 0, 3000), bins=120, log=True, color="#3572a5")
    for q, name in ((stats.median_us, "median"), (stats.p99_us, "p99")):
        ax.axvline(q, color="k", lw=0.8, ls="--")
        ax.text(q, ax.get_ylim()[1] * 0.5, f" {name} {q:.0f} us", fontsize=8)
    ax.set_xlabel("period (us), clipped at 3000")
    ax.set_ylabel("steps")
    mode = "process" if args.process else "thread"
    ax.set_title(f"engine loop at {args.rate:.0f} Hz, K={args.modes}, {mode}, load={args.load}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
