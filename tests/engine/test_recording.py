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
    body = RigidBody(phys.mass, phys.inertia, phys.centre)
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


# --------------------------------------------------------------------------- streaming
def _rows(n):
    rows = np.random.default_rng(0).normal(size=(n, len(COLUMNS)))
    rows[:, 0] = np.arange(n) * 1e-3
    return rows


@pytest.mark.parametrize("suffix", [".csv", ".npz"])
def test_writer_streams_and_matches_save_recording(tmp_path, suffix):
    from engine.files import TEMP_PREFIX
    from engine.recording import FLUSH_ROWS, RecordingWriter, save_recording

    rows = _rows(3 * FLUSH_ROWS + 7)
    path = tmp_path / f"log{suffix}"
    with RecordingWriter(path, scene="0123456789abcdef") as writer:
        writer.append(rows[: 2 * FLUSH_ROWS])
        partial = [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]
        assert len(partial) == 1 and not path.exists()  # on disk already, not yet in place
        assert partial[0].stat().st_size >= FLUSH_ROWS * len(COLUMNS) * 8 * 0.5
        writer.append(rows[2 * FLUSH_ROWS:])
    assert sorted(tmp_path.iterdir()) == [path]
    np.testing.assert_array_equal(load_recording(path), rows)  # bit-exact, as save_recording
    reference = save_recording(tmp_path / f"ref{suffix}", rows, scene="0123456789abcdef")
    np.testing.assert_array_equal(load_recording(reference), load_recording(path))
    from engine.recording import recording_scene

    assert recording_scene(path) == recording_scene(reference) == "0123456789abcdef"


def test_an_interrupted_recording_keeps_its_rows(tmp_path):
    """Ctrl+C in the loop: leaving the ``with`` block writes every row recorded so far."""
    from engine.recording import RecordingWriter

    rows = _rows(1000)
    path = tmp_path / "int.csv"
    with pytest.raises(KeyboardInterrupt), RecordingWriter(path) as writer:
        for row in rows[:600]:
            writer.on_frame(row)
        raise KeyboardInterrupt
    np.testing.assert_array_equal(load_recording(path), rows[:600])


def test_a_tagged_recording_is_still_a_trajectory(tmp_path):
    from engine.recording import save_recording

    path = save_recording(tmp_path / "rec.csv", _rows(5), scene="00000000000000ff")
    assert path.read_text().splitlines()[0].endswith(",haptic_mz,scene=00000000000000ff")
    assert TrajectoryDevice(path).duration == pytest.approx(4e-3)


def test_a_recording_with_a_byte_order_mark_loads(tmp_path):
    from engine.recording import save_recording

    path = save_recording(tmp_path / "rec.csv", _rows(3))
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    np.testing.assert_array_equal(load_recording(path), _rows(3))


def test_a_damaged_npz_recording_names_the_file(tmp_path):
    from engine.recording import save_recording

    path = save_recording(tmp_path / "rec.npz", _rows(300))
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match="rec.npz: not a skelasm recording"):
        load_recording(path)
