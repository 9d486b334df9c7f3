"""The kept mode band is symmetric about zero at every K: symmetric pairs feel no side force.

A rectangular peg in a rectangular blind pocket, both mirror-symmetric about the planes
x = 0 and y = 0 (and so are their descriptor grids), is evaluated on its axis at several
depths and K, even and odd. By symmetry the exact correlation has no force across either
plane and no torque about x or y there. The lopsided band an even K kept before
(``-K/2 ... K/2 - 1``) gave this pair 219 and 76 mN sideways and 1,575 mN·mm of torque
at its seat at K = 8, against a thousandth of a mN with the symmetric band.
"""

from __future__ import annotations

import numpy as np
import pytest

SCENE = """name = "mirror-symmetric rectangular peg"
units = "mm"
assembled_pose = [0, 0, -12, 0, 0, 0]
insertion_axis = [0, 0, -1]
[descriptor]
grid = 24
[correlation]
modes = 8
[[part]]
name = "block"
file = "block.stl"
pose = [0, 0, 0, 0, 0, 0]
fixed = true
[[part]]
name = "peg"
file = "peg.stl"
pose = [0, 0, 5, 0, 0, 0]
"""


@pytest.fixture(scope="module")
def symmetric_scene(tmp_path_factory):
    trimesh = pytest.importorskip("trimesh")
    folder = tmp_path_factory.mktemp("mirror")
    block = trimesh.creation.box((30, 24, 20))
    block.apply_translation((0, 0, -10))
    pocket = trimesh.creation.box((10.2, 8.2, 12))
    pocket.apply_translation((0, 0, -6 + 0.001))
    block = block.difference(pocket)
    peg = trimesh.creation.box((10, 8, 20))
    peg.apply_translation((0, 0, 10))
    block.export(folder / "block.stl")
    peg.export(folder / "peg.stl")
    (folder / "scene.toml").write_text(SCENE)
    from engine.scene import load_scene

    return load_scene(folder / "scene.toml")


@pytest.mark.parametrize("band", ["box", "smooth"])
@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("modes", [7, 8, 9, 16])
def test_a_mirror_symmetric_pair_feels_no_side_force_or_tilting_torque(
        symmetric_scene, modes, backend, band):
    """With the box band of the tails as the grids cut them, and with the guidance's
    smooth band (a ball, Lanczos-tapered, of the windowed tails; docs/fine_level.md).
    """
    from engine.correlation.from_scene import correlator_for_scene

    corr = correlator_for_scene(symmetric_scene, modes=modes, backend=backend, band=band)
    # off the axis (along x) the pair does feel a side force and a tilting torque, far
    # above the float32 floor that the mirror plane y = 0 still leaves across it (at low K
    # the tapered band's side force is small: 0.25 of 336 at K = 8)
    off = corr.evaluate(np.eye(3), np.array([0.3, 0.0, -8.0]))
    assert abs(off.force[0]) > 100 * abs(off.force[1]) and abs(off.force[0]) > 0.1
    assert abs(off.torque[1]) > 100 * abs(off.torque[0]) and abs(off.torque[1]) > 1.0
    length = 20.0  # the peg's length: torque over force
    for depth in (-12.0, -8.0, -3.0):
        ev = corr.evaluate(np.eye(3), np.array([0.0, 0.0, depth]))
        scale = float(np.linalg.norm(ev.force))
        assert np.isfinite(scale) and abs(ev.force[2]) > 1.0
        # float32 sums leave a few parts in a million of the force
        assert np.all(np.abs(ev.force[:2]) < 1e-4 * scale), (modes, depth, ev.force)
        assert np.all(np.abs(ev.torque[:2]) < 1e-4 * scale * length), (modes, depth, ev.torque)


def test_the_landscape_of_a_mirror_symmetric_pair_is_mirror_symmetric(symmetric_scene):
    from engine.correlation.from_scene import correlator_for_scene

    corr = correlator_for_scene(symmetric_scene, modes=8, backend="numpy")
    land = corr.landscape(np.eye(3), modes=8, forces=False)
    energy = np.asarray(land.energy, dtype=np.float64)
    axes = [np.asarray(a) for a in land.translations]
    # the translations of the section are symmetric about 0 in x and y where the grid is
    for a in range(2):
        centre = int(np.argmin(np.abs(axes[a])))
        assert abs(axes[a][centre]) < 1e-9
        span = min(centre, len(axes[a]) - 1 - centre)
        lo = np.take(energy, range(centre - span, centre), axis=a)
        hi = np.take(energy, range(centre + span, centre, -1), axis=a)
        scale = np.max(np.abs(energy))
        np.testing.assert_allclose(lo, hi, atol=1e-4 * scale)
