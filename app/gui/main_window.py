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
import shiboken6
from PySide6 import QtCore, QtGui, QtWidgets

from app.gui import quantities
from app.gui.accuracy import AccuracyIndicator
from app.gui.contact import OverlapGauge
from app.gui.fits_panel import FitsPanel
from app.gui.landscape_view import LandscapeView
from app.gui.params_panel import ParamsPanel
from app.gui.parts_panel import PartsPanel, PoseHistory
from app.gui.pose_dialog import PoseDialog
from app.gui.session import FILE_FILTER, PART_SUFFIXES, SCENE_SUFFIXES, Session
from app.gui.slice_view import SliceView
from app.gui.strip_chart import StripChart
from app.gui.tasks import TaskBoard
from app.gui.view_panel import ViewPanel
from app.gui.viewport import VIEW_NAMES, Viewport
from app.gui.widgets import ContentScroll, ElidedLabel, Readouts
from engine import pose as posemath
from engine import runtime
from engine.params import QuantityUnits

ORGANISATION = "skelasm"
APPLICATION = "skelasm"
MAX_RECENT = 8

HELP_TEXT = """<h3>Assembling</h3>
<ul>
<li><b>Drag</b> the orange part (or its blue ghost) with the left button: the ghost (the
input proxy) follows the mouse and the engine pulls the part after it. With an axis chosen
in the toolbar (I: the insertion axis, X, Y, Z; F: free) the ghost moves along that axis
only, drawn through the part; free, it moves in the view plane.</li>
<li><b>Shift + drag</b> up/down, or the <b>wheel</b> while dragging: move along the view
direction (along the chosen axis, when one is chosen).</li>
<li><b>Ctrl + drag</b>: rotate the proxy about the part's centre (the scene's pivot, else its
centre of mass) with an arcball, or about the chosen axis through it.</li>
<li>Elsewhere the mouse turns (left), pans (middle) and zooms (wheel) the camera.</li>
<li>The readout at the top right says how far the part is from its seat, and
<b>SEATED</b> when it is within the scene's tolerance.</li>
</ul>
<h3>Keys</h3>
<table>
<tr><td>Ctrl+O</td><td>open a scene or part</td></tr>
<tr><td>Ctrl+S</td><td>save the scene</td></tr>
<tr><td>Space</td><td>pause / resume the engine</td></tr>
<tr><td>Ctrl+R</td><td>put the part back at its start pose</td></tr>
<tr><td>Ctrl+P</td><td>type the pose of the part</td></tr>
<tr><td>Ctrl+Z, Ctrl+Shift+Z</td><td>undo / redo a change of the part's pose</td></tr>
<tr><td>Ctrl+Alt+Z, Ctrl+Alt+Shift+Z</td><td>undo / redo a change of a setting (K, sigma,
penalty, kappa, coupling, effects)</td></tr>
<tr><td>I, X, Y, Z, F</td><td>drag along the insertion axis, x, y, z; free drag</td></tr>
<tr><td>1 … 6, 0, 7</td><td>views from +X, −X, +Y, −Y, +Z, −Z; isometric; along the
insertion axis</td></tr>
<tr><td>[ and ]</td><td>fewer / more modes (accuracy against time)</td></tr>
<tr><td>Ctrl+0</td><td>reset the camera (isometric, whole scene)</td></tr>
<tr><td>F12</td><td>save a screenshot of the window</td></tr>
</table>
<p>Keys without Ctrl act while the 3D view has the focus (click it); typed in or beside a
field of a panel they never move the camera or the part.</p>"""

#: The window's size when nothing is remembered, and the share of the screen it may take.
DEFAULT_SIZE = (1500, 920)
SCREEN_SHARE = 0.94
#: Smallest sizes of the 3D view and of a dock's content (pixels): a window made small keeps
#: both (a dock's content scrolls below its own minimum).
MIN_VIEW = (200, 150)
MIN_DOCK = (140, 80)
#: A remembered window smaller than this is a damaged layout and is not restored.
LAYOUT_MIN = (640, 400)
#: The engine counts as below its rate under this share of its target (steps per second).
RATE_WARNING = 0.9

#: Standard views: name, key.
VIEW_KEYS = (("+x", "1"), ("-x", "2"), ("+y", "3"), ("-y", "4"), ("+z", "5"), ("-z", "6"),
             ("iso", "0"), ("insertion", "7"))
CONSTRAINT_KEYS = (("free", "F", "free drag (view plane)"),
                   ("insertion", "I", "along the insertion axis"),
                   ("x", "X", "along x"), ("y", "Y", "along y"), ("z", "Z", "along z"))


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


def toggle_view_action(dock: QtWidgets.QDockWidget) -> QtGui.QAction:
    """The dock's own show/hide action, as a ``QAction``.

    PySide6 keeps a map from C++ addresses to Python wrappers. When a C++ object dies
    without the binding being told (a closed window's render surface) while Python still
    holds its wrapper, a new object allocated at the same address is handed out as that old
    wrapper, of the old type: once, after a window was closed and another opened, the
    action came back as a ``QSurface`` and building the menu failed. The stale wrapper is
    then invalidated, which drops it from the map, and the action asked for again.
    """
    action = dock.toggleViewAction()
    if not isinstance(action, QtGui.QAction):
        shiboken6.invalidate(action)
        action = dock.toggleViewAction()
    if not isinstance(action, QtGui.QAction):
        raise TypeError(f"the {dock.windowTitle()!r} panel's show/hide action came back as "
                        f"{type(action).__name__}: restart the application")
    return action


