"""The receive port (kilonet.port, issue 42): one chain between the medium and a program, its
stages in a fixed order whatever order they were plugged in, and the only writer of the entries
the medium calls."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from kilonet.clock import KernelEnvironment
from kilonet.message import Message
from kilonet.params import Params
from kilonet.port import ReceivePorts
from kilonet.ranging import DistanceMeasurement, calibration_tables


def _ports(
    overrides: dict | None = None, n: int = 2
) -> tuple[ReceivePorts, KernelEnvironment, np.ndarray]:
    """Ports of ``n`` robots, their clock and their ``running`` flags."""
    params = Params(seed=1).with_overrides(overrides or {})
    env = KernelEnvironment()
    running = np.ones(n, dtype=bool)
    tables = calibration_tables(n, np.random.default_rng(0))
    return ReceivePorts(params.robot, env, running, tables), env, running


def test_stages_run_in_order_and_the_medium_is_told_of_every_reroute():
    ports, env, _ = _ports()
    rerouted: list = []
    ports.on_reroute(rerouted.append)
    got: list = []
    ports.connect(
        [lambda m, d: got.append(("rx0", m.data, d)), lambda m, d: got.append(("rx1", m.data, d))],
        [deque(maxlen=3), deque(maxlen=3)],
        lambda robot: None,
    )
    assert rerouted == [None]
    # A fault plugged in before a watcher: the watcher still sees the reception after the delay.
    ports.delay(1, 1.0, 0.5, np.random.default_rng(3))
    ports.watch(1, lambda m, d: got.append(("watch", env.now, d)))
    assert rerouted == [None, 1, 1]
    ports.entries[0](Message(b"\x01"), 40)
    ports.entries[1](Message(b"\x02"), 41)
    assert got == [("rx0", b"\x01", 40)]
    env.run(until=1.0)
    (watch, rx1) = got[1:]
    assert watch[0] == "watch" and 0 < watch[1] < 0.5 and watch[2] == 41
    assert rx1 == ("rx1", b"\x02", 41)


def test_a_delayed_reception_reaches_only_a_running_robot_and_a_stopped_port_drops():
    ports, env, running = _ports()
    got: list = []
    ports.connect(
        [got.append, lambda m, d: got.append(d)], [deque(maxlen=3)] * 2, lambda robot: None
    )
    ports.delay(1, 1.0, 0.5, np.random.default_rng(3))
    ports.entries[1](Message(b"\x02"), 41)
    running[1] = False  # the robot crashed while the reception was delayed
    env.run(until=1.0)
    assert got == []
    before = ports.entries[0]
    ports.stop(0)
    assert ports.entries[0] is not before
    ports.entries[0](Message(b"\x03"), 42)
    assert got == []


def test_polled_mode_with_measurements_buffers_raw_readings_and_counts_overflow():
    ports, _, _ = _ports({"robot.rx_mode": "polled", "robot.rx_distance": "raw"}, n=1)
    buffer: deque = deque(maxlen=2)
    overflow: list[int] = []
    ports.connect([pytest.fail], [buffer], overflow.append)
    for k in range(3):
        ports.entries[0](Message(bytes([k + 1])), 50)
    assert overflow == [0]
    assert [m.data for m, _ in buffer] == [b"\x02", b"\x03"]
    assert all(isinstance(d, DistanceMeasurement) for _, d in buffer)
