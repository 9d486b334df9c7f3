"""`skelasm gui` leaves nothing behind: Ctrl+C quits at once and cleanly, and a killed window
takes its engine process and its private virtual screen with it.

Each test starts the real command in a new session (as a terminal would start it in its own
process group), so the processes it leaves can be found by session id in /proc.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"),
                                reason="reads /proc and uses Linux's parent-death signal")

START_TIMEOUT = 180.0  # seconds for the window and its engine process to come up (busy CI)
EXIT_TIMEOUT = 20.0


def session_processes(sid: int) -> dict[int, str]:
    """Map pid -> command name of every live (not zombie) process in session ``sid``."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        name = stat[stat.index("(") + 1:stat.rindex(")")]
        fields = stat[stat.rindex(")") + 2:].split()
        state, session = fields[0], int(fields[3])
        if session == sid and state != "Z":
            found[int(entry.name)] = name
    return found


def wait_for(predicate, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.2)
    return predicate()


@pytest.fixture
def gui(small_scene, tmp_path):
    """Start `skelasm gui SCENE` on its own virtual screen; yield the Popen once the engine
    process and Xvfb run beside it.
    """
    env = dict(os.environ, XDG_CONFIG_HOME=str(tmp_path / "config"),
               SKELASM_CACHE=os.environ.get("SKELASM_CACHE", str(tmp_path / "cache")))
    env.pop("DISPLAY", None)  # skelasm starts its own Xvfb, as on a headless machine
    env.pop("QT_QPA_PLATFORM", None)
    proc = subprocess.Popen([sys.executable, "-m", "app", "gui", str(small_scene)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    def engine_and_screen_up() -> bool:
        # Xvfb and the engine process (a Python child of the window's own process; other
        # short-lived children, such as an OpenCL compiler's, do not count)
        others = {pid: name for pid, name in session_processes(proc.pid).items()
                  if pid != proc.pid}
        return ("Xvfb" in others.values()
                and any(name.startswith("python") for name in others.values()))

    up = wait_for(lambda: engine_and_screen_up() or proc.poll() is not None, START_TIMEOUT)
    if proc.poll() is not None or not up:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"skelasm gui did not come up (exit {proc.returncode}): {err[-2000:]}")
    time.sleep(3.0)  # into the event loop, the engine stepping
    yield proc
    if proc.poll() is None:
        proc.kill()
    proc.communicate()  # reap it and close its pipes
    for pid in session_processes(proc.pid):
        os.kill(pid, signal.SIGKILL)


def test_ctrl_c_quits_at_once_without_traceback(gui):
    os.killpg(gui.pid, signal.SIGINT)  # what a terminal's Ctrl+C does: the whole group
    try:
        out, err = gui.communicate(timeout=EXIT_TIMEOUT)
    except subprocess.TimeoutExpired:
        gui.kill()
        out, err = gui.communicate()
        pytest.fail(f"one Ctrl+C did not quit within {EXIT_TIMEOUT} s: {err[-2000:]}")
    assert gui.returncode == 130, err
    assert "Traceback" not in err, err
    assert "leaked shared_memory" not in err and "terminate called" not in err, err
    assert wait_for(lambda: not session_processes(gui.pid), 5.0), session_processes(gui.pid)


def test_sigkill_leaves_no_process_behind(gui):
    children = session_processes(gui.pid)
    assert len(children) >= 3, children
    gui.kill()
    gui.wait()
    assert wait_for(lambda: not session_processes(gui.pid), 10.0), (
        f"left running after SIGKILL of skelasm gui: {session_processes(gui.pid)}")
