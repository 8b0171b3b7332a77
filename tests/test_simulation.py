"""Tests for kilonet.simulation: the run, its random streams, the robot API and its results."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from kilonet.counters import LOSS_CAUSES
from kilonet.message import Layout, Message
from kilonet.params import Params
from kilonet.placement import PlacementError
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.simulation import STREAMS, Simulation, stream_for


def quiet_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """Parameters without a battery model, with perfect clocks and the disc medium (one hard
    radius, iid ranging noise), plus overrides."""
    return Params(seed=seed).with_overrides(
        {
            "battery.enabled": False,
            "robot.clock_sd": 0.0,
            "medium.reach": "disc",
            "ranging.model": "gaussian",
            **(overrides or {}),
        }
    )


# --------------------------------------------------------------------- reproducibility

HOPS = Layout("hops", type=1, fields=[("hops", "B")])


class Hops(Kilobot):
    """A gradient-like program: robot 0 is the source; others keep min(heard) + 1."""

    def setup(self) -> None:
        self.hops = 0 if self.kilo_uid == 0 else 255
        if self.hops == 0:
            self.set_color(3, 3, 3)

    def message_tx(self) -> Message | None:
        return None if self.hops == 255 else HOPS.pack(hops=self.hops)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        heard = HOPS.unpack(message).hops
        if heard + 1 < self.hops:
            self.hops = heard + 1
            self.set_color(self.hops % 4, 0, 3 - self.hops % 4)
            self.log("hops", hops=self.hops, distance_mm=distance_mm)

    def loop(self) -> None:
        if self.kilo_ticks % 64 == 0 and self.rand.random() < 0.5:
            self.log("tick", value=float(self.rand.random()))


def _gradient_run(seed: int) -> Simulation:
    params = Params(seed=seed, duration_s=20.0).with_overrides(
        {
            "medium.loss_prob": 0.3,
            "ranging.sigma_mm": 2.0,
            "ranging.bias_sigma_mm": 1.5,
            "trace.messages": True,
            "battery.idle_drain_v_per_h": 50.0,
        }
    )
    positions = hex_lattice(12, spacing_mm=45.0, jitter_mm=4.0, rng=stream_for(seed, "placement"))
    sim = Simulation(positions, Hops, params)
    sim.run()
    return sim


def _frames(sim: Simulation) -> dict[str, pd.DataFrame]:
    t = sim.trace
    return {
        "robots": sim.robots_frame(),
        "led": t.led_frame(),
        "events": t.events_frame(),
        "messages": t.messages_frame(),
        "stops": t.stops_frame(),
        "poses": t.poses_frame(),
    }


def test_same_seed_gives_identical_traces():
    a, b = _frames(_gradient_run(5)), _frames(_gradient_run(5))
    for name in a:
        assert a[name].equals(b[name]), name
    # The run did something worth comparing: losses, noisy estimates, a spreading gradient.
    assert len(a["messages"]) > 400  # 12 robots, 20 s, one message every 0.5 s
    assert a["robots"]["lost_random"].sum() > 100
    assert len(a["events"]) > 10 and len(a["led"]) > 5
    assert a["events"]["event"].eq("hops").sum() >= 11


def test_different_seed_gives_a_different_trace():
    a, b = _frames(_gradient_run(5)), _frames(_gradient_run(6))
    for name in ("robots", "events", "messages"):
        assert not a[name].equals(b[name]), name


def test_streams_are_independent_and_match_stream_for():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, Params(seed=11))
    assert set(STREAMS) == {
        "medium",
        "ranging",
        "battery",
        "faults",
        "motion",
        "placement",
        "clock",
        "sensors",
        "calibration",
        "radio",
    }
    first = {name: float(stream_for(11, name).random()) for name in STREAMS}
    assert len(set(first.values())) == len(STREAMS)
    assert float(sim.stream("placement").random()) == first["placement"]
    assert float(stream_for(12, "placement").random()) != first["placement"]


def test_robot_random_sources_differ_and_repeat():
    def draws(seed: int) -> list[int]:
        sim = Simulation([[0, 0], [50, 0], [100, 0]], Kilobot, Params(seed=seed))
        return [r.rand_hard() for r in sim.robots]

    assert draws(3) == draws(3)
    assert len(set(draws(3))) > 1 or len(set(draws(4))) > 1
    assert all(0 <= v <= 255 for v in draws(3))


def test_rand_soft_is_kilolibs_generator_the_same_on_every_robot_until_seeded():
    sim = Simulation([[0, 0], [50, 0], [100, 0]], Kilobot, Params(seed=3))
    a, b, c = sim.robots
    assert [a.rand_soft() for _ in range(4)] == [253, 21, 184, 123]  # kilolib: seed 0xAA
    assert [b.rand_soft() for _ in range(4)] == [253, 21, 184, 123]
    c.rand_seed(c.rand_hard())
    assert [c.rand_soft() for _ in range(8)] != [a.rand_soft() for _ in range(8)]


# ----------------------------------------------------------------------- program API


class Clock(Kilobot):
    """Logs setup and every loop() with its tick count."""

    def __init__(self, log: list) -> None:
        self.journal = log

    def setup(self) -> None:
        self.journal.append(("setup", self.kilo_uid, self._kenv.now))

    def loop(self) -> None:
        self.journal.append(("loop", self.kilo_uid, self._kenv.now, self.kilo_ticks))


@pytest.mark.parametrize("loop_ticks", [1, 8])
def test_setup_once_then_loop_every_few_ticks_of_the_robots_own_clock(loop_ticks):
    log: list = []
    params = Params(seed=4).with_overrides(
        {"battery.enabled": False, "robot.loop_ticks": loop_ticks, "robot.clock_sd": 0.02}
    )
    sim = Simulation([[0, 0], [50, 0]], lambda i: Clock(log), params)
    sim.run(3.0)
    assert [e for e in log if e[0] == "setup"] == [("setup", 0, 0.0), ("setup", 1, 0.0)]
    for robot in (0, 1):
        rate = sim.clocks.rate_hz(robot)
        times = np.array([e[2] for e in log if e[0] == "loop" and e[1] == robot])
        ticks = [e[3] for e in log if e[0] == "loop" and e[1] == robot]
        assert 0.0 <= times[0] < 1 / rate
        np.testing.assert_allclose(np.diff(times), loop_ticks / rate, rtol=1e-9)
        assert ticks == list(range(0, loop_ticks * len(ticks), loop_ticks))  # mid-tick, exact
    assert sim.clocks.rate_hz(0) != sim.clocks.rate_hz(1)


def test_kilo_ticks_count_the_hardware_timer_on_perfect_clocks():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params())
    sim.run(2.5)
    assert sim.robots[0].ticks_per_s == 8e6 / 1024 / 256  # 30.52 Hz; TICKS_PER_SEC says 31
    assert sim.robots[0].kilo_ticks == 76  # 2.5 s x 30.52
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params({"robot.ticks_per_s": 32}))
    sim.run(2.0)
    assert sim.robots[1].kilo_ticks == 64


def test_each_robot_counts_ticks_at_its_own_rate():
    params = Params(seed=2).with_overrides({"battery.enabled": False, "robot.clock_sd": 0.01})
    sim = Simulation(hex_lattice(50, spacing_mm=40.0), Kilobot, params)
    sim.run(100.0)
    ticks = np.array([r.kilo_ticks for r in sim.robots])
    rate = sim.params.robot.ticks_per_s
    expected = np.floor(100.0 * rate * sim.clocks.factor + sim.clocks.phase)
    np.testing.assert_array_equal(ticks, expected)
    assert ticks.max() - ticks.min() > 60  # ±1 % of 3,052 ticks: tens of ticks apart
    assert sim.robots_frame()["clock_factor"].tolist() == sim.clocks.factor.tolist()


def test_kilo_uid_only_with_hardware_uids():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params())
    assert [r.kilo_uid for r in sim.robots] == [0, 1]
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params({"robot.hardware_uids": False}))
    with pytest.raises(AttributeError, match="hardware_uids = false"):
        _ = sim.robots[0].kilo_uid


def test_program_per_robot_and_type_check():
    class Source(Kilobot):
        pass

    sim = Simulation([[0, 0], [50, 0]], lambda i: Source() if i == 0 else Kilobot(), Params())
    assert [type(r).__name__ for r in sim.robots] == ["Source", "Kilobot"]
    with pytest.raises(TypeError, match=r"program\(1\) returned str, not a Kilobot"):
        Simulation([[0, 0], [50, 0]], lambda i: Kilobot() if i == 0 else "x", Params())


def test_bad_placement_is_refused():
    with pytest.raises(PlacementError, match="closer than the 33 mm"):
        Simulation([[0, 0], [20, 0]], Kilobot, Params())


class Painter(Kilobot):
    def setup(self) -> None:
        self.set_color(1, 2, 3)
        self.set_color(1, 2, 3)  # unchanged: not recorded again
        self.log("painted", shade=[1, 2, 3])

    def loop(self) -> None:
        if self.kilo_ticks >= 32:
            self.set_color(0, 0, 0)


def test_led_changes_and_events_are_traced():
    sim = Simulation([[0, 0], [50, 0]], Painter, quiet_params())
    sim.run(2.0)
    led = sim.trace.led_frame()
    rows = led[["t_s", "robot", "r", "g", "b"]].values.tolist()
    assert rows[:2] == [[0.0, 0, 1, 2, 3], [0.0, 1, 1, 2, 3]]
    assert sorted(row[1:] for row in rows[2:]) == [[0, 0, 0, 0], [1, 0, 0, 0]]
    off = led[led["r"] == 0]["t_s"]
    tick = 1 / sim.params.robot.ticks_per_s
    assert ((off >= 32 * tick) & (off < 33 * tick + 1e-9)).all()  # the loop of tick 32
    events = sim.trace.events_frame()
    assert events.values.tolist() == [
        [0.0, 0, "painted", '{"shade": [1, 2, 3]}'],
        [0.0, 1, "painted", '{"shade": [1, 2, 3]}'],
    ]
    frame = sim.robots_frame()
    assert frame[["led_r", "led_g", "led_b"]].values.tolist() == [[0, 0, 0], [0, 0, 0]]


@pytest.mark.parametrize("color", [(4, 0, 0), (0, -1, 0), (0, 0, 1.5)])
def test_set_color_refuses_out_of_range(color):
    sim = Simulation([[0, 0], [50, 0]], Kilobot, Params())
    with pytest.raises(ValueError, match="0-3"):
        sim.robots[0].set_color(*color)


def test_stop_when_ends_the_run_early():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params())
    sim.run(30.0, stop_when=lambda: sim.env.now >= 4.0)
    assert sim.env.now == 4.0
    sim = Simulation([[0, 0], [50, 0]], Kilobot, quiet_params({"duration_s": 3.0}))
    sim.run()
    assert sim.env.now == 3.0


# ---------------------------------------------------------------------------- results


class Chatter(Kilobot):
    def setup(self) -> None:
        self.heard = 0

    def message_tx(self) -> Message | None:
        return Message(b"\x01\x02")

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.heard += 1


def test_summary_totals_match_per_robot_counters_and_callbacks():
    params = quiet_params({"medium.loss_prob": 0.2, "medium.airtime_s": 0.02, "seed": 9})
    positions = hex_lattice(7, spacing_mm=40.0)
    positions[4] += [30.0, 30.0]  # out of some robots' range: hidden terminals, collisions
    sim = Simulation(positions, Chatter, params)
    sim.run(20.0)
    c = sim.medium.counters
    s = sim.summary()
    assert s["robots"] == 7 and s["seed"] == 9 and s["sim_time_s"] == 20.0
    assert s["messages_sent"] == sum(c["sent"])
    assert s["backoffs"] == sum(c["backoffs"]) > 0
    assert s["bytes_sent"] == 5 * s["messages_sent"]
    assert s["receptions_delivered"] == sum(c["received"]) == sum(r.heard for r in sim.robots)
    assert [c["received"][i] for i in range(7)] == [r.heard for r in sim.robots]
    for cause in LOSS_CAUSES:
        assert s[f"lost_{cause}"] == sum(c[f"lost_{cause}"])
    assert s["lost_random"] > 0 and s["lost_collision"] > 0
    assert s["robots_stopped"] == 0
    frame = sim.robots_frame()
    assert frame["received"].tolist() == c["received"]
    assert frame["sent"].tolist() == c["sent"]
    assert frame[["x0_mm", "y0_mm"]].values.tolist() == positions.tolist()


def test_a_robot_alone_is_a_simulation():
    sim = Simulation([[0, 0]], Painter, quiet_params({"duration_s": 1.0}))
    sim.run()
    assert sim.n_robots == 1 and sim.robots[0].color == (1, 2, 3)
    assert sim.robots_frame().sent.tolist() == [0]
    with pytest.raises(PlacementError, match="0 robots, at least 1 is needed"):
        Simulation(np.empty((0, 2)), Kilobot, Params())


def test_reception_listeners_see_what_the_program_is_handed_before_it_is():
    seen: list = []

    class Shouter(Kilobot):
        def message_tx(self):
            return Message(b"\x05", 1)

    class Ear(Kilobot):
        def setup(self):
            self.got = 0

        def message_rx(self, message, distance_mm):
            assert len(seen) == self.got + 1  # the listener came first
            self.got += 1

    sim = Simulation([[0, 0], [50, 0]], lambda i: Shouter() if i else Ear(), quiet_params())
    sim.watch_receptions(0, lambda message, distance: seen.append((message.data, distance)))
    sim.run(3.0)
    assert sim.robots[0].got == len(seen) == sim.robots_frame().received[0] > 0
    assert {data for data, _ in seen} == {b"\x05"}
    with pytest.raises(RuntimeError, match="before the simulation starts"):
        sim.watch_receptions(1, print)


class Blinker(Kilobot):
    """kilolib's blink: on, delay(500), off, delay(500), and round again."""

    def loop(self):
        self.set_color(1, 0, 0)
        yield self.delay(500)
        self.set_color(0, 0, 0)
        yield self.delay(500)


