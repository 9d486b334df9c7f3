"""A cheap strip chart: energy, force and torque magnitudes over the last seconds (QPainter).

Samples go into fixed-size numpy ring buffers; painting draws at most one point per pixel
column, so the cost does not grow with the engine rate.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets


def value_range(values: np.ndarray) -> tuple[float, float]:
    """The vertical range ``(lo, hi)`` for finite ``values``.

    Their span, widened to at least 2 % of their magnitude (a part resting in a fit jitters by
    parts per thousand, which a tight autoscale would blow up into what looks like noise).
    """
    lo, hi = float(np.min(values)), float(np.max(values))
    floor = max(0.02 * max(abs(lo), abs(hi)), 1e-12)
    if hi - lo < floor:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - 0.5 * floor, mid + 0.5 * floor
    return lo, hi


class StripChart(QtWidgets.QWidget):
    """Three traces (energy, |force|, |torque|) against time, each with its own vertical scale.

    Parameters
    ----------
    seconds : float
        Width of the time window shown.
    capacity : int
        Samples kept; older ones are overwritten.
    """

    TRACES = (("E", QtGui.QColor(31, 119, 180)), ("|F|", QtGui.QColor(214, 39, 40)),
              ("|T|", QtGui.QColor(148, 103, 189)))

    def __init__(self, parent=None, *, seconds: float = 10.0, capacity: int = 4000):
        super().__init__(parent)
        self.seconds = float(seconds)
        self._t = np.full(capacity, np.nan)  # (capacity,) float64 seconds
        self._v = np.full((capacity, 3), np.nan)  # (capacity, 3) energy, |force|, |torque|
        self._next = 0
        self.units = ("", "", "")  # of energy, force and torque
        self.setMinimumHeight(130)
        self.setSizePolicy(QtWidgets.QSizePolicy.Expanding, QtWidgets.QSizePolicy.Preferred)

    def add(self, t: float, energy: float, force: float, torque: float = float("nan")) -> None:
        """Append one sample (time in seconds, energy, force and torque magnitudes)."""
        i = self._next % len(self._t)
        self._t[i] = t
        self._v[i] = (energy, force, torque)
        self._next += 1

    def set_units(self, energy: str, force: str, torque: str = "") -> None:
        """The units the traces' labels name."""
        self.units = (energy, force, torque)
        self.update()

    def labels(self) -> tuple[str, ...]:
        """The names of the two traces, with their units."""
        return tuple(f"{name} ({unit})" if unit else name
                     for (name, _colour), unit in zip(self.TRACES, self.units, strict=True))

    def clear(self) -> None:
        """Drop every sample."""
        self._t[:] = np.nan
        self._v[:] = np.nan
        self._next = 0

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """(k,) times and (k, 3) values inside the window, oldest first."""
        n = min(self._next, len(self._t))
        if n == 0:
            return np.zeros(0), np.zeros((0, 3))
        order = (np.arange(n) + (self._next - n)) % len(self._t)
        t, v = self._t[order], self._v[order]
        keep = t >= t[-1] - self.seconds
        return t[keep], v[keep]

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:  # noqa: N802 (Qt API)
        """Paint the traces over the last :attr:`seconds`, each with its own range and label.

        The labels stand one per line above the plot, so that units and ranges fit a narrow
        dock.
        """
        p = QtGui.QPainter(self)
        p.fillRect(self.rect(), self.palette().base())
        w, h = self.width(), self.height()
        t, v = self.samples()
        p.setPen(self.palette().text().color())
        font = p.font()
        font.setPointSizeF(max(font.pointSizeF() * 0.85, 6))
        p.setFont(font)
        line = p.fontMetrics().height()
        margin_top, margin_bottom = line * len(self.TRACES) + 4, 4
        plot_h = max(h - margin_top - margin_bottom, 1)
        if len(t) < 2:
            p.drawText(QtCore.QRectF(0, 0, w, h), QtCore.Qt.AlignCenter, "no samples yet")
            p.end()
            return
        t_end = t[-1]
        x = (w - 1) * (1.0 - (t_end - t) / self.seconds)
        # one point per pixel column is enough for a chart this size
        col = np.clip(x.astype(np.intp), 0, w - 1)
        _, first = np.unique(col[::-1], return_index=True)
        pick = np.sort(len(col) - 1 - first)
        names = self.labels()
        for k, (_name, colour) in enumerate(self.TRACES):
            name = names[k]
            y = v[pick, k]
            ok = np.isfinite(y)
            if not np.any(ok):
                continue
            lo, hi = value_range(y[ok])
            ys = margin_top + plot_h * (1.0 - (y - lo) / (hi - lo))
            xs = x[pick][ok]
            poly = QtGui.QPolygonF(
                [QtCore.QPointF(float(a), float(b)) for a, b in zip(xs, ys[ok], strict=True)]
            )
            p.setPen(QtGui.QPen(colour, 1.5))
            p.drawPolyline(poly)
            text = f"{name} {y[ok][-1]:.4g}  [{lo:.3g}, {hi:.3g}]"
            p.drawText(4, line * (k + 1), text)
        p.setPen(self.palette().mid().color())
        p.drawText(w - 60, h - 6, f"last {self.seconds:.0f} s")
        p.end()
