"""Every frozen parameter type of the engine, and every default, defined once.

Parameters are constant inputs (what a scene file or a GUI control sets); the time-varying
state of a simulation lives elsewhere. Each type here is a frozen dataclass that checks its
values on construction, so an instance is always valid, and every default value the engine
uses is written once, in this module:

- :class:`DescriptorParams`: the skeletal density's ``sigma``, ``penalty``, ``lambda_out``
  and the sampling grid (``grid`` samples or ``spacing``, ``padding`` cells).
- :class:`CorrelationParams`: the retained modes per axis ``K`` (``m' = K^3``) and the
  interpolation table settings.
- :class:`SimulationParams`, :class:`CouplingParams`, :class:`Effects`,
  :class:`DeviceConfig`, :class:`MassSpec`: the scene's ``[simulation]``, ``[coupling]``,
  ``[effects]``, ``[device]`` tables and the per-part mass keys; :class:`SimConfig` holds
  them all.
- :class:`Physics`: the resolved constants of the moving body and its coupling (mass,
  inertia, the spring-damper gains, kappa, gravity, time step): the one type for the
  coupling gains.
- :class:`HapticLimits`: how the coupling's reaction is rendered on a device.

Lengths are in the scene's unit (:data:`LENGTH_UNITS` lists the known ones); times in
seconds; angles in radians.
"""

from __future__ import annotations

import copy
import ipaddress
import math
from dataclasses import dataclass, field
from typing import SupportsFloat, TypeAlias

import numpy as np
import numpy.typing as npt

from engine.errors import InputError

#: A value as a user gave it (a scene's TOML, an option, a JSON field) before it is checked:
#: the validators below take anything and return the checked type or raise InputError.
UserValue: TypeAlias = object

# ---------------------------------------------------------------------------------------------
# units

#: Length units a scene or a part may declare: the length of one unit in metres.
LENGTH_UNITS: dict[str, float] = {
    "km": 1000.0,
    "m": 1.0,
    "dm": 0.1,
    "cm": 0.01,
    "mm": 0.001,
    "um": 1e-6,
    "nm": 1e-9,
    "in": 0.0254,
    "ft": 0.3048,
}
#: The unit a scene is read in when it declares none (a warning says so if it has meshes).
DEFAULT_UNIT = "mm"
#: Standard gravity, m/s^2.
STANDARD_GRAVITY = 9.81


def unit_scale(unit: str, to: str) -> float:
    """Factor that converts a length in ``unit`` into ``to`` (both in :data:`LENGTH_UNITS`)."""
    for u in (unit, to):
        if u not in LENGTH_UNITS:
            raise InputError(f"unknown length unit {u!r}; valid units: {', '.join(LENGTH_UNITS)}")
    return LENGTH_UNITS[unit] / LENGTH_UNITS[to]


def gravity_vector(
    units: str, direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
) -> tuple[float, float, float]:
    """Standard gravity along ``direction`` in ``units`` per second squared.

    Parameters
    ----------
    units : str
        The scene's length unit (a key of :data:`LENGTH_UNITS`).
    direction : (3,) float
        Direction of the pull, any non-zero length (part 1's frame).
    """
    if units not in LENGTH_UNITS:
        raise InputError(f"unknown length unit {units!r}; valid units: {', '.join(LENGTH_UNITS)}")
    d = np.asarray(direction, dtype=np.float64).reshape(3)
    norm = float(np.linalg.norm(d))
    if not (math.isfinite(norm) and norm > 0):
        raise InputError(f"gravity direction must be a non-zero vector, got {tuple(direction)}")
    g = STANDARD_GRAVITY / LENGTH_UNITS[units]
    x, y, z = (float(g * c / norm) for c in d)
    return (x, y, z)


def _number(value: UserValue) -> float | None:
    """``value`` as a float if it reads as a number (not a bool), else None."""
    if isinstance(value, bool) or not isinstance(value, (SupportsFloat, str)):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def _positive(owner: str, name: str, value: UserValue) -> float:
    x = _number(value)
    if x is None or not (math.isfinite(x) and x > 0):
        raise InputError(f"{owner} {name} must be a positive finite number, got {value!r}")
    return x


def _at_least(owner: str, name: str, value: UserValue, minimum: float) -> float:
    x = _number(value)
    if x is None or not (math.isfinite(x) and x >= minimum):
        raise InputError(f"{owner} {name} must be a finite number of at least {minimum:g}, "
                         f"got {value!r}")
    return x


# ---------------------------------------------------------------------------------------------
# descriptor and correlation

#: Samples along the longest side of the largest part (the ``[descriptor] grid`` default).
DEFAULT_GRID = 64
#: Free cells around each part's grid. 6, not 4: the correlation sums over a periodic DFT
#: box, and the descriptor's outside tail (about ``-i lambda_out``, falling off over a few
#: cells) must fade before the box edge so that periodic images of the two parts do not
#: meet within the range of motion the landscape covers; every bundled scene was tuned and
#: its seating measured with 6, so 6 also keeps their results unchanged.
DEFAULT_PADDING = 6.0
#: Retained modes per axis K (``m' = K^3``): the paper's 16^3 of 128^3 was enough there.
DEFAULT_MODES = 16
#: Ways of choosing the retained modes (``CorrelationParams.selection``).
MODE_SELECTIONS = ("cube", "largest")
#: The bands the modal sum can keep (``CorrelationParams.band``; what each is:
#: ``engine.correlation.spectrum.BANDS``). "box", the plain truncation, is what a correlator
#: keeps unless told: the search ranks fits with it and its landscape's minimum is the fit.
BAND_NAMES = ("box", "smooth")
#: The band of the field that guides a part: the ball of modes, Lanczos-tapered, of the
#: densities windowed where their tails end. The box band is a cube along part 1's grid
#: and rings (Gibbs) at big flat faces: pairs turned in their files felt forces across
#: their planes of symmetry, and were held at ways' mouths, tilted in T-slots or short of
#: a cover's seat. On two unseen generated sets (26 pairs each) the smooth band seats 51
#: where the box band seats 46 (docs/fine_level.md). Read when a guidance field is built.
GUIDANCE_BAND = "smooth"