def test_a_blocking_loop_runs_again_at_once_and_its_delays_run_on_its_own_clock():
    params = Params(seed=5).with_overrides({"battery.enabled": False, "robot.clock_sd": 0.02})
    sim = Simulation([[0, 0], [50, 0]], Blinker, params)
    sim.run(10.0)
    led = sim.trace.led_frame()
    for robot in (0, 1):
        times = led[led.robot == robot]["t_s"].to_numpy()
        own_half_s = 0.5 / sim.clocks.factor[robot]
        assert len(times) >= 19
        np.testing.assert_allclose(np.diff(times), own_half_s, rtol=1e-9)  # no tick in between
        assert times[0] == pytest.approx(sim.clocks.first_mid_tick_s(robot))


class Forgetful(Kilobot):
    def loop(self):
        self.delay(100)  # no yield: nothing blocks
        yield self.delay(100)


def test_a_delay_that_is_not_yielded_is_an_error_that_says_so():
    sim = Simulation([[0, 0], [50, 0]], Forgetful, Params(seed=1))
    with pytest.raises(RuntimeError, match=r"delay\(\) was called without `yield`"):
        sim.run(1.0)


class PlainDelay(Kilobot):
    def loop(self):
        self.delay(100)


def test_delay_in_a_plain_loop_is_refused_with_the_way_out():
    sim = Simulation([[0, 0], [50, 0]], PlainDelay, Params(seed=1))
    with pytest.raises(RuntimeError, match=r"write `yield self\.delay\(ms\)`"):
        sim.run(1.0)


