"""`skelasm warm`: compile the engine's kernels once, so that the first start is quick."""

from __future__ import annotations

import argparse
import sys
import time

from app.gui.app import DEFAULT_SCENE  # the bundled example (standard library imports only)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm warm`` to ``sub``."""
    parser = sub.add_parser(
        "warm",
        help="compile the engine's kernels (once after installing: the first start is quick)",
        description="Run the engine's start on a scene at a coarse grid so that its kernels "
        "are compiled and cached (numba beside the installed modules, OpenCL by the driver): "
        "on a fresh install the window's first start otherwise compiles them, half a minute "
        "or more on 2 cores before the part can be dragged. Leaves no descriptors behind.",
    )
    parser.add_argument("scene", nargs="?", default=str(DEFAULT_SCENE),
                        help="scene file (default: the bundled peg in hole)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Warm the kernels, saying each stage and its seconds."""
    from engine.runtime.warm import warm_kernels

    t0 = time.perf_counter()

    def say(stage: str) -> None:
        print(f"skelasm warm: {stage} ({time.perf_counter() - t0:.0f} s so far)",
              file=sys.stderr, flush=True)

    stages = warm_kernels(args.scene, progress=say)
    print(f"kernels compiled and cached in {time.perf_counter() - t0:.1f} s: "
          + ", ".join(f"{name} {seconds:.1f} s" for name, seconds in stages))
    return 0
