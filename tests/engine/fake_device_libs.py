"""Stand-ins for pyOpenHaptics and pyspacemouse, following their documented interfaces.

They let the device adapters be tested without the hardware or the vendor libraries: the
OpenHaptics fake runs the servo callback in its own thread at about 1 kHz, as the
OpenHaptics scheduler does, and refuses ``set_force`` outside a servo frame, as the real
library does; the space mouse fake returns ``read()`` states with the library's fields.
Tests install them with :func:`install` (``monkeypatch.setitem(sys.modules, ...)``).
"""

from __future__ import annotations

import sys
import threading
import time
import types
from collections import namedtuple

import numpy as np


class FakeTouch:
    """The simulated stylus and servo loop behind the fake ``pyOpenHaptics`` modules."""

    def __init__(self, *, sends=True, fail_open=False):
        self.transform = np.eye(4)  # row-major here; served column-major, as OpenHaptics
        self.forces: list[list[float]] = []
        self.sends = sends  # False: the servo never calls back (no data)
        self.fail_open = fail_open
        self.unplugged = False
        self.in_frame = False
        self.closed = False

    def move(self, translation=(0.0, 0.0, 0.0), rotation=None):
        m = np.eye(4)
        if rotation is not None:
            m[:3, :3] = rotation
        m[:3, 3] = translation
        self.transform = m

    # -- pyOpenHaptics.hd ------------------------------------------------------------------
    def get_transform(self):
        return self.transform.T.tolist()  # column-major: translation in [3][0..2]

    def set_force(self, force):
        if not self.in_frame:
            raise RuntimeError("HD_ILLEGAL_BEGIN: set_force outside a servo frame")
        self.forces.append([float(f) for f in force])

    # -- pyOpenHaptics.hd_callback.hd_callback -------------------------------------------------
    def hd_callback(self, func):
        def frame():
            self.in_frame = True
            try:
                func()
            finally:
                self.in_frame = False
        return frame

    # -- pyOpenHaptics.hd_device.HapticDevice ------------------------------------------------
    def haptic_device(self, callback, device_name="Default Device", scheduler_type="async"):
        touch = self
        if touch.fail_open:
            raise RuntimeError(f"HD_COMM_ERROR: cannot open {device_name}")

        class Device:
            def __init__(self):
                self._stop = threading.Event()
                self._thread = threading.Thread(target=self._run, daemon=True)
                self._thread.start()

            def _run(self):
                while not self._stop.is_set() and not touch.unplugged:
                    if touch.sends:
                        callback()
                    time.sleep(0.001)

            def close(self):
                self._stop.set()
                self._thread.join(1.0)
                touch.closed = True

        return Device()


def install_openhaptics(monkeypatch, touch: FakeTouch) -> None:
    package = types.ModuleType("pyOpenHaptics")
    hd = types.ModuleType("pyOpenHaptics.hd")
    hd.get_transform = touch.get_transform
    hd.set_force = touch.set_force
    callback = types.ModuleType("pyOpenHaptics.hd_callback")
    callback.hd_callback = touch.hd_callback
    device = types.ModuleType("pyOpenHaptics.hd_device")
    device.HapticDevice = touch.haptic_device
    package.hd, package.hd_callback, package.hd_device = hd, callback, device
    for name, module in (("pyOpenHaptics", package), ("pyOpenHaptics.hd", hd),
                         ("pyOpenHaptics.hd_callback", callback),
                         ("pyOpenHaptics.hd_device", device)):
        monkeypatch.setitem(sys.modules, name, module)


SpaceState = namedtuple("SpaceState", "t x y z roll pitch yaw buttons")


class FakeSpaceMouse:
    """The fake ``pyspacemouse`` module: ``open()``, ``read()``, ``close()``."""

    def __init__(self, *, present=True):
        self.present = present
        self.state = SpaceState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0, 0])
        self.unplugged = False
        self.closed = False

    def deflect(self, x=0.0, y=0.0, z=0.0, roll=0.0, pitch=0.0, yaw=0.0):
        self.state = SpaceState(0.0, x, y, z, roll, pitch, yaw, [0, 0])

    def open(self, *args, **kwargs):
        return self.present

    def read(self):
        if self.unplugged:
            raise OSError("read error: device disconnected")
        return self.state

    def close(self):
        self.closed = True


def install_spacemouse(monkeypatch, mouse: FakeSpaceMouse) -> None:
    module = types.ModuleType("pyspacemouse")
    module.open, module.read, module.close = mouse.open, mouse.read, mouse.close
    monkeypatch.setitem(sys.modules, "pyspacemouse", module)
