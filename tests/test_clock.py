"""Tests for kilonet.clock: robot clocks, reusable timers, and the kernel environment with the
recurring calls that stand in for one timer per robot loop."""

from __future__ import annotations

import numpy as np
import pytest
import simpy
from hypothesis import given
from hypothesis import strategies as st

from kilonet.clock import KernelEnvironment, RobotClocks, Timer

# Coarse values on purpose: loops and other events often fall due at the very same time, where
# only the insertion order SimPy keeps decides which runs first.
_PERIOD_S = st.sampled_from([0.25, 0.5, 1.0, 0.3])
# Each loop's own period: robots' clocks differ, so their loops drift past each other.
_PERIODS_S = st.lists(st.sampled_from([0.25, 0.5, 0.3, 0.31, 0.75]), min_size=8, max_size=8)
_FIRST_S = st.lists(st.sampled_from([0.0, 0.1, 0.2, 0.05]), min_size=1, max_size=8)
_EVENT_TIMES = st.lists(st.sampled_from([0.0, 0.1, 0.25, 0.5, 0.6, 1.0, 1.3, 2.0]), max_size=12)
_CHUNK_S = st.sampled_from([3.0, 1.0, 0.5, 0.25, 0.7])
_WHEN = st.sampled_from([0.0, 0.5, 1.0, 4.0])  # 4 s: never, in a 3 s run


class Boom(RuntimeError):
    """What a loop raises in these tests."""


def _journal(periods_s, first_s, event_times, chunk_s, *, round_of_loops, stops=None, raises=None):
    """(what, simulated time) of every loop call and every other event in a 3 s run, with the
    loops on one Timer each or recurring calls of the environment (loop k every
    ``periods_s[k]``),
    added in turn with the other events (as the simulation adds a robot's loop after its first
    transmit opportunity).

    The run goes in chunks of ``chunk_s`` (as a progress bar runs it). Every loop call queues
    events of its own: one half a period ahead, one a whole period ahead (due with the loop's
    next call) and one urgent at once. Loop k stops for good at ``stops[k]`` s, and raises
    :class:`Boom` the first time it runs at or after ``raises[k]`` s; the run carries on."""
    env = KernelEnvironment()
    journal = []
    stops, raises = stops or {}, raises or {}

    def event(name):
        return Timer(env, lambda _timer: journal.append((name, env.now)), None)

    def loop_call(k):
        period_s = periods_s[k]

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

    for k, first in enumerate(first_s):
        for j, t in enumerate(event_times[k :: len(first_s)]):
            event(f"event {k}.{j}").schedule(t)
        call = loop_call(k)
        if round_of_loops:
            handle = env.every(first, periods_s[k], lambda call=call, k=k: call() or env.cancel(k))
            assert handle == k
        else:
            Timer(
                env, lambda timer, call=call, p=periods_s[k]: call() and timer.schedule(p), k
            ).schedule(first)
    while env.now < 3.0:
        try:
            env.run(until=min(3.0, env.now + chunk_s))
        except Boom as exc:
            journal.append((f"loop {exc.args[0]} raised", env.now))
    return journal


@given(_PERIODS_S, _FIRST_S, _EVENT_TIMES, _CHUNK_S)
def test_a_loop_schedule_runs_loops_when_and_in_the_order_one_timer_each_would(
    periods_s, first_s, event_times, chunk_s
):
    separate = _journal(periods_s, first_s, event_times, chunk_s, round_of_loops=False)
    joint = _journal(periods_s, first_s, event_times, chunk_s, round_of_loops=True)
    assert joint == separate
    for k, first in enumerate(first_s):
        calls = [t for what, t in joint if what == f"loop {k}"]
        assert len(calls) == pytest.approx((3.0 - first) / periods_s[k], abs=1.01)


@given(_PERIOD_S, _FIRST_S, _EVENT_TIMES, _CHUNK_S)
def test_loops_of_one_period_run_as_one_timer_each_would(period_s, first_s, event_times, chunk_s):
    periods = [period_s] * 8
    separate = _journal(periods, first_s, event_times, chunk_s, round_of_loops=False)
    assert _journal(periods, first_s, event_times, chunk_s, round_of_loops=True) == separate


@given(_PERIODS_S, _FIRST_S, _EVENT_TIMES, _CHUNK_S, st.data())
def test_a_loop_that_stops_or_raises_leaves_the_schedule_and_the_others_go_on(
    periods_s, first_s, event_times, chunk_s, data
):
    stops = {k: data.draw(_WHEN) for k in range(len(first_s))}
    raises = {k: data.draw(_WHEN) for k in range(len(first_s))}
    kwargs = {"stops": stops, "raises": raises}
    separate = _journal(periods_s, first_s, event_times, chunk_s, round_of_loops=False, **kwargs)
    joint = _journal(periods_s, first_s, event_times, chunk_s, round_of_loops=True, **kwargs)
    assert joint == separate
    for k in range(len(first_s)):
        calls = [t for what, t in joint if what == f"loop {k}"]
        assert all(t < stops[k] for t in calls)
        assert sum(t >= raises[k] for t in calls) <= 1  # the call that raised is its last


def test_a_schedule_whose_loops_all_stopped_leaves_the_queue_empty():
    env = KernelEnvironment()
    calls = []

    def call():
        calls.append(round(env.now, 9))
        if env.now >= 1.0:
            env.cancel(handle)

    handle = env.every(0.1, 0.25, call)
    env.run()  # without `until`: returns only once nothing is queued
    assert calls == [0.1, 0.35, 0.6, 0.85, 1.1]
    assert env.peek() == float("inf")


