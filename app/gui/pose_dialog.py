"""Typing the proxy's pose: a small dialog with six fields.

The pose is part 2's, relative to part 1 and in part 1's frame, about its pivot (the scene's
``pivot``, else its centre of mass, as ``evaluate --pose`` reads a typed pose): the pivot's
displacement in the scene's unit and the rotation vector about it in degrees (axis times
angle), so a typed rotation turns the part in place, and an unturned pose reads as in the
scene file (``engine.pose.pivot_to_origin`` and ``origin_to_pivot`` convert). "Move the
ghost" sends it as the proxy's pose (the part follows under the forces); "Place the part"
puts part and proxy there at rest.
"""

from __future__ import annotations

import math

import numpy as np
from PySide6 import QtCore, QtWidgets

from app.gui.widgets import SignificantSpinBox
from engine import pose as posemath
from engine.params import DEFAULT_UNIT, MAX_POSE_TRANSLATION, MAX_ROTATION_VECTOR

#: Significant digits a pose field shows (its value is kept exactly).
POSE_DIGITS = 7


class PoseDialog(QtWidgets.QDialog):
    """Six fields for a pose relative to part 1.

    Signals
    -------
    move_proxy(object)
        (6,) float64 pose (radians) to send as the proxy's.
    place_part(object)
        (6,) float64 pose (radians) to put the part and proxy at, at rest.
    """

    move_proxy = QtCore.Signal(object)
    place_part = QtCore.Signal(object)

    def __init__(self, parent=None, *, unit: str = DEFAULT_UNIT, pivot=(0.0, 0.0, 0.0)):
        super().__init__(parent)
        self.pivot = np.asarray(pivot, float).reshape(3)
        self.setWindowTitle("Pose of the moving part")
        self.setModal(False)
        lay = QtWidgets.QVBoxLayout(self)
        note = QtWidgets.QLabel(
            "Part 2 relative to part 1, in part 1's frame: how far its centre (pivot) moved, "
            "and its rotation as axis × angle about that centre (as in the scene file when "
            "not turned).")
        note.setWordWrap(True)
        lay.addWidget(note)
        form = QtWidgets.QFormLayout()
        self.fields: list[QtWidgets.QDoubleSpinBox] = []
        for name in ("x", "y", "z", "rx", "ry", "rz"):
            # any pose a scene may hold, shown to POSE_DIGITS and kept exactly (a pose in
            # metres keeps its micrometres)
            box = SignificantSpinBox(POSE_DIGITS)
            box.setObjectName(f"pose_{name}")
            limit = (math.degrees(MAX_ROTATION_VECTOR) if name.startswith("r")
                     else MAX_POSE_TRANSLATION)
            box.setRange(-limit, limit)
            box.setKeyboardTracking(False)
            box.setSuffix(f" {unit}" if not name.startswith("r") else " °")
            form.addRow(name, box)
            self.fields.append(box)
        lay.addLayout(form)
        self.presets = QtWidgets.QHBoxLayout()
        lay.addLayout(self.presets)
        buttons = QtWidgets.QDialogButtonBox()
        self.move_button = buttons.addButton("Move the ghost", QtWidgets.QDialogButtonBox.ApplyRole)
        self.place_button = buttons.addButton("Place the part",
                                              QtWidgets.QDialogButtonBox.ActionRole)
        self.place_button.setToolTip("Put the part and the ghost there at rest, at once")
        buttons.addButton(QtWidgets.QDialogButtonBox.Close)
        buttons.rejected.connect(self.close)
        self.move_button.clicked.connect(lambda: self.move_proxy.emit(self.pose()))
        self.place_button.clicked.connect(lambda: self.place_part.emit(self.pose()))
        lay.addWidget(buttons)

    def add_preset(self, text: str, pose_source) -> None:
        """A button that fills the fields from ``pose_source()`` ((6,) origin pose)."""
        button = QtWidgets.QPushButton(text)
        button.clicked.connect(lambda: self.set_pose(pose_source()))
        self.presets.addWidget(button)

    def set_pose(self, pose: np.ndarray) -> None:
        """Show an origin pose (6,) (translation, rotation vector in radians) as a pivot pose."""
        p = posemath.origin_to_pivot(np.asarray(pose, float).reshape(6), self.pivot)
        shown = np.concatenate([p[:3], np.degrees(p[3:])])
        for box, value in zip(self.fields, shown, strict=True):
            box.setValue(float(value))

    def pose(self) -> np.ndarray:
        """(6,) float64 origin pose of what is typed (rotation vector in radians)."""
        v = np.array([box.value() for box in self.fields], float)
        return posemath.pivot_to_origin(np.concatenate([v[:3], np.radians(v[3:])]), self.pivot)
