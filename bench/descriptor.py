"""`skelasm bench descriptor`: seconds per part and error against brute force.

For each usable backend, each test mesh (tori of about 1e3, 2e4 and 2e5 triangles: a
curved closed surface with a hole, so both the inside and the outside have a medial
axis) and each cubic grid size, time ``compute_descriptor(method="tree")`` (tree build
included) and measure its relative L2 error against ``method="brute"`` on a random
sample of the same grid points. Prints a markdown table (wall seconds and the process's
CPU seconds, which tell what a loaded machine hides) and writes a log-log plot.
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

from engine.grid import Grid

#: Torus sections (major, minor) per requested triangle count (2 * major * minor).
_TORUS = {1000: (32, 16), 20000: (160, 64), 200000: (500, 200)}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of the benchmark."""
    parser.add_argument("--grids", type=int, nargs="+", default=[32, 64, 128],
                        help="grid sizes N (N^3 samples); default 32 64 128")  # fmt: skip
    parser.add_argument("--triangles", type=int, nargs="+", default=[1000, 20000, 200000],
                        help="approximate triangle counts of the test tori")  # fmt: skip
    parser.add_argument("--backends", nargs="+", default=None,
                        help="numba and/or opencl (default: all that work here)")  # fmt: skip
    parser.add_argument("--sample", type=int, default=1000,
                        help="points compared with brute force per case (0: skip)")  # fmt: skip
    parser.add_argument("--quick", action="store_true",
                        help="small run: grids 16 32, triangles 1000 20000")  # fmt: skip
    parser.add_argument("-o", "--output", default="descriptor_bench.png", help="PNG plot")


def torus(triangles: int) -> tuple[np.ndarray, np.ndarray]:
    """A torus (major radius 1, minor 0.35) with about ``triangles`` triangles."""
    import trimesh

    if triangles in _TORUS:
        major, minor = _TORUS[triangles]
    else:
        minor = max(3, int(round(np.sqrt(triangles / 5.0))))
        major = max(3, int(round(triangles / (2.0 * minor))))
    m = trimesh.creation.torus(1.0, 0.35, major_sections=major, minor_sections=minor)
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def cubic_grid(vertices: np.ndarray, n: int, padding: int = 3) -> Grid:
    """An n^3 grid centred on the part, ``padding`` cells beyond its longest side."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    padding = min(padding, max(0, (n - 3) // 2))
    spacing = float((hi - lo).max()) / (n - 1 - 2 * padding)
    centre = 0.5 * (lo + hi)
    origin = centre - 0.5 * spacing * (n - 1)
    return Grid(tuple(origin), spacing, (n, n, n))


def _usable_backends() -> list[str]:
    from engine.backend import available_backends, get_backend
    from engine.descriptor.opencl_kernels import kernel_builds

    names = ["numba"]
    if "opencl" in available_backends() and kernel_builds(get_backend("opencl")):
        names.append("opencl")
    return names


def _sample_error(vertices, faces, grid, rho, backend, sample, rng) -> float:
    """Relative L2 error of ``rho`` against brute force on ``sample`` random grid points."""
    from engine.descriptor import compute as d
    from engine.params import DescriptorParams

    flat = rho.reshape(-1)
    idx = rng.choice(flat.size, size=min(sample, flat.size), replace=False)
    points = grid.points().reshape(-1, 3)[idx]
    local = d._localise(vertices[faces], grid.center, grid.spacing, False)
    out = d._run(local, (points - grid.center) / grid.spacing, 2, DescriptorParams(), backend)
    ref = out[:, 0] + 1j * out[:, 1]
    return float(np.linalg.norm(flat[idx] - ref) / np.linalg.norm(ref))


def run(args: argparse.Namespace) -> int:
    """Run the benchmark; print the table, write the plot."""
    from engine.descriptor import compute_descriptor, resolve_backend

    grids = [16, 32] if args.quick else args.grids
    tris = [1000, 20000] if args.quick else args.triangles
    backends = args.backends or _usable_backends()
    rng = np.random.default_rng(0)
    rows = []
    for name in backends:
        backend = resolve_backend(name)
        # Warm up: numba compilation / OpenCL build are not part of a part's cost.
        v, f = torus(1000)
        compute_descriptor(v, f, cubic_grid(v, 8), backend=backend)
        compute_descriptor(v, f, cubic_grid(v, 8), backend=backend, method="brute")
        for count in tris:
            v, f = torus(count)
            for n in grids:
                grid = cubic_grid(v, n)
                cpu0 = _cpu_seconds()
                t0 = time.perf_counter()
                rho = compute_descriptor(v, f, grid, backend=backend)
                seconds = time.perf_counter() - t0
                cpu = _cpu_seconds() - cpu0
                err = (
                    _sample_error(v, f, grid, rho, backend, args.sample, rng)
                    if args.sample > 0
                    else float("nan")
                )
                rows.append((backend.describe(), name, len(f), n, seconds, err, cpu))
                print(f"  {name:6s} {len(f):7d} triangles {n:4d}^3: {seconds:8.2f} s "
                      f"(CPU {cpu:.1f} s), error {err:.1e}", flush=True)  # fmt: skip
    print()
    print("| backend | triangles | grid | seconds | CPU seconds | rel. L2 error vs brute force |")
    print("|---|---:|---:|---:|---:|---:|")
    for _, name, m, n, seconds, err, cpu in rows:
        print(f"| {name} | {m} | {n}^3 | {seconds:.2f} | {cpu:.1f} | {err:.1e} |")
    print()
    for desc in sorted({r[0] for r in rows}):
        print(f"- {desc}")
    print(f"- {os.cpu_count()} CPU cores; load average at the end {os.getloadavg()[0]:.1f}")
    _plot(rows, args.output)
    print(f"plot written to {args.output}")
    return 0


def _cpu_seconds() -> float:
    """CPU time of this process, all threads (OpenCL on the CPU and numba included)."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _plot(rows, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.5))
    for name in sorted({r[1] for r in rows}):
        for m in sorted({r[2] for r in rows}):
            pts = [(r[3], r[4]) for r in rows if r[1] == name and r[2] == m]
            if pts:
                n, s = zip(*sorted(pts), strict=True)
                ax.loglog(np.asarray(n) ** 3, s, "o-", label=f"{name}, {m} triangles")
    ax.axhline(120, color="grey", ls="--", lw=0.8)
    ax.set_xlabel("grid samples")
    ax.set_ylabel("seconds per part")
    ax.set_title("Skeletal density descriptor (tree method)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
