"""`skelasm precompute PART`: a part's skeletal density on a grid, written to an .npz file.

PART is a part file (STEP, STL, OBJ, PLY, OFF) or a scene file (``.toml``). For a part file
the output (default ``./<stem>.npz`` in the current directory, or ``./<stem>-<body>.npz``
with ``--body``) holds ``rho`` (complex64, nx x ny x nz), ``origin`` (where grid index
(0, 0, 0) lies in the part's frame), ``spacing``, ``shape`` and the parameters. A STEP file
with several solids needs ``--body NAME`` (the error lists the names): one body per run.
For a scene file every part is computed with the scene's shared spacing (options override
the scene's ``[descriptor]`` values) into the cache the GUI and ``skelasm simulate`` read;
only with ``-o DIR`` is one ``<scene>-<part>.npz`` per part written there too.

Results are cached (see ``engine.descriptor.store``): a second run with the same inputs only
loads.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from app.commands.arguments import int_in_range
from engine.backend import choices, describe_auto
from engine.loading import DEFAULT_RELATIVE_TOLERANCE
from engine.params import DEFAULT_GRID, DescriptorParams


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (value > 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (0 <= value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {text}")
    return value


def _grid_samples(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    from engine.params import MAX_GRID

    if not 4 <= value <= MAX_GRID:  # the range DescriptorParams holds a scene's grid to
        raise argparse.ArgumentTypeError(f"must be an integer from 4 to {MAX_GRID}, got "
                                         f"{value}: fewer than 4 samples resolve nothing, "
                                         f"{MAX_GRID}^3 take 64 GiB per part")
    return value


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm precompute`` (a part's or a scene's descriptors to .npz) to ``sub``."""
    parser = sub.add_parser(
        "precompute",
        help="compute a part's skeletal density descriptor and write it to an .npz file",
        description="Compute the skeletal density descriptor of a part (STEP, STL, OBJ, PLY, "
        "OFF) on a regular grid in the part's own frame and write it as .npz (rho, origin, "
        "spacing, shape, sigma, penalty, lambda_out). Given a scene file (.toml), compute "
        "both of its parts with the scene's shared spacing into the cache (the window and "
        "simulate read it), and with -o DIR also write them there. Results are cached: the "
        "same inputs load in well under a second the next time.",
    )
    parser.add_argument("part", metavar="PART", nargs="+",
                        help="part file, or a scene file (.toml); several part files: a "
                        "parts library, each part into the cache (or -o FOLDER), resumable")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--grid", type=_grid_samples, metavar="N",
                      help="samples along the part's longest side, padding not included "
                      f"(default {DEFAULT_GRID}; for a scene: its [descriptor] grid)")
    size.add_argument("--spacing", type=_positive_float, metavar="H",
                      help="grid spacing in the part's unit, instead of --grid")
    parser.add_argument("--sigma", type=_positive_float, metavar="S",
                        help=f"Gaussian width on eta/|xi| - 1 (default {DescriptorParams.sigma:g})")
    parser.add_argument("--penalty", type=_positive_float, metavar="P",
                        help="penalty factor lambda_in / lambda_out "
                        f"(default {DescriptorParams.penalty:g})")
    parser.add_argument("--lambda-out", type=_positive_float, metavar="L",
                        help=f"weight outside the part (default {DescriptorParams.lambda_out:g})")
    parser.add_argument("--padding", type=_non_negative_float, metavar="C",
                        help="free cells around the part on each side "
                        f"(default {DescriptorParams.padding:g})")
    parser.add_argument("--tolerance", type=_positive_float, metavar="T",
                        help="STEP tessellation tolerance in the file's unit (default: the "
                        "part's bounding-box diagonal / "
                        f"{1 / DEFAULT_RELATIVE_TOLERANCE:g})")
    parser.add_argument("--body", metavar="NAME",
                        help="which solid of a multi-body STEP file")
    parser.add_argument("--backend", choices=choices("descriptor"),
                        help="compute backend (default: SKELASM_BACKEND, else auto: "
                        f"{describe_auto('descriptor')}, where its kernel builds)")
    parser.add_argument("--device", metavar="D",
                        help="OpenCL device: part of its name, or PLATFORM:DEVICE indices")
    parser.add_argument("--method", choices=("adaptive", "tree", "brute"), default="adaptive",
                        help="hierarchy with adaptive sampling (default: exact where the "
                        "field is rough, interpolated elsewhere), hierarchy at every point, "
                        "or every triangle (the reference)")
    parser.add_argument("--no-cache", action="store_true",
                        help="compute even if cached, and store nothing in the cache")
    parser.add_argument("-o", "--output", metavar="OUT",
                        help="output .npz (default: ./<stem>.npz in the current directory); "
                        "for a scene, a folder to write <scene>-<part>.npz into (default: "
                        "none, the cache only)")
    parser.add_argument("--force", action="store_true",
                        help="replace existing output files (never an input file)")
    parser.add_argument("--workers", type=int_in_range(1, 1024), metavar="N",
                        help="several parts: compute them on a local Dask cluster of N "
                        "processes, a task per part (default: one after another here)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="several parts: on the Dask scheduler at ADDRESS "
                        "(tcp://host:8786), a task per part")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object (grid, spacing, triangles, seconds, "
                        "backend, output, ...) instead of text")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Compute the descriptors of a scene's parts (a .toml path) or of one part file.

    Returns the exit status.
    """
    from engine.errors import InputError

    if args.workers is not None and args.scheduler is not None:
        raise InputError("--workers and --scheduler: give one (a local cluster, or an address)")
    if len(args.part) > 1:
        from app.commands.library import run_library

        return run_library(args, [Path(p) for p in args.part], _params(args))
    if args.workers is not None or args.scheduler is not None:
        raise InputError("--workers and --scheduler share out several parts: give two or "
                         "more part files")
    path = Path(args.part[0])
    if path.suffix.lower() == ".toml":
        return _run_scene(args, path)
    return _run_part(args, path)


def _backend(args: argparse.Namespace):
    """A backend name for lazy creation (only on a cache miss), or the Backend for --device."""
    if args.device is None:
        return args.backend
    from engine.descriptor.compute import resolve_backend

    # a device names an OpenCL device: the registry's choice on it (one rule for "auto")
    return resolve_backend(args.backend or "opencl", device=args.device)


def _progress(args: argparse.Namespace, label: str):
    """A tqdm bar on stderr when stdout is a terminal (and no --json); else nothing."""
    if args.json or not sys.stdout.isatty():
        return None, lambda: None
    from tqdm import tqdm

    bar = tqdm(total=1000, desc=label, unit="", file=sys.stderr, leave=False,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")

    def update(fraction: float) -> None:
        bar.n = int(round(1000 * min(max(fraction, 0.0), 1.0)))
        bar.refresh()

    return update, bar.close


def _params(args: argparse.Namespace, base=None):
    from dataclasses import replace

    from engine.descriptor.compute import check_grid_sigma
    from engine.params import DescriptorParams

    base = base or DescriptorParams()
    params = replace(
        base,
        sigma=args.sigma if args.sigma is not None else base.sigma,
        penalty=args.penalty if args.penalty is not None else base.penalty,
        lambda_out=args.lambda_out if args.lambda_out is not None else base.lambda_out,
    )
    check_grid_sigma(params.sigma)  # before the computation: a grid at this sigma takes hours
    return params


def _samples_padding(args: argparse.Namespace) -> tuple[int | None, float]:
    """(samples along the longest side, or None for ``--spacing``; padding cells) of a part."""
    from engine.params import DEFAULT_PADDING

    samples = None if args.spacing is not None else (args.grid or DEFAULT_GRID)
    return samples, DEFAULT_PADDING if args.padding is None else args.padding


def _output_folder(args: argparse.Namespace, what: str) -> Path | None:
    """The ``-o`` folder of a scene or a library (None: the cache only), checked."""
    from engine.errors import InputError

    folder = Path(args.output) if args.output else None
    if folder is None and args.no_cache:
        raise InputError("--no-cache without -o would keep nothing: add -o FOLDER to write "
                         "the descriptors there, or drop --no-cache to fill the cache")
    if folder is not None and not folder.is_dir():
        raise InputError(f"{folder}: no such folder ({what}, -o names a folder)")
    return folder


def _record(descriptor, part, output: Path | None, samples) -> dict:
    g = descriptor.grid
    return {
        "part": part.source,
        "name": part.name,
        "unit": part.unit,
        "grid": list(g.shape),
        "samples": samples,
        "spacing": g.spacing,
        "origin": list(g.origin),
        "triangles": descriptor.triangles,
        "seconds": round(descriptor.seconds, 4),
        "compute_seconds": None if descriptor.compute_seconds != descriptor.compute_seconds
        else round(descriptor.compute_seconds, 4),
        "from_cache": descriptor.from_cache,
        "backend": descriptor.backend,
        "method": descriptor.method,
        "sigma": descriptor.params.sigma,
        "penalty": descriptor.params.penalty,
        "lambda_out": descriptor.params.lambda_out,
        "output": None if output is None else str(output.resolve()),
        "warnings": list(part.warnings),
    }


def _describe(rec: dict) -> str:
    nx, ny, nz = rec["grid"]
    how = "from the cache" if rec["from_cache"] else f"computed on {rec['backend']}"
    unit = "" if rec["unit"] == "unspecified" else f" {rec['unit']}"
    return (f"{rec['name']}: {rec['triangles']} triangles, grid {nx} x {ny} x {nz} "
            f"(h = {rec['spacing']:.4g}{unit}), {rec['seconds']:.2f} s {how} -> "
            f"{rec['output'] or 'the cache'}")


def _run_part(args: argparse.Namespace, path: Path) -> int:
    from engine.descriptor import descriptor_for_part, grid_for_part
    from engine.errors import InputError
    from engine.files import check_output
    from engine.loading import load_part

    stem = path.stem if args.body is None else f"{path.stem}-{args.body}"
    if args.output and Path(args.output).is_dir():
        output = Path(args.output) / f"{stem}.npz"  # a folder: the default name inside it
    elif args.output:
        output = Path(args.output)
        if output.suffix != ".npz":  # never a name the user did not write
            raise InputError(f"{output}: a descriptor file ends in .npz; give -o a name "
                             f"such as {output.with_suffix('.npz').name}, or a folder")
    else:
        output = Path.cwd() / f"{stem}.npz"
    check_output(output, force=args.force, inputs=[path], what="descriptor")
    part = load_part(path, tolerance=args.tolerance, body=args.body)
    samples, padding = _samples_padding(args)
    grid = grid_for_part(part, samples=samples, spacing=args.spacing, padding=padding)
    if not args.json:
        for line in part.warnings:
            print(f"warning: {line}", file=sys.stderr)
    update, close = _progress(args, part.name)
    try:
        descriptor = descriptor_for_part(part, grid, _params(args), backend=_backend(args),
                                         method=args.method, use_cache=not args.no_cache,
                                         progress=update)
    finally:
        close()
    written = descriptor.save(output)
    rec = _record(descriptor, part, written, samples)
    rec["padding"] = padding
    if args.json:
        print(json.dumps(rec))
    else:
        print(_describe(rec))
    return 0


def _run_scene(args: argparse.Namespace, path: Path) -> int:
    from dataclasses import replace

    from engine.descriptor import descriptors_for_scene, scene_spacing
    from engine.files import check_output
    from engine.scene import load_scene, load_scene_parts, require_assembled
    from engine.sim.auto import complete_scene

    if args.body is not None or args.tolerance is not None:
        raise ValueError("--body and --tolerance apply to part files; a scene sets them per "
                         "[[part]] (body = ..., tolerance = ...)")
    scene = load_scene(path)
    require_assembled(scene, "skelasm precompute (its settings are chosen at the fit)")
    scene, _ = complete_scene(scene)  # what it leaves open, chosen from the parts
    d = scene.descriptor
    if args.grid is not None:
        d = replace(d, grid=args.grid, spacing=None)
    if args.spacing is not None:
        d = replace(d, grid=None, spacing=args.spacing)
    d = _params(args, d)
    if args.padding is not None:
        d = replace(d, padding=args.padding)
    scene = replace(scene, descriptor=d)
    # without -o the scene's descriptors only fill the cache: nothing in the current folder
    folder = _output_folder(args, "for a scene")
    parts = load_scene_parts(scene)
    stem = scene.path.parent.name if scene.path.name == "scene.toml" else scene.path.stem
    inputs = [scene.path, *(spec.file for spec in scene.parts)]
    for part in parts if folder is not None else ():  # every output checked before the work
        check_output(folder / f"{stem}-{part.name}.npz", force=args.force, inputs=inputs,
                     what="descriptor")
    if not args.json:
        for part in parts:
            for line in part.warnings:
                print(f"warning: {line}", file=sys.stderr)
    update, close = _progress(args, scene.name)
    try:
        descriptors = descriptors_for_scene(scene, parts=parts, backend=_backend(args),
                                            method=args.method, use_cache=not args.no_cache,
                                            progress=update)
    finally:
        close()
    records = []
    for part, descriptor in zip(parts, descriptors, strict=True):
        written = (descriptor.save(folder / f"{stem}-{part.name}.npz") if folder is not None
                   else None)
        records.append(_record(descriptor, part, written, d.grid))
    if args.json:
        print(json.dumps({
            "scene": str(scene.path),
            "spacing": scene_spacing(scene, parts),
            "padding": d.padding,
            "seconds": round(sum(r["seconds"] for r in records), 4),
            "parts": records,
        }))
    else:
        for rec in records:
            print(_describe(rec))
    return 0
