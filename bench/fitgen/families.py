"""The families of fits real products have, each a random design drawn from a generator.

Every family is a function ``(rng) -> FitDesign`` that draws the sizes of one pair and
returns how to model both parts with the CAD kernel (:mod:`bench.fitgen.kernel`) and the
fit's ground truth, all in one *canonical* frame: millimetres, part 2 seated, travelling
along -z to get there, part 1 below it (its top face at z = 0 for most families), the fit's
axis on the z axis. :mod:`bench.fitgen.generate` then places both parts in their files'
own frames (insertion axis anywhere, origins off the axis) and converts the truth with them.

Sizes: a nominal size (the fit's diameter or width) from 3 to 150 mm, log-uniform within
each family's sensible range; clearances from 0.005 to 0.5 mm (diametral: the total play
across the fit), log-uniform, at most a tenth of the size. Plays are small-angle estimates of
how far part 2 can move from its centred seat before it touches part 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from bench.fitgen import kernel as k

#: Range of nominal sizes and of diametral clearances (mm).
SIZE_RANGE = (3.0, 150.0)
CLEARANCE_RANGE = (0.005, 0.5)

Z = (0.0, 0.0, 1.0)


@dataclass(frozen=True)
class FitDesign:
    """One pair drawn from a family, in the canonical frame (mm; see the module docstring).

    Attributes
    ----------
    family : str
    description : str
        One line: the fit and its sizes.
    names : (str, str)
        Part names (the files' stems): fixed, moving.
    fixed, moving : callable () -> int
        Model the part's solid in the current gmsh model, seated; return its volume tag.
    nominal : float
        Nominal size of the fit (its diameter or width), mm.
    clearance : float
        Diametral clearance of the main fit, mm.
    radial_play : float
        Largest move of part 2 across the insertion axis, from its centred seat, before it
        touches part 1 (mm).
    angular_play : float
        Largest turn of part 2 about a constrained axis through :attr:`centre`, from its
        seat, before it touches (radians; small-angle estimate).
    min_gap : float
        Smallest gap anywhere in the fit (mm): the tessellation's chord error must stay
        below it or the meshes touch.
    free_translations, free_rotations : tuple of (3,) tuple
        Unit vectors of the directions the fit leaves free (translation along, rotation
        about).
    centre : (3,) tuple
        Point of part 2 on the fit's axis, halfway along the engagement: where the misaim
        tilts it, and where its position error is measured.
    lateral : (3,) tuple
        Unit direction, across the insertion axis and constrained, of the sideways misaim.
    """

    family: str
    description: str
    names: tuple[str, str]
    fixed: Callable[[], int]
    moving: Callable[[], int]
    nominal: float
    clearance: float
    radial_play: float
    angular_play: float
    min_gap: float
    free_translations: tuple[tuple[float, float, float], ...] = ()
    free_rotations: tuple[tuple[float, float, float], ...] = ()
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lateral: tuple[float, float, float] = (1.0, 0.0, 0.0)
    extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- draws
def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


def _mm(x: float) -> float:
    """A drawn length rounded to 0.01 mm, as a drawing gives it."""
    return round(x, 2)


def _size(rng: np.random.Generator, lo: float = SIZE_RANGE[0],
          hi: float = SIZE_RANGE[1]) -> float:
    return _mm(_log_uniform(rng, max(lo, SIZE_RANGE[0]), min(hi, SIZE_RANGE[1])))


def _clearance(rng: np.random.Generator, size: float) -> float:
    """Diametral clearance, 5 to 500 micrometres, at most a tenth of ``size``; to 1 um."""
    hi = min(CLEARANCE_RANGE[1], 0.1 * size)
    return round(_log_uniform(rng, CLEARANCE_RANGE[0], hi), 3)


def _chamfer(rng: np.random.Generator, size: float, most: float = 0.08) -> float:
    """A lead-in chamfer of up to ``most`` of ``size`` (none in a third of the parts)."""
    if rng.uniform() < 1 / 3:
        return 0.0
    return _mm(max(0.05, size * _u(rng, 0.02, most)))


# --------------------------------------------------------------------------- families
def round_peg(rng: np.random.Generator, *, through: bool) -> FitDesign:
    """A round peg in a through hole in a plate, or in a blind hole in a block."""
    d = _size(rng)
    c = _clearance(rng, d)
    depth = _mm(d * _u(rng, 0.6, 1.5))               # plate thickness / hole depth
    side = _mm(d * _u(rng, 1.8, 3.0))
    below = _mm(d * _u(rng, 0.1, 0.3)) if through else 0.0
    length = _mm(depth + below + d * _u(rng, 0.4, 1.2))
    tip, sink = _chamfer(rng, d), _chamfer(rng, d, 0.05)
    bottom = -depth - below
    height = depth if through else _mm(depth + d * _u(rng, 0.3, 0.8))

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -height, side, side, height)
        tools = [k.cylinder(-height - 1, height + 2, (d + c) / 2) if through
                 else k.cylinder(-depth, depth + 1, (d + c) / 2)]
        if sink:
            tools.append(k.countersink(0.0, (d + c) / 2, sink))
        return k.cut(block, tools)

    def moving() -> int:
        return k.rod(bottom, length, d / 2, chamfer0=tip)

    kind = "through hole in a plate" if through else "blind hole"
    return FitDesign(
        family="round_through" if through else "round_blind",
        description=f"round peg {d:g} in a {kind} {d + c:g} ({depth:g} deep), clearance {c:g}",
        names=("plate" if through else "block", "peg"), fixed=fixed, moving=moving,
        nominal=d, clearance=c, radial_play=c / 2, angular_play=math.atan(c / depth),
        min_gap=c / 2, free_translations=(Z,) if through else (), free_rotations=(Z,),
        centre=(0.0, 0.0, bottom + length / 2))


def rect_peg(rng: np.random.Generator, *, through: bool) -> FitDesign:
    """A rectangular peg in a through hole in a plate, or in a blind pocket."""
    a = _size(rng)
    b = _mm(a * _u(rng, 0.4, 1.0))
    c = _clearance(rng, b)
    depth = _mm(max(a, b) * _u(rng, 0.5, 1.2))
    side = _mm(a * _u(rng, 1.8, 2.8))
    below = _mm(b * _u(rng, 0.1, 0.3)) if through else 0.0
    length = _mm(depth + below + b * _u(rng, 0.4, 1.2))
    height = depth if through else _mm(depth + b * _u(rng, 0.3, 0.8))
    bottom = -depth - below
    round_ = _mm(b * _u(rng, 0.02, 0.06)) if rng.uniform() < 0.5 else 0.0

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -height, side, side, height)
        if through:
            return k.cut(block, [k.centred_box(a + c, b + c, -height - 1, height + 2)])
        return k.cut(block, [k.centred_box(a + c, b + c, -depth, depth + 1)])

    def moving() -> int:
        peg = k.centred_box(a, b, bottom, length)
        return k.fillet_edges_at(peg, bottom, max(a, b), round_) if round_ else peg

    kind = "through hole in a plate" if through else "blind pocket"
    twist = c / max(a, b)
    return FitDesign(
        family="rect_through" if through else "rect_blind",
        description=f"rectangular peg {a:g} x {b:g} in a {kind} {a + c:g} x {b + c:g} "
        f"({depth:g} deep), clearance {c:g}",
        names=("plate" if through else "block", "peg"), fixed=fixed, moving=moving,
        nominal=a, clearance=c, radial_play=c / 2,
        angular_play=max(math.atan(c / depth), twist), min_gap=c / 2,
        free_translations=(Z,) if through else (), centre=(0.0, 0.0, bottom + length / 2))


def round_through(rng: np.random.Generator) -> FitDesign:
    """Round peg, through hole (free: along and about the axis)."""
    return round_peg(rng, through=True)


def round_blind(rng: np.random.Generator) -> FitDesign:
    """Round peg, blind hole (free: about the axis)."""
    return round_peg(rng, through=False)


def rect_through(rng: np.random.Generator) -> FitDesign:
    """Rectangular peg, through hole (free: along the axis)."""
    return rect_peg(rng, through=True)


def rect_blind(rng: np.random.Generator) -> FitDesign:
    """Rectangular peg, blind pocket (free: none)."""
    return rect_peg(rng, through=False)


def stepped(rng: np.random.Generator) -> FitDesign:
    """A stepped, chamfered peg in a counterbored hole; its shoulder seats on the step."""
    d1 = _size(rng, 6.0)
    d2 = _mm(d1 * _u(rng, 0.45, 0.75))
    c = _clearance(rng, d2)
    h1 = _mm(d1 * _u(rng, 0.3, 0.8))                 # counterbore depth
    h2 = _mm(d2 * _u(rng, 0.6, 1.5))                 # small bore depth below it
    gap = _mm(max(0.2, 0.1 * d2))                    # the small end stops short of the floor
    through = bool(rng.uniform() < 0.5)
    side = _mm(d1 * _u(rng, 1.8, 2.6))
    height = _mm(h1 + h2 + (0 if through else d2 * _u(rng, 0.3, 0.6)))
    above = _mm(d1 * _u(rng, 0.3, 0.8))
    tip, step_chamfer, sink = _chamfer(rng, d2, 0.1), _chamfer(rng, d2, 0.05), \
        _chamfer(rng, d1, 0.04)
    bottom = -h1 - h2 + gap

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -height, side, side, height)
        small = (k.cylinder(-height - 1, height + 2, (d2 + c) / 2) if through
                 else k.cylinder(-h1 - h2, h2 + 1, (d2 + c) / 2))
        tools = [k.cylinder(-h1, h1 + 1, (d1 + c) / 2), small]
        if sink:
            tools.append(k.countersink(0.0, (d1 + c) / 2, sink))
        if step_chamfer:
            tools.append(k.countersink(-h1, (d2 + c) / 2, step_chamfer))
        return k.cut(block, tools)

    def moving() -> int:
        big = k.rod(-h1, h1 + above, d1 / 2, chamfer1=_mm(0.05 * d1))
        small = k.rod(bottom, h1 + h2 - gap + 0.0, d2 / 2, chamfer0=tip)
        return k.fuse(big, [small])

    return FitDesign(
        family="stepped", description=f"stepped peg {d1:g} / {d2:g} in a counterbored "
        f"{'through' if through else 'blind'} hole {d1 + c:g} x {h1:g} deep / {d2 + c:g}, "
        f"clearance {c:g}; the shoulder seats on the step",
        names=("block", "stepped_peg"), fixed=fixed, moving=moving, nominal=d1, clearance=c,
        radial_play=c / 2, angular_play=math.atan(c / (h1 + h2 - gap)), min_gap=c / 2,
        free_rotations=(Z,), centre=(0.0, 0.0, 0.5 * (bottom + above)))


def keyed(rng: np.random.Generator) -> FitDesign:
    """A hub slid onto a shaft with a parallel key, stopped by the shaft's collar."""
    d = _size(rng, 8.0)
    c = _clearance(rng, d)
    ck = round(min(CLEARANCE_RANGE[1], max(CLEARANCE_RANGE[0], c * _u(rng, 0.5, 2.0))), 3)
    w = _mm(d * _u(rng, 0.22, 0.3))                  # key width
    h = _mm(w * _u(rng, 0.9, 1.1))                   # key height
    t1 = _mm(0.6 * h)                                 # depth in the shaft
    top_gap = _mm(_u(rng, 0.1, 0.4) + c)
    hub_len = _mm(d * _u(rng, 0.8, 1.5))
    hub_od = _mm(d * _u(rng, 1.6, 2.2) + 2 * (h - t1))
    collar_d = _mm(min(hub_od * 0.95, d * _u(rng, 1.3, 1.6) + 2 * (h - t1)))
    collar_h = _mm(d * _u(rng, 0.3, 0.6))
    shaft_len = _mm(hub_len + d * _u(rng, 0.2, 0.8))
    key_lo, key_hi = _mm(0.15 * hub_len), _mm(shaft_len - 0.1 * hub_len)

    def fixed() -> int:
        collar = k.cylinder(-collar_h, collar_h, collar_d / 2)
        shaft = k.rod(-0.5, shaft_len + 0.5, d / 2, chamfer1=_mm(0.04 * d))
        key = k.box(-w / 2, d / 2 - t1, key_lo, w, h, key_hi - key_lo)
        return k.fuse(collar, [shaft, key])

    def moving() -> int:
        body = k.cylinder(0, hub_len, hub_od / 2)
        bore = k.cylinder(-1, hub_len + 2, (d + c) / 2)
        keyway = k.box(-(w + ck) / 2, 0, -1, w + ck, d / 2 + (h - t1) + top_gap, hub_len + 2)
        return k.cut(body, [bore, keyway])

    twist = ck / (d / 2 + (h - t1) / 2)
    return FitDesign(
        family="keyed", description=f"hub bore {d + c:g} on a shaft {d:g} (clearance {c:g}) "
        f"with a parallel key {w:g} x {h:g} in a keyway {w + ck:g} (clearance {ck:g}); the "
        "hub stops on the shaft's collar",
        names=("shaft", "hub"), fixed=fixed, moving=moving, nominal=d, clearance=c,
        radial_play=c / 2, angular_play=max(math.atan(c / hub_len), twist),
        min_gap=min(c, ck) / 2, centre=(0.0, 0.0, hub_len / 2))


def _spline_solid(minor: float, major: float, width: float, teeth: int, z0: float,
                  length: float) -> int:
    core = k.cylinder(z0, length, minor / 2)
    boxes = []
    for i in range(teeth):
        tooth = k.box(-width / 2, 0, z0, width, major / 2 + 1, length)
        k.rotate_z(tooth, i * 2 * math.pi / teeth)
        boxes.append(tooth)
    star = k.fuse(core, boxes)
    return k.intersect(star, k.cylinder(z0 - 1, length + 2, major / 2))


def spline(rng: np.random.Generator) -> FitDesign:
    """A straight-sided splined shaft through a splined hub (free: along the axis)."""
    teeth = int(rng.choice([6, 8, 10]))
    big = _size(rng, 12.0)
    small = _mm(big * _u(rng, 0.8, 0.88))
    width = _mm(big * _u(rng, 0.18, 0.26) * 6 / teeth)
    c = _clearance(rng, big - small)
    cw = round(min(CLEARANCE_RANGE[1], max(CLEARANCE_RANGE[0], c * _u(rng, 0.8, 2.0))), 3)
    c_major = _mm(c + _u(rng, 0.1, 0.4))
    thick = _mm(big * _u(rng, 0.5, 1.2))
    side = _mm(big * _u(rng, 1.6, 2.4))
    below = _mm(big * _u(rng, 0.1, 0.3))
    length = _mm(thick + below + big * _u(rng, 0.3, 1.0))
    bottom = -thick - below

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -thick, side, side, thick)
        return k.cut(block, [_spline_solid(small + c, big + c_major, width + cw, teeth,
                                           -thick - 1, thick + 2)])

    def moving() -> int:
        return _spline_solid(small, big, width, teeth, bottom, length)

    twist = 2 * cw / (small + big)
    return FitDesign(
        family="spline", description=f"straight-sided spline {teeth} x {small:g} x {big:g}, "
        f"teeth {width:g}: minor clearance {c:g}, width {cw:g}, major {c_major:g}; through a "
        f"{thick:g} hub",
        names=("hub", "splined_shaft"), fixed=fixed, moving=moving, nominal=big, clearance=c,
        radial_play=c / 2, angular_play=max(math.atan(c / thick), twist),
        min_gap=min(c, cw) / 2, free_translations=(Z,),
        centre=(0.0, 0.0, bottom + length / 2))


