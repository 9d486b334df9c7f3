"""Loading a scene's parts into the scene's unit, with the checks that keep units honest.

Each part has a unit: the ``unit`` of its ``[[part]]`` if given, else the one its STEP
header declares; a mesh file (STL, OBJ, PLY, OFF) carries none and is read in the scene's
unit. Every part is converted into the scene's unit. Two checks warn, once per scene:

- a scene that declares no ``units`` and holds a mesh part without a ``unit`` (the mesh is
  read as millimetres, which is wrong for the many OBJ files drawn in metres);
- parts whose sizes differ by a factor near 25.4, 1000, 100 or 10: the signature of a part
  read in the wrong unit (an inch declaration on a part drawn in millimetres, a mesh in
  metres read as millimetres). The message names the units that would explain it.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from engine.loading import Part, load_part
from engine.params import LENGTH_UNITS
from engine.scene.model import Scene

#: Size ratios that betray a unit mix-up, with the unit pairs that produce them.
SUSPICIOUS_RATIOS: dict[float, tuple[tuple[str, str], ...]] = {
    25.4: (("in", "mm"),),
    1000.0: (("m", "mm"), ("mm", "um")),
    100.0: (("m", "cm"),),
    10.0: (("cm", "mm"), ("m", "dm")),
}
#: How close (relative) a size ratio must come to a suspicious one to warn.
RATIO_TOLERANCE = 0.08


def load_scene_parts(scene: Scene) -> list[Part]:
    """Load every part of a scene (``engine.loading.Part``), converted into the scene's unit.

    Each part's ``unit`` becomes the scene's; a line in its ``warnings`` says when it was
    converted, and the unit checks of this module add theirs (each once per scene).
    """
    parts: list[Part] = []
    origins: list[str] = []  # where each part's unit came from, for the messages
    unitless: list[int] = []
    for i, spec in enumerate(scene.parts):
        part = load_part(spec.file, tolerance=spec.tolerance, body=spec.body, unit=spec.unit)
        notes = list(part.warnings)
        if spec.unit is not None:
            unit, origin = spec.unit, f"read as {spec.unit} by its [[part]] unit"
        elif part.unit in LENGTH_UNITS:
            unit, origin = part.unit, f"declared {part.unit} by its STEP header"
        else:
            unit = scene.units
            origin = f"a mesh file without a unit, read in the scene's {scene.units}"
            unitless.append(i)
        vertices = part.vertices
        if unit != scene.units:
            factor = LENGTH_UNITS[unit] / LENGTH_UNITS[scene.units]
            vertices = vertices * factor
            notes.append(f"{spec.file}: converted from {unit} to the scene's {scene.units} "
                         f"(x{factor:g})")
        parts.append(replace(part, name=spec.name, vertices=vertices, unit=scene.units,
                             warnings=tuple(notes)))
        origins.append(origin)

    if unitless and not scene.units_declared:
        i = unitless[0]
        names = ", ".join(repr(scene.parts[j].name) for j in unitless)
        parts[i] = _warn(parts[i], (
            f"{scene.path}: the scene declares no units, and {names} "
            f"{'is a mesh file' if len(unitless) == 1 else 'are mesh files'} (STL, OBJ, PLY, "
            f"OFF carry no unit): read as {scene.units}. If that is wrong (OBJ files are often "
            'in metres), add `units = "m"` (or the right unit) at the top of the scene, or '
            '`unit = "m"` to the part\'s [[part]]'))
    if len(parts) >= 2:
        message = unit_mismatch(parts, [s.name for s in scene.parts], origins, scene.units)
        if message is not None:
            parts[-1] = _warn(parts[-1], f"{scene.path}: {message}")
    return parts


def unit_mismatch(parts: list[Part], names: list[str], origins: list[str], units: str
                  ) -> str | None:
    """A warning when two parts' sizes differ by a factor near a unit ratio, else None.

    Parameters
    ----------
    parts : list of Part
        The parts, converted into ``units``.
    names, origins : list of str
        Each part's name and where its unit came from.
    units : str
        The scene's unit.
    """
    sizes = [float(np.max(p.extent)) for p in parts]
    big = int(np.argmax(sizes))
    small = int(np.argmin(sizes))
    if sizes[small] <= 0:
        return None
    ratio = sizes[big] / sizes[small]
    for factor, pairs in SUSPICIOUS_RATIOS.items():
        if abs(math.log(ratio / factor)) < math.log1p(RATIO_TOLERANCE):
            causes = " or ".join(f"a part in {a} read as {b}" for a, b in pairs)
            return (
                f"parts {names[big]!r} ({sizes[big]:.4g} {units}) and {names[small]!r} "
                f"({sizes[small]:.4g} {units}) differ in size by a factor of {ratio:.4g}, close "
                f"to {factor:g}: the likely cause is {causes} ({names[big]!r}: "
                f"{origins[big]}; {names[small]!r}: {origins[small]}). If so, give that "
                "part's [[part]] the unit its file is really in, e.g. "
                f'`unit = "{pairs[0][1]}"` for {names[big]!r}'
            )
    return None


def _warn(part: Part, line: str) -> Part:
    return replace(part, warnings=(*part.warnings, line))
