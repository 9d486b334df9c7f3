"""Background work of the engine, on one worker thread.

Frozen requests carry ids; the worker answers each by a frozen response echoing the id.

Data: a :class:`FieldRequest` captures everything needed to build a geometric field (effects,
kappa, locked rotation (3, 3) float64, K, descriptor parameters, and the descriptors to reuse
when only K or the rotation lock changed); a :class:`LandscapeRequest` a correlator and a
rotation (3, 3) float64. Responses carry the built field and descriptors, or the landscape,
or the error.

One worker (:class:`JobWorker`, a ``ThreadPoolExecutor(max_workers=1)`` as napari's layer
slicer uses): a newer request of the same kind supersedes the older one, which is cancelled
(dropped if it has not started; told to stop through its ``cancel`` callback if it has), and
the loop drops any response whose id is not the newest it asked for. Nothing here runs on
the loop thread; the loop only collects finished responses between two steps.

:class:`BackgroundWork` is the one interface for background work (``submit(kind, run)``
superseding the same kind, ``cancel``, ``wait_until_idle``, ``shutdown``): the engine's
jobs and the window's own (opening a scene, the accuracy indicator) submit through a
:class:`JobWorker`, and a distributed driver implements the same four verbs. Two
executors stay special on purpose: the refresh lane below (milliseconds, priority raised
while the loop waits for it) and the job process (:mod:`engine.runtime.job_process`, the
correlator's spectral work out of the loop's interpreter, behind ``Correlator.spectral``).

Rotation-cache refreshes (:class:`RefreshRequest`: a field and the part's rotation) have a
lane of their own (:class:`RefreshLane`, one thread): they take milliseconds and are asked
for every few milliradians of rotation, so they must not queue behind a descriptor job of
minutes. A newer request for the same field supersedes one not started yet; requests for
two fields (the one in use and a new K's waiting to be handed over) are built in the order
they were asked; the field installs only the response whose id it is waiting for.
"""

from __future__ import annotations

import itertools
import queue
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

import numpy as np

import engine.params
from engine.backend import spare_cores
from engine.correlation import Correlator
from engine.errors import Cancelled
from engine.params import CouplingParams, DescriptorParams, Effects, Physics, SimConfig
from engine.runtime.pacing import drop_realtime_priority, raise_thread_priority
from engine.sim import (
    GeometricField,
    NullField,
    RotationCacheField,
    field_for_effects,
    rotational_stiffness,
)

if TYPE_CHECKING:
    from engine.correlation import Landscape
    from engine.correlation.near import NearField
    from engine.correlation.rotation_cache import RotationCache
    from engine.descriptor import Descriptor

__all__ = [
    "FieldModel",
    "FieldRequest",
    "FieldResponse",
    "NearResponse",
    "JobWorker",
    "LandscapeRequest",
    "LadderResponse",
    "LandscapeResponse",
    "RefreshLane",
    "RefreshRequest",
    "RefreshResponse",
    "Response",
    "build_field",
    "compute_landscape",
]

_ids = itertools.count(1)


def next_id() -> int:
    """A fresh request id (increasing)."""
    return next(_ids)


