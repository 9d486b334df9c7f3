"""Generate the modelled pairs of the real-fit suite (assets/real/) with gmsh's OpenCASCADE kernel.

Run from the project root with the development extra installed (gmsh is GPL: only this
script uses it, the installed program never imports it; the files it writes are
committed)::

    .venv/bin/python assets/make_real_pairs.py

Each pair is modelled as a machinist would draw it: nominal sizes from ISO 286 (hole basis,
limits below), every part drawn at the middle of its tolerance zone, so the clearance at the
assembled pose is the fit's mean clearance. Small lead-in rounds sit where real parts have
chamfers. The parts are then written as:

- STEP (gmsh's OpenCASCADE writer; the scene says nothing of the tessellation: the engine
  chooses a chord tolerance below the fit's tightest gap, engine.sim.auto);
- STL or OBJ, tessellated the way CAD exporters do: by OpenCASCADE's B-rep mesher (through
  the project's own STEP loader, with a chord tolerance below the radial clearance), which
  gives full-length strips on cylinders and fans of slivers on flat faces with circular
  edges; STL is written as a triangle soup, as CAD programs write it; some in millimetres,
  some in metres (their scenes then say ``unit = "m"`` for the part).

The pairs from public repositories (the ``factory_*`` folders) are copied, not generated:
see their SOURCE.md.

ISO 286-2 values used (micrometres; diameter ranges "over-up to" in mm)::

    range     IT6  IT7  IT8  IT9  IT10 | shaft upper deviation es:  a     d    f    g   h
    3-6        8   12   18   30   48   |                          -270  -30  -10   -4   0
    6-10       9   15   22   36   58   |                          -280  -40  -13   -5   0
    10-18     11   18   27   43   70   |                          -290  -50  -16   -6   0
    18-30     13   21   33   52   84   |                          -300  -65  -20   -7   0
    30-50     16   25   39   62  100   |                          -310  -80  -25   -9   0

H holes: lower deviation 0, upper = IT. JS: +-IT/2. Shaft lower deviation = es - IT.
(a11 at 18-30: es -300, IT11 130.)
"""

from __future__ import annotations

import math
import re
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import gmsh
import trimesh

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "assets" / "real"
sys.path.insert(0, str(ROOT))

from engine.loading import load_part  # noqa: E402  (the project's STEP tessellation)

occ = None  # gmsh.model.occ once initialised

# ISO 286-2 tables (micrometres) for the ranges used here, keyed by the range's upper limit.
IT = {6: {6: 8, 7: 12, 8: 18, 9: 30, 10: 48},
      10: {6: 9, 7: 15, 8: 22, 9: 36, 10: 58},
      18: {6: 11, 7: 18, 8: 27, 9: 43, 10: 70},
      30: {6: 13, 7: 21, 8: 33, 9: 52, 10: 84, 11: 130},
      50: {6: 16, 7: 25, 8: 39, 9: 62, 10: 100}}
SHAFT_ES = {6: {"a": -270, "d": -30, "f": -10, "g": -4, "h": 0},
            10: {"a": -280, "d": -40, "f": -13, "g": -5, "h": 0},
            18: {"a": -290, "d": -50, "f": -16, "g": -6, "h": 0},
            30: {"a": -300, "d": -65, "f": -20, "g": -7, "h": 0},
            50: {"a": -310, "d": -80, "f": -25, "g": -9, "h": 0}}


def _range(size: float) -> int:
    for upper in sorted(IT):
        if size <= upper:
            return upper
    raise ValueError(f"no ISO 286 range for {size} mm here")


def hole_limits(size: float, letter: str, grade: int) -> tuple[float, float]:
    """(lower, upper) limit in mm of a hole ``size letter grade`` (H or JS)."""
    it = IT[_range(size)][grade] / 1000.0
    if letter == "H":
        return size, size + it
    if letter == "JS":
        return size - it / 2, size + it / 2
    raise ValueError(letter)


