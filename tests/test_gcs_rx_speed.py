"""gcs merging's receive fast path against the careful one (issue 44).

A seed sends the very message objects of its current transform again and again; a robot that
completed that transform from them only marks it heard when one comes again, without unpacking
it. A run must end exactly as one in which every transform half takes the careful path.
"""

from __future__ import annotations

import pytest

from kilonet import scenarios
from kilonet.protocols.gcs.phase6_merging import FrameMerging

SETTINGS = {"placement.robots": 40}


def _outcome(result) -> tuple:
    """What the robots did: every event they logged, their estimates, the messages sent and
    when the run ended (the summary's central optimum is the solver's, not theirs)."""
    sim = result.sim
    events = sim.trace.events_frame().to_csv(index=False)
    estimates = [r.position_estimate() for r in sim.robots]
    return events, estimates, result.summary["messages_sent"], sim.env.now


def test_repeated_transform_halves_change_nothing_but_when_heard(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fast = scenarios.run(scenarios.get("gcs"), SETTINGS, seed=2)

    calls = {"heard": 0, "careful": 0}
    track, take = FrameMerging._track_transform, FrameMerging._take_half

    def counted(self: FrameMerging, message) -> None:
        calls["heard"] += 1
        track(self, message)

    def careful(self: FrameMerging, message):
        calls["careful"] += 1
        key = take(self, message)
        self.repeated.clear()  # never a repeat: every half is unpacked and compared
        return key

    monkeypatch.setattr(FrameMerging, "_track_transform", counted)
    monkeypatch.setattr(FrameMerging, "_take_half", careful)
    slow = scenarios.run(scenarios.get("gcs"), SETTINGS, seed=2)
    assert calls["careful"] == calls["heard"] > 1000
    assert _outcome(slow) == _outcome(fast)

    def unpacked(self: FrameMerging, message):
        calls["careful"] += 1
        return take(self, message)

    calls.update(heard=0, careful=0)
    monkeypatch.setattr(FrameMerging, "_take_half", unpacked)
    again = scenarios.run(scenarios.get("gcs"), SETTINGS, seed=2)
    assert _outcome(again) == _outcome(fast)
    assert calls["careful"] < calls["heard"] / 2  # the fast path took most of them
