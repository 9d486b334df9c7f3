"""`skelasm landscape SCENE --plane xy --offset Z -o OUT.png`: a section of E(t)."""

from __future__ import annotations

import argparse

from app.commands.arguments import add_band_argument, check_rotation_vector, finite_float


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm landscape`` (an image of the translational energy landscape) to ``sub``."""
    parser = sub.add_parser(
        "landscape",
        help="image of the translational energy landscape in one plane",
        description="Energy over all translations of part 2 for one fixed rotation (one "
        "inverse FFT), cut by a plane and written as an image with the fitted pose marked.",
    )
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument("--plane", default="xy", choices=("xy", "xz", "yz"),
                        help="translation plane of the section")
    parser.add_argument("--offset", type=finite_float, default=None,
                        help="translation along the plane's normal (default: the fitted pose's)")
    parser.add_argument("--rotation", nargs=3, type=finite_float, metavar=("RX", "RY", "RZ"),
                        help="rotation vector of part 2 (radians); default: the fitted pose's")
    parser.add_argument("--modes", type=int, help="modes per axis K (default: the scene's)")
    add_band_argument(parser)
    parser.add_argument("-o", "--output", required=True, help="image file to write (PNG)")
    parser.add_argument("--force", action="store_true",
                        help="replace an existing image (never an input file)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Compute the landscape at the rotation asked for and write its section as an image.

    Returns the exit status.
    """
    import numpy as np

    from app.commands.evaluate import progress_bar
    from app.commands.scale import energy_scale
    from engine.correlation import correlator_for_scene
    from engine.params import GUIDANCE_BAND
    from engine.pose import rotation_matrix
    from engine.scene import load_scene, require_assembled
    from engine.sim.auto import complete_scene

    if args.modes is not None:  # the options first: a bad one costs nothing
        from engine.params import check_modes

        check_modes(args.modes, "--modes")
    if args.rotation is not None:
        check_rotation_vector(args.rotation, "--rotation")
    check_image_output(args.output, force=args.force, inputs=[args.scene])  # parts: below
    scene = load_scene(args.scene)
    require_assembled(scene, "skelasm landscape")
    scene, _ = complete_scene(scene)  # what it leaves open, from the parts
    check_image_output(args.output, force=args.force,
                       inputs=[scene.path, *(spec.file for spec in scene.parts)])
    fitted = np.asarray(scene.assembled_pose, dtype=float)
    rotvec = np.asarray(args.rotation if args.rotation is not None else fitted[3:], dtype=float)
    scale = energy_scale(scene)
    energy_unit = scale.units.energy
    update, close = progress_bar("landscape")
    try:
        corr = correlator_for_scene(
            scene, modes=args.modes, backend="numpy", kappa=scale.kappa,
            band=args.band or GUIDANCE_BAND,
            progress=None if update is None else (lambda f: update(0.8 * f)))
        land = corr.landscape(rotation_matrix(rotvec), forces=False,
                              progress=None if update is None else (
                                  lambda f: update(0.8 + 0.2 * f)))
    finally:
        close()
    normal = {"xy": 2, "xz": 1, "yz": 0}[args.plane]
    offset = float(args.offset) if args.offset is not None else float(fitted[normal])
    section, u, v = land.section(args.plane, offset)
    axes = [a for a in range(3) if a != normal]
    write_section_png(
        args.output, section, u, v, args.plane,
        title=f"{scene.name}: E(t), {args.plane} at {'xyz'[normal]} = {offset:g} {scene.units}, "
        f"K = {land.modes}, {corr.params.band} band\nE in {energy_unit}, "
        f"kappa = {scale.kappa:.4g} {scale.units.kappa}",
        units=scene.units,
        fitted=fitted[axes],
        lowest=np.unravel_index(int(np.argmin(section)), section.shape),
    )
    t_min, e_min = land.minimum()
    fit_energy = land.lookup(fitted[:3]).energy
    print(f"landscape  {land.energy.shape[0]}^3 translations in {land.seconds:.2f} s "
          f"(FFT size {corr.size}, K = {land.modes})")
    print(f"section    min {section.min():.5g}, max {section.max():.5g} {energy_unit}")
    print(f"fitted     t = {fitted[:3].tolist()}: E = {fit_energy:.5g} {energy_unit}")
    print(f"minimum    t = {np.round(t_min, 4).tolist()}: E = {e_min:.5g} {energy_unit} "
          "(whole landscape)")
    print(f"scale      {scale.describe()}")
    print(f"wrote      {args.output}")
    return 0


def check_image_output(path, *, force: bool, inputs) -> None:
    """Check an image's path before the work: writable, not an input, a format matplotlib has."""
    from pathlib import Path

    from matplotlib.backend_bases import FigureCanvasBase

    from engine.errors import InputError
    from engine.files import check_output

    suffix = Path(path).suffix.lstrip(".").lower()
    formats = FigureCanvasBase.get_supported_filetypes()
    if suffix not in formats:
        raise InputError(f"{path}: cannot write images of type {suffix or '(none)'!r}; end "
                         f"the name with one of .{', .'.join(sorted(formats))}")
    check_output(path, force=force, inputs=inputs, what="image")


def write_section_png(path, section, u, v, plane, *, title, units, fitted, lowest,
                      image_format: str | None = None) -> None:  # fmt: skip
    """Write a section image with the fitted pose (cross) and the section's minimum (circle).

    The image is written whole or not at all (``engine.files.atomic_write``); its format
    is ``image_format``, by default the file's suffix.
    """
    from pathlib import Path

    import matplotlib

    from engine.files import atomic_write

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(6.4, 5.2), dpi=110)
    lim = float(np.max(np.abs(section))) or 1.0
    image = ax.imshow(
        section.T, origin="lower", extent=(u[0], u[-1], v[0], v[-1]), cmap="RdBu_r",
        vmin=-lim, vmax=lim, aspect="equal",
    )
    fig.colorbar(image, ax=ax, label="energy E")
    ax.plot(fitted[0], fitted[1], marker="x", color="k", markersize=11, mew=2.5,
            label="fitted pose", linestyle="none")
    ax.plot(u[lowest[0]], v[lowest[1]], marker="o", mfc="none", color="lime", markersize=11,
            mew=2, label="lowest in section", linestyle="none")
    ax.set_xlabel(f"t{plane[0]} ({units})")
    ax.set_ylabel(f"t{plane[1]} ({units})")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    with atomic_write(path, what="image") as fh:
        fig.savefig(fh, format=image_format or Path(path).suffix.lstrip(".").lower() or "png")
    plt.close(fig)