# Ranges that keep every computation finite and bounded (docs/limits.md gives the reasons
# and the measurements behind each).
#: sigma: below 0.05 the quadrature refines every piece of surface to ``sigma |xi|`` and its
#: cost grows like 1/sigma^2 (0.01 took about 4 minutes on a 16-sample grid that 0.5 does
#: in 1 s), while the ridge gets narrower than any grid resolves; above 50 the Gaussian is
#: flat over any part (rho only scales as 1/sigma) and the cost keeps growing.
SIGMA_RANGE = (0.05, 50.0)
#: The largest sigma for a descriptor on a grid: above it a sample near the surface costs
#: 50 ms or more (0.8 s at 50), so a 32-sample grid takes 10 minutes at 50 and a 64-sample
#: one hours. Point queries (``descriptor_at_points``) allow the whole SIGMA_RANGE.
SIGMA_GRID_MAX = 10.0
#: penalty = lambda_in / lambda_out: the descriptor is stored as complex64 and the energy
#: sums products of two of them over up to 1e8 samples, so the weights stay within a few
#: decades of 1 (the product of the extremes, squared, stays far below float32's 3e38).
PENALTY_RANGE = (1e-3, 1e3)
#: lambda_out: as penalty.
LAMBDA_OUT_RANGE = (1e-6, 1e6)
#: Samples along one side of a grid (``grid``, or part size / ``spacing``): 2048^3 complex64
#: is 64 GiB per part before its FFT, more than any machine this runs on; memory is checked
#: against the machine as well (engine.grid.check_memory).
MAX_GRID = 2048
#: Free cells around a part: the outside tail fades within a few cells, so more than this
#: only costs memory (the FFT grows with the cube of the padded size).
MAX_PADDING = 64.0
#: Largest rotation vector of any pose, in radians: beyond it the angle's double precision
#: is coarser than 1e-12 rad per 1e4 rad, and a sine of it is meaningless (1e300 rad
#: overflows into NaN). The scene reader, the simulation's guard and the pose dialog use it.
MAX_ROTATION_VECTOR = 1e4
#: Largest distance of a pose from the origin, in the scene's unit (a light year in
#: millimetres is 1e19): past it a number is a typo, and its square overflows at 1e154.
MAX_POSE_TRANSLATION = 1e20
#: Retained modes per axis K: m' = K^3 terms per pose, so K = 128 is 2.1 million terms, a
#: fraction of a second per pose, far below any interactive rate; K is also at most the
#: scene's FFT size (the correlator says so when it is smaller).
MAX_MODES = 128

# The rotation cache (engine.sim.fields.RotationCacheField; docs/correlation.md)
#: Rotation (radians) from a rotation cache's reference beyond which it is refreshed: there
#: its energy and force errors are at the level of the rotated spectrum's interpolation.
REFRESH_ANGLE = 1e-3
#: While a background refresh is pending, the cache serves up to this rotation from its
#: reference; beyond it the full per-pose path runs.
LIMIT_ANGLE = 4e-3
#: Where the full per-pose path costs more than :data:`FULL_PATH_SHARE` of the loop's
#: period (measured when the field is built), the cache serves on up to this rotation
#: while a background refresh is pending: its torque error grows linearly with the angle
#: (docs/correlation.md, "When the full path is too slow for the loop"), a late pose
#: breaks the period.
STALE_ANGLE = 12e-3
#: The share of the loop's period a full per-pose evaluation may take on the loop thread.
FULL_PATH_SHARE = 0.25
#: A new field (a new K, new descriptors) that the runtime built while the part turned is
#: handed over once a first cache serves the part's rotation; the lane builds one, at most
#: this many times, while the field in use serves on (engine.runtime.handover)...
HANDOVER_TRIES = 4
#: ...and for at most this long (seconds): then it is handed over as it is.
HANDOVER_SECONDS = 0.1
#: A synchronous refresh costs about two full per-pose evaluations (measured at K = 16 to
#: 64): the cache is refreshed only if, at the rate the part turned since the last pose, the
#: new cache would serve at least this many poses; otherwise the full path runs.
MIN_POSES_PER_CACHE = 3


def check_modes(modes: UserValue, what: str = "modes") -> int:
    """K as asked for by a user (scene, option): an integer from 1 to :data:`MAX_MODES`.

    (``CorrelationParams`` itself takes any K from 1 up: the engine clamps K to the FFT
    size, and asks for "all modes" with a large K.)
    """
    if isinstance(modes, bool) or not isinstance(modes, (int, np.integer)) or not (
            1 <= modes <= MAX_MODES):
        raise InputError(f"{what} K = {modes!r} must be an integer from 1 to {MAX_MODES}: "
                         "each pose sums K^3 terms, so a larger K is far too slow to run "
                         "(16 to 48 is usual)")
    return int(modes)


def check_steps(seconds: float, rate_hz: float, what: str) -> int:
    """Steps of a run of ``seconds`` at ``rate_hz``; an InputError above :data:`MAX_STEPS`."""
    steps = seconds * rate_hz
    if not (math.isfinite(steps) and steps <= MAX_STEPS):
        raise InputError(
            f"{what} = {seconds:g} s at {rate_hz:g} Hz is {steps:.3g} steps, above the "
            f"{MAX_STEPS:.0e} one run may take ({MAX_STEPS / rate_hz:.3g} s at this rate): "
            "shorten it (times are seconds from the start, not Unix times or milliseconds)")
    return max(1, int(round(steps)))


