"""Input devices that drive the proxy: pose in, force and torque out, behind one interface.

Data: proxy poses are (6,) float64 ``(tx, ty, tz, rx, ry, rz)`` relative to part 1 in scene
units; forces and torques (3,) float64 in part 1's frame, already scaled and clamped by the
coupling (:class:`engine.params.HapticLimits`, applied by :mod:`engine.sim`).

Devices: :class:`MouseDevice` (fed by the GUI), :class:`TrajectoryDevice` (CSV
``t,tx,ty,tz,rx,ry,rz``, linearly interpolated, held after the last row),
:class:`SpaceMouseDevice` (3D mouse via pyspacemouse or hidapi), :class:`OpenHapticsDevice`
(via pyOpenHaptics, force sent from its own servo callback), :class:`UdpBridgeDevice` (pose
in, force out over UDP for an external servo loop such as a CHAI3D program). A device that
cannot be opened or goes away raises :class:`DeviceError` naming it and saying what to do;
the engine then keeps running on the mouse.

UDP bridge wire format (little-endian): the client sends ``<Q6d`` (sequence number, pose)
to ``host:port``; the engine answers each step with ``<Q6d`` (sequence number of the newest
pose it used, force (3), torque (3)) to the sender's address (or ``reply_port``).
"""

from __future__ import annotations

import csv
import math
import socket
import struct
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from engine.errors import InputError
from engine.pose import rotation_matrix, rotation_vector

__all__ = [
    "DeviceError",
    "DeviceCapabilities",
    "Device",
    "MouseDevice",
    "TrajectoryDevice",
    "SpaceMouseDevice",
    "OpenHapticsDevice",
    "UdpBridgeDevice",
    "open_device",
    "read_trajectory",
]


class DeviceError(OSError):
    """A device is absent, unplugged or misconfigured; the message names it and the fix."""


@dataclass(frozen=True)
class DeviceCapabilities:
    """What a device can do.

    Attributes
    ----------
    name : str
    dof : int
        Degrees of freedom of its pose input (3 or 6).
    force_feedback, torque_feedback : bool
    max_force, max_torque : float
        Largest force / torque it renders (inf when it renders none, so no clamp applies).
    rate_hz : float
        Its native update rate (0: whenever it is read).
    """

    name: str
    dof: int = 6
    force_feedback: bool = False
    torque_feedback: bool = False
    max_force: float = math.inf
    max_torque: float = math.inf
    rate_hz: float = 0.0


class Device:
    """Base class: override :meth:`read_pose`, and the others when the device needs them."""

    capabilities: DeviceCapabilities = DeviceCapabilities("device")

    @property
    def name(self) -> str:
        """The device's name, from its capabilities (``"mouse"``, ``"udp"``, ...)."""
        return self.capabilities.name

    def connect(self) -> None:
        """Open the device; raises DeviceError when it is absent."""

    def disconnect(self) -> None:
        """Close the device (idempotent)."""

    def read_pose(self, time_s: float) -> np.ndarray | None:
        """(6,) float64 proxy pose at simulated time ``time_s``, or None for "unchanged".

        Raises DeviceError when the device was lost.
        """
        raise NotImplementedError

    def write_force(self, force: np.ndarray, torque: np.ndarray) -> None:
        """Render a force (3,) and torque (3,) (no-op for devices without feedback)."""

    def __enter__(self) -> Device:
        self.connect()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.disconnect()


class MouseDevice(Device):
    """The proxy pose as set by the GUI (:meth:`set_pose`, from any thread)."""

    capabilities = DeviceCapabilities("mouse", dof=6)

    def __init__(self, pose: np.ndarray | None = None):
        self._pose: tuple[float, ...] | None = None if pose is None else _pose_tuple(pose)
        self._seen: tuple[float, ...] | None = None

    def set_pose(self, pose: np.ndarray | tuple[float, ...]) -> None:
        """Set the proxy pose (6,); a tuple swap, atomic under the GIL."""
        self._pose = _pose_tuple(pose)

    def read_pose(self, time_s: float) -> np.ndarray | None:
        """The pose last set by :meth:`set_pose`, or None when unchanged since the last read."""
        pose = self._pose
        if pose is None or pose is self._seen:
            return None
        self._seen = pose
        return np.array(pose)


def _pose_tuple(pose: Any) -> tuple[float, ...]:
    p = tuple(float(v) for v in np.asarray(pose, dtype=float).reshape(6))
    if not all(math.isfinite(v) for v in p):
        raise ValueError(f"pose must be six finite numbers, got {pose!r}")
    return p


