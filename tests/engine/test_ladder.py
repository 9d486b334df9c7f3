"""The sigma ladder (engine.descriptor.ladder) and its background job (engine.runtime.ladder_jobs).

Known answers: a sigma between the nodes, interpolated, against the same sigma computed
directly on the same grid; a node's own sigma reproduced; a sigma outside the span refused.
The engine: with the ladders complete, a new sigma is served from them (the descriptors'
provenance says so) and a new penalty applies on top; the job gives way to other work.
All on the bundled peg in hole at a 16-sample grid (a ladder of both parts: about 8 s).
"""

from __future__ import annotations

import collections
import time
from dataclasses import replace

import numpy as np
import pytest

from engine import runtime as rt
from engine.descriptor import descriptor_for_part, grid_for_part, scene_spacing
from engine.descriptor import ladder as lad
from engine.errors import Cancelled
from engine.grid import Grid
from engine.params import Effects
from engine.runtime.jobs import FieldRequest, FieldResponse, JobWorker, LadderResponse
from engine.runtime.ladder_jobs import LadderJobs
from engine.scene import load_scene, load_scene_parts


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A cache of the module's own: the ladders computed once serve every test here."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SKELASM_CACHE", str(tmp_path_factory.mktemp("ladder-cache")))
        yield


@pytest.fixture(scope="module")
def ladders(cache, small_peg_scene):
    """(scene, parts, grids) of the small peg scene as the engine opens it, ladders cached."""
    handle = rt.open_scene(small_peg_scene)
    scene, parts = handle.scene, list(handle.parts)
    spacing = scene_spacing(scene, parts)
    grids = [grid_for_part(p, spacing=spacing, padding=scene.descriptor.padding)
             for p in parts]
    before = [lad.ladder_cached(p, g, scene.descriptor) for p, g in zip(parts, grids, strict=True)]
    for part, grid in zip(parts, grids, strict=True):
        seen: list[float] = []
        nodes = lad.ladder_for_part(part, grid, scene.descriptor, progress=seen.append)
        assert [d.params.sigma for d in nodes] == pytest.approx(list(lad.ladder_sigmas()))
        assert seen and seen[-1] == 1.0 and seen == sorted(seen)
    assert not any(before), "a fresh cache holds no ladder"
    assert all(lad.ladder_cached(p, g, scene.descriptor) for p, g in zip(parts, grids, strict=True))
    assert lad.scene_ladder_cached(scene, parts)
    return scene, parts, grids


def test_ladder_nodes_are_chebyshev_points_in_log_sigma_within_the_span():
    s = lad.ladder_sigmas()
    lo, hi = lad.LADDER_SPAN
    assert len(s) == lad.LADDER_NODES and np.all(np.diff(s) > 0)
    assert lo < s[0] and s[-1] < hi
    # symmetric about the span's middle in log sigma
    assert np.log(s) + np.log(s[::-1]) == pytest.approx(np.full(len(s), np.log(lo * hi)))


@pytest.mark.parametrize("which", [0, 1])
def test_a_sigma_between_the_nodes_is_interpolated_as_a_direct_computation(ladders, which):
    # The ladder of the peg's block at its scene grid (69 x 69 x 41) measured 1.8e-3 of RMS
    # at sigma 0.7; here (16 samples) 1.8e-3 and 1.5e-3. The bound, 5e-3, is the adaptive
    # sampling's own tolerance (3e-3 of RMS per sample, ADAPTIVE_TOLERANCE) with a margin:
    # each node carries that error and the weights sum to 1. The largest error (2e-2 and
    # 5.8e-2 of RMS, at a few samples at the surface, where the adaptive sampling settles
    # differently per sigma) is bounded at 0.1.
    scene, parts, grids = ladders
    params = replace(scene.descriptor, sigma=0.7, penalty=5.0)
    got = lad.interpolated_descriptor(parts[which], grids[which], params)
    direct = descriptor_for_part(parts[which], grids[which], params)
    assert got.method == "ladder" and got.ladder == tuple(lad.ladder_sigmas())
    assert direct.method == "adaptive" and direct.ladder == ()
    assert got.params == params and got.grid == grids[which]
    err = np.abs(got.rho.astype(np.complex128) - direct.rho)
    rms = np.sqrt(np.mean(np.abs(direct.rho) ** 2))
    assert np.sqrt(np.mean(err ** 2)) / rms < 5e-3
    assert err.max() / rms < 0.1


def test_a_nodes_own_sigma_is_the_node(ladders):
    scene, parts, grids = ladders
    s = float(lad.ladder_sigmas()[2])
    params = replace(scene.descriptor, sigma=s)
    got = lad.interpolated_descriptor(parts[1], grids[1], params)
    node = descriptor_for_part(parts[1], grids[1], params)
    np.testing.assert_allclose(got.rho, node.rho, rtol=1e-5, atol=1e-5 * np.abs(node.rho).max())


