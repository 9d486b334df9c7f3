"""The window as a workbench: keys that never take text from a field, a cancelled change
that puts the boxes back, a layout that keeps its views, a seat readout independent of K,
overshoot shown, a parts list with undo, and the cosmetics of a first hour.
"""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore, QtGui

from app.gui.app import DEFAULT_SCENE as PEG


def _direction(win) -> np.ndarray:
    return np.asarray(win.viewport.plotter.camera.GetDirectionOfProjection())


def test_digits_typed_in_a_field_or_beside_it_never_turn_the_camera(make_window, qtbot):
    win = make_window(PEG, first_frame=False)
    win.activateWindow()
    view = win.viewport.widget
    view.setFocus()
    qtbot.waitUntil(view.hasFocus, timeout=5000)
    qtbot.keyClick(view, "1")  # with the 3D view focused, a digit is a view key
    plus_x = _direction(win)
    assert np.allclose(plus_x, [-1, 0, 0], atol=1e-6)
    # typed into a spin box: the value takes the text, the camera stays
    field = win.params.sigma.field
    field.setFocus()
    qtbot.waitUntil(field.hasFocus, timeout=5000)
    field.selectAll()
    qtbot.keyClicks(field, "0.6")
    assert field.text().startswith("0.6")
    assert np.allclose(_direction(win), plus_x, atol=1e-9)
    # a click beside the field (on the panel) takes the focus from the view: a digit typed
    # next does nothing to the camera
    view.setFocus()
    qtbot.waitUntil(view.hasFocus, timeout=5000)
    label = win.params.recompute_cost
    qtbot.mouseClick(label, QtCore.Qt.LeftButton)
    assert not view.hasFocus()
    qtbot.keyClicks(win.focusWidget() or win, "06")
    assert np.allclose(_direction(win), plus_x, atol=1e-9)
    # the menu still turns it, whatever has the focus
    win.view_actions["+z"].trigger()
    assert np.allclose(_direction(win), [0, 0, -1], atol=1e-6)


# ------------------------------------------------------------------ layout
def _rect_in(win, widget) -> QtCore.QRect:
    return QtCore.QRect(widget.mapTo(win, QtCore.QPoint(0, 0)), widget.size())


def _overlapping_siblings(root) -> list[tuple[str, str]]:
    """Pairs of visible sibling widgets under ``root`` whose rectangles meet."""
    from PySide6 import QtWidgets

    found = []
    for parent in [root, *root.findChildren(QtWidgets.QWidget)]:
        kids = [c for c in parent.children() if isinstance(c, QtWidgets.QWidget)
                and c.isVisible() and not c.isWindow()]
        for i, a in enumerate(kids):
            found += [(repr(a), repr(b)) for b in kids[i + 1:]
                      if a.geometry().intersects(b.geometry())]
    return found


def test_at_500_by_350_the_view_and_every_dock_keep_a_size_and_nothing_overlaps(
        make_window, qtbot):
    from app.gui.main_window import MIN_DOCK, MIN_VIEW

    win = make_window(PEG, first_frame=False)
    win.resize(500, 350)
    qtbot.wait(300)
    assert (win.width(), win.height()) == (500, 350)
    view = win.viewport.widget
    assert view.isVisible() and view.width() >= MIN_VIEW[0] and view.height() >= MIN_VIEW[1]
    docks = (win.dock_readouts, win.dock_params, win.dock_slice, win.dock_landscape)
    rects = [_rect_in(win, view)]
    for dock in docks:
        content = dock.widget()
        assert dock.isVisible(), dock.objectName()
        assert content.width() >= MIN_DOCK[0] and content.height() >= MIN_DOCK[1], \
            (dock.objectName(), content.size())
        assert win.rect().contains(_rect_in(win, dock)), dock.objectName()
        rects.append(_rect_in(win, dock))
        # texts squeezed below their size scroll rather than lie over each other
        assert not _overlapping_siblings(content.widget()), dock.objectName()
    for i, a in enumerate(rects):
        assert not any(a.intersects(b) for b in rects[i + 1:])
    # a wrapped readout gets the height its text needs at its width (it lay over the next row)
    win.readouts.set("pose", "at (0.000, 0.000, -18.000) mm, turned 3.01° about (0.00, 1.00, "
                     "0.01), a text long enough to wrap in a narrow dock")
    win.landscape_view.set_progress("computing the energy landscape at this orientation: 0 %, "
                                    "estimating the time left")
    qtbot.wait(200)
    for label in [*win.readouts.labels.values(), win.seat_detail, win.seat_label,
                  win.landscape_view.info]:
        if label.isVisible() and label.text():
            assert label.width() >= 60, label.objectName()  # not squeezed to nothing
            assert label.height() >= label.heightForWidth(label.width()), label.objectName()


