"""Tests for kilonet.medium: every behaviour of the infrared channel, as exact timelines.

The style is SimPy's own: tiny robot programs log ``(name, robot, t_s, values)`` into a shared
list and the tests assert on exact times and counts. Programs read the true clock
(``self._kenv.now``) only to log it; what they send and when is fixed by the test.

Controlling when a robot transmits: with ``robot.tx_period_s`` tiny (1 ms) and no jitter, a
robot gets a transmit opportunity every millisecond, so a program that offers its message only
once ``now >= t`` starts transmitting in ``[t, t + 1 ms)``.

The exact timelines use perfect clocks and the thesis library's timing (200 ms ± 20 ms, back-off
U(0, 10 ms), a robot with nothing to send asked again a period later); the kilolib defaults and
the robots' own clocks have tests of their own at the end.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.message import Message, PayloadError, message_crc
from kilonet.params import Params
from kilonet.reception import GaussianRanging
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation
from kilonet.testing.outside import arrive

THESIS_TIMING = {
    "robot.clock_sd": 0.0,
    "robot.tx_period_s": 0.2,
    "robot.tx_jitter_s": 0.02,
    "robot.tx_retry": "period",
    "medium.backoff_max_s": 0.01,
}


#: The thesis's and Kilombo's medium: one hard radius, iid ranging noise, a carrier sensed the
#: instant it begins (the mechanisms below are tested on it; tests/validation/ checks the
#: fitted default against real robots).
DISC = {"medium.reach": "disc", "ranging.model": "gaussian", "medium.sense_delay_s": 0.0}


def quiet_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """No battery model (no drain, no periodic updates), perfect clocks, the disc medium and
    the thesis's timing, plus overrides."""
    return Params(seed=seed).with_overrides(
        {"battery.enabled": False, **DISC, **THESIS_TIMING, **(overrides or {})}
    )


class Radio(Kilobot):
    """A test program that offers numbered messages and logs every callback.

    Parameters
    ----------
    log : list
        Shared journal of ``(name, robot, t_s, *values)`` tuples (``self.journal``; the name
        ``log`` is the robot API's event recorder).
    send : bool
        Whether the robot offers messages at all.
    after_s : float
        Offer messages only from this simulated time on.
    max_messages : int or float
        Stop offering after this many messages went on the air.
    size : int
        Payload bytes (robot uid, 2-byte sequence number, zero padding).
    """

    def __init__(
        self,
        log: list,
        *,
        send: bool = True,
        after_s: float = 0.0,
        max_messages: float = math.inf,
        size: int = 3,
    ) -> None:
        self.journal = log
        self.send = send
        self.after_s = after_s
        self.max_messages = max_messages
        self.size = size

    @property
    def now(self) -> float:
        return self._kenv.now

    def setup(self) -> None:
        self.seq = 0

    def message_tx(self) -> Message | None:
        self.journal.append(("offer", self.kilo_uid, self.now))
        if not self.send or self.now < self.after_s or self.seq >= self.max_messages:
            return None
        head = bytes([self.kilo_uid]) + self.seq.to_bytes(2, "little")
        return Message(head + bytes(self.size - 3))

    def message_tx_success(self) -> None:
        self.journal.append(("tx", self.kilo_uid, self.now, self.seq))
        self.seq += 1

    def message_rx(self, message: Message, distance_mm: int) -> None:
        sender, seq = message.data[0], int.from_bytes(message.data[1:3], "little")
        self.journal.append(("rx", self.kilo_uid, self.now, sender, seq, distance_mm))


def build(positions, params: Params, log: list, **per_robot) -> Simulation:
    """A simulation whose robot ``i`` runs ``Radio(log, **per_robot.get(f"r{i}", {}))``;
    robots not named are silent listeners."""
    return Simulation(
        positions,
        lambda i: Radio(log, **per_robot.get(f"r{i}", {"send": False})),
        params,
        headings_rad=[0.0] * len(positions),
    )


def run_and_drain(sim: Simulation, until_s: float) -> None:
    """Run to ``until_s``, then stop all offers and let every message on the air land, so
    that each message sent has reached its fate (delivered or lost) at every receiver."""
    sim.run(until_s)
    for robot in sim.robots:
        robot.send = False
    sim.run(until_s + 1.0)


def entries(log: list, name: str, robot: int | None = None) -> list[tuple]:
    """Log entries called ``name`` (of ``robot`` if given), without the name."""
    return [e[1:] for e in log if e[0] == name and (robot is None or e[1] == robot)]


def rx_times(log: list, robot: int) -> list[float]:
    return [e[1] for e in entries(log, "rx", robot)]


# ------------------------------------------------------------------------------------ range


@pytest.mark.parametrize("range_mm", [85.0, 60.0])
def test_range_inside_hears_outside_does_not(range_mm):
    # Sender at the origin; listeners just inside, exactly at and just outside the range.
    log: list = []
    positions = [[0, 0], [range_mm - 0.1, 0], [0, range_mm + 0.1], [-range_mm, 0]]
    sim = build(positions, quiet_params({"medium.range_mm": range_mm}), log, r0={})
    run_and_drain(sim, 5.0)
    sent = sim.medium.counters["sent"][0]
    assert sent > 20
    assert len(rx_times(log, 1)) == sent  # just inside
    assert len(rx_times(log, 2)) == 0  # just outside
    assert len(rx_times(log, 3)) == sent  # exactly at the range: in range
    assert sim.medium.receivers_of(0) == [1, 3]


def test_range_default_is_85_mm():
    assert Params().medium.range_mm == 85.0


# ------------------------------------------------------------------------------ line of sight


