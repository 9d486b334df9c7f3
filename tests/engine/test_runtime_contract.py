"""One contract for both transports: every test here runs on the thread engine and on the
process engine (``start_engine(process=...)``), on a small real scene (the peg in hole on a
coarse grid, K = 8).

What the contract says: frames carry every field (``step_us``, ``paused``, period, device,
recompute state) and keep coming while paused; preparation reports progress, then
ReadyEvent brings the descriptors; landscapes and descriptors are answered by the engine;
K changes and recomputes reach the frames; the simulated time advances by the loop's
period through every command (a rate override holds).
"""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from engine import runtime as rt
from engine.correlation import LocalSpectral
from engine.descriptor import Descriptor
from engine.runtime.pacing import STATS_EVERY, STATS_WINDOW

TRANSPORTS = ["thread", "process"]


@pytest.fixture(scope="module")
def small_scene(small_peg_scene) -> Path:
    """The peg in hole with a 16-sample grid and K = 8 (conftest's small_peg_scene)."""
    return small_peg_scene


def start(scene: Path, transport: str, **kw) -> rt.EngineHandle:
    handle = rt.open_scene(scene)
    return rt.start_engine(handle, process=transport == "process", backend="numba", **kw)


class Collector:
    """Drains an engine's frames and events while waiting for something."""

    def __init__(self, engine: rt.EngineHandle):
        self.engine = engine
        self.frames: list[rt.Frame] = []
        self.events: list[rt.Event] = []

    def drain(self) -> None:
        self.frames += self.engine.poll_frames()
        self.events += self.engine.poll_events()

    def wait(self, predicate, timeout: float = 120.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.drain()
            if predicate():
                return True
            time.sleep(0.01)
        return False

    def change_modes(self, k: int, timeout: float = 60.0) -> bool:
        """Send SetModes(k); True once a frame shows K = k."""
        self.engine.send(rt.SetModes(k))
        return self.wait(lambda: bool(self.frames) and self.frames[-1].modes == k, timeout)

    def landscape(self, timeout: float = 60.0):
        """Ask for a landscape; the first one that arrives (None: none in time)."""
        self.engine.send(rt.RequestLandscape())
        if not self.wait(lambda: self.of(rt.LandscapeReady), timeout):
            return None
        return self.of(rt.LandscapeReady)[0].landscape

    def of(self, kind):
        return [e for e in self.events if isinstance(e, kind)]

    def ready(self) -> bool:
        fatal = [e for e in self.of(rt.ErrorEvent) if e.fatal]
        assert not fatal, fatal
        return bool(self.of(rt.ReadyEvent))


class PeriodLog(Collector):
    """A Collector for timing: keeps the newest frame and each frame's (step, K, longest
    period of its window) as a plain tuple.

    A thread engine's loop shares the interpreter, and its garbage collector, with this
    reader. Keeping every Frame (a thousand a second, each a few container objects the
    collector tracks) made the young generations' collections take 1 to 2 ms, with the
    interpreter lock held, while K changed: the loop then measured its reader, not the
    K change. Tuples of numbers are untracked at their first collection.
    """

    def __init__(self, engine: rt.EngineHandle):
        super().__init__(engine)
        self.rows: list[tuple[int, int, float]] = []

    def drain(self) -> None:
        frames = self.engine.poll_frames()
        self.rows += [(f.step, f.modes, f.period.max_us) for f in frames]
        if frames:
            self.frames = frames[-1:]
        self.events += self.engine.poll_events()


@pytest.fixture(params=TRANSPORTS)
def transport(request) -> str:
    return request.param


def test_preparation_reports_progress_then_ready_with_descriptors(small_scene, transport):
    engine = start(small_scene, transport)
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        assert engine.process == (transport == "process")
        progress = [e.fraction for e in seen.of(rt.ProgressEvent) if e.task == "correlator"]
        assert progress and progress == sorted(progress) and progress[-1] == 1.0
        first_ready = seen.events.index(seen.of(rt.ReadyEvent)[0])
        assert all(seen.events.index(e) < first_ready for e in seen.of(rt.ProgressEvent))
        ready = seen.of(rt.ReadyEvent)[0]
        assert len(ready.descriptors) == 2
        assert all(isinstance(d, Descriptor) and d.rho.ndim == 3 for d in ready.descriptors)
        assert "numba" in ready.backend and "loop thread" in ready.message
        # a landscape is answered by the engine, at the rotation asked for
        engine.send(rt.RequestLandscape((0.0, 0.0, 0.2)))
        assert seen.wait(lambda: seen.of(rt.LandscapeReady), 60.0)
        answer = seen.of(rt.LandscapeReady)[0]
        assert answer.rotvec == (0.0, 0.0, 0.2)
        assert answer.landscape.energy.ndim == 3 and answer.landscape.modes == 8
        # a new K is built off the loop and reaches the frames
        engine.send(rt.SetModes(6))
        assert seen.wait(lambda: seen.frames and seen.frames[-1].modes == 6, 60.0)
    finally:
        engine.stop()
    assert not engine.running


def test_frames_are_complete_and_keep_coming_while_paused(small_scene, transport):
    # issue 10, bug 2: the process engine wrote neither step_us nor paused and sent no
    # frames while paused
    engine = start(small_scene, transport)
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        # frames are drained before events: those that came with the ReadyEvent may predate
        # the field (modes 0, no evaluation); a later drain's last frame does not
        with_ready = len(seen.frames)
        assert seen.wait(lambda: len(seen.frames) > with_ready
                         and seen.frames[-1].period.window >= 100, 30.0)
        f = seen.frames[-1]
        assert f.step_us > 0 and f.eval_us > 0 and f.period.rate_hz > 0
        assert f.modes == 8 and f.device == "mouse" and not f.paused and f.recompute is None
        assert f.time == pytest.approx(f.step * 1e-3)
        assert f.part_pose.shape == (6,) and not f.part_pose.flags.writeable
        engine.send(rt.Pause())
        assert seen.wait(lambda: seen.frames[-1].paused, 10.0)
        paused_at = len(seen.frames)
        time.sleep(0.3)
        seen.drain()
        while_paused = seen.frames[paused_at:]
        assert len(while_paused) > 10 and all(p.paused for p in while_paused)
        assert len({p.step for p in while_paused}) == 1 and while_paused[-1].step_us > 0
        engine.send(rt.Pause(False))
        assert seen.wait(lambda: not seen.frames[-1].paused
                         and seen.frames[-1].step > while_paused[-1].step, 10.0)
        # a device that cannot be opened: the mouse stays, and the frames say so
        engine.send(rt.SetDevice("trajectory", (("file", "no-such-file.csv"),)))
        assert seen.wait(lambda: seen.of(rt.DeviceEvent), 10.0)
        lost = seen.of(rt.DeviceEvent)[0]
        assert not lost.connected and lost.fallback == "mouse"
        assert seen.frames[-1].device == "mouse"
    finally:
        engine.stop()


def test_recompute_and_rate_override_hold_through_every_command(small_scene, transport):
    # issue 10, bug 1: start_engine(rate_hz=250) paced at 250 Hz but stepped 1 ms after
    # SetKappa, SetCoupling, SetEffects and the descriptor hand-over. Checked without
    # timing: the simulated time of every frame is its step times the 4 ms period
    engine = start(small_scene, transport, rate_hz=250.0)
    seen = Collector(engine)
    handle = rt.open_scene(small_scene)
    cfg = handle.config

    def steps_at_4ms(since: int) -> bool:
        frames = seen.frames[since:]
        return bool(frames) and all(abs(f.time - f.step * 4e-3) < 1e-9 for f in frames)

    try:
        assert seen.wait(seen.ready)
        commands = [
            rt.SetKappa(2.0),
            rt.SetCoupling(replace(cfg.coupling, frequency_hz=cfg.coupling.frequency_hz * 2)),
            rt.SetEffects(replace(cfg.effects, damping=not cfg.effects.damping)),
            rt.SetModes(6),
            rt.SetKappa(None),
            rt.Reset(),
        ]
        for command in commands:
            mark = len(seen.frames)
            engine.send(command)
            assert seen.wait(lambda m=mark: len(seen.frames) > m + 20, 30.0)
            assert steps_at_4ms(mark), command
        # a recompute: progress in the frames and events, then the swap with descriptors
        mark = len(seen.frames)
        engine.send(rt.SetDescriptorParams(params=replace(handle.scene.descriptor, sigma=0.7)))
        assert seen.wait(lambda: seen.of(rt.DescriptorsSwapped), 120.0)
        swapped = seen.of(rt.DescriptorsSwapped)[0]
        assert swapped.sigma == pytest.approx(0.7) and len(swapped.descriptors) == 2
        assert swapped.descriptors[0].params.sigma == pytest.approx(0.7)
        assert [e for e in seen.of(rt.ProgressEvent) if e.task == "descriptors"]
        during = [f.recompute for f in seen.frames[mark:] if f.recompute is not None]
        assert during and all(0.0 <= r <= 1.0 for r in during)
        assert seen.wait(lambda: seen.frames[-1].recompute is None, 10.0)
        mark = len(seen.frames)
        assert seen.wait(lambda: len(seen.frames) > mark + 20, 30.0)
        assert steps_at_4ms(mark)
    finally:
        engine.stop()
    assert any(isinstance(e, rt.StoppedEvent) for e in engine.poll_events() + seen.events)


def test_engine_without_guidance_answers_landscape_requests_with_a_typed_failure(
        small_scene, transport):
    engine = start(small_scene, transport)
    seen = Collector(engine)
    handle = rt.open_scene(small_scene)
    try:
        assert seen.wait(seen.ready)
        engine.send(rt.SetEffects(replace(handle.config.effects, guidance="none")))
        sent = len(seen.frames)  # frames drained before may predate the field (modes 0 too)
        assert seen.wait(lambda: len(seen.frames) > sent and seen.frames[-1].modes == 0, 30.0)
        engine.send(rt.RequestLandscape())
        assert seen.wait(lambda: seen.of(rt.LandscapeFailed), 10.0), (
            f"no LandscapeFailed within 10 s; engine running: {engine.running}, last frame "
            f"step {seen.frames[-1].step} K {seen.frames[-1].modes}, events: "
            f"{[(type(e).__name__, getattr(e, 'message', '')) for e in seen.events]}")
        assert "guidance is off" in seen.of(rt.LandscapeFailed)[0].message
        assert not seen.of(rt.ErrorEvent)
        assert np.allclose(seen.frames[-1].force, 0.0)
    finally:
        engine.stop()


def _job_processes(parent: int) -> list[int]:
    """Processes whose parent is ``parent`` and that run the job process's program."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{entry}/cmdline", "rb") as f:
                command = f.read()
        except OSError:
            continue
        if (int(fields[1]) == parent and fields[0] != "Z"
                and b"engine.runtime.job_process" in command):
            found.append(int(entry))
    return found


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="reads /proc (Linux)")
def test_a_real_time_engine_computes_k_changes_in_a_job_process_that_ends_with_it(
        small_scene):
    # issue 10, bug 3: the jobs of a K change shared the loop's interpreter lock and
    # lengthened its periods; an engine whose loop thread runs real-time (the process
    # engine, where the OS grants it) computes them in a process of its own
    engine = start(small_scene, "process")
    seen = Collector(engine)
    home = engine.transport.pid
    try:
        assert seen.wait(seen.ready)
        if "real-time (SCHED_FIFO" not in seen.of(rt.ReadyEvent)[0].message:
            pytest.skip("the OS did not grant the loop thread real-time scheduling here")
        assert seen.wait(lambda: _job_processes(home), 60.0), \
            "no job process under the engine's process"
        (child,) = _job_processes(home)
        for k in (6, 10):
            assert seen.change_modes(k)
        assert not [e for e in seen.of(rt.ErrorEvent)], seen.of(rt.ErrorEvent)
        landscape = seen.landscape()
        assert landscape is not None and landscape.modes == 10
        assert _job_processes(home) == [child]  # the same one served them all
    finally:
        engine.stop()
    deadline = time.monotonic() + 10
    while child in _job_processes(home) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert child not in _job_processes(home)


def _thread_loop(scene: Path, **kw) -> rt.EngineLoop:
    """A thread-engine loop on ``scene``, prepared in its thread (as start_engine's)."""
    from engine.sim import build_simulation

    handle = rt.open_scene(scene)
    sim, model = build_simulation(handle, backend="numba", prepare=False)
    loop = rt.EngineLoop(sim, model=model, prepare=True, base_dir=handle.path.parent, **kw)
    loop.start()
    return loop


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="reads /proc (Linux)")
@pytest.mark.parametrize("paced", [True, False])
def test_a_loop_at_normal_priority_keeps_its_spectral_work_in_its_own_process(
        small_scene, paced, monkeypatch):
    # on 2 cores a loop thread at normal priority can lose its CPU to a job process
    # (measured worse with one), and an unpaced run is headless: neither starts one
    import engine.runtime.job_process as job_process

    monkeypatch.setattr(job_process, "cpu_cores", lambda: 2)
    before = set(_job_processes(os.getpid()))
    engine = rt.EngineHandle(_thread_loop(small_scene, realtime=paced))
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        assert seen.change_modes(6)
        assert isinstance(engine.transport.sim.field.correlator.spectral, LocalSpectral)
        assert set(_job_processes(os.getpid())) == before
    finally:
        engine.stop()


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="reads /proc (Linux)")
def test_a_paced_loop_at_normal_priority_on_many_cores_offloads_to_a_job_process(
        small_scene, monkeypatch):
    # with cores to spare, the job process keeps a K change's landscapes off the loop's
    # interpreter lock, real-time scheduling or not (measured on 16 cores)
    import engine.runtime.job_process as job_process
    from engine.runtime.job_process import RemoteSpectral

    monkeypatch.setattr(job_process, "cpu_cores", lambda: job_process.CORES_WITHOUT_REALTIME)
    engine = rt.EngineHandle(_thread_loop(small_scene, realtime=True))
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        assert seen.change_modes(6)
        spectral = engine.transport.sim.field.correlator.spectral
        assert isinstance(spectral, RemoteSpectral)
        assert _job_processes(os.getpid()) == [spectral.jobs.pid]
    finally:
        engine.stop()