# ------------------------------------------------------------------------ timing guarantees


class TickCounter(Kilobot):
    """Counts its loop() calls and the ticks they saw."""

    def setup(self) -> None:
        self.calls = 0
        self.first = self.last = None

    def loop(self) -> None:
        ticks = self.kilo_ticks
        if self.first is None:
            self.first = ticks
        self.last = ticks
        self.calls += 1


class GeneratorTickCounter(TickCounter):
    """The same counter as a generator loop that never blocks (kilolib-style ports with
    ``yield self.delay(ms)`` only in some branches look like this between their delays)."""

    def loop(self):
        super().loop()
        if False:
            yield self.delay(0)


@pytest.mark.parametrize("program", [TickCounter, GeneratorTickCounter])
@pytest.mark.parametrize("loop_ticks", [1, 3])
def test_loop_runs_exactly_once_per_tick_over_long_runs_with_drifting_clocks(program, loop_ticks):
    params = quiet_params({"robot.clock_sd": 0.01, "robot.loop_ticks": loop_ticks}, seed=4)
    sim = Simulation(hex_lattice(12, spacing_mm=200.0), program, params)
    sim.run(600.0)
    for robot in sim.robots:
        assert robot.last - robot.first == (robot.calls - 1) * loop_ticks
        assert robot.first in (0, 1)  # the middle of tick 0 may have passed at the start
        assert robot.kilo_ticks - robot.last <= loop_ticks  # no call missing at the end either


