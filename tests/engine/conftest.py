"""Fixtures shared by the engine tests: compute backends that work here."""

from __future__ import annotations

import functools

import pytest

from engine.backend import available_backends, get_backend


@functools.lru_cache(maxsize=1)
def _opencl_problem() -> str | None:
    """None when the descriptor kernel compiles on the OpenCL backend, else why not."""
    if "opencl" not in available_backends():
        return "no OpenCL device"
    from engine.backend import BackendError
    from engine.descriptor.opencl_kernels import build_program

    try:
        build_program(get_backend("opencl").context)
    except BackendError as exc:
        return str(exc)
    return None


@pytest.fixture(params=["numba", "opencl"])
def descriptor_backend(request):
    """Each compute backend usable for the descriptor (OpenCL skipped when absent/broken)."""
    from engine.descriptor import resolve_backend

    if request.param == "opencl":
        problem = _opencl_problem()
        if problem:
            pytest.skip(problem)
    return resolve_backend(request.param)


@pytest.fixture
def opencl_backend():
    """The OpenCL backend, or skip."""
    problem = _opencl_problem()
    if problem:
        pytest.skip(problem)
    return get_backend("opencl")


@pytest.fixture(scope="session")
def small_peg_scene(tmp_path_factory):
    """The bundled peg in hole with a 16-sample grid and K = 8 (descriptors in about a second)."""
    from pathlib import Path

    src = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole"
    lines = []
    for line in (src / "scene.toml").read_text().splitlines():
        key = line.split("=")[0].strip()
        if key == "grid":
            line = "grid = 16"
        elif key == "modes":
            line = "modes = 8"
        elif key == "file":
            line = f'file = "{(src / line.split(chr(34))[1]).as_posix()}"'
        lines.append(line)
    path = tmp_path_factory.mktemp("small_peg") / "scene.toml"
    path.write_text("\n".join(lines) + "\n")
    return path
