"""Display and settings set-up for the GUI tests (pytest-qt).

pyvistaqt needs an OpenGL window: Qt's ``offscreen`` platform cannot give it one (VTK
reports "Render window is not current"), so the tests run on a real X display. Without
``DISPLAY`` this file starts a private Xvfb server for the session (``Xvfb -displayfd``
picks a free display number) and stops it at the end. If neither a display nor Xvfb is
there, it probes Qt's offscreen platform once in a subprocess; when that cannot render
either, every GUI test is skipped with the reason.

Settings: QSettings is pointed at a temporary directory before any window exists, so tests
never read or write the user's recent files and layout.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from app.display import start_virtual_screen, stop_virtual_screens

_SETTINGS_DIR = tempfile.mkdtemp(prefix="skelasm-gui-settings-")
# Descriptors of the tests' scenes go to a private cache, computed once per test run and
# removed at its end (it can reach the cache's 2 GiB cap); a cache the caller names is kept.
_OWN_CACHE = "SKELASM_CACHE" not in os.environ
if _OWN_CACHE:
    os.environ["SKELASM_CACHE"] = tempfile.mkdtemp(prefix="skelasm-gui-cache-")


_PROBE = """
import pyvista as pv
from PySide6 import QtWidgets
from pyvistaqt import QtInteractor
app = QtWidgets.QApplication([])
p = QtInteractor(None, auto_update=False)
p.add_mesh(pv.Sphere())
p.show(); app.processEvents(); p.render()
img = p.screenshot(return_img=True)
assert img.std() > 0
"""


def _display_problem() -> str | None:
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return None
    if start_virtual_screen() is not None:
        return None
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen")
    probe = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True,
                           timeout=120)
    if probe.returncode == 0:
        os.environ["QT_QPA_PLATFORM"] = "offscreen"
        return None
    return ("no display for the GUI tests: DISPLAY is unset, Xvfb is not installed "
            "(apt-get install xvfb) and Qt's offscreen platform cannot give VTK an OpenGL "
            "window")


try:
    import PySide6  # noqa: F401
    import pyvistaqt  # noqa: F401

    DISPLAY_PROBLEM = _display_problem()
except ImportError as exc:  # the [gui] extra is not installed
    DISPLAY_PROBLEM = f"the GUI packages are not installed: {exc}"

os.environ["XDG_CONFIG_HOME"] = _SETTINGS_DIR


def pytest_collection_modifyitems(config, items):
    here = Path(__file__).parent
    for item in items:
        if Path(str(item.fspath)).is_relative_to(here):
            item.add_marker(pytest.mark.gui)
            if DISPLAY_PROBLEM:
                item.add_marker(pytest.mark.skip(reason=DISPLAY_PROBLEM))


def pytest_sessionfinish(session, exitstatus):
    stop_virtual_screens()
    shutil.rmtree(_SETTINGS_DIR, ignore_errors=True)
    if _OWN_CACHE:
        shutil.rmtree(os.environ["SKELASM_CACHE"], ignore_errors=True)


@pytest.fixture(scope="session")
def qapp_args():
    return ["skelasm-tests"]


@pytest.fixture(scope="session", autouse=True)
def _workers_finish():
    """At the end, wait for engine workers that closed windows cancelled: one still in
    compiled parallel code when the interpreter exits aborts the process.
    """
    yield
    from app.gui.session import wait_for_workers

    assert wait_for_workers(180.0), "engine background threads did not stop"


@pytest.fixture(scope="session", autouse=True)
def _settings_location(qapp):
    from PySide6 import QtCore

    from app.gui.main_window import APPLICATION, ORGANISATION

    qapp.setOrganizationName(ORGANISATION)
    qapp.setApplicationName(APPLICATION)
    for fmt in (QtCore.QSettings.NativeFormat, QtCore.QSettings.IniFormat):
        QtCore.QSettings.setPath(fmt, QtCore.QSettings.UserScope, _SETTINGS_DIR)
    yield


@pytest.fixture
def settings(tmp_path):
    """A QSettings in a test's own directory."""
    from PySide6 import QtCore

    return QtCore.QSettings(str(tmp_path / "settings.ini"), QtCore.QSettings.IniFormat)


EXAMPLE_SCENE = Path(__file__).resolve().parents[2] / "assets" / "peg_in_hole" / "scene.toml"


def _box(lo, hi):
    import trimesh

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.
                                translation_matrix((lo + hi) / 2))


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory) -> Path:
    """A small scene (a block above a plate) on a coarse grid, so the real engine prepares
    its descriptors in seconds.
    """
    d = tmp_path_factory.mktemp("small_scene")
    _box((-10, -10, -3), (10, 10, 0)).export(d / "plate.stl")
    _box((-4, -4, 0), (4, 4, 8)).export(d / "block.stl")
    (d / "scene.toml").write_text(
        'name = "Small test scene"\nunits = "mm"\nassembled_pose = [0, 0, 3, 0, 0, 0]\n\n'
        "[descriptor]\nsigma = 0.5\npenalty = 3.0\ngrid = 12\npadding = 3\n\n"
        "[correlation]\nmodes = 8\n\n"
        '[[part]]\nname = "plate"\nfile = "plate.stl"\npose = [0, 0, 0, 0, 0, 0]\n'
        "fixed = true\n\n"
        '[[part]]\nname = "block"\nfile = "block.stl"\npose = [0, 0, 8, 0, 0, 0]\n'
    )
    return d / "scene.toml"


def _wait_until(qtbot, predicate, timeout_ms: int, what) -> None:
    try:
        # bool(): waitUntil takes a callback returning None as an assertion that passed
        qtbot.waitUntil(lambda: bool(predicate()), timeout=timeout_ms)
    except Exception as exc:  # pytestqt's TimeoutError
        said = what() if callable(what) else what
        raise AssertionError(f"timed out after {timeout_ms} ms waiting for {said}") from exc


@pytest.fixture
def wait_until(qtbot):
    """``wait_until(predicate, timeout_ms, what)``: qtbot.waitUntil whose failure says what
    did not happen (``what``: a string, or a callable giving one, read at the timeout).
    """
    return lambda predicate, timeout_ms, what: _wait_until(qtbot, predicate, timeout_ms, what)


@pytest.fixture
def make_window(qtbot, settings):
    """Factory: a shown MainWindow on a scene, waiting for its first engine frame."""
    windows = []

    def make(scene: Path, *, first_frame: bool = True, **kwargs):
        from app.gui.main_window import MainWindow

        win = MainWindow(settings=settings, **kwargs)
        qtbot.addWidget(win)
        win.show()
        qtbot.waitExposed(win)
        win.open_path(scene, wait=True)
        windows.append(win)
        if first_frame:
            _wait_until(qtbot, lambda: win.latest_frame is not None, 15000, "a first frame")
        return win

    yield make
    for win in windows:
        win.close()
