"""The fit generator (bench/fitgen) and the generated mode of ``skelasm bench seating``.

Without gmsh (a development extra) the tests that model parts skip, saying how to install
it; the error function, the family cycle and the T-junctions need no CAD kernel. The slow
test pushes one generated pair of four families (of every family with
SKELASM_GENERATED=all) with the misaim protocol and requires each to seat guided, without
tipping: the criterion is the benchmark's and is not relaxed here.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from bench.fitgen.families import CLEARANCE_RANGE, FAMILIES, SIZE_RANGE
from bench.fitgen.generate import family_of
from bench.seating import constrained_errors, free_direction_errors

SEED = 2026
#: One pair of every family.
COUNT = len(FAMILIES)


def _gmsh_or_skip():
    from bench.fitgen import KernelMissing, require_gmsh

    try:
        require_gmsh()
    except KernelMissing as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The fixed-seed set: one pair of each family."""
    _gmsh_or_skip()
    from bench.fitgen import generate

    return generate(COUNT, SEED, tmp_path_factory.mktemp("fits"))


def _pair(generated, family):
    for p in generated:
        if p.truth.family == family:
            return p
    raise AssertionError(f"no {family} pair in the set")


def _meshes(pair):
    """Both parts' meshes in their files' frames and the scene's unit; STEP tessellated at
    the chord tolerance the truth gives.
    """
    from bench.fitgen.export import UNITS
    from engine.loading import load_part

    t = pair.truth
    out = []
    for name in (t.fixed_file, t.moving_file):
        path = pair.folder / name
        if path.suffix == ".step":  # gmsh writes STEP in millimetres
            part = load_part(path, tolerance=t.chord_tolerance * UNITS[t.unit])
            out.append((np.array(part.vertices) / UNITS[t.unit], np.array(part.faces)))
        else:
            part = load_part(path)
            out.append((np.array(part.vertices), np.array(part.faces)))
    return out


def _boundary_edges(faces) -> int:
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                    axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return int((counts != 2).sum())


# ------------------------------------------------------------------------ no CAD kernel
def test_the_families_of_the_brief_are_all_there():
    assert set(FAMILIES) == {"round_through", "round_blind", "rect_through", "rect_blind",
                             "stepped", "keyed", "spline", "dovetail", "tslot", "sleeve",
                             "plate_on_pins", "bolt_nut", "multi_fit"}


def test_every_block_of_pairs_holds_every_family_once():
    n = len(FAMILIES)
    for block in range(3):
        names = [family_of(SEED, block * n + i) for i in range(n)]
        assert sorted(names) == sorted(FAMILIES)
    assert [family_of(SEED, i) for i in range(n)] != [family_of(SEED + 1, i) for i in range(n)]


def test_a_missing_kernel_is_one_line_naming_the_install(monkeypatch):
    from bench.fitgen import INSTALL_HINT, KernelMissing, require_gmsh

    monkeypatch.setitem(sys.modules, "gmsh", None)  # import gmsh now raises ImportError
    with pytest.raises(KernelMissing) as info:
        require_gmsh()
    assert INSTALL_HINT in str(info.value) and "\n" not in str(info.value)
    assert INSTALL_HINT == 'pip install -e ".[assets]"'