@pytest.mark.parametrize(
    ("blocker", "blocked"),
    [
        ((40.0, 0.0), True),  # on the segment
        ((40.0, 16.4), True),  # its disc still crosses the segment
        ((40.0, 16.5), False),  # gap = radius: the disc only touches the line
        ((40.0, 25.0), False),  # clear of the segment
        ((-40.0, 0.0), False),  # on the line but behind the sender
    ],
)
def test_line_of_sight_third_disc_blocks(blocker, blocked):
    log: list = []
    params = quiet_params({"medium.occlusion": "block"})
    sim = build([[0, 0], [80, 0], blocker], params, log, r0={})
    run_and_drain(sim, 5.0)
    sent = sim.medium.counters["sent"][0]
    assert sent > 20
    assert len(rx_times(log, 1)) == (0 if blocked else sent)
    assert len(rx_times(log, 2)) == sent  # the third robot itself hears the sender


def test_bodies_block_nothing_by_default():
    log: list = []
    sim = build([[0, 0], [80, 0], [40, 0]], quiet_params(), log, r0={})
    run_and_drain(sim, 5.0)
    sent = sim.medium.counters["sent"][0]
    assert len(rx_times(log, 1)) == sent > 20
    assert sim.medium.counters["lost_occlusion"] == [0, 0, 0]


def test_graded_occlusion_loses_its_share_of_receptions_through_a_body():
    log: list = []
    params = quiet_params(
        {
            "medium.occlusion": "graded",
            "medium.occlusion_loss": 0.3,
            "medium.occlusion_range_factor": 0.95,
        }
    )
    sim = build([[0, 0], [80, 0], [40, 0], [0, 60]], params, log, r0={})
    run_and_drain(sim, 200.0)
    c = sim.medium.counters
    sent = c["sent"][0]
    assert c["received"][1] + c["lost_occlusion"][1] == sent > 900
    assert c["lost_occlusion"][1] / sent == pytest.approx(0.3, abs=4 * math.sqrt(0.21 / sent))
    assert c["lost_occlusion"][2] == c["lost_occlusion"][3] == 0  # clear links lose nothing
    assert c["received"][2] == c["received"][3] == sent


def test_graded_occlusion_shortens_the_reach_through_a_body():
    log: list = []
    params = quiet_params({"medium.occlusion": "graded", "medium.occlusion_range_factor": 0.9})
    sim = build([[0, 0], [80, 0], [40, 0]], params, log, r0={})  # 80 mm > 0.9 * 85 mm
    run_and_drain(sim, 5.0)
    assert len(rx_times(log, 1)) == 0 and len(rx_times(log, 2)) > 20


# ------------------------------------------------------------------------------------ offers


def test_offer_rate_and_jitter_bounds():
    log: list = []
    params = quiet_params({"robot.tx_period_s": 0.2, "robot.tx_jitter_s": 0.02})
    sim = build([[0, 0], [500, 0]], params, log, r0={})
    sim.run(60.0)
    offers = np.array([t for _, t in entries(log, "offer", 0)])
    assert 0.0 <= offers[0] <= 0.2  # first offer at U(0, period)
    gaps = np.diff(offers)
    assert gaps.min() >= 0.18 - 1e-12
    assert gaps.max() <= 0.22 + 1e-12
    assert gaps.std() > 0.005  # the jitter is really there
    # 60 s / 0.2 s = 300 offers; 4 sd of the mean gap (0.02/sqrt(3)/sqrt(300)) is ~1.3 %.
    assert 294 <= len(offers) <= 306
    c = sim.medium.counters
    assert c["sent"][0] == len(offers) == len(entries(log, "tx", 0))


def test_offers_without_jitter_are_exactly_periodic():
    log: list = []
    params = quiet_params({"robot.tx_period_s": 0.5, "robot.tx_jitter_s": 0.0})
    sim = build([[0, 0], [500, 0]], params, log, r0={})
    sim.run(10.0)
    offers = np.array([t for _, t in entries(log, "offer", 0)])
    assert 0.0 <= offers[0] <= 0.5
    np.testing.assert_allclose(np.diff(offers), 0.5, atol=1e-9)
    assert len(offers) in (19, 20)


def test_message_tx_none_sends_nothing():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(), log, r0={"send": False})
    sim.run(20.0)
    c = sim.medium.counters
    assert len(entries(log, "offer", 0)) > 90  # opportunities keep coming
    assert c["sent"][0] == c["bytes_sent"][0] == 0
    assert entries(log, "tx") == [] and entries(log, "rx") == []


class EveryOther(Radio):
    """Offers a message at every second opportunity only."""

    def setup(self) -> None:
        super().setup()
        self.calls = 0

    def message_tx(self) -> Message | None:
        self.calls += 1
        return super().message_tx() if self.calls % 2 == 0 else None


