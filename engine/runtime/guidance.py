"""The loop's geometric field and physics.

What the user asked for, the background jobs that build it, and the hand-over between two
steps.

Data: the desired state (effects, coupling, kappa, K, descriptor parameters) and the
descriptors in use (``engine.descriptor.Descriptor`` of part 1 and part 2). Everything that
costs more than a step (descriptors, correlators, spectra, landscapes, a new K) is a frozen
request to the :class:`engine.runtime.jobs.JobWorker`; cheap changes (physics gains, free
axes) apply between two steps. Events go to the loop's event queue.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from engine.correlation import Correlator, LocalSpectral
from engine.errors import Cancelled
from engine.params import CouplingParams, DescriptorParams, Effects, Physics
from engine.runtime.fine_level import FineLevels
from engine.runtime.handover import Handover
from engine.runtime.job_process import JobProcess, JobProcessGone
from engine.runtime.jobs import (
    FieldModel,
    FieldRequest,
    FieldResponse,
    JobWorker,
    LadderResponse,
    LandscapeResponse,
    NearResponse,
    RefreshLane,
    Response,
    build_field,
    next_id,
)
from engine.runtime.ladder_jobs import LadderJobs
from engine.runtime.landscapes import Landscapes
from engine.runtime.messages import (
    DescriptorsSwapped,
    ErrorEvent,
    Event,
    ProgressEvent,
    ReadyEvent,
    describe_error,
)
from engine.sim import (
    GeometricField,
    RotationCacheField,
    Simulation,
    evaluator_name,
    field_correlator,
)

if TYPE_CHECKING:
    from engine.descriptor import Descriptor

__all__ = ["Guidance"]

_log = logging.getLogger(__name__)


class Guidance:
    """Keeps a simulation's field and physics up to date with the user's commands.

    Parameters
    ----------
    sim : Simulation
    model : FieldModel or None
        The scene's ``engine.sim.SceneModel``: rebuilds physics and fields. None: a field
        handed in by the caller, which commands that rebuild it (K, descriptors, guidance)
        cannot change (they answer ErrorEvent).
    events : deque
        Where events go.
    """

    def __init__(self, sim: Simulation, model: FieldModel | None,
                 events: collections.deque[Event]):
        self.sim = sim
        self.model = model
        self.events = events
        self.worker = JobWorker()
        self.refresh_lane = RefreshLane()
        self.handover = Handover(self.attach, self.worker.dispose)  # waits for a cache
        self.landscapes = Landscapes(self.worker, events)
        self.fine = FineLevels(sim, model, self.worker, events)  # the fine level, built after
        self.ladder = LadderJobs(model, self.worker, events)  # sigma ladders, after both
        #: Refresh rotation caches in the refresh lane (the loop is paced in real time);
        #: False: synchronously, in the step (reproducible, for unpaced runs).
        self.background_refresh = False
        #: Truncations and landscapes in a process of their own (job_process.wanted decides)
        self.job_process = False
        self.jobs: JobProcess | None = None
        #: Why that work runs in this process after all (None: it does not, or need not).
        self.jobs_problem: str | None = None
        self.effects = sim.effects
        self.coupling: CouplingParams | None = None
        self.kappa: float | None = None  # None: the scale-invariant default
        #: The descriptor parameters asked for (SetDescriptorParams); None: the scene's.
        self.descriptor: DescriptorParams | None = None
        self.modes = int(sim.field.modes)
        # a field built before the loop lends its descriptors to a new K, as one built in it
        self.descriptors: tuple[Descriptor, ...] = (
            () if model is None else model.descriptors_of(sim.field))
        self.recompute: float | None = None  # fraction done of a descriptor job
        self.ready_message = ""
        self._in_use: tuple[str, DescriptorParams | None] = (
            self.effects.guidance if self.descriptors else "", None)
        self._field_id = 0  # newest field request
        self._field_task = ""
        self._physics_dirty = False
        # the last physics resolved and what it was resolved from: resolving reads the
        # mesh's mass properties (milliseconds), so a K change must not do it on the loop
        self._resolved: tuple[tuple[object, ...], Physics] | None = None
        self._deferred = False  # a field change waits for the descriptors being computed
        #: What was in use before a coarse field at new parameters (None: no coarse one)
        self._coarse_from: tuple[str, DescriptorParams | None] | None = None

    # -- requests -------------------------------------------------------------------------------
    def prepare(self, modes: int) -> None:
        """Build the first field in the background (ReadyEvent when done).

        A scene whose descriptors are not cached gets a first field on a coarse grid
        (seconds); the scene's own are then computed like a sigma change (progress, then
        DescriptorsSwapped), while the part can already be dragged.
        """
        self.modes = int(modes)
        if self.job_process and self.jobs is None:
            # started now, its imports run while the first field is built
            self.jobs = JobProcess()
        self._request("correlator", coarse_first=True)

    def set_modes(self, modes: int) -> None:
        """New K: a new field is built in the background; the old one steps meanwhile."""
        self.modes = int(modes)
        self._request("field")

    def set_descriptor_params(self, params: DescriptorParams) -> None:
        """New descriptor parameters (the scene's replaced whole): recompute in the background.

        A new penalty rescales the cached descriptors; a new sigma is interpolated from the
        sigma ladders where they serve it (:mod:`engine.runtime.ladder_jobs`), else a coarse
        field comes first (seconds), then the scene's grid; Cancel returns to the sigma before.
        """
        self.descriptor = params
        self._request("descriptors", coarse_first=True)

    def set_effects(self, effects: Effects) -> None:
        """New effects (axes, damping, gravity); a new guidance or rotation lock: a new field."""
        old, self.effects = self.effects, effects
        self._physics_dirty = True
        if old.guidance != effects.guidance or old.rotation != effects.rotation:
            self._request("descriptors" if old.guidance != effects.guidance else "field")

    def set_coupling(self, coupling: CouplingParams) -> None:
        """New coupling gains (applied by :meth:`apply_physics`)."""
        self.coupling = coupling
        self._physics_dirty = True

    def set_kappa(self, kappa: float | None) -> None:
        """New geometric gain (applied by :meth:`apply_physics`)."""
        self.kappa = kappa
        self._physics_dirty = True

    def cancel_recompute(self) -> None:
        """Cancel the running field job: the field in use and its descriptor parameters stay."""
        if self.worker.cancel("field"):
            self.events.append(ProgressEvent(self._field_task, 1.0, "cancelled"))
        self._field_id = 0
        self.handover.drop()
        self.recompute = None
        _, self.descriptor = self._coarse_from or self._in_use
        if self._coarse_from is not None:  # back to the descriptors before the coarse field
            self._request("descriptors")
            return
        if self._deferred:  # a K or rotation change waited for the cancelled job
            self._deferred = False
            self._request("field")

    def request_landscape(self, rotvec: tuple[float, ...] | None) -> None:
        """Landscape at ``rotvec`` (default: the part's rotation), computed by the worker."""
        pose = self.sim.part_pose()[3:] if rotvec is None else rotvec
        self.landscapes.request(self.sim.field, tuple(float(v) for v in pose))

    def _request(self, task: str, *, coarse_first: bool = False) -> None:
        model = self.model
        if model is None:
            raise RuntimeError("this engine has no scene model to rebuild its field from")
        if task == "field" and self.recompute is not None:
            # descriptors are being computed: a new K or rotation lock must not cancel them;
            # it is applied to the field they make (see _field)
            self._deferred = True
            return
        key = (self.effects.guidance, self.descriptor)
        # only a new K or rotation lock reuses the descriptors in use; "descriptors" computes
        # them (a new sigma, or the scene's own after a coarse first field)
        reuse = self.descriptors if key == self._in_use and task == "field" else ()
        if not reuse and task == "field" and self.effects.guidance != "none":
            task = "descriptors"  # no descriptors to reuse: they are computed (or loaded)
        current = field_correlator(self.sim.field)
        rot = self.sim.state.rotation.copy()
        rot.setflags(write=False)
        request = FieldRequest(
            id=next_id(), task=task, effects=self.effects, kappa=self._physics().kappa,
            locked_rotation=rot, modes=self.modes, descriptor=self.descriptor,
            descriptors=reuse, backend=current.backend if current is not None else "",
            correlator=current if reuse else None, coarse_first=coarse_first,
        )
        self._field_id, self._field_task = request.id, task
        self.handover.drop()  # a field held back is superseded
        self.fine.cancel()
        self.ladder.pause()
        report = task != "field"
        self.recompute = 0.0 if task == "descriptors" else None

        def progress(fraction: float) -> None:
            if request.id == self._field_id:
                if task == "descriptors":
                    self.recompute = float(fraction)
                self.events.append(ProgressEvent(task, float(fraction)))

        def run(cancelled: Callable[[], bool]) -> Response:
            try:
                # the part turns on while the field is built only where the loop is paced
                return build_field(model, request, progress=progress if report else None,
                                   cancel=cancelled, rotation_now=(
                                       self._rotation_now if self.background_refresh else None))
            except Cancelled:
                raise
            except Exception as exc:  # delivered to the loop, never raised in the worker
                return FieldResponse(request.id, request, error=exc)

        self.worker.submit("field", run)

    def _rotation_now(self) -> np.ndarray:
        """The part's rotation as the loop last stepped it (any thread).

        The loop replaces the state's rotation matrix at each step rather than writing
        into it, so the matrix read here is whole.
        """
        return self.sim.state.rotation

    def attach(self, fld: GeometricField) -> None:
        """Let a rotation-cache field refresh in the lane when the loop is paced.

        The period budgets its full path (timed there if the worker did not build it).
        """
        if isinstance(fld, RotationCacheField):
            if self.background_refresh:
                fld.refresh_in_background(self.refresh_lane.submit, period=self.sim.dt)
            else:
                fld.refresh_in_background(None)

    # -- between two steps (loop thread) --------------------------------------------------------
    def apply_physics(self) -> None:
        """Resolve and apply the physics if a command changed it (once per batch)."""
        if self._physics_dirty:
            self._physics_dirty = False
            self.sim.set_effects(self.effects, self._physics())

    def take_responses(self) -> None:
        """Swap in fields, caches and fine levels; deliver landscapes; drop what is superseded.

        With the lane on, a new field waits for a cache of its own (engine.runtime.handover).
        """
        fld = self.sim.field
        for done in self.refresh_lane.responses():
            if done.field is not fld:
                self.handover.refreshed(done)
            elif done.cache is None:
                fld.refresh_failed(done.id)
            else:
                fld.install(done.id, done.cache)
        for response in self.worker.responses():
            if isinstance(response, LandscapeResponse):
                self.landscapes.deliver(response)
            elif isinstance(response, NearResponse):
                self.fine.deliver(response, tuple(self.descriptors))
            elif isinstance(response, LadderResponse):
                self.ladder.deliver(response)
            else:
                self._field(response)
        held = self.handover.due(self.sim.state.rotation)
        if held is not None:
            self._swap(held, attached=True)
        fld = self.sim.field  # the loop waits for the lane while its poses are not cached
        self.refresh_lane.hurry(isinstance(fld, RotationCacheField) and fld.pending != 0
                                and fld.last_path in ("stale", "full"))

    def _field(self, r: FieldResponse) -> None:
        if r.id != self._field_id:
            return  # superseded
        self.recompute = None
        if r.error is not None or r.field is None:
            err = r.error or RuntimeError("no field")
            self.events.append(ErrorEvent(describe_error(err), type(err).__name__))
        elif not (self.background_refresh
                  and self.handover.hold(r, self.sim.state.rotation, self.sim.dt)):
            self._swap(r)

    def _swap(self, r: FieldResponse, *, attached: bool = False) -> None:
        assert r.field is not None
        req = r.request
        if isinstance(self.sim.field, RotationCacheField):
            self.refresh_lane.forget(self.sim.field)
        self.worker.dispose(self.sim.field)  # its arrays are freed there, not in a period
        self.sim.set_field(r.field)
        self.fine.swapped(r, tuple(self.descriptors))
        self.ladder.resume(r)  # queued behind the fine level
        if not attached:
            self.attach(r.field)
        self.offload(r.field)
        if self.model is not None:  # the fit's stiffness is the new field's
            self.model.geometric_rotation = r.stiffness
        self._physics_dirty = True
        self.descriptors = r.descriptors
        if req.task == "descriptors" and r.coarse_grid is not None:
            self._coarse_from = self._coarse_from or self._in_use
        elif req.task != "field":
            self._coarse_from = None
        self._in_use = (req.effects.guidance, req.descriptor)
        if req.task == "correlator":
            message = self.ready_message
            if r.coarse_grid is not None:
                message += (f"; a coarse first field (grid {r.coarse_grid}) while the scene's "
                            "own descriptors are computed")
            self.events.append(ReadyEvent(r.descriptors, evaluator_name(r.field), message,
                                          coarse_grid=r.coarse_grid))
            if r.coarse_grid is not None:
                self._request("descriptors")
        elif req.task == "field":  # built without progress reports: say that it is done
            self.events.append(ProgressEvent("field", 1.0, "done"))
        elif req.task == "descriptors":
            params = r.descriptors[0].params if r.descriptors else req.descriptor
            sigma, penalty = (0.0, 0.0) if params is None else (params.sigma, params.penalty)
            self.events.append(DescriptorsSwapped(r.descriptors, float(sigma), float(penalty),
                                                  r.seconds, coarse_grid=r.coarse_grid))
            if r.coarse_grid is not None:  # the scene's own grid at these parameters follows
                self._request("descriptors")
            elif self._deferred or req.modes != self.modes or req.effects != self.effects:
                self._deferred = False
                self._request("field")

    def offload(self, fld: GeometricField) -> None:
        """Have the job process compute ``fld``'s truncations and landscapes (:func:`offload`)."""
        offload(self, fld)

    def _physics(self) -> Physics:
        if self.model is None:
            kappa = self.sim.physics.kappa if self.kappa is None else self.kappa
            return replace(self.sim.physics, kappa=kappa)
        key = (self.effects, self.coupling, self.kappa, self.model.geometric_rotation)
        if self._resolved is None or self._resolved[0] != key:
            self._resolved = (key, self.model.physics(self.effects, self.coupling, self.kappa))
        return self._resolved[1]

    def close(self) -> None:
        """Cancel the jobs and stop the worker and the refresh lane."""
        self.worker.shutdown()
        self.refresh_lane.shutdown()
        if self.jobs is not None:
            self.jobs.close()


def offload(guidance: Guidance, fld: GeometricField) -> None:
    """Have the job process compute ``fld``'s correlator's truncations and landscapes.

    A worker job (the spectra cross once); a new K's correlators share it. Nothing when
    the guidance's :attr:`Guidance.job_process` is off.
    """
    corr = field_correlator(fld)
    if (not guidance.job_process or not isinstance(corr, Correlator)
            or not isinstance(corr.spectral, LocalSpectral)):
        return

    def run(cancelled: Callable[[], bool]) -> None:
        try:
            if guidance.jobs is None:
                guidance.jobs = JobProcess()
            corr.spectral = guidance.jobs.spectral(corr.spectra)  # one assignment
        except (JobProcessGone, OSError) as exc:  # the work stays here: same results
            guidance.jobs_problem = str(exc)
            _log.warning("truncations and landscapes run in the loop's process: %s", exc)

    guidance.worker.submit("offload", run)