def shaft_limits(size: float, letter: str, grade: int) -> tuple[float, float]:
    """(lower, upper) limit in mm of a shaft ``size letter grade``."""
    r = _range(size)
    es = SHAFT_ES[r][letter] / 1000.0
    return size + es - IT[r][grade] / 1000.0, size + es


def mid(limits: tuple[float, float]) -> float:
    return 0.5 * (limits[0] + limits[1])


# --------------------------------------------------------------------------- gmsh helpers
def _one(out) -> int:
    vols = [t for d, t in out if d == 3]
    if len(vols) != 1:
        raise RuntimeError(f"boolean gave {len(vols)} volumes")
    return vols[0]


def _fuse(a: int, others: list[int]) -> int:
    return _one(occ.fuse([(3, a)], [(3, t) for t in others])[0])


def _cut(a: int, tools: list[int]) -> int:
    return _one(occ.cut([(3, a)], [(3, t) for t in tools])[0])


def _intersect(a: int, b: int) -> int:
    return _one(occ.intersect([(3, a)], [(3, b)])[0])


def _circles_at(z: float, radius: float, tol: float = 0.05) -> list[int]:
    """Curves lying in the plane z within ``radius`` of the z axis."""
    occ.synchronize()
    found = gmsh.model.getEntitiesInBoundingBox(-radius - tol, -radius - tol, z - tol,
                                                radius + tol, radius + tol, z + tol, 1)
    return [t for _, t in found]


def _fillet(vol: int, curves: list[int], r: float) -> int:
    return _one(occ.fillet([vol], curves, [r]))


def _rod(z0: float, length: float, radius: float, chamfer0: float = 0.0,
         chamfer1: float = 0.0) -> int:
    """A round bar along z from z0, with 45-degree chamfers on its ends (cones: a CAD
    exporter tessellates them as strips, like the cylinder)."""
    parts = []
    z, top = z0, z0 + length
    if chamfer0 > 0:
        parts.append(occ.addCone(0, 0, z0, 0, 0, chamfer0, radius - chamfer0, radius))
        z += chamfer0
    if chamfer1 > 0:
        parts.append(occ.addCone(0, 0, top - chamfer1, 0, 0, chamfer1, radius,
                                 radius - chamfer1))
        top -= chamfer1
    body = occ.addCylinder(0, 0, z, 0, 0, top - z, radius)
    return _fuse(body, parts) if parts else body


def _countersink(z: float, radius: float, chamfer: float) -> int:
    """A 45-degree cone that chamfers the mouth (at height z, opening upwards) of a bore."""
    return occ.addCone(0, 0, z - chamfer, 0, 0, chamfer + 1, radius, radius + chamfer + 1)


def _prism_xz(points_xz: list[tuple[float, float]], y0: float, length: float) -> int:
    """Prism of a polygon in the plane y = y0, extruded by ``length`` along +y."""
    pts = [occ.addPoint(x, y0, z) for x, z in points_xz]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    return _one(occ.extrude([(2, surface)], 0, length, 0))


def _write_step(path: Path, name: str) -> None:
    """Write the current model's one volume to ``path``, its product named ``name``."""
    occ.synchronize()
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.write(str(path))
    text = path.read_text()
    text = re.sub(r"PRODUCT\('([^']*)',\s*'([^']*)'", f"PRODUCT('{name}',\n  '{name}'", text)
    # a fixed date keeps regenerated files byte-identical
    text = re.sub(r"FILE_NAME\('([^']*)','[^']*'", r"FILE_NAME('\1','2026-01-01T00:00:00'", text)
    path.write_text(text)


# --------------------------------------------------------------------------- the pairs
@dataclass
class Pair:
    folder: str
    title: str
    fit: str                    # one line for the scene and the README
    free: str                   # which axes the fit leaves free (scene comment)
    fixed: tuple                # (name, builder, format, unit, tolerance)
    moving: tuple               # (name, builder, format, unit, tolerance, origin (3,))
    assembled: tuple            # (6,) part 2 in part 1's frame
    axis: tuple                 # insertion direction, part 1's frame
    backoff: float              # start this far back along the axis (mm)


