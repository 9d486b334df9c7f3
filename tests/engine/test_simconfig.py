"""Simulation tables of a scene: defaults, scale with part size, errors with the line."""

from __future__ import annotations

import numpy as np
import pytest

from engine.simconfig import (
    AXES,
    SimConfigError,
    parse_simconfig,
)

TEXT = """name = "x"
assembled_pose = [0, 0, 0, 0, 0, 0]

[simulation]
rate_hz = 1000

[coupling]
frequency_hz = 12
stiffnes = 3

[effects]
guidance = "collision"
"""


def box(size=(1.0, 2.0, 4.0)):
    import trimesh

    m = trimesh.creation.box(extents=size)
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_defaults_with_no_tables():
    cfg = parse_simconfig({})
    assert cfg.simulation.rate_hz == 1000 and cfg.effects.axes == AXES
    assert cfg.effects.guidance == "skeletal" and cfg.device.kind == "mouse"


def test_unknown_key_names_its_line():
    sections = {"simulation": {"rate_hz": 1000}, "coupling": {"frequency_hz": 12, "stiffnes": 3},
                "effects": {"guidance": "collision"}}
    with pytest.raises(SimConfigError) as err:
        parse_simconfig(sections, path="s.toml", text=TEXT)
    msg = str(err.value)
    assert msg.startswith("s.toml:9: [coupling] stiffnes: unknown key")
    assert "stiffness" in msg  # lists the known keys


@pytest.mark.parametrize(
    "sections,match",
    [
        ({"simulation": {"rate_hz": -5}}, "rate_hz: must be positive"),
        ({"simulation": {"rate_hz": "fast"}}, "must be a number"),
        ({"effects": {"guidance": "magnets"}}, "must be one of skeletal, collision, none"),
        ({"effects": {"axes": ["x", "q"]}}, "axes: must be"),
        ({"effects": {"damping": 1}}, "must be true or false"),
        ({"effects": {"gravity": [0, 0]}}, "list of 3 numbers"),
        ({"device": {"kind": "joystick"}}, "must be one of mouse"),
        ({"device": {"kind": "trajectory"}}, "needs file"),
        ({"coupling": {"frequency_hz": 400}}, "too stiff"),
    ],
)
def test_bad_values(sections, match):
    with pytest.raises(SimConfigError, match=match):
        parse_simconfig(sections)


def test_part_mass_keys_and_bad_inertia():
    cfg = parse_simconfig({}, parts=({}, {"density": 2.0, "inertia": [1, 2, 3]}))
    assert cfg.masses[1].density == 2.0
    assert cfg.masses[1].inertia == ((1, 0, 0), (0, 2, 0), (0, 0, 3))
    with pytest.raises(SimConfigError, match="symmetric positive definite"):
        parse_simconfig({}, parts=({}, {"inertia": [1, -2, 3]}))
    with pytest.raises(SimConfigError, match=r"\[part\] colour: unknown key"):
        parse_simconfig({}, parts=({}, {"colour": "red"}))


def test_axes_words_and_gravity_in_scene_units():
    cfg = parse_simconfig({"effects": {"axes": "translation", "gravity": True}}, units="mm")
    assert not cfg.effects.rotation
    np.testing.assert_allclose(cfg.effects.gravity, [0, 0, -9810.0])
    cfg = parse_simconfig({"effects": {"axes": ["z", "rz"]}})
    np.testing.assert_array_equal(cfg.effects.translation_mask, [0, 0, 1])
    np.testing.assert_array_equal(cfg.effects.rotation_mask, [0, 0, 1])
    assert cfg.effects.rotation


def test_scene_file_sections_reach_simconfig(tmp_path):
    import trimesh

    from engine.scene import load_scene
    from engine.simconfig import simconfig_from_scene

    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "a.stl")
    text = (
        'units = "mm"\nassembled_pose = [0, 0, 0, 0, 0, 0]\n\n[effects]\naxes = "translation"\n'
        'damping = "yes"\n\n[[part]]\nname = "a"\nfile = "a.stl"\npose = [0, 0, 0, 0, 0, 0]\n\n'
        '[[part]]\nname = "b"\nfile = "a.stl"\npose = [0, 0, 2, 0, 0, 0]\nmass = 2.5\n'
    )
    (tmp_path / "s.toml").write_text(text)
    scene = load_scene(tmp_path / "s.toml")
    with pytest.raises(SimConfigError, match=r"s.toml:6: \[effects\] damping"):
        simconfig_from_scene(scene)
    (tmp_path / "s.toml").write_text(text.replace('damping = "yes"', "damping = false"))
    cfg = simconfig_from_scene(load_scene(tmp_path / "s.toml"))
    assert cfg.masses[1].mass == 2.5 and not cfg.effects.damping and not cfg.effects.rotation