@pytest.mark.parametrize(("first_s", "period_s"), [(-0.1, 0.5), (0.0, 0.0), (0.1, -1.0)])
def test_a_negative_first_time_or_a_period_not_above_zero_is_refused(first_s, period_s):
    with pytest.raises(ValueError, match="first_s >= 0 and period_s > 0"):
        KernelEnvironment().every(first_s, period_s, lambda: True)


@pytest.mark.parametrize("delay", [-1e-9, -0.5, float("nan")])
def test_an_event_in_the_past_is_refused_and_the_clock_never_runs_backwards(delay):
    env = KernelEnvironment()
    env.run(until=1.0)
    with pytest.raises(ValueError, match="in the past"):
        env.schedule(env.event(), delay=delay)
    with pytest.raises(ValueError, match="in the past"):
        Timer(env, lambda _t: None, None).schedule(delay)
    with pytest.raises(ValueError, match="in the past"):
        env.schedule_at(env.event(), 1.0 + delay)
    with pytest.raises(ValueError, match=r"in the past|Negative delay"):
        env.timeout(delay)  # SimPy's Timeout refuses a negative delay itself, the kernel NaN
    assert env.now == 1.0 and env.peek() == float("inf")


def _process_journal(env: simpy.Environment) -> list:
    """What SimPy's own events do on ``env``: processes, timeouts, conditions, an interrupt,
    a failed event that is caught, run in chunks and to the end."""
    journal = []

    def sleeper(name, delays):
        try:
            for d in delays:
                yield env.timeout(d)
                journal.append((name, env.now))
        except simpy.Interrupt as why:
            journal.append((name, "interrupted", why.cause, env.now))

    def boss():
        a = env.process(sleeper("a", [0.5, 0.5, 0.25]))
        b = env.process(sleeper("b", [0.25] * 8))
        yield env.all_of([env.timeout(0.75), env.timeout(1.0)])
        journal.append(("all", env.now))
        b.interrupt("enough")
        failing = env.event()
        failing.fail(KeyError("k"))
        try:
            yield failing
        except KeyError:
            journal.append(("caught", env.now))
        yield a
        journal.append(("a done", env.now, a.value))
        yield env.any_of([env.timeout(2.0), env.timeout(0.5, value="fast")])
        journal.append(("any", env.now))

    env.process(boss())
    env.run(until=1.1)
    journal.append(("paused", env.now))
    env.run()
    journal.append(("end", env.now))
    return journal


def test_simpy_events_and_processes_run_on_the_kernel_environment_as_on_simpys():
    assert _process_journal(KernelEnvironment()) == _process_journal(simpy.Environment())


def test_an_unhandled_failed_event_raises_as_in_simpy():
    for env in (KernelEnvironment(), simpy.Environment()):
        event = env.event()
        event.fail(KeyError("lost"))
        with pytest.raises(KeyError, match="lost"):
            env.run(until=1.0)


# ------------------------------------------------------------------------------ robot clocks


def test_perfect_clocks_tick_at_the_nominal_rate_in_phase():
    clocks = RobotClocks.draw(5, 31.0, 0.0, np.random.default_rng(1))
    assert clocks.factor.tolist() == [1.0] * 5 and clocks.phase.tolist() == [0.0] * 5
    assert [clocks.ticks_at(0, t) for t in (0.0, 0.03, 1.0, 10.0)] == [0, 0, 31, 310]


def test_clock_rates_spread_with_clock_sd_and_phases_are_uniform():
    clocks = RobotClocks.draw(20_000, 31.0, 0.01, np.random.default_rng(2))
    assert np.std(clocks.factor - 1) == pytest.approx(0.01, rel=0.03)
    assert abs(np.mean(clocks.factor - 1)) < 3e-4
    assert np.max(np.abs(clocks.factor - 1)) <= 0.05 + 1e-12  # clipped at 5 sd
    assert clocks.phase.min() >= 0 and clocks.phase.max() < 1
    assert np.mean(clocks.phase) == pytest.approx(0.5, abs=0.01)


def test_a_fast_clock_counts_more_ticks_and_shortens_its_own_seconds():
    clocks = RobotClocks(31.0, np.array([1.0, 1.02]), np.array([0.0, 0.25]))
    assert clocks.ticks_at(1, 100.0) == int(100 * 31 * 1.02 + 0.25) == 3162
    assert clocks.true_s(1, 1.02) == pytest.approx(1.0)
    assert clocks.rate_hz(1) == pytest.approx(31.62)


@given(st.floats(0.0, 0.999), st.floats(0.9, 1.1))
def test_the_first_loop_falls_mid_tick_of_tick_zero_or_one(phase, factor):
    clocks = RobotClocks(31.0, np.array([factor]), np.array([phase]))
    t = clocks.first_mid_tick_s(0)
    assert 0 <= t < 1 / clocks.rate_hz(0)
    assert (t * clocks.rate_hz(0) + phase) % 1 == pytest.approx(0.5, abs=1e-9)


@given(_PERIODS_S, _FIRST_S, _CHUNK_S, st.sampled_from([0.0, 0.3, 1.0, 1.05]))
def test_recurring_calls_added_while_running_run_as_one_timer_each_would(
    periods_s, first_s, chunk_s, added_at_s
):
    def journal(recurring: bool) -> list:
        env = KernelEnvironment()
        log = []

        def start(k, first):
            def call():
                log.append((k, env.now))

            if recurring:
                env.every(first, periods_s[k], call)
            else:
                Timer(env, lambda t, p=periods_s[k]: call() or t.schedule(p), k).schedule(first)

        start(0, first_s[0])
        adder = Timer(env, lambda _t: [start(k, f) for k, f in enumerate(first_s)], None)
        adder.schedule(added_at_s)
        while env.now < 3.0:
            env.run(until=min(3.0, env.now + chunk_s))
        return log

    assert journal(True) == journal(False)
