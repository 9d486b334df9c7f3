"""The installed Qt binding keeps Python's ``None`` alive while our widgets paint.

PySide6 6.12.0 on Python 3.10 and 3.11 drops one reference to ``None`` on every call of a
Qt method that returns nothing (``update``, ``setPen``, ``drawLine``, ``setText``...). A
repaint of the strip chart does about ten such calls; after some minutes the count reaches
zero, Python frees ``None`` and aborts with "Fatal Python error: none_dealloc". pyproject.toml
excludes that release for those Pythons; these tests catch a binding with the same fault.

From Python 3.12 ``None`` is immortal: it cannot be freed, so this fault cannot crash
there, and its reference count says nothing (extensions built for the stable ABI still
add and drop references to it: on 3.13 the count was seen 777 above its immortal value at
one moment and back on it the next). The tests are skipped there.
"""

from __future__ import annotations

import gc
import sys
import time

import numpy as np
import pytest
from PySide6 import QtCore, QtWidgets

from app.gui import colourmap
from app.gui.canvas import FieldCanvas, Marker
from app.gui.strip_chart import StripChart

#: Waits for an engine to start: the first start in a fresh environment compiles the
#: numba kernels (a minute or two on a loaded 2-core machine). A guard against a hang,
#: not a check of speed.
ENGINE_START_MS = 600_000

pytestmark = pytest.mark.skipif(
    sys.version_info >= (3, 12),
    reason="None is immortal from Python 3.12: it cannot be freed and its count means nothing",
)

REPAINTS = 300
#: A sound binding moves the count by a few at most (objects holding None made or freed
#: meanwhile); the faulty one loses at least one per repaint.
TOLERANCE = 10


class PaintCounter(QtCore.QObject):
    """Counts the paint events a widget and its children receive (an event filter that lets
    them through). A container's repaint paints only what its children leave uncovered, often
    nothing of its own: its children's paint events are what a repaint of it costs.
    """

    def __init__(self, widget):
        super().__init__(widget)
        self.count = 0
        self.widgets = [widget, *widget.findChildren(QtWidgets.QWidget)]
        for w in self.widgets:
            w.installEventFilter(self)

    def eventFilter(self, obj, event):  # noqa: N802 (Qt API)
        if event.type() == QtCore.QEvent.Type.Paint:
            self.count += 1
        return False

    def remove(self) -> None:
        for w in self.widgets:
            w.removeEventFilter(self)


def none_references_lost(widget, repaints: int = REPAINTS) -> int:
    """How many references to None ``repaints`` repaints of ``widget`` dropped.

    Each repaint is a ``repaint()`` call (a Qt method that returns nothing) and a ``grab()``,
    which paints the widget and its children into a pixmap at once. ``repaint()`` alone is
    not enough: right after a window is shown it does nothing, and in the running window
    the backing store coalesces synchronous repaints (12 paints for 300 calls, counted), so
    a check built on it alone measured almost no painting. The count of paint events is
    checked, so that a check of paints that never happen fails instead of passing.
    """
    painted = PaintCounter(widget)
    # the collector off: freeing an earlier test's garbage meanwhile (objects holding None)
    # read as references lost (108 in one CI run)
    gc.collect()
    gc.disable()
    try:
        widget.grab()  # the first paint builds caches that may hold None for good
        start = painted.count
        before = sys.getrefcount(None)
        for _ in range(repaints):
            widget.repaint()
            widget.grab()
        lost = before - sys.getrefcount(None)
        done = painted.count - start
    finally:
        gc.enable()
        painted.remove()
    assert done >= repaints, f"{type(widget).__name__}: {done} of {repaints} repaints painted"
    return lost


@pytest.fixture
def shown(qtbot):
    def show(widget):
        qtbot.addWidget(widget)
        widget.resize(420, 300)
        widget.show()
        qtbot.waitExposed(widget)
        return widget

    return show


def test_a_label_keeps_none_alive(shown):
    """The issue's ten-second reproduction, as a test: setText returns nothing."""
    from PySide6 import QtWidgets

    label = shown(QtWidgets.QLabel("a"))
    before = sys.getrefcount(None)
    for i in range(REPAINTS):
        label.setText(str(i))
    assert before - sys.getrefcount(None) < TOLERANCE


def test_strip_chart_repaints_keep_none_alive(shown):
    chart = shown(StripChart(seconds=10.0))
    t = np.linspace(0.0, 9.0, 400)
    for ti in t:
        chart.add(float(ti), float(np.sin(ti)), float(abs(np.cos(ti))))
    assert len(chart.samples()[0]) == len(t)
    assert none_references_lost(chart) < TOLERANCE


def test_field_canvas_repaints_keep_none_alive(shown):
    canvas = shown(FieldCanvas())
    u, v = np.meshgrid(np.linspace(-1, 1, 40), np.linspace(-1, 1, 30), indexing="ij")
    canvas.set_field(np.exp(-(u**2 + v**2)), (-1, 1, -1, 1), 0.0, 1.0,
                     colourmap.table("sequential"), axis_names=("x", "y"), bar_label="rho")
    canvas.set_segments(np.array([[[-0.5, -0.5], [0.5, 0.5]], [[-0.5, 0.5], [0.5, -0.5]]]))
    canvas.set_markers([Marker(0.0, 0.0, "cross", "white", "minimum"),
                        Marker(0.3, -0.2, "star", "yellow", "part"),
                        Marker(-0.3, 0.2, "circle", "black")])
    assert canvas.field_rgb() is not None
    assert none_references_lost(canvas) < TOLERANCE