# (A) Ø5 H7/h6 pin through a plate (through hole) --------------------------------------------
PIN_HOLE = mid(hole_limits(5, "H", 7))       # 5.006
PIN_D = mid(shaft_limits(5, "h", 6))         # 4.996


def pin_plate() -> int:
    plate = occ.addBox(-15, -15, -10, 30, 30, 10)
    return _cut(plate, [occ.addCylinder(0, 0, -11, 0, 0, 12, PIN_HOLE / 2),
                        _countersink(0.0, PIN_HOLE / 2, 0.3)])


def pin() -> int:
    return _rod(-10, 20, PIN_D / 2, 0.4, 0.4)


# (B) Ø20 H7/g6 shaft in a blind bore ---------------------------------------------------------
BORE20 = mid(hole_limits(20, "H", 7))        # 20.0105
SHAFT20 = mid(shaft_limits(20, "g", 6))      # 19.9865


def bore_block() -> int:
    block = occ.addBox(-20, -20, -30, 40, 40, 30)
    return _cut(block, [occ.addCylinder(0, 0, -20, 0, 0, 21, BORE20 / 2),
                        _countersink(0.0, BORE20 / 2, 0.5)])


def shaft20() -> int:
    return _rod(-20, 35, SHAFT20 / 2, 0.5, 1.0)


# (C) Ø50 H7/h6 spigot in a recess (register fit of a flange) --------------------------------
RECESS50 = mid(hole_limits(50, "H", 7))      # 50.0125
SPIGOT50 = mid(shaft_limits(50, "h", 6))     # 49.992


def recess_housing() -> int:
    housing = occ.addBox(-40, -40, -12, 80, 80, 12)
    return _cut(housing, [occ.addCylinder(0, 0, -5, 0, 0, 6, RECESS50 / 2)])


def spigot_cover() -> int:
    cover = occ.addCylinder(0, 0, 0, 0, 0, 6, 35)
    spigot = _rod(-4.5, 4.6, SPIGOT50 / 2, 0.5)
    return _fuse(cover, [spigot])


# (D) thin-walled sleeve, Ø30 H7/g6, 1 mm wall, through bore --------------------------------
BORE30 = mid(hole_limits(30, "H", 7))        # 30.0105
SLEEVE30 = mid(shaft_limits(30, "g", 6))     # 29.9865
SLEEVE_ID = 28.0


def sleeve_housing() -> int:
    housing = occ.addBox(-25, -25, -20, 50, 50, 20)
    return _cut(housing, [occ.addCylinder(0, 0, -21, 0, 0, 22, BORE30 / 2),
                          _countersink(0.0, BORE30 / 2, 0.5)])


def sleeve() -> int:
    outer = _rod(-20, 25, SLEEVE30 / 2, 0.3)
    return _cut(outer, [occ.addCylinder(0, 0, -21, 0, 0, 27, SLEEVE_ID / 2)])


# (E) keyed shaft and hub: Ø20 H7/g6, parallel key 6 x 6 (ISO 773 / DIN 6885 B) -------------
KEY_W = mid(shaft_limits(6, "h", 9))         # 5.985, key width h9
KEYWAY_W = mid(hole_limits(6, "JS", 9))      # 6.000, hub keyway JS9
KEY_BOTTOM, KEY_TOP, HUB_T2 = 6.5, 12.5, 2.8  # t1 = 3.5 in the shaft, t2 = 2.8 in the hub


def keyed_shaft() -> int:
    collar = occ.addCylinder(0, 0, -10, 0, 0, 10, 15)
    shaft = _rod(-0.5, 40.5, SHAFT20 / 2, 0.0, 0.5)
    key = occ.addBox(-KEY_W / 2, KEY_BOTTOM, 6, KEY_W, KEY_TOP - KEY_BOTTOM, 28)
    return _fuse(collar, [shaft, key])


