"""`skelasm report SCENE -o DIR`: a headless report of one scene, as Markdown with images.

What the user would check before assembling: the parts and their mesh checks, the
descriptors (grid, time, backend), descriptor slices, the energy, force and torque at the
start, fitted, colliding and separated poses, what the mode count costs in time and
accuracy at the fitted pose, and energy sections through the fitted pose.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time
from pathlib import Path

from engine.backend import choices

KS = (4, 8, 12, 16, 24, 32)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm report`` (a Markdown report of a scene) to ``sub``."""
    parser = sub.add_parser(
        "report",
        help="write a Markdown report of a scene (parts, descriptors, energies, landscapes)",
        description="Compute (or load from the cache) both descriptors of a scene, evaluate "
        "energy, force and torque at telling poses and over mode counts, and write "
        "DIR/report.md with descriptor slices and energy landscape sections as PNG.",
    )
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument("-o", "--output", default="report", help="output folder (default: report)")
    parser.add_argument("--force", action="store_true",
                        help="replace the report and images already in the folder")
    parser.add_argument("--backend", choices=choices("per_pose"), default="auto",
                        help="per-pose backend (default: auto, the registry's choice here)")
    parser.set_defaults(run=run)


def _poses(scene, extent: float):
    """Named relative poses: start, fitted, collision (shifted sideways), separated (far)."""
    import numpy as np

    from engine.scene import relative_start_pose

    fitted = np.asarray(scene.assembled_pose, dtype=float)
    axis = np.asarray(scene.insertion_axis if scene.insertion_axis is not None else (0, 0, -1.0))
    axis = axis / np.linalg.norm(axis)
    side = np.cross(axis, [1.0, 0.0, 0.0])
    if np.linalg.norm(side) < 1e-6:
        side = np.cross(axis, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    shifted = fitted.copy()
    shifted[:3] += 0.25 * extent * side
    far = fitted.copy()
    far[:3] -= 3.0 * extent * axis
    return [
        ("start", relative_start_pose(scene)),
        ("fitted", fitted),
        ("collision (sideways by 1/4 of the moving part)", shifted),
        ("separated (3 part sizes back)", far),
    ]


def _slice_png(path: Path, descriptor, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from engine.files import atomic_write

    rho = descriptor.rho
    k = rho.shape[2] // 2
    x, y, z = descriptor.grid.axes()
    fig, axes = plt.subplots(1, 2, figsize=(9, 4), dpi=100)
    for ax, part, label in ((axes[0], rho.imag, "Im rho"), (axes[1], rho.real, "Re rho")):
        lim = float(np.percentile(np.abs(part[:, :, k]), 99)) or 1.0
        im = ax.imshow(part[:, :, k].T, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim,
                       extent=(x[0], x[-1], y[0], y[-1]))
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title(f"{name}: {label}, z = {z[k]:.3g}", fontsize=9)
    fig.tight_layout()
    with atomic_write(path, what="image") as fh:
        fig.savefig(fh, format="png")
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    """Write ``OUTPUT/report.md`` and its figures for a scene with two parts; returns 0."""
    from engine.files import check_output, check_output_folder, move_into_place, staged_path
    from engine.scene import load_scene, require_assembled
    from engine.sim.auto import complete_scene

    scene = load_scene(args.scene)
    if len(scene.parts) < 2:
        raise ValueError(f"{scene.path}: a report needs a scene with two parts")
    require_assembled(scene, "skelasm report")
    out = check_output_folder(args.output, create=True, what="report folder")
    scene, parts = complete_scene(scene)  # what the scene leaves open, chosen from the parts
    inputs = [scene.path, *(spec.file for spec in scene.parts)]
    outputs = [out / "report.md", out / "landscape_xy.png", out / "landscape_xz.png"]
    outputs += [out / f"slice_{part.name}.png" for part in parts]
    if out.is_dir():  # every file checked before the work
        for path in outputs:
            check_output(path, force=args.force, inputs=inputs, what="report file")
    out.mkdir(parents=True, exist_ok=True)
    # every file is written under a staged name and moved into place at the end: an
    # interrupted report (Ctrl+C, SIGTERM) leaves the folder as it was, not half a report
    staged: dict[Path, Path] = {path: staged_path(path) for path in outputs}
    try:
        _write_report(args, scene, parts, out, staged)
    except BaseException:
        for tmp in staged.values():
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise
    for final, tmp in staged.items():
        if tmp.exists():
            move_into_place(tmp, final)
    print(f"wrote {out / 'report.md'}")
    return 0


def _write_report(args: argparse.Namespace, scene, parts, out: Path,
                  staged: dict[Path, Path]) -> None:  # fmt: skip
    """Compute the report and write its files to their staged names."""
    import numpy as np

    from app.commands.landscape import write_section_png
    from app.commands.scale import energy_scale
    from engine.correlation import Correlator
    from engine.descriptor import descriptors_for_scene
    from engine.files import write_text
    from engine.pose import rotation_matrix

    lines = [f"# {scene.name}", "", f"Scene: `{scene.path}`, units: {scene.units}.", ""]

    lines += ["## Parts", "", "| part | file | triangles | extent | checks |",
              "|---|---|---|---|---|"]
    for spec, part in zip(scene.parts, parts, strict=False):
        extent = " x ".join(f"{e:.4g}" for e in part.extent)
        checks = "; ".join(part.warnings) or "closed, consistent"
        lines.append(
            f"| {part.name} | {spec.file.name} | {len(part.faces)} | {extent} | {checks} |"
        )

    t0 = time.perf_counter()
    descriptors = descriptors_for_scene(scene, parts=parts)
    seconds = time.perf_counter() - t0
    lines += ["", "## Descriptors", "",
              f"sigma = {scene.descriptor.sigma}, penalty = {scene.descriptor.penalty}, "
              f"one spacing h = {descriptors[0].grid.spacing:.4g} {scene.units} "
              f"({seconds:.2f} s in all, cache included).", "",
              "| part | grid | seconds | backend | from cache | slice |",
              "|---|---|---|---|---|---|"]
    for part, d in zip(parts, descriptors, strict=False):
        image = f"slice_{part.name}.png"
        _slice_png(staged[out / image], d, part.name)
        lines.append(f"| {part.name} | {'x'.join(map(str, d.grid.shape))} | {d.seconds:.2f} | "
                     f"{d.backend} | {d.from_cache} | ![{part.name}]({image}) |")

    scale = energy_scale(scene)
    u = scale.units
    corr = Correlator(descriptors[0], descriptors[1], modes=scene.modes, backend=args.backend,
                      kappa=scale.kappa)
    lines += ["", f"## Energy, force and torque (K = {scene.modes}, per-pose backend "
              f"{corr.backend_name})", "",
              f"E in {u.energy}, F in {u.force}, T in {u.torque}: {scale.describe()}. "
              "Microseconds: median of 20 warm evaluations.", "",
              "| pose | t | rotation vector | E | abs F | abs T | microseconds |",
              "|---|---|---|---|---|---|---|"]
    corr.evaluate(np.eye(3), np.zeros(3))  # warm-up (compilation, lazy tables) is not timed
    for label, pose in _poses(scene, float(np.max(parts[1].extent))):
        rot_p = rotation_matrix(pose[3:])
        ev = corr.evaluate(rot_p, pose[:3])
        micro = float(np.median([corr.evaluate(rot_p, pose[:3]).microseconds
                                 for _ in range(20)]))
        lines.append(
            f"| {label} | {np.round(pose[:3], 3).tolist()} | {np.round(pose[3:], 3).tolist()} | "
            f"{ev.energy:.5g} | {np.linalg.norm(ev.force):.4g} | "
            f"{np.linalg.norm(ev.torque):.4g} | {micro:.0f} |"
        )

    fitted = np.asarray(scene.assembled_pose, dtype=float)
    rot = rotation_matrix(fitted[3:])
    full = min(corr.size, 64)
    lines += ["", "## What the mode count costs, at the fitted pose", "",
              f"Relative to K = {full}. Microseconds: median of 200 calls.", "",
              f"| K | m' | E ({u.energy}) | error of E | microseconds |",
              "|---|---|---|---|---|"]
    corr.set_modes(full)
    reference = corr.evaluate(rot, fitted[:3]).energy
    for k in [k for k in KS if k < full] + [full]:
        corr.set_modes(k)
        times = [corr.evaluate(rot, fitted[:3]).microseconds for _ in range(200)]
        e = corr.evaluate(rot, fitted[:3]).energy
        err = abs(e - reference) / (abs(reference) or 1.0)
        lines.append(f"| {k} | {k ** 3} | {e:.5g} | {err:.2e} | {np.median(times):.0f} |")
    corr.set_modes(scene.modes)

    land = corr.landscape(rot, forces=False)
    lines += ["", "## Energy landscape through the fitted pose", ""]
    t_min, e_min = land.minimum()
    lines.append(f"Lowest energy over all {land.energy.shape[0]}^3 grid translations: "
                 f"E = {e_min:.5g} {u.energy} at t = {np.round(t_min, 3).tolist()} (fitted: "
                 f"{fitted[:3].tolist()}, one cell = {land.spacing:.3g} {scene.units}).")
    lines.append("")
    for plane, normal in (("xy", 2), ("xz", 1)):
        section, u, v = land.section(plane, float(fitted[normal]))
        axes = [a for a in range(3) if a != normal]
        image = f"landscape_{plane}.png"
        write_section_png(
            staged[out / image], section, u, v, plane,
            title=f"{scene.name}: E(t), {plane} through the fitted pose, K = {land.modes}",
            units=scene.units, fitted=fitted[axes],
            lowest=np.unravel_index(int(np.argmin(section)), section.shape),
            image_format="png",
        )
        lines.append(f"![{plane}]({image})")
    write_text(staged[out / "report.md"], "\n".join(lines) + "\n", what="report")
