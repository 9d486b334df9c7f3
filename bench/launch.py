"""`skelasm bench launch`: seconds from ``skelasm gui`` to a part that can be dragged.

Runs the window as ``skelasm gui`` does (engine in its own process unless ``--thread``), in a
fresh process and a fresh descriptor cache (nothing of the scene cached, as on a first
launch), and records from the process's start: the window shown, the scene opened, the first
field in use (the part can be dragged: a coarse first field where the scene's grid is not
cached), the scene's own descriptors in use. Without a screen a private Xvfb is started.

Whether the kernels are compiled is the installation's state, not the benchmark's: on a fresh
install run it before and after ``skelasm warm`` (or delete numba's ``*.nbi``/``*.nbc`` files
under ``engine/`` and PoCL's cache to see a first launch again). Prints a table and writes a
plot (``-o``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ASSETS = Path(__file__).resolve().parents[1] / "assets"

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
marks = {}
from app.gui.app import check_display, make_application
problem = check_display()
if problem:
    raise SystemExit(problem)
from PySide6 import QtCore
app = make_application()
from app.gui.main_window import MainWindow
from engine import runtime
win = MainWindow(engine_kwargs={"process": sys.argv[2] == "process"})
win.show()
app.processEvents()
marks["window shown"] = time.perf_counter() - t0
win.open_path(sys.argv[1], wait=True)
marks["scene opened"] = time.perf_counter() - t0
end = time.monotonic() + float(sys.argv[3])
while time.monotonic() < end and "scene's descriptors in use" not in marks:
    app.processEvents(QtCore.QEventLoop.AllEvents, 20)
    if win.guidance_ready and "part draggable on a field" not in marks:
        marks["part draggable on a field"] = time.perf_counter() - t0
    if (win.guidance_ready and win.tasks.get("descriptors") is None
            and win.tasks.get("correlator") is None):
        marks["scene's descriptors in use"] = time.perf_counter() - t0
    time.sleep(0.005)
print(json.dumps({"marks": marks, "error": win.guidance_error or win.last_error}))
win.close()
app.processEvents()
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench launch`` to ``parser``."""
    parser.add_argument("scene", nargs="?", default=str(ASSETS / "peg_in_hole" / "scene.toml"),
                        help="scene file (default: the bundled peg in hole)")
    parser.add_argument("--thread", action="store_true",
                        help="the engine in a thread of the window's process")
    parser.add_argument("--limit", type=float, default=600.0,
                        help="give up after this many seconds (600)")
    parser.add_argument("-o", "--output", default="launch_bench.png", help="PNG plot")


def run(args: argparse.Namespace) -> int:
    """Launch the window once in a fresh cache, print when each stage was reached."""
    with tempfile.TemporaryDirectory(prefix="skelasm-launch-") as tmp:
        env = dict(os.environ, SKELASM_CACHE=tmp)
        started = time.perf_counter()
        out = subprocess.run(
            [sys.executable, "-c", _CHILD, str(args.scene),
             "thread" if args.thread else "process", str(args.limit)],
            capture_output=True, text=True, env=env, timeout=args.limit + 120)
        wall = time.perf_counter() - started
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode != 0 or not lines:
        print(out.stderr[-3000:], file=sys.stderr)
        raise RuntimeError(f"the window did not report (exit status {out.returncode})")
    result = json.loads(lines[-1])
    print(f"scene {args.scene}; engine in {'a thread' if args.thread else 'its own process'}; "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; process wall "
          f"{wall:.1f} s")
    print("| stage | seconds from the process's start |")
    print("|---|---|")
    for stage, seconds in result["marks"].items():
        print(f"| {stage} | {seconds:.1f} |")
    if result.get("error"):
        print(f"error: {result['error']}")
    _plot(result["marks"], args.output)
    print(f"plot written to {args.output}")
    return 0 if "part draggable on a field" in result["marks"] else 1


def _plot(marks: dict[str, float], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 2.6))
    names = list(marks)
    ax.barh(names, [marks[n] for n in names], color="#3182bd")
    ax.axvline(30.0, color="#c0392b", ls="--", lw=1, label="30 s")
    ax.invert_yaxis()
    ax.set_xlabel("seconds from the process's start")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
