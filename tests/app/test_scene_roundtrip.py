"""Opening and saving a scene through the window's parameter panel changes no value.

The panel takes every range, step and default from ``engine.params.CONTROLS``; a scene's
value beyond a slider's comfortable stretch (K = 64 where the slider ends at 48) is shown in
the field and kept; Save as writes what the panel shows (``ParamsPanel.scene_settings``).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from types import SimpleNamespace

import pytest

from app.gui.params_panel import ParamsPanel
from app.gui.scene_file import write_scene
from engine.params import (
    CONTROLS,
    PENALTY_RANGE,
    SIGMA_GRID_MAX,
    DescriptorParams,
    check_modes,
)
from engine.scene import load_scene, scene_to_toml

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted(ROOT.glob("assets/**/scene.toml"))
PEG = ROOT / "assets" / "peg_in_hole" / "scene.toml"


def _open_and_save(qtbot, scene_path: Path, out: Path):
    """What the window does: show the scene in the panel, then Save as. (scene, saved)."""
    scene = load_scene(scene_path)
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    panel.load_config(scene.config, scene.modes, scene.descriptor)
    saved = write_scene(SimpleNamespace(scene=scene), out, **panel.scene_settings())
    return scene, load_scene(saved), panel


def test_the_project_has_scenes_to_round_trip():
    assert len(SCENES) >= 16, SCENES


@pytest.mark.parametrize("path", SCENES, ids=lambda p: str(p.parent.relative_to(ROOT)))
def test_opening_and_saving_a_scene_changes_no_value(qtbot, tmp_path, path):
    scene, again, _panel = _open_and_save(qtbot, path, tmp_path / "saved.toml")
    # every value the scene writer writes (file paths relative to one folder)
    assert scene_to_toml(again, tmp_path) == scene_to_toml(scene, tmp_path)
    assert again.modes == scene.modes and again.descriptor == scene.descriptor
    assert again.config == scene.config


def _scene_with(tmp_path: Path, **tables: dict[str, object]) -> Path:
    """The peg in hole with some of its settings replaced (files kept where they are)."""
    text = PEG.read_text(encoding="utf-8")
    for table, values in tables.items():
        for key, value in values.items():
            pattern = re.compile(rf"(?m)^{key}\s*=.*$")
            line = f"{key} = {value!r}".replace("'", '"')
            block = re.search(rf"(?ms)^\[{table}\]\n(.*?)(?=^\[|\Z)", text)
            if block and pattern.search(block.group(1)):
                body = pattern.sub(line, block.group(1), count=1)
                text = text[:block.start(1)] + body + text[block.end(1):]
            elif block:
                text = text[:block.start(1)] + line + "\n" + text[block.start(1):]
            else:
                text = f"{text.rstrip()}\n\n[{table}]\n{line}\n"
    out = tmp_path / "edge.toml"
    out.write_text(text.replace('file = "', f'file = "{PEG.parent}/'), encoding="utf-8")
    return out


def test_values_beyond_the_sliders_are_shown_and_kept(qtbot, tmp_path):
    path = _scene_with(tmp_path, correlation={"modes": 128},
                       descriptor={"sigma": SIGMA_GRID_MAX, "penalty": PENALTY_RANGE[0]},
                       simulation={"kappa": 5e12}, coupling={"frequency_hz": 120.0})
    scene, again, panel = _open_and_save(qtbot, path, tmp_path / "saved.toml")
    assert (scene.modes, scene.descriptor.sigma, scene.descriptor.penalty) == (
        128, SIGMA_GRID_MAX, PENALTY_RANGE[0])
    # shown: the fields hold the values, the sliders sit at their ends
    assert panel.modes.field.value() == 128
    assert panel.modes.slider.value() == panel.modes.slider.maximum()
    assert panel.sigma.field.value() == pytest.approx(SIGMA_GRID_MAX)
    assert panel.sigma.slider.value() == panel.sigma.slider.maximum()
    assert panel.penalty.slider.value() == panel.penalty.slider.minimum()
    assert panel.kappa.field.value() == pytest.approx(5e12)
    assert panel.coupling.value() == 120.0
    # kept: saved as they were
    assert again.modes == 128
    assert again.descriptor == scene.descriptor
    assert again.config.simulation.kappa == 5e12
    assert again.config.coupling == scene.config.coupling


def test_an_exact_value_between_the_fields_decimals_is_kept(qtbot, tmp_path):
    path = _scene_with(tmp_path, descriptor={"sigma": 0.43751, "penalty": 2.00049})
    scene, again, _panel = _open_and_save(qtbot, path, tmp_path / "saved.toml")
    assert again.descriptor.sigma == 0.43751 and again.descriptor.penalty == 2.00049


def test_a_value_decades_below_the_fields_decimals_is_shown(qtbot, tmp_path):
    """A logarithmic field shows significant digits: a kappa of 2.5e-5 is not "0.0000"."""
    path = _scene_with(tmp_path, simulation={"kappa": 2.5e-5},
                       descriptor={"penalty": 1.5e-3})
    scene, again, panel = _open_and_save(qtbot, path, tmp_path / "saved.toml")
    assert panel.kappa.field.text() == "2.5e-05" and panel.kappa.field.value() == 2.5e-5
    assert panel.penalty.field.text() == "0.0015"
    assert again.config.simulation.kappa == 2.5e-5 and again.descriptor.penalty == 1.5e-3
    panel.kappa.field.lineEdit().setText("7.25e-7")  # typed in the same notation
    panel.kappa.field.interpretText()
    assert panel.kappa.value() == 7.25e-7


def test_the_panel_starts_from_the_engines_defaults(qtbot):
    from engine.params import DEFAULT_UNIT, Effects, gravity_vector

    panel = ParamsPanel()
    qtbot.addWidget(panel)
    for name, widget in (("modes", panel.modes), ("sigma", panel.sigma),
                         ("penalty", panel.penalty), ("coupling_hz", panel.coupling)):
        assert widget.value() == CONTROLS[name].default, name
    assert panel.guidance.currentText() == Effects().guidance
    panel.gravity.setChecked(True)
    assert panel.scene_settings()["effects"].gravity == gravity_vector(DEFAULT_UNIT)


def test_a_scale_free_kappa_is_saved_as_the_default(qtbot, tmp_path):
    path = _scene_with(tmp_path, simulation={"kappa": 2.5})
    scene = load_scene(path)
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    panel.load_config(scene.config, scene.modes, scene.descriptor)
    assert panel.scene_settings()["kappa"] == 2.5
    panel.kappa_default.setChecked(True)  # back to the scale-free default
    saved = write_scene(SimpleNamespace(scene=scene), tmp_path / "s.toml",
                        **panel.scene_settings())
    assert load_scene(saved).config.simulation.kappa is None


def test_a_control_accepts_exactly_what_a_scene_may_hold(tmp_path):
    modes = CONTROLS["modes"]
    assert check_modes(int(modes.allowed[1])) == modes.allowed[1]
    with pytest.raises(ValueError):
        check_modes(int(modes.allowed[1]) + 1)
    for name in ("sigma", "penalty"):
        lo, hi = CONTROLS[name].allowed
        for value in (lo, hi):
            assert getattr(load_scene(_scene_with(tmp_path, descriptor={name: value})).descriptor,
                           name) == value
        for value in (lo * 0.99, hi * 1.01):
            with pytest.raises(ValueError, match=name):
                load_scene(_scene_with(tmp_path, descriptor={name: value}))
    assert CONTROLS["sigma"].default == DescriptorParams().sigma
    assert CONTROLS["penalty"].default == DescriptorParams().penalty


def test_a_typed_value_is_held_to_what_the_engine_accepts(qtbot):
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    panel.modes.setValue(1000)
    assert panel.modes.value() == CONTROLS["modes"].allowed[1]
    panel.sigma.setValue(1e-6)
    assert panel.sigma.value() == CONTROLS["sigma"].allowed[0]


def test_no_gui_control_carries_its_own_range():
    """Every SliderField in app/gui is built from engine.params.CONTROLS, not literals."""
    calls = []
    for source in sorted((ROOT / "app" / "gui").glob("*.py")):
        tree = ast.parse(source.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id == "SliderField"):
                calls.append((source.name, node))
    assert calls, "no SliderField found: the check looks in the wrong place"
    for name, node in calls:
        first = node.args[0] if node.args else None
        assert (isinstance(first, ast.Subscript) and isinstance(first.value, ast.Name)
                and first.value.id == "CONTROLS"), (
            f"{name}:{node.lineno}: a SliderField not built from CONTROLS[...]")
        assert not any(isinstance(a, ast.Constant) and isinstance(a.value, (int, float))
                       for a in node.args[1:]), f"{name}:{node.lineno}: a numeric literal"


@pytest.fixture(scope="module")
def generated_scenes(tmp_path_factory) -> list[Path]:
    """Scenes as a generated set makes them: ``skelasm scene new`` on two part files, every
    setting it chooses itself (bench.fitgen makes its scenes so).
    """
    from app.cli import main

    out = []
    for pair in ("peg_in_hole", "dovetail"):
        scene = load_scene(ROOT / "assets" / pair / "scene.toml")
        files = [str(p.file) for p in scene.parts]
        target = tmp_path_factory.mktemp(pair) / "scene.toml"
        pose = [repr(float(x)) for x in scene.assembled_pose]
        argv = ["scene", "new", *files, "-o", str(target), "--force", "--assembled", *pose]
        assert main(argv) == 0, argv
        out.append(target)
    return out


@pytest.mark.slow
def test_opening_and_saving_a_generated_scene_changes_no_value(qtbot, tmp_path,
                                                               generated_scenes):
    for path in generated_scenes:
        scene, again, _panel = _open_and_save(qtbot, path, tmp_path / f"{path.parent.name}.toml")
        assert scene_to_toml(again, tmp_path) == scene_to_toml(scene, tmp_path), path
        assert again.modes == scene.modes and again.descriptor == scene.descriptor
