"""Simulation tables of a scene: defaults, values, errors naming the line, part mass keys."""

from __future__ import annotations

import numpy as np
import pytest

from engine.params import AXES, SimConfig, gravity_vector
from engine.scene import SceneError, load_scene, save_scene

HEAD = """name = "x"
assembled_pose = [0, 0, 0, 0, 0, 0]

[[part]]
file = "a.stl"

[[part]]
file = "a.stl"
name = "b"
"""


@pytest.fixture
def folder(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(1, 2, 4)).export(tmp_path / "a.stl")
    return tmp_path


def scene_of(folder, text):
    path = folder / "s.toml"
    path.write_text(text)
    return load_scene(path)


def test_defaults_with_no_tables(folder):
    cfg = scene_of(folder, HEAD).config
    assert cfg == SimConfig(masses=cfg.masses)
    assert cfg.simulation.rate_hz == 1000 and cfg.effects.axes == AXES
    assert cfg.effects.guidance == "skeletal" and cfg.device.kind == "mouse"


def test_unknown_key_names_its_line_and_the_valid_keys(folder):
    text = HEAD + "\n[simulation]\nrate_hz = 1000\n\n[coupling]\nfrequency_hz = 12\nstiffnes = 3\n"
    with pytest.raises(SceneError) as err:
        scene_of(folder, text)
    msg = str(err.value)
    assert msg.startswith(f"{folder / 's.toml'}:16: unknown key 'stiffnes' in [coupling]; ")
    assert "valid keys: frequency_hz, damping_ratio, stiffness" in msg
    assert err.value.line == 16


@pytest.mark.parametrize(
    "table,match",
    [
        ("[simulation]\nrate_hz = -5", "rate_hz in \\[simulation\\] must be a positive number, "
                                       "got -5; remove the line for the default \\(1000"),
        ("[simulation]\nrate_hz = 'fast'", "must be a positive number"),
        ("[simulation]\nkappa = 'strong'", 'or "auto"'),
        ("[effects]\nguidance = 'magnets'", "must be one of skeletal, collision, none"),
        ("[effects]\naxes = ['x', 'q']", "axes in \\[effects\\] must be"),
        ("[effects]\ndamping = 1", "must be true or false"),
        ("[effects]\ngravity = [0, 0]", "must be 3 numbers"),
        ("[effects]\ngravity = true\ngravity_direction = [0, 0, 0]", "must not be zero"),
        ("[device]\nkind = 'joystick'", "must be one of mouse"),
        ("[device]\nkind = 'trajectory'", "needs a file"),
        ("[device]\nkind = 'mouse'\nport = 5", "unknown key 'port' in \\[device\\]"),
        ("[coupling]\nfrequency_hz = 400", "too stiff"),
        ("[correlation]\nselection = 'best'", "unknown key 'selection' in \\[correlation\\]"),
    ],
)
def test_bad_values_name_file_line_and_fix(folder, table, match):
    text = HEAD + "\n" + table + "\n"
    with pytest.raises(SceneError, match=match) as err:
        scene_of(folder, text)
    assert err.value.line is not None and err.value.line > 10
    assert str(err.value).startswith(f"{folder / 's.toml'}:{err.value.line}: ")
    assert "; " in str(err.value).split(": ", 1)[1]  # a fix follows the problem


def test_part_mass_keys_and_bad_inertia(folder):
    scene = scene_of(folder, HEAD + "density = 2.0\ninertia = [1, 2, 3]\n")
    assert scene.config.masses[1].density == 2.0
    assert scene.config.masses[1].inertia == ((1, 0, 0), (0, 2, 0), (0, 0, 3))
    assert scene.config.mass_spec(0).mass is None and scene.config.mass_spec(5).mass is None
    with pytest.raises(SceneError, match="symmetric positive definite") as err:
        scene_of(folder, HEAD + "inertia = [1, -2, 3]\n")
    assert err.value.line == 10
    with pytest.raises(SceneError, match="unknown key 'colour' in \\[\\[part\\]\\] #2"):
        scene_of(folder, HEAD + "colour = 'red'\n")


@pytest.mark.parametrize("units,g", [("mm", 9810.0), ("m", 9.81), ("ft", 9.81 / 0.3048),
                                      ("dm", 98.1)])
def test_axes_words_and_gravity_in_scene_units(folder, units, g):
    text = f'units = "{units}"\n' + HEAD + '\n[effects]\naxes = "translation"\ngravity = true\n'
    effects = scene_of(folder, text).config.effects
    assert not effects.rotation
    np.testing.assert_allclose(effects.gravity, [0, 0, -g])
    np.testing.assert_allclose(gravity_vector(units), [0, 0, -g])
    effects = scene_of(folder, HEAD + '\n[effects]\naxes = ["z", "rz"]\n').config.effects
    np.testing.assert_array_equal(effects.translation_mask, [0, 0, 1])
    np.testing.assert_array_equal(effects.rotation_mask, [0, 0, 1])
    assert effects.rotation


def test_trajectory_file_is_relative_to_the_scene_and_survives_a_move(folder):
    (folder / "push.csv").write_text("t,tx,ty,tz,rx,ry,rz\n0,0,0,0,0,0,0\n")
    scene = scene_of(folder, HEAD + '\n[device]\nkind = "trajectory"\nfile = "push.csv"\n')
    assert scene.config.device.option("file") == str((folder / "push.csv").resolve())
    (folder / "sub").mkdir()
    again = load_scene(save_scene(scene, folder / "sub" / "copy.toml"))
    assert again.config.device == scene.config.device
    assert 'file = "../push.csv"' in (folder / "sub" / "copy.toml").read_text()


def test_scene_tables_reach_the_config(folder):
    text = ('units = "mm"\n' + HEAD + "mass = 2.5\n\n[effects]\naxes = \"translation\"\n"
            'damping = "yes"\n')
    with pytest.raises(SceneError, match=r"s.toml:15: damping in \[effects\]"):
        scene_of(folder, text)
    cfg = scene_of(folder, text.replace('damping = "yes"', "damping = false")).config
    assert cfg.masses[1].mass == 2.5 and not cfg.effects.damping and not cfg.effects.rotation
