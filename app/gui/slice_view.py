"""Descriptor slice view: an axis-aligned plane through either part's descriptor.

Shows the real part, the imaginary part or the magnitude of ``rho (nx, ny, nz) complex64``
on the plane (real/imaginary with a diverging map centred on zero, magnitude with a
sequential one), the part's outline (the mesh cut by the same plane) on top, and a colour
bar. The plane is moved with the slider, the wheel or a vertical drag on the image; the
window mirrors it as a translucent quad in the 3D view.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtWidgets

from app.gui import colourmap, geometry
from app.gui.canvas import FieldCanvas

COMPONENTS = ("imaginary", "real", "magnitude")


def slice_values(rho: np.ndarray, axis: int, index: int, component: str) -> np.ndarray:
    """(nu, nv) float64 slice of a complex (nx, ny, nz) field at ``index`` along ``axis``.

    (u, v) are the two remaining axes in increasing order.
    """
    if component not in COMPONENTS:
        raise ValueError(f"unknown component {component!r}; valid: {', '.join(COMPONENTS)}")
    plane = np.take(rho, int(index), axis=axis)
    if component == "real":
        return np.asarray(plane.real, dtype=np.float64)
    if component == "imaginary":
        return np.asarray(plane.imag, dtype=np.float64)
    return np.abs(plane).astype(np.float64)


class SliceView(QtWidgets.QWidget):
    """Signals: ``plane_changed(object)`` with (4, 3) world corners of the plane, or None.

    :meth:`preview` shows the plane at other descriptor parameters (a sigma or penalty
    slider held) until it is called with None.
    """

    plane_changed = QtCore.Signal(object)

    def __init__(self, parent=None):
        super().__init__(parent)
        from app.gui.slice_preview import SlicePreview

        self._descriptors: tuple = ()
        self._preview_params = None  # the parameters previewed, None: those in use
        self._preview: tuple | None = None  # (key, plane) of the last preview computed
        self.previews = SlicePreview(self)
        self.previews.ready.connect(self._preview_ready)
        self.previews.failed.connect(self._preview_failed)
        self._meshes: list = []  # (name, vertices, faces) per part
        self._world: list[np.ndarray] = []  # (4, 4) world transform per part
        self._lut_div = colourmap.table("diverging")
        self._lut_seq = colourmap.table("sequential")
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(2, 2, 2, 2)
        row = QtWidgets.QHBoxLayout()
        self.part = QtWidgets.QComboBox()
        self.axis = QtWidgets.QComboBox()
        self.axis.addItems(["x", "y", "z"])
        self.axis.setCurrentIndex(1)
        self.component = QtWidgets.QComboBox()
        self.component.addItems(COMPONENTS)
        for label, w in (("part", self.part), ("normal", self.axis), ("show", self.component)):
            row.addWidget(QtWidgets.QLabel(label))
            row.addWidget(w)
        row.addStretch(1)
        lay.addLayout(row)
        row = QtWidgets.QHBoxLayout()
        self.offset = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.offset.setObjectName("slice_offset")
        self.offset_label = QtWidgets.QLabel("-")
        self.offset_label.setMinimumWidth(110)
        row.addWidget(QtWidgets.QLabel("plane"))
        row.addWidget(self.offset, 1)
        row.addWidget(self.offset_label)
        lay.addLayout(row)
        self.preview_note = QtWidgets.QLabel("")
        self.preview_note.setObjectName("slice_preview_note")
        self.preview_note.setWordWrap(True)
        self.preview_note.setStyleSheet("color: #8a5a00")
        self.preview_note.hide()
        lay.addWidget(self.preview_note)
        self.canvas = FieldCanvas()
        self.canvas.clear("descriptors not ready yet")
        lay.addWidget(self.canvas, 1)
        self.hover = QtWidgets.QLabel(" ")
        self.hover.setObjectName("slice_hover")
        self.hover.setSizePolicy(QtWidgets.QSizePolicy.Ignored,
                                 QtWidgets.QSizePolicy.Preferred)
        lay.addWidget(self.hover)
        self.canvas.hovered.connect(self._hovered)
        self.part.currentIndexChanged.connect(lambda _i: self._reset_range())
        self.axis.currentIndexChanged.connect(lambda _i: self._reset_range())
        self.component.currentIndexChanged.connect(lambda _i: self.refresh())
        self.offset.valueChanged.connect(lambda _v: self.refresh())
        self.canvas.scrolled.connect(lambda s: self.offset.setValue(self.offset.value() + s))
        self._drag_acc = 0.0
        self.canvas.dragged.connect(self._dragged)

    # ------------------------------------------------------------------ inputs
    def set_parts(self, meshes, world_transforms) -> None:
        """Part meshes (name, vertices (n,3), faces (m,3)) and (4, 4) world transforms."""
        self._meshes = list(meshes)
        self._world = [np.asarray(m, float) for m in world_transforms]
        current = self.part.currentIndex()
        self.part.blockSignals(True)
        self.part.clear()
        for i, (name, *_rest) in enumerate(self._meshes[:2]):
            self.part.addItem(f"{name} ({'moving' if i == 1 else 'fixed'})")
        self.part.setCurrentIndex(max(current, 0) if current < self.part.count() else 0)
        self.part.blockSignals(False)

    def set_world_transform(self, index: int, matrix: np.ndarray) -> None:
        """Update a part's (4, 4) world transform (the moving part moves)."""
        if index < len(self._world):
            self._world[index] = np.asarray(matrix, float)
            if index == self.part.currentIndex():
                self._emit_plane()

    def set_descriptors(self, descriptors: tuple) -> None:
        """Descriptors of part 1 and part 2 (objects with ``rho`` and ``grid``)."""
        self._descriptors = tuple(descriptors)
        if not self._descriptors:
            self.canvas.clear("no descriptors (guidance off or not ready)")
            return
        self._reset_range(keep=True)

    def preview(self, params) -> None:
        """Show the plane at ``params`` (DescriptorParams), or with None the ones in use.

        Computed in the background, for whichever plane is shown.
        """
        self._preview_params = params
        if params is None:
            self.previews.clear()
            self._preview = None
            self.preview_note.hide()
        self.refresh()

    def _preview_key(self):
        d = self._current()
        if d is None or self._preview_params is None:
            return None
        i = self.part.currentIndex()
        return (i, self.axis.currentIndex(), self.offset.value(), d.grid, self._preview_params)

    def _preview_values(self):
        """The previewed plane's complex values, or None (then asks for them)."""
        key = self._preview_key()
        if key is None:
            return None
        if self._preview is not None and self._preview[0] == key:
            return self._preview[1]
        i, axis, index, grid, params = key
        if i < len(self._meshes):
            _, vertices, faces = self._meshes[i]
            self.preview_note.setText(f"computing the preview at sigma {params.sigma:.3g}, "
                                      f"penalty {params.penalty:.3g}…")
            self.preview_note.show()
            self.previews.request(key, np.asarray(vertices), np.asarray(faces), grid, axis,
                                  index, params)
        return None

    def _preview_ready(self, key, plane) -> None:
        if key != self._preview_key():
            return
        self._preview = (key, plane)
        params = key[-1]
        self.preview_note.setText(f"preview at sigma {params.sigma:.3g}, penalty "
                                  f"{params.penalty:.3g}: not in use until its descriptors "
                                  "are computed")
        self.refresh()

    def _preview_failed(self, key, message: str) -> None:
        if key == self._preview_key():
            self.preview_note.setText(f"no preview: {message}")

    # ------------------------------------------------------------------ state
    def _current(self):
        i = self.part.currentIndex()
        if i < 0 or i >= len(self._descriptors):
            return None
        return self._descriptors[i]

    def _reset_range(self, keep: bool = False) -> None:
        d = self._current()
        if d is None:
            return
        n = d.grid.shape[self.axis.currentIndex()]
        old = self.offset.value()
        self.offset.blockSignals(True)
        self.offset.setRange(0, n - 1)
        self.offset.setValue(min(old, n - 1) if keep and old > 0 else n // 2)
        self.offset.blockSignals(False)
        self.refresh()

    def _hovered(self, where) -> None:
        """Show the descriptor's value under the cursor (``where``: (u, v, value) or None)."""
        if where is None or self._current() is None:
            self.hover.setText(" ")
            return
        u, v, value = where
        a = self.axis.currentIndex()
        nu, nv = (geometry.AXES[k] for k in range(3) if k != a)
        self.hover.setText(f"{nu} = {u:.3g}, {nv} = {v:.3g} (part's frame): "
                           f"{self.component.currentText()} ρ = {value:.4g}")

    def _dragged(self, fraction: float) -> None:
        self._drag_acc += fraction * (self.offset.maximum() + 1)
        steps = int(self._drag_acc)
        if steps:
            self._drag_acc -= steps
            self.offset.setValue(self.offset.value() + steps)

    def plane(self) -> tuple[int, int, float]:
        """(part index, axis, offset in the part's frame) of the current plane."""
        d = self._current()
        a = self.axis.currentIndex()
        if d is None:
            return self.part.currentIndex(), a, 0.0
        return (self.part.currentIndex(), a,
                float(d.grid.origin[a] + d.grid.spacing * self.offset.value()))

    def current_values(self) -> np.ndarray | None:
        """The current slice of the chosen part's descriptor, or None when no part is chosen.

        A (nu, nv) float array of the chosen component of rho in the chosen plane.
        """
        d = self._current()
        if d is None:
            return None
        plane = self._preview_values()
        if plane is not None:  # the previewed parameters' plane (axis 0 of a 1-thick block)
            return slice_values(plane[None], 0, 0, self.component.currentText())
        return slice_values(d.rho, self.axis.currentIndex(), self.offset.value(),
                            self.component.currentText())

    # ------------------------------------------------------------------ drawing
    def refresh(self) -> None:
        """Redraw the slice, its range and colour map, and the part's outline in the plane."""
        d = self._current()
        if d is None:
            return
        a = self.axis.currentIndex()
        values = self.current_values()
        comp = self.component.currentText()
        if comp == "magnitude":
            lo, hi, lut = 0.0, colourmap.symmetric_range(values)[1], self._lut_seq
        else:
            (lo, hi), lut = colourmap.symmetric_range(values), self._lut_div
        uv = [k for k in range(3) if k != a]
        g = d.grid
        lo_g, hi_g = np.asarray(g.origin), g.upper
        extent = (lo_g[uv[0]], hi_g[uv[0]], lo_g[uv[1]], hi_g[uv[1]])
        names = tuple(geometry.AXES[k] for k in uv)
        self.canvas.set_field(values, extent, lo, hi, lut, axis_names=names,
                              bar_label=f"{comp[:4]} ρ")
        _, _, offset = self.plane()
        self.offset_label.setText(f"{geometry.AXES[a]} = {offset:.4g}")
        i = self.part.currentIndex()
        if i < len(self._meshes):
            _, vertices, faces = self._meshes[i]
            seg = geometry.section_segments(vertices, faces, a, offset)
            self.canvas.set_segments(seg[..., uv])
        self._emit_plane()

    def _emit_plane(self) -> None:
        d = self._current()
        i = self.part.currentIndex()
        if d is None or i >= len(self._world) or not self.isVisible():
            self.plane_changed.emit(None)
            return
        a = self.axis.currentIndex()
        _, _, offset = self.plane()
        uv = [k for k in range(3) if k != a]
        lo_g, hi_g = np.asarray(d.grid.origin), d.grid.upper
        corners = np.zeros((4, 3))
        corners[:, a] = offset
        for c, (su, sv) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
            corners[c, uv[0]] = (lo_g, hi_g)[su][uv[0]]
            corners[c, uv[1]] = (lo_g, hi_g)[sv][uv[1]]
        m = self._world[i]
        self.plane_changed.emit(corners @ m[:3, :3].T + m[:3, 3])

    def showEvent(self, event) -> None:  # noqa: N802
        """Announce the slice plane, so that the 3D view shows it."""
        super().showEvent(event)
        self._emit_plane()

    def hideEvent(self, event) -> None:  # noqa: N802
        """Hide the slice plane in the 3D view (``plane_changed(None)``)."""
        super().hideEvent(event)
        self.plane_changed.emit(None)
