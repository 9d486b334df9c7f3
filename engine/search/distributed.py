"""The search's blocks as Dask tasks: a local cluster, or a scheduler at an address.

Works on the callables of :mod:`engine.search.work` (``run(cancelled) -> response``).
:class:`DaskWork` implements the verbs of ``engine.runtime.BackgroundWork`` (``submit``,
``cancel``, ``wait_until_idle``, ``shutdown``), ``responses`` as ``JobWorker`` gives them,
and ``share``: a value scattered to every worker once (a pair's spectra, tens of MB), which
the blocks then read by key instead of carrying it. Dask is imported only here and only
when a :class:`DaskWork` is made: the rest of skelasm runs without it.

Every task runs its transforms on one thread (a worker process per core is the cluster's
parallelism), so a block gives the same numbers, bit for bit, as in the calling process.
A cancelled block that has started runs to its end (Dask does not interrupt a task); its
response is dropped.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable
from typing import Any, TypeVar

from engine.backend import cpu_cores, spare_cores
from engine.errors import InputError
from engine.search.work import Shared, receive_shared

T = TypeVar("T")

#: Seconds :meth:`DaskWork.shutdown` gives the client and a local cluster to close.
CLOSE_SECONDS = 30.0


def _run_block(run: Callable[[Callable[[], bool]], Any], shared: dict[str, Any]) -> Any:
    """On a worker: keep the shared values, run the block on one thread."""
    receive_shared(shared)
    with spare_cores(cpu_cores() - 1):
        return run(lambda: False)


class DaskWork:
    """Blocks of work on a Dask cluster (see the module docstring).

    Parameters
    ----------
    client : distributed.Client
        A connected client.
    owned : object, optional
        A cluster this object made and closes at :meth:`shutdown`.
    """

    def __init__(self, client: Any, owned: Any = None) -> None:
        self._client = client
        self._owned = owned
        self._shared: dict[str, Any] = {}
        self._jobs: dict[str, Any] = {}
        self._done: list[Any] = []
        self._lock = threading.Lock()

    @classmethod
    def connect(cls, address: str | None = None, *, workers: int = 2) -> DaskWork:
        """A client of the scheduler at ``address``, or of a new local cluster.

        The local cluster has ``workers`` processes of one thread each.

        Raises
        ------
        InputError
            Dask is not installed, or the scheduler cannot be reached.
        """
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise InputError("Dask is not installed: pip install 'dask[distributed]'") from exc
        if address is not None:
            try:
                return cls(Client(address, timeout="10s"))
            except (OSError, TimeoutError) as exc:
                raise InputError(f"no Dask scheduler answers at {address}: start one "
                                 "(dask scheduler) or leave out --scheduler") from exc
        if workers < 1:
            raise InputError(f"a local cluster needs at least 1 worker, got {workers}")
        cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                               dashboard_address=None)
        return cls(Client(cluster), owned=cluster)

    @property
    def workers(self) -> int:
        """Workers the scheduler knows now."""
        return len(self._client.scheduler_info().get("workers", {}))

    def share(self, value: T) -> Shared[T]:
        """Scatter ``value`` to every worker once; blocks read it through the handle."""
        key = f"skelasm-shared-{uuid.uuid4().hex}"
        self._shared[key] = self._client.scatter(value, broadcast=True, hash=False)
        return Shared(key, value)

    def submit(self, kind: str, run: Callable[[Callable[[], bool]], Any]) -> None:
        """Run ``run`` as a task; a job of the same ``kind`` still pending is cancelled."""
        self.cancel(kind)
        future = self._client.submit(_run_block, run, dict(self._shared), pure=False,
                                     key=f"{kind}-{uuid.uuid4().hex}")
        with self._lock:
            self._jobs[kind] = future
        future.add_done_callback(lambda f, kind=kind: self._finished(kind, f))

    def _finished(self, kind: str, future: Any) -> None:
        with self._lock:
            if kind in self._jobs and self._jobs[kind] is future:
                del self._jobs[kind]
                if str(future.status) in ("finished", "error"):  # not "cancelled"
                    self._done.append(future)

    def cancel(self, kind: str) -> bool:
        """Cancel the job of ``kind``; True if one was pending or running."""
        with self._lock:
            future = self._jobs.pop(kind, None)
        if future is None or future.done():
            return False
        future.cancel()
        return True

    def responses(self) -> list[Any]:
        """Responses finished since the last call, in the order they finished.

        A task that raised raises here (its exception, as the worker raised it).
        """
        with self._lock:
            done, self._done = self._done, []
        return [future.result() for future in done]

    def wait_until_idle(self, timeout: float) -> bool:
        """Wait for the submitted tasks; True when none is left."""
        from distributed import wait

        with self._lock:
            pending = list(self._jobs.values())
        try:
            wait(pending, timeout=timeout)
        except TimeoutError:
            return False
        return True

    def shutdown(self, timeout: float = 2.0) -> None:
        """Cancel every task, let go of the shared values, close what this object made."""
        with self._lock:
            jobs, self._jobs = list(self._jobs.values()), {}
        for future in jobs:
            future.cancel()
        self._shared.clear()
        # a local cluster's processes take seconds to stop on a loaded machine (2 s were
        # not enough on 2 busy cores); they are this process's children and end with it
        wait = max(float(timeout), CLOSE_SECONDS)
        for closing in (self._client, self._owned):
            if closing is None:
                continue
            try:
                closing.close(timeout=wait)
            except TimeoutError:
                pass
