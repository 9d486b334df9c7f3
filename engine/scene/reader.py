"""Reading a scene file: TOML text to a validated :class:`~engine.scene.model.Scene`.

The file is read once; every table is checked by one reader (:class:`_Table`) with one
error format, ``FILE:LINE: problem; fix`` (:class:`~engine.scene.model.SceneError`).
tomllib gives no line numbers, so the offending key is looked up in the text
(:func:`key_line`). Every key the format knows is listed in the ``*_KEYS`` tuples below;
any other key is an error naming the valid ones.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable
from pathlib import Path
from typing import Literal, TypeAlias, TypeVar, overload

import numpy as np

from engine.errors import InputError
from engine.files import MAX_SCENE_BYTES, decode_text, input_problem, read_input
from engine.params import (
    AXES,
    DEFAULT_GRID,
    DEFAULT_UNIT,
    DEVICE_OPTIONS,
    DEVICES,
    GUIDANCE,
    LENGTH_UNITS,
    MAX_GRAVITY_G,
    MAX_MODES,
    MAX_POSE_TRANSLATION,
    MAX_ROTATION_VECTOR,
    SIGMA_GRID_MAX,
    SIGMA_RANGE,
    STANDARD_GRAVITY,
    CorrelationParams,
    CouplingParams,
    DescriptorParams,
    DeviceConfig,
    Effects,
    MassSpec,
    SeatSpec,
    SimConfig,
    SimulationParams,
    gravity_vector,
)
from engine.scene.model import PartSpec, Scene, SceneError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

D = TypeVar("D")  # a default, returned as given when the key is absent
T = TypeVar("T")

#: Top-level keys of a scene file.
TOP_KEYS = ("name", "units", "assembled_pose", "insertion_axis", "free_axes",
            "seat_tolerance")
#: Tables of a scene file (``part`` is the array of ``[[part]]`` tables).
TABLES = ("descriptor", "correlation", "simulation", "coupling", "effects", "device", "part")
#: Keys of ``[descriptor]``.
DESCRIPTOR_KEYS = ("sigma", "penalty", "lambda_out", "grid", "spacing", "padding")
#: Keys of ``[correlation]``. ``CorrelationParams`` also holds oversample, refine,
#: fine_modes and selection; a scene may set them once the engine builds its correlator
#: from ``Scene.correlation`` (until then a key that changed nothing would mislead).
CORRELATION_KEYS = ("modes",)

#: A setting's value that leaves it to the engine, chosen from the parts and the machine at
#: hand each time the scene loads (``modes = "auto"``: K follows the machine's budget, so a
#: scene made beside a CPU gets a GPU's K on a GPU).
AUTO = "auto"
#: Keys of ``[simulation]``.
SIMULATION_KEYS = ("rate_hz", "kappa", "guidance_gain", "body_damping_ratio", "seconds")
#: Keys of ``[coupling]``.
COUPLING_KEYS = ("frequency_hz", "damping_ratio", "stiffness", "angular_stiffness", "damping",
                 "angular_damping")
#: Keys of ``[effects]``.
EFFECTS_KEYS = ("guidance", "axes", "damping", "gravity", "gravity_direction")
#: Keys of ``[device]`` for every kind (plus ``DEVICE_OPTIONS[kind]``).
DEVICE_KEYS = ("kind", "max_force", "force_scale")
#: Keys of a ``[[part]]``.
PART_KEYS = ("name", "file", "pose", "fixed", "body", "tolerance", "unit", "pivot", "hold",
             "mass", "density", "inertia", "center_of_mass")
#: Words ``[effects] axes`` accepts besides a list of axes.
AXES_WORDS = {"all": AXES, "translation": AXES[:3], "rotation": AXES[3:]}

_HEADER = re.compile(r"^\s*(\[\[?)\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")

#: Where a table sits in a TOML file: ``()`` the top level, ``("descriptor",)`` a table,
#: ``("part", 1)`` the second ``[[part]]`` (names, and indices into arrays of tables).
TablePath: TypeAlias = tuple[str | int, ...]
_KEY = re.compile(r"""^\s*(?:"([^"]+)"|'([^']+)'|([A-Za-z0-9_\-]+))\s*(?:\.|=)""")


