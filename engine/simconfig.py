"""Simulation settings of a scene: the ``[simulation]``, ``[coupling]``, ``[effects]`` and
``[device]`` tables and the per-part ``mass`` / ``density`` / ``inertia`` keys.

The scene loader (``engine.scene``) hands the raw tables over in ``Scene.sections``; this
module validates them into frozen parameter dataclasses (:class:`SimConfig`); the defaults
that scale with the moving part's size are resolved by ``engine.sim.resolve_physics``.
Gravity is off by default; ``gravity = true`` means 9.81 m/s^2 converted to the scene's unit
along ``gravity_direction`` (part 1's frame), the only physical, not scaled, default.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from engine.errors import InputError
from engine.params import (
    AXES,
    DEVICE_OPTIONS,
    DEVICES,
    GUIDANCE,
    CouplingParams,
    DeviceConfig,
    Effects,
    MassSpec,
    Physics,
    SimConfig,
    SimulationParams,
    gravity_vector,
)

__all__ = [
    "AXES", "DEVICES", "GUIDANCE", "CouplingParams", "DeviceConfig", "Effects", "MassSpec",
    "Physics", "SimConfig", "SimConfigError", "SimulationParams",
    "parse_simconfig", "simconfig_from_scene",
]

class SimConfigError(InputError):
    """A bad key or value in a scene's simulation tables; the message names the line."""


# ---------------------------------------------------------------------------------------------
# parsing


def _line_of(text: str | None, section: str | None, key: str) -> int | None:
    """1-based line of ``key = ...`` inside ``[section]`` (or top level / ``[[part]]`` n)."""
    if not text:
        return None
    current: str | None = None
    part_index = -1
    target_part = None
    if section and section.startswith("part#"):
        target_part = int(section[5:])
    key_re = re.compile(rf"^\s*{re.escape(key)}\s*=")
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if stripped.startswith("[[") and stripped.endswith("]]"):
            current = stripped[2:-2].strip()
            if current == "part":
                part_index += 1
            continue
        if stripped.startswith("[") and stripped.endswith("]"):
            current = stripped[1:-1].strip()
            continue
        if not key_re.match(line):
            continue
        if target_part is not None:
            if current == "part" and part_index == target_part:
                return number
        elif current == section:
            return number
    return None


def _header_line(text: str | None, section: str) -> int | None:
    if not text:
        return None
    for number, line in enumerate(text.splitlines(), start=1):
        if line.strip() == f"[{section}]":
            return number
    return None


