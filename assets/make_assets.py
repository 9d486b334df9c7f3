"""Generate the example parts (STEP, millimetres) with gmsh's OpenCASCADE kernel.

Run from the project root with the development extra installed (gmsh is GPL: only this
script uses it, the installed program never imports it; the STEP files it writes are
committed)::

    .venv/bin/python assets/make_assets.py

Every pair is modelled in its assembly frame (part 1's own frame). Part 2 is then moved so
that its own frame origin sits at a natural point of the part (the peg's tip, the cover's
underside, ...); the scene's ``assembled_pose`` is that point, a pure translation with round
numbers, so the answer the tests check is exact. Mating surfaces have zero clearance: the
moving part's pockets are cut with the fixed part's own solid.

Besides the four pairs, the script writes ``tests/data/two_bodies.step`` (a multi-body STEP
with named solids) and ``tests/data/corrupt.step`` (a truncated STEP) for the loader tests.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import gmsh

ROOT = Path(__file__).resolve().parent.parent
ASSETS = ROOT / "assets"
TEST_DATA = ROOT / "tests" / "data"

occ = None  # gmsh.model.occ once initialised


# --------------------------------------------------------------------------- helpers
def _start(name: str) -> None:
    gmsh.model.add(name)


def _write_step(path: Path, names: list[str]) -> None:
    """Write every volume of the current model to ``path`` and name its products.

    gmsh's STEP writer calls every product ``Open CASCADE STEP translator ...``; the
    loader reads product names as part names, so they are replaced here, in order: the
    root product gets the file's stem, the solids get ``names``.
    """
    occ.synchronize()
    path.parent.mkdir(parents=True, exist_ok=True)
    gmsh.write(str(path))
    text = path.read_text()
    pattern = re.compile(r"PRODUCT\('([^']*)',\s*'([^']*)'")
    found = pattern.findall(text)
    if len(found) == 1:
        labels = [names[0]]
    else:
        if len(found) != len(names) + 1:
            raise RuntimeError(f"{path}: {len(found)} products for {len(names)} names")
        labels = [path.stem, *names]
    it = iter(labels)
    text = pattern.sub(lambda m: f"PRODUCT('{(label := next(it))}',\n  '{label}'", text)
    # the date in the header would make every run differ from the committed files
    text = re.sub(r"FILE_NAME\('([^']*)','[^']*'", r"FILE_NAME('\1','2026-01-01T00:00:00'", text)
    path.write_text(text)


def _curves_in_box(xmin, ymin, zmin, xmax, ymax, zmax) -> list[int]:
    occ.synchronize()
    found = gmsh.model.getEntitiesInBoundingBox(xmin, ymin, zmin, xmax, ymax, zmax, 1)
    return [t for d, t in found]


def _fuse(a: int, others: list[int]) -> int:
    out, _ = occ.fuse([(3, a)], [(3, t) for t in others])
    vols = [t for d, t in out if d == 3]
    if len(vols) != 1:
        raise RuntimeError(f"fuse gave {len(vols)} volumes")
    return vols[0]


def _cut(a: int, tools: list[int]) -> int:
    out, _ = occ.cut([(3, a)], [(3, t) for t in tools])
    vols = [t for d, t in out if d == 3]
    if len(vols) != 1:
        raise RuntimeError(f"cut gave {len(vols)} volumes")
    return vols[0]


def _prism_yz(points_yz: list[tuple[float, float]], x0: float, length: float) -> int:
    """Prism of a polygon in a plane x = x0, extruded by ``length`` along +x."""
    pts = [occ.addPoint(x0, y, z) for y, z in points_yz]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    out = occ.extrude([(2, surface)], length, 0, 0)
    return [t for d, t in out if d == 3][0]


def _prism_xz(points_xz: list[tuple[float, float]], y0: float, length: float) -> int:
    """Prism of a polygon in a plane y = y0, extruded by ``length`` along +y."""
    pts = [occ.addPoint(x, y0, z) for x, z in points_xz]
    lines = [occ.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
    out = occ.extrude([(2, surface)], 0, length, 0)
    return [t for d, t in out if d == 3][0]


# --------------------------------------------------------------------------- (a) peg in hole
# Block 40 x 40 x 20, top face at z = 0 centred on the z axis, blind hole radius 5, depth 15.
# Peg: radius 5, length 30, own origin at the centre of its bottom face. Seated: peg bottom
# on the hole bottom, so assembled_pose = (0, 0, -15).
PEG_R, HOLE_DEPTH, PEG_LEN = 5.0, 15.0, 30.0


def peg_block() -> int:
    block = occ.addBox(-20, -20, -20, 40, 40, 20)
    hole = occ.addCylinder(0, 0, -HOLE_DEPTH, 0, 0, HOLE_DEPTH + 1, PEG_R)
    block = _cut(block, [hole])
    # a 1 mm chamfer-like round on the hole's mouth makes a lead-in, as real parts have
    edge = _curves_in_box(-PEG_R - 0.1, -PEG_R - 0.1, -0.1, PEG_R + 0.1, PEG_R + 0.1, 0.1)
    out = occ.fillet([block], edge, [1.0])
    return [t for d, t in out if d == 3][0]


def peg() -> int:
    z0 = -HOLE_DEPTH  # seated, in the block's frame
    body = occ.addCylinder(0, 0, z0, 0, 0, PEG_LEN, PEG_R)
    # round the top edge only: the bottom must sit flat on the hole's bottom
    edge = _curves_in_box(-PEG_R - 0.1, -PEG_R - 0.1, z0 + PEG_LEN - 0.1, PEG_R + 0.1,
                          PEG_R + 0.1, z0 + PEG_LEN + 0.1)
    out = occ.fillet([body], edge, [1.0])
    return [t for d, t in out if d == 3][0]


# --------------------------------------------------------------------------- (b) boss and pins
# Base plate 60 x 40 x 8 with its top face at z = 0; a boss radius 10, height 10, filleted to
# the plate (radius 2, concave) and with a rounded top edge (radius 3, a toroidal patch); two
# pins with hemispherical tips at unequal places so that the fit is unique. The cover is a
# 60 x 40 x 16 block on top of the plate with the matching pockets (cut with the base itself:
# zero clearance). Cover origin: the centre of its underside, which is the plate's top face
# centre when assembled: assembled_pose = (0, 0, 0) plus no rotation.
BOSS_R, BOSS_H = 10.0, 10.0
PINS = ((20.0, 8.0, 2.5, 7.0), (-21.0, -9.0, 2.0, 6.0))  # x, y, radius, height (tip included)


def boss_base() -> int:
    plate = occ.addBox(-30, -20, -8, 60, 40, 8)
    boss = occ.addCylinder(0, 0, 0, 0, 0, BOSS_H, BOSS_R)
    base = _fuse(plate, [boss])
    top = _curves_in_box(-BOSS_R - .1, -BOSS_R - .1, BOSS_H - .1, BOSS_R + .1, BOSS_R + .1,
                         BOSS_H + .1)
    root = _curves_in_box(-BOSS_R - .1, -BOSS_R - .1, -.1, BOSS_R + .1, BOSS_R + .1, .1)
    out = occ.fillet([base], top + root, [3.0] * len(top) + [2.0] * len(root))
    base = [t for d, t in out if d == 3][0]
    pins = []
    for x, y, r, h in PINS:
        shaft = occ.addCylinder(x, y, -1, 0, 0, h - r + 1, r)
        tip = occ.addSphere(x, y, h - r, r)
        pins.append(_fuse(shaft, [tip]))
    return _fuse(base, pins)


def boss_cover() -> int:
    cover = occ.addBox(-30, -20, 0, 60, 40, 16)
    tool = boss_base()
    return _cut(cover, [tool])


# --------------------------------------------------------------------------- (c) bracket and slot
# Block 40 x 30 x 15 (top face z = 0) with a closed slot 30 long (x), 2 wide (y), 10 deep.
# Bracket: a thin L, web 30 x 2 x 10 going down into the slot and a flange 30 x 16 x 2 on top
# of the web, reaching towards +y, its far top edge rounded (1.5 mm). Seated, the web's bottom
# sits on the slot's floor and the flange on the block's top face (a web taller than the slot
# left the flange hanging above the block, and the energy then preferred pushing the web
# through the 5 mm floor to bring the flange down onto the top face). Bracket origin: the
# centre of the web's bottom edge: assembled_pose = (0, 0, -10).
SLOT_L, SLOT_W, SLOT_D, WEB_H = 30.0, 2.0, 10.0, 10.0


def slot_block() -> int:
    block = occ.addBox(-20, -15, -15, 40, 30, 15)
    slot = occ.addBox(-SLOT_L / 2, -SLOT_W / 2, -SLOT_D, SLOT_L, SLOT_W, SLOT_D + 1)
    return _cut(block, [slot])


def bracket() -> int:
    z0 = -SLOT_D  # seated, in the block's frame
    web = occ.addBox(-SLOT_L / 2, -SLOT_W / 2, z0, SLOT_L, SLOT_W, WEB_H)
    flange = occ.addBox(-SLOT_L / 2, -SLOT_W / 2, z0 + WEB_H, SLOT_L, 16, 2)
    body = _fuse(web, [flange])
    # the flange's far top edge is rounded (a fillet inside the L would sit in the block's
    # sharp slot edge when seated)
    far_y = -SLOT_W / 2 + 16
    outer = _curves_in_box(-SLOT_L / 2 - .1, far_y - .1, z0 + WEB_H + 2 - .1, SLOT_L / 2 + .1,
                           far_y + .1, z0 + WEB_H + 2 + .1)
    out = occ.fillet([body], outer, [1.5])
    return [t for d, t in out if d == 3][0]


# --------------------------------------------------------------------------- (d) dovetail
# Block 40 (x) x 40 (y) x 16 (z), top face z = 0, with a blind dovetail groove along y: open
# at y = -20, ending at y = 10; 10 wide at the top face, 16 wide at its floor, 8 deep (60
# degree flanks, about). The slide is the same trapezoid, 30 long, under a 20 x 30 x 5 cap
# that rests on the block's top face. Slide origin: the centre of the trapezoid's narrow top
# line at its leading end (y = 10 when seated): assembled_pose = (0, 10, 0). It goes in
# along +y.
DT_TOP, DT_BOTTOM, DT_DEPTH, DT_END = 10.0, 16.0, 8.0, 10.0


def _dovetail_profile() -> list[tuple[float, float]]:
    return [(-DT_TOP / 2, 0.0), (-DT_BOTTOM / 2, -DT_DEPTH), (DT_BOTTOM / 2, -DT_DEPTH),
            (DT_TOP / 2, 0.0)]


def dovetail_block() -> int:
    block = occ.addBox(-20, -20, -16, 40, 40, 16)
    # the groove's profile is extended 1 mm above the top face so the cut is clean
    groove = _prism_xz([(-DT_TOP / 2, 1.0), *_dovetail_profile(), (DT_TOP / 2, 1.0)],
                       -21, DT_END + 21)
    return _cut(block, [groove])


def dovetail_slide() -> int:
    tenon = _prism_xz(_dovetail_profile(), DT_END - 30.0, 30.0)
    cap = occ.addBox(-10, DT_END - 30.0, 0, 20, 30, 5)
    return _fuse(tenon, [cap])


# --------------------------------------------------------------------------- scenes
# Each moving part starts far enough back that the two parts' descriptor grids (the parts
# plus `padding` cells) do not overlap: no geometric force acts before the user moves the
# proxy, so a scene opens at rest (7 mm clear of contact at grid 56, 10 for boss_pins).
#: The degrees of freedom each fit leaves free (part 1's frame): the round peg turns in its
#: blind hole; the others are locked by their walls, floors and ends.
FREE_AXES = {"peg_in_hole": ["rz"], "boss_pins": [], "bracket_slot": [], "dovetail": []}


def free_axes_line(folder: str) -> str:
    """The scene's ``free_axes`` line for ``folder``, commented."""
    axes = FREE_AXES[folder]
    value = "[" + ", ".join(f'"{a}"' for a in axes) + "]"
    note = ("degrees of freedom the fit leaves free, part 1's frame" if axes
            else "the fit locks every axis")
    return f"free_axes = {value}   # {note}"


