"""A 2D field viewer: a colour-mapped (nu, nv) array painted with QPainter.

The canvas adds a colour bar and line and point overlays. Used by the descriptor slice and
the energy landscape views.

Coordinates: the array's first index runs along the horizontal axis u, the second along the
vertical axis v (up); ``extent = (u0, u1, v0, v1)`` are the centres of the corner samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from app.gui import colourmap


@dataclass(frozen=True)
class Marker:
    """A point marked on a :class:`FieldCanvas`, in field coordinates ``(u, v)``.

    ``shape`` is ``"cross"``, ``"star"`` or ``"circle"``; ``colour`` a Qt colour name; an
    optional ``label`` is written beside it.
    """

    u: float
    v: float
    shape: str  # "cross" or "star" or "circle"
    colour: str
    label: str = ""


class FieldCanvas(QtWidgets.QWidget):
    """Paints one colour-mapped field, with its overlays and colour bar.

    Emits ``scrolled(int)`` on the wheel, ``dragged(float)`` with the vertical drag
    distance as a fraction of the widget height (for moving a slice plane), and
    ``hovered(object)`` with ``(u, v, value)`` of the sample under the cursor (None when the
    cursor leaves the field).
    """

    scrolled = QtCore.Signal(int)
    dragged = QtCore.Signal(float)
    hovered = QtCore.Signal(object)

    BAR_WIDTH = 14
    BAR_GAP = 8
    LABEL_WIDTH = 76

    def __init__(self, parent=None):
        super().__init__(parent)
        self._image: QtGui.QImage | None = None
        self._rgb: np.ndarray | None = None
        self._extent = (0.0, 1.0, 0.0, 1.0)
        self._range = (0.0, 1.0)
        self._lut = colourmap.table("diverging")
        self._segments = np.zeros((0, 2, 2))
        self._markers: list[Marker] = []
        self._axis_names = ("u", "v")
        self._bar_label = ""
        self._message = "no data"
        self._drag_y: float | None = None
        self._values: np.ndarray | None = None  # (nu, nv) float64 as shown
        self.setMouseTracking(True)  # hover reports the value under the cursor
        self.setMinimumSize(220, 180)
        self.setSizePolicy(QtWidgets.QSizePolicy.Expanding, QtWidgets.QSizePolicy.Expanding)

    # ------------------------------------------------------------------ content
    def set_field(self, values: np.ndarray, extent, lo: float, hi: float, lut: np.ndarray,
                  *, axis_names=("u", "v"), bar_label: str = "") -> None:
        """Show ``values`` (nu, nv) float mapped from [lo, hi] through ``lut`` (256, 3)."""
        values = np.asarray(values, dtype=np.float64)
        if values.ndim != 2:
            raise ValueError(f"a field to show must be 2D, got shape {values.shape}")
        self._values = values
        rgb = colourmap.apply(values.T[::-1], lo, hi, lut)  # rows: v from top to bottom
        self._rgb = np.ascontiguousarray(rgb)
        h, w, _ = self._rgb.shape
        self._image = QtGui.QImage(self._rgb.data, w, h, 3 * w, QtGui.QImage.Format_RGB888)
        self._extent = tuple(float(e) for e in extent)
        self._range = (float(lo), float(hi))
        self._lut = lut
        self._axis_names = axis_names
        self._bar_label = bar_label
        self._message = ""
        self.update()

    def clear(self, message: str = "no data") -> None:
        """Drop the field and show ``message`` in its place."""
        self._image, self._rgb, self._message = None, None, message
        self._values = None
        self.update()

    def set_segments(self, segments: np.ndarray) -> None:
        """(k, 2, 2) float line segments in (u, v) coordinates (part outlines)."""
        self._segments = np.asarray(segments, dtype=np.float64).reshape(-1, 2, 2)
        self.update()

    def set_markers(self, markers: list[Marker]) -> None:
        """Replace the markers drawn over the field."""
        self._markers = list(markers)
        self.update()

    def field_rgb(self) -> np.ndarray | None:
        """(h, w, 3) uint8 colours of the field as shown (before scaling), or None."""
        return None if self._rgb is None else self._rgb.copy()

    # ------------------------------------------------------------------ geometry
    def _plot_rect(self) -> QtCore.QRectF:
        """Where the field goes: the largest rectangle with the field's aspect ratio."""
        avail = QtCore.QRectF(self.rect()).adjusted(
            28, 6, -(self.BAR_WIDTH + self.BAR_GAP + self.LABEL_WIDTH), -22
        )
        u0, u1, v0, v1 = self._extent
        du, dv = max(abs(u1 - u0), 1e-12), max(abs(v1 - v0), 1e-12)
        scale = min(avail.width() / du, avail.height() / dv)
        w, h = du * scale, dv * scale
        return QtCore.QRectF(avail.left() + (avail.width() - w) / 2,
                             avail.top() + (avail.height() - h) / 2, w, h)

    def to_widget(self, u: np.ndarray, v: np.ndarray, rect: QtCore.QRectF):
        """Widget coordinates ``(x, y)`` of field points ``(u, v)`` in the plot rectangle ``rect``.

        ``u`` and ``v`` may be arrays of any one shape; ``x`` and ``y`` have that shape.
        """
        u0, u1, v0, v1 = self._extent
        x = rect.left() + (np.asarray(u) - u0) / (u1 - u0 or 1.0) * rect.width()
        y = rect.bottom() - (np.asarray(v) - v0) / (v1 - v0 or 1.0) * rect.height()
        return x, y

    # ------------------------------------------------------------------ painting
    def paintEvent(self, event) -> None:  # noqa: N802 (Qt API)
        """Paint the field image, the line overlays, the markers and the colour bar."""
        p = QtGui.QPainter(self)
        p.fillRect(self.rect(), self.palette().window())
        if self._image is None:
            p.setPen(self.palette().text().color())
            p.drawText(self.rect(), QtCore.Qt.AlignCenter, self._message)
            p.end()
            return
        rect = self._plot_rect()
        # samples are cell centres: the image spans half a cell beyond the extent
        nu, nv = self._image.width(), self._image.height()
        hu = rect.width() / max(nu - 1, 1) / 2
        hv = rect.height() / max(nv - 1, 1) / 2
        p.setRenderHint(QtGui.QPainter.SmoothPixmapTransform, False)
        p.drawImage(rect.adjusted(-hu, -hv, hu, hv), self._image)
        p.setRenderHint(QtGui.QPainter.Antialiasing, True)
        if len(self._segments):
            p.setPen(QtGui.QPen(QtGui.QColor(20, 20, 20), 1.4))
            x, y = self.to_widget(self._segments[..., 0], self._segments[..., 1], rect)
            lines = [QtCore.QLineF(x[i, 0], y[i, 0], x[i, 1], y[i, 1]) for i in range(len(x))]
            p.drawLines(lines)
        for m in self._markers:
            x, y = self.to_widget(m.u, m.v, rect)
            self._draw_marker(p, float(x), float(y), m)
        self._draw_axes(p, rect)
        self._draw_bar(p, rect)
        p.end()

    def _draw_marker(self, p: QtGui.QPainter, x: float, y: float, m: Marker) -> None:
        colour = QtGui.QColor(m.colour)
        p.setPen(QtGui.QPen(QtGui.QColor("black"), 3.0))
        r = 7
        for pen in (QtGui.QPen(QtGui.QColor("white"), 3.5), QtGui.QPen(colour, 1.8)):
            p.setPen(pen)
            if m.shape == "cross":
                p.drawLine(QtCore.QLineF(x - r, y, x + r, y))
                p.drawLine(QtCore.QLineF(x, y - r, x, y + r))
            elif m.shape == "star":
                for k in range(3):
                    a = np.pi * k / 3
                    dx, dy = r * np.cos(a), r * np.sin(a)
                    p.drawLine(QtCore.QLineF(x - dx, y - dy, x + dx, y + dy))
            else:
                p.drawEllipse(QtCore.QPointF(x, y), r, r)
        if m.label:
            p.setPen(QtGui.QColor("black"))
            p.drawText(QtCore.QPointF(x + r + 2, y - r), m.label)

    def _draw_axes(self, p: QtGui.QPainter, rect: QtCore.QRectF) -> None:
        p.setPen(self.palette().text().color())
        u0, u1, v0, v1 = self._extent
        fm = p.fontMetrics()
        p.drawText(QtCore.QPointF(rect.left(), rect.bottom() + fm.height()), f"{u0:.3g}")
        t = f"{u1:.3g}"
        p.drawText(QtCore.QPointF(rect.right() - fm.horizontalAdvance(t),
                                  rect.bottom() + fm.height()), t)
        name = self._axis_names[0]
        p.drawText(QtCore.QPointF(rect.center().x() - fm.horizontalAdvance(name) / 2,
                                  rect.bottom() + fm.height()), name)
        p.save()
        p.translate(rect.left() - 6, rect.center().y())
        p.rotate(-90)
        p.drawText(QtCore.QPointF(-fm.horizontalAdvance(self._axis_names[1]) / 2, 0),
                   self._axis_names[1])
        p.restore()
        p.drawText(QtCore.QPointF(2, rect.bottom()), f"{v0:.3g}")
        p.drawText(QtCore.QPointF(2, rect.top() + fm.ascent()), f"{v1:.3g}")

    def _draw_bar(self, p: QtGui.QPainter, rect: QtCore.QRectF) -> None:
        x = rect.right() + self.BAR_GAP + 6
        top, h = rect.top(), rect.height()
        bar = np.ascontiguousarray(np.repeat(self._lut[::-1][:, None, :], 4, axis=1))
        img = QtGui.QImage(bar.data, 4, 256, 12, QtGui.QImage.Format_RGB888)
        p.drawImage(QtCore.QRectF(x, top, self.BAR_WIDTH, h), img)
        p.setPen(self.palette().text().color())
        p.drawRect(QtCore.QRectF(x, top, self.BAR_WIDTH, h))
        lo, hi = self._range
        fm = p.fontMetrics()
        ticks = [(hi, top + fm.ascent()), (lo, top + h)]
        if lo < 0 < hi:
            ticks.append((0.0, top + h * hi / (hi - lo) + fm.ascent() / 2))
        for value, y in ticks:
            p.drawText(QtCore.QPointF(x + self.BAR_WIDTH + 4, y), f"{value:.3g}")
        if self._bar_label:
            p.drawText(QtCore.QPointF(x + self.BAR_WIDTH + 4, top + h / 4), self._bar_label)

    # ------------------------------------------------------------------ mouse
    def wheelEvent(self, event) -> None:  # noqa: N802
        """Emit ``scrolled`` with the wheel's direction (+1 or -1)."""
        steps = int(np.sign(event.angleDelta().y()))
        if steps:
            self.scrolled.emit(steps)
        event.accept()

    def mousePressEvent(self, event) -> None:  # noqa: N802
        """Start a vertical drag on the left button."""
        if event.button() == QtCore.Qt.LeftButton:
            self._drag_y = event.position().y()
            self.setCursor(QtCore.Qt.SizeVerCursor)

    def value_at(self, x: float, y: float) -> tuple[float, float, float] | None:
        """``(u, v, value)`` of the sample nearest widget point (x, y), or None off the field."""
        if self._values is None:
            return None
        rect = self._plot_rect()
        u0, u1, v0, v1 = self._extent
        nu, nv = self._values.shape
        fu = (x - rect.left()) / max(rect.width(), 1e-9)
        fv = (rect.bottom() - y) / max(rect.height(), 1e-9)
        iu, iv = int(round(fu * (nu - 1))), int(round(fv * (nv - 1)))
        if not (0 <= iu < nu and 0 <= iv < nv):
            return None
        u = u0 + (u1 - u0) * iu / max(nu - 1, 1)
        v = v0 + (v1 - v0) * iv / max(nv - 1, 1)
        return float(u), float(v), float(self._values[iu, iv])

    def mouseMoveEvent(self, event) -> None:  # noqa: N802
        """Report the value under the cursor; while dragging, emit ``dragged`` as well.

        ``dragged`` carries the vertical move since the last event, per widget height.
        """
        if self._drag_y is not None:
            dy = self._drag_y - event.position().y()
            self._drag_y = event.position().y()
            self.dragged.emit(dy / max(self.height(), 1))
        self.hovered.emit(self.value_at(event.position().x(), event.position().y()))

    def leaveEvent(self, event) -> None:  # noqa: N802
        """The cursor left: no value under it."""
        self.hovered.emit(None)
        super().leaveEvent(event)

    def mouseReleaseEvent(self, event) -> None:  # noqa: N802
        """End the drag."""
        self._drag_y = None
        self.unsetCursor()
