"""A device's legal poses never end the run: a jump of the proxy is followed at a bounded pace.

The issue's case: a UDP peer sent two in-workspace poses 1,980 mm apart, 0.3 s apart; the
coupling threw the part after the proxy in one step and the run ended "diverged ... check the
[coupling] gains and the part's mass", blaming the scene for the network peer's jump.
"""

from __future__ import annotations

import numpy as np
import pytest

from engine.devices import Device, DeviceCapabilities, TrajectoryDevice
from engine.errors import Diverged
from engine.params import Effects, SimConfig
from engine.runtime.loop import EngineLoop
from engine.runtime.messages import DeviceEvent, ErrorEvent
from engine.sim import NullField, RigidBody, Simulation, resolve_physics
from engine.sim.guard import MAX_PROXY_STEP_LENGTHS, MAX_PROXY_STEP_RADIANS, limit_proxy_step

trimesh = pytest.importorskip("trimesh")


class Jumper(Device):
    """A network-like device: its own pose sequence, one per reading (None: no packet)."""

    capabilities = DeviceCapabilities("udp", dof=6)

    def __init__(self, poses):
        self.poses = list(poses)

    def read_pose(self, time_s):
        return self.poses.pop(0) if self.poses else None


def make_sim():
    mesh = trimesh.creation.box(extents=(10.0, 10.0, 30.0))  # a peg, 30 mm long
    config = SimConfig(effects=Effects())
    phys = resolve_physics(config, np.asarray(mesh.vertices), np.asarray(mesh.faces))
    body = RigidBody(phys.mass, phys.inertia, phys.centre)
    return Simulation(body, phys, config.effects, NullField(), np.zeros(6),
                      dt=config.simulation.dt)


def jump_then_hold(far):
    """0.3 s at the origin, then one packet 1,980 mm away, then silence."""
    return [np.zeros(6)] * 300 + [np.asarray(far, float)]


@pytest.mark.parametrize("far", [
    [1980.0, 0, 0, 0, 0, 0],
    [0, -1400.0, 1400.0, 0, 0, 0],
    [0, 0, 0, 3.0, 0, 0],
    [1000.0, 0, 0, 0, 2.5, 0.5],
])
def test_a_jump_of_a_device_never_ends_the_run(far):
    sim = make_sim()
    loop = EngineLoop(sim, device=Jumper(jump_then_hold(far)), realtime=False)
    loop.run(max_steps=300 + 5000)  # before: Diverged within a few steps of the jump
    events = loop.poll_events()
    notes = [e.message for e in events if isinstance(e, DeviceEvent) and e.connected]
    assert any(n.startswith("udp's pose jumped") for n in notes), notes  # names the device
    assert not [e for e in events if isinstance(e, ErrorEvent)]
    np.testing.assert_allclose(sim.proxy_pose, far, atol=1e-9)  # it got there
    assert np.all(np.isfinite(sim.part_pose()))


def test_without_the_pace_the_same_jump_diverges():
    """The test above can fail: the unpaced proxy makes the integrator diverge."""
    sim = make_sim()
    loop = EngineLoop(sim, device=Jumper(jump_then_hold([1980.0, 0, 0, 0, 0, 0])),
                      realtime=False)
    loop.inputs.paced = False
    with pytest.raises(Diverged):
        loop.run(max_steps=400)


def test_a_trajectory_is_replayed_exactly_not_paced():
    sim = make_sim()
    rows = np.array([[0, 0, 0, 0, 0, 0, 0], [0.1, 0, 0, 5.0, 0, 0, 0]], float)
    loop = EngineLoop(sim, device=TrajectoryDevice(rows), realtime=False)
    assert not loop.inputs.paced


def test_limit_proxy_step_moves_a_bounded_step_along_the_way():
    length = 30.0
    out, short = limit_proxy_step(np.zeros(6), np.array([100.0, 0, 0, 0, 0, 1.0]), length)
    assert short
    np.testing.assert_allclose(out[:3], [MAX_PROXY_STEP_LENGTHS * length, 0, 0])
    np.testing.assert_allclose(out[3:], [0, 0, MAX_PROXY_STEP_RADIANS])
    near = np.array([0.1, 0.2, 0, 0.001, 0, 0])
    out, short = limit_proxy_step(np.zeros(6), near, length)
    assert not short and np.array_equal(out, near)
