"""The slice view's preview of new descriptor parameters while their slider is held.

Recomputing both parts' descriptors at a new sigma takes tens of seconds on a 2-core
machine; one plane of one part takes a fraction of a second
(:func:`engine.descriptor.descriptor_slice`: a few thousand points, each exact). So while
the sigma or penalty slider is held, the slice view shows its plane at the value under the
slider, computed by a background worker (the engine's :class:`engine.runtime.JobWorker`);
a newer request supersedes an older one, and an answer for an older request is dropped.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore

from engine.runtime import JobWorker


class SlicePreview(QtCore.QObject):
    """Computes one descriptor plane at other parameters off the GUI thread.

    Signals
    -------
    ready(object, object)
        ``(key, plane)``: the newest request's key and its (nu, nv) complex64 plane.
    failed(object, str)
        ``(key, message)``: the newest request could not be computed.
    """

    ready = QtCore.Signal(object, object)
    failed = QtCore.Signal(object, str)
    _answered = QtCore.Signal(int, object, object, str)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._worker = JobWorker(name="skelasm-slice-preview")
        self._request = 0
        # emitted from the worker, delivered on this object's (the GUI's) thread
        self._answered.connect(self._deliver, QtCore.Qt.QueuedConnection)

    def request(self, key, vertices: np.ndarray, faces: np.ndarray, grid, axis: int,
                index: int, params) -> None:
        """Compute the plane ``index`` along ``axis`` of ``grid`` at ``params``."""
        from engine.descriptor import descriptor_slice

        self._request += 1
        request = self._request

        def work(cancelled) -> None:
            try:
                plane = descriptor_slice(vertices, faces, grid, axis, index, params,
                                         backend="numba")
            except Exception as exc:  # noqa: BLE001 - shown in the view, never raised here
                if not cancelled():
                    self._answered.emit(request, key, None, f"{type(exc).__name__}: {exc}")
                return
            if not cancelled():
                self._answered.emit(request, key, plane, "")

        self._worker.submit("slice", work)  # cancels the superseded one

    def clear(self) -> None:
        """Drop the request in flight: its answer is no longer wanted."""
        self._request += 1
        self._worker.cancel("slice")

    def wait_until_idle(self, timeout: float = 60.0) -> bool:
        """Wait until the last request has been computed (tests); True when it has."""
        return self._worker.wait_until_idle(timeout)

    def shutdown(self) -> None:
        """Drop what is queued and stop the worker (the window closes)."""
        self._request += 1
        self._worker.shutdown(timeout=0.0)

    def _deliver(self, request: int, key, plane, message: str) -> None:
        if request != self._request:
            return
        if plane is None:
            self.failed.emit(key, message)
        else:
            self.ready.emit(key, plane)
