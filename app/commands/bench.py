"""`skelasm bench WHAT`: measured tables and plots (descriptor, correlation, loop).

Each benchmark lives in the top-level ``bench`` package as a module with
``add_arguments(parser)`` and ``run(args)``.
"""

from __future__ import annotations

import argparse
import importlib

BENCHMARKS = {
    "descriptor": "seconds per part to compute descriptors, per backend, and the error",
    "correlation": "microseconds per 6-DOF evaluation against accuracy, per mode count",
    "loop": "achieved engine rate and period distribution, headless or with the GUI",
    "soak": "the window with its engine and a dragged proxy for minutes",
    "seating": "real CAD pairs pushed misaimed: final errors, guided and collision-only",
    "accuracy": "error against time for every accuracy dial (K, grid, sigma, quadrature, "
                "interpolation, backend)",
    "search": "the fit search on pairs with a known fit: seconds, rank of the true fit, "
              "errors, joint kind",
    "loading": "seconds and peak memory to load STL meshes of 1e4 to 1e6 triangles with "
               "fans and doubled faces",
    "tuning": "seconds from a new sigma or penalty to the running engine using it",
    "launch": "seconds from `skelasm gui` to a part that can be dragged, in a fresh cache",
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm bench BENCHMARK`` with one subcommand per benchmark of :data:`BENCHMARKS`.

    A benchmark whose module cannot be imported (an optional dependency missing) still gets
    its subcommand, which then says what is missing.
    """
    parser = sub.add_parser("bench", help="run a benchmark, print its table, write its plot")
    which = parser.add_subparsers(dest="benchmark", metavar="BENCHMARK")
    which.required = True
    for name, text in BENCHMARKS.items():
        p = which.add_parser(name, help=text)
        try:
            module = importlib.import_module(f"bench.{name}")
        except ImportError:
            p.set_defaults(run=_missing(name))
            continue
        module.add_arguments(p)
        p.set_defaults(run=module.run)


def _missing(name: str):
    def run(args: argparse.Namespace) -> int:
        raise RuntimeError(f"the {name} benchmark is not available in this installation")

    return run
