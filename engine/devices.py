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

UDP bridge wire format (little-endian, docs/devices.md): the peer sends a 72-byte pose packet
:data:`POSE_V1` (magic ``SKAS``, version 1, type 1, flags, session token, sequence number,
pose) to ``host:port``; the engine answers each packet it accepts at most once, at its next
step, with a 72-byte :data:`FORCE_V1` (same header, the sequence number of the newest pose it
used, force (3), torque (3), clamped). The header-less 56-byte ``<Q6d`` packets of the first
bridge are still accepted, and answered in kind, when no token is configured.
"""

from __future__ import annotations

import csv
import errno
import io
import logging
import math
import socket
import struct
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from engine.errors import InputError
from engine.files import MAX_TRAJECTORY_BYTES, decode_text, read_input
from engine.params import UDP_MAX_ROTATION, UdpBridgeParams
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

    def stats(self) -> dict[str, object]:
        """Counters worth reporting after a run (packets, drops); empty for most devices."""
        return {}

    def __enter__(self) -> Device:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
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


def _pose_tuple(pose: ArrayLike) -> tuple[float, ...]:
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
    # bounded, from a regular file only (/dev/zero never ends); utf-8-sig: a byte-order
    # mark (spreadsheets write one) is not part of a column name
    text = decode_text(read_input(path, what="trajectory file", limit=MAX_TRAJECTORY_BYTES),
                       path, what="trajectory file")
    with io.StringIO(text, newline="") as fh:
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
# UDP bridge (wire format and security model: docs/devices.md)


#: First four bytes of every version-1 packet, both directions.
WIRE_MAGIC = b"SKAS"
#: Wire format version this engine speaks.
WIRE_VERSION = 1
#: Packet types (the header's ``type`` byte).
POSE_TYPE, FORCE_TYPE = 1, 2
#: Version-1 pose packet (72 bytes): magic, version, type 1, flags (0), token (0 when the
#: engine has none), sequence number, pose (6).
POSE_V1 = struct.Struct("<4sBBHQQ6d")
#: Version-1 force packet (72 bytes): magic, version, type 2, flags (:data:`FORCE_CLAMPED`,
#: ...), token, sequence number of the newest pose used, force (3), torque (3).
FORCE_V1 = struct.Struct("<4sBBHQQ6d")
#: Header-less packets of the first bridge (56 bytes each: sequence number, six numbers),
#: accepted only when no token is configured; a legacy pose is answered in the legacy form.
POSE_PACKET = struct.Struct("<Q6d")
FORCE_PACKET = struct.Struct("<Q6d")
#: Flags of a force packet.
FORCE_CLAMPED, TORQUE_CLAMPED, POSE_REFUSED = 1, 2, 4
#: Why a packet is dropped: the keys of :attr:`UdpBridgeDevice.dropped`.
DROP_REASONS = ("size", "header", "token", "legacy", "foreign", "non_finite", "workspace")
#: Most packets one read takes from the socket (about 4 us each), so that a flood costs a step
#: at most a quarter of a millisecond; the rest wait for the next step (or the kernel drops
#: them when its buffer is full). A servo loop sends one per step.
MAX_PACKETS_PER_READ = 64

_log = logging.getLogger(__name__)


def _clamped(vector: Sequence[float] | np.ndarray,
             limit: float) -> tuple[tuple[float, float, float], bool]:
    """A (3,) vector as three floats with its norm at most ``limit`` (and whether it was cut).

    Non-finite input becomes zero. Plain floats: a few microseconds less per step than numpy.
    """
    x, y, z = (float(v) for v in vector)
    norm = math.hypot(x, y, z)
    if not math.isfinite(norm):  # a NaN or an infinity (or an overflow) somewhere in it
        return (0.0, 0.0, 0.0), True
    if norm > limit:
        k = limit / norm
        return (x * k, y * k, z * k), True
    return (x, y, z), False


class UdpBridgeDevice(Device):
    """Exchange pose and force with an external servo loop over UDP.

    The network is treated as hostile. One peer at a time: the configured ``peer``, or the
    first source that sends a valid packet (with the ``token`` when one is set); packets from
    any other source are dropped. A pose that is not finite or lies outside the workspace is
    dropped, never handed to the simulation. Each packet accepted from the peer earns at most
    one reply, sent only to the peer, with the force and torque clamped to ``max_force`` and
    ``max_torque``. Dropped packets are counted in :attr:`dropped` (:meth:`stats`) and the
    first of each kind is logged. Wire format: :data:`POSE_V1`, :data:`FORCE_V1`.

    Parameters
    ----------
    host, port : str, int
        Where the engine listens (port 0: any free port, see ``address``).
    **options
        The other keys of :class:`engine.params.UdpBridgeParams` (``reply_port``, ``peer``,
        ``token``, ``allow_remote``, ``timeout``, ``max_force``, ``max_torque``,
        ``workspace``).

    Raises
    ------
    DeviceError
        A bad option (port out of range, a host beyond loopback without ``allow_remote``).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 47800, **options: Any):
        try:
            self.params = UdpBridgeParams.from_options({"host": host, "port": port, **options})
        except InputError as exc:
            raise DeviceError(str(exc)) from None  # its messages start with "udp"
        p = self.params
        self.capabilities = DeviceCapabilities(
            "udp", dof=6, force_feedback=True, torque_feedback=True, max_force=p.max_force,
            max_torque=p.max_torque,
        )
        self._sock: socket.socket | None = None
        self._source: tuple[str, int] | None = None  # the peer's address, once it sent
        self._reply_to: tuple[str, int] | None = None
        self._legacy = False  # the peer's newest packet was header-less: answer in kind
        self._owed = False  # a packet from the peer is not answered yet
        self._refused = False  # ... and its pose was dropped
        self._seq = 0
        self._last_packet: float | None = None
        self.packets_in = 0
        self.packets_out = 0
        self.dropped = dict.fromkeys(DROP_REASONS, 0)

    @property
    def address(self) -> tuple[str, int]:
        """The bound (host, port)."""
        if self._sock is None:
            raise DeviceError("udp: not connected")
        return self._sock.getsockname()

    @property
    def peer(self) -> tuple[str, int] | None:
        """The address packets are accepted from, once the peer has sent (or None)."""
        return self._source

    def connect(self) -> None:
        """Listen on ``host:port`` with a non-blocking UDP socket.

        Beyond loopback (``allow_remote``) a warning is logged. Raises DeviceError when the
        address cannot be bound (port taken, address not on this machine).
        """
        p = self.params
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((p.host, p.port))
        except OSError as exc:
            sock.close()
            raise DeviceError(f"udp: cannot listen on {p.host}:{p.port} "
                              f"({exc.strerror or exc}); pick another [device] port") from exc
        sock.setblocking(False)
        self._sock = sock
        if p.remote:
            _log.warning(
                "udp: listening on %s:%d, beyond this machine (allow_remote = true): a host "
                "that reaches this port and knows the token can drive the proxy, and the token "
                "travels in clear; use a trusted network", p.host, self.address[1])

    def disconnect(self) -> None:
        """Close the socket (idempotent); a summary of dropped packets goes to the log."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
            if any(self.dropped.values()):
                _log.info("udp: %s", self.drop_summary())

    def stats(self) -> dict[str, object]:
        """Packets accepted, replies sent, packets dropped by reason, and the peer."""
        peer = None if self._source is None else f"{self._source[0]}:{self._source[1]}"
        return {"peer": peer, "packets_in": self.packets_in, "replies": self.packets_out,
                "dropped": sum(self.dropped.values()),
                "dropped_by_reason": {k: n for k, n in self.dropped.items() if n}}

    def drop_summary(self) -> str:
        """One line: how many packets were dropped and why."""
        reasons = ", ".join(f"{k.replace('_', '-')} {n}" for k, n in self.dropped.items() if n)
        return f"dropped {sum(self.dropped.values())} packet(s) ({reasons or 'none'})"

    def _drop(self, reason: str, addr: tuple[str, int]) -> None:
        if self.dropped[reason] == 0:
            _log.warning("udp: dropped a packet from %s:%d (%s); later ones of this kind are "
                         "counted, not logged", addr[0], addr[1], _DROP_TEXT[reason])
        self.dropped[reason] += 1

    def _accepts_source(self, addr: tuple[str, int]) -> bool:
        if self._source is not None:
            return addr == self._source
        wanted = self.params.peer_address
        return wanted is None or (addr[0] == wanted[0] and wanted[1] in (None, addr[1]))

    def _decode(self, data: bytes, addr: tuple[str, int]) -> tuple[int, tuple[float, ...]] | None:
        """(sequence number, pose) of a packet in either form, or None (counted as dropped)."""
        token = self.params.token or 0
        if len(data) == POSE_V1.size:
            magic, version, kind, _, sent_token, seq, *pose = POSE_V1.unpack(data)
            if magic != WIRE_MAGIC or version != WIRE_VERSION or kind != POSE_TYPE:
                self._drop("header", addr)
                return None
            if sent_token != token:
                self._drop("token", addr)
                return None
            self._legacy = False
            return seq, tuple(pose)
        if len(data) == POSE_PACKET.size:
            if token:
                self._drop("legacy", addr)
                return None
            seq, *pose = POSE_PACKET.unpack(data)
            self._legacy = True
            return seq, tuple(pose)
        self._drop("size", addr)
        return None

    def _pose_problem(self, pose: tuple[float, ...]) -> str | None:
        if not all(map(math.isfinite, pose)):
            return "non_finite"
        if (math.hypot(*pose[:3]) > self.params.workspace
                or math.hypot(*pose[3:]) > UDP_MAX_ROTATION):
            return "workspace"
        return None

    def read_pose(self, time_s: float) -> np.ndarray | None:
        """The newest valid pose (6,) float64 among the waiting packets, or None when none came.

        Packets from another source than the peer, of the wrong size or header, with the wrong
        token, or whose pose is not finite or outside the workspace are dropped and counted
        (at most :data:`MAX_PACKETS_PER_READ` are taken per call). Raises DeviceError when the
        peer sent nothing for ``timeout`` seconds after its first packet.
        """
        if self._sock is None:
            raise DeviceError("udp: not connected")
        newest = None
        for _ in range(MAX_PACKETS_PER_READ):
            try:
                data, addr = self._sock.recvfrom(256)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # an ICMP error of an earlier reply: not the peer's packet
                if exc.errno in (errno.ECONNREFUSED, errno.ECONNRESET):
                    continue
                raise DeviceError(f"udp: socket error ({exc})") from exc
            if not self._accepts_source(addr):
                self._drop("foreign", addr)
                continue
            decoded = self._decode(data, addr)
            if decoded is None:
                continue
            seq, pose = decoded
            problem = self._pose_problem(pose)
            if problem is not None:
                self._drop(problem, addr)
                if self._source is not None:  # the peer's own packet: answered, as refused
                    self._owed, self._refused = True, True
                    self._last_packet = time.monotonic()
                continue
            if self._source is None:
                self._lock(addr)
            self._seq, newest = seq, pose
            self._owed, self._refused = True, False
            self.packets_in += 1
        now = time.monotonic()
        if newest is not None:
            self._last_packet = now
            return np.array(newest, dtype=np.float64)
        if self._last_packet is not None and now - self._last_packet > self.params.timeout:
            self._last_packet = None
            raise DeviceError(
                f"udp: no pose packet for {self.params.timeout:g} s from {self._source}; the "
                "external servo loop stopped (restart it; the scene goes on with the mouse)"
            )
        return None

    def _lock(self, addr: tuple[str, int]) -> None:
        self._source = addr
        reply_port = self.params.reply_port
        self._reply_to = addr if reply_port is None else (addr[0], reply_port)
        _log.info("udp: peer %s:%d connected; packets from any other source are dropped",
                  addr[0], addr[1])

    def write_force(self, force: np.ndarray, torque: np.ndarray) -> None:
        """Answer the peer's newest packet with ``force`` (3,) and ``torque`` (3,), clamped.

        At most one reply per packet accepted from the peer: without a new packet since the
        last reply nothing is sent. Norms are clamped to ``max_force`` / ``max_torque`` (a
        non-finite vector is sent as zero); a datagram that cannot be sent is dropped.
        """
        if self._sock is None or self._reply_to is None or not self._owed:
            return
        f, f_clamped = _clamped(force, self.params.max_force)
        t, t_clamped = _clamped(torque, self.params.max_torque)
        if self._legacy:
            packet = FORCE_PACKET.pack(self._seq, *f, *t)
        else:
            flags = (FORCE_CLAMPED * f_clamped) | (TORQUE_CLAMPED * t_clamped) | (
                POSE_REFUSED * self._refused)
            packet = FORCE_V1.pack(WIRE_MAGIC, WIRE_VERSION, FORCE_TYPE, flags,
                                   self.params.token or 0, self._seq, *f, *t)
        self._owed = False
        try:
            self._sock.sendto(packet, self._reply_to)
            self.packets_out += 1
        except OSError:
            pass  # a lost datagram is normal for UDP; the peer's next packet gets another


_DROP_TEXT = {
    "size": "not the size of a pose packet",
    "header": "not a skelasm version-1 pose packet",
    "token": "wrong session token",
    "legacy": "header-less packet while a token is configured",
    "foreign": "not from the peer",
    "non_finite": "pose not finite",
    "workspace": "pose outside the workspace",
}


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
        dev = UdpBridgeDevice(**options)
    else:
        raise ValueError(
            f"unknown device {kind!r}; valid: mouse, trajectory, spacemouse, openhaptics, udp"
        )
    dev.connect()
    return dev

