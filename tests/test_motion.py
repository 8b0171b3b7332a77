"""Tests for kilonet.motion: forward motion, pivoting, per-robot errors, contact, and the
medium's receiver sets following robots that move."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.distance import pdist

from kilonet.message import Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


def exact_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """No battery, no speed or turn-rate errors, unless the test sets them."""
    return Params(seed=seed).with_overrides(
        {
            "battery.enabled": False,
            "motion.speed_error": 0.0,
            "motion.turn_error": 0.0,
            **(overrides or {}),
        }
    )


def drive(sim: Simulation, motors: dict[int, tuple[int, int]], seconds: float) -> None:
    """Run the given robots' motors for ``seconds`` from now, then switch them off."""
    sim.start()
    for robot, (left, right) in motors.items():
        sim.robots[robot].set_motors(left, right)
    sim.run(sim.env.now + seconds)
    for robot in motors:
        sim.robots[robot].set_motors(0, 0)


# -------------------------------------------------------------------- speed and turn rate


@pytest.mark.parametrize("heading", [0.0, math.pi / 2, 2.5])
def test_forward_at_nominal_speed(heading):
    sim = Simulation([[0, 0], [500, 500]], Kilobot, exact_params(), headings_rad=[heading, 0])
    drive(sim, {0: (255, 255)}, 2.0)
    expected = [20 * math.cos(heading), 20 * math.sin(heading)]
    assert sim.world.positions_mm[0].tolist() == pytest.approx(expected, abs=1e-9)
    assert sim.world.positions_mm[1].tolist() == [500.0, 500.0]
    assert sim.world.heading_rad[0] == pytest.approx(heading, abs=1e-12)


def test_speed_parameter():
    params = exact_params({"motion.speed_mm_s": 4.0})
    sim = Simulation([[0, 0], [500, 0]], Kilobot, params, headings_rad=[0, 0])
    drive(sim, {0: (255, 255)}, 5.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([20.0, 0.0], abs=1e-9)


@pytest.mark.parametrize(
    ("motors", "turn_rad"),
    [((0, 255), math.pi / 4), ((255, 0), -math.pi / 4)],  # right only: left turn; left only: right
)
def test_pivot_at_nominal_rate(motors, turn_rad):
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[1.0, 0])
    drive(sim, {0: motors}, 1.0)
    assert sim.world.heading_rad[0] == pytest.approx(1.0 + turn_rad, abs=1e-12)
    assert sim.world.positions_mm[0].tolist() == [0.0, 0.0]  # pivoting does not translate


def test_heading_wraps_to_0_2pi():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[0.1, 0])
    drive(sim, {0: (255, 0)}, 1.0)
    assert sim.world.heading_rad[0] == pytest.approx(0.1 - math.pi / 4 + 2 * math.pi, abs=1e-12)


def test_per_robot_speed_and_turn_errors():
    n = 30
    positions = [[100.0 * k, 0.0] for k in range(n)]
    params = exact_params({"motion.speed_error": 0.2, "motion.turn_error": 0.2})
    sim = Simulation(positions, Kilobot, params, headings_rad=[math.pi / 2] * n)
    speeds = sim.motion.speed_mm_s.copy()
    turns = sim.motion.turn_rad_s.copy()
    # Each robot's own error, drawn once: sd about 20 % of nominal.
    assert np.std(speeds) == pytest.approx(2.0, rel=0.4)
    assert np.std(np.degrees(turns)) == pytest.approx(9.0, rel=0.4)
    assert np.mean(speeds) == pytest.approx(10.0, abs=4 * 2.0 / math.sqrt(n))
    drive(sim, dict.fromkeys(range(n), (255, 255)), 1.0)
    travelled = sim.world.positions_mm[:, 1]
    np.testing.assert_allclose(travelled, speeds, atol=1e-9)
    np.testing.assert_allclose(
        sim.world.positions_mm[:, 0], [100.0 * k for k in range(n)], atol=1e-9
    )
    drive(sim, dict.fromkeys(range(n), (0, 255)), 1.0)
    np.testing.assert_allclose(sim.world.heading_rad, math.pi / 2 + turns, atol=1e-9)
    # Same seed, same robots: the errors are part of the reproducible run.
    again = Simulation(positions, Kilobot, params, headings_rad=[math.pi / 2] * n)
    np.testing.assert_array_equal(again.motion.speed_mm_s, speeds)