def check_range(what: str, value: UserValue, bounds: tuple[float, float], why: str
                ) -> float:
    """``value`` as a float when within ``bounds`` (inclusive), else an InputError.

    The message gives the value, the range and ``why`` (what goes wrong outside it).
    """
    lo, hi = bounds
    x = _number(value)
    if x is None or not lo <= x <= hi:
        shown = f"{value:g}" if isinstance(value, (int, float)) else repr(value)
        raise InputError(f"{what} = {shown} is outside its range {lo:g} to {hi:g}: {why}")
    return x


@dataclass(frozen=True, kw_only=True)
class DescriptorParams:
    """Parameters of the skeletal density and of its sampling grid.

    Attributes
    ----------
    sigma : float
        Width of the Gaussian on ``eta/|xi| - 1`` (dimensionless).
    penalty : float
        ``P = lambda_in / lambda_out``.
    lambda_out : float
        Weight outside the part (``c = -lambda_out`` there).
    grid : int or None
        Samples along the longest side of the largest part of a scene; None when
        ``spacing`` is set (a given ``spacing`` wins, and ``grid`` is stored as None).
    spacing : float or None
        Grid spacing ``h`` in the scene's unit, shared by both parts.
    padding : float
        Free cells around each part.

    Only ``sigma``, ``penalty`` and ``lambda_out`` shape the density at a point; the grid
    fields say where it is sampled.
    """

    sigma: float = 0.5
    penalty: float = 3.0
    lambda_out: float = 1.0
    grid: int | None = DEFAULT_GRID
    spacing: float | None = None
    padding: float = DEFAULT_PADDING

    def __post_init__(self) -> None:
        for name in ("sigma", "penalty", "lambda_out"):
            object.__setattr__(self, name, _positive("descriptor parameter", name,
                                                     getattr(self, name)))
        check_range("descriptor sigma", self.sigma, SIGMA_RANGE,
                    "a smaller sigma makes the quadrature's cost grow like 1/sigma^2 (minutes "
                    "at 0.01) and a larger one flattens the density while the cost grows")
        check_range("descriptor penalty", self.penalty, PENALTY_RANGE,
                    "the descriptor is stored in single precision and its products overflow "
                    "or vanish beyond it")
        check_range("descriptor lambda_out", self.lambda_out, LAMBDA_OUT_RANGE,
                    "the descriptor is stored in single precision and its products overflow "
                    "or vanish beyond it")
        if self.spacing is not None:
            object.__setattr__(self, "spacing", _positive("descriptor", "spacing",
                                                          self.spacing))
            object.__setattr__(self, "grid", None)
        elif self.grid is None:
            raise InputError("descriptor needs grid (samples along the longest side) or "
                             "spacing; give one of them")
        else:
            grid = self.grid
            if (isinstance(grid, bool) or not isinstance(grid, (int, np.integer))
                    or not 4 <= grid <= MAX_GRID):
                raise InputError(f"descriptor grid must be an integer from 4 to {MAX_GRID}, "
                                 f"got {grid!r}: {MAX_GRID}^3 samples take 64 GiB per part")
            object.__setattr__(self, "grid", int(grid))
        object.__setattr__(self, "padding", _at_least("descriptor", "padding", self.padding, 0.0))
        check_range("descriptor padding", self.padding, (0.0, MAX_PADDING),
                    "the outside tail fades within a few cells; more padding only grows the "
                    "grid and its FFT")

    @property
    def lambda_in(self) -> float:
        """Weight inside the part: ``penalty * lambda_out``."""
        return self.penalty * self.lambda_out


