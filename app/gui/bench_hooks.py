"""The GUI half of ``skelasm bench loop --gui``.

Runs the window on a scene for a while and measures what the user sees.

:func:`run_gui_for` opens the main window, waits for the engine, then for ``seconds`` moves
the proxy along a circle through the same path a mouse drag takes (``SetProxyPose`` from the
GUI thread) and reports the render rate, the event-loop latency and the engine's rate.
It needs a display (``xvfb-run -a`` on a headless machine).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np


def run_gui_for(seconds: float = 10.0, scene: str | Path | None = None, *,
                wait_ready: float = 180.0, drag_radius: float | None = None,
                engine_kwargs: dict | None = None, keep_periods: bool = False,
                handle_transform=None, window_size: tuple[int, int] | None = None) -> dict:
    """Run the window for ``seconds`` while the proxy is dragged; return measurements.

    Parameters
    ----------
    seconds : float
        Measured time, after the engine is ready.
    scene : path, optional
        Default: the peg-in-hole example.
    wait_ready : float
        Longest wait for the engine's descriptors (ReadyEvent) before measuring anyway.
    drag_radius : float, optional
        Radius of the proxy's circle, scene units (default: a tenth of the moving part).
    engine_kwargs : dict, optional
        Passed to ``engine.runtime.start_engine`` (``rate_hz``, ``modes``, ``backend``,
        ``switch_interval``, ``process``).
    keep_periods : bool
        Also return ``periods``: every engine loop period (seconds) of the measured time
        (thread engine only).
    handle_transform : callable, optional
        SceneHandle -> SceneHandle before the engine starts (e.g. rotation locked).
    window_size : (int, int), optional
        Window width and height (default: the window's own, 1500 x 920).

    Returns
    -------
    dict
        ``fps`` (renders per second), ``latency_ms_p50/p95/p99/max`` (how late a 20 ms
        timer fired), ``engine_rate_hz`` (median of the frames' period stats),
        ``engine_p99_us``, ``eval_us`` (median), ``frames_received``, ``frames_rendered``,
        ``seconds``, ``guidance_ready``, ``engine`` ("engine" or "engine process"), ``scene``.
    """
    from app.gui.app import DEFAULT_SCENE, check_display, make_application

    problem = check_display()
    if problem:
        raise RuntimeError(problem)
    from PySide6 import QtCore, QtWidgets

    from app.gui.main_window import MainWindow
    from engine import runtime

    app = make_application()
    scene = Path(scene) if scene else DEFAULT_SCENE
    with tempfile.TemporaryDirectory(prefix="skelasm-bench-gui-") as tmp:
        settings = QtCore.QSettings(str(Path(tmp) / "settings.ini"),
                                    QtCore.QSettings.IniFormat)
        win = MainWindow(settings=settings, engine_kwargs=engine_kwargs,
                         handle_transform=handle_transform)
        if window_size is not None:
            win.resize(*window_size)
        win.show()
        try:
            win.open_path(scene, wait=True)
            if win.session.handle is None:
                raise RuntimeError(win.last_error or f"could not open {scene}")

            def spin_until(predicate, limit: float) -> bool:
                end = time.perf_counter() + limit
                while time.perf_counter() < end:
                    app.processEvents(QtCore.QEventLoop.AllEvents, 20)
                    if predicate():
                        return True
                    time.sleep(0.002)
                return predicate()

            spin_until(lambda: win.latest_frame is not None, 30.0)
            ready = spin_until(lambda: win.guidance_ready or win.guidance_error, wait_ready)
            ready = win.guidance_ready
            handle = win.session.handle
            start = np.asarray(win.latest_frame.proxy_pose, float).copy() \
                if win.latest_frame is not None else np.asarray(handle.start_pose, float)
            size = float(np.ptp(handle.parts[-1].vertices, axis=0).max())
            radius = drag_radius if drag_radius is not None else 0.1 * size

            rates, evals, p99 = [], [], []
            t0 = time.perf_counter()

            def drag_step() -> None:
                t = time.perf_counter() - t0
                pose = start.copy()
                pose[0] += radius * np.sin(2 * np.pi * 0.5 * t)
                pose[1] += radius * (1 - np.cos(2 * np.pi * 0.5 * t))
                win.session.send(runtime.SetProxyPose(tuple(pose)))
                f = win.latest_frame
                if f is not None:
                    rates.append(f.period.rate_hz)
                    evals.append(f.eval_us)
                    p99.append(f.period.p99_us)

            engine = win.session.engine
            loop = engine.transport if engine is not None else None
            window = loop.window if isinstance(loop, runtime.EngineLoop) else None
            if keep_periods and window is not None:
                del window.periods[:]
                window.keep = True
            driver = QtCore.QTimer()
            driver.timeout.connect(drag_step)
            driver.start(16)
            win.latency.reset()
            rendered0 = win.viewport.frames_rendered
            received0 = win.frames_received
            t_start = time.perf_counter()
            spin_until(lambda: False, seconds)
            elapsed = time.perf_counter() - t_start
            driver.stop()
            lat = np.asarray(win.latency.samples, float)
            rendered = win.viewport.frames_rendered - rendered0

            def pct(q):
                return float(np.percentile(lat, q)) if lat.size else float("nan")

            periods = None
            if keep_periods and window is not None:
                window.keep = False
                periods = np.asarray(window.periods, float)
            return {
                "periods": periods,
                "scene": str(scene),
                "scene_name": handle.scene.name,
                "backend": win.evaluator,
                "engine": win.session.engine_name,
                "engine_note": win.engine_note,
                "guidance_ready": bool(ready),
                "guidance_error": win.guidance_error,
                "seconds": elapsed,
                "fps": rendered / elapsed,
                "view_pixels": [win.viewport.widget.width(), win.viewport.widget.height()],
                "frames_rendered": int(rendered),
                "frames_received": int(win.frames_received - received0),
                "latency_ms_p50": pct(50),
                "latency_ms_p95": pct(95),
                "latency_ms_p99": pct(99),
                "latency_ms_max": float(lat.max()) if lat.size else float("nan"),
                "engine_rate_hz": float(np.median(rates)) if rates else 0.0,
                "engine_p99_us": float(np.median(p99)) if p99 else 0.0,
                "eval_us": float(np.median(evals)) if evals else 0.0,
            }
        finally:
            win.close()
            win.deleteLater()
            QtWidgets.QApplication.processEvents()
            # free Qt and VTK objects now, not during interpreter shutdown
            import gc

            gc.collect()
            from app.gui.session import wait_for_workers

            wait_for_workers(120.0)


def run_loop_benchmark(args, load=None):
    """``skelasm bench loop --gui``: the engine loop with the application window running.

    Parameters
    ----------
    args : argparse.Namespace
        bench/loop.py's options (``scene``, ``seconds``, ``rate``, ``modes``, ``backend``,
        ``switch_interval``, ``translation_only``).
    load : threading.Thread, optional
        Extra competing load, started when the measurement starts.

    Returns
    -------
    periods : (n,) float64
        Engine loop periods in seconds over the measured time.
    info : dict
        ``what``, ``field``, ``eval_us``, ``gui_fps``, ``gui_latency_ms`` (p50/p99/max) and
        ``guidance_ready``.
    """
    from dataclasses import replace

    kwargs = {"rate_hz": args.rate, "modes": args.modes, "backend": args.backend}
    if args.process:
        # the engine process keeps no period list for us: its frames carry its period stats
        kwargs["process"] = True
    if args.switch_interval is not None:
        kwargs["switch_interval"] = args.switch_interval
    transform = None
    if args.translation_only:
        def transform(handle):
            effects = replace(handle.config.effects, axes=("x", "y", "z"))
            return replace(handle, config=replace(handle.config, effects=effects))
    if load is not None:
        load.start()
    r = run_gui_for(args.seconds, args.scene, engine_kwargs=kwargs, keep_periods=True,
                    handle_transform=transform)
    periods = r["periods"] if r["periods"] is not None else np.zeros(0)
    info = {
        "what": f"{r['scene_name']} ({Path(r['scene']).name}), GUI {r['engine']}",
        "field": r["backend"] if r["guidance_ready"] else
        f"no correlator ({r['guidance_error'] or 'not ready'})",
        "eval_us": r["eval_us"],
        "gui_fps": round(r["fps"], 1),
        "gui_latency_ms": {k: round(r[f"latency_ms_{k}"], 1) for k in ("p50", "p99", "max")},
        "guidance_ready": r["guidance_ready"],
        "engine_rate_hz": r["engine_rate_hz"],
        "engine_p99_us": r["engine_p99_us"],
        "engine_note": r["engine_note"],
    }
    return periods, info


def main() -> None:  # python -m app.gui.bench_hooks [SECONDS] [SCENE]
    """Run the window for ``SECONDS`` on ``SCENE`` (command-line arguments) and print its figures.

    The figures are printed as JSON, without the individual periods.
    """
    import json
    import sys

    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    scene = sys.argv[2] if len(sys.argv) > 2 else None
    result = run_gui_for(seconds, scene)
    result.pop("periods")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