def test_a_sigma_outside_the_span_is_not_interpolated(ladders):
    scene, parts, grids = ladders
    lo, hi = lad.LADDER_SPAN
    for sigma in (0.5 * lo, 1.5 * hi):
        assert not lad.in_span(sigma)
        with pytest.raises(ValueError, match="outside the ladder's span"):
            lad.interpolated_descriptor(parts[0], grids[0], replace(scene.descriptor,
                                                                    sigma=sigma))
    assert lad.in_span(lo) and lad.in_span(hi)


def test_an_incomplete_ladder_is_not_interpolated(cache, tmp_path, small_peg_scene):
    scene = load_scene(small_peg_scene)
    part = load_scene_parts(scene)[1]
    grid = grid_for_part(part, samples=6, padding=1)  # a ladder no other test computes
    assert not lad.ladder_cached(part, grid, scene.descriptor)
    with pytest.raises(lad.LadderIncomplete):
        lad.interpolated_descriptor(part, grid, replace(scene.descriptor, sigma=0.7))


def test_the_fine_levels_grids_get_ladders_and_a_new_sigmas_level_reads_them(
        ladders, small_peg_scene, monkeypatch):
    """The scene's ladder job also ladders the fine level's two grids (they do not depend
    on sigma); a level at a new sigma then reads its fine descriptors from them instead of
    computing them (24 to 65 s afresh on the bundled pairs), and a direct computation in the
    cache still comes first.
    """
    from engine.sim import build_simulation
    from engine.sim.fine import fine_rungs

    handle = rt.open_scene(small_peg_scene)
    sim, model = build_simulation(handle, prepare=False, modes=8)
    scene, parts, grids = ladders
    rungs = fine_rungs(parts[0], parts[1], grids[0], grids[1], model.assembled_pose,
                       model._fit)
    assert len(rungs) == 2  # the level is finer than the descriptors here
    assert all(g.spacing < grids[0].spacing for _, g in rungs)
    assert not any(lad.ladder_cached(p, g, scene.descriptor) for p, g in rungs)
    seen: list[float] = []
    model.prepare_ladder(progress=seen.append)
    assert seen[-1] == 1.0 and seen == sorted(seen)
    assert all(lad.ladder_cached(p, g, scene.descriptor) for p, g in rungs)

    params = replace(scene.descriptor, sigma=0.8)  # not a node, never computed here
    part, grid = rungs[1]
    got = lad.descriptor_preferring_ladder(part, grid, params)
    assert got.method == "ladder"
    # the level at that sigma computes no descriptor: both fine grids come from the ladders
    computed: list[Grid] = []
    real = lad.descriptor_for_part

    def counting(part, grid, params, **kw):
        if kw.get("progress") is not None or kw.get("cancel") is not None:
            computed.append(grid)  # a computation asked for (the ladder loads without)
        return real(part, grid, params, **kw)

    monkeypatch.setattr(lad, "descriptor_for_part", counting)
    d1, d2 = (replace(lad.interpolated_descriptor(p, g, params), params=params)
              for p, g in zip(parts, grids, strict=True))
    near = model.near_field(sim.effects, (d1, d2), cancel=lambda: False)
    assert near is not None and computed == []
    # a direct computation in the cache comes first (exact, and as quick)
    direct = real(part, grid, params)
    again = lad.descriptor_preferring_ladder(part, grid, params)
    assert again.method == direct.method == "adaptive"
    err = np.abs(got.rho.astype(np.complex128) - direct.rho)
    rms = np.sqrt(np.mean(np.abs(direct.rho) ** 2))
    assert np.sqrt(np.mean(err ** 2)) / rms < 5e-3  # as on the scene's grids (above)