def test_view_reset_layout_brings_back_the_default_docks(make_window, qtbot):
    win = make_window(PEG, first_frame=False)
    qtbot.wait(100)
    default = {d.objectName(): win.dockWidgetArea(d) for d in
               (win.dock_readouts, win.dock_params, win.dock_slice, win.dock_landscape)}
    win.dock_landscape.hide()
    win.dock_slice.setFloating(True)
    win.addDockWidget(QtCore.Qt.LeftDockWidgetArea, win.dock_readouts)
    # the menu's action, found through Qt's typed lookup: the menu bar's action list once
    # came back with a QSurface wrapper where an action had been (a recycled address)
    action = next(a for a in win.findChildren(QtGui.QAction) if a.text() == "Reset &layout")
    action.trigger()
    qtbot.wait(100)
    win.dock_parts.raise_()  # tabbed with the slice: shown when its tab is chosen
    assert win.dock_parts.isVisible()
    win.dock_slice.raise_()
    for dock in (win.dock_readouts, win.dock_params, win.dock_slice, win.dock_landscape):
        assert dock.isVisible() and not dock.isFloating(), dock.objectName()
        assert win.dockWidgetArea(dock) == default[dock.objectName()], dock.objectName()
    assert win.viewport.widget.width() > 0.3 * win.width()


def test_a_damaged_layout_is_not_restored(settings, qtbot):
    from app.gui.main_window import LAYOUT_MIN, MainWindow

    win = MainWindow(settings=settings)
    qtbot.addWidget(win)
    win.show()
    qtbot.waitExposed(win)
    win.dock_landscape.hide()
    win.resize(500, 350)
    qtbot.wait(100)
    win.save_layout()  # squeezed: not saved
    assert settings.value("window/geometry") is None
    # a squeezed layout saved anyway (by an older version): not restored
    settings.setValue("window/geometry", win.saveGeometry())
    settings.setValue("window/state", win.saveState())
    assert not win._layout_usable(QtCore.QRect(20000, 20000, 1000, 700))  # off every screen
    win.close()
    again = MainWindow(settings=settings)
    qtbot.addWidget(again)
    again.show()
    qtbot.waitExposed(again)
    try:
        assert again.width() >= LAYOUT_MIN[0] and again.height() >= LAYOUT_MIN[1]
        assert again.dock_landscape.isVisible()  # the default docks, not the damaged ones
    finally:
        again.close()


