"""`skelasm simulate`: headless runs, JSON, logs, messages for bad scenes and devices."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[2]
PEG = ROOT / "assets" / "peg_in_hole" / "scene.toml"


def copy_scene(tmp_path, extra=""):
    for f in PEG.parent.glob("*.step"):
        shutil.copy(f, tmp_path / f.name)
    text = PEG.read_text()
    head, sep, tail = text.partition("[[part]]")
    (tmp_path / "scene.toml").write_text(head + extra + "\n" + sep + tail)
    return tmp_path / "scene.toml"


def run_json(capsys, *argv):
    assert main(["simulate", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_trajectory_moves_part_and_log_replays(tmp_path, capsys):
    traj = tmp_path / "in.csv"
    traj.write_text("t,tx,ty,tz,rx,ry,rz\n0,0,0,5,0,0,0\n0.5,1,0,-5,0,0,0.1\n")
    log = tmp_path / "out.csv"
    out = run_json(capsys, PEG, "--guidance", "none", "--trajectory", traj, "--log", log)
    assert out["steps"] == 1500  # trajectory length + 1 s at 1 kHz
    # the coupling settles on the held last row
    np.testing.assert_allclose(out["final_pose"], [1, 0, -5, 0, 0, 0.1], atol=1e-3)
    assert set(out["period_us"]) == {"median", "p1", "p99", "max"} and out["rate_hz"] > 0
    # the log is itself a trajectory: replaying it gives the same final pose
    again = run_json(capsys, PEG, "--guidance", "none", "--trajectory", log, "--seconds", 1.5)
    np.testing.assert_array_equal(again["final_pose"], out["final_pose"])


def test_no_trajectory_keeps_proxy_at_start(capsys):
    out = run_json(capsys, PEG, "--guidance", "none", "--seconds", 0.2)
    np.testing.assert_allclose(out["final_pose"], [0, 0, 12, 0, 0, 0], atol=1e-9)
    assert out["steps"] == 200


@pytest.mark.slow
def test_realtime_holds_rate(capsys):
    """A timing check, so slow-marked and skipped on a loaded machine: behind schedule the
    loop catches up with short periods and the median falls below the period.
    """
    import os

    if os.getloadavg()[0] > 0.5 * (os.cpu_count() or 1):
        pytest.skip(f"machine loaded (load average {os.getloadavg()[0]:.1f})")
    out = run_json(capsys, PEG, "--guidance", "none", "--seconds", 0.5, "--realtime")
    assert out["period_us"]["median"] == pytest.approx(1000.0, rel=0.05)
    assert out["wall_seconds"] >= 0.49


def test_bad_scene_names_the_line(tmp_path, capsys):
    scene = copy_scene(tmp_path, "[coupling]\nfrequency_hz = -3\n")
    assert main(["simulate", str(scene), "--guidance", "none"]) == 2
    err = capsys.readouterr().err
    line = next(i for i, l in enumerate(scene.read_text().splitlines(), 1) if "frequency_hz" in l)
    assert f"scene.toml:{line}: frequency_hz in [coupling] must be a positive number" in err


def test_missing_device_falls_back_to_mouse(tmp_path, capsys):
    scene = copy_scene(tmp_path, '[device]\nkind = "spacemouse"\n')
    out = run_json(capsys, scene, "--guidance", "none", "--seconds", 0.1)
    assert out["steps"] == 100
    assert any(n.startswith("spacemouse:") for n in out["notes"])


def test_missing_trajectory_file(tmp_path, capsys):
    assert main(["simulate", str(PEG), "--trajectory", str(tmp_path / "no.csv"),
                 "--guidance", "none"]) == 2
    assert "no.csv: no such trajectory file" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------
# seating: each example pair, started misaligned, pushed along its insertion axis

PAIRS = ("peg_in_hole", "boss_pins", "bracket_slot", "dovetail")


#: Modes per axis for the seating runs: at the scenes' K = 16 (of an FFT size of 140 for a
#: 56-sample part grid) the peg in hole's energy has a spurious minimum with the peg tilted
#: 20 degrees below the seated energy; from K = 24 the seated pose is the minimum, and at
#: K = 32 the peg stops 0.364 mm from the seat (half a cell: 0.357 mm); K = 48 seats it.
SEATING_MODES = 48

#: The bracket's 2 mm web in its 2 mm slot (2.8 cells) needs finer modes: with all modes the
#: energy minimum lies 0.1 mm from the seat, at K = 96 0.3 mm, at K = 64 0.5 mm and at K = 48
#: 0.8 mm short (2 mm features in a 103 mm FFT box). K = 96 costs about 20 ms a pose, so
#: this run takes about 100 s.
PAIR_MODES = {"bracket_slot": 96}

#: Where the seating protocol starts, back along the insertion axis from the seat (mm): inside
#: the descriptors' reach, as the scenes started before they were moved out of it to open at
#: rest; the push covers this in ``push_s``.
APPROACH = {"peg_in_hole": 20.0, "boss_pins": 16.0, "bracket_slot": 15.0, "dovetail": 35.0}


def seating_run(name, guidance="skeletal", *, offset_frac=0.03, tilt_deg=3.0, push_s=2.0,
                hold_s=2.0, modes=None, gain=None):
    """Run one pair: start laterally offset by ``offset_frac`` of the moving part's width and
    tilted by ``tilt_deg``, the proxy (keeping that misalignment) pushed along the insertion
    axis to the assembled depth in ``push_s``, then held. Returns a dict of errors.
    """
    from dataclasses import replace

    from bench.seating import RestWatch, push_until_rest
    from engine.devices import TrajectoryDevice
    from engine.pose import relative_pose
    from engine.runtime import EngineLoop, open_scene
    from engine.sim import build_simulation

    handle = open_scene(ROOT / "assets" / name / "scene.toml")
    cfg = handle.config
    sim_params = cfg.simulation if gain is None else replace(cfg.simulation, guidance_gain=gain)
    handle = replace(handle, config=replace(cfg, effects=replace(cfg.effects, guidance=guidance),
                                            simulation=sim_params))
    axis = np.array(handle.scene.insertion_axis, float)
    axis /= np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    lateral = np.cross(axis, helper)
    lateral /= np.linalg.norm(lateral)
    tilt_axis = np.cross(axis, lateral)
    width = float(np.ptp(handle.parts[1].vertices @ lateral))
    start = np.array(handle.start_pose, float)
    if name in APPROACH:
        start = np.asarray(handle.assembled_pose, float) - np.r_[APPROACH[name] * axis, 0, 0, 0]
    start[:3] += offset_frac * width * lateral
    start[3:] += np.radians(tilt_deg) * tilt_axis
    handle = replace(handle, start_pose=start)
    if modes is None:
        modes = PAIR_MODES.get(name, SEATING_MODES)
    sim, model = build_simulation(handle, prepare=True, backend="auto", modes=modes)
    target = np.array(handle.assembled_pose, float)
    end = start.copy()
    end[:3] += axis * float((target[:3] - start[:3]) @ axis)
    traj = TrajectoryDevice(np.array([[0.0, *start], [push_s, *end]]))
    h = sim.field.correlator.spacing if hasattr(sim.field, "correlator") else float("nan")
    # a tenth of a second at a time, ended once the part is at rest after the push (the
    # benchmark's rule, at this test's tolerances: its mean pose would move less than 5 %
    # of them in the time left, and it trembles by less than them)
    loop = EngineLoop(sim, model=model, device=traj, realtime=False,
                      frame_queue=int(round(0.1 / sim.dt)) + 16)
    done = push_until_rest(loop, int((push_s + hold_s) / sim.dt), push_s,
                           RestWatch(0.5 * h, 1.0, sim.dt))
    err = relative_pose(target, sim.part_pose())
    return {
        "pair": name,
        "guidance": guidance,
        "distance": float(np.linalg.norm(err[:3])),
        "lateral": float(np.linalg.norm(err[:3] - axis * (err[:3] @ axis))),
        "axial": float(err[:3] @ axis),
        "angle_deg": float(np.degrees(np.linalg.norm(err[3:]))),
        "half_cell": 0.5 * h,
        "start_offset": offset_frac * width,
        "final_pose": sim.part_pose(),
        "modes": modes,
        "seconds": done * sim.dt,
    }


_RUNS: dict = {}

#: Pairs that do not seat, with their figures (xfail, not strict). None now: the bracket's
#: web, which ended 4.52 mm beside its slot when the fine level came in, seats at K = 96
#: (0.251 mm off against half a cell of 0.357, 0.12 degree; collision-only 2.451 mm).
NOT_SEATING: dict[str, str] = {}

SEATING_PAIRS = [pytest.param(n, marks=pytest.mark.xfail(reason=NOT_SEATING[n], strict=False))
                 if n in NOT_SEATING else n for n in PAIRS]


def cached_run(name, guidance):
    if (name, guidance) not in _RUNS:
        r = seating_run(name, guidance)
        _RUNS[name, guidance] = r
        # shown with -s: the figures of the report
        print(f"\nSEATING {name} {guidance}: distance {r['distance']:.3f} (lateral "
              f"{r['lateral']:.3f}, axial {r['axial']:+.3f}), angle {r['angle_deg']:.2f} deg, "
              f"half cell {r['half_cell']:.3f}, start offset {r['start_offset']:.3f}, "
              f"K {r['modes']}, at rest or ended at {r['seconds']:.1f} s")
    return _RUNS[name, guidance]


@pytest.mark.slow
@pytest.mark.parametrize("name", SEATING_PAIRS)
def test_guided_pair_seats(name):
    r = cached_run(name, "skeletal")
    assert r["distance"] <= r["half_cell"], r
    assert r["angle_deg"] <= 1.0, r


#: The pairs whose collision-only baseline is run here: all but the bracket, whose baseline
#: alone took three minutes of a CI run, four times the other three baselines together; its
#: guided run stays.
BASELINE_PAIRS = ("peg_in_hole", "boss_pins", "dovetail")


@pytest.mark.slow
@pytest.mark.parametrize("name", BASELINE_PAIRS)
def test_collision_only_pair_is_measured(name):
    # the baseline is measured, not required to seat: guidance must do at least as well
    guided = cached_run(name, "skeletal")
    baseline = cached_run(name, "collision")
    assert np.all(np.isfinite(baseline["final_pose"]))
    assert guided["distance"] <= baseline["distance"] + guided["half_cell"]


def free_energy_run(axes, start, steps=2000, band="box"):
    """Free part (no proxy, damping off) in the peg's real field at the default 1 ms step:
    (total energy per step, its starting value, the largest kinetic energy).

    ``band``: the modal sum's. The box band's deep well at K = 16 throws the peg about
    (largest kinetic energies 25,000 to 50,000), the hardest case for the integrator; the
    guidance's smooth band is lowest at z = -12 at this K (the level brings the peg the
    last 3 mm to its seat), so a peg let go there hardly moves (0.8 mm, 460 of kinetic
    energy) and is judged from where it falls.
    """
    from dataclasses import replace

    import engine.params
    from engine.runtime import open_scene
    from engine.sim import build_simulation, kinetic_energy

    handle = open_scene(PEG)
    cfg = handle.config
    effects = replace(cfg.effects, damping=False, axes=axes)
    handle = replace(handle, config=replace(cfg, effects=effects),
                     start_pose=np.asarray(start, float))
    # the modal field's energy: the fine level (force steps at its cells' faces) has its
    # own test (tests/engine/test_near_level.py: 2.3 % with it)
    guidance, engine.params.GUIDANCE_BAND = engine.params.GUIDANCE_BAND, band
    try:
        sim, _ = build_simulation(handle, prepare=True, coupled=False, modes=16, fine=False)
    finally:
        engine.params.GUIDANCE_BAND = guidance
    sim.evaluate_field()
    e0 = sim.total_energy()
    energy, kinetic = [], []
    for _ in range(steps):
        sim.step()
        energy.append(sim.total_energy())
        kinetic.append(kinetic_energy(sim.body, sim.state))
    return np.asarray(energy), e0, max(kinetic)


@pytest.mark.slow
def test_energy_bounded_in_the_real_field_translation_only():
    """Rotation locked (landscape lookup, force = -grad of the interpolated energy): the
    total energy stays within a fraction of a percent of the kinetic energy the part
    reaches (measured 0.33 % at most, 0.08 % drift; 5.4 % with trilinear lookup).
    """
    energy, e0, scale = free_energy_run(("x", "y", "z"), [0.3, 0.0, -12.0, 0.0, 0.0, 0.0])
    assert scale > 1000.0  # it fell into the hole and moved
    assert np.max(np.abs(energy - e0)) < 0.02 * scale
    assert abs(energy[-500:].mean() - energy[:500].mean()) < 0.01 * scale


@pytest.mark.slow
@pytest.mark.parametrize(("start", "band"), [
    ([0.2, 0.0, -14.5, 0.02, 0.0, 0.0], "box"),
    ([0.3, 0.0, -12.0, 0.03, -0.02, 0.0], "box"),
    ([0.2, 0.0, -14.5, 0.02, 0.0, 0.0], "smooth"),  # 0.06 % of 7,306; it rises 7 mm
])
def test_energy_bounded_in_the_real_field_with_rotation(start, band):
    """Rotation free: the torque is the derivative of the interpolated energy and the step
    is velocity Verlet with a torque-free drift at fixed angular momentum, so a tilted peg
    rattling in (or dropped into) its hole for 2 s keeps its total energy (measured 0.44 %
    and 0.19 % of the kinetic energy at most; 5.6 % and 20 % with an explicit gyroscopic
    term, and the drop 18 % with the moment-spectrum torque and symplectic Euler).
    """
    energy, e0, scale = free_energy_run(("x", "y", "z", "rx", "ry", "rz"), start, band=band)
    assert scale > 1000.0
    assert np.max(np.abs(energy - e0)) < 0.02 * scale
    assert abs(energy[-500:].mean() - energy[:500].mean()) < 0.01 * scale


@pytest.mark.slow
def test_dovetail_holds_still_without_input():
    """The dovetail's slide, left at its start pose with the proxy there, is drawn a few
    millimetres towards the groove but stays nearly level over 2 s. Held by the coupling at
    its file's origin (its front face, 15 mm ahead of its centre of mass), the geometric
    pull on its body had a 15 mm lever against the rotational spring and tipped it 34
    degrees; held at its centre of mass it tilts 7.5 degrees (the energy itself falls as the
    slide's body swings down along the block's back face).
    """
    from engine.pose import relative_pose
    from engine.runtime import open_scene
    from engine.sim import build_simulation

    handle = open_scene(ROOT / "assets" / "dovetail" / "scene.toml")
    sim, _ = build_simulation(handle, prepare=True)
    sim.run(2000)
    moved = relative_pose(handle.start_pose, sim.part_pose())
    assert np.degrees(np.linalg.norm(moved[3:])) < 10.0
