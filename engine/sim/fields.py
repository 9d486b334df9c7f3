"""Geometric force fields acting on the moving part.

What the simulation asks of the correlation engine at one pose.

Data: the part's rotation (3, 3) float64 and origin (3,) float64 relative to part 1; each
field returns an :class:`engine.correlation.Evaluation` already scaled by its gain
``kappa`` (energy float, force (3,) float64, torque (3,) float64 about world axes through
the part's origin, zeros where no torque is computed).

- :class:`CorrelatorField`: the per-pose modal sum of a Correlator (torque only if its
  rotation is on);
- :class:`RotationCacheField`: rotation free, the same model evaluated from the products of
  the two spectra kept at a reference rotation (no table gathers per pose), refreshed as the
  part turns (synchronously, or by a background lane the runtime attaches);
- :class:`LandscapeField`: rotation locked, the translational energy landscape at the locked
  rotation, computed once and looked up per step (no modal sum);
- :class:`NullField`: guidance off, nothing computed.

:func:`field_for_effects` picks the cheapest of them that gives what the effects ask for.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING, Protocol

import numpy as np

from engine.correlation import Evaluation
from engine.params import (
    FULL_PATH_SHARE,
    LIMIT_ANGLE,
    MIN_POSES_PER_CACHE,
    REFRESH_ANGLE,
    STALE_ANGLE,
)
from engine.pose import rotation_matrix, rotation_vector

if TYPE_CHECKING:
    from engine.correlation import Correlator, Landscape
    from engine.correlation.rotation_cache import RotationCache
    from engine.correlation.tables import ModeTable
    from engine.params import Effects

_ZERO3 = np.zeros(3)
_ZERO3.setflags(write=False)

#: The sample of a field that computes nothing.
ZERO_EVALUATION = Evaluation(0.0, _ZERO3, _ZERO3, 0.0, 0)


class GeometricField(Protocol):
    """What the simulation needs from the correlation engine."""

    rotation: bool
    modes: int
    kappa: float

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy, force and torque at one pose, scaled by ``kappa``."""
        ...

    def set_modes(self, modes: int) -> None:
        """Keep ``modes`` modes per axis from now on."""
        ...


class NullField:
    """Guidance off: no geometric force, nothing computed."""

    rotation = False

    def __init__(self) -> None:
        self.modes = 0
        self.kappa = 0.0

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The zero sample."""
        return ZERO_EVALUATION

    def set_modes(self, modes: int) -> None:
        """Remember ``modes`` (nothing depends on it)."""
        self.modes = int(modes)


def _gain(after: np.ndarray, before: np.ndarray | None, rot: np.ndarray, t: np.ndarray,
          last: tuple[np.ndarray, np.ndarray]) -> float:
    """Energy a switch of model at this pose gave a part stepped through its poses.

    ``after`` and ``before``: ``(energy, force (3), torque (3), ...)`` of the new and the
    old model at this pose (``before`` None: nothing to compare, 0). The new model's energy
    here exceeds the old one's by the jump, and the step that arrived here already took half
    of the new force's difference over its displacement (a velocity Verlet step's second
    half-kick uses the new model): the part's gain over the old model's stretch is their sum,
    ``dE + 1/2 (dF . dt + dT . dtheta)`` (``dt``, ``dtheta`` the move from the last pose). A
    cache refreshed at every step so gains nothing; a stretch of ``n`` steps of ``s`` ends
    ``1/2 K s^2 (n^2 - n)`` richer.
    """
    if before is None:
        return 0.0
    shift = t - last[1]
    turn = rotation_vector(rot @ last[0].T)
    gain = (float(after[0]) - float(before[0])
            + 0.5 * float((after[1:4] - before[1:4]) @ shift
                          + (after[4:7] - before[4:7]) @ turn))
    return gain if math.isfinite(gain) else 0.0


def _scaled(ev: Evaluation, kappa: float, microseconds: float | None = None) -> Evaluation:
    """``ev`` times ``kappa``; a missing torque becomes zeros."""
    torque = _ZERO3 if ev.torque is None else kappa * np.asarray(ev.torque, np.float64)
    return Evaluation(
        kappa * float(ev.energy),
        kappa * np.asarray(ev.force, np.float64),
        torque,
        float(ev.microseconds if microseconds is None else microseconds),
        int(ev.modes),
    )


class CorrelatorField:
    """The per-pose modal sum of a Correlator, times ``kappa``.

    The correlator is built with ``kappa=1``; this field scales by its own ``kappa`` so that
    the gain can change live. With ``rotation=False`` on the correlator no torque is
    computed and the torque is reported as zeros.
    """

    def __init__(self, correlator: Correlator, kappa: float):
        self.correlator = correlator
        self.kappa = float(kappa)
        self.rotation = bool(correlator.rotation)
        self.modes = int(correlator.modes)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The correlator's evaluation at ``(rotation, translation)``, times kappa."""
        return _scaled(self.correlator.evaluate(rotation, translation), self.kappa)

    def set_modes(self, modes: int) -> None:
        """Change the correlator's modes per axis."""
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)


