"""`skelasm bench loading`: seconds and peak memory to load meshes an exporter writes.

Data: binary STL files of a closed cylinder tessellated the way CAD exporters do it, with
``sections`` facets around the axis: two strips of side triangles and two caps, each cap
a fan of ``sections`` triangles around its centre (stored once per triangle: the centre
is ``sections`` copies of one vertex), plus 1 % doubled triangles. Such a file of ``m``
triangles is loaded by :func:`engine.loading.load_part` in a fresh process per size, after
a tetrahedron has loaded there (the imports are not counted); the table gives the load
time and the CPU time the process spent in it (on a shared machine the wall time grows
with the other work, the CPU time much less), the process's peak resident memory above
what it held before loading, and the welding's work (occupied cells and neighbour pairs
examined). A plot of time and memory against size is written.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Default mesh sizes (triangles).
SIZES = (10_000, 100_000, 1_000_000)
#: Share of triangles written twice (exporters double faces at seams).
DOUBLED = 0.01

_CHILD = """
import json, os, resource, sys, tempfile, time
import numpy as np
import engine.loading as loading
from bench.loading import write_stl
# warm up on a tetrahedron: the imports trimesh and scipy make inside load_part, not counted
tetra = np.array([[[0, 0, 0], [0, 1, 0], [1, 0, 0]], [[0, 0, 0], [1, 0, 0], [0, 0, 1]],
                  [[0, 0, 0], [0, 0, 1], [0, 1, 0]], [[1, 0, 0], [0, 1, 0], [0, 0, 1]]])
with tempfile.TemporaryDirectory() as folder:
    write_stl(os.path.join(folder, "tetra.stl"), tetra)
    loading.load_part(os.path.join(folder, "tetra.stl"))