def test_the_bench_without_the_kernel_exits_2_with_that_line(monkeypatch, tmp_path, capsys):
    import argparse

    from bench import seating

    monkeypatch.setitem(sys.modules, "gmsh", None)
    parser = argparse.ArgumentParser()
    seating.add_arguments(parser)
    args = parser.parse_args(["--generated", "2", "--seed", "1", "--keep",
                              str(tmp_path / "set"), "-o", str(tmp_path / "p.png")])
    assert seating.run(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert 'pip install -e ".[assets]"' in err[-1]
    assert not (tmp_path / "p.png").exists()


def test_the_bench_pushes_only_the_generated_pairs_it_is_given(generated, monkeypatch,
                                                              tmp_path, capsys):
    import argparse

    from bench import seating

    pushed: list = []

    class Pushed(Exception):
        pass

    def push_all(cases, args):
        pushed.extend(c.name for c in cases)
        raise Pushed

    monkeypatch.setattr(seating, "_push_all", push_all)
    parser = argparse.ArgumentParser()
    seating.add_arguments(parser)
    root = str(generated[0].folder.parent)  # the set on disk: reused, not modelled again
    base = ["--generated", str(COUNT), "--seed", str(SEED), "--keep", root, "-o",
            str(tmp_path / "p.png")]
    with pytest.raises(Pushed):
        seating.run(parser.parse_args(base + ["--pairs", "round_blind", "002"]))
    names = [p.folder.name for p in generated]
    assert pushed == [n for n in names if "round_blind" in n or "002" in n]
    assert 1 <= len(pushed) < COUNT
    pushed.clear()
    assert seating.run(parser.parse_args(base + ["--pairs", "gearbox"])) == 2
    assert pushed == []
    assert "no generated pair is named like gearbox" in capsys.readouterr().err


def test_t_junctions_keep_the_surface_and_open_it():
    import trimesh

    from bench.fitgen.export import t_junctions

    box = trimesh.creation.box((3.0, 4.0, 5.0))
    v, f = t_junctions(np.array(box.vertices), np.array(box.faces), 5,
                       np.random.default_rng(0))
    opened = trimesh.Trimesh(v, f, process=False)
    assert _boundary_edges(np.array(box.faces)) == 0
    assert _boundary_edges(f) > 0
    assert opened.area == pytest.approx(box.area)
    assert opened.volume == pytest.approx(box.volume)


# ------------------------------------------------------------------------ at rest
def _stretches(rates, dt=1e-3, steps=100, centre=None, length=1.0, degrees=0.5,
               left=3.0, tremble=0.0):
    """Feed a RestWatch stretches of a part moving at ``rates`` (length/s, deg/s, one pair
    per stretch), trembling by ``tremble`` (length) from step to step; for each stretch,
    whether it then says the part is at rest. ``left`` (s) is left after the first.
    """
    from bench.seating import RestWatch

    watch = RestWatch(length, degrees, dt, centre)
    pose, said = np.zeros(6), []
    for move, turn in rates:
        t = dt * np.arange(1, steps + 1)[:, None]
        poses = np.tile(pose, (steps, 1))
        poses[:, 0:1] += move * t
        poses[:, 5:6] += np.radians(turn) * t
        pose = poses[-1].copy()
        poses[::2, 1] += tremble  # every other step off to one side
        said.append(watch.add(poses, left))
        left -= steps * dt
    return said


def test_a_part_at_rest_ends_the_run_and_a_creeping_one_does_not():
    from bench.seating import REST_CHUNKS, REST_FRACTION, REST_WINDOW

    first = 2 * REST_WINDOW + REST_CHUNKS - 1  # stretches before it can say so
    # still: at rest once both windows are filled and REST_CHUNKS stretches judged
    assert _stretches([(0.0, 0.0)] * (first + 2)) == [False] * (first - 1) + [True] * 3
    # creeping fast enough to move 10 % of the tolerance in the 3 s left: never
    creep = 2 * REST_FRACTION * 1.0 / 3.0
    assert not any(_stretches([(creep, 0.0)] * 12))
    # the same creep with a tenth of a second left moves the part too little to matter
    assert _stretches([(creep, 0.0)] * first, left=0.1 + first * 0.1)[-1]
    # turning: judged against the degrees
    assert not any(_stretches([(0.0, 2 * REST_FRACTION * 0.5 / 3.0)] * 12))
    # a move breaks the count
    said = _stretches([(0.0, 0.0)] * first + [(1.0, 0.0)] + [(0.0, 0.0)] * (first + 1))
    assert said[first - 1] and not any(said[first:2 * first]) and said[-1]
    # a part trembling by half its tolerance either side of a still mean is at rest; by
    # one and a half not
    assert _stretches([(0.0, 0.0)] * first, tremble=1.0)[-1]
    assert not any(_stretches([(0.0, 0.0)] * 12, tremble=3.0))
    # a turn about an origin far from the fit moves the fit's centre: judged there
    # (0.005 deg/s turns it 0.015 deg in the 3 s left, within 5 % of 0.5 deg, and moves a
    # centre 1000 away 0.26, past 5 % of 1)
    assert _stretches([(0.0, 0.005)] * first)[-1]
    assert not any(_stretches([(0.0, 0.005)] * 12, centre=np.array([0.0, 1000.0, 0.0])))


# ------------------------------------------------------------------------ the errors
def _rot(rotvec):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix()


def test_free_direction_errors_with_nothing_free():
    pos, lat, axial, tilt = free_direction_errors([3.0, 4.0, 0.0], _rot([0, 0, 0]), [0, 0, -1])
    assert (pos, lat, axial, tilt) == pytest.approx((5.0, 5.0, 0.0, 0.0))
    # along the insertion axis counts as axial, signed with the axis
    pos, lat, axial, tilt = free_direction_errors([0.0, 0.0, -2.0], _rot([0.3, 0.4, 0]),
                                                  [0, 0, -1])
    assert (pos, lat, axial) == pytest.approx((2.0, 0.0, 2.0))
    assert tilt == pytest.approx(math.degrees(0.5))


def test_free_translations_in_any_direction_are_taken_out():
    s = 1 / math.sqrt(2)
    # free along (1, 1, 0)/sqrt 2: of (1, 1, 1) only the z part is left
    pos, lat, axial, _ = free_direction_errors([1.0, 1.0, 1.0], np.eye(3), [0, 0, 1],
                                               [(s, s, 0.0)])
    assert (pos, lat, axial) == pytest.approx((1.0, 0.0, 1.0))
    # two free directions, not orthogonal, span the xy plane
    pos, lat, axial, _ = free_direction_errors([3.0, 4.0, 5.0], np.eye(3), [0, 0, 1],
                                               [(1, 0, 0), (s, s, 0)])
    assert (pos, lat, axial) == pytest.approx((5.0, 0.0, 5.0))
    # along an oblique insertion axis, free: nothing is left of a move along it
    axis = np.array([1.0, 2.0, 2.0]) / 3
    pos, *_ = free_direction_errors(0.7 * axis, np.eye(3), axis, [tuple(axis)])
    assert pos == pytest.approx(0.0, abs=1e-12)


def test_free_rotations_in_any_direction_are_taken_out():
    a = np.array([1.0, 2.0, 2.0]) / 3                  # the free rotation axis
    b = np.cross(a, [1.0, 0.0, 0.0])
    b /= np.linalg.norm(b)                             # one across it
    spin = _rot(1.0 * a)
    assert free_direction_errors(np.zeros(3), spin, a, (), [a])[3] == pytest.approx(0, abs=1e-6)
    # a turn of 0.2 rad across the free axis, after any spin about it: a has turned 0.2
    both = _rot(0.2 * b) @ spin
    assert free_direction_errors(np.zeros(3), both, a, (), [a])[3] == pytest.approx(
        math.degrees(0.2))
    # nothing free: the whole angle
    assert free_direction_errors(np.zeros(3), _rot(0.2 * b), a)[3] == pytest.approx(
        math.degrees(0.2))
    # two free (x, y): only the turn about z counts
    assert free_direction_errors(np.zeros(3), _rot([0, 0, 0.3]), [0, 0, 1], (),
                                 [(1, 0, 0), (0, 1, 0)])[3] == pytest.approx(math.degrees(0.3))
    assert free_direction_errors(np.zeros(3), _rot([0.5, 0, 0]), [0, 0, 1], (),
                                 [(1, 0, 0), (0, 1, 0)])[3] == pytest.approx(0.0, abs=1e-9)
    # all three free
    assert free_direction_errors(np.zeros(3), _rot([0.5, 0.2, 0.1]), [0, 0, 1], (),
                                 np.eye(3))[3] == 0.0


def test_the_named_axes_of_the_real_suite_agree_with_the_vectors():
    error = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.4])
    axis = np.array([0.0, 0.0, -1.0])
    eye = np.eye(3)
    for free, ft, fr in [((), (), ()), (("tz", "rz"), (eye[2],), (eye[2],)),
                         (("ty",), (eye[1],), ()), (("rz",), (), (eye[2],))]:
        assert constrained_errors(error, axis, free) == pytest.approx(
            free_direction_errors(error[:3], _rot(error[3:]), axis, ft, fr))
    # through hole: along z and the spin about z are free; the tilt is the axis' turn
    pos, lat, axial, tilt = constrained_errors(error, axis, ("tz", "rz"))
    assert pos == pytest.approx(math.hypot(0.1, 0.2))
    assert axial == 0.0
    assert tilt == pytest.approx(math.degrees(np.arccos((_rot(error[3:]) @ eye[2])[2])))


