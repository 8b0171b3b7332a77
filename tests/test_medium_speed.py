"""The medium's fast delivery path against its careful one (issue 44).

A transmission whose receptions partly fail (collided, or lost to a cause) is delivered by one
C-level ``map`` over the receivers a byte mask keeps (:meth:`InfraredMedium._end_of_airtime`).
The careful path (:meth:`InfraredMedium._deliver_carefully`, taken when receiver lists changed
while a message was on the air) goes receiver by receiver with its own counting. On a dense
swarm with collisions, random losses and a weak signal at the edge, both must make the same
deliveries, in the same order, with the same distance estimates, and the same counters.
"""

from __future__ import annotations

from typing import ClassVar

import pytest

from kilonet.medium import InfraredMedium
from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.simulation import Simulation


class Recorder(Kilobot):
    """Offers its index at every opportunity; logs every reception into a shared journal."""

    journal: ClassVar[list[tuple[float, int, int, int]]] = []

    def setup(self) -> None:
        self.me = Message(bytes([self._kindex]), 1)

    def message_tx(self) -> Message:
        return self.me

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.journal.append((self._kenv.now, self._kindex, message.data[0], distance_mm))


def _run(careful: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[list, dict, dict, list]:
    """A dense 60-robot run, delivered by the fast path or (``careful``) always carefully:
    its journal of receptions, its counters, its summary and its traced transmissions."""
    import numpy as np

    if careful:
        monkeypatch.setattr(InfraredMedium, "_end_of_airtime", InfraredMedium._deliver_carefully)
    journal: ClassVar[list[tuple[float, int, int, int]]] = []
    monkeypatch.setattr(Recorder, "journal", journal)
    positions = hex_lattice(60, spacing_mm=40.0, jitter_mm=3.0, rng=np.random.default_rng(3))
    params = Params(seed=5, duration_s=8.0).with_overrides(
        {
            "robot.tx_period_s": 0.2,
            "robot.tx_jitter_s": 0.02,
            "medium.loss_prob": 0.1,
            "battery.enabled": False,
            "trace.messages": True,
        }
    )
    sim = Simulation(positions, Recorder, params)
    sim.run()
    return journal, sim.medium.counters, sim.summary(), list(sim.trace._messages)


def test_fast_delivery_matches_the_careful_path(monkeypatch: pytest.MonkeyPatch) -> None:
    fast_journal, fast_counts, fast_summary, fast_traced = _run(False, monkeypatch)
    monkeypatch.undo()
    careful_journal, careful_counts, careful_summary, careful_traced = _run(True, monkeypatch)
    # The run exercises every branch: clean receptions, collisions, random and signal losses.
    assert fast_summary["lost_collision"] > 1000
    assert fast_summary["lost_random"] > 1000
    assert fast_summary["lost_signal"] > 0
    assert len(fast_journal) == fast_summary["receptions_delivered"] > 10_000
    assert fast_journal == careful_journal
    assert fast_counts == careful_counts
    assert fast_traced == careful_traced  # (t_s, sender, receivers, delivered) per message
    for key in ("receptions_delivered", "lost_collision", "lost_random", "lost_signal"):
        assert fast_summary[key] == careful_summary[key]
