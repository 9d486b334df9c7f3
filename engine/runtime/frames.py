"""The one frame layout: a simulation snapshot packed into a row of float64, and back.

Data: a frame row is ``(FRAME_WIDTH,)`` float64, one named slot range per quantity
(:data:`SLOTS`); :func:`pack_frame` fills it from the simulation after each loop iteration
and :func:`unpack_frame` turns it into an :class:`engine.runtime.messages.Frame`. The
thread transport and the process transport carry these rows through a :class:`FrameRing`
(in the process's memory, or in shared memory), and the recorder keeps the columns of a
recording (``engine.recording.COLUMNS``) taken from the same rows (:data:`RECORDING_INDEX`).

Slots hold numbers only: ``recompute`` None is NaN, ``paused`` is 0 or 1, and the device's
name is at most 16 ASCII bytes reinterpreted as two float64 (copied bit for bit, never
computed with).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Protocol

import numpy as np

from engine.recording import COLUMNS
from engine.runtime.messages import Frame, PeriodStats

if TYPE_CHECKING:
    from engine.correlation import Evaluation

__all__ = [
    "FRAME_FIELDS",
    "FRAME_WIDTH",
    "RECORDING_INDEX",
    "SLOTS",
    "FrameRing",
    "encode_device_name",
    "pack_frame",
    "unpack_frame",
]

#: (name, number of float64 slots) in row order.
FRAME_FIELDS: tuple[tuple[str, int], ...] = (
    ("time", 1),  # simulated time after the step
    ("input_time", 1),  # simulated time at which the proxy pose was read
    ("step", 1),
    ("proxy_pose", 6),
    ("part_pose", 6),
    ("energy", 1),
    ("force", 3),
    ("torque", 3),
    ("coupling_force", 3),
    ("coupling_torque", 3),
    ("haptic_force", 3),
    ("haptic_torque", 3),
    ("eval_us", 1),
    ("step_us", 1),
    ("modes", 1),
    ("paused", 1),
    ("recompute", 1),
    ("period", 6),  # rate_hz, median_us, p1_us, p99_us, max_us, window
    ("device", 2),  # 16 bytes of ASCII
)


def _slots() -> dict[str, slice]:
    out, at = {}, 0
    for name, n in FRAME_FIELDS:
        out[name] = slice(at, at + n)
        at += n
    return out


#: Slot range of each field in a row.
SLOTS: dict[str, slice] = _slots()
#: float64 values in one row.
FRAME_WIDTH: int = SLOTS["device"].stop

_RECORDED = ("input_time", "proxy_pose", "part_pose", "energy", "force", "torque",
             "haptic_force", "haptic_torque")
#: Row indices of the recording's columns (``engine.recording.COLUMNS``), in their order.
RECORDING_INDEX: np.ndarray = np.concatenate(
    [np.arange(SLOTS[n].start, SLOTS[n].stop) for n in _RECORDED]
)
assert len(RECORDING_INDEX) == len(COLUMNS)

_NAME_BYTES = 8 * (SLOTS["device"].stop - SLOTS["device"].start)
_I = {name: s.start for name, s in SLOTS.items()}


def encode_device_name(name: str) -> np.ndarray:
    """(2,) float64 holding ``name`` as ASCII bytes (cut to 16; compute once per device)."""
    raw = name.encode("ascii", "replace")[:_NAME_BYTES].ljust(_NAME_BYTES, b"\0")
    return np.frombuffer(raw, dtype=np.float64).copy()


def _decode_device_name(values: np.ndarray) -> str:
    return np.ascontiguousarray(values, np.float64).tobytes().rstrip(b"\0").decode("ascii")


class SimulationView(Protocol):
    """What a frame reads of ``engine.sim.Simulation`` after a step."""

    time: float
    step_time: float
    steps: int
    proxy_pose: np.ndarray
    sample: Evaluation
    coupling_force: np.ndarray
    coupling_torque: np.ndarray
    haptic_force: np.ndarray
    haptic_torque: np.ndarray

    def part_pose(self) -> np.ndarray:
        """(6,) pose of the part."""
        ...


def pack_frame(
    row: np.ndarray,
    sim: SimulationView,
    *,
    modes: int,
    step_us: float,
    period: PeriodStats,
    paused: bool,
    recompute: float | None,
    device: np.ndarray,
) -> None:
    """Write the simulation's state after a step into ``row`` (FRAME_WIDTH,) float64.

    ``device`` is :func:`encode_device_name` of the device in use.
    """
    i = _I
    s = sim.sample
    row[i["time"]] = sim.time
    row[i["input_time"]] = sim.step_time
    row[i["step"]] = sim.steps
    row[SLOTS["proxy_pose"]] = sim.proxy_pose
    row[SLOTS["part_pose"]] = sim.part_pose()
    row[i["energy"]] = s.energy
    row[SLOTS["force"]] = s.force
    row[SLOTS["torque"]] = 0.0 if s.torque is None else s.torque
    row[SLOTS["coupling_force"]] = sim.coupling_force
    row[SLOTS["coupling_torque"]] = sim.coupling_torque
    row[SLOTS["haptic_force"]] = sim.haptic_force
    row[SLOTS["haptic_torque"]] = sim.haptic_torque
    row[i["eval_us"]] = s.microseconds
    row[i["step_us"]] = step_us
    row[i["modes"]] = modes
    row[i["paused"]] = 1.0 if paused else 0.0
    row[i["recompute"]] = math.nan if recompute is None else recompute
    p = i["period"]
    row[p:p + 6] = (period.rate_hz, period.median_us, period.p1_us, period.p99_us,
                    period.max_us, period.window)
    row[SLOTS["device"]] = device


def unpack_frame(row: np.ndarray) -> Frame:
    """The :class:`Frame` of a packed row (its arrays are read-only views of a copy)."""
    r = np.array(row, dtype=np.float64)
    r.setflags(write=False)
    i = _I
    p = i["period"]
    recompute = float(r[i["recompute"]])
    return Frame(
        time=float(r[i["time"]]),
        step=int(r[i["step"]]),
        proxy_pose=r[SLOTS["proxy_pose"]],
        part_pose=r[SLOTS["part_pose"]],
        energy=float(r[i["energy"]]),
        force=r[SLOTS["force"]],
        torque=r[SLOTS["torque"]],
        coupling_force=r[SLOTS["coupling_force"]],
        coupling_torque=r[SLOTS["coupling_torque"]],
        haptic_force=r[SLOTS["haptic_force"]],
        haptic_torque=r[SLOTS["haptic_torque"]],
        eval_us=float(r[i["eval_us"]]),
        step_us=float(r[i["step_us"]]),
        period=PeriodStats(float(r[p]), float(r[p + 1]), float(r[p + 2]), float(r[p + 3]),
                           float(r[p + 4]), int(r[p + 5])),
        modes=int(r[i["modes"]]),
        paused=bool(r[i["paused"]]),
        recompute=None if math.isnan(recompute) else recompute,
        device=_decode_device_name(r[SLOTS["device"]]),
    )


class FrameRing:
    """The newest ``capacity`` frame rows in a float64 buffer: one writer, one reader.

    Layout: ``buffer[0]`` counts the rows written; slot ``j % capacity`` holds row ``j`` as
    ``[seq, row...]`` with ``seq = 2 j + 1`` while it is being written and ``2 j + 2`` once
    complete (a sequence lock per slot). The writer never waits; the reader copies a slot
    and keeps it only if ``seq`` was complete and unchanged across the copy, so it never
    sees a torn row, and rows overwritten before it read them are simply dropped (a stale
    pose is worthless to a viewer). The buffer may be process memory (thread transport) or
    shared memory (process transport): the protocol is the same.

    Parameters
    ----------
    buffer : (FrameRing.size(capacity),) float64, optional
        Zeroed storage; default: a new array.
    capacity : int
    """

    def __init__(self, capacity: int = 64, buffer: np.ndarray | None = None):
        self.capacity = max(1, int(capacity))
        n = self.size(self.capacity)
        self.buffer = np.zeros(n) if buffer is None else buffer
        if self.buffer.shape != (n,) or self.buffer.dtype != np.float64:
            raise ValueError(f"a FrameRing of {self.capacity} rows needs ({n},) float64")
        self._slots = self.buffer[1:].reshape(self.capacity, FRAME_WIDTH + 1)
        self._read = 0  # rows consumed by the reader

    @staticmethod
    def size(capacity: int) -> int:
        """float64 values of the buffer for ``capacity`` rows."""
        return 1 + int(capacity) * (FRAME_WIDTH + 1)

    @property
    def written(self) -> int:
        """Rows written so far."""
        return int(self.buffer[0])

    def write(self, row: np.ndarray) -> None:
        """Publish one row (writer side; never blocks)."""
        j = int(self.buffer[0])
        slot = self._slots[j % self.capacity]
        slot[0] = 2 * j + 1
        slot[1:] = row
        slot[0] = 2 * j + 2
        self.buffer[0] = j + 1

    def read_rows(self, max_rows: int | None = None) -> list[np.ndarray]:
        """Rows written since the last call that are still there, oldest first (reader)."""
        end = int(self.buffer[0])
        start = max(self._read, end - self.capacity)
        if max_rows is not None:
            end = min(end, start + int(max_rows))
        out = []
        for j in range(start, end):
            slot = self._slots[j % self.capacity]
            seq = slot[0]
            if seq != 2 * j + 2:
                continue  # overwritten by a newer row, or being written
            row = slot[1:].copy()
            if slot[0] == seq:
                out.append(row)
        self._read = max(self._read, end)
        return out

    def read_frames(self, max_frames: int | None = None) -> list[Frame]:
        """:meth:`read_rows` unpacked into frames."""
        return [unpack_frame(r) for r in self.read_rows(max_frames)]