def _way(rng: np.random.Generator, through: bool, width: float) -> tuple[float, float, float]:
    """(way length, seat height of the slide's lower end, slide length) along z."""
    length = _mm(width * _u(rng, 1.2, 3.0))
    stop = 0.0 if through else _mm(width * _u(rng, 0.2, 0.4))
    run = length - stop
    slide = _mm(run * _u(rng, 0.5, 0.9) if through else run * _u(rng, 0.6, 1.2))
    low = _mm(-slide * _u(rng, 0.5, 0.9)) if through else -run
    return length, low, slide


def dovetail(rng: np.random.Generator) -> FitDesign:
    """A dovetail slide in its way, open both ends (free: along the way) or stopped."""
    top = _size(rng, 8.0, 120.0)                     # groove width at the top face
    depth = _mm(top * _u(rng, 0.3, 0.45))
    angle = math.radians(float(rng.choice([45.0, 55.0, 60.0])))
    c = _clearance(rng, depth)                       # normal to each flank
    floor = _mm(c + _u(rng, 0.05, 0.3))
    through = bool(rng.uniform() < 0.5)
    length, low, slide = _way(rng, through, top)
    bw = _mm(top + 2 * depth / math.tan(angle) + top * _u(rng, 0.6, 1.2))
    base = _mm(depth * _u(rng, 0.6, 1.5))
    cap_w = _mm(top * _u(rng, 1.2, 2.0))
    cap_h = _mm(depth * _u(rng, 0.6, 1.2))

    def half(y: float, shrink: float = 0.0) -> float:
        return top / 2 - y / math.tan(angle) - shrink / math.sin(angle)

    def fixed() -> int:
        block = k.box(-bw / 2, -depth - base, -length, bw, depth + base, length)
        lead = 1 / math.tan(angle)
        z0 = -length - 1 if through else low  # a stopped way's end wall stops the slide
        groove = k.prism_xy([(-half(0.0) + lead, 1.0), (-half(-depth), -depth),
                             (half(-depth), -depth), (half(0.0) - lead, 1.0)], z0, 1 - z0)
        return k.cut(block, [groove])

    def moving() -> int:
        y = -(depth - floor)
        tenon = k.prism_xy([(-half(0.0, c), 0.0), (-half(y, c), y), (half(y, c), y),
                            (half(0.0, c), 0.0)], low, slide)
        cap = k.box(-cap_w / 2, 0.0, low, cap_w, cap_h, slide)
        return k.fuse(cap, [tenon])

    play_x, play_y = c / math.sin(angle), c / math.cos(angle)
    return FitDesign(
        family="dovetail", description=f"{math.degrees(angle):g}-degree dovetail way "
        f"{top:g} wide at the top, {depth:g} deep, {'open both ends' if through else 'stopped'}"
        f"; clearance {c:g} normal to the flanks, {floor:g} under the tenon",
        names=("way", "slide"), fixed=fixed, moving=moving, nominal=top, clearance=2 * c,
        # the largest turn: about the flanks' common normal (yaw), sideways play at each end;
        # a roll or pitch about the centre drives the cap into the face it rests on
        radial_play=max(play_x, play_y), angular_play=math.atan(2 * play_x / slide),
        min_gap=c, free_translations=(Z,) if through else (),
        centre=(0.0, 0.0, low + slide / 2), extra={"through": through})