def test_only_non_none_offers_are_sent_and_counted():
    log: list = []
    sim = Simulation([[0, 0], [50, 0]], lambda i: EveryOther(log, send=i == 0), quiet_params())
    sim.run(20.0)
    c = sim.medium.counters
    calls = sim.robots[0].calls
    assert c["sent"][0] == calls // 2
    assert c["bytes_sent"][0] == 6 * (calls // 2)  # 3 data bytes + type + 2-byte CRC


def test_tx_success_once_per_message_sent_under_contention():
    # Three robots in range of each other with long airtime: many back-offs.
    log: list = []
    params = quiet_params({"medium.airtime_s": 0.05})
    sim = build([[0, 0], [50, 0], [25, 40]], params, log, r0={}, r1={}, r2={})
    sim.run(30.0)
    c = sim.medium.counters
    assert sum(c["backoffs"]) > 0
    for r in range(3):
        tx = entries(log, "tx", r)
        assert len(tx) == c["sent"][r] > 0
        assert [seq for _, _, seq in tx] == list(range(len(tx)))  # one call per message
        assert len(entries(log, "offer", r)) == c["sent"][r]  # asked only when the air is free


# --------------------------------------------------------------------------------- CSMA/CA


def _contention(csma: bool) -> tuple[Simulation, list]:
    """Two robots in range of each other, airtime a quarter of the offer period; a wide jitter
    keeps their relative phase well mixed."""
    log: list = []
    params = quiet_params(
        {
            "medium.csma": csma,
            "medium.airtime_s": 0.05,
            "medium.backoff_max_s": 0.01,
            "robot.tx_period_s": 0.2,
            "robot.tx_jitter_s": 0.1,
        }
    )
    sim = build([[0, 0], [50, 0]], params, log, r0={}, r1={})
    run_and_drain(sim, 60.0)
    return sim, log


def test_csma_backs_off_and_avoids_collisions():
    sim, log = _contention(csma=True)
    c = sim.medium.counters
    assert c["backoffs"][0] > 0 and c["backoffs"][1] > 0
    assert c["lost_collision"] == [0, 0]
    assert c["received"][1] == c["sent"][0] > 250
    assert c["received"][0] == c["sent"][1] > 250
    # No two transmissions overlap in time.
    starts = sorted(t for _, t, _ in entries(log, "tx"))
    assert np.diff(starts).min() >= 0.05 - 1e-12


def test_csma_asks_for_a_message_only_while_the_other_is_off_the_air():
    sim, log = _contention(csma=True)
    airtime = 0.05
    for me, other in ((0, 1), (1, 0)):
        other_tx = np.array([t for _, t, _ in entries(log, "tx", other)])
        offers = [t for _, t in entries(log, "offer", me) if t < 60.0]  # not while draining

        def on_air(t: float, other_tx=other_tx) -> bool:
            k = np.searchsorted(other_tx, t, side="left") - 1
            return k >= 0 and t < other_tx[k] + airtime

        # Carrier sense comes first, as in kilolib: a robot that senses the other on the air
        # backs off without calling message_tx(), and sends whenever it is called.
        assert sim.medium.counters["backoffs"][me] > 20
        assert not any(on_air(t) for t in offers)
        assert len(offers) == len(entries(log, "tx", me))


def test_without_csma_overlapping_transmissions_collide():
    sim, _ = _contention(csma=False)
    c = sim.medium.counters
    assert c["backoffs"] == [0, 0]
    assert c["lost_collision"][0] > 20 and c["lost_collision"][1] > 20
    # Every transmission that reached a robot was either delivered or lost to a collision.
    assert c["received"][1] + c["lost_collision"][1] == c["sent"][0]
    assert c["received"][0] + c["lost_collision"][0] == c["sent"][1]


# ----------------------------------------------------------------------------------- airtime


def test_delivery_exactly_airtime_after_transmission_starts():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params({"medium.airtime_s": 0.05}), log, r0={})
    sim.run(10.0)
    starts = {seq: t for _, t, seq in entries(log, "tx", 0)}
    arrivals = {seq: t for _, t, _, seq, _ in entries(log, "rx", 1)}
    assert len(arrivals) == len(starts) - (max(starts.values()) + 0.05 >= 10.0)
    for seq, t in arrivals.items():
        assert t == pytest.approx(starts[seq] + 0.05, abs=1e-12)


@pytest.mark.parametrize(
    ("overrides", "airtime_s"),
    [
        # kilolib v2: 9 data + type + CRC16 = 12 bytes at 8 MHz / 269 cycles a bit, plus the
        # preamble and contention check of message_send.S: about 4.4 ms
        ({}, 12 * 8 / 29_740 + 0.0012),
        ({"medium.message_format": "thesis"}, 4 * 8 / 29_740 + 0.0012),
        ({"medium.bitrate_bps": 1000.0, "medium.preamble_s": 0.0}, 12 * 8 / 1000),
        ({"medium.airtime_s": 0.25}, 0.25),
    ],
)
def test_airtime_derived_from_format_and_bitrate(overrides, airtime_s):
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(overrides), log, r0={"max_messages": 1})
    assert sim.medium.airtime_s == pytest.approx(airtime_s, rel=1e-12)
    sim.run(1.0)
    [(_, start, _)] = entries(log, "tx", 0)
    [(_, arrival, _, _, _)] = entries(log, "rx", 1)
    assert arrival - start == pytest.approx(airtime_s, abs=1e-12)


# -------------------------------------------------------------------------------- collisions


def _hidden_terminal(c_after_s: float) -> tuple[Simulation, list]:
    """A and C out of each other's range both reach B; D hears only A. A and C send one
    message each (A at once, C from ``c_after_s``); airtime 0.5 s."""
    log: list = []
    params = quiet_params(
        {"medium.airtime_s": 0.5, "robot.tx_period_s": 0.001, "robot.tx_jitter_s": 0.0}
    )
    #            A        B         C         D
    positions = [[0, 0], [70, 0], [140, 0], [-60, 0]]
    once = {"max_messages": 1}
    sim = build(positions, params, log, r0=once, r2={**once, "after_s": c_after_s})
    assert sim.medium.receivers_of(0) == [1, 3]
    assert sim.medium.receivers_of(2) == [1]
    sim.run(3.0)
    return sim, log