def key_line(text: str, table: TablePath, key: str | None = None) -> int | None:
    """1-based line of ``key`` in ``table`` of a TOML text, or of the table's header.

    ``table`` is ``()`` for the top level, ``("descriptor",)`` for a table and
    ``("part", 1)`` for the second ``[[part]]``. Returns None when not found.
    """
    current: TablePath = ()
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


def _toml(value: object) -> str:
    """A default as the scene file would write it."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return f"{value:g}" if isinstance(value, float) else str(value)


class _Table:
    """Reads one table of a scene; each bad key raises a SceneError naming its line."""

    def __init__(self, path: Path, text: str, where: TablePath, values: object, label: str):
        self.path, self.text, self.where, self.label = path, text, where, label
        if not isinstance(values, dict):
            raise self.fail(None, f"{label} must be a table of key = value lines, got "
                                  f"{values!r}", f"write it as {label} followed by its keys")
        self.values: dict[str, object] = values

    def fail(self, key: str | None, problem: str, fix: str) -> SceneError:
        """The error for ``key`` (None: the table itself): ``FILE:LINE: problem; fix``."""
        line = key_line(self.text, self.where, key)
        where = f"{self.path}:{line}" if line else str(self.path)
        return SceneError(f"{where}: {problem}; {fix}", path=str(self.path), line=line)

    def reject_unknown(self, allowed: tuple[str, ...]) -> None:
        """Fail on the first key not in ``allowed``."""
        for key in self.values:
            if key not in allowed:
                raise self.fail(key, f"unknown key {key!r} in {self.label}",
                                f"valid keys: {', '.join(allowed)}")

    def _bad(self, key: str, what: str, default: object) -> SceneError:
        value = self.values[key]
        fix = (f"remove the line for the default ({_toml(default)})"
               if default is not None else "correct the value")
        return self.fail(key, f"{key} in {self.label} must be {what}, got {value!r}", fix)

    @overload
    def number(self, key: str, default: D, *, positive: bool = False,
               minimum: float | None = None, auto: Literal[False] = False) -> float | D: ...

    @overload
    def number(self, key: str, default: None, *, positive: bool = False,
               minimum: float | None = None, auto: Literal[True]) -> float | None: ...

    def number(self, key: str, default: D | None, *, positive: bool = False,
               minimum: float | None = None, auto: bool = False) -> float | D | None:
        """A finite number; ``auto``: the word "auto" reads as None (a derived default)."""
        if key not in self.values:
            return default
        value = self.values[key]
        if auto and value == "auto":
            return None
        what = ("a positive number" if positive else
                f"a number of at least {minimum:g}" if minimum is not None else "a number")
        if auto:
            what += ' or "auto"'
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value
        ):
            raise self._bad(key, what, default)
        if (positive and value <= 0) or (minimum is not None and value < minimum):
            raise self._bad(key, what, default)
        return float(value)

    def integer(self, key: str, default: D, *, minimum: int) -> int | D:
        """An integer of at least ``minimum``."""
        if key not in self.values:
            return default
        value = self.values[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise self._bad(key, f"an integer of at least {minimum}", default)
        return int(value)

    @overload
    def vector(self, key: str, n: int) -> np.ndarray | None: ...

    @overload
    def vector(self, key: str, n: int, default: D) -> np.ndarray | D: ...

    def vector(self, key: str, n: int, default: D | None = None) -> np.ndarray | D | None:
        """``n`` finite numbers as a (n,) float64 array."""
        if key not in self.values:
            return default
        value = self.values[key]
        ok = isinstance(value, list) and len(value) == n and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            for x in value
        )
        if not ok:
            what = ("six numbers (tx, ty, tz, rx, ry, rz; rotation vector in radians)" if n == 6
                    else f"{n} numbers")
            raise self._bad(key, what, None)
        out = np.array(value, dtype=np.float64)
        if n == 6:  # a pose: numbers a rotation and a distance can be computed from
            if math.hypot(*out[3:]) > MAX_ROTATION_VECTOR:
                raise self.fail(key, f"{self.label}: {key} has a rotation vector of "
                                f"{math.hypot(*out[3:]):.3g} rad, above "
                                f"{MAX_ROTATION_VECTOR:g} (beyond it the angle has lost "
                                "its precision)", "rotations are rotation vectors in radians: "
                                "reduce it modulo 2 pi")
            if math.hypot(*out[:3]) > MAX_POSE_TRANSLATION:
                raise self.fail(key, f"{self.label}: {key} puts the part "
                                f"{math.hypot(*out[:3]):.3g} from the origin, beyond "
                                f"{MAX_POSE_TRANSLATION:g} in any unit", "check the numbers "
                                "and the scene's units")
        return out

    def string(self, key: str, default: D) -> str | D:
        """A non-empty string."""
        if key not in self.values:
            return default
        value = self.values[key]
        if not isinstance(value, str) or not value.strip():
            raise self._bad(key, "a non-empty string", None)
        return value

    def choice(self, key: str, default: str, valid: tuple[str, ...], *,
               fix: str | None = None) -> str:
        """One of ``valid``."""
        if key not in self.values:
            return default
        value = self.values[key]
        if value not in valid:
            raise self.fail(key, f"{key} in {self.label} must be one of {', '.join(valid)}, "
                                 f"got {value!r}",
                            fix or f"remove the line for the default ({_toml(default)})")
        return str(value)

    def boolean(self, key: str, default: bool) -> bool:
        """A boolean, true or false."""
        if key not in self.values:
            return default
        value = self.values[key]
        if not isinstance(value, bool):
            raise self._bad(key, "true or false", default)
        return value

    def table(self, key: str, label: str) -> _Table:
        """The sub-table ``key`` (empty when absent)."""
        return _Table(self.path, self.text, (*self.where, key), self.values.get(key, {}), label)

    def build(self, cls: Callable[..., T], *, key: str | None = None, **values: object) -> T:
        """``cls(**values)``, its InputError turned into a SceneError at ``key``'s line."""
        try:
            return cls(**values)
        except InputError as exc:
            # the line of the key the message names first, if the table sets it (UDP
            # `port`, `padding` of a [descriptor], `mass` of a [[part]]), else ``key``'s
            named = [(m.start(), k) for k in self.values if isinstance(k, str)
                     for m in [re.search(rf"(?<![\w-]){re.escape(k)}(?![\w-])", str(exc))]
                     if m is not None]
            if named:
                key = min(named)[1]
            raise self.fail(key, f"{self.label}: {exc}", "correct the value") from None