SCENE_TEMPLATE = """\
# {title}: generated by assets/make_assets.py ({note})
name = "{title}"
units = "mm"
assembled_pose = {assembled}   # part 2 in part 1's frame when seated
insertion_axis = {axis}        # direction part 2 travels to seat, part 1's frame
{free_axes}

[descriptor]
sigma = 0.5
penalty = 3.0
grid = {grid}          # samples along the longest side of the largest part
padding = 6

[correlation]
modes = 24           # from K = 24 the seated pose is the energy minimum; K = 16 is faster

[[part]]             # fixed
name = "{name1}"
file = "{file1}"
pose = [0, 0, 0, 0, 0, 0]
fixed = true

[[part]]             # moving: starts {backoff} mm back along the insertion axis
name = "{name2}"
file = "{file2}"
pose = {start}
"""


def _fmt(v) -> str:
    return "[" + ", ".join(f"{x:g}" for x in v) + "]"


def write_pair(folder: str, title: str, note: str, part1, part2, assembled, axis,
               backoff: float, grid: int = 56) -> None:
    (name1, fn1), (name2, fn2, origin2) = part1, part2
    out = ASSETS / folder
    for name, fn, shift in ((name1, fn1, None), (name2, fn2, origin2)):
        gmsh.clear()
        _start(name)
        vol = fn()
        if shift is not None:
            occ.translate([(3, vol)], -shift[0], -shift[1], -shift[2])
        _write_step(out / f"{name}.step", [name])
    start = [assembled[i] - backoff * axis[i] for i in range(3)] + [0.0, 0.0, 0.0]
    (out / "scene.toml").write_text(
        SCENE_TEMPLATE.format(
            title=title, note=note, assembled=_fmt(assembled), axis=_fmt(axis), grid=grid,
            name1=name1, file1=f"{name1}.step", name2=name2, file2=f"{name2}.step",
            start=_fmt(start), backoff=f"{backoff:g}", free_axes=free_axes_line(folder),
        )
    )