def test_window_views_keep_none_alive(make_window, small_scene, wait_until, qtbot, request):
    """The whole window with the engine running: slice view, landscape view, strip chart
    and readouts repaint and update from live frames without losing references to None.
    """
    compiles = _Compiles()  # from before the engine starts
    request.addfinalizer(compiles.close)
    win = make_window(small_scene)
    wait_until(lambda: win.guidance_ready or win.guidance_error, ENGINE_START_MS,
               "the engine's descriptors and correlator")
    assert win.guidance_error is None, win.guidance_error
    win.dock_slice.show()
    win.dock_landscape.show()
    qtbot.wait(500)
    frames = win.frames_received
    # garbage of earlier tests (cycles holding None) must not be collected inside the
    # window: that is a true release, not a lost reference, and it made these checks fail
    # after other window tests (30 "lost" over the chart's repaints once, in CI)
    gc.collect()
    gc.disable()
    try:
        for widget in (win.slice_view, win.slice_view.canvas, win.landscape_view,
                       win.landscape_view.canvas, win.chart):
            lost = lost_while_nothing_compiles(widget, compiles)
            assert lost < WINDOW_TOLERANCE, f"{type(widget).__name__}: {lost} lost"
        counts = none_counts_while_live(qtbot)
    finally:
        gc.enable()
    assert win.frames_received > frames
    lost = level_drop(counts)
    assert lost < LIVE_TOLERANCE, f"{lost:g} references to None lost; readings {counts}"


class _Compiles:
    """Counts the compilations numba starts and those running, in any thread."""

    def __init__(self):
        from numba.core import event

        class Listener(event.Listener):
            def on_start(inner, ev):  # noqa: N805 -- the listener's own self
                self.started += 1
                self.running += 1

            def on_end(inner, ev):  # noqa: N805
                self.running -= 1

        self.started = self.running = 0
        self._event = event
        self._listener = Listener()
        event.register("numba:compile", self._listener)

    def close(self):
        self._event.unregister("numba:compile", self._listener)


def lost_while_nothing_compiles(widget, compiles: _Compiles, attempts: int = 20) -> int:
    """:func:`none_references_lost` over a run during which the engine compiled nothing.

    A kernel compiling in the engine's threads makes and frees objects holding None by the
    thousand: with numba's cache empty (a fresh clone, as in CI) single runs read 1760 and
    1799 lost, others as many gained, and one CI run failed at 224. A run is measured
    again when a compilation started or ran during it (waiting for a running one to end
    first); a faulty binding loses its references in every run. ``compiles`` must watch
    from before the engine starts.
    """
    for _ in range(attempts):
        end = time.monotonic() + 60.0
        while compiles.running and time.monotonic() < end:
            time.sleep(0.05)
        before = compiles.started
        lost = none_references_lost(widget)
        if compiles.started == before and not compiles.running:
            return lost
    raise AssertionError(f"the engine compiled kernels through all {attempts} runs")


#: Repaints inside the running window: the engine's threads make and free objects holding
#: None meanwhile, so the count wanders by tens; a faulty binding loses at least one per
#: ``repaint()`` call alone (``REPAINTS`` of them), and one per Qt call its painting makes.
WINDOW_TOLERANCE = REPAINTS // 3


#: Seconds the live window is watched, and how often its count of None is read.
LIVE_SECONDS, LIVE_SAMPLE_MS = 3.0, 150
#: A faulty binding loses one reference per Qt call that returns nothing: in 3 s the live
#: window changed its labels' text 265 times and repainted the chart 25 times (about ten
#: calls each), so it would lose hundreds. A sound one keeps a level that only wanders with
#: what is alive at the moment of reading (single readings up to 23 above it, seen here;
#: the medians of :func:`level_drop` moved by at most 1).
LIVE_TOLERANCE = 30


def none_counts_while_live(qtbot) -> list[int]:
    """Python's count of references to None, read every ``LIVE_SAMPLE_MS`` for
    ``LIVE_SECONDS`` by a timer inside the window's running event loop.

    One wait, not one per reading: each ``qtbot.wait`` itself keeps about six references
    to None (measured), which would read as a steady gain and hide a loss.
    """
    from PySide6 import QtCore

    counts: list[int] = []
    timer = QtCore.QTimer()
    timer.setInterval(LIVE_SAMPLE_MS)
    timer.timeout.connect(lambda: counts.append(sys.getrefcount(None)))
    timer.start()
    qtbot.wait(round(LIVE_SECONDS * 1000))  # live frames: setText, chart updates, repaints
    timer.stop()
    return counts


def level_drop(counts: list[int], share: float = 0.2) -> float:
    """How far the count's level fell: the median of the first ``share`` of the readings
    less the median of the last ``share``. Medians, so that what a single reading happens
    to catch alive (a batch of frames, an event) does not count as a loss or a gain.
    """
    k = max(1, round(share * len(counts)))
    return float(np.median(counts[:k]) - np.median(counts[-k:]))


def test_level_drop_reads_a_steady_loss_and_not_a_passing_one():
    """The live check's measure: a steady loss of one reference per reading is seen whole;
    a batch of references alive at one reading and gone at the next is not.
    """
    steady = [1000 - i for i in range(60)]
    assert level_drop(steady) == 48.0
    passing = [1000] * 60
    passing[0], passing[-1] = 1020, 980  # caught alive at the first reading, freed at the last
    assert level_drop(passing) == 0.0
