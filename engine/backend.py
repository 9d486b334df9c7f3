"""Compute backends: one registry and one vocabulary for every kernel of the engine.

The names, validated in one place (:func:`check_name`):

- ``"numpy"``: the pure-numpy reference; always present.
- ``"numba"``: code compiled in process for the CPU (numba).
- ``"opencl"``: a pyopencl context and queue on one device: a GPU if there is one, else a
  CPU device (PoCL); ``SKELASM_DEVICE`` (or ``device=``) picks it by a substring of its
  name or by ``platform:device`` indices, as ``PYOPENCL_CTX`` does.
- ``"auto"``: chosen per capability, by :func:`resolve` only. This is the one fallback
  rule.

Each *capability* (the descriptor's kernels, the per-pose sum, the transforms) is
implemented for some of these backends; :data:`CAPABILITIES` registers them, and
:func:`resolve` is the one place a capability's choice is made, with the same meaning of
"auto" for all: the first backend of the capability's order that works here (a backend it
marks ``gpu_only`` counts only on a GPU device; a capability may also test that its kernel
builds on the backend); :func:`describe_auto` says so in words for help texts and status
lines. :func:`get_backend` makes a backend by its name and knows no "auto". Commands and
benchmarks offer :func:`choices`. A backend asked for by name is used or fails with its
cause; nothing falls back silently from a named choice.

``SKELASM_BACKEND`` overrides the default name. Each backend is created once per process
(per device) and shared. A backend that cannot be created is registered with the error
that stopped it, and fails only when asked for by name, raising :class:`BackendError`
whose cause (``__cause__``) is that original error; "auto" simply passes over it. scipy's
``scipy.fft`` backend registry and trimesh's engine wrappers work the same way.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from engine.errors import InputError

#: The backend names, reference first.
BACKENDS = ("numpy", "numba", "opencl")
#: What a user may ask for ("auto": :func:`resolve` chooses per capability).
CHOICES = BACKENDS + ("auto",)


class BackendError(RuntimeError):
    """A requested compute backend cannot be used here (the cause says why)."""


@dataclass(frozen=True)
class Capability:
    """One kind of work and the backends it is implemented for.

    Attributes
    ----------
    name : str
        ``"descriptor"``, ``"per_pose"`` or ``"fft"``.
    backends : tuple of str
        The backends it has, in the order "auto" tries them; the last is its reference,
        which always works.
    gpu_only : frozenset of str
        Backends "auto" takes only on a GPU device (a per-pose OpenCL launch costs more on
        a CPU device than numba's whole sum).
    """

    name: str
    backends: tuple[str, ...]
    gpu_only: frozenset[str] = frozenset()

    @property
    def reference(self) -> str:
        """The backend that always works (the last of the order)."""
        return self.backends[-1]


#: The capabilities and the backends each is implemented for, in "auto"'s order.
CAPABILITIES: dict[str, Capability] = {
    # the descriptor has no pure-numpy implementation: numba is its reference
    "descriptor": Capability("descriptor", ("opencl", "numba")),
    "per_pose": Capability("per_pose", ("opencl", "numba", "numpy"),
                           gpu_only=frozenset({"opencl"})),
    # the transforms run through scipy.fft on the CPU (the numpy stack)
    "fft": Capability("fft", ("numpy",)),
    # the search's scan, a block of rotations' landscapes reduced to their minima
    # (engine.search.opencl_scan); on PoCL the OpenCL scan takes every core, where the
    # numpy one takes one per block (a Dask worker's thread), so "auto" takes it on a GPU
    "scan": Capability("scan", ("opencl", "numpy"), gpu_only=frozenset({"opencl"})),
}


@dataclass(frozen=True)
class Backend:
    """A compute backend.

    Attributes
    ----------
    name : {"numpy", "numba", "opencl"}
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
        """The pyopencl device, or None."""
        return None if self.context is None else self.context.devices[0]

    def describe(self) -> str:
        """One line naming the backend and device, for logs and status bars."""
        kind = "GPU" if self.is_gpu else "CPU"
        return f"{self.name} on {self.device_name} ({kind})"


def check_name(name: str) -> str:
    """``name`` in lower case, if it is one of :data:`CHOICES`; else a ValueError listing them."""
    lowered = str(name).lower()
    if lowered not in CHOICES:
        raise ValueError(f"unknown backend {name!r}; valid: {', '.join(CHOICES)}")
    return lowered


def _capability(capability: str) -> Capability:
    try:
        return CAPABILITIES[capability]
    except KeyError:
        raise ValueError(f"unknown capability {capability!r}; valid: "
                         f"{', '.join(CAPABILITIES)}") from None


def choices(capability: str) -> tuple[str, ...]:
    """What a user may ask ``capability`` to run on: its backends, reference first, and "auto"."""
    return tuple(reversed(_capability(capability).backends)) + ("auto",)


def describe_auto(capability: str) -> str:
    """What "auto" means for ``capability``, in words (help texts, status lines).

    For example ``"opencl (on a GPU), else numba, else numpy"``: the capability's order,
    read from :data:`CAPABILITIES`.
    """
    cap = _capability(capability)
    return ", else ".join(f"{name} (on a GPU)" if name in cap.gpu_only else name
                          for name in cap.backends)


def check_choice(capability: str, name: str) -> str:
    """``name`` in lower case, if ``capability`` offers it; else a ValueError listing them."""
    valid = choices(capability)
    lowered = str(name).lower()
    if lowered not in valid:
        what = _capability(capability).name.replace("_", "-")
        raise ValueError(f"the {what} computation has no backend {name!r}; "
                         f"valid: {', '.join(valid)}")
    return lowered


def resolve(
    capability: str,
    name: str | Backend | None = None,
    device: str | None = None,
    *,
    usable: Callable[[Backend], bool] | None = None,
) -> Backend:
    """The backend ``capability`` runs on: the one place its choice is made.

    Parameters
    ----------
    capability : {"descriptor", "per_pose", "fft", "scan"}
    name : str, Backend or None
        A name of :func:`choices`, "auto", or a created backend. None: ``SKELASM_BACKEND``
        (its reference where the capability has no such backend), else "auto".
    device : str, optional
        OpenCL device selector (``SKELASM_DEVICE`` by default).
    usable : callable, optional
        For "auto": whether the capability's kernel builds on a candidate (a backend that
        works in general may not compile a particular kernel).

    Raises
    ------
    ValueError
        A name or backend the capability has no implementation for.
    BackendError
        A backend asked for by name cannot be used here (its cause says why).
    """
    cap = _capability(capability)
    if isinstance(name, Backend):
        check_choice(capability, name.name)
        return name
    if name is None:
        # the environment's default; one the capability has no implementation for (numpy
        # for the descriptor) means its reference
        env = os.environ.get("SKELASM_BACKEND", "").strip().lower() or "auto"
        name = env if env in cap.backends or env == "auto" else cap.reference
    name = check_choice(capability, name)
    if name != "auto":
        return get_backend(name, device)
    for candidate in cap.backends[:-1]:
        try:
            made = get_backend(candidate, device)
        except BackendError as exc:
            _refuse_asked_device(candidate, device, exc)
            continue
        if candidate in cap.gpu_only and not made.is_gpu:
            continue
        if usable is not None and not usable(made):
            continue
        return made
    return get_backend(cap.reference, None)


_lock = threading.RLock()
_made: dict[tuple[str, str | None], Backend | BaseException] = {}


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


def _make_numpy(device: str | None) -> Backend:
    return Backend("numpy", "numpy (CPU)")


def _make_numba(device: str | None) -> Backend:
    try:
        import numba
    except ImportError as exc:
        raise BackendError(f"numba cannot be imported ({exc}): install it with "
                           "`pip install numba`, or use --backend numpy") from exc
    return Backend("numba", f"numba (CPU, {numba.get_num_threads()} threads)")


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


_FACTORIES: dict[str, Callable[[str | None], Backend]] = {
    "numpy": _make_numpy,
    "numba": _make_numba,
    "opencl": _make_opencl,
}


def _create(name: str, device: str | None) -> Backend:
    """The backend ``name`` (created once); raises :class:`BackendError` from its cause."""
    key = (name, device if name == "opencl" else None)
    with _lock:
        if key not in _made:
            try:
                _made[key] = _FACTORIES[name](key[1])
            except Exception as exc:  # noqa: BLE001 - registered, raised when asked for
                _made[key] = exc
        made = _made[key]
    if isinstance(made, BaseException):
        if isinstance(made, BackendError):
            raise BackendError(str(made)) from (made.__cause__ or made)
        raise BackendError(f"the {name} backend cannot be used here: {made}") from made
    return made


def get_backend(name: str, device: str | None = None) -> Backend:
    """The compute backend ``name``, created once per (name, device) and shared.

    Parameters
    ----------
    name : {"numpy", "numba", "opencl"}
        A backend's name. "auto" is not one: it is chosen per capability by
        :func:`resolve`, the one place a choice is made.
    device : str, optional
        OpenCL device selector (see the module docstring); defaults to ``SKELASM_DEVICE``.

    Raises
    ------
    ValueError
        Unknown backend name, or "auto".
    BackendError
        The backend cannot be used here; its ``__cause__`` is the original error.
    """
    name = check_name(name)
    if name == "auto":
        raise ValueError("'auto' is chosen per capability: use engine.backend.resolve("
                         f"capability) with one of {', '.join(CAPABILITIES)}")
    return _create(name, device or os.environ.get("SKELASM_DEVICE") or None)


def _refuse_asked_device(candidate: str, device: str | None, exc: BackendError) -> None:
    """An InputError when "auto" would pass over an OpenCL device a user asked for.

    Passing over it silently would hide a typo in the device's name.
    """
    device = device or os.environ.get("SKELASM_DEVICE") or None
    if candidate == "opencl" and device is not None:
        asked = "SKELASM_DEVICE" if device == os.environ.get("SKELASM_DEVICE") else "device"
        raise InputError(
            f"{asked} = {device!r} picks no usable OpenCL device "
            f"({str(exc).splitlines()[0]}); give part of a device's name or "
            "PLATFORM:DEVICE indices, or unset it to let the engine choose") from exc


def check_environment() -> None:
    """Check the ``SKELASM_*`` variables that pick backends, once, at start-up.

    Each is otherwise read deep inside an "auto" choice that passes over a backend that
    fails, so a typo would be ignored without a word. ``SKELASM_DEVICE`` is checked only
    when set (it starts OpenCL to find the device).

    Raises
    ------
    InputError
        Naming the variable, its value and the fix.
    """
    name = os.environ.get("SKELASM_BACKEND", "").strip()
    if name:
        try:
            check_name(name)
        except ValueError as exc:
            raise InputError(f"SKELASM_BACKEND = {name!r}: {exc}; or unset it") from None
    env_count("SKELASM_CORRELATION_THREADS", 1)
    device = os.environ.get("SKELASM_DEVICE", "").strip()
    if device:
        try:
            _create("opencl", device)
        except BackendError as exc:
            raise InputError(
                f"SKELASM_DEVICE = {device!r} picks no usable OpenCL device "
                f"({str(exc).splitlines()[0]}); give part of a device's name or "
                "PLATFORM:DEVICE indices, or unset it to let the engine choose") from exc


def env_count(name: str, default: int) -> int:
    """A positive whole number from the environment variable ``name`` (``default`` if unset).

    Raises
    ------
    InputError
        The variable is set to anything but a positive whole number.
    """
    text = os.environ.get(name, "").strip()
    if not text:
        return default
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise InputError(f"{name} = {text!r} is not a positive whole number: set it to 1 or "
                         "more, or unset it for the default")
    return value


def cpu_cores() -> int:
    """CPU cores this process may run on (its affinity where the OS tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not Linux
        return max(1, os.cpu_count() or 1)


_budget = threading.local()


def thread_budget() -> int:
    """Threads one numeric call made in the calling thread may use (transforms).

    Every core, unless the thread is inside :func:`spare_cores`.
    """
    return int(getattr(_budget, "threads", 0)) or cpu_cores()


@contextlib.contextmanager
def spare_cores(count: int = 1) -> Iterator[int]:
    """Within, the calling thread's numeric calls leave ``count`` cores free (at least one thread).

    The runtime's job worker builds fields and landscapes this way beside a loop that must
    step every millisecond: on two cores, a transform on both of them kept the loop thread
    waiting for a CPU (docs/runtime.md, "K changes"). Other threads are not affected.
    Yields the threads left.
    """
    before = getattr(_budget, "threads", 0)
    _budget.threads = max(1, cpu_cores() - int(count))
    try:
        yield _budget.threads
    finally:
        _budget.threads = before


def backend_problem(name: str, device: str | None = None) -> str | None:
    """None when the backend ``name`` works here, else the first line of why not."""
    try:
        _create(check_name(name), device)
    except BackendError as exc:
        return str(exc).splitlines()[0]
    return None


def available_backends() -> list[str]:
    """Names of the backends that work here (OpenCL: a device compiles a kernel), numpy first."""
    return [name for name in BACKENDS if backend_problem(name) is None]
