"""Scene files: two parts, their poses, the assembled answer and the descriptor settings.

A scene is a TOML file (see docs/ARCHITECTURE.md)::

    name = "Peg in hole"
    units = "mm"
    assembled_pose = [0, 0, -15, 0, 0, 0]   # part 2 in part 1's frame when seated
    insertion_axis = [0, 0, -1]             # optional, part 1's frame

    [descriptor]          # optional: sigma, penalty, lambda_out, grid | spacing, padding
    [correlation]         # optional: modes
    [[part]]              # first: fixed.  name, file, pose, fixed, body, tolerance
    [[part]]              # second: moving (plus mass, density, inertia, center_of_mass)

The tables ``[simulation]``, ``[coupling]``, ``[effects]`` and ``[device]`` are kept raw in
``Scene.sections`` and validated by ``engine.simconfig``; the mass keys of a ``[[part]]``
are kept raw in ``PartSpec.extras``. Every other key is rejected. Errors are
:class:`SceneError` (a ``ValueError``) and read ``FILE:LINE: problem; fix``: tomllib gives
no line numbers, so the offending key is looked up in the text.

Poses are six numbers ``(tx, ty, tz, rx, ry, rz)`` (translation, then rotation vector in
radians), world poses of each part; ``relative_start_pose`` gives part 2 in part 1's frame.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, overload

import numpy as np

from engine.errors import InputError
from engine.params import (
    DEFAULT_GRID,
    DEFAULT_MODES,
    DEFAULT_PADDING,
    LENGTH_UNITS,
    DescriptorParams,
)

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

#: Length units a scene may declare, in metres (one table for the whole engine).
UNITS = LENGTH_UNITS

#: Top-level keys and tables of a scene file.
TOP_KEYS = ("name", "units", "assembled_pose", "insertion_axis", "descriptor", "correlation",
            "part")
#: Tables kept raw for the simulation settings (``engine.simconfig`` validates them).
SIM_SECTIONS = ("simulation", "coupling", "effects", "device")
#: Keys of ``[descriptor]``.
DESCRIPTOR_KEYS = ("sigma", "penalty", "lambda_out", "grid", "spacing", "padding")
#: Keys of ``[correlation]``.
CORRELATION_KEYS = ("modes",)
#: Keys of a ``[[part]]`` this module reads.
PART_KEYS = ("name", "file", "pose", "fixed", "body", "tolerance")
#: Keys of a ``[[part]]`` kept raw in ``PartSpec.extras`` for the simulation.
PART_EXTRA_KEYS = ("mass", "density", "inertia", "center_of_mass")


class SceneError(InputError):
    """A bad scene file: the message reads ``FILE:LINE: problem; fix``.

    Attributes
    ----------
    path : str
    line : int or None
    """

    def __init__(self, message: str, *, path: str = "", line: int | None = None):
        super().__init__(message)
        self.path = path
        self.line = line


def _readonly(values: Any, n: int) -> np.ndarray:
    a = np.array(values, dtype=np.float64).reshape(n)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class PartSpec:
    """One ``[[part]]`` table.

    Attributes
    ----------
    name : str
        Default: ``body`` if given, else the file's stem.
    file : Path
        Resolved (absolute) path of the part file.
    pose : (6,) float64
        World pose (read-only array).
    fixed : bool
        True for the first part, False for the second.
    body : str or None
        Which solid of a multi-body STEP file.
    tolerance : float or None
        STEP tessellation tolerance, in the file's unit (None: the loader's default).
    extras : dict
        Other keys (mass, density, inertia, center_of_mass), raw, for ``engine.simconfig``.
    """

    name: str
    file: Path
    pose: np.ndarray
    fixed: bool
    body: str | None = None
    tolerance: float | None = None
    extras: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", _readonly(self.pose, 6))
        object.__setattr__(self, "file", Path(self.file))


@dataclass(frozen=True, eq=False)
class Scene:
    """A parsed scene file.

    Attributes
    ----------
    path : Path
        The scene file (absolute).
    name : str
    units : str
        One of :data:`UNITS`.
    parts : tuple of PartSpec
        The fixed part first, then the moving part (one or two).
    assembled_pose : (6,) float64
        Part 2 relative to part 1 when assembled (read-only).
    insertion_axis : (3,) float64 or None
        Unit direction part 2 travels to seat, in part 1's frame.
    descriptor : DescriptorParams
    modes : int
        Retained modes per axis K (m' = K^3).
    sections : dict
        Raw ``[simulation]``, ``[coupling]``, ``[effects]``, ``[device]`` tables (present ones).
    """

    path: Path
    name: str
    units: str
    parts: tuple[PartSpec, ...]
    assembled_pose: np.ndarray
    insertion_axis: np.ndarray | None = None
    descriptor: DescriptorParams = field(default_factory=DescriptorParams)
    modes: int = DEFAULT_MODES
    sections: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        object.__setattr__(self, "parts", tuple(self.parts))
        object.__setattr__(self, "assembled_pose", _readonly(self.assembled_pose, 6))
        if self.insertion_axis is not None:
            object.__setattr__(self, "insertion_axis", _readonly(self.insertion_axis, 3))

    @property
    def fixed_part(self) -> PartSpec:
        return self.parts[0]

    @property
    def moving_part(self) -> PartSpec | None:
        return self.parts[1] if len(self.parts) > 1 else None


# --------------------------------------------------------------------------- line lookup
_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")
_KEY = re.compile(r"""^\s*(?:"([^"]+)"|'([^']+)'|([A-Za-z0-9_\-]+))\s*(?:\.|=)""")