# ------------------------------------------------------------------ the seat and K
def test_a_part_that_does_not_move_keeps_its_seat_reading_whatever_k(make_window,
                                                                        wait_until):
    """The seat is judged from the pose alone; a K change that leaves the part where it is
    leaves the readout as it was, and the readout names the K the part rests at.
    """
    from engine import runtime

    win = make_window(PEG)
    k = win.session.handle.scene.modes
    wait_until(lambda: win.latest_frame.modes == k, 600000, f"a field at the scene's K = {k}")
    seated = tuple(float(v) for v in win.session.handle.assembled_pose)
    win.pause_action.trigger()  # paused, the part stays exactly where a Reset puts it
    wait_until(lambda: win.latest_frame.paused, 5000, "a paused frame")
    win.session.send(runtime.Reset(seated))
    wait_until(lambda: np.allclose(win.latest_frame.part_pose, seated, atol=1e-9)
               and win.seat is not None and win.seat.seated, 10000, "the part seated")
    before = (win.seat.distance, win.seat.angle_deg)
    assert "K =" not in win.seat_detail.text()
    win._step_modes(-2)
    win._step_modes(-2)  # "[" twice
    wait_until(lambda: win.latest_frame.modes == k - 4, 300000, f"frames at K = {k - 4}")
    wait_until(lambda: f"K = {k - 4}" in win.seat_detail.text(), 5000,
               lambda: f"the readout naming K: {win.seat_detail.text()!r}")
    assert np.allclose(win.latest_frame.part_pose, seated, atol=1e-9)
    assert win.seat_label.text() == "SEATED"
    assert (win.seat.distance, win.seat.angle_deg) == before
    assert f"scene's K is {k}" in win.seat_detail.text()


# ------------------------------------------------------------------ overshoot shown
def test_a_part_pushed_into_the_blind_floor_shows_the_overlap(make_window, wait_until):
    from app.gui.viewport import MOVING_COLOUR, OVERLAP_COLOUR
    from engine import runtime

    win = make_window(PEG)
    seated = np.asarray(win.session.handle.assembled_pose, float)
    win.pause_action.trigger()  # paused: the part stays exactly where a Reset puts it
    wait_until(lambda: win.latest_frame.paused, 5000, "a paused frame")
    wait_until(lambda: win.overlap.map is not None, 120000,
               lambda: f"the overlap map ({win.overlap.error})")
    cell = win.overlap.map.threshold
    actor = win.viewport._actors["moving"]

    def colour():
        return "#" + "".join(f"{round(255 * c):02x}" for c in actor.GetProperty().GetColor())

    for past, text in ((1.5, "1."), (0.0, None), (-27.0, "none")):
        pose = seated + [0, 0, -past, 0, 0, 0]  # down the bore: into its floor
        win.session.send(runtime.Reset(tuple(float(v) for v in pose)))
        wait_until(lambda p=pose: np.allclose(win.latest_frame.part_pose, p, atol=1e-9),
                   5000, "the part where it was put")
        wait_until(lambda p=pose: win.overlap_depth is not None and np.allclose(
            win.overlap.map.depth(p), win.overlap_depth), 5000, "the readout at the pose")
        shown = win.readouts.text("overlap")
        if past > 0:
            assert win.overlap_depth == pytest.approx(past, abs=0.5 * cell), shown
            assert shown.startswith(text) and shown.endswith(" mm into block"), shown
            assert colour() == OVERLAP_COLOUR
            assert "#c0392b" in win.readouts.labels["overlap"].styleSheet()  # white on red
        else:
            assert win.overlap_depth <= cell, shown  # seated: at most contact
            assert "into" not in shown, shown
            assert colour() == MOVING_COLOUR.lower()
        if text == "none":
            assert shown == "none" and win.overlap_depth == 0.0


# ------------------------------------------------------------------ parts list and undo
def test_the_parts_list_shows_each_part_and_hides_it_in_the_view(make_window):
    win = make_window(PEG, first_frame=False)
    panel = win.parts_panel
    handle = win.session.handle
    assert panel.rowCount() == 2
    for i, (part, spec) in enumerate(zip(handle.parts, handle.scene.parts, strict=True)):
        row = [panel.item(i, c).text() for c in range(1, panel.columnCount())]
        assert row[0] == part.name and row[1] == spec.file.name
        assert row[3] == f"{len(part.faces):,}"
        assert row[5] == ("moves" if i == 1 else "fixed")
    assert panel.item(0, 5).text() == "yes"  # the block is a closed mesh
    actors = win.viewport._actors
    panel.set_shown(0, False)
    assert not actors["fixed_block"].GetVisibility() and actors["moving"].GetVisibility()
    panel.set_shown(1, False)
    assert not actors["moving"].GetVisibility() and not actors["ghost_edges"].GetVisibility()
    panel.set_shown(0, True)
    panel.set_shown(1, True)
    assert actors["fixed_block"].GetVisibility() and actors["moving"].GetVisibility()