def hub() -> int:
    body = occ.addCylinder(0, 0, 0, 0, 0, 20, 20)
    bore = occ.addCylinder(0, 0, -1, 0, 0, 22, BORE20 / 2)
    keyway = occ.addBox(-KEYWAY_W / 2, 0, -1, KEYWAY_W, BORE20 / 2 + HUB_T2, 22)
    return _cut(body, [bore, keyway])


# (F) straight-sided spline ISO 14, light series 6 x 23 x 26 --------------------------------
N_SPLINE, B_SPLINE = 6, 6.0
HUB_MINOR = mid(hole_limits(23, "H", 7))     # 23.0105
SHAFT_MINOR = mid(shaft_limits(23, "f", 7))  # 22.9695
HUB_SLOT = mid(hole_limits(6, "H", 9))       # 6.015
SHAFT_TOOTH = mid(shaft_limits(6, "d", 10))  # 5.946
HUB_MAJOR = mid(hole_limits(26, "H", 10))    # 26.042
SHAFT_MAJOR = 26.0 + (-300 - 65) / 1000.0    # 25.635, a11 (-300 / -430)


def _spline_solid(minor: float, major: float, width: float, z0: float, length: float) -> int:
    core = occ.addCylinder(0, 0, z0, 0, 0, length, minor / 2)
    teeth = []
    for k in range(N_SPLINE):
        box = occ.addBox(-width / 2, 0, z0, width, major / 2 + 1, length)
        occ.rotate([(3, box)], 0, 0, 0, 0, 0, 1, k * 2 * math.pi / N_SPLINE)
        teeth.append(box)
    star = _fuse(core, teeth)
    return _intersect(star, occ.addCylinder(0, 0, z0 - 1, 0, 0, length + 2, major / 2))


def spline_hub() -> int:
    block = occ.addBox(-25, -25, -20, 50, 50, 20)
    return _cut(block, [_spline_solid(HUB_MINOR, HUB_MAJOR, HUB_SLOT, -21, 22)])


def spline_shaft() -> int:
    return _spline_solid(SHAFT_MINOR, SHAFT_MAJOR, SHAFT_TOOTH, -20, 40)


# (G) rectangular peg 10 x 16 H7/g6 in a blind pocket ---------------------------------------
POCKET = (mid(hole_limits(10, "H", 7)), mid(hole_limits(16, "H", 7)))    # 10.0075, 16.009
RPEG = (mid(shaft_limits(10, "g", 6)), mid(shaft_limits(16, "g", 6)))    # 9.9905, 15.9885


def pocket_block() -> int:
    block = occ.addBox(-20, -20, -25, 40, 40, 25)
    return _cut(block, [occ.addBox(-POCKET[0] / 2, -POCKET[1] / 2, -15, *POCKET, 16)])


def rect_peg() -> int:
    body = occ.addBox(-RPEG[0] / 2, -RPEG[1] / 2, -15, *RPEG, 30)
    occ.synchronize()
    found = gmsh.model.getEntitiesInBoundingBox(-9, -9, -15.05, 9, 9, -14.95, 1)
    return _fillet(body, [t for _, t in found], 0.5)


# (H) 60-degree dovetail slide, open both ends, 0.05 mm flank clearance ----------------------
DT_TOP, DT_DEPTH, DT_ANGLE = 20.0, 8.0, math.radians(60.0)
DT_CLEAR, DT_FLOOR = 0.05, 0.1               # normal to the flanks; under the tenon


def _dt_half(z: float, shrink: float = 0.0) -> float:
    """Half width of the groove at height z (z <= 0), less ``shrink`` normal to a flank."""
    return DT_TOP / 2 - z / math.tan(DT_ANGLE) - shrink / math.sin(DT_ANGLE)


