"""A sender whose receivers stay the same when a neighbour moves keeps its receiver and handler
lists (``InfraredMedium._derive``): what it delivers must be what rebuilding the lists gives."""

from __future__ import annotations

import pytest

from kilonet import scenarios
from kilonet.medium import InfraredMedium


def _run(monkeypatch: pytest.MonkeyPatch, *, relist: bool) -> tuple[dict, list, dict, int]:
    derive = InfraredMedium._derive
    kept = 0

    def counting(self: InfraredMedium, s: int, *, relist: bool = relist) -> None:
        nonlocal kept
        before = self._rx_r[s]
        derive(self, s, relist=relist)
        kept += self._rx_r[s] is before

    with monkeypatch.context() as m:
        m.setattr(InfraredMedium, "_derive", counting)
        result = scenarios.run(scenarios.get("follower"), {}, seed=1)
    summary = {k: v for k, v in result.summary.items() if k not in {"wall_time_s", "cpu_s"}}
    events = result.sim.trace.events_frame().to_dict("records")
    return summary, events, result.sim.medium.counters, kept


def test_kept_lists_deliver_what_rebuilt_lists_deliver(monkeypatch):
    fast = _run(monkeypatch, relist=False)
    careful = _run(monkeypatch, relist=True)
    assert fast[:3] == careful[:3]
    # The follower's motion moves links without changing who hears whom many times over.
    assert fast[3] > 100 and careful[3] == 0
