"""The main window: 3D view in the centre, docks around it.

The docks hold readouts, parameters, descriptor slices and the energy landscape; the
window also owns the menus, shortcuts, recent files and remembered layout.

One QTimer (:attr:`MainWindow.TICK_MS`) drives the GUI side of the loop: drain the engine's
frames and events, move actors, update readouts (throttled) and render once if anything
changed. A second, idle timer measures event-loop latency (how late it fires).
"""

from __future__ import annotations

import collections
import time
from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app.gui.landscape_view import LandscapeView
from app.gui.params_panel import ParamsPanel
from app.gui.session import FILE_FILTER, PART_SUFFIXES, SCENE_SUFFIXES, Session
from app.gui.slice_view import SliceView
from app.gui.strip_chart import StripChart
from app.gui.viewport import Viewport
from app.gui.widgets import Readouts
from engine import pose as posemath
from engine import runtime

ORGANISATION = "skelasm"
APPLICATION = "skelasm"
MAX_RECENT = 8

HELP_TEXT = """<h3>Assembling</h3>
<ul>
<li><b>Drag</b> the orange part (or its blue ghost) with the left button: the ghost (the
input proxy) follows the mouse in the view plane and the engine pulls the part after it.</li>
<li><b>Shift + drag</b> up/down, or the <b>wheel</b> while dragging: move along the view
direction.</li>
<li><b>Ctrl + drag</b>: rotate the proxy about its centre (arcball).</li>
<li>Elsewhere the mouse turns (left), pans (middle) and zooms (wheel) the camera.</li>
</ul>
<h3>Keys</h3>
<table>
<tr><td>Ctrl+O</td><td>open a scene or part</td></tr>
<tr><td>Ctrl+S</td><td>save the scene</td></tr>
<tr><td>Space</td><td>pause / resume the engine</td></tr>
<tr><td>Ctrl+R</td><td>put the part back at its start pose</td></tr>
<tr><td>[ and ]</td><td>fewer / more modes (accuracy against time)</td></tr>
<tr><td>Ctrl+0</td><td>reset the camera</td></tr>
<tr><td>F12</td><td>save a screenshot of the window</td></tr>
</table>"""


class LatencyMonitor(QtCore.QObject):
    """Fires every ``interval_ms`` and records how late each firing was (milliseconds)."""

    def __init__(self, parent=None, interval_ms: int = 20, keep: int = 3000):
        super().__init__(parent)
        self.interval = interval_ms / 1000.0
        self.samples: collections.deque[float] = collections.deque(maxlen=keep)
        self._timer = QtCore.QTimer(self)
        self._timer.setTimerType(QtCore.Qt.PreciseTimer)
        self._timer.timeout.connect(self._fired)
        self._last = None

    def start(self) -> None:
        """Start the timer; lateness counts from now."""
        self._last = time.perf_counter()
        self._timer.start(int(self.interval * 1000))

    def _fired(self) -> None:
        now = time.perf_counter()
        if self._last is not None:
            self.samples.append(max(0.0, (now - self._last - self.interval) * 1000.0))
        self._last = now

    def reset(self) -> None:
        """Forget the recorded lateness samples."""
        self.samples.clear()


