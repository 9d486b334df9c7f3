"""Undo and redo of the window's settings (K, sigma, penalty, kappa, coupling, effects)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from app.gui.params_panel import ParamsPanel
from engine import runtime
from engine.scene import load_scene

PEG = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"


def _panel(qtbot):
    scene = load_scene(PEG)
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    panel.load_config(scene.config, scene.modes, scene.descriptor)
    sent = []
    panel.command.connect(sent.append)
    return panel, sent


def test_each_setting_change_is_undone_and_redone_with_the_commands_that_apply_it(qtbot):
    panel, sent = _panel(qtbot)
    start = panel.scene_settings()
    assert not panel.can_undo() and not panel.undo()
    panel.modes.setValue(20)  # typed values apply at once
    panel.sigma.setValue(0.8)
    panel.kappa_default.setChecked(False)
    panel.kappa.setValue(3.0)
    changed = panel.scene_settings()
    assert changed["modes"] == 20 and changed["descriptor"].sigma == 0.8
    sent.clear()
    assert panel.undo()  # kappa back to the typed default's
    assert panel.undo()  # the kappa box unticked
    assert panel.undo()  # sigma
    assert [type(c) for c in sent][-1] is runtime.SetDescriptorParams
    assert sent[-1].params.sigma == start["descriptor"].sigma
    assert panel.sigma.value() == start["descriptor"].sigma
    assert panel.undo()  # K
    assert isinstance(sent[-1], runtime.SetModes) and sent[-1].modes == start["modes"]
    assert panel.scene_settings() == start and not panel.can_undo()
    while panel.redo():
        pass
    assert panel.scene_settings() == changed
    assert isinstance(sent[-1], runtime.SetKappa) and sent[-1].kappa == 3.0
    # a new change after an undo drops what could be redone
    panel.undo()
    panel.penalty.setValue(5.0)
    assert not panel.can_redo()


def test_a_cancelled_recompute_is_not_a_change_to_undo(qtbot):
    panel, sent = _panel(qtbot)
    panel.sigma.setValue(0.9)
    assert panel.can_undo()
    panel.recompute_ended("cancelled")  # the sigma before stays in use
    assert not panel.can_undo()
    effects = panel.scene_settings()["effects"]
    panel.set_effects(replace(effects, damping=not effects.damping))
    assert panel.undo()
    assert panel.scene_settings()["effects"] == effects
