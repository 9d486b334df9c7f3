"""Small reusable widgets: a slider with a numeric field, and a key/value readout grid."""

from __future__ import annotations

import math

from PySide6 import QtCore, QtWidgets


class SliderField(QtWidgets.QWidget):
    """A horizontal slider and a spin box showing one float value, linear or logarithmic.

    With ``on_release`` the value is committed only when the slider is let go (or a value is
    typed and Enter pressed, or set from code); while the slider is dragged the field shows
    the value it would take. Expensive parameters use it, so that a drag across the slider
    starts one recompute, not one per pixel.

    Signals
    -------
    valueChanged(float)
        Every committed change, from either the slider or the field.
    previewed(float)
        While an ``on_release`` slider is held: the value it would commit.
    """

    valueChanged = QtCore.Signal(float)  # noqa: N815 (Qt naming)
    previewed = QtCore.Signal(float)
    STEPS = 1000

    def __init__(self, lo: float, hi: float, value: float, *, decimals: int = 3,
                 log: bool = False, integer: bool = False, suffix: str = "",
                 on_release: bool = False, parent=None):
        super().__init__(parent)
        if not lo < hi:
            raise ValueError(f"slider range must have lo < hi, got {lo}, {hi}")
        if log and lo <= 0:
            raise ValueError("a logarithmic slider needs a positive lower bound")
        self.lo, self.hi, self.log, self.integer = lo, hi, log, integer
        self.slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.slider.setRange(0, self.STEPS if not integer else int(hi - lo))
        if integer:
            self.field: QtWidgets.QAbstractSpinBox = QtWidgets.QSpinBox()
            self.field.setRange(int(lo), int(hi))
        else:
            self.field = QtWidgets.QDoubleSpinBox()
            self.field.setDecimals(decimals)
            self.field.setRange(lo, hi)
            self.field.setSingleStep(10 ** -(decimals - 1) if decimals > 1 else 0.1)
        self.field.setSuffix(suffix)
        self.field.setKeyboardTracking(False)
        self.field.setMinimumWidth(80)
        lay = QtWidgets.QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.slider, 1)
        lay.addWidget(self.field)
        self._value = float(value)
        self._sync(self._value)
        self.on_release = on_release
        self.slider.setTracking(not on_release)  # without tracking: valueChanged on release
        self.slider.valueChanged.connect(self._from_slider)
        self.slider.sliderMoved.connect(self._preview)
        self.field.valueChanged.connect(self._from_field)

    def _to_pos(self, v: float) -> int:
        if self.integer:
            return int(round(v - self.lo))
        if self.log:
            f = (math.log(v) - math.log(self.lo)) / (math.log(self.hi) - math.log(self.lo))
        else:
            f = (v - self.lo) / (self.hi - self.lo)
        return int(round(min(max(f, 0.0), 1.0) * self.STEPS))

    def _from_pos(self, pos: int) -> float:
        if self.integer:
            return float(self.lo + pos)
        f = pos / self.STEPS
        if self.log:
            return math.exp(math.log(self.lo) + f * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + f * (self.hi - self.lo)

    def _sync(self, v: float) -> None:
        for w in (self.slider, self.field):
            w.blockSignals(True)
        self.slider.setValue(self._to_pos(v))
        self.field.setValue(int(round(v)) if self.integer else v)
        for w in (self.slider, self.field):
            w.blockSignals(False)

    def _from_slider(self, pos: int) -> None:
        self._set(self._from_pos(pos))

    def _preview(self, pos: int) -> None:
        """While the slider is held (``on_release``): show the value it would commit."""
        if not self.on_release:
            return
        v = self._from_pos(pos)
        self.field.blockSignals(True)
        self.field.setValue(int(round(v)) if self.integer else v)
        self.field.blockSignals(False)
        self.previewed.emit(float(int(round(v))) if self.integer else v)

    def _from_field(self, v) -> None:
        self._set(float(v))

    def _set(self, v: float) -> None:
        v = min(max(float(v), self.lo), self.hi)
        if self.integer:
            v = float(round(v))
        self._sync(v)
        if v != self._value:
            self._value = v
            self.valueChanged.emit(v)

    def value(self) -> float:
        """The current value, within the slider's range."""
        return self._value

    def setValue(self, v: float) -> None:  # noqa: N802 (Qt naming)
        """Set the value and emit valueChanged if it changed."""
        self._set(v)

    def setValueSilently(self, v: float) -> None:  # noqa: N802
        """Set the value without emitting (for values coming back from the engine)."""
        self._value = min(max(float(v), self.lo), self.hi)
        self._sync(self._value)


class Readouts(QtWidgets.QWidget):
    """A two-column grid of named values, updated as text."""

    def __init__(self, names: list[tuple[str, str]], parent=None):
        super().__init__(parent)
        lay = QtWidgets.QFormLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.setHorizontalSpacing(12)
        lay.setVerticalSpacing(2)
        self.labels: dict[str, QtWidgets.QLabel] = {}
        for key, title in names:
            label = QtWidgets.QLabel("-")
            label.setTextInteractionFlags(QtCore.Qt.TextSelectableByMouse)
            label.setObjectName(f"readout_{key}")
            label.setWordWrap(True)
            label.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)
            lay.addRow(title, label)
            self.labels[key] = label

    def set(self, key: str, text: str, tooltip: str | None = None) -> None:
        """Show ``text`` (and a tooltip) for ``key``; the label is touched only on a change."""
        label = self.labels[key]
        if label.text() != text:
            label.setText(text)
        if tooltip is not None and label.toolTip() != tooltip:
            label.setToolTip(tooltip)

    def set_title(self, key: str, title: str) -> None:
        """Rename the value named ``key`` (units change with the scene)."""
        form = self.layout()
        field = form.labelForField(self.labels[key])
        if field is not None and field.text() != title:
            field.setText(title)

    def title(self, key: str) -> str:
        """The name shown for the value named ``key``."""
        return self.layout().labelForField(self.labels[key]).text()

    def text(self, key: str) -> str:
        """The text shown for the value named ``key``."""
        return self.labels[key].text()