@dataclass(frozen=True)
class CorrelationParams:
    """Settings of the per-pose correlation (the scene's ``[correlation]`` table).

    Attributes
    ----------
    modes : int
        Retained modes per axis K (``m' = K^3``): the accuracy/time dial.
    oversample : float
        Zero-padding factor of the spectrum the rotated frequencies are interpolated from.
    refine : int
        For ``K <= fine_modes``, the interpolation table is ``refine`` times finer.
    fine_modes : int
        Largest K that uses the refined table.
    selection : {"cube", "largest"}
        Which modes are retained: the low-frequency cube, or the largest ones.
    band : {"box", "smooth"}
        The band kept of the cube (:data:`BAND_NAMES`): its shape, taper and whether the
        densities are windowed first.
    """

    modes: int = DEFAULT_MODES
    oversample: float = 2.0
    refine: int = 2
    fine_modes: int = 24
    selection: str = "cube"
    band: str = "box"

    def __post_init__(self) -> None:
        for name in ("modes", "refine", "fine_modes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InputError(f"correlation {name} must be a positive integer, got {value!r}")
            object.__setattr__(self, name, int(value))
        object.__setattr__(self, "oversample", _at_least("correlation", "oversample",
                                                         self.oversample, 1.0))
        if self.selection not in MODE_SELECTIONS:
            raise InputError(f"correlation selection must be one of "
                             f"{', '.join(MODE_SELECTIONS)}, got {self.selection!r}")
        if self.band not in BAND_NAMES:
            raise InputError(f"correlation band must be one of {', '.join(BAND_NAMES)}, "
                             f"got {self.band!r}")


# ---------------------------------------------------------------------------------------------
# units of the reported quantities

#: SI names of kg u^2/s^2 and kg u/s^2 for the common length units u.
_NAMED = {"m": ("J", "N", "N·m"), "mm": ("µJ", "mN", "mN·mm"),
          "cm": ("100 µJ", "10 mN", "10 mN·cm"), "um": ("pJ", "µN", "µN·µm")}


@dataclass(frozen=True)
class QuantityUnits:
    """The units of energy, force, torque and kappa in a scene of length unit ``length``.

    Masses are in kg and times in seconds; lengths in the scene's unit ``u``. The energy
    ``E = -kappa Re f`` is kappa times a volume (``u^3``): with kappa in ``kg/(u s^2)`` it is
    in ``kg u^2/s^2``; the force ``-dE/dt`` in ``kg u/s^2``; the torque in ``kg u^2/s^2``.
    For millimetre scenes these are µJ, mN and mN·mm.
    """

    length: str
    energy: str
    force: str
    torque: str
    kappa: str

    @classmethod
    def of(cls, length: str) -> QuantityUnits:
        """The units for a scene in ``length`` (a key of :data:`LENGTH_UNITS`)."""
        u = length
        energy, force, torque = _NAMED.get(u, (f"kg·{u}²/s²", f"kg·{u}/s²", f"kg·{u}²/s²"))
        return cls(length=u, energy=energy, force=force, torque=torque, kappa=f"kg/({u}·s²)")


# ---------------------------------------------------------------------------------------------
# the assembled fit

#: Degrees of freedom, in part 1's frame: three translations, three rotations.
AXES = ("x", "y", "z", "rx", "ry", "rz")
#: Angle within which part 2 counts as seated when the scene gives none (degrees).
DEFAULT_SEAT_ANGLE_DEG = 1.0
#: Distance within which part 2 counts as seated when the scene gives none, as a fraction
#: of part 2's bounding-box diagonal.
DEFAULT_SEAT_DISTANCE_FRACTION = 0.02


@dataclass(frozen=True)
class SeatSpec:
    """How the assembled fit is judged (the scene's ``free_axes`` and ``seat_tolerance``).

    Attributes
    ----------
    free_axes : tuple of str, or None
        The degrees of freedom the fit leaves free, in part 1's frame (names from
        :data:`AXES`: a peg in a through hole leaves ``("z", "rz")``); ``()`` when the fit
        locks every axis, None when the scene does not say.
    distance : float or None
        Largest distance of part 2's centre from its seat that counts as seated, in the
        scene's unit; None: :data:`DEFAULT_SEAT_DISTANCE_FRACTION` of part 2's size.
    angle_deg : float
        Largest angle from the seated orientation that counts as seated (degrees).
    """

    free_axes: tuple[str, ...] | None = None
    distance: float | None = None
    angle_deg: float = DEFAULT_SEAT_ANGLE_DEG

    def __post_init__(self) -> None:
        if self.free_axes is not None:
            axes = tuple(str(a) for a in self.free_axes)
            unknown = [a for a in axes if a not in AXES]
            if unknown:
                raise InputError(f"free_axes: unknown axis {unknown[0]!r}; valid: "
                                 f"{', '.join(AXES)} (part 1's frame)")
            if len(set(axes)) != len(axes):
                raise InputError(f"free_axes: an axis is listed twice in {list(axes)}")
            object.__setattr__(self, "free_axes", axes)
        if self.distance is not None:
            distance = _at_least("seat_tolerance", "distance", self.distance, 0.0)
            if distance == 0.0:
                raise InputError("seat_tolerance distance must be positive, got 0")
            object.__setattr__(self, "distance", distance)
        angle = float(self.angle_deg)
        if not (0.0 < angle <= 180.0):
            raise InputError(f"seat_tolerance: the angle must be in (0, 180] degrees, got "
                             f"{self.angle_deg!r}")
        object.__setattr__(self, "angle_deg", angle)


# ---------------------------------------------------------------------------------------------
# simulation tables

#: Engine rate (``[simulation] rate_hz``): the haptic loop's 1 kHz.
DEFAULT_RATE_HZ = 1000.0
#: Engine rates: above 100 kHz a step is shorter than one field evaluation (50 us or more),
#: so no loop holds the rate and each simulated second costs 1e5 steps or more.
RATE_RANGE = (1.0, 100_000.0)
#: Most steps one run may take (duration times rate): 1e8 steps is 28 hours at 1 kHz and
#: hours of computing; a duration beyond it is almost always a unit slip (Unix times,
#: milliseconds).
MAX_STEPS = 100_000_000
#: Gravity, in standard gravities: beyond it the pull dwarfs every other force and the
#: part leaves the grid within a step.
MAX_GRAVITY_G = 100.0
#: Masses in kg (or the unit mass when a scene gives none): outside this the coupling's
#: gains ``m (2 pi f)^2`` and their square roots overflow or vanish.
MASS_RANGE = (1e-9, 1e9)
#: A given inertia may differ from the mesh's own (for the part's mass) by at most this
#: factor: a real part's density varies less, and larger factors are unit slips
#: (kg m^2 against kg mm^2 is 1e6).
INERTIA_FACTOR = 10.0
#: kappa may be at most this multiple of its scale-free default (``guidance_gain k / L``
#: with the default gain): beyond it the geometric force is so much stiffer than the
#: coupling that the fixed step cannot follow it.
MAX_KAPPA_FACTOR = 1e4
#: Geometric guidance kinds (``[effects] guidance``).
GUIDANCE = ("skeletal", "collision", "none")
#: Input device kinds (``[device] kind``).
DEVICES = ("mouse", "trajectory", "spacemouse", "openhaptics", "udp")
#: Device-specific keys of ``[device]``, per kind.
DEVICE_OPTIONS: dict[str, tuple[str, ...]] = {
    "mouse": (),
    "trajectory": ("file",),
    "spacemouse": ("translation_speed", "rotation_speed"),
    "openhaptics": ("name",),
    "udp": ("host", "port", "reply_port", "peer", "token", "allow_remote", "timeout",
            "max_force", "max_torque", "workspace"),
}


@dataclass(frozen=True)
class SimulationParams:
    """The ``[simulation]`` table.

    Attributes
    ----------
    rate_hz : float
        Engine rate; the fixed time step is ``1 / rate_hz`` seconds.
    kappa : float or None
        Geometric force gain ``E = -kappa Re f``; ``None``: the scale-invariant default
        ``guidance_gain * k_lin / L``.
    guidance_gain : float
        Dimensionless factor in the default kappa. 0.2: on the peg in hole, the seated part
        holds a 3 degree / 3 % misaligned proxy to 0.05 degree and 0.01 mm, and the part is
        drawn in a few millimetres ahead of the proxy rather than snapping in from its start
        (gain 1 pulls it 18 mm in 0.2 s).
    body_damping_ratio : float
        Viscous damping of the free body (relative to its coupling frequency), applied when
        ``Effects.damping`` is on; keeps the body from ringing inside a stiff geometric well.
    seconds : float
        Default duration of a headless run.
    """

    rate_hz: float = DEFAULT_RATE_HZ
    kappa: float | None = None
    guidance_gain: float = 0.2
    body_damping_ratio: float = 0.5
    seconds: float = 5.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate_hz", _positive("simulation", "rate_hz", self.rate_hz))
        object.__setattr__(self, "seconds", _positive("simulation", "seconds", self.seconds))
        check_range("simulation rate_hz", self.rate_hz, RATE_RANGE,
                    "above it a step is shorter than one field evaluation, so no loop holds "
                    "the rate")
        check_steps(self.seconds, self.rate_hz, "[simulation] seconds")
        for name in ("guidance_gain", "body_damping_ratio"):
            object.__setattr__(self, name, _at_least("simulation", name, getattr(self, name),
                                                     0.0))
        if self.kappa is not None:
            object.__setattr__(self, "kappa", _at_least("simulation", "kappa", self.kappa, 0.0))

    @property
    def dt(self) -> float:
        """Fixed time step in seconds."""
        return 1.0 / self.rate_hz


@dataclass(frozen=True)
class CouplingParams:
    """The ``[coupling]`` table: six-axis spring-damper between proxy and part.

    Absolute gains (``stiffness`` in force/length, ``angular_stiffness`` in torque/radian,
    ``damping``, ``angular_damping``) override the scale-free ``frequency_hz`` /
    ``damping_ratio`` defaults, which give a stiffness of ``m (2 pi f)^2`` for the body's
    mass ``m`` whatever the length unit.
    """

    frequency_hz: float = 10.0
    damping_ratio: float = 1.0
    stiffness: float | None = None
    angular_stiffness: float | None = None
    damping: float | None = None
    angular_damping: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "frequency_hz", _positive("coupling", "frequency_hz",
                                                           self.frequency_hz))
        object.__setattr__(self, "damping_ratio", _at_least("coupling", "damping_ratio",
                                                            self.damping_ratio, 0.0))
        for name in ("stiffness", "angular_stiffness"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _positive("coupling", name, getattr(self, name)))
        for name in ("damping", "angular_damping"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _at_least("coupling", name, getattr(self, name),
                                                         0.0))