def test_hidden_terminals_collide_at_the_common_receiver():
    sim, log = _hidden_terminal(c_after_s=0.2)  # C starts while A is still on the air
    c = sim.medium.counters
    assert c["sent"][0] == c["sent"][2] == 1
    [(_, start_a, _)], [(_, start_c, _)] = entries(log, "tx", 0), entries(log, "tx", 2)
    assert start_a < start_c < start_a + 0.5  # C cannot sense A: it starts while A is on air
    assert entries(log, "rx", 1) == []
    assert c["lost_collision"][1] == 2 and c["received"][1] == 0
    [(_, t, sender, seq, _)] = entries(log, "rx", 3)  # D hears only A, cleanly
    assert (sender, seq) == (0, 0)
    [(_, start, _)] = entries(log, "tx", 0)
    assert t == pytest.approx(start + 0.5, abs=1e-12)
    assert c["lost_collision"][3] == 0 and c["received"][3] == 1


def test_hidden_terminals_that_do_not_overlap_are_both_received():
    sim, log = _hidden_terminal(c_after_s=1.0)  # C starts after A's airtime ended
    c = sim.medium.counters
    assert [(s, q) for _, _, s, q, _ in entries(log, "rx", 1)] == [(0, 0), (2, 0)]
    assert c["lost_collision"] == [0, 0, 0, 0]


@pytest.mark.parametrize(("third_at_s", "lost", "delivered"), [(1.15, 3, 0), (1.2, 2, 1)])
def test_collision_chain_corrupts_every_overlapping_reception(third_at_s, lost, delivered):
    # S1 [1.00, 1.10), S2 [1.08, 1.18), S3 [third, third + 0.1): S1 and S3 never overlap, but
    # S3 overlaps S2 (lost) when it starts at 1.15, and is clean when it starts at 1.2.
    log: list = []
    params = quiet_params(
        {
            "medium.csma": False,
            "medium.airtime_s": 0.1,
            "robot.tx_period_s": 0.001,
            "robot.tx_jitter_s": 0.0,
        }
    )
    positions = [[0, 0], [60, 0], [0, 60], [-60, 0]]  # R and three senders around it
    once = {"max_messages": 1}
    sim = build(
        positions,
        params,
        log,
        r1={**once, "after_s": 1.0},
        r2={**once, "after_s": 1.08},
        r3={**once, "after_s": third_at_s},
    )
    sim.run(2.0)
    c = sim.medium.counters
    assert c["lost_collision"][0] == lost
    assert c["received"][0] == len(entries(log, "rx", 0)) == delivered
    if delivered:
        assert [s for _, _, s, _, _ in entries(log, "rx", 0)] == [3]


# ------------------------------------------------------------------------------ half duplex


def _half_duplex(csma: bool) -> tuple[Simulation, list]:
    """A sends at 1.0 s, B at 1.05 s (airtime 0.1 s): B starts during A's message."""
    log: list = []
    params = quiet_params(
        {
            "medium.csma": csma,
            "medium.airtime_s": 0.1,
            "robot.tx_period_s": 0.001,
            "robot.tx_jitter_s": 0.0,
        }
    )
    once = {"max_messages": 1}
    sim = build(
        [[0, 0], [50, 0]], params, log, r0={**once, "after_s": 1.0}, r1={**once, "after_s": 1.05}
    )
    sim.run(2.0)
    return sim, log


def test_half_duplex_transmitting_ruins_the_reception_in_progress():
    sim, log = _half_duplex(csma=False)
    c = sim.medium.counters
    assert c["sent"] == [1, 1]
    assert entries(log, "rx", 1) == []
    assert c["lost_collision"][1] == 1 and c["received"][1] == 0


def test_half_duplex_no_reception_while_transmitting():
    # B's message reaches A while A is still transmitting (A is on the air until ~1.1 s):
    # a half-duplex radio cannot receive it.
    sim, log = _half_duplex(csma=False)
    c = sim.medium.counters
    assert entries(log, "rx", 0) == []
    assert c["lost_collision"][0] == 1 and c["received"][0] == 0


def test_half_duplex_avoided_by_carrier_sense():
    sim, log = _half_duplex(csma=True)
    c = sim.medium.counters
    assert c["backoffs"][1] > 0
    [(_, a_start, _)] = entries(log, "tx", 0)
    [(_, b_start, _)] = entries(log, "tx", 1)
    assert b_start >= a_start + 0.1
    assert c["received"] == [1, 1] and c["lost_collision"] == [0, 0]


# ------------------------------------------------------------------------------------- loss


def _ring(n: int, radius_mm: float) -> list[list[float]]:
    """A sender at the origin and ``n`` listeners on a circle around it."""
    angles = 2 * np.pi * np.arange(n) / n
    return [[0.0, 0.0], *np.column_stack([np.cos(angles), np.sin(angles)]) * radius_mm]


@pytest.mark.parametrize("loss_prob", [0.3, 0.75])
def test_random_loss_share_matches_loss_prob(loss_prob):
    log: list = []
    sim = build(_ring(5, 60.0), quiet_params({"medium.loss_prob": loss_prob}), log, r0={})
    run_and_drain(sim, 60.0)
    c = sim.medium.counters
    sent = c["sent"][0]
    for r in range(1, 6):
        assert c["received"][r] + c["lost_random"][r] == sent
        assert len(rx_times(log, r)) == c["received"][r]  # lost messages are never delivered
    receptions = 5 * sent
    share = sum(c["received"][1:]) / receptions
    tolerance = 4 * math.sqrt(loss_prob * (1 - loss_prob) / receptions)
    assert abs(share - (1 - loss_prob)) <= tolerance
    assert sum(c["lost_collision"]) == sum(c["lost_battery"]) == sum(c["lost_fault"]) == 0


@pytest.mark.parametrize(("loss_prob", "delivered"), [(0.0, True), (1.0, False)])
def test_loss_extremes(loss_prob, delivered):
    log: list = []
    sim = build(_ring(3, 60.0), quiet_params({"medium.loss_prob": loss_prob}), log, r0={})
    run_and_drain(sim, 10.0)
    c = sim.medium.counters
    sent = c["sent"][0]
    assert c["received"][1:] == [sent if delivered else 0] * 3
    assert c["lost_random"][1:] == [0 if delivered else sent] * 3