def tslot(rng: np.random.Generator) -> FitDesign:
    """A T-slot slide (T tenon under a cap) in a T-slot, open (free: along it) or stopped."""
    neck = _size(rng, 5.0, 60.0)
    under = _mm(neck * _u(rng, 1.6, 2.0))
    neck_h = _mm(neck * _u(rng, 0.5, 1.0))
    under_h = _mm(neck * _u(rng, 0.6, 1.0))
    c = _clearance(rng, neck)
    floor = _mm(c / 2 + _u(rng, 0.1, 0.4))
    through = bool(rng.uniform() < 0.5)
    length, low, slide = _way(rng, through, under)
    bw = _mm(under + 2 * neck * _u(rng, 0.5, 1.0))
    base = _mm(neck * _u(rng, 0.4, 0.8))
    cap_w = _mm(min(bw, neck * _u(rng, 1.5, 2.5)))
    cap_h = _mm(neck * _u(rng, 0.4, 0.8))
    total = neck_h + under_h + base

    def fixed() -> int:
        block = k.box(-bw / 2, -total, -length, bw, total, length)
        z0 = -length - 1 if through else low  # a stopped slot's end wall stops the slide
        run = 1 - z0
        slot = [k.box(-neck / 2, -neck_h - 0.5, z0, neck, neck_h + 1.5, run),
                k.box(-under / 2, -neck_h - under_h, z0, under, under_h, run)]
        return k.cut(block, slot)

    def moving() -> int:
        cap = k.box(-cap_w / 2, 0.0, low, cap_w, cap_h, slide)
        stem = k.box(-(neck - c) / 2, -neck_h - c / 2, low, neck - c, neck_h + c / 2, slide)
        head_top, head_low = -neck_h - c / 2, -neck_h - under_h + floor
        head = k.box(-(under - c) / 2, head_low, low, under - c, head_top - head_low, slide)
        return k.fuse(cap, [stem, head])

    return FitDesign(
        family="tslot", description=f"T-slot slide: neck {neck - c:g} in {neck:g}, head "
        f"{under - c:g} in {under:g} (clearance {c:g}), "
        f"{'open both ends' if through else 'stopped'}",
        names=("table", "tslide"), fixed=fixed, moving=moving, nominal=neck, clearance=c,
        radial_play=c / 2, angular_play=math.atan(c / slide), min_gap=c / 2,  # yaw, as dovetail
        free_translations=(Z,) if through else (), centre=(0.0, 0.0, low + slide / 2),
        extra={"through": through})


