"""The user's landscape requests: computed by the runtime's worker, the newest one wins.

Data: the id of the newest :class:`engine.runtime.jobs.LandscapeRequest`; answers go to
the loop's event queue (:class:`engine.runtime.messages.LandscapeReady`, ``ProgressEvent``
"landscape", ``LandscapeFailed``).
"""

from __future__ import annotations

import collections

import numpy as np

from engine.pose import rotation_matrix
from engine.runtime.jobs import (
    JobWorker,
    LandscapeRequest,
    LandscapeResponse,
    compute_landscape,
    next_id,
)
from engine.runtime.messages import (
    Event,
    LandscapeFailed,
    LandscapeReady,
    ProgressEvent,
    describe_error,
)
from engine.sim import GeometricField, field_correlator

__all__ = ["Landscapes"]


class Landscapes:
    """Asks the worker for landscapes and delivers the newest one's answer as events."""

    def __init__(self, worker: JobWorker, events: collections.deque[Event]):
        self.worker = worker
        self.events = events
        self._newest = 0

    def request(self, fld: GeometricField, rotvec: tuple[float, ...]) -> None:
        """The landscape of ``fld``'s correlator at rotation vector ``rotvec``."""
        corr = field_correlator(fld)
        if corr is None:
            self.events.append(LandscapeFailed("no landscape: guidance is off", "ValueError"))
            return
        rv = tuple(float(v) for v in rotvec)
        request = LandscapeRequest(next_id(), corr, rotation_matrix(np.array(rv)), rv)
        self._newest = request.id

        def progress(fraction: float) -> None:
            if request.id == self._newest:
                self.events.append(ProgressEvent("landscape", float(fraction)))

        self.worker.submit("landscape", lambda cancelled: compute_landscape(
            request, progress=progress, cancel=cancelled))

    def deliver(self, r: LandscapeResponse) -> None:
        """The worker's answer, as an event (dropped if a newer request superseded it)."""
        if r.id != self._newest:
            return
        if r.error is not None or r.landscape is None:
            err = r.error or RuntimeError("no landscape")
            self.events.append(LandscapeFailed(describe_error(err), type(err).__name__))
        else:
            self.events.append(LandscapeReady(r.landscape, r.rotvec))
