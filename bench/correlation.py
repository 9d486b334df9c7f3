"""`skelasm bench correlation`: what accuracy costs in time, per mode count and backend.

For each example pair (``assets/*/scene.toml``; synthetic Gaussian pairs when the assets
or the descriptor store are missing, with a note) and each per-pose backend present:
median microseconds per full 6-DOF evaluation (energy, force, torque, rotation included)
over many varied poses, and the errors of energy, force magnitude and force direction
against the full-mode result, and the shift of the energy minimum of the landscape at
the fitted rotation. Also measures the interpolation error of the rotated spectrum
against the exact spectrum of the sampled field at the rotated frequencies (a direct,
non-uniform Fourier sum over every sample: the field rotated exactly, no interpolation).
Prints a markdown table and writes a PNG (energy error against time, one curve per
backend), then a per-pose cost table (median and p99 microseconds per K, per backend, up to
K = 64) and a second PNG beside the first (``<output>_pose_cost.png``: cost against K).
Rows where a compiled backend could not take the table and ran on the numpy reference are
marked.

Then the rotation cache (what the simulation runs with rotation free): per pair and K (16 to
64 by default), the median microseconds of a cached pose beside the full numba path, the
refresh time, and the cached model's relative error 1 mrad from its reference rotation
against the full path; on the bundled pairs and on CAD-tessellated pairs from
``assets/real`` (:data:`REAL_SCENES`, where their descriptors can be had); a third PNG
(``<output>_rotation_cache.png``). ``--pose-cost-only`` measures only this.
"""

from __future__ import annotations

import argparse
import math
import os
import time
import types
from pathlib import Path

import numpy as np

from engine.backend import choices