def sleeve(rng: np.random.Generator) -> FitDesign:
    """A thin-walled sleeve in a through or blind bore."""
    d = _size(rng, 6.0)
    wall = _mm(max(0.5, d * _u(rng, 0.03, 0.08)))
    c = _clearance(rng, d)
    length = _mm(d * _u(rng, 0.6, 1.5))
    through = bool(rng.uniform() < 0.5)
    depth = _mm(length * _u(rng, 0.5, 0.85))
    side = _mm(d * _u(rng, 1.5, 2.2))
    below = _mm(length * _u(rng, 0.0, 0.1)) if through else 0.0
    height = depth if through else _mm(depth + d * _u(rng, 0.2, 0.5))
    bottom = -depth - below
    tip = _mm(min(wall / 2, _chamfer(rng, d, 0.03)))

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -height, side, side, height)
        bore = (k.cylinder(-height - 1, height + 2, (d + c) / 2) if through
                else k.cylinder(-depth, depth + 1, (d + c) / 2))
        return k.cut(block, [bore])

    def moving() -> int:
        outer = k.rod(bottom, length, d / 2, chamfer0=tip)
        return k.cut(outer, [k.cylinder(bottom - 1, length + 2, d / 2 - wall)])

    return FitDesign(
        family="sleeve", description=f"thin-walled sleeve {d:g} x {wall:g} wall in a "
        f"{'through' if through else 'blind'} bore {d + c:g}, {depth:g} deep, clearance {c:g}",
        names=("housing", "sleeve"), fixed=fixed, moving=moving, nominal=d, clearance=c,
        radial_play=c / 2, angular_play=math.atan(c / depth), min_gap=c / 2,
        free_translations=(Z,) if through else (), free_rotations=(Z,),
        centre=(0.0, 0.0, bottom + length / 2), extra={"through": through, "wall": wall})


