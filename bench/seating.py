"""`skelasm bench seating`: whether each real pair seats from a misaimed push.

For each pair of the real-fit suite (``assets/real/*/scene.toml``): the proxy is aimed 3 %
of the moving part's width sideways and tilted 3 degrees, then pushed along the insertion
axis to the assembled depth in 2 s and held (5 simulated seconds in all by default, ended
early once the part is at rest: :class:`RestWatch`), the simulation stepped headless at
the scene's rate. The final pose is compared with the
assembled pose in the axes the fit constrains (:data:`FITS`: a through hole leaves the
translation along its axis free, a round fit the rotation about it): the position error in
% of the moving part's width along the aim's direction, and the tilt in degrees. Guided
(skeletal) beside collision-only. Prints a markdown table, writes a PNG (both errors per
pair, guided and collision-only) and shows progress with the time left on a terminal.

Seated means within :data:`SEAT_FRACTION` of the width and :data:`SEAT_DEGREES` of tilt.

``--generated N --seed S`` runs the same protocol on N unseen pairs made by the fit
generator (:mod:`bench.fitgen`, docs/generated_fits.md), each a scene made only by ``scene
new``: the misaim tilts the part about its fit centre, errors are measured there, the free
directions are the fit's own vectors, and the tolerances widen to the fit's radial and
angular play where those are larger. Every run also records, at every step, the angle
between the part's orientation and the proxy's, and is *tipped* when it exceeds the fit's
angular play plus the misaim. Prints a table per family and overall, and a table of the runs.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "assets" / "real"

#: Seated: constrained position error within this fraction of the width ...
SEAT_FRACTION = 0.02
#: ... and constrained tilt within this many degrees.
SEAT_DEGREES = 0.5
#: The misaim: sideways offset (fraction of the width) and tilt (degrees) of the proxy.
OFFSET_FRACTION, TILT_DEGREES = 0.03, 3.0
#: The push to the assembled depth takes this long (s); the rest of the run holds it there.
PUSH_SECONDS = 2.0
#: A run ends once the part is at rest after the push (:class:`RestWatch`): its mean pose
#: over the last :data:`REST_WINDOW` tenths of a second, against the mean over the tenths
#: before them, drifts so slowly that at that rate it would move less than
#: :data:`REST_FRACTION` of the seat's tolerances in the run's time left ...
REST_FRACTION = 0.05
REST_WINDOW = 3
#: ... while it trembles about that mean by less than the tolerances themselves (some seated
#: parts tremble by a few tenths of a degree from step to step, docs/fine_level.md) ...
REST_TREMBLE = 1.0
#: ... for this many tenths in a row.
REST_CHUNKS = 3

_AXES = ("tx", "ty", "tz", "rx", "ry", "rz")


@dataclass(frozen=True)
class Fit:
    """What a pair's fit leaves free, in part 1's frame.

    Attributes
    ----------
    free : tuple of str
        Free axes among ``tx ty tz rx ry rz``.
    lateral : (3,) tuple or None
        Direction the proxy is aimed off (None: the protocol's default, the insertion axis
        crossed with the coordinate axis least aligned with it).
    misfit : (6,) tuple
        A small misalignment from the assembled pose that makes the parts interpenetrate
        (used by the tests: beyond the clearance in a constrained axis).
    """

    free: tuple[str, ...]
    lateral: tuple[float, float, float] | None = None
    misfit: tuple[float, ...] = (0.1, 0.0, 0.0, 0.0, 0.0, 0.0)


#: The fits of the suite, by folder of assets/real.
FITS: dict[str, Fit] = {
    "iso_pin_5_H7h6_through": Fit(("tz", "rz")),
    "iso_shaft_20_H7g6_blind": Fit(("rz",)),
    "iso_spigot_50_H7h6": Fit(("rz",)),
    "iso_sleeve_30_H7g6_thinwall": Fit(("tz", "rz")),
    "keyed_hub_20": Fit(()),
    "spline_6x23x26": Fit(("tz",)),
    "rect_peg_10x16_H7g6": Fit(()),
    "dovetail_60_slide": Fit(("ty",), lateral=(1.0, 0.0, 0.0)),
    "factory_round_peg_8mm_loose": Fit(("tz", "rz")),
    "factory_round_peg_16mm_tight": Fit(("tz", "rz"), misfit=(0.3, 0, 0, 0, 0, 0)),
    "factory_rect_peg_8mm_loose": Fit(("tz",), misfit=(0.15, 0, 0, 0, 0, 0)),
    "factory_rect_peg_12mm_tight": Fit(("tz",), misfit=(0.15, 0, 0, 0, 0, 0)),
}


@dataclass(frozen=True)
class SeatingResult:
    """One run's outcome; lengths in the scene's unit, angles in degrees."""

    pair: str
    guidance: str
    width: float            # moving part's extent along the aim's direction
    position_error: float   # norm over the constrained translation axes
    lateral_error: float    # its part across the insertion axis
    axial_error: float      # signed, along the insertion axis (0 when that axis is free)
    tilt_deg: float         # rotation error in the constrained rotation axes
    final_pose: tuple[float, ...]
    modes: int
    seconds: float          # simulated
    wall_seconds: float
    family: str = ""        # a generated pair's family ("" for the real suite)
    position_tolerance: float | None = None  # None: SEAT_FRACTION of the width
    angle_tolerance_deg: float = SEAT_DEGREES
    max_proxy_angle_deg: float = math.nan    # largest part-to-proxy angle over the run
    tip_limit_deg: float = TILT_DEGREES      # beyond it the run tipped
    setup_seconds: float = 0.0               # wall: loading, descriptors, fields
    cpu_seconds: float = math.nan            # the push's CPU time, every thread of the process

    @property
    def position_percent(self) -> float:
        """Position error in % of the width."""
        return 100.0 * self.position_error / self.width

    @property
    def seated(self) -> bool:
        """Within the position and angle tolerances.

        :data:`SEAT_FRACTION` of the width, or the fit's radial play where larger;
        :data:`SEAT_DEGREES`, or the fit's angular play where larger.
        """
        tol = (SEAT_FRACTION * self.width if self.position_tolerance is None
               else self.position_tolerance)
        return self.position_error <= tol and self.tilt_deg <= self.angle_tolerance_deg

    @property
    def tipped(self) -> bool:
        """The part turned further from the proxy than the fit's play plus the misaim.

        Further than the simulation's wrist allows at that limit, which stops a part a
        millionth of its play past it (``engine.sim.simulation.STOP_PAST_PLAY``): a real
        pair (no play) held at the stop turned 3.000003 degrees, not past the misaim.
        """
        from engine.sim.simulation import STOP_PAST_PLAY

        return self.max_proxy_angle_deg > self.tip_limit_deg * (1.0 + 2 * STOP_PAST_PLAY)


@dataclass(frozen=True)
class SeatingCase:
    """One pair to push, and what its fit leaves free (part 1's frame, the scene's unit).

    Attributes
    ----------
    name : str
        The pair's name in the tables.
    scene : Path
    free_translations, free_rotations : tuple of (3,) tuple
        Unit vectors of the free directions.
    lateral : (3,) tuple or None
        The misaim's sideways direction (None: the protocol's default).
    family : str
    width : float or None
        Part 2's width along ``lateral`` (None: measured from its mesh).
    radial_play, angular_play_deg : float
        The fit's plays: the tolerances widen to them, the tip limit adds the angular one.
    centre : (3,) tuple or None
        Part 2's fit centre in its own frame: the misaim turns about it and the position
        error is measured there. None: part 2's file origin (the real suite's parts have it
        on the fit's axis).
    """

    name: str
    scene: Path
    free_translations: tuple[tuple[float, float, float], ...] = ()
    free_rotations: tuple[tuple[float, float, float], ...] = ()
    lateral: tuple[float, float, float] | None = None
    family: str = ""
    width: float | None = None
    radial_play: float = 0.0
    angular_play_deg: float = 0.0
    centre: tuple[float, float, float] | None = None


def real_case(name: str) -> SeatingCase:
    """The case of a pair of assets/real (its free axes from :data:`FITS`)."""
    fit = FITS[name]
    eye = np.eye(3)
    return SeatingCase(
        name=name, scene=REAL / name / "scene.toml",
        free_translations=tuple(tuple(eye[i]) for i, a in enumerate(_AXES[:3])
                                if a in fit.free),
        free_rotations=tuple(tuple(eye[i]) for i, a in enumerate(_AXES[3:]) if a in fit.free),
        lateral=fit.lateral)


def generated_case(pair) -> SeatingCase:
    """The case of a generated pair (a :class:`bench.fitgen.GeneratedPair`)."""
    t = pair.truth
    return SeatingCase(
        name=pair.folder.name, scene=pair.scene, free_translations=t.free_translations,
        free_rotations=t.free_rotations, lateral=t.lateral, family=t.family, width=t.width,
        radial_play=t.radial_play, angular_play_deg=t.angular_play_deg, centre=t.centre)


def pair_names() -> list[str]:
    """Folders of assets/real that hold a scene, sorted."""
    return sorted(p.parent.name for p in REAL.glob("*/scene.toml"))


def misaim(axis: np.ndarray, lateral: np.ndarray | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """(lateral, tilt_axis) unit vectors of the protocol for an insertion ``axis`` (3,)."""
    axis = axis / np.linalg.norm(axis)
    if lateral is None:
        helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
        lateral = np.cross(axis, helper)
    lateral = np.asarray(lateral, float)
    lateral = lateral / np.linalg.norm(lateral)
    tilt_axis = np.cross(axis, lateral)
    return lateral, tilt_axis / np.linalg.norm(tilt_axis)


def free_direction_errors(displacement: np.ndarray, rotation: np.ndarray, axis: np.ndarray,
                          free_translations=(), free_rotations=()
                          ) -> tuple[float, float, float, float]:
    """(position, lateral, axial, tilt_deg) of a pose error, free directions taken out.

    Parameters
    ----------
    displacement : (3,) float
        How far the measured point of part 2 is from its seated place (part 1's frame).
    rotation : (3, 3) float
        The rotation from the seated orientation to the current one (part 1's frame).
    axis : (3,) float
        The insertion axis.
    free_translations, free_rotations : sequence of (3,) float
        Directions the fit leaves free (any length, need not be orthogonal).

    Returns
    -------
    position : float
        The displacement less its part in the span of the free translations.
    lateral, axial : float
        That remainder across the insertion axis, and along it (signed).
    tilt_deg : float
        With no free rotation, the whole rotation's angle; with one free axis ``a``, the
        angle ``a`` has turned (its spin about itself is free); with two, the turn about the
        third axis (their cross product; twist of a swing-twist split); with three, 0.
    """
    from scipy.spatial.transform import Rotation

    t = np.asarray(displacement, float).reshape(3).copy()
    free_t = np.asarray(free_translations, float).reshape(-1, 3)
    if len(free_t):
        basis = np.linalg.svd(free_t, full_matrices=False)[2]  # (r, 3) orthonormal rows
        basis = basis[: np.linalg.matrix_rank(free_t)]
        t -= basis.T @ (basis @ t)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    axial = float(t @ axis)
    lateral = float(np.linalg.norm(t - axial * axis))
    rot = np.asarray(rotation, float).reshape(3, 3)
    free_r = np.asarray(free_rotations, float).reshape(-1, 3)
    rank = np.linalg.matrix_rank(free_r) if len(free_r) else 0
    if rank == 0:
        tilt = float(np.linalg.norm(Rotation.from_matrix(rot).as_rotvec()))
    elif rank == 1:
        a = free_r[0] / np.linalg.norm(free_r[0])
        tilt = float(np.arccos(np.clip((rot @ a) @ a, -1.0, 1.0)))
    elif rank == 2:
        n = np.cross(free_r[0], free_r[1])
        if np.linalg.norm(n) < 1e-12:
            n = np.cross(free_r[0], free_r[2])
        n /= np.linalg.norm(n)
        x, y, z, w = Rotation.from_matrix(rot).as_quat()
        tilt = float(2.0 * math.atan2(abs(np.dot((x, y, z), n)), abs(w)))
    else:
        tilt = 0.0
    return float(np.linalg.norm(t)), lateral, axial, math.degrees(tilt)


def constrained_errors(error: np.ndarray, axis: np.ndarray, free: tuple[str, ...]
                       ) -> tuple[float, float, float, float]:
    """(position, lateral, axial, tilt_deg) of a pose error (6,) in the target's frame.

    ``free`` names the free axes (``tx ty tz rx ry rz``): :func:`free_direction_errors` with
    the coordinate axes they name. Free translation axes are dropped from the position error.
    The tilt is the whole rotation angle when no rotation is free, the angle the part's free
    rotation axis has turned when one is, and 0 when all are.
    """
    from scipy.spatial.transform import Rotation

    eye = np.eye(3)
    return free_direction_errors(
        np.asarray(error[:3], float), Rotation.from_rotvec(np.asarray(error[3:], float))
        .as_matrix(), axis, [eye[i] for i, n in enumerate(_AXES[:3]) if n in free],
        [eye[i] for i, n in enumerate(_AXES[3:]) if n in free])


def proxy_angles(part_poses: np.ndarray, proxy_poses: np.ndarray) -> np.ndarray:
    """(k,) degrees between the part's orientation and the proxy's, poses (k, 6)."""
    from scipy.spatial.transform import Rotation

    part = Rotation.from_rotvec(np.asarray(part_poses, float).reshape(-1, 6)[:, 3:])
    proxy = Rotation.from_rotvec(np.asarray(proxy_poses, float).reshape(-1, 6)[:, 3:])
    return np.degrees((part.inv() * proxy).magnitude())


def misaimed_push(start: np.ndarray, target: np.ndarray, axis: np.ndarray,
                  lateral: np.ndarray, tilt_axis: np.ndarray, width: float,
                  centre: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) poses (6,) of the protocol's proxy, part 1's frame.

    From ``start`` (where the scene puts part 2), :data:`OFFSET_FRACTION` of ``width`` along
    ``lateral`` and :data:`TILT_DEGREES` about ``tilt_axis``; the end is that pose moved
    along the unit ``axis`` to the depth of ``target`` (the assembled pose). With ``centre``
    (3,) (part 2's fit centre in its own frame) the tilt turns about it and the centre is
    what reaches the depth; without, both use part 2's file origin (the real suite's parts
    have it on the fit's axis).
    """
    from engine.pose import pose_to_matrix, rotate_about

    start = np.array(start, float)
    start[:3] += OFFSET_FRACTION * width * np.asarray(lateral, float)
    tilt = math.radians(TILT_DEGREES) * np.asarray(tilt_axis, float)
    if centre is None:
        start[3:] += tilt
        end_shift = np.asarray(target[:3], float) - start[:3]
    else:
        c = np.asarray(centre, float)
        m = pose_to_matrix(start)
        start = rotate_about(start, tilt, m[:3, :3] @ c + m[:3, 3])
        now, seat = pose_to_matrix(start), pose_to_matrix(target)
        end_shift = (seat[:3, :3] @ c + seat[:3, 3]) - (now[:3, :3] @ c + now[:3, 3])
    end = start.copy()
    end[:3] += axis * float(end_shift @ axis)
    return start, end


def seating_run(pair: str | SeatingCase, guidance: str = "skeletal", *, seconds: float = 5.0,
                modes: int | None = None, backend: str = "auto",
                progress=None, until_rest: bool = True) -> SeatingResult:
    """Run the misaim protocol on one pair (see the module docstring).

    ``pair`` is a folder of assets/real or a :class:`SeatingCase`. ``progress(fraction)`` is
    called as the simulation advances. ``until_rest``: end the run once the part is at rest
    after the push (:class:`RestWatch`; ``seconds`` of the result says when), else run all
    of ``seconds``.
    """
    from engine.devices import TrajectoryDevice
    from engine.pose import pose_to_matrix, relative_pose
    from engine.runtime import EngineLoop, open_scene
    from engine.sim import build_simulation

    case = real_case(pair) if isinstance(pair, str) else pair
    t_setup = time.perf_counter()
    handle = open_scene(case.scene)
    cfg = handle.config
    handle = replace(handle, config=replace(cfg, effects=replace(cfg.effects,
                                                                 guidance=guidance)))
    axis = np.array(handle.scene.insertion_axis, float)
    axis /= np.linalg.norm(axis)
    lateral, tilt_axis = misaim(axis, None if case.lateral is None else np.array(case.lateral))
    target = np.array(handle.assembled_pose, float)
    seat = pose_to_matrix(target)
    if case.width is None:  # part 2's extent along the aim, seated
        width = float(np.ptp(handle.parts[1].vertices @ (seat[:3, :3].T @ lateral)))
    else:
        width = float(case.width)
    start, end = misaimed_push(np.array(handle.start_pose, float), target, axis, lateral,
                               tilt_axis, width, case.centre)
    handle = replace(handle, start_pose=start)
    k = int(modes if modes is not None else handle.scene.modes)
    sim, model = build_simulation(handle, prepare=True, backend=backend, modes=k)
    device = TrajectoryDevice(np.array([[0.0, *start], [PUSH_SECONDS, *end]]))
    total = int(round(seconds / sim.dt))
    chunk = max(1, int(round(0.1 / sim.dt)))
    # every step's frame stays in the ring until read: the part-to-proxy angle at each step
    loop = EngineLoop(sim, model=model, device=device, realtime=False, frame_queue=chunk + 16)
    worst = 0.0
    rest = RestWatch(max(SEAT_FRACTION * width, case.radial_play),
                     max(SEAT_DEGREES, case.angular_play_deg), sim.dt, case.centre)

    def turns(frames) -> None:
        nonlocal worst
        angles = proxy_angles(np.array([f.part_pose for f in frames]),
                              np.array([f.proxy_pose for f in frames]))
        worst = max(worst, float(angles.max()))

    t0, cpu0 = time.perf_counter(), time.process_time()
    setup = t0 - t_setup
    done = push_until_rest(loop, total, PUSH_SECONDS, rest if until_rest else None,
                           each=turns, progress=progress)
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    final = np.asarray(sim.part_pose(), float)
    if case.centre is None:  # at part 2's origin, in the seat's frame (constrained_errors)
        error = relative_pose(target, final)
        position, lat, axial, tilt_deg = free_direction_errors(
            error[:3], pose_to_matrix(error)[:3, :3], axis, case.free_translations,
            case.free_rotations)
    else:
        c = np.asarray(case.centre, float)
        now = pose_to_matrix(final)
        moved = (now[:3, :3] @ c + now[:3, 3]) - (seat[:3, :3] @ c + seat[:3, 3])
        position, lat, axial, tilt_deg = free_direction_errors(
            moved, now[:3, :3] @ seat[:3, :3].T, axis, case.free_translations,
            case.free_rotations)
    return SeatingResult(pair=case.name, guidance=guidance, width=width,
                         position_error=position, lateral_error=lat, axial_error=axial,
                         tilt_deg=tilt_deg, final_pose=tuple(float(x) for x in final),
                         modes=k, seconds=done * sim.dt, wall_seconds=wall, family=case.family,
                         position_tolerance=max(SEAT_FRACTION * width, case.radial_play),
                         angle_tolerance_deg=max(SEAT_DEGREES, case.angular_play_deg),
                         max_proxy_angle_deg=worst,
                         tip_limit_deg=case.angular_play_deg + TILT_DEGREES,
                         setup_seconds=setup, cpu_seconds=cpu)


def push_until_rest(loop: Any, total: int, push_seconds: float, rest: RestWatch | None, *,
                    each=None, progress=None) -> int:
    """Step ``loop`` (an unpaced ``EngineLoop``) a tenth of a second at a time; steps run.

    Up to ``total`` steps, or until ``rest`` says the part is at rest after the first
    ``push_seconds`` (None: all of them). The loop's frame queue must hold a tenth of a
    second of frames. ``each(frames)`` sees every stretch's frames; ``progress(fraction)``
    is called after each.
    """
    dt = loop.sim.dt
    chunk = max(1, int(round(0.1 / dt)))
    done = 0
    while done < total:
        done += loop.run(max_steps=min(chunk, total - done))
        frames = loop.poll_frames()
        if frames:
            if each is not None:
                each(frames)
            if (rest is not None and rest.add(np.array([f.part_pose for f in frames]),
                                              (total - done) * dt)
                    and done * dt >= push_seconds):
                break
        loop.poll_events()
        if progress is not None:
            progress(done / total)
    return done


class RestWatch:
    """Says when a run's part is at rest: it may end there with the same result.

    Fed the poses of each stretch of steps of ``dt`` (s), it keeps each stretch's mean
    position of the fit's centre (``centre`` in the part's frame; None: its origin) and mean
    orientation. At rest after :data:`REST_CHUNKS` stretches in a row in which the mean of
    the last :data:`REST_WINDOW` stretches has drifted from the mean of the ones before so
    little that at that rate, for the time left, it would move by less than
    :data:`REST_FRACTION` of the seat's tolerances ``length`` and ``degrees``, and the part
    trembled about its stretch's mean by less than :data:`REST_TREMBLE` of them. A part
    coming to rest slows down, so its mean pose at the end lies within that fraction of the
    tolerances of the one where the run stops; a trembling part's pose at any one step is a
    draw from its tremble, at the stop as at the end. A part still creeping (pressed along a
    free axis, sliding off a ledge) keeps the run going.
    """

    def __init__(self, length: float, degrees: float, dt: float, centre=None):
        self.length, self.degrees, self.dt = float(length), float(degrees), float(dt)
        self.centre = None if centre is None else np.asarray(centre, float)
        self._means: list[tuple[np.ndarray, Any, int]] = []  # (point, turn, steps) per stretch
        self.still = 0
        #: The last stretch's drift and tremble, position then tilt, each in what it may be.
        self.measures = (math.inf,) * 4

    def add(self, poses: np.ndarray, left: float) -> bool:
        """True once at rest: ``poses`` (n, 6) of one stretch of the run, ``left`` (s) to run."""
        from scipy.spatial.transform import Rotation

        poses = np.asarray(poses, float).reshape(-1, 6)
        turns = Rotation.from_rotvec(poses[:, 3:])
        points = poses[:, :3] if self.centre is None else poses[:, :3] + turns.apply(self.centre)
        point, turn = points.mean(axis=0), turns.mean()
        tremble = float(np.max(np.linalg.norm(points - point, axis=1)))
        tremble_deg = float(np.degrees(np.max((turns * turn.inv()).magnitude())))
        self._means = (self._means + [(point, turn, len(poses))])[-2 * REST_WINDOW:]
        if len(self._means) < 2 * REST_WINDOW:
            return False
        late, early = self._means[REST_WINDOW:], self._means[:REST_WINDOW]
        span = sum(m[2] for m in late) * self.dt  # the windows' means lie this far apart
        drift = float(np.linalg.norm(_mean_point(late) - _mean_point(early)))
        drift_deg = float(np.degrees((_mean_turn(late) * _mean_turn(early).inv()).magnitude()))
        scale = left / span  # at that rate, for the time left
        length, degrees = self.length, self.degrees
        self.measures = (drift * scale / (REST_FRACTION * length),
                         tremble / (REST_TREMBLE * length),
                         drift_deg * scale / (REST_FRACTION * degrees),
                         tremble_deg / (REST_TREMBLE * degrees))
        self.still = self.still + 1 if max(self.measures) <= 1.0 else 0
        return self.still >= REST_CHUNKS


def _mean_point(means: list) -> np.ndarray:
    return np.mean([m[0] for m in means], axis=0)


def _mean_turn(means: list) -> Any:
    from scipy.spatial.transform import Rotation

    return Rotation.concatenate([m[1] for m in means]).mean()


# ---------------------------------------------------------------------------- command
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``skelasm bench seating``."""
    from engine.backend import choices

    parser.add_argument("--pairs", nargs="*", default=None, metavar="NAME",
                        help="folders of assets/real (default: every pair); with "
                        "--generated, the generated pairs whose folder names contain one "
                        "(such as 002_round_blind or 002)")
    parser.add_argument("--guidance", choices=("skeletal", "collision", "both"),
                        default="both", help="guided, collision-only, or both (default)")
    parser.add_argument("--seconds", type=float, default=5.0,
                        help="simulated seconds per run (the push takes the first 2)")
    parser.add_argument("--full", action="store_true",
                        help="run all the seconds, also after the part has come to rest "
                        "(by default a run ends there: its mean pose would move by less "
                        "than 5 %% of the seat's tolerances)")
    parser.add_argument("--modes", type=int, default=None,
                        help="modes per axis K (default: each scene's)")
    parser.add_argument("--backend", default="auto", choices=choices("per_pose"),
                        help="per-pose backend (auto: the registry's first that works here)")
    parser.add_argument("-o", "--output", default="bench_seating.png", help="plot (PNG)")
    parser.add_argument("--generated", type=int, default=None, metavar="N",
                        help="instead of assets/real: N unseen pairs from the fit generator "
                        "(needs gmsh: pip install -e \".[assets]\"), cycling through its "
                        "families, each made a scene by `scene new` alone")
    parser.add_argument("--seed", type=int, default=None, metavar="S",
                        help="with --generated: the seed that draws the set (default: a new "
                        "one, printed)")
    parser.add_argument("--keep", default=None, metavar="DIR",
                        help="with --generated: write the pairs into DIR and keep them "
                        "(default: a temporary folder; a DIR holding this seed and count "
                        "already is reused)")
    parser.add_argument("--workers", type=int, default=1,
                        help="runs at once, each in its own process (default 1)")
    parser.add_argument("--band", choices=("smooth", "box"), default=None,
                        help="the guidance's band: smooth (a ball of modes, Lanczos-tapered, "
                        "each descriptor's tail ended at one distance from its part, the fine "
                        "level's window a cylinder about the insertion axis) or box (a cube "
                        "band, tails cut by the grids, a box window) (default: the engine's, "
                        "smooth; docs/fine_level.md)")


def use_band(band: str | None) -> None:
    """The guidance band a run asked for: here, and in each pool process as it starts."""
    if band is None:
        return
    import engine.params
    from engine.sim import fine

    engine.params.GUIDANCE_BAND = band
    fine.WINDOW_SHAPE = "cylinder" if band == "smooth" else "box"


class _Progress:
    """One line on a terminal: run i of n, its fraction, and the time left (estimated)."""

    def __init__(self, runs: int, stream=sys.stderr):
        self.runs, self.stream = runs, stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.start = time.perf_counter()
        self.index, self.label = 0, ""

    def begin(self, index: int, label: str) -> None:
        self.index, self.label = index, label
        self(0.0)

    def __call__(self, fraction: float) -> None:
        if not self.tty:
            return
        done = self.index + fraction
        elapsed = time.perf_counter() - self.start
        left = elapsed / done * (self.runs - done) if done > 0 else float("nan")
        text = "?" if math.isnan(left) else f"{left:4.0f} s"
        self.stream.write(f"\r[{self.index + 1}/{self.runs}] {self.label:<45} "
                          f"{100 * fraction:3.0f} %  time left {text}   ")
        self.stream.flush()

    def finished(self, count: int, label: str) -> None:
        """``count`` runs are done (runs finishing out of order, in a pool)."""
        self.begin(count - 1, label)
        self(1.0)

    def end(self) -> None:
        if self.tty:
            self.stream.write("\r" + " " * 90 + "\r")
            self.stream.flush()


def run(args: argparse.Namespace) -> int:
    """Run the benchmark: table on stdout, plot to ``args.output``."""
    # here; a pool's processes switch them on as they start
    use_band(getattr(args, "band", None))
    if getattr(args, "generated", None) is not None:
        return run_generated(args)
    names = args.pairs or pair_names()
    unknown = [n for n in names if n not in FITS]
    if unknown:
        print(f"unknown pair(s) {', '.join(unknown)}; choose from {', '.join(FITS)}",
              file=sys.stderr)
        return 2
    guidances = ("skeletal", "collision") if args.guidance == "both" else (args.guidance,)
    jobs = [(n, g) for n in names for g in guidances]
    bar = _Progress(len(jobs))
    results: list[SeatingResult] = []
    for i, (name, guidance) in enumerate(jobs):
        bar.begin(i, f"{name} ({guidance})")
        r = seating_run(name, guidance, seconds=args.seconds, modes=args.modes,
                        backend=args.backend, progress=bar, until_rest=not args.full)
        results.append(r)
        bar.end()
        print(f"{name} ({guidance}): position {r.position_percent:.2f} % of the width, tilt "
              f"{r.tilt_deg:.2f} deg, {'seated' if r.seated else 'not seated'} "
              f"({r.wall_seconds:.0f} s{_rested(r, args.seconds)})", file=sys.stderr,
              flush=True)
    print(table(results))
    _plot(results, args.output)
    print(f"\nplot: {args.output}")
    return 0


def table(results: list[SeatingResult]) -> str:
    """Markdown table of the runs."""
    lines = [f"Misaim {100 * OFFSET_FRACTION:g} % of the width sideways and "
             f"{TILT_DEGREES:g} degrees; seated: within {100 * SEAT_FRACTION:g} % and "
             f"{SEAT_DEGREES:g} degrees in the constrained axes.", "",
             "| pair | free | guidance | K | width | position error (% width) | lateral | "
             "axial | tilt (deg) | seated | wall s | push CPU s | max turn from proxy (deg) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        free = " ".join(FITS[r.pair].free) or "none"
        lines.append(
            f"| {r.pair} | {free} | {r.guidance} | {r.modes} | {r.width:.2f} | "
            f"{r.position_percent:.2f} | {r.lateral_error:.3f} | {r.axial_error:+.3f} | "
            f"{r.tilt_deg:.2f} | {'yes' if r.seated else 'no'} | {r.wall_seconds:.0f} | "
            f"{r.cpu_seconds:.0f} | {r.max_proxy_angle_deg:.2f}{' tipped' if r.tipped else ''} |")
    return "\n".join(lines)


def _plot(results: list[SeatingResult], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    names = sorted({r.pair for r in results}, key=[r.pair for r in results].index)
    fig, axes = plt.subplots(1, 2, figsize=(12, 0.45 * len(names) + 2), dpi=110,
                             sharey=True)
    y = np.arange(len(names))
    for j, guidance in enumerate(("skeletal", "collision")):
        rows = {r.pair: r for r in results if r.guidance == guidance}
        if not rows:
            continue
        off = (j - 0.5) * 0.38
        pos = [rows[n].position_percent if n in rows else np.nan for n in names]
        tilt = [rows[n].tilt_deg if n in rows else np.nan for n in names]
        label = "guided" if guidance == "skeletal" else "collision only"
        axes[0].barh(y + off, pos, height=0.36, label=label)
        axes[1].barh(y + off, tilt, height=0.36, label=label)
    axes[0].axvline(100 * SEAT_FRACTION, color="k", ls="--", lw=1)
    axes[1].axvline(SEAT_DEGREES, color="k", ls="--", lw=1)
    for ax, values in zip(axes, ([r.position_percent for r in results],
                                 [r.tilt_deg for r in results]), strict=True):
        # errors span from thousandths to hundreds: start the axis below the smallest
        ax.set_xscale("log")
        small = [v for v in values if v > 0]
        ax.set_xlim(left=min(0.01, 0.5 * min(small)) if small else 0.01)
        ax.xaxis.set_minor_formatter(NullFormatter())  # labels at the decades only
    axes[0].set_xlabel("position error, % of width (constrained axes; log)")
    axes[1].set_xlabel("tilt, degrees (constrained axes; log)")
    axes[0].set_yticks(y, names)
    axes[0].invert_yaxis()
    axes[0].legend(loc="lower right")
    fig.suptitle("Seating from a misaimed push (dashed: the seating criterion)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


# ---------------------------------------------------------------------------- generated
def _job(case: SeatingCase, guidance: str, seconds: float, modes: int | None,
         backend: str, until_rest: bool) -> SeatingResult:
    """One run in a pool's process (no progress across processes)."""
    return seating_run(case, guidance, seconds=seconds, modes=modes, backend=backend,
                       until_rest=until_rest)


def _rested(r: SeatingResult, seconds: float) -> str:
    """", at rest at 3.1 s" where the run ended before ``seconds``, else ""."""
    return f", at rest at {r.seconds:.1f} s" if r.seconds < seconds - 1e-9 else ""


def _say(r: SeatingResult, seconds: float) -> None:
    print(f"{r.pair} ({r.guidance}): position {r.position_percent:.2f} % of the width, tilt "
          f"{r.tilt_deg:.2f} deg, {'seated' if r.seated else 'not seated'}, max turn from "
          f"the proxy {r.max_proxy_angle_deg:.2f} deg{' (tipped)' if r.tipped else ''} "
          f"({r.setup_seconds:.0f} + {r.wall_seconds:.0f} s, push {r.cpu_seconds:.0f} CPU s"
          f"{_rested(r, seconds)})",
          file=sys.stderr, flush=True)


def run_generated(args: argparse.Namespace) -> int:
    """``--generated N``: make the set, push every pair, print the tables, write the plot."""
    import secrets
    import tempfile

    from bench.fitgen import KernelMissing, generate
    from bench.fitgen.scenes import SceneNewFailed

    if args.generated < 1 or args.workers < 1:
        print("--generated and --workers must be at least 1", file=sys.stderr)
        return 2
    seed = args.seed if args.seed is not None else secrets.randbelow(10**6)
    print(f"generated set: {args.generated} pairs, seed {seed}", file=sys.stderr, flush=True)
    with tempfile.TemporaryDirectory(prefix="skelasm_fits_") as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        bar = _Progress(args.generated)
        try:
            pairs = generate(args.generated, seed, root,
                             progress=lambda i, family: bar.begin(i, f"modelling {family}"))
        except (KernelMissing, FileExistsError, SceneNewFailed) as exc:
            bar.end()
            print(f"skelasm bench seating: {exc}", file=sys.stderr)
            return 2
        bar.end()
        if args.pairs:
            pairs = [p for p in pairs if any(n in p.folder.name for n in args.pairs)]
            if not pairs:
                print(f"skelasm bench seating: no generated pair is named like "
                      f"{' or '.join(args.pairs)} (the folders are NNN_family)", file=sys.stderr)
                return 2
        results = _push_all([generated_case(p) for p in pairs], args)
    print(family_table(results, seed=seed, count=args.generated))
    print()
    print(generated_table(results))
    _plot_generated(results, args.output, seed)
    print(f"\nplot: {args.output}")
    if args.keep:
        print(f"pairs: {args.keep}")
    return 0


def _push_all(cases: list[SeatingCase], args: argparse.Namespace) -> list[SeatingResult]:
    guidances = ("skeletal", "collision") if args.guidance == "both" else (args.guidance,)
    jobs = [(c, g) for c in cases for g in guidances]
    bar = _Progress(len(jobs))
    results: list[SeatingResult] = []
    if args.workers == 1:
        for i, (case, guidance) in enumerate(jobs):
            bar.begin(i, f"{case.name} ({guidance})")
            results.append(seating_run(case, guidance, seconds=args.seconds, modes=args.modes,
                                       backend=args.backend, progress=bar,
                                       until_rest=not args.full))
            bar.end()
            _say(results[-1], args.seconds)
        return results
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # fresh interpreters: a fork would copy this process's numba and OpenCL threads' state
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=args.workers, mp_context=spawn,
                             initializer=use_band,
                             initargs=(getattr(args, "band", None),)) as pool:
        futures = {pool.submit(_job, c, g, args.seconds, args.modes, args.backend,
                               not args.full): (c, g) for c, g in jobs}
        bar.begin(0, f"{args.workers} runs at a time")
        for future in as_completed(futures):
            results.append(future.result())
            bar.end()
            _say(results[-1], args.seconds)
            bar.finished(len(results), f"{args.workers} runs at a time")
    bar.end()
    order = {(c.name, g): i for i, (c, g) in enumerate(jobs)}
    return sorted(results, key=lambda r: order[r.pair, r.guidance])


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else math.nan


def family_table(results: list[SeatingResult], *, seed: int | None = None,
                 count: int | None = None) -> str:
    """Markdown table per family and guidance, then overall."""
    head = (f"Generated set: {count} pairs, seed {seed}. " if seed is not None else "")
    lines = [head + f"Misaim {100 * OFFSET_FRACTION:g} % of the width sideways and "
             f"{TILT_DEGREES:g} degrees about the fit centre; seated: within "
             f"{100 * SEAT_FRACTION:g} % of the width (or the radial play) and {SEAT_DEGREES:g} "
             "degree (or the angular play) in the constrained directions; tipped: turned from "
             "the proxy by more than the angular play plus the misaim at some step.", "",
             "| family | guidance | pairs | seated | tipped | position error, % width: "
             "median / worst | tilt, deg: median / worst | max turn from proxy, deg | "
             "wall s per run: setup + push (median) | push CPU s: median / worst |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    families = sorted({r.family for r in results}, key=[r.family for r in results].index)
    for family in [*families, "all"]:
        for guidance in ("skeletal", "collision"):
            rows = [r for r in results if r.guidance == guidance
                    and (family == "all" or r.family == family)]
            if not rows:
                continue
            pos = [r.position_percent for r in rows]
            tilt = [r.tilt_deg for r in rows]
            name = f"**{family}**" if family == "all" else family
            lines.append(
                f"| {name} | {'guided' if guidance == 'skeletal' else 'collision only'} | "
                f"{len(rows)} | {sum(r.seated for r in rows)} | {sum(r.tipped for r in rows)} "
                f"| {_median(pos):.2f} / {max(pos):.2f} | {_median(tilt):.2f} / "
                f"{max(tilt):.2f} | {max(r.max_proxy_angle_deg for r in rows):.2f} | "
                f"{_median([r.setup_seconds for r in rows]):.0f} + "
                f"{_median([r.wall_seconds for r in rows]):.0f} | "
                f"{_median([r.cpu_seconds for r in rows]):.0f} / "
                f"{max(r.cpu_seconds for r in rows):.0f} |")
    return "\n".join(lines)


def generated_table(results: list[SeatingResult]) -> str:
    """Markdown table of the runs of a generated set."""
    lines = ["| pair | guidance | K | width | position error (% width) | tolerance (% width) | "
             "tilt (deg) | tolerance (deg) | max turn from proxy (deg) | limit (deg) | seated | "
             "wall s (setup + push) | push CPU s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        tol = 100 * (r.position_tolerance or SEAT_FRACTION * r.width) / r.width
        lines.append(
            f"| {r.pair} | {'guided' if r.guidance == 'skeletal' else 'collision only'} | "
            f"{r.modes} | {r.width:.4g} | {r.position_percent:.2f} | {tol:.2f} | "
            f"{r.tilt_deg:.2f} | {r.angle_tolerance_deg:.2f} | {r.max_proxy_angle_deg:.2f}"
            f"{' tipped' if r.tipped else ''} | {r.tip_limit_deg:.2f} | "
            f"{'yes' if r.seated else 'no'} | {r.setup_seconds:.0f} + {r.wall_seconds:.0f} | "
            f"{r.cpu_seconds:.0f} |")
    return "\n".join(lines)


def _plot_generated(results: list[SeatingResult], path: str, seed: int) -> None:
    """Plot the seated share per family and every run's errors over their tolerances."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator

    families = sorted({r.family for r in results}, key=[r.family for r in results].index)
    fig, axes = plt.subplots(1, 2, figsize=(13, 0.5 * len(families) + 2.5), dpi=110)
    y = np.arange(len(families))
    bars = (("skeletal", "seated", "guided: seated", "tab:blue"),
            ("collision", "seated", "collision only: seated", "tab:orange"),
            ("skeletal", "tipped", "guided: tipped", "tab:grey"))
    for j, (guidance, what, label, colour) in enumerate(bars):
        share = []
        for family in families:
            rows = [r for r in results if r.family == family and r.guidance == guidance]
            share.append(100.0 * sum(getattr(r, what) for r in rows) / len(rows) if rows
                         else np.nan)
        axes[0].barh(y + (j - 1) * 0.27, share, height=0.25, label=label, color=colour)
    axes[0].set_yticks(y, families)
    axes[0].invert_yaxis()
    axes[0].set_xlim(0, 100)
    axes[0].set_xlabel("% of the family's pairs")
    axes[0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize="small",
                   frameon=False)
    for guidance, marker in (("skeletal", "o"), ("collision", "x")):
        rows = [r for r in results if r.guidance == guidance]
        if not rows:
            continue
        px = [max(r.position_error / (r.position_tolerance or SEAT_FRACTION * r.width), 1e-3)
              for r in rows]
        py = [max(r.tilt_deg / r.angle_tolerance_deg, 1e-3) for r in rows]
        axes[1].scatter(px, py, marker=marker, label="guided" if guidance == "skeletal"
                        else "collision only")
    axes[1].axvline(1, color="k", ls="--", lw=1)
    axes[1].axhline(1, color="k", ls="--", lw=1)
    axes[1].set_xscale("log")
    axes[1].set_yscale("log")
    for scale in (axes[1].xaxis, axes[1].yaxis):  # 0.1, 0.2, 0.5, 1, 2, 5, 10: no crowding
        scale.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        scale.set_minor_locator(LogLocator(subs=(2.0, 5.0)))
        scale.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axes[1].set_xlabel("position error / its tolerance (log)")
    axes[1].set_ylabel("tilt / its tolerance (log)")
    axes[1].legend(loc="upper left")
    fig.suptitle(f"Generated fits, seed {seed}: seating from a misaimed push (seated: lower "
                 "left of the dashed lines)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