class FieldModel(Protocol):
    """What rebuilding physics and fields needs of a scene.

    ``engine.sim.SceneModel`` is one.
    """

    backend: str
    modes: int
    config: SimConfig
    #: Rotational stiffness of the field in use (part of what physics depends on); the loop
    #: sets it when it swaps a field in (:attr:`FieldResponse.stiffness`).
    geometric_rotation: float | None
    #: (6,) part 2 relative to part 1 when assembled: where a field's stiffness is measured.
    assembled_pose: np.ndarray

    def physics(
        self, effects: Effects, coupling: CouplingParams | None = None,
        kappa: float | None = None,
    ) -> Physics:
        """Physics constants for ``effects`` (and a changed coupling or kappa)."""
        ...

    def field(
        self,
        effects: Effects,
        kappa: float,
        locked_rotation: np.ndarray,
        *,
        descriptor: DescriptorParams | None = None,
        modes: int | None = None,
        grid: int | None = None,
        progress: Callable[[float], None] | None = None,
        cancel: Callable[[], bool] | None = None,
    ) -> tuple[GeometricField, tuple[Descriptor, ...]]:
        """(field, descriptors) for ``effects``."""
        ...

    def descriptors_of(self, fld: GeometricField) -> tuple[Descriptor, ...]:
        """The descriptors of ``fld`` if this model built it before any loop, else ()."""
        ...

    def near_field(self, effects: Effects, descriptors: Sequence[Descriptor], *,
                   cancel: Callable[[], bool] | None = None) -> NearField | None:
        """The fine level where the parts meet for these descriptors, or None."""
        ...

    def first_grid(self, effects: Effects, *,
                   descriptor: DescriptorParams | None = None) -> int | None:
        """The coarse grid of a first field, or None when the scene's own is quick."""
        ...


@dataclass(frozen=True, kw_only=True)
class FieldRequest:
    """Build the geometric field for these inputs (built by keyword only).

    Attributes
    ----------
    id : int
    task : str
        "correlator" (the first preparation), "descriptors" (new descriptor parameters or
        guidance: progress is reported) or "modes" (new K or rotation lock only).
    effects : Effects
    kappa : float
    locked_rotation : (3, 3) float64, read-only
        The part's rotation when the request was made (used when rotation is locked).
    modes : int
        K, modes per axis.
    descriptor : DescriptorParams or None
        The descriptor parameters as the user asked for them (the window's panel builds
        them; they reach the kernels as they are); None: the scene's.
    descriptors : tuple of Descriptor
        Reuse these (only K or the rotation lock changed); empty: compute them.
    backend : str
        Per-pose evaluator for a rebuilt correlator ("" : the model's).
    correlator : Correlator or None
        The field in use's correlator, built from ``descriptors``: only K changed, so its
        spectra and compiled kernels are shared (:meth:`Correlator.with_modes`) and only the
        mode table is cut again; nothing is read from disk or transformed.
    coarse_first : bool
        The first field of a scene: when its descriptors are not cached, build it on the
        model's coarse grid (:meth:`FieldModel.first_grid`), seconds instead of minutes, and
        say so in the response; the caller then asks for the scene's own.
    """

    id: int
    task: str
    effects: Effects
    kappa: float
    locked_rotation: np.ndarray
    modes: int
    descriptor: DescriptorParams | None = None
    descriptors: tuple[Descriptor, ...] = ()
    backend: str = ""
    correlator: Correlator | None = None
    coarse_first: bool = False


@dataclass(frozen=True)
class FieldResponse:
    """Answer to a :class:`FieldRequest` with the same ``id``.

    ``field`` is None when it failed (``error``) or was cancelled (``cancelled``).
    """

    id: int
    request: FieldRequest
    field: GeometricField | None = None
    descriptors: tuple[Descriptor, ...] = ()
    seconds: float = 0.0
    error: BaseException | None = None
    cancelled: bool = False
    coarse_grid: int | None = None  # the coarse grid the field was built on, if any
    #: The field's rotational stiffness at the assembled pose per unit kappa
    #: (``engine.sim.rotational_stiffness``; None: no torque, or nothing constrained).
    stiffness: float | None = None


@dataclass(frozen=True)
class NearResponse:
    """The fine level where the parts meet, built for ``descriptors`` (in the worker).

    ``near`` is None where the pair has none (``SceneModel.near_field``) or it failed
    (``error``).
    """

    descriptors: tuple[Descriptor, ...]
    near: NearField | None = None
    seconds: float = 0.0
    error: BaseException | None = None


