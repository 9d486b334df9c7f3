"""Compute backends: an OpenCL context (GPU if present, else PoCL on the CPU) or numpy.

The backend is picked once per process and can be forced with ``SKELASM_BACKEND``
(``numpy`` or ``opencl``) and ``SKELASM_DEVICE`` (a substring of the device name, or
``platform:device`` indices as in ``PYOPENCL_CTX``), or by the command-line options
``--backend`` and ``--device``. A backend that is missing fails only when asked for.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import Any

BACKENDS = ("numpy", "opencl")


class BackendError(RuntimeError):
    """A requested compute backend cannot be used here."""


@dataclass(frozen=True)
class Backend:
    """A compute backend.

    Attributes
    ----------
    name : str
        ``"numpy"`` or ``"opencl"``.
    device_name : str
        Human-readable device, e.g. ``"pthread-AMD EPYC (Portable Computing Language)"``.
    is_gpu : bool
        Whether the device is a GPU.
    context, queue : pyopencl objects or None
        Set for OpenCL only.
    """

    name: str
    device_name: str
    is_gpu: bool = False
    context: Any = field(default=None, repr=False, compare=False)
    queue: Any = field(default=None, repr=False, compare=False)

    @property
    def device(self) -> Any:
        """The pyopencl device, or None for numpy."""
        return None if self.context is None else self.context.devices[0]

    def describe(self) -> str:
        """One line naming the backend and device, for logs and status bars."""
        kind = "GPU" if self.is_gpu else "CPU"
        return f"{self.name} on {self.device_name} ({kind})"


_lock = threading.Lock()
_cache: dict[tuple[str, str | None], Backend] = {}


def _opencl_devices() -> list[Any]:
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - depends on the install
        raise BackendError(
            "pyopencl is not installed: install it with `pip install pyopencl "
            "pocl-binary-distribution`, or use --backend numpy"
        ) from exc
    devices = []
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        raise BackendError(
            f"no OpenCL platform found ({exc}): install a GPU driver's OpenCL ICD or "
            "`pip install pocl-binary-distribution` for the CPU, or use --backend numpy"
        ) from exc
    for platform in platforms:
        try:
            devices.extend(platform.get_devices())
        except cl.Error:
            continue
    if not devices:
        raise BackendError(
            "OpenCL platforms are installed but offer no device: "
            "`pip install pocl-binary-distribution` for the CPU, or use --backend numpy"
        )
    return devices


def _pick_device(devices: list[Any], wanted: str | None) -> Any:
    import pyopencl as cl

    if wanted:
        if ":" in wanted and all(part.isdigit() for part in wanted.split(":")):
            p, d = (int(x) for x in wanted.split(":"))
            try:
                return cl.get_platforms()[p].get_devices()[d]
            except (IndexError, cl.Error) as exc:
                raise BackendError(f"no OpenCL device {wanted!r}; have: {_names(devices)}") from exc
        for dev in devices:
            if wanted.lower() in f"{dev.name} {dev.platform.name}".lower():
                return dev
        raise BackendError(f"no OpenCL device matches {wanted!r}; have: {_names(devices)}")
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    others = [d for d in devices if not d.type & cl.device_type.GPU]
    problems = []
    for dev in gpus + others:
        problem = _compile_problem(dev)
        if problem is None:
            return dev
        problems.append(f"{dev.name} ({dev.platform.name}): {problem}")
    raise BackendError(
        "no OpenCL device can compile kernels here: " + "; ".join(problems)
        + ". On Debian, `apt-get install pocl-opencl-icd` gives a working CPU device; "
        "or use --backend numpy"
    )


def _compile_problem(dev: Any) -> str | None:
    """None when ``dev`` builds a trivial kernel, else the first line of the build error.

    Some installs list a device that cannot compile anything (seen here: the PoCL 3.0 wheel's
    LLVM 14 does not know this CPU, "unknown target CPU 'generic'"), so the automatic choice
    skips devices that fail this probe.
    """
    import pyopencl as cl

    try:
        ctx = cl.Context([dev])
        cl.Program(ctx, "__kernel void probe(__global float *x) { x[0] = 1.0f; }").build()
    except Exception as exc:  # pyopencl raises several types (RuntimeError, cl.Error, ...)
        lines = [ln for ln in str(exc).splitlines() if ln.strip()]
        return lines[0][:200] if lines else type(exc).__name__
    return None


def _names(devices: list[Any]) -> str:
    return ", ".join(f"{d.name} ({d.platform.name})" for d in devices)


def get_backend(name: str | None = None, *, device: str | None = None) -> Backend:
    """The compute backend, created once per (name, device) and shared.

    Parameters
    ----------
    name : {"opencl", "numpy"}, optional
        Defaults to ``SKELASM_BACKEND``, else OpenCL when a device is present, else numpy.
    device : str, optional
        Device selector (see module docstring); defaults to ``SKELASM_DEVICE``.

    Raises
    ------
    ValueError
        Unknown backend name.
    BackendError
        OpenCL was asked for explicitly and cannot be used.
    """
    explicit = name is not None or "SKELASM_BACKEND" in os.environ
    name = (name or os.environ.get("SKELASM_BACKEND") or "auto").lower()
    device = device or os.environ.get("SKELASM_DEVICE") or None
    if name not in BACKENDS + ("auto",):
        raise ValueError(f"unknown backend {name!r}; valid: {', '.join(BACKENDS + ('auto',))}")
    with _lock:
        key = (name, device)
        if key in _cache:
            return _cache[key]
        if name == "numpy":
            backend = Backend("numpy", "numpy (CPU)")
        else:
            try:
                backend = _make_opencl(device)
            except BackendError:
                if explicit and name == "opencl":
                    raise
                backend = Backend("numpy", "numpy (CPU; no usable OpenCL device)")
        _cache[key] = backend
        return backend


def _make_opencl(device: str | None) -> Backend:
    import pyopencl as cl

    dev = _pick_device(_opencl_devices(), device)
    try:
        ctx = cl.Context([dev])
        queue = cl.CommandQueue(ctx)
    except cl.Error as exc:
        raise BackendError(f"could not open OpenCL device {dev.name}: {exc}") from exc
    return Backend(
        "opencl",
        f"{dev.name.strip()} ({dev.platform.name.strip()})",
        is_gpu=bool(dev.type & cl.device_type.GPU),
        context=ctx,
        queue=queue,
    )


def available_backends() -> list[str]:
    """Names of the backends that work here (OpenCL: a device compiles a kernel), numpy first."""
    names = ["numpy"]
    try:
        _pick_device(_opencl_devices(), None)
        names.append("opencl")
    except BackendError:
        pass
    return names