# -------------------------------------------------------------------------------- rx modes


def test_callback_mode_calls_message_rx_on_arrival():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params({"medium.airtime_s": 0.01}), log, r0={})
    sim.run(5.0)
    rx = entries(log, "rx", 1)
    starts = {seq: t for _, t, seq in entries(log, "tx", 0)}
    assert len(rx) == sim.medium.counters["received"][1] > 20
    assert all(t == pytest.approx(starts[seq] + 0.01, abs=1e-12) for _, t, _, seq, _ in rx)
    assert sim.robots[1].get_message() is None  # nothing is buffered in callback mode


class Buffered(Radio):
    """A Radio without ``message_rx``: in polled mode its receptions wait in the buffer."""

    message_rx = Kilobot.message_rx


@pytest.mark.parametrize("rx_buffer", [3, 5])
def test_polled_mode_keeps_the_newest_messages(rx_buffer):
    log: list = []
    params = quiet_params(
        {"robot.rx_mode": "polled", "robot.rx_buffer": rx_buffer, "ranging.sigma_mm": 0.0}
    )
    programs = [Radio(log, max_messages=8), Buffered(log, send=False)]
    sim = Simulation([[0, 0], [50, 0]], lambda i: programs[i], params)
    sim.run(5.0)
    c = sim.medium.counters
    assert c["sent"][0] == c["received"][1] == 8
    assert c["lost_overflow"][1] == 8 - rx_buffer
    assert entries(log, "rx") == []  # nothing drains a buffer of a program without message_rx
    robot = sim.robots[1]
    polled = [robot.get_message() for _ in range(rx_buffer)]
    assert [(m.data[0], int.from_bytes(m.data[1:3], "little")) for m, _ in polled] == [
        (0, seq) for seq in range(8 - rx_buffer, 8)
    ]
    assert [d for _, d in polled] == [50] * rx_buffer
    assert robot.get_message() is None


@pytest.mark.parametrize("loop", [False, True])
def test_polled_mode_hands_a_callback_program_its_messages_after_each_loop(loop):
    # A kilolib v2 program (message_rx, no polling) under the thesis's buffered library: the
    # kernel drains its buffer into message_rx after every loop() call, a tick late at most.
    log: list = []
    params = quiet_params({"robot.rx_mode": "polled", "ranging.sigma_mm": 0.0})

    class Listener(Radio):
        def loop(self) -> None:
            self.journal.append(("loop", self.kilo_uid, self.now))

    listener = (Listener if loop else Radio)(log, send=False)
    sim = Simulation([[0, 0], [50, 0]], lambda i: Radio(log) if i == 0 else listener, params)
    sim.run(10.0)
    c = sim.medium.counters
    rx = entries(log, "rx", 1)
    starts = {seq: t for _, t, seq in entries(log, "tx", 0)}
    assert c["received"][1] > 40 and c["lost_overflow"][1] == 0
    assert len(rx) == c["received"][1] - len(listener._krx)
    tick_s = 1 / sim.clocks.rate_hz(1)
    delays = [t - starts[seq] - sim.medium.airtime_s for _, t, _, seq, _ in rx]
    assert min(delays) > 0 and max(delays) <= tick_s
    if loop:  # each batch arrives right after a loop call, at the same time
        loops = {t for _, t in entries(log, "loop", 1)}
        assert {t for _, t, *_ in rx} <= loops


def test_drain_messages_hands_over_the_buffer_oldest_first():
    log: list = []
    params = quiet_params({"robot.rx_mode": "polled", "ranging.sigma_mm": 0.0})
    programs = [Radio(log, max_messages=2), Buffered(log, send=False)]
    sim = Simulation([[0, 0], [50, 0]], lambda i: programs[i], params)
    sim.run(5.0)
    listener = programs[1]
    listener.message_rx = Radio.message_rx.__get__(listener)
    assert listener.drain_messages() == 2
    assert [seq for _, _, _, seq, _ in entries(log, "rx", 1)] == [0, 1]
    assert listener.drain_messages() == 0


class Poller(Radio):
    """Polls its buffer every loop() and logs each message as ``("poll", ...)``."""

    def loop(self) -> None:
        while (got := self.get_message()) is not None:
            message, distance_mm = got
            seq = int.from_bytes(message.data[1:3], "little")
            self.journal.append(
                ("poll", self.kilo_uid, self.now, message.data[0], seq, distance_mm)
            )


def test_polled_get_message_returns_messages_in_arrival_order():
    log: list = []
    params = quiet_params({"robot.rx_mode": "polled", "ranging.sigma_mm": 0.0})
    sim = Simulation([[0, 0], [60, 0], [30, 40]], lambda i: Poller(log, send=i > 0), params)
    sim.run(10.0)
    c = sim.medium.counters
    assert c["lost_overflow"][0] == 0 and c["lost_collision"][0] == 0
    polled = entries(log, "poll", 0)
    transmitted = sorted(entries(log, "tx"), key=lambda e: e[1])
    last_poll = polled[-1][1]
    expected = [(r, seq) for r, t, seq in transmitted if t + sim.medium.airtime_s < last_poll]
    assert [(s, q) for _, _, s, q, _ in polled] == expected
    assert {(s, d) for _, _, s, _, d in polled} == {(1, 60), (2, 50)}


# ------------------------------------------------------------------------- distance estimate