def test_kilo_tx_period_below_the_jitter_is_refused():
    class Fast(Kilobot):
        def setup(self) -> None:
            self.kilo_tx_period = 100  # one tick of kilolib's timer, 33 ms: below the jitter

    params = quiet_params({"robot.tx_period_s": 0.2, "robot.tx_jitter_s": 0.05})
    with pytest.raises(ValueError, match=r"must exceed robot.tx_jitter_s = 0.05 s"):
        Simulation([[0, 0]], Fast, params).run(1.0)


@pytest.mark.parametrize("times_the_period", [1.0, 1.4])
def test_a_jitter_not_below_the_period_is_refused_naming_both_keys(times_the_period):
    jitter_s = Params().robot.tx_period_s * times_the_period
    with pytest.raises(ValueError, match=r"robot\.tx_jitter_s .* below robot\.tx_period_s"):
        Params().with_overrides({"robot.tx_jitter_s": jitter_s})


def test_offers_never_run_the_clock_backwards_at_the_largest_jitter():
    times = []

    class Stamp(Kilobot):
        def message_tx(self):
            times.append(self._kenv.now)
            return None

    params = quiet_params(
        {"robot.tx_period_s": 0.2, "robot.tx_jitter_s": 0.1999, "robot.tx_retry": "period"}
    )
    Simulation(hex_lattice(5, spacing_mm=200.0), Stamp, params).run(20.0)
    assert len(times) > 400 and times == sorted(times)