usage = resource.getrusage(resource.RUSAGE_SELF)
before, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
start = time.perf_counter()
part = loading.load_part(sys.argv[1])
seconds = time.perf_counter() - start
usage = resource.getrusage(resource.RUSAGE_SELF)
peak, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime - cpu
print(json.dumps({"seconds": seconds, "cpu_seconds": cpu, "peak_mib": (peak - before) / 1024.0,
                  "triangles": part.triangles, "vertices": len(part.vertices),
                  "volume": part.volume, "warnings": len(part.warnings),
                  **{f"weld_{k}": v for k, v in loading.WELD_STATS.items()}}))
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench loading`` to ``parser``."""
    parser.add_argument("--triangles", type=int, nargs="+", default=list(SIZES),
                        help="mesh sizes in triangles (default 1e4 1e5 1e6)")
    parser.add_argument("-o", "--output", default="loading_bench.png", help="PNG plot")
    parser.add_argument("--timeout", type=float, default=600.0,
                        help="seconds one load may take before it is stopped (default 600)")


def fan_cylinder(triangles: int, *, radius: float = 10.0, height: float = 20.0
                 ) -> np.ndarray:  # fmt: skip
    """(m, 3, 3) float32 triangle soup of a closed cylinder with fan caps and doubled faces.

    ``sections = triangles / (4 * (1 + DOUBLED))`` facets around the axis: each makes two
    side triangles and one triangle of each cap's fan; then ``DOUBLED`` of them again.
    """
    sections = max(3, int(round(triangles / (4 * (1 + DOUBLED)))))
    angle = 2 * np.pi * np.arange(sections + 1) / sections
    ring = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)  # (s+1, 2)
    ring[-1] = ring[0]
    a, b = ring[:-1], ring[1:]
    z0, z1 = np.zeros(sections), np.full(sections, height)

    def point(xy: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.column_stack([xy, z])  # (s, 3)

    centre0 = np.zeros((sections, 3))
    centre1 = np.tile([0.0, 0.0, height], (sections, 1))
    side1 = np.stack([point(a, z0), point(b, z0), point(b, z1)], axis=1)
    side2 = np.stack([point(a, z0), point(b, z1), point(a, z1)], axis=1)
    cap0 = np.stack([centre0, point(b, z0), point(a, z0)], axis=1)
    cap1 = np.stack([centre1, point(a, z1), point(b, z1)], axis=1)
    soup = np.concatenate([side1, side2, cap0, cap1])  # (4 s, 3, 3)
    doubled = np.random.default_rng(0).choice(len(soup), int(DOUBLED * len(soup)),
                                              replace=False)
    return np.concatenate([soup, soup[doubled]]).astype(np.float32)


def write_stl(path: str | os.PathLike, soup: np.ndarray) -> None:
    """Write a (m, 3, 3) triangle soup as binary STL (normals left zero)."""
    record = np.zeros(len(soup), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)),
                                        ("attribute", "<u2")])
    record["corners"] = soup
    with open(path, "wb") as fh:
        fh.write(b"skelasm bench loading".ljust(80, b" "))
        fh.write(np.uint32(len(soup)).tobytes())
        fh.write(record.tobytes())


def measure(path: str | os.PathLike, *, timeout: float) -> dict:
    """Load ``path`` in a fresh process; its seconds, peak memory and weld counts."""
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")}
    try:
        done = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True,
                              text=True, timeout=timeout, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"stopped after {timeout:g} s"}
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["?"])[-1]
        return {"error": f"exit {done.returncode}: {tail}"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def run(args: argparse.Namespace) -> int:
    """Write each mesh, load it in a fresh process, print the table and write the plot."""
    rows = []
    print(f"{'triangles':>10} {'sections':>9} {'file MB':>8} {'load s':>8} {'cpu s':>7} "
          f"{'peak MiB':>9} {'cells':>9} {'pairs':>9}  result")
    with tempfile.TemporaryDirectory(prefix="skelasm-bench-loading-") as folder:
        for size in args.triangles:
            soup = fan_cylinder(size)
            path = Path(folder) / f"cylinder_{size}.stl"
            write_stl(path, soup)
            del soup
            row = {"requested": size, "triangles_in": int((path.stat().st_size - 84) // 50),
                   "megabytes": path.stat().st_size / 1e6, **measure(path,
                                                                     timeout=args.timeout)}
            path.unlink()
            rows.append(row)
            sections = int(round(size / (4 * (1 + DOUBLED))))
            if "error" in row:
                print(f"{row['triangles_in']:>10} {sections:>9} {row['megabytes']:>8.1f} "
                      f"{'-':>8} {'-':>7} {'-':>9} {'-':>9} {'-':>9}  {row['error']}")
                continue
            print(f"{row['triangles_in']:>10} {sections:>9} {row['megabytes']:>8.1f} "
                  f"{row['seconds']:>8.2f} {row['cpu_seconds']:>7.2f} {row['peak_mib']:>9.0f} "
                  f"{row['weld_cells']:>9} "
                  f"{row['weld_pairs']:>9}  {row['triangles']} triangles kept, volume "
                  f"{row['volume']:.6g}, {row['warnings']} warnings")
    _plot(rows, args.output)
    print(f"plot written to {args.output}")
    return 0 if all("error" not in r for r in rows) else 1


def _plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = [r for r in rows if "error" not in r]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    x = [r["triangles_in"] for r in good]
    ax.loglog(x, [r["seconds"] for r in good], "o-", label="wall")
    ax.loglog(x, [max(r.get("cpu_seconds", 0.0), 1e-3) for r in good], "s--", label="CPU")
    ax.legend()
    ax.set_xlabel("triangles in the STL")
    ax.set_ylabel("load time (s)")
    ax.set_title("load_part: time")
    bx.loglog(x, [max(r["peak_mib"], 1e-1) for r in good], "o-", color="tab:orange")
    bx.set_xlabel("triangles in the STL")
    bx.set_ylabel("peak memory above start (MiB)")
    bx.set_title("load_part: peak memory")
    for axis in (ax, bx):
        axis.grid(True, which="both", alpha=0.3)
    fig.suptitle("Fan-capped cylinders with 1 % doubled triangles (binary STL)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
