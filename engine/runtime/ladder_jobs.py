"""The scene's sigma ladders, computed by the engine's job worker at low priority.

Works on the loop's scene model (``engine.sim.SceneModel.prepare_ladder``) and the guidance's
:class:`engine.runtime.jobs.JobWorker`. Once a field on the scene's own grid is in use, the
worker computes the nodes missing from each part's ladder (:mod:`engine.descriptor.ladder`),
each cached as it ends; from then on a new sigma inside the ladder's span is interpolated
(seconds) instead of computed. The job gives way to any other: a field request cancels it
(the guidance asks again once that field is in use), and a job of another kind queued
behind it (the fine level, a landscape) makes it stop and queue again behind that job. A
stop loses only the node being computed. Progress goes out as ``ProgressEvent("ladder",
fraction)`` over both ladders (cached nodes count as done); its message is "done" when the
ladders are complete, "paused" when a field job stopped it, "failed: ..." when it failed.
``SKELASM_LIVE_SIGMA=0`` turns it off (the test suite does: minutes of background work on
every engine it starts).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, MutableSequence
from typing import Protocol, runtime_checkable

from engine.errors import Cancelled
from engine.runtime.jobs import FieldResponse, JobWorker, LadderResponse
from engine.runtime.messages import Event, ProgressEvent

__all__ = ["LadderJobs", "LadderModel"]

_log = logging.getLogger(__name__)

#: Progress is reported in steps of at least this fraction (the job runs for minutes).
PROGRESS_STEP = 0.002


@runtime_checkable
class LadderModel(Protocol):
    """A scene model that computes its sigma ladders (``engine.sim.SceneModel`` is one)."""

    def prepare_ladder(self, *, progress: Callable[[float], None] | None = None,
                       cancel: Callable[[], bool] | None = None) -> None:
        """Compute the nodes missing from the scene's ladders."""
        ...


class LadderJobs:
    """Starts, pauses and resumes the ladders' job for the guidance (see the module)."""

    def __init__(self, model: object, worker: JobWorker, events: MutableSequence[Event]):
        off = os.environ.get("SKELASM_LIVE_SIGMA", "1").strip() in ("0", "no", "off", "false")
        self.model = model if not off and isinstance(model, LadderModel) else None
        self.worker, self.events = worker, events
        self.complete = False  # every node cached (or the job failed: not asked again)
        self.fraction = 0.0  # of both ladders, as last reported

    def resume(self, r: FieldResponse) -> None:
        """``r``'s field is in use: on the scene's own grid with skeletal guidance, go on."""
        if (self.model is None or self.complete or r.coarse_grid is not None
                or r.request.effects.guidance != "skeletal"):
            return
        self._submit()

    def pause(self) -> None:
        """A field job goes first (the guidance resumes the ladders after its swap)."""
        if self.worker.cancel("ladder"):
            self.events.append(ProgressEvent("ladder", self.fraction, "paused"))

    def deliver(self, r: LadderResponse) -> None:
        """The job ended: done, failed, or it gave way and is queued again."""
        if r.error is not None:
            self.complete = True
            _log.warning("the sigma ladder could not be computed: %s", r.error)
            self.events.append(ProgressEvent("ladder", self.fraction, f"failed: {r.error}"))
        elif r.complete:
            self.complete = True
            self.events.append(ProgressEvent("ladder", 1.0, "done"))
        else:
            self._submit()  # behind the job it gave way to

    def _submit(self) -> None:
        model = self.model
        assert model is not None
        worker = self.worker

        def progress(fraction: float) -> None:
            if fraction >= 1.0 or fraction - self.fraction >= PROGRESS_STEP:
                self.fraction = float(fraction)
                self.events.append(ProgressEvent("ladder", self.fraction))

        def run(cancelled: Callable[[], bool]) -> LadderResponse:
            t0 = time.perf_counter()
            gave_way = False

            def stop() -> bool:
                nonlocal gave_way
                gave_way = gave_way or worker.waiting("ladder")
                return cancelled() or gave_way

            try:
                model.prepare_ladder(progress=progress, cancel=stop)
            except Cancelled:
                if cancelled():
                    raise
                return LadderResponse(False, time.perf_counter() - t0)
            except Exception as exc:  # delivered to the loop, never raised in the worker
                return LadderResponse(False, time.perf_counter() - t0, exc)
            return LadderResponse(True, time.perf_counter() - t0)

        worker.submit("ladder", run)
