"""Energy landscape view: a 2D section of the translational energy E(t) at a fixed rotation.

The engine computes the landscape (one inverse FFT) off its loop when asked
(``RequestLandscape``) and answers with an ``engine.correlation.Landscape``. This view cuts
it with a plane through the part's current translation, marks the current pose (cross) and
the section's minimum (star), and re-cuts as the part moves; the window asks for a new
landscape when the part's rotation has turned by more than :attr:`ROTATION_TOLERANCE` or K
has changed.

The engine's landscape is computed with kappa = 1; this view multiplies it by the kappa the
engine's per-pose readouts use (:meth:`LandscapeView.set_scale`), so the landscape, the
readouts and the strip chart show one energy, in one unit. The value under the cursor is
shown as the mouse moves over the picture.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtWidgets

from app.gui import colourmap
from app.gui.canvas import FieldCanvas, Marker
from engine import pose as posemath
from engine.params import QuantityUnits

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
        self.kappa = 1.0  # scale of the engine's kappa-1 landscape: the readouts' kappa
        self.units = QuantityUnits.of("mm")
        self.modes: int | None = None  # the K the engine uses now
        self._progress: str | None = None
        self._lut = colourmap.table("diverging")
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
        row.addStretch(1)
        lay.addLayout(row)
        # on a line of its own, the whole width: beside the combo box the row's height was
        # worked out for another width than the label got, and its wrapped lines overran it
        lay.addWidget(self.info)
        self.canvas = FieldCanvas()
        self.canvas.clear("landscape not computed yet")
        lay.addWidget(self.canvas, 1)
        self.hover = QtWidgets.QLabel(" ")
        self.hover.setObjectName("landscape_hover")
        self.hover.setSizePolicy(QtWidgets.QSizePolicy.Ignored,
                                 QtWidgets.QSizePolicy.Preferred)
        lay.addWidget(self.hover)
        self.canvas.hovered.connect(self._hovered)
        self.plane.currentIndexChanged.connect(lambda _i: self.refresh())

    @property
    def landscape(self):
        """The landscape shown (from the engine's ``LandscapeReady``), or None."""
        return self._landscape

    def set_scale(self, kappa: float, units: QuantityUnits) -> None:
        """The kappa the readouts use (the landscape is shown times it) and the units."""
        self.kappa, self.units = float(kappa), units
        self.refresh()

    def set_modes(self, modes: int) -> None:
        """The K the engine uses now (a landscape of another K is out of date)."""
        self.modes = int(modes)

    def set_progress(self, text: str | None) -> None:
        """Say that a landscape is being computed (``text``), or that none is (None)."""
        self._progress = text
        if text is not None:
            self.info.setText(text)

    def needs_landscape(self, pose: np.ndarray) -> bool:
        """True when no landscape is held, K changed or ``pose`` turned too far from its one."""
        if self._landscape is None:
            return True
        if self.modes is not None and self._landscape.modes != self.modes:
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
        energy = energy * self.kappa  # in the readouts' scale and unit
        finite = energy[np.isfinite(energy)]
        a = float(np.max(np.abs(finite))) if finite.size else 1.0
        a = a if a > 0 else 1.0
        unit = self.units.length
        self.canvas.set_field(energy, (u[0], u[-1], v[0], v[-1]), -a, a, self._lut,
                              axis_names=(f"t{plane[0]} ({unit})", f"t{plane[1]} ({unit})"),
                              bar_label=f"E ({self.units.energy})")
        iu, iv = np.unravel_index(int(np.argmin(energy)), energy.shape)
        ia, ib = "xyz".index(plane[0]), "xyz".index(plane[1])
        markers = [
            Marker(float(u[iu]), float(v[iv]), "star", "#1a9641", "min"),
            Marker(float(self._pose[ia]), float(self._pose[ib]), "cross", "#000000", "part"),
        ]
        self.canvas.set_markers(markers)
        tmin, emin = self._landscape.minimum()
        emin *= self.kappa
        k = self._landscape.modes
        stale = (f" (K is now {self.modes}: recomputing)"
                 if self.modes is not None and self.modes != k else "")
        e = self.units.energy
        self.info.setText(
            f"E in {e} with kappa = {self.kappa:.4g} {self.units.kappa} (as the readouts); "
            f"K = {k}{stale}; section min {energy[iu, iv]:.4g} {e} at ({u[iu]:.3g}, "
            f"{v[iv]:.3g}); overall min {emin:.4g} {e} at ({tmin[0]:.3g}, {tmin[1]:.3g}, "
            f"{tmin[2]:.3g}) {unit}; computed in {self._landscape.seconds:.2g} s"
        )
        if self._progress is not None:
            self.info.setText(f"{self._progress}; {self.info.text()}")

    def _hovered(self, where) -> None:
        """Show the energy under the cursor (``where``: (u, v, value) or None)."""
        if where is None or self._landscape is None:
            self.hover.setText(" ")
            return
        u, v, value = where
        plane = self.plane.currentText()
        unit = self.units.length
        self.hover.setText(f"t{plane[0]} = {u:.3g} {unit}, t{plane[1]} = {v:.3g} {unit}: "
                           f"E = {value:.4g} {self.units.energy}")

    def showEvent(self, event) -> None:  # noqa: N802
        """Refresh on showing, as nothing is drawn while hidden."""
        super().showEvent(event)
        self.refresh()
