"""Choosing the per-pose path: the numpy reference, or a compiled kernel, measured.

Works on the per-pose backends the registry offers (``engine.backend.choices("per_pose")``:
"numpy", "numba", "opencl", "auto") and on kernels with the small interface the correlator
calls: ``pose(table, rot, t)`` returning ``[E, F (3), T (3)]``, ``supports(table)`` and
``describe()``. "numpy" has no kernel (the correlator runs
:mod:`engine.correlation.reference`). "auto" is the registry's one rule
(``engine.backend.resolve("per_pose")``): the first of OpenCL on a GPU, numba and numpy
whose kernel builds here and can sum the table; a kernel passed over is a note in the
description, not an error. (The order is what measuring them gave: on a CPU device an
OpenCL launch costs more than numba's whole sum, on a GPU OpenCL is the faster.) A kernel
asked for by name that cannot be built raises :class:`engine.backend.BackendError` with
the original error as its cause.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import numpy as np

from engine.backend import (
    CAPABILITIES,
    Backend,
    BackendError,
    backend_problem,
    check_choice,
    describe_auto,
    get_backend,
    resolve,
)
from engine.correlation.tables import ModeTable
from engine.pose import rotation_matrix

#: The compiled per-pose kernels (the registry's per-pose backends but the reference).
COMPILED = tuple(b for b in CAPABILITIES["per_pose"].backends if b != "numpy")


class Kernel(Protocol):
    """What the correlator asks of a compiled per-pose kernel."""

    name: str

    def pose(self, table: ModeTable, rot: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(7,) float64 ``[E, F (3), T (3)]``."""
        ...

    def supports(self, table: ModeTable) -> bool:
        """Whether the kernel can sum this table."""
        ...

    def describe(self) -> str:
        """Name and device, for status lines."""
        ...


def make_kernel(name: str, selection: str, rotation: bool) -> Kernel:
    """The compiled kernel ``name`` ("numba" or "opencl") for tables of this kind.

    The kernel modules import their compilers (numba, pyopencl) at the top, so they are
    imported only here, after the backend registry has vouched for the compiler.
    """
    backend = get_backend(check_choice("per_pose", name))  # BackendError when missing
    try:
        if name == "numba":
            from engine.correlation.numba_kernels import NumbaKernel

            return NumbaKernel(selection)
        if name == "opencl":
            from engine.correlation.opencl_kernels import OpenCLKernel

            return OpenCLKernel(selection, rotation, backend)
    except BackendError:
        raise
    except Exception as exc:  # noqa: BLE001 - a kernel that does not build on this device
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise BackendError(f"the {name} per-pose kernel cannot be built here: {first}") from exc
    raise ValueError(f"no compiled per-pose kernel is called {name!r}; valid: "
                     f"{', '.join(COMPILED)}")


_warming: dict[str, threading.Thread] = {}
_warming_lock = threading.Lock()


def warm_up(name: str, selection: str) -> None:
    """Start compiling the numba kernel on a worker thread, when ``name`` may use it.

    The first compilation takes seconds (numba then keeps it on disk); started before the
    spectra are computed, it overlaps with them. Does nothing when numba is absent, not
    asked for, or already compiling or compiled.
    """
    if check_choice("per_pose", name) not in ("numba", "auto") or backend_problem(
            "numba") is not None:
        return
    kind = "cube" if selection == "cube" else "list"
    with _warming_lock:
        if kind in _warming:
            return
        from engine.correlation.numba_kernels import compile_now

        thread = threading.Thread(target=compile_now, args=(kind,), daemon=True,
                                  name=f"skelasm-compile-{kind}")
        _warming[kind] = thread
        thread.start()


def choose(
    name: str, table: ModeTable, selection: str, rotation: bool,
    progress: Callable[[float], None] | None = None,
) -> tuple[dict[str, Kernel], str, str]:
    """The kernels built, the short name of the one to use, and a line saying why.

    ``name`` "numpy" builds nothing; "numba" or "opencl" builds that kernel (or raises);
    "auto" takes the registry's choice (:func:`engine.backend.resolve`), building the
    kernels it tries.
    """
    name = check_choice("per_pose", name)
    if name == "numpy":
        return {}, "numpy", "numpy (reference, asked for)"
    if name != "auto":
        kernel = make_kernel(name, selection, rotation)
        _tune_threads(kernel, table)
        return {name: kernel}, name, f"{kernel.describe()} (asked for)"
    kernels: dict[str, Kernel] = {}
    notes: list[str] = []

    def usable(backend: Backend) -> bool:
        try:
            kernels[backend.name] = make_kernel(backend.name, selection, rotation)
        except BackendError as exc:
            notes.append(f"{backend.name} unavailable: {str(exc).splitlines()[0]}")
            return False
        if not kernels[backend.name].supports(table):
            notes.append(f"{backend.name}: the table exceeds its kernel's limit")
            return False
        return True

    chosen = resolve("per_pose", "auto", usable=usable).name
    if progress is not None:
        progress(1.0)
    extra = "".join(f"; {n}" for n in notes)
    if chosen == "numpy":
        return kernels, "numpy", f"numpy (auto: no compiled backend{extra})"
    _tune_threads(kernels[chosen], table)
    return kernels, chosen, (f"{kernels[chosen].describe()} (auto: "
                             f"{describe_auto('per_pose')}{extra})")


def _tune_threads(kernel: Any, table: ModeTable) -> None:
    """Let a kernel with a parallel variant use it only where it is clearly faster.

    Clearly faster means below three quarters of the serial time, measured interleaved.
    """
    if not getattr(kernel, "can_parallel", False) or not kernel.supports(table):
        return
    serial, parallel = [], []
    for _ in range(6):
        kernel.parallel = False
        serial.append(median_microseconds(kernel, table, calls=2))
        kernel.parallel = True
        parallel.append(median_microseconds(kernel, table, calls=2))
    kernel.parallel = float(np.median(parallel)) < 0.75 * float(np.median(serial))


def median_microseconds(kernel: Any, table: ModeTable, calls: int = 30) -> float:
    """Median wall time of ``kernel.pose`` at a few generic poses (after one warm-up)."""
    rng = np.random.default_rng(0)
    g = table.geometry
    rot = rotation_matrix(rng.normal(size=3))
    kernel.pose(table, rot, g.centre_fixed - rot @ g.centre_moving)
    times = []
    for _ in range(calls):
        rot = rotation_matrix(rng.normal(size=3))
        t = g.centre_fixed - rot @ g.centre_moving + rng.normal(size=3)
        start = time.perf_counter()
        kernel.pose(table, rot, t)
        times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e6)
