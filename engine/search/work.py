"""Running the search's blocks: here, on the project's background worker, or on Dask.

Works on callables ``run(cancelled) -> response`` (the search's
:class:`~engine.search.scan.ScanBlock`). The verbs are those of
``engine.runtime.BackgroundWork`` (``submit(kind, run)``, ``cancel``, ``wait_until_idle``,
``shutdown``), plus ``responses()`` as ``engine.runtime.JobWorker`` gives them, and
``share(value)``: a large input (a pair's spectra) handed over once instead of with every
block. :class:`~engine.search.distributed.DaskWork` implements them on a Dask cluster;
without one the search runs its blocks in the calling thread.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar

T = TypeVar("T")

#: Values shared with this process by a cluster, by key (filled on a Dask worker).
_SHARED: dict[str, Any] = {}
_SHARED_LOCK = threading.Lock()


class Shared(Generic[T]):
    """A value handed to work once: held here, or looked up by ``key`` where the work runs.

    Pickled (to be sent to a cluster), it leaves its value behind: the cluster has it under
    ``key`` already (:meth:`~engine.search.distributed.DaskWork.share`).
    """

    def __init__(self, key: str, value: T | None = None) -> None:
        self.key = key
        self._value = value

    def get(self) -> T:
        """The value (here, or as the cluster shared it with this process)."""
        if self._value is not None:
            return self._value
        with _SHARED_LOCK:
            if self.key not in _SHARED:
                raise LookupError(f"the shared value {self.key!r} was not handed to this "
                                  "process: share it through the work that runs the block")
            return _SHARED[self.key]  # type: ignore[no-any-return]

    def __getstate__(self) -> dict[str, Any]:
        return {"key": self.key, "_value": None}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)


def receive_shared(values: dict[str, Any]) -> None:
    """Keep ``values`` by key for :meth:`Shared.get` in this process (a cluster's worker)."""
    with _SHARED_LOCK:
        _SHARED.update(values)


class BlockWork(Protocol):
    """Where blocks run: ``engine.runtime.BackgroundWork``'s verbs, ``responses``, ``share``."""

    def share(self, value: T) -> Shared[T]:
        """Hand ``value`` over once; blocks read it through the handle."""
        ...

    def submit(self, kind: str, run: Callable[[Callable[[], bool]], Any]) -> None:
        """Queue ``run`` as the newest job of ``kind``."""
        ...

    def cancel(self, kind: str) -> bool:
        """Cancel the job of ``kind``."""
        ...

    def responses(self) -> list[Any]:
        """The responses finished since the last call, in the order they finished."""
        ...

    def wait_until_idle(self, timeout: float) -> bool:
        """Wait for the submitted jobs; True when none is left."""
        ...

    def shutdown(self, timeout: float = 2.0) -> None:
        """Cancel every job and stop."""
        ...
