"""Setting a scene's fit up in the window: assembled pose, insertion axis, free axes, tolerance.

What ``skelasm scene new`` and the scene file's top keys say, set in a dialog (Scene > Set up
the fit…):

- the **assembled pose**: part 2 relative to part 1 when seated, as the scene file writes it
  (its file origin's displacement and rotation vector in degrees); typed, or "Current pose"
  (where part 2 is now);
- the **insertion axis**: typed, "View direction" (into the screen, part 1's frame), or
  "Picked face" (the axis of a bore's wall, a shaft's side or a flat face clicked in the 3D
  view: :func:`engine.scene.face_axis.face_axis`);
- the **free axes**: ticked, or "Measure" (the joint the parts' motions allow at the assembled
  pose typed, :func:`engine.search.joint.motion_joint`);
- the **seat tolerance**: a distance (0: 2 % of part 2's size) and an angle.

"Apply and save" hands a :class:`app.gui.scene_file.FitSetup` to the window, which writes
the scene with it and opens it again (the engine then seats the part on the new fit).
"""

from __future__ import annotations

import math

import numpy as np
from PySide6 import QtCore, QtWidgets

from app.gui.pose_dialog import POSE_DIGITS
from app.gui.scene_file import FitSetup
from app.gui.widgets import SignificantSpinBox
from engine.params import AXES, MAX_POSE_TRANSLATION, MAX_ROTATION_VECTOR


