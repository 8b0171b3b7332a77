"""Tests for kilonet.faults: crashes, removals and faulty receivers, by time and by chance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import line
from kilonet.simulation import Simulation


def quiet_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """No battery model, perfect clocks and the thesis's 200 ms timing, plus overrides."""
    return Params(seed=seed).with_overrides(
        {
            "battery.enabled": False,
            "robot.clock_sd": 0.0,
            "robot.tx_period_s": 0.2,
            "robot.tx_jitter_s": 0.02,
            **(overrides or {}),
        }
    )


class Numbered(Kilobot):
    """Offers numbered messages when ``send`` is set; logs tx, rx and loop calls."""

    def __init__(self, log: list, *, send: bool = False) -> None:
        self.journal = log
        self.send = send
        self.seq = 0

    @property
    def now(self) -> float:
        return self._kenv.now

    def message_tx(self) -> Message | None:
        return Message(self.seq.to_bytes(2, "little")) if self.send else None

    def message_tx_success(self) -> None:
        self.journal.append(("tx", self.kilo_uid, self.now, self.seq))
        self.seq += 1

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.journal.append(("rx", self.kilo_uid, self.now, int.from_bytes(message.data, "little")))

    def loop(self) -> None:
        self.journal.append(("loop", self.kilo_uid, self.now, None))


class _Buffered(Numbered):
    """Numbered without message_rx: in polled mode its receptions stay in the buffer."""

    message_rx = Kilobot.message_rx


def times(log: list, name: str, robot: int) -> list[float]:
    return [t for n, r, t, _ in log if n == name and r == robot]


def _sender_and_listeners(positions, params=None) -> tuple[Simulation, list]:
    log: list = []
    sim = Simulation(positions, lambda i: Numbered(log, send=i == 0), params or quiet_params())
    return sim, log


# --------------------------------------------------------------------------------- crash


def test_crashed_sender_stops_sending():
    sim, log = _sender_and_listeners([[0, 0], [50, 0]])
    sim.faults.crash_at(0, 5.0)
    sim.run(10.0)
    tx = times(log, "tx", 0)
    assert len(tx) > 20 and max(tx) < 5.0
    assert max(times(log, "loop", 0)) < 5.0  # the program stops altogether
    assert max(times(log, "rx", 1)) <= max(tx) + sim.medium.airtime_s + 1e-12
    assert max(times(log, "loop", 1)) > 9.9  # the listener runs on
    assert sim.trace.stops_frame().values.tolist() == [[5.0, 0, "crash"]]
    frame = sim.robots_frame()
    assert frame["running"].tolist() == [False, True]
    assert frame["present"].tolist() == [True, True]
    assert frame["stop_cause"].tolist() == ["crash", ""]


def test_crashed_receiver_stops_receiving():
    sim, log = _sender_and_listeners([[0, 0], [50, 0], [0, 50]])
    sim.faults.crash_at(1, 5.0)
    sim.run(10.0)
    rx = times(log, "rx", 1)
    assert len(rx) > 20 and max(rx) < 5.0
    assert max(times(log, "rx", 2)) > 9.5  # the other listener still hears
    assert sim.medium.receivers_of(0) == [2]
    received = sim.medium.counters["received"]
    assert received[1] == len(rx) and received[2] == len(times(log, "rx", 2))


def test_message_on_the_air_is_not_delivered_to_a_robot_that_crashed_meanwhile():
    params = quiet_params({"medium.airtime_s": 0.5, "robot.tx_jitter_s": 0.0})
    sim, log = _sender_and_listeners([[0, 0], [50, 0]], params)
    sim.run(3.0)
    on_air_from = times(log, "tx", 0)[-1]
    assert on_air_from + 0.5 > 3.0  # 0.5 s airtime, 0.2 s period: always a message on the air
    sim.faults.crash_at(1, 3.0)
    sim.run(5.0)
    assert max(times(log, "rx", 1)) < 3.0


def test_crashed_robot_still_blocks_line_of_sight():
    params = quiet_params({"medium.occlusion": "block"})
    sim, log = _sender_and_listeners([[0, 0], [40, 0], [80, 0]], params)
    sim.faults.crash_at(1, 1.0)
    sim.run(6.0)
    assert times(log, "rx", 2) == []
    assert sim.medium.receivers_of(0) == []


def test_removed_robot_no_longer_blocks():
    params = quiet_params({"medium.occlusion": "block"})
    sim, log = _sender_and_listeners([[0, 0], [40, 0], [80, 0]], params)
    sim.faults.remove_at(1, 2.0)
    sim.run(6.0)
    heard = times(log, "rx", 2)
    assert len(heard) > 15 and min(heard) > 2.0
    assert sim.medium.receivers_of(0) == [2]
    assert sim.trace.stops_frame().values.tolist() == [[2.0, 1, "removed"]]
    frame = sim.robots_frame()
    assert frame["present"].tolist() == [True, False, True]
    assert frame["stop_cause"].tolist() == ["", "removed", ""]


# ------------------------------------------------------------------------- faulty receiver


