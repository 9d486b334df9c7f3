"""Small reusable widgets: a slider with a numeric field, and a key/value readout grid."""

from __future__ import annotations

import math
import re

from PySide6 import QtCore, QtGui, QtWidgets

from engine.params import ControlRange


class SignificantSpinBox(QtWidgets.QDoubleSpinBox):
    """A spin box that holds any double and shows it to ``digits`` significant digits.

    A plain QDoubleSpinBox rounds its value to a fixed number of decimals: 4 decimals show
    a kappa of 2e-5 as 0.0000. A logarithmic control spans decades, so its field shows
    significant digits (``2e-05``, ``26.32``, ``5e+12``) and keeps the value it is given.
    """

    #: Qt's largest number of decimals: the value is then never rounded.
    EXACT = 323

    def __init__(self, digits: int, parent=None):
        super().__init__(parent)
        self.digits = int(digits)
        self.setDecimals(self.EXACT)

    def textFromValue(self, value: float) -> str:  # noqa: N802 (Qt naming)
        """``value`` to :attr:`digits` significant digits."""
        return f"{value:.{self.digits}g}"

    def valueFromText(self, text: str) -> float:  # noqa: N802
        """The number typed (any float notation), the suffix left out."""
        try:
            return float(self._number(text))
        except ValueError:
            return self.value()

    def validate(self, text: str, pos: int):
        """Acceptable: a number within the range; Intermediate: a number being typed."""
        number = self._number(text)
        try:
            value = float(number)
        except ValueError:
            partial = re.fullmatch(r"[-+]?\d*\.?\d*(?:[eE][-+]?\d*)?", number)
            state = QtGui.QValidator.Intermediate if partial else QtGui.QValidator.Invalid
            return state, text, pos
        if self.minimum() <= value <= self.maximum():
            return QtGui.QValidator.Acceptable, text, pos
        return QtGui.QValidator.Intermediate, text, pos

    def _number(self, text: str) -> str:
        suffix = self.suffix()
        if suffix and text.endswith(suffix):
            text = text[: -len(suffix)]
        return text.strip()


