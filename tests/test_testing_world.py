"""kilonet.testing's scripted world: exact timelines of what a robot hears, does and sends, the
medium's rules at the receiver, neighbours in the real medium, assertions and misuse."""

from __future__ import annotations

import itertools

import pytest

from kilonet.message import Layout, Message, PayloadError
from kilonet.ranging import DistanceMeasurement
from kilonet.robot import Kilobot
from kilonet.testing import Replay, ScriptedWorld, ScriptError

PING = Layout("ping", type=2, fields=[("n", "B")])
AIRTIME_S = 12 * 8 / 29_740 + 0.0012  # kilolib: 12 bytes at 29.7 kbit/s, plus the preamble


class Listener(Kilobot):
    """Keeps what it hears; sends nothing."""

    def setup(self) -> None:
        self.got: list[tuple[int, int]] = []

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.got.append((PING.unpack(message).n, distance_mm))


class Chatter(Kilobot):
    """Offers PING(n) at every opportunity, n counting the messages sent."""

    def setup(self) -> None:
        self.n = 0

    def message_tx(self) -> Message:
        return PING.pack(n=self.n % 256)

    def message_tx_success(self) -> None:
        self.n += 1


class Reactor(Kilobot):
    """On each PING: LED to its n (mod 4, red), motors on for n > 1, logs it, answers n + 1."""

    def setup(self) -> None:
        self.answer: Message | None = None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        n = PING.unpack(message).n
        self.set_color(n % 4, 0, 0)
        if n > 1:
            self.set_motors(self.kilo_straight_left, self.kilo_straight_right)
        else:
            self.set_motors(0, 0)
        self.log("ping", n=n, distance_mm=distance_mm)
        self.answer = PING.pack(n=n + 1)

    def message_tx(self) -> Message | None:
        answer, self.answer = self.answer, None
        return answer


# ------------------------------------------------------------------------ time and hearing


def test_time_moves_only_when_the_test_says_so():
    world = ScriptedWorld(Listener())
    assert world.now_s == 0.0 and world.sim is None
    world.advance(1.5)
    assert world.now_s == 1.5
    world.run_until(2.0)
    world.advance(0.0)
    assert world.now_s == 2.0
    assert world.kilo_ticks == world.sim.clocks.ticks_at(0, 2.0)


def test_a_scripted_message_arrives_at_its_time_plus_airtime_at_its_distance():
    world = ScriptedWorld(Listener())
    entry = world.hear(PING.pack(n=7), at_s=0.25, distance_mm=61.4, sender="a")
    world.advance(0.25 + AIRTIME_S / 2)
    assert world.robot.got == [] and entry.fate == "on air"
    world.advance(AIRTIME_S)
    assert world.robot.got == [(7, 61)]
    (heard,) = world.heard(PING)
    assert heard.t_s == pytest.approx(0.25 + AIRTIME_S)
    assert (heard.distance, heard.sender, heard.fields) == (61, "a", PING.record(7))
    assert entry.fate == "delivered"
    assert world.sim.robots_frame().received[0] == 1


def test_scripted_distances_can_come_with_the_runs_ranging_noise():
    world = ScriptedWorld(Listener(), params={"ranging.model": "gaussian", "ranging.sigma_mm": 2.0})
    world.hear_every(PING.pack(n=1), period_s=0.1, until_s=5.0, distance_mm=60, noise=True)
    world.advance(6.0)
    distances = [d for _, d in world.robot.got]
    assert len(distances) == 50 and len(set(distances)) > 3
    assert sum(distances) / 50 == pytest.approx(60, abs=1.0)


def test_hear_every_schedules_from_now_until_before_the_end():
    world = ScriptedWorld(Listener())
    world.advance(1.0)
    entries = world.hear_every(PING.pack(n=1), period_s=0.5, until_s=3.0)
    assert [e.at_s for e in entries] == [1.0, 1.5, 2.0, 2.5]


def test_the_same_seed_and_script_give_the_same_run_and_steps_do_not_matter():
    def records(seed: int, steps: list[float]):
        world = ScriptedWorld(Reactor(), seed=seed)
        world.hear_every(PING.pack(n=2), period_s=0.3, until_s=3.0, distance_mm=45)
        for dt in steps:
            world.advance(dt)
        return world.sent(), world.colors(), world.motor_commands(), world.events()

    assert records(3, [3.0]) == records(3, [1.0, 0.5, 1.5]) == records(3, [0.1] * 30)
    assert records(3, [3.0])[0] != records(4, [3.0])[0]  # another seed, another clock


