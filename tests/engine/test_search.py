"""engine.search: the fits of known pairs are found without being told, with their joints."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree
from search_pairs import through_round

from engine.correlation import correlator_for_scene
from engine.correlation.walls import surface_points
from engine.errors import Cancelled
from engine.pose import pose_to_matrix
from engine.scene import load_scene
from engine.scene.parts import load_scene_parts
from engine.search import SearchSettings, find_fits
from engine.search.cluster import placed, set_distance, surface_spread

ASSETS = Path(__file__).resolve().parents[2] / "assets"


def _prepared(scene_path):
    scene = load_scene(scene_path)
    parts = load_scene_parts(scene)
    points = surface_points(parts[1].vertices, parts[1].faces, 256, seed=0)
    corr = correlator_for_scene(scene, parts=parts)
    return scene, corr, points


def _dense(scene_path):
    part = load_scene_parts(load_scene(scene_path))[1]
    return surface_points(part.vertices, part.faces, 8192, seed=1)


def _miss(fit, pose, points, dense):
    """How far the fit puts part 2's surface from where ``pose`` does, in % of its size.

    The mean distance of the fit's surface points to the nearest of a dense sample of the
    surface at ``pose`` (two samples of one surface lie a sample's spacing apart).
    """
    m = pose_to_matrix(pose)
    want = placed(dense, m[:3, :3], m[:3, 3])
    got = placed(points, fit.rotation, fit.translation)
    return 100.0 * float(np.mean(cKDTree(want).query(got)[0])) / surface_spread(points)


@pytest.fixture(scope="module")
def through_path(tmp_path_factory):
    return through_round(tmp_path_factory.mktemp("through"))[0]


@pytest.fixture(scope="module")
def through(through_path):
    _, corr, points = _prepared(through_path)
    return corr, points, np.zeros(6), _dense(through_path)


@pytest.fixture(scope="module")
def through_result(through):
    corr, points, _, _ = through
    return find_fits(corr, SearchSettings(level=1, scan_modes=12, top=3), points=points)


def test_a_scan_without_the_torque_finds_the_same_fit(through, through_result, through_path):
    # trilinear spectra (no moment spectra) for the scan: several times cheaper per rotation
    corr, points, seat, dense = through
    scan = correlator_for_scene(through_path, rotation=False).spectra
    assert not scan.geometry.rotation and corr.spectra.geometry.rotation
    fast = find_fits(corr, SearchSettings(level=1, scan_modes=12, top=3), points=points,
                     scan=scan)
    assert _miss(fast.fits[0], seat, points, dense) < 2.0
    assert fast.fits[0].joint.kind == through_result.fits[0].joint.kind


def test_a_through_round_peg_is_found_top1_and_is_cylindrical_along_the_bore(through,
                                                                             through_result):
    _, points, seat, dense = through
    best = through_result.fits[0]
    assert _miss(best, seat, points, dense) < 2.0
    assert best.joint.kind == "cylindrical"
    (slide,) = best.joint.slides
    (axis, point), = best.joint.turns
    assert abs(slide[2]) > 0.97 and abs(axis[2]) > 0.97  # along the bore, z
    assert np.linalg.norm(point[:2]) < 1.0  # through the bore's axis
    assert 0.0 < best.joint.confidence <= 1.0


def test_the_result_says_what_it_did(through_result):
    r = through_result
    assert r.settings.rotations == 576 and r.lattice == 24
    assert r.candidates <= r.settings.keep and r.clusters >= len(r.fits) >= 1
    energies = [f.energy for f in r.fits]
    assert energies == sorted(energies) and [f.rank for f in r.fits] == list(
        range(1, len(r.fits) + 1))
    assert all(f.cluster_size >= 1 for f in r.fits)
    # fits that put the peg in one place were merged, whatever the peg's symmetry
    pts = np.random.default_rng(0).normal(size=(50, 3))
    for a in r.fits:
        for b in r.fits:
            if a is not b:
                assert set_distance(placed(pts, a.rotation, a.translation),
                                    placed(pts, b.rotation, b.translation)) > 0


def test_the_same_seed_and_settings_give_the_same_fits(through, through_result):
    corr, points, _, _ = through
    again = find_fits(corr, SearchSettings(level=1, scan_modes=12, top=3), points=points)
    assert len(again.fits) == len(through_result.fits)
    for a, b in zip(again.fits, through_result.fits, strict=True):
        assert np.array_equal(a.pose, b.pose) and a.energy == b.energy
        assert a.joint.kind == b.joint.kind


def test_progress_reports_fractions_and_time_left_and_cancel_stops(through):
    corr, points, _, _ = through
    seen = []
    find_fits(corr, SearchSettings(level=0, scan_modes=8, chunk=8, clusters=1, top=1),
              points=points, progress=lambda f, left: seen.append((f, left)))
    fractions = [f for f, _ in seen]
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert fractions == sorted(fractions)
    assert any(left is not None and left >= 0 for _, left in seen[1:-1])
    with pytest.raises(Cancelled):
        find_fits(corr, SearchSettings(level=0, scan_modes=8, chunk=8), points=points,
                  cancel=lambda: len(seen) > 0 and seen.append((0, 0)) is None and
                  len(seen) > 3)


@pytest.mark.slow
def test_the_bundled_peg_is_found_without_its_assembled_pose():
    # at its own settings (grid 56, K = 24): at grid 36 the energy itself prefers a tilted
    # peg beside the hole to the seat, which no search can mend
    scene, corr, points = _prepared(ASSETS / "peg_in_hole" / "scene.toml")
    result = find_fits(corr, SearchSettings(level=1, top=3), points=points)
    dense = _dense(ASSETS / "peg_in_hole" / "scene.toml")
    misses = [_miss(f, scene.assembled_pose, points, dense) for f in result.fits]
    assert min(misses) < 3.0, misses  # among the top 3, modulo the peg's symmetry
    best = result.fits[int(np.argmin(misses))]
    assert best.joint.kind == "revolute"
    (axis, _), = best.joint.turns
    assert abs(axis[2]) > 0.97


def _search_pair(path, level=1):
    _, corr, points = _prepared(path)
    scan = correlator_for_scene(path, rotation=False).spectra
    result = find_fits(corr, SearchSettings(level=level, scan_modes=12, top=3), points=points,
                       scan=scan)
    return corr, points, _dense(path), result


def test_a_box_in_a_pocket_at_a_random_rotation_is_found_and_rigid(tmp_path):
    from search_pairs import box_in_pocket

    from engine.pose import rotation_matrix
    from engine.search.refine import minimise

    turn = rotation_matrix(np.random.default_rng(7).normal(size=3))
    path, seat = box_in_pocket(tmp_path, turn)
    corr, points, dense, result = _search_pair(path)
    best = result.fits[0]
    # the energy's own minimum near the seat lies a little deeper than the pocket's floor
    # at this coarse grid (a fit's minimum past a blind floor): the search must find that
    seated = minimise(corr, rotation_matrix(seat[3:]), seat[:3], length=7.0)
    assert best.energy <= seated[2] + 1e-6 * abs(seated[2])
    assert _miss(best, seat, points, dense) < 8.0
    assert best.joint.kind == "rigid"


@pytest.mark.slow
def test_a_keyed_shaft_through_a_hub_is_found_and_prismatic_along_it(tmp_path):
    from search_pairs import keyed_through

    path, seat = keyed_through(tmp_path)
    _, points, dense, result = _search_pair(path)
    best = result.fits[0]
    assert _miss(best, seat, points, dense) < 2.0  # the key in its keyway, not turned away
    assert best.joint.kind == "prismatic"
    (slide,) = best.joint.slides
    assert abs(slide[2]) > 0.97
