"""The GUI's pure pieces: cross-sections, arcball, colour maps, strip chart, slider field."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.gui import colourmap, geometry
from app.gui.slice_view import slice_values
from engine import pose as posemath


def test_cube_section_is_its_square_outline():
    cube = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    seg = geometry.section_segments(cube.vertices, cube.faces, "z", 0.3)
    # every end point lies on the plane and on the square's boundary
    assert seg.shape[1:] == (2, 3) and len(seg) >= 4
    assert np.allclose(seg[..., 2], 0.3)
    pts = seg.reshape(-1, 3)
    assert np.allclose(np.max(np.abs(pts[:, :2]), axis=1), 1.0)
    # and the segments add up to the perimeter (2 + 2 + 2 + 2)
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1).sum()
    assert length == pytest.approx(8.0)


def test_section_outside_the_mesh_is_empty():
    cube = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    assert geometry.section_segments(cube.vertices, cube.faces, 0, 1.5).shape == (0, 2, 3)
    with pytest.raises(ValueError, match="valid: x, y, z"):
        geometry.section_segments(cube.vertices, cube.faces, "w", 0.0)


def test_arcball_rotation_turns_v0_into_v1():
    rng = np.random.default_rng(3)
    for _ in range(20):
        v0, v1 = rng.normal(size=(2, 3))
        v0 /= np.linalg.norm(v0)
        v1 /= np.linalg.norm(v1)
        r = posemath.rotation_matrix(geometry.arcball_rotation(v0, v1))
        assert np.allclose(r @ v0, v1, atol=1e-9)


def test_arcball_vector_is_on_the_unit_sphere_and_centred():
    assert np.allclose(geometry.arcball_vector(50, 50, 50, 50, 10), [0, 0, 1])
    for x, y in ((55, 52), (200, -40)):
        assert np.linalg.norm(geometry.arcball_vector(x, y, 50, 50, 10)) == pytest.approx(1.0)


def test_rotate_about_keeps_the_centre_fixed():
    """The drag's rotation (engine.pose.rotate_about, which the 3D view calls) turns about the
    centre it is given.
    """
    pose = np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3])
    centre = np.array([0.5, -1.0, 2.0])
    rv = np.array([0.0, 0.0, np.pi / 2])
    out = posemath.rotate_about(pose, rv, centre)
    # a point at the centre stays put; a point one unit along x goes to one unit along y
    m_in, m_out = posemath.pose_to_matrix(pose), posemath.pose_to_matrix(out)
    q_centre = np.linalg.solve(m_in, np.append(centre, 1.0))
    assert np.allclose(m_out @ q_centre, np.append(centre, 1.0))
    q_x = np.linalg.solve(m_in, np.append(centre + [1, 0, 0], 1.0))
    assert np.allclose((m_out @ q_x)[:3], centre + [0, 1, 0])


def test_colourmap_diverging_is_centred():
    lut = colourmap.table("diverging")
    assert lut.shape == (256, 3) and lut.dtype == np.uint8
    rgb = colourmap.apply(np.array([[-1.0, 0.0, 1.0]]), -1.0, 1.0, lut)
    assert rgb[0, 0, 2] > rgb[0, 0, 0]  # negative: blue
    assert rgb[0, 2, 0] > rgb[0, 2, 2]  # positive: red
    assert np.ptp(rgb[0, 1].astype(int)) < 10  # zero: grey
    with pytest.raises(ValueError, match="valid: diverging, sequential"):
        colourmap.table("rainbow")


def test_symmetric_range_ignores_medial_axis_spikes():
    values = np.concatenate([np.linspace(-1, 1, 1000), [500.0]])
    lo, hi = colourmap.symmetric_range(values)
    assert lo == -hi and 0.9 < hi < 1.1


def test_slice_values_components():
    rho = (np.arange(24).reshape(2, 3, 4) + 1j * -np.arange(24).reshape(2, 3, 4))
    rho = rho.astype(np.complex64)
    assert np.array_equal(slice_values(rho, 1, 2, "real"), rho[:, 2, :].real)
    assert np.array_equal(slice_values(rho, 0, 1, "imaginary"), rho[1].imag)
    assert np.allclose(slice_values(rho, 2, 3, "magnitude"), np.abs(rho[:, :, 3]))
    with pytest.raises(ValueError, match="valid: imaginary, real, magnitude"):
        slice_values(rho, 0, 0, "phase")


def test_strip_chart_keeps_the_last_seconds(qtbot):
    from app.gui.strip_chart import StripChart

    chart = StripChart(seconds=2.0, capacity=50)
    qtbot.addWidget(chart)
    for i in range(100):
        chart.add(0.1 * i, -i, 2 * i, 3 * i)
    t, v = chart.samples()
    assert t[-1] == pytest.approx(9.9) and t[0] >= 9.9 - 2.0
    i = np.round(t * 10)
    assert np.array_equal(v[:, 0], -i) and np.array_equal(v[:, 1], 2 * i)
    assert np.array_equal(v[:, 2], 3 * i)
    chart.resize(300, 120)
    chart.show()
    img = chart.grab().toImage()
    assert img.width() == 300


def test_slider_field_log_mapping_and_signal(qtbot):
    from app.gui.widgets import SliderField
    from engine.params import ControlRange

    field = SliderField(ControlRange(allowed=(1e-3, 1e3), comfortable=(0.01, 100.0),
                                     default=1.0, step=0.1, log=True))
    qtbot.addWidget(field)
    assert field.slider.value() == 500  # 1 is the geometric middle of [0.01, 100]
    seen = []
    field.valueChanged.connect(seen.append)
    field.slider.setValue(750)
    assert seen and seen[-1] == pytest.approx(10.0)
    field.setValueSilently(0.1)
    assert len(seen) == 1 and field.slider.value() == 250
    # beyond the slider's stretch: kept and shown, the slider at its end
    field.setValueSilently(500.0)
    assert field.value() == 500.0 and field.field.value() == pytest.approx(500.0)
    assert field.slider.value() == field.slider.maximum() and len(seen) == 1
    field.setValue(5e4)  # a typed value is held to what the control allows
    assert field.value() == 1e3
    with pytest.raises(ValueError):
        ControlRange(allowed=(0.0, 1.0), comfortable=(0.0, 1.0), default=0.5, step=0.1,
                     log=True)


def test_strip_chart_range_does_not_magnify_jitter():
    from app.gui.strip_chart import value_range

    # a resting part: energy -20166 +- 2 spans 2 % of its size, centred on the values
    lo, hi = value_range(np.array([-20168.0, -20166.0, -20164.0]))
    assert hi - lo == pytest.approx(0.02 * 20168.0)
    assert (lo + hi) / 2 == pytest.approx(-20166.0)
    # a real change keeps its own span
    assert value_range(np.array([-20000.0, 0.0, 500.0])) == (-20000.0, 500.0)
    # all zero (parts apart): still a non-empty range
    lo, hi = value_range(np.zeros(5))
    assert hi > lo


def test_a_stale_wrapper_for_a_docks_action_is_dropped_and_asked_again(qtbot):
    """PySide6 once handed back a dock's show/hide action as a dead object's wrapper of
    another type (a ``QSurface``): the menu is built from the action asked for again.
    """
    import shiboken6
    from PySide6 import QtCore, QtGui, QtWidgets

    from app.gui.main_window import toggle_view_action

    win = QtWidgets.QMainWindow()
    qtbot.addWidget(win)
    dock = QtWidgets.QDockWidget("Slice", win)
    real = dock.toggleViewAction()
    other = QtWidgets.QMainWindow()
    qtbot.addWidget(other)
    stale = other.statusBar()  # made by Qt, as the render surface's was: a wrapper that
    answers = [stale, real]  # invalidating drops from the binding's map
    dock.toggleViewAction = lambda: answers.pop(0)
    action = toggle_view_action(dock)
    assert action is real and isinstance(action, QtGui.QAction)
    assert not shiboken6.isValid(stale) and not answers
    fresh = other.statusBar()  # the next lookup at that address makes a new wrapper
    assert fresh is not stale and shiboken6.isValid(fresh)

    dock.toggleViewAction = QtCore.QObject  # always the wrong type: a clear error
    with pytest.raises(TypeError, match="'Slice' panel's show/hide action came back as QObject"):
        toggle_view_action(dock)


def test_the_pose_dialog_keeps_any_pose_a_scene_may_hold(qtbot):
    """Fields hold the engine's whole pose range and keep a value exactly (no 4 decimals)."""
    from app.gui.pose_dialog import PoseDialog
    from engine.params import MAX_POSE_TRANSLATION, MAX_ROTATION_VECTOR

    dialog = PoseDialog(unit="m")
    qtbot.addWidget(dialog)
    pose = np.array([2.5e-5, -1.2345678e-3, 0.0, 0.0, 0.0, 1.0e-4])  # micrometres, in m
    dialog.set_pose(pose)
    np.testing.assert_allclose(dialog.pose(), pose, rtol=0, atol=1e-15)
    assert dialog.fields[0].text() == "2.5e-05 m"
    far = np.array([3e7, 0.0, 0.0, 0.0, 0.0, 0.0])  # beyond the old ±1e6 fields
    dialog.set_pose(far)
    np.testing.assert_allclose(dialog.pose(), far, rtol=1e-15)
    assert dialog.fields[0].maximum() == MAX_POSE_TRANSLATION
    assert dialog.fields[3].maximum() == pytest.approx(np.degrees(MAX_ROTATION_VECTOR))