@dataclass(frozen=True)
class Effects:
    """The ``[effects]`` table: what the simulation computes. Switched-off work is skipped.

    Attributes
    ----------
    guidance : {"skeletal", "collision", "none"}
        Skeletal densities (geometric guidance), the collision-only indicator density (the
        paper's baseline) or no geometric force at all (no correlator is built).
    axes : tuple of str
        Free degrees of freedom among ``x y z rx ry rz`` (part 1's frame). No rotational axis:
        rotation is locked, no torque is computed and the translational landscape is looked
        up instead of summing modes.
    damping : bool
        Coupling and body damping on; off conserves energy (for tests).
    gravity : tuple of 3 float or None
        Gravity acceleration in scene units per second squared, part 1's frame (see
        :func:`gravity_vector`).
    """

    guidance: str = "skeletal"
    axes: tuple[str, ...] = AXES
    damping: bool = True
    gravity: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.guidance not in GUIDANCE:
            raise InputError(
                f"guidance must be one of {', '.join(GUIDANCE)}; got {self.guidance!r}"
            )
        bad = [a for a in self.axes if a not in AXES]
        if bad:
            raise InputError(f"unknown axes {bad}; valid axes are {', '.join(AXES)}")
        object.__setattr__(self, "axes", tuple(a for a in AXES if a in self.axes))
        if self.gravity is not None:
            g = tuple(float(x) for x in self.gravity)
            if len(g) != 3 or not all(math.isfinite(x) for x in g):
                raise InputError(f"gravity must be three finite numbers, got {self.gravity!r}")
            object.__setattr__(self, "gravity", g)

    @property
    def rotation(self) -> bool:
        """True when any rotational axis is free."""
        return any(a.startswith("r") for a in self.axes)

    @property
    def translation_mask(self) -> np.ndarray:
        """(3,) float64: 1 for free translation axes, 0 for locked ones."""
        return np.array([float(a in self.axes) for a in AXES[:3]])

    @property
    def rotation_mask(self) -> np.ndarray:
        """(3,) float64: 1 for free rotation axes, 0 for locked ones."""
        return np.array([float(a in self.axes) for a in AXES[3:]])


#: Default clamp of the force norm a UDP bridge sends, in device units (newtons for the usual
#: desktop haptic devices, which render 3 to 12 N at most): finite, so that nothing a packet
#: or the simulation does can send an unbounded force; ``[device] max_force`` sets another.
UDP_MAX_FORCE = 10.0
#: Default clamp of the torque norm a UDP bridge sends, in device units (newton metres:
#: 6-DOF desktop devices render well under 1 N m); ``[device] max_torque`` sets another.
UDP_MAX_TORQUE = 1.0
#: Default ``[device] workspace`` of a UDP bridge: a pose packet whose translation lies farther
#: than this from part 1's origin (scene units) is dropped as out of the workspace.
UDP_WORKSPACE = 1000.0
#: Largest rotation-vector norm (radians) a UDP pose packet may carry: a client sends at most
#: pi (or a few turns when it unwraps); beyond this the packet is garbage, and the rotation's
#: sine and cosine lose their precision.
UDP_MAX_ROTATION = 1000.0


def _port(name: str, value: UserValue, *, zero: bool) -> int:
    low = 0 if zero else 1
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            low <= int(value) <= 65535):
        any_free = " (0: any free port)" if zero else ""
        raise InputError(f"{name} {value!r} is not a UDP port: a port is a whole number from "
                         f"{low} to 65535{any_free}; pick one such as 47800")
    return int(value)


def _ipv4(name: str, value: UserValue) -> str:
    if value == "localhost":
        return "127.0.0.1"
    try:
        return str(ipaddress.IPv4Address(value))
    except (ValueError, TypeError):
        raise InputError(f"{name} {value!r} is not an IPv4 address; write one such as "
                         '"127.0.0.1" (or "localhost")') from None


