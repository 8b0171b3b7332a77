"""Collided receptions counted a batch of messages at a time (issue 44).

The medium hands each message's set of collided receivers to
:meth:`kilonet.counters.MediumCounters.collided`, which counts the sets by NumPy every few
hundred messages and whenever the counters are read. These tests hold that fast path to the
careful one: the same counts as one update per collided reception, however the batches fall and
whenever the counters are read.
"""

from __future__ import annotations

import numpy as np
import pytest

from kilonet.counters import _COLLISION_BATCH, MediumCounters
from kilonet.medium import InfraredMedium
from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.simulation import Simulation


def test_batched_collision_counts_equal_one_update_per_collided_reception() -> None:
    n = 40
    rng = np.random.default_rng(7)
    counters = MediumCounters(n)
    received, lost = [0] * n, [0] * n
    messages = 3 * _COLLISION_BATCH + 17  # batches fold mid-way, and a partial one is left
    for k in range(messages):
        hit = {int(r) for r in rng.choice(n, size=int(rng.integers(1, 12)), replace=False)}
        counters.received[:] = [c + 1 for c in counters.received]  # as clean_delivery+fold
        received = [c + 1 for c in received]
        counters.collided(hit)
        for r in hit:
            received[r] -= 1
            lost[r] += 1
        if k == _COLLISION_BATCH // 2:  # a read mid-batch counts what is pending
            assert counters.as_dict()["lost_collision"] == lost
    counted = counters.as_dict()
    assert counted["received"] == received
    assert counted["lost_collision"] == lost
    assert sum(lost) > _COLLISION_BATCH


class Chatter(Kilobot):
    """Offers a message at every opportunity: a dense swarm of them collides all the time."""

    def setup(self) -> None:
        self.me = Message(bytes([self._kindex]), 1)

    def message_tx(self) -> Message:
        return self.me


def _counters(read_every_s: float | None) -> dict[str, list[int]]:
    """A dense 50-robot run's counters, read every ``read_every_s`` simulated seconds on the
    way (None: only at the end)."""
    positions = hex_lattice(50, spacing_mm=40.0, jitter_mm=3.0, rng=np.random.default_rng(2))
    params = Params(seed=4, duration_s=12.0).with_overrides(
        {"robot.tx_period_s": 0.2, "robot.tx_jitter_s": 0.02, "battery.enabled": False}
    )
    sim = Simulation(positions, Chatter, params)
    if read_every_s is None:
        sim.run()
    else:
        t = 0.0
        while t < params.duration_s:
            t = min(params.duration_s, t + read_every_s)
            sim.run(t)
            sim.medium.counters  # noqa: B018 (the read folds whatever is pending)
    return {k: list(v) for k, v in sim.medium.counters.items()}


def test_batched_counts_equal_the_careful_paths_however_often_they_are_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    at_end = _counters(None)
    on_the_way = _counters(0.37)
    # The careful path counts every collided reception on its own, at its end of airtime: a
    # reception long over that the channel marks again (a robot's own transmission keeps its
    # channel busy) is never counted twice.
    monkeypatch.setattr(InfraredMedium, "_end_of_airtime", InfraredMedium._deliver_carefully)
    careful = _counters(None)
    assert sum(at_end["lost_collision"]) > 10 * _COLLISION_BATCH
    assert on_the_way == at_end == careful
