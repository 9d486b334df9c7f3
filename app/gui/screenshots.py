"""Screenshots of the running application for the documentation.

``python -m app.gui.screenshots OUTDIR [SCENE]`` (under ``xvfb-run -a`` without a screen)
opens the window on a scene at 1280 x 800, waits for the engine's descriptors and a
landscape, pulls the part towards its fit with the proxy, and saves the whole window and each
view as PNG; then it moves the proxy down the insertion axis to the assembled pose, lets the
engine seat the part, cuts the fixed part open and saves the seated part and its readouts;
then, paused, it places the part past its seat (into a blind bore's floor: the overlap
readout and the red part) and saves the window at 1280 x 800 and at 1920 x 1080 (the
virtual screen must be that large: ``xvfb-run -a -s "-screen 0 2000x1200x24"``).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def take(outdir: str | Path, scene: str | Path | None = None, *, wait_ready: float = 600.0,
         slice_part: int = 0) -> list[Path]:
    """Open the window on ``scene`` and save the screenshots for the documentation in ``outdir``.

    Waits up to ``wait_ready`` seconds for the engine's descriptors; ``slice_part`` picks the
    part shown in the descriptor slice. Returns the paths of the PNG files written.
    """
    from PySide6 import QtCore

    from app.gui.app import DEFAULT_SCENE, make_application
    from app.gui.main_window import MainWindow
    from engine import runtime

    app = make_application()
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    scene = Path(scene) if scene else DEFAULT_SCENE
    tmp = tempfile.TemporaryDirectory()
    settings = QtCore.QSettings(str(Path(tmp.name) / "s.ini"), QtCore.QSettings.IniFormat)
    win = MainWindow(settings=settings, engine_kwargs={"process": True})  # as `skelasm gui`
    win.resize(1280, 800)
    win.show()

    def spin(seconds: float, until=None) -> bool:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            app.processEvents(QtCore.QEventLoop.AllEvents, 20)
            if until is not None and until():
                return True
            time.sleep(0.003)
        return bool(until and until())

    win.open_path(scene, wait=True)
    if win.session.handle is None:
        raise RuntimeError(win.last_error or f"could not open {scene}")
    spin(30, lambda: win.latest_frame is not None)
    if not spin(wait_ready, lambda: win.guidance_ready or win.guidance_error):
        print("warning: the engine was not ready; views will be empty", file=sys.stderr)
    handle = win.session.handle
    start = np.asarray(handle.start_pose, float)
    goal = np.asarray(handle.assembled_pose, float)
    # drag the proxy (the ghost) towards the fit and off to the side, so that the part,
    # the ghost and the forces all show
    size = float(np.ptp(handle.parts[-1].vertices, axis=0).max())
    for f in np.linspace(0.0, 1.0, 30):
        pose = start + 0.2 * f * (goal - start)
        pose[0] += 0.35 * size * f
        win.session.send(runtime.SetProxyPose(tuple(pose)))
        spin(0.05)
    spin(2.0)
    view = win.slice_view
    view.part.setCurrentIndex(slice_part)
    view.axis.setCurrentIndex(1)
    view.component.setCurrentText("imaginary")
    win.landscape_view.plane.setCurrentText("xz")
    spin(20, lambda: win.landscape_view.landscape is not None)
    spin(1.0)
    shots = {
        "window.png": None,
        "view_3d.png": win.viewport.widget,
        "descriptor_slice.png": win.dock_slice,
        "energy_landscape.png": win.dock_landscape,
        "readouts.png": win.dock_readouts,
        "parameters.png": win.dock_params,
    }
    written = [win.save_screenshot(outdir / name, widget) for name, widget in shots.items()]
    # seat the part with the proxy alone: back to the start, then down to the fit
    win.session.send(runtime.Reset())
    spin(1.0)
    for f in np.linspace(0.0, 1.0, 60):
        win.session.send(runtime.SetProxyPose(tuple(start + f * (goal - start))))
        spin(0.05)
    spin(10.0, lambda: win.seat is not None and win.seat.seated)
    spin(1.0)
    if win.seat is None or not win.seat.seated:
        print(f"warning: the part did not seat: {win.seat_label.text()}", file=sys.stderr)
    win.view_panel.clip.setChecked(True)
    win.view_panel.opacity.setValue(60)
    spin(1.0)
    written += [win.save_screenshot(outdir / "seated_window.png"),
                win.save_screenshot(outdir / "seated_view_3d.png", win.viewport.widget),
                win.save_screenshot(outdir / "seated_readouts.png", win.dock_readouts)]
    # past the seat, paused so that it stays: the overlap readout and the red part
    win.pause_action.trigger()
    axis = handle.scene.insertion_axis
    past = goal.copy()
    past[:3] += 0.1 * size * (np.asarray(axis, float) if axis is not None else [0, 0, -1.0])
    win.session.send(runtime.Reset(tuple(float(v) for v in past)))
    spin(3.0, lambda: win.overlap_depth is not None and win.overlap_depth > 0)
    spin(1.0)
    written.append(win.save_screenshot(outdir / "overshoot_window.png"))
    win.resize(1920, 1080)
    spin(2.0)
    written.append(win.save_screenshot(outdir / "window_1920x1080.png"))
    win.close()
    tmp.cleanup()
    from app.gui.session import wait_for_workers

    wait_for_workers(120.0)
    return written


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit("usage: python -m app.gui.screenshots OUTDIR [SCENE]")
    for p in take(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else None):
        print(p)
