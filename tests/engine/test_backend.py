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
    assert backend_mod.get_backend().name == "numpy"


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
    # nothing fails until numba is asked for: auto passes over it
    assert fresh_registry.get_backend("auto", order=("numba", "numpy")).name == "numpy"
    assert "numba" not in fresh_registry.available_backends()
    with pytest.raises(fresh_registry.BackendError, match="simulated") as info:
        fresh_registry.get_backend("numba")
    assert info.value.__cause__ is original
    # and again, with the same cause (the failure is registered, not retried)
    with pytest.raises(fresh_registry.BackendError) as again:
        fresh_registry.get_backend("numba")
    assert again.value.__cause__ is original


def test_auto_takes_the_first_backend_of_the_order_that_works(fresh_registry):
    pytest.importorskip("numba")
    assert fresh_registry.get_backend("auto", order=("numba", "numpy")).name == "numba"
    assert fresh_registry.get_backend("auto", order=("numpy", "numba")).name == "numpy"
    first = fresh_registry.available_backends()
    expected = next(n for n in fresh_registry.AUTO_ORDER if n in first)
    assert fresh_registry.get_backend().name == expected


def test_names_are_checked_in_one_place():
    assert backend_mod.check_name("NumBa") == "numba"
    with pytest.raises(ValueError, match="valid: numpy, numba, opencl, auto"):
        backend_mod.check_name("cuda")
