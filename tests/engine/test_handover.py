"""Handing a new field over while the part turns (engine.runtime.handover).

A new K's field whose first cache no longer serves the part's rotation is held back while
the refresh lane builds it one where the part will be; the field in use serves meanwhile.
Held fields are handed over once their cache serves, or after a few tries or a tenth of a
second as they are; superseded ones are dropped. And the lane: requests for two fields are
both answered, a newer one for the same field supersedes the older.
"""

from __future__ import annotations

import collections
import time

import numpy as np
import pytest

import engine.runtime as rt
import engine.runtime.handover as handover_module
from engine.params import HANDOVER_TRIES, Effects
from engine.pose import rotation_matrix
from engine.runtime.handover import Handover
from engine.runtime.jobs import FieldRequest, FieldResponse, RefreshLane, RefreshResponse

pytest.importorskip("numba")

from gaussian_pair import pair  # noqa: E402

from engine.correlation import Correlator  # noqa: E402 -- after the numba check
from engine.sim.fields import RotationCacheField  # noqa: E402

AXIS = np.array([0.48, -0.6, 0.64])
T = np.array([0.3, -0.2, 0.4])
PERIOD = 1e-3


def turned(mrad):
    return rotation_matrix(mrad * 1e-3 * AXIS)


@pytest.fixture(scope="module")
def correlator():
    d1, d2 = pair()
    return Correlator(d1, d2, modes=8, backend="numba", use_cache=False)


class Lane:
    """A lane the test drives: requests are kept until the test builds them."""

    def __init__(self):
        self.asked: list[tuple[int, RotationCacheField, np.ndarray]] = []

    def submit(self, fld, rotation):
        self.asked.append((len(self.asked) + 1, fld, np.array(rotation)))
        return len(self.asked)

    def deliver(self, handover):
        rid, fld, rot = self.asked[-1]
        handover.refreshed(RefreshResponse(rid, fld, fld.build_cache(rot)))


def held_field(correlator, full_us=2000.0):
    """A new field built at I, timed at ``full_us`` (K = 8), and its response."""
    fld = RotationCacheField(correlator.with_modes(8), 1.0, np.eye(3))
    fld.full_us = full_us
    request = FieldRequest(id=1, task="field", effects=Effects(), kappa=1.0,
                           locked_rotation=np.eye(3), modes=8)
    return fld, FieldResponse(1, request, fld)


def handover_with(lane):
    return Handover(lambda f: f.refresh_in_background(lane.submit, period=PERIOD))


def test_a_field_whose_cache_serves_is_handed_over_at_once(correlator):
    lane = Lane()
    handover = handover_with(lane)
    fld, response = held_field(correlator)
    assert not handover.hold(response, turned(3.0), PERIOD)  # within the 4 mrad limit
    assert not lane.asked and handover.held is None
    assert handover.due(turned(3.0)) is None


def test_a_field_is_held_until_a_cache_serves_where_the_part_turned_to(correlator):
    """The part turns 1 mrad a pose and is 20 mrad from the new field's first cache. The
    lane is asked for a cache where the part will be when it is built: a refresh takes
    about 1.5 full-path poses (2 ms here), so 4 poses on. It arrives two poses later; the
    field is then handed over and its first pose is served by that cache, where the field
    swapped in at once would have run the full path.
    """
    lane = Lane()
    handover = handover_with(lane)
    fld, response = held_field(correlator)
    assert handover.due(turned(19.0)) is None  # the iteration before: nothing held
    assert handover.hold(response, turned(20.0), PERIOD)
    assert handover.held is response and fld.pending == 1
    ((_, asked_field, ahead),) = lane.asked
    assert asked_field is fld
    np.testing.assert_allclose(ahead, turned(24.0), atol=1e-12)
    assert handover.due(turned(20.0)) is None  # pending: the field in use serves on
    assert handover.due(turned(21.0)) is None
    lane.deliver(handover)
    np.testing.assert_allclose(fld.reference_rotation, turned(24.0), atol=1e-12)
    assert handover.due(turned(22.0)) is response
    assert handover.held is None
    assert handover.counts == {"held": 1, "served": 1, "gave_up": 0, "dropped": 0}
    fld.evaluate(turned(23.0), T)
    assert fld.last_path == "cached"
    # the counterpart: the same field swapped in at once takes the full path
    at_once, _ = held_field(correlator)
    at_once.refresh_in_background(Lane().submit, period=PERIOD)
    at_once.evaluate(turned(23.0), T)
    assert at_once.last_path == "full"


