"""`skelasm bench soak`: the window, its engine and a dragged proxy, for a long time.

Runs what ``skelasm gui`` runs (the window with the engine in its own process) on a scene
while the proxy is dragged along a circle through the path a mouse drag takes, for
``--minutes`` (default 15), in a child process so that a hard crash of the window (a binding
fault that frees ``None`` aborts the interpreter) is seen and reported, not taken down with
the benchmark. Once a minute it prints (on stderr) the time done and left, the child's
memory and whether it is alive; at the end the window's figures (frames received and
rendered, engine rate, evaluation cost) and the exit status. Exit 0 only if the window ran
the whole time and closed cleanly.

Not part of the test suite (it takes a quarter of an hour): run it before a release and
after changing the Qt binding or the engine transport.
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

DEFAULT_SCENE = Path(__file__).resolve().parents[1] / "assets" / "peg_in_hole" / "scene.toml"

_CHILD = """
import json, sys
from app.gui.bench_hooks import run_gui_for
result = run_gui_for(float(sys.argv[1]), sys.argv[2] or None, engine_kwargs={"process": True})
result.pop("periods", None)
with open(sys.argv[3], "w") as out:
    json.dump(result, out)
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of ``skelasm bench soak`` to ``parser``."""
    parser.add_argument("--minutes", type=float, default=15.0,
                        help="how long the window runs with a dragged proxy (default %(default)g)")
    parser.add_argument("--scene", default=str(DEFAULT_SCENE),
                        help="scene file (default: the peg-in-hole example)")
    parser.add_argument("--json", action="store_true", help="print one JSON object at the end")


def _rss_mib(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def run(args: argparse.Namespace) -> int:
    """Run the window in a child process for ``--minutes`` and report how it went.

    Prints progress once a minute on stderr and a summary at the end (JSON with ``--json``).
    Returns 0 only if the window ran the whole time and closed cleanly, else 1.
    """
    if not args.minutes > 0:
        raise ValueError(f"--minutes must be positive, got {args.minutes}")
    scene = Path(args.scene)
    if not scene.is_file():
        raise FileNotFoundError(f"{scene}: no such scene file")
    seconds = 60.0 * args.minutes
    with tempfile.TemporaryDirectory(prefix="skelasm-soak-") as tmp:
        out = Path(tmp) / "result.json"
        log = Path(tmp) / "child.log"
        t0 = time.monotonic()
        with open(log, "w") as err:
            child = subprocess.Popen([sys.executable, "-c", _CHILD, str(seconds), str(scene),
                                      str(out)], stdout=err, stderr=subprocess.STDOUT,
                                     env=dict(os.environ))
            # the engine's preparation comes before the measured time: allow for it
            limit = seconds + 900.0
            next_report = 60.0
            while child.poll() is None and time.monotonic() - t0 < limit:
                time.sleep(1.0)
                elapsed = time.monotonic() - t0
                if elapsed >= next_report:
                    print(f"soak: {elapsed / 60:5.1f} min, about "
                          f"{max(0.0, seconds - elapsed) / 60:4.1f} min left; window alive, "
                          f"{_rss_mib(child.pid):.0f} MiB", file=sys.stderr, flush=True)
                    next_report += 60.0
            if child.poll() is None:
                child.kill()
                child.wait()
        elapsed = time.monotonic() - t0
        text = log.read_text(errors="replace")
        result = json.loads(out.read_text()) if out.exists() else None
    ok = child.returncode == 0 and result is not None and result.get("guidance_ready")
    summary = {
        "ok": bool(ok),
        "exit_status": child.returncode,
        "wall_minutes": elapsed / 60.0,
        "measured_minutes": (result or {}).get("seconds", 0.0) / 60.0,
        "window": result,
        "problems": [line for line in text.splitlines()
                     if "Fatal" in line or "Traceback" in line or "Error" in line][:20],
    }
    if args.json:
        print(json.dumps(summary, indent=1))
    else:
        print(f"soak of {scene}: {'clean' if ok else 'FAILED'} "
              f"(exit status {child.returncode}, {elapsed / 60:.1f} min wall)")
        if result:
            print(f"  measured {result['seconds'] / 60:.1f} min: "
                  f"{result['frames_received']} engine frames received, "
                  f"{result['frames_rendered']} renders ({result['fps']:.1f} fps), "
                  f"engine {result['engine_rate_hz']:.0f} Hz (p99 period "
                  f"{result['engine_p99_us']:.0f} us), {result['eval_us']:.0f} us per "
                  f"evaluation, event loop late p99 {result['latency_ms_p99']:.1f} ms")
        for line in summary["problems"]:
            print(f"  {line}")
        if not ok and not result:
            print(text[-3000:])
    return 0 if ok else 1
