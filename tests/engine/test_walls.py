"""The walls: part 2's point shell against part 1's signed distance (engine.correlation.walls).

Against closed forms on a flat face, finite differences of the energy, and the simulation:
the walls' stiffness follows the part's mass and the step, a part dropped into its hole
gains no energy from them (the passivity observer), and they hold a peg at a floor that
the skeletal energy alone lets it pass.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from engine.correlation.walls import WALL_STEPS, Walls, WallShell, surface_points
from engine.descriptor.compute import signed_distance
from engine.grid import Grid
from engine.pose import rotation_matrix


def _floor_and_block(spacing: float = 0.25) -> tuple[Walls, trimesh.Trimesh]:
    """A slab whose top face is z = 0 (20 x 20 x 10) and a 4 mm cube's shell over it."""
    slab = trimesh.creation.box(extents=(20.0, 20.0, 10.0))
    slab.apply_translation((0.0, 0.0, -5.0))
    grid = Grid((-6.0, -6.0, -3.0), spacing, (49, 49, 25))
    distance = signed_distance(slab.vertices, slab.faces,
                               grid.points().reshape(-1, 3)).reshape(grid.shape)
    cube = trimesh.creation.box(extents=(4.0, 4.0, 4.0))
    shell = WallShell.on(grid, distance, cube.vertices, cube.faces,
                         (np.full(3, -3.0), np.full(3, 3.0)))
    return Walls(shell, stiffness=1000.0), cube


def test_the_shell_is_uniform_over_the_area():
    cube = trimesh.creation.box(extents=(4.0, 4.0, 2.0))  # faces of 16 and 8 mm^2
    p = surface_points(cube.vertices, cube.faces, 60_000, seed=3)
    assert np.allclose(np.abs(p).max(axis=0), (2.0, 2.0, 1.0))
    top = np.count_nonzero(np.isclose(p[:, 2], 1.0))
    side = np.count_nonzero(np.isclose(p[:, 0], 2.0))
    area = 2 * 16 + 4 * 8
    assert top / len(p) == pytest.approx(16 / area, rel=0.05)
    assert side / len(p) == pytest.approx(8 / area, rel=0.05)
    again = surface_points(cube.vertices, cube.faces, 60_000, seed=3)
    assert np.array_equal(p, again)


def test_a_face_pushes_back_as_its_share_of_the_shell():
    walls, _ = _floor_and_block()
    n = walls.terms
    assert n > 10_000
    # clear of the face: nothing; the cube's bottom face d below it: its share of the shell
    # (a sixth of the area) times the stiffness times d, and the side strips below the
    # face half as much over their depth
    assert np.all(walls.raw(np.eye(3), np.array([0.3, -0.2, 2.05])) == 0.0)
    for d in (0.02, 0.1):
        s = walls.raw(np.eye(3), np.array([0.3, -0.2, 2.0 - d]))
        expected = walls.stiffness * d * (1 / 6) * (1 + d / 2)
        assert s[3] == pytest.approx(expected, rel=0.05)
        assert abs(s[1]) < 0.02 * s[3] and abs(s[2]) < 0.02 * s[3]
        assert s[0] == pytest.approx(0.5 * walls.stiffness * d * d / 6, rel=0.08)


def test_with_an_insertion_axis_the_shell_is_the_leading_faces():
    from engine.correlation.walls import LEADING

    walls, cube = _floor_and_block()
    shell = walls.shell
    down = WallShell.on(shell.grid, shell.distance, cube.vertices, cube.faces,
                        (np.full(3, -3.0), np.full(3, 3.0)), lead=np.array([0.0, 0.0, -2.0]))
    assert LEADING is not None
    assert np.allclose(down.points[:, 2], -2.0)  # the cube's bottom face alone
    # the face has the points the whole surface had: three times as dense or more
    assert len(down.points) > 3 * walls.terms / 6
    # the whole shell on the face: the face is as stiff as the walls
    lead = Walls(down, stiffness=1000.0)
    s = lead.raw(np.eye(3), np.array([0.3, -0.2, 1.9]))
    assert s[3] == pytest.approx(1000.0 * 0.1, rel=1e-3)
    # a part moving sideways leads with a side: the bottom face is not in the shell
    side = WallShell.on(shell.grid, shell.distance, cube.vertices, cube.faces,
                        (np.full(3, -3.0), np.full(3, 3.0)), lead=np.array([1.0, 0.0, 0.0]))
    assert np.allclose(side.points[:, 0], 2.0)