def test_faulty_receiver_drops_a_share_and_delays_others():
    params = quiet_params({"medium.airtime_s": 0.01})
    sim, log = _sender_and_listeners([[0, 0], [50, 0], [0, 50]], params)
    sim.faults.faulty_receiver(1, drop_prob=0.4, delay_prob=0.5, delay_s=0.3)
    sim.run(60.0)
    sim.robots[0].send = False
    sim.run(61.0)  # every delayed message has arrived
    c = sim.medium.counters
    sent = c["sent"][0]
    # Dropped receptions are counted as fault losses, the others as delivered.
    assert c["received"][1] + c["lost_fault"][1] == sent
    share = c["lost_fault"][1] / sent
    assert abs(share - 0.4) <= 4 * math.sqrt(0.4 * 0.6 / sent)
    starts = {seq: t for n, r, t, seq in log if n == "tx"}
    delays = np.array([t - starts[seq] - 0.01 for n, r, t, seq in log if n == "rx" and r == 1])
    assert len(delays) == c["received"][1]
    assert delays.min() >= -1e-12 and delays.max() <= 0.3
    delayed = (delays > 1e-9).mean()
    assert abs(delayed - 0.5) <= 4 * math.sqrt(0.25 / len(delays))
    # The healthy listener gets everything exactly one airtime after it was sent.
    healthy = [t - starts[seq] for n, r, t, seq in log if n == "rx" and r == 2]
    assert len(healthy) == sent
    np.testing.assert_allclose(healthy, 0.01, atol=1e-12)
    assert c["lost_fault"][2] == 0


def test_faulty_receiver_in_polled_mode_buffers_delayed_messages():
    params = quiet_params({"robot.rx_mode": "polled", "robot.rx_buffer": 1000})
    log: list = []
    programs = [Numbered(log, send=True), _Buffered(log)]
    sim = Simulation([[0, 0], [50, 0]], lambda i: programs[i], params)
    sim.faults.faulty_receiver(1, drop_prob=0.0, delay_prob=1.0, delay_s=0.1)
    sim.run(10.0)
    sim.robots[0].send = False
    sim.run(11.0)
    sent = sim.medium.counters["sent"][0]
    robot = sim.robots[1]
    got = []
    while (item := robot.get_message()) is not None:
        got.append(int.from_bytes(item[0].data, "little"))
    assert sorted(got) == list(range(sent))
    assert times(log, "rx", 1) == []


def test_delayed_message_to_a_crashed_receiver_is_not_delivered():
    sim, log = _sender_and_listeners([[0, 0], [50, 0]])
    sim.faults.faulty_receiver(1, drop_prob=0.0, delay_prob=1.0, delay_s=1.0)
    sim.faults.crash_at(1, 3.0)
    sim.run(10.0)
    rx = times(log, "rx", 1)
    # Messages sent in the last second before the crash were still held back at 3 s.
    assert len(rx) > 3 and max(rx) < 3.0
    assert len(rx) < len([t for t in times(log, "tx", 0) if t < 3.0])


# --------------------------------------------------------------------------- random faults


def _random_faults(seed: int) -> Simulation:
    params = quiet_params(
        {
            "faults.crash_fraction": 0.3,
            "faults.crash_from_s": 1.0,
            "faults.crash_to_s": 2.0,
            "faults.remove_fraction": 0.2,
            "faults.remove_from_s": 3.0,
            "faults.remove_to_s": 4.0,
            "faults.faulty_rx_fraction": 0.4,
        },
        seed=seed,
    )
    sim = Simulation(line(10, spacing_mm=40.0), Kilobot, params)
    sim.run(5.0)
    return sim


def test_random_faults_pick_round_fraction_times_n_robots():
    sim = _random_faults(seed=3)
    stops = sim.trace.stops_frame()
    crashes = stops[stops["cause"] == "crash"]
    removals = stops[stops["cause"] == "removed"]
    assert len(crashes) == 3 and crashes["robot"].is_unique
    assert len(removals) == 2 and removals["robot"].is_unique
    assert crashes["t_s"].between(1.0, 2.0).all()
    assert removals["t_s"].between(3.0, 4.0).all()
    assert len(sim.faults.faulty_receivers) == 4
    assert (~sim.world.present).sum() == 2


def test_random_faults_are_reproducible():
    a, b = _random_faults(seed=3), _random_faults(seed=3)
    assert a.trace.stops_frame().equals(b.trace.stops_frame())
    assert a.faults.faulty_receivers == b.faults.faulty_receivers
    picks = {
        seed: (
            tuple(_random_faults(seed).trace.stops_frame()["robot"]),
            tuple(sorted(_random_faults(seed).faults.faulty_receivers)),
        )
        for seed in (3, 4, 5)
    }
    assert len(set(picks.values())) > 1


@pytest.mark.parametrize(("fraction", "count"), [(0.0, 0), (0.14, 1), (0.3, 3), (1.0, 10)])
def test_crash_fraction_counts(fraction, count):
    params = quiet_params(
        {"faults.crash_fraction": fraction, "faults.crash_from_s": 0.5, "faults.crash_to_s": 0.5}
    )
    sim = Simulation(line(10, spacing_mm=40.0), Kilobot, params)
    sim.run(1.0)
    assert (~sim.world.running).sum() == count
    assert sim.trace.stops_frame()["t_s"].eq(0.5).all()
