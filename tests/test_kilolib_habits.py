"""kilolib habits a ported C program brings: RGB(), message_crc, TICKS_PER_SEC, C integers,
messages it tries to change, message_tx returning something else, a loop spinning on a sensor."""

from __future__ import annotations

import dataclasses

import pytest

from kilonet.cint import c_div, c_mod, int16, uint8
from kilonet.message import Message, PayloadError, message_crc
from kilonet.params import Params
from kilonet.robot import RGB, TICKS_PER_SEC, Kilobot
from kilonet.simulation import Simulation

PAIR = [[0.0, 0.0], [50.0, 0.0]]


class Colours(Kilobot):
    def setup(self):
        self.set_color(RGB(1, 2, 3))
        self.ticks = self.TICKS_PER_SEC


def test_set_color_takes_kilolibs_packed_rgb():
    sim = Simulation(PAIR, Colours, Params(seed=1, duration_s=0.1))
    sim.run()
    assert sim.robots[0].color == (1, 2, 3)
    assert RGB(3, 0, 0) == 3 and RGB(0, 0, 3) == 48
    assert sim.robots[0].ticks == TICKS_PER_SEC == 31


def test_ticks_per_sec_follows_the_nominal_rate():
    params = Params(seed=1, duration_s=0.1).with_overrides({"robot.ticks_per_s": 32})
    sim = Simulation(PAIR, Colours, params)
    sim.run()
    assert sim.robots[0].ticks == 32


def test_rgb_and_set_color_refuse_what_kilolib_would_mask():
    with pytest.raises(ValueError, match="0-3"):
        RGB(4, 0, 0)
    sim = Simulation(PAIR, Kilobot, Params(seed=1))
    with pytest.raises(ValueError, match="0-63"):
        sim.robots[0].set_color(64)


def test_message_crc_is_a_robot_method_as_in_kilolib():
    msg = Message(bytes([5]), 1)
    assert Kilobot.message_crc(msg) == message_crc(msg)
    with_crc = dataclasses.replace(msg, crc=Kilobot.message_crc(msg))
    assert with_crc.crc_ok and with_crc.crc == message_crc(msg)


def test_changing_a_message_says_what_to_write_instead():
    msg = Message(bytes([5]), 1)
    with pytest.raises(AttributeError, match=r"msg = dataclasses.replace\(msg, crc=\.\.\.\)"):
        msg.crc = 0
    with pytest.raises(AttributeError, match=r"msg\.data = "):
        msg.data = b"x"
    assert msg.crc is None and msg.data == bytes([5])


def test_c_integers():
    assert int16(300 * 110) == 33000 - 65536
    assert uint8(-1) == 255
    assert (c_div(-30, 64), c_mod(-30, 64)) == (0, -30)


@pytest.mark.parametrize("returned", [b"\x01", "hi", 7, (i for i in range(3))])
def test_message_tx_returning_no_message_names_the_robot(returned):
    class Wrong(Kilobot):
        def message_tx(self):
            return returned if self.kilo_uid == 1 else None

    sim = Simulation(PAIR, Wrong, Params(seed=1, duration_s=2))
    with pytest.raises(
        PayloadError, match=r"robot 1's message_tx\(\) returned " + type(returned).__name__
    ):
        sim.run()


def test_an_oversized_payload_is_a_payload_error_naming_the_robot():
    class Big(Kilobot):
        def message_tx(self):
            return Message(bytes(10), 1)

    with pytest.raises(PayloadError, match="exceeds the kilolib limit"):
        Simulation(PAIR, Big, Params(seed=1, duration_s=2)).run()


class Speaker(Kilobot):
    def message_tx(self):
        return Message(bytes([1]), 1)


class SpinsOnTheSensor(Kilobot):
    """kilolib's literal retry loop: spin while the ADC is busy with an arriving message."""

    def setup(self):
        self.failed = 0
        self.spun = []

    def message_rx(self, message, distance):
        # called at the end of a reception: the next message may already be arriving; either
        # way the loop below must end.
        self.spin()

    def loop(self):
        self.spin()

    def spin(self):
        tries = 0
        while self.get_ambientlight() == -1:
            tries += 1
        self.spun.append(tries)


def test_a_loop_spinning_on_a_busy_sensor_reads_once_the_message_has_ended():
    params = Params(seed=1, duration_s=20)
    sim = Simulation(PAIR, lambda i: SpinsOnTheSensor() if i == 0 else Speaker(), params)
    sim.run()
    spun = sim.robots[0].spun
    assert len(spun) > 100
    busy = [t for t in spun if t]
    assert busy, "no loop met a message arriving (seed 1 has some)"
    # a message holds the ADC for at most its airtime: 3.2 ms / 104 us = 31 conversions
    assert max(busy) <= sim.medium.airtime_s / (13 * 64 / 8e6) + 1