def test_watertight_needs_every_edge_twice():
    from app.gui.parts_panel import watertight

    tetra = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    assert watertight(tetra)
    assert not watertight(tetra[:3])  # one face missing: three edges used once


def test_ctrl_z_undoes_a_drag_and_typed_poses_and_ctrl_shift_z_redoes(make_window, qtbot,
                                                                       wait_until):
    from test_window import drag

    win = make_window(PEG)
    handle = win.session.handle
    start = np.asarray(handle.start_pose, float)
    win.pause_action.trigger()  # paused: the part stays where it is put, the ghost moves
    wait_until(lambda: win.latest_frame.paused, 5000, "a paused frame")

    def at(part, proxy, what):
        wait_until(lambda: np.allclose(win.latest_frame.part_pose, part, atol=1e-6)
                   and np.allclose(win.latest_frame.proxy_pose, proxy, atol=1e-6), 5000,
                   lambda: f"{what}: part {win.latest_frame.part_pose}, "
                           f"ghost {win.latest_frame.proxy_pose}")

    at(start, start, "the start")
    b = start + [3.0, 0, -2.0, 0, 0, 0.2]
    c = start + [-2.0, 1.0, 0, 0.1, 0, 0]
    win.show_pose_dialog()
    win.pose_dialog.place_part.emit(b)  # typed: part and ghost at b
    at(b, b, "placed at b")
    win.pose_dialog.move_proxy.emit(c)  # typed: the ghost to c, the part (paused) stays
    at(b, c, "the ghost at c")
    win.pose_dialog.hide()
    grab = win.viewport.moving_part_screen_position()
    drag(win.viewport.widget, grab, grab + QtCore.QPoint(40, 0))
    dragged = win.session.relative(win.viewport.proxy_pose)  # where the drag left the ghost
    assert not np.allclose(dragged, c, atol=1e-3)
    at(b, dragged, "the ghost dragged")
    win.activateWindow()
    win.viewport.widget.setFocus()
    qtbot.waitUntil(win.viewport.widget.hasFocus, timeout=5000)
    undo = QtGui.QKeySequence(QtGui.QKeySequence.Undo)[0]
    redo = QtGui.QKeySequence(QtGui.QKeySequence.Redo)[0]
    qtbot.keyClick(win.viewport.widget, undo.key(), undo.keyboardModifiers())
    at(b, c, "undo of the drag")
    qtbot.keyClick(win.viewport.widget, undo.key(), undo.keyboardModifiers())
    at(b, b, "undo of the typed ghost pose")
    qtbot.keyClick(win.viewport.widget, undo.key(), undo.keyboardModifiers())
    at(start, start, "undo of the placed part")
    qtbot.keyClick(win.viewport.widget, undo.key(), undo.keyboardModifiers())
    assert win.statusBar().currentMessage() == "nothing to undo"
    qtbot.keyClick(win.viewport.widget, redo.key(), redo.keyboardModifiers())
    at(b, b, "redo of the placed part")
    qtbot.keyClick(win.viewport.widget, redo.key(), redo.keyboardModifiers())
    qtbot.keyClick(win.viewport.widget, redo.key(), redo.keyboardModifiers())
    at(b, dragged, "redo of the drag")


