"""Loading a scene's parts into the scene's unit, with the checks that keep units honest.

Each part has a unit: the ``unit`` of its ``[[part]]`` if given, else the one its STEP
header declares; a mesh file (STL, OBJ, PLY, OFF) carries none and is read in the scene's
unit. Every part is converted into the scene's unit. Four checks warn, once per scene:

- a scene that declares no ``units`` and holds a mesh part without a ``unit`` (the mesh is
  read as millimetres, which is wrong for the many OBJ files drawn in metres);
- two parts whose sizes differ by a factor near 25.4, 1000, 100 or 10 (after allowing for
  mating parts of somewhat different size): the signature of a part read in the wrong
  unit, such as an inch declaration on a part drawn in millimetres, or a mesh in metres
  read as millimetres. The message names the part, the unit it was read in and where that
  came from, the unit that would explain it, and the ``unit`` line that fixes it;
- poses that keep the parts many times their size apart (``units = "m"`` over poses
  written in millimetres): the energy is 0 wherever part 2 goes;
- poses that move part 2 by a sliver of the parts' size (``units = "um"`` over poses
  written in millimetres, with parts converted from their files): the parts overlap.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from engine.loading import Part, load_part
from engine.params import LENGTH_UNITS
from engine.scene.model import Scene

#: Size ratios that betray a unit mix-up (a part read in a unit this many times too large).
UNIT_FACTORS = (25.4, 1000.0, 100.0, 10.0)
#: Parts of one assembly whose largest sides differ by less than this are never suspected.
COMPARABLE_RATIO = 4.0
#: How far apart two mating parts' sizes may be once a suspected unit error is undone.
MATING_SPREAD = 3.0
#: Without other evidence (both parts' units from the same kind of source and equal), only a
#: ratio this close (relative) to a unit factor is suspected.
EXACT_TOLERANCE = 0.1


def load_scene_parts(scene: Scene) -> list[Part]:
    """Load every part of a scene (``engine.loading.Part``), converted into the scene's unit.

    Each part's ``unit`` becomes the scene's; a line in its ``warnings`` says when it was
    converted, and the unit checks of this module add theirs (each once per scene).
    """
    return load_scene_parts_and_units(scene)[0]


def load_scene_parts_and_units(scene: Scene) -> tuple[list[Part], list[str]]:
    """:func:`load_scene_parts`, and the unit each part's file was read in.

    The file's unit is what a ``[[part]] tolerance`` is written in (the STEP header's,
    or the part's ``unit``).
    """
    parts: list[Part] = []
    units: list[str] = []  # each part's unit before conversion
    kinds: list[str] = []  # where it came from: "part" (its [[part]]), "header", "mesh"
    for spec in scene.parts:
        part = load_part(spec.file, tolerance=spec.tolerance, body=spec.body, unit=spec.unit)
        notes = list(part.warnings)
        if spec.unit is not None:
            unit, kind = spec.unit, "part"
        elif part.unit in LENGTH_UNITS:
            unit, kind = part.unit, "header"
        else:
            unit, kind = scene.units, "mesh"
        vertices = part.vertices
        if unit != scene.units:
            factor = LENGTH_UNITS[unit] / LENGTH_UNITS[scene.units]
            vertices = vertices * factor
            notes.append(f"{spec.file}: converted from {unit} to the scene's {scene.units} "
                         f"(x{factor:g})")
        parts.append(replace(part, name=spec.name, vertices=vertices, unit=scene.units,
                             warnings=tuple(notes)))
        units.append(unit)
        kinds.append(kind)

    meshes = [i for i, k in enumerate(kinds) if k == "mesh"]
    if meshes and not scene.units_declared:
        names = ", ".join(repr(scene.parts[j].name) for j in meshes)
        parts[meshes[0]] = _warn(parts[meshes[0]], (
            f"{scene.path}: the scene declares no units, and {names} "
            f"{'is a mesh file' if len(meshes) == 1 else 'are mesh files'} (STL, OBJ, PLY, "
            f"OFF carry no unit): read as {scene.units}. If that is wrong (OBJ files are often "
            'in metres), add `units = "m"` (or the right unit) at the top of the scene, or '
            '`unit = "m"` to the part\'s [[part]]'))
    if len(parts) >= 2:
        sizes = [float(np.max(p.extent)) for p in parts[:2]]
        pair = [s.name for s in scene.parts[:2]]
        message = unit_mismatch(sizes, pair, units[:2], kinds[:2], scene.units)
        if message is not None:
            parts[1] = _warn(parts[1], f"{scene.path}: {message}")
        for check in (out_of_reach, too_near):
            message = check(scene, sizes)
            if message is not None:
                parts[1] = _warn(parts[1], f"{scene.path}: {message}")
    return parts, units


#: Poses that keep the parts farther apart than this many times their summed sizes never
#: let their densities meet (the energy is 0 there): the signature of poses written in
#: another unit than the scene's (``units = "m"`` over poses in millimetres).
POSE_REACH = 10.0


def _distances(scene: Scene) -> tuple[float, float]:
    """How far part 2 starts from part 1, and how far it is assembled from it."""
    start = float(np.linalg.norm(scene.parts[1].pose[:3] - scene.parts[0].pose[:3]))
    seat = float(np.linalg.norm(np.asarray(scene.assembled_pose, float)[:3]))
    return start, seat


def out_of_reach(scene: Scene, sizes: list[float]) -> str | None:
    """A warning when the scene's poses keep part 2 out of part 1's reach, else None.

    Parameters
    ----------
    scene : Scene
    sizes : list of 2 float
        Largest bounding-box side of each part, in the scene's unit.
    """
    reach = POSE_REACH * (sizes[0] + sizes[1])
    start, seat = _distances(scene)
    if not (reach > 0) or min(start, seat) <= reach:
        return None
    u = scene.units
    return (f"part 2 starts {start:.4g} {u} from part 1 and is assembled {seat:.4g} {u} from "
            f"it, more than {POSE_REACH:g} times the parts' sizes ({sizes[0]:.4g} and "
            f"{sizes[1]:.4g} {u}): their densities never meet there and the energy is 0. "
            f"Poses are read in the scene's unit ({u}); if they were written in another, "
            "correct `units` or the poses")


#: Poses whose translations are all under this fraction of the smaller part's size, and not
#: all zero, betray poses written in a larger unit than the scene's (millimetres under
#: ``units = "um"``): the parts, converted from their files, are far larger than the moves.
POSE_NEAR = 0.01


def too_near(scene: Scene, sizes: list[float]) -> str | None:
    """A warning when the scene's poses move part 2 by a sliver of the parts' size, else None.

    Parameters
    ----------
    scene : Scene
    sizes : list of 2 float
        Largest bounding-box side of each part, in the scene's unit.
    """
    start, seat = _distances(scene)
    near = POSE_NEAR * min(sizes)
    if not near > 0 or max(start, seat) == 0 or max(start, seat) >= near:
        return None
    u = scene.units
    return (f"part 2 starts {start:.4g} {u} from part 1 and is assembled {seat:.4g} {u} from "
            f"it, under {100 * POSE_NEAR:g} % of the parts' sizes ({sizes[0]:.4g} and "
            f"{sizes[1]:.4g} {u}): the parts overlap wherever part 2 goes. Poses are read in "
            f"the scene's unit ({u}); if they were written in a larger one, correct `units` "
            "or the poses")


_SOURCES = {"part": "its [[part]] unit", "header": "its STEP header",
            "mesh": "a mesh file carries none: the scene's unit"}


def unit_mismatch(sizes: list[float], names: list[str], units: list[str], kinds: list[str],
                  scene_units: str) -> str | None:
    """A warning when two parts' sizes betray a unit mix-up, else None.

    Mating parts are of comparable size. When the larger part's largest side is many times
    the smaller's, and dividing the ratio by a unit factor (25.4, 1000, 100, 10) brings it
    within :data:`MATING_SPREAD` of 1, one part was most likely read in the wrong unit. That
    is suspected when the two parts' units differ or only one is a mesh file without a
    unit; when their units agree and come from the same kind of source, only a ratio
    within :data:`EXACT_TOLERANCE` of a factor is.

    Parameters
    ----------
    sizes : list of 2 float
        Largest bounding-box side of each part, in the scene's unit.
    names : list of 2 str
    units : list of 2 str
        The unit each part was read in (before conversion into the scene's).
    kinds : list of 2 str
        Where that unit came from: ``"part"`` (its ``[[part]]``), ``"header"`` (its STEP
        header) or ``"mesh"`` (a mesh file without one: the scene's unit).
    scene_units : str
    """
    if min(sizes) <= 0:
        return None
    big = int(np.argmax(sizes))
    small = 1 - big
    ratio = sizes[big] / sizes[small]
    if ratio < COMPARABLE_RATIO:
        return None
    factor = min(UNIT_FACTORS, key=lambda k: abs(math.log(ratio / k)))
    rest = ratio / factor
    if abs(math.log(rest)) > math.log(MATING_SPREAD):
        return None
    evidence = units[0] != units[1] or (kinds[0] != kinds[1] and "mesh" in kinds)
    if not evidence and abs(math.log(rest)) > math.log1p(EXACT_TOLERANCE):
        return None
    # the suspect: a part whose unit stands apart (a mesh read in the scene's unit, or a
    # unit unlike the other part's); the larger one was read in too large a unit
    suspect = big
    if kinds[small] == "mesh" and kinds[big] != "mesh":
        suspect = small
    metres = LENGTH_UNITS[units[suspect]] * (1 / factor if suspect == big else factor)
    right = next((u for u, m in LENGTH_UNITS.items() if math.isclose(m, metres, rel_tol=1e-9)),
                 None)
    if right is not None:
        really, fix = right, f'give its [[part]] `unit = "{right}"`'
    else:
        really = f"a unit {factor:g} times {'smaller' if suspect == big else 'larger'}"
        fix = "give its [[part]] the unit its file is drawn in"
    return (
        f"parts {names[big]!r} ({sizes[big]:.4g} {scene_units}) and {names[small]!r} "
        f"({sizes[small]:.4g} {scene_units}) differ in size by a factor of {ratio:.4g}, "
        f"close to {factor:g}: likely {names[suspect]!r} is not in {units[suspect]}, the unit "
        f"it was read in ({_SOURCES[kinds[suspect]]}), but in {really}. If so, {fix}; if "
        "the parts really differ this much, ignore this"
    )


#: The unit checks' lines begin so, and the commands print them as warnings, not notes.
UNITS_PREFIX = "units: "


def _warn(part: Part, line: str) -> Part:
    return replace(part, warnings=(*part.warnings, UNITS_PREFIX + line))


def say_notes(lines: list[str]) -> list[str]:
    """The parts' lines as a command prints them.

    ``warning:`` for the unit checks' (the parts overlap or never meet), ``note:`` for the
    loader's repairs.
    """
    return [f"warning: {line}" if line.startswith(UNITS_PREFIX) else f"note: {line}"
            for line in lines]
