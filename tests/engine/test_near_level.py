"""The fine level where the parts meet (engine.correlation.near, engine.sim.fine).

- With a window of 1 over everything part 2 can reach, the modal sum plus the fine level
  is the full discrete correlation, whatever K: checked against the brute-force spatial sum
  ``h^3 sum rho1[p] rho2[p - t]`` at lattice translations, for odd and even K (a band the
  level did not subtract exactly, such as the lopsided one of an even K, fails it).
- Its force and torque are the derivatives of its energy (central differences), at a
  turned pose, with part 2's density read from a finer grid blended into its own.
- Part 2's density is continuous where its fine region ends (a point swept across it).
- The level's extent and fineness follow from the fit; the simulation adds it to the field
  and follows the field's K.
"""

from __future__ import annotations

import numpy as np
import pytest

from engine.correlation.near import NearField, NearLevel, smooth_window, trilinear
from engine.grid import Grid
from engine.pose import rotation_matrix


@pytest.fixture(scope="module")
def pair(small_peg_scene):
    from engine.descriptor.store import descriptors_for_scene
    from engine.scene import load_scene

    scene = load_scene(small_peg_scene)
    d1, d2 = descriptors_for_scene(scene)[:2]
    return scene, d1, d2


def _covering_level(d1, d2, pad: int) -> tuple[NearLevel, Grid, np.ndarray]:
    """Part 1's samples in a grid ``pad`` cells larger (zeros there), window 1 everywhere."""
    h = d1.grid.spacing
    grid = Grid(tuple(np.asarray(d1.grid.origin) - pad * h), h,
                tuple(np.asarray(d1.grid.shape) + 2 * pad))
    rho1 = np.zeros(grid.shape, np.complex64)
    rho1[pad:-pad, pad:-pad, pad:-pad] = d1.rho
    everywhere = (np.full(3, -np.inf), np.full(3, np.inf), h)
    level = NearLevel.from_samples(grid, rho1, everywhere, None, None, d2.grid, d2.rho,
                                   np.zeros(d2.grid.shape), d2.grid, d2.rho, smooth=False)
    return level, grid, rho1


@pytest.mark.parametrize(("modes", "band"), [(5, "box"), (8, "box"), (11, "box"),
                                             (8, "smooth"), (11, "smooth")])
def test_modal_sum_plus_fine_level_is_the_full_correlation_at_any_k(pair, modes, band):
    from dataclasses import replace

    from engine.correlation import support
    from engine.correlation.from_scene import correlator_for_scene

    scene, d1, d2 = pair
    corr = correlator_for_scene(scene, modes=modes, backend="numpy", band=band)
    if band == "smooth":  # the band is of the densities with their tails shaped:
        # the level, and the sum it must complete, are of the same
        d1, d2 = (replace(d, rho=support.supported(d.rho, d.grid)) for d in (d1, d2))
    pad = max(d2.grid.shape)  # part 2's whole grid, at any of the translations below
    level, grid, rho1 = _covering_level(d1, d2, pad)
    near = NearField(level)
    assert near.follow(corr.table) and near.modes == modes
    h = d1.grid.spacing
    lattice = np.asarray(d1.grid.origin) - np.asarray(d2.grid.origin)
    points = grid.points().reshape(-1, 3)
    for cells in [(0, 0, 3), (1, -2, 6), (0, 0, 12)]:
        t = lattice + h * np.array(cells)
        rho2 = trilinear(d2.rho.astype(np.complex128), d2.grid, points - t)
        brute = -float((h ** 3 * np.sum(rho1.reshape(-1) * rho2)).real)  # E, kappa = 1
        coarse = corr.evaluate(np.eye(3), t).energy
        total = coarse + near.evaluate(np.eye(3), t).energy
        scale = h ** 3 * float(np.sum(np.abs(rho1.reshape(-1) * rho2)))
        # the modal sum alone is far off the full correlation; with the level it is exact
        assert abs(coarse - brute) > 1e-2 * scale, (cells, coarse, brute)
        assert total == pytest.approx(brute, abs=2e-5 * scale), (cells, total, brute)


