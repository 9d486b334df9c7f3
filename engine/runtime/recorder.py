"""Recording a session from the loop: the recording's columns taken from each frame row.

Data: frame rows ``(FRAME_WIDTH,)`` float64 in (``engine.runtime.frames``), recording rows
``(n, len(engine.recording.COLUMNS))`` float64 out, one per step; the file format, loading
and replay are in :mod:`engine.recording`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from engine.recording import COLUMNS, save_recording
from engine.runtime.frames import RECORDING_INDEX

__all__ = ["Recorder"]


class Recorder:
    """Collects one recording row per step.

    Pass :meth:`on_frame` to ``EngineLoop(on_frame=...)``.

    Runs in the loop thread; rows go to a preallocated float64 buffer that doubles when
    full.
    """

    def __init__(self, capacity: int = 10000):
        self._rows = np.empty((max(16, int(capacity)), len(COLUMNS)), dtype=np.float64)
        self.count = 0

    def on_frame(self, row: np.ndarray) -> None:
        """Keep the recording's columns of a frame row (FRAME_WIDTH,) float64."""
        if self.count == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self._rows[self.count] = row[RECORDING_INDEX]
        self.count += 1

    @property
    def rows(self) -> np.ndarray:
        """(n, len(COLUMNS)) float64 view of the recorded rows."""
        return self._rows[: self.count]

    def save(self, path: str | Path) -> Path:
        """Write the rows to ``.csv`` or ``.npz`` (``engine.recording.save_recording``)."""
        return save_recording(path, self.rows)