def plate_on_pins(rng: np.random.Generator) -> FitDesign:
    """A plate with two holes lowered onto a base's two pins, resting on the base."""
    span = _size(rng, 15.0)                          # plate length (x)
    breadth = _mm(span * _u(rng, 0.4, 0.8))
    pin = _mm(max(2.0, span * _u(rng, 0.06, 0.12)))
    c = _clearance(rng, pin)
    pitch = _mm(span * _u(rng, 0.5, 0.75))
    pin_h = _mm(pin * _u(rng, 1.2, 2.5))
    thick = _mm(max(1.0, pin * _u(rng, 0.8, 1.5)))
    base_x, base_y = _mm(span * _u(rng, 1.0, 1.3)), _mm(breadth * _u(rng, 1.0, 1.3))
    base_h = _mm(max(2.0, pin * _u(rng, 1.0, 2.0)))
    tip = _mm(0.15 * pin)
    xs = (-pitch / 2, pitch / 2)

    def fixed() -> int:
        base = k.box(-base_x / 2, -base_y / 2, -base_h, base_x, base_y, base_h)
        pins = [k.rod(-base_h / 2, base_h / 2 + pin_h, pin / 2, chamfer1=tip, x=x) for x in xs]
        return k.fuse(base, pins)

    def moving() -> int:
        plate = k.box(-span / 2, -breadth / 2, 0.0, span, breadth, thick)
        return k.cut(plate, [k.cylinder(-1, thick + 2, (pin + c) / 2, x=x) for x in xs])

    engaged = min(thick, pin_h)
    return FitDesign(
        family="plate_on_pins", description=f"plate {span:g} x {breadth:g} x {thick:g} with "
        f"two holes {pin + c:g} at {pitch:g} onto two pins {pin:g} (clearance {c:g})",
        names=("base", "plate"), fixed=fixed, moving=moving, nominal=span, clearance=c,
        radial_play=c / 2, angular_play=max(math.atan(c / pitch), math.atan(c / engaged)),
        min_gap=c / 2, centre=(0.0, 0.0, thick / 2))


