"""Building a :class:`~engine.sim.Simulation` from a loaded scene.

The moving part's mass properties, the physics constants scaled to its size, the
geometric field the effects ask for, and the simulation itself.

Data: the moving part's mesh (vertices (n, 3) float64, faces (m, 3) int64, own frame), the
scene's validated simulation settings, and poses (6,) float64 relative to part 1.

Scale invariance. Every default is tied to the moving part's length ``L`` (largest side of
its bounding box) and to its mass, so that the same pair drawn in metres and in millimetres
moves alike:

- mass: ``mass`` if given, else ``density * volume`` if ``density`` is given, else 1 (a
  dimensionless unit mass); inertia from the mesh with the same density.
- coupling: a spring-damper with natural frequency ``frequency_hz`` and damping ratio
  ``damping_ratio`` for the body's mass and mean inertia, so the stiffness in force per
  length is ``m (2 pi f)^2`` whatever the length unit.
- kappa (geometric force gain): the correlation energy is an integral over volume of two
  dimensionless densities, so its gradient scales with an area ``L^2``; the default
  ``kappa = guidance_gain * k / L`` (``k`` the linear coupling stiffness) makes the ratio of
  geometric to coupling force independent of the unit.
- gravity: as the effects give it (already in scene units), not scaled.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import numpy as np

import engine.params
from engine.errors import Cancelled, InputError
from engine.loading import Part
from engine.params import (
    DEFAULT_UNIT,
    INERTIA_FACTOR,
    MASS_RANGE,
    MAX_KAPPA_FACTOR,
    CouplingParams,
    DescriptorParams,
    Effects,
    HapticLimits,
    MassSpec,
    Physics,
    SimConfig,
    SimulationParams,
    check_range,
    unit_scale,
)
from engine.pose import rotation_matrix
from engine.sim.body import RigidBody
from engine.sim.coupling import HAND_DAMPING_RATIO, hand_stiffness, weakest_inertia
from engine.sim.fields import GeometricField, NullField, field_correlator, field_for_effects
from engine.sim.simulation import Simulation

if TYPE_CHECKING:
    from engine.correlation import Correlator
    from engine.correlation.near import NearField, NearLevel
    from engine.descriptor import Descriptor
    from engine.scene import Scene
    from engine.sim.auto import FitMeasure


#: Samples along the largest part's longest side of a scene's first field when its own
#: descriptors are not cached: about a twentieth of the work of grid 64, seconds instead of
#: minutes, so the part can be dragged while the scene's own are computed and swapped in.
COARSE_GRID = 24


class LoadedScene(Protocol):
    """What building a simulation reads of a loaded scene (the runtime's scene handle)."""

    @property
    def scene(self) -> Scene:
        """The scene file as read."""

    @property
    def config(self) -> SimConfig:
        """The simulation settings of the scene."""

    @property
    def parts(self) -> Sequence[Part]:
        """The loaded parts: part 1 (fixed) and, in a pair, part 2 (moving)."""

    @property
    def start_pose(self) -> np.ndarray:
        """(6,) float64 start pose of the moving part relative to part 1."""


# ---------------------------------------------------------------------------------------------
# physics constants of the moving part


def mass_properties(
    vertices: np.ndarray, faces: np.ndarray, spec: MassSpec, units: str = DEFAULT_UNIT
) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass, (3, 3) inertia about the centre of mass, (3,) centre, from a mesh and a MassSpec.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
    spec : MassSpec
    units : str
        The scene's length unit (names the unit of a refused inertia).

    Notes
    -----
    Uses trimesh's mass properties (exact for a closed mesh). A mesh that is not closed or
    whose volume comes out non-positive falls back to its bounding box, uniformly filled.
    Without density or mass the density is chosen so the mass is 1.
    """
    import trimesh

    mesh = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces), process=False)
    volume = float(mesh.volume) if len(faces) else 0.0
    if volume > 0 and mesh.is_watertight:
        center = np.asarray(mesh.center_mass, float)
        unit_inertia = np.asarray(mesh.moment_inertia, float) / volume  # per unit mass
    else:
        lo, hi = np.min(vertices, axis=0), np.max(vertices, axis=0)
        size = np.maximum(hi - lo, 1e-12)
        volume = float(np.prod(size))
        center = 0.5 * (lo + hi)
        unit_inertia = np.diag(
            [(size[1] ** 2 + size[2] ** 2), (size[0] ** 2 + size[2] ** 2),
             (size[0] ** 2 + size[1] ** 2)]
        ) / 12.0
    if spec.mass is not None:
        mass = spec.mass
    elif spec.density is not None:
        mass = spec.density * volume
    else:
        mass = 1.0
    inertia = mass * unit_inertia
    if spec.inertia is not None:
        inertia = np.asarray(spec.inertia, float)
        check_inertia(inertia, mass * unit_inertia, mass, units)
    if spec.center_of_mass is not None:
        center = np.asarray(spec.center_of_mass, float)
    return float(mass), inertia, center


def check_inertia(given: np.ndarray, own: np.ndarray, mass: float, units: str) -> None:
    """Refuse a given inertia far from the mesh's own for the part's mass.

    Within :data:`engine.params.INERTIA_FACTOR` either way (largest principal moments
    compared) it is taken as given; beyond, it is almost always a unit slip, which the
    message names.

    Parameters
    ----------
    given, own : (3, 3) float64
        The scene's inertia and the uniform-density mesh's, both about the centre of mass.
    mass : float
    units : str
        The scene's length unit (inertia is in kg times its square).
    """
    ratio = float(np.max(np.linalg.eigvalsh(own)) / np.max(np.linalg.eigvalsh(given)))
    if 1.0 / INERTIA_FACTOR <= ratio <= INERTIA_FACTOR:
        return
    how = f"{ratio:.3g} times smaller" if ratio > 1 else f"{1 / ratio:.3g} times larger"
    moments = ", ".join(f"{v:.4g}" for v in np.linalg.eigvalsh(own))
    given_moments = ", ".join(f"{v:.4g}" for v in np.linalg.eigvalsh(given))
    other = "m" if units != "m" else "mm"
    factor = unit_scale(other, units) ** 2
    raise InputError(
        f"part inertia (principal moments {given_moments}) is {how} than the mesh's own for "
        f"mass {mass:g} ({moments}). Inertia is in kg {units}^2 (the mass times the scene's "
        f"unit squared): a value in kg {other}^2 is {factor:g} times "
        f"{'smaller' if factor > 1 else 'larger'}, so check its unit. A given inertia may "
        f"differ from the mesh's by at most a factor of {INERTIA_FACTOR:g} (uneven "
        "density); remove it to use the mesh's")


def check_physics(physics: Physics, default_kappa: float) -> None:
    """Refuse gains that no fixed step can integrate: a kappa far above its default.

    Parameters
    ----------
    physics : Physics
    default_kappa : float
        The scale-free default (``guidance_gain k / L`` with the default gain).
    """
    top = MAX_KAPPA_FACTOR * default_kappa
    if physics.kappa > top:
        raise InputError(
            f"kappa = {physics.kappa:g} is {physics.kappa / default_kappa:.3g} times its "
            f"scale-free default ({default_kappa:.4g} for this part and coupling); at most "
            f"{MAX_KAPPA_FACTOR:g} times that ({top:.4g}) keeps the geometric force within "
            "what the time step can follow: lower [simulation] kappa or write \"auto\"")


#: Near a fit the geometric torque is left in charge of the part's orientation: the default
#: rotational stiffness of the coupling is at most the geometric rotational stiffness at the
#: assembled pose divided by this. The Hessian at the seat overstates the stiffness the part
#: meets over a misalignment of degrees (on the 5 mm pin at K = 48, 3.4 times), so the
#: margin is wide: at 10 the pin kept 0.51 degree of a 3 degree proxy tilt, at 100 (with
#: the coupling held at the fit, :func:`hold_point`) 0.19.
ROTATION_AUTHORITY = 100.0
#: The rotational coupling is never softer than this fraction of the mass-based default
#: ``I (2 pi f)^2`` (a tenth of the coupling frequency), so the orientation stays in the
#: user's hand away from any fit. Held at the fit (:func:`hold_point`) a long part meets
#: no lever from the geometric pull at its leading end: the 50 mm Factory peg at 1 % went
#: in straight (0.33 degree); held at its centre of mass at 1 % it was thrown 44 degrees at
#: the hole's mouth, which is why this was 0.25 before.
MIN_ROTATION_FRACTION = 0.01
#: The hand's play: within this angle of the proxy the lowered rotational spring lets the
#: fit turn the part into line; past it the spring is the mass-based one again, so a
#: torque at a hole's mouth cannot throw the part over (with the lowered spring alone
#: the 16 mm Factory peg turned 62 degrees from the proxy during a push, and the
#: dovetail's slide 55). The misaim of the seating protocol is 3 degrees.
HAND_PLAY_RAD = math.radians(3.0)
#: Rotation step of the finite differences that measure the geometric rotational stiffness.
STIFFNESS_STEP_RAD = math.radians(0.5)


def part_pivot(handle: LoadedScene, index: int = -1) -> np.ndarray:
    """(3,) point, in a part's own frame, that its typed and dragged rotations turn about.

    The scene's ``pivot`` for the part if it names one, else the part's centre of mass
    (the coupling holds the part at :func:`hold_point` instead, where the fit is). ``index``
    -1 is the moving part.
    """
    i = index % len(handle.parts)
    spec = handle.scene.parts[i]
    if spec.pivot is not None:
        return np.array(spec.pivot, dtype=np.float64)
    part = handle.parts[i]
    return np.asarray(mass_properties(part.vertices, part.faces, handle.config.mass_spec(i),
                                      handle.scene.units)[2], dtype=np.float64)


def _box_corners(vertices: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the axis-aligned bounding box of ``vertices`` (n, 3)."""
    v = np.asarray(vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    pick = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], bool)
    return np.where(pick, hi, lo)