def key_line(text: str, table: tuple[Any, ...], key: str | None = None) -> int | None:
    """1-based line of ``key`` in ``table`` of a TOML text, or of the table's header.

    ``table`` is ``()`` for the top level, ``("descriptor",)`` for a table and
    ``("part", 1)`` for the second ``[[part]]``. Returns None when not found.
    """
    current: tuple[Any, ...] = ()
    counts: dict[str, int] = {}
    header_line = None
    for lineno, line in enumerate(text.splitlines(), 1):
        m = _HEADER.match(line)
        if m:
            name = tuple(s.strip().strip('"') for s in m.group(2).split("."))
            if m.group(1) == "[[":
                counts[m.group(2)] = counts.get(m.group(2), -1) + 1
                current = (*name, counts[m.group(2)])
            else:
                current = name
            if current == table:
                header_line = lineno
                if key is None:
                    return lineno
            continue
        if key is not None and current == table:
            k = _KEY.match(line)
            if k and (k.group(1) or k.group(2) or k.group(3)) == key:
                return lineno
    return header_line


class _Checker:
    """Validates one table and raises SceneError naming the key's line."""

    def __init__(self, path: Path, text: str, table: tuple[Any, ...], values: dict[str, Any],
                 label: str):
        self.path, self.text, self.where, self.values, self.label = path, text, table, values, label

    def fail(self, key: str | None, problem: str) -> SceneError:
        line = key_line(self.text, self.where, key)
        where = f"{self.path}:{line}" if line else str(self.path)
        return SceneError(f"{where}: {problem}", path=str(self.path), line=line)

    def reject_unknown(self, allowed: tuple[str, ...]) -> None:
        for key in self.values:
            if key not in allowed:
                raise self.fail(
                    key,
                    f"unknown key {key!r} in {self.label}; valid keys: {', '.join(allowed)}",
                )

    @overload
    def number(self, key: str, default: float, *, positive: bool = ...,
               minimum: float | None = ...) -> float: ...

    @overload
    def number(self, key: str, default: None, *, positive: bool = ...,
               minimum: float | None = ...) -> float | None: ...

    def number(self, key: str, default: float | None, *, positive: bool = False,
               minimum: float | None = None) -> float | None:
        if key not in self.values:
            return default
        value = self.values[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value
        ):
            raise self.fail(key, f"{key} in {self.label} must be a number, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"{key} in {self.label} must be positive, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.fail(key, f"{key} in {self.label} must be at least {minimum:g}, "
                                 f"got {value!r}")
        return float(value)

    @overload
    def integer(self, key: str, default: int, *, minimum: int) -> int: ...

    @overload
    def integer(self, key: str, default: None, *, minimum: int) -> int | None: ...

    def integer(self, key: str, default: int | None, *, minimum: int) -> int | None:
        if key not in self.values:
            return default
        value = self.values[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self.fail(key, f"{key} in {self.label} must be an integer of at least "
                                 f"{minimum}, got {value!r}")
        return int(value)

    @overload
    def vector(self, key: str, n: int, default: np.ndarray) -> np.ndarray: ...

    @overload
    def vector(self, key: str, n: int, default: None = ...) -> np.ndarray | None: ...

    def vector(self, key: str, n: int, default: np.ndarray | None = None) -> np.ndarray | None:
        if key not in self.values:
            return default
        value = self.values[key]
        ok = isinstance(value, list) and len(value) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in value
        )
        if not ok:
            what = "six numbers (tx, ty, tz, rx, ry, rz; rotation vector in radians)" if n == 6 \
                else f"{n} numbers"
            raise self.fail(key, f"{key} in {self.label} must be {what}, got {value!r}")
        return np.array(value, dtype=np.float64)

    @overload
    def string(self, key: str, default: str) -> str: ...

    @overload
    def string(self, key: str, default: None) -> str | None: ...

    def string(self, key: str, default: str | None) -> str | None:
        if key not in self.values:
            return default
        value = self.values[key]
        if not isinstance(value, str) or not value.strip():
            raise self.fail(key, f"{key} in {self.label} must be a non-empty string, "
                                 f"got {value!r}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        if key not in self.values:
            return default
        value = self.values[key]
        if not isinstance(value, bool):
            raise self.fail(key, f"{key} in {self.label} must be true or false, got {value!r}")
        return value

    def table(self, key: str) -> dict[str, Any]:
        value = self.values.get(key, {})
        if not isinstance(value, dict):
            raise self.fail(key, f"{key} must be a table ([{key}]), got {value!r}")
        return value


# --------------------------------------------------------------------------- load / save
def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file.

    Raises
    ------
    SceneError
        Unreadable file, bad TOML, unknown key, bad value, missing part file; the message
        names the file and line.
    """
    p = Path(path).resolve()
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file", path=str(path)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: cannot read the scene file ({exc})", path=str(path)) from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"at line (\d+)", str(exc))
        line = int(m.group(1)) if m else None
        if line is None and "end of document" in str(exc):
            line = max(1, len(text.splitlines()))
        where = f"{p}:{line}" if line else str(p)
        raise SceneError(f"{where}: not valid TOML ({exc}); check the syntax there",
                         path=str(p), line=line) from exc
    return _parse(p, text, data)


def _parse(p: Path, text: str, data: dict[str, Any]) -> Scene:
    top = _Checker(p, text, (), data, "the scene")
    top.reject_unknown(TOP_KEYS + SIM_SECTIONS)
    name = top.string("name", p.parent.name if p.name == "scene.toml" else p.stem)
    units = top.string("units", "mm")
    if units not in UNITS:
        raise top.fail("units", f"units must be one of {', '.join(UNITS)}, got {units!r}")
    if "assembled_pose" not in data:
        raise top.fail(None, "assembled_pose is missing; add `assembled_pose = [tx, ty, tz, rx, "
                             "ry, rz]` (part 2 in part 1's frame when assembled)")
    assembled = top.vector("assembled_pose", 6, np.zeros(6))  # present: checked above
    axis = top.vector("insertion_axis", 3)
    if axis is not None:
        norm = float(np.linalg.norm(axis))
        if norm == 0:
            raise top.fail("insertion_axis", "insertion_axis must not be zero")
        axis = axis / norm

    d = _Checker(p, text, ("descriptor",), top.table("descriptor"), "[descriptor]")
    d.reject_unknown(DESCRIPTOR_KEYS)
    if "grid" in d.values and "spacing" in d.values:
        raise d.fail("spacing", "give grid or spacing in [descriptor], not both")
    spacing = d.number("spacing", None, positive=True)
    grid = d.integer("grid", None if spacing is not None else DEFAULT_GRID, minimum=4)
    descriptor = DescriptorParams(
        sigma=d.number("sigma", 0.5, positive=True),
        penalty=d.number("penalty", 3.0, positive=True),
        lambda_out=d.number("lambda_out", 1.0, positive=True),
        grid=grid,
        spacing=spacing,
        padding=d.number("padding", DEFAULT_PADDING, minimum=0.0),
    )

    c = _Checker(p, text, ("correlation",), top.table("correlation"), "[correlation]")
    c.reject_unknown(CORRELATION_KEYS)
    modes = c.integer("modes", DEFAULT_MODES, minimum=1)

    raw_parts = data.get("part")
    if raw_parts is None:
        raise top.fail(None, "no [[part]] tables; add one [[part]] for the fixed part and one "
                             "for the moving part, each with file and pose")
    if not isinstance(raw_parts, list) or not all(isinstance(t, dict) for t in raw_parts):
        raise top.fail("part", "part must be written as [[part]] tables")
    if len(raw_parts) > 2:
        raise _Checker(p, text, ("part", 2), raw_parts[2], "[[part]] #3").fail(
            None, f"{len(raw_parts)} [[part]] tables; a scene has two parts (fixed, then moving)"
        )
    parts: list[PartSpec] = []
    for i, table in enumerate(raw_parts):
        label = f"[[part]] #{i + 1}"
        pc = _Checker(p, text, ("part", i), table, label)
        pc.reject_unknown(PART_KEYS + PART_EXTRA_KEYS)
        file = pc.string("file", None)
        if file is None:
            raise pc.fail(None, f"{label} has no file; add `file = \"part.step\"` (relative to "
                                "the scene file)")
        resolved = Path(file) if Path(file).is_absolute() else (p.parent / file)
        if not resolved.is_file():
            raise pc.fail("file", f"part file {file!r} not found (looked for {resolved})")
        body = pc.string("body", None)
        pname = pc.string("name", body if body is not None else Path(file).stem)
        if any(q.name == pname for q in parts):
            raise pc.fail("name", f"two parts named {pname!r}; give them different names")
        fixed = pc.boolean("fixed", i == 0)
        if fixed != (i == 0):
            raise pc.fail("fixed", "the first [[part]] is the fixed one and the second moves; "
                                   "swap the tables instead of setting fixed")
        tolerance = pc.number("tolerance", None, positive=True)
        pose = pc.vector("pose", 6, np.zeros(6))
        extras = {k: v for k, v in table.items() if k in PART_EXTRA_KEYS}
        parts.append(PartSpec(name=pname, file=resolved.resolve(), pose=pose, fixed=fixed,
                              body=body, tolerance=tolerance, extras=extras))

    sections = {}
    for key in SIM_SECTIONS:
        if key in data:
            sections[key] = top.table(key)
    return Scene(path=p, name=name, units=units, parts=tuple(parts), assembled_pose=assembled,
                 insertion_axis=axis, descriptor=descriptor, modes=modes, sections=sections)


def save_scene(scene: Scene, path: str | os.PathLike) -> Path:
    """Write a scene as TOML; part files are written relative to the new file where possible.

    Returns the path written. ``load_scene(save_scene(s, p))`` gives back ``s``'s values.
    """
    import tomli_w

    out = Path(path).resolve()
    data: dict[str, Any] = {"name": scene.name, "units": scene.units,
                            "assembled_pose": _floats(scene.assembled_pose)}
    if scene.insertion_axis is not None:
        data["insertion_axis"] = _floats(scene.insertion_axis)
    d = scene.descriptor
    desc: dict[str, Any] = {"sigma": d.sigma, "penalty": d.penalty, "lambda_out": d.lambda_out}
    if d.spacing is not None:
        desc["spacing"] = d.spacing
    else:
        desc["grid"] = int(d.grid if d.grid is not None else DEFAULT_GRID)
    desc["padding"] = d.padding
    data["descriptor"] = desc
    data["correlation"] = {"modes": int(scene.modes)}
    for key in SIM_SECTIONS:
        if key in scene.sections:
            data[key] = scene.sections[key]
    parts = []
    for spec in scene.parts:
        try:
            file = os.path.relpath(spec.file, out.parent)
        except ValueError:  # another drive on Windows
            file = str(spec.file)
        table: dict[str, Any] = {"name": spec.name, "file": Path(file).as_posix(),
                                 "pose": _floats(spec.pose), "fixed": bool(spec.fixed)}
        if spec.body is not None:
            table["body"] = spec.body
        if spec.tolerance is not None:
            table["tolerance"] = spec.tolerance
        table.update(spec.extras)
        parts.append(table)
    data["part"] = parts
    out.write_text(tomli_w.dumps(data), encoding="utf-8")
    return out


def _floats(a: np.ndarray) -> list[float]:
    return [float(x) for x in np.asarray(a).ravel()]


# --------------------------------------------------------------------------- helpers
def relative_start_pose(scene: Scene) -> np.ndarray:
    """(6,) pose of part 2 in part 1's frame at the start, from the parts' world poses."""
    from engine.pose import relative_pose

    if len(scene.parts) < 2:
        raise SceneError(f"{scene.path}: the scene has no moving part (a second [[part]])",
                         path=str(scene.path))
    return relative_pose(scene.parts[0].pose, scene.parts[1].pose)


def load_scene_parts(scene: Scene) -> list:
    """Load every part of a scene (``engine.loading.Part``), in the scene's unit.

    A STEP file in another unit than the scene's is scaled to it (a warning says so);
    mesh files, which carry no unit, are taken to be in the scene's unit.
    """
    from dataclasses import replace

    from engine.loading import load_part

    parts = []
    for spec in scene.parts:
        part = load_part(spec.file, tolerance=spec.tolerance, body=spec.body)
        part = replace(part, name=spec.name)
        if part.unit in UNITS and part.unit != scene.units:
            factor = UNITS[part.unit] / UNITS[scene.units]
            note = (f"{spec.file}: converted from {part.unit} to the scene's {scene.units} "
                    f"(x{factor:g})")
            part = replace(part, vertices=part.vertices * factor, unit=scene.units,
                           warnings=(*part.warnings, note))
        parts.append(part)
    return parts