class PrivateRate(TickCounter):
    """A program with state named like the kernel's former slots."""

    def setup(self) -> None:
        super().setup()
        self._rate, self._theta, self._index, self._env, self._sim = 0.5, 0.9, -1, None, None
        self._color, self._rx_buffer = "red", []


def test_a_program_attribute_named_like_kernel_state_changes_nothing():
    params = quiet_params({"robot.clock_sd": 0.01})
    plain = Simulation([[0, 0]], TickCounter, params)
    private = Simulation([[0, 0]], PrivateRate, params)
    plain.run(10.0)
    private.run(10.0)
    assert private.robots[0].kilo_ticks == plain.robots[0].kilo_ticks > 300
    assert private.robots[0].calls == plain.robots[0].calls
    assert private.robots[0]._rate == 0.5


def test_kernel_names_are_refused_when_a_program_defines_or_sets_them():
    class Defines(Kilobot):
        _kstate = 3

    with pytest.raises(TypeError, match=r"Defines\._kstate: names starting with '_k'"):
        Simulation([[0, 0]], Defines, quiet_params())

    class SetsNew(Kilobot):
        def setup(self) -> None:
            self._kmine = 1

    with pytest.raises(TypeError, match=r"robot 0 \(SetsNew\) set _kmine"):
        Simulation([[0, 0]], SetsNew, quiet_params()).run(1.0)

    class Overwrites(Kilobot):
        def setup(self):
            self._krate = 0.5
            yield self.delay(10)

    with pytest.raises(TypeError, match=r"robot 0 \(Overwrites\) set _krate: names"):
        Simulation([[0, 0]], Overwrites, quiet_params()).run(1.0)


class SlowStart(Kilobot):
    def setup(self):
        self.started = True
        yield self.delay(100)


def test_a_plain_setup_calling_a_generator_parent_setup_is_refused():
    class Plain(SlowStart):
        def setup(self) -> None:
            super().setup()
            self.mine = True

    with pytest.raises(TypeError, match=r"Plain\.setup is a plain function but calls super"):
        Simulation([[0, 0]], Plain, quiet_params())


def test_a_generator_setup_running_its_generator_parent_setup_works():
    class Chained(SlowStart):
        def setup(self):
            yield from super().setup()
            self.mine = self.kilo_ticks

    class Replaces(SlowStart):  # overrides without calling the parent: allowed
        def setup(self) -> None:
            self.mine = 0

    sim = Simulation(
        [[0, 0], [100, 0]], lambda i: Chained() if i == 0 else Replaces(), quiet_params()
    )
    sim.run(1.0)
    assert sim.robots[0].started and sim.robots[0].mine == 3  # 100 ms of 31 ticks a second
    assert not hasattr(sim.robots[1], "started") and sim.robots[1].mine == 0