DEFAULT_MODES = ("4", "8", "16", "24", "32", "48", "64", "full")
CACHE_MODES = ("16", "24", "32", "48", "64")
#: CAD-tessellated pairs (under assets/real) the rotation-cache table measures as well.
REAL_SCENES = ("iso_pin_5_H7h6_through", "factory_round_peg_8mm_loose")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench correlation`` to ``parser``."""
    parser.add_argument("--scenes", nargs="*", default=None,
                        help="scene files (default: assets/*/scene.toml)")
    parser.add_argument("--synthetic", action="store_true",
                        help="use synthetic Gaussian pairs instead of the example scenes")
    parser.add_argument("--modes", nargs="*", default=list(DEFAULT_MODES),
                        help="modes per axis to measure ('full' = the whole FFT lattice)")
    parser.add_argument("--backends", nargs="*", default=None,
                        choices=[c for c in choices("per_pose") if c != "auto"],
                        help="per-pose backends (default: every one that works here)")
    parser.add_argument("--poses", type=int, default=300, help="poses timed per row")
    parser.add_argument("--error-poses", type=int, default=8,
                        help="poses at which errors against the full-mode result are measured")
    parser.add_argument("--refine", type=int, default=2,
                        help="refined-table factor of the Correlator (1: plain q lattice)")
    parser.add_argument("--fine-modes", type=int, default=24,
                        help="largest K served by the refined table")
    parser.add_argument("-o", "--output", default="bench_correlation.png", help="plot (PNG)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cache-modes", nargs="*", default=list(CACHE_MODES),
                        help="modes per axis of the rotation-cache table (none: skip it)")
    parser.add_argument("--real-scenes", nargs="*", default=None,
                        help="CAD-tessellated scenes for the rotation-cache table (default: "
                             + ", ".join(f"assets/real/{n}" for n in REAL_SCENES) + ")")
    parser.add_argument("--pose-cost-only", action="store_true",
                        help="only the rotation-cache table (no accuracy sweep)")


# ---------------------------------------------------------------------------- pairs
def _synthetic_pairs() -> list[tuple[str, object, object, np.ndarray, float]]:
    """Two Gaussian-blob pairs on 40^3-ish grids (a stand-in for the example scenes)."""
    from engine.grid import Grid

    def field(grid, blobs):
        p = grid.points()
        out = np.zeros(grid.shape, dtype=complex)
        for a, mu, s in blobs:
            out += a * np.exp(-np.sum((p - np.asarray(mu)) ** 2, -1) / (2 * s * s))
        return out.astype(np.complex64)

    rng = np.random.default_rng(7)
    pairs = []
    for name, n1, n2 in (("synthetic A", (44, 44, 32), (24, 24, 40)),
                         ("synthetic B", (40, 40, 40), (30, 30, 30))):
        h = 0.5
        g1 = Grid(tuple(-0.5 * h * (np.asarray(n1) - 1)), h, n1)
        g2 = Grid(tuple(-0.5 * h * (np.asarray(n2) - 1)), h, n2)
        b1 = [(complex(*rng.normal(size=2)), rng.normal(scale=3, size=3), rng.uniform(0.8, 2))
              for _ in range(6)]
        b2 = [(complex(*rng.normal(size=2)), rng.normal(scale=2, size=3), rng.uniform(0.8, 2))
              for _ in range(4)]
        d1 = types.SimpleNamespace(rho=field(g1, b1), grid=g1)
        d2 = types.SimpleNamespace(rho=field(g2, b2), grid=g2)
        pairs.append((name, d1, d2, np.zeros(6), 4.0))
    return pairs


def _scene_pairs(paths: list[str]) -> list[tuple[str, object, object, np.ndarray, float]]:
    from engine.descriptor import descriptors_for_scene
    from engine.scene import load_scene

    pairs = []
    for path in paths:
        scene = load_scene(path)
        d1, d2 = descriptors_for_scene(scene)[:2]
        extent = float(np.max(d2.grid.upper - np.asarray(d2.grid.origin)))
        name = os.path.basename(os.path.dirname(os.path.abspath(path)))
        pairs.append((name, d1, d2, np.asarray(scene.assembled_pose, dtype=float),
                      0.1 * extent))
    return pairs


# ---------------------------------------------------------------------------- measures
def _poses(
    fitted: np.ndarray, spread: float, count: int, rng
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Poses around the fitted one: translations within ``spread``, rotations up to ~0.3 rad."""
    from engine.pose import rotation_matrix

    out = []
    base = rotation_matrix(fitted[3:])
    for _ in range(count):
        rot = rotation_matrix(rng.normal(scale=0.15, size=3)) @ base
        out.append((rot, fitted[:3] + rng.normal(scale=spread, size=3)))
    return out


def _time_backend(corr, poses) -> tuple[float, float]:
    times = [corr.evaluate(rot, t).microseconds for rot, t in poses]
    return float(np.median(times)), float(np.percentile(times, 99))


def _errors(results, reference) -> tuple[float, float, float]:
    """Median relative energy error (to the RMS full-mode energy), |F| error, direction (deg)."""
    e_ref = np.array([r.energy for r in reference])
    e = np.array([r.energy for r in results])
    scale_e = float(np.sqrt(np.mean(e_ref**2))) or 1.0
    f_ref = np.array([r.force for r in reference])
    f = np.array([r.force for r in results])
    mag_ref = np.linalg.norm(f_ref, axis=1)
    mag = np.linalg.norm(f, axis=1)
    scale_f = float(np.sqrt(np.mean(mag_ref**2))) or 1.0
    cos = np.sum(f * f_ref, axis=1) / np.maximum(mag * mag_ref, 1e-300)
    angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    strong = mag_ref > 0.1 * scale_f
    return (
        float(np.median(np.abs(e - e_ref)) / scale_e),
        float(np.median(np.abs(mag - mag_ref)) / scale_f),
        float(np.median(angle[strong])) if np.any(strong) else float("nan"),
    )


