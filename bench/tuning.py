"""`skelasm bench tuning`: how long a new sigma or penalty takes to reach the running engine.

For each scene (default: the four bundled pairs) the engine is started as the window starts
it (its loop in real time, the job worker beside it) in a fresh cache, left to finish its
first field and fine level, and then sent the window's commands in turn: a new sigma, a new
penalty at that sigma, and the scene's own values back. For each change it records, from
the command:

- ``coarse``: a coarse field at the new parameters is in use (a new sigma), the part moves
  on it;
- ``swapped``: the new descriptors on the scene's grid are in use;
- ``fine``: the fine level where the parts meet is back (the guidance is whole again).

Then it waits for the engine's sigma ladders (``engine.runtime.ladder_jobs``, computed in
the background since the first field; the row "live sigma prepared" gives the seconds its
nodes took to compute, from the cache entries, and the wait after the last change) and
sends the new sigma again, its direct descriptors (on the scene's grids and the fine
level's) removed from the cache first, so that it is served by the ladders as a sigma never
seen would be.

Prints a table and writes a bar plot (``-o``). The machine's load shows in every figure:
compare the rows of one run, not runs.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ASSETS = Path(__file__).resolve().parents[1] / "assets"
DEFAULT_SCENES = [str(ASSETS / n / "scene.toml")
                  for n in ("peg_in_hole", "boss_pins", "bracket_slot", "dovetail")]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench tuning`` to ``parser``."""
    parser.add_argument("scenes", nargs="*", default=DEFAULT_SCENES,
                        help="scene files (default: the four bundled pairs)")
    parser.add_argument("--sigma", type=float, default=0.7, help="the new sigma (0.7)")
    parser.add_argument("--penalty", type=float, default=5.0, help="the new penalty (5)")
    parser.add_argument("-o", "--output", default="tuning_bench.png", help="PNG plot")


def _wait(engine, sim, t0: float, *, limit: float = 900.0) -> dict[str, float]:
    """Seconds from ``t0`` to the coarse field, the scene's grid and the fine level."""
    import engine.runtime as rt

    seen: dict[str, float] = {}
    while time.perf_counter() - t0 < limit:
        for e in engine.poll_events():
            now = time.perf_counter() - t0
            if isinstance(e, rt.ErrorEvent):
                raise RuntimeError(e.message)
            grid = getattr(e, "coarse_grid", None)
            if isinstance(e, rt.ReadyEvent | rt.DescriptorsSwapped):
                seen["coarse" if grid is not None else "swapped"] = now
        engine.poll_frames()
        if "swapped" in seen and sim.near is not None:
            seen["fine"] = time.perf_counter() - t0
            return seen
        time.sleep(0.01)
    raise RuntimeError(f"no fine level within {limit:.0f} s")


def _wait_ladder(engine, t0: float, *, limit: float = 1800.0) -> float:
    """Seconds from ``t0`` until the engine says its sigma ladders are complete."""
    import engine.runtime as rt

    while time.perf_counter() - t0 < limit:
        for e in engine.poll_events():
            if isinstance(e, rt.ProgressEvent) and e.task == "ladder" and e.message:
                if e.message != "done":
                    raise RuntimeError(f"sigma ladder: {e.message}")
                return time.perf_counter() - t0
        engine.poll_frames()
        time.sleep(0.05)
    raise RuntimeError(f"no sigma ladder within {limit:.0f} s")


def _rungs(handle) -> list:
    """(part, grid) of every descriptor the engine ladders: the scene's grids, the level's."""
    from engine.descriptor.store import grid_for_part, scene_spacing
    from engine.sim.auto import measure_fit
    from engine.sim.fine import fine_rungs

    parts = list(handle.parts)
    spacing = scene_spacing(handle.scene, parts)
    rungs = [(p, grid_for_part(p, spacing=spacing, padding=handle.scene.descriptor.padding))
             for p in parts]
    if len(parts) > 1:
        pose = handle.scene.assembled_pose
        fit = measure_fit(parts[0], parts[1], pose, handle.scene.insertion_axis)
        rungs += fine_rungs(parts[0], parts[1], rungs[0][1], rungs[1][1], pose, fit)
    return rungs


def _ladder_seconds(handle) -> float:
    """Seconds the ladders' nodes took to compute (as their cache entries say)."""
    from engine import cache
    from engine.descriptor import ladder
    from engine.descriptor.store import CACHE_KIND, cache_key_parts

    d = handle.scene.descriptor
    total = 0.0
    for part, grid in _rungs(handle):
        for s in ladder.ladder_sigmas():
            key = cache.content_key(CACHE_KIND, cache_key_parts(
                part, grid, replace(d, sigma=float(s)), "adaptive"))
            arrays = cache.load(CACHE_KIND, key)
            total += float(arrays["compute_seconds"]) if arrays is not None else math.nan
    return total


