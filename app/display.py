"""A screen for Qt and VTK: the user's, or a private virtual one (Xvfb) on a headless Linux box.

No Qt here: this runs before Qt is imported, because Qt reads ``DISPLAY`` when it starts.
"""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import sys

_servers: list[subprocess.Popen] = []


def has_screen() -> bool:
    """Whether a display is there (always true off Linux, where Qt talks to the OS directly)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or (
        os.environ.get("QT_QPA_PLATFORM", "").split(":")[0] in ("offscreen", "minimal", "vnc")
    )


def start_virtual_screen(width: int = 1920, height: int = 1080) -> str | None:
    """Start Xvfb on a free display number, set ``DISPLAY``, and return it (``":N"``).

    None when Xvfb is not installed or does not start. The server stops when this process
    exits.
    """
    exe = shutil.which("Xvfb")
    if exe is None:
        return None
    r, w = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(w), "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp"],
        pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    if not number or proc.poll() is not None:
        proc.kill()
        return None
    _servers.append(proc)
    atexit.register(stop_virtual_screens)
    display = f":{number}"
    os.environ["DISPLAY"] = display
    return display


def stop_virtual_screens() -> None:
    """Stop every Xvfb this process started."""
    while _servers:
        proc = _servers.pop()
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