def bolt_nut(rng: np.random.Generator) -> FitDesign:
    """A hex-head bolt with a plain shank into a plain (unthreaded) hex nut."""
    d = _size(rng, 3.0, 64.0)
    c = _clearance(rng, d)
    s = _mm(d * _u(rng, 1.5, 1.7))                   # across flats
    m = _mm(d * _u(rng, 0.8, 1.0))                   # nut height
    head = _mm(d * _u(rng, 0.6, 0.7))
    shank = _mm(m + d * _u(rng, 0.5, 2.0))
    turn = float(rng.uniform(0, math.pi / 3))
    tip = _mm(0.1 * d)
    sink = _chamfer(rng, d, 0.1)

    def fixed() -> int:
        nut = k.prism_xy(k.hexagon(s), -m, m)
        tools = [k.cylinder(-m - 1, m + 2, (d + c) / 2)]
        if sink:
            tools.append(k.countersink(0.0, (d + c) / 2, sink))
        return k.cut(nut, tools)

    def moving() -> int:
        hexagon = k.prism_xy(k.hexagon(s), 0.0, head)
        k.rotate_z(hexagon, turn)
        return k.fuse(hexagon, [k.rod(-shank, shank + 0.5, d / 2, chamfer0=tip)])

    return FitDesign(
        family="bolt_nut", description=f"bolt {d:g} x {shank:g} (hex {s:g}) through a plain "
        f"nut {d + c:g} x {m:g}, clearance {c:g}; the head seats on the nut",
        names=("nut", "bolt"), fixed=fixed, moving=moving, nominal=d, clearance=c,
        radial_play=c / 2, angular_play=math.atan(c / m), min_gap=c / 2,
        free_rotations=(Z,), centre=(0.0, 0.0, (head - shank) / 2))