class FitDialog(QtWidgets.QDialog):
    """The fit's settings (see the module docstring).

    Signals
    -------
    applied(object)
        The :class:`FitSetup` to write into the scene.
    """

    applied = QtCore.Signal(object)

    def __init__(self, parent=None, *, unit: str, current_pose, view_direction, measure,
                 pick_face=None):
        """The dialog, with the window's callbacks.

        ``current_pose()``: part 2's pose now (origin pose, radians); ``view_direction()``:
        a unit vector into the screen in part 1's frame; ``measure(pose)``: the free axes'
        names at that origin pose (None where the parts do not meet), and a line on it;
        ``pick_face(done)``: lets the user click a face, then calls ``done(axis, line)`` (the
        axis in part 1's frame, or None, and a line on what was found).
        """
        super().__init__(parent)
        self.setWindowTitle("Set up the fit")
        self.setModal(False)
        self._current, self._view, self._measure = current_pose, view_direction, measure
        lay = QtWidgets.QVBoxLayout(self)
        form = QtWidgets.QFormLayout()
        self.pose_fields = [self._box(n, unit) for n in ("x", "y", "z", "rx", "ry", "rz")]
        row = QtWidgets.QHBoxLayout()
        for box in self.pose_fields:
            row.addWidget(box)
        current = QtWidgets.QPushButton("Current pose")
        current.setToolTip("Where part 2 is now, relative to part 1")
        current.clicked.connect(lambda: self.set_assembled(self._current()))
        row.addWidget(current)
        form.addRow(f"assembled pose ({unit}, deg)", row)
        self.axis_fields = []
        row = QtWidgets.QHBoxLayout()
        for name in ("x", "y", "z"):
            box = QtWidgets.QDoubleSpinBox()
            box.setObjectName(f"fit_axis_{name}")
            box.setRange(-1.0, 1.0)
            box.setDecimals(4)
            box.setSingleStep(0.1)
            self.axis_fields.append(box)
            row.addWidget(box)
        view = QtWidgets.QPushButton("View direction")
        view.setToolTip("Into the screen, as the view looks now (part 1's frame)")
        view.clicked.connect(lambda: self.set_axis(self._view()))
        row.addWidget(view)
        self._pick = pick_face
        picked = QtWidgets.QPushButton("Picked face")
        picked.setObjectName("fit_pick_face")
        picked.setToolTip("Then click a bore's wall, a shaft's side or a flat face in the 3D "
                          "view: its axis, pointing the way part 2 goes to it")
        picked.setEnabled(pick_face is not None)
        picked.clicked.connect(self._pick_face)
        row.addWidget(picked)
        form.addRow("insertion axis", row)
        self.free = {}
        row = QtWidgets.QHBoxLayout()
        for name in AXES:
            check = QtWidgets.QCheckBox(name)
            check.setObjectName(f"fit_free_{name}")
            self.free[name] = check
            row.addWidget(check)
        measure_button = QtWidgets.QPushButton("Measure")
        measure_button.setToolTip("The motions the parts allow at the assembled pose above: "
                                  "slides and turns that keep part 2 out of part 1")
        measure_button.clicked.connect(self._measured)
        row.addWidget(measure_button)
        form.addRow("free axes", row)
        self.distance = QtWidgets.QDoubleSpinBox()
        self.distance.setObjectName("fit_seat_distance")
        self.distance.setRange(0.0, 1e6)
        self.distance.setDecimals(4)
        self.distance.setSuffix(f" {unit}")
        self.distance.setSpecialValueText("2 % of part 2's size")
        self.degrees = QtWidgets.QDoubleSpinBox()
        self.degrees.setObjectName("fit_seat_degrees")
        self.degrees.setRange(0.01, 45.0)
        self.degrees.setSuffix(" deg")
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.distance)
        row.addWidget(self.degrees)
        form.addRow("seat tolerance", row)
        lay.addLayout(form)
        self.note = QtWidgets.QLabel("Apply and save writes these into the scene file and "
                                     "opens it again.")
        self.note.setObjectName("fit_note")
        self.note.setWordWrap(True)
        lay.addWidget(self.note)
        buttons = QtWidgets.QDialogButtonBox()
        apply = buttons.addButton("Apply and save", QtWidgets.QDialogButtonBox.AcceptRole)
        apply.setObjectName("fit_apply")
        buttons.addButton(QtWidgets.QDialogButtonBox.Close)
        buttons.accepted.connect(self._apply)
        buttons.rejected.connect(self.close)
        lay.addWidget(buttons)

    @staticmethod
    def _box(name: str, unit: str) -> SignificantSpinBox:
        box = SignificantSpinBox(POSE_DIGITS)
        box.setObjectName(f"fit_pose_{name}")
        limit = (math.degrees(MAX_ROTATION_VECTOR) if name.startswith("r")
                 else MAX_POSE_TRANSLATION)
        box.setRange(-limit, limit)
        box.setToolTip(f"{name} ({'deg, rotation vector' if name.startswith('r') else unit})")
        return box

    # ------------------------------------------------------------------ values
    def set_scene(self, scene) -> None:
        """Show ``scene``'s fit (an ``engine.scene.Scene``)."""
        self.set_assembled(np.asarray(scene.assembled_pose, float))
        self.set_axis(scene.insertion_axis)
        for name, check in self.free.items():
            check.setChecked(name in (scene.seat.free_axes or ()))
        self.distance.setValue(scene.seat.distance or 0.0)
        self.degrees.setValue(scene.seat.angle_deg)

    def set_assembled(self, pose) -> None:
        """Show an origin pose (translation, rotation vector in radians)."""
        p = np.asarray(pose, float).reshape(6)
        for box, value in zip(self.pose_fields, [*p[:3], *np.degrees(p[3:])], strict=True):
            box.setValue(float(value))

    def set_axis(self, axis) -> None:
        """Show a direction (normalised), or zeros for none."""
        a = np.zeros(3) if axis is None else np.asarray(axis, float).reshape(3)
        n = float(np.linalg.norm(a))
        for box, value in zip(self.axis_fields, a / n if n > 0 else a, strict=True):
            box.setValue(float(value))

    def assembled(self) -> np.ndarray:
        """The typed assembled pose (translation, rotation vector in radians)."""
        v = np.array([box.value() for box in self.pose_fields], float)
        return np.concatenate([v[:3], np.radians(v[3:])])

    def setup(self) -> FitSetup:
        """What the dialog holds."""
        axis = np.array([box.value() for box in self.axis_fields], float)
        n = float(np.linalg.norm(axis))
        return FitSetup(
            assembled_pose=tuple(float(v) for v in self.assembled()),
            insertion_axis=None if n == 0 else tuple(float(v) for v in axis / n),  # type: ignore[arg-type]
            free_axes=tuple(name for name, check in self.free.items() if check.isChecked()),
            seat_distance=self.distance.value() or None,
            seat_degrees=float(self.degrees.value()))

    def _pick_face(self) -> None:
        self.note.setText("Click a bore's wall, a shaft's side or a flat face in the 3D view.")
        self._pick(self._face_picked)

    def _face_picked(self, axis, line: str) -> None:
        if axis is not None:
            self.set_axis(axis)
        self.note.setText(line)

    def _measured(self) -> None:
        names, line = self._measure(self.assembled())
        if names is not None:
            for name, check in self.free.items():
                check.setChecked(name in names)
        self.note.setText(line)

    def _apply(self) -> None:
        self.applied.emit(self.setup())
