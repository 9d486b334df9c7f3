"""Part loading: STEP units and welding, multi-body names, mesh checks and their messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from engine.errors import InputError
from engine.loading import (
    Part,
    PartError,
    _edge_defects,
    check_mesh,
    load_part,
    load_parts,
    part_from_mesh,
    step_products,
    step_unit,
    step_units,
)

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"
DATA = ROOT / "tests" / "data"
STEP_FILES = sorted(ASSETS.glob("*/*.step"))


def box_mesh(size=2.0):
    """Closed, outward-wound cube centred at the origin: (8, 3) vertices, (12, 3) faces."""
    h = size / 2
    v = np.array([[x, y, z] for x in (-h, h) for y in (-h, h) for z in (-h, h)], dtype=float)
    # index = 4*ix + 2*iy + iz
    f = np.array([
        [0, 1, 3], [0, 3, 2],  # x = -h
        [4, 6, 7], [4, 7, 5],  # x = +h
        [0, 4, 5], [0, 5, 1],  # y = -h
        [2, 3, 7], [2, 7, 6],  # y = +h
        [0, 2, 6], [0, 6, 4],  # z = -h
        [1, 5, 7], [1, 7, 3],  # z = +h
    ])
    return v, f


def test_box_fixture_is_outward():
    v, f = box_mesh()
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    normals = np.cross(b - a, c - a)
    centres = (a + b + c) / 3
    assert np.all(np.einsum("ij,ij->i", normals, centres) > 0)


# --------------------------------------------------------------------------- example STEP parts
def test_example_parts_exist():
    assert len(STEP_FILES) == 8, STEP_FILES


@pytest.mark.parametrize("path", STEP_FILES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_example_step_loads_closed_in_mm(path):
    part = load_part(path)
    assert part.unit == "mm"
    assert part.name == path.stem
    assert part.vertices.dtype == np.float64 and part.faces.dtype == np.int64
    assert _edge_defects(part.faces) == (0, 0), "not watertight after welding"
    assert part.warnings == ()
    assert part.volume > 0
    assert 10 <= part.extent.max() <= 70  # tens of millimetres, not metres
    assert part.triangles < 8000


@pytest.mark.parametrize(
    "path, volume, lower, upper",
    [
        # 40 x 30 x 15 block minus a 30 x 2 x 10 slot
        ("bracket_slot/block.step", 40 * 30 * 15 - 30 * 2 * 10, (-20, -15, -15), (20, 15, 0)),
        # 40 x 40 x 16 block minus a 30 long trapezoid (10 + 16) / 2 * 8
        ("dovetail/block.step", 40 * 40 * 16 - 13 * 8 * 30, (-20, -20, -16), (20, 20, 0)),
        ("dovetail/slide.step", 13 * 8 * 30 + 20 * 30 * 5, (-10, -30, -8), (10, 0, 5)),
    ],
)
def test_planar_parts_have_exact_volume_and_bounds(path, volume, lower, upper):
    part = load_part(ASSETS / path)
    assert part.volume == pytest.approx(volume, rel=1e-6)
    np.testing.assert_allclose(part.bounds, [lower, upper], atol=1e-4)


def test_tolerance_controls_tessellation():
    # cylinder radius 5, length 30, top edge rounded with radius 1
    exact = math.pi * 25 * 30 - 2 * math.pi * (5 - 1 + 4 / (3 * math.pi)) * (1 - math.pi / 4)
    coarse = load_part(ASSETS / "peg_in_hole/peg.step", tolerance=0.2)
    fine = load_part(ASSETS / "peg_in_hole/peg.step", tolerance=0.005)
    assert fine.triangles > 2 * coarse.triangles
    assert abs(fine.volume - exact) < abs(coarse.volume - exact)
    assert fine.volume == pytest.approx(exact, rel=2e-3)
    for part in (coarse, fine):
        assert _edge_defects(part.faces) == (0, 0)


def test_step_in_metres_keeps_its_unit(tmp_path):
    text = (ASSETS / "dovetail/slide.step").read_text()
    assert "SI_UNIT(.MILLI.,.METRE.)" in text
    metres = tmp_path / "slide_m.step"
    metres.write_text(text.replace("SI_UNIT(.MILLI.,.METRE.)", "SI_UNIT($,.METRE.)"))
    part = load_part(metres)
    assert part.unit == "m"
    np.testing.assert_allclose(part.bounds, [(-10, -30, -8), (10, 0, 5)], atol=1e-4)
    assert _edge_defects(part.faces) == (0, 0)


def test_step_unit_parser():
    assert step_unit("#1 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );") == (
        "mm", 1e-3)
    assert step_unit("#1=(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT($,.METRE.));") == ("m", 1.0)
    inch = ("#5 = ( CONVERSION_BASED_UNIT('INCH',#6) LENGTH_UNIT() NAMED_UNIT(#7) );")
    assert step_unit(inch) == ("in", 0.0254)
    assert step_unit("nothing here") is None
    assert step_unit("#1=(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.DECI.,.METRE.));") == ("dm", 0.1)


CONTEXT = """DATA;
#10 = ( GEOMETRIC_REPRESENTATION_CONTEXT(3) GLOBAL_UNCERTAINTY_ASSIGNED_CONTEXT((#14))
GLOBAL_UNIT_ASSIGNED_CONTEXT((#11,#12,#13)) REPRESENTATION_CONTEXT('','') );
{units}
#12 = ( NAMED_UNIT(*) PLANE_ANGLE_UNIT() SI_UNIT($,.RADIAN.) );
#13 = ( NAMED_UNIT(*) SI_UNIT($,.STERADIAN.) SOLID_ANGLE_UNIT() );
ENDSEC;
"""


@pytest.mark.parametrize(
    "units,expected",
    [
        # an inch defined from a millimetre written after it: the millimetre is no declaration
        ("#11 = ( CONVERSION_BASED_UNIT('INCH',#20) LENGTH_UNIT() NAMED_UNIT(#21) );\n"
         "#20 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(25.4),#22);\n"
         "#21 = DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.);\n"
         "#22 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );", [("in", 0.0254)]),
        # the same, the millimetre first
        ("#9 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );\n"
         "#11 = ( CONVERSION_BASED_UNIT('INCH',#20) LENGTH_UNIT() NAMED_UNIT(#21) );\n"
         "#20 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(25.4),#9);", [("in", 0.0254)]),
        # a conversion under another name is matched by its length
        ("#11 = ( CONVERSION_BASED_UNIT('DECIMETRE',#20) LENGTH_UNIT() NAMED_UNIT(#21) );\n"
         "#20 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(100.),#22);\n"
         "#22 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );", [("dm", 0.1)]),
        ("#11 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.CENTI.,.METRE.) );", [("cm", 0.01)]),
    ],
)
def test_step_units_come_from_the_geometry_context(units, expected):
    text = CONTEXT.format(units=units)
    assert step_units(text) == expected
    assert step_unit(text) == expected[0]


def test_inch_declaration_is_read_as_declared_and_a_unit_overrides_it(tmp_path):
    text = (ASSETS / "dovetail/slide.step").read_text()
    mm = "#658 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );"
    inch = ("#658 = ( CONVERSION_BASED_UNIT('INCH',#90001) LENGTH_UNIT() NAMED_UNIT(#90002) );"
            "\n#90001 = LENGTH_MEASURE_WITH_UNIT(LENGTH_MEASURE(25.4),#90003);"
            "\n#90002 = DIMENSIONAL_EXPONENTS(1.,0.,0.,0.,0.,0.,0.);"
            "\n#90003 = ( LENGTH_UNIT() NAMED_UNIT(*) SI_UNIT(.MILLI.,.METRE.) );")
    path = tmp_path / "slide_in.step"
    path.write_text(text.replace(mm, inch))
    part = load_part(path)
    assert part.unit == "in" and part.warnings == ()
    # the numbers written in the file, labelled with the declared unit
    np.testing.assert_allclose(part.bounds, [(-10, -30, -8), (10, 0, 5)], atol=1e-4)
    again = load_part(path, unit="mm", tolerance=0.01)
    assert again.unit == "mm"
    np.testing.assert_allclose(again.bounds, part.bounds, atol=1e-4)
    assert any("declares in; its coordinates are read as mm" in w for w in again.warnings)
    with pytest.raises(PartError, match="unknown length unit 'yard'"):
        load_part(path, unit="yard")


def test_several_declared_units_are_reported(tmp_path):
    text = (DATA / "two_bodies.step").read_text()
    mm = "SI_UNIT(.MILLI.,.METRE.)"
    assert text.count(mm) == 3
    last = text.rindex(mm)
    path = tmp_path / "mixed.step"
    path.write_text(text[:last] + "SI_UNIT(.CENTI.,.METRE.)" + text[last + len(mm):])
    parts = load_parts(path)
    assert any("declares several length units (mm, cm)" in w for w in parts[0].warnings)


def test_anonymous_bodies_take_their_product_ids(tmp_path):
    import re

    text = (DATA / "two_bodies.step").read_text()
    # some exporters write the real name as the product's id and a generic one as its name
    renamed = re.sub(r"PRODUCT\('(block|peg)',\s*'(block|peg)'",
                     lambda m: f"PRODUCT('{m.group(1)}','SOLID'", text)
    assert renamed.count("'SOLID'") == 2
    path = tmp_path / "anonymous.step"
    path.write_text(renamed)
    assert step_products(renamed) == [("block", "SOLID"), ("peg", "SOLID")]
    parts = load_parts(path)
    assert [p.name for p in parts] == ["block", "peg"]
    np.testing.assert_allclose(parts[1].bounds[:, 2], [-15, 15], atol=1e-4)  # the peg


def test_mesh_takes_the_unit_it_is_given(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(1, 1, 1)).export(tmp_path / "b.obj")
    assert load_part(tmp_path / "b.obj").unit == "unspecified"
    assert load_part(tmp_path / "b.obj", unit="dm").unit == "dm"


def test_multibody_step_gives_named_parts():
    parts = load_parts(DATA / "two_bodies.step")
    assert [p.name for p in parts] == ["block", "peg"]
    block, peg = parts
    # the peg is seated in the block's hole: its bottom at z = -15
    np.testing.assert_allclose(peg.bounds[:, 2], [-15, 15], atol=1e-4)
    np.testing.assert_allclose(block.bounds, [(-20, -20, -20), (20, 20, 0)], atol=1e-4)
    for part in parts:
        assert _edge_defects(part.faces) == (0, 0)
        assert part.source == str(DATA / "two_bodies.step")
    with pytest.raises(PartError, match="2 bodies.*'block', 'peg'.*--body"):
        load_part(DATA / "two_bodies.step")
    assert load_part(DATA / "two_bodies.step", body="peg").name == "peg"
    with pytest.raises(PartError, match="no body named 'pin'"):
        load_part(DATA / "two_bodies.step", body="pin")


def test_corrupt_step_gives_part_error_and_keeps_stdout_clean(capfd):
    with pytest.raises(PartError) as info:
        load_parts(DATA / "corrupt.step")
    message = str(info.value)
    assert "corrupt.step" in message and "re-export" in message
    out, _ = capfd.readouterr()
    assert out == ""  # OpenCASCADE's own messages must not reach stdout (--json)


def test_not_a_step_file(tmp_path):
    bad = tmp_path / "notes.step"
    bad.write_text("this is not CAD data\n")
    with pytest.raises(PartError, match="notes.step: not a STEP file"):
        load_parts(bad)


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(PartError, match="no such file"):
        load_parts(tmp_path / "nothing.step")
    odd = tmp_path / "part.xyz"
    odd.write_text("1 2 3\n")
    with pytest.raises(PartError, match="unknown part file type.*\\.step"):
        load_parts(odd)
    assert issubclass(PartError, InputError) and issubclass(PartError, ValueError)


def test_bad_tolerance():
    with pytest.raises(PartError, match="tolerance"):
        load_parts(ASSETS / "peg_in_hole/peg.step", tolerance=-1)


# --------------------------------------------------------------------------- mesh files
def test_stl_triangle_soup_is_welded_closed(tmp_path):
    import trimesh

    v, f = box_mesh(2.0)
    soup = trimesh.Trimesh(v[f].reshape(-1, 3), np.arange(36).reshape(12, 3), process=False)
    path = tmp_path / "box.stl"
    soup.export(path)
    part = load_part(path)
    assert part.unit == "unspecified" and part.name == "box"
    assert len(part.vertices) == 8 and part.triangles == 12
    assert part.volume == pytest.approx(8.0)
    assert part.warnings == ()


def test_obj_loads(tmp_path):
    v, f = box_mesh(3.0)
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    path = tmp_path / "cube.obj"
    path.write_text("\n".join(lines) + "\n")
    part = load_part(path)
    assert part.volume == pytest.approx(27.0)
    np.testing.assert_allclose(part.bounds, [(-1.5,) * 3, (1.5,) * 3])


def test_obj_with_nan_is_rejected(tmp_path):
    v, f = box_mesh()
    lines = [f"v {x} {y} {z}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    lines[3] = "v nan 0 0"
    path = tmp_path / "nan.obj"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(PartError, match="nan.obj: 1 of 8 vertices have non-finite"):
        load_part(path)


def test_empty_files(tmp_path):
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    with pytest.raises(PartError, match="empty.stl: the file is empty"):
        load_part(empty)
    no_faces = tmp_path / "points.obj"
    no_faces.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    with pytest.raises(PartError, match="points.obj"):
        load_part(no_faces)


def test_corrupt_stl(tmp_path):
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"\x00" * 80 + (1000).to_bytes(4, "little") + b"\x01\x02\x03")
    with pytest.raises(PartError, match="bad.stl"):
        load_part(bad)


# --------------------------------------------------------------------------- check_mesh
def test_check_mesh_empty_and_nan():
    with pytest.raises(PartError, match="src: the mesh is empty"):
        check_mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), source="src")
    v, f = box_mesh()
    v[2, 1] = np.inf
    with pytest.raises(PartError, match="non-finite"):
        check_mesh(v, f, source="src")


def test_check_mesh_bad_indices():
    v, f = box_mesh()
    f[0, 0] = 8
    with pytest.raises(PartError, match="face indices outside 0..7"):
        check_mesh(v, f, source="src")


def test_inverted_normals_are_flipped():
    v, f = box_mesh()
    v2, f2, warnings = check_mesh(v, f[:, ::-1], source="inv.stl")
    assert any("inv.stl" in w and "pointed inwards" in w for w in warnings)
    part = part_from_mesh(v, f[:, ::-1])
    assert part.volume == pytest.approx(8.0)
    np.testing.assert_array_equal(np.sort(f2, axis=1), np.sort(f, axis=1))


def test_inconsistent_winding_is_repaired():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    f = np.array(sphere.faces)
    rng = np.random.default_rng(1)
    bad = rng.choice(len(f), size=7, replace=False)
    f[bad] = f[bad][:, ::-1]
    v2, f2, warnings = check_mesh(np.array(sphere.vertices), f, source="s.ply")
    assert any("7 of 320 triangles were wound against" in w for w in warnings), warnings
    np.testing.assert_array_equal(f2, sphere.faces)  # exactly the original winding back
    assert _edge_defects(f2) == (0, 0)


def test_open_mesh_warns_but_loads():
    v, f = box_mesh()
    v2, f2, warnings = check_mesh(v, f[1:], source="open.stl")
    assert len(f2) == 11
    assert any("open.stl: the mesh is not watertight: 3 boundary edges" in w for w in warnings)
    assert _signed_volume_positive(v2, f2)


def _signed_volume_positive(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return np.einsum("ij,ij->i", a - v.mean(0), np.cross(b - v.mean(0), c - v.mean(0))).sum() > 0


def test_degenerate_and_duplicate_triangles_are_dropped():
    v, f = box_mesh()
    v = np.vstack([v, [[-1, -1, 0.0]]])  # vertex 8: midpoint of edge 0-1 (collinear)
    extra = np.array([[0, 0, 5], [0, 8, 1], [2, 3, 7]])  # repeated, zero area, duplicate
    v2, f2, warnings = check_mesh(v, np.vstack([f, extra]), source="d.off")
    assert len(f2) == 12
    assert any("dropped 1 degenerate triangles (a repeated vertex)" in w for w in warnings)
    # the dangling flat triangle shares its long side with two box faces: nothing to flip with
    assert any("dropped 1 degenerate triangles (zero area, with no single neighbour" in w
               for w in warnings), warnings
    assert any("dropped 1 duplicate triangles" in w for w in warnings), warnings
    assert len(v2) == 8  # the unused midpoint is gone


def test_near_duplicate_vertices_are_welded():
    v, f = box_mesh(20.0)
    soup = v[f].reshape(-1, 3)
    soup = soup + np.random.default_rng(0).normal(scale=1e-7, size=soup.shape)
    v2, f2, warnings = check_mesh(soup, np.arange(36).reshape(12, 3), source="soup")
    assert len(v2) == 8 and warnings == ()
    assert _edge_defects(f2) == (0, 0)


def test_part_arrays_are_read_only():
    v, f = box_mesh()
    part = part_from_mesh(v, f, name="box")
    with pytest.raises(ValueError):
        part.vertices[0, 0] = 5.0
    assert part.diagonal == pytest.approx(math.sqrt(12))
    assert part.area == pytest.approx(24.0)


def test_step_without_geometry(tmp_path):
    empty = tmp_path / "nothing.step"
    empty.write_text(
        "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\n"
        "FILE_NAME('','',(''),(''),'','','');\nFILE_SCHEMA(('AUTOMOTIVE_DESIGN'));\n"
        "ENDSEC;\nDATA;\nENDSEC;\nEND-ISO-10303-21;\n"
    )
    with pytest.raises(PartError, match="nothing.step: .*(re-export|export the part)"):
        load_parts(empty)


def test_far_from_origin_float32_soup_is_welded():
    """An STL-like float32 soup 1e4 mm from the origin still welds closed."""
    v, f = box_mesh(10.0)
    soup = (v[f].reshape(-1, 3) + 1e4).astype(np.float32).astype(np.float64)
    v2, f2, warnings = check_mesh(soup, np.arange(36).reshape(12, 3), source="far")
    assert len(v2) == 8 and warnings == ()
    assert part_from_mesh(v2, f2).volume == pytest.approx(1000.0, rel=1e-5)


def test_obj_with_two_objects_is_one_part(tmp_path):
    v, f = box_mesh(1.0)
    lines = ["o first"] + [f"v {x} {y} {z}" for x, y, z in v]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    lines += ["o second"] + [f"v {x + 5} {y} {z}" for x, y, z in v]
    lines += [f"f {a + 9} {b + 9} {c + 9}" for a, b, c in f]
    path = tmp_path / "two.obj"
    path.write_text("\n".join(lines) + "\n")
    part = load_part(path)
    assert part.triangles == 24 and part.volume == pytest.approx(2.0)
    np.testing.assert_allclose(part.bounds, [(-0.5, -0.5, -0.5), (5.5, 0.5, 0.5)])


# --------------------------------------------------------------------------- closed CAD meshes
def cad_style_box():
    """A 2 x 2 x 2 box tessellated as CAD exporters do: a vertex in the middle of the edge
    between corners 4 and 5, a fan from it over the face x = +1, and on the face y = -1 a
    zero-area triangle (4, m, 5) whose three distinct corners are collinear. Written as a
    triangle soup (each triangle its own vertices), as GLB and STL store it.

    Returns (vertices (n, 3), faces (m, 3)) with every edge paired once it is welded.
    """
    v, _ = box_mesh()
    v = np.vstack([v, [[1.0, -1.0, 0.0]]])  # 8: midpoint of edge 4-5
    centre = np.zeros(3)
    faces = [
        [0, 1, 3], [0, 3, 2], [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
        [8, 4, 6], [8, 6, 7], [8, 7, 5],  # fan over x = +1 from the edge's midpoint
        [0, 4, 5], [0, 5, 1],  # y = -1
    ]
    oriented = []
    for tri in faces:
        a, b, c = v[tri]
        normal = np.cross(b - a, c - a)
        oriented.append(tri if normal @ ((a + b + c) / 3 - centre) > 0 else tri[::-1])
    # the flat triangle's winding pairs its edges with its neighbours': 5 -> 4 against (0, 4, 5)
    oriented.append([5, 4, 8])
    f = np.array(oriented)
    return v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)


def test_cad_mesh_with_collinear_corners_stays_closed(tmp_path):
    import trimesh

    soup_v, soup_f = cad_style_box()
    reference = trimesh.Trimesh(soup_v, soup_f, process=False)
    reference.merge_vertices()
    assert reference.is_watertight  # trimesh calls it closed once welded
    areas = _tri_areas(soup_v, soup_f)
    assert (areas == 0).sum() == 1  # the collinear-corner triangle

    v, f, warnings = check_mesh(soup_v, soup_f, source="cad.stl")
    assert _edge_defects(f) == (0, 0), warnings
    assert not any("watertight" in w for w in warnings), warnings
    assert any("removed by edge flips" in w for w in warnings), warnings
    assert _tri_areas(v, f).min() > 0.1
    assert len(f) == len(soup_f) - 1 + 1  # the flat triangle gone, its neighbour split in two
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(8.0, rel=1e-12)
    # the same through the file loader, as an STL
    reference.export(tmp_path / "cad.stl")
    part = load_part(tmp_path / "cad.stl")
    assert _edge_defects(part.faces) == (0, 0)
    assert not any("watertight" in w for w in part.warnings), part.warnings
    assert part.volume == pytest.approx(8.0, rel=1e-6)


def test_flat_triangle_chain_on_one_edge_is_flipped_away():
    """Two midpoints on one edge: two stacked flat triangles; flips resolve both."""
    v, _ = box_mesh()
    v = np.vstack([v, [[1.0, -1.0, -0.5]], [[1.0, -1.0, 0.5]]])  # 8, 9 on edge 4-5
    faces = [
        [0, 1, 3], [0, 3, 2], [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
        [8, 4, 6], [8, 6, 9], [9, 6, 7], [9, 7, 5],  # x = +1, fanned through 8 and 9
        [0, 4, 5], [0, 5, 1],
    ]
    oriented = []
    for tri in faces:
        a, b, c = v[tri]
        normal = np.cross(b - a, c - a)
        oriented.append(tri if normal @ ((a + b + c) / 3) > 0 else tri[::-1])
    oriented += [[5, 4, 8], [5, 8, 9]]  # flat: 5 -> 4 against (0, 4, 5), then split at 8
    f = np.array(oriented)
    assert _edge_defects(f) == (0, 0)
    v2, f2, warnings = check_mesh(v, f, source="chain.obj")
    assert _edge_defects(f2) == (0, 0), warnings
    assert _tri_areas(v2, f2).min() > 0.1
    assert _signed_volume_positive(v2, f2)


def _tri_areas(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


# --------------------------------------------------------------------------- reliability
def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _write_stl(path, v, f):
    import trimesh

    trimesh.Trimesh(v, f, process=False).export(str(path))
    return path


def test_overlapping_shells_have_the_inside_density_of_their_union(tmp_path):
    """Two overlapping boxes in one STL: before, the overlap counted twice (volume 16, Im rho
    higher in the overlap); now the part is their union (volume 15) with its density.
    """
    import manifold3d

    from engine.descriptor import descriptor_for_part, grid_for_part

    a, fa = _box((0, 0, 0), (2, 2, 2))
    b, fb = _box((1, 1, 1), (3, 3, 3))
    path = _write_stl(tmp_path / "two.stl", np.vstack([a, b]), np.vstack([fa, fb + 8]))
    part = load_part(path)
    assert part.volume == pytest.approx(15.0, rel=1e-12)
    assert _edge_defects(part.faces) == (0, 0)
    assert any("2 closed shells overlap" in w and "joined into 1 solid" in w
               for w in part.warnings)
    # the union made independently of the loader, as one shell
    solids = [manifold3d.Manifold(manifold3d.Mesh64(vert_properties=v,
                                                    tri_verts=f.astype(np.uint64)))
              for v, f in ((a, fa), (b, fb))]
    union = (solids[0] + solids[1]).to_mesh64()
    reference = part_from_mesh(union.vert_properties[:, :3], union.tri_verts.astype(np.int64))
    grid = grid_for_part(part, samples=16, padding=2)
    rho = descriptor_for_part(part, grid, method="brute", use_cache=False).rho
    expected = descriptor_for_part(reference, grid, method="brute", use_cache=False).rho
    np.testing.assert_allclose(rho, expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max())
    # without the union the overlap counts twice: the density in it is visibly off
    v2, f2, _ = check_mesh(np.vstack([a, b]), np.vstack([fa, fb + 8]), source="raw",
                           union=False)
    doubled = descriptor_for_part(Part("raw", v2, f2), grid, method="brute",
                                  use_cache=False).rho
    centre = tuple(np.round((1.5 - np.asarray(grid.origin)) / grid.spacing).astype(int))
    assert abs(doubled[centre].imag - rho[centre].imag) > 0.05 * abs(rho[centre].imag)


def test_disjoint_shells_and_cavities_are_left_as_they_are():
    outer, fo = _box((0, 0, 0), (4, 4, 4))
    inner, fi = _box((1, 1, 1), (2, 2, 2))
    far, ff = _box((10, 0, 0), (11, 1, 1))
    v = np.vstack([outer, inner, far])
    f = np.vstack([fo, fi[:, ::-1] + 8, ff + 16])  # the cavity faces inwards
    part = part_from_mesh(v, f)
    assert part.triangles == 36 and part.warnings == ()
    assert part.volume == pytest.approx(64 - 1 + 1)


def test_random_bytes_named_stl_say_so_without_trimesh_s_optional_module(tmp_path,
                                                                         monkeypatch):
    import sys

    junk = tmp_path / "junk.stl"
    junk.write_bytes(np.random.default_rng(1).bytes(5000))
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)
    with pytest.raises(PartError, match=r"junk.stl: not an STL file: not binary STL \(its "
                                        r"header announces \d+ triangles.*not ASCII STL"):
        load_part(junk)


def test_a_tiny_cube_away_from_the_origin_loads():
    """Welding took 1e-6 of the position (1e-6 at (1, 1, 1)): the whole cube was welded."""
    v, f = _box((1, 1, 1), (1 + 1e-6,) * 3)
    part = part_from_mesh(v.astype(np.float32).astype(np.float64), f)
    assert part.triangles == 12
    assert part.volume == pytest.approx(1e-18, rel=1e-3)


def test_a_cube_below_the_float32_resolution_where_it_lies_says_why():
    v, f = _box((100, 100, 100), (100 + 1e-6,) * 3)
    with pytest.raises(PartError, match=r"tiny: no usable triangles: the part is 0 across as "
                                        r"stored but has coordinates as large as 100, where "
                                        r"they resolve only 1.2e-05; move the part near the "
                                        r"origin"):
        check_mesh(v.astype(np.float32).astype(np.float64), f, source="tiny")


def test_a_step_part_too_small_for_opencascade_is_refused(tmp_path):
    text = (ASSETS / "dovetail/slide.step").read_text()
    tiny = tmp_path / "tiny.step"
    tiny.write_text(text.replace("SI_UNIT(.MILLI.,.METRE.)", "SI_UNIT(.NANO.,.METRE.)"))
    with pytest.raises(PartError, match=r"tiny.step: the model is 38.3 nm \(3.83e-05 mm\) "
                                        r"across, too small for OpenCASCADE to tessellate"):
        load_part(tiny)


def test_a_too_fine_step_tolerance_is_refused_before_tessellating():
    """``--tolerance 1e-7`` ran over 150 s and 2.4 GB; now refused at once with the finest."""
    with pytest.raises(PartError, match=r"peg.step: a tessellation tolerance of 1e-07 mm would "
                                        r"make about .* triangles .*use a tolerance of at "
                                        r"least [0-9.e-]+ mm"):
        load_part(ASSETS / "peg_in_hole" / "peg.step", tolerance=1e-7)


def test_a_surface_folded_through_itself_is_reported():
    import manifold3d

    sphere = manifold3d.Manifold.sphere(1.0, 32).to_mesh64()
    v = np.array(sphere.vert_properties[:, :3])
    f = np.array(sphere.tri_verts, dtype=np.int64)
    assert part_from_mesh(v, f).warnings == ()
    cap = v[:, 2] > 0.3
    v[cap, 2] = -v[cap, 2] - 0.2  # the top cap pushed down through the bottom
    warnings = part_from_mesh(v, f, name="folded").warnings
    assert any("folded: the surface intersects itself or overlaps itself" in w
               for w in warnings)