def test_distance_estimate_without_noise_is_true_distance_rounded():
    log: list = []
    positions = [[0, 0], [50.4, 0], [0, 60.6], [-70, 0], [0, -44.5001]]
    sim = build(positions, quiet_params({"ranging.sigma_mm": 0.0}), log, r0={})
    sim.run(5.0)
    for r, expected in ((1, 50), (2, 61), (3, 70), (4, 45)):
        estimates = {d for _, _, _, _, d in entries(log, "rx", r)}
        assert estimates == {expected}


def test_distance_noise_has_zero_mean_and_sigma_sd():
    log: list = []
    sim = build(_ring(5, 60.0), quiet_params({"ranging.sigma_mm": 2.0}), log, r0={})
    sim.run(60.0)
    errors = np.array([d - 60 for _, _, _, _, d in entries(log, "rx")], dtype=float)
    assert len(errors) > 1400
    assert np.all(errors == np.round(errors))  # whole millimetres
    # Rounding adds variance 1/12 to sigma^2 = 4.
    assert abs(errors.mean()) <= 4 * 2.0 / math.sqrt(len(errors))
    assert errors.std() == pytest.approx(math.sqrt(4 + 1 / 12), rel=0.08)


def test_per_robot_bias_shifts_one_receivers_estimates_consistently():
    # Two senders out of each other's range; three listeners each hear both.
    log: list = []
    positions = [[0, 0], [100, 0], [50, 0], [50, 40], [50, -40]]
    params = quiet_params({"ranging.sigma_mm": 0.5, "ranging.bias_sigma_mm": 5.0})
    sim = build(positions, params, log, r0={}, r1={})
    sim.run(60.0)
    pos = np.array(positions, dtype=float)
    bias = sim.medium.reception.bias_mm
    mean_errors = []
    for r in (2, 3, 4):
        per_sender = []
        for s in (0, 1):
            true_mm = float(np.hypot(*(pos[r] - pos[s])))
            errs = [d - true_mm for _, _, snd, _, d in entries(log, "rx", r) if snd == s]
            assert len(errs) > 100
            per_sender.append(np.mean(errs))
        # The same shift whichever robot it hears from, equal to the receiver's bias.
        assert per_sender[0] == pytest.approx(per_sender[1], abs=0.3)
        assert per_sender[0] == pytest.approx(bias[r], abs=0.3)
        mean_errors.append(per_sender[0])
    assert len(set(np.round(mean_errors, 9))) == 3  # each receiver carries its own bias


def test_per_robot_bias_is_drawn_with_bias_sigma():
    params = quiet_params({"ranging.bias_sigma_mm": 5.0})
    sim = Simulation([[40.0 * k, 0.0] for k in range(80)], Kilobot, params)
    assert sim.medium.reception.bias_mm.std() == pytest.approx(5.0, rel=0.3)
    assert abs(sim.medium.reception.bias_mm.mean()) <= 4 * 5.0 / math.sqrt(80)
    assert not quiet_params().ranging.bias_sigma_mm  # no bias by default
    np.testing.assert_array_equal(
        Simulation([[0, 0], [50, 0]], Kilobot, quiet_params()).medium.reception.bias_mm, [0.0, 0.0]
    )


def test_distance_estimate_is_clipped_to_min_and_max():
    log: list = []
    positions = [[0, 0], [35, 0], [0, 45], [-60, 0]]
    params = quiet_params({"ranging.sigma_mm": 0.0, "ranging.min_mm": 40, "ranging.max_mm": 50})
    sim = build(positions, params, log, r0={})
    sim.run(3.0)
    for r, expected in ((1, 40), (2, 45), (3, 50)):
        assert {d for _, _, _, _, d in entries(log, "rx", r)} == {expected}


def test_distance_estimate_saturates_at_255_mm():
    log: list = []
    params = quiet_params({"ranging.sigma_mm": 3.0, "medium.range_mm": 400.0})
    sim = build([[0, 0], [300, 0], [0, 254]], params, log, r0={})
    sim.run(10.0)
    assert {d for _, _, _, _, d in entries(log, "rx", 1)} == {255}
    near_ceiling = [d for _, _, _, _, d in entries(log, "rx", 2)]
    assert max(near_ceiling) == 255 and min(near_ceiling) < 254


# ----------------------------------------------------------------------------------- payload


def test_nine_byte_payload_passes():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(), log, r0={"size": 9})
    run_and_drain(sim, 2.0)
    c = sim.medium.counters
    assert c["sent"][0] == c["received"][1] > 5
    assert c["bytes_sent"][0] == 12 * c["sent"][0]


def test_ten_byte_payload_raises_at_offer_time():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(), log, r0={"size": 10})
    with pytest.raises(PayloadError, match="10 bytes"):
        sim.run(2.0)
    [(_, first_offer)] = entries(log, "offer", 0)
    assert sim.env.now == first_offer
    assert sim.medium.counters["sent"][0] == 0 and entries(log, "tx") == []


class Fixed(Kilobot):
    """Offers one fixed message forever."""

    def __init__(self, message: Message | None) -> None:
        self.message = message
        self.send = True

    def message_tx(self) -> Message | None:
        return self.message if self.send else None


@pytest.mark.parametrize(
    ("message", "ok"),
    [
        (Message(((1 << 23) - 1).to_bytes(3, "little")), True),  # 23 significant bits
        (Message(b"\x00\x01"), True),
        (Message((1 << 23).to_bytes(3, "little")), False),  # 24 significant bits
        (Message(b"\x00\x00\x00\x00"), False),  # 4 bytes
        (Message(b"\x01", type=1), False),  # the thesis format has no type byte
    ],
)
def test_thesis_format_payload_limit(message, ok):
    params = quiet_params({"medium.message_format": "thesis"})
    sim = Simulation([[0, 0], [50, 0]], lambda i: Fixed(message if i == 0 else None), params)
    if ok:
        run_and_drain(sim, 2.0)
        assert sim.medium.counters["received"][1] == sim.medium.counters["sent"][0] > 5
    else:
        with pytest.raises(PayloadError):
            sim.run(2.0)
        assert sim.medium.counters["sent"][0] == 0