def _forget(handle, sigma: float) -> None:
    """Remove the direct descriptors at ``sigma`` from the cache (the scene's grids, the level's).

    The ladders then serve them as they would a sigma never seen.
    """
    from engine import cache
    from engine.descriptor.store import CACHE_KIND, cache_key_parts

    d = replace(handle.scene.descriptor, sigma=sigma)
    for part, grid in _rungs(handle):
        key = cache.content_key(CACHE_KIND, cache_key_parts(part, grid, d, "adaptive"))
        cache.entry_path(CACHE_KIND, key).unlink(missing_ok=True)


def measure(scene: str, sigma: float, penalty: float) -> list[dict]:
    """One scene's rows: the first start, then each change."""
    import engine.runtime as rt
    from engine.runtime.api import start_engine
    from engine.runtime.scene_handle import open_scene

    handle = open_scene(scene)
    own = handle.scene.descriptor
    t0 = time.perf_counter()
    engine = start_engine(handle, process=False)  # a thread: the fine level can be seen
    try:
        sim = engine.transport.sim
        rows = [{"change": "first start", **_wait(engine, sim, t0)}]
        for label, params in ((f"sigma {sigma:g}", replace(own, sigma=sigma)),
                              (f"penalty {penalty:g}", replace(own, sigma=sigma,
                                                               penalty=penalty)),
                              ("back to the scene's", own)):
            time.sleep(1.0)
            t0 = time.perf_counter()
            engine.send(rt.SetDescriptorParams(params=params))
            rows.append({"change": label, **_wait(engine, sim, t0)})
        waited = _wait_ladder(engine, time.perf_counter())
        rows.append({"change": "live sigma prepared", "ladder": _ladder_seconds(handle),
                     "waited": waited})
        _forget(handle, sigma)
        time.sleep(1.0)
        t0 = time.perf_counter()
        engine.send(rt.SetDescriptorParams(params=replace(own, sigma=sigma)))
        rows.append({"change": f"sigma {sigma:g}, ladder ready", **_wait(engine, sim, t0)})
    finally:
        engine.stop()
    for row in rows:
        row["scene"] = handle.scene.name
    return rows


def run(args: argparse.Namespace) -> int:
    """Measure every scene in a fresh cache, print the table and write the plot."""
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="skelasm-tuning-") as tmp:
        os.environ["SKELASM_CACHE"] = tmp  # nothing cached: every first computation counts
        os.environ["SKELASM_LIVE_SIGMA"] = "1"  # the ladders, whatever the caller's setting
        for scene in args.scenes:
            rows += measure(scene, args.sigma, args.penalty)
    print(f"cpu cores: {os.cpu_count()}; load average {os.getloadavg()[0]:.1f} at the end")
    print("| scene | change | coarse field in use, s | scene's grid in use, s | fine level, s |")
    print("|---|---|---|---|---|")
    for r in rows:
        if "ladder" in r:
            continue
        cells = [f"{r[k]:.1f}" if k in r else "-" for k in ("coarse", "swapped", "fine")]
        print(f"| {r['scene']} | {r['change']} | {' | '.join(cells)} |")
    print("\n| scene | ladder nodes computed, s | waited after the last change, s |")
    print("|---|---|---|")
    for r in rows:
        if "ladder" in r:
            print(f"| {r['scene']} | {r['ladder']:.0f} | {r['waited']:.0f} |")
    _plot(rows, args.output)
    print(f"plot written to {args.output}")
    return 0


def _plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    changes = [r for r in rows if r["change"] != "first start" and "ladder" not in r]
    fig, ax = plt.subplots(figsize=(9, 4))
    labels = [f"{r['scene']}\n{r['change']}" for r in changes]
    x = range(len(changes))
    for i, (key, colour) in enumerate((("coarse", "#9ecae1"), ("swapped", "#3182bd"),
                                       ("fine", "#08519c"))):
        ax.bar([k + (i - 1) * 0.27 for k in x], [r.get(key, math.nan) for r in changes],
               width=0.27, color=colour, label={"coarse": "coarse field in use",
                                                 "swapped": "scene's grid in use",
                                                 "fine": "fine level back"}[key])
    ax.axhline(5.0, color="#c0392b", lw=1, ls="--", label="5 s")
    ax.set_xticks(list(x))
    ax.set_xticklabels(labels, fontsize=6, rotation=60, ha="right")
    ax.set_ylabel("seconds after the command")
    ax.set_yscale("log")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
