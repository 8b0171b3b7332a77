"""Tests for kilonet.battery: drain with time and motor use, degradation, cut-off."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.battery import degradation
from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


def battery_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """A battery without motor drain or motor-speed errors unless the test sets them, on the
    disc medium (one hard radius: the range a low battery shrinks is one number)."""
    return Params(seed=seed).with_overrides(
        {
            "battery.enabled": True,
            "medium.reach": "disc",
            "battery.motor_drain_v_per_h": 0.0,
            "motion.speed_error": 0.0,
            "motion.turn_error": 0.0,
            "motion.motor_offset_sd": 0.0,
            "motion.motor_gain_sd": 0.0,
            "motion.calibration_sd": 0.0,
            "robot.clock_sd": 0.0,
            "robot.tx_period_s": 0.2,
            "robot.tx_jitter_s": 0.02,
            **(overrides or {}),
        }
    )


class Meter(Kilobot):
    """Logs its voltage every loop() and offers a message when ``send`` is set."""

    def __init__(self, log: list, *, send: bool = False) -> None:
        self.journal = log
        self.send = send

    def loop(self) -> None:
        self.journal.append(("volts", self.kilo_uid, self._kenv.now, self.get_voltage()))

    # kilolib's get_voltage() is a raw ADC reading: about 169 counts per volt.

    def message_tx(self) -> Message | None:
        return Message(b"\x01") if self.send else None

    def message_tx_success(self) -> None:
        self.journal.append(("tx", self.kilo_uid, self._kenv.now))

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.journal.append(("rx", self.kilo_uid, self._kenv.now))


def test_degradation_level():
    volts = np.array([4.2, 3.6, 3.5, 3.4, 3.2, 3.0])
    np.testing.assert_allclose(degradation(volts, 3.6, 3.2), [0, 0, 0.25, 0.5, 1, 1], atol=1e-12)


def test_voltage_falls_linearly_with_time():
    log: list = []
    params = battery_params({"battery.idle_drain_v_per_h": 36.0, "robot.loop_ticks": 16})
    sim = Simulation([[0, 0], [500, 0]], lambda i: Meter(log), params)
    sim.run(10.0)
    for robot in (0, 1):
        readings = [(t, v) for name, r, t, v in log if name == "volts" and r == robot]
        assert len(readings) == 20  # every 16 of 31 ticks a second
        for t, v in readings:
            volts = 4.2 - 0.01 * t  # 36 V/h = 0.01 V/s
            assert v == round(169 * volts + 6)  # kilolib's reading: 716 at 4.2 V, 547 at 3.2 V
    assert sim.battery.voltage(0) == pytest.approx(4.1, abs=1e-12)
    np.testing.assert_allclose(sim.robots_frame()["voltage_v"], [4.1, 4.1], atol=1e-12)


def test_voltage_falls_faster_with_motors_running():
    params = battery_params(
        {"battery.idle_drain_v_per_h": 36.0, "battery.motor_drain_v_per_h": 36.0}
    )
    sim = Simulation([[0, 0], [300, 0], [0, 300]], Kilobot, params, headings_rad=[0, 0, 0])
    sim.start()
    sim.robots[1].spinup_motors()
    sim.robots[1].set_motors(75, 75)  # two motors: 2 x 0.01 V/s extra
    sim.robots[2].spinup_motors()
    sim.robots[2].set_motors(0, 75)  # one motor (pivoting): 0.01 V/s extra
    sim.run(5.0)
    sim.robots[1].set_motors(0, 0)
    sim.robots[2].set_motors(0, 0)
    sim.run(10.0)
    np.testing.assert_allclose(sim.battery.voltages(), [4.1, 4.0, 4.05], atol=1e-9)


def test_disabled_battery_keeps_its_voltage_and_never_degrades():
    params = battery_params(
        {"battery.enabled": False, "battery.initial_v": 3.3, "battery.idle_drain_v_per_h": 90.0}
    )
    log: list = []
    sim = Simulation([[0, 0], [80, 0]], lambda i: Meter(log, send=i == 0), params)
    sim.run(10.0)
    assert sim.battery.voltage(0) == 3.3
    assert sim.medium.receivers_of(0) == [1]  # full range
    assert sum(sim.medium.counters["lost_battery"]) == 0
    assert sim.stop_causes == {}


def _degraded(initial_v: float) -> tuple[Simulation, list]:
    """A sender with a near (60 mm) and a far (75 mm) listener, all at ``initial_v``."""
    log: list = []
    params = battery_params({"battery.initial_v": initial_v, "battery.idle_drain_v_per_h": 0.0})
    sim = Simulation([[0, 0], [60, 0], [0, 75]], lambda i: Meter(log, send=i == 0), params)
    sim.run(60.0)
    return sim, log


def test_full_battery_does_not_degrade():
    sim, _ = _degraded(4.2)
    c = sim.medium.counters
    assert c["received"][1] == c["received"][2] > 250
    assert sum(c["lost_battery"]) == 0
    np.testing.assert_allclose(sim.battery.led_factor, 1.0)
    np.testing.assert_allclose(sim.battery.motor_factor, 1.0)


def test_low_battery_shrinks_range_and_raises_loss():
    # 3.4 V is halfway from degrade_v (3.6) to cutoff_v (3.2): range x 0.8 = 68 mm, extra loss
    # 0.5 x 0.5 = 0.25 per reception, motors x 0.75, LED x 0.65.
    sim, _ = _degraded(3.4)
    c = sim.medium.counters
    assert sim.medium.receivers_of(0) == [1]
    assert c["received"][2] == 0 and c["lost_battery"][2] == 0  # out of the shrunk range
    sent = c["sent"][0]
    near = c["received"][1] + c["lost_battery"][1]
    assert sent - 1 <= near <= sent  # the last message may still be on the air
    share = c["lost_battery"][1] / near
    assert abs(share - 0.25) <= 4 * math.sqrt(0.25 * 0.75 / near)
    np.testing.assert_allclose(sim.battery.motor_factor, 0.75, atol=1e-12)
    np.testing.assert_allclose(sim.battery.led_factor, 0.65, atol=1e-12)


def test_low_battery_slows_the_motors():
    params = battery_params({"battery.initial_v": 3.4, "battery.idle_drain_v_per_h": 0.0})
    sim = Simulation([[0, 0], [300, 0]], Kilobot, params, headings_rad=[0.0, 0.0])
    sim.start()
    sim.robots[0].spinup_motors()
    sim.robots[0].set_motors(75, 75)
    sim.run(2.0)
    sim.robots[0].set_motors(0, 0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([15.0, 0.0], abs=1e-9)


def test_range_shrinks_as_the_battery_drains():
    # 100 V/h: 4.2 V at 0 s, degrade_v 3.6 V at 21.6 s; the 75 mm listener drops out when the
    # range falls below 75 mm, i.e. factor 75/85 = 1 - f * 0.4, f = 0.294, V = 3.482 at 25.8 s.
    log: list = []
    params = battery_params({"battery.idle_drain_v_per_h": 100.0})
    sim = Simulation([[0, 0], [0, 75]], lambda i: Meter(log, send=i == 0), params)
    sim.run(35.0)
    heard = [t for name, r, t in (e[:3] for e in log) if name == "rx" and r == 1]
    assert 25.0 <= heard[-1] <= 27.0
    assert len([t for t in heard if t < 21.6]) > 100


def test_cutoff_stops_the_robot():
    # 100 V/h from 4.2 V reaches cutoff_v = 3.2 V after 36 s.
    log: list = []
    params = battery_params({"battery.idle_drain_v_per_h": 100.0})
    sim = Simulation([[0, 0], [0, 50]], lambda i: Meter(log, send=True), params)
    sim.run(45.0)
    stops = sim.trace.stops_frame()
    assert stops["cause"].tolist() == ["battery", "battery"]
    assert ((stops["t_s"] >= 36.0) & (stops["t_s"] < 37.0)).all()
    assert sim.stop_causes == {0: "battery", 1: "battery"}
    frame = sim.robots_frame()
    assert frame["stop_cause"].tolist() == ["battery", "battery"]
    assert not frame["running"].any() and frame["present"].all()
    stopped_at = stops["t_s"].max()
    assert all(t <= stopped_at for name, _, t, *_ in log if name in ("tx", "rx", "volts"))
    assert sim.summary()["robots_stopped"] == 2