def test_the_job_process_rule():
    from engine.runtime.job_process import CORES_WITHOUT_REALTIME, wanted

    assert wanted(True, True, cores=2)
    assert not wanted(True, False, cores=CORES_WITHOUT_REALTIME - 1)
    assert wanted(True, False, cores=CORES_WITHOUT_REALTIME)
    assert not wanted(False, True, cores=64)  # unpaced: headless, never


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="reads /proc (Linux)")
def test_a_loop_told_so_offloads_its_correlator_to_one_job_process(small_scene):
    from engine.runtime.job_process import RemoteSpectral

    engine = rt.EngineHandle(_thread_loop(small_scene, job_process=True))
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        for k in (6, 10):
            assert seen.change_modes(k)
        spectral = engine.transport.sim.field.correlator.spectral
        assert isinstance(spectral, RemoteSpectral) and spectral.here == 0
        assert _job_processes(os.getpid()) == [spectral.jobs.pid]
        landscape = seen.landscape()
        assert landscape is not None and landscape.modes == 10
        assert not seen.of(rt.ErrorEvent)
        child = spectral.jobs.pid
    finally:
        engine.stop()
    assert child not in _job_processes(os.getpid())  # closed with the engine


def test_a_job_process_that_cannot_start_leaves_the_work_to_the_engine(small_scene,
                                                                        monkeypatch):
    from engine.runtime import guidance, job_process

    monkeypatch.setattr(guidance, "JobProcess", lambda: job_process.JobProcess(
        command=["/nonexistent/python-for-skelasm"]))
    engine = rt.EngineHandle(_thread_loop(small_scene, job_process=True))
    seen = Collector(engine)
    try:
        assert seen.wait(seen.ready)
        assert seen.change_modes(6)
        landscape = seen.landscape()
        assert landscape is not None and landscape.modes == 6
        assert not seen.of(rt.ErrorEvent)
        problem = engine.transport.guidance.jobs_problem
        assert problem is not None and "could not be started" in problem
        assert isinstance(engine.transport.sim.field.correlator.spectral, LocalSpectral)
    finally:
        engine.stop()


