"""Engine loop: rate, frames, commands, background recompute and swap, device loss."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest
from sim_fakes import well

from engine import api
from engine.devices import Device, DeviceCapabilities, DeviceError
from engine.errors import Cancelled
from engine.loop import EngineLoop, period_stats
from engine.params import Effects, SimConfig
from engine.sim import CorrelatorField, RigidBody, Simulation, resolve_physics


def tetra():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


class FakeModel:
    """Stands in for SceneModel: builds spring-well fields, slowly, with progress."""

    def __init__(self, delay=0.2):
        self.config = SimConfig()
        self.delay = delay
        self.built = []
        self.scene = None

    def physics(self, effects, coupling=None, kappa=None):
        v, f = tetra()
        return resolve_physics(self.config, v, f, effects=effects, kappa=kappa)

    def field(self, effects, kappa, rot, *, sigma=None, penalty=None, modes=None,
              progress=None, cancel=None):
        for i in range(10):
            if cancel is not None and cancel():
                raise Cancelled("cancelled")
            time.sleep(self.delay / 10)
            if progress:
                progress((i + 1) / 10)
        c = well(stiffness=1.0, modes=modes or 16)
        c.sigma = sigma
        self.built.append(c)
        return CorrelatorField(c, kappa), ("d1", "d2")


def make_loop(realtime=True, **kw):
    model = FakeModel()
    phys = model.physics(Effects())
    body = RigidBody(phys.mass, phys.inertia, phys.center)
    corr = well(stiffness=1.0)
    sim = Simulation(body, phys, Effects(), CorrelatorField(corr, phys.kappa), np.zeros(6))
    loop = EngineLoop(sim, model=model, realtime=realtime, **kw)
    return loop, corr, model


def wait_for(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_period_stats_known_values():
    p = np.full(1000, 1e-3)
    p[-1] = 5e-3
    s = period_stats(p)
    assert s.median_us == pytest.approx(1000.0)
    assert s.max_us == pytest.approx(5000.0)
    assert s.rate_hz == pytest.approx(1000 / (0.999 + 0.005))


def test_loop_publishes_frames_at_rate_from_its_own_thread():
    # 250 Hz: this test checks the scheduling logic on a shared CI machine, where a 1 kHz
    # loop is at the mercy of other processes; `skelasm bench loop` measures 1 kHz
    loop, corr, _ = make_loop(keep_periods=True, rate_hz=250.0)
    loop.start()
    time.sleep(1.0)
    loop.send(api.Stop())
    loop.stop()
    assert not loop.is_alive()
    periods = np.array(loop.periods)
    assert len(periods) > 100
    # the loop catches up after short overruns, so between stalls of the machine (gaps over
    # 5 periods, after which it re-anchors instead of racing) it holds the target rate; the
    # tail is the benchmark's business
    stalls = periods > 5 * 4e-3
    assert loop.overruns <= stalls.sum()
    kept = periods[~stalls]
    assert len(kept) / kept.sum() == pytest.approx(250.0, rel=0.15)
    assert corr.threads == {"skelasm-engine"}  # the field is evaluated in the engine thread only
    frames = loop.poll_frames()
    assert frames and frames[-1].step == loop.sim.steps
    assert frames[-1].proxy_pose.flags.writeable is False
    assert any(isinstance(e, api.StoppedEvent) for e in loop.poll_events())


def test_stale_frames_are_dropped():
    loop, _, _ = make_loop(realtime=False, frame_queue=8)
    loop.run(max_steps=100)
    frames = loop.poll_frames()
    assert len(frames) == 8 and loop.frames_published == 100
    assert [f.step for f in frames] == list(range(93, 101))


def test_commands_apply_between_steps():
    loop, corr, _ = make_loop(realtime=False)
    loop.send(api.SetModes(24))
    loop.send(api.SetProxyPose((0.5, 0, 0, 0, 0, 0)))
    loop.run(max_steps=3000)
    assert corr.modes == 24 and loop.poll_frames()[-1].modes == 24
    assert loop.sim.part_pose()[0] > 0.1  # the part followed the proxy against the well
    loop.send(api.Pause())
    before = loop.sim.steps
    loop.run(max_steps=10)
    assert loop.sim.steps == before and loop.poll_frames()[-1].paused
    loop.send(api.Pause(False))
    loop.send(api.Reset())
    loop.run(max_steps=1)
    assert np.linalg.norm(loop.sim.part_pose()) < 1e-3
    with pytest.raises(TypeError):
        loop.send("not a command")


def test_recompute_in_background_keeps_old_field_until_swap():
    loop, old, model = make_loop(realtime=True)
    loop.start()
    loop.send(api.SetDescriptorParams(sigma=0.8))
    assert wait_for(lambda: model.built, 5.0)
    assert wait_for(lambda: loop.sim.field.correlator is model.built[0], 2.0)
    events = loop.poll_events()
    loop.stop()
    progress = [e.fraction for e in events if isinstance(e, api.ProgressEvent)]
    assert progress and progress == sorted(progress) and progress[-1] == 1.0
    assert any(isinstance(e, api.DescriptorsSwapped) for e in events)
    # while the worker ran, the loop kept stepping on the old field
    assert old.evaluations > 50
    assert model.built[0].sigma == 0.8
    assert model.built[0].threads <= {"skelasm-engine"}


def test_recompute_can_be_cancelled():
    loop, old, model = make_loop(realtime=True)
    model.delay = 1.0
    loop.start()
    loop.send(api.SetDescriptorParams(penalty=5.0))
    time.sleep(0.15)
    loop.send(api.CancelRecompute())
    assert wait_for(lambda: any(isinstance(e, api.ProgressEvent) and e.message == "cancelled"
                                for e in list(loop.events)), 3.0)
    loop.stop()
    assert loop.sim.field.correlator is old and model.built == []


class FlakyDevice(Device):
    capabilities = DeviceCapabilities("flaky", force_feedback=True)

    def __init__(self, fail_after):
        self.reads = 0
        self.fail_after = fail_after
        self.forces = []

    def read_pose(self, t):
        self.reads += 1
        if self.reads > self.fail_after:
            raise DeviceError("flaky: unplugged; plug it back in")
        return np.array([0.1, 0, 0, 0, 0, 0])

    def write_force(self, force, torque):
        self.forces.append(np.array(force))


def test_lost_device_falls_back_to_mouse_and_keeps_running():
    dev = FlakyDevice(fail_after=20)
    loop, _, _ = make_loop(realtime=False, device=dev)
    loop.run(max_steps=100)
    events = [e for e in loop.poll_events() if isinstance(e, api.DeviceEvent)]
    assert len(events) == 1 and "unplugged" in events[0].message and events[0].fallback == "mouse"
    assert loop.sim.steps == 100 and loop.device.name == "mouse"
    assert len(dev.forces) == 20  # forces were rendered while it lived
    loop.send(api.SetProxyPose((0.2, 0, 0, 0, 0, 0)))
    loop.run(max_steps=5)
    np.testing.assert_allclose(loop.sim.proxy_pose[0], 0.2)


def test_errors_in_commands_become_events():
    loop, _, _ = make_loop(realtime=False)
    loop.model = None
    loop.send(api.SetDescriptorParams(sigma=1.0))
    loop.run(max_steps=2)
    errs = [e for e in loop.poll_events() if isinstance(e, api.ErrorEvent)]
    assert errs and not errs[0].fatal


def test_process_engine_frames_through_shared_memory():
    from pathlib import Path

    from engine.loop import ProcessEngine

    scene = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"
    engine = ProcessEngine(str(scene), options={"fake": True})
    engine.start()
    try:
        assert engine.wait_ready(timeout=60)
        engine.send(api.SetProxyPose((1.0, 0, 5.0, 0, 0, 0)))
        frames = []

        def moved():
            frames.extend(engine.poll_frames())
            return bool(frames) and frames[-1].part_pose[0] > 0.5

        assert wait_for(moved, 10.0)  # the part followed the proxy in the other process
        assert frames[-1].step > 0 and frames[-1].proxy_pose[0] == 1.0
        assert len({f.step for f in frames}) == len(frames)  # only new frames are returned
    finally:
        engine.stop()
    assert not engine.is_alive()


def test_api_end_to_end_on_a_scene_without_guidance():
    from dataclasses import replace
    from pathlib import Path

    scene = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"
    handle = api.open_scene(scene)
    assert handle.parts[1].vertices.shape[1] == 3
    np.testing.assert_allclose(handle.world_pose(handle.start_pose), handle.scene.parts[1].pose)
    cfg = handle.config
    handle = replace(handle, config=replace(cfg, effects=replace(cfg.effects, guidance="none")))
    engine = api.start_engine(handle)
    try:
        assert wait_for(lambda: any(isinstance(e, api.ReadyEvent) for e in list(
            engine._loop.events)), 10.0)
        engine.send(api.SetProxyPose((0.0, 0.0, 0.0, 0.0, 0.0, 0.0)))
        assert wait_for(lambda: (f := engine.latest_frame()) is not None
                        and f.part_pose[2] < 0.5, 10.0)
        assert engine.running
    finally:
        engine.stop()
    assert not engine.running
    assert any(isinstance(e, api.StoppedEvent) for e in engine.poll_events())


def test_device_maximum_clamps_the_rendered_force():
    dev = FlakyDevice(fail_after=10**9)
    dev.capabilities = DeviceCapabilities("flaky", force_feedback=True, max_force=0.25)
    loop, _, _ = make_loop(realtime=False, device=dev)
    loop.run(max_steps=5)
    assert loop.sim.limits.max_force == 0.25
    assert np.linalg.norm(dev.forces[-2]) == pytest.approx(0.25)  # the proxy is 0.1 away
    assert np.linalg.norm(dev.forces[-1]) == 0.0  # and the device is let go at the end


def _in_thread(func):
    out = []
    worker = threading.Thread(target=lambda: out.append(func()))
    worker.start()
    worker.join()
    return out[0]


@pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="Linux scheduling API")
def test_raise_thread_priority_reports_what_the_os_granted(monkeypatch):
    from engine.loop import REALTIME_PRIORITY, raise_thread_priority

    monkeypatch.delenv("SKELASM_REALTIME", raising=False)

    def ask():
        said = raise_thread_priority()
        return said, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority

    said, policy, priority = _in_thread(ask)  # only that thread changes
    if said.startswith("real-time"):
        assert policy == os.SCHED_FIFO and priority == REALTIME_PRIORITY
    else:
        assert "refused" in said and policy == os.SCHED_OTHER
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread is untouched
    monkeypatch.setenv("SKELASM_REALTIME", "0")
    said, policy, _ = _in_thread(ask)
    assert said == "normal (SKELASM_REALTIME=0)" and policy == os.SCHED_OTHER


def test_loop_asks_for_priority_only_when_told(monkeypatch):
    monkeypatch.setenv("SKELASM_REALTIME", "0")
    plain, _, _ = make_loop(realtime=False)
    plain.run(max_steps=3)
    assert plain.scheduling == "normal (not asked for)"
    asked, _, _ = make_loop(realtime=False, raise_priority=True)
    asked.run(max_steps=3)
    assert asked.scheduling == "normal (SKELASM_REALTIME=0)"