def dovetail_way() -> int:
    block = occ.addBox(-30, -30, -20, 60, 60, 20)
    d = DT_DEPTH
    groove = _prism_xz([(-_dt_half(0.0) + 1 / math.tan(DT_ANGLE), 1.0), (-_dt_half(-d), -d),
                        (_dt_half(-d), -d), (_dt_half(0.0) - 1 / math.tan(DT_ANGLE), 1.0)],
                       -31, 62)
    return _cut(block, [groove])


def dovetail_slide() -> int:
    z = -(DT_DEPTH - DT_FLOOR)
    tenon = _prism_xz([(-_dt_half(0.0, DT_CLEAR), 0.0), (-_dt_half(z, DT_CLEAR), z),
                       (_dt_half(z, DT_CLEAR), z), (_dt_half(0.0, DT_CLEAR), 0.0)], -20, 40)
    body = occ.addBox(-20, -20, 0, 40, 40, 10)
    return _fuse(body, [tenon])


PAIRS = [
    Pair("iso_pin_5_H7h6_through", "Pin 5 H7/h6 through a plate",
         f"5 H7/h6: hole {PIN_HOLE:.4f}, pin {PIN_D:.4f} (limits: hole 5.000-5.012, pin "
         "4.992-5.000; clearance 0 to 0.020, mean 0.010)",
         "through hole: translation along z and rotation about z are free",
         ("plate", pin_plate, "stl", "mm", 0.002),
         ("pin", pin, "stl", "mm", 0.002, (0, 0, -10)),
         (0, 0, -10, 0, 0, 0), (0, 0, -1), 15.0),
    Pair("iso_shaft_20_H7g6_blind", "Shaft 20 H7/g6 in a blind bore",
         f"20 H7/g6: bore {BORE20:.4f}, shaft {SHAFT20:.4f} (limits: bore 20.000-20.021, shaft "
         "19.980-19.993; clearance 0.007 to 0.041, mean 0.024)",
         "blind bore: rotation about z is free; the shaft bottoms on the bore's floor",
         ("block", bore_block, "step", "mm", 0.004),
         ("shaft", shaft20, "step", "mm", 0.004, (0, 0, -20)),
         (0, 0, -20, 0, 0, 0), (0, 0, -1), 25.0),
    Pair("iso_spigot_50_H7h6", "Flange spigot 50 H7/h6 in a recess",
         f"50 H7/h6: recess {RECESS50:.4f}, spigot {SPIGOT50:.4f} (limits: recess "
         "50.000-50.025, spigot 49.984-50.000; clearance 0 to 0.041, mean 0.0205)",
         "register fit: rotation about z is free; the cover seats on the housing's face",
         ("housing", recess_housing, "obj", "m", 0.004),
         ("cover", spigot_cover, "obj", "m", 0.004, (0, 0, 0)),
         (0, 0, 0, 0, 0, 0), (0, 0, -1), 10.0),
    Pair("iso_sleeve_30_H7g6_thinwall", "Thin-walled sleeve 30 H7/g6 in a through bore",
         f"30 H7/g6: bore {BORE30:.4f}, sleeve {SLEEVE30:.4f} x {SLEEVE_ID:g} bore (wall "
         f"{(SLEEVE30 - SLEEVE_ID) / 2:.3f}); limits: bore 30.000-30.021, sleeve "
         "29.980-29.993; clearance 0.007 to 0.041, mean 0.024",
         "through bore: translation along z and rotation about z are free",
         ("housing", sleeve_housing, "stl", "m", 0.005),
         ("sleeve", sleeve, "stl", "m", 0.005, (0, 0, -20)),
         (0, 0, -20, 0, 0, 0), (0, 0, -1), 25.0),
    Pair("keyed_hub_20", "Hub onto a keyed shaft 20 H7/g6, key 6 x 6",
         f"bore 20 H7/g6 ({BORE20:.4f} on {SHAFT20:.4f}, mean clearance 0.024); parallel key "
         f"6 h9 ({KEY_W:.4f}) in a hub keyway 6 JS9 ({KEYWAY_W:.4f}): width clearance "
         "-0.015 to 0.045, mean 0.015; key top 0.3 below the keyway's (t1 3.5, t2 2.8)",
         "none: the key locks rotation, the shaft's collar stops the hub",
         ("shaft", keyed_shaft, "step", "mm", 0.004),
         ("hub", hub, "step", "mm", 0.004, (0, 0, 0)),
         (0, 0, 0, 0, 0, 0), (0, 0, -1), 45.0),
    Pair("spline_6x23x26", "Straight-sided spline ISO 14 6 x 23 x 26",
         f"minor 23 H7/f7 ({HUB_MINOR:.4f} / {SHAFT_MINOR:.4f}, mean clearance 0.041), "
         f"width 6 H9/d10 ({HUB_SLOT:.4f} / {SHAFT_TOOTH:.4f}, mean 0.069), major 26 H10/a11 "
         f"({HUB_MAJOR:.3f} / {SHAFT_MAJOR:.3f})",
         "through hub: translation along z is free; the splines lock rotation",
         ("hub", spline_hub, "obj", "mm", 0.004),
         ("shaft", spline_shaft, "obj", "mm", 0.004, (0, 0, -20)),
         (0, 0, -20, 0, 0, 0), (0, 0, -1), 25.0),
    Pair("rect_peg_10x16_H7g6", "Rectangular peg 10 x 16 H7/g6 in a blind pocket",
         f"10 H7/g6 ({POCKET[0]:.4f} / {RPEG[0]:.4f}, mean clearance 0.017) by 16 H7/g6 "
         f"({POCKET[1]:.4f} / {RPEG[1]:.4f}, mean 0.0205)",
         "none: the pocket's walls and floor constrain every axis",
         ("block", pocket_block, "stl", "mm", 0.004),
         ("peg", rect_peg, "stl", "mm", 0.004, (0, 0, -15)),
         (0, 0, -15, 0, 0, 0), (0, 0, -1), 20.0),
    Pair("dovetail_60_slide", "60-degree dovetail slide, open both ends",
         f"groove {DT_TOP:g} wide at the top, {DT_DEPTH:g} deep, 60-degree flanks; tenon "
         f"{DT_CLEAR:g} clear of each flank (normal), {DT_FLOOR:g} above the floor; slide "
         "rests on the way's top face",
         "translation along y (the way) is free",
         ("way", dovetail_way, "step", "mm", None),
         ("slide", dovetail_slide, "step", "mm", None, (0, 0, 0)),
         (0, 0, 0, 0, 0, 0), (0, 1, 0), 50.0),
]