def test_the_level_sets_part_1s_stop_faces_back_by_the_depth_asked():
    """A slab (top face z = 0) that part 2 comes down onto: under its top face, down to
    the depth, each sample takes the density as far above the face as it is below (at
    least a cell above, where no sample inside reaches the interpolant); deeper
    samples, samples under its side faces (their normals across the axis) and samples
    outside keep theirs. Along a sideways axis nothing faces against it and nothing moves.
    """
    from engine.sim.fine import STOP_REACH_CELLS, set_back_stops

    slab = trimesh.creation.box(extents=(20.0, 20.0, 10.0))
    slab.apply_translation((0.0, 0.0, -5.0))
    grid = Grid((-12.0, -3.0, -3.1), 0.25, (97, 25, 25))  # no node on the face
    p = grid.points()
    distance = signed_distance(slab.vertices, slab.faces,
                               p.reshape(-1, 3)).reshape(grid.shape)
    inside = distance < 0
    # outside: linear in z (trilinear reads it exactly); inside: a constant
    rho = np.where(inside, 3.0j, -1.0j * (1.0 + p[..., 2]) + 0.1 * p[..., 0])
    depth = 0.6
    out = set_back_stops(rho, grid, distance, np.array([0.0, 0.0, -1.0]), depth)
    under_top = inside & (p[..., 2] > -depth) & (np.abs(p[..., 0]) < 10.0 - depth)
    assert under_top.sum() > 1000
    z, x = p[..., 2][under_top], p[..., 0][under_top]
    np.testing.assert_allclose(out[under_top], -1.0j * (1.0 + np.maximum(-z, 0.25))
                               + 0.1 * x, atol=1e-9)
    beside = inside & (np.abs(p[..., 0]) > 10.0 - 0.3) & (p[..., 2] < -0.3)
    assert beside.sum() > 100  # under the slab's sides x = +-10, down the axis
    kept = ~under_top
    np.testing.assert_array_equal(out[kept & ~inside], rho[kept & ~inside])
    np.testing.assert_array_equal(out[inside & (p[..., 2] < -depth - 1e-9)],
                                  rho[inside & (p[..., 2] < -depth - 1e-9)])
    np.testing.assert_array_equal(out[beside], rho[beside])
    sideways = set_back_stops(rho, grid, distance, np.array([0.0, 1.0, 0.0]), depth)
    np.testing.assert_array_equal(sideways, rho)
    # part 2 rests on the top only where x < -2: elsewhere the top is a rim, kept
    u, v = np.meshgrid(np.linspace(-8.0, -2.0, 61), np.linspace(-3.0, 3.0, 61))
    seated = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)
    rim = set_back_stops(rho, grid, distance, np.array([0.0, 0.0, -1.0]), depth, seated)
    x_all = p[..., 0]
    rests = under_top & (x_all > -7.5) & (x_all < -2.0)
    assert rests.sum() > 300
    np.testing.assert_array_equal(rim[rests], out[rests])
    away = under_top & (x_all > -2.0 + STOP_REACH_CELLS * 0.25 + 1e-9)
    assert away.sum() > 300
    np.testing.assert_array_equal(rim[away], rho[away])


def test_the_force_and_torque_are_the_energys_derivatives():
    walls, _ = _floor_and_block()
    rot = rotation_matrix(np.array([0.05, -0.03, 0.1]))
    t = np.array([0.3, -0.2, 1.9])
    s = walls.raw(rot, t)
    assert s[0] > 0
    eps = 1e-5
    for k in range(3):
        step = np.zeros(3)
        step[k] = eps
        de = walls.raw(rot, t + step)[0] - walls.raw(rot, t - step)[0]
        assert -de / (2 * eps) == pytest.approx(s[1 + k], rel=1e-3, abs=1e-6 * walls.stiffness)
        turn_p = rotation_matrix(step) @ rot
        turn_m = rotation_matrix(-step) @ rot
        de = walls.raw(turn_p, t)[0] - walls.raw(turn_m, t)[0]
        assert -de / (2 * eps) == pytest.approx(s[4 + k], rel=1e-3, abs=1e-6 * walls.stiffness)


def test_the_observer_books_the_energy_a_step_makes():
    walls, _ = _floor_and_block()
    rot = np.eye(3)
    # pressed in and let out along the face's normal, in steps: the trapezoid's work
    # against the energy given up; a jump books nothing
    made = []
    for z in np.r_[np.linspace(2.1, 1.85, 26), np.linspace(1.85, 2.1, 26)]:
        made.append(walls.evaluate(rot, np.array([0.0, 0.0, z])).switched)
    assert made[0] == 0.0
    stiff = walls.stiffness / 6
    # entering: the step the bottom face crosses z = 0 on makes energy (its force starts
    # mid-step); over the way in and out the books close to within the side strips' share
    assert max(made) > 0
    assert abs(sum(made)) < 0.05 * 0.5 * stiff * 0.15 ** 2
    far = walls.evaluate(rot, np.array([0.0, 0.0, 0.5]))
    assert far.switched == 0.0


