"""The hand-over of a new field to the loop while the part turns.

A new K or new descriptors give a new :class:`engine.sim.RotationCacheField`, built in the
worker with its first cache at the rotation the part had when the build ended
(``RotationCacheField.catch_up``). A part that turns a milliradian or two per millisecond
(dragged, or rattling in a tight fit) is past that cache's limit angle by the time the
loop swaps the field in, and its full per-pose path, milliseconds at K = 24 on this kind of
machine, would serve the loop's first poses. So the loop holds the new field back: the
refresh lane builds a cache for it where the part will be when the cache is done
(extrapolated from the part's last turn over the poses a refresh takes), the field in use
serves meanwhile, and the new field is swapped in once its cache serves the part's rotation
(:meth:`RotationCacheField.serves_at`). At most
:data:`~engine.params.HANDOVER_TRIES` caches and :data:`~engine.params.HANDOVER_SECONDS`:
then it is handed over as it is (docs/runtime.md, "Handing a new field over").

Data: the held :class:`engine.runtime.jobs.FieldResponse`, the lane request it waits for,
the part's rotation at the last iteration (3, 3) float64.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from engine.params import HANDOVER_SECONDS, HANDOVER_TRIES
from engine.runtime.jobs import FieldResponse, RefreshResponse
from engine.sim import RotationCacheField

__all__ = ["Handover"]


class Handover:
    """Holds a finished field back until a first cache serves the part's rotation.

    Parameters
    ----------
    attach : callable(field)
        Attaches a field to the refresh lane (``Guidance.attach``).
    dispose : callable(object), optional
        Takes a dropped response, to free it off the loop's thread
        (``JobWorker.dispose``); default: dropped here.
    """

    def __init__(self, attach: Callable[[RotationCacheField], None],
                 dispose: Callable[[object], None] | None = None):
        self.attach = attach
        self.dispose = dispose
        self.period = 1e-3  # the loop's period (seconds): a refresh's time in poses
        self.held: FieldResponse | None = None
        self._field: RotationCacheField | None = None
        self._asked = 0  # id of the lane request the held field waits for
        self._tries = 0
        self._since = 0.0  # when the field was held (perf_counter)
        self._poses = 0  # iterations since the last request
        self._lead = 0  # poses the last request took (0: none arrived yet)
        self._previous: np.ndarray | None = None  # the part's rotation one iteration ago
        #: Fields held, handed over once their cache served, handed over as they were, and
        #: dropped while held (a newer field or request superseded them, or a cancel)
        self.counts = {"held": 0, "served": 0, "gave_up": 0, "dropped": 0}

    def hold(self, response: FieldResponse, rotation: np.ndarray, period: float) -> bool:
        """Hold ``response``'s field back if its cache does not serve ``rotation``.

        ``period``: the loop's (seconds). False: it serves (or is not a rotation-cache
        field); swap it in now.
        """
        self.drop()
        self.period = float(period)
        fld = response.field
        if not isinstance(fld, RotationCacheField) or fld.serves_at(rotation):
            return False
        self.attach(fld)
        self.held, self._field = response, fld
        self._tries, self._since, self._lead = 0, time.perf_counter(), 0
        self.counts["held"] += 1
        self._ask(rotation, self._previous)
        return True

    def _ask(self, rotation: np.ndarray, previous: np.ndarray | None) -> None:
        assert self._field is not None
        fld = self._field
        lead = self._lead
        if lead == 0:  # none arrived yet: a refresh costs about 1.5 full-path poses
            lead = math.ceil(1.5 * (fld.full_us or 0.0) * 1e-6 / self.period) + 1
        self._asked = fld.ask_ahead(rotation, rotation if previous is None else previous, lead)
        self._tries += 1
        self._poses = 0

    def refreshed(self, done: RefreshResponse) -> None:
        """A lane response: installed in the held field if it is the one it waits for."""
        if self._field is None or done.field is not self._field or done.id != self._asked:
            return
        self._asked = 0
        self._lead = max(1, self._poses)
        if done.cache is None:
            self._field.refresh_failed(done.id)
        else:
            self._field.install(done.id, done.cache)

    def due(self, rotation: np.ndarray) -> FieldResponse | None:
        """Once per iteration: the held response if it is to be swapped in now, else None.

        Asks the lane again where the cache that arrived no longer serves the part.
        """
        # kept, not copied: the loop replaces the state's rotation at each step (a hot path)
        previous, self._previous = self._previous, rotation
        fld = self._field
        if fld is None or self.held is None:
            return None
        self._poses += 1
        in_time = time.perf_counter() - self._since < HANDOVER_SECONDS
        if self._asked and in_time:
            return None  # a cache is being built
        if (not self._asked and in_time and self._tries < HANDOVER_TRIES
                and not fld.serves_at(rotation)):
            self._ask(rotation, previous)  # it arrived, and the part has turned past it
            return None
        held = self.held
        self.counts["served" if fld.serves_at(rotation) else "gave_up"] += 1
        fld.take_up(rotation if previous is None else previous, self._lead)
        self.held, self._field, self._asked = None, None, 0
        return held

    def drop(self) -> None:
        """Forget the held field (superseded, or cancelled)."""
        held, self.held, self._field, self._asked = self.held, None, None, 0
        if held is not None:
            self.counts["dropped"] += 1
            if self.dispose is not None:
                self.dispose(held)