def build_near(model: FieldModel, effects: Effects, descriptors: tuple[Descriptor, ...],
               cancel: Callable[[], bool]) -> NearResponse:
    """Run the fine level's job (in the worker); a failure comes back as ``error``."""
    t0 = time.perf_counter()
    try:
        near = model.near_field(effects, descriptors, cancel=cancel)
    except Cancelled:
        raise
    except Exception as exc:  # delivered to the loop, never raised in the worker
        return NearResponse(descriptors, None, time.perf_counter() - t0, exc)
    return NearResponse(descriptors, near, time.perf_counter() - t0)


@dataclass(frozen=True)
class LandscapeRequest:
    """Compute the translational energy landscape of ``correlator`` at ``rotation``."""

    id: int
    correlator: Correlator
    rotation: np.ndarray  # (3, 3) float64
    rotvec: tuple[float, ...]


@dataclass(frozen=True)
class LandscapeResponse:
    """Answer to a :class:`LandscapeRequest` with the same ``id``."""

    id: int
    rotvec: tuple[float, ...]
    landscape: Landscape | None = None
    error: BaseException | None = None
    cancelled: bool = False


@dataclass(frozen=True)
class LadderResponse:
    """The sigma ladders' job ended (``engine.runtime.ladder_jobs``).

    ``complete``: every node is cached; False: it gave way to other work, or failed (``error``).
    """

    complete: bool
    seconds: float = 0.0
    error: BaseException | None = None


Response = FieldResponse | LandscapeResponse | NearResponse | LadderResponse


def _warm(fld: GeometricField, rotation: np.ndarray) -> None:
    """Evaluate once, so that tables built lazily on first use are built here.

    That is off the loop, before the field is handed over.
    """
    fld.evaluate(np.asarray(rotation, np.float64), np.zeros(3))


def build_field(
    model: FieldModel,
    request: FieldRequest,
    *,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    rotation_now: Callable[[], np.ndarray] | None = None,
) -> FieldResponse:
    """Run a :class:`FieldRequest` (in the worker): the field, warmed up, and its descriptors.

    ``rotation_now`` reads the part's rotation as the loop steps it: a rotation-cache field
    then rebuilds its first cache there before it is handed over
    (:meth:`RotationCacheField.catch_up`), not at the rotation the request was made at, and
    its full path is timed here (:meth:`RotationCacheField.measure_full_path`).
    """
    t0 = time.perf_counter()
    r = request
    coarse: int | None = None
    if r.descriptors and r.effects.guidance != "none":
        d1, d2 = r.descriptors[0], r.descriptors[1]
        backend = r.backend or model.backend

        def make(rotation: bool) -> Correlator:
            if r.correlator is not None and r.correlator.rotation == rotation:
                return r.correlator.with_modes(r.modes)
            return Correlator(d1, d2, modes=r.modes, rotation=rotation, backend=backend,
                              kappa=1.0, band=engine.params.GUIDANCE_BAND)

        fld = field_for_effects(r.effects, make, kappa=r.kappa,
                                locked_rotation=r.locked_rotation)
        descs: tuple[Descriptor, ...] = (d1, d2)
    else:
        coarse = (model.first_grid(r.effects, descriptor=r.descriptor)
                  if r.coarse_first else None)
        fld, descs = model.field(
            r.effects, r.kappa, r.locked_rotation, descriptor=r.descriptor,
            modes=r.modes, progress=progress, cancel=cancel,
            **({} if coarse is None else {"grid": coarse}),
        )
    if cancel is not None and cancel():
        raise Cancelled("superseded")
    # the fit's stiffness changes with K (on the peg at grid 56: 3.9e3 at K = 8, 8.5e4 at
    # K = 24), and the default rotational coupling follows it: the loop puts it in use with
    # the field (the model's is the field's in use, until then)
    stiffness = rotational_stiffness(fld, model.assembled_pose)
    if not isinstance(fld, NullField):
        _warm(fld, r.locked_rotation)
    if rotation_now is not None and isinstance(fld, RotationCacheField):
        # what the full path would cost the loop, timed here; before the catch-up, so that
        # the part does not turn on while it is timed
        fld.measure_full_path()
        fld.catch_up(rotation_now)
    return FieldResponse(r.id, r, fld, tuple(descs), time.perf_counter() - t0,
                         coarse_grid=coarse, stiffness=stiffness)


