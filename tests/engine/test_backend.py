import pytest

from engine import backend as backend_mod


def test_numpy_backend_always_available():
    b = backend_mod.get_backend("numpy")
    assert b.name == "numpy"
    assert b.context is None
    assert "numpy" in backend_mod.available_backends()


def test_unknown_backend_names_the_valid_ones():
    with pytest.raises(ValueError, match="numpy, opencl"):
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