def multi_fit(rng: np.random.Generator) -> FitDesign:
    """A cover with a spigot in a recess and a hole on a dowel pin: two fits at once."""
    d = _size(rng, 10.0)
    c = _clearance(rng, d)
    pin = _mm(max(1.5, d * _u(rng, 0.08, 0.15)))
    c2 = round(min(CLEARANCE_RANGE[1], max(CLEARANCE_RANGE[0], c * _u(rng, 0.5, 2.0),)), 3)
    c2 = min(c2, round(0.1 * pin, 3))
    radius = _mm(d / 2 + pin * _u(rng, 1.2, 2.5))    # the dowel's distance from the axis
    recess = _mm(d * _u(rng, 0.1, 0.3))
    gap = _mm(max(0.1, 0.1 * recess))                # the spigot stops short of the floor
    pin_h = _mm(pin * _u(rng, 1.2, 2.0))
    cover_d = _mm(2 * radius + pin * _u(rng, 3.0, 5.0))
    cover_t = _mm(max(pin_h + 1.0, d * _u(rng, 0.15, 0.35)))
    side = _mm(cover_d * _u(rng, 1.05, 1.4))
    height = _mm(recess + d * _u(rng, 0.2, 0.5))
    angle = float(rng.uniform(0, 2 * math.pi))
    px, py = radius * math.cos(angle), radius * math.sin(angle)

    def fixed() -> int:
        block = k.box(-side / 2, -side / 2, -height, side, side, height)
        block = k.cut(block, [k.cylinder(-recess, recess + 1, (d + c) / 2)])
        dowel = k.rod(-height / 2, height / 2 + pin_h, pin / 2, chamfer1=_mm(0.15 * pin),
                      x=px, y=py)
        return k.fuse(block, [dowel])

    def moving() -> int:
        cover = k.cylinder(0.0, cover_t, cover_d / 2)
        spigot = k.rod(-recess + gap, recess - gap + 0.5, d / 2, chamfer0=_mm(0.03 * d))
        body = k.fuse(cover, [spigot])
        return k.cut(body, [k.cylinder(-recess - 1, pin_h + recess + 1.5, (pin + c2) / 2,
                                       x=px, y=py)])

    return FitDesign(
        family="multi_fit", description=f"cover with a spigot {d:g} in a recess {d + c:g} "
        f"({recess:g} deep) and a hole {pin + c2:g} on a dowel {pin:g} at radius {radius:g}",
        names=("base", "cover"), fixed=fixed, moving=moving, nominal=d, clearance=c,
        radial_play=c / 2,
        angular_play=max(math.atan((c + c2) / (2 * radius)), math.atan(c / (recess - gap))),
        min_gap=min(c, c2) / 2, centre=(0.0, 0.0, (cover_t - recess + gap) / 2))


#: The families, in the order the generator cycles through them.
FAMILIES: dict[str, Callable[[np.random.Generator], FitDesign]] = {
    "round_through": round_through,
    "round_blind": round_blind,
    "rect_through": rect_through,
    "rect_blind": rect_blind,
    "stepped": stepped,
    "keyed": keyed,
    "spline": spline,
    "dovetail": dovetail,
    "tslot": tslot,
    "sleeve": sleeve,
    "plate_on_pins": plate_on_pins,
    "bolt_nut": bolt_nut,
    "multi_fit": multi_fit,
}