def _wait(engine, events, predicate, timeout=180.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        events += engine.poll_events()
        engine.poll_frames()
        for e in events:
            if isinstance(e, rt.ErrorEvent):
                raise AssertionError(e.message)
        found = [e for e in events if predicate(e)]
        if found:
            return found[-1]
        time.sleep(0.01)
    raise AssertionError(f"timed out; events: {[type(e).__name__ for e in events][-20:]}")


def test_with_the_ladders_ready_a_new_sigma_is_served_from_them_and_a_penalty_on_top(
        ladders, small_peg_scene, monkeypatch):
    monkeypatch.setenv("SKELASM_LIVE_SIGMA", "1")
    handle = rt.open_scene(small_peg_scene)
    own = handle.scene.descriptor
    engine = rt.start_engine(handle, process=False, backend="numba")
    events: list = []
    try:
        _wait(engine, events, lambda e: isinstance(e, rt.ReadyEvent))
        assert lad.scene_ladder_cached(handle.scene, list(handle.parts))
        sigma = 0.9  # not a node, and never computed directly here
        events.clear()
        engine.send(rt.SetDescriptorParams(params=replace(own, sigma=sigma)))
        swapped = _wait(engine, events, lambda e: isinstance(e, rt.DescriptorsSwapped))
        assert swapped.coarse_grid is None and swapped.sigma == pytest.approx(sigma)
        assert [d.method for d in swapped.descriptors] == ["ladder", "ladder"]
        assert all(d.ladder == tuple(lad.ladder_sigmas()) for d in swapped.descriptors)
        events.clear()
        engine.send(rt.SetDescriptorParams(params=replace(own, sigma=sigma, penalty=5.0)))
        again = _wait(engine, events, lambda e: isinstance(e, rt.DescriptorsSwapped))
        assert again.penalty == pytest.approx(5.0)
        for before, after in zip(swapped.descriptors, again.descriptors, strict=True):
            assert after.method == "ladder" and after.params.penalty == 5.0
            ratio = after.rho / before.rho  # lambda_in 5 / 3 inside, 1 outside
            inside = np.isclose(ratio, 5.0 / before.params.penalty, rtol=1e-4)
            outside = np.isclose(ratio, 1.0, rtol=1e-4)
            assert np.all(inside | outside) and inside.any() and outside.any()
    finally:
        engine.stop()


class _SlowLadder:
    """A model whose ladder is three nodes of 20 cancel polls each."""

    def __init__(self):
        self.calls = 0
        self.nodes = 0

    def prepare_ladder(self, *, progress=None, cancel=None):
        self.calls += 1
        while self.nodes < 3:
            for _ in range(20):
                time.sleep(0.005)
                if cancel():
                    raise Cancelled("stopped")
            self.nodes += 1
            progress(self.nodes / 3)


def _swapped(guidance="skeletal", coarse=None):
    request = FieldRequest(id=1, task="descriptors", effects=Effects(guidance=guidance),
                           kappa=1.0, locked_rotation=np.eye(3), modes=8)
    return FieldResponse(1, request, coarse_grid=coarse)


def _pump(worker, jobs, until, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end and not until():
        for r in worker.responses():
            if isinstance(r, LadderResponse):
                jobs.deliver(r)
        time.sleep(0.005)


def test_the_ladder_job_gives_way_to_other_work_and_resumes(monkeypatch):
    monkeypatch.setenv("SKELASM_LIVE_SIGMA", "1")
    worker, events, model = JobWorker(), collections.deque(), _SlowLadder()
    jobs = LadderJobs(model, worker, events)
    try:
        jobs.resume(_swapped(coarse=24))  # a coarse first field: not yet
        jobs.resume(_swapped(guidance="collision"))
        assert model.calls == 0 and worker.wait_until_idle(1.0)
        jobs.resume(_swapped())
        _pump(worker, jobs, lambda: model.nodes >= 1)
        ran = []
        worker.submit("landscape", lambda cancelled: ran.append(model.calls))
        _pump(worker, jobs, lambda: jobs.complete)
        assert jobs.complete and model.nodes == 3
        assert ran == [1] and model.calls >= 2  # it stopped for the landscape, then went on
        assert events[-1] == rt.ProgressEvent("ladder", 1.0, "done")
        fractions = [e.fraction for e in events if not e.message]
        assert fractions == sorted(fractions) and fractions[-1] == 1.0
    finally:
        worker.shutdown()


def test_a_field_job_pauses_the_ladder_job_and_the_next_swap_resumes_it(monkeypatch):
    monkeypatch.setenv("SKELASM_LIVE_SIGMA", "1")
    worker, events, model = JobWorker(), collections.deque(), _SlowLadder()
    jobs = LadderJobs(model, worker, events)
    try:
        jobs.resume(_swapped())
        _pump(worker, jobs, lambda: model.calls == 1)
        jobs.pause()
        assert events[-1].message == "paused"
        assert worker.wait_until_idle(2.0) and not jobs.complete
        assert not [r for r in worker.responses() if isinstance(r, LadderResponse)]
        jobs.resume(_swapped())
        _pump(worker, jobs, lambda: jobs.complete)
        assert jobs.complete and model.calls == 2
    finally:
        worker.shutdown()


def test_live_sigma_off_starts_no_ladder_job(monkeypatch):
    monkeypatch.setenv("SKELASM_LIVE_SIGMA", "0")
    worker, model = JobWorker(), _SlowLadder()
    try:
        LadderJobs(model, worker, collections.deque()).resume(_swapped())
        assert worker.wait_until_idle(1.0) and model.calls == 0
    finally:
        worker.shutdown()
