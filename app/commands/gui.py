"""`skelasm gui [SCENE]`: the desktop application (PySide6 + pyvistaqt).

Qt is imported only inside :func:`run`, so the rest of the command line works without it.
"""

from __future__ import annotations

import argparse

from app.commands.arguments import finite_float
from app.gui import SCREENSHOT_AFTER


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Add ``skelasm gui`` (the desktop application) to ``sub``."""
    parser = sub.add_parser(
        "gui",
        help="open the desktop application (drag parts, watch forces, tune parameters)",
        description="Open the desktop application on a scene (default: the peg-in-hole "
        "example). On a Linux machine without a screen it starts a private virtual one "
        "(Xvfb) and says so; use --screenshot to see the window.",
    )
    parser.add_argument("scene", nargs="?", default=None,
                        help="scene (.toml) or part file (STEP, STL, OBJ, PLY, OFF)")
    parser.add_argument("--screenshot", metavar="OUT.png", default=None,
                        help="save a picture of the whole window (after --quit-after seconds, "
                        f"default {SCREENSHOT_AFTER:g}) and quit")
    parser.add_argument("--quit-after", metavar="SECONDS", type=finite_float, default=None,
                        help="quit after this many seconds")
    parser.add_argument("--engine", choices=("process", "thread"), default="process",
                        help="where the engine loop runs: its own process (default; VTK holds "
                        "the GIL while it renders, which slows a thread engine beside the "
                        "window: `skelasm bench loop --gui` measures both, figures in "
                        "docs/runtime.md) or a thread of the window's process")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Open the window on the scene asked for; returns its exit status.

    Raises RuntimeError naming the packages to install when the GUI's dependencies are
    missing.
    """
    if args.quit_after is not None and args.quit_after < 0:
        raise ValueError(f"--quit-after must be zero or positive, got {args.quit_after}")
    try:
        from app.gui.app import run as run_gui
    except ImportError as exc:
        raise _missing_gui(exc) from exc
    try:
        return run_gui(args.scene, screenshot=args.screenshot, quit_after=args.quit_after,
                       engine_process=args.engine == "process")
    except ModuleNotFoundError as exc:  # the window imports Qt and VTK only when it opens
        if (exc.name or "").split(".")[0] not in GUI_MODULES:
            raise
        raise _missing_gui(exc) from exc


#: Top-level modules the ``gui`` extra brings (PySide6, pyvista, pyvistaqt and VTK).
GUI_MODULES = ("PySide6", "shiboken6", "pyvista", "pyvistaqt", "vtk", "vtkmodules", "qtpy")


def _missing_gui(exc: ImportError) -> RuntimeError:
    return RuntimeError(
        f"the window needs the `gui` extra (PySide6, pyvista, pyvistaqt), and "
        f"{exc.name or exc} is not installed; install it with: pip install 'skelasm[gui]' "
        "(or, from a clone: pip install -e '.[gui]'); the other commands work without it")