def test_only_the_process_engine_asks_for_priority(small_scene, monkeypatch):
    # a real-time loop thread sharing the interpreter with a window slowed the window's
    # thread (a GUI test: 2.7-3.0 s at normal priority, 4.0-14.3 s with SCHED_FIFO, one
    # CI failure; most of it was the job threads inheriting SCHED_FIFO, since fixed) and
    # showed no gain on K changes: the thread engine stays at normal priority, the
    # process engine asks
    monkeypatch.setenv("SKELASM_REALTIME", "0")  # ask, but let the OS answer "no" here
    # at normal priority both loops wait by spinning, yielding the CPU (engine.runtime.pacing)
    for transport, said in (("thread", "normal (not asked for)"),
                            ("process", "normal (SKELASM_REALTIME=0)")):
        engine = start(small_scene, transport)
        seen = Collector(engine)
        try:
            assert seen.wait(seen.ready)
            message = seen.of(rt.ReadyEvent)[0].message
            assert f"its loop thread: {said}, waiting by spinning" in message, transport
        finally:
            engine.stop()


def _load_too_high() -> str | None:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0
    cpus = os.cpu_count() or 1
    if load > 0.5 * cpus:
        return f"load average {load:.1f} on {cpus} CPUs: timing would measure the machine"
    return None