class LandscapeField:
    """Rotation locked: the translational energy landscape at the locked rotation.

    Computed once (an inverse FFT over all translations) and looked up per step, times
    ``kappa``.
    """

    rotation = False

    def __init__(self, correlator: Correlator, locked_rotation: np.ndarray, kappa: float):
        self.correlator = correlator
        self.locked_rotation = np.array(locked_rotation, np.float64).reshape(3, 3)
        self.kappa = float(kappa)
        self.modes = int(correlator.modes)
        self.landscape: Landscape = correlator.landscape(self.locked_rotation)

    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """The landscape's value at ``translation`` (``rotation`` is the locked one)."""
        return _scaled(self.landscape.lookup(np.asarray(translation, np.float64)), self.kappa)

    def set_modes(self, modes: int) -> None:
        """Change the modes and recompute the landscape (an FFT, tens of ms)."""
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)
        self.landscape = self.correlator.landscape(self.locked_rotation)


#: Submits a background refresh: ``submit(field, rotation)`` returns the request's id.
RefreshSubmitter = Callable[["RotationCacheField", np.ndarray], int]


def _angle_between(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (radians) of the rotation from ``b`` to ``a``: ``|a - b|_F = 2 sqrt 2 sin(x/2)``."""
    half = float(np.linalg.norm(a - b)) / (2.0 * np.sqrt(2.0))
    return 2.0 * float(np.arcsin(min(half, 1.0)))


class RotationCacheField:
    """Rotation free: the correlator's model evaluated from a rotation cache, times ``kappa``.

    The cache (:mod:`engine.correlation.rotation_cache`) keeps the products of the two
    spectra at a reference rotation ``R0``; a pose costs the translation phases and three
    contractions over the kept cube, no table gathers, and the force and torque are the exact
    derivatives of the energy reported. The model is first order in the rotation since
    ``R0``, so the cache is rebuilt at the part's rotation once that has moved more than
    ``refresh_angle`` from ``R0``:

    - synchronously, in :meth:`evaluate`, by default (headless and unpaced runs: the
      trajectory does not depend on timing), unless the part turns so fast (by the angle
      it moved since the last pose) that a new cache would serve fewer than ``min_poses``
      poses: then the full path runs;
    - in the background once :meth:`refresh_in_background` attached a submitter (the
      runtime's refresh lane, when the loop is paced in real time): the request goes out
      at half the refresh angle, for the rotation the part will have when the cache
      arrives (extrapolated from its last turn over the poses the last refresh took, as far
      as the old cache serves);
      :meth:`install` swaps the new cache in between two steps, and meanwhile the old cache
      serves up to ``limit_angle``, beyond which the full per-pose path runs; where that
      path costs more than the lane's budget (:attr:`full_us` against the budget given
      with the submitter), the old cache serves on up to ``stale_angle`` ("stale" poses),
      so that no pose breaks the loop's period, and the full path runs only beyond.

    Each switch of model (a refresh, or the full path taking over) reports in
    ``Evaluation.switched`` the energy the first-order model gave the part over the stretch
    it served (it lacks the curvature in the rotation since its anchor; :func:`_gain`),
    which the simulation takes back (docs/correlation.md, "What a refresh gives the part").

    Built (its first cache included) wherever it is constructed: the runtime's worker.
    ``last_path`` says which path served the last pose (``"cached"``, ``"refreshed"``,
    ``"stale"``, ``"full"``); ``counts`` counts them and the refreshes.
    """

    rotation = True

    def __init__(self, correlator: Correlator, kappa: float, rotation: np.ndarray, *,
                 refresh_angle: float = REFRESH_ANGLE, limit_angle: float = LIMIT_ANGLE,
                 stale_angle: float | None = None, min_poses: float = MIN_POSES_PER_CACHE):
        from engine.correlation.rotation_cache import build_rotation_cache, cached_pose

        if stale_angle is None:  # the default, or the limit angle where that is larger
            stale_angle = max(STALE_ANGLE, limit_angle)
        if not (0.0 < refresh_angle <= limit_angle <= stale_angle):
            raise ValueError(f"the refresh, limit and stale angles ({refresh_angle!r}, "
                             f"{limit_angle!r}, {stale_angle!r}) must be positive and "
                             "in increasing order")
        self._build: Callable[[ModeTable, np.ndarray], RotationCache] = build_rotation_cache
        self._pose: Callable[..., np.ndarray] = cached_pose
        self.correlator = correlator
        self.kappa = float(kappa)
        self.modes = int(correlator.modes)
        self.refresh_angle = float(refresh_angle)
        self.limit_angle = float(limit_angle)
        self.stale_angle = float(stale_angle)
        self.min_poses = float(min_poses)
        self.cache: RotationCache = self._build(correlator.table, rotation)
        self._submit: RefreshSubmitter | None = None
        #: The most a full-path pose may cost on the evaluating thread (microseconds)
        self.budget_us = math.inf
        #: Microseconds of one full-path pose (:meth:`measure_full_path`; None: not measured)
        self.full_us: float | None = None
        self._pending = 0  # id of the background refresh asked for; 0: none
        self._waited = 0  # poses since it was asked for
        self._lead = 0  # poses the last background refresh took to arrive
        self._last = self.cache.rotation  # the last pose's rotation
        self._last_t: np.ndarray | None = None  # and its translation (None: no pose yet)
        self._previous: RotationCache | None = None  # the cache a background refresh replaced
        self.last_path = "cached"
        self.counts = {"cached": 0, "refreshed": 0, "stale": 0, "full": 0, "refreshes": 0,
                       "background_refreshes": 0}

    # -- the pose ---------------------------------------------------------------------------
    def evaluate(self, rotation: np.ndarray, translation: np.ndarray) -> Evaluation:
        """Energy, force and torque at one pose, times kappa (see the class docstring)."""
        start = time.perf_counter()
        rot = np.ascontiguousarray(rotation, dtype=np.float64).reshape(3, 3)
        t = np.ascontiguousarray(translation, dtype=np.float64).reshape(3)
        cache = self.cache
        out = self._pose(cache, rot, t, self.kappa)
        path = "cached"
        self._waited += 1
        last_t = self._last_t
        self._last_t = t.copy()
        # the model that served the last pose, evaluated at this one (None: the full path
        # served it, or this field served none)
        before = out if self.last_path != "full" and last_t is not None else None
        if self._previous is not None:  # a background refresh was installed since
            if before is not None:
                before = self._pose(self._previous, rot, t, self.kappa)
            self._previous = None
        last = (self._last, t if last_t is None else last_t)  # the last pose
        if not out[7] <= self.refresh_angle:  # also NaN: a bad pose goes to the full path
            if self._submit is None:
                # a refresh costs about two full poses: not worth it while the part turns
                # so fast (the angle it moved since the last pose, at least) that the new
                # cache would serve fewer than min_poses poses
                moved = _angle_between(rot, self._last)
                self._last = rot.copy()
                if not self.min_poses * moved <= self.refresh_angle:
                    return self._full(rot, t, start, before, last)
                cache = self.cache = self._build(cache.table, rot)
                self.counts["refreshes"] += 1
                out = self._pose(cache, rot, t, self.kappa)
                path = "refreshed"
            elif not out[7] <= self.limit_angle:
                self._ask(rot)
                if not (out[7] <= self.stale_angle and self._full_too_slow()):
                    return self._full(rot, t, start, before, last)
                path = "stale"
        if self._submit is not None and out[7] > 0.5 * self.refresh_angle:
            self._ask(rot)
        self.last_path = path
        self.counts[path] += 1
        self._last = rot.copy()
        gain = 0.0 if before is out else _gain(out, before, rot, t, last)
        return Evaluation(float(out[0]), out[1:4], out[4:7],
                          (time.perf_counter() - start) * 1e6, cache.table.modes, gain)

    def _ask(self, rot: np.ndarray, reach: float | None = None) -> None:
        """Ask the background lane for a cache, unless one is pending.

        Asked for at half the refresh angle, at the rotation the part will have when it
        arrives: this one carried on by the last pose's turn for as many poses as the last
        background refresh took, if that is less than ``reach``: by default the angle up to
        which the old cache serves meanwhile (the stale angle where the full path is over
        its budget, else the limit angle).
        """
        if self._pending or self._submit is None:
            return
        ahead = rot
        if self._lead > 0:
            turn = rotation_vector(rot @ self._last.T)
            if reach is None:  # where stale poses serve, so may a cache asked for further ahead
                reach = self.stale_angle if self._full_too_slow() else self.limit_angle
            if np.linalg.norm(turn) * self._lead < reach:
                ahead = rotation_matrix(turn * self._lead) @ rot
        self._waited = 0
        self._pending = self._submit(self, np.array(ahead))

    def ask_ahead(self, rotation: np.ndarray, previous: np.ndarray, lead: int) -> int:
        """Ask the lane for a cache where the part will be ``lead`` poses from now.

        For a field built and not in use yet (the runtime's hand-over,
        ``engine.runtime.handover``): the part turned from ``previous`` to ``rotation`` over
        its last pose, and is assumed to go on turning so, up to the stale angle. Returns
        the request's id (0: no lane attached).
        """
        rot = np.array(rotation, dtype=np.float64).reshape(3, 3)
        self.take_up(previous, lead)
        self._pending = 0
        self._ask(rot, reach=self.stale_angle)
        self._last = rot
        return self._pending

    def take_up(self, previous: np.ndarray, lead: int) -> None:
        """Start where the field in use leaves off: its last pose's rotation was ``previous``.

        ``lead``: the poses a background refresh took, the first request's extrapolation.
        """
        self._last = np.array(previous, dtype=np.float64).reshape(3, 3)
        self._lead = max(0, int(lead))

    def serves_at(self, rotation: np.ndarray) -> bool:
        """Whether the cache in use serves ``rotation`` without the full path (limit angle)."""
        return _angle_between(np.asarray(rotation), self.cache.rotation) <= self.limit_angle

    def _full(self, rot: np.ndarray, t: np.ndarray, start: float,
              before: np.ndarray | None, last: tuple[np.ndarray, np.ndarray]) -> Evaluation:
        self.last_path = "full"
        self.counts["full"] += 1
        self._last = rot.copy()
        ev = _scaled(self.correlator.evaluate(rot, t), self.kappa,
                     (time.perf_counter() - start) * 1e6)
        torque = _ZERO3 if ev.torque is None else ev.torque
        after: np.ndarray = np.concatenate(([ev.energy], ev.force, torque))
        return replace(ev, switched=_gain(after, before, rot, t, last))

    # -- refreshes --------------------------------------------------------------------------
    @property
    def reference_rotation(self) -> np.ndarray:
        """(3, 3) the rotation the cache in use was built at."""
        return self.cache.rotation

    @property
    def pending(self) -> int:
        """Id of the background refresh asked for and not installed yet (0: none)."""
        return self._pending

    def refresh_in_background(self, submit: RefreshSubmitter | None,
                              period: float | None = None) -> None:
        """Refresh through ``submit`` from now on (None: synchronously, in :meth:`evaluate`).

        ``period``: the loop's period (seconds). A full-path pose then has
        :data:`~engine.params.FULL_PATH_SHARE` of it as its budget (:attr:`budget_us`);
        beyond it, while a refresh is pending, the old cache serves up to the stale angle
        instead. A field whose full path was not timed yet (one the runtime's worker did
        not build) is timed here: call this before the loop runs.
        """
        self._submit = submit
        self.budget_us = math.inf
        if submit is not None and period is not None:
            if self.full_us is None:
                self.measure_full_path()
            self.budget_us = FULL_PATH_SHARE * float(period) * 1e6
        self._pending = 0

    def measure_full_path(self, calls: int = 3) -> float:
        """Time the full path (median of ``calls`` poses, microseconds); sets :attr:`full_us`.

        At the cache's rotation with the two grid boxes centred on each other, so that the
        boxes overlap and the whole sum runs. For the thread that builds the field (the
        runtime's worker), before it is handed over.
        """
        g = self.correlator.table.geometry
        rot = self.cache.rotation
        t = g.centre_fixed - rot @ g.centre_moving
        times = []
        for _ in range(max(1, int(calls))):
            begin = time.perf_counter()
            self.correlator.evaluate(rot, t)
            times.append((time.perf_counter() - begin) * 1e6)
        self.full_us = float(np.median(times))
        return self.full_us

    def _full_too_slow(self) -> bool:
        """Whether a full-path pose was measured to cost more than the budget."""
        return self.full_us is not None and self.full_us > self.budget_us

    def build_cache(self, rotation: np.ndarray) -> RotationCache:
        """A cache of the current table at ``rotation`` (only reads; any thread)."""
        return self._build(self.cache.table, rotation)

    def catch_up(self, rotation_now: Callable[[], np.ndarray], *, tries: int = 3) -> int:
        """Rebuild the first cache at the part's rotation now; returns the rebuilds.

        For the thread that built the field, before it is handed over. The first cache is
        built at the rotation the part had when the field was asked for; a part that turned
        meanwhile (a new K takes tens of milliseconds on a real grid) would be past the
        limit angle when the field is swapped in, and the full path would serve until the
        first background refresh arrived. Rebuilt until the part turns less than half the
        refresh angle during a build, at most ``tries`` times.
        """
        rebuilt = 0
        for _ in range(tries):
            rot = np.array(rotation_now(), dtype=np.float64).reshape(3, 3)
            if _angle_between(rot, self.cache.rotation) <= 0.5 * self.refresh_angle:
                break
            self.cache = self.build_cache(rot)
            self._last = self.cache.rotation
            rebuilt += 1
        return rebuilt

    def install(self, request_id: int, cache: RotationCache) -> bool:
        """Swap in ``cache``, built for request ``request_id`` (the thread that evaluates).

        False (and nothing changes) when that request is no longer the one pending, or the
        cache belongs to another table (the modes changed meanwhile).
        """
        if request_id != self._pending:
            return False
        self._pending = 0
        if cache.table is not self.cache.table:
            return False
        self._previous = self.cache  # the next pose measures the switch against it
        self.cache = cache
        self._lead = self._waited
        self.counts["refreshes"] += 1
        self.counts["background_refreshes"] += 1
        return True

    def refresh_failed(self, request_id: int) -> None:
        """The background refresh ``request_id`` failed: the next pose asks again."""
        if request_id == self._pending:
            self._pending = 0

    def set_modes(self, modes: int) -> None:
        """Change the correlator's modes and rebuild the cache at its rotation (here, now).

        The runtime does not call this on the loop thread: a K change builds a new field in
        its worker.
        """
        self.correlator.set_modes(int(modes))
        self.modes = int(modes)
        self._pending = 0
        self._previous = None
        self.cache = self._build(self.correlator.table, self.cache.rotation)

    def describe(self) -> str:
        """The evaluator in words: the cache, how it is refreshed, the full path beneath."""
        how = ("in the background" if self._submit is not None else "synchronously")
        beyond = self.stale_angle if self._full_too_slow() else self.limit_angle
        return (f"rotation cache (refreshed {how} every {self.refresh_angle * 1e3:g} mrad; "
                f"full path beyond {beyond * 1e3:g} mrad while one is pending: "
                f"{self.correlator.backend_name})")


def cache_serves(correlator: Correlator) -> bool:
    """Whether a :class:`RotationCacheField` can serve ``correlator``.

    Rotation on, the kept cube, part 2's table within the compiled kernels' reach, numba
    present, and a compiled per-pose backend in use (one asked for the numpy reference gets
    it).
    """
    from engine.backend import backend_problem
    from engine.correlation import Correlator

    if not isinstance(correlator, Correlator):  # another field source (a test's well)
        return False
    if (correlator.backend == "numpy" or correlator.selection != "cube"
            or backend_problem("numba") is not None):
        return False
    from engine.correlation.rotation_cache import serves

    return bool(correlator.rotation) and serves(correlator.table)


def field_correlator(fld: GeometricField) -> Correlator | None:
    """The correlator behind a field (None: a field without one, guidance off)."""
    if isinstance(fld, (CorrelatorField, LandscapeField, RotationCacheField)):
        return fld.correlator
    return None


def evaluator_name(fld: GeometricField) -> str:
    """The per-pose evaluator behind a field, in words (the frames' and reports' "backend")."""
    if isinstance(fld, RotationCacheField):
        return fld.describe()
    if isinstance(fld, (CorrelatorField, LandscapeField)):
        return str(fld.correlator.backend_name or type(fld).__name__)
    return type(fld).__name__


def field_for_effects(
    effects: Effects,
    make_correlator: Callable[[bool], Correlator] | None,
    *,
    kappa: float,
    locked_rotation: np.ndarray,
    rotation_cache: bool = True,
) -> GeometricField:
    """The cheapest field that provides what ``effects`` asks for.

    Parameters
    ----------
    effects : Effects
    make_correlator : callable(rotation: bool) -> Correlator, or None
        Builds the correlator; called with ``rotation=False`` when rotation is locked so
        that no torque spectra or sums are computed. Not called when guidance is off or no
        moving part exists (None).
    kappa : float
    locked_rotation : (3, 3) float64
        The part's rotation: the locked one when rotation is locked, else where the rotation
        cache is first built.
    rotation_cache : bool
        With rotation free, evaluate from a rotation cache where one can serve the
        correlator (:func:`cache_serves`); False: always the full per-pose path.

    Returns
    -------
    NullField, LandscapeField (rotation locked), RotationCacheField (rotation free, the
    cache serves) or CorrelatorField.
    """
    if effects.guidance == "none" or make_correlator is None:
        return NullField()
    if not effects.rotation:
        return LandscapeField(make_correlator(False), locked_rotation, kappa)
    correlator = make_correlator(True)
    if rotation_cache and cache_serves(correlator):
        return RotationCacheField(correlator, kappa, locked_rotation)
    return CorrelatorField(correlator, kappa)