# ---------------------------------------------------------------------------------------------
# trajectory


TRAJECTORY_COLUMNS = ("t", "tx", "ty", "tz", "rx", "ry", "rz")


def read_trajectory(path: str | Path) -> np.ndarray:
    """Read a trajectory CSV.

    Parameters
    ----------
    path : str or Path
        CSV with a header naming at least ``t,tx,ty,tz,rx,ry,rz`` (other columns, such as
        those of a recorded session, are ignored).

    Returns
    -------
    (n, 7) float64
        Rows of time (s, strictly increasing) and proxy pose.

    Raises
    ------
    InputError
        Missing file or column, bad number (with the line), times not increasing.
    """
    path = Path(path)
    try:
        fh = open(path, newline="", encoding="utf-8")
    except OSError as exc:
        raise InputError(f"{path}: cannot open the trajectory file ({exc.strerror})") from exc
    with fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise InputError(f"{path}: the trajectory file is empty; it needs a header "
                             f"{','.join(TRAJECTORY_COLUMNS)} and rows") from None
        missing = [c for c in TRAJECTORY_COLUMNS if c not in header]
        if missing:
            raise InputError(
                f"{path}:1: the header lacks column(s) {', '.join(missing)}; a trajectory "
                f"needs {','.join(TRAJECTORY_COLUMNS)}"
            )
        index = [header.index(c) for c in TRAJECTORY_COLUMNS]
        rows = []
        for line, row in enumerate(reader, start=2):
            if not row or all(not c.strip() for c in row):
                continue
            try:
                rows.append([float(row[i]) for i in index])
            except (ValueError, IndexError):
                raise InputError(
                    f"{path}:{line}: expected numbers in columns {','.join(TRAJECTORY_COLUMNS)}, "
                    f"got {row!r}"
                ) from None
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    if len(data) == 0:
        raise InputError(f"{path}: the trajectory has a header but no rows")
    if not np.all(np.isfinite(data)):
        raise InputError(f"{path}: the trajectory holds NaN or infinite values")
    if np.any(np.diff(data[:, 0]) <= 0):
        line = int(np.argmax(np.diff(data[:, 0]) <= 0)) + 3
        raise InputError(f"{path}:{line}: times must increase strictly from row to row")
    return data


class TrajectoryDevice(Device):
    """A scripted proxy: poses linearly interpolated in time.

    The pose is held after the last row (and before the first).

    Parameters
    ----------
    samples : (n, 7) float64 or str or Path
        Rows ``t, tx, ty, tz, rx, ry, rz`` or a CSV file (:func:`read_trajectory`).
    """

    capabilities = DeviceCapabilities("trajectory", dof=6)

    def __init__(self, samples: np.ndarray | str | Path):
        if isinstance(samples, (str, Path)):
            self.source = str(samples)
            samples = read_trajectory(samples)
        else:
            self.source = "<array>"
        data = np.asarray(samples, dtype=np.float64)
        if data.ndim != 2 or data.shape[1] != 7 or len(data) == 0:
            raise ValueError(f"trajectory samples must be (n, 7), got shape {data.shape}")
        self.samples = data
        self.times = np.ascontiguousarray(data[:, 0])
        self.poses = np.ascontiguousarray(data[:, 1:])

    @property
    def duration(self) -> float:
        """Time of the last row in seconds; the pose is held after it."""
        return float(self.times[-1])

    def pose_at(self, time_s: float) -> np.ndarray:
        """(6,) interpolated pose."""
        times = self.times
        if time_s <= times[0]:
            return self.poses[0].copy()
        if time_s >= times[-1]:
            return self.poses[-1].copy()
        i = int(np.searchsorted(times, time_s, side="right")) - 1
        t0, t1 = times[i], times[i + 1]
        if time_s == t0:
            return self.poses[i].copy()
        a = (time_s - t0) / (t1 - t0)
        return (1.0 - a) * self.poses[i] + a * self.poses[i + 1]

    def read_pose(self, time_s: float) -> np.ndarray:
        """The trajectory's pose at ``time_s`` (:meth:`pose_at`)."""
        return self.pose_at(time_s)


# ---------------------------------------------------------------------------------------------
# 3D mouse