class _Reader:
    """Reads one table, remembering keys used, raising SimConfigError with the line."""

    def __init__(self, table: Mapping[str, Any], section: str, path: str, text: str | None):
        if not isinstance(table, Mapping):
            raise SimConfigError(
                f"{path}: [{section}] must be a table of key = value lines, got {table!r}"
            )
        self.table = dict(table)
        self.section = section
        self.path = path
        self.text = text
        self.used: set[str] = set()

    def where(self, key: str) -> str:
        line = _line_of(self.text, self.section, key)
        name = self.section if not self.section.startswith("part#") else "[part]"
        head = f"{self.path}:{line}" if line else self.path
        label = f"[{name}]" if not name.startswith("[") else name
        return f"{head}: {label} {key}"

    def fail(self, key: str, problem: str) -> SimConfigError:
        return SimConfigError(f"{self.where(key)}: {problem}")

    def number(self, key: str, default, *, positive=False, minimum=None, allow_none=False):
        self.used.add(key)
        if key not in self.table:
            return default
        value = self.table[key]
        if allow_none and (value == "auto" or value is None):
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            extra = ' or "auto"' if allow_none else ""
            raise self.fail(key, f"must be a number{extra}, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise self.fail(key, f"must be finite, got {value!r}")
        if positive and value <= 0:
            raise self.fail(key, f"must be positive, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.fail(key, f"must be at least {minimum}, got {value!r}")
        return value

    def boolean(self, key: str, default: bool) -> bool:
        self.used.add(key)
        if key not in self.table:
            return default
        value = self.table[key]
        if not isinstance(value, bool):
            raise self.fail(key, f"must be true or false, got {value!r}")
        return value

    def choice(self, key: str, default: str, valid: tuple[str, ...]) -> str:
        self.used.add(key)
        if key not in self.table:
            return default
        value = self.table[key]
        if value not in valid:
            raise self.fail(key, f"must be one of {', '.join(valid)}; got {value!r}")
        return value

    def vector(self, key: str, default, n=3):
        self.used.add(key)
        if key not in self.table:
            return default
        value = self.table[key]
        if (
            not isinstance(value, (list, tuple))
            or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            or not all(math.isfinite(float(v)) for v in value)
        ):
            raise self.fail(key, f"must be a list of {n} numbers, got {value!r}")
        return tuple(float(v) for v in value)

    def finish(self, allowed_extra: tuple[str, ...] = ()) -> None:
        unknown = [k for k in self.table if k not in self.used and k not in allowed_extra]
        if unknown:
            known = ", ".join(sorted(self.used))
            raise self.fail(unknown[0], f"unknown key; known keys here are: {known}")


def parse_simconfig(
    sections: Mapping[str, Any],
    *,
    parts: tuple[Mapping[str, Any], ...] = (),
    units: str = "mm",
    path: str = "<scene>",
    text: str | None = None,
) -> SimConfig:
    """Validate the raw simulation tables of a scene.

    Parameters
    ----------
    sections : mapping
        Raw TOML tables by name; only ``simulation``, ``coupling``, ``effects`` and
        ``device`` are read (missing ones take their defaults).
    parts : tuple of mapping
        Per-part extra keys (``mass``, ``density``, ``inertia``, ``center_of_mass``), one
        mapping per ``[[part]]`` in file order.
    units : str
        The scene's length unit (for gravity).
    path, text : str
        Scene file name and text, to name the line of a bad key.

    Returns
    -------
    SimConfig

    Raises
    ------
    SimConfigError
        Unknown key or bad value; the message has ``path:line: [table] key: problem``.
    """
    sim = _Reader(sections.get("simulation", {}), "simulation", path, text)
    simulation = SimulationParams(
        rate_hz=sim.number("rate_hz", 1000.0, positive=True),
        kappa=sim.number("kappa", None, minimum=0.0, allow_none=True),
        guidance_gain=sim.number("guidance_gain", 0.2, minimum=0.0),
        body_damping_ratio=sim.number("body_damping_ratio", 0.5, minimum=0.0),
        seconds=sim.number("seconds", 5.0, positive=True),
    )
    sim.finish()

    cpl = _Reader(sections.get("coupling", {}), "coupling", path, text)
    coupling = CouplingParams(
        frequency_hz=cpl.number("frequency_hz", 10.0, positive=True),
        damping_ratio=cpl.number("damping_ratio", 1.0, minimum=0.0),
        stiffness=cpl.number("stiffness", None, positive=True, allow_none=True),
        angular_stiffness=cpl.number("angular_stiffness", None, positive=True, allow_none=True),
        damping=cpl.number("damping", None, minimum=0.0, allow_none=True),
        angular_damping=cpl.number("angular_damping", None, minimum=0.0, allow_none=True),
    )
    cpl.finish()
    if coupling.frequency_hz * 2 * math.pi / simulation.rate_hz > 1.0:
        raise cpl.fail(
            "frequency_hz",
            f"{coupling.frequency_hz} Hz is too stiff for the {simulation.rate_hz} Hz rate "
            f"(needs 2 pi f dt <= 1); lower it or raise [simulation] rate_hz",
        )

    eff = _Reader(sections.get("effects", {}), "effects", path, text)
    guidance = eff.choice("guidance", "skeletal", GUIDANCE)
    eff.used.add("axes")
    axes_value = eff.table.get("axes", "all")
    axes: tuple[str, ...]
    if axes_value == "all":
        axes = AXES
    elif axes_value == "translation":
        axes = AXES[:3]
    elif axes_value == "rotation":
        axes = AXES[3:]
    elif isinstance(axes_value, (list, tuple)) and all(a in AXES for a in axes_value):
        axes = tuple(axes_value)
    else:
        raise eff.fail(
            "axes",
            f'must be "all", "translation", "rotation" or a list of {", ".join(AXES)}; '
            f"got {axes_value!r}",
        )
    damping = eff.boolean("damping", True)
    eff.used.add("gravity")
    gvalue = eff.table.get("gravity", False)
    direction = eff.vector("gravity_direction", (0.0, 0.0, -1.0))
    gravity: tuple[float, float, float] | None
    if gvalue is False:
        gravity = None
    elif gvalue is True:
        if float(np.linalg.norm(direction)) == 0:
            raise eff.fail("gravity_direction", "must not be the zero vector")
        try:
            gravity = gravity_vector(units, direction)
        except InputError:
            raise eff.fail(
                "gravity", f"unit {units!r} unknown; give gravity as [gx, gy, gz]"
            ) from None
    else:
        gravity = eff.vector("gravity", None)
    eff.finish()
    effects = Effects(guidance=guidance, axes=axes, damping=damping, gravity=gravity)

    dev = _Reader(sections.get("device", {}), "device", path, text)
    kind = dev.choice("kind", "mouse", DEVICES)
    max_force = dev.number("max_force", None, positive=True, allow_none=True)
    force_scale = dev.number("force_scale", 1.0, positive=True)
    per_kind = DEVICE_OPTIONS[kind]
    options = tuple((k, dev.table[k]) for k in per_kind if k in dev.table)
    dev.used.update(per_kind)
    dev.finish()
    if kind == "trajectory" and not dict(options).get("file"):
        raise dev.fail("kind", 'a trajectory device needs file = "path/to.csv" in [device]')
    device = DeviceConfig(kind=kind, max_force=max_force, force_scale=force_scale, options=options)

    masses = []
    for i, extras in enumerate(parts):
        pr = _Reader(extras, f"part#{i}", path, text)
        mass = pr.number("mass", None, positive=True)
        density = pr.number("density", None, positive=True)
        pr.used.add("inertia")
        inertia = None
        if "inertia" in pr.table:
            raw = pr.table["inertia"]
            try:
                arr = np.asarray(raw, dtype=float)
            except (TypeError, ValueError):
                arr = np.zeros(0)
            if arr.shape == (3,):
                arr = np.diag(arr)
            if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
                raise pr.fail("inertia", f"must be 3 principal moments or a 3x3 list, got {raw!r}")
            if not np.allclose(arr, arr.T) or np.any(np.linalg.eigvalsh(arr) <= 0):
                raise pr.fail("inertia", "must be symmetric positive definite")
            inertia = tuple(tuple(float(v) for v in row) for row in arr)
        com = pr.vector("center_of_mass", None)
        pr.finish(allowed_extra=_PART_KEYS)
        masses.append(MassSpec(mass=mass, density=density, inertia=inertia, center_of_mass=com))
    return SimConfig(simulation, coupling, effects, device, tuple(masses), units)


#: Keys of a [[part]] table the scene loader owns (not ours to reject).
_PART_KEYS = ("name", "file", "pose", "fixed")


def simconfig_from_scene(scene: Any) -> SimConfig:
    """:func:`parse_simconfig` for an ``engine.scene.Scene`` (reads its file for line numbers)."""
    path = str(getattr(scene, "path", "<scene>"))
    text = None
    try:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    except OSError:
        pass
    parts = tuple(dict(getattr(p, "extras", {}) or {}) for p in getattr(scene, "parts", ()))
    return parse_simconfig(
        getattr(scene, "sections", {}) or {},
        parts=parts,
        units=str(getattr(scene, "units", "mm")),
        path=path,
        text=text,
    )
