"""A screen for Qt and VTK: the user's, or a private virtual one (Xvfb) on a headless Linux box.

No Qt here: this runs before Qt is imported, because Qt reads ``DISPLAY`` when it starts.
"""

from __future__ import annotations

import atexit
import ctypes
import os
import shutil
import signal
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
    exits, and on Linux also when it is killed (the kernel sends Xvfb SIGTERM when its
    parent dies, ``PR_SET_PDEATHSIG``), so a crashed or killed window leaves no server.
    """
    exe = shutil.which("Xvfb")
    if exe is None:
        return None
    r, w = os.pipe()
    proc = subprocess.Popen(
        [exe, "-displayfd", str(w), "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp"],
        pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
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


_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the forked child before exec: die with the parent, and leave its process group.

    Asks the kernel for SIGTERM when the parent dies, and leaves the terminal's process
    group, so that Ctrl+C reaches the window (which then closes cleanly and stops this server)
    rather than killing the screen under it.
    """
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)
    os.setpgid(0, 0)


def ensure_screen(program: str) -> str | None:
    """None when Qt and VTK can open windows, starting a private Xvfb if needed; else why not.

    Starting Xvfb is announced on stderr, naming ``program``.
    """
    if has_screen():
        return None
    display = start_virtual_screen()
    if display is None:
        return ("no screen: DISPLAY is not set and Xvfb is not installed. Run on a desktop, "
                "or install a virtual screen (apt-get install xvfb; skelasm starts it by "
                "itself) and add --screenshot OUT.png to see the window")
    print(f"{program}: no screen found; running on a virtual screen (Xvfb {display}). "
          "Use --screenshot OUT.png --quit-after SECONDS to see the window.", file=sys.stderr)
    return None


def stop_virtual_screens() -> None:
    """Stop every Xvfb this process started."""
    while _servers:
        proc = _servers.pop()
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