def main() -> int:
    global occ
    gmsh.initialize(["-noenv"])
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setString("Geometry.OCCTargetUnit", "MM")
    occ = gmsh.model.occ
    try:
        write_pair("peg_in_hole", "Peg in hole", "blind hole, zero clearance",
                   ("block", peg_block), ("peg", peg, (0, 0, -HOLE_DEPTH)),
                   [0, 0, -HOLE_DEPTH, 0, 0, 0], [0, 0, -1], backoff=27)
        write_pair("boss_pins", "Boss and pins", "filleted boss, two pins, matching cover",
                   ("base", boss_base), ("cover", boss_cover, (0, 0, 0)),
                   [0, 0, 0, 0, 0, 0], [0, 0, -1], backoff=27)
        write_pair("bracket_slot", "Bracket in slot", "2 mm wall in a 2 mm slot",
                   ("block", slot_block), ("bracket", bracket, (0, 0, -SLOT_D)),
                   [0, 0, -SLOT_D, 0, 0, 0], [0, 0, -1], backoff=22)
        write_pair("dovetail", "Dovetail", "blind dovetail groove, slides in along +y",
                   ("block", dovetail_block), ("slide", dovetail_slide, (0, DT_END, 0)),
                   [0, DT_END, 0, 0, 0, 0], [0, 1, 0], backoff=42)
        # a multi-body STEP: the peg-in-hole pair, seated, in one file
        gmsh.clear()
        _start("two_bodies")
        peg_block()
        peg()
        _write_step(TEST_DATA / "two_bodies.step", ["block", "peg"])
    finally:
        gmsh.finalize()
    # a STEP file cut off in the middle of its DATA section
    text = (ASSETS / "peg_in_hole" / "peg.step").read_text()
    (TEST_DATA / "corrupt.step").write_text(text[: len(text) // 3])
    return 0


if __name__ == "__main__":
    sys.exit(main())
