"""Writing a scene: a :class:`~engine.scene.model.Scene` to TOML that reads back the same.

One writer for every table. Part files (and a trajectory device's file) are written
relative to the new file's folder where possible. The text is checked by the reader before
it replaces the destination, so a scene that could not be loaded is never written.
"""

from __future__ import annotations

import os
import re
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

import numpy as np
import numpy.typing as npt

from engine.files import write_text
from engine.params import (
    CouplingParams,
    DeviceConfig,
    Effects,
    MassSpec,
    SeatSpec,
    SimulationParams,
    gravity_vector,
)
from engine.scene.model import Scene, SceneError
from engine.scene.reader import AUTO, AXES_WORDS, CORRELATION_KEYS, parse_scene

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

#: One TOML table as tomli_w writes it: keys to numbers, strings, booleans, lists, tables.
TomlTable: TypeAlias = dict[str, object]


def _floats(a: npt.ArrayLike) -> list[float]:
    return [float(x) for x in np.asarray(a, dtype=np.float64).ravel()]


#: One scalar of an array as tomli_w writes it (number, plain string, boolean), or an array of
#: such scalars already written on one line.
_ITEM = r'(?:[-+0-9.a-z][-+0-9.eE_a-z]*|"[^"\\\n]*"|\[[^\[\]\n"]*\])'
_MULTILINE_ARRAY = re.compile(r"\[\n((?:[ ]+" + _ITEM + r",\n)+)[ ]*\]")


def compact_arrays(text: str) -> str:
    r"""``text`` with tomli_w's one-item-per-line arrays of scalars written on one line.

    ``pose = [\n    0.0,\n    12.0,\n]`` becomes ``pose = [0.0, 12.0]``; arrays of such
    arrays (a 3x3 inertia) go on one line too. Anything else is left as tomli_w wrote it.
    """
    def one_line(match: re.Match[str]) -> str:
        items = [item.strip().rstrip(",") for item in match.group(1).splitlines()]
        return "[" + ", ".join(items) + "]"

    for _ in range(2):  # inner arrays first, then the arrays of them
        text = _MULTILINE_ARRAY.sub(one_line, text)
    return text


def _relative(file: str | Path, folder: Path) -> str:
    try:
        return Path(os.path.relpath(Path(file), folder)).as_posix()
    except ValueError:  # another drive on Windows
        return Path(file).as_posix()


def _given(obj: DataclassInstance) -> TomlTable:
    """The fields of a parameter dataclass that are not None."""
    return {f.name: getattr(obj, f.name) for f in fields(obj) if getattr(obj, f.name) is not None}


def scene_to_toml(scene: Scene, folder: Path) -> TomlTable:
    """The TOML tables of ``scene`` as a dict, files relative to ``folder``.

    ``[descriptor]`` and ``[correlation]`` hold what the scene's file gave and what the
    engine chose from the parts (``Scene.given``, ``Scene.chosen``; everything for a scene
    built in code), so a setting left to the engine stays the engine's; the simulation
    tables are written when they differ from their defaults.
    """
    data: TomlTable = {"name": scene.name}
    if scene.units_declared:
        data["units"] = scene.units
    if scene.assembled_known:
        data["assembled_pose"] = _floats(scene.assembled_pose)
    if scene.insertion_axis is not None:
        data["insertion_axis"] = _floats(scene.insertion_axis)
    if scene.seat.free_axes is not None:
        data["free_axes"] = list(scene.seat.free_axes)
    if scene.seat.distance is not None or scene.seat.angle_deg != SeatSpec().angle_deg:
        data["seat_tolerance"] = [scene.seat.distance if scene.seat.distance is not None
                                  else 0.0, scene.seat.angle_deg]
    chosen = {key for key, _, _ in scene.chosen}

    def written(table: str, key: str) -> bool:
        # what the scene's file gave or the engine chose; everything for a scene built in code
        name = f"{table}.{key}"
        return scene.given is None or name in scene.given or name in chosen

    descriptor = {k: v for k, v in _given(scene.descriptor).items() if written("descriptor", k)}
    if descriptor:
        data["descriptor"] = descriptor
    correlation = {k: v for k, v in _given(scene.correlation).items()
                   if k in CORRELATION_KEYS and written("correlation", k)}
    if "correlation.modes" in chosen:
        correlation["modes"] = AUTO  # the machine's budget bounds K: chosen again where it loads
    if correlation:
        data["correlation"] = correlation
    config = scene.config
    if config.simulation != SimulationParams():
        data["simulation"] = _given(config.simulation)
    if config.coupling != CouplingParams():
        data["coupling"] = _given(config.coupling)
    if config.effects != Effects():
        data["effects"] = _effects(config.effects, scene.units)
    if config.device != DeviceConfig():
        device = config.device
        table: TomlTable = {"kind": device.kind, "force_scale": device.force_scale}
        if device.max_force is not None:
            table["max_force"] = device.max_force
        for key, value in device.options:
            table[key] = _relative(str(value), folder) if key == "file" else value
        data["device"] = table
    parts = []
    for i, spec in enumerate(scene.parts):
        part: TomlTable = {"name": spec.name, "file": _relative(spec.file, folder),
                                "pose": _floats(spec.pose), "fixed": bool(spec.fixed)}
        if spec.body is not None:
            part["body"] = spec.body
        if spec.tolerance is not None:
            part["tolerance"] = spec.tolerance
        if spec.unit is not None:
            part["unit"] = spec.unit
        if spec.pivot is not None:
            part["pivot"] = _floats(spec.pivot)
        if spec.hold is not None:
            part["hold"] = _floats(spec.hold)
        mass = config.mass_spec(i)
        if mass != MassSpec():
            if mass.mass is not None:
                part["mass"] = mass.mass
            if mass.density is not None:
                part["density"] = mass.density
            if mass.inertia is not None:
                part["inertia"] = [list(r) for r in mass.inertia]
            if mass.center_of_mass is not None:
                part["center_of_mass"] = list(mass.center_of_mass)
        parts.append(part)
    data["part"] = parts
    return data