def test_a_part_that_outruns_the_lane_is_handed_over_after_the_tries(correlator):
    """Rattling 20 mrad to and fro each pose: too fast to extrapolate (beyond the stale
    angle over the lead), and each cache is past the limit when it arrives. The lane is
    asked HANDOVER_TRIES times; then the field is handed over as it is.
    """
    lane = Lane()
    handover = handover_with(lane)
    fld, response = held_field(correlator)
    handover.due(turned(10.0))
    assert handover.hold(response, turned(20.0), PERIOD)
    given = None
    for i in range(3 * HANDOVER_TRIES):
        lane.deliver(handover)
        given = handover.due(turned(40.0 if i % 2 == 0 else 20.0))
        if given is not None:
            break
    assert given is response
    assert len(lane.asked) == HANDOVER_TRIES
    assert handover.counts["gave_up"] == 1 and handover.counts["served"] == 0


def test_a_steady_turn_is_followed_by_the_next_request(correlator):
    """10 mrad a pose, steadily: the first cache (asked for without extrapolating, the
    guess being past the stale angle) is behind when it arrives; the next request is
    carried on by the last turn over the one pose the first took, and serves.
    """
    lane = Lane()
    handover = handover_with(lane)
    fld, response = held_field(correlator)
    handover.due(turned(10.0))
    assert handover.hold(response, turned(20.0), PERIOD)
    np.testing.assert_allclose(lane.asked[0][2], turned(20.0), atol=1e-12)
    assert handover.due(turned(20.0)) is None  # the same iteration, after the hold
    lane.deliver(handover)
    assert handover.due(turned(30.0)) is None
    np.testing.assert_allclose(lane.asked[1][2], turned(40.0), atol=1e-12)
    lane.deliver(handover)
    assert handover.due(turned(40.0)) is response
    assert handover.counts["served"] == 1 and len(lane.asked) == 2


def test_a_held_field_waits_at_most_the_hand_over_time(correlator, monkeypatch):
    """Past HANDOVER_SECONDS the field is handed over with its request still pending; the
    lane's answer then goes to the field in use, as any refresh does.
    """
    lane = Lane()
    handover = handover_with(lane)
    fld, response = held_field(correlator)
    assert handover.hold(response, turned(20.0), PERIOD)
    monkeypatch.setattr(handover_module, "HANDOVER_SECONDS", 0.0)
    assert handover.due(turned(21.0)) is response
    rid, _, rot = lane.asked[-1]
    assert fld.pending == rid and fld.install(rid, fld.build_cache(rot))


def test_a_superseded_field_is_dropped(correlator):
    lane = Lane()
    handover = handover_with(lane)
    disposed = []
    handover.dispose = disposed.append  # freed off the loop's thread (Guidance: the worker)
    fld, response = held_field(correlator)
    assert handover.hold(response, turned(20.0), PERIOD)
    handover.drop()
    assert disposed == [response] and handover.held is None
    lane.deliver(handover)  # its cache arrives: nothing is installed
    np.testing.assert_array_equal(fld.reference_rotation, np.eye(3))
    assert handover.due(turned(20.0)) is None and handover.held is None
    handover.drop()  # nothing held: nothing more to count
    # a newer field arriving while one is held supersedes it too
    assert handover.hold(held_field(correlator)[1], turned(20.0), PERIOD)
    assert handover.hold(held_field(correlator)[1], turned(20.0), PERIOD)
    assert handover.counts == {"held": 3, "served": 0, "gave_up": 0, "dropped": 2}
    assert len(disposed) == 2


def test_the_lane_answers_two_fields_and_supersedes_within_one(correlator):
    """The field in use and a new K's field held back ask the lane at once: both are built
    (in the order asked). A newer request for one field replaces its request not started.
    """
    lane = RefreshLane()
    old = RotationCacheField(correlator.with_modes(8), 1.0, np.eye(3))
    new = RotationCacheField(correlator.with_modes(6), 1.0, np.eye(3))
    started = []
    build = old.build_cache

    def slow(rotation):  # holds the lane's thread while the next requests queue
        started.append(rotation)
        time.sleep(0.2)
        return build(rotation)

    old.build_cache = slow
    try:
        first = lane.submit(old, turned(1.0))
        time.sleep(0.05)  # the first build has started
        lane.submit(old, turned(2.0))
        newest_old = lane.submit(old, turned(3.0))  # supersedes turned(2.0)
        new_id = lane.submit(new, turned(4.0))
        dropped = lane.submit(RotationCacheField(correlator.with_modes(6), 1.0, np.eye(3)),
                              turned(5.0))
        lane.forget(lane._next[next(reversed(list(lane._next)))].field)  # the last field
        end = time.monotonic() + 10.0
        done = []
        while len(done) < 3 and time.monotonic() < end:
            done += lane.responses()
            time.sleep(0.01)
        time.sleep(0.3)
        done += lane.responses()
    finally:
        lane.shutdown()
    assert [d.id for d in done] == [first, newest_old, new_id]
    assert dropped not in [d.id for d in done]
    assert lane.superseded == 1
    assert [d.field for d in done] == [old, old, new]
    np.testing.assert_array_equal(done[2].cache.rotation, turned(4.0))