def _fine_level(d1, d2, ratio: int = 2) -> NearLevel:
    """A level over the middle of part 1's grid, part 2 read from a finer grid where it meets."""
    g1, g2 = d1.grid, d2.grid
    h = g1.spacing
    lo1 = np.asarray(g1.origin) + 4 * h
    hi1 = g1.upper - 4 * h
    cells = np.round((hi1 - lo1) / h).astype(int)
    nodes = Grid(tuple(lo1), h, tuple(cells + 1))
    fixed = Grid(tuple(lo1), h / ratio, tuple(cells * ratio + 1))
    node_rho = trilinear(d1.rho.astype(np.complex128), g1, nodes.points().reshape(-1, 3))
    # fine samples: part 1's own interpolated, with a detail the nodes do not have
    rho1 = trilinear(d1.rho.astype(np.complex128), g1, fixed.points().reshape(-1, 3)) \
        * (1.0 + 0.2 * np.cos(fixed.points().reshape(-1, 3) @ np.array([2.1, 1.7, 0.9]) / h))
    window = (lo1 + 2 * h, hi1 - 2 * h, 2 * h)
    lo2 = np.asarray(g2.origin) + 3 * h
    moving = Grid(tuple(lo2), h / ratio,
                  tuple((np.asarray(g2.shape) - 7) * ratio + 1))
    wave = np.exp(1j * moving.points() @ np.array([1.3, 0.7, 2.1]) / h)  # a detail
    rho2 = trilinear(d2.rho.astype(np.complex128), g2, moving.points().reshape(-1, 3)
                     ).reshape(moving.shape) * (1.0 + 0.3 * wave)
    window2 = smooth_window(moving, lo2 + 2 * h, moving.upper - 2 * h, 2 * h)
    return NearLevel.from_samples(nodes, node_rho.reshape(nodes.shape), window, fixed,
                                  rho1.reshape(fixed.shape), moving, rho2, window2, g2, d2.rho)


def test_force_and_torque_are_the_energys_derivatives(pair):
    scene, d1, d2 = pair
    near = NearField(_fine_level(d1, d2), kappa=2.5)
    near.prepare("no band", None, 0)
    assert near.terms > 1000 and len(near._fine_points) > 100  # both tiers
    rotvec = np.array([0.05, -0.08, 0.11])
    t = np.asarray(scene.assembled_pose[:3], float) + np.array([0.13, -0.07, 3.1])
    ev = near.evaluate(rotation_matrix(rotvec), t)
    assert abs(ev.energy) > 0 and np.linalg.norm(ev.force) > 0
    step = 1e-4 * d1.grid.spacing
    for i in range(3):
        d = np.zeros(3)
        d[i] = step
        de = (near.evaluate(rotation_matrix(rotvec), t + d).energy
              - near.evaluate(rotation_matrix(rotvec), t - d).energy) / (2 * step)
        assert -de == pytest.approx(ev.force[i], rel=2e-3, abs=2e-3 * np.linalg.norm(ev.force))
    a = 1e-5
    for i in range(3):  # theta about world axes through part 2's origin: R -> exp(theta) R
        d = np.zeros(3)
        d[i] = a
        rp = rotation_matrix(d) @ rotation_matrix(rotvec)
        rm = rotation_matrix(-d) @ rotation_matrix(rotvec)
        de = (near.evaluate(rp, t).energy - near.evaluate(rm, t).energy) / (2 * a)
        assert -de == pytest.approx(ev.torque[i], rel=2e-3,
                                    abs=2e-3 * np.linalg.norm(ev.torque))


def test_part_2s_density_is_continuous_where_its_fine_region_ends(pair):
    _, d1, d2 = pair
    level = _fine_level(d1, d2)
    moving = level.moving_grid
    # one mass of part 1, seen from part 2's frame sweeping across the fine region's edge
    p = np.zeros(3)
    y, z = moving.centre[1], moving.centre[2]
    xs = np.linspace(moving.origin[0] - 2 * moving.spacing,
                     moving.origin[0] + 2 * moving.spacing, 401)
    near = NearField(level)
    near._points = p.reshape(1, 3)
    near._masses = np.array([[1.0, 0.3]], np.float32)
    near._key = "one mass"
    energy = np.array([near.raw(np.eye(3), -np.array([x, y, z]))[0] for x in xs])
    jumps = np.abs(np.diff(energy))
    typical = np.median(jumps)
    assert typical > 0
    # continuous: no step is much larger than the slope's, at the edge or anywhere
    assert jumps.max() < 20 * typical, (jumps.max(), typical)
    # and the fine grid does serve inside: the values differ from the coarse ones there
    inside = trilinear(d2.rho.astype(np.complex128), d2.grid, np.array([[xs[-1], y, z]]))[0]
    assert abs(energy[-1] - (1.0 * inside.real - 0.3 * inside.imag)) > 1e-6 * abs(inside)