def test_the_stiffness_follows_the_mass_and_the_step():
    walls, _ = _floor_and_block()
    walls.for_body(2.0, 1e-3)
    assert walls.stiffness == pytest.approx(WALL_STEPS * 2.0 / 1e-6)
    walls.for_body(2.0, 2e-3)
    assert walls.stiffness == pytest.approx(WALL_STEPS * 2.0 / 4e-6)
    # all points in contact at once stay within the velocity Verlet's limit
    assert math.sqrt(WALL_STEPS) < 2.0


@pytest.fixture(scope="module")
def dropped_peg(tmp_path_factory):
    """A 5.8 mm peg over a 6 mm blind bore (6 mm deep), free (no proxy, no damping), tilted
    and dropped towards its floor: the scene as a user writes it, the rest chosen.
    """
    from dataclasses import replace

    from engine.runtime import open_scene
    from engine.sim import build_simulation

    folder = tmp_path_factory.mktemp("blind")
    block = trimesh.creation.box(extents=(20.0, 20.0, 10.0))
    block.apply_translation((0.0, 0.0, -5.0))
    bore = trimesh.creation.cylinder(radius=3.0, height=12.0, sections=48)
    bore.apply_translation((0.0, 0.0, 0.0))  # from z = -6 to 6: 6 mm into the block
    block.difference(bore).export(folder / "block.stl")
    peg = trimesh.creation.cylinder(radius=2.9, height=10.0, sections=48)
    peg.apply_translation((0.0, 0.0, 5.0))  # its end at its origin
    peg.export(folder / "peg.stl")
    (folder / "scene.toml").write_text(
        'name = "blind"\nunits = "mm"\nassembled_pose = [0, 0, -6, 0, 0, 0]\n'
        "insertion_axis = [0, 0, -1]\n\n"
        '[[part]]\nname = "block"\nfile = "block.stl"\npose = [0, 0, 0, 0, 0, 0]\n'
        "fixed = true\n\n"
        '[[part]]\nname = "peg"\nfile = "peg.stl"\npose = [0, 0, 8, 0, 0, 0]\n')
    handle = open_scene(folder / "scene.toml")
    cfg = handle.config
    effects = replace(cfg.effects, damping=False, axes=("x", "y", "z", "rx", "ry", "rz"))
    handle = replace(handle, config=replace(cfg, effects=effects),
                     start_pose=np.array([0.02, 0.0, -4.0, 0.002, -0.001, 0.0]))
    sim, _ = build_simulation(handle, prepare=True, coupled=False)
    return sim


def test_the_simulation_gives_the_walls_its_mass_and_step(dropped_peg):
    sim = dropped_peg
    walls = sim.near.walls
    assert walls is not None and walls.terms > 1000
    assert np.allclose(walls.shell.points[:, 2], 0.0, atol=1e-9)  # the peg's end alone
    assert walls.stiffness == pytest.approx(WALL_STEPS * sim.body.mass / sim.dt ** 2)
    dt = sim.dt
    try:
        sim.dt = 2 * dt
        assert walls.stiffness == pytest.approx(WALL_STEPS * sim.body.mass / (2 * dt) ** 2)
    finally:
        sim.dt = dt


def test_a_peg_dropped_onto_its_floor_gains_no_energy_from_the_walls(dropped_peg):
    """2 s free (no proxy, no damping): the guidance pulls the peg onto its floor, whose
    walls throw it back, again and again. Averaged over the last half second the total
    energy is not above its start by 5 % of the largest kinetic energy (measured: 4 to 15 %
    below; 25 % above, its floor set back, when the observer took a step of more than a
    cell for a jump). At the deepest of a bounce the step's stored energy reads up to 17 % above
    (a stiff spring's, returned as it lets go), so the average, not the peak, is judged.
    Without the walls the peg sinks 2.2 mm into its floor.
    """
    from engine.sim import kinetic_energy

    sim = dropped_peg
    sim.reset()
    sim.evaluate_field()
    e0 = sim.total_energy()
    energy, kinetic, touched, lowest = [], [], 0, np.inf
    for _ in range(2000):
        sim.step()
        energy.append(sim.total_energy())
        kinetic.append(kinetic_energy(sim.body, sim.state))
        touched += sim.near.walls.raw(sim.state.rotation, sim.state.origin(sim.body))[0] > 0
        lowest = min(lowest, float(sim.part_pose()[2]))
    scale = max(kinetic)
    assert scale > 1000.0 and touched > 100
    assert np.mean(energy[-500:]) - e0 < 0.05 * scale
    assert lowest > -6.0 - 1.0  # the floor at z = -6 held (2.2 mm past without walls)
