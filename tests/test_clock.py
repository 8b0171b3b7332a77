"""Tests for kilonet.clock: reusable timers and the loop round that stands in for one timer
per robot loop."""

from __future__ import annotations

import pytest
import simpy
from hypothesis import given
from hypothesis import strategies as st

from kilonet.clock import LoopRound, Timer

# Coarse values on purpose: loops and other events often fall due at the very same time, where
# only the insertion order SimPy keeps decides which runs first.
_PERIOD_S = st.sampled_from([0.25, 0.5, 1.0, 0.3])
_FIRST_S = st.lists(st.sampled_from([0.0, 0.1, 0.2, 0.05]), min_size=1, max_size=8)
_EVENT_TIMES = st.lists(st.sampled_from([0.0, 0.1, 0.25, 0.5, 0.6, 1.0, 1.3, 2.0]), max_size=12)
_CHUNK_S = st.sampled_from([3.0, 1.0, 0.5, 0.25, 0.7])
_WHEN = st.sampled_from([0.0, 0.5, 1.0, 4.0])  # 4 s: never, in a 3 s run


class Boom(RuntimeError):
    """What a loop raises in these tests."""


def _journal(period_s, first_s, event_times, chunk_s, *, round_of_loops, stops=None, raises=None):
    """(what, simulated time) of every loop call and every other event in a 3 s run, with the
    loops on one Timer each or in a LoopRound, added in turn with the other events (as the
    simulation adds a robot's loop after its first transmit opportunity).

    The run goes in chunks of ``chunk_s`` (as a progress bar runs it). Every loop call queues
    events of its own: one half a period ahead, one a whole period ahead (due with the loop's
    next call) and one urgent at once. Loop k stops for good at ``stops[k]`` s, and raises
    :class:`Boom` the first time it runs at or after ``raises[k]`` s; the run carries on."""
    env = simpy.Environment()
    journal = []
    stops, raises = stops or {}, raises or {}

    def event(name):
        return Timer(env, lambda _timer: journal.append((name, env.now)), None)

    def loop_call(k):
        def call():
            if env.now >= stops.get(k, float("inf")):
                return False
            journal.append((f"loop {k}", env.now))
            event(f"half a period after loop {k}").schedule(period_s / 2)
            event(f"a period after loop {k}").schedule(period_s)
            urgent = env.event()
            urgent.callbacks.append(lambda _e: journal.append((f"urgent from {k}", env.now)))
            urgent.succeed()
            if env.now >= raises.get(k, float("inf")):
                raise Boom(k)
            return True

        return call

    loops = LoopRound(env, period_s)
    for k, first in enumerate(first_s):
        for j, t in enumerate(event_times[k :: len(first_s)]):
            event(f"event {k}.{j}").schedule(t)
        call = loop_call(k)
        if round_of_loops:
            loops.add(first, call)
        else:
            Timer(env, lambda timer, call=call: call() and timer.schedule(period_s), k).schedule(
                first
            )
    loops.start()
    while env.now < 3.0:
        try:
            env.run(until=min(3.0, env.now + chunk_s))
        except Boom as exc:
            journal.append((f"loop {exc.args[0]} raised", env.now))
    return journal


@given(_PERIOD_S, _FIRST_S, _EVENT_TIMES, _CHUNK_S)
def test_a_loop_round_runs_loops_when_and_in_the_order_one_timer_each_would(
    period_s, first_s, event_times, chunk_s
):
    separate = _journal(period_s, first_s, event_times, chunk_s, round_of_loops=False)
    joint = _journal(period_s, first_s, event_times, chunk_s, round_of_loops=True)
    assert joint == separate
    assert sum(what.startswith("loop") for what, _ in joint) >= len(first_s) * (3.0 // period_s)


@given(_PERIOD_S, _FIRST_S, _EVENT_TIMES, _CHUNK_S, st.data())
def test_a_loop_that_stops_or_raises_leaves_the_round_and_the_others_go_on(
    period_s, first_s, event_times, chunk_s, data
):
    stops = {k: data.draw(_WHEN) for k in range(len(first_s))}
    raises = {k: data.draw(_WHEN) for k in range(len(first_s))}
    kwargs = {"stops": stops, "raises": raises}
    separate = _journal(period_s, first_s, event_times, chunk_s, round_of_loops=False, **kwargs)
    joint = _journal(period_s, first_s, event_times, chunk_s, round_of_loops=True, **kwargs)
    assert joint == separate
    for k in range(len(first_s)):
        calls = [t for what, t in joint if what == f"loop {k}"]
        assert all(t < stops[k] for t in calls)
        assert sum(t >= raises[k] for t in calls) <= 1  # the call that raised is its last


def test_a_round_whose_loops_all_stopped_leaves_the_queue_empty():
    env = simpy.Environment()
    calls = []

    def call():
        calls.append(round(env.now, 9))
        return env.now < 1.0

    loops = LoopRound(env, 0.25)
    loops.add(0.1, call)
    loops.start()
    env.run()  # without `until`: returns only once nothing is queued
    assert calls == [0.1, 0.35, 0.6, 0.85, 1.1]


def test_a_first_time_outside_the_period_is_refused():
    with pytest.raises(ValueError, match=r"0.5 s is outside \[0, 0.5\) s"):
        LoopRound(simpy.Environment(), 0.5).add(0.5, lambda: True)


def test_a_round_takes_loops_only_before_it_starts_and_starts_once():
    loops = LoopRound(simpy.Environment(), 0.5)
    loops.add(0.1, lambda: True)
    loops.start()
    with pytest.raises(RuntimeError, match="before it starts"):
        loops.add(0.2, lambda: True)
    with pytest.raises(RuntimeError, match="starts only once"):
        loops.start()