class SpaceMouseDevice(Device):
    """A 3D mouse (3Dconnexion) through pyspacemouse, a rate-control device.

    Its deflection moves the proxy with speed ``translation_speed`` (scene units per second at
    full deflection) and ``rotation_speed`` (radians per second).
    """

    capabilities = DeviceCapabilities("spacemouse", dof=6, rate_hz=0.0)

    def __init__(self, start_pose: np.ndarray, *, translation_speed: float = 1.0,
                 rotation_speed: float = 1.0):
        self.pose = np.array(start_pose, dtype=float).reshape(6)
        self.translation_speed = float(translation_speed)
        self.rotation_speed = float(rotation_speed)
        self._module: Any = None
        self._last_time: float | None = None

    def connect(self) -> None:
        """Open the 3D mouse through pyspacemouse.

        Raises DeviceError when the package is missing, the device cannot be opened or none is
        plugged in.
        """
        try:
            import pyspacemouse  # type: ignore[import-not-found]
        except ImportError:
            raise DeviceError(
                "spacemouse: the pyspacemouse package is not installed "
                "(pip install pyspacemouse, which needs hidapi); using the mouse instead"
            ) from None
        try:
            ok = pyspacemouse.open()
        except Exception as exc:  # the library raises plain exceptions for USB trouble
            raise DeviceError(f"spacemouse: could not open the device ({exc}); check that it "
                              "is plugged in and that you may read /dev/hidraw*") from exc
        if not ok:
            raise DeviceError("spacemouse: no 3D mouse found; plug it in (and check the udev "
                              "rule for /dev/hidraw*), or pick the mouse")
        self._module = pyspacemouse

    def disconnect(self) -> None:
        """Close the device (idempotent); errors of an unplugged device are ignored."""
        if self._module is not None:
            try:
                self._module.close()
            except Exception:
                pass
            self._module = None

    def read_pose(self, time_s: float) -> np.ndarray:
        """The proxy pose (6,) float64, moved by the deflection since the last read.

        Deflection times ``translation_speed`` (``rotation_speed``), times the seconds since the
        last read (zero on the first read), is added to the pose. Raises DeviceError when the
        device stops answering or was unplugged.
        """
        if self._module is None:
            raise DeviceError("spacemouse: not connected")
        try:
            state = self._module.read()
        except Exception as exc:
            raise DeviceError(f"spacemouse: the device stopped answering ({exc}); "
                              "plug it back in") from exc
        if state is None:
            raise DeviceError("spacemouse: the device was unplugged; plug it back in")
        dt = 0.0 if self._last_time is None else max(0.0, time_s - self._last_time)
        self._last_time = time_s
        v = np.array([state.x, state.y, state.z], dtype=float) * self.translation_speed
        w = np.array([state.roll, state.pitch, state.yaw], dtype=float) * self.rotation_speed
        self.pose[:3] += dt * v
        self.pose[3:] += dt * w
        return self.pose.copy()


# ---------------------------------------------------------------------------------------------
# OpenHaptics


