"""Scene files: parsing, defaults, errors with line numbers, save and reload."""

from __future__ import annotations

import textwrap
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from engine.loading import _edge_defects
from engine.params import DEFAULT_GRID, DEFAULT_MODES, MassSpec, SimConfig
from engine.pose import compose, pose_to_matrix
from engine.scene import (
    SceneError,
    key_line,
    load_scene,
    load_scene_parts,
    relative_start_pose,
    save_scene,
)

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "assets").glob("*/scene.toml"))

MINIMAL = """\
assembled_pose = [0, 0, -15, 0, 0, 0]

[[part]]
file = "block.step"

[[part]]
file = "peg.step"
pose = [1, 2, 3, 0, 0, 0.5]
"""


@pytest.fixture
def scene_dir(tmp_path):
    src = ROOT / "assets" / "peg_in_hole"
    for name in ("block.step", "peg.step"):
        (tmp_path / name).write_bytes((src / name).read_bytes())
    return tmp_path


def write(folder: Path, text: str, name: str = "scene.toml") -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


def test_example_scenes_exist():
    assert {p.parent.name for p in SCENES} == {"peg_in_hole", "boss_pins", "bracket_slot",
                                              "dovetail"}


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.parent.name)
def test_example_scene_is_consistent(path):
    scene = load_scene(path)
    assert scene.units == "mm"
    assert len(scene.parts) == 2
    assert scene.parts[0].fixed and not scene.parts[1].fixed
    assert np.allclose(scene.parts[0].pose, 0)
    assert 48 <= scene.descriptor.grid <= 64
    axis = scene.insertion_axis
    assert axis is not None and np.linalg.norm(axis) == pytest.approx(1.0)
    # the start pose is the assembled pose backed off along the insertion axis, no rotation
    start = relative_start_pose(scene)
    offset = start[:3] - scene.assembled_pose[:3]
    assert np.allclose(start[3:], 0) and np.allclose(scene.assembled_pose[3:], 0)
    back = -float(offset @ axis)
    assert back > 0
    assert np.allclose(offset, -back * axis)
    # parts are closed, and at the start they do not overlap (boxes separated along the axis)
    fixed, moving = load_scene_parts(scene)
    for part in (fixed, moving):
        assert _edge_defects(part.faces) == (0, 0)
    lo2, hi2 = moving.bounds + start[:3]
    lo1, hi1 = fixed.bounds
    gap = np.maximum(lo2 - hi1, lo1 - hi2).max()
    assert gap > 0


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.parent.name)
def test_assembled_parts_interlock_without_overlap(path):
    """At the assembled pose the parts touch (zero clearance) but do not overlap.

    Sample points of the moving part's surface, pushed slightly inwards, must lie outside
    the fixed part; pushed outwards, some (those on the mating faces) must lie inside it.
    """
    import trimesh

    scene = load_scene(path)
    fixed, moving = load_scene_parts(scene)
    m1 = trimesh.Trimesh(fixed.vertices, fixed.faces, process=False)
    m2 = trimesh.Trimesh(moving.vertices, moving.faces, process=False)
    m2.apply_transform(pose_to_matrix(scene.assembled_pose))
    points, index = trimesh.sample.sample_surface_even(m2, 3000, seed=1)
    normals = m2.face_normals[index]
    eps = 0.05
    inside_in = m1.contains(points - eps * normals)  # inside the moving part
    inside_out = m1.contains(points + eps * normals)  # just outside the moving part
    assert inside_in.mean() < 0.01  # no interpenetration
    assert inside_out.mean() > 0.05  # the mating faces touch


def test_minimal_scene_defaults(scene_dir):
    scene = load_scene(write(scene_dir, MINIMAL))
    assert scene.name == scene_dir.name and scene.units == "mm"
    assert scene.descriptor.grid == DEFAULT_GRID and scene.descriptor.spacing is None
    assert scene.modes == DEFAULT_MODES and scene.insertion_axis is None
    assert [p.name for p in scene.parts] == ["block", "peg"]
    assert scene.parts[1].file == (scene_dir / "peg.step").resolve()
    assert scene.config == SimConfig(masses=(MassSpec(), MassSpec()))
    np.testing.assert_allclose(relative_start_pose(scene), [1, 2, 3, 0, 0, 0.5])
    params = scene.descriptor
    assert (params.sigma, params.penalty, params.lambda_out) == (0.5, 3.0, 1.0)