# --------------------------------------------------------------------------- load
def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file (read once; every table checked).

    Raises
    ------
    SceneError
        Unreadable file, bad TOML, unknown key, bad value, missing part file; the message
        names the file and line, the problem and the fix.
    """
    try:
        # bounded and only from a regular file: /dev/zero or a FIFO never ends; utf-8-sig:
        # a byte-order mark (Windows editors write one) is not TOML
        data = read_input(path, what="scene file", limit=MAX_SCENE_BYTES)
        text = decode_text(data, path, what="scene file")
    except InputError as exc:
        m = re.match(r".*?:(\d+): ", str(exc))
        raise SceneError(str(exc), path=str(path), line=int(m.group(1)) if m else None
                         ) from None
    return parse_scene(text, Path(path).resolve())


def parse_scene(text: str, path: Path) -> Scene:
    """Validate a scene's TOML ``text``; relative part files are relative to ``path``'s folder.

    Raises
    ------
    SceneError
        As :func:`load_scene`.
    """
    p = Path(path).resolve()
    try:
        data = tomllib.loads(text)
    except RecursionError:
        # tomllib parses nested arrays recursively: thousands of levels exhaust the stack
        raise SceneError(f"{p}: nested too deeply to read (arrays or tables within each "
                         "other thousands of levels deep); a scene nests at most a 3x3 "
                         "list: check the file", path=str(p)) from None
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"at line (\d+)", str(exc))
        line = int(m.group(1)) if m else None
        if line is None and "end of document" in str(exc):
            line = max(1, len(text.splitlines()))
        where = f"{p}:{line}" if line else str(p)
        raise SceneError(f"{where}: not valid TOML ({exc}); check the syntax there",
                         path=str(p), line=line) from exc

    top = _Table(p, text, (), data, "the scene")
    top.reject_unknown(TOP_KEYS + TABLES)
    name = top.string("name", p.parent.name if p.name == "scene.toml" else p.stem)
    units_declared = "units" in data
    units = top.choice("units", DEFAULT_UNIT, tuple(LENGTH_UNITS),
                       fix="write the unit the scene's poses and lengths are in")
    # optional: `skelasm search` finds the fits of a scene without one; what needs it asks
    # for it (engine.scene.require_assembled)
    assembled_known = "assembled_pose" in data
    assembled = top.vector("assembled_pose", 6, np.zeros(6))
    axis = top.vector("insertion_axis", 3)
    if axis is not None:
        norm = float(np.linalg.norm(axis))
        if norm == 0:
            raise top.fail("insertion_axis", "insertion_axis must not be zero",
                           "give the direction part 2 travels to seat, e.g. [0, 0, -1]")
        axis = axis / norm

    seat = _seat(top)
    descriptor = _descriptor(top.table("descriptor", "[descriptor]"))
    correlation = _correlation(top.table("correlation", "[correlation]"))
    parts, masses = _parts(top, data, p)
    config = SimConfig(
        simulation=(sim := _simulation(top.table("simulation", "[simulation]"))),
        coupling=_coupling(top.table("coupling", "[coupling]"), sim),
        effects=_effects(top.table("effects", "[effects]"), units),
        device=_device(top.table("device", "[device]"), p),
        masses=masses,
        units=units,
    )
    given = frozenset(f"{table}.{key}" for table in ("descriptor", "correlation", "simulation",
                                                      "coupling")
                      if isinstance(data.get(table), dict) for key in data[table]
                      if data[table][key] != AUTO)
    return Scene(path=p, name=name, units=units, units_declared=units_declared,
                 parts=tuple(parts), assembled_pose=assembled, assembled_known=assembled_known,
                 insertion_axis=axis, seat=seat,
                 descriptor=descriptor, correlation=correlation, config=config, given=given)


def _seat(top: _Table) -> SeatSpec:
    free = top.values.get("free_axes")
    if free is not None and not (isinstance(free, list) and all(isinstance(a, str) for a in free)):
        raise top.fail("free_axes", "free_axes must be a list of axis names",
                       f"write e.g. `free_axes = [\"z\", \"rz\"]` (valid: {', '.join(AXES)}; "
                       "`[]` when the fit locks every axis)")
    tolerance = top.vector("seat_tolerance", 2)
    try:
        return SeatSpec(free_axes=None if free is None else tuple(free),
                        # a distance of 0 asks for the default (a fraction of part 2's size)
                        distance=None if tolerance is None or tolerance[0] == 0
                        else float(tolerance[0]),
                        **({} if tolerance is None else {"angle_deg": float(tolerance[1])}))
    except InputError as exc:
        key = "free_axes" if str(exc).startswith("free_axes") else "seat_tolerance"
        raise top.fail(key, str(exc), "seat_tolerance is [distance in the scene's unit, "
                       "angle in degrees]; free_axes names axes of part 1's frame") from exc


def _descriptor(d: _Table) -> DescriptorParams:
    d.reject_unknown(DESCRIPTOR_KEYS)
    if "grid" in d.values and "spacing" in d.values:
        raise d.fail("spacing", "both grid and spacing in [descriptor]",
                     "give grid or spacing, not both")
    base = DescriptorParams()
    spacing = d.number("spacing", None, positive=True)
    sigma = d.number("sigma", base.sigma, positive=True)
    if sigma > SIGMA_GRID_MAX:
        raise d.fail("sigma", f"sigma = {sigma:g} in [descriptor] is above {SIGMA_GRID_MAX:g}: "
                              "each sample near the surface then costs 50 ms or more, hours "
                              "for a grid, while the density only scales as 1/sigma",
                     f"use sigma from {SIGMA_RANGE[0]:g} to {SIGMA_GRID_MAX:g} "
                     f"(default {base.sigma:g})")
    return d.build(
        DescriptorParams,
        sigma=sigma,
        penalty=d.number("penalty", base.penalty, positive=True),
        lambda_out=d.number("lambda_out", base.lambda_out, positive=True),
        grid=d.integer("grid", None if spacing is not None else DEFAULT_GRID, minimum=4),
        spacing=spacing,
        padding=d.number("padding", base.padding, minimum=0.0),
    )


def _correlation(c: _Table) -> CorrelationParams:
    c.reject_unknown(CORRELATION_KEYS)
    base = CorrelationParams()
    value = c.values.get("modes")
    if value is None or value == AUTO:  # absent, or left to the engine (engine.sim.auto)
        return c.build(CorrelationParams, modes=base.modes)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_MODES:
        raise c._bad("modes", f'an integer from 1 to {MAX_MODES} (each pose sums K^3 terms), '
                     'or "auto" (chosen from the parts and the machine)', base.modes)
    return c.build(CorrelationParams, modes=value)


def _simulation(s: _Table) -> SimulationParams:
    s.reject_unknown(SIMULATION_KEYS)
    base = SimulationParams()
    return s.build(
        SimulationParams,
        rate_hz=s.number("rate_hz", base.rate_hz, positive=True),
        kappa=s.number("kappa", None, minimum=0.0, auto=True),
        guidance_gain=s.number("guidance_gain", base.guidance_gain, minimum=0.0),
        body_damping_ratio=s.number("body_damping_ratio", base.body_damping_ratio, minimum=0.0),
        seconds=s.number("seconds", base.seconds, positive=True),
    )


def _coupling(c: _Table, sim: SimulationParams) -> CouplingParams:
    c.reject_unknown(COUPLING_KEYS)
    base = CouplingParams()
    coupling = c.build(
        CouplingParams,
        frequency_hz=c.number("frequency_hz", base.frequency_hz, positive=True),
        damping_ratio=c.number("damping_ratio", base.damping_ratio, minimum=0.0),
        stiffness=c.number("stiffness", None, positive=True, auto=True),
        angular_stiffness=c.number("angular_stiffness", None, positive=True, auto=True),
        damping=c.number("damping", None, minimum=0.0, auto=True),
        angular_damping=c.number("angular_damping", None, minimum=0.0, auto=True),
    )
    if coupling.frequency_hz * 2 * math.pi / sim.rate_hz > 1.0:
        raise c.fail("frequency_hz", f"frequency_hz = {coupling.frequency_hz:g} Hz in [coupling] "
                                     f"is too stiff for the {sim.rate_hz:g} Hz rate (the step "
                                     "needs 2 pi f dt <= 1)",
                     "lower it or raise [simulation] rate_hz")
    return coupling


def _effects(e: _Table, units: str) -> Effects:
    e.reject_unknown(EFFECTS_KEYS)
    guidance = e.choice("guidance", "skeletal", GUIDANCE)
    raw_axes = e.values.get("axes", "all")
    if isinstance(raw_axes, str) and raw_axes in AXES_WORDS:
        axes = AXES_WORDS[raw_axes]
    elif isinstance(raw_axes, list) and all(a in AXES for a in raw_axes):
        axes = tuple(raw_axes)
    else:
        raise e.fail("axes", f"axes in [effects] must be \"all\", \"translation\", \"rotation\" "
                             f"or a list of {', '.join(AXES)}, got {raw_axes!r}",
                     'remove the line for the default ("all")')
    damping = e.boolean("damping", True)
    direction = e.vector("gravity_direction", 3, np.array([0.0, 0.0, -1.0]))
    if float(np.linalg.norm(direction)) == 0:
        raise e.fail("gravity_direction", "gravity_direction in [effects] must not be zero",
                     "give the direction of the pull, e.g. [0, 0, -1]")
    raw_gravity = e.values.get("gravity", False)
    gravity: tuple[float, float, float] | None
    if raw_gravity is False:
        gravity = None
    elif raw_gravity is True:
        gravity = gravity_vector(units, tuple(direction))
    else:
        g = e.vector("gravity", 3, np.zeros(3))  # present: a list here
        gravity = (float(g[0]), float(g[1]), float(g[2]))
        top = MAX_GRAVITY_G * STANDARD_GRAVITY / LENGTH_UNITS[units]
        size = math.hypot(*gravity)
        if size > top:
            raise e.fail("gravity", f"gravity in [effects] has magnitude {size:.3g} "
                                    f"{units}/s^2, above "
                                    f"{MAX_GRAVITY_G:g} standard gravities ({top:g} {units}/s^2): "
                                    "the pull would dwarf every other force",
                         "write `gravity = true` for standard gravity, or a vector in the "
                         f"scene's unit per second squared ({units}/s^2)")
    return e.build(Effects, guidance=guidance, axes=axes, damping=damping, gravity=gravity)


def _device(d: _Table, scene_path: Path) -> DeviceConfig:
    kind = d.choice("kind", "mouse", DEVICES)
    d.reject_unknown(DEVICE_KEYS + DEVICE_OPTIONS[kind])
    options = [(k, d.values[k]) for k in DEVICE_OPTIONS[kind] if k in d.values]
    if kind == "trajectory":
        file = d.string("file", None)
        if file is None:
            raise d.fail("kind", "a trajectory device needs a file",
                         'add file = "path/to.csv" (relative to the scene file) to [device]')
        resolved = Path(file) if Path(file).is_absolute() else scene_path.parent / file
        options = [(k, str(_absolute(resolved)) if k == "file" else v) for k, v in options]
    return d.build(
        DeviceConfig,
        kind=kind,
        max_force=d.number("max_force", None, positive=True, auto=True),
        force_scale=d.number("force_scale", 1.0, positive=True),
        options=tuple(options),
    )


def _absolute(path: Path) -> Path:
    """``path`` with its links resolved, or made absolute where they loop (refused later)."""
    try:
        return path.resolve()
    except (OSError, RuntimeError):  # Python 3.11 raises RuntimeError for a loop of links
        return path.absolute()


def _parts(top: _Table, data: dict[str, object], p: Path
           ) -> tuple[list[PartSpec], tuple[MassSpec, ...]]:
    raw_parts = data.get("part")
    if raw_parts is None:
        raise top.fail(None, "no [[part]] tables",
                       "add one [[part]] for the fixed part and one for the moving part, each "
                       "with file and pose")
    if not isinstance(raw_parts, list) or not all(isinstance(t, dict) for t in raw_parts):
        raise top.fail("part", "part is not written as [[part]] tables",
                       "write each part as a [[part]] table")
    if len(raw_parts) > 2:
        raise _Table(p, top.text, ("part", 2), raw_parts[2], "[[part]] #3").fail(
            None, f"{len(raw_parts)} [[part]] tables",
            "a scene has two parts (fixed, then moving): remove the others")
    parts: list[PartSpec] = []
    masses: list[MassSpec] = []
    for i, table in enumerate(raw_parts):
        label = f"[[part]] #{i + 1}"
        pc = _Table(p, top.text, ("part", i), table, label)
        pc.reject_unknown(PART_KEYS)
        file = pc.string("file", None)
        if file is None:
            raise pc.fail(None, f"{label} has no file",
                          'add `file = "part.step"` (relative to the scene file)')
        resolved = Path(file) if Path(file).is_absolute() else (p.parent / file)
        problem = input_problem(resolved, what="part file")
        if problem is not None and not os.path.lexists(resolved):
            raise pc.fail("file", f"part file {file!r} not found (looked for {resolved})",
                          "check the name; relative paths are relative to the scene file")
        if problem is not None:  # a folder, FIFO, device, link loop: said as what it is
            why, _, fix = problem.removeprefix(f"{resolved}: ").partition("; ")
            raise pc.fail("file", f"part file {file!r} ({resolved}): {why}", fix)
        body = pc.string("body", None)
        pname = pc.string("name", body if body is not None else Path(file).stem)
        if any(q.name == pname for q in parts):
            raise pc.fail("name", f"two parts named {pname!r}", "give them different names")
        fixed = pc.boolean("fixed", i == 0)
        if fixed != (i == 0):
            raise pc.fail("fixed", "the first [[part]] is the fixed one and the second moves",
                          "swap the tables instead of setting fixed")
        parts.append(PartSpec(
            name=pname, file=resolved.resolve(), pose=pc.vector("pose", 6, np.zeros(6)),
            fixed=fixed, body=body, tolerance=pc.number("tolerance", None, positive=True),
            unit=(pc.choice("unit", DEFAULT_UNIT, tuple(LENGTH_UNITS),
                            fix="write the unit the part's file is drawn in")
                  if "unit" in table else None),
            pivot=pc.vector("pivot", 3),
            hold=pc.vector("hold", 3),
        ))
        if i == 0 and parts[-1].hold is not None:
            raise pc.fail("hold", "the fixed part is not held: `hold` names where the "
                          "coupling holds the moving part", "move `hold` to the second [[part]]")
        inertia = pc.values.get("inertia")
        if inertia is not None and not isinstance(inertia, list):
            raise pc._bad("inertia", "3 principal moments or a 3x3 list", None)
        com = pc.vector("center_of_mass", 3)
        masses.append(pc.build(
            MassSpec, key="inertia",
            mass=pc.number("mass", None, positive=True),
            density=pc.number("density", None, positive=True),
            inertia=inertia,
            center_of_mass=None if com is None else tuple(float(x) for x in com),
        ))
    return parts, tuple(masses)


#: Range errors raised after reading (they need the parts' meshes: the inertia against the
#: mesh's own, kappa against its scale-free default, a pose against the part's size, the
#: spacing against its longest side): the start of the message -> the key it is about.
_LATE_ERRORS: tuple[tuple[re.Pattern[str], TablePath, str], ...] = (
    (re.compile(r"^kappa\b"), ("simulation",), "kappa"),
    (re.compile(r"^(spacing|grid)\b"), ("descriptor",), "spacing"),
    (re.compile(r"^grid\b"), ("descriptor",), "grid"),
    (re.compile(r"^padding\b"), ("descriptor",), "padding"),
    (re.compile(r"^part inertia\b"), ("part", -1), "inertia"),
    (re.compile(r"^(part )?mass\b"), ("part", -1), "mass"),
    (re.compile(r"^proxy pose\b"), ("part", -1), "pose"),
    (re.compile(r"^gravity\b"), ("effects",), "gravity"),
)


def locate_late_error(path: str | os.PathLike, message: str) -> SceneError | None:
    """A :class:`SceneError` at ``FILE:LINE`` for a range error found after reading, or None.

    ``message`` is an ``InputError``'s text that names a scene key first (``kappa = ...``,
    ``part inertia ...``, ``proxy pose ...``); the line is that key's in the scene file, in
    the moving (last) ``[[part]]`` for a part's key. None when the message names no key
    the file sets (the value came from an option or a default).
    """
    p = Path(path)
    try:
        text = decode_text(read_input(p, what="scene file", limit=MAX_SCENE_BYTES), p,
                           what="scene file")
    except InputError:
        return None
    parts = len(re.findall(r"^\s*\[\[\s*part\s*\]\]", text, re.M))
    for pattern, table, key in _LATE_ERRORS:
        if not pattern.search(message):
            continue
        where = (table[0], parts - 1) if table[-1] == -1 else table
        line = key_line(text, where, key)
        if line is None or key_line(text, where) == line:  # the key is not set there
            continue
        return SceneError(f"{p}:{line}: {message}", path=str(p), line=line)
    return None
