"""Delivery at the end of a message's airtime, with collisions and losses in the same
transmissions: every reception is delivered with its own estimate or counted lost exactly once.

With noise-free Gaussian ranging each estimate is the rounded true distance, so a reception
handed to the wrong receiver, or with another receiver's estimate, shows."""

from __future__ import annotations

import math

import numpy as np

from kilonet import Kilobot, Message, Params, Simulation
from kilonet.counters import LOSS_CAUSES

N = 10
POSITIONS = np.array([(40.0 * (k % 4), 37.0 * (k // 4) + 3.0 * k) for k in range(N)])
QUIET_AFTER_TICKS = 31 * 20  # senders fall silent 20 s before the end: nothing is left on air


class Recorder(Kilobot):
    """Sends its index until QUIET_AFTER_TICKS; records each reception's sender and estimate."""

    def setup(self) -> None:
        self.heard: list[tuple[int, int]] = []
        self.msg = Message(bytes([self.kilo_uid]), 1)

    def message_tx(self) -> Message | None:
        return self.msg if self.kilo_ticks < QUIET_AFTER_TICKS else None

    def message_rx(self, message: Message, distance: int) -> None:
        self.heard.append((message.data[0], distance))


def test_every_reception_is_delivered_right_or_counted_lost_once():
    params = Params(seed=3, duration_s=40.0).with_overrides(
        {
            "medium.loss_prob": 0.2,
            "medium.csma": False,  # collisions aplenty
            "medium.reach": "disc",
            "medium.range_mm": 200.0,
            "ranging.model": "gaussian",
            "ranging.sigma_mm": 0.0,
        }
    )
    sim = Simulation(POSITIONS, Recorder, params)
    sim.run()
    c = sim.medium.counters
    lost = {cause: c[f"lost_{cause}"] for cause in LOSS_CAUSES}
    assert sum(lost["collision"]) > 100 and sum(lost["random"]) > 100
    for r, robot in enumerate(sim.robots):
        senders = {s for s in range(N) if r in sim.medium.receivers_of(s)}
        assert len(robot.heard) == c["received"][r]
        arrived = c["received"][r] + sum(lost[cause][r] for cause in LOSS_CAUSES)
        assert arrived == sum(c["sent"][s] for s in senders)
        for s, estimate in robot.heard:
            assert s in senders
            assert estimate == math.floor(math.dist(POSITIONS[s], POSITIONS[r]) + 0.5)


def test_fast_delivery_does_what_receiver_by_receiver_delivery_does(monkeypatch):
    from kilonet.medium import InfraredMedium

    params = Params(seed=5, duration_s=30.0).with_overrides(
        {"medium.loss_prob": 0.3, "medium.csma": False}
    )

    def run() -> tuple[list, dict]:
        sim = Simulation(POSITIONS, Recorder, params)
        sim.run()
        return [robot.heard for robot in sim.robots], {
            k: list(v) for k, v in sim.medium.counters.items()
        }

    fast = run()
    monkeypatch.setattr(InfraredMedium, "_end_of_airtime", InfraredMedium._deliver_carefully)
    careful = run()
    assert sum(fast[1]["lost_collision"]) > 100 and sum(fast[1]["lost_random"]) > 100
    assert fast == careful