def test_relative_start_pose_with_a_moved_fixed_part(scene_dir):
    text = MINIMAL.replace('file = "block.step"', 'file = "block.step"\npose = [5, 0, 0, 0, 0, 1]')
    scene = load_scene(write(scene_dir, text))
    rel = relative_start_pose(scene)
    np.testing.assert_allclose(compose(scene.parts[0].pose, rel), scene.parts[1].pose, atol=1e-12)


def test_simulation_tables_and_mass_keys_are_read_with_the_rest(scene_dir):
    text = MINIMAL + '\nmass = 0.2\n\n[simulation]\nrate_hz = 500\n\n[device]\nkind = "udp"\n'
    scene = load_scene(write(scene_dir, text))
    assert scene.config.simulation.rate_hz == 500 and scene.config.device.kind == "udp"
    assert scene.config.masses == (MassSpec(), MassSpec(mass=0.2))
    with pytest.raises(SceneError, match="kind in \\[device\\] must be one of mouse"):
        load_scene(write(scene_dir, text.replace('"udp"', '"csv"')))


@pytest.mark.parametrize(
    "text, line, pattern",
    [
        # unknown keys name the line and list the valid ones
        (MINIMAL.replace("[[part]]\nfile = \"peg", "[[part]]\ncolour = 1\nfile = \"peg"), 7,
         "unknown key 'colour' in \\[\\[part\\]\\] #2; valid keys: name, file, pose"),
        (MINIMAL + "\n[descriptor]\nsigma = 0.5\nsgima = 1\n", 12,
         "unknown key 'sgima' in \\[descriptor\\]; valid keys: sigma, penalty"),
        ("speed = 3\n" + MINIMAL, 1, "unknown key 'speed' in the scene"),
        (MINIMAL + "\n[descriptor]\nsigma = -1\n", 11,
         "sigma in \\[descriptor\\] must be a positive number, got -1; remove the line "
         "for the default \\(0.5\\)"),
        (MINIMAL + "\n[descriptor]\ngrid = 64\nspacing = 0.5\n", 12, "grid or spacing"),
        (MINIMAL + "\n[descriptor]\ngrid = 6.5\n", 11,
         "grid in \\[descriptor\\] must be an integer"),
        (MINIMAL + "\n[correlation]\nmodes = 0\n", 11, "modes"),
        (MINIMAL + "\n[correlation]\nmodes = \"fast\"\n", 11,
         "modes in \\[correlation\\] must be an integer from 1 to .* or \"auto\""),
        (MINIMAL.replace("pose = [1, 2, 3, 0, 0, 0.5]", "pose = [1, 2, 3]"), 8,
         "pose in \\[\\[part\\]\\] #2 must be six numbers"),
        (MINIMAL.replace("peg.step", "nothing.step"), 7, "part file 'nothing.step' not found"),
        ('units = "furlong"\n' + MINIMAL, 1,
         "units in the scene must be one of .*mm.*; write the unit"),
        (MINIMAL.replace("[[part]]\nfile = \"peg", "[[part]]\nfixed = true\nfile = \"peg"), 7,
         "first \\[\\[part\\]\\] is the fixed one"),
        (MINIMAL.replace("assembled_pose = [0, 0, -15, 0, 0, 0]", "assembled_pose = [0, 0, 'a']"),
         1, "assembled_pose in the scene must be six numbers"),
        ("insertion_axis = [0, 0, 0]\n" + MINIMAL, 1, "insertion_axis must not be zero"),
        (MINIMAL.replace('file = "peg.step"', 'file = "peg.step"\nname = "block"'), 8,
         "two parts named 'block'"),
        (MINIMAL + "[[part]]\nfile = \"peg.step\"\n", 9, "3 \\[\\[part\\]\\] tables"),
        (MINIMAL.replace('file = "peg.step"\n', ""), 6, "\\[\\[part\\]\\] #2 has no file"),
        # bad TOML: tomllib's own line
        (MINIMAL.replace("[[part]]\nfile = \"peg", "[[part]]\nname = peg\nfile = \"peg"), 7,
         "not valid TOML"),
        (MINIMAL.replace("pose = [1, 2, 3, 0, 0, 0.5]", "pose = [1, 2, 3, 0, 0, 0.5"), 8,
         "not valid TOML.*end of document"),
    ],
)
def test_errors_name_the_line(scene_dir, text, line, pattern):
    path = write(scene_dir, text)
    with pytest.raises(SceneError, match=pattern) as info:
        load_scene(path)
    assert info.value.line == line, str(info.value)
    assert str(info.value).startswith(f"{path}:{line}: ")
    assert isinstance(info.value, ValueError)


