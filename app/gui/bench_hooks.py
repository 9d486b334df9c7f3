"""The GUI half of ``skelasm bench loop --gui``: run the window on a scene for a while and
measure what the user sees.

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
                engine_kwargs: dict | None = None) -> dict:
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
        Passed to ``engine.api.start_engine`` (``rate_hz``, ``modes``, ``backend``).

    Returns
    -------
    dict
        ``fps`` (renders per second), ``latency_ms_p50/p95/p99/max`` (how late a 20 ms
        timer fired), ``engine_rate_hz`` (median of the frames' period stats),
        ``engine_p99_us``, ``eval_us`` (median), ``frames_received``, ``frames_rendered``,
        ``seconds``, ``guidance_ready``, ``engine`` (real or preview), ``scene``.
    """
    from app.gui.app import DEFAULT_SCENE, check_display, make_application

    problem = check_display()
    if problem:
        raise RuntimeError(problem)
    from PySide6 import QtCore, QtWidgets

    from app.gui.main_window import MainWindow
    from engine import api

    app = make_application()
    scene = Path(scene) if scene else DEFAULT_SCENE
    with tempfile.TemporaryDirectory(prefix="skelasm-bench-gui-") as tmp:
        settings = QtCore.QSettings(str(Path(tmp) / "settings.ini"),
                                    QtCore.QSettings.IniFormat)
        win = MainWindow(settings=settings, engine_kwargs=engine_kwargs)
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
                win.session.send(api.SetProxyPose(tuple(pose)))
                f = win.latest_frame
                if f is not None:
                    rates.append(f.period.rate_hz)
                    evals.append(f.eval_us)
                    p99.append(f.period.p99_us)

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

            return {
                "scene": str(scene),
                "engine": win.session.engine_name,
                "guidance_ready": bool(ready),
                "guidance_error": win.guidance_error,
                "seconds": elapsed,
                "fps": rendered / elapsed,
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
            QtWidgets.QApplication.processEvents()


def main() -> None:  # python -m app.gui.bench_hooks [SECONDS] [SCENE]
    import json
    import sys

    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 10.0
    scene = sys.argv[2] if len(sys.argv) > 2 else None
    print(json.dumps(run_gui_for(seconds, scene), indent=2))


if __name__ == "__main__":
    main()
