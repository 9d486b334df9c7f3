"""How the fixed part is drawn: its opacity, and a plane that cuts it open.

A small group of controls; it only emits what the user chose and keeps no scene state (the
3D view applies it: :meth:`app.gui.viewport.Viewport.set_fixed_opacity` and ``set_clip``).
"""

from __future__ import annotations

from PySide6 import QtCore, QtWidgets


class ViewPanel(QtWidgets.QGroupBox):
    """Opacity of the fixed part and a clipping plane through it.

    Signals
    -------
    opacity_changed(float)
        0.05 (nearly clear) to 1 (solid).
    clip_changed(object)
        ``(axis, fraction, side)``: cut normal to axis 0, 1, 2 of part 1's frame at that
        fraction of the part's extent, removing the ``side`` (+1 or -1) of the plane; None:
        no cut.
    """

    opacity_changed = QtCore.Signal(float)
    clip_changed = QtCore.Signal(object)

    def __init__(self, parent=None):
        super().__init__("Fixed part", parent)
        form = QtWidgets.QFormLayout(self)
        self.opacity = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.opacity.setObjectName("fixed_opacity")
        self.opacity.setRange(5, 100)
        self.opacity.setValue(100)
        self.opacity.setToolTip("Make the fixed part see-through, to watch the moving part "
                                "inside it")
        self.opacity_label = QtWidgets.QLabel("100 %")
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.opacity, 1)
        row.addWidget(self.opacity_label)
        form.addRow("opacity", row)
        self.clip = QtWidgets.QCheckBox("cut open")
        self.clip.setToolTip("Cut the fixed part by a plane and remove one side, to see "
                             "into a hole")
        self.clip_axis = QtWidgets.QComboBox()
        self.clip_axis.setToolTip("The side removed (axes of part 1's frame); −y faces the "
                                  "default camera")
        self.clip_axis.addItems([f"remove {s}{a} side" for a in "xyz" for s in "−+"])
        self.clip_axis.setCurrentIndex(2)  # -y: towards the default (isometric) camera
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.clip)
        row.addWidget(self.clip_axis)
        form.addRow("plane", row)
        self.clip_position = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.clip_position.setObjectName("clip_position")
        self.clip_position.setRange(0, 100)
        self.clip_position.setValue(50)
        self.clip_position.setToolTip("Where the plane cuts, across the fixed part's extent")
        form.addRow("at", self.clip_position)
        self.opacity.valueChanged.connect(self._opacity)
        self.clip.toggled.connect(lambda _b: self._clip())
        self.clip_axis.currentIndexChanged.connect(lambda _i: self._clip())
        self.clip_position.valueChanged.connect(lambda _v: self._clip())

    def _opacity(self, percent: int) -> None:
        self.opacity_label.setText(f"{percent} %")
        self.opacity_changed.emit(percent / 100.0)

    def _clip(self) -> None:
        if not self.clip.isChecked():
            self.clip_changed.emit(None)
            return
        index = self.clip_axis.currentIndex()
        self.clip_changed.emit((index // 2, self.clip_position.value() / 100,
                                -1 if index % 2 == 0 else 1))