class SliderField(QtWidgets.QWidget):
    """A horizontal slider and a spin box showing one value, linear or logarithmic.

    Its range, step and default come from an :class:`engine.params.ControlRange` (the
    engine's parameter module is their one source): the field accepts every value the
    engine accepts, the slider spans the comfortable stretch of it. A value given from code
    (:meth:`setValueSilently`, a scene's setting) is kept exactly as given, also beyond the
    slider's stretch: the field shows it and the slider sits at its end.

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

    def __init__(self, control: ControlRange, *, suffix: str = "", on_release: bool = False,
                 parent=None):
        super().__init__(parent)
        self.control = control
        self.lo, self.hi = control.comfortable
        self.log, self.integer = control.log, control.integer
        lo, hi = control.allowed
        self.slider = QtWidgets.QSlider(QtCore.Qt.Horizontal)
        self.slider.setRange(0, self.STEPS if not self.integer else int(self.hi - self.lo))
        if self.integer:
            self.field: QtWidgets.QAbstractSpinBox = QtWidgets.QSpinBox()
            self.field.setRange(int(lo), int(hi))
            self.field.setSingleStep(max(1, int(control.step)))
        elif self.log:
            self.field = SignificantSpinBox(control.decimals)
            self.field.setRange(lo, hi)
            self.field.setSingleStep(control.step)
        else:
            self.field = QtWidgets.QDoubleSpinBox()
            self.field.setDecimals(control.decimals)
            self.field.setRange(lo, hi)
            self.field.setSingleStep(control.step)
        self.field.setSuffix(suffix)
        self.field.setKeyboardTracking(False)
        self.field.setMinimumWidth(80)
        self.field.setMaximumWidth(140)  # a wide allowed range would size it to its maximum
        lay = QtWidgets.QHBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.slider, 1)
        lay.addWidget(self.field)
        self._value = float(control.default)
        self._sync(self._value)
        self.on_release = on_release
        self.slider.setTracking(not on_release)  # without tracking: valueChanged on release
        self.slider.valueChanged.connect(self._from_slider)
        self.slider.sliderMoved.connect(self._preview)
        self.field.valueChanged.connect(self._from_field)

    def _to_pos(self, v: float) -> int:
        """The slider position showing ``v``: its end for a value beyond its stretch."""
        v = min(max(v, self.lo), self.hi)
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
        v = self.control.clamp(v)
        self._sync(v)
        if v != self._value:
            self._value = v
            self.valueChanged.emit(v)

    def value(self) -> float:
        """The current value (exactly as last set or committed)."""
        return self._value

    def setValue(self, v: float) -> None:  # noqa: N802 (Qt naming)
        """Commit ``v`` (within the allowed range) and emit valueChanged if it changed."""
        self._set(v)

    def setValueSilently(self, v: float) -> None:  # noqa: N802
        """Show ``v`` without emitting (a scene's setting, a value from the engine).

        The value is kept exactly as given, also outside the slider's stretch, so that what
        was loaded is what is saved.
        """
        self._value = float(v)
        self._sync(self._value)


class Readouts(QtWidgets.QWidget):
    """A two-column grid of named values, updated as text."""

    def __init__(self, names: list[tuple[str, str]], parent=None):
        super().__init__(parent)
        lay = QtWidgets.QFormLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)
        lay.setHorizontalSpacing(12)
        lay.setVerticalSpacing(2)
        # a narrow dock puts a value under its name rather than squeezing it to nothing
        lay.setRowWrapPolicy(QtWidgets.QFormLayout.WrapLongRows)
        self.labels: dict[str, QtWidgets.QLabel] = {}
        for key, title in names:
            label = QtWidgets.QLabel("-")
            label.setTextInteractionFlags(QtCore.Qt.TextSelectableByMouse)
            label.setObjectName(f"readout_{key}")
            label.setWordWrap(True)
            label.setSizePolicy(QtWidgets.QSizePolicy.Ignored, QtWidgets.QSizePolicy.Preferred)
            label.setMinimumWidth(80)
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


def elided(widget: QtWidgets.QWidget, text: str, width: int,
           mode=QtCore.Qt.ElideRight) -> str:
    """``text`` on one line, cut with an ellipsis to ``width`` pixels of ``widget``'s font."""
    one_line = " ".join(text.split())
    return widget.fontMetrics().elidedText(one_line, mode, max(width, 0))


class ElidedProgressBar(QtWidgets.QProgressBar):
    """A progress bar whose caption stays on one line and is cut with an ellipsis to fit.

    The middle goes: the end, where the percentage and the time left are, stays.
    ``format()`` keeps the whole caption, shown in full as the tooltip.
    """

    def text(self) -> str:  # noqa: D102 (Qt API: what the style draws)
        return elided(self, super().text(), self.contentsRect().width() - 8,
                      QtCore.Qt.ElideMiddle)

    def setFormat(self, text: str) -> None:  # noqa: N802 (Qt API)
        """Set the caption (``%p``: the percentage) and its tooltip."""
        super().setFormat(text)
        self.setToolTip(text.replace(" %p%", "").replace("%p%", ""))


class ElidedLabel(QtWidgets.QLabel):
    """A one-line label that takes at most ``max_width`` pixels and cuts its text to fit.

    The whole text is the tooltip. In a status bar it leaves the bar's messages their room.
    """

    def __init__(self, text: str = "", max_width: int = 420, parent=None):
        super().__init__(parent)
        self._full = ""
        self._max_width = max_width
        self.setSizePolicy(QtWidgets.QSizePolicy.Preferred, QtWidgets.QSizePolicy.Fixed)
        self.setText(text)

    def full_text(self) -> str:
        """The text as set, before cutting."""
        return self._full

    def text(self) -> str:  # noqa: D102 (the text as set, as a QLabel's)
        return self._full

    def setText(self, text: str) -> None:  # noqa: N802 (Qt API)
        """Show ``text``, cut to the label's width, whole in the tooltip."""
        self._full = text
        self.setToolTip(text)
        self._show()
        self.updateGeometry()

    def sizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        """As wide as the text, at most ``max_width``."""
        hint = super().sizeHint()
        wide = self.fontMetrics().horizontalAdvance(self._full) + 8
        return QtCore.QSize(min(wide, self._max_width), hint.height())

    def minimumSizeHint(self) -> QtCore.QSize:  # noqa: N802 (Qt API)
        """Small: the label gives way before the bar's messages do."""
        return QtCore.QSize(min(60, self.sizeHint().width()), super().minimumSizeHint().height())

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt API)
        """Cut the text again to the new width."""
        super().resizeEvent(event)
        self._show()

    def _show(self) -> None:
        super().setText(elided(self, self._full, self.width()))


class ContentScroll(QtWidgets.QScrollArea):
    """A dock's scroll area that never gives its widget less height than its width needs.

    A ``QScrollArea`` that resizes its widget goes by the widget's minimum size, which for
    word-wrapped labels is one line: squeezed, a wrapped readout lay over the next row. Here
    the widget's minimum height follows its layout's ``minimumHeightForWidth`` at the width
    shown, on every resize and every change of its layout (a longer text), so a dock too
    short for its content scrolls instead.
    """

    def __init__(self, widget: QtWidgets.QWidget, parent=None):
        super().__init__(parent)
        self.setWidget(widget)
        self.setWidgetResizable(True)
        self.setFrameShape(QtWidgets.QFrame.NoFrame)
        widget.installEventFilter(self)

    def eventFilter(self, obj, event) -> bool:  # noqa: N802 (Qt API)
        """Fit again when the widget's layout asks to be redone."""
        if obj is self.widget() and event.type() == QtCore.QEvent.LayoutRequest:
            self.fit()
        return False

    def resizeEvent(self, event) -> None:  # noqa: N802 (Qt API)
        """Fit the widget's minimum height to the new width."""
        super().resizeEvent(event)
        self.fit()

    def fit(self) -> None:
        """Set the widget's minimum height to what its layout needs at the visible width."""
        widget = self.widget()
        layout = widget.layout() if widget is not None else None
        if layout is None or not layout.hasHeightForWidth():
            return
        need = layout.minimumHeightForWidth(max(self.viewport().width(), 1))
        if need > 0 and widget.minimumHeight() != need:
            widget.setMinimumHeight(need)