# ---------------------------------------------------------------------------- no overlaps


def _min_distance_while_driving(sim, motors, seconds, dt=0.02) -> float:
    """Drive and return the smallest centre distance seen at every ``dt``."""
    sim.start()
    for robot, (left, right) in motors.items():
        sim.robots[robot].set_motors(left, right)
    closest = math.inf
    end = sim.env.now + seconds
    while sim.env.now < end - 1e-9:
        sim.run(sim.env.now + dt)
        for robot in motors:  # integrate the poses up to now before looking
            sim.motion.set_motors(robot, *sim.motion.motors[robot])
        closest = min(closest, float(pdist(sim.world.positions_mm).min()))
    return closest


def test_blocked_move_stops_at_contact():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    closest = _min_distance_while_driving(sim, {0: (255, 255)}, 3.0)
    assert closest >= 33.0 - 1e-9
    assert sim.world.positions_mm[0].tolist() == pytest.approx([17.0, 0.0], abs=1e-9)
    assert sim.motion.blocked_count[0] > 0
    poses = sim.trace.poses_frame()
    gaps = np.hypot(poses["x_mm"] - 50.0, poses["y_mm"])
    assert gaps.min() >= 33.0 - 1e-9


def test_head_on_robots_stop_at_contact():
    sim = Simulation([[0, 0], [60, 0]], Kilobot, exact_params(), headings_rad=[0, math.pi])
    closest = _min_distance_while_driving(sim, {0: (255, 255), 1: (255, 255)}, 3.0)
    assert closest >= 33.0 - 1e-9
    assert float(pdist(sim.world.positions_mm)[0]) == pytest.approx(33.0, abs=1e-9)


def test_glancing_move_stops_at_contact():
    # Robot 0 drives along y = 20 past robot 1 at (60, 0): their discs meet off-centre.
    positions = [[0, 20], [60, 0], [0, -60], [120, 40]]
    sim = Simulation(positions, Kilobot, exact_params(), headings_rad=[0, 0, 0.3, math.pi])
    motors = {0: (255, 255), 2: (255, 255), 3: (255, 255)}
    closest = _min_distance_while_driving(sim, motors, 4.0)
    assert closest >= 33.0 - 1e-9
    x_contact = 60 - math.sqrt(33.0**2 - 20.0**2)  # 33.75 mm
    assert sim.world.positions_mm[0].tolist() == pytest.approx([x_contact, 20.0], abs=1e-9)


# ------------------------------------------------------------- the medium follows motion


class Talker(Kilobot):
    """Robot 0 listens; every other robot offers a message at every opportunity."""

    def __init__(self, log: list) -> None:
        self.journal = log

    def message_tx(self) -> Message | None:
        return None if self.kilo_uid == 0 else Message(b"\x01")

    def message_tx_success(self) -> None:
        self.journal.append(("tx", self.kilo_uid, self._sim.env.now))

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.journal.append(("rx", self.kilo_uid, self._sim.env.now, distance_mm))