# ------------------------------------------------------------------------ generated pairs
def test_the_set_holds_one_pair_of_every_family(generated):
    assert sorted(p.truth.family for p in generated) == sorted(FAMILIES)
    units = {p.truth.unit for p in generated}
    formats = {f for p in generated for f in p.truth.formats}
    assert units == {"mm", "m"} and formats == {"step", "stl", "obj"}
    assert any(any(p.truth.open_mesh) for p in generated)


def test_the_same_seed_gives_the_same_bytes(generated, tmp_path):
    from bench.fitgen import generate

    again = generate(3, SEED, tmp_path / "again")   # pair i does not depend on the count
    for first, second in zip(generated[:3], again, strict=True):
        names = sorted(p.name for p in first.folder.iterdir())
        assert names == sorted(p.name for p in second.folder.iterdir())
        for name in names:
            assert (first.folder / name).read_bytes() == (second.folder / name).read_bytes(), \
                name
    other = generate(3, SEED + 1, tmp_path / "other")
    assert [p.truth.description for p in other] != [p.truth.description for p in again]


@pytest.mark.parametrize("family", list(FAMILIES))
def test_parts_are_closed_or_deliberately_open_at_their_size_and_unit(generated, family):
    from bench.fitgen.export import UNITS
    from engine.runtime import open_scene

    pair = _pair(generated, family)
    t = pair.truth
    scale = UNITS[t.unit]  # mm per scene unit
    assert SIZE_RANGE[0] <= t.nominal * scale <= SIZE_RANGE[1]
    assert CLEARANCE_RANGE[0] <= t.clearance * scale <= CLEARANCE_RANGE[1]
    assert 0 < t.radial_play and 0 < t.angular_play_deg < 10
    for (v, f), opened, fmt in zip(_meshes(pair), t.open_mesh, t.formats, strict=True):
        assert (_boundary_edges(f) > 0) == opened, (fmt, opened)
        # the numbers in the file are in the scene's unit (STEP: millimetres, converted)
        assert 0.5 <= np.ptp(v, axis=0).max() / t.nominal <= 25
    handle = open_scene(pair.scene)
    assert handle.scene.units == t.unit
    for part in handle.parts:  # as the scene loads them, in the scene's unit
        assert 0.5 <= np.ptp(part.vertices, axis=0).max() / t.nominal <= 25
    # the truth's vectors are unit vectors, the free ones across or along the axis
    for v in (t.insertion_axis, t.lateral, *t.free_translations, *t.free_rotations):
        assert np.linalg.norm(v) == pytest.approx(1.0)
    assert abs(np.dot(t.lateral, t.insertion_axis)) < 1e-9