#: The degrees of freedom each fit leaves free (part 1's frame), as the scene's ``free_axes``.
FREE_AXES = {
    "iso_pin_5_H7h6_through": ["z", "rz"], "iso_shaft_20_H7g6_blind": ["rz"],
    "iso_sleeve_30_H7g6_thinwall": ["z", "rz"], "iso_spigot_50_H7h6": ["rz"],
    "keyed_hub_20": [], "rect_peg_10x16_H7g6": [], "spline_6x23x26": ["z"],
    "dovetail_60_slide": ["y"],
}


# --------------------------------------------------------------------------- writing
def _build(builder, origin) -> None:
    gmsh.clear()
    gmsh.model.add("part")
    vol = builder()
    if origin is not None:
        occ.translate([(3, vol)], -origin[0], -origin[1], -origin[2])


def _export(pair: Pair, spec, origin) -> tuple[str, float | None, str]:
    """Write one part; returns (file name, scene tolerance or None, unit)."""
    name, builder, fmt, unit, tol = spec[:5]
    out = OUT / pair.folder
    out.mkdir(parents=True, exist_ok=True)
    if fmt == "step":
        _build(builder, origin)
        path = out / f"{name}.step"
        _write_step(path, name)
        if unit != "mm":
            raise ValueError("gmsh writes STEP in millimetres only")
        return path.name, tol, unit
    _build(builder, origin)
    with tempfile.TemporaryDirectory() as tmp:
        step = Path(tmp) / f"{name}.step"
        _write_step(step, name)
        part = load_part(step, tolerance=tol)
    scale = 1e-3 if unit == "m" else 1.0
    mesh = trimesh.Trimesh(part.vertices * scale, part.faces, process=False)
    path = out / f"{name}.{fmt}"
    if fmt == "stl":
        mesh.export(path, file_type="stl")  # binary, a triangle soup as CAD programs write
    else:
        text = trimesh.exchange.obj.export_obj(mesh, include_normals=False,
                                                include_texture=False, digits=9 if
                                                unit == "m" else 6, header=None)
        path.write_text(text)
    return path.name, None, unit