# ----------------------------------------------------------------------------- message trace


def test_message_trace_records_each_transmission_at_its_end():
    log: list = []
    params = quiet_params(
        {"trace.messages": True, "medium.loss_prob": 0.5, "medium.airtime_s": 0.01}
    )
    sim = build(_ring(4, 60.0), params, log, r0={})
    run_and_drain(sim, 10.0)
    frame = sim.trace.messages_frame()
    starts = [t for _, t, _ in entries(log, "tx", 0)]
    assert len(frame) == len(starts) == sim.medium.counters["sent"][0]
    np.testing.assert_allclose(frame["t_s"], np.array(starts) + 0.01, atol=1e-12)
    assert frame["sender"].eq(0).all() and frame["receivers"].eq(4).all()
    assert (
        frame["delivered"].sum() == sum(sim.medium.counters["received"]) == len(entries(log, "rx"))
    )
    assert frame["delivered"].between(0, 4).all() and frame["delivered"].nunique() > 2


def test_message_trace_is_off_by_default():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(), log, r0={})
    sim.run(2.0)
    assert sim.trace.messages_frame().empty


# ------------------------------------------------- kilolib's timing on each robot's own clock


def kilolib_params(overrides: dict | None = None) -> Params:
    """kilolib v2 defaults (0.5 s period, no jitter, asked again a tick after None), no
    battery."""
    return Params(seed=3).with_overrides({"battery.enabled": False, **DISC, **(overrides or {})})


def test_kilolib_offers_every_16_ticks_of_each_robots_own_clock():
    log: list = []
    sim = build([[0, 0], [500, 0]], kilolib_params(), log, r0={}, r1={})
    sim.run(60.0)
    period = 16 * 256 / 7812.5  # kilolib: tx_clock gains 255 a tick and fires above 3906
    for robot in (0, 1):
        offers = np.array([t for _, t in entries(log, "offer", robot)])
        factor = sim.clocks.factor[robot]
        np.testing.assert_allclose(np.diff(offers), period / factor, rtol=1e-9)
        assert 0.0 <= offers[0] <= period / factor
    assert sim.clocks.factor[0] != sim.clocks.factor[1]


def test_kilolib_asks_again_at_the_next_tick_when_there_is_nothing_to_send():
    log: list = []
    sim = build([[0, 0], [500, 0]], kilolib_params(), log, r0={"after_s": 2.0})
    sim.run(4.0)
    offers = np.array([t for _, t in entries(log, "offer", 0)])
    tick = 1 / sim.clocks.rate_hz(0)
    asked = offers[offers < 2.0]
    np.testing.assert_allclose(np.diff(asked), tick, rtol=1e-9)  # about 31 times a second
    assert len(asked) == pytest.approx((2.0 - asked[0]) / tick, abs=1.01)
    [(_, first, _), *_] = entries(log, "tx", 0)
    assert 2.0 <= first < 2.0 + tick + 1e-12  # sent at the first tick it has something


def test_kilo_tx_period_is_kilolibs_setting_in_timer_counts():
    log: list = []
    sim = build([[0, 0], [500, 0]], kilolib_params(), log, r0={})
    bot = sim.robots[0]
    assert bot.kilo_tx_period == 3906  # kilolib's default: 16 ticks
    sim.start()
    bot.kilo_tx_period = 1953  # fires at the first tick whose 255 counts pass 1953: the 8th
    assert bot.kilo_tx_period == 1953
    sim.run(20.0)
    offers = np.array([t for _, t in entries(log, "offer", 0)])
    own_s = 8 * 256 / 7812.5
    np.testing.assert_allclose(np.diff(offers)[2:], own_s / sim.clocks.factor[0], rtol=1e-9)
    with pytest.raises(ValueError, match="uint16"):
        bot.kilo_tx_period = 0


class Crc(Radio):
    """Sends its numbered message with a fixed ``crc`` value (``None``: the correct one)."""

    def __init__(self, log: list, crc: int | str | None) -> None:
        super().__init__(log)
        self.crc = crc

    def message_tx(self) -> Message | None:
        message = super().message_tx()
        if message is None or self.crc is None:
            return message
        crc = message_crc(message) if self.crc == "computed" else self.crc
        return Message(message.data, message.type, crc=crc)


@pytest.mark.parametrize(("crc", "accepted"), [(None, True), ("computed", True), (0, False)])
def test_a_receiver_drops_a_message_whose_crc_does_not_match(crc, accepted):
    log: list = []
    sim = Simulation(
        [[0, 0], [50, 0], [0, 50]],
        lambda i: Crc(log, crc) if i == 0 else Radio(log, send=False),
        quiet_params(),
    )
    run_and_drain(sim, 10.0)
    c = sim.medium.counters
    sent = c["sent"][0]
    assert sent > 40  # on the air either way: it occupies the channel
    for r in (1, 2):
        assert c["received"][r] == (sent if accepted else 0)
        assert c["lost_crc"][r] == (0 if accepted else sent)
        assert len(rx_times(log, r)) == c["received"][r]


def test_message_crc_is_kilolibs_crc_ccitt_over_nine_data_bytes_and_the_type():
    assert message_crc(Message(bytes(9), 0)) == 0x9C87  # all zero, the research helper's vector
    assert message_crc(Message(b"", 0)) == message_crc(Message(bytes(9), 0))  # padded to nine
    assert message_crc(Message(b"\x01", 0)) != message_crc(Message(b"\x00\x01", 0))
    assert message_crc(Message(bytes(9), 1)) != message_crc(Message(bytes(9), 0))


