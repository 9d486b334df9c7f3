"""`skelasm bench descriptor`: seconds per part and error against brute force.

For each usable backend, each method (``adaptive`` and ``tree`` by default), each test
mesh (tori of about 1e3, 2e4 and 2e5 triangles: a curved closed surface with a hole, so
both the inside and the outside have a medial axis) and each cubic grid size, time
``compute_descriptor`` (tree build included) and measure its relative L2 error against
``method="brute"`` on a random sample of the same grid points. Then the same on
CAD-tessellated parts (:mod:`bench.cad_meshes`: a peg and a plate with a hole, slivers
with aspect ratios up to 275) beside well-shaped meshes of the same parts and size, and
print the CAD / well-shaped per-point cost ratio. Prints markdown tables (wall seconds
and the process's CPU seconds, which tell what a loaded machine hides), the headline
(128^3 samples, 2e5 triangles) and writes a plot of both.
"""

from __future__ import annotations

import argparse
import os
import resource
import time

import numpy as np

from engine.backend import choices
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
                        choices=[c for c in choices("descriptor") if c != "auto"],
                        help="descriptor backends (default: all that work here)")  # fmt: skip
    parser.add_argument("--methods", nargs="+", default=["adaptive", "tree"],
                        help="adaptive, tree (default both)")  # fmt: skip
    parser.add_argument("--cad-grid", type=int, default=32,
                        help="grid of the CAD / well-shaped comparison (0: skip it)")  # fmt: skip
    parser.add_argument("--sample", type=int, default=1000,
                        help="points compared with brute force per case (0: skip)")  # fmt: skip
    parser.add_argument("--quick", action="store_true",
                        help="small run: grids 16 32, tori 1000 20000, CAD grid 16")  # fmt: skip
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
    """The descriptor's backends (the registry's) that work here, its reference first."""
    from engine.backend import CAPABILITIES, backend_problem, get_backend
    from engine.descriptor.opencl_kernels import kernel_builds

    names = []
    for name in reversed(CAPABILITIES["descriptor"].backends):
        if backend_problem(name) is None and (name != "opencl"
                                              or kernel_builds(get_backend(name))):
            names.append(name)
    return names


def _sample_error(vertices, faces, grid, rho, backend, sample, rng) -> float:
    """Relative L2 error of ``rho`` against brute force on ``sample`` random grid points."""
    from engine.descriptor import descriptor_at_points

    flat = rho.reshape(-1)
    idx = rng.choice(flat.size, size=min(sample, flat.size), replace=False)
    points = grid.points().reshape(-1, 3)[idx]
    ref = descriptor_at_points(vertices, faces, points, spacing=grid.spacing, backend=backend,
                               method="brute")  # fmt: skip
    return float(np.linalg.norm(flat[idx] - ref) / np.linalg.norm(ref))


def _timed(vertices, faces, grid, backend, method) -> tuple[np.ndarray, float, float]:
    """(rho, wall seconds, CPU seconds) of one descriptor."""
    from engine.descriptor import compute_descriptor

    cpu0 = _cpu_seconds()
    t0 = time.perf_counter()
    rho = compute_descriptor(vertices, faces, grid, backend=backend, method=method)
    return rho, time.perf_counter() - t0, _cpu_seconds() - cpu0


def _cad_parts() -> list[tuple[str, str, tuple[np.ndarray, np.ndarray]]]:
    """(name, well-shaped counterpart's name or "", mesh) of the CAD comparison."""
    from bench import cad_meshes as cm

    return [
        ("CAD peg", "", cm.cad_peg()),
        ("well-shaped peg", "CAD peg", cm.well_shaped_peg()),
        ("torus", "CAD peg", cm.torus(1150)),
        ("CAD plate with hole", "", cm.cad_plate_with_hole()),
        ("well-shaped plate", "CAD plate with hole", cm.well_shaped_plate_with_hole()),
    ]