class MainWindow(QtWidgets.QMainWindow):
    """The skelasm desktop application's window.

    Parameters
    ----------
    settings : QSettings, optional
        Where recent files and the layout are kept (tests pass a temporary one).
    realtime : bool
        Run the engine on the wall clock (True) or as fast as it can.
    """

    TICK_MS = 10
    READOUT_PERIOD = 0.1  # seconds between text updates
    VIEW_PERIOD = 0.2  # seconds between landscape re-cuts / slice plane moves

    def __init__(self, *, settings: QtCore.QSettings | None = None, realtime: bool = True,
                 engine_kwargs=None, handle_transform=None):
        super().__init__()
        self.settings = settings or QtCore.QSettings(ORGANISATION, APPLICATION)
        self.session = Session(self, realtime=realtime, engine_kwargs=engine_kwargs,
                               handle_transform=handle_transform)
        self.session.opened.connect(self._scene_opened)
        self.session.open_failed.connect(self._open_failed)
        self.last_error: str | None = None
        self.error_dialog: QtWidgets.QMessageBox | None = None
        self.latest_frame: runtime.Frame | None = None
        self.frames_received = 0
        self.engine_note = ""  # the engine's ReadyEvent message (its loop's scheduling)
        self._landscape_pending = False
        self._force_scale = 0.0
        self._torque_scale = 0.0
        self._last_readout = 0.0
        self._last_view = 0.0
        self._fps_t = time.perf_counter()
        self._fps_frames = 0
        self.fps = 0.0
        self.descriptor_seconds = None
        self.guidance_ready = False  # a correlator is in use: landscapes can be asked for
        self.guidance_error: str | None = None

        self.setWindowTitle("skelasm")
        self.setAcceptDrops(True)
        self.setDockNestingEnabled(True)
        self.viewport = Viewport(self)
        self.setCentralWidget(self.viewport.widget)
        self.viewport.proxy_dragged.connect(self._proxy_dragged)
        self.viewport.drag_state.connect(self._drag_state)

        self.readouts = Readouts([
            ("energy", "energy E"),
            ("force", "|force|"),
            ("torque", "|torque|"),
            ("rate", "engine rate"),
            ("eval", "µs / evaluation"),
            ("modes", "m' (modes)"),
            ("period", "period p50 / p99"),
            ("backend", "evaluator"),
            ("device", "device"),
        ])
        self.chart = StripChart(seconds=10.0)
        box = QtWidgets.QWidget()
        lay = QtWidgets.QVBoxLayout(box)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.readouts)
        lay.addWidget(self.chart, 1)
        self.dock_readouts = self._dock("Readouts", box, QtCore.Qt.RightDockWidgetArea)

        self.params = ParamsPanel()
        self.params.command.connect(self._command)
        scroll = QtWidgets.QScrollArea()
        scroll.setWidget(self.params)
        scroll.setWidgetResizable(True)
        self.dock_params = self._dock("Parameters", scroll, QtCore.Qt.RightDockWidgetArea)

        self.slice_view = SliceView()
        self.slice_view.plane_changed.connect(self.viewport.show_slice_plane)
        self.dock_slice = self._dock("Descriptor slice", self.slice_view,
                                     QtCore.Qt.LeftDockWidgetArea)
        self.landscape_view = LandscapeView()
        self.dock_landscape = self._dock("Energy landscape", self.landscape_view,
                                         QtCore.Qt.LeftDockWidgetArea)

        self.status_engine = QtWidgets.QLabel("engine: -")
        self.status_fps = QtWidgets.QLabel("fps: -")
        self.status_latency = QtWidgets.QLabel("latency: -")
        for w in (self.status_engine, self.status_fps, self.status_latency):
            self.statusBar().addPermanentWidget(w)
        self._build_menus()
        self.params.pause.toggled.connect(self._pause_changed)

        self.latency = LatencyMonitor(self)
        self._tick_timer = QtCore.QTimer(self)
        self._tick_timer.setTimerType(QtCore.Qt.PreciseTimer)
        self._tick_timer.timeout.connect(self.tick)
        self.resize(1500, 920)
        self._restore_layout()
        self._tick_timer.start(self.TICK_MS)
        self.latency.start()

    # ------------------------------------------------------------------ construction
    def _dock(self, title: str, widget, area) -> QtWidgets.QDockWidget:
        dock = QtWidgets.QDockWidget(title, self)
        dock.setObjectName(title.lower().replace(" ", "_"))
        dock.setWidget(widget)
        self.addDockWidget(area, dock)
        return dock

    def _action(self, menu, text, slot, shortcut=None, checkable=False):
        action = QtGui.QAction(text, self)
        if shortcut:
            action.setShortcut(QtGui.QKeySequence(shortcut))
            action.setShortcutContext(QtCore.Qt.WindowShortcut)
        action.setCheckable(checkable)
        action.triggered.connect(slot)
        menu.addAction(action)
        self.addAction(action)  # shortcuts work while the menu bar is hidden or unfocused
        return action

    def _build_menus(self) -> None:
        bar = self.menuBar()
        file = bar.addMenu("&File")
        self._action(file, "&Open scene or part…", self.open_dialog, QtGui.QKeySequence.Open)
        self.recent_menu = file.addMenu("Open &recent")
        self._action(file, "&Save scene as…", self.save_dialog, QtGui.QKeySequence.Save)
        file.addSeparator()
        self._action(file, "Save screens&hot…", self.screenshot_dialog, "F12")
        file.addSeparator()
        self._action(file, "&Quit", self.close, QtGui.QKeySequence.Quit)
        self._update_recent_menu()

        view = bar.addMenu("&View")
        for dock in (self.dock_readouts, self.dock_params, self.dock_slice, self.dock_landscape):
            view.addAction(dock.toggleViewAction())
        view.addSeparator()
        self._action(view, "Reset &camera", self.reset_camera, "Ctrl+0")

        sim = bar.addMenu("&Simulation")
        self.pause_action = self._action(sim, "&Pause", self._toggle_pause, "Space",
                                         checkable=True)
        self._action(sim, "&Reset pose", lambda: self._command(runtime.Reset()), "Ctrl+R")
        self._action(sim, "&More modes", lambda: self._step_modes(+2), "]")
        self._action(sim, "&Fewer modes", lambda: self._step_modes(-2), "[")

        help_menu = bar.addMenu("&Help")
        self._action(help_menu, "&Controls", self._show_help, "F1")
        self._action(help_menu, "&About", self._about)

    # ------------------------------------------------------------------ settings
    def _restore_layout(self) -> None:
        geometry = self.settings.value("window/geometry")
        state = self.settings.value("window/state")
        if geometry is not None:
            self.restoreGeometry(geometry)
        if state is not None:
            self.restoreState(state)
        else:
            # dock sizes only take once the window is laid out
            QtCore.QTimer.singleShot(0, self._default_dock_sizes)

    def _default_dock_sizes(self) -> None:
        w = self.width()
        self.resizeDocks([self.dock_slice, self.dock_readouts],
                         [int(0.27 * w), int(0.25 * w)], QtCore.Qt.Horizontal)
        h = self.height()
        self.resizeDocks([self.dock_slice, self.dock_landscape], [h // 2, h // 2],
                         QtCore.Qt.Vertical)
        self.resizeDocks([self.dock_readouts, self.dock_params], [int(0.42 * h), int(0.58 * h)],
                         QtCore.Qt.Vertical)

    def save_layout(self) -> None:
        """Save the window geometry and the dock layout to the settings."""
        self.settings.setValue("window/geometry", self.saveGeometry())
        self.settings.setValue("window/state", self.saveState())
        self.settings.sync()

    def recent_files(self) -> list[str]:
        """The recently opened files from the settings, newest first."""
        value = self.settings.value("recent", [])
        if isinstance(value, str):
            value = [value]
        return [str(v) for v in (value or [])]

    def _remember(self, path: str) -> None:
        path = str(Path(path).resolve())
        recent = [p for p in self.recent_files() if p != path]
        self.settings.setValue("recent", [path, *recent][:MAX_RECENT])
        self.settings.setValue("last_dir", str(Path(path).parent))
        self.settings.sync()
        self._update_recent_menu()

    def _update_recent_menu(self) -> None:
        self.recent_menu.clear()
        recent = self.recent_files()
        for i, path in enumerate(recent):
            action = self.recent_menu.addAction(f"&{i + 1} {Path(path).name}")
            action.setToolTip(path)
            action.triggered.connect(lambda _c=False, p=path: self.open_path(p))
        self.recent_menu.setEnabled(bool(recent))

    # ------------------------------------------------------------------ files
    def open_dialog(self) -> None:
        """Ask for a scene or part file and open it."""
        start = str(self.settings.value("last_dir", str(Path.cwd())))
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Open scene or part", start,
                                                        FILE_FILTER)
        if path:
            self.open_path(path)

    def open_path(self, path: str | Path, *, wait: bool = False) -> None:
        """Open a scene (or a part as the moving part); ``wait`` loads in this thread."""
        self.statusBar().showMessage(f"opening {path} …")
        if wait:
            self.session.open_sync(path)
        else:
            self.session.open(path)

    def save_dialog(self) -> None:
        """Ask where to save the scene and save it (or say that there is none)."""
        if self.session.handle is None:
            self.show_error("There is no scene to save.")
            return
        start = str(self.settings.value("last_dir", str(Path.cwd())))
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Save scene", start,
                                                        "Scenes (*.toml)")
        if path:
            self.save_scene(path)

    def save_scene(self, path: str | Path) -> Path:
        """Write the current scene, with the part where it is now, to a TOML file."""
        from app.gui.scene_file import write_scene

        pose = None
        if self.latest_frame is not None:
            pose = np.asarray(self.latest_frame.part_pose, float)
        try:
            out = write_scene(self.session.handle, Path(path), moving_relative_pose=pose,
                              sigma=self.params.sigma.value(),
                              penalty=self.params.penalty.value(),
                              modes=int(self.params.modes.value()))
        except (OSError, ValueError) as exc:
            self.show_error(f"Could not save the scene: {exc}")
            raise
        self._remember(str(out))
        self.statusBar().showMessage(f"saved {out}", 5000)
        return out

    def screenshot_dialog(self) -> None:
        """Ask where to save a screenshot of the window and save it."""
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Save screenshot",
                                                        "skelasm.png", "PNG images (*.png)")
        if path:
            self.save_screenshot(path)

    def save_screenshot(self, path: str | Path, widget: QtWidgets.QWidget | None = None) -> Path:
        """Render now and save a picture of the window (or of one widget) as PNG."""
        self.viewport.request_render()
        self.viewport.render_if_dirty(force=True)
        QtWidgets.QApplication.processEvents()
        pixmap = (widget or self).grab()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if not pixmap.save(str(path)):
            raise OSError(f"{path}: could not write the PNG")
        return path

    def dragEnterEvent(self, event) -> None:  # noqa: N802
        """Accept a drag that carries a file the window can open."""
        if any(_droppable(u) for u in event.mimeData().urls()):
            event.acceptProposedAction()

    def dropEvent(self, event) -> None:  # noqa: N802
        """Open the first dropped file the window can open."""
        for url in event.mimeData().urls():
            if _droppable(url):
                self.open_path(url.toLocalFile())
                event.acceptProposedAction()
                return

    # ------------------------------------------------------------------ session events
    def _scene_opened(self, handle) -> None:
        self.latest_frame = None
        self._landscape_pending = False
        self.guidance_ready = False
        self.guidance_error = None
        self._force_scale = self._torque_scale = 0.0
        self.chart.clear()
        views = self.session.part_views()
        self.viewport.set_scene(views)
        scene = handle.scene
        title = scene.name
        self.setWindowTitle(f"{title} — skelasm")
        meshes = [(v.name, v.vertices, v.faces) for v in views]
        self.slice_view.set_parts(meshes, [posemath.pose_to_matrix(v.pose) for v in views])
        self.slice_view.set_descriptors(())
        self.landscape_view.set_landscape(None)
        self.landscape_view.canvas.clear("landscape not computed yet")
        self.params.load_config(handle.config, scene.modes, scene.descriptor.sigma,
                                scene.descriptor.penalty)
        if self.session.engine is None:
            self.statusBar().showMessage(
                f"{title}: one part loaded; open a second part (the moving one) to assemble")
        else:
            self.statusBar().showMessage(f"{title}: preparing descriptors…")
        if not Path(handle.path).name.startswith("generated_"):
            self._remember(str(handle.path))

    def _open_failed(self, path: str, message: str) -> None:
        self.show_error(f"Could not open {Path(path).name}:\n\n{message}")

    def show_error(self, message: str) -> None:
        """Show a message without blocking the event loop; the session goes on."""
        self.last_error = message
        self.statusBar().showMessage(message.replace("\n\n", " ").replace("\n", " "), 15000)
        if self.error_dialog is not None:
            self.error_dialog.close()
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Warning, "skelasm", message,
                                    QtWidgets.QMessageBox.Ok, self)
        box.setWindowModality(QtCore.Qt.WindowModal)
        box.open()
        self.error_dialog = box

    def _command(self, command) -> None:
        self.session.send(command)
        if isinstance(command, runtime.SetModes):
            self.statusBar().showMessage(f"m' = {command.modes ** 3:,} modes", 3000)

    def _proxy_dragged(self, world_pose) -> None:
        if self.session.handle is not None:
            self.session.send(runtime.SetProxyPose(tuple(self.session.relative(world_pose))))

    def _drag_state(self, dragging: bool) -> None:
        if dragging:
            self.statusBar().showMessage(
                "dragging: Shift = depth, wheel = depth, Ctrl = rotate", 2000)

    def _toggle_pause(self, checked: bool) -> None:
        self.params.pause.setChecked(checked)

    def _pause_changed(self, paused: bool) -> None:
        self.pause_action.blockSignals(True)
        self.pause_action.setChecked(paused)
        self.pause_action.blockSignals(False)

    def _step_modes(self, delta: int) -> None:
        self.params.modes.setValue(self.params.modes.value() + delta)

    def reset_camera(self) -> None:
        """Fit the camera to the scene again."""
        self.viewport.plotter.reset_camera()
        self.viewport.request_render()

    def _show_help(self) -> None:
        QtWidgets.QMessageBox.information(self, "skelasm controls", HELP_TEXT)

    def _about(self) -> None:
        QtWidgets.QMessageBox.about(
            self, "About skelasm",
            "skelasm: force-guided assembly of CAD parts with skeletal densities and "
            f"Fourier correlations.\n\nEngine: {self.session.engine_name}")

    # ------------------------------------------------------------------ the loop
    def tick(self) -> None:
        """Drain the engine, update the views, render if needed (GUI thread only)."""
        frames, events = self.session.poll()
        for event in events:
            self._handle_event(event)
        if frames:
            self.frames_received += len(frames)
            # wall-clock time base: the chart shows the last seconds the user lived through,
            # however fast the simulation runs; frames within a batch keep their spacing
            now = time.perf_counter()
            newest = frames[-1].time
            for f in frames:
                self.chart.add(now - (newest - f.time), f.energy,
                               float(np.linalg.norm(f.force)))
            self._show_frame(frames[-1])
        self.viewport.render_if_dirty()
        self._count_fps()

    def _count_fps(self) -> None:
        now = time.perf_counter()
        if now - self._fps_t >= 1.0:
            rendered = self.viewport.frames_rendered
            self.fps = (rendered - self._fps_frames) / (now - self._fps_t)
            self._fps_frames, self._fps_t = rendered, now
            lat = list(self.latency.samples)[-100:]
            # renders happen only when something moved: say so rather than show "0 fps"
            self.status_fps.setText(f"{self.fps:.0f} fps" if self.fps > 0 else "view idle")
            if lat:
                self.status_latency.setText(f"event loop late ≤ {max(lat):.0f} ms")

    def _show_frame(self, frame: runtime.Frame) -> None:
        self.latest_frame = frame
        s = self.session
        if s.handle is None:
            return
        proxy_world = s.world(frame.proxy_pose)
        part_world = s.world(frame.part_pose)
        self.viewport.set_poses(proxy_world, part_world)
        r1 = s.part1_rotation()
        force, torque = r1 @ np.asarray(frame.force), r1 @ np.asarray(frame.torque)
        fn = float(np.linalg.norm(force))
        tn = float(np.linalg.norm(torque))
        # arrows scaled by a slowly decaying peak, so they stay readable in any unit
        self._force_scale = max(fn, 0.995 * self._force_scale)
        self._torque_scale = max(tn, 0.995 * self._torque_scale)
        self.viewport.set_wrench(
            force, torque,
            1.0 / self._force_scale if self._force_scale > 0 else 0.0,
            1.0 / self._torque_scale if self._torque_scale > 0 else 0.0,
        )
        now = time.perf_counter()
        if now - self._last_readout >= self.READOUT_PERIOD:
            self._last_readout = now
            self._update_readouts(frame, fn, tn)
            self.chart.update()
        if now - self._last_view >= self.VIEW_PERIOD:
            self._last_view = now
            self.slice_view.set_world_transform(1, posemath.pose_to_matrix(part_world))
            if self.dock_landscape.isVisible():
                self.landscape_view.set_pose(np.asarray(frame.part_pose))
                self._maybe_request_landscape(np.asarray(frame.part_pose))

    def _update_readouts(self, f: runtime.Frame, fn: float, tn: float) -> None:
        r = self.readouts
        r.set("energy", f"{f.energy:.5g}")
        r.set("force", f"{fn:.4g}")
        r.set("torque", f"{tn:.4g}")
        r.set("rate", f"{f.period.rate_hz:,.0f} Hz")
        r.set("eval", f"{f.eval_us:.1f} µs")
        r.set("modes", f"{f.modes ** 3:,}  (K = {f.modes})")
        r.set("period", f"{f.period.median_us:.0f} / {f.period.p99_us:.0f} µs")
        r.set("device", f.device + ("  (paused)" if f.paused else ""))
        self.status_engine.setText(f"engine {f.period.rate_hz:,.0f} Hz · {f.eval_us:.0f} µs/eval")

    def _maybe_request_landscape(self, pose: np.ndarray) -> None:
        if not self.guidance_ready or self._landscape_pending:
            return
        if not self.landscape_view.needs_landscape(pose):
            return
        self._landscape_pending = True
        self.session.send(runtime.RequestLandscape(tuple(float(x) for x in pose[3:])))

    def _handle_event(self, event) -> None:
        if isinstance(event, runtime.ReadyEvent):
            self.guidance_ready = bool(event.descriptors)
            self.params.set_progress(None, "ready")
            self.readouts.set("backend", event.backend or "-")
            self.slice_view.set_descriptors(event.descriptors)
            self.engine_note = event.message
            self.statusBar().showMessage(event.message or "engine ready", 4000)
        elif isinstance(event, runtime.DescriptorsSwapped):
            self.guidance_ready = bool(event.descriptors)
            self.slice_view.set_descriptors(event.descriptors)
            self.descriptor_seconds = event.seconds
            self.params.set_progress(None, f"updated in {event.seconds:.1f} s")
            self.landscape_view.set_landscape(None)
            self._landscape_pending = False
        elif isinstance(event, runtime.ProgressEvent):
            if event.task == "descriptors":
                if event.message == "cancelled":
                    self.params.set_progress(None, "cancelled")
                else:
                    self.params.set_progress(event.fraction)
            elif event.task == "correlator":  # the first preparation after opening
                if event.fraction < 1.0:
                    self.params.set_progress(event.fraction, "preparing descriptors %p%",
                                             cancellable=False)
            else:
                self.statusBar().showMessage(
                    f"{event.task}: {event.fraction:.0%} {event.message}", 2000)
        elif isinstance(event, runtime.LandscapeReady):
            self._landscape_pending = False
            self.landscape_view.set_landscape(event.landscape)
            if self.latest_frame is not None:
                self.landscape_view.set_pose(np.asarray(self.latest_frame.part_pose))
        elif isinstance(event, runtime.LandscapeFailed):
            self._landscape_pending = False
            self.statusBar().showMessage(f"landscape: {event.message}", 15000)
        elif isinstance(event, runtime.ErrorEvent):
            if not self.guidance_ready and not event.fatal:
                self.guidance_error = event.message  # preparing the correlator failed
            if event.fatal:
                self.show_error(f"The engine stopped: {event.message}")
            else:
                if self.params.cancel.isEnabled():  # a recompute was running: it failed
                    self.params.set_progress(None, "recompute failed")
                self.statusBar().showMessage(f"{event.kind}: {event.message}", 15000)
                self.last_error = event.message
        elif isinstance(event, runtime.DeviceEvent):
            text = f"device {event.device}: {event.message}"
            if not event.connected:
                text += f" (now using the {event.fallback})"
            self.statusBar().showMessage(text, 15000)
            self.readouts.set("device", event.fallback if not event.connected else event.device)
        elif isinstance(event, runtime.StoppedEvent):
            if event.reason != "stopped":
                self.show_error(f"The engine stopped: {event.reason}")

    # ------------------------------------------------------------------ closing
    def closeEvent(self, event) -> None:  # noqa: N802
        """Save the layout, stop the engine and the 3D view, then close."""
        self.save_layout()
        self._tick_timer.stop()
        self.session.close()
        self.viewport.close()
        super().closeEvent(event)


def _droppable(url: QtCore.QUrl) -> bool:
    if not url.isLocalFile():
        return False
    return Path(url.toLocalFile()).suffix.lower() in SCENE_SUFFIXES + PART_SUFFIXES
