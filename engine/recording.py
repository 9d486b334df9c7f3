"""Record and replay a session.

Per step, a recording holds the input (proxy) trajectory, the part's pose and the forces.

Data: one row per step, float64 columns :data:`COLUMNS`: ``t`` (simulated seconds at
the start of the step), the proxy pose used by the step (``tx..rz``: the columns a
trajectory CSV needs, so a recording is itself a trajectory), the part's pose after the
step (``part_*``), energy, geometric force and torque, haptic force and torque.

Files: ``.csv`` (header line, numbers written with 17 significant digits so that replay
is bit-exact) or ``.npz`` (``columns`` and ``rows`` arrays).

Recording: ``engine.runtime.Recorder`` takes these columns from the loop's frame rows.
Replay: :func:`replay_device` turns a recording into a
:class:`engine.devices.TrajectoryDevice`; stepping the same scene with it at the same
rate feeds the exact recorded proxy pose to every step and so reproduces the motion.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.devices import TrajectoryDevice
from engine.errors import InputError

COLUMNS = (
    "t", "tx", "ty", "tz", "rx", "ry", "rz",
    "part_tx", "part_ty", "part_tz", "part_rx", "part_ry", "part_rz",
    "energy", "fx", "fy", "fz", "mx", "my", "mz",
    "haptic_fx", "haptic_fy", "haptic_fz", "haptic_mx", "haptic_my", "haptic_mz",
)


def save_recording(path: str | Path, rows: np.ndarray) -> Path:
    """Write rows (n, 26) to ``.csv`` or ``.npz`` (by suffix)."""
    path = Path(path)
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, len(COLUMNS))
    if path.suffix.lower() == ".npz":
        np.savez_compressed(path, columns=np.array(COLUMNS), rows=rows)
    else:
        np.savetxt(path, rows, delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.17g")
    return path


def load_recording(path: str | Path) -> np.ndarray:
    """(n, 26) float64 rows of a recording (``.csv`` or ``.npz``)."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".npz":
            with np.load(path) as data:
                columns = tuple(str(c) for c in data["columns"])
                rows = data["rows"]
        else:
            with open(path, encoding="utf-8") as fh:
                columns = tuple(c.strip() for c in fh.readline().split(","))
            rows = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except OSError as exc:
        raise InputError(f"{path}: cannot read the recording ({exc})") from exc
    except (ValueError, KeyError) as exc:
        raise InputError(f"{path}: not a skelasm recording ({exc})") from exc
    if columns != COLUMNS:
        raise InputError(f"{path}: unexpected columns; a recording has {','.join(COLUMNS)}")
    return np.asarray(rows, dtype=np.float64)


def replay_device(path_or_rows: str | Path | np.ndarray) -> TrajectoryDevice:
    """A trajectory device that feeds the recorded proxy poses back, step by step."""
    rows = (
        load_recording(path_or_rows)
        if isinstance(path_or_rows, (str, Path))
        else np.asarray(path_or_rows, float)
    )
    return TrajectoryDevice(rows[:, :7])