#: The twelve edges of a box, as pairs of corner indices of :func:`_box_corners` (corner
#: ``i`` takes ``hi`` on axis ``k`` where bit ``k`` of ``i`` is set).
_BOX_EDGES = np.array([(i, i | (1 << k)) for i in range(8) for k in range(3)
                       if not i & (1 << k)])


def surface_box(vertices: np.ndarray, faces: np.ndarray, lo: np.ndarray,
                hi: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The bounding box of the part of a triangle surface that lies inside a box, or None.

    Exact: the corners of each triangle clipped to the box ``[lo, hi]`` are the triangle's
    corners inside it, the crossings of its edges with the box's faces, and the crossings of
    the box's edges with the triangle; the box of all of them is returned as ``(lo, hi)``.

    Parameters
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int
    lo, hi : (3,) float64
        The box.
    """
    v = np.asarray(vertices, np.float64)
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    tri = v[np.asarray(faces, np.int64)]  # (m, 3, 3)
    near = np.all((tri.min(axis=1) <= hi) & (tri.max(axis=1) >= lo), axis=1)
    tri = tri[near]
    if len(tri) == 0:
        return None
    tol = 1e-9 * max(1.0, float(np.max(np.abs(np.concatenate([lo, hi])))))
    points = [tri.reshape(-1, 3)]
    # the triangles' edges against the box's six face planes
    a, b = tri, np.roll(tri, -1, axis=1)  # (m, 3, 3): edge j from corner j to j + 1
    d = b - a
    for axis in range(3):
        for plane in (lo[axis], hi[axis]):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (plane - a[..., axis]) / d[..., axis]
            ok = (t >= 0.0) & (t <= 1.0)
            points.append((a + np.where(ok, t, 0.0)[..., None] * d)[ok])
    # the box's twelve edges against the triangles
    corners = _box_corners(np.stack([lo, hi]))
    p0, p1 = corners[_BOX_EDGES[:, 0]], corners[_BOX_EDGES[:, 1]]  # (12, 3)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    normal = np.cross(e1, e2)  # (m, 3)
    along = (p1 - p0) @ normal.T  # (12, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("mk,mk->m", tri[:, 0], normal)[None, :] - p0 @ normal.T
        t = t / along
    ok = np.isfinite(t) & (t >= 0.0) & (t <= 1.0)
    hit = p0[:, None, :] + np.where(ok, t, 0.0)[..., None] * (p1 - p0)[:, None, :]  # (12, m, 3)
    # barycentric test of each hit against its triangle
    w = hit - tri[None, :, 0]
    d11, d12, d22 = (np.einsum("mk,mk->m", e1, e1), np.einsum("mk,mk->m", e1, e2),
                     np.einsum("mk,mk->m", e2, e2))
    w1, w2 = np.einsum("emk,mk->em", w, e1), np.einsum("emk,mk->em", w, e2)
    den = d11 * d22 - d12 * d12
    with np.errstate(divide="ignore", invalid="ignore"):
        bu = (d22 * w1 - d12 * w2) / den
        bv = (d11 * w2 - d12 * w1) / den
    eps = 1e-12
    ok &= (bu >= -eps) & (bv >= -eps) & (bu + bv <= 1.0 + eps)
    points.append(hit[ok])
    pts = np.concatenate(points)
    pts = pts[np.all((pts >= lo - tol) & (pts <= hi + tol), axis=1)]
    if len(pts) == 0:
        return None
    return np.minimum(pts.min(axis=0), hi), np.maximum(pts.max(axis=0), lo)


#: How far around the moving part's box part 1's surface is looked for, as a fraction of the
#: box's smallest side: a rectangular peg's box lies wholly inside its hole, the walls a
#: clearance away (the Factory rectangular pegs': 0.07 mm for the 12 mm tight one, 0.09 mm
#: for the 8 mm loose one, where this margin is 0.8 and 0.69 mm).
FIT_MARGIN = 0.1


def _fit_middle(fixed: Part, moving: np.ndarray,
                assembled_pose: np.ndarray) -> np.ndarray | None:
    """(3,) the middle of the fit in the moving part's own frame, or None.

    In part 1's frame, with the moving part at its assembled pose: the box where the two
    parts' bounding boxes overlap (the moving part's box rotated to the pose, then boxed
    again), narrowed to the box around part 1's surface within :data:`FIT_MARGIN` of the
    moving part's box: the walls of the hole or bore the part sits in, so that a pin in a
    flange at the top of a tall housing is held at the flange, not in the housing's empty
    inside. Its centre is mapped into the moving part's frame. None where the boxes do not
    meet; the overlap alone where no surface of part 1 is that near.
    """
    pose = np.asarray(assembled_pose, np.float64).reshape(6)
    rot = rotation_matrix(pose[3:])
    placed = _box_corners(moving) @ rot.T + pose[:3]
    near_lo, near_hi = placed.min(axis=0), placed.max(axis=0)
    vertices = np.asarray(fixed.vertices, np.float64)
    lo = np.maximum(vertices.min(axis=0), near_lo)
    hi = np.minimum(vertices.max(axis=0), near_hi)
    if np.any(hi - lo <= 0):
        return None
    margin = FIT_MARGIN * float(np.min(near_hi - near_lo))
    walls = surface_box(vertices, fixed.faces, near_lo - margin, near_hi + margin)
    if walls is not None:
        narrow_lo, narrow_hi = np.maximum(lo, walls[0]), np.minimum(hi, walls[1])
        if np.all(narrow_hi - narrow_lo > 0):
            lo, hi = narrow_lo, narrow_hi
    return np.asarray(rot.T @ (0.5 * (lo + hi) - pose[:3]), np.float64)


class FitHold:
    """Where the coupling holds the moving part: at the fit, also past its seat.

    At and before the assembled pose the hold point is the middle of the fit there
    (:func:`hold_point`). A part that goes on past its seat along the insertion axis (a peg
    through a through hole: that axis is free, and the energy draws it on) carries the fit
    up its own axis: the hold point slides back along the part's line through it that lies
    on the insertion axis at the assembled pose (a peg's own axis) by as far as the part has
    gone past, so it stays at the fit, but never beyond the part's far end.

    Held there the coupling is a remote centre of compliance at the fit wherever the part
    is along the axis. Held at a fixed point of the part, the 16 mm Factory peg, 3.4 mm past
    its seat and aimed 0.48 mm sideways, rested 0.76 degree tilted (the sideways pull 3.4 mm
    below the fit tilted it about the fit); held at the fit, 0.10. Before the seat the hold
    point stays put: a first version that also slid it towards the leading end while the
    part went in (the middle of where the parts' boxes overlapped) toppled the thin-walled
    sleeve 22 degrees at the mouth when the proxy's tilt opposed its sideways aim.

    Parameters
    ----------
    fixed : Part
        Part 1 (its frame is the scene's).
    moving : (n, 3) float64
        The moving part's vertices in its own frame.
    assembled_pose : (6,) float64
        Part 2 relative to part 1 at the seat.
    axis : (3,) float64
        The insertion axis, part 1's frame (the way part 2 travels to its seat).
    rest : (3,) float64, optional
        The hold point at and before the seat, in the part's own frame (the scene's
        ``hold``); by default the middle of the fit.
    """

    def __init__(self, fixed: Part, moving: np.ndarray, assembled_pose: np.ndarray,
                 axis: np.ndarray, rest: np.ndarray | None = None):
        if rest is None:
            rest = _fit_middle(fixed, moving, assembled_pose)
        if rest is None:
            raise ValueError("the parts' boxes do not meet at the assembled pose")
        #: The hold point at and before the assembled pose, in the part's own frame.
        self.rest = rest
        a = np.asarray(axis, np.float64).reshape(3)
        self.axis = a / np.linalg.norm(a)
        pose = np.asarray(assembled_pose, np.float64).reshape(6)
        rot = rotation_matrix(pose[3:])
        #: The part's origin at the assembled pose (part 1's frame).
        self.seat = pose[:3].copy()
        #: The insertion axis in the part's own frame, as it is at the assembled pose: the
        #: hold point slides along this line of the part.
        self.along = rot.T @ self.axis
        #: How far the hold point can slide back before it leaves the part's box.
        self.reach = max(0.0, float(np.max((self.rest - _box_corners(moving)) @ self.along)))

    def at(self, rotation: np.ndarray, origin: np.ndarray) -> np.ndarray:
        """(3,) the hold point in the part's own frame, the part at ``rotation``, ``origin``."""
        past = float((np.asarray(origin, np.float64) - self.seat) @ self.axis)
        if not past > 0.0:
            return self.rest
        return self.rest - min(past, self.reach) * self.along


def fit_hold(handle: LoadedScene) -> FitHold | None:
    """The scene's :class:`FitHold`, or None (hold at :func:`hold_point` throughout).

    None for a single part, a scene without an insertion axis, or parts whose boxes do not
    meet at the assembled pose.
    """
    if len(handle.parts) < 2 or handle.scene.insertion_axis is None:
        return None
    try:
        return FitHold(handle.parts[0], handle.parts[1].vertices,
                       handle.scene.assembled_pose, handle.scene.insertion_axis,
                       rest=hold_point(handle))
    except ValueError:
        return None


def hold_point(handle: LoadedScene) -> np.ndarray | None:
    """(3,) point in the moving part's own frame where the coupling holds it, or None.

    The middle of the fit: the centre of the box where the two parts' bounding boxes
    overlap at the assembled pose (the engaged length of a peg, the spigot of a cover),
    narrowed to where part 1's surface is (:func:`_fit_middle`), mapped into the moving
    part's frame. Held there the coupling is a remote centre of
    compliance at the fit: a tilt is resisted by the rotational spring alone, not also by
    the translational spring times the square of the lever from the fit to the centre of
    mass (a 50 mm peg held at its centre of mass pivots 20 mm below it in a 9 mm plate).
    Where the scene names an insertion axis the point follows the fit past the seat
    (:class:`FitHold`). The scene's ``hold`` for the moving part, where it names one,
    replaces the middle of the fit (a part in several fits at once, whose boxes' middle
    is not where it should pivot). None (hold at the centre of mass) for a single part or
    where the boxes do not overlap at the assembled pose.
    """
    if len(handle.parts) < 2:
        return None
    named = handle.scene.parts[1].hold
    if named is not None:
        return np.array(named, dtype=np.float64)
    return _fit_middle(handle.parts[0], handle.parts[1].vertices,
                       handle.scene.assembled_pose)


def rotational_stiffness(field: GeometricField, pose: np.ndarray) -> float | None:
    """Geometric rotational stiffness of a field at a pose, per unit kappa.

    The Hessian ``H = -dT/dtheta`` (3, 3) is taken by central differences of the torque
    (rotation steps of :data:`STIFFNESS_STEP_RAD` about the world axes through the part's
    origin) and symmetrised; the stiffness is the mean of its positive eigenvalues, the
    directions the fit constrains (a free axis, such as a round peg's spin, has none).

    Parameters
    ----------
    field : GeometricField
        Must compute torque (``field.rotation``) with a non-zero ``kappa``.
    pose : (6,) float64
        Part 2 relative to part 1 (the assembled pose).

    Returns
    -------
    float or None
        Torque per radian per unit kappa; None when the field computes no torque or the
        pose constrains no rotation.
    """
    if not field.rotation or field.kappa <= 0:
        return None
    # a correlator's field is probed through the correlator: the full model, and the
    # field's own state (a rotation cache, its counts) is left as it is
    corr = field_correlator(field)
    probe: GeometricField | Correlator = field if corr is None else corr
    p = np.asarray(pose, np.float64).reshape(6)
    a = STIFFNESS_STEP_RAD
    hessian = np.zeros((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = a
        plus = probe.evaluate(rotation_matrix(p[3:] + d), p[:3]).torque
        minus = probe.evaluate(rotation_matrix(p[3:] - d), p[:3]).torque
        if plus is None or minus is None:
            return None
        hessian[:, i] = -(np.asarray(plus) - np.asarray(minus)) / (2 * a)
    eig = np.linalg.eigvalsh(0.5 * (hessian + hessian.T))
    positive = eig[eig > 0]
    if len(positive) == 0:
        return None
    return float(np.mean(positive)) / (field.kappa if corr is None else corr.kappa)


def resolve_physics(
    config: SimConfig,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    part_index: int = 1,
    effects: Effects | None = None,
    kappa: float | None = None,
    geometric_rotation: float | None = None,
    measured: tuple[float, np.ndarray, np.ndarray] | None = None,
) -> Physics:
    """Scale the defaults to the moving part (and to the fit, where it is known).

    Parameters
    ----------
    config : SimConfig
    vertices : (n, 3) float64
        The moving part's mesh, in its own frame.
    faces : (m, 3) int64
    part_index : int
        Which MassSpec applies (the moving part is 1).
    effects : Effects, optional
        Overrides ``config.effects`` (live changes from the GUI).
    kappa : float, optional
        Overrides the scene's / the default kappa.
    geometric_rotation : float, optional
        The field's rotational stiffness at the assembled pose per unit kappa
        (:func:`rotational_stiffness`). The default rotational coupling stiffness is the
        mass-based ``I (2 pi f)^2``, lowered to ``kappa * geometric_rotation /
        ROTATION_AUTHORITY`` where the fit is softer than that (but not below
        ``MIN_ROTATION_FRACTION`` of the mass-based one).
    measured : (mass, inertia, centre), optional
        :func:`mass_properties` of this mesh and part, measured before (it costs about a
        millisecond per thousand triangles: a caller on the loop thread passes it).
    """
    effects = effects or config.effects
    if measured is None:
        measured = mass_properties(vertices, faces, config.mass_spec(part_index), config.units)
    mass, inertia, center = measured
    v = np.asarray(vertices, float)
    length = float(np.max(np.ptp(v, axis=0))) if len(v) else 1.0
    length = length if length > 0 else 1.0
    i_mean = float(np.trace(inertia) / 3.0)
    omega = 2 * math.pi * config.coupling.frequency_hz
    zeta = config.coupling.damping_ratio
    c = config.coupling
    k_lin = c.stiffness if c.stiffness is not None else mass * omega**2
    default_kappa = SimulationParams().guidance_gain * k_lin / length
    if kappa is None:
        kappa = config.simulation.kappa
    if kappa is None:
        kappa = config.simulation.guidance_gain * k_lin / length
    k_rot = k_hand = i_mean * omega**2
    if c.angular_stiffness is not None:
        k_rot = k_hand = c.angular_stiffness
    elif geometric_rotation is not None and geometric_rotation > 0 and kappa > 0:
        k_fit = kappa * geometric_rotation / ROTATION_AUTHORITY
        k_rot = max(min(k_rot, k_fit), MIN_ROTATION_FRACTION * k_rot)
    c_lin = c.damping if c.damping is not None else 2 * zeta * math.sqrt(k_lin * mass)
    c_rot = c.angular_damping if c.angular_damping is not None else 2 * zeta * math.sqrt(
        k_rot * i_mean
    )
    # past the hand's play the hand holds the part: as stiff as the scene's step allows
    # (never softer than the mass-based spring; a longer step lowers it, Simulation), damped
    # at HAND_DAMPING_RATIO about the weakest axis
    i_min = weakest_inertia(inertia)
    if c.angular_stiffness is None:
        k_hand = max(k_hand, hand_stiffness(inertia, 1.0 / config.simulation.rate_hz))
    c_hand = c.angular_damping if c.angular_damping is not None else (
        2 * HAND_DAMPING_RATIO * zeta * math.sqrt(k_hand * i_min))
    zb = config.simulation.body_damping_ratio
    body_c_lin = 2 * zb * math.sqrt(k_lin * mass)
    body_c_rot = 2 * zb * math.sqrt(k_rot * i_mean)
    if not effects.damping:
        c_lin = c_rot = c_hand = body_c_lin = body_c_rot = 0.0
    gravity = np.zeros(3) if effects.gravity is None else np.asarray(effects.gravity, float)
    check_range("part mass", mass, MASS_RANGE,
                "the coupling's gains m (2 pi f)^2 and their square roots overflow or vanish "
                "outside it (a density times the mesh's volume gives this mass)")
    physics = Physics(
        mass=mass,
        inertia=inertia,
        centre=center,
        length=length,
        k_lin=float(k_lin),
        c_lin=float(c_lin),
        k_rot=float(k_rot),
        c_rot=float(c_rot),
        body_c_lin=float(body_c_lin),
        body_c_rot=float(body_c_rot),
        kappa=float(kappa),
        gravity=gravity,
        k_rot_hard=float(k_hand) if k_hand > k_rot else 0.0,
        c_rot_hard=float(c_hand),
        rot_play=HAND_PLAY_RAD,
    )
    check_physics(physics, default_kappa)
    return physics


def coupling_choices(config: SimConfig, physics: Physics,
                     geometric_rotation: float | None) -> list[tuple[str, float, str]]:
    """``(key, value, reason)`` for the coupling's gains that the scene leaves open.

    What :func:`resolve_physics` made of ``config`` for a part (``physics``) and the fit's
    rotational stiffness per unit kappa measured at the seat (``geometric_rotation``), in
    the scene's force, torque and length units. A gain the scene's ``[coupling]`` sets is
    the scene's, and not listed.
    """
    c = config.coupling
    f = c.frequency_hz
    out: list[tuple[str, float, str]] = []
    if c.stiffness is None:
        out.append(("coupling.stiffness", physics.k_lin,
                    f"the part's mass {physics.mass:.4g} held at {f:g} Hz, m (2 pi f)^2: "
                    "the same motion in any unit"))
    if c.angular_stiffness is None:
        i_mean = float(np.trace(physics.inertia) / 3.0)
        mass_based = i_mean * (2 * math.pi * f) ** 2
        fit = None if geometric_rotation is None else physics.kappa * geometric_rotation
        if fit is not None and physics.k_rot < mass_based * (1 - 1e-9):
            floor = physics.k_rot <= MIN_ROTATION_FRACTION * mass_based * (1 + 1e-9)
            why = (f"the fit's rotational stiffness at the seat, {fit:.4g}, over "
                   f"{ROTATION_AUTHORITY:g}" + (f", raised to its floor ("
                                               f"{100 * MIN_ROTATION_FRACTION:g} % of the "
                                               "mass-based spring)" if floor else "")
                   + ": within the hand's play the fit turns the part into line")
        else:
            why = (f"the part's mean inertia at {f:g} Hz, I (2 pi f)^2"
                   + ("" if fit is None else f" (the fit, {fit:.4g} at the seat, is stiffer)"))
        out.append(("coupling.angular_stiffness", physics.k_rot, why))
        if physics.k_rot_hard > 0:
            out.append(("coupling.hand_stiffness", physics.k_rot_hard,
                        f"past {math.degrees(physics.rot_play):g} degrees from the hand in "
                        "the fit (from the first degree away from it), as stiff as a "
                        f"{1000.0 / config.simulation.rate_hz:g} ms step integrates about the "
                        "part's weakest axis: a torque on the way in cannot throw the part "
                        "over"))
    return out


def rigid_body(physics: Physics) -> RigidBody:
    """The moving part's constant properties."""
    return RigidBody(physics.mass, physics.inertia, physics.centre)


# ---------------------------------------------------------------------------------------------
# geometric fields of a scene


class SceneModel:
    """Builds the physics and geometric fields of a loaded scene (constant data, no state).

    The engine loop keeps one to rebuild them when the user changes effects, coupling, kappa
    or descriptor parameters.

    Parameters
    ----------
    handle : LoadedScene
    modes : int, optional
        K (default: the scene's ``[correlation] modes``).
    backend : str
        Per-pose backend for the correlator.
    """

    def __init__(self, handle: LoadedScene, *, modes: int | None = None,
                 backend: str = "auto"):
        self.handle = handle
        self.config = handle.config
        self.scene = handle.scene
        self.parts = tuple(handle.parts)
        self.moving = self.parts[1] if len(self.parts) > 1 else self.parts[0]
        self.has_pair = len(self.parts) > 1
        self.modes = int(modes or self.scene.modes)
        self.backend = backend
        self.start_pose = np.array(handle.start_pose, np.float64).reshape(6)
        self.assembled_pose = np.array(handle.scene.assembled_pose, np.float64).reshape(6)
        self._near: tuple[object, NearLevel | None] | None = None  # near_field's last level
        #: Rotational stiffness at the assembled pose, per unit kappa, of the field last
        #: built (None: no field, or rotation locked); sets the default rotational coupling.
        self.geometric_rotation: float | None = None
        #: The field :func:`build_simulation` built (``prepare=True``) and its descriptors.
        self.prepared: tuple[GeometricField, tuple[Descriptor, ...]] | None = None

    def physics(
        self, effects: Effects, coupling: CouplingParams | None = None, kappa: float | None = None
    ) -> Physics:
        """Physics constants for ``effects`` (and a changed coupling or kappa).

        The rotational coupling is scaled to the fit of the field last built.
        """
        config = self.config if coupling is None else replace(self.config, coupling=coupling)
        return resolve_physics(
            config, self.moving.vertices, self.moving.faces, effects=effects, kappa=kappa,
            geometric_rotation=self.geometric_rotation, measured=self._moving_mass,
        )

    @functools.cached_property
    def _fit(self) -> FitMeasure:
        """The pair's fit at its seat (``engine.sim.auto.measure_fit``), measured once.

        A new sigma or penalty builds the fine level again; on the boss with its pins the
        measure took 5.3 of the 8.5 s that a new penalty's level took.
        """
        from engine.sim.auto import measure_fit

        return measure_fit(self.parts[0], self.parts[1], self.assembled_pose,
                           self.scene.insertion_axis)

    @functools.cached_property
    def _moving_mass(self) -> tuple[float, np.ndarray, np.ndarray]:
        """The moving part's (mass, inertia, centre), measured once.

        A new K re-resolves the physics on the loop thread, where measuring the mesh cost a
        millisecond per thousand triangles.
        """
        return mass_properties(self.moving.vertices, self.moving.faces,
                               self.config.mass_spec(1), self.config.units)

    def descriptors(
        self,
        effects: Effects,
        *,
        descriptor: DescriptorParams | None = None,
        grid: int | None = None,
        progress: Callable[[float], None] | None = None,
        cancel: Callable[[], bool] | None = None,
    ) -> tuple[Descriptor, Descriptor]:
        """The two descriptors for ``effects.guidance`` (skeletal or collision-only).

        ``descriptor`` replaces the scene's ``[descriptor]`` whole (None: the scene's); it
        reaches the kernels as it is. ``grid`` replaces its sampling (samples along the
        largest part's longest side) for a coarse first field.
        """
        from engine.descriptor.collision import collision_descriptor
        from engine.descriptor.store import descriptors_for_scene

        scene = self._scene_with(descriptor, grid)
        # a new sigma inside the ladders' span, on the scene's grid: interpolated (seconds)
        descs = self._from_ladder(scene) if grid is None and descriptor is not None else None
        # the backend is the registry's choice for the descriptor (engine.backend.resolve:
        # an OpenCL device that cannot build its kernel is passed over there); an error
        # while computing is an error, not a reason to compute again elsewhere
        if descs is None:
            descs = descriptors_for_scene(
                scene, parts=list(self.parts), backend=None, progress=progress, cancel=cancel
            )
        d1, d2 = descs[0], descs[1]
        if effects.guidance == "collision":
            d1 = collision_descriptor(d1, self.parts[0])
            d2 = collision_descriptor(d2, self.parts[1])
        return d1, d2

    def _scene_with(self, descriptor: DescriptorParams | None, grid: int | None) -> Scene:
        d = self.scene.descriptor if descriptor is None else descriptor
        if grid is not None:
            d = replace(d, grid=int(grid), spacing=None, padding=self._padding_for(int(grid)))
        return self.scene if d is self.scene.descriptor else replace(self.scene, descriptor=d)

    def _padding_for(self, grid: int) -> float:
        """Padding in cells of a ``grid`` that reaches as far (in mm) as the scene's own.

        A field reaches no farther than its descriptors' padding: kept in cells, a coarse
        first field (cells 2.3 times larger on the peg in hole) pulled the peg down onto the
        block from 3 mm above it, where the scene's own field is still exactly zero.
        """
        from engine.descriptor import scene_spacing

        own = scene_spacing(self.scene, self.parts)
        coarse = scene_spacing(replace(self.scene, descriptor=replace(
            self.scene.descriptor, grid=grid, spacing=None)), self.parts)
        return float(self.scene.descriptor.padding) * own / coarse

    def _from_ladder(self, scene: Scene) -> list[Descriptor] | None:
        """The scene's descriptors from its sigma ladders (None: computed or loaded as usual).

        Only where the sigma is inside the span, both ladders are cached, and the direct
        descriptors are not (a cache hit is exact and as quick).
        """
        from engine.descriptor import ladder
        from engine.descriptor.store import descriptors_cached

        parts = list(self.parts)
        if (not ladder.in_span(scene.descriptor.sigma) or descriptors_cached(scene, parts)
                or not ladder.scene_ladder_cached(scene, parts)):
            return None
        try:
            return ladder.ladder_descriptors_for_scene(scene, parts)
        except ladder.LadderIncomplete:  # a node evicted since: computed as usual
            return None

    def ladder_ready(self, *, descriptor: DescriptorParams | None = None) -> bool:
        """Whether ``descriptor``'s sigma is served by the scene's cached sigma ladders."""
        from engine.descriptor import ladder

        scene = self._scene_with(descriptor, None)
        return (ladder.in_span(scene.descriptor.sigma)
                and ladder.scene_ladder_cached(scene, list(self.parts)))

    def prepare_ladder(self, *, progress: Callable[[float], None] | None = None,
                       cancel: Callable[[], bool] | None = None) -> None:
        """The nodes missing from the sigma ladders (a low-priority job): scene, then level."""
        from engine.sim.fine import prepare_ladders

        fit = self._fit if self.has_pair and self.scene.assembled_known else None
        prepare_ladders(self.scene, list(self.parts), self.assembled_pose, fit,
                        progress=progress, cancel=cancel)

    def descriptors_cached(self, *, descriptor: DescriptorParams | None = None) -> bool:
        """Whether the scene's descriptors (at its own grid) are in the cache already."""
        from engine.descriptor.store import descriptors_cached

        return descriptors_cached(self._scene_with(descriptor, None), list(self.parts))

    def near_field(self, effects: Effects, descriptors: Sequence[Descriptor], *,
                   progress: Callable[[float], None] | None = None,
                   cancel: Callable[[], bool] | None = None) -> NearField | None:
        """The fine level over the fit (:mod:`engine.sim.fine`), or None.

        None where guidance is not skeletal, the scene has one part, the descriptors are
        not the pair's, or the parts do not meet at the assembled pose.
        """
        if effects.guidance != "skeletal" or not self.has_pair or len(descriptors) < 2:
            return None
        from engine.correlation.near import NearField
        from engine.sim.fine import build_level

        d1, d2 = descriptors[0], descriptors[1]
        key = (d1.params, d1.grid, d2.params, d2.grid)
        if self._near is None or self._near[0] != key:  # a new K keeps the level
            level = build_level(self.parts[0], self.parts[1], d1, d2, self.assembled_pose,
                                self.scene.insertion_axis, fit=self._fit, progress=progress,
                                cancel=cancel)
            self._near = (key, level)
        level = self._near[1]
        return None if level is None else NearField(level)

    def descriptors_of(self, fld: GeometricField) -> tuple[Descriptor, ...]:
        """The descriptors of ``fld`` if :func:`build_simulation` built it here, else ().

        A loop that starts with that field reuses them for a new K.
        """
        if self.prepared is not None and self.prepared[0] is fld:
            return self.prepared[1]
        return ()

    def first_grid(self, effects: Effects, *,
                   descriptor: DescriptorParams | None = None) -> int | None:
        """The grid of a scene's first field (None: the scene's own, at once).

        :data:`COARSE_GRID` while the scene's own descriptors are finer, not cached, and not
        served by the sigma ladders either.
        """
        d = self.scene.descriptor
        finer = d.spacing is not None or d.grid is None or d.grid > COARSE_GRID
        if effects.guidance == "none" or not self.has_pair or not finer:
            return None
        if self.descriptors_cached(descriptor=descriptor):
            return None
        return None if self.ladder_ready(descriptor=descriptor) else COARSE_GRID

    def check_memory(self) -> None:
        """Refuse a scene whose correlation FFT would not fit (ResourceError), before work.

        The grids of both parts and the FFT size follow from the part sizes alone
        (``grid_for_part`` itself refuses a descriptor grid that does not fit).
        """
        from engine.correlation.correlator import required_fft_size
        from engine.descriptor import grid_for_part, scene_spacing
        from engine.grid import check_fft_memory

        spacing = scene_spacing(self.scene, self.parts)
        shapes = [grid_for_part(p, spacing=spacing, padding=self.scene.descriptor.padding).shape
                  for p in self.parts[:2]]
        size = required_fft_size(shapes[0], shapes[-1])
        check_fft_memory(size, 2 + 4, f"the correlation's {size}^3 FFT")

    def field(
        self,
        effects: Effects,
        kappa: float,
        locked_rotation: np.ndarray,
        *,
        descriptor: DescriptorParams | None = None,
        modes: int | None = None,
        grid: int | None = None,
        progress: Callable[[float], None] | None = None,
        cancel: Callable[[], bool] | None = None,
    ) -> tuple[GeometricField, tuple[Descriptor, ...]]:
        """(field, descriptors) for ``effects``; nothing is built that effects switch off.

        Only reads the model (the runtime's worker calls it while the loop resolves physics
        from :attr:`geometric_rotation`): the field's stiffness is the caller's to measure
        (:func:`rotational_stiffness`) and to put in use.

        Parameters
        ----------
        effects : Effects
        kappa : float
        locked_rotation : (3, 3) float64
            The part's rotation, used when the effects lock rotation.
        descriptor : DescriptorParams, optional
            Replacing the scene's ``[descriptor]`` whole (as the window's panel built it).
        modes : int, optional
            K (default: this model's).
        grid : int, optional
            Samples along the largest part's longest side, replacing the scene's (a coarse
            first field while the scene's own is computed).
        progress, cancel : callable, optional
            Fraction done 0..1; True to stop (raises ``engine.errors.Cancelled``).
        """
        if effects.guidance == "none" or not self.has_pair:
            return NullField(), ()
        from engine.correlation import Correlator

        def stage(lo: float, hi: float) -> Callable[[float], None] | None:
            if progress is None:
                return None
            return lambda f: progress(lo + (hi - lo) * float(f))

        self.check_memory()  # before minutes of descriptors, not at the FFT after them
        d1, d2 = self.descriptors(
            effects, descriptor=descriptor, grid=grid, progress=stage(0.0, 0.9),
            cancel=cancel
        )
        if cancel is not None and cancel():
            raise Cancelled("recompute cancelled")
        k = int(modes or self.modes)

        def make(rotation: bool) -> Correlator:
            return Correlator(d1, d2, modes=k, rotation=rotation, backend=self.backend,
                              kappa=1.0, band=engine.params.GUIDANCE_BAND)

        field = field_for_effects(effects, make, kappa=kappa, locked_rotation=locked_rotation)
        if progress is not None:
            progress(1.0)
        return field, (d1, d2)


def build_simulation(
    handle: LoadedScene,
    *,
    modes: int | None = None,
    backend: str = "auto",
    rate_hz: float | None = None,
    prepare: bool = True,
    coupled: bool = True,
    fine: bool = True,
) -> tuple[Simulation, SceneModel]:
    """The simulation of a loaded scene, and the model that rebuilds its parts.

    Parameters
    ----------
    handle : LoadedScene
        The scene, its validated settings, the part meshes and the start pose.
    modes : int, optional
        K (default: the scene's).
    backend : str
        Per-pose evaluator of the correlator.
    rate_hz : float, optional
        Overrides ``[simulation] rate_hz``: the simulation's time step is ``1 / rate_hz``
        and stays so through every later change of physics, effects or field.
    prepare : bool
        True: the descriptors and correlator are built now (blocking). False: the field
        starts as :class:`NullField`; build it later with ``model.field(...)`` (the engine
        loop does so in its worker) and hand it over with ``sim.set_field``.
    coupled : bool
        False: no proxy and no coupling (a free part, for energy checks).
    fine : bool
        With ``prepare``, add the fine level where the parts meet
        (:meth:`SceneModel.near_field`).

    Returns
    -------
    (Simulation, SceneModel)
    """
    model = SceneModel(handle, modes=modes, backend=backend)
    effects = handle.config.effects
    physics = model.physics(effects)
    rate = handle.config.simulation.rate_hz if rate_hz is None else float(rate_hz)
    field: GeometricField = NullField()
    if prepare:
        field, descriptors = model.field(effects, physics.kappa,
                                         rotation_matrix(model.start_pose[3:]))
        model.prepared = (field, descriptors)
        model.geometric_rotation = rotational_stiffness(field, model.assembled_pose)
        physics = model.physics(effects)  # the rotational coupling scaled to the fit
    limits = HapticLimits.from_device(handle.config.device)
    follow = fit_hold(handle)  # its rest point is hold_point's, found once
    sim = Simulation(rigid_body(physics), physics, effects, field, model.start_pose,
                     dt=1.0 / rate, limits=limits, coupled=coupled,
                     hold=hold_point(handle) if follow is None else follow.rest,
                     follow=follow)
    if prepare and fine and model.prepared is not None:
        sim.set_near(model.near_field(effects, model.prepared[1]))
    return sim, model
