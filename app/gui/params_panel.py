"""The parameter panel: accuracy (m'), descriptor parameters, kappa, coupling and effects.

Beside the accuracy settings it shows what they cost now: the measured microseconds per
pose (the frames' ``eval_us``, a running median) and, for K, an estimate of the truncation
error (the share of the correlation spectrum's weight outside the kept cube, from
:class:`app.gui.accuracy.AccuracyIndicator`); beside sigma and penalty, the last recompute's
seconds. docs/accuracy.md says how to read them.

It only emits engine commands (``engine.runtime`` dataclasses) through :attr:`command`; the
window forwards them. The expensive parameters (K, sigma, penalty) apply when their slider is
let go or a typed value is entered, never while a slider moves: each starts a background
build, which the engine runs while the old field stays in use.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import replace

import numpy as np
from PySide6 import QtCore, QtWidgets

from app.gui.widgets import ElidedProgressBar, SliderField
from engine import runtime
from engine.descriptor.ladder import LADDER_SPAN
from engine.params import (
    AXES,
    CONTROLS,
    DEFAULT_UNIT,
    GUIDANCE,
    CouplingParams,
    DescriptorParams,
    Effects,
    gravity_vector,
)


class ParamsPanel(QtWidgets.QWidget):
    """Sliders and fields for the live parameters.

    Signals
    -------
    command(object)
        An ``engine.runtime`` command to send.
    descriptor_preview(object)
        While the sigma or penalty slider is held: the descriptor parameters it would
        apply (the slice view previews them).
    """

    command = QtCore.Signal(object)
    descriptor_preview = QtCore.Signal(object)

    def __init__(self, parent=None):
        super().__init__(parent)
        self._cost_modes = 0
        self._effects = Effects()
        self._coupling = CouplingParams()
        #: The scene's descriptor parameters: a recompute sends them with the panel's sigma
        #: and penalty, whole (the object built here reaches the kernels).
        self._descriptor = DescriptorParams()
        #: The sigma and penalty the engine's descriptors use, and those of a recompute
        #: sent and not yet applied (None: none running).
        self._in_use = (self._descriptor.sigma, self._descriptor.penalty)
        self._pending: tuple[float, float] | None = None
        # gravity in scene units per s^2 (the default unit until a scene says otherwise)
        self._gravity_vector: tuple[float, float, float] = gravity_vector(DEFAULT_UNIT)
        lay = QtWidgets.QVBoxLayout(self)
        lay.setContentsMargins(4, 4, 4, 4)

        acc = QtWidgets.QGroupBox("Accuracy (applies on release)")
        form = QtWidgets.QFormLayout(acc)
        self.modes = SliderField(CONTROLS["modes"], on_release=True)
        self.modes.setObjectName("modes")
        self.modes.setToolTip(
            "K: Fourier modes kept per axis (m' = K³ in all). More is more accurate and\n"
            "costs about K³ per evaluation; the new tables are built in the background.")
        self.modes_label = QtWidgets.QLabel()
        form.addRow("K (modes/axis)", self.modes)
        form.addRow("m' = K³", self.modes_label)
        self.pose_cost = QtWidgets.QLabel("-")
        self.pose_cost.setObjectName("pose_cost")
        self.pose_cost.setToolTip(
            "Measured time of the correlator per step (energy, force, torque) at the K in\n"
            "use: the median of the last frames. It grows about like K³.")
        self.truncation = QtWidgets.QLabel("-")
        self.truncation.setObjectName("truncation")
        self.truncation.setWordWrap(True)
        self.truncation.setToolTip(
            "Share of the correlation spectrum's weight |ρ1^|·|ρ2^| outside the K³ cube:\n"
            "a bound on the energy's truncation error relative to its largest value\n"
            "(at the scene's orientation; phases cancel, so the error is usually smaller);\n"
            "for the force the weight is |k|·|ρ1^|·|ρ2^| (the force reads higher\n"
            "frequencies). It says nothing of the grid or sigma. While the K slider is held\n"
            "it shows the values at the K it would apply. See docs/accuracy.md.")
        form.addRow("cost now", self.pose_cost)
        form.addRow("error bound", self.truncation)
        self._pose_us: deque[float] = deque(maxlen=50)
        self._profile: np.ndarray | None = None
        self.modes.valueChanged.connect(self._modes_changed)
        self.modes.previewed.connect(lambda k: self._show_truncation(int(k)))
        self._show_modes(int(self.modes.value()))
        lay.addWidget(acc)

        desc = QtWidgets.QGroupBox("Descriptors (apply on release)")
        form = QtWidgets.QFormLayout(desc)
        self.sigma = SliderField(CONTROLS["sigma"], on_release=True)
        self.penalty = SliderField(CONTROLS["penalty"], on_release=True)
        lo, hi = LADDER_SPAN
        self.sigma.setToolTip(
            "Width of the skeletal density's kernel (dimensionless). Applies when the slider "
            f"is let go\nor a typed value is entered. Live sigma: {lo:g} to {hi:g} reach the "
            "scene's grid within seconds,\ninterpolated from descriptors at a few sigmas that "
            "the engine prepares in the background\nafter a scene opens (\"preparing live "
            "sigma\" in the status bar; cached for the next time).\nOther sigmas, or before "
            "then: a coarse grid within seconds, then the scene's grid.\nWhile the slider is "
            "held the slice view previews it.")
        self.penalty.setToolTip("Penalty P = lambda_in / lambda_out: how much more an overlap "
                                "costs than a gap.\nA new penalty rescales the descriptors "
                                "(a second or so); the slice view previews it while held.")
        form.addRow("sigma", self.sigma)
        form.addRow("penalty P", self.penalty)
        self.progress = ElidedProgressBar()
        self.progress.setRange(0, 1000)
        self.progress.setValue(0)
        self.progress.setTextVisible(True)
        self.progress.setFormat("idle")
        self.cancel = QtWidgets.QPushButton("Cancel")
        self.cancel.setEnabled(False)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(self.progress, 1)
        row.addWidget(self.cancel)
        form.addRow(row)
        self.recompute_cost = QtWidgets.QLabel("a change recomputes both descriptors")
        self.recompute_cost.setObjectName("recompute_cost")
        self.recompute_cost.setWordWrap(True)
        self.recompute_cost.setToolTip(
            "sigma costs once, when the descriptors are recomputed (seconds on a coarse\n"
            "grid, up to a minute on a fine one); a penalty rescales them; the cost per pose\n"
            "does not change.")
        form.addRow("cost", self.recompute_cost)
        self.in_use = QtWidgets.QLabel("-")
        self.in_use.setObjectName("descriptors_in_use")
        self.in_use.setWordWrap(True)
        self.in_use.setToolTip("The sigma and penalty of the descriptors the engine uses now;\n"
                               "a cancelled or failed recompute leaves them, and the boxes "
                               "show them again.")
        form.addRow("in use", self.in_use)
        #: Undo and redo of the settings: the states before each change, and after undos
        self._undo: list[dict[str, object]] = []
        self._redo: list[dict[str, object]] = []
        self._state: dict[str, object] | None = None  # the settings as last applied
        self._replaying = False  # an undo or redo sends the commands: not a new change
        self.command.connect(self._record)
        self.sigma.valueChanged.connect(lambda _v: self._send_descriptor_params())
        self.sigma.previewed.connect(lambda v: self.descriptor_preview.emit(
            replace(self.descriptor_params(), sigma=float(v))))
        self.penalty.previewed.connect(lambda v: self.descriptor_preview.emit(
            replace(self.descriptor_params(), penalty=float(v))))
        self.penalty.valueChanged.connect(lambda _v: self._send_descriptor_params())
        self.cancel.clicked.connect(self._cancel)
        lay.addWidget(desc)

        sim = QtWidgets.QGroupBox("Forces")
        form = QtWidgets.QFormLayout(sim)
        self.kappa_default = QtWidgets.QCheckBox("scale-free default")
        self.kappa_default.setChecked(True)
        self.kappa_default.setToolTip(
            "kappa scales the fit's energy E = -kappa Re f. The scale-free default ties it\n"
            "to the coupling stiffness and the part's size; untick to set it yourself.")
        self.kappa = SliderField(CONTROLS["kappa"], on_release=True)
        self.kappa.setEnabled(False)
        self.kappa_value = QtWidgets.QLabel("kappa: -")
        self.kappa_value.setObjectName("kappa_value")
        self.kappa_value.setWordWrap(True)
        form.addRow("kappa", self.kappa_default)
        form.addRow("", self.kappa)
        form.addRow("", self.kappa_value)
        self.coupling = SliderField(CONTROLS["coupling_hz"], suffix=" Hz")
        self.coupling.setToolTip(
            "Coupling stiffness as the natural frequency of part + spring: k = m (2 pi f)^2,\n"
            "so the same setting works whatever the unit of length."
        )
        form.addRow("coupling", self.coupling)
        self.kappa_default.toggled.connect(self._kappa_changed)
        self.kappa.valueChanged.connect(lambda _v: self._kappa_changed())
        self.coupling.valueChanged.connect(self._coupling_changed)
        lay.addWidget(sim)

        eff = QtWidgets.QGroupBox("Effects")
        form = QtWidgets.QFormLayout(eff)
        self.guidance = QtWidgets.QComboBox()
        self.guidance.addItems(GUIDANCE)
        self.rotation = QtWidgets.QCheckBox("rotation free")
        self.rotation.setToolTip(
            "Free: the part turns under the fit's torque. Locked: it only slides, and the\n"
            "engine builds a translation landscape for the locked orientation.")
        self.damping = QtWidgets.QCheckBox("damping")
        self.gravity = QtWidgets.QCheckBox("gravity")
        form.addRow("guidance", self.guidance)
        box = QtWidgets.QHBoxLayout()
        for w in (self.rotation, self.damping, self.gravity):
            box.addWidget(w)
        form.addRow(box)
        self.set_effects(self._effects, emit=False)
        self.guidance.currentTextChanged.connect(lambda _t: self._effects_changed())
        for w in (self.rotation, self.damping, self.gravity):
            w.toggled.connect(lambda _b: self._effects_changed())
        lay.addWidget(eff)

        buttons = QtWidgets.QHBoxLayout()
        self.pause = QtWidgets.QPushButton("Pause")
        self.pause.setCheckable(True)
        self.reset = QtWidgets.QPushButton("Reset pose")
        buttons.addWidget(self.pause)
        buttons.addWidget(self.reset)
        self.pause.toggled.connect(self._pause_toggled)
        self.reset.clicked.connect(lambda: self.command.emit(runtime.Reset()))
        lay.addLayout(buttons)
        lay.addStretch(1)

    # ------------------------------------------------------------------ from the scene
    def load_config(self, config, modes: int, descriptor: DescriptorParams) -> None:
        """Show a scene's settings (its SimConfig, K, ``[descriptor]``) without sending anything."""
        self.modes.setValueSilently(modes)
        self._pose_us.clear()
        self.pose_cost.setText("-")
        self.set_truncation_profile(None)
        self.recompute_cost.setText("a change recomputes both descriptors")
        self._show_modes(modes)
        self._descriptor = descriptor
        self.sigma.setValueSilently(descriptor.sigma)
        self.penalty.setValueSilently(descriptor.penalty)
        self._pending = None
        self._show_in_use((descriptor.sigma, descriptor.penalty))
        self._coupling = config.coupling
        self.coupling.setValueSilently(config.coupling.frequency_hz)
        kappa = config.simulation.kappa
        self.kappa_default.blockSignals(True)
        self.kappa_default.setChecked(kappa is None)
        self.kappa_default.blockSignals(False)
        self.kappa.setEnabled(kappa is not None)
        if kappa is not None:
            self.kappa.setValueSilently(kappa)
        self._gravity_vector = gravity_vector(config.units)
        self.set_effects(config.effects, emit=False)
        self.set_progress(None)
        self._undo.clear()
        self._redo.clear()
        self._state = self.scene_settings()

    # ------------------------------------------------------------------ undo / redo
    def _record(self, command) -> None:
        """Keep the settings before a change the user made (K, sigma, penalty, kappa, ...)."""
        if self._replaying or self._state is None:
            return
        now = self.scene_settings()
        if now != self._state:
            self._undo.append(self._state)
            del self._undo[:-100]
            self._redo.clear()
            self._state = now

    def can_undo(self) -> bool:
        """Whether there is a settings change to undo."""
        return bool(self._undo)

    def can_redo(self) -> bool:
        """Whether there is an undone settings change to redo."""
        return bool(self._redo)

    def undo(self) -> bool:
        """Go back to the settings before the last change (sending what differs)."""
        if not self._undo or self._state is None:
            return False
        self._redo.append(self.scene_settings())
        self._apply(self._undo.pop())
        return True

    def redo(self) -> bool:
        """Apply the settings the last undo left."""
        if not self._redo:
            return False
        self._undo.append(self.scene_settings())
        self._apply(self._redo.pop())
        return True

    def _apply(self, state: dict[str, object]) -> None:
        """Show ``state`` and send the engine the commands for what differs from now."""
        now = self.scene_settings()
        self._replaying = True
        try:
            if state["modes"] != now["modes"]:
                k = int(state["modes"])  # type: ignore[call-overload]
                self.modes.setValueSilently(k)
                self._modes_changed(k)
            d, d_now = state["descriptor"], now["descriptor"]
            if (d.sigma, d.penalty) != (d_now.sigma, d_now.penalty):  # type: ignore[attr-defined]
                self.sigma.setValueSilently(d.sigma)  # type: ignore[attr-defined]
                self.penalty.setValueSilently(d.penalty)  # type: ignore[attr-defined]
                self._send_descriptor_params()
            if state["effects"] != now["effects"]:
                self.set_effects(state["effects"])  # type: ignore[arg-type]
            if state["coupling"] != now["coupling"]:
                self._coupling = state["coupling"]  # type: ignore[assignment]
                self.coupling.setValueSilently(self._coupling.frequency_hz)
                self.command.emit(runtime.SetCoupling(self._coupling))
            if state["kappa"] != now["kappa"]:
                kappa = state["kappa"]
                self.kappa_default.blockSignals(True)
                self.kappa_default.setChecked(kappa is None)
                self.kappa_default.blockSignals(False)
                if kappa is not None:
                    self.kappa.setValueSilently(float(kappa))  # type: ignore[arg-type]
                self._kappa_changed()
        finally:
            self._replaying = False
        self._state = self.scene_settings()

    def scene_settings(self) -> dict[str, object]:
        """What the panel shows, as the scene writer's keywords (``write_scene``).

        The panel is the one source of what is saved: K, sigma and penalty exactly as shown
        (a scene's value beyond a slider's stretch included), the effects, the coupling and
        kappa (None: the scale-free default).
        """
        return {
            "modes": int(self.modes.value()),
            "descriptor": self.descriptor_params(),
            "effects": self._effects,
            "coupling": self._coupling,
            "kappa": None if self.kappa_default.isChecked() else self.kappa.value(),
        }

    def set_effects(self, effects: Effects, *, emit: bool = True) -> None:
        """Show ``effects`` in the panel's controls; with ``emit``, send them to the engine.

        The controls are updated without emitting their own signals, so setting effects from the
        engine's state does not echo back as a command.
        """
        self._effects = effects
        if effects.gravity is not None:
            self._gravity_vector = effects.gravity
        widgets = (self.guidance, self.rotation, self.damping, self.gravity)
        for w in widgets:
            w.blockSignals(True)
        self.guidance.setCurrentText(effects.guidance)
        self.rotation.setChecked(effects.rotation)
        self.damping.setChecked(effects.damping)
        self.gravity.setChecked(effects.gravity is not None)
        for w in widgets:
            w.blockSignals(False)
        if emit:
            self.command.emit(runtime.SetEffects(effects))

    def show_kappa(self, value: float, unit: str) -> None:
        """Show the kappa the engine uses (its value, not the slider's), in ``unit``."""
        default = self.kappa_default.isChecked()
        origin = "the scale-free default" if default else "set here"
        self.kappa_value.setText(f"kappa = {value:.4g} {unit} ({origin})")
        if default:
            self.kappa.setValueSilently(value)  # a custom kappa starts from the one in use

    # ------------------------------------------------------------------ what accuracy costs
    def show_pose_cost(self, eval_us: float, modes: int) -> None:
        """Add one frame's correlator microseconds at ``modes``; show the running median."""
        if not (math.isfinite(eval_us) and eval_us >= 0):
            return
        if modes != self._cost_modes:
            self._pose_us.clear()  # a new K: the old figures no longer say anything
            self._cost_modes = modes
        self._pose_us.append(float(eval_us))
        # statistics, not numpy: np.median drops references to None on this Python (see
        # tests/app/test_binding.py), and this runs on every readout
        median = float(statistics.median(self._pose_us))
        self.pose_cost.setText(f"{median:.0f} µs per pose at K = {modes}")

    def set_truncation_profile(self, profile: np.ndarray | None) -> None:
        """Use ``profile``: (2, N + 1) float64, the energy's and the force's share per K.

        None: unknown (no pair, or before the first profile came).
        """
        self._profile = None if profile is None else np.asarray(profile, dtype=float)
        self._show_truncation(None)

    def truncation_at(self, k: int) -> tuple[float, float] | None:
        """The energy's and the force's share outside K³, None before a profile came."""
        if self._profile is None or self._profile.shape[-1] == 0:
            return None
        i = min(max(int(k), 0), self._profile.shape[-1] - 1)
        return float(self._profile[0, i]), float(self._profile[1, i])

    def show_descriptor_cost(self, seconds: float) -> None:
        """Show the last descriptor recompute's seconds (what a sigma or penalty costs)."""
        self.recompute_cost.setText(f"last recompute {seconds:.1f} s; per pose unchanged")

    def _show_truncation(self, preview: int | None) -> None:
        current = int(self.modes.value())
        now = self.truncation_at(current)
        if now is None:
            self.truncation.setText("-")
            return
        text = (f"energy ≤ {_percent(now[0])}, force ≤ {_percent(now[1])} at K = {current} "
                "(weight outside K³)")
        at = self.truncation_at(preview) if preview is not None else None
        if at is not None and preview != current:
            text = (f"at K = {preview} if applied: energy ≤ {_percent(at[0])}, force ≤ "
                    f"{_percent(at[1])} (now {_percent(now[0])}, {_percent(now[1])})")
        self.truncation.setText(text)

    # ------------------------------------------------------------------ progress
    def set_progress(self, fraction: float | None, text: str = "", *,
                     cancellable: bool = True) -> None:
        """Show a running task (0..1; -1: running, fraction unknown) or, with None, an idle bar.

        ``text`` is the bar's caption (``%p`` is the percentage).
        """
        if fraction is None:
            self.progress.setRange(0, 1000)
            self.progress.setValue(0)
            self.progress.setFormat(text or "idle")
            self.cancel.setEnabled(False)
            return
        if fraction < 0:  # busy, with no fraction to show
            self.progress.setRange(0, 0)
        else:
            self.progress.setRange(0, 1000)
            self.progress.setValue(int(round(1000 * min(max(fraction, 0.0), 1.0))))
        self.progress.setFormat(text or "recomputing descriptors %p%")
        self.cancel.setEnabled(cancellable)

    # ------------------------------------------------------------------ handlers
    def _show_modes(self, k: int) -> None:
        self.modes_label.setText(f"{k ** 3:,} modes")
        self._show_truncation(None)

    def _modes_changed(self, k: float) -> None:
        self._show_modes(int(k))
        self.command.emit(runtime.SetModes(int(k)))

    def descriptor_params(self) -> DescriptorParams:
        """The descriptor's parameters as shown: the scene's, with the panel's sigma and penalty."""
        return replace(self._descriptor, sigma=self.sigma.value(), penalty=self.penalty.value())

    def _send_descriptor_params(self) -> None:
        self.set_progress(0.0, "starting recompute")
        params = self.descriptor_params()
        self._pending = (params.sigma, params.penalty)
        self._show_in_use(self._in_use)
        self.command.emit(runtime.SetDescriptorParams(params=params))

    def _show_in_use(self, values: tuple[float, float]) -> None:
        self._in_use = values
        text = f"sigma {values[0]:.4g}, penalty {values[1]:.4g}"
        if self._pending is not None and self._pending != values:
            text += (f" (until sigma {self._pending[0]:.4g}, penalty {self._pending[1]:.4g} "
                     "are ready)")
        self.in_use.setText(text)

    def descriptors_applied(self) -> None:
        """The engine swapped in new descriptors: those of the recompute sent, if any."""
        if self._pending is not None:
            values, self._pending = self._pending, None
            self._show_in_use(values)
        self.descriptor_preview.emit(None)  # what was previewed is in use now

    def recompute_ended(self, text: str) -> None:
        """A recompute was cancelled or failed: the boxes show the values in use again."""
        self._pending = None
        self.descriptor_preview.emit(None)
        self.sigma.setValueSilently(self._in_use[0])
        self.penalty.setValueSilently(self._in_use[1])
        now = self.scene_settings()
        if self._undo and self._undo[-1] == now:  # the change did not happen: nothing to undo
            self._undo.pop()
        self._state = now
        self._show_in_use(self._in_use)
        self.set_progress(None, f"{text}; sigma {self._in_use[0]:.4g} in use")

    def _cancel(self) -> None:
        self.command.emit(runtime.CancelRecompute())
        self.recompute_ended("cancelled")

    def _kappa_changed(self, *_args) -> None:
        custom = not self.kappa_default.isChecked()
        self.kappa.setEnabled(custom)
        self.command.emit(runtime.SetKappa(self.kappa.value() if custom else None))

    def _coupling_changed(self, hz: float) -> None:
        # absolute gains would override the frequency; the slider speaks frequency only
        self._coupling = replace(self._coupling, frequency_hz=hz, stiffness=None,
                                 angular_stiffness=None, damping=None, angular_damping=None)
        self.command.emit(runtime.SetCoupling(self._coupling))

    def _effects_changed(self) -> None:
        axes = AXES if self.rotation.isChecked() else AXES[:3]
        kept = [a for a in self._effects.axes if a in AXES[:3]] or list(AXES[:3])
        if self.rotation.isChecked():
            axes = tuple(kept) + AXES[3:]
        else:
            axes = tuple(kept)
        gravity = None
        if self.gravity.isChecked():
            gravity = self._gravity_vector
        effects = Effects(guidance=self.guidance.currentText(), axes=axes,
                          damping=self.damping.isChecked(), gravity=gravity)
        self._effects = effects
        self.command.emit(runtime.SetEffects(effects))

    def _pause_toggled(self, paused: bool) -> None:
        self.pause.setText("Resume" if paused else "Pause")
        self.command.emit(runtime.Pause(paused))


def _percent(share: float) -> str:
    """A share as a percentage with two significant digits (0.0431 -> "4.3 %")."""
    return f"{100.0 * share:.2g} %"