def test_missing_assembled_pose_and_parts(scene_dir):
    # an assembled pose is optional (skelasm search finds the fits); what needs it says so
    from engine.scene import require_assembled

    bare = load_scene(write(scene_dir, MINIMAL.replace("assembled_pose = [0, 0, -15, 0, 0, 0]",
                                                       "")))
    assert not bare.assembled_known and not bare.assembled_pose.any()
    with pytest.raises(SceneError, match="run `skelasm search .*` to find the fits"):
        require_assembled(bare, "the test")
    require_assembled(load_scene(write(scene_dir, MINIMAL)), "the test")
    with pytest.raises(SceneError, match="no \\[\\[part\\]\\] tables"):
        load_scene(write(scene_dir, "assembled_pose = [0, 0, 0, 0, 0, 0]\n"))
    with pytest.raises(SceneError, match="no such scene file"):
        load_scene(scene_dir / "absent.toml")


def test_key_line_lookup():
    text = textwrap.dedent("""\
        a = 1
        [t]
        b = 2   # comment
        "c" = 3
        [[p]]
        x = 1
        [[p]]
        x = 2
        [t.sub]
        b = 9
        """)
    assert key_line(text, (), "a") == 1
    assert key_line(text, ("t",), "b") == 3
    assert key_line(text, ("t",), "c") == 4
    assert key_line(text, ("p", 1), "x") == 8
    assert key_line(text, ("p", 1)) == 7
    assert key_line(text, ("t", "sub"), "b") == 10
    assert key_line(text, ("t",), "zzz") == 2  # falls back to the table's header
    assert key_line(text, ("nothing",), "x") is None


EVERY_TABLE = MINIMAL + textwrap.dedent("""\
    mass = 0.25
    tolerance = 0.02
    unit = "cm"
    pivot = [1, 2, 3]
    hold = [0, 0, -4]
    inertia = [[2, 0.1, 0], [0.1, 3, 0], [0, 0, 4]]
    center_of_mass = [0, 0, 1.5]

    [descriptor]
    spacing = 0.75
    sigma = 0.7
    penalty = 2.5
    lambda_out = 1.5
    padding = 3

    [correlation]
    modes = 12

    [simulation]
    rate_hz = 500
    kappa = 0.3
    guidance_gain = 0.4
    body_damping_ratio = 0.25
    seconds = 2

    [coupling]
    frequency_hz = 8.0
    damping_ratio = 0.7
    stiffness = 40
    angular_damping = 0.01

    [effects]
    guidance = "collision"
    axes = ["z", "rz"]
    damping = false
    gravity = true
    gravity_direction = [0, -1, 0]

    [device]
    kind = "udp"
    max_force = 4.0
    force_scale = 0.5
    port = 9000
    host = "127.0.0.1"
    """)


def assert_same_scene(a, b):
    """Every field of two scenes is equal (the path aside)."""
    for f in fields(a):
        # given and chosen say where the values came from (the file, the parts), not what
        # they are: a saved scene gives every value it writes
        if f.name in ("path", "parts", "assembled_pose", "insertion_axis", "given", "chosen"):
            continue
        assert getattr(a, f.name) == getattr(b, f.name), f.name
    np.testing.assert_array_equal(a.assembled_pose, b.assembled_pose)
    assert (a.insertion_axis is None) == (b.insertion_axis is None)
    if a.insertion_axis is not None:
        np.testing.assert_array_equal(a.insertion_axis, b.insertion_axis)
    assert len(a.parts) == len(b.parts)
    for pa, pb in zip(a.parts, b.parts, strict=True):
        for f in fields(pa):
            va, vb = getattr(pa, f.name), getattr(pb, f.name)
            if isinstance(va, np.ndarray) or isinstance(vb, np.ndarray):
                np.testing.assert_array_equal(va, vb, err_msg=f.name)
            else:
                assert va == vb, f.name


