"""Compile every kernel the engine's first start needs, once, so that later starts are quick.

The engine's numeric kernels are compiled on first use (numba functions, cached on disk
beside their modules; the OpenCL programs, cached by the driver). On a fresh install that
first use is the window's first start: the kernels of the first coarse field alone took 26 s
to compile on a 2-core machine before the part could be dragged (the tree over the mesh, the
descriptor, the per-pose correlation), and the scene's own field, its fine level and the
slice preview more. :func:`warm_kernels` runs the start's path on a scene at a coarse grid
and small K (the compiled code does not depend on the sizes), in a cache of its own so that
it leaves no descriptors behind; ``skelasm warm`` calls it, and the README's install
command runs that.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np

T = TypeVar("T")

#: Where the engine's cache lives (engine.cache); the warm-up points it at a folder of its own.
CACHE_ENV = "SKELASM_CACHE"
#: The coarsest grid and K that still take every branch of the start's path.
WARM_GRID = 16
WARM_MODES = 9


def warm_kernels(scene: str | os.PathLike,
                 progress: Callable[[str], None] | None = None) -> list[tuple[str, float]]:
    """Run the engine's start path on ``scene`` so that its kernels are compiled and cached.

    Returns (stage, seconds) per stage. The descriptors are computed into a temporary cache,
    removed after; the compiled kernels stay where their compilers keep them.
    """
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    stages: list[tuple[str, float]] = []
    before = os.environ.get(CACHE_ENV)
    with tempfile.TemporaryDirectory(prefix="skelasm-warm-") as tmp:
        os.environ[CACHE_ENV] = tmp
        # the numba descriptor kernel (the slice preview's, and the descriptors' without
        # OpenCL) compiles in a second process meanwhile: a compiler holds its process's GIL
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            beside = pool.submit(_warm_slice, str(scene))
            try:
                _warm(Path(scene), stages, progress)
            finally:
                if before is None:
                    os.environ.pop(CACHE_ENV, None)
                else:
                    os.environ[CACHE_ENV] = before
            stages.append(("the slice preview, beside", beside.result()))
    return stages


def _warm_slice(scene: str) -> float:
    """Compile the numba descriptor kernel (in a process of its own); returns its seconds."""
    from dataclasses import replace

    from engine.descriptor import descriptor_slice, grid_for_part
    from engine.runtime.scene_handle import open_scene

    t0 = time.perf_counter()
    handle = open_scene(scene)
    d = handle.scene.descriptor
    part = handle.parts[0]
    g = grid_for_part(part, samples=WARM_GRID, padding=d.padding)
    descriptor_slice(part.vertices, part.faces, g, 2, g.shape[2] // 2, replace(d, sigma=0.7),
                     backend="numba")
    return time.perf_counter() - t0


def _warm(scene: Path, stages: list[tuple[str, float]],
          progress: Callable[[str], None] | None) -> None:
    from dataclasses import replace

    import engine.runtime as rt
    from engine.runtime.api import start_engine
    from engine.runtime.scene_handle import open_scene

    def stage(name: str, fn: Callable[[], T]) -> T:
        if progress is not None:
            progress(name)
        t0 = time.perf_counter()
        out = fn()
        stages.append((name, time.perf_counter() - t0))
        return out

    handle = stage("loading the parts", lambda: open_scene(scene))
    d = handle.scene.descriptor
    coarse = replace(d, grid=WARM_GRID, spacing=None)
    small = replace(handle, scene=replace(handle.scene, descriptor=coarse))
    # the engine as the window starts it, in a thread: the loop, its job worker, its arrays
    # as they come (read-only ones compile specialisations of their own)
    engine = start_engine(small, modes=WARM_MODES, process=False)
    seen: set[type] = set()
    try:
        sim = engine.transport.sim  # type: ignore[attr-defined]

        def until(what: str, done: Callable[[], bool], limit: float = 600.0) -> None:
            end = time.monotonic() + limit
            while not done():
                for e in engine.poll_events():
                    if isinstance(e, rt.ErrorEvent):
                        raise RuntimeError(f"the engine failed before {what}: {e.message}")
                    seen.add(type(e))
                engine.poll_frames()
                if time.monotonic() > end or not engine.running:
                    raise RuntimeError(f"the engine did not reach {what} in {limit:.0f} s")
                time.sleep(0.01)

        stage("descriptors, correlation tables and the per-pose evaluator",
              lambda: until("its first field", lambda: rt.ReadyEvent in seen))
        stage("the fine level and its walls",
              lambda: until("the fine level", lambda: sim.near is not None))

        def steps() -> None:
            pose = np.array(small.start_pose, np.float64)
            for k in range(25):
                pose[0] += 0.01 * k
                engine.send(rt.SetProxyPose(tuple(float(v) for v in pose)))
                time.sleep(0.02)
                engine.poll_frames()

        stage("the loop's steps", steps)
    finally:
        engine.stop()
