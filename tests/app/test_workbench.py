"""The window as a workbench: keys that never take text from a field, a cancelled change
that puts the boxes back, a layout that keeps its views, a seat readout independent of K,
overshoot shown, a parts list with undo, and the cosmetics of a first hour.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore

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