def test_save_and_reload_round_trip_keeps_every_field(scene_dir, tmp_path):
    scene = load_scene(write(scene_dir, 'insertion_axis = [0, 0, -2]\n' + EVERY_TABLE))
    # the values really differ from the defaults, so the comparison can fail
    assert scene.config.effects.gravity == pytest.approx((0, -9810.0, 0))
    assert scene.parts[1].unit == "cm" and scene.config.masses[1].inertia[0][1] == 0.1
    assert scene.correlation.modes == 12 and scene.config.device.option("port")
    np.testing.assert_array_equal(scene.parts[1].hold, [0, 0, -4])
    out = tmp_path / "elsewhere" / "deeper" / "copy.toml"  # folders made by the writer
    again = load_scene(save_scene(scene, out))
    assert_same_scene(again, scene)
    np.testing.assert_allclose(again.insertion_axis, [0, 0, -1])
    assert again.descriptor.spacing == 0.75 and again.descriptor.grid is None
    assert "../" in out.read_text()  # part files written relative to the new location
    # a scene without units stays without (its warning about mesh units survives a save)
    bare = load_scene(save_scene(load_scene(write(scene_dir, MINIMAL)), tmp_path / "b.toml"))
    assert not bare.units_declared and "units" not in (tmp_path / "b.toml").read_text()


def test_saved_arrays_sit_on_one_line_and_read_back_the_same(scene_dir, tmp_path):
    scene = load_scene(write(scene_dir, 'insertion_axis = [0, 0, -2]\n' + EVERY_TABLE))
    text = save_scene(scene, tmp_path / "s.toml").read_text()
    pose_lines = [line for line in text.splitlines() if line.startswith("pose = ")]
    assert len(pose_lines) == 2 and all(line.endswith("]") for line in pose_lines)
    assert any(line.startswith("inertia = [[") for line in text.splitlines())
    # whatever it collapses, TOML reads back the same values as tomli_w's own layout
    tricky = {"a": [[1.0, 2.0], [3.5e-3, -4.0]], "b": ["x, y", "z]", ""], "c": [True, 1],
              "d": [{"k": 1}], "e": ["a\"b", 2], "f": [], "g": [[], [1]]}
    import tomli_w

    from engine.scene.reader import tomllib
    from engine.scene.writer import compact_arrays

    compact = compact_arrays(tomli_w.dumps(tricky))
    assert tomllib.loads(compact) == tricky
    assert 'a = [[1.0, 2.0], [0.0035, -4.0]]' in compact


def test_the_gui_saves_through_the_scene_writer_and_it_loads_back(scene_dir, tmp_path):
    from app.gui.scene_file import write_scene
    from engine.params import CouplingParams, Effects
    from engine.pose import compose
    from engine.runtime import open_scene

    handle = open_scene(write(scene_dir, 'units = "mm"\n' + EVERY_TABLE.replace(
        'unit = "cm"\n', "")))
    moved = np.array([0.5, -0.25, 3.0, 0.01, 0.02, 0.3])
    effects = Effects(guidance="skeletal", axes=("x", "y", "z"), gravity=(0.0, 0.0, -1.0))
    coupling = CouplingParams(frequency_hz=5.0)
    out = write_scene(handle, tmp_path / "saved", moving_relative_pose=moved,
                      descriptor=replace(handle.scene.descriptor, sigma=0.9, penalty=4.0),
                      modes=20, effects=effects, coupling=coupling, kappa=2.0)
    assert out.suffix == ".toml"
    again = load_scene(out)
    scene = handle.scene
    expected = replace(
        scene,
        parts=(scene.parts[0], replace(scene.parts[1], pose=compose(scene.parts[0].pose,
                                                                     moved))),
        descriptor=replace(scene.descriptor, sigma=0.9, penalty=4.0),
        correlation=replace(scene.correlation, modes=20),
        config=replace(scene.config, effects=effects, coupling=coupling,
                       simulation=replace(scene.config.simulation, kappa=2.0)),
    )
    np.testing.assert_allclose(again.parts[1].pose, expected.parts[1].pose, atol=1e-12)
    expected = replace(expected, parts=(expected.parts[0],
                                        replace(expected.parts[1], pose=again.parts[1].pose)))
    assert_same_scene(again, expected)


