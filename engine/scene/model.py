"""The parsed scene: two parts, their poses, the assembled answer and every parameter table.

All values here are validated (``engine.scene.reader`` builds them from a file); the
parameter tables are the frozen types of ``engine.params``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from engine.errors import InputError
from engine.params import (
    DEFAULT_UNIT,
    CorrelationParams,
    DescriptorParams,
    MassSpec,
    SeatSpec,
    SimConfig,
)
from engine.pose import relative_pose


class SceneError(InputError):
    """A bad scene file: the message reads ``FILE:LINE: problem; fix``.

    Attributes
    ----------
    path : str
        The scene file.
    line : int or None
        1-based line of the offending key or table (None when it has none).
    """

    def __init__(self, message: str, *, path: str = "", line: int | None = None):
        super().__init__(message)
        self.path = path
        self.line = line


def _readonly(values: npt.ArrayLike, n: int) -> np.ndarray:
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
        World pose ``(tx, ty, tz, rx, ry, rz)`` of the part's file frame (read-only).
    fixed : bool
        True for the first part, False for the second.
    body : str or None
        Which solid of a multi-body STEP file.
    tolerance : float or None
        STEP tessellation tolerance, in the part's unit (None: the loader's default).
    unit : str or None
        Length unit of the file's coordinates; overrides the file's own declaration
        (None: the STEP header's unit, or the scene's for mesh files).
    pivot : (3,) float64 or None
        Point, in the part's file frame and scene units, that typed or dragged rotations
        turn about (None: the centre of the part's bounding box).
    hold : (3,) float64 or None
        The moving part only: point, in its file frame and scene units, where the coupling
        holds it at and before its seat (None: the middle of the fit,
        ``engine.sim.build.hold_point``).
    mass : MassSpec
        ``mass``, ``density``, ``inertia``, ``center_of_mass`` (None: from the mesh).
    """

    name: str
    file: Path
    pose: np.ndarray
    fixed: bool
    body: str | None = None
    tolerance: float | None = None
    unit: str | None = None
    pivot: np.ndarray | None = None
    hold: np.ndarray | None = None
    mass: MassSpec = field(default_factory=MassSpec)

    def __post_init__(self) -> None:
        object.__setattr__(self, "pose", _readonly(self.pose, 6))
        object.__setattr__(self, "file", Path(self.file))
        if self.pivot is not None:
            object.__setattr__(self, "pivot", _readonly(self.pivot, 3))
        if self.hold is not None:
            object.__setattr__(self, "hold", _readonly(self.hold, 3))


@dataclass(frozen=True, eq=False)
class Scene:
    """A parsed scene file.

    Attributes
    ----------
    path : Path
        The scene file (absolute).
    name : str
    units : str
        The scene's length unit (a key of ``engine.params.LENGTH_UNITS``); every part is
        converted into it.
    units_declared : bool
        False when the file gave no ``units`` (then ``units`` is the default, mm).
    parts : tuple of PartSpec
        The fixed part first, then the moving part (one or two).
    assembled_pose : (6,) float64
        Part 2 relative to part 1 when assembled (read-only); zeros when not known.
    assembled_known : bool
        False when the file gives no ``assembled_pose`` (``skelasm search`` finds the fits;
        :func:`require_assembled` stops what needs one).
    insertion_axis : (3,) float64 or None
        Unit direction part 2 travels to seat, in part 1's frame.
    seat : SeatSpec
        The axes the fit leaves free and the tolerance of "seated" (``free_axes``,
        ``seat_tolerance``).
    descriptor : DescriptorParams
        The ``[descriptor]`` table.
    correlation : CorrelationParams
        The ``[correlation]`` table.
    config : SimConfig
        The ``[simulation]``, ``[coupling]``, ``[effects]``, ``[device]`` tables and each
        part's mass keys.
    given : frozenset of str
        The settings the file gives, as ``"table.key"`` (``"descriptor.grid"``,
        ``"correlation.modes"``, ``"coupling.angular_stiffness"``, ...); every other
        setting is the engine's to choose from the parts (:mod:`engine.sim.auto`). None
        (the default for scenes built in code): every setting counts as given.
    chosen : tuple of (str, str, str)
        The settings chosen from the parts, as ``(key, value, reason)``; empty until
        :func:`engine.sim.auto.complete_scene` fills them.
    """

    path: Path
    name: str
    parts: tuple[PartSpec, ...]
    assembled_pose: np.ndarray
    units: str = DEFAULT_UNIT
    units_declared: bool = True
    insertion_axis: np.ndarray | None = None
    seat: SeatSpec = field(default_factory=SeatSpec)
    descriptor: DescriptorParams = field(default_factory=DescriptorParams)
    correlation: CorrelationParams = field(default_factory=CorrelationParams)
    config: SimConfig = field(default_factory=SimConfig)
    given: frozenset[str] | None = None
    chosen: tuple[tuple[str, str, str], ...] = ()
    assembled_known: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        object.__setattr__(self, "parts", tuple(self.parts))
        object.__setattr__(self, "assembled_pose", _readonly(self.assembled_pose, 6))
        if self.insertion_axis is not None:
            object.__setattr__(self, "insertion_axis", _readonly(self.insertion_axis, 3))

    def gives(self, key: str) -> bool:
        """Whether the file sets ``key`` (``"descriptor.grid"``), so the engine keeps it."""
        return self.given is None or key in self.given

    @property
    def modes(self) -> int:
        """Retained modes per axis K: ``correlation.modes``."""
        return self.correlation.modes

    @property
    def fixed_part(self) -> PartSpec:
        """The first part, which does not move."""
        return self.parts[0]

    @property
    def moving_part(self) -> PartSpec | None:
        """The second part, or None for a scene with one part."""
        return self.parts[1] if len(self.parts) > 1 else None


def relative_start_pose(scene: Scene) -> np.ndarray:
    """(6,) pose of part 2 in part 1's frame at the start, from the parts' world poses."""
    if len(scene.parts) < 2:
        raise SceneError(f"{scene.path}: the scene has no moving part; add a second [[part]] "
                         "with the part that moves", path=str(scene.path))
    return relative_pose(scene.parts[0].pose, scene.parts[1].pose)


def require_assembled(scene: Scene, what: str) -> None:
    """Stop ``what`` (a command, a use) with one line when the scene has no assembled pose.

    Raises
    ------
    SceneError
        The scene's file gives no ``assembled_pose``.
    """
    if not scene.assembled_known:
        raise SceneError(
            f"{scene.path}: {what} needs the scene's assembled_pose, which it does not give; "
            f"run `skelasm search {scene.path}` to find the fits, then add the one you want "
            "as `assembled_pose = [tx, ty, tz, rx, ry, rz]`", path=str(scene.path))
