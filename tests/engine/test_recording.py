"""Record and replay: a replayed recording reproduces the motion exactly."""

from __future__ import annotations

import numpy as np
import pytest
from sim_fakes import well

from engine.devices import TrajectoryDevice
from engine.errors import InputError
from engine.params import Effects, SimConfig
from engine.recording import COLUMNS, load_recording, replay_device
from engine.runtime import EngineLoop, Recorder
from engine.sim import CorrelatorField, RigidBody, Simulation, resolve_physics


def spring_well():
    """The spring well, named as the engine names a correlator's evaluator."""
    c = well(stiffness=2.0)
    c.backend, c.backend_name = "numpy", "spring well"
    return c


def make_sim():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    phys = resolve_physics(SimConfig(), v, f)
    body = RigidBody(phys.mass, phys.inertia, phys.center)
    return Simulation(body, phys, Effects(), CorrelatorField(spring_well(), phys.kappa),
                      np.zeros(6))


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_replay_reproduces_final_pose(tmp_path, suffix):
    rng = np.random.default_rng(3)
    times = np.linspace(0.0, 0.8, 9)
    poses = np.cumsum(rng.normal(scale=0.05, size=(9, 6)), axis=0)
    traj = TrajectoryDevice(np.column_stack([times, poses]))

    rec = Recorder(capacity=100)  # grows past its capacity
    loop = EngineLoop(make_sim(), device=traj, realtime=False, on_frame=rec.on_frame)
    loop.run(max_steps=1000)
    final = loop.sim.part_pose()
    path = rec.save(tmp_path / f"session{suffix}")
    rows = load_recording(path)
    assert rows.shape == (1000, len(COLUMNS))
    np.testing.assert_array_equal(rows[-1, 7:13], final)

    replay = EngineLoop(make_sim(), device=replay_device(path), realtime=False)
    replay.run(max_steps=1000)
    np.testing.assert_array_equal(replay.sim.part_pose(), final)
    # and the motion was not trivial
    assert np.linalg.norm(final) > 0.01


def test_bad_recording_names_the_file(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b\n1,2\n")
    with pytest.raises(InputError, match="x.csv"):
        load_recording(p)