def test_a_scene_that_would_not_load_is_never_written(scene_dir, tmp_path):
    scene = load_scene(write(scene_dir, MINIMAL))
    (scene_dir / "peg.step").unlink()
    with pytest.raises(SceneError, match="part file .*peg.step.* not found"):
        save_scene(scene, tmp_path / "x.toml")
    assert not (tmp_path / "x.toml").exists()


def test_scene_parts_take_the_scene_unit(tmp_path):
    src = ROOT / "assets" / "dovetail"
    text = (src / "slide.step").read_text()
    (tmp_path / "slide_m.step").write_text(
        text.replace("SI_UNIT(.MILLI.,.METRE.)", "SI_UNIT($,.METRE.)"))
    (tmp_path / "block.step").write_bytes((src / "block.step").read_bytes())
    path = write(tmp_path, """\
        assembled_pose = [0, 10, 0, 0, 0, 0]
        [[part]]
        file = "block.step"
        [[part]]
        file = "slide_m.step"
        """)
    block, slide = load_scene_parts(load_scene(path))
    assert slide.unit == "mm"
    np.testing.assert_allclose(slide.bounds, [(-10e3, -30e3, -8e3), (10e3, 0, 5e3)], atol=0.1)
    assert any("converted from m" in w for w in slide.warnings)


def test_scene_part_body_selects_a_solid(tmp_path):
    data = ROOT / "tests" / "data" / "two_bodies.step"
    path = write(tmp_path, f"""\
        assembled_pose = [0, 0, 0, 0, 0, 0]
        [[part]]
        file = "{data.as_posix()}"
        body = "block"
        [[part]]
        name = "pin"
        file = "{data.as_posix()}"
        body = "peg"
        tolerance = 0.01
        """)
    scene = load_scene(path)
    block, pin = load_scene_parts(scene)
    assert block.name == "block"  # the body's name by default
    assert pin.name == "pin"
    np.testing.assert_allclose(pin.bounds[:, 2], [-15, 15], atol=1e-6)
    assert block.volume > 10 * pin.volume
    coarse = load_scene_parts(load_scene(write(tmp_path, path.read_text().replace(
        "tolerance = 0.01", "tolerance = 0.2"), "coarse.toml")))[1]
    assert pin.triangles > coarse.triangles


# --------------------------------------------------------------------------- units
INCH_FROM_MM = """#658 = ( CONVERSION_BASED_UNIT('INCH',#90001) LENGTH_UNIT() NAMED_UNIT(#90002) );
#90001 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(25.4),#90003);
#90002 = DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.);
#90003 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );"""


def inch_declared_slide(folder: Path) -> Path:
    """The dovetail slide, drawn in mm, with a header that declares inches (defined from mm,
    as Pro/E writes it).
    """
    text = (ROOT / "assets" / "dovetail" / "slide.step").read_text()
    mm = "#658 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );"
    assert mm in text
    path = folder / "slide_in.step"
    path.write_text(text.replace(mm, INCH_FROM_MM))
    (folder / "block.step").write_bytes((ROOT / "assets" / "dovetail" / "block.step").read_bytes())
    return path


def box_stl(folder: Path, name: str, extents) -> str:
    import trimesh

    trimesh.creation.box(extents=extents).export(folder / name)
    return name


def two_part_scene(folder: Path, first: str, second: str, head: str = 'units = "mm"',
                   extra: str = "") -> Path:
    return write(folder, f"""\
{head}
assembled_pose = [0, 0, 0, 0, 0, 0]
[[part]]
file = "{first}"
[[part]]
file = "{second}"
{extra}""")


def all_warnings(parts):
    return [w for p in parts for w in p.warnings]


def test_wrong_inch_declaration_loads_as_declared_warns_and_a_part_unit_fixes_it(tmp_path):
    inch_declared_slide(tmp_path)
    block, slide = load_scene_parts(load_scene(two_part_scene(tmp_path, "block.step",
                                                              "slide_in.step")))
    # as declared: 25.4 times the drawn size
    np.testing.assert_allclose(slide.bounds, 25.4 * np.array([(-10, -30, -8), (10, 0, 5)]),
                               atol=1e-3)
    mismatch = [w for w in all_warnings([block, slide]) if "differ in size" in w]
    assert len(mismatch) == 1, all_warnings([block, slide])
    assert "close to 25.4" in mismatch[0] and "'slide_in' is not in in" in mismatch[0]
    assert "its STEP header" in mismatch[0] and 'unit = "mm"' in mismatch[0]
    # the per-part unit fixes it, with a note that it overrides the header
    fixed = two_part_scene(tmp_path, "block.step", "slide_in.step", extra='unit = "mm"\n')
    block, slide = load_scene_parts(load_scene(fixed))
    np.testing.assert_allclose(slide.bounds, [(-10, -30, -8), (10, 0, 5)], atol=1e-6)
    notes = all_warnings([block, slide])
    assert not any("differ in size" in w for w in notes), notes
    assert any("declares in; its coordinates are read as mm" in w for w in notes), notes


