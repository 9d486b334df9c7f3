"""Energy landscape view: a 2D section of the translational energy E(t) at a fixed rotation.

The engine computes the landscape (one inverse FFT) off its loop when asked
(``RequestLandscape``) and answers with an ``engine.correlation.Landscape``. This view cuts
it with a plane through the part's current translation, marks the current pose (cross) and
the section's minimum (star), and re-cuts as the part moves; the window asks for a new
landscape only when the part's rotation has turned by more than :attr:`ROTATION_TOLERANCE`.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtWidgets

from app.gui import colormap
from app.gui.canvas import FieldCanvas, Marker
from engine import pose as posemath

PLANES = ("xy", "xz", "yz")


def rotation_angle_between(r1: np.ndarray, r2: np.ndarray) -> float:
    """Angle in radians between two (3, 3) rotations."""
    c = (np.trace(np.asarray(r1).T @ np.asarray(r2)) - 1.0) / 2.0
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


class LandscapeView(QtWidgets.QWidget):
    """Dock view: a plane section of the translational energy landscape through the part.

    Shows the energy in the chosen plane through the current pose of part 2, with the
    section's minimum and the part marked. A landscape holds for one rotation: the window asks
    for a new one when the part has turned more than :attr:`ROTATION_TOLERANCE` from it
    (:meth:`needs_landscape`).
    """

    ROTATION_TOLERANCE = np.radians(3.0)

    def __init__(self, parent=None):
        super().__init__(parent)
        self._landscape = None
        self._pose = np.zeros(6)
        self._lut = colormap.table("diverging")
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(2, 2, 2, 2)
        row = QtWidgets.QHBoxLayout()
        self.plane = QtWidgets.QComboBox()
        self.plane.addItems(PLANES)
        self.plane.setCurrentText("xz")
        self.info = QtWidgets.QLabel("waiting for the engine")
        self.info.setWordWrap(True)
        # long numbers must not widen the dock
        self.info.setSizePolicy(QtWidgets.QSizePolicy.Ignored,
                                QtWidgets.QSizePolicy.Preferred)
        row.addWidget(QtWidgets.QLabel("section"))
        row.addWidget(self.plane)
        row.addWidget(self.info, 1)
        lay.addLayout(row)
        self.canvas = FieldCanvas()
        self.canvas.clear("landscape not computed yet")
        lay.addWidget(self.canvas, 1)
        self.plane.currentIndexChanged.connect(lambda _i: self.refresh())

    @property
    def landscape(self):
        """The landscape shown (from the engine's ``LandscapeReady``), or None."""
        return self._landscape

    def needs_landscape(self, pose: np.ndarray) -> bool:
        """True when no landscape is held or ``pose``'s rotation is too far from its one."""
        if self._landscape is None:
            return True
        r = posemath.rotation_matrix(np.asarray(pose, float)[3:])
        return rotation_angle_between(r, self._landscape.rotation) > self.ROTATION_TOLERANCE

    def set_landscape(self, landscape) -> None:
        """Show a new landscape from the engine."""
        self._landscape = landscape
        self.refresh()

    def set_pose(self, pose: np.ndarray) -> None:
        """Current pose of part 2 relative to part 1, (6,) float64."""
        self._pose = np.asarray(pose, float).copy()
        self.refresh()

    def section(self):
        """(energy (nu, nv), u (nu,), v (nv,)) through the current pose, or None."""
        if self._landscape is None:
            return None
        plane = self.plane.currentText()
        normal = {"xy": 2, "xz": 1, "yz": 0}[plane]
        axis = self._landscape.translations[normal]
        offset = float(np.clip(self._pose[normal], axis[0], axis[-1]))
        return self._landscape.section(plane, offset)

    def refresh(self) -> None:
        """Redraw the section, its markers and the summary line (only while visible)."""
        if self._landscape is None or not self.isVisible():
            return
        plane = self.plane.currentText()
        energy, u, v = self.section()
        finite = energy[np.isfinite(energy)]
        a = float(np.max(np.abs(finite))) if finite.size else 1.0
        a = a if a > 0 else 1.0
        self.canvas.set_field(energy, (u[0], u[-1], v[0], v[-1]), -a, a, self._lut,
                              axis_names=(f"t{plane[0]}", f"t{plane[1]}"), bar_label="E")
        iu, iv = np.unravel_index(int(np.argmin(energy)), energy.shape)
        ia, ib = "xyz".index(plane[0]), "xyz".index(plane[1])
        markers = [
            Marker(float(u[iu]), float(v[iv]), "star", "#1a9641", "min"),
            Marker(float(self._pose[ia]), float(self._pose[ib]), "cross", "#000000", "part"),
        ]
        self.canvas.set_markers(markers)
        tmin, emin = self._landscape.minimum()
        self.info.setText(
            f"section E min {energy[iu, iv]:.3g} at ({u[iu]:.3g}, {v[iv]:.3g});  "
            f"global min {emin:.3g} at ({tmin[0]:.3g}, {tmin[1]:.3g}, {tmin[2]:.3g});  "
            f"K={self._landscape.modes}, {self._landscape.seconds * 1e3:.0f} ms"
        )

    def showEvent(self, event) -> None:  # noqa: N802
        """Refresh on showing, as nothing is drawn while hidden."""
        super().showEvent(event)
        self.refresh()