#: A K change may stall the loop by no more than this, or three times the longest period of
#: the steady loop just before, whichever is more (the bug was a stall of 1.2 s; reading the
#: spectra back from the cache cost 10 to 125 ms; the host alone stalls 8 to 12 ms at times).
STALL_BOUND_US = 20_000.0


@pytest.mark.slow
@pytest.mark.parametrize("rotation", ["free", "locked"])
def test_changing_k_never_stalls_the_loop(small_scene, transport, rotation):
    # issue 10, bug 3: SetModes recomputed the landscape's FFTs (rotation locked) or
    # re-sliced the spectra on the loop thread: one K change stalled the 1 kHz loop for
    # 1.2 s. A timing check, so slow-marked and skipped on a busy machine; `skelasm bench
    # loop --modes-sweep 12,6,8` measures the same with the full period distribution.
    # Two bounds: no stall beyond what the steady loop shows on this machine (asserted),
    # and the 2 ms goal (an expected failure where missed, with the figures).
    # Both figures are the longest period of one statistics window (STATS_WINDOW periods):
    # the steady loop's, then the one that holds the six K changes (sent as fast as the
    # loop takes them, as a dragged slider does), so that the host's own stalls, which
    # come at random, weigh the same in both.
    problem = _load_too_high()
    if problem:
        pytest.skip(problem)
    handle = rt.open_scene(small_scene)
    if rotation == "locked":
        effects = replace(handle.config.effects, axes=("x", "y", "z"))
        handle = replace(handle, config=replace(handle.config, effects=effects))
    engine = rt.start_engine(handle, process=transport == "process", backend="numba")
    seen = PeriodLog(engine)
    window = STATS_WINDOW + STATS_EVERY  # steps until a frame's statistics are all new
    try:
        assert seen.wait(seen.ready)
        time.sleep(1.5)  # past the start's own periods
        seen.drain()
        mark = seen.frames[-1].step
        assert seen.wait(lambda: seen.frames[-1].step >= mark + window, 10.0)
        steady = seen.frames[-1].period.max_us  # one window, no command
        begun = seen.frames[-1].step
        assert seen.wait(lambda: seen.frames[-1].step >= begun + STATS_EVERY, 10.0)
        for k in (12, 6, 10, 8, 12, 6):
            engine.send(rt.SetModes(k))
            assert seen.wait(lambda k=k: seen.frames[-1].modes == k, 30.0)
        done = seen.frames[-1].step
        # windows that begin after the steady one and, together, hold every K change
        end = max(begun + window, done + STATS_EVERY)
        assert seen.wait(lambda: seen.frames[-1].step >= end, 30.0)
        longest = max(top for step, _, top in seen.rows if begun + window <= step <= end)
    finally:
        engine.stop()
    assert longest <= max(STALL_BOUND_US, 3.0 * steady), (
        f"longest period {longest:.0f} us while K changed, {steady:.0f} us steady")
    if longest >= 2000.0:
        pytest.xfail(f"the goal is 2 ms: longest period {longest:.0f} us while K changed, "
                     f"{steady:.0f} us in the steady window before (docs/runtime.md, "
                     "'Handing a new field over': a K change's jobs still lengthen some "
                     "periods, through the interpreter lock and the cores they share with "
                     "the loop's process; the host alone stalls a loop at times too)")