# ------------------------------------------------------------------ cosmetics
def test_save_starts_in_the_users_folder_not_the_bundled_assets(make_window, tmp_path,
                                                                 monkeypatch):
    from pathlib import Path

    from PySide6 import QtWidgets

    win = make_window(PEG, first_frame=False)  # opened from assets/: the last folder
    assert Path(str(win.settings.value("last_dir"))) == PEG.parent.resolve()
    starts = []
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        staticmethod(lambda _w, _t, start, _f: (starts.append(start), ("", ""))[1]))
    win.save_dialog()
    assert Path(starts[-1]).parent == Path.home()
    assert Path(starts[-1]).name == "scene.toml"
    win.save_scene(tmp_path / "mine" / "fit.toml")
    win.save_dialog()
    assert Path(starts[-1]).parent == (tmp_path / "mine").resolve()
    win.screenshot_dialog()
    assert Path(starts[-1]) == (tmp_path / "mine").resolve() / "skelasm.png"


def test_long_progress_and_task_texts_stay_on_one_line_within_their_widgets(make_window,
                                                                           qtbot):
    win = make_window(PEG, first_frame=False)
    win.resize(1280, 800)
    long = ("preparing descriptors and correlation tables for a scene with many parts: "
            "23 %, about 13 s left")
    win.params.set_progress(0.23, long)
    bar = win.params.progress
    shown = bar.text()
    assert "…" in shown and shown.endswith("13 s left") and "\n" not in shown
    assert bar.fontMetrics().horizontalAdvance(shown) <= bar.contentsRect().width()
    assert bar.toolTip() == long and bar.format() == long
    win.tasks.start("open", long, reports_fraction=False)
    win.tasks.get("open").clock.started -= 5.0  # shown once a second old
    qtbot.waitUntil(lambda: long in win.status_task.text(), timeout=5000)
    qtbot.wait(50)
    assert win.status_task.width() <= 360
    assert win.status_task.toolTip() == win.status_task.text()
    win.statusBar().showMessage("a long message " * 20)
    assert win.statusBar().toolTip() == "a long message " * 20


def test_the_ghost_is_drawn_over_the_opaque_part(make_window, qtbot):
    from app.gui.viewport import GHOST_COLOUR, GHOST_LINES

    win = make_window(PEG)
    vp = win.viewport
    for key in GHOST_LINES:  # on the overlay layer: over every surface
        assert vp._overlay.HasViewProp(vp._actors[key]), key
        assert not vp.plotter.renderer.HasViewProp(vp._actors[key]), key
    blue = np.array([int(GHOST_COLOUR[i:i + 2], 16) for i in (1, 3, 5)])

    def ghost_pixels() -> int:
        vp.plotter.ren_win.Render()
        img = vp.plotter.screenshot(return_img=True).astype(int)
        return int((np.abs(img[..., :3] - blue).sum(axis=-1) < 60).sum())

    # the ghost sits on the part at the start: its outline shows over it
    shown = ghost_pixels()
    for key in GHOST_LINES:
        vp._actors[key].SetVisibility(False)
    hidden = ghost_pixels()
    assert shown > 300 and hidden < 0.1 * shown, (shown, hidden)


def test_the_open_dialog_shows_its_columns_whole(make_window, qtbot):
    from PySide6 import QtWidgets

    from app.gui.session import FILE_FILTER

    win = make_window(PEG, first_frame=False)
    win.resize(1280, 800)
    dialog = win.file_dialog("Open scene or part", str(PEG.parent), FILE_FILTER)
    view = dialog.findChild(QtWidgets.QTreeView)
    if view is None:
        pytest.skip("the platform's own file dialog is used here: Qt's columns do not apply")
    dialog.show()
    try:
        assert dialog.width() >= 820 and dialog.height() >= 520
        qtbot.waitUntil(lambda: view.model().rowCount(view.rootIndex()) >= 3, timeout=5000)
        qtbot.wait(100)
        header = view.header()
        for column in range(1, header.count()):  # size, type, date: as wide as their text
            if not header.isSectionHidden(column):
                assert header.sectionSize(column) >= view.sizeHintForColumn(column), column
    finally:
        dialog.close()