def view_key(sequence: QtGui.QKeySequence) -> bool:
    """True for a shortcut of one key without Ctrl, Alt or Meta that types text."""
    if sequence.count() != 1:
        return False
    combo = sequence[0]
    mods = combo.keyboardModifiers() & ~QtCore.Qt.ShiftModifier & ~QtCore.Qt.KeypadModifier
    if mods != QtCore.Qt.NoModifier:
        return False
    key = combo.key()
    return key == QtCore.Qt.Key_Space or 0x21 <= int(key.value) <= 0x7E


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
        self.viewport.widget.setMinimumSize(*MIN_VIEW)
        self.viewport.proxy_dragged.connect(self._proxy_dragged)
        self.viewport.drag_state.connect(self._drag_state)

        self.units = QuantityUnits.of("mm")
        self.kappa = 0.0  # the kappa the engine uses (E = -kappa Re f), resolved here
        self.tasks = TaskBoard()
        self.rate_low = False  # the engine runs below RATE_WARNING of its target rate
        self.seat = None  # engine.seat.SeatState of the latest frame
        self.overlap_depth: float | None = None  # part 2's depth in part 1 (scene unit)
        self._requested_modes: int | None = None
        self._coupling = None  # the coupling the panel last sent (None: the scene's)
        self._kappa_override: float | None = None
        self._effects = None  # the effects last sent to the engine
        self.evaluator = "-"  # the per-pose evaluator the engine picked (ReadyEvent)

        self.seat_label = QtWidgets.QLabel("no scene")
        self.seat_label.setObjectName("seat_state")
        self.seat_label.setAlignment(QtCore.Qt.AlignCenter)
        self.seat_label.setWordWrap(True)
        self.seat_detail = QtWidgets.QLabel("")
        self.seat_detail.setWordWrap(True)
        self._show_seated(False)
        self.readouts = Readouts([
            ("pose", "part 2 (rel. part 1)"),
            ("seat", "to the seat"),
            ("overlap", "overlap"),
            ("free", "free axes"),
            ("energy", "energy E"),
            ("force", "|force F|"),
            ("torque", "|torque T|"),
            ("kappa", "kappa"),
            ("rate", "engine"),
            ("eval", "fit forces take"),
            ("modes", "accuracy"),
            ("device", "input"),
        ])
        self.chart = StripChart(seconds=10.0)
        box = QtWidgets.QWidget()
        lay = QtWidgets.QVBoxLayout(box)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.seat_label)
        lay.addWidget(self.seat_detail)
        lay.addWidget(self.readouts)
        lay.addWidget(self.chart, 1)
        self.dock_readouts = self._dock("Readouts", box, QtCore.Qt.RightDockWidgetArea)

        self.params = ParamsPanel()
        self.params.command.connect(self._command)
        self.accuracy = AccuracyIndicator(self)  # the truncation estimate beside K
        self.accuracy.profile_ready.connect(self.params.set_truncation_profile)
        self.overlap = OverlapGauge(self)  # how deep part 2 sits in part 1
        self.overlap.ready.connect(lambda _m: self._show_overlap())
        self.view_panel = ViewPanel()
        self.view_panel.opacity_changed.connect(self.viewport.set_fixed_opacity)
        self.view_panel.clip_changed.connect(self.viewport.set_clip)
        self.params.layout().insertWidget(self.params.layout().count() - 1, self.view_panel)
        self.dock_params = self._dock("Parameters", self.params, QtCore.Qt.RightDockWidgetArea)

        self.slice_view = SliceView()
        self.slice_view.plane_changed.connect(self.viewport.show_slice_plane)
        self.params.descriptor_preview.connect(self.slice_view.preview)
        self.dock_slice = self._dock("Descriptor slice", self.slice_view,
                                     QtCore.Qt.LeftDockWidgetArea)
        self.landscape_view = LandscapeView()
        self.dock_landscape = self._dock("Energy landscape", self.landscape_view,
                                         QtCore.Qt.LeftDockWidgetArea)
        self.parts_panel = PartsPanel()
        self.parts_panel.visibility_changed.connect(self.viewport.set_part_visible)
        self.dock_parts = self._dock("Parts", self.parts_panel, QtCore.Qt.LeftDockWidgetArea)
        self.tabifyDockWidget(self.dock_slice, self.dock_parts)
        self.fits_panel = FitsPanel()
        self.fits_panel.find.clicked.connect(self.find_fits)
        self.fits_panel.chosen.connect(self._show_fit)
        self.fits_panel.place.connect(self._typed_part_pose)
        self.fits_panel.use_as_seat.connect(self._fit_as_seat)
        self.dock_fits = self._dock("Fits", self.fits_panel, QtCore.Qt.LeftDockWidgetArea)
        self.tabifyDockWidget(self.dock_parts, self.dock_fits)
        self.dock_slice.raise_()
        self.history = PoseHistory()  # the part's poses before each change, for Undo

        self.status_task = ElidedLabel("", 360)  # cut to fit: the messages keep their room
        self.status_task.setObjectName("status_task")
        self.status_engine = QtWidgets.QLabel("engine: -")
        self.status_engine.setObjectName("status_engine")
        self.status_fps = QtWidgets.QLabel("fps: -")
        self.status_latency = QtWidgets.QLabel("latency: -")
        for w in (self.status_task, self.status_engine, self.status_fps, self.status_latency):
            self.statusBar().addPermanentWidget(w)
        # a message cut by the bar's width is whole in its tooltip
        self.statusBar().messageChanged.connect(lambda text: self.statusBar().setToolTip(text))
        self._build_menus()
        self._build_toolbar()
        self.params.pause.toggled.connect(self._pause_changed)
        self.viewport.constraint_changed.connect(self._constraint_changed)
        self.pose_dialog: PoseDialog | None = None
        self.fit_dialog = None  # Edit > Set up the fit (app.gui.fit_dialog), made on first use

        self.latency = LatencyMonitor(self)
        self._tick_timer = QtCore.QTimer(self)
        self._tick_timer.setTimerType(QtCore.Qt.PreciseTimer)
        self._tick_timer.timeout.connect(self.tick)
        self.resize(*DEFAULT_SIZE)
        self._default_state = self.saveState()  # what View > Reset layout restores
        self._restore_layout()
        self.fit_to_screen()
        self._tick_timer.start(self.TICK_MS)
        self.latency.start()
        self.viewport.widget.setFocus()  # the view keys act from the start

    # ------------------------------------------------------------------ construction
    def _dock(self, title: str, widget, area) -> QtWidgets.QDockWidget:
        dock = QtWidgets.QDockWidget(title, self)
        dock.setObjectName(title.lower().replace(" ", "_"))
        # in a scroll area: a dock squeezed below its content's minimum scrolls instead of
        # laying its texts over each other, and keeps a size of its own (MIN_DOCK)
        scroll = ContentScroll(widget)
        scroll.setMinimumSize(*MIN_DOCK)
        dock.setWidget(scroll)
        # a click anywhere on a dock takes the keyboard focus from the 3D view, so keys
        # typed beside a missed field reach no view shortcut
        dock.setFocusPolicy(QtCore.Qt.ClickFocus)
        self.addDockWidget(area, dock)
        return dock

    def _action(self, menu, text, slot, shortcut=None, checkable=False):
        action = QtGui.QAction(text, self)
        action.setCheckable(checkable)
        action.triggered.connect(slot)
        menu.addAction(action)
        if shortcut:
            action.setShortcut(QtGui.QKeySequence(shortcut))
        if shortcut and view_key(action.shortcut()):
            # a key that types text (a digit, a letter, Space, a bracket) acts only while
            # the 3D view has the focus: typed beside a missed field it must not turn the
            # camera (a click on a dock takes the focus from the view, see _dock)
            action.setShortcutContext(QtCore.Qt.WidgetWithChildrenShortcut)
            self.viewport.widget.addAction(action)
        elif shortcut:
            action.setShortcutContext(QtCore.Qt.WindowShortcut)
            self.addAction(action)  # shortcuts work while the menu bar is hidden or unfocused
        return action

    def _menu(self, parent, title: str) -> QtWidgets.QMenu:
        """A menu made here and added to ``parent`` (the menu bar or a menu).

        Made in Python rather than taken from ``addMenu(title)``: a wrapper looked up by its
        C++ address can come back as a stale wrapper of a deleted object at that address
        (a QSurface from a closed 3D view, seen once on Python 3.10), while a menu made here
        has its own.
        """
        menu = QtWidgets.QMenu(title, self)
        parent.addMenu(menu)
        return menu

    def _build_menus(self) -> None:
        bar = QtWidgets.QMenuBar(self)  # made here, for the reason given in _menu
        self.setMenuBar(bar)
        file = self._menu(bar, "&File")
        self._action(file, "&Open scene or part…", self.open_dialog, QtGui.QKeySequence.Open)
        self.recent_menu = self._menu(file, "Open &recent")
        self._action(file, "&Save scene as…", self.save_dialog, QtGui.QKeySequence.Save)
        file.addSeparator()
        self._action(file, "Save screens&hot…", self.screenshot_dialog, "F12")
        file.addSeparator()
        self._action(file, "&Quit", self.close, QtGui.QKeySequence.Quit)
        self._update_recent_menu()

        edit = self._menu(bar, "&Edit")
        self.undo_action = self._action(edit, "&Undo pose", self.undo_pose,
                                        QtGui.QKeySequence.Undo)
        self.redo_action = self._action(edit, "&Redo pose", self.redo_pose,
                                        QtGui.QKeySequence.Redo)
        self._action(edit, "Undo &setting", self.undo_setting, "Ctrl+Alt+Z")
        self._action(edit, "Redo s&etting", self.redo_setting, "Ctrl+Alt+Shift+Z")
        edit.addSeparator()
        self._action(edit, "&Find fits", self.find_fits)
        self._action(edit, "Set up the &fit…", self.fit_dialog_open)
        view = self._menu(bar, "&View")
        for dock in (self.dock_readouts, self.dock_params, self.dock_slice, self.dock_landscape,
                     self.dock_parts, self.dock_fits):
            view.addAction(toggle_view_action(dock))
        view.addSeparator()
        self._action(view, "Reset &layout", self.reset_layout)
        self._action(view, "Reset &camera", self.reset_camera, "Ctrl+0")
        views = self._menu(view, "&Standard views")
        self.view_actions: dict[str, QtGui.QAction] = {}
        for name, key in VIEW_KEYS:
            self.view_actions[name] = self._action(
                views, VIEW_NAMES[name], lambda _c=False, n=name: self.set_view(n), key)
        drag = self._menu(bar, "&Drag")
        self.constraint_group = QtGui.QActionGroup(self)
        self.constraint_actions: dict[str, QtGui.QAction] = {}
        for name, key, text in CONSTRAINT_KEYS:
            action = self._action(drag, text.capitalize(),
                                  lambda _c=False, n=name: self.set_constraint(n), key,
                                  checkable=True)
            action.setIconText({"free": "Free", "insertion": "Insertion"}.get(name, name.upper()))
            action.setToolTip(f"Drag {text} ({key}); Ctrl-drag turns about it")
            self.constraint_group.addAction(action)
            self.constraint_actions[name] = action
        self.constraint_actions["free"].setChecked(True)
        drag.addSeparator()
        self._action(drag, "Type the &pose…", self.show_pose_dialog, "Ctrl+P")

        sim = self._menu(bar, "&Simulation")
        self.pause_action = self._action(sim, "&Pause", self._toggle_pause, "Space",
                                         checkable=True)
        self._action(sim, "&Reset pose", lambda: self._command(runtime.Reset()), "Ctrl+R")
        self._action(sim, "&More modes", lambda: self._step_modes(+2), "]")
        self._action(sim, "&Fewer modes", lambda: self._step_modes(-2), "[")

        help_menu = self._menu(bar, "&Help")
        self._action(help_menu, "&Controls", self._show_help, "F1")
        self._action(help_menu, "&About", self._about)

    def _build_toolbar(self) -> None:
        bar = self.addToolBar("Insertion")
        bar.setObjectName("insertion_toolbar")
        bar.setToolButtonStyle(QtCore.Qt.ToolButtonTextOnly)
        bar.addWidget(QtWidgets.QLabel(" drag "))
        for action in self.constraint_actions.values():
            bar.addAction(action)
        bar.addSeparator()
        bar.addWidget(QtWidgets.QLabel(" view "))
        for name, _key in VIEW_KEYS:
            action = self.view_actions[name]
            action.setIconText({"iso": "Iso", "insertion": "Axis"}.get(
                name, name.upper().replace("-", "−")))
            action.setToolTip(f"View {VIEW_NAMES[name]} ({action.shortcut().toString()})")
            bar.addAction(action)
        bar.addSeparator()
        pose = QtGui.QAction("Pose…", self)
        pose.setToolTip("Type the pose of the moving part (Ctrl+P)")
        pose.triggered.connect(self.show_pose_dialog)
        bar.addAction(pose)
        self.toolbar = bar

    # ------------------------------------------------------------------ settings
    def _restore_layout(self) -> None:
        """The remembered window and docks, unless damaged (too small, or off every screen)."""
        geometry = self.settings.value("window/geometry")
        state = self.settings.value("window/state")
        if geometry is not None:
            self.restoreGeometry(geometry)
            if not self._layout_usable(self.geometry()):
                self.resize(*DEFAULT_SIZE)
                state = None
        if state is not None:
            self.restoreState(state)
        else:
            # dock sizes only take once the window is laid out
            QtCore.QTimer.singleShot(0, self._default_dock_sizes)

    def _layout_usable(self, rect: QtCore.QRect) -> bool:
        """A window of ``rect`` is big enough to work in and lies mostly on a screen."""
        if rect.width() < LAYOUT_MIN[0] or rect.height() < LAYOUT_MIN[1]:
            return False
        screens = QtGui.QGuiApplication.screens()
        area = max((s.availableGeometry().intersected(rect) for s in screens),
                   key=lambda r: r.width() * r.height(), default=QtCore.QRect())
        return area.width() * area.height() >= 0.5 * rect.width() * rect.height()

    def reset_layout(self) -> None:
        """Every dock back where a first launch puts it, at its default size."""
        self.restoreState(self._default_state)
        for dock in (self.dock_readouts, self.dock_params, self.dock_slice, self.dock_landscape,
                     self.dock_parts, self.dock_fits):
            dock.setFloating(False)
            dock.show()
        self.dock_slice.raise_()
        self.toolbar.show()
        self._default_dock_sizes()

    def _available_geometry(self) -> QtCore.QRect:
        """The part of the screen the window may use (without panels and docks of the OS).

        The screen holding the window's centre, found among the application's screens:
        ``QWidget.screen()`` would tie the wrapper of that application-wide QScreen to this
        window (PySide's parent heuristic for returned QObjects), and pyvistaqt traced
        use-after-free crashes far from the cause to exactly that call (its ``rwi.py``,
        invariant 4).
        """
        centre = self.frameGeometry().center()
        for screen in QtGui.QGuiApplication.screens():
            if screen.geometry().contains(centre):
                return screen.availableGeometry()
        return QtGui.QGuiApplication.primaryScreen().availableGeometry()

    def fit_to_screen(self, available: QtCore.QRect | None = None) -> None:
        """Keep the window within the screen it is on (a remembered size is clamped too).

        ``available``: the screen's free area (default: the window's screen's).
        """
        area = available if available is not None else self._available_geometry()
        frame = self.frameGeometry()
        extra_w = max(frame.width() - self.width(), 0)
        extra_h = max(frame.height() - self.height(), 0)
        max_w = int(area.width() * SCREEN_SHARE) - extra_w
        max_h = int(area.height() * SCREEN_SHARE) - extra_h
        w, h = min(self.width(), max_w), min(self.height(), max_h)
        if (w, h) != (self.width(), self.height()):
            self.resize(w, h)
        frame = self.frameGeometry()
        x = min(max(frame.x(), area.x()), area.x() + area.width() - frame.width())
        y = min(max(frame.y(), area.y()), area.y() + area.height() - frame.height())
        if (x, y) != (frame.x(), frame.y()):
            self.move(x, y)

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
        """Save the window geometry and the dock layout to the settings.

        A window squeezed below :data:`LAYOUT_MIN` or off every screen is not saved: the
        layout remembered before it stays.
        """
        if not self._layout_usable(self.geometry()):
            return
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
        dialog = self.file_dialog("Open scene or part", start, FILE_FILTER)
        dialog.setFileMode(QtWidgets.QFileDialog.ExistingFile)
        if dialog.exec() and dialog.selectedFiles():
            self.open_path(dialog.selectedFiles()[0])

    def file_dialog(self, title: str, start: str, filters: str) -> QtWidgets.QFileDialog:
        """A file dialog large enough for its columns: 80 % of the window, at least 820 x 520.

        Qt's own dialog opened at its default size, and the file names were cut.
        """
        dialog = QtWidgets.QFileDialog(self, title, start, filters)
        area = self._available_geometry()
        width = min(max(int(0.8 * self.width()), 820), area.width())
        height = min(max(int(0.8 * self.height()), 520), area.height())
        dialog.resize(width, height)
        view = dialog.findChild(QtWidgets.QTreeView)  # Qt's own dialog; none when native
        if view is not None:
            header = view.header()
            header.setStretchLastSection(False)
            header.setSectionResizeMode(0, QtWidgets.QHeaderView.Stretch)
            for column in range(1, header.count()):
                header.setSectionResizeMode(column, QtWidgets.QHeaderView.ResizeToContents)
        return dialog

    def open_path(self, path: str | Path, *, wait: bool = False) -> None:
        """Open a scene (or a part as the moving part); ``wait`` loads in this thread."""
        self.statusBar().showMessage(f"opening {path} …")
        self.tasks.start("open", f"opening {Path(path).name}", reports_fraction=False)
        if wait:
            self.session.open_sync(path)
        else:
            self.session.open(path)

    def save_dialog(self) -> None:
        """Ask where to save the scene and save it (or say that there is none)."""
        if self.session.handle is None:
            self.show_error("There is no scene to save.")
            return
        start = str(self.save_folder() / Path(self.session.handle.path).name)
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Save scene", start,
                                                        "Scenes (*.toml)")
        if path:
            try:
                self.save_scene(path)
            except (OSError, ValueError):
                pass  # save_scene has shown what went wrong; the scene in use is untouched

    def save_folder(self) -> Path:
        """Where a Save dialog starts, never the bundled examples' folder (assets/).

        The folder last saved to, else the one last opened from, else home.
        """
        from app.gui.app import DEFAULT_SCENE

        bundled = DEFAULT_SCENE.resolve().parents[1]
        for key in ("last_save_dir", "last_dir"):
            value = self.settings.value(key)
            if not value:
                continue
            folder = Path(str(value)).resolve()
            if folder.is_dir() and not folder.is_relative_to(bundled):
                return folder
        return Path.home()

    def undo_setting(self) -> None:
        """Back to the parameters before the last change (K, sigma, penalty, kappa, ...)."""
        if not self.params.undo():
            self.statusBar().showMessage("no setting to undo", 3000)

    def redo_setting(self) -> None:
        """The parameters the last undo left."""
        if not self.params.redo():
            self.statusBar().showMessage("no setting to redo", 3000)

    def find_fits(self) -> None:
        """Run the search on the open scene (the Fits dock shows progress and the fits)."""
        handle = self.session.handle
        if handle is None or len(handle.parts) < 2:
            self.show_error("Open a scene with two parts to find where part 2 fits.")
            return
        self.dock_fits.show()
        self.dock_fits.raise_()
        self.fits_panel.start(handle.scene, self.units.length)

    def _show_fit(self, fit) -> None:
        """Draw a found fit in the 3D view: part 2's edges there and its free axes."""
        from app.gui.fits_panel import fit_pose

        handle = self.session.handle
        if fit is None or handle is None:
            self.viewport.show_fit(None)
            return
        part1 = posemath.pose_to_matrix(handle.part1_world_pose)
        world = part1 @ posemath.pose_to_matrix(fit_pose(fit))
        r1, t1 = part1[:3, :3], part1[:3, 3]
        axes = [(t1, r1 @ d) for d in fit.joint.slides]
        axes += [(r1 @ p + t1, r1 @ a) for a, p in fit.joint.turns]
        self.viewport.show_fit(world, axes)

    def _fit_as_seat(self, fit) -> None:
        """Set up the fit dialog with a found fit: its pose and its free axes."""
        from app.gui.fits_panel import fit_pose
        from engine.search.joint import axis_names

        self.fit_dialog_open()
        if self.fit_dialog is None:
            return
        self.fit_dialog.set_assembled(fit_pose(fit))
        names, _ = axis_names(fit.joint)
        for name, check in self.fit_dialog.free.items():
            check.setChecked(name in names)
        self.fit_dialog.note.setText(f"Fit {fit.rank}: a {fit.joint.kind} joint (confidence "
                                     f"{fit.joint.confidence:.2f}). Apply and save writes it "
                                     "into the scene as its seat.")

    def fit_dialog_open(self) -> None:
        """The scene's fit (assembled pose, insertion axis, free axes, seat tolerance)."""
        from app.gui.fit_dialog import FitDialog

        handle = self.session.handle
        if handle is None or len(handle.parts) < 2:
            self.show_error("Open a scene with two parts to set up their fit.")
            return
        if self.fit_dialog is None:
            self.fit_dialog = FitDialog(
                self, unit=self.units.length, current_pose=self._current_part_pose,
                view_direction=self._view_direction_in_part1, measure=self._measure_free_axes,
                pick_face=self._pick_face_axis)
            self.fit_dialog.applied.connect(self.apply_fit)
        self.fit_dialog.set_scene(handle.scene)
        self.fit_dialog.show()
        self.fit_dialog.raise_()

    def _current_part_pose(self) -> np.ndarray:
        handle = self.session.handle
        return np.asarray(self.latest_frame.part_pose if self.latest_frame is not None
                          else handle.start_pose, float)

    def _view_direction_in_part1(self) -> np.ndarray:
        """Into the screen, in part 1's frame."""
        d = np.asarray(self.viewport.plotter.camera.direction, float)
        part1 = posemath.pose_to_matrix(self.session.handle.part1_world_pose)
        return part1[:3, :3].T @ (d / np.linalg.norm(d))

    def _pick_face_axis(self, done) -> None:
        """The next click in the 3D view picks a face; ``done(axis, line)`` with its axis."""
        self.statusBar().showMessage("Click a bore's wall, a shaft's side or a flat face")
        self.viewport.pick_next_face(lambda picked: done(*self._face_axis_of(picked)))

    def _face_axis_of(self, picked):
        """(axis in part 1's frame or None, line) for a ``viewport.pick_face`` result.

        The axis points the way part 2 travels to the face: from part 2's centre to a face
        of part 1, from a face of part 2 to part 1's centre.
        """
        from engine.scene.face_axis import FaceAxisError, face_axis

        handle = self.session.handle
        if picked is None or handle is None or len(handle.parts) < 2:
            return None, "Nothing picked: click on a part's face."
        key, triangle = picked
        moving = key == "moving"
        part, other = handle.parts[1::-1] if moving else handle.parts[:2]
        m = posemath.pose_to_matrix(self._current_part_pose())  # part 2 in part 1's frame
        # the other part's centre in the picked part's frame: the axis points from it
        centre = other.vertices.mean(axis=0)
        centre = m[:3, :3].T @ (centre - m[:3, 3]) if moving else m[:3, :3] @ centre + m[:3, 3]
        try:
            found = face_axis(part.vertices, part.faces, triangle, towards=centre)
        except FaceAxisError as exc:
            return None, f"{part.name}: {exc}"
        # part 2 travels towards a face of part 1, and from a face of its own towards part 1
        axis = -(m[:3, :3] @ found.direction) if moving else found.direction
        what = (f"a {found.kind}, radius {quantities.number(found.radius)} {self.units.length}"
                if found.radius else "a flat face")
        self.statusBar().showMessage(f"{part.name}: {what}", 8000)
        return axis, (f"The axis of {part.name}'s picked face ({what}, {len(found.faces)} "
                      "triangles), the way part 2 goes to it.")

    def _measure_free_axes(self, pose: np.ndarray):
        """The free axes the parts' motions allow at ``pose``, and a line on what was found."""
        from engine.pose import rotation_matrix
        from engine.search.joint import Surfaces, axis_names, motion_joint

        fixed, moving = self.session.handle.parts[0], self.session.handle.parts[-1]
        length = 0.5 * float(np.max(np.ptp(moving.vertices, axis=0)))
        joint = motion_joint(Surfaces.of(fixed.vertices, fixed.faces, moving.vertices,
                                         moving.faces),
                             rotation_matrix(pose[3:]), pose[:3], length=length)
        if joint is None:
            return None, "The parts do not meet at this pose: nothing to measure."
        names, others = axis_names(joint)
        line = (f"A {joint.kind} joint (confidence {joint.confidence:.2f}): free "
                f"{', '.join(names) or 'none'}")
        if others:
            line += f", and {len(others)} direction(s) along no axis of part 1"
        return names, line + "."

    def apply_fit(self, setup) -> None:
        """Write the fit into the scene file (Save as for a bundled one) and open it again."""
        from app.gui.scene_file import write_scene

        handle = self.session.handle
        target = Path(handle.scene.path)
        bundled = Path(__file__).resolve().parents[2] / "assets"
        if target.resolve().is_relative_to(bundled):
            path, _ = QtWidgets.QFileDialog.getSaveFileName(
                self, "Save the scene with its fit", str(self.save_folder() / target.name),
                "Scenes (*.toml)")
            if not path:
                return
            target = Path(path)
        try:
            out = write_scene(handle, target, fit=setup, **self.params.scene_settings())
        except (OSError, ValueError) as exc:
            self.show_error(f"Could not save the fit: {exc}")
            return
        self.statusBar().showMessage(f"saved the fit in {out}; opening it again", 5000)
        self.open_path(out)

    def save_scene(self, path: str | Path) -> Path:
        """Write the current scene, with the part where it is now, to a TOML file.

        The file dialog has asked before replacing a file; a part file of the scene is never
        replaced (``engine.files.check_output``). Errors are shown, then raised.
        """
        from app.gui.scene_file import write_scene
        from engine.files import check_output

        pose = None
        if self.latest_frame is not None:
            pose = np.asarray(self.latest_frame.part_pose, float)
        target = Path(path)
        if target.suffix.lower() != ".toml":
            target = target.with_suffix(".toml")  # as the scene writer names it
        handle = self.session.handle
        inputs = [spec.file for spec in handle.scene.parts] if handle is not None else []
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            check_output(target, force=True, inputs=inputs, what="scene")
            out = write_scene(handle, Path(path), moving_relative_pose=pose,
                              **self.params.scene_settings())
        except (OSError, ValueError) as exc:
            self.show_error(f"Could not save the scene: {exc}")
            raise
        self._remember(str(out))
        self.settings.setValue("last_save_dir", str(Path(out).resolve().parent))
        self.statusBar().showMessage(f"saved {out}", 5000)
        return out

    def screenshot_dialog(self) -> None:
        """Ask where to save a screenshot of the window and save it."""
        path, _ = QtWidgets.QFileDialog.getSaveFileName(
            self, "Save screenshot", str(self.save_folder() / "skelasm.png"),
            "PNG images (*.png)")
        if path:
            try:
                self.save_screenshot(path)
            except (OSError, ValueError) as exc:
                self.show_error(f"Could not save the screenshot: {exc}")

    def save_screenshot(self, path: str | Path, widget: QtWidgets.QWidget | None = None) -> Path:
        """Render now and save a picture of the window (or of one widget) as PNG.

        Written whole or not at all (a temporary file renamed into place); a part or scene
        file is never replaced.
        """
        import os
        import tempfile

        from engine.files import TEMP_PREFIX, TEMP_SUFFIX, check_output, move_into_place

        self.viewport.request_render()
        self.viewport.render_if_dirty(force=True)
        QtWidgets.QApplication.processEvents()
        pixmap = (widget or self).grab()
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        handle = self.session.handle
        inputs = ([handle.scene.path, *(spec.file for spec in handle.scene.parts)]
                  if handle is not None else [])
        check_output(path, force=True, inputs=[p for p in inputs if p], what="screenshot")
        # Qt writes a temporary file in the folder, renamed over the target when whole (a
        # QBuffer in memory would do, but PySide6 leaks references to None through it)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{TEMP_PREFIX}{path.name}.",
                                   suffix=TEMP_SUFFIX)
        os.close(fd)
        try:
            if not pixmap.save(tmp, "PNG"):
                raise OSError(f"{path}: could not write the PNG (disk full or no permission?)")
            with open(tmp, "rb+") as fh:
                os.fsync(fh.fileno())
            move_into_place(tmp, path)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
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
        self.tasks.clear()  # the opening among them
        self.seat = None
        self._requested_modes = None
        self._coupling = None
        self._kappa_override = handle.config.simulation.kappa
        self._effects = handle.config.effects
        views = self.session.part_views()
        scene = handle.scene
        frame = self.session.part1_rotation()
        insertion = None if scene.insertion_axis is None else frame @ scene.insertion_axis
        self.viewport.set_scene(views, frame=frame, insertion_axis=insertion)
        self.view_actions["insertion"].setEnabled(insertion is not None)
        self.constraint_actions["insertion"].setEnabled(insertion is not None)
        # the insertion axis, where the scene gives one, is the drag a first user needs
        self.set_constraint("insertion" if insertion is not None else "free")
        title = scene.name
        self.setWindowTitle(f"{title} — skelasm")
        self._set_units(quantities.units_of(handle))
        self.readouts.set("free", quantities.free_axes_text(scene.seat.free_axes))
        for key in ("pose", "seat", "energy", "force", "torque", "rate", "eval", "modes"):
            self.readouts.set(key, "-")
        self._show_seated(False, "no frame yet" if len(views) > 1 else "one part: nothing "
                          "to seat")
        self.viewport.set_overlap(False)
        self.parts_panel.set_parts(handle)
        self.history.clear()
        if len(handle.parts) > 1:
            self.readouts.set("overlap", "measuring…")
            self.overlap.submit(handle.parts[0], handle.parts[1])
        meshes = [(v.name, v.vertices, v.faces) for v in views]
        self.slice_view.set_parts(meshes, [posemath.pose_to_matrix(v.pose) for v in views])
        self.slice_view.set_descriptors(())
        self.landscape_view.set_landscape(None)
        self.landscape_view.canvas.clear("landscape not computed yet")
        self.params.load_config(handle.config, scene.modes, scene.descriptor)
        self._update_kappa()
        if self.session.engine is None:
            self.statusBar().showMessage(
                f"{title}: one part loaded; open a second part (the moving one) to assemble")
        else:
            self.tasks.start("correlator")
            self.params.set_progress(0.0, "preparing descriptors %p%", cancellable=False)
            chosen = "; ".join(f"{key} = {value}" for key, value, _ in scene.chosen)
            placed, self.session.placement = self.session.placement, None
            self.statusBar().showMessage(
                (f"{placed}. " if placed else "")
                + f"{title}: preparing descriptors (minutes the first time; then cached)"
                + (f"; chosen from the parts: {chosen}" if chosen else ""))
        # what the scene left open and the engine chose, with why (hover the parameters)
        self.params.setToolTip("\n".join(f"{key} = {value}: chosen, {reason}"
                                          for key, value, reason in scene.chosen))
        if not Path(handle.path).name.startswith("generated_"):
            self._remember(str(handle.path))

    def _open_failed(self, path: str, message: str) -> None:
        self.tasks.finish("open")
        self._show_tasks()
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
        """Send a command from the panels, and say what the engine now does about it."""
        self.session.send(command)
        if self.session.engine is None:
            return
        if isinstance(command, runtime.SetModes):
            self._requested_modes = command.modes
            if self.latest_frame is None or self.latest_frame.modes != command.modes:
                self.tasks.start("field", f"building the tables for K = {command.modes} "
                                 f"({command.modes ** 3:,} modes)", reports_fraction=False)
        elif isinstance(command, runtime.SetDescriptorParams):
            self.tasks.start("descriptors", f"recomputing descriptors (sigma "
                             f"{command.params.sigma:.3g}, penalty {command.params.penalty:.3g})")
        elif isinstance(command, runtime.SetEffects):
            old = self._effects
            new = command.effects
            if old is not None and old.guidance != new.guidance:
                self.tasks.start("descriptors", f"recomputing descriptors for guidance "
                                 f"'{new.guidance}'")
                self.params.set_progress(0.0, "recomputing descriptors %p%")
            elif old is not None and old.rotation != new.rotation:
                what = ("building the translation landscape for the locked rotation"
                        if not new.rotation else "building the tables for free rotation")
                self.tasks.start("field", what, reports_fraction=False)
            self._effects = new
        elif isinstance(command, runtime.SetCoupling):
            self._coupling = command.coupling
            self._update_kappa()
        elif isinstance(command, runtime.SetKappa):
            self._kappa_override = command.kappa
            self._update_kappa()
        elif isinstance(command, runtime.Reset):
            self._remember_pose()
        elif isinstance(command, runtime.Pause):
            self._show_engine_state()
        self._show_tasks()

    def _proxy_dragged(self, world_pose) -> None:
        if self.session.handle is None:
            return
        self.session.send(runtime.SetProxyPose(tuple(self.session.relative(world_pose))))
        if self.params.pause.isChecked():
            self.statusBar().showMessage(
                "paused: the part stays where it is until you resume (Space)", 3000)
        elif not self.guidance_ready and self.session.engine is not None:
            self.statusBar().showMessage(self._not_ready_text(), 5000)

    def _not_ready_text(self) -> str:
        """Why the part does not meet part 1 yet, while the engine prepares the fit."""
        if self.guidance_error:
            return (f"no contact forces: preparing the descriptors failed "
                    f"({self.guidance_error}); the part follows the ghost through its spring "
                    "only")
        task = self.tasks.get("correlator")
        how_far = f" ({task.clock.text()})" if task is not None else ""
        return ("the fit's forces are not ready yet: the engine is preparing descriptors"
                f"{how_far}; until then the part follows the ghost through its spring only "
                "and passes through part 1")

    def _drag_state(self, dragging: bool) -> None:
        if dragging:
            self._remember_pose()
        if dragging and self.guidance_ready:
            axis = self.viewport.constraint
            along = "in the view plane" if axis == "free" else (
                "along the insertion axis" if axis == "insertion" else f"along {axis}")
            self.statusBar().showMessage(
                f"dragging {along}: Shift or wheel = depth, Ctrl = rotate; "
                "I, X, Y, Z, F choose the axis", 3000)

    def set_constraint(self, name: str) -> None:
        """Drag along an axis ("insertion", "x", "y", "z") or freely ("free")."""
        self.viewport.set_constraint(name)
        self._constraint_changed(self.viewport.constraint)

    def _constraint_changed(self, name: str) -> None:
        action = self.constraint_actions.get(name)
        if action is not None and not action.isChecked():
            action.setChecked(True)
        self.viewport.request_render()

    def set_view(self, name: str) -> None:
        """Look along a standard direction (``app.gui.viewport.VIEWS`` or "insertion")."""
        if name == "insertion" and self.viewport.insertion_axis is None:
            self.statusBar().showMessage("this scene gives no insertion axis", 4000)
            return
        self.viewport.set_view(name)
        self.statusBar().showMessage(f"view {VIEW_NAMES[name]}", 2000)

    def show_pose_dialog(self) -> None:
        """Open the dialog that takes the moving part's pose as numbers."""
        if self.session.handle is None or len(self.session.handle.parts) < 2:
            self.show_error("Open a scene with two parts to place the moving part.")
            return
        if self.pose_dialog is None:
            dialog = PoseDialog(self, unit=self.units.length,
                                pivot=self.session.moving.pivot)
            dialog.add_preset("Current", lambda: np.asarray(
                self.latest_frame.part_pose if self.latest_frame is not None
                else self.session.handle.start_pose, float))
            dialog.add_preset("Start", lambda: np.asarray(self.session.handle.start_pose))
            dialog.add_preset("Assembled", lambda: np.asarray(self.session.handle.assembled_pose))
            dialog.move_proxy.connect(self._typed_proxy_pose)
            dialog.place_part.connect(self._typed_part_pose)
            self.pose_dialog = dialog
        pose = (self.latest_frame.part_pose if self.latest_frame is not None
                else self.session.handle.start_pose)
        self.pose_dialog.set_pose(np.asarray(pose, float))
        self.pose_dialog.show()
        self.pose_dialog.raise_()

    def _typed_proxy_pose(self, pose) -> None:
        self._remember_pose()
        self.session.send(runtime.SetProxyPose(tuple(float(v) for v in pose)))

    def _typed_part_pose(self, pose) -> None:
        self._remember_pose()
        self.session.send(runtime.Reset(tuple(float(v) for v in pose)))

    def _remember_pose(self) -> None:
        """Keep the part's and the ghost's poses before a change, for Undo."""
        f = self.latest_frame
        if f is not None:
            self.history.push(f.part_pose, f.proxy_pose)

    def undo_pose(self) -> None:
        """Put the part and its ghost back where they were before the last change."""
        self._step_history(self.history.undo, "undo")

    def redo_pose(self) -> None:
        """Redo the pose change the last Undo took back."""
        self._step_history(self.history.redo, "redo")

    def _step_history(self, step, what: str) -> None:
        f = self.latest_frame
        state = step(f.part_pose, f.proxy_pose) if f is not None else None
        if state is None:
            self.statusBar().showMessage(f"nothing to {what}", 3000)
            return
        part, proxy = state
        # the part at rest where it was, then the ghost where it was: the part follows it
        self.session.send(runtime.Reset(tuple(float(v) for v in part)))
        self.session.send(runtime.SetProxyPose(tuple(float(v) for v in proxy)))
        left, ahead = self.history.depth
        self.statusBar().showMessage(f"{what}: pose restored ({left} to undo, {ahead} to "
                                     "redo)", 3000)

    def _toggle_pause(self, checked: bool) -> None:
        self.params.pause.setChecked(checked)

    def _pause_changed(self, paused: bool) -> None:
        self.pause_action.blockSignals(True)
        self.pause_action.setChecked(paused)
        self.pause_action.blockSignals(False)

    def _step_modes(self, delta: int) -> None:
        self.params.modes.setValue(self.params.modes.value() + delta)

    def reset_camera(self) -> None:
        """The default camera again: isometric, the whole scene in view."""
        self.viewport.reset_camera()

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
                               float(np.linalg.norm(f.force)), float(np.linalg.norm(f.torque)))
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
            self._show_tasks()  # the time spent counts on while no event comes

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
                self.landscape_view.set_modes(frame.modes)
                self.landscape_view.set_pose(np.asarray(frame.part_pose))
                self._maybe_request_landscape(np.asarray(frame.part_pose))

    def _update_readouts(self, f: runtime.Frame, fn: float, tn: float) -> None:
        r = self.readouts
        u = self.units
        handle, part = self.session.handle, self.session.moving
        if handle is not None and part is not None and len(handle.parts) > 1:
            pose = np.asarray(f.part_pose, float)
            self.seat = quantities.seat_of(handle, part, pose)
            r.set("pose", quantities.pose_text(pose, u.length, part.pivot),
                  "Part 2's pose in part 1's frame about its pivot (its centre of mass "
                  "unless the scene sets pivot):\nhow far the pivot moved, and the rotation "
                  "about it (the scene file's pose when not turned)")
            head, detail = quantities.seat_text(self.seat, u.length)
            if self.tasks.get("descriptors") is not None:
                # the coarse first field's rest can lie a cell off the seat (the peg in hole
                # rests 1.1 degrees tilted there, 0.8 on its own grid)
                detail += "; judged on a coarse first field until the scene's descriptors are ready"
            if Path(handle.path) in self.session.drawn_seats:
                detail += ("; the seat is where the two files draw the parts until Edit > Set "
                           "up the fit or Find fits sets it")
            scene_k = handle.scene.modes
            if scene_k is not None and f.modes > 0 and f.modes != scene_k:
                # the judgement takes the pose alone; it is the part that rests elsewhere on
                # a truncated field (the peg pushed onto its floor: 0.98 mm and 0.10 deg from
                # the seat at K = 24, 1.25 mm and 0.28 deg at 20, 1.44 mm and 3.08 deg at 16)
                detail += (f"; the part rests where the field at K = {f.modes} puts it (the "
                           f"scene's K is {scene_k}): another K can move it on or off its seat")
            r.set("seat", f"{self.seat.distance:.3g} {u.length}, {self.seat.angle_deg:.2f}°",
                  "Distance of part 2's centre of mass from where it sits when assembled, and "
                  "the angle from the seated orientation, the fit's free axes left out")
            self._show_seated(self.seat.seated, head, detail)
            self._show_overlap(pose)
        r.set("energy", f"{quantities.number(f.energy, 5)} {u.energy}")
        r.set("force", f"{quantities.number(fn)} {u.force}")
        r.set("torque", f"{quantities.number(tn)} {u.torque}")
        r.set("eval", f"{f.eval_us:.1f} µs per step",
              f"Time the correlator took for this step's energy, force and torque\n"
              f"evaluator: {self.evaluator}")
        self.params.show_pose_cost(f.eval_us, f.modes)
        r.set("modes", f"{f.modes ** 3:,} modes (K = {f.modes})",
              "K Fourier modes per axis are kept, m' = K³ in all: more is more accurate "
              "and slower")
        r.set("device", f.device + ("  (paused)" if f.paused else ""))
        self._show_engine_state(f)
        if (self._requested_modes is not None and f.modes == self._requested_modes):
            self._requested_modes = None
            if self.tasks.get("field") is not None:
                self.tasks.finish("field")
                self.params.set_progress(None, f"K = {f.modes} in use")
        self._show_tasks()

    def _show_overlap(self, pose: np.ndarray | None = None) -> None:
        """How deep part 2 sits in part 1, and the part in red when past contact."""
        gauge, u = self.overlap, self.units.length
        if pose is None and self.latest_frame is not None:
            pose = np.asarray(self.latest_frame.part_pose, float)
        if gauge.map is None or pose is None:
            if gauge.error:
                self.readouts.set("overlap", "not measured", gauge.error)
            return
        depth, limit = gauge.map.depth(pose), gauge.map.threshold
        self.overlap_depth = depth
        name = self.session.handle.parts[0].name if self.session.handle is not None else ""
        over = depth > limit
        if over:
            text = f"{depth:.3g} {u} into {name}"
        elif depth > 0:
            text = f"touching ({depth:.2g} {u}, within a cell of {limit:.2g} {u})"
        else:
            text = "none"
        self.readouts.set("overlap", text,
                          "How far the deepest point of part 2's surface lies inside part 1 "
                          "(its signed distance on a grid of cell "
                          f"{limit:.3g} {u});\nbeyond a cell the parts interpenetrate: the "
                          "part turns red")
        label = self.readouts.labels["overlap"]
        style = "color: white; background: #c0392b; font-weight: bold" if over else ""
        if label.styleSheet() != style:
            label.setStyleSheet(style)
        self.viewport.set_overlap(over)

    def _show_engine_state(self, f: runtime.Frame | None = None) -> None:
        """The engine's rate in words, PAUSED, or a warning when it runs below its target."""
        f = f or self.latest_frame
        paused = self.params.pause.isChecked() or (f is not None and f.paused)
        target = (self.session.handle.config.simulation.rate_hz
                  if self.session.handle is not None else 0.0)
        rate = f.period.rate_hz if f is not None else 0.0
        detail = ""
        if f is not None:
            detail = (f"loop period median {f.period.median_us:.0f} µs, 99th percentile "
                      f"{f.period.p99_us:.0f} µs, longest {f.period.max_us:.0f} µs over the "
                      f"last {f.period.window} steps\nevaluator: {self.evaluator}\n"
                      f"{self.engine_note}")
        self.rate_low = bool(
            f is not None and not paused and self.session.realtime and target > 0
            and f.period.window > 0 and rate < RATE_WARNING * target)
        if paused:
            text, style = "PAUSED (Space resumes)", "color: white; background: #555; padding: 0 4px"
            self.readouts.set("rate", "paused", detail)
        elif self.rate_low:
            text = f"engine slow: {rate:,.0f} of {target:,.0f} steps/s (lower K?)"
            style = "color: black; background: #ffb000; padding: 0 4px"
            self.readouts.set("rate", f"{rate:,.0f} steps/s, below its {target:,.0f}",
                              "Forces come less often than the engine's rate: lower K, or "
                              f"close other programs\n{detail}")
        else:
            text, style = (f"engine {rate:,.0f} steps/s" if f is not None else "engine: -"), ""
            self.readouts.set("rate", f"{rate:,.0f} steps/s (target {target:,.0f})", detail)
        if self.status_engine.text() != text:
            self.status_engine.setText(text)
            self.status_engine.setStyleSheet(style)
        self.status_engine.setToolTip(detail)

    def _show_tasks(self) -> None:
        """Running background tasks in the status bar and the parameters' progress bar."""
        text = self.tasks.summary()
        if self.status_task.text() != text:
            self.status_task.setText(text)
        task = (self.tasks.get("correlator") or self.tasks.get("descriptors")
                or self.tasks.get("field"))
        if task is None:
            return
        if task.reports_fraction and task.clock.fraction is not None:
            left = task.clock.seconds_left()
            suffix = f", {quantities.duration_text(left)} left" if left is not None else ""
            self.params.set_progress(task.clock.fraction,
                                     f"{task.label} {100 * task.clock.fraction:.0f} %{suffix}",
                                     cancellable=self.tasks.get("correlator") is None)
        elif not task.reports_fraction:
            self.params.set_progress(-1.0, f"{task.label}…", cancellable=False)

    def _show_seated(self, seated: bool, head: str = "", detail: str = "") -> None:
        """The seat headline: green SEATED, or how far part 2 is from its seat."""
        style = ("font-weight: bold; font-size: 15pt; padding: 4px; color: white; "
                 "background: #2e8b3e; border-radius: 4px" if seated else
                 "font-weight: bold; padding: 4px; color: #333; background: #e4e6ea; "
                 "border-radius: 4px")
        if self.seat_label.styleSheet() != style:
            self.seat_label.setStyleSheet(style)
        if head and self.seat_label.text() != head:
            self.seat_label.setText(head)
        if self.seat_detail.text() != detail:
            self.seat_detail.setText(detail)

    def _set_units(self, units: QuantityUnits) -> None:
        """Label the readouts, the chart and the landscape in ``units``."""
        self.units = units
        r = self.readouts
        r.set_title("energy", f"energy E ({units.energy})")
        r.set_title("force", f"|force F| ({units.force})")
        r.set_title("torque", f"|torque T| ({units.torque})")
        self.chart.set_units(units.energy, units.force, units.torque)

    def _update_kappa(self) -> None:
        """Resolve the kappa the engine uses now and show it everywhere E is shown."""
        handle = self.session.handle
        if handle is None or len(handle.parts) < 2:
            return
        self.kappa = quantities.physics_kappa(handle, coupling=self._coupling,
                                              kappa=self._kappa_override)
        origin = "scale-free default" if self._kappa_override is None else "set by the user"
        self.readouts.set("kappa", f"{quantities.number(self.kappa)} {self.units.kappa}",
                          f"E = -kappa Re f; kappa is the {origin}")
        self.params.show_kappa(self.kappa, self.units.kappa)
        self.landscape_view.set_scale(self.kappa, self.units)

    def _maybe_request_landscape(self, pose: np.ndarray) -> None:
        if not self.guidance_ready or self._landscape_pending:
            return
        if not self.landscape_view.needs_landscape(pose):
            return
        self._landscape_pending = True
        self.tasks.start("landscape", "computing the energy landscape at this orientation")
        self.session.send(runtime.RequestLandscape(tuple(float(x) for x in pose[3:])))

    def _handle_event(self, event) -> None:
        if isinstance(event, runtime.ReadyEvent):
            self.guidance_ready = bool(event.descriptors)
            self.tasks.finish("correlator")
            self.params.set_progress(None, "ready")
            self.evaluator = event.backend or "-"
            self.slice_view.set_descriptors(event.descriptors)
            self.accuracy.submit(event.descriptors)
            self.engine_note = event.message
            self.statusBar().showMessage(
                "ready: drag the orange part (or its blue ghost) to its seat", 6000)
            if event.coarse_grid is not None:  # the scene's own descriptors follow
                self.tasks.start("descriptors", "computing the scene's descriptors (the part "
                                 f"moves on a coarse grid of {event.coarse_grid} meanwhile)")
        elif isinstance(event, runtime.DescriptorsSwapped) and event.coarse_grid is not None:
            # a new sigma on a coarse grid: the part moves on it while the scene's grid is
            # computed; the sigma before stays "in use" for Cancel, which returns to it
            self.guidance_ready = bool(event.descriptors)
            self.slice_view.set_descriptors(event.descriptors)
            self.tasks.start("descriptors", f"sigma {event.sigma:.3g} on a coarse grid of "
                             f"{event.coarse_grid} in {event.seconds:.1f} s; now the scene's grid")
            self.landscape_view.set_landscape(None)
            self._landscape_pending = False
        elif isinstance(event, runtime.DescriptorsSwapped):
            self.guidance_ready = bool(event.descriptors)
            self.tasks.finish("descriptors")
            self.tasks.finish("field")  # a field request that had to recompute descriptors
            self.slice_view.set_descriptors(event.descriptors)
            self.accuracy.submit(event.descriptors)
            self.params.show_descriptor_cost(event.seconds)
            self.params.descriptors_applied()
            self.descriptor_seconds = event.seconds
            self.params.set_progress(None, f"updated in {event.seconds:.1f} s")
            self.landscape_view.set_landscape(None)
            self._landscape_pending = False
        elif isinstance(event, runtime.ProgressEvent):
            self._progress(event)
        elif isinstance(event, runtime.LandscapeReady):
            self._landscape_pending = False
            self.tasks.finish("landscape")
            self.landscape_view.set_progress(None)
            self.landscape_view.set_landscape(event.landscape)
            if self.latest_frame is not None:
                self.landscape_view.set_pose(np.asarray(self.latest_frame.part_pose))
        elif isinstance(event, runtime.LandscapeFailed):
            self._landscape_pending = False
            self.tasks.finish("landscape")
            self.landscape_view.set_progress(None)
            self.statusBar().showMessage(f"landscape: {event.message}", 15000)
        elif isinstance(event, runtime.ErrorEvent):
            if not self.guidance_ready and not event.fatal:
                self.guidance_error = event.message  # preparing the correlator failed
                self.tasks.finish("correlator")
            if event.fatal:
                self.show_error(f"The engine stopped: {event.message}")
            else:
                if self.params.cancel.isEnabled():  # a recompute was running: it failed
                    self.params.recompute_ended("recompute failed")
                for task in ("descriptors", "field"):
                    self.tasks.finish(task)
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
        self._show_tasks()

    def _progress(self, event: runtime.ProgressEvent) -> None:
        if event.task == "ladder":  # the sigma ladders: the status bar only, never the panel
            if event.message:  # done, paused (a field job goes first) or failed
                self.tasks.finish("ladder")
            else:
                self.tasks.progress("ladder", event.fraction)
            return
        if event.message == "cancelled":
            self.tasks.finish(event.task)
            if event.task == "descriptors":
                self.params.recompute_ended("cancelled")
            return
        if event.message == "done" or (event.task == "field" and event.fraction >= 1.0):
            self.tasks.finish(event.task)
            self.params.set_progress(None, "ready")
            return
        task = self.tasks.progress(event.task, event.fraction)
        if event.task == "landscape":
            if task.clock.elapsed >= 1.0:
                self.landscape_view.set_progress(task.text())
            return
        if event.fraction >= 1.0 and event.task == "correlator":
            self.params.set_progress(1.0, "warming up the evaluator", cancellable=False)

    # ------------------------------------------------------------------ closing
    def closeEvent(self, event) -> None:  # noqa: N802
        """Save the layout, stop the engine and the 3D view, then close."""
        self.save_layout()
        self._tick_timer.stop()
        self.accuracy.shutdown()
        self.fits_panel.shutdown()
        self.slice_view.previews.shutdown()
        self.overlap.shutdown()
        self.session.close()
        self.viewport.close()
        super().closeEvent(event)


def _droppable(url: QtCore.QUrl) -> bool:
    if not url.isLocalFile():
        return False
    return Path(url.toLocalFile()).suffix.lower() in SCENE_SUFFIXES + PART_SUFFIXES