def test_a_smaller_fit_gets_a_finer_level():
    from engine.sim.fine import MAX_RATIO, fine_ratio

    h = 1.0
    big = fine_ratio(np.zeros(3), np.full(3, 60.0), h)
    mid = fine_ratio(np.zeros(3), np.full(3, 20.0), h)
    small = fine_ratio(np.zeros(3), np.full(3, 8.0), h)
    assert big == 1 and big < mid <= small == MAX_RATIO


def test_the_simulation_adds_the_level_and_follows_k(small_peg_scene):
    from engine.runtime import open_scene
    from engine.sim import build_simulation

    handle = open_scene(small_peg_scene)
    sim, _ = build_simulation(handle, backend="numpy")
    near = sim.near
    assert near is not None
    rot, origin = np.eye(3), np.asarray(handle.scene.assembled_pose[:3], float)
    sim.reset(np.r_[origin, 0.0, 0.0, 0.0])
    total = sim.evaluate_field()
    assert near.terms > 0 and near.modes == sim.field.modes
    alone = sim.field.evaluate(rot, sim.state.origin(sim.body))
    extra = near.evaluate(rot, sim.state.origin(sim.body))
    assert total.energy == pytest.approx(alone.energy + extra.energy)
    assert np.allclose(total.force, alone.force + extra.force)
    assert abs(extra.energy) > 1e-3 * abs(alone.energy)
    sim.field.set_modes(sim.field.modes + 2)
    sim.field_changed()
    sim.evaluate_field()
    assert near.modes == sim.field.modes


def test_the_engine_loop_adds_the_level_in_the_background_and_keeps_it_for_a_new_k(
        small_peg_scene):
    import time

    import engine.runtime as rt
    from engine.sim import build_simulation

    handle = rt.open_scene(small_peg_scene)
    sim, model = build_simulation(handle, modes=8, backend="numba", prepare=False)
    loop = rt.EngineLoop(sim, model=model, realtime=False, prepare=True)
    try:
        end = time.monotonic() + 120.0
        while sim.near is None and time.monotonic() < end:
            loop.run(max_steps=20)
        near = sim.near
        assert near is not None, "no fine level within two minutes"
        loop.run(max_steps=5)
        assert near.modes == 8 and near.terms > 0
        loop.send(rt.SetModes(12))
        end = time.monotonic() + 60.0
        while sim.field.modes != 12 and time.monotonic() < end:
            loop.run(max_steps=20)
        loop.run(max_steps=5)
        assert sim.field.modes == 12 and sim.near is near and near.modes == 12
    finally:
        loop.guidance.close()


def test_a_free_part_keeps_its_energy_with_the_level(monkeypatch):
    """The bundled peg, free (no proxy, no damping), tilted and dropped into its hole at
    K = 16 with the fine level: 2 s at 1 ms, the total energy within 5 % of the largest
    kinetic energy (measured 2.3 %; 0.7 % without the level, whose force steps at its cells'
    faces). In the box band's field, whose deep well throws the peg about (largest kinetic
    energy 38,807). In the guidance's smooth band the same drop reaches 2,266 and the
    level's steps cost 153 of it, 6.8 % (873 in the box band's): docs/fine_level.md;
    tests/engine/test_walls.py drops a peg onto its floor in the smooth band.
    """
    from dataclasses import replace
    from pathlib import Path

    import engine.params
    from engine.runtime import open_scene

    monkeypatch.setattr(engine.params, "GUIDANCE_BAND", "box")
    from engine.sim import build_simulation, kinetic_energy

    peg = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"
    handle = open_scene(peg)
    cfg = handle.config
    effects = replace(cfg.effects, damping=False, axes=("x", "y", "z", "rx", "ry", "rz"))
    handle = replace(handle, config=replace(cfg, effects=effects),
                     start_pose=np.array([0.3, 0.0, -12.0, 0.03, -0.02, 0.0]))
    sim, _ = build_simulation(handle, prepare=True, coupled=False, modes=16)
    assert sim.near is not None
    # the correlation's level alone (the peg's end lies below the plate, out of the box:
    # no walls; tests/engine/test_walls.py drops a peg onto a floor with them)
    assert sim.near.walls is None
    sim.evaluate_field()
    e0 = sim.total_energy()
    energy, kinetic = [], []
    for _ in range(2000):
        sim.step()
        energy.append(sim.total_energy())
        kinetic.append(kinetic_energy(sim.body, sim.state))
    scale = max(kinetic)
    assert scale > 1000.0
    assert np.max(np.abs(np.asarray(energy) - e0)) < 0.05 * scale