def _loopback(host: str) -> bool:
    return host.startswith("127.")


@dataclass(frozen=True)
class UdpBridgeParams:
    """The keys of a ``[device]`` table of kind ``udp`` (see ``docs/devices.md``).

    Attributes
    ----------
    host : str
        IPv4 address the bridge listens on; a loopback address unless ``allow_remote``.
    port : int
        UDP port it listens on (1 to 65535; 0: any free port, for tests).
    reply_port : int or None
        Send replies to this port on the peer's host instead of the peer's own port.
    peer : str or None
        ``"host"`` or ``"host:port"``: the only source it accepts packets from. None: the
        first source that sends a valid packet (and, with ``token``, the right token).
    token : int or None
        Session token (1 to 2**63 - 1) every pose packet must carry; with a token the
        header-less 56-byte packet of the first version is refused.
    allow_remote : bool
        Allow ``host`` (and ``peer``) beyond loopback; then a token is required.
    timeout : float
        Seconds without a packet from the peer, after its first, at which the device is lost.
    max_force, max_torque : float
        Clamps of the force and torque norms sent (device units; finite).
    workspace : float
        Largest distance from part 1's origin (scene units) of an accepted pose.
    """

    host: str = "127.0.0.1"
    port: int = 47800
    reply_port: int | None = None
    peer: str | None = None
    token: int | None = None
    allow_remote: bool = False
    timeout: float = 1.0
    max_force: float = UDP_MAX_FORCE
    max_torque: float = UDP_MAX_TORQUE
    workspace: float = UDP_WORKSPACE

    def __post_init__(self) -> None:
        if not isinstance(self.allow_remote, bool):
            raise InputError(f"udp allow_remote must be true or false, got {self.allow_remote!r}")
        object.__setattr__(self, "host", _ipv4("udp host", self.host))
        object.__setattr__(self, "port", _port("udp port", self.port, zero=True))
        if self.reply_port is not None:
            object.__setattr__(self, "reply_port",
                               _port("udp reply_port", self.reply_port, zero=False))
        for name in ("timeout", "max_force", "max_torque", "workspace"):
            object.__setattr__(self, name, _positive("udp", name, getattr(self, name)))
        if self.token is not None and (isinstance(self.token, bool) or not isinstance(
                self.token, (int, np.integer)) or not 0 < int(self.token) < 2**63):
            raise InputError(f"udp token {self.token!r} is not a session token: a whole number "
                             "from 1 to 2**63 - 1 (make one with python -c \"import secrets; "
                             "print(secrets.randbits(63))\")")
        if self.peer is not None:
            host, _, port = str(self.peer).partition(":")
            address = _ipv4("udp peer", host)
            if port:
                try:
                    number = int(port)
                except ValueError:
                    number = -1
                address += f":{_port('udp peer port', number, zero=False)}"
            object.__setattr__(self, "peer", address)
        remote = [f"{name} {value}" for name, value in (("host", self.host), ("peer", self.peer))
                  if value is not None and not _loopback(value)]
        if remote and not self.allow_remote:
            raise InputError(
                f"udp {remote[0]} is beyond this machine, where any host that reaches the port "
                "could drive the proxy; use 127.0.0.1, or add allow_remote = true and a token")
        if remote and self.token is None:
            raise InputError(f"udp {remote[0]} with allow_remote needs a session token "
                             "(token = a whole number from 1 to 2**63 - 1 that the client sends)")

    @property
    def remote(self) -> bool:
        """True when the bridge listens beyond loopback."""
        return not _loopback(self.host)

    @property
    def peer_address(self) -> tuple[str, int | None] | None:
        """The configured peer as (host, port or None for any port), or None."""
        if self.peer is None:
            return None
        host, _, port = self.peer.partition(":")
        return host, int(port) if port else None

    @classmethod
    def from_options(cls, options: dict[str, UserValue]) -> UdpBridgeParams:
        """From a ``[device]`` table's udp options; ``"auto"`` or None: the default."""
        keys = DEVICE_OPTIONS["udp"]
        unknown = [k for k in options if k not in keys]
        if unknown:
            raise InputError(f"udp options {unknown} are unknown; valid: {', '.join(keys)}")
        given = {k: v for k, v in options.items() if v is not None and v != "auto"}
        return cls(**given)  # type: ignore[arg-type]  # user values: __post_init__ checks each


@dataclass(frozen=True)
class DeviceConfig:
    """The ``[device]`` table: which input drives the proxy and how force is rendered.

    Attributes
    ----------
    kind : {"mouse", "trajectory", "spacemouse", "openhaptics", "udp"}
    max_force : float or None
        Clamp of the rendered force norm (device units); None: the device's own maximum.
    force_scale : float
        Device force per simulation force.
    options : tuple of (str, value)
        Device-specific keys (:data:`DEVICE_OPTIONS`: ``file`` for a trajectory,
        ``port``/``host`` for udp, ...).
    """

    kind: str = "mouse"
    max_force: float | None = None
    force_scale: float = 1.0
    options: tuple[tuple[str, UserValue], ...] = ()

    def __post_init__(self) -> None:
        if self.kind not in DEVICES:
            raise InputError(f"device must be one of {', '.join(DEVICES)}; got {self.kind!r}")
        object.__setattr__(self, "force_scale", _positive("device", "force_scale",
                                                          self.force_scale))
        if self.max_force is not None:
            object.__setattr__(self, "max_force", _positive("device", "max_force",
                                                            self.max_force))
        bad = [k for k, _ in self.options if k not in DEVICE_OPTIONS[self.kind]]
        if bad:
            valid = ", ".join(DEVICE_OPTIONS[self.kind]) or "none"
            raise InputError(f"device options {bad} do not apply to a {self.kind} device; "
                             f"its options: {valid}")
        if self.kind == "udp":
            self._carry_udp_limits()

    def _carry_udp_limits(self) -> None:
        # The device sees only the options (open_device(kind, pose, options)), so the table's
        # max_force travels among them too: the bridge clamps what it sends at the same value
        # as the simulation. "auto" (or no value) leaves the default, UDP_MAX_FORCE.
        options = dict(self.options)
        given = options.pop("max_force", None)
        if given is not None and given != "auto":
            given = _positive("device", "max_force", given)
            if self.max_force is not None and given != self.max_force:
                raise InputError(f"device max_force is given twice ({self.max_force!r} and "
                                 f"{given!r}); give it once")
            object.__setattr__(self, "max_force", given)
        if self.max_force is not None:
            options["max_force"] = self.max_force
        UdpBridgeParams.from_options(options)  # every udp key checked when the scene is read
        object.__setattr__(self, "options", tuple(
            (k, options[k]) for k in DEVICE_OPTIONS["udp"] if k in options))

    def option(self, key: str, default: UserValue = None) -> UserValue:
        """A device-specific option."""
        return dict(self.options).get(key, default)