def test_mesh_in_metres_beside_a_step_in_mm_warns_and_unit_m_fixes_it(tmp_path):
    (tmp_path / "block.step").write_bytes(
        (ROOT / "assets" / "dovetail" / "block.step").read_bytes())
    box_stl(tmp_path, "pin_m.stl", (0.01, 0.01, 0.04))  # a 40 mm pin drawn in metres
    parts = load_scene_parts(load_scene(two_part_scene(tmp_path, "block.step", "pin_m.stl")))
    mismatch = [w for w in all_warnings(parts) if "differ in size" in w]
    assert len(mismatch) == 1 and "close to 1000" in mismatch[0], all_warnings(parts)
    assert "'pin_m' is not in mm" in mismatch[0] and 'unit = "m"' in mismatch[0]
    fixed = load_scene_parts(load_scene(two_part_scene(tmp_path, "block.step", "pin_m.stl",
                                                       extra='unit = "m"\n')))
    np.testing.assert_allclose(fixed[1].extent, [10, 10, 40], rtol=1e-6)  # STL is float32
    assert not any("differ in size" in w for w in all_warnings(fixed))


def test_parts_that_really_differ_in_size_do_not_cry_wolf(tmp_path):
    box_stl(tmp_path, "plate.stl", (60, 60, 5))
    box_stl(tmp_path, "pin.stl", (5, 5, 5))  # 12 times smaller: near 10, but same units
    parts = load_scene_parts(load_scene(two_part_scene(tmp_path, "plate.stl", "pin.stl")))
    assert all_warnings(parts) == []
    box_stl(tmp_path, "pin10.stl", (6, 6, 6))  # exactly 10 times smaller, one unit source
    parts = load_scene_parts(load_scene(two_part_scene(tmp_path, "plate.stl", "pin10.stl")))
    assert any("close to 10:" in w for w in all_warnings(parts))


def test_a_scene_of_meshes_without_units_says_so_once(tmp_path):
    box_stl(tmp_path, "a.stl", (0.04, 0.04, 0.02))
    box_stl(tmp_path, "b.stl", (0.01, 0.01, 0.03))
    path = two_part_scene(tmp_path, "a.stl", "b.stl", head="")
    scene = load_scene(path)
    assert scene.units == "mm" and not scene.units_declared
    parts = load_scene_parts(scene)
    notes = all_warnings(parts)
    assert len([w for w in notes if "declares no units" in w]) == 1, notes
    assert "'a', 'b' are mesh files" in notes[0] and 'units = "m"' in notes[0]
    np.testing.assert_allclose(parts[0].extent, [0.04, 0.04, 0.02])  # read as mm, as said
    # declaring the unit silences it; the meshes are then taken in that unit
    metres = load_scene(two_part_scene(tmp_path, "a.stl", "b.stl", head='units = "m"'))
    parts = load_scene_parts(metres)
    assert all_warnings(parts) == [] and parts[0].unit == "m"
    # a scene of STEP parts without units is not warned about (STEP files carry a unit)
    scene_dir = tmp_path / "steps"
    scene_dir.mkdir()
    for name in ("block.step", "slide.step"):
        (scene_dir / name).write_bytes((ROOT / "assets" / "dovetail" / name).read_bytes())
    steps = load_scene_parts(load_scene(two_part_scene(scene_dir, "block.step", "slide.step",
                                                       head="")))
    assert all_warnings(steps) == []


@pytest.mark.parametrize("unit,scale", [("dm", 100.0), ("cm", 10.0), ("in", 25.4),
                                        ("um", 1e-3), ("ft", 304.8), ("m", 1000.0)])