# --------------------------------------------------------------- the reception model is a seam


class DistanceLoss(GaussianRanging):
    """Loses receptions with probability (d / 100 mm)^2: farther links fail more often."""

    def loss_probability(self, shares, distance_mm):
        thresholds = super().loss_probability(shares, distance_mm)
        return thresholds + ((distance_mm / 100.0) ** 2)[None, :]


def test_a_swapped_in_reception_model_decides_the_losses():
    log: list = []
    params = quiet_params()
    positions = [[0, 0], [20 + 13, 0], [0, 50], [-80, 0]]

    def make(model):
        sim = Simulation(
            positions,
            lambda i: Radio(log, send=i == 0),
            params,
            reception=model(params, len(positions)) if model else None,
        )
        run_and_drain(sim, 120.0)
        return sim.medium.counters

    def distance_loss(p, n):
        # The model draws from streams of its own, so the medium's are untouched.
        rng = np.random.default_rng(7)
        return DistanceLoss(p, n, rng, np.random.default_rng(8))

    plain, lossy = make(None), make(distance_loss)
    sent = lossy["sent"][0]
    assert plain["lost_random"] == [0, 0, 0, 0]
    for r, d in ((1, 33.0), (2, 50.0), (3, 80.0)):
        expected = (d / 100) ** 2
        assert lossy["lost_random"][r] / sent == pytest.approx(
            expected, abs=4 * math.sqrt(expected * (1 - expected) / sent)
        )
        assert lossy["received"][r] + lossy["lost_random"][r] == sent


# ------------------------------------------------------- messages from outside the swarm


def test_a_message_from_outside_is_a_reception_like_any_other():
    """kilonet.testing.outside.arrive (the test kit's scripted messages): airtime, carrier,
    collisions with the swarm's own messages, CRC, loss, counters and trace (sender -1)."""
    log: list = []
    params = quiet_params({"trace.messages": True, "ranging.sigma_mm": 0.0})
    sim = build([[0, 0], [50, 0]], params, log, r1={"after_s": 1.0, "max_messages": 1})
    sim.start()
    medium, env = sim.medium, sim.env
    airtime = medium.airtime_s
    outcomes = []

    def at(t_s, *args, **kwargs):
        env.timeout(t_s).callbacks.append(
            lambda _e: outcomes.append(arrive(sim, 0, *args, **kwargs))
        )

    at(0.1, Message(b"\x09\x01\x00"), 61.7)  # estimate from the model: round(61.7)
    at(0.2, Message(b"\x09\x02\x00"), 61.7, estimate_mm=40)
    at(0.3, Message(b"\x09\x03\x00", crc=0), 50.0)
    at(0.4, Message(b"\x09\x04\x00"), 50.0, lose=True)
    at(0.5, Message(b"\x09\x05\x00"), 50.0)
    at(0.5 + airtime / 2, Message(b"\x09\x06\x00"), 50.0)  # overlaps the one before
    sim.run(0.9)
    assert entries(log, "rx", 0) == [
        (0, pytest.approx(0.1 + airtime), 9, 1, 62),
        (0, pytest.approx(0.2 + airtime), 9, 2, 40),
    ]
    assert outcomes == [None, None, "crc", "random", None, None]
    frame = sim.robots_frame()
    assert (frame.received[0], frame.lost_crc[0], frame.lost_random[0]) == (2, 1, 1)
    assert frame.lost_collision[0] == 2
    assert sim.trace.messages_frame().sender.tolist() == [-1] * 6
    # The swarm's own message reaches robot 0 as before; a robot that stopped hears nothing.
    run_and_drain(sim, 2.0)
    assert [e[2] for e in entries(log, "rx", 0)] == [9, 9, 1]
    sim.stop_robot(0, "crash")
    assert arrive(sim, 0, Message(b"\x09"), 50.0) == "stopped"
    with pytest.raises(PayloadError, match="exceeds the kilolib limit"):
        arrive(sim, 1, Message(bytes(range(1, 11))), 50.0)


def test_a_tx_source_replaces_what_the_medium_asks_at_opportunities():
    log: list = []
    sim = build([[0, 0], [50, 0]], quiet_params(), log)
    asked = []
    sim.medium.set_tx_source(0, lambda: asked.append(sim.env.now) or Message(b"\x00\x07\x00"))
    sim.run(1.0)
    assert len(asked) == 5  # one opportunity every 200 ms
    assert [e[2:4] for e in entries(log, "rx", 1)] == [(0, 7)] * 5  # sender byte 0, seq 7


@pytest.mark.parametrize(("gap_s", "collide"), [(0.0001, True), (0.0003, False)])
def test_a_carrier_is_sensed_only_a_sense_delay_after_it_begins(gap_s, collide):
    # Robot 1 starts 0.1 ms after robot 0: within the 0.2 ms it takes to sense robot 0's
    # carrier, so both send and collide at robot 2; 0.3 ms after, robot 1 defers.
    log: list = []
    params = quiet_params({"medium.sense_delay_s": 0.0002, "robot.tx_jitter_s": 0.0})
    sim = build([[0, 0], [40, 0], [20, 30]], params, log, r0={"max_messages": 1})
    sim.medium.channel.occupy(_Tx(), 0, [1, 2], 0.0, sim.medium.airtime_s)
    assert sim.medium.channel.busy(1, gap_s) is not collide
    assert sim.medium.channel.busy(0, gap_s)  # a sender hears its own transmission at once


class _Tx:
    corrupted = None