def test_sent_led_motor_and_event_records_are_exact_timelines():
    world = ScriptedWorld(Reactor(), layouts=[PING])
    world.hear(PING.pack(n=2), at_s=0.5, distance_mm=40)
    world.hear(PING.pack(n=1), at_s=2.0, distance_mm=70)
    world.advance(3.0)
    t1, t2 = 0.5 + AIRTIME_S, 2.0 + AIRTIME_S
    assert world.colors() == [(pytest.approx(t1), (2, 0, 0)), (pytest.approx(t2), (1, 0, 0))]
    left, right = world.robot.kilo_straight_left, world.robot.kilo_straight_right
    assert world.motor_commands() == [
        (pytest.approx(t1), (left, right)),
        (pytest.approx(t2), (0, 0)),
    ]
    assert [(e.name, e.fields) for e in world.events("ping")] == [
        ("ping", {"n": 2, "distance_mm": 40}),
        ("ping", {"n": 1, "distance_mm": 70}),
    ]
    # Answers go out at the next transmit opportunity after each reception: kilolib asks
    # again at every tick while the program has nothing to send.
    answers = world.sent(PING)
    assert [s.fields.n for s in answers] == [3, 2]
    tick = 1 / world.sim.clocks.rate_hz(0)
    assert t1 < answers[0].t_s <= t1 + tick and t2 < answers[1].t_s <= t2 + tick
    frames = world.frames()
    assert frames["sent"].data.tolist() == ["03", "02"]
    assert frames["motors"].left.tolist() == [left, 0]
    assert frames["script"].fate.tolist() == ["delivered", "delivered"]


def test_polled_mode_buffers_three_and_raw_mode_hands_readings():
    class Poller(Kilobot):
        def setup(self):
            self.got = []

        def loop(self):
            if self.kilo_ticks >= 31:  # polls only after about a second
                while (received := self.get_message()) is not None:
                    self.got.append(PING.unpack(received[0]).n)

    world = ScriptedWorld(Poller(), params={"robot.rx_mode": "polled"})
    for n in range(5):
        world.hear(PING.pack(n=n), at_s=0.1 * (n + 1))
    world.advance(2.0)
    assert world.robot.got == [2, 3, 4]  # the buffer kept the last three
    assert len(world.heard()) == 5  # all five reached the buffer
    assert world.sim.robots_frame().lost_overflow[0] == 2

    world = ScriptedWorld(Listener(), params={"robot.rx_distance": "raw"})
    world.hear(PING.pack(n=1), at_s=0.1, distance_mm=57)
    world.advance(1.0)
    ((_, raw),) = world.robot.got
    assert isinstance(raw, DistanceMeasurement)
    assert world.robot.estimate_distance(raw) == 57


# ------------------------------------------------------------- the medium at the receiver


def test_overlapping_scripted_messages_collide():
    world = ScriptedWorld(Listener())
    a = world.hear(PING.pack(n=1), at_s=0.2, sender="a")
    b = world.hear(PING.pack(n=2), at_s=0.2 + AIRTIME_S / 2, sender="b")
    c = world.hear(PING.pack(n=3), at_s=0.2 + 1.2 * AIRTIME_S, sender="c")  # after a, within b
    d = world.hear(PING.pack(n=4), at_s=0.3, sender="d")
    world.advance(1.0)
    assert (a.fate, b.fate, c.fate, d.fate) == ("collision", "collision", "collision", "delivered")
    assert world.robot.got == [(4, 50)]
    assert world.sim.robots_frame().lost_collision[0] == 3


def test_wrong_crc_and_scripted_loss_are_dropped_and_counted():
    world = ScriptedWorld(Listener())
    bad = world.hear(PING.pack(n=1), at_s=0.1, corrupt=True)
    lost = world.hear(PING.pack(n=2), at_s=0.2, lost=True)
    world.advance(1.0)
    assert (bad.fate, lost.fate, world.robot.got) == ("crc", "lost", [])
    frame = world.sim.robots_frame()
    assert (frame.lost_crc[0], frame.lost_random[0]) == (1, 1)
    world = ScriptedWorld(Listener(), params={"medium.loss_prob": 1.0})
    assert world.hear(PING.pack(n=1), at_s=0.1).fate == "scheduled"
    world.advance(1.0)
    assert world.script[0].fate == "random"


def test_the_robot_senses_the_carrier_of_a_scripted_message_and_waits():
    # Receptions back to back for 3 s (each as long as 0.3 s of airtime): the channel is
    # never free at the robot, so it never sends; once they stop, it does.
    world = ScriptedWorld(Chatter(), params={"medium.airtime_s": 0.3})
    world.hear_every(PING.pack(n=9), period_s=0.3, until_s=3.0)
    world.advance(3.0)
    assert world.sent() == [] and world.sim.robots_frame().backoffs[0] > 0
    world.advance(1.0)
    assert world.sent()[0].t_s >= 3.0


