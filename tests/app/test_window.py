"""The main window against the real engine (``engine.runtime``), under Xvfb or a real display."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app.gui.app import DEFAULT_SCENE as EXAMPLE_SCENE
from engine import pose as posemath
from engine import runtime


def _mouse(widget, kind, pos, buttons, modifiers=QtCore.Qt.NoModifier, button=None):
    p = QtCore.QPointF(pos)
    g = QtCore.QPointF(widget.mapToGlobal(pos))
    event = QtGui.QMouseEvent(kind, p, g, button if button is not None else QtCore.Qt.NoButton,
                              buttons, modifiers)
    QtWidgets.QApplication.sendEvent(widget, event)


def drag(widget, start: QtCore.QPoint, end: QtCore.QPoint, steps: int = 10,
         modifiers=QtCore.Qt.NoModifier) -> None:
    """A left-button drag as the user does it: press, several moves, release."""
    left = QtCore.Qt.LeftButton
    _mouse(widget, QtCore.QEvent.MouseButtonPress, start, left, modifiers, left)
    for k in range(1, steps + 1):
        p = start + (end - start) * (k / steps)
        _mouse(widget, QtCore.QEvent.MouseMove, p, left, modifiers)
        QtWidgets.QApplication.processEvents()
    _mouse(widget, QtCore.QEvent.MouseButtonRelease, end, QtCore.Qt.NoButton, modifiers, left)


def test_window_opens_on_the_example_scene(make_window, settings):
    win = make_window(EXAMPLE_SCENE)
    assert "Peg in hole" in win.windowTitle()
    assert win.session.engine is not None and win.session.engine.running
    actors = win.viewport._actors
    assert {"moving", "ghost", "fixed_block", "force", "torque"} <= set(actors)
    # the 3D view shows the parts: its pixels are far from one flat background colour
    img = win.viewport.plotter.screenshot(return_img=True)
    assert img.std() > 10
    # a scene that opened is remembered
    assert win.recent_files()[0] == str(EXAMPLE_SCENE.resolve())
    assert win.recent_menu.actions()[0].toolTip() == str(EXAMPLE_SCENE.resolve())


def test_mouse_drag_moves_the_proxy_and_the_part_follows(make_window, wait_until):
    win = make_window(EXAMPLE_SCENE)
    vp = win.viewport
    # the peg's scene gives an insertion axis, which drags then follow: here, a free drag
    assert vp.constraint == "insertion"
    win.set_constraint("free")
    start_proxy = np.asarray(win.latest_frame.proxy_pose).copy()
    start_part = np.asarray(win.latest_frame.part_pose).copy()
    grab = vp.moving_part_screen_position()
    assert vp.pick_moving(QtCore.QPointF(grab)), "the moving part is not under its centre"
    basis = vp._camera_basis()  # right, up, back in world coordinates
    drag(vp.widget, grab, grab + QtCore.QPoint(80, 0))
    assert not vp.dragging
    # the engine got the new proxy: it moved to the screen's right, not up or towards us
    wait_until(lambda: np.linalg.norm(win.latest_frame.proxy_pose[:3] - start_proxy[:3]) > 1,
               5000, "the engine's proxy to move")
    r1 = win.session.part1_rotation()
    moved = r1 @ (np.asarray(win.latest_frame.proxy_pose[:3]) - start_proxy[:3])
    along = basis.T @ moved
    assert along[0] > 0.9 * np.linalg.norm(moved)
    # and the part follows the proxy through the coupling (over the peg's free space)
    wait_until(
        lambda: np.linalg.norm(win.latest_frame.part_pose[:3] - start_part[:3])
        > 0.8 * np.linalg.norm(moved), 10000, "the part to follow the proxy")
    assert np.dot(win.latest_frame.part_pose[:3] - start_part[:3], r1.T @ basis[:, 0]) > 0
    # a drag away from the part turns the camera and leaves the proxy alone
    proxy = win.session.relative(vp.proxy_pose)  # where the drag left it
    wait_until(lambda: np.allclose(win.latest_frame.proxy_pose, proxy, atol=1e-9), 5000,
               "the engine's proxy to reach the end of the drag")
    camera = np.array(vp.plotter.camera.position)
    corner = QtCore.QPoint(10, vp.widget.height() - 10)
    assert not vp.pick_moving(QtCore.QPointF(corner))
    drag(vp.widget, corner, corner + QtCore.QPoint(40, -40))
    n = win.frames_received
    wait_until(lambda: win.frames_received > n + 5, 5000, "more frames")
    assert np.allclose(win.latest_frame.proxy_pose, proxy, atol=1e-9)
    assert not np.allclose(vp.plotter.camera.position, camera)


def test_ctrl_drag_rotates_and_shift_drag_moves_in_depth(make_window, wait_until):
    win = make_window(EXAMPLE_SCENE)
    vp = win.viewport
    win.set_constraint("free")
    grab = vp.moving_part_screen_position()
    seen = []
    vp.proxy_dragged.connect(lambda pose: seen.append(np.asarray(pose)))
    start = vp.proxy_pose
    drag(vp.widget, grab, grab + QtCore.QPoint(60, 0), modifiers=QtCore.Qt.ControlModifier)
    turned = seen[-1]
    angle = np.linalg.norm(posemath.rotation_vector(
        posemath.rotation_matrix(turned[3:]) @ posemath.rotation_matrix(start[3:]).T))
    assert angle > np.radians(5)
    # about the camera's up axis (a horizontal arcball drag)
    up = vp._camera_basis()[:, 1]
    rv = posemath.rotation_vector(posemath.rotation_matrix(turned[3:])
                                  @ posemath.rotation_matrix(start[3:]).T)
    assert abs(np.dot(rv / np.linalg.norm(rv), up)) > 0.95
    seen.clear()
    wait_until(lambda: not vp.dragging, 1000, "the drag to end")
    grab = vp.moving_part_screen_position()
    before = vp.proxy_pose
    drag(vp.widget, grab, grab + QtCore.QPoint(0, -50), modifiers=QtCore.Qt.ShiftModifier)
    delta = seen[-1][:3] - before[:3]
    back = vp._camera_basis()[:, 2]
    assert np.dot(delta, back) > 0.95 * np.linalg.norm(delta) > 0


def test_opening_a_corrupt_file_shows_an_error_and_the_session_goes_on(
        make_window, tmp_path, wait_until):
    win = make_window(EXAMPLE_SCENE)
    handle = win.session.handle
    bad_part = tmp_path / "broken.stl"
    bad_part.write_bytes(b"solid broken\n facet normal 0 0 1\n  outer loop\n garbage\n")
    bad_scene = tmp_path / "broken.toml"
    bad_scene.write_text('name = "x"\n[[part]]\nname = 3\nfile = \n')
    for bad in (bad_part, bad_scene, tmp_path / "missing.step", tmp_path / "notes.txt"):
        (tmp_path / "notes.txt").write_text("not a part")
        win.last_error = None
        win.open_path(bad)  # in the background, as from the menu
        wait_until(lambda: win.last_error is not None, 15000, f"an error for {bad.name}")
        assert bad.name in win.last_error
        assert win.error_dialog is not None and win.error_dialog.isVisible()
        assert win.statusBar().currentMessage()
        win.error_dialog.close()
        # nothing lost: the same scene, its engine still running and publishing
        assert win.session.handle is handle and win.session.engine.running
        n = win.frames_received
        wait_until(lambda n=n: win.frames_received > n + 5, 5000, "frames after the error")


def test_part_file_becomes_the_moving_part(make_window, tmp_path, wait_until):
    import trimesh

    from engine.scene import load_scene

    win = make_window(EXAMPLE_SCENE)
    # drawn beside the block, as a file of the same assembly draws it: it starts there
    post = trimesh.creation.box(extents=(4, 4, 10))
    post.apply_translation((100.0, 0.0, 0.0))
    post.export(tmp_path / "post.stl")
    win.open_path(tmp_path / "post.stl")
    # opening a pair measures its fit (2 s here, 10 s on a loaded machine): a generous wait
    wait_until(lambda: win.session.handle.parts[1].name == "post", 60000, "the new part")
    assert win.session.handle.parts[0].name == "block"
    assert len(win.session.handle.parts[1].faces) == 12
    np.testing.assert_allclose(win.session.handle.start_pose, np.zeros(6), atol=1e-12)
    assert "where its file draws it" in win.statusBar().currentMessage()
    # the peg's seat, axis and free axes are not the new pair's: its seat is as drawn
    scene = win.session.handle.scene
    np.testing.assert_array_equal(scene.assembled_pose, np.zeros(6))
    assert scene.insertion_axis is None and scene.seat.free_axes is None
    wait_until(lambda: win.latest_frame is not None, 10000, "frames of the new scene")
    wait_until(lambda: "where the two files draw" in win.seat_detail.text(), 10000,
               "the seat readout to say the seat is the drawn placement")
    # drawn through the block's body (centred on its own origin): parked above the block
    trimesh.creation.box(extents=(40, 40, 10)).export(tmp_path / "slab.stl")
    win.open_path(tmp_path / "slab.stl")
    wait_until(lambda: win.session.handle.parts[1].name == "slab", 60000, "the slab")
    handle = win.session.handle
    assert "starts above it" in win.statusBar().currentMessage()
    top = handle.parts[0].vertices[:, 2].max()
    assert handle.start_pose[2] + handle.parts[1].vertices[:, 2].min() > top
    # the generated scene holds that start, so Save keeps it
    saved = load_scene(handle.path)
    np.testing.assert_allclose(saved.parts[1].pose, handle.scene.parts[1].pose)


def test_a_scene_that_finishes_loading_after_close_starts_no_engine(small_scene, qtbot):
    # a worker's answer queued before close() used to start an engine nobody would stop
    from app.gui.session import Session

    session = Session()
    handle = runtime.open_scene(small_scene)
    session.close()
    session._loaded.emit(handle, None, str(small_scene))  # the queued answer arrives
    qtbot.wait(20)
    assert session.engine is None and session.handle is None


def test_layout_and_recent_files_are_remembered(make_window, settings, qtbot):
    from app.gui.main_window import MainWindow

    win = make_window(EXAMPLE_SCENE, first_frame=False)
    win.dock_landscape.hide()
    win.resize(1200, 800)
    win.close()
    again = MainWindow(settings=settings)
    qtbot.addWidget(again)
    again.show()
    try:
        assert not again.dock_landscape.isVisible() and again.dock_slice.isVisible()
        assert again.size() == QtCore.QSize(1200, 800)
        assert again.recent_files() == [str(EXAMPLE_SCENE.resolve())]
    finally:
        again.close()


def test_save_scene_writes_the_current_pose(make_window, tmp_path, wait_until):
    from engine.scene import load_scene

    win = make_window(EXAMPLE_SCENE)
    target = np.asarray(win.latest_frame.part_pose) + [3.0, 0, 0, 0, 0, 0]
    win.session.send(runtime.SetProxyPose(tuple(target)))
    wait_until(lambda: abs(win.latest_frame.part_pose[0] - target[0]) < 0.3, 10000,
               "the part to reach the new proxy")
    win.params.modes.setValue(12)
    out = win.save_scene(tmp_path / "sub" / "saved")
    assert out.suffix == ".toml"
    scene = load_scene(out)
    assert [p.name for p in scene.parts] == ["block", "peg"]
    saved_rel = posemath.relative_pose(scene.parts[0].pose, scene.parts[1].pose)
    assert np.allclose(saved_rel, win.latest_frame.part_pose, atol=0.3)
    assert scene.modes == 12
    assert scene.parts[1].file.exists()  # paths rewritten relative to the new place


def test_saving_never_replaces_a_part_file_and_a_dialog_never_raises(make_window, tmp_path,
                                                                      monkeypatch):
    win = make_window(EXAMPLE_SCENE)
    part = win.session.handle.scene.parts[0].file
    before = part.read_bytes()
    # a screenshot aimed at a part file (the dialog already asked "replace?") is refused
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        staticmethod(lambda *a, **k: (str(part), "")))
    win.screenshot_dialog()  # a slot: shows the error, raises nothing
    assert part.read_bytes() == before
    assert "screenshot" in win.last_error and str(part.name) in win.last_error
    # a scene saved into a folder that cannot be made: an error shown, nothing raised
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setattr(QtWidgets.QFileDialog, "getSaveFileName",
                        staticmethod(lambda *a, **k: (str(blocker / "sub" / "s.toml"), "")))
    win.last_error = ""
    win.save_dialog()
    assert "Could not save the scene" in win.last_error
    # a real screenshot is a whole PNG, written through a temporary file
    out = win.save_screenshot(tmp_path / "shot.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert QtGui.QImage(str(out)).width() > 100
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def _drag_enter(pos: QtCore.QPointF, mime: QtCore.QMimeData) -> QtGui.QDragEnterEvent:
    """A drag-enter event at ``pos``: PySide6 6.12 takes a float point (its integer one is
    deprecated), 6.11 and earlier only an integer one.
    """
    args = (QtCore.Qt.CopyAction, mime, QtCore.Qt.LeftButton, QtCore.Qt.NoModifier)
    try:
        return QtGui.QDragEnterEvent(pos, *args)
    except TypeError:
        return QtGui.QDragEnterEvent(pos.toPoint(), *args)


def test_dropping_a_file_on_the_window_opens_it(make_window, small_scene, wait_until):
    win = make_window(EXAMPLE_SCENE)
    mime = QtCore.QMimeData()
    mime.setUrls([QtCore.QUrl.fromLocalFile(str(small_scene))])
    pos = QtCore.QPointF(win.width() / 2, win.height() / 2)
    enter = _drag_enter(pos, mime)
    QtWidgets.QApplication.sendEvent(win, enter)
    assert enter.isAccepted()
    drop = QtGui.QDropEvent(pos, QtCore.Qt.CopyAction, mime, QtCore.Qt.LeftButton,
                            QtCore.Qt.NoModifier)
    QtWidgets.QApplication.sendEvent(win, drop)
    wait_until(lambda: "Small test scene" in win.windowTitle(), 20000, "the dropped scene")
    # a file of an unknown kind is not accepted
    mime.setUrls([QtCore.QUrl.fromLocalFile(str(small_scene.with_suffix(".txt")))])
    enter = _drag_enter(pos, mime)
    enter.ignore()
    QtWidgets.QApplication.sendEvent(win, enter)
    assert not enter.isAccepted()


def test_space_pauses_the_engine(make_window, wait_until, qtbot):
    win = make_window(EXAMPLE_SCENE)
    win.viewport.widget.setFocus()
    win.pause_action.trigger()
    assert win.params.pause.isChecked()
    wait_until(lambda: win.latest_frame.paused, 5000, "a paused frame")
    step = win.latest_frame.step
    qtbot.wait(300)
    assert win.latest_frame.step == step  # paused: frames keep coming, steps do not
    win.params.pause.click()  # the panel's button resumes, and the menu follows
    assert not win.pause_action.isChecked()
    wait_until(lambda: win.latest_frame.step > step, 5000, "steps after resuming")


def test_the_window_shows_the_settings_chosen_from_the_parts(make_window, tmp_path,
                                                              wait_until):
    """A scene that leaves the grid and K to the engine: the window lists the choices."""
    import trimesh

    plate = trimesh.creation.box(extents=(20, 20, 3))
    plate.apply_translation((0, 0, -1.5))
    plate.export(tmp_path / "plate.stl")
    block = trimesh.creation.box(extents=(8, 8, 8))
    block.apply_translation((0, 0, 4))
    block.export(tmp_path / "block.stl")
    (tmp_path / "scene.toml").write_text(
        'name = "Chosen"\nunits = "mm"\nassembled_pose = [0, 0, 0, 0, 0, 0]\n'
        'insertion_axis = [0, 0, -1]\n\n'
        '[[part]]\nname = "plate"\nfile = "plate.stl"\npose = [0, 0, 0, 0, 0, 0]\n'
        "fixed = true\n\n"
        '[[part]]\nname = "block"\nfile = "block.stl"\npose = [0, 0, 8, 0, 0, 0]\n')
    win = make_window(tmp_path / "scene.toml")
    wait_until(lambda: win.session.handle is not None, 20000, "the scene")
    chosen = win.session.handle.scene.chosen
    assert [key for key, _, _ in chosen] == ["descriptor.spacing", "correlation.modes",
                                             "descriptor.sigma", "descriptor.penalty",
                                             "descriptor.padding"]
    tip = win.params.toolTip()
    assert "correlation.modes = " in tip and "chosen, " in tip