def test_a_plain_loop_calling_a_generator_parent_loop_is_refused():
    class Parent(Kilobot):
        def loop(self):
            yield self.delay(10)

    class Child(Parent):
        def loop(self) -> None:
            super().loop()

    with pytest.raises(
        TypeError, match=r"Child\.loop is a plain function but calls super\(\)\.loop"
    ):
        Simulation([[0, 0]], Child, quiet_params())


# --------------------------------------------------------------------- the wiring


def _held_by_robot(robot: Kilobot) -> dict[str, object]:
    """Every attribute a robot holds: its kernel slots and its program's own."""
    slots = [name for name in Kilobot.__slots__ if not name.startswith("__")]
    return {**{n: getattr(robot, n) for n in slots if hasattr(robot, n)}, **vars(robot)}


def test_no_component_holds_the_simulation():
    sim = Simulation(hex_lattice(7, spacing_mm=40.0), Hops, quiet_params())
    for part in (sim.medium, sim.battery, sim.motion, sim.sensors, sim.faults):
        held = [name for name, value in vars(part).items() if value is sim]
        assert held == [], f"{type(part).__name__} holds the simulation in {held}"
    sim.run(1.0)
    for robot in sim.robots:
        held = [name for name, value in _held_by_robot(robot).items() if value is sim]
        assert held == [], f"robot {robot.kilo_uid} holds the simulation in {held}"
    assert sim.robots[0]._kservices is sim.robot_services


class _Carrying(Kilobot):
    """Reads the extra hardware it was fitted with, or notes that it has none."""

    def setup(self) -> None:
        try:
            self.reading = self.hardware("probe")()
        except LookupError as error:
            self.reading = str(error)


def test_extra_hardware_is_fitted_per_robot_and_reached_by_name():
    fitted = []

    def fit(sim: Simulation, index: int):
        fitted.append(index)
        if index == 1:
            return None  # robot 1 carries none
        world = sim.world
        return lambda: float(world.positions_mm[index, 0])  # a sensor reading the truth

    sim = Simulation(
        [[0, 0], [50, 0], [100, 0]], _Carrying, quiet_params(), hardware={"probe": fit}
    )
    sim.start()
    assert fitted == [0, 1, 2]
    assert sim.robots[0].reading == 0.0
    assert sim.robots[2].reading == 100.0
    assert "robot 1 carries no 'probe' hardware" in sim.robots[1].reading
    bare = Simulation([[0, 0]], _Carrying, quiet_params())
    bare.start()
    assert "carries no 'probe' hardware" in bare.robots[0].reading


class _Everything(Kilobot):
    """Every part of the robot API a plain program can reach."""

    def setup(self) -> None:
        self.kilo_tx_period = 3000
        self.readings = (self.get_ambientlight(), self.get_voltage(), self.get_temperature())
        self.rates = (self.ticks_per_s, self.TICKS_PER_SEC, self.polled, self.kilo_tx_period)
        self.set_motors(self.kilo_straight_left, self.kilo_straight_right)

    def loop(self) -> None:
        self.set_color(self.kilo_ticks % 4, 0, 0)
        if self.kilo_ticks > 20:
            self.spinup_motors()
            self.set_motors(0, 0)

    def message_tx(self) -> Message:
        return Message(bytes([self.kilo_uid]))

    def message_rx(self, message: Message, distance: int) -> None:
        self.log("heard", distance=self.estimate_distance(distance))


def test_the_robot_api_runs_on_its_services_alone():
    sim = Simulation(hex_lattice(4, spacing_mm=40.0), _Everything, quiet_params())
    sim.run(2.0)
    assert all(r.rates == (30.517578125, 31, False, 3000) for r in sim.robots)
    assert all(r.readings[1] == 716 for r in sim.robots)  # 4.2 V
    assert len(sim.trace.events_frame()) > 0
    for robot in sim.robots:  # what it reached it reached through its services
        assert not any(value is sim for value in _held_by_robot(robot).values())
