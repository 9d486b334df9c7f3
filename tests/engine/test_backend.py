import pytest

from engine import backend as backend_mod


def test_numpy_backend_always_available():
    b = backend_mod.get_backend("numpy")
    assert b.name == "numpy"
    assert b.context is None
    assert "numpy" in backend_mod.available_backends()


def test_unknown_backend_names_the_valid_ones():
    with pytest.raises(ValueError, match="numpy, numba, opencl, auto"):
        backend_mod.get_backend("cuda")


def test_environment_variable_forces_backend(monkeypatch):
    monkeypatch.setenv("SKELASM_BACKEND", "numpy")
    assert backend_mod.resolve("per_pose").name == "numpy"


def test_auto_is_chosen_per_capability_only():
    """One meaning of "auto": resolve(capability); get_backend makes backends by name."""
    with pytest.raises(ValueError, match="per capability"):
        backend_mod.get_backend("auto")
    assert not hasattr(backend_mod, "AUTO_ORDER")  # no second, capability-free order


@pytest.mark.skipif("opencl" not in backend_mod.available_backends(), reason="no OpenCL device")
def test_opencl_backend_has_context_and_queue():
    b = backend_mod.get_backend("opencl")
    assert b.name == "opencl"
    assert b.queue is not None and b.device is not None
    assert b.describe().startswith("opencl on ")


@pytest.mark.skipif("opencl" not in backend_mod.available_backends(), reason="no OpenCL device")
def test_missing_device_gives_clear_message():
    with pytest.raises(backend_mod.BackendError, match="no OpenCL device matches 'no-such-gpu'"):
        backend_mod.get_backend("opencl", device="no-such-gpu")


@pytest.mark.gpu
def test_automatic_choice_prefers_a_gpu():
    cl = pytest.importorskip("pyopencl")
    gpus = []
    for platform in cl.get_platforms():
        try:
            gpus += [d for d in platform.get_devices() if d.type & cl.device_type.GPU]
        except cl.Error:
            continue
    if not gpus:
        pytest.skip("no GPU OpenCL device here")
    chosen = backend_mod.get_backend("opencl")
    assert chosen.is_gpu, chosen.describe()
    # the descriptor and correlation tests then run their OpenCL cases on this GPU


@pytest.fixture
def fresh_registry(monkeypatch):
    """The registry with nothing created yet (restored afterwards)."""
    monkeypatch.setattr(backend_mod, "_made", {})
    monkeypatch.delenv("SKELASM_BACKEND", raising=False)
    return backend_mod


def test_numba_backend_is_registered():
    pytest.importorskip("numba")
    b = backend_mod.get_backend("numba")
    assert b.name == "numba" and b.context is None
    assert "numba" in backend_mod.available_backends()


def test_missing_backend_fails_only_when_asked_for_with_its_original_error(fresh_registry,
                                                                           monkeypatch):
    original = ImportError("No module named 'numba' (simulated)")

    def broken(device):
        raise original

    monkeypatch.setitem(fresh_registry._FACTORIES, "numba", broken)
    monkeypatch.setitem(fresh_registry.CAPABILITIES, "per_pose",
                        fresh_registry.Capability("per_pose", ("numba", "numpy")))
    # nothing fails until numba is asked for: auto passes over it
    assert fresh_registry.resolve("per_pose").name == "numpy"
    assert "numba" not in fresh_registry.available_backends()
    with pytest.raises(fresh_registry.BackendError, match="simulated") as info:
        fresh_registry.get_backend("numba")
    assert info.value.__cause__ is original
    # and again, with the same cause (the failure is registered, not retried)
    with pytest.raises(fresh_registry.BackendError) as again:
        fresh_registry.get_backend("numba")
    assert again.value.__cause__ is original


def test_auto_takes_the_first_backend_of_the_order_that_works(fresh_registry, monkeypatch):
    pytest.importorskip("numba")
    caps, cap = fresh_registry.CAPABILITIES, fresh_registry.Capability
    monkeypatch.setitem(caps, "per_pose", cap("per_pose", ("numba", "numpy")))
    assert fresh_registry.resolve("per_pose").name == "numba"
    monkeypatch.setitem(caps, "per_pose", cap("per_pose", ("numpy", "numba")))
    assert fresh_registry.resolve("per_pose").name == "numpy"


def test_names_are_checked_in_one_place():
    assert backend_mod.check_name("NumBa") == "numba"
    with pytest.raises(ValueError, match="valid: numpy, numba, opencl, auto"):
        backend_mod.check_name("cuda")


# ------------------------------------------------------------------ capabilities


def test_each_capability_offers_its_backends_reference_first_and_auto():
    assert backend_mod.choices("per_pose") == ("numpy", "numba", "opencl", "auto")
    assert backend_mod.choices("descriptor") == ("numba", "opencl", "auto")
    assert backend_mod.choices("fft") == ("numpy", "auto")
    with pytest.raises(ValueError, match="valid: numba, opencl, auto"):
        backend_mod.check_choice("descriptor", "numpy")
    with pytest.raises(ValueError, match="valid: descriptor, per_pose, fft"):
        backend_mod.choices("ray tracing")


class _FakeOpenCL:
    """An OpenCL backend on a CPU or a GPU device, without OpenCL."""

    def __init__(self, gpu):
        self.gpu = gpu

    def __call__(self, device):
        return backend_mod.Backend("opencl", "fake device", is_gpu=self.gpu)