def interpolation_error(corr, rotation: np.ndarray, modes: int) -> tuple[float, float]:
    """Error of the interpolated rotated spectrum against the exact one.

    The exact value of part 2's centred spectrum at ``-R^T w`` is the direct sum
    ``h^3 sum_n rho2[n] exp(2 pi i (R^T w).(x_n - c2))`` over every sample (the sampled
    field rotated exactly). Returns the relative RMS error over the kept cube, weighted by
    ``|rho1^(w)|`` (what the score sees), and the relative error of the score ``f`` at the
    pose that puts the grid centres together.
    """
    from engine.correlation.reference import interpolate_rows
    from engine.correlation.spectrum import cube_weights, kept_indices
    from engine.correlation.tables import cube_reach

    grid = corr.moving_grid
    h = grid.spacing
    kept = kept_indices(modes, corr.size)
    kx, ky, kz = np.meshgrid(kept, kept, kept, indexing="ij")
    kvec = np.stack([kx.ravel(), ky.ravel(), kz.ravel()], 1).astype(np.float64)  # (m', 3)
    approx = interpolate_rows(corr.spectra, kvec @ rotation, cube_reach(modes), False)[0]
    w = np.stack([kx.ravel(), ky.ravel(), kz.ravel()], 1) / (corr.size * h)  # (m', 3)
    rw = w @ rotation  # rows: R^T w
    offsets = [h * (np.arange(n) - 0.5 * (n - 1)) for n in grid.shape]
    rho = corr.spectra.moving_rho.astype(np.complex128)
    exact = np.empty(len(w), dtype=np.complex128)
    # separable over the sample axes: exp(2 pi i rw.x) = prod_a exp(2 pi i rw_a x_a)
    for lo in range(0, len(w), 512):
        r = rw[lo : lo + 512]
        ex = np.exp(2j * np.pi * r[:, 0:1] * offsets[0][None, :])  # (c, nx)
        ey = np.exp(2j * np.pi * r[:, 1:2] * offsets[1][None, :])
        ez = np.exp(2j * np.pi * r[:, 2:3] * offsets[2][None, :])
        tmp = np.einsum("ijk,ck->cij", rho, ez, optimize=True)
        tmp = np.einsum("cij,cj->ci", tmp, ey, optimize=True)
        exact[lo : lo + 512] = h**3 * np.einsum("ci,ci->c", tmp, ex)
    wrapped = np.mod(kept, corr.size)
    a = (corr.spectra.fixed.values[np.ix_(wrapped, wrapped, wrapped)]
         * cube_weights(modes, corr.size)).ravel().astype(np.complex128)
    weight = np.abs(a)
    spectral = float(np.sqrt(np.sum(weight * np.abs(approx - exact) ** 2)
                             / np.sum(weight * np.abs(exact) ** 2)))
    f_exact = np.sum(a * exact)
    f_approx = np.sum(a * approx)
    score = float(abs(f_approx - f_exact) / max(abs(f_exact), 1e-300))
    return spectral, score