def compute_landscape(
    request: LandscapeRequest,
    *,
    progress: Callable[[float], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> LandscapeResponse:
    """Run a :class:`LandscapeRequest` (in the worker); a failure comes back as ``error``."""
    try:
        land = request.correlator.landscape(request.rotation, progress=progress, cancel=cancel)
    except Cancelled:
        raise
    except Exception as exc:  # delivered to the loop (LandscapeFailed), never lost in the worker
        return LandscapeResponse(request.id, request.rotvec, error=exc)
    return LandscapeResponse(request.id, request.rotvec, land)


T = TypeVar("T")


def _drain(done: queue.SimpleQueue[T]) -> list[T]:
    """Everything queued in ``done`` now, oldest first, without waiting."""
    out: list[T] = []
    while True:
        try:
            out.append(done.get_nowait())
        except queue.Empty:
            return out


@dataclass
class _Job:
    future: Future[None]
    cancel: threading.Event = field(default_factory=threading.Event)


#: Seconds :meth:`JobWorker.dispose` waits for the caller to let go of what it handed over.
DISPOSE_WAIT = 0.05


@runtime_checkable
class BackgroundWork(Protocol):
    """The one interface for background work: one slot per kind, superseded work cancelled.

    napari's layer slicer works so. A ``run`` takes a ``cancelled()`` callable, returns a
    response (None: nothing to answer; a response is delivered as the implementation
    says) and may raise ``engine.errors.Cancelled`` once ``cancelled()`` turns True.
    """

    def submit(self, kind: str, run: Callable[[Callable[[], bool]], Any]) -> None:
        """Queue ``run`` as the newest job of ``kind``, cancelling the older one."""
        ...

    def cancel(self, kind: str) -> bool:
        """Cancel the job of ``kind``; True if one was pending or running."""
        ...

    def wait_until_idle(self, timeout: float) -> bool:
        """Wait for the submitted jobs; True when none is left."""
        ...

    def shutdown(self, timeout: float = 2.0) -> None:
        """Cancel every job and stop."""
        ...


class JobWorker:
    """One background thread for jobs: :class:`BackgroundWork` on a thread.

    Finished responses queue up for the loop (:meth:`responses`).

    Each job has a kind (``"field"``, ``"landscape"``; the window's ``"open"``,
    ``"profile"``); :meth:`submit` cancels the pending or running job of the same kind
    before queueing the new one. ``name`` names the thread.
    """

    def __init__(self, name: str = "skelasm-jobs") -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
        self._jobs: dict[str, _Job] = {}
        self._done: queue.SimpleQueue[Response] = queue.SimpleQueue()
        self._closed = False
        self._queued = 0  # jobs submitted and not yet finished or dropped

    @property
    def busy(self) -> bool:
        """True while a job is queued or running."""
        return self._queued > 0

    def submit(self, kind: str, run: Callable[[Callable[[], bool]], Response | None]) -> None:
        """Queue ``run(cancelled)`` as the newest job of ``kind``.

        ``run`` returns a response (None: a job with nothing to answer), or raises
        ``engine.errors.Cancelled`` once ``cancelled()`` turns True (then there is no
        response: the caller knows it cancelled).
        """
        if self._closed:
            return
        self.cancel(kind)
        flag = threading.Event()

        def body() -> None:
            try:
                if flag.is_set():
                    return
                try:
                    with spare_cores(1):  # the loop steps on the core left
                        response = run(flag.is_set)
                except Cancelled:
                    return
                if response is not None:
                    self._done.put(response)
            finally:
                self._queued -= 1

        self._queued += 1
        future = self._pool.submit(body)
        future.add_done_callback(lambda f: self._dropped(f))
        self._jobs[kind] = _Job(future, flag)

    def dispose(self, thing: object) -> None:
        """Let the worker's thread drop ``thing``, not the caller's.

        Freeing a replaced field's arrays took 0.4 to 2.3 ms (a landscape at grid 56: 44 MB)
        on whichever thread dropped the last reference; on the loop thread that is a missed
        period. The caller hands over its last reference; the worker, queued behind the
        jobs, waits until it holds the only one (the caller's frame may still hold it when
        the worker first looks), at most :data:`DISPOSE_WAIT` seconds, and drops it.
        """
        if self._closed:
            return
        box = [thing]
        del thing
        self._queued += 1

        def body() -> None:
            try:
                end = time.monotonic() + DISPOSE_WAIT
                # two: the box's reference and getrefcount's own argument
                while sys.getrefcount(box[0]) > 2 and time.monotonic() < end:
                    time.sleep(0.001)
                box.clear()
            finally:
                self._queued -= 1

        future = self._pool.submit(body)
        future.add_done_callback(lambda f: self._dropped(f))

    def _dropped(self, future: Future[None]) -> None:
        if future.cancelled():  # never started: body() did not count it down
            self._queued -= 1

    def cancel(self, kind: str) -> bool:
        """Cancel the job of ``kind``; True if one was pending or running."""
        job = self._jobs.pop(kind, None)
        if job is None or job.future.done():
            return False
        job.cancel.set()
        job.future.cancel()  # succeeds only if it has not started
        return True

    def waiting(self, but: str) -> bool:
        """Whether a job of a kind other than ``but`` is queued (from a job of kind ``but``).

        A low-priority job polls it to give way (:mod:`engine.runtime.ladder_jobs`).
        """
        return any(kind != but and not job.future.done()
                   for kind, job in list(self._jobs.items()))

    def responses(self) -> list[Response]:
        """Responses finished since the last call, in the order they finished."""
        return _drain(self._done)

    def wait_until_idle(self, timeout: float) -> bool:
        """Wait for the submitted jobs; True when none is left."""
        _, pending = wait([job.future for job in self._jobs.values()], timeout)
        return not pending

    def shutdown(self, timeout: float = 2.0) -> None:
        """Cancel every job and stop the thread.

        Waits at most ``timeout`` seconds for a running job to notice.
        """
        self._closed = True
        running = [job.future for job in self._jobs.values()]
        for kind in list(self._jobs):
            self.cancel(kind)
        self._pool.shutdown(wait=False, cancel_futures=True)
        wait(running, timeout)


@dataclass(frozen=True)
class RefreshRequest:
    """Rebuild ``field``'s rotation cache at ``rotation`` (3, 3) float64."""

    id: int
    field: RotationCacheField
    rotation: np.ndarray


@dataclass(frozen=True)
class RefreshResponse:
    """Answer to a :class:`RefreshRequest` with the same ``id``.

    ``cache`` is None when the build failed (``error``); ``thread`` names the thread that
    built it and ``seconds`` how long it took.
    """

    id: int
    field: RotationCacheField
    cache: RotationCache | None = None
    seconds: float = 0.0
    thread: str = ""
    error: BaseException | None = None


#: A refresh lane's thread ends after this many seconds without a request.
IDLE_SECONDS = 1.0


class RefreshLane:
    """One thread of its own for rotation-cache refreshes (started on a request, ending idle).

    :meth:`submit` is a :data:`engine.sim.fields.RefreshSubmitter`: it queues the request
    (superseding one for the same field not started yet) and returns its id at once; the
    loop collects the finished ones with :meth:`responses` between two steps and hands them
    to the field.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        # the request not started yet, per field (by identity), oldest first
        self._next: dict[int, RefreshRequest] = {}
        self._done: queue.SimpleQueue[RefreshResponse] = queue.SimpleQueue()
        self._thread: threading.Thread | None = None
        self._closed = False
        self.superseded = 0  # requests replaced before they started
        #: ``SCHED_FIFO`` priority of the lane's thread while :meth:`hurry` is on (None: it
        #: stays at ordinary priority); a real-time loop sets it
        #: (``engine.runtime.pacing.LANE_PRIORITY``)
        self.priority: int | None = None
        #: What the lane's thread was granted when it was last hurried, in words
        self.scheduling = "normal (not asked for)"
        self.hurried = False
        self.hurries = 0  # times hurried
        self._native_id: int | None = None  # the lane's thread, while it runs

    def submit(self, fld: RotationCacheField, rotation: np.ndarray) -> int:
        """Queue a refresh of ``fld`` at ``rotation``; returns the request's id."""
        request = RefreshRequest(next_id(), fld, np.array(rotation, np.float64).reshape(3, 3))
        with self._cond:
            if self._closed:
                return request.id
            if self._next.pop(id(fld), None) is not None:
                self.superseded += 1
            self._next[id(fld)] = request
            if self._thread is None:
                self._thread = threading.Thread(target=self._main, name="skelasm-refresh",
                                                 daemon=True)
                self._thread.start()
            self._cond.notify()
        return request.id

    def hurry(self, on: bool) -> None:
        """Run the lane's thread at :attr:`priority` (on) or at ordinary priority (off).

        The loop turns it on while it waits for a cache (its poses are stale, or on the
        full path) and off once one serves: a real-time lane all the time took a fifth to a
        third of a software-rendered window's frames on two cores (docs/runtime.md).
        """
        if self.priority is None or on == self.hurried:
            return
        with self._cond:
            self.hurried = on
            self.hurries += 1 if on else 0
            if self._native_id is not None:
                self._set_priority(self._native_id)

    def describe(self) -> str:
        """The lane's priority in words, for reports."""
        if self.priority is None:
            return "ordinary priority"
        if not self.hurries:
            return f"not hurried (would run at SCHED_FIFO {self.priority})"
        times = "once" if self.hurries == 1 else f"{self.hurries} times"
        return f"hurried {times}, to {self.scheduling}"

    def _set_priority(self, native_id: int) -> None:
        if self.hurried and self.priority is not None:
            self.scheduling = raise_thread_priority(self.priority, native_id)
        else:
            drop_realtime_priority(native_id)

    def forget(self, fld: RotationCacheField) -> None:
        """Drop ``fld``'s request not started yet (a field the loop no longer uses)."""
        with self._cond:
            self._next.pop(id(fld), None)

    def _main(self) -> None:
        name = threading.current_thread().name
        with self._cond:
            self._native_id = threading.get_native_id()
            if self.hurried:
                self._set_priority(self._native_id)
        while True:
            with self._cond:
                if not self._next and not self._closed:
                    self._cond.wait(IDLE_SECONDS)
                if self._closed or not self._next:
                    # closed, or idle: the thread ends (the next request starts another), so
                    # a lane whose owner was never closed leaves no thread behind
                    self._thread = self._native_id = None
                    return
                request = self._next.pop(next(iter(self._next)))
            start = time.perf_counter()
            try:
                cache = request.field.build_cache(request.rotation)
            except Exception as exc:  # delivered to the loop, never raised in the lane
                self._done.put(RefreshResponse(request.id, request.field, None,
                                               time.perf_counter() - start, name, exc))
                continue
            self._done.put(RefreshResponse(request.id, request.field, cache,
                                           time.perf_counter() - start, name))

    def responses(self) -> list[RefreshResponse]:
        """Refreshes finished since the last call, oldest first."""
        return _drain(self._done)

    def shutdown(self, timeout: float = 2.0) -> None:
        """Drop the request not started and stop the thread (waits for a running build)."""
        with self._cond:
            self._closed = True
            self._next.clear()
            self._cond.notify()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout)
