"""Building a simulation: mass properties, size-scaled physics, the time step."""

from __future__ import annotations

import math

import numpy as np
import pytest

from engine.params import Effects, MassSpec, SimConfig
from engine.sim import mass_properties, resolve_physics


def box(size=(1.0, 2.0, 4.0)):
    import trimesh

    m = trimesh.creation.box(extents=size)
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_mass_properties_of_a_box():
    v, f = box()
    m, inertia, c = mass_properties(v, f, MassSpec(density=3.0))
    assert m == pytest.approx(24.0)
    np.testing.assert_allclose(np.diag(inertia), 24.0 / 12 * np.array([20, 17, 5]), rtol=1e-9)
    np.testing.assert_allclose(c, 0.0, atol=1e-12)
    m, inertia, _ = mass_properties(v, f, MassSpec())
    assert m == 1.0


def test_defaults_scale_with_part_size():
    v, f = box()
    a = resolve_physics(SimConfig(), v, f)
    b = resolve_physics(SimConfig(), v * 1000.0, f)
    assert a.mass == b.mass == 1.0
    assert b.length == pytest.approx(1000 * a.length)
    # same natural frequency, so the same motion in units of L
    assert math.sqrt(a.k_lin / a.mass) == pytest.approx(math.sqrt(b.k_lin / b.mass))
    assert b.inertia[0, 0] == pytest.approx(1e6 * a.inertia[0, 0])
    assert math.sqrt(a.k_rot / a.inertia[0, 0]) == pytest.approx(
        math.sqrt(b.k_rot / b.inertia[0, 0]), rel=0.3)
    # kappa ~ k / L: geometric force (~ kappa L^2) over coupling force (~ k L) is unit-free
    assert a.kappa * a.length**2 / (a.k_lin * a.length) == pytest.approx(
        b.kappa * b.length**2 / (b.k_lin * b.length))


def test_damping_off_zeroes_every_damper():
    v, f = box()
    p = resolve_physics(SimConfig(effects=Effects(damping=False)), v, f)
    assert p.c_lin == p.c_rot == p.body_c_lin == p.body_c_rot == 0.0