@pytest.mark.parametrize("gpu", [False, True])
def test_auto_means_the_first_of_a_capabilitys_order_that_works_here(fresh_registry,
                                                                     monkeypatch, gpu):
    pytest.importorskip("numba")
    monkeypatch.setitem(fresh_registry._FACTORIES, "opencl", _FakeOpenCL(gpu))
    monkeypatch.delenv("SKELASM_DEVICE", raising=False)
    # the descriptor takes OpenCL on any device; the per-pose sum only on a GPU
    assert fresh_registry.resolve("descriptor").name == "opencl"
    assert fresh_registry.resolve("per_pose").name == ("opencl" if gpu else "numba")
    # a kernel that does not build there is passed over, to the next of the order
    assert fresh_registry.resolve("descriptor", usable=lambda b: b.name != "opencl").name == (
        "numba")
    assert fresh_registry.resolve("fft").name == "numpy"


def test_a_missing_backend_passes_to_the_reference_under_auto_and_fails_when_named(
        fresh_registry, monkeypatch):
    original = ImportError("No module named 'numba' (simulated)")

    def broken(device):
        raise original

    monkeypatch.setitem(fresh_registry._FACTORIES, "numba", broken)
    monkeypatch.setitem(fresh_registry._FACTORIES, "opencl", broken)
    # a device asked for by name makes "auto" refuse to pass over OpenCL (next test file)
    monkeypatch.delenv("SKELASM_DEVICE", raising=False)
    assert fresh_registry.resolve("per_pose").name == "numpy"
    with pytest.raises(fresh_registry.BackendError) as info:
        fresh_registry.resolve("per_pose", "numba")  # named: no silent fallback
    assert info.value.__cause__ is original
    with pytest.raises(fresh_registry.BackendError):
        fresh_registry.resolve("descriptor")  # its reference, numba, is what is missing


def test_the_environment_default_is_the_capabilitys_reference_where_it_lacks_it(
        fresh_registry, monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setenv("SKELASM_BACKEND", "numpy")
    assert fresh_registry.resolve("per_pose").name == "numpy"
    assert fresh_registry.resolve("descriptor").name == "numba"  # no numpy descriptor
    given = fresh_registry.get_backend("numba")
    assert fresh_registry.resolve("descriptor", given) is given
    with pytest.raises(ValueError, match="descriptor"):
        fresh_registry.resolve("descriptor", fresh_registry.get_backend("numpy"))


def _options(parser, path=()):
    """(command path, action) for every option of ``parser`` and of its subcommands."""
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, (*path, name))
        else:
            yield path, action


def test_commands_and_benchmarks_offer_the_registrys_choices():
    from app.cli import build_parser

    offered = {}
    for path, action in _options(build_parser()):
        if action.dest in ("backend", "backends"):
            offered[" ".join(path)] = action.choices
    # the benchmarks are subcommands of `skelasm bench`: they are looked at too
    assert {"evaluate", "precompute", "bench loop", "bench correlation"} <= set(offered), offered
    assert {"search", "bench search"} <= set(offered), offered
    registry = [set(backend_mod.choices(c)) for c in ("per_pose", "descriptor", "scan")]
    for name, names in offered.items():
        assert names is not None, f"{name}: a backend option without the registry's choices"
        assert set(names) in registry + [c - {"auto"} for c in registry], (name, names)


def _sources_beside_the_registry():
    """Every module of engine/, app/ and bench/ but engine/backend.py, parsed.

    Yields (path relative to the project, module tree).
    """
    import ast
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    for folder in ("engine", "app", "bench"):
        for source in (root / folder).rglob("*.py"):
            if source != root / "engine" / "backend.py":
                yield source.relative_to(root), ast.parse(source.read_text(encoding="utf-8"))


def test_no_module_declares_its_own_list_of_backends():
    """Tuples or lists naming numba and opencl together live in engine/backend.py only."""
    import ast

    found = []
    for path, tree in _sources_beside_the_registry():
        for node in ast.walk(tree):
            if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
                names = {e.value for e in node.elts if isinstance(e, ast.Constant)}
                if {"numba", "opencl"} <= names:
                    found.append(f"{path}:{node.lineno}")
    assert not found, f"backend lists outside the registry: {found}"


def test_no_module_keeps_a_second_name_for_the_registrys_backends():
    """Callers ask engine.backend (choices, CAPABILITIES); no other module re-exports them."""
    import ast

    found = []
    for path, tree in _sources_beside_the_registry():
        for node in tree.body:
            targets = node.targets if isinstance(node, ast.Assign) else []
            for target in targets:
                if isinstance(target, ast.Name) and "BACKEND" in target.id:
                    found.append(f"{path}:{node.lineno} {target.id}")
    assert not found, f"backend vocabularies outside the registry: {found}"


def test_a_descriptor_failure_is_not_computed_again_on_another_backend(monkeypatch):
    """One fallback rule: the registry's "auto". A failure while computing propagates."""
    import engine.descriptor.store as store
    import engine.runtime as rt
    from engine.sim.build import SceneModel

    model = SceneModel(rt.open_scene("assets/peg_in_hole/scene.toml"))
    calls = []

    def failing(scene, **kw):
        calls.append(kw.get("backend"))
        raise RuntimeError("the kernel failed (simulated)")

    monkeypatch.setattr(store, "descriptors_for_scene", failing)
    with pytest.raises(RuntimeError, match="simulated"):
        model.descriptors(model.config.effects)
    assert calls == [None]  # asked once, for the registry's choice, and not again