def test_a_k_change_while_the_part_turns_is_handed_over_where_the_part_is(small_peg_scene):
    """Guidance with the lane on: the new K's field, built at one rotation, finds the part
    20 mrad on. The field in use serves until the lane's cache for the new field lands;
    the new field then serves the part's rotation from its cache, not the full path.
    """
    from engine.runtime.guidance import Guidance
    from engine.sim import build_simulation

    sim, model = build_simulation(rt.open_scene(small_peg_scene), modes=8, backend="numba")
    guidance = Guidance(sim, model, collections.deque())
    guidance.background_refresh = True
    try:
        old = sim.field
        assert isinstance(old, RotationCacheField)
        guidance.attach(old)
        guidance.set_modes(10)
        assert guidance.worker.wait_until_idle(30.0)
        sim.state._R = rotation_matrix(2e-2 * AXIS) @ sim.state.rotation  # turned meanwhile
        guidance.take_responses()
        assert guidance.handover.held is not None and sim.field is old
        end = time.monotonic() + 10.0
        while sim.field is old and time.monotonic() < end:
            time.sleep(0.005)
            guidance.take_responses()
    finally:
        guidance.close()
    new = sim.field
    assert isinstance(new, RotationCacheField) and new.modes == 10
    assert new.serves_at(sim.state.rotation)
    assert guidance.handover.counts["served"] == 1
    new.evaluate(sim.state.rotation, sim.state.origin(sim.body))
    assert new.last_path == "cached"


class HeldLane(RefreshLane):
    """A lane that keeps its requests until the test answers them, and records hurries."""

    def __init__(self):
        super().__init__()
        self.asked: list[tuple[int, RotationCacheField, np.ndarray]] = []
        self.answers: list[RefreshResponse] = []
        self.hurries: list[bool] = []

    def submit(self, fld, rotation):
        self.asked.append((len(self.asked) + 1, fld, np.array(rotation)))
        return len(self.asked)

    def responses(self):
        out, self.answers = self.answers, []
        return out

    def hurry(self, on):
        self.hurries.append(on)


def test_the_loop_hurries_the_lane_only_while_it_waits_for_a_cache(small_peg_scene):
    """Guidance, once per iteration: the lane is hurried (engine.runtime.pacing's
    LANE_PRIORITY beside a real-time loop) while the field in use has a refresh pending and
    its last pose was not served by a cache of its own (stale, or the full path); let go
    once a cache is installed.
    """
    from engine.runtime.guidance import Guidance
    from engine.sim import build_simulation

    sim, model = build_simulation(rt.open_scene(small_peg_scene), modes=8, backend="numba")
    guidance = Guidance(sim, model, collections.deque())
    guidance.background_refresh = True
    guidance.refresh_lane = lane = HeldLane()
    try:
        fld = sim.field
        assert isinstance(fld, RotationCacheField)
        guidance.attach(fld)
        origin = sim.state.origin(sim.body)
        fld.evaluate(fld.reference_rotation, origin)
        guidance.take_responses()
        assert lane.hurries == [False] and not fld.pending  # served by the cache
        rot = rotation_matrix(3e-2 * AXIS) @ fld.reference_rotation
        fld.evaluate(rot, origin)  # past the limit angle: a refresh asked for
        assert fld.pending == 1 and fld.last_path in ("stale", "full")
        guidance.take_responses()
        assert lane.hurries[-1] is True
        rid, asked_for, at = lane.asked[-1]
        lane.answers.append(RefreshResponse(rid, asked_for, asked_for.build_cache(at)))
        guidance.take_responses()  # installed: the next pose is served by it
        assert lane.hurries[-1] is False and not fld.pending
    finally:
        guidance.close()