def test_a_message_arriving_while_the_robot_transmits_is_lost():
    # Runs are reproducible: learn when the robot sends, then script a message into its
    # airtime in a second run of the same seed.
    first = ScriptedWorld(Chatter(), seed=5)
    first.advance(2.0)
    t_send = first.sent()[1].t_s
    world = ScriptedWorld(Chatter(), seed=5)
    entry = world.hear(PING.pack(n=1), at_s=t_send + AIRTIME_S / 2)
    world.advance(2.0)
    assert world.sent()[1].t_s == t_send
    assert entry.fate == "collision"


def test_a_stopped_robot_hears_nothing():
    world = ScriptedWorld(Listener())
    world.start().faults.crash_at(0, 0.5)
    entry = world.hear(PING.pack(n=1), at_s=1.0)
    world.advance(2.0)
    assert entry.fate == "stopped" and world.robot.got == []


# ------------------------------------------------------------ neighbours in the real medium


def test_replay_offers_the_latest_due_message_or_each_once():
    a, b = PING.pack(n=1), PING.pack(n=2)
    repeating = Replay([(0.0, a), (1.0, b), (2.0, None)])
    assert [repeating.due(t) for t in (0.5, 1.0, 1.5, 2.5)] == [a, b, b, None]
    once = Replay([(0.0, a), (0.0, b)], repeat=False)
    assert [once.due(0.1), once.due(0.2), once.due(0.3)] == [a, b, None]
    with pytest.raises(ScriptError, match="schedule time -1"):
        Replay([(-1, a)])
    with pytest.raises(ScriptError, match="not a Message"):
        Replay([(0.0, "hello")])


def test_replay_neighbours_follow_the_mediums_transmit_rules_and_noise():
    world = ScriptedWorld(Listener(), params={"ranging.model": "gaussian", "ranging.sigma_mm": 1.0})
    near = world.add_neighbour(Replay.every(PING.pack(n=1), from_s=1.0), distance_mm=45)
    far = world.add_neighbour(Replay.every(PING.pack(n=2), until_s=3.0), at_mm=(0, -80))
    world.advance(6.0)
    near_sent, far_sent = world.sent(robot=near), world.sent(robot=far)
    assert near_sent[0].t_s >= 1.0 and far_sent[-1].t_s < 3.0
    # One offer per period of each neighbour's own clock (kilolib: 0.5 s).
    gaps = [b.t_s - a.t_s for a, b in itertools.pairwise(near_sent)]
    assert gaps == pytest.approx(
        [world.sim.medium.tx_period_own_s(near) / world.sim.clocks.factor[near]] * len(gaps)
    )
    heard = world.heard(PING)
    assert {h.sender for h in heard} == {near, far}
    assert len(heard) == len(near_sent) + len(far_sent)
    near_d = [h.distance for h in heard if h.sender == near]
    assert len(set(near_d)) > 1 and abs(sum(near_d) / len(near_d) - 45) < 1.5


def test_neighbours_out_of_each_others_range_collide_at_the_robot():
    # Hidden terminals: the neighbours cannot sense each other's carrier.
    params = {"medium.airtime_s": 0.2, "robot.tx_period_s": 0.25}
    world = ScriptedWorld(Listener(), params=params)
    world.add_neighbour(Replay.every(PING.pack(n=1)), at_mm=(-100, 0))  # 200 mm apart
    world.add_neighbour(Replay.every(PING.pack(n=2)), at_mm=(100, 0))
    world.advance(10.0)
    assert world.sim.robots_frame().lost_collision[0] > 0


# ------------------------------------------------------------------------------ assertions


def test_eventually_returns_the_first_time_it_held():
    world = ScriptedWorld(Listener())
    world.hear(PING.pack(n=1), at_s=0.4)
    held = world.eventually(lambda: world.robot.got, within_s=1.0)
    assert held == pytest.approx(0.4 + AIRTIME_S) and world.now_s == held