def run(args: argparse.Namespace) -> int:
    """Measure time and accuracy per pair, mode count and backend; print the tables, write the plot.

    Each pair's full-mode numpy result is the reference for the errors of every other row.
    Returns the exit status (0).
    """
    from engine.correlation import Correlator
    from engine.correlation.tables import cube_reach
    from engine.pose import rotation_matrix

    _check_output(args.output)
    rng = np.random.default_rng(args.seed)
    note = ""
    # the bundled scenes beside this package, wherever the command is run from
    bundled = Path(__file__).resolve().parents[1] / "assets"
    paths = (args.scenes if args.scenes is not None
             else sorted(str(p) for p in bundled.glob("*/scene.toml")))
    pairs = []
    if not args.synthetic and paths:
        try:
            pairs = _scene_pairs(paths)
        except ImportError as exc:
            note = f"NOTE: example scenes unusable ({exc}); synthetic Gaussian pairs measured."
    elif not args.synthetic:
        note = "NOTE: no example scenes found; synthetic Gaussian pairs measured."
    if not pairs:
        pairs = _synthetic_pairs()
    if note:
        print(note)

    if args.pose_cost_only:
        return _rotation_cache_section(args, pairs, rng)
    rows = []
    costs: list[tuple[str, str, int, float, float, bool]] = []
    curves: dict[tuple[str, str], list[tuple[float, float, str]]] = {}
    interp_rows = []
    for name, d1, d2, fitted, spread in pairs:
        start = time.perf_counter()
        corr = Correlator(d1, d2, modes=16, backend="numpy", refine=args.refine,
                          fine_modes=args.fine_modes)
        setup = time.perf_counter() - start
        backends = args.backends or _present_backends(corr)
        print(f"\n## {name}: grids {d1.grid.shape} and {d2.grid.shape}, h = {d1.grid.spacing:.4g}, "
              f"FFT size {corr.size} (x{corr.spectra.oversample_factor} for part 2), "
              f"setup {setup:.1f} s")
        timing_poses = _poses(fitted, spread, args.poses, rng)
        error_poses = _poses(fitted, spread, args.error_poses, rng)
        # reference: numpy at full modes
        corr.use_backend("numpy")
        corr.set_modes(corr.size)
        t0 = time.perf_counter()
        reference = [corr.evaluate(rot, t) for rot, t in error_poses]
        full_us = (time.perf_counter() - t0) / len(error_poses) * 1e6
        base_rot = rotation_matrix(fitted[3:])
        land_full = corr.landscape(base_rot, forces=False)
        t_full, _ = land_full.minimum()
        for mode_text in args.modes:
            k = corr.size if mode_text == "full" else int(mode_text)
            corr.set_modes(k)
            land = corr.landscape(base_rot, forces=False) if k < corr.size else land_full
            shift = float(np.linalg.norm(land.minimum()[0] - t_full))
            for backend in backends:
                if k == corr.size and backend != "numpy":
                    continue  # the per-pose tables of the compiled paths cover K <= ~64
                corr.use_backend(backend)
                fallbacks = corr.stats["reference_fallbacks"]
                if backend == "numpy":
                    if k == corr.size:
                        med, p99 = full_us, full_us
                    else:
                        med, p99 = _time_backend(corr, timing_poses[: max(5, args.poses // 20)])
                else:
                    _time_backend(corr, timing_poses[:5])  # warm-up
                    med, p99 = _time_backend(corr, timing_poses)
                ran_on_reference = corr.stats["reference_fallbacks"] > fallbacks
                results = [corr.evaluate(rot, t) for rot, t in error_poses]
                e_err, f_err, angle = _errors(results, reference)
                label = "full" if k == corr.size else f"{k}^3"
                rows.append((name, backend, label, med, p99, e_err, f_err, angle,
                             shift, shift / corr.spacing))
                if k < corr.size:  # the full lattice's cost is in the table above
                    costs.append((name, backend, k, med, p99, ran_on_reference))
                curves.setdefault((name, backend), []).append((med, max(e_err, 1e-9), label))
                print(f"  {backend:6s} {label:>6s}: {med:9.1f} us (p99 {p99:9.1f}), energy err "
                      f"{e_err:.2e}, |F| err {f_err:.2e}, F dir {angle:.2f} deg, min shift "
                      f"{shift:.3g} ({shift / corr.spacing:.2f} cells)")
        for angle in (0.05, 0.5, math.pi):
            rot = rotation_matrix(np.array([1.0, 2.0, -1.5]) / np.linalg.norm([1, 2, -1.5]) * angle)
            for k in (16, 24, 32):
                spectral, score = interpolation_error(corr, rot, k)
                fine = corr.spectra.fine_for(cube_reach(k))
                lattice = (f"refined x{corr.spectra.refine}" if fine
                           else f"q = {corr.spectra.oversample_factor}")
                interp_rows.append((name, angle, k, lattice, spectral, score))
        print(f"  picked by auto here: {_auto_pick(d1, d2, args)}")

    print("\n| pair | backend | m' | median us | p99 us | energy err | abs F err | F dir err (deg) "
          "| min shift (cells) |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for name, backend, label, med, p99, e_err, f_err, angle, _shift, cells in rows:
        print(f"| {name} | {backend} | {label} | {med:.1f} | {p99:.1f} | {e_err:.2e} | {f_err:.2e} "
              f"| {angle:.2f} | {cells:.2f} |")
    print("\nInterpolation error of the rotated spectrum (cubic Hermite, against the "
          "exact non-uniform Fourier sum of the sampled field):\n")
    print("| pair | rotation (rad) | K | lattice | spectrum rel. RMS (weighted by abs rho1^) "
          "| score rel. err |")
    print("|---|---:|---:|---|---:|---:|")
    for name, angle, k, lattice, spectral, score in interp_rows:
        print(f"| {name} | {angle:.3g} | {k} | {lattice} | {spectral:.2e} | {score:.2e} |")
    cost_path = _cost_path(args.output)
    _print_costs(costs)
    _plot(curves, args.output)
    _plot_costs(costs, cost_path)
    print(f"\nwrote {args.output} and {cost_path}")
    return _rotation_cache_section(args, pairs, rng)


# ---------------------------------------------------------------------------- rotation cache
def _real_pairs(args: argparse.Namespace) -> list[tuple[str, object, object, np.ndarray, float]]:
    """The CAD-tessellated pairs whose descriptors are stored; the others are named, skipped.

    Computing them takes minutes: ``skelasm precompute`` first.
    """
    from engine.runtime import open_scene
    from engine.sim.build import SceneModel

    real = Path(__file__).resolve().parents[1] / "assets" / "real"
    paths = (args.real_scenes if args.real_scenes is not None
             else [str(real / n / "scene.toml") for n in REAL_SCENES
                   if (real / n / "scene.toml").is_file()])
    usable = []
    for path in paths:
        if SceneModel(open_scene(path)).descriptors_cached():
            usable.append(path)
        else:
            print(f"  ({path}: descriptors not stored; run skelasm precompute on it first)")
    return _scene_pairs(usable) if usable else []


def rotation_cache_costs(corr, fitted: np.ndarray, spread: float, modes: list[int],
                         poses: int, rng) -> list[dict[str, float]]:
    """Per K: cached and full-path median (p99) microseconds, refresh ms, cached error at 1 mrad.

    ``corr`` a numba Correlator with rotation on; poses scattered around ``fitted`` (within
    ``spread``), rotations within 1 mrad of a cache built 0.05 rad from the fitted rotation.
    """
    from engine.correlation.rotation_cache import serves
    from engine.pose import rotation_matrix

    base = rotation_matrix(fitted[3:])
    out = []
    for k in modes:
        corr.set_modes(k)
        if not serves(corr.table):  # part 2's table too large for the compiled kernels
            print(f"  (K = {k}: part 2's table exceeds the compiled kernels' limit; the "
                  "full path runs on the numpy reference and no cache is built)")
            continue
        r0 = rotation_matrix(rng.normal(scale=0.05, size=3)) @ base
        sample = [(rotation_matrix(rng.normal(size=3) * 3e-4) @ r0,
                   fitted[:3] + rng.normal(scale=spread, size=3)) for _ in range(poses)]
        refresh = []
        for _ in range(3 if k >= 48 else 10):
            start = time.perf_counter()
            cache = corr.rotation_cache(r0)
            refresh.append(time.perf_counter() - start)
        for rot, t in sample[:5]:
            corr.evaluate_cached(cache, rot, t)
            corr.evaluate(rot, t)
        cached = [corr.evaluate_cached(cache, rot, t).microseconds for rot, t in sample]
        full = [corr.evaluate(rot, t).microseconds
                for rot, t in sample[: max(20, poses // max(1, (k // 16) ** 2))]]
        err = np.zeros(3)
        for rot_t in sample[:4]:
            axis = rng.normal(size=3)
            rot = rotation_matrix(1e-3 * axis / np.linalg.norm(axis)) @ r0
            a, b = corr.evaluate_cached(cache, rot, rot_t[1]), corr.evaluate(rot, rot_t[1])
            assert a.torque is not None and b.torque is not None
            for i, (x, y) in enumerate(((a.energy, b.energy), (a.force, b.force),
                                        (a.torque, b.torque))):
                err[i] = max(err[i], float(np.linalg.norm(np.subtract(x, y))
                                           / max(float(np.linalg.norm(y)), 1e-300)))
        out.append({"K": k, "cached_us": float(np.median(cached)),
                    "cached_p99": float(np.percentile(cached, 99)),
                    "full_us": float(np.median(full)), "full_p99": float(np.percentile(full, 99)),
                    "refresh_ms": 1e3 * float(np.median(refresh)), "err_E": float(err[0]),
                    "err_F": float(err[1]), "err_T": float(err[2])})
    return out


def _rotation_cache_section(args: argparse.Namespace, pairs, rng) -> int:
    """The rotation-cache table and plot (bundled or given pairs, then the CAD pairs)."""
    from engine.backend import backend_problem
    from engine.correlation import Correlator

    modes = [int(m) for m in args.cache_modes]
    if not modes:
        return 0
    problem = backend_problem("numba")
    if problem is not None:
        print(f"\n(rotation cache not measured: numba is not usable here: {problem})")
        return 0
    rows = []
    for name, d1, d2, fitted, spread in list(pairs) + _real_pairs(args):
        corr = Correlator(d1, d2, modes=modes[0], backend="numba", refine=args.refine,
                          fine_modes=args.fine_modes)
        for row in rotation_cache_costs(corr, fitted, spread, modes, args.poses, rng):
            rows.append((name, row))
            print(f"  {name} K={row['K']}: cached {row['cached_us']:.0f} us, full "
                  f"{row['full_us']:.0f} us, refresh {row['refresh_ms']:.2f} ms", flush=True)
    print("\nRotation cache (the simulation's path with rotation free), median (p99) "
          "microseconds per 6-DOF pose, numba, one thread; refresh = building the cache; "
          "error = cached model against the full path 1 mrad from the cache's rotation:\n")
    print("| pair | K | cached us | full path us | refresh ms | rel. error E / F / T at 1 mrad |")
    print("|---|---:|---:|---:|---:|---|")
    for name, r in rows:
        print(f"| {name} | {r['K']} | {r['cached_us']:.0f} ({r['cached_p99']:.0f}) | "
              f"{r['full_us']:.0f} ({r['full_p99']:.0f}) | {r['refresh_ms']:.2f} | "
              f"{r['err_E']:.1e} / {r['err_F']:.1e} / {r['err_T']:.1e} |")
    path = f"{os.path.splitext(args.output)[0]}_rotation_cache.png"
    _plot_cache(rows, path)
    print(f"\nwrote {path}")
    return 0


def _plot_cache(rows, path: str) -> None:
    """Cached and full-path median microseconds against K, per pair; the goals marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    names = sorted({name for name, _ in rows})
    for i, name in enumerate(names):
        pts = sorted((r["K"], r["cached_us"], r["full_us"]) for n, r in rows if n == name)
        colour = f"C{i % 10}"
        ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", color=colour,
                label=f"{name} cached")
        ax.plot([p[0] for p in pts], [p[2] for p in pts], "s:", color=colour, alpha=0.6,
                label=f"{name} full path")
    ax.plot([16, 32, 64], [20, 100, 1000], "k*", ms=10, label="goal (20 / 100 / 1000 us)")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("modes per axis K")
    ax.set_ylabel("median time per 6-DOF evaluation (us)")
    ax.set_title("Per pose: the rotation cache against the full path (numba, one thread)",
                 fontsize=10)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _check_output(path: str) -> None:
    """Refuse, before any work, a plot path whose folder is missing or not writable."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise FileNotFoundError(f"{path}: the folder {folder} does not exist; create it or "
                                "pass -o with an existing folder")
    if not os.access(folder, os.W_OK):
        raise PermissionError(f"{path}: the folder {folder} is not writable; pass -o with a "
                              "writable folder")


def _cost_path(path: str) -> str:
    """The per-pose cost plot's path: ``<output stem>_pose_cost.png`` beside the first."""
    stem, _ = os.path.splitext(path)
    return f"{stem}_pose_cost.png"


def _print_costs(costs) -> None:
    """Per-pose cost per pair and K: median (p99) microseconds, one column per backend."""
    backends = [b for b in choices("per_pose")[:-1] if any(c[1] == b for c in costs)]
    table: dict[tuple[str, int], dict[str, str]] = {}
    for name, backend, k, med, p99, on_reference in costs:
        mark = " (ran on numpy)" if on_reference and backend != "numpy" else ""
        table.setdefault((name, k), {})[backend] = f"{med:.0f} ({p99:.0f}){mark}"
    print("\nPer-pose cost, full 6-DOF (energy, force, torque), median (p99) microseconds:\n")
    print("| pair | K | m' | " + " | ".join(backends) + " |")
    print("|---|---:|---:|" + "---:|" * len(backends))
    for (name, k), cells in sorted(table.items()):
        print(f"| {name} | {k} | {k**3} | "
              + " | ".join(cells.get(b, "-") for b in backends) + " |")


def _plot_costs(costs, path: str) -> None:
    """Median microseconds per pose against K, per pair and backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    styles = {"numpy": "s-", "numba": "o-", "opencl": "^-"}
    series: dict[tuple[str, str], list[tuple[int, float]]] = {}
    for name, backend, k, med, _p99, _ref in costs:
        series.setdefault((name, backend), []).append((k, med))
    for (name, backend), points in sorted(series.items()):
        points = sorted(points)
        ax.plot([p[0] for p in points], [p[1] for p in points], styles.get(backend, "x-"),
                label=f"{name} / {backend}")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.axhline(100, color="grey", lw=0.8, ls="--")
    ax.axhline(1000, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("modes per axis K (m' = K^3)")
    ax.set_ylabel("median time per 6-DOF evaluation (us)")
    ax.set_title("Per-pose cost against K (dashed: 100 us, dotted: 1 ms)", fontsize=10)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _auto_pick(d1, d2, args) -> str:
    from engine.correlation import Correlator

    return Correlator(d1, d2, modes=16, backend="auto", refine=args.refine,
                      fine_modes=args.fine_modes).backend_name


def _present_backends(corr) -> list[str]:
    names = ["numpy"]
    for name in choices("per_pose")[1:-1]:  # the compiled ones (numpy is the reference)
        try:
            corr.use_backend(name)
            names.append(name)
        except Exception as exc:  # noqa: BLE001 - absent backends are reported, not fatal
            print(f"  ({name} not measured: {str(exc).splitlines()[0]})")
    corr.use_backend("numpy")
    return names


def _plot(curves, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), dpi=110)
    styles = {"numpy": "s-", "numba": "o-", "opencl": "^-"}
    for (name, backend), points in sorted(curves.items()):
        # the full-mode rows are the reference (error 0 by definition): not plotted
        points = sorted(p for p in points if p[2] != "full")
        if not points:
            continue
        xs = [p[0] for p in points]
        ys = [p[1] for p in points]
        ax.plot(xs, ys, styles.get(backend, "x-"), label=f"{name} / {backend}")
        for x, y, label in points:
            ax.annotate(label, (x, y), fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axvline(100, color="grey", lw=0.8, ls="--")
    ax.axvline(1000, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("median time per 6-DOF evaluation (us)")
    ax.set_ylabel("energy error vs full modes (relative to RMS energy)")
    ax.set_title("Fourier correlation: accuracy against time (dashed: 100 us, dotted: 1 ms)",
                 fontsize=10)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
