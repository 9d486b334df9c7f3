"""Start-up of the desktop application: QApplication, window, optional timed screenshot."""

from __future__ import annotations

import os
import signal
import socket
import sys
from pathlib import Path

from app.gui import SCREENSHOT_AFTER

DEFAULT_SCENE = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"


def make_application(argv: list[str] | None = None):
    """The QApplication, created once.

    It carries the organisation and application names that QSettings uses.
    """
    from PySide6 import QtWidgets

    from app.gui.main_window import APPLICATION, ORGANISATION

    app = QtWidgets.QApplication.instance()
    if app is None:
        app = QtWidgets.QApplication(argv if argv is not None else [sys.argv[0]])
    app.setOrganizationName(ORGANISATION)
    app.setApplicationName(APPLICATION)
    return app


def check_display() -> str | None:
    """A message when no display is reachable (pyvistaqt needs an OpenGL window), else None.

    On a headless Linux machine a private Xvfb is started (see :mod:`app.display`).
    """
    from app.display import ensure_screen

    return ensure_screen("skelasm")


_signal_wakeup: list = []


def _quit_on_signals(app, window) -> list[int]:
    """Close the window and leave the event loop on SIGINT (Ctrl+C) or SIGTERM.

    Python runs its signal handlers only between bytecodes, and Qt's event loop runs none
    while it waits: the signal also writes a byte to a socket that Qt watches
    (:func:`signal.set_wakeup_fd`), which wakes the loop at once. Returns a list that
    receives the signal numbers caught.
    """
    from PySide6 import QtCore

    caught: list[int] = []
    receive, send = socket.socketpair()
    receive.setblocking(False)
    send.setblocking(False)
    signal.set_wakeup_fd(send.fileno())
    notifier = QtCore.QSocketNotifier(receive.fileno(), QtCore.QSocketNotifier.Type.Read, app)

    def drain() -> None:
        try:
            receive.recv(64)
        except OSError:
            pass

    notifier.activated.connect(drain)
    _signal_wakeup[:] = [receive, send, notifier]  # alive as long as the application

    def finish() -> None:
        window.close()
        app.quit()

    def handler(signum, frame) -> None:
        if not caught:
            QtCore.QTimer.singleShot(0, finish)
        caught.append(signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    return caught


def run(scene: str | None = None, *, screenshot: str | None = None,
        quit_after: float | None = None, engine_process: bool = False) -> int:
    """Open the window on ``scene`` (default: the peg-in-hole example) and run the event loop.

    With ``quit_after`` seconds, the window saves ``screenshot`` (if given) and quits then;
    with only ``screenshot``, it does so after :data:`app.gui.SCREENSHOT_AFTER` seconds.
    """
    problem = check_display()
    if problem:
        raise RuntimeError(problem)
    from PySide6 import QtCore

    app = make_application()
    from app.gui.main_window import MainWindow

    window = MainWindow(engine_kwargs={"process": True} if engine_process else None)
    # from here on Ctrl+C closes the window, also while the scene is still loading
    interrupted = _quit_on_signals(app, window)
    window.show()
    path = Path(scene) if scene else DEFAULT_SCENE
    window.open_path(path, wait=True)
    status = {"code": 0}
    if window.session.handle is None and window.last_error:
        print(f"skelasm gui: {window.last_error}", file=sys.stderr)
        status["code"] = 2 if quit_after is not None or screenshot else 0
    if screenshot and quit_after is None:
        quit_after = SCREENSHOT_AFTER
    if quit_after is not None:
        def finish() -> None:
            if screenshot:
                out = window.save_screenshot(screenshot)
                print(f"skelasm gui: saved {out}")
            window.close()
            app.quit()

        QtCore.QTimer.singleShot(int(quit_after * 1000), finish)
    if interrupted:  # Ctrl+C while the scene loaded: the event loop need not start
        window.close()
    else:
        app.exec()
    # a second Ctrl+C while background work winds down leaves at once, without a traceback
    signal.signal(signal.SIGINT, lambda *_: os._exit(130))
    if interrupted:
        status["code"] = 130
    # free the window (Qt, VTK, the engine thread) while the interpreter is whole: left to
    # shutdown, a half-torn-down VTK object crashed it ("none_dealloc") now and then
    window.close()
    window.deleteLater()
    app.processEvents()
    import gc

    gc.collect()
    from app.gui.session import wait_for_workers

    if not wait_for_workers(2.0):
        print("skelasm gui: waiting for background work to stop…", file=sys.stderr)
        wait_for_workers(120.0)
    return status["code"]