def run(args: argparse.Namespace) -> int:
    """Run the benchmark; print the tables, write the plot."""
    from bench.cad_meshes import aspect_ratios
    from engine.descriptor import compute_descriptor, resolve_backend

    grids = [16, 32] if args.quick else args.grids
    tris = [1000, 20000] if args.quick else args.triangles
    cad_grid = 16 if args.quick else args.cad_grid
    backends = args.backends or _usable_backends()
    rng = np.random.default_rng(0)
    rows = []
    cad_rows = []
    for name in backends:
        backend = resolve_backend(name)
        # Warm up: numba compilation / OpenCL build are not part of a part's cost.
        v, f = torus(1000)
        for method in ("brute", *args.methods):
            compute_descriptor(v, f, cubic_grid(v, 8), backend=backend, method=method)
        for count in tris:
            v, f = torus(count)
            for n in grids:
                grid = cubic_grid(v, n)
                for method in args.methods:
                    rho, seconds, cpu = _timed(v, f, grid, backend, method)
                    err = (_sample_error(v, f, grid, rho, backend, args.sample, rng)
                           if args.sample > 0 else float("nan"))  # fmt: skip
                    rows.append((backend.describe(), name, len(f), n, seconds, err, cpu, method))
                    print(f"  {name:6s} {method:8s} {len(f):7d} triangles {n:4d}^3: "
                          f"{seconds:8.2f} s (CPU {cpu:.1f} s), error {err:.1e}",
                          flush=True)  # fmt: skip
        if cad_grid > 0:
            for part, reference, (v, f) in _cad_parts():
                grid = cubic_grid(v, cad_grid)
                for method in args.methods:
                    rho, seconds, cpu = _timed(v, f, grid, backend, method)
                    err = (_sample_error(v, f, grid, rho, backend, args.sample, rng)
                           if args.sample > 0 else float("nan"))  # fmt: skip
                    per_point = 1e6 / grid.size
                    cad_rows.append((name, part, reference, len(f),
                                     float(aspect_ratios(v, f).max()), cad_grid, method,
                                     seconds * per_point, cpu * per_point, err))  # fmt: skip
                    print(f"  {name:6s} {method:8s} {part:20s} {len(f):5d} triangles "
                          f"{cad_grid}^3: {seconds / grid.size * 1e6:7.1f} us/point, "
                          f"error {err:.1e}", flush=True)  # fmt: skip
    _print_tables(rows, cad_rows)
    _plot(rows, cad_rows, args.output)
    print(f"plot written to {args.output}")
    return 0


def _print_tables(rows, cad_rows) -> None:
    print()
    print("| backend | method | triangles | grid | seconds | CPU seconds | rel. L2 error vs brute "
          "force |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|")
    for _, name, m, n, seconds, err, cpu, method in rows:
        print(f"| {name} | {method} | {m} | {n}^3 | {seconds:.2f} | {cpu:.1f} | {err:.1e} |")
    head = [r for r in rows if r[3] == 128 and r[2] >= 190000]
    for r in head:
        print(f"- headline ({r[1]}, {r[7]}): 128^3 samples, {r[2]} triangles: {r[4]:.1f} s "
              f"(CPU {r[6]:.1f} s), error {r[5]:.1e}")  # fmt: skip
    if cad_rows:
        print()
        print("| backend | method | part | triangles | max aspect | grid | us/point | CPU "
              "us/point | rel. L2 error |")  # fmt: skip
        print("|---|---|---|---:|---:|---:|---:|---:|---:|")
        for be, part, _, m, aspect, n, method, us, cpu_us, err in cad_rows:
            print(f"| {be} | {method} | {part} | {m} | {aspect:.0f} | {n}^3 | {us:.1f} | "
                  f"{cpu_us:.1f} | {err:.1e} |")  # fmt: skip
        cost = {(r[0], r[6], r[1]): r[8] for r in cad_rows}  # CPU us/point
        for be, part, reference, *_, method, _us, cpu_us, _err in cad_rows:
            if reference:
                ratio = cost[(be, method, reference)] / cpu_us
                print(f"- {be} {method}: {reference} / {part} per-point CPU cost ratio "
                      f"{ratio:.2f}")  # fmt: skip
    print()
    for desc in sorted({r[0] for r in rows}):
        print(f"- {desc}")
    print(f"- {os.cpu_count()} CPU cores; load average at the end {os.getloadavg()[0]:.1f}")


def _cpu_seconds() -> float:
    """CPU time of this process, all threads (OpenCL on the CPU and numba included)."""
    use = resource.getrusage(resource.RUSAGE_SELF)
    return use.ru_utime + use.ru_stime


def _plot(rows, cad_rows, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.5))
    for name in sorted({r[1] for r in rows}):
        for method in sorted({r[7] for r in rows}):
            for m in sorted({r[2] for r in rows}):
                pts = [(r[3], r[4]) for r in rows if r[1] == name and r[2] == m and r[7] == method]
                if pts:
                    n, s = zip(*sorted(pts), strict=True)
                    ax.loglog(np.asarray(n) ** 3, s, "o-" if method == "adaptive" else "s--",
                              label=f"{name} {method}, {m} triangles")  # fmt: skip
    ax.axhline(15, color="grey", ls="--", lw=0.8)
    ax.set_xlabel("grid samples")
    ax.set_ylabel("seconds per part")
    ax.set_title("Tori: seconds per part (15 s target dashed)")
    ax.legend(fontsize=7)
    if cad_rows:
        labels = [f"{r[0]} {r[1]} {r[6]}" for r in cad_rows]
        bx.bar(range(len(cad_rows)), [r[8] for r in cad_rows],
               color=["tab:red" if "CAD" in r[1] else "tab:blue" for r in cad_rows])  # fmt: skip
        bx.set_xticks(range(len(cad_rows)), labels, rotation=60, ha="right", fontsize=7)
        bx.set_ylabel("CPU microseconds per grid point")
        bx.set_title(f"CAD tessellations (red) vs well-shaped (blue), {cad_rows[0][5]}^3")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