@dataclass(frozen=True)
class MassSpec:
    """Per-part mass properties; None: computed from the mesh.

    ``mass``, ``density``, ``inertia`` (3x3 about the centre of mass) and ``center_of_mass``
    (part frame).
    """

    mass: float | None = None
    density: float | None = None
    inertia: tuple[tuple[float, ...], ...] | None = None
    center_of_mass: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("mass", "density"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _positive("part", name, getattr(self, name)))
        if self.mass is not None:
            check_range("part mass", self.mass, MASS_RANGE,
                        "the coupling's gains m (2 pi f)^2 and their square roots overflow or "
                        "vanish outside it")
        if self.inertia is not None:
            try:
                arr = np.asarray(self.inertia, dtype=np.float64)
            except (TypeError, ValueError):
                arr = np.zeros(0)
            if arr.shape == (3,):
                arr = np.diag(arr)
            if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
                raise InputError(f"part inertia must be 3 principal moments or a 3x3 list, "
                                 f"got {self.inertia!r}")
            if not np.allclose(arr, arr.T) or np.any(np.linalg.eigvalsh(arr) <= 0):
                raise InputError("part inertia must be symmetric positive definite")
            object.__setattr__(self, "inertia", tuple(tuple(float(v) for v in row)
                                                      for row in arr))
        if self.center_of_mass is not None:
            c = tuple(float(v) for v in self.center_of_mass)
            if len(c) != 3 or not all(math.isfinite(v) for v in c):
                raise InputError(f"part center_of_mass must be three finite numbers, "
                                 f"got {self.center_of_mass!r}")
            object.__setattr__(self, "center_of_mass", c)


@dataclass(frozen=True)
class SimConfig:
    """All simulation settings of a scene (validated; size-dependent defaults not resolved).

    Attributes
    ----------
    simulation, coupling, effects, device
        The four tables.
    masses : tuple of MassSpec
        One per ``[[part]]``, in file order (may be shorter: missing ones are ``MassSpec()``).
    units : str
        The scene's length unit.
    """

    simulation: SimulationParams = field(default_factory=SimulationParams)
    coupling: CouplingParams = field(default_factory=CouplingParams)
    effects: Effects = field(default_factory=Effects)
    device: DeviceConfig = field(default_factory=DeviceConfig)
    masses: tuple[MassSpec, ...] = ()
    units: str = DEFAULT_UNIT

    def mass_spec(self, index: int) -> MassSpec:
        """The MassSpec of part ``index`` (``MassSpec()`` when the scene gives none)."""
        return self.masses[index] if 0 <= index < len(self.masses) else MassSpec()


# ---------------------------------------------------------------------------------------------
# resolved constants


def _readonly(value: npt.ArrayLike, shape: tuple[int, ...]) -> np.ndarray:
    a = np.array(value, dtype=np.float64).reshape(shape)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Physics:
    """Resolved constants of the moving body and its coupling (MuJoCo's "model").

    The one type for the coupling gains: the spring-damper reads ``k_lin``, ``c_lin``,
    ``k_rot``, ``c_rot`` from here. ``engine.sim.resolve_physics`` derives every field
    from a scene's :class:`SimConfig` and the moving part's mesh; the body fields default
    to a unit mass and inertia so that a coupling alone can be written
    ``Physics(k_lin=10.0, c_lin=0.0, k_rot=2.0, c_rot=0.0)``.

    Attributes
    ----------
    k_lin, c_lin, k_rot, c_rot : float
        Coupling stiffness and damping: force/length, force*s/length, torque/rad,
        torque*s/rad.
    mass : float
    inertia : (3, 3) float64
        Inertia tensor about the centre of mass, in the part's own frame (read-only).
    centre : (3,) float64
        Centre of mass in the part's own frame (read-only).
    length : float
        The part's characteristic length L (largest bounding-box side).
    body_c_lin, body_c_rot : float
        Viscous damping of the body against the world (0 with damping off).
    kappa : float
        Geometric force gain.
    gravity : (3,) float64
        Gravity acceleration (zeros when off; read-only).
    k_rot_hard, c_rot_hard : float
        The rotational coupling beyond ``rot_play``: past that angle between the part and
        the proxy the spring stiffens from ``k_rot`` to ``k_rot_hard`` (torque/rad) and
        the damping to ``c_rot_hard``. 0: no stiffening (a linear spring).
    rot_play : float
        The angle (rad) within which the coupling turns the part with ``k_rot`` alone.

    The time step is not here: :class:`engine.sim.Simulation` owns it, set once.
    """

    k_lin: float
    c_lin: float
    k_rot: float
    c_rot: float
    mass: float = 1.0
    inertia: np.ndarray = field(default_factory=lambda: np.eye(3))
    centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    length: float = 1.0
    body_c_lin: float = 0.0
    body_c_rot: float = 0.0
    kappa: float = 1.0
    gravity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    k_rot_hard: float = 0.0
    c_rot_hard: float = 0.0
    rot_play: float = math.pi

    def __post_init__(self) -> None:
        for name in ("k_lin", "c_lin", "k_rot", "c_rot", "body_c_lin", "body_c_rot", "kappa",
                     "k_rot_hard", "c_rot_hard", "rot_play"):
            object.__setattr__(self, name, _at_least("physics", name, getattr(self, name), 0.0))
        for name in ("mass", "length"):
            object.__setattr__(self, name, _positive("physics", name, getattr(self, name)))
        object.__setattr__(self, "inertia", _readonly(self.inertia, (3, 3)))
        object.__setattr__(self, "centre", _readonly(self.centre, (3,)))
        object.__setattr__(self, "gravity", _readonly(self.gravity, (3,)))

    def with_play(self, rot_play: float) -> Physics:
        """A copy with ``rot_play`` alone changed, clamped to ``[0, self.rot_play]``.

        The loop narrows the play at every step while the part nears its fit; the other
        fields were checked when this was made, and ``dataclasses.replace`` checking them
        again (three arrays copied) cost 91 microseconds a call against 4.5.
        """
        out = copy.copy(self)
        object.__setattr__(out, "rot_play", min(max(float(rot_play), 0.0), self.rot_play))
        return out


