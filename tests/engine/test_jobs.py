"""The job worker's field builds: a K change reuses the spectra in use (issue 10, bug 3)."""

import time
from dataclasses import replace

import numpy as np
import pytest

import engine.correlation.correlator as correlator_module
import engine.runtime as rt
from engine.pose import rotation_matrix
from engine.runtime.jobs import FieldRequest, build_field
from engine.sim.build import SceneModel
from engine.sim.fields import LandscapeField, RotationCacheField


@pytest.fixture(scope="module")
def model(small_peg_scene):
    return SceneModel(rt.open_scene(small_peg_scene), backend="numba")


@pytest.mark.parametrize("rotation", [True, False])
def test_a_k_change_cuts_the_spectra_in_use_again(model, rotation, monkeypatch):
    axes = ("x", "y", "z", "rx", "ry", "rz") if rotation else ("x", "y", "z")
    effects = replace(model.config.effects, axes=axes)
    kappa = model.physics(effects).kappa
    field, descriptors = model.field(effects, kappa, np.eye(3))
    old = field.correlator

    # from here on, building spectra (disk cache or FFT) fails the test
    def no_spectra(*args, **kwargs):
        raise AssertionError("a K change rebuilt the spectra")

    monkeypatch.setattr(correlator_module, "build_spectra", no_spectra)
    request = FieldRequest(id=1, task="field", effects=effects, kappa=kappa,
                           locked_rotation=np.eye(3), modes=12, descriptors=descriptors,
                           correlator=old)
    response = build_field(model, request)
    assert response.error is None
    new = response.field
    # rotation free: the rotation cache serves the numba correlator (its first cache built
    # here, in the worker's build)
    assert isinstance(new, RotationCacheField if rotation else LandscapeField)
    assert new.correlator.spectra is old.spectra
    assert new.correlator.table.modes == 12 and old.table.modes == 8
    # the shared spectra give the same result as a correlator built from scratch at K = 12
    monkeypatch.undo()
    fresh, _ = model.field(effects, kappa, np.eye(3), modes=12)
    if rotation:  # the same path: a cache at the same rotation (model.field has turned it)
        fresh = RotationCacheField(fresh.correlator, kappa, np.eye(3))
    pose = (np.eye(3), np.array([0.3, -0.2, 4.0]))
    a, b = new.evaluate(*pose), fresh.evaluate(*pose)
    assert a.energy == pytest.approx(b.energy, rel=1e-12)
    assert np.allclose(a.force, b.force, rtol=1e-10, atol=1e-12 * abs(a.energy))