class OpenHapticsDevice(Device):
    """A 3D Systems Touch / Phantom through pyOpenHaptics (and the OpenHaptics libraries).

    OpenHaptics reads the stylus and renders force only inside its own servo loop (about
    1 kHz, its scheduler thread, between ``hdBeginFrame`` and ``hdEndFrame``), so the device
    runs a servo callback there (``pyOpenHaptics.hd_device.HapticDevice`` with an
    ``hd_callback``): each tick it stores the stylus transform and sends the newest force
    the engine wrote. The engine's own loop only reads and writes those two slots (single
    assignments of new objects, so neither side ever sees a half-written value).

    The stylus maps to the proxy as ``t = start + scale * (p - p0)`` and
    ``R = (R_s R_s0^T) R_start`` (``p0``, ``R_s0``: the stylus at connect time). Force only
    (3-DOF feedback), clamped by the coupling to the device's nominal maximum. A servo loop
    that stops delivering samples for :attr:`stale_after` seconds (cable pulled, device
    error) makes :meth:`read_pose` raise :class:`DeviceError`.
    """

    capabilities = DeviceCapabilities(
        "openhaptics", dof=6, force_feedback=True, max_force=3.3, rate_hz=1000.0
    )

    #: Seconds without a new servo sample after which the device counts as lost.
    stale_after = 0.25

    def __init__(self, start_pose: np.ndarray, *, scale: float = 1.0, name: str = "Default Device"):
        self.start = np.array(start_pose, dtype=float).reshape(6)
        self.scale = float(scale)
        self.device_name = name
        self._hd: Any = None
        self._device: Any = None
        self._servo: Any = None
        self._sample: tuple[float, np.ndarray] | None = None  # (monotonic time, 4x4)
        self._force: list[float] = [0.0, 0.0, 0.0]
        self._origin: np.ndarray | None = None

    def connect(self) -> None:
        """Start the servo callback and wait (up to 1 s) for its first stylus sample.

        The stylus at that moment is the origin the proxy moves from. Raises DeviceError when the
        libraries are missing, the device cannot be opened or it sends no data.
        """
        try:
            import pyOpenHaptics.hd as hd  # type: ignore[import-not-found]
            from pyOpenHaptics.hd_callback import hd_callback  # type: ignore[import-not-found]
            from pyOpenHaptics.hd_device import HapticDevice  # type: ignore[import-not-found]
        except (ImportError, OSError):  # OSError: the package is there, libHD.so is not
            raise DeviceError(
                "openhaptics: pyOpenHaptics (and the OpenHaptics SDK libraries) are not "
                "installed; install them from 3D Systems and pip, or pick the mouse"
            ) from None
        self._hd = hd

        @hd_callback
        def servo() -> None:  # runs in the OpenHaptics scheduler thread, inside a frame
            self._sample = (time.monotonic(), np.asarray(hd.get_transform(), dtype=float))
            hd.set_force(self._force)

        self._servo = servo  # keep the C callback alive as long as the device
        try:
            device = HapticDevice(callback=servo, device_name=self.device_name,
                                  scheduler_type="async")
        except Exception as exc:
            raise DeviceError(f"openhaptics: could not open {self.device_name!r} ({exc}); "
                              "check the cable and the Touch setup utility") from exc
        self._device = device
        deadline = time.monotonic() + 1.0
        while self._sample is None and time.monotonic() < deadline:
            time.sleep(0.005)
        if self._sample is None:
            self.disconnect()
            raise DeviceError(f"openhaptics: {self.device_name!r} sent no data within 1 s; "
                              "check the cable and the Touch setup utility, or pick the mouse")
        self._origin = self._sample[1].reshape(4, 4).T.copy()  # the stylus at connect time

    def disconnect(self) -> None:
        """Zero the force, close the device (idempotent) and forget the stylus origin."""
        if self._device is not None:
            self._force = [0.0, 0.0, 0.0]
            try:
                self._device.close()
            except Exception:
                pass
            self._device = None
        self._sample = None
        self._origin = None

    def read_pose(self, time_s: float) -> np.ndarray:
        """The proxy pose (6,) float64 from the stylus transform the servo callback sampled last.

        See the class docstring for the mapping. Raises DeviceError when not connected or when
        the newest sample is older than :attr:`stale_after` seconds.
        """
        sample = self._sample
        if self._device is None or sample is None:
            raise DeviceError("openhaptics: not connected")
        stamp, transform = sample
        if time.monotonic() - stamp > self.stale_after:
            raise DeviceError(f"openhaptics: no data from {self.device_name!r} for "
                              f"{self.stale_after:g} s (cable pulled or device error); "
                              "reconnect it")
        m = transform.reshape(4, 4).T  # OpenHaptics matrices are column-major
        rot, p = m[:3, :3], m[:3, 3]
        assert self._origin is not None
        pose = self.start.copy()
        pose[:3] += self.scale * (p - self._origin[:3, 3])
        relative = rot @ self._origin[:3, :3].T
        pose[3:] = rotation_vector(relative @ rotation_matrix(self.start[3:]))
        return pose

    def write_force(self, force: np.ndarray, torque: np.ndarray) -> None:
        """Hand ``force`` (3,) to the servo callback, which renders it; the torque is not rendered.

        Raises DeviceError for a non-finite force.
        """
        if not np.all(np.isfinite(force)):
            raise DeviceError("openhaptics: refusing to send a non-finite force")
        self._force = [float(force[0]), float(force[1]), float(force[2])]


# ---------------------------------------------------------------------------------------------
# UDP bridge


POSE_PACKET = struct.Struct("<Q6d")
FORCE_PACKET = struct.Struct("<Q6d")