def test_closeness_is_one_in_the_fit_and_falls_smoothly_to_zero_half_a_box_away():
    from types import SimpleNamespace

    from engine.correlation.near import NearField
    from engine.pose import rotation_matrix

    lo, hi = np.array([0.0, 0.0, 0.0]), np.array([4.0, 2.0, 10.0])  # reach: 5
    anchor = np.array([1.0, -2.0, 0.5])  # part 2's point at the box's centre at the seat
    turn = rotation_matrix(np.array([0.3, -0.2, 0.9]))
    seat = np.array([2.0, 1.0, 5.0]) - turn @ anchor

    def at(*shift, anchored=True):
        level = SimpleNamespace(window_box=(lo, hi, 1.0), anchor=anchor if anchored else None)
        return NearField.closeness(SimpleNamespace(level=level), turn,
                                   seat + np.array(shift, float))

    assert at(0, 0, 0) == 1.0 and at(2.0, -1.0, 5.0) == 1.0  # seated, on the box's edge
    assert at(0, 0, 5.0 + 2.5) == pytest.approx(0.5)         # half the reach beyond
    assert at(0, -4.0, 9.0) == pytest.approx(0.0)              # 5 away, diagonally
    assert at(-9.0, 0, 0) == 0.0
    ramp = [at(0, 0, 5.0 + d) for d in np.linspace(0.0, 5.0, 51)]
    assert all(a >= b for a, b in zip(ramp[:-1], ramp[1:], strict=True))  # falls
    assert ramp[1] > 0.99 and ramp[-2] < 0.01                # flat at both ends (C1)
    assert at(0, 0, 100.0, anchored=False) == 1.0            # no anchor: near


def test_the_shells_factor_is_one_in_and_near_part_1_and_zero_far_out_of_it():
    from engine.correlation.near import SurfaceShell

    grid = Grid((-4.0, -4.0, -4.0), 0.5, (17, 17, 17))
    distance = np.broadcast_to(grid.axes()[2][None, None, :], grid.shape).astype(np.float32)
    shell = SurfaceShell(grid, distance, reach=1.0, taper=1.0)
    z = np.array([0.0, 0.9, -0.9, 1.5, -1.5, 2.0, -2.5, 3.5, -3.5])
    w = shell.weight(np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=-1))
    assert np.allclose(w, [1.0, 1.0, 1.0, 0.5, 1.0, 0.0, 1.0, 0.0, 1.0])


def test_the_levels_window_keeps_to_a_shell_about_part_1s_surface(small_peg_scene):
    """Built for a scene, the level's window is the plain one inside part 1 and out to the
    shell's reach, and zero beyond its taper out of part 1 (in open space).
    """
    from dataclasses import replace

    from engine.runtime import open_scene
    from engine.sim import build_simulation

    handle = open_scene(small_peg_scene)
    sim, _ = build_simulation(handle, backend="numpy")
    level = sim.near.level
    shell = level.surface
    assert shell is not None and shell.reach > 0 and shell.taper > 0
    nodes = level.fixed_nodes
    d = trilinear(np.asarray(shell.distance, np.float64), shell.grid,
                  nodes.points().reshape(-1, 3)).reshape(nodes.shape)
    w, plain = level.window(nodes), replace(level, surface=None).window(nodes)
    kept = (d <= shell.reach) & (plain > 0)
    far = (d >= shell.reach + shell.taper) & (plain > 0)
    assert kept.any() and far.any() and (kept & (d < -shell.reach - shell.taper)).any()
    assert np.allclose(w[kept], plain[kept]) and np.all(w[far] == 0.0)
