"""The torque is continuous where a seated part rests: at R = I and at the half turns.

Rotations that map the frequency lattice onto itself (the identity, a seated part's
relative rotation, and the half turns about the axes) put every kept mode exactly on a
node of part 2's interpolation table, and a rotation a hair away puts it in any of the
eight cells around that node. These tests check the interpolant's properties that make the
torque continuous there (cubic Hermite along every lattice line: it takes the node's own
derivatives at every node), and the torque itself: equal at rotations of -1e-9 and +1e-9
rad, equal to the central difference of the energy, on the numpy reference, the numba
kernel and the OpenCL kernel, on the refined table (small K) and on the plain lattice
(K beyond it). The bundled pairs at K = 24 and 48 are in ``test_correlation_scenes.py``.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

from engine.correlation import Correlator, interpolation
from engine.grid import Grid
from engine.pose import rotation_matrix

H = 0.5
GRID1 = Grid((-4.0, -4.0, -4.0), H, (17, 17, 17))
GRID2 = Grid((-3.0, -3.5, -3.0), H, (13, 15, 13))
# off-centre, anisotropic blobs, so the torque at R = I is far from zero on every axis
BLOBS1 = [(1 + 2j, (0.6, -0.4, 0.2), (1.0, 0.6, 0.8)), (-0.5j, (-1.0, 0.8, -0.5), (0.7, 0.9, 0.5))]
BLOBS2 = [(0.5 - 1j, (0.4, 0.3, -0.6), (0.9, 0.5, 0.7)), (1j, (-0.8, 0.5, 0.4), (0.6, 0.8, 0.9))]

#: The rotations that put every mode on a lattice node.
HALF_TURNS = {"identity": (0.0, 0.0, 0.0), "x": (np.pi, 0.0, 0.0), "y": (0.0, np.pi, 0.0),
              "z": (0.0, 0.0, np.pi)}

RADIUS, SIDE = 3, 8


def field(grid: Grid, blobs) -> np.ndarray:
    """(nx, ny, nz) complex64 samples of a sum of axis-aligned anisotropic Gaussians."""
    p = grid.points()
    out = np.zeros(grid.shape, dtype=complex)
    for a, mu, s in blobs:
        out += a * np.exp(-0.5 * np.sum(((p - np.asarray(mu)) / np.asarray(s)) ** 2, axis=-1))
    return out.astype(np.complex64)


def descriptor(grid: Grid, blobs):
    return types.SimpleNamespace(rho=field(grid, blobs), grid=grid)


@pytest.fixture(scope="module")
def pair():
    """A correlator on the numpy reference; K = 8 reads the refined table."""
    return Correlator(descriptor(GRID1, BLOBS1), descriptor(GRID2, BLOBS2), modes=8,
                      backend="numpy", use_cache=False)


# ------------------------------------------------------------------ the interpolant
def _row(node) -> int:
    """Row of lattice node ``node`` (integers) in a (SIDE^3, 8) table of radius RADIUS."""
    ix, iy, iz = (int(v) + RADIUS for v in node)
    return (ix * SIDE + iy) * SIDE + iz


def test_hermite_reproduces_cubic_polynomials():
    """Value and gradient exact for every polynomial of degree 3 (not only quadratics)."""
    rng = np.random.default_rng(2)
    powers = [(i, j, k) for i in range(4) for j in range(4) for k in range(4) if i + j + k <= 3]
    coeff = rng.normal(size=len(powers))

    def poly(x, y, z, d=(0, 0, 0)):
        total = 0.0
        for c, (i, j, k) in zip(coeff, powers, strict=True):
            term = c
            for p, v, n in ((i, x, d[0]), (j, y, d[1]), (k, z, d[2])):
                if n:
                    term = term * p * v ** max(p - 1, 0) if p else 0.0
                else:
                    term = term * v**p
            total += term
        return total

    idx = np.arange(-RADIUS, RADIUS + 2)
    x, y, z = np.meshgrid(idx, idx, idx, indexing="ij")
    table = np.zeros((SIDE, SIDE, SIDE, 8))
    table[..., 1] = poly(x, y, z)
    for a in range(3):
        table[..., 3 + 2 * a] = poly(x, y, z, tuple(int(b == a) for b in range(3)))
    table = table.reshape(-1, 8)
    for u in rng.uniform(-RADIUS + 0.5, RADIUS - 0.5, size=(50, 3)):
        got = interpolation.hermite(table, 1, interpolation.cell(*u, RADIUS, SIDE))
        expected = [poly(*u)] + [poly(*u, tuple(int(b == a) for b in range(3)))
                                 for a in range(3)]
        np.testing.assert_allclose(got, expected, atol=1e-9)


def test_hermite_gradient_is_the_node_derivative_from_every_cell():
    """At a node, each of the eight cells around it gives the node's own derivatives.

    This is what keeps the torque continuous where every mode sits on a node; the
    interpolant before (quadratic corrections) gave one-sided gradients differing by
    about the table's third differences.
    """
    rng = np.random.default_rng(3)
    table = rng.normal(size=(SIDE**3, 8))
    for node in rng.integers(-RADIUS + 1, RADIUS, size=(6, 3)).astype(float):
        expected = table[_row(node), [1, 3, 5, 7]]
        for signs in np.ndindex(2, 2, 2):
            u = node + 1e-12 * (2 * np.array(signs) - 1)
            got = interpolation.hermite(table, 1, interpolation.cell(*u, RADIUS, SIDE))
            np.testing.assert_allclose(got, expected, atol=1e-9)


def test_hermite_is_continuous_across_faces():
    """Value and the derivatives along a face agree from both cells (random table)."""
    rng = np.random.default_rng(4)
    table = rng.normal(size=(SIDE**3, 8))
    for axis in range(3):
        for _ in range(5):
            u = rng.uniform(-RADIUS + 1, RADIUS - 1, size=3)
            u[axis] = float(rng.integers(-RADIUS + 1, RADIUS))
            step = np.zeros(3)
            step[axis] = 1e-12
            below = interpolation.hermite(table, 0, interpolation.cell(*(u - step), RADIUS, SIDE))
            above = interpolation.hermite(table, 0, interpolation.cell(*(u + step), RADIUS, SIDE))
            along = [0] + [1 + a for a in range(3) if a != axis]
            np.testing.assert_allclose(np.take(below, along), np.take(above, along), atol=1e-9)


# ------------------------------------------------------------------ torque and force
def _torque_difference(corr, rot, t, eps):
    """``-dE/dtheta`` by central differences under ``R -> exp([theta]x) R``."""
    fd = np.empty(3)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        plus = corr.evaluate(rotation_matrix(d) @ rot, t).energy
        minus = corr.evaluate(rotation_matrix(-d) @ rot, t).energy
        fd[a] = -(plus - minus) / (2 * eps)
    return fd


def _force_difference(corr, rot, t, eps):
    fd = np.empty(3)
    for a in range(3):
        d = np.zeros(3)
        d[a] = eps
        fd[a] = -(corr.evaluate(rot, t + d).energy - corr.evaluate(rot, t - d).energy) / (2 * eps)
    return fd


def check_smooth_at(corr, rot, t, *, tolerance):
    """Torque and force at ``rot`` are one-sided-equal and central differences of E.

    Each axis: rotations by -1e-9 and +1e-9 rad give the same torque (to 1e-5 of |T|), and
    the torque equals the central difference of the energy (step 1e-4 rad) to
    ``tolerance`` of |T|; the force likewise against the central difference in ``t``.
    """
    ev = corr.evaluate(rot, t)
    scale_t = np.linalg.norm(ev.torque)
    scale_f = np.linalg.norm(ev.force)
    assert scale_t > 0 and scale_f > 0
    for a in range(3):
        d = np.zeros(3)
        d[a] = 1e-9
        minus = corr.evaluate(rotation_matrix(-d) @ rot, t)
        plus = corr.evaluate(rotation_matrix(d) @ rot, t)
        assert np.linalg.norm(plus.torque - minus.torque) < 1e-5 * scale_t, a
        assert np.linalg.norm(plus.force - minus.force) < 1e-5 * scale_f, a
    fd_torque = _torque_difference(corr, rot, t, 1e-4)
    assert np.linalg.norm(ev.torque - fd_torque) < tolerance * scale_t
    fd_force = _force_difference(corr, rot, t, 1e-4 * H)
    assert np.linalg.norm(ev.force - fd_force) < tolerance * scale_f


@pytest.mark.parametrize("turn", list(HALF_TURNS))
@pytest.mark.parametrize("modes", [8, 26])  # the refined table; the plain lattice
def test_torque_is_continuous_at_lattice_rotations(pair, turn, modes):
    corr = pair.with_modes(modes)
    assert corr.table.fine == (modes == 8)
    rot = rotation_matrix(np.asarray(HALF_TURNS[turn]))
    check_smooth_at(corr, rot, np.array([0.4, -0.3, 0.25]), tolerance=1e-3)


@pytest.mark.parametrize("turn", list(HALF_TURNS))
def test_numba_torque_is_continuous_at_lattice_rotations(pair, turn):
    """The compiled kernel, float32 tables: the same to its precision."""
    corr = pair.with_modes(12)
    corr.use_backend("numba")
    rot = rotation_matrix(np.asarray(HALF_TURNS[turn]))
    t = np.array([0.4, -0.3, 0.25])
    check_smooth_at(corr, rot, t, tolerance=1e-3)
    ref = pair.with_modes(12).evaluate(rot, t)
    got = corr.evaluate(rot, t)
    np.testing.assert_allclose(got.torque, ref.torque, atol=1e-5 * np.linalg.norm(ref.torque))


@pytest.mark.parametrize("turn", list(HALF_TURNS))
def test_opencl_agrees_with_numpy_at_lattice_rotations(pair, turn, opencl_backend):
    """The OpenCL kernel (float32 pose) at and a hair off the node-hitting rotations."""
    corr = pair.with_modes(12)
    try:
        corr.use_backend("opencl")
    except Exception as exc:  # noqa: BLE001 - no usable OpenCL device here
        pytest.skip(f"OpenCL kernel cannot run here: {str(exc).splitlines()[0]}")
    reference = pair.with_modes(12)
    t = np.array([0.4, -0.3, 0.25])
    for angle in (-1e-9, 0.0, 1e-9):
        rot = rotation_matrix(np.array([angle, -angle, angle])) @ rotation_matrix(
            np.asarray(HALF_TURNS[turn]))
        got, ref = corr.evaluate(rot, t), reference.evaluate(rot, t)
        assert got.energy == pytest.approx(ref.energy, rel=1e-4)
        np.testing.assert_allclose(got.force, ref.force, atol=1e-4 * np.linalg.norm(ref.force))
        np.testing.assert_allclose(got.torque, ref.torque,
                                   atol=1e-4 * np.linalg.norm(ref.torque))


def test_landscape_force_is_continuous_at_its_lattice(pair):
    """A locked-rotation scene's lookup: the force at a lattice translation is one value."""
    corr = pair.with_modes(8)
    land = corr.landscape(np.eye(3))
    i = land.energy.shape[0] // 2 + 1
    node = np.array([ax[i] for ax in land.translations])
    at = land.lookup(node)
    np.testing.assert_allclose(at.force, land.force[:, i, i, i], rtol=1e-6)
    for signs in np.ndindex(2, 2, 2):
        near = land.lookup(node + 1e-9 * H * (2 * np.array(signs) - 1))
        np.testing.assert_allclose(near.force, at.force, atol=1e-6 * np.linalg.norm(at.force))