@pytest.mark.parametrize("family", list(FAMILIES))
def test_scene_new_wrote_the_pair_as_given(generated, family):
    from engine.runtime import open_scene

    pair = _pair(generated, family)
    t = pair.truth
    handle = open_scene(pair.scene)
    np.testing.assert_allclose(handle.assembled_pose, t.assembled_pose, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(handle.scene.insertion_axis, t.insertion_axis, atol=1e-9)
    assert [Path(p.file).name for p in handle.scene.parts] == [t.fixed_file, t.moving_file]
    assert (pair.folder / "scene_push.csv").is_file()


def test_scene_new_gets_the_files_unit_pose_and_axis_and_nothing_else(monkeypatch, tmp_path):
    _gmsh_or_skip()
    import app.cli
    from bench.fitgen import generate

    calls = []
    real_main = app.cli.main

    def spy(argv=None):
        calls.append(list(argv))
        return real_main(argv)

    monkeypatch.setattr(app.cli, "main", spy)
    pairs = generate(2, SEED, tmp_path / "set")
    assert len(calls) == 2
    for argv, pair in zip(calls, pairs, strict=True):
        assert argv[:2] == ["scene", "new"]
        options = [a for a in argv[2:] if a.startswith("--") or a == "-o"]
        assert options == ["-o", "--unit", "--assembled", "--insertion-axis"]
        assert len(argv) == 2 + 2 + 2 + 2 + 7 + 4  # files, -o, --unit, 6 + 3 numbers
        assert argv[argv.index("--unit") + 1] == pair.truth.unit


@pytest.mark.parametrize("family", list(FAMILIES))
def test_the_seat_is_clear_and_a_misfit_beyond_the_play_is_not(generated, family):
    from bench.fitgen.checks import interference
    from engine.pose import pose_to_matrix, rotate_about

    pair = _pair(generated, family)
    t = pair.truth
    fixed, moving = _meshes(pair)
    seat = np.array(t.assembled_pose)
    gap = t.min_gap  # a misfit by half a play more than the play goes about this deep or more
    assert 0 < gap <= t.radial_play
    # touching faces (a floor, a shoulder, a cap on its face) give rounding-sized depths
    assert interference(fixed, moving, seat) < 0.1 * gap
    shifted = seat.copy()
    shifted[:3] += 1.5 * t.radial_play * np.array(t.lateral)
    assert interference(fixed, moving, shifted) > 0.25 * gap
    m = pose_to_matrix(seat)
    centre = m[:3, :3] @ np.array(t.centre) + m[:3, 3]
    beyond = 1.5 * math.radians(t.angular_play_deg)
    tilt_axis = np.cross(t.insertion_axis, t.lateral)
    assert interference(fixed, moving, rotate_about(seat, beyond * tilt_axis, centre)) \
        > 0.25 * gap
    if not t.free_rotations:  # a keyed, splined, square or pinned fit does not spin
        twist = rotate_about(seat, beyond * np.array(t.insertion_axis), centre)
        assert interference(fixed, moving, twist) > 0.25 * gap


# ------------------------------------------------------------------------ slow: seating
_RUNS: dict = {}


#: Families whose pair of the tests' set (seed 2026) does not seat guided without tipping
#: with the settings `scene new` chooses on a CPU (K <= 25 and the fine level where the
#: parts meet, with its walls: docs/settings.md, docs/fine_level.md), with the measured
#: figures (xfail, not strict: a pair that starts to pass shows as XPASS). "Turned" is the
#: largest angle from the proxy during the push; the hand's wrist stops it at the 3 degree
#: misaim. The criterion stays.
NOT_SEATING: dict[str, str] = {
    "spline": "K 25: tilt 0.57 deg (0.50 allowed)",
    "rect_blind": "K 25: 85.7 % of the width short, 5.94 deg: turned round the wrist's stop "
                  "at the mouth (3.00 deg from the proxy) and caught on the rim",
}


#: The families CI pushes, three of those that seat, a minute or so each: a key, a nut and
#: a part with several fits. All thirteen (the ten others about 15 minutes more on a 2-core
#: machine) are pushed with SKELASM_GENERATED=all, and by `skelasm bench seating
#: --generated` (docs/measurements/seating_generated.md).
PUSHED_IN_TESTS = ("keyed", "bolt_nut", "multi_fit")


def _seating_params():
    every = os.environ.get("SKELASM_GENERATED") == "all"
    return [pytest.param(f, marks=pytest.mark.xfail(reason=NOT_SEATING[f], strict=False))
            if f in NOT_SEATING else f
            for f in FAMILIES if every or f in PUSHED_IN_TESTS]


@pytest.mark.slow
@pytest.mark.parametrize("family", _seating_params())
def test_every_family_seats_guided_without_tipping(generated, family):
    from bench.seating import PUSH_SECONDS, generated_case, seating_run

    pair = _pair(generated, family)
    r = seating_run(generated_case(pair), "skeletal", seconds=5.0)
    # shown with -s: the figures of docs/measurements/seating_generated.md
    print(f"\nSEATING {pair.folder.name}: position {r.position_error:.4g} (tolerance "
          f"{r.position_tolerance:.4g}, {r.position_percent:.2f} % of {r.width:.4g}), tilt "
          f"{r.tilt_deg:.2f} deg (tolerance {r.angle_tolerance_deg:.2f}), max turn from the "
          f"proxy {r.max_proxy_angle_deg:.2f} deg (limit {r.tip_limit_deg:.2f}), K {r.modes}, "
          f"ended at {r.seconds:.1f} s")
    assert PUSH_SECONDS <= r.seconds <= 5.0 + 1e-9  # the push, and on to rest at most
    assert r.position_error <= r.position_tolerance, r
    assert r.tilt_deg <= r.angle_tolerance_deg, r
    assert not r.tipped, r


def test_the_misaimed_push_ends_with_the_fit_centre_at_the_seat_depth():
    from bench.seating import OFFSET_FRACTION, TILT_DEGREES, misaim, misaimed_push
    from engine.pose import pose_to_matrix

    axis = np.array([2.0, -1.0, 2.0]) / 3
    lateral, tilt_axis = misaim(axis)
    target = np.array([120.0, -340.0, 75.0, 0.4, -1.1, 0.3])  # the file origin far off
    centre = np.array([-150.0, 80.0, 210.0])                  # part 2's, in its own frame
    back = target.copy()
    back[:3] -= 40.0 * axis
    start, end = misaimed_push(back, target, axis, lateral, tilt_axis, 20.0, centre)

    def at(pose):
        m = pose_to_matrix(pose)
        return m[:3, :3] @ centre + m[:3, 3], m[:3, :3]

    (c_seat, r_seat), (c_start, r_start), (c_end, r_end) = at(target), at(start), at(end)
    # the centre starts 40 back and 3 % of the width aside; ends at the depth, still aside
    np.testing.assert_allclose(c_start - c_seat, -40.0 * axis + OFFSET_FRACTION * 20 * lateral,
                               atol=1e-9)
    np.testing.assert_allclose(c_end - c_seat, OFFSET_FRACTION * 20 * lateral, atol=1e-9)
    # turned by the misaim about the tilt axis, in part 1's frame, and not further
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_matrix(r_end @ r_seat.T).as_rotvec()
    np.testing.assert_allclose(turn, math.radians(TILT_DEGREES) * tilt_axis, atol=1e-12)
    np.testing.assert_allclose(r_start, r_end)


def test_the_expected_failures_name_families():
    assert set(NOT_SEATING) <= set(FAMILIES)
    assert all(reason.startswith("K ") for reason in NOT_SEATING.values())


def test_a_gmsh_session_leaves_the_process_signal_handling_as_it_was():
    """Gmsh's initialisation stops ignoring SIGPIPE behind Python's back: a later write to a
    dead child's pipe then killed the whole test run.
    """
    import signal

    pytest.importorskip("gmsh")
    from bench.fitgen import kernel

    def ignored(number: int) -> bool:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("SigIgn:"):
                return bool(int(line.split()[1], 16) >> (number - 1) & 1)
        pytest.skip("no /proc/self/status here to read the signal mask from")

    before = ignored(signal.SIGPIPE), signal.getsignal(signal.SIGINT)
    with kernel.session():
        assert ignored(signal.SIGPIPE) == before[0]
    assert (ignored(signal.SIGPIPE), signal.getsignal(signal.SIGINT)) == before


def test_the_tables_give_each_push_s_cpu_seconds():
    """The push's CPU time is in every table (the affordability target is judged on it).

    On a shared machine the wall time is not the cost.
    """
    from bench.seating import SeatingResult, family_table, generated_table

    def result(cpu, family):
        return SeatingResult(pair=f"000_{family}", guidance="skeletal", width=10.0,
                             position_error=0.1, lateral_error=0.1, axial_error=0.0,
                             tilt_deg=0.1, final_pose=(0.0,) * 6, modes=25, seconds=5.0,
                             wall_seconds=99.0, family=family, setup_seconds=7.0,
                             cpu_seconds=cpu)

    runs = [result(31.0, "keyed"), result(47.0, "keyed"), result(12.0, "spline")]
    rows = {line.split("|")[1].strip(): line for line in family_table(runs).splitlines()
            if line.startswith("| ")}
    assert rows["keyed"].rstrip().endswith("| 39 / 47 |")
    assert rows["**all**"].rstrip().endswith("| 31 / 47 |")
    assert [line.rstrip().endswith(f"| {c} |") for line, c in
            zip(generated_table(runs).splitlines()[2:], (31, 47, 12), strict=True)] == [True] * 3


def test_a_part_held_at_the_wrists_stop_has_not_tipped():
    """The wrist stops a part a millionth of its play past it: a real pair (no play, limit
    the misaim's 3 degrees) held there is not tipped; a hundredth of a degree more is.
    """
    import math

    from bench.seating import TILT_DEGREES, SeatingResult
    from engine.sim.simulation import STOP_PAST_PLAY

    def turned(degrees):
        return SeatingResult(pair="p", guidance="skeletal", width=10.0, position_error=0.1,
                             lateral_error=0.1, axial_error=0.0, tilt_deg=0.1,
                             final_pose=(0.0,) * 6, modes=25, seconds=5.0, wall_seconds=1.0,
                             max_proxy_angle_deg=degrees, tip_limit_deg=TILT_DEGREES)

    at_stop = math.degrees(math.radians(3.0) * (1.0 + STOP_PAST_PLAY))
    assert at_stop > TILT_DEGREES  # the stop itself lies past the limit ...
    assert not turned(at_stop).tipped  # ... and is not a tip
    assert turned(TILT_DEGREES + 0.01).tipped