class UdpBridgeDevice(Device):
    """Exchange pose and force with an external servo loop over UDP (see module docstring).

    Parameters
    ----------
    host, port : str, int
        Where the engine listens for pose packets (port 0: any free port, see ``address``).
    reply_port : int, optional
        Send forces to this port on the sender's host instead of the sender's port.
    timeout : float
        Seconds without a packet, after the first one, at which the device counts as lost.
    max_force : float
        Force the external device renders at most.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 47800, *, reply_port: int | None = None,
                 timeout: float = 1.0, max_force: float = math.inf):
        self.host = host
        self.port = int(port)
        self.reply_port = reply_port
        self.timeout = float(timeout)
        self.capabilities = DeviceCapabilities(
            "udp", dof=6, force_feedback=True, torque_feedback=True, max_force=max_force
        )
        self._sock: socket.socket | None = None
        self._peer: tuple[str, int] | None = None
        self._seq = 0
        self._last_packet: float | None = None
        self.packets_in = 0
        self.packets_out = 0

    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port)."""
        if self._sock is None:
            raise DeviceError("udp: not connected")
        return self._sock.getsockname()

    def connect(self) -> None:
        """Listen on ``host:port`` with a non-blocking UDP socket.

        Raises DeviceError when the address cannot be bound (port taken, bad host).
        """
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((self.host, self.port))
        except OSError as exc:
            sock.close()
            raise DeviceError(f"udp: cannot listen on {self.host}:{self.port} ({exc.strerror}); "
                              "pick another [device] port") from exc
        sock.setblocking(False)
        self._sock = sock

    def disconnect(self) -> None:
        """Close the socket (idempotent)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def read_pose(self, time_s: float) -> np.ndarray | None:
        """The newest pose (6,) float64 among the waiting packets, or None when none came.

        Packets of the wrong size are skipped. The newest packet sets the sequence number and the
        address :meth:`write_force` answers to. Raises DeviceError when no packet came for
        ``timeout`` seconds after the last one.
        """
        if self._sock is None:
            raise DeviceError("udp: not connected")
        newest = None
        while True:
            try:
                data, addr = self._sock.recvfrom(256)
            except BlockingIOError:
                break
            except OSError as exc:
                raise DeviceError(f"udp: socket error ({exc})") from exc
            if len(data) != POSE_PACKET.size:
                continue
            seq, *pose = POSE_PACKET.unpack(data)
            self._seq = seq
            self._peer = addr if self.reply_port is None else (addr[0], int(self.reply_port))
            newest = pose
            self.packets_in += 1
        now = time.monotonic()
        if newest is not None:
            self._last_packet = now
            return np.array(newest, dtype=float)
        if self._last_packet is not None and now - self._last_packet > self.timeout:
            self._last_packet = None
            raise DeviceError(
                f"udp: no pose packet for {self.timeout:g} s from {self._peer}; the external "
                "servo loop stopped (restart it; the scene goes on with the mouse)"
            )
        return None

    def write_force(self, force: np.ndarray, torque: np.ndarray) -> None:
        """Send ``force`` (3,) and ``torque`` (3,) to the sender of the newest pose.

        The packet carries that pose's sequence number; nothing is sent before a first pose, and
        a datagram that cannot be sent is dropped (the next step sends another).
        """
        if self._sock is None or self._peer is None:
            return
        packet = FORCE_PACKET.pack(self._seq, *map(float, force), *map(float, torque))
        try:
            self._sock.sendto(packet, self._peer)
            self.packets_out += 1
        except OSError:
            pass  # a lost datagram is normal for UDP; the next step sends another


# ---------------------------------------------------------------------------------------------


def open_device(kind: str, start_pose: np.ndarray, options: dict | None = None,
                base: Path | None = None) -> Device:
    """Create and connect the device named by a scene's ``[device] kind``.

    Raises
    ------
    DeviceError
        When it cannot be opened (the caller falls back to the mouse).
    ValueError
        Unknown kind.
    """
    options = dict(options or {})
    if kind == "mouse":
        dev: Device = MouseDevice(start_pose)
    elif kind == "trajectory":
        file = Path(options.get("file", ""))
        if base is not None and not file.is_absolute():
            file = base / file
        try:
            dev = TrajectoryDevice(file)
        except InputError as exc:
            raise DeviceError(f"trajectory: {exc}") from exc
    elif kind == "spacemouse":
        dev = SpaceMouseDevice(
            start_pose,
            translation_speed=float(options.get("translation_speed", 1.0)),
            rotation_speed=float(options.get("rotation_speed", 1.0)),
        )
    elif kind == "openhaptics":
        dev = OpenHapticsDevice(start_pose, name=str(options.get("name", "Default Device")))
    elif kind == "udp":
        dev = UdpBridgeDevice(
            str(options.get("host", "127.0.0.1")),
            int(options.get("port", 47800)),
            reply_port=options.get("reply_port"),
            timeout=float(options.get("timeout", 1.0)),
        )
    else:
        raise ValueError(
            f"unknown device {kind!r}; valid: mouse, trajectory, spacemouse, openhaptics, udp"
        )
    dev.connect()
    return dev

