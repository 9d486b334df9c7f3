"""The descriptor parameters travel as one frozen object from the widget to the kernel.

The parameter panel builds a :class:`engine.params.DescriptorParams` (the scene's, with the
panel's sigma and penalty) and the very same object reaches the descriptor kernels
(``compute_descriptor``): this test walks the path on the real engine (thread transport,
so nothing is pickled on the way) and counts the carriers the object rides in. A path that
unpacked sigma into a float, or rebuilt the parameters on the way, breaks the identity.
"""

from __future__ import annotations

import dataclasses
import threading

import pytest

import engine.descriptor.store as store
import engine.runtime.guidance as guidance
import engine.runtime.jobs as jobs
from app.gui.params_panel import ParamsPanel
from engine import runtime
from engine.params import DescriptorParams

#: The most carriers the parameters may pass through between the widget and the kernel.
MAX_HOPS = 6


def _no_loose_floats(cls) -> None:
    names = {f.name for f in dataclasses.fields(cls)}
    assert not names & {"sigma", "penalty"}, f"{cls.__name__} carries loose {names}"


def test_sigma_reaches_the_kernel_as_the_object_the_widget_built(qtbot, small_scene,
                                                                 monkeypatch):
    handle = runtime.open_scene(small_scene)
    panel = ParamsPanel()
    qtbot.addWidget(panel)
    panel.load_config(handle.config, handle.scene.modes, handle.scene.descriptor)
    sent = []
    panel.command.connect(sent.append)

    engine = runtime.start_engine(handle, process=False, realtime=False)
    try:
        deadline = 600.0  # the first start in a fresh environment compiles the kernels
        seen: list[object] = []
        ready = threading.Event()

        def wait_ready() -> bool:
            seen.extend(engine.poll_events())
            return any(isinstance(e, runtime.ReadyEvent) for e in seen)

        qtbot.waitUntil(wait_ready, timeout=int(deadline * 1000))
        # the carriers, recorded where each hands the object on
        carriers: list[tuple[str, object]] = []
        real_build, real_scene, real_compute = (guidance.build_field,
                                                store.descriptors_for_scene,
                                                store.descriptor_and_side)

        def build_field(model, request, **kw):
            carriers.append(("FieldRequest", request.descriptor))
            return real_build(model, request, **kw)

        def descriptors_for_scene(scene, **kw):
            carriers.append(("Scene", scene.descriptor))
            return real_scene(scene, **kw)

        def descriptor_and_side(vertices, faces, grid, params, **kw):
            carriers.append(("compute_descriptor", params))
            ready.set()
            return real_compute(vertices, faces, grid, params, **kw)

        monkeypatch.setattr(guidance, "build_field", build_field)  # as the worker calls it
        monkeypatch.setattr(store, "descriptors_for_scene", descriptors_for_scene)
        monkeypatch.setattr(store, "descriptor_and_side", descriptor_and_side)

        panel.sigma.setValue(0.8)  # a typed value: applied at once
        (command,) = [c for c in sent if isinstance(c, runtime.SetDescriptorParams)]
        built = command.params
        assert isinstance(built, DescriptorParams) and built.sigma == 0.8
        assert built.grid == handle.scene.descriptor.grid  # the scene's, sigma replaced
        engine.send(command)
        assert ready.wait(deadline), "no descriptor was computed for the new sigma"
    finally:
        engine.stop()
    path = [("SetDescriptorParams", built), *carriers]
    kernel = [obj for where, obj in path if where == "compute_descriptor"]
    assert kernel and all(obj is built for obj in kernel), path  # the same object, unchanged
    hops = [where for where, obj in path if obj is built]
    assert hops[:4] == ["SetDescriptorParams", "FieldRequest", "Scene", "compute_descriptor"]
    assert len(dict.fromkeys(hops)) <= MAX_HOPS, hops
    for cls in (runtime.SetDescriptorParams, jobs.FieldRequest):
        _no_loose_floats(cls)
    with pytest.raises(TypeError):  # parameter objects are built by keyword only
        jobs.FieldRequest(1, "field", None, 1.0, None, 8)
    with pytest.raises(TypeError):
        DescriptorParams(0.8, 3.0)  # type: ignore[misc]
    with pytest.raises(TypeError):
        runtime.SetDescriptorParams(built)  # type: ignore[misc]