@dataclass(frozen=True)
class HapticLimits:
    """Rendering of the coupling's reaction on a device: scale, then clamp the norms."""

    force_scale: float = 1.0
    max_force: float = math.inf
    max_torque: float = math.inf

    @classmethod
    def from_device(cls, device: DeviceConfig) -> HapticLimits:
        """The limits a ``[device]`` table asks for (no clamp where it gives none).

        A udp bridge always clamps: its "auto" resolves to :data:`UDP_MAX_FORCE` and
        :data:`UDP_MAX_TORQUE` (or its ``max_force`` / ``max_torque``), never to infinity.
        """
        if device.kind == "udp":
            udp = UdpBridgeParams.from_options(dict(device.options))
            return cls(force_scale=device.force_scale, max_force=udp.max_force,
                       max_torque=udp.max_torque)
        return cls(force_scale=device.force_scale,
                   max_force=math.inf if device.max_force is None else device.max_force)


# ------------------------------------------------------------------ what a control offers
@dataclass(frozen=True)
class ControlRange:
    """What a GUI control of one parameter offers: the one source of its range and default.

    A control is a slider beside a numeric field. The field accepts every value the engine
    accepts (``allowed``); the slider spans the stretch a user usually wants
    (``comfortable``), so that a drag is fine-grained where it matters. A value outside the
    comfortable stretch (a scene's K = 64 where the slider ends at 48) is shown in the field
    and kept, with the slider at its end: opening and saving a scene never changes a value.

    Attributes
    ----------
    allowed : (float, float)
        Every value the engine accepts, inclusive.
    comfortable : (float, float)
        The slider's span, within ``allowed``.
    default : float
        The value a control starts with (the engine's default where it has one).
    step : float
        The field's step (its arrows, the wheel).
    log : bool
        The slider is logarithmic (``comfortable`` must then be positive).
    integer : bool
        Whole numbers only.
    decimals : int
        Decimals the field shows.
    """

    allowed: tuple[float, float]
    comfortable: tuple[float, float]
    default: float
    step: float
    log: bool = False
    integer: bool = False
    decimals: int = 3

    def __post_init__(self) -> None:
        lo, hi = self.allowed
        c_lo, c_hi = self.comfortable
        if not (lo <= c_lo < c_hi <= hi and lo <= self.default <= hi):
            raise ValueError(f"a control's ranges must nest (allowed {self.allowed}, "
                             f"comfortable {self.comfortable}, default {self.default})")
        if self.log and c_lo <= 0:
            raise ValueError("a logarithmic slider needs a positive comfortable range")
        if not self.step > 0:
            raise ValueError(f"a control's step must be positive, got {self.step}")

    def clamp(self, value: float) -> float:
        """``value`` within :attr:`allowed` (whole for an integer control)."""
        v = min(max(float(value), self.allowed[0]), self.allowed[1])
        return float(round(v)) if self.integer else v


#: The controls of the live parameters, by name: their range, step and default, derived
#: from the parameter types and limits above so that a control accepts every value a scene
#: may hold. The comfortable stretches are where users work (K 4 to 48: beyond, a pose
#: costs milliseconds on a CPU; sigma to 3 and penalty to 20: beyond, the density is flat
#: or the overlap cost hides every fit).
CONTROLS: dict[str, ControlRange] = {
    "modes": ControlRange(allowed=(1.0, float(MAX_MODES)), comfortable=(4.0, 48.0),
                          default=float(DEFAULT_MODES), step=1.0, integer=True, decimals=0),
    "sigma": ControlRange(allowed=(SIGMA_RANGE[0], SIGMA_GRID_MAX), comfortable=(0.05, 3.0),
                          default=DescriptorParams.sigma, step=0.01, log=True, decimals=3),
    "penalty": ControlRange(allowed=PENALTY_RANGE, comfortable=(1.0, 20.0),
                            default=DescriptorParams.penalty, step=0.1, log=True, decimals=3),
    # kappa's own bound is relative to the part (MAX_KAPPA_FACTOR times its scale-free
    # default), checked when physics is resolved: the control takes any kappa >= 0
    "kappa": ControlRange(allowed=(0.0, 1e300), comfortable=(1e-6, 1e9), default=1.0,
                          step=0.1, log=True, decimals=4),
    # a coupling frequency must be positive and, at the fastest rate, leave the step stable
    # (2 pi f dt <= 1, engine.scene.reader)
    "coupling_hz": ControlRange(allowed=(1e-6, RATE_RANGE[1] / (2 * math.pi)),
                                comfortable=(0.5, 50.0),
                                default=CouplingParams.frequency_hz, step=0.5, log=True,
                                decimals=3),
}
