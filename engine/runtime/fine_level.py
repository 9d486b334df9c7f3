"""The fine level where the parts meet, built in the background and added to the loop's field.

Works on the loop's :class:`engine.sim.Simulation` and the descriptors its field was built
from (``engine.descriptor.Descriptor``). The level (``engine.correlation.near``) is built by
the guidance's job worker after a field with new descriptors is in use (a coarse first field
gets none), and added when it is done and still for the descriptors in use; a new K keeps
it (the level follows the field's band); a request for a new field cancels a level still
being built, and the field's swap asks for it again.
"""

from __future__ import annotations

from collections.abc import MutableSequence
from typing import TYPE_CHECKING

from engine.runtime.jobs import FieldModel, FieldResponse, JobWorker, NearResponse, build_near
from engine.runtime.messages import ErrorEvent, Event

if TYPE_CHECKING:
    from engine.descriptor import Descriptor
    from engine.sim import Simulation


def _same(a: tuple[Descriptor, ...], b: tuple[Descriptor, ...]) -> bool:
    return len(a) == len(b) and all(x is y for x, y in zip(a, b, strict=True))


class FineLevels:
    """Builds and adds the fine level for the loop (see the module)."""

    def __init__(self, sim: Simulation, model: FieldModel | None, worker: JobWorker,
                 events: MutableSequence[Event]):
        self.sim, self.model, self.worker, self.events = sim, model, worker, events

    def cancel(self) -> None:
        """A new field is asked for: it goes first."""
        self.worker.cancel("near")

    def swapped(self, r: FieldResponse, in_use: tuple[Descriptor, ...]) -> None:
        """``r``'s field replaced one built from ``in_use``: keep, drop or ask for the level."""
        descriptors = tuple(r.descriptors)
        if not _same(descriptors, in_use):
            self.sim.set_near(None)
        model, effects = self.model, r.request.effects
        if (self.sim.near is not None or r.coarse_grid is not None or model is None
                or effects.guidance != "skeletal" or len(descriptors) < 2):
            return
        self.worker.submit("near", lambda cancelled: build_near(model, effects, descriptors,
                                                                cancelled))

    def deliver(self, r: NearResponse, in_use: tuple[Descriptor, ...]) -> None:
        """Add a finished level if it is for the descriptors in use."""
        if not _same(tuple(r.descriptors), in_use):
            return  # superseded
        if r.error is not None:
            self.events.append(ErrorEvent(
                f"the fine level where the parts meet could not be built ({r.error}); the "
                "guidance goes on without it", type(r.error).__name__))
            return
        self.sim.set_near(r.near)