def test_robot_driving_out_of_range_stops_being_heard():
    # The talker drives away from 50 mm at 10 mm/s and leaves the 85 mm range at 3.5 s.
    log: list = []
    params = exact_params({"ranging.sigma_mm": 0.0})
    sim = Simulation([[0, 0], [50, 0]], lambda i: Talker(log), params, headings_rad=[0, 0])
    drive(sim, {1: (255, 255)}, 6.0)
    rx = [(t, d) for name, _, t, *rest in log if name == "rx" for d in rest]
    last = max(t for t, _ in rx)
    assert 3.2 <= last <= 3.5 + 0.05 + 0.0032 + 1e-9
    assert len([t for t, _ in rx if t > 3.0]) >= 1
    # Each estimate tracks the talker's distance when it sent (poses step every 50 ms).
    for t, d in rx:
        assert abs(d - (50 + 10 * t)) <= 1.5
    assert sim.medium.receivers_of(1) == []
    sent_after = [t for name, r, t, *_ in log if name == "tx" and t > 3.6]
    assert len(sent_after) > 5  # it kept talking, nobody heard


def test_robot_driving_into_range_starts_being_heard():
    # From 150 mm towards the listener: in range (85 mm) from 6.5 s, contact at 33 mm (11.7 s).
    log: list = []
    params = exact_params({"ranging.sigma_mm": 0.0})
    sim = Simulation([[0, 0], [150, 0]], lambda i: Talker(log), params, headings_rad=[0, math.pi])
    drive(sim, {1: (255, 255)}, 15.0)
    rx = [t for name, _, t, *_ in log if name == "rx"]
    assert 6.5 - 0.05 <= min(rx) <= 6.5 + 0.25
    assert sim.world.positions_mm[1].tolist() == pytest.approx([33.0, 0.0], abs=1e-9)
    assert sim.medium.receivers_of(1) == [0]


def test_line_of_sight_follows_a_moving_blocker():
    # A blocker drives across the line between talker and listener and out again.
    log: list = []
    positions = [[0, 0], [80, 0], [40, -40]]
    params = exact_params({"motion.speed_mm_s": 10.0})
    sim = Simulation(
        positions,
        lambda i: Talker(log) if i < 2 else Kilobot(),
        params,
        headings_rad=[0, 0, math.pi / 2],
    )
    drive(sim, {2: (255, 255)}, 8.0)  # y from -40 to +40: blocks while |y| < 16.5
    rx = [t for name, r, t, *_ in log if name == "rx" and r == 0]
    blocked = [t for t in rx if 2.35 + 0.06 < t < 5.65 - 0.01]
    assert blocked == []
    assert any(t < 2.3 for t in rx) and any(t > 5.7 for t in rx)


class Counter:
    """Counts calls to a wrapped function."""

    def __init__(self, fn) -> None:
        self.fn = fn
        self.calls = 0

    def __call__(self, *args, **kwargs):
        self.calls += 1
        return self.fn(*args, **kwargs)


def test_static_swarm_records_no_poses_and_never_rebuilds():
    log: list = []
    positions = [[0, 0], [40, 0], [0, 40], [40, 40]]
    sim = Simulation(positions, lambda i: Talker(log), exact_params())
    rebuild = Counter(sim.medium.rebuild_topology)
    sim.medium.rebuild_topology = rebuild
    sim.run(20.0)
    assert sim.trace.poses_frame().empty
    assert rebuild.calls == 0
    assert len([e for e in log if e[0] == "rx"]) > 100
    np.testing.assert_array_equal(sim.world.positions_mm, positions)


def test_crashed_robot_stops_moving():
    sim = Simulation([[0, 0], [300, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    sim.faults.crash_at(0, 1.0)
    sim.start()
    sim.robots[0].set_motors(255, 255)
    sim.run(3.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([10.0, 0.0], abs=1e-9)
    sim.robots[0].set_motors(255, 255)  # a stopped robot ignores its motors
    sim.run(4.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([10.0, 0.0], abs=1e-9)


def test_removed_robot_is_no_obstacle():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    sim.faults.remove_at(1, 0.5)
    drive(sim, {0: (255, 255)}, 8.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([80.0, 0.0], abs=1e-9)
    assert sim.motion.blocked_count[0] == 0