def test_per_part_unit_converts_mesh_into_the_scene_unit(tmp_path, unit, scale):
    box_stl(tmp_path, "a.stl", (2, 2, 1))
    path = two_part_scene(tmp_path, "a.stl", "a.stl", extra=f'name = "b"\nunit = "{unit}"\n')
    a, b = load_scene_parts(load_scene(path))
    np.testing.assert_allclose(b.extent, scale * np.array([2, 2, 1]), rtol=1e-12)
    np.testing.assert_allclose(a.extent, [2, 2, 1])
    assert a.unit == b.unit == "mm"
    assert any(f"converted from {unit} to the scene's mm" in w for w in b.warnings)


def test_scene_in_feet_or_decimetres_converts_step_parts(tmp_path):
    for name in ("block.step", "slide.step"):
        (tmp_path / name).write_bytes((ROOT / "assets" / "dovetail" / name).read_bytes())
    for units, per_mm in (("ft", 1 / 304.8), ("dm", 0.01)):
        scene = load_scene(two_part_scene(tmp_path, "block.step", "slide.step",
                                          head=f'units = "{units}"'))
        block, slide = load_scene_parts(scene)
        np.testing.assert_allclose(slide.bounds, per_mm * np.array([(-10, -30, -8), (10, 0, 5)]),
                                   rtol=1e-9, atol=1e-12)
        assert slide.unit == units


# --------------------------------------------------------------------------- pivots
def test_part_pivot_is_the_centre_or_the_scene_named_point(tmp_path):
    import trimesh

    from engine.pose import pivot_to_origin, pose_to_matrix
    from engine.runtime import open_scene
    from engine.sim import part_pivot

    # a body drawn far from its file's origin, as bodies of an assembly file are
    trimesh.creation.box(extents=(4, 4, 10)).apply_translation([75, 0, 5]).export(
        tmp_path / "pin.stl")
    box_stl(tmp_path, "base.stl", (20, 20, 5))
    scene = load_scene(two_part_scene(tmp_path, "base.stl", "pin.stl",
                                      extra="pose = [0, 0, 3, 0, 0, 0]\n"))
    centre = part_pivot(open_scene(scene.path))
    np.testing.assert_allclose(centre, [75, 0, 5], atol=1e-5)
    # a 2 degree tilt typed for the pin turns it in place; the scene's own poses stay
    # origin poses of part 2 relative to part 1
    tilt = np.array([0, 0, 0, 0, np.radians(2.0), 0])
    placed = pivot_to_origin(relative_start_pose(scene) + tilt, centre)
    np.testing.assert_allclose(pose_to_matrix(placed)[:3] @ np.append(centre, 1.0),
                               centre + [0, 0, 3], atol=1e-9)
    np.testing.assert_allclose(relative_start_pose(scene), [0, 0, 3, 0, 0, 0])
    named = two_part_scene(tmp_path, "base.stl", "pin.stl", extra="pivot = [75, 0, 0]\n")
    np.testing.assert_array_equal(part_pivot(open_scene(named)), [75, 0, 0])
    with pytest.raises(SceneError, match="pivot in \\[\\[part\\]\\] #2 must be 3 numbers"):
        load_scene(two_part_scene(tmp_path, "base.stl", "pin.stl", extra="pivot = [1, 2]\n"))


def test_a_hold_point_belongs_to_the_moving_part(tmp_path):
    box_stl(tmp_path, "base.stl", (20, 20, 5))
    box_stl(tmp_path, "pin.stl", (4, 4, 10))
    named = load_scene(two_part_scene(tmp_path, "base.stl", "pin.stl", extra="hold = [0, 0, -3]\n"))
    np.testing.assert_array_equal(named.parts[1].hold, [0, 0, -3])
    assert named.parts[0].hold is None
    on_fixed = write(tmp_path, """\
units = "mm"
assembled_pose = [0, 0, 0, 0, 0, 0]
[[part]]
file = "base.stl"
hold = [0, 0, 1]
[[part]]
file = "pin.stl"
""")
    with pytest.raises(SceneError, match=r"scene.toml:5: the fixed part is not held.*second"):
        load_scene(on_fixed)
    with pytest.raises(SceneError, match="hold in \\[\\[part\\]\\] #2 must be 3 numbers"):
        load_scene(two_part_scene(tmp_path, "base.stl", "pin.stl", extra="hold = [1, 2]\n"))