def _effects(effects: Effects, units: str) -> TomlTable:
    words = {v: k for k, v in AXES_WORDS.items()}
    table: TomlTable = {
        "guidance": effects.guidance,
        "axes": words.get(effects.axes, list(effects.axes)),
        "damping": effects.damping,
    }
    if effects.gravity is not None:
        g = np.asarray(effects.gravity, dtype=np.float64)
        direction = tuple(float(x) for x in g / max(float(np.linalg.norm(g)), 1e-300))
        standard = gravity_vector(units, direction)  # type: ignore[arg-type]
        if np.allclose(standard, g, rtol=1e-12, atol=0.0):
            table["gravity"] = True
            table["gravity_direction"] = list(direction)
        else:
            table["gravity"] = _floats(g)
    return table


def annotate_chosen(text: str, chosen: tuple[tuple[str, str, str], ...]) -> str:
    """``text`` with ``  # chosen: REASON`` beside each setting chosen from the parts.

    ``chosen`` holds ``(key, value, reason)`` with keys ``"table.key"`` or
    ``"part.INDEX.key"`` (``Scene.chosen``); a key the text does not hold is skipped.
    """
    reasons = {key: reason for key, _, reason in chosen}
    if not reasons:
        return text
    lines = text.split("\n")
    table, parts = "", -1
    for i, line in enumerate(lines):
        stripped = line.strip()
        if stripped == "[[part]]":
            parts += 1
            table = f"part.{parts}"
        elif stripped.startswith("[") and stripped.endswith("]"):
            table = stripped.strip("[]")
        elif "=" in stripped and not stripped.startswith("#"):
            name = stripped.split("=", 1)[0].strip()
            reason = reasons.get(f"{table}.{name}" if table else name)
            if reason is not None:
                lines[i] = f"{line}  # chosen: {reason}"
    return "\n".join(lines)


def save_scene(scene: Scene, path: str | os.PathLike) -> Path:
    """Write a scene as TOML (atomically) and return the path written.

    ``.toml`` is appended when missing. The text is read back with the scene reader
    before it replaces the destination, so ``load_scene(save_scene(s, p))`` gives back
    ``s``'s values, and a scene that would not load is never written.

    Raises
    ------
    SceneError
        The scene does not read back (a bug, or a part file that no longer exists).
    """
    import tomli_w

    out = Path(path)
    if out.suffix.lower() != ".toml":
        out = out.with_suffix(".toml")
    out = out.resolve()
    notes = tuple((key, value, f"{value} here; {reason}" if key == "correlation.modes"
                   else reason) for key, value, reason in scene.chosen)
    text = annotate_chosen(compact_arrays(tomli_w.dumps(scene_to_toml(scene, out.parent))),
                           notes)
    try:
        # first: the relative part paths are checked through it ("../" needs it to exist)
        out.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SceneError(f"{out}: cannot create its folder ({exc}); choose a folder you may "
                         "write to", path=str(out)) from exc
    parse_scene(text, out)  # raises SceneError naming the line of what does not read back
    try:
        write_text(out, text, what="scene")  # temporary file, fsync, rename: never half-written
    except OSError as exc:
        raise SceneError(f"{out}: cannot write the scene ({exc}); choose a folder you may "
                         "write to", path=str(out)) from exc
    return out