def test_without_the_correlator_in_use_the_spectra_are_built(model, monkeypatch):
    effects = model.config.effects
    kappa = model.physics(effects).kappa
    _, descriptors = model.field(effects, kappa, np.eye(3))
    calls = []
    real = correlator_module.build_spectra
    monkeypatch.setattr(correlator_module, "build_spectra",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    build_field(model, FieldRequest(id=2, task="field", effects=effects, kappa=kappa,
                                    locked_rotation=np.eye(3), modes=12,
                                    descriptors=descriptors))
    assert calls


def test_a_rotation_cache_field_is_handed_over_at_the_rotation_the_part_has_now(model):
    """The request is made at I; by the end of the build the part has turned 20 mrad. The
    first cache is built where the part is then, so the loop's first poses are served by it
    rather than by the full path (which costs milliseconds on a real grid).
    """
    effects = replace(model.config.effects, axes=("x", "y", "z", "rx", "ry", "rz"))
    kappa = model.physics(effects).kappa
    field, descriptors = model.field(effects, kappa, np.eye(3))
    turned = rotation_matrix(np.array([0.0, 2e-2, 0.0]))
    request = FieldRequest(id=3, task="field", effects=effects, kappa=kappa,
                           locked_rotation=np.eye(3), modes=12, descriptors=descriptors,
                           correlator=field.correlator)
    late = build_field(model, request, rotation_now=lambda: turned).field
    assert isinstance(late, RotationCacheField)
    np.testing.assert_array_equal(late.reference_rotation, turned)
    # its full path is timed here, in the worker, not at the loop's first slow pose
    assert late.full_us is not None and late.full_us > 0
    asked = build_field(model, request).field  # without it: the request's rotation
    np.testing.assert_array_equal(asked.reference_rotation, np.eye(3))
    assert asked.full_us is None


def test_jobs_leave_a_core_to_the_loop(monkeypatch):
    """A job's numeric calls may use every core but one; the caller's thread keeps them all."""
    import engine.backend as backend
    from engine.runtime.jobs import JobWorker, LandscapeResponse

    monkeypatch.setattr(backend, "cpu_cores", lambda: 4)
    worker = JobWorker()
    try:
        worker.submit("landscape", lambda cancelled: LandscapeResponse(
            1, (backend.thread_budget(),)))
        assert worker.wait_until_idle(10.0)
        (response,) = worker.responses()
    finally:
        worker.shutdown()
    assert response.rotvec == (3,)
    assert backend.thread_budget() == 4


def _wait_idle(worker, timeout=10.0):
    end = time.monotonic() + timeout
    while worker.busy and time.monotonic() < end:
        time.sleep(0.01)
    return not worker.busy


def test_the_worker_drops_what_it_is_handed_on_its_own_thread():
    """Freeing a replaced field's arrays takes milliseconds: not on the caller's thread."""
    import threading
    import weakref

    from engine.runtime.jobs import JobWorker

    class Thing:
        pass

    dropped = []
    worker = JobWorker()
    try:
        thing = Thing()
        weakref.finalize(thing, lambda: dropped.append(threading.current_thread().name))
        worker.dispose(thing)
        del thing
        assert _wait_idle(worker)
    finally:
        worker.shutdown()
    assert len(dropped) == 1 and dropped[0].startswith("skelasm-jobs"), dropped


def test_a_replaced_field_is_freed_off_the_loop_thread(small_peg_scene):
    """A K change's old field (a landscape: 44 MB at grid 56, 0.4 to 2.3 ms to free) is
    dropped on the worker's thread; before, the loop thread freed it inside a period.
    """
    import threading
    import weakref

    from engine.sim import build_simulation

    handle = rt.open_scene(small_peg_scene)
    effects = replace(handle.config.effects, axes=("x", "y", "z"))  # a landscape field
    handle = replace(handle, config=replace(handle.config, effects=effects))
    sim, model = build_simulation(handle, modes=8, backend="numba", prepare=False)
    loop = rt.EngineLoop(sim, model=model, realtime=False, prepare=True)
    dropped = []
    try:
        end = time.monotonic() + 30.0
        while not loop.guidance.descriptors and time.monotonic() < end:
            loop.run(max_steps=20)
        assert isinstance(sim.field, LandscapeField)
        weakref.finalize(sim.field, lambda: dropped.append(threading.current_thread().name))
        loop.send(rt.SetModes(12))
        end = time.monotonic() + 30.0
        while sim.field.modes != 12 and time.monotonic() < end:
            loop.run(max_steps=20)
        assert sim.field.modes == 12
        loop.run(max_steps=5)
        assert _wait_idle(loop.guidance.worker)
    finally:
        loop.guidance.close()
    assert len(dropped) == 1 and dropped[0].startswith("skelasm-jobs"), (
        f"the replaced field was freed on {dropped}, not the worker's thread")


def test_the_loop_asks_for_fields_at_the_rotation_it_steps(model, monkeypatch):
    """Guidance gives the worker a reader of the simulation's rotation, read at call time."""
    import collections

    import engine.runtime.guidance as guidance_module
    from engine.sim import build_simulation

    sim, sim_model = build_simulation(model.handle, modes=8, backend="numba")
    guidance = guidance_module.Guidance(sim, sim_model, collections.deque())
    readers = []
    monkeypatch.setattr(guidance_module, "build_field",
                        lambda m, r, **kw: readers.append(kw["rotation_now"]) or
                        guidance_module.FieldResponse(r.id, r, cancelled=True))
    try:
        guidance.set_modes(12)  # unpaced: refreshed in the step, no catch-up, no timing
        assert guidance.worker.wait_until_idle(10.0)
        guidance.background_refresh = True  # paced
        guidance.set_modes(16)
        assert guidance.worker.wait_until_idle(10.0)
    finally:
        guidance.close()
    unpaced, read = readers
    assert unpaced is None
    sim.state._R = turned = rotation_matrix(np.array([0.0, 0.0, 0.3]))
    assert read() is turned


def test_a_k_change_brings_the_new_fields_stiffness_into_the_physics(small_peg_scene):
    """The fit's rotational stiffness changes with K, and the default rotational coupling
    follows it: a K change measures it on the new field (in the worker), and the loop puts
    it into the physics when it swaps the field in. Before, the physics kept the stiffness
    of the last field built from descriptors.
    """
    import time

    from engine.sim import build_simulation, rotational_stiffness
    from engine.sim.build import ROTATION_AUTHORITY

    handle = rt.open_scene(small_peg_scene)
    sim, model = build_simulation(handle, modes=8, backend="numba")
    at8 = model.geometric_rotation
    assert at8 is not None
    # a geometric gain at which the fit sets the rotational coupling (a quarter of the
    # mass-based stiffness I (2 pi f)^2 at the stiffer of K = 8 and 12, so that both stay
    # under that cap; at the default gain it sits at its floor here), so that the
    # stiffness shows in it
    physics = model.physics(sim.effects)
    k_mass = np.trace(physics.inertia) / 3 * (2 * np.pi * model.config.coupling.frequency_hz) ** 2
    fresh, _ = model.field(sim.effects, 1.0, np.eye(3), modes=12)
    at12 = rotational_stiffness(fresh, model.assembled_pose)
    kappa = 0.25 * k_mass * ROTATION_AUTHORITY / max(at8, at12)
    loop = rt.EngineLoop(sim, model=model, realtime=False, prepare=True)
    try:
        end = time.monotonic() + 30.0
        while not loop.guidance.descriptors and time.monotonic() < end:
            loop.run(max_steps=20)  # the first field, built by the worker as the window's is
        assert loop.guidance.descriptors  # so a K change reuses them
        loop.send(rt.SetKappa(kappa))
        loop.run(max_steps=1)
        k_rot_at8 = sim.physics.k_rot
        loop.send(rt.SetModes(12))
        end = time.monotonic() + 30.0
        while sim.field.modes != 12 and time.monotonic() < end:
            loop.run(max_steps=20)
        assert sim.field.modes == 12
        loop.run(max_steps=1)  # the physics is resolved between two steps
    finally:
        loop.guidance.close()
    in_use, k_rot = model.geometric_rotation, sim.physics.k_rot  # set by the loop at the swap
    assert abs(at12 - at8) > 0.05 * at8  # K matters on this scene, so the check can fail
    assert kappa * at12 / ROTATION_AUTHORITY < k_mass  # the fit, not the cap, sets it
    assert in_use == pytest.approx(at12, rel=1e-9)
    assert k_rot == pytest.approx(kappa * at12 / ROTATION_AUTHORITY, rel=1e-9)
    assert k_rot_at8 == pytest.approx(kappa * at8 / ROTATION_AUTHORITY, rel=1e-9)


def test_a_descriptor_job_leaves_the_stiffness_in_use_alone(model):
    """The worker's descriptor path used to write the new field's stiffness into the model
    while the loop resolved physics from it: a gain changed during a recompute then scaled
    the rotational coupling to a field not yet in use. The response carries it; only the
    loop puts it in use, at the swap.
    """
    from engine.sim import rotational_stiffness

    effects = replace(model.config.effects, axes=("x", "y", "z", "rx", "ry", "rz"))
    kappa = model.physics(effects).kappa
    before = model.geometric_rotation
    model.geometric_rotation = in_use = 123.0
    try:
        response = build_field(model, FieldRequest(id=4, task="descriptors", effects=effects,
                                                   kappa=kappa, locked_rotation=np.eye(3),
                                                   modes=12))
        assert model.geometric_rotation == in_use
    finally:
        model.geometric_rotation = before
    assert response.error is None and response.stiffness is not None
    assert response.stiffness == pytest.approx(
        rotational_stiffness(response.field, model.assembled_pose), rel=1e-12)
    assert response.stiffness != pytest.approx(in_use)


def test_a_field_built_before_the_loop_lends_its_descriptors_to_a_new_k(
        small_peg_scene, monkeypatch):
    """A simulation prepared before its loop (``build_simulation(prepare=True)``, as
    ``skelasm bench loop`` and scripts do): a K change reuses the field's descriptors and
    correlator, as for a field the loop built; before, it took the descriptor path (the
    descriptors read again from the cache and a new correlator built, 0.6 s on the peg).
    """
    from engine.runtime import guidance as guidance_module
    from engine.runtime.messages import DescriptorsSwapped, ProgressEvent
    from engine.sim import build_simulation

    handle = rt.open_scene(small_peg_scene)
    sim, model = build_simulation(handle, modes=8, backend="numba")
    assert model.prepared is not None and model.prepared[0] is sim.field
    requests = []
    real = guidance_module.build_field
    monkeypatch.setattr(guidance_module, "build_field",
                        lambda m, r, **kw: requests.append(r) or real(m, r, **kw))
    loop = rt.EngineLoop(sim, model=model, realtime=False)
    try:
        assert loop.guidance.descriptors is model.prepared[1]
        first = sim.field.correlator
        loop.send(rt.SetModes(12))
        end = time.monotonic() + 30.0
        while sim.field.modes != 12 and time.monotonic() < end:
            loop.run(max_steps=20)
        assert sim.field.modes == 12
        events = list(loop.events)
    finally:
        loop.guidance.close()
    assert [r.task for r in requests] == ["field"]
    assert requests[0].correlator is first and requests[0].descriptors == model.prepared[1]
    assert not any(isinstance(e, DescriptorsSwapped) for e in events)
    assert any(isinstance(e, ProgressEvent) and e.task == "field" and e.fraction == 1.0
               for e in events)
    # a loop given another field than the prepared one reuses nothing
    other, _ = model.field(sim.effects, 1.0, np.eye(3), modes=8)
    sim.set_field(other)
    fresh = rt.EngineLoop(sim, model=model, realtime=False)
    try:
        assert fresh.guidance.descriptors == ()
    finally:
        fresh.guidance.close()