#: What a user knows of a pair: the files, their unit, the assembled pose, the insertion
#: axis and the fit's free axes. Grid, K and the STEP tessellation are the engine's to choose
#: (engine.sim.auto).
SCENE = """\
# {title}: generated by assets/make_real_pairs.py
# fit: {fit}
# free axes: {free}
name = "{title}"
units = "mm"
assembled_pose = {assembled}   # part 2 in part 1's frame when seated
insertion_axis = {axis}        # direction part 2 travels to seat, part 1's frame
free_axes = {free_axes}   # degrees of freedom the fit leaves free, part 1's frame

[[part]]             # fixed
name = "{name1}"
file = "{file1}"
pose = [0, 0, 0, 0, 0, 0]
fixed = true{extra1}

[[part]]             # moving: starts {backoff:g} mm back along the insertion axis
name = "{name2}"
file = "{file2}"
pose = {start}{extra2}
"""


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


def _extra(unit: str, tol: float | None, fmt: str) -> str:
    lines = []
    if fmt != "step" or unit != "mm":
        lines.append(f'unit = "{unit}"' + ("             # OBJ/STL carry no unit"
                                            if fmt != "step" else
                                            "             # as its STEP header says"))
    del tol  # a scene says what a user knows: the engine chooses the tessellation
    return "".join("\n" + line for line in lines)


def write_pair(pair: Pair) -> None:
    file1, tol1, unit1 = _export(pair, pair.fixed, None)
    file2, tol2, unit2 = _export(pair, pair.moving, pair.moving[5])
    start = [pair.assembled[i] - pair.backoff * pair.axis[i] for i in range(3)]
    start += list(pair.assembled[3:])
    (OUT / pair.folder / "scene.toml").write_text(SCENE.format(
        title=pair.title, fit=pair.fit, free=pair.free, assembled=_fmt(pair.assembled),
        free_axes="[" + ", ".join(f'"{a}"' for a in FREE_AXES[pair.folder]) + "]",
        axis=_fmt(pair.axis),
        name1=pair.fixed[0], file1=file1, extra1=_extra(unit1, tol1, pair.fixed[2]),
        name2=pair.moving[0], file2=file2, extra2=_extra(unit2, tol2, pair.moving[2]),
        start=_fmt(start), backoff=pair.backoff))
    (OUT / pair.folder / "SOURCE.md").write_text(
        f"# {pair.title}\n\nModelled for skelasm by `assets/make_real_pairs.py` (gmsh's "
        "OpenCASCADE kernel) to the fit below; released under the project's licence.\n\n"
        f"- Fit: {pair.fit}\n- Free axes: {pair.free}\n"
        f"- Files: `{file1}` ({pair.fixed[2].upper()}, {unit1}), `{file2}` "
        f"({pair.moving[2].upper()}, {unit2})\n")


def main(argv: list[str]) -> int:
    global occ
    gmsh.initialize(["-noenv"])
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setString("Geometry.OCCTargetUnit", "MM")
    occ = gmsh.model.occ
    try:
        for pair in PAIRS:
            if argv and pair.folder not in argv:
                continue
            write_pair(pair)
            print(f"{pair.folder}: written")
    finally:
        gmsh.finalize()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
