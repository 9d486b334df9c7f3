"""The real-fit suite (assets/real): scenes parse, parts load at their real size, the
assembled pose is free of interference and a small misalignment is not, and (slow) each
pair seats from the misaim protocol of ``skelasm bench seating``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from bench.seating import (
    FITS,
    PUSH_SECONDS,
    SEAT_DEGREES,
    SEAT_FRACTION,
    pair_names,
    seating_run,
)

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "assets" / "real"
PAIRS = pair_names()

#: Bounding-box sides (x, y, z) in mm of (fixed part, moving part), from the drawings (the
#: modelled parts' ISO 286 mid-tolerance sizes) or the source's own figures (Factory). The
#: spline shaft's x side is that of its teeth at +-30 degrees: 2 R cos(30 deg - asin(w / 2R))
#: with R = 12.8175 and w = 5.946.
KNOWN_SIZES = {
    "iso_pin_5_H7h6_through": ((30, 30, 10), (4.996, 4.996, 20)),
    "iso_shaft_20_H7g6_blind": ((40, 40, 30), (19.9865, 19.9865, 35)),
    "iso_spigot_50_H7h6": ((80, 80, 12), (70, 70, 10.5)),
    "iso_sleeve_30_H7g6_thinwall": ((50, 50, 20), (29.9865, 29.9865, 25)),
    "keyed_hub_20": ((30, 30, 50), (40, 40, 20)),
    "spline_6x23x26": ((50, 50, 20), (24.568, 25.635, 40)),
    "rect_peg_10x16_H7g6": ((40, 40, 25), (9.9905, 15.9885, 30)),
    "dovetail_60_slide": ((60, 60, 20), (40, 40, 17.9)),
    "factory_round_peg_8mm_loose": ((25, 25, 8.9916), (7.986, 7.986, 50)),
    "factory_round_peg_16mm_tight": ((25, 25, 8.9916), (15.994, 15.994, 50)),
    "factory_rect_peg_8mm_loose": ((25, 25, 8.9916), (7.964, 6.91, 50)),
    "factory_rect_peg_12mm_tight": ((25, 25, 8.9916), (12, 8, 50)),
}

#: Pairs measured not to seat guided from the misaim protocol, with the measured figures
#: (xfail): the scenes say only what a user knows and the engine chooses grid, K, the
#: tessellation and the fine level with its walls within this machine's budget
#: (docs/settings.md, docs/fine_level.md). None today: the blind shaft and the
#: rectangular peg in its pocket, which ended 0.73 and 0.53 mm short of their floors
#: before the walls, seat (0.59 and 0.60 %). The criterion stays: 2 % of the width and
#: 0.5 degree.
NOT_SEATING: dict[str, str] = {}


# ------------------------------------------------------------------------------- fast
def test_every_pair_is_listed():
    assert len(PAIRS) >= 10
    assert set(SEATED_IN_TESTS) <= set(PAIRS) and set(BASELINE) <= set(PAIRS)
    assert sorted(FITS) == PAIRS
    assert set(KNOWN_SIZES) == set(PAIRS)
    readme = (REAL / "README.md").read_text()
    for name in PAIRS:
        assert f"`{name}`" in readme, name


@pytest.mark.parametrize("name", PAIRS)
def test_scene_parses_with_files_and_licence_note(name):
    from engine.scene import load_scene

    folder = REAL / name
    scene = load_scene(folder / "scene.toml")
    assert len(scene.parts) == 2
    for part in scene.parts:
        assert part.file.is_file()
        assert part.file.parent == folder.resolve()
    assert scene.insertion_axis is not None
    assert np.isclose(np.linalg.norm(scene.insertion_axis), 1.0)
    note = (folder / "SOURCE.md").read_text()
    assert "icen" in note  # a licence is named
    if "BSD" in note:  # copied under a licence that asks for its text to travel with it
        assert (folder / "LICENSE").is_file()
    # every free axis the suite declares is written in the scene's comment too
    text = (folder / "scene.toml").read_text()
    assert "# free axes:" in text
    for axis in FITS[name].free:
        assert axis in {"tx", "ty", "tz", "rx", "ry", "rz"}


# ------------------------------------------------------------------------------- slow
def _depth_into(vertices, faces, points) -> float:
    """Deepest of ``points`` (k, 3) inside the closed (or nearly closed) mesh: winding number
    above 0.5 for inside, exact distance to the triangles for the depth.
    """
    import trimesh

    from engine.descriptor import winding_number

    inside = winding_number(vertices, faces, points) > 0.5
    if not inside.any():
        return 0.0
    mesh = trimesh.Trimesh(np.array(vertices), np.array(faces), process=False)
    _, distance, _ = trimesh.proximity.closest_point(mesh, np.array(points[inside]))
    return float(distance.max())


def interference(parts, pose, samples=20000) -> float:
    """Deepest interpenetration (scene units) of part 2 at ``pose`` (6,) relative to part 1:
    points of either surface (vertices and random samples) inside the other part.
    """
    import trimesh
    from scipy.spatial.transform import Rotation

    a, b = parts
    rot = Rotation.from_rotvec(np.array(pose[3:], float)).as_matrix()
    shift = np.asarray(pose[:3], float)
    pb = np.vstack([b.vertices, trimesh.Trimesh(np.array(b.vertices), np.array(b.faces),
                                                process=False).sample(samples, seed=1)])
    pa = np.vstack([a.vertices, trimesh.Trimesh(np.array(a.vertices), np.array(a.faces),
                                                process=False).sample(samples, seed=2)])
    return max(_depth_into(a.vertices, a.faces, pb @ rot.T + shift),
               _depth_into(b.vertices, b.faces, (pa - shift) @ rot))


_HANDLES: dict = {}


def handle(name):
    from engine.runtime import open_scene

    if name not in _HANDLES:
        _HANDLES[name] = open_scene(REAL / name / "scene.toml")
    return _HANDLES[name]


@pytest.mark.slow
@pytest.mark.parametrize("name", PAIRS)
def test_pair_loads_at_its_real_size(name):
    h = handle(name)
    assert h.scene.units == "mm"
    for part, known in zip(h.parts, KNOWN_SIZES[name], strict=True):
        assert part.unit == "mm"
        # a unit slip (x1000, x25.4, x10) is far outside; chord sag of round parts is within
        np.testing.assert_allclose(np.ptp(part.vertices, axis=0), known, rtol=2e-3, atol=0.01)


@pytest.mark.slow
@pytest.mark.parametrize("name", PAIRS)
def test_assembled_pose_is_clear_and_a_small_misfit_is_not(name):
    h = handle(name)
    seated = np.asarray(h.assembled_pose, float)
    # touching faces (a floor, a shoulder) give depths of rounding size only
    assert interference(h.parts, seated) < 1e-3
    misfit = seated + np.asarray(FITS[name].misfit, float)
    assert interference(h.parts, misfit) > 0.01
    assert interference(h.parts, np.asarray(h.start_pose, float)) < 1e-3


_RUNS: dict = {}


def cached_run(name, guidance):
    if (name, guidance) not in _RUNS:
        r = seating_run(name, guidance, seconds=5.0)
        _RUNS[name, guidance] = r
        # shown with -s: the figures of docs/real_pairs.md
        print(f"\nSEATING {name} {guidance}: position {r.position_percent:.2f} % of "
              f"{r.width:.2f} (lateral {r.lateral_error:.3f}, axial {r.axial_error:+.3f}), "
              f"tilt {r.tilt_deg:.2f} deg, K {r.modes}, ended at {r.seconds:.1f} s")
    return _RUNS[name, guidance]


#: The pairs the slow tests push: a floor (the blind shaft), a key stopped by a collar, and
#: an OBJ drawn in metres with a tight play. `skelasm bench seating` pushes all twelve
#: (docs/measurements/seating_real.md): about 20 minutes of CI for all, 4 for these (the
#: 60 mm dovetail alone took 2.3; the bundled dovetail is pushed in test_simulate).
#: SKELASM_REAL_PAIRS=all pushes all twelve here too.
SEATED_IN_TESTS = ("iso_shaft_20_H7g6_blind", "keyed_hub_20", "factory_rect_peg_12mm_tight")


def _seating_params():
    names = PAIRS if os.environ.get("SKELASM_REAL_PAIRS") == "all" else SEATED_IN_TESTS
    return [pytest.param(n, marks=pytest.mark.xfail(reason=NOT_SEATING[n], strict=False))
            if n in NOT_SEATING else n for n in names]


@pytest.mark.slow
@pytest.mark.parametrize("name", _seating_params())
def test_guided_pair_seats(name):
    r = cached_run(name, "skeletal")
    assert PUSH_SECONDS <= r.seconds <= 5.0 + 1e-9  # the push, and on to rest at most
    assert r.position_error <= SEAT_FRACTION * r.width, r
    assert r.tilt_deg <= SEAT_DEGREES, r


#: The collision-only baseline in the slow tests: one pair of each kind (through, blind,
#: keyed, slide); `skelasm bench seating` measures all twelve (its own descriptors each).
BASELINE = ("iso_pin_5_H7h6_through", "iso_shaft_20_H7g6_blind", "keyed_hub_20",
            "dovetail_60_slide")


@pytest.mark.slow
@pytest.mark.parametrize("name", BASELINE)
def test_collision_only_pair_is_measured(name):
    # the baseline is measured, not required to seat; the push must have moved the part
    r = cached_run(name, "collision")
    assert np.all(np.isfinite(r.final_pose))
    h = handle(name)
    axis = np.asarray(h.scene.insertion_axis, float)
    travelled = (np.asarray(r.final_pose[:3]) - np.asarray(h.start_pose[:3])) @ axis
    assert travelled > 0.0
    assert math.isfinite(r.tilt_deg)