def test_eventually_says_what_happened_instead():
    world = ScriptedWorld(Reactor(), layouts=[PING])
    world.hear(PING.pack(n=2), at_s=0.2, distance_mm=40, sender="left")
    world.hear(PING.pack(n=5), at_s=0.2, sender="right")
    with pytest.raises(AssertionError) as failure:
        world.eventually(lambda: world.robot.color == (3, 0, 0), within_s=1.0)
    text = str(failure.value)
    assert "world.robot.color == (3, 0, 0)" in text
    assert "did not hold within 1 s (from 0.000 to 1.000 s)" in text
    assert "scripted but not delivered (2)" in text and "[collision]" in text
    assert "from 'left'  Ping(n=2)" in text
    assert "robot 0 (Reactor) at 1.000 s" in text and "LED (0, 0, 0)" in text


def test_never_fails_at_the_first_time_it_held_with_the_state_that_led_there():
    world = ScriptedWorld(Reactor(), layouts=[PING])
    world.never(lambda: world.robot.color != (0, 0, 0), for_s=1.0)
    world.hear(PING.pack(n=3), at_s=1.5, distance_mm=40, sender="s")
    with pytest.raises(AssertionError) as failure:
        world.never(lambda: world.robot.color != (0, 0, 0), for_s=2.0, what="LED stays off")
    text = str(failure.value)
    assert text.startswith(f"LED stays off held at {1.5 + AIRTIME_S:.3f} s")
    assert "0.504 s into the 2 s from 1.000 s" in text
    assert "ping distance_mm=40, n=3" in text and "answer=Ping(n=4)" in text


def test_assert_sent_finds_the_message_or_lists_what_was_sent():
    world = ScriptedWorld(Reactor(), layouts=[PING])
    world.hear(PING.pack(n=2), at_s=0.1)
    found = world.assert_sent(PING, within_s=1.0, n=3)
    assert found.fields == PING.record(3) and found.t_s < 0.5  # its first opportunity
    assert world.assert_sent(2).message.type == 2
    with pytest.raises(AssertionError) as failure:
        world.assert_sent(PING, n=pytest.approx(10, abs=2))
    text = str(failure.value)
    assert "robot 0 sent no ping with n=10 ± 2" in text
    assert "it sent 1 of type 2 and 0 of other types" in text and "Ping(n=3)" in text


# ------------------------------------------------------------------------------ misuse


def test_time_going_backwards_is_refused():
    world = ScriptedWorld(Listener())
    world.advance(2.0)
    with pytest.raises(ScriptError, match=r"advance\(-0.5\): time only moves forward"):
        world.advance(-0.5)
    with pytest.raises(ScriptError, match=r"run_until\(1.0\) is before now \(2.000 s\)"):
        world.run_until(1.0)
    with pytest.raises(ScriptError, match=r"hear\(\) at 1.000 s from 'x': that is before now"):
        world.hear(PING.pack(n=1), at_s=1.0, sender="x")
    with pytest.raises(ScriptError, match="within_s=-1"):
        world.eventually(lambda: True, within_s=-1)


def test_messages_too_long_for_the_payload_are_refused_naming_who():
    world = ScriptedWorld(Listener())
    with pytest.raises(PayloadError, match=r"hear\(\) at 0.000 s from 'b': message payload of 10"):
        world.hear(Message(bytes(range(1, 11)), 1), sender="b")

    class Talker(Kilobot):
        def message_tx(self):
            return Message(bytes(range(1, 11)), 1)

    world = ScriptedWorld(Talker())
    with pytest.raises(PayloadError, match=r"robot 0 \(Talker\) offered a message at 0\.\d+ s"):
        world.advance(1.0)


def test_unknown_robots_and_impossible_worlds_are_refused():
    world = ScriptedWorld(Listener())
    world.add_neighbour(Listener(), distance_mm=40)
    with pytest.raises(ScriptError, match=r"robot 2 is not in this world: .* 1 neighbour \(1-1\)"):
        world.sent(robot=2)
    with pytest.raises(ScriptError, match="distance_mm=300 is outside"):
        world.hear(PING.pack(n=1), distance_mm=300)
    with pytest.raises(ScriptError, match=r"at_mm=.* or distance_mm="):
        world.add_neighbour(Listener())
    with pytest.raises(ScriptError, match="is not a Kilobot program"):
        ScriptedWorld(object())
    world.advance(0.1)
    with pytest.raises(ScriptError, match="add them before the first advance"):
        world.add_neighbour(Listener(), distance_mm=40)
    with pytest.raises(ScriptError, match="needs the message's Layout"):
        world.assert_sent(2, n=1)
    with pytest.raises(ScriptError, match="layout 'ping' has no field m; it has n"):
        world.assert_sent(PING, m=1)
    twice = Listener()
    world = ScriptedWorld(twice)
    world.add_neighbour(twice, distance_mm=40)
    with pytest.raises(ScriptError, match="one program instance cannot run on two robots"):
        world.advance(1.0)
