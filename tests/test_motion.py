"""Tests for kilonet.motion: forward motion, pivoting, per-robot errors, contact, and the
medium's receiver sets following robots that move."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.distance import pdist

from kilonet.message import Message
from kilonet.motion import motor_drive
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.simulation import Simulation

#: One hard radius (85 mm) and iid ranging noise: where a test needs the range to be one number.
DISC = {"medium.reach": "disc", "ranging.model": "gaussian"}


def exact_params(overrides: dict | None = None, *, seed: int = 1) -> Params:
    """No battery, no per-robot speed, turn-rate, motor-curve or calibration errors, unless the
    test sets them: every motor's curve is duty = 60 + 15 * drive, stored values 75."""
    return Params(seed=seed).with_overrides(
        {
            "battery.enabled": False,
            "motion.speed_error": 0.0,
            "motion.turn_error": 0.0,
            "motion.motor_offset_sd": 0.0,
            "motion.motor_gain_sd": 0.0,
            "motion.calibration_sd": 0.0,
            **(overrides or {}),
        }
    )


def drive(sim: Simulation, motors: dict[int, tuple[int, int]], seconds: float) -> None:
    """Spin up, then run the given robots' motors for ``seconds`` from now, then stop them."""
    sim.start()
    for robot, (left, right) in motors.items():
        sim.robots[robot].spinup_motors()
        sim.robots[robot].set_motors(left, right)
    sim.run(sim.env.now + seconds)
    for robot in motors:
        sim.robots[robot].set_motors(0, 0)


STRAIGHT, LEFT, RIGHT = (75, 75), (75, 0), (0, 75)
#: The rear legs in the body frame (forward, left), mm: 16.5 mm out at 125.5 degrees.
LEG = (16.5 * math.cos(math.radians(125.5)), 16.5 * math.sin(math.radians(125.5)))


def rotate(v, angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


# ------------------------------------------------------------- the motor curve, kilolib's API


def test_calibrated_values_are_the_true_best_ones_without_calibration_error():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params())
    bot = sim.robots[0]
    assert (bot.kilo_turn_left, bot.kilo_turn_right) == (75, 75)
    assert (bot.kilo_straight_left, bot.kilo_straight_right) == (75, 75)


def test_each_robot_stores_calibration_values_that_miss_its_true_best_ones():
    n = 400
    params = exact_params({"motion.motor_offset_sd": 3.0, "motion.calibration_sd": 2.0})
    sim = Simulation([[50.0 * k, 0.0] for k in range(n)], Kilobot, params)
    best = sim.motion.offset + sim.motion.gain  # duty at drive 1, per robot and motor
    stored = np.array([[r.kilo_turn_left, r.kilo_turn_right] for r in sim.robots])
    straight = np.array([[r.kilo_straight_left, r.kilo_straight_right] for r in sim.robots])
    assert np.std(best[:, 0]) == pytest.approx(3.0, rel=0.15)  # the robots differ ...
    miss = np.concatenate([(stored - best).ravel(), (straight - best).ravel()])
    assert np.std(miss) == pytest.approx(np.hypot(2.0, 1 / np.sqrt(12)), rel=0.1)  # ... and so
    assert abs(np.mean(miss)) < 0.15  # do their stored values, by calibration error and rounding
    assert (stored != straight).any()


def test_motor_drive_follows_the_curve_with_stall_and_start_thresholds():
    p = exact_params().motion
    assert motor_drive(90, 60.0, 15.0, True, p) == (2.0, True)
    assert motor_drive(150, 60.0, 15.0, True, p) == (2.0, True)  # saturates at max_drive
    assert motor_drive(69, 60.0, 15.0, True, p) == (0.6, True)
    assert motor_drive(67, 60.0, 15.0, True, p) == (0.0, False)  # stalls below 0.5
    assert motor_drive(75, 60.0, 15.0, False, p) == (0.0, False)  # at rest: needs 1.2 to start
    assert motor_drive(78, 60.0, 15.0, False, p) == (1.2, True)
    assert motor_drive(0, 60.0, 15.0, True, p) == (0.0, False)


def test_a_motor_at_rest_needs_a_spin_up_at_its_calibrated_value():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    sim.start()
    bot = sim.robots[0]
    bot.set_motors(bot.kilo_straight_left, bot.kilo_straight_right)
    sim.run(2.0)
    assert sim.world.positions_mm[0].tolist() == [0.0, 0.0]  # static friction holds it
    bot.spinup_motors()
    bot.set_motors(bot.kilo_straight_left, bot.kilo_straight_right)
    sim.run(4.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([20.0, 0.0], abs=1e-9)
    bot.set_motors(66, 66)  # drive 0.4: below the stall threshold, the motors stop
    sim.run(6.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([20.0, 0.0], abs=1e-9)


@pytest.mark.parametrize(("duty", "speed_mm_s"), [(75, 10.0), (69, 6.0), (90, 20.0), (255, 20.0)])
def test_forward_speed_follows_the_drive(duty, speed_mm_s):
    sim = Simulation([[0, 0], [500, 500]], Kilobot, exact_params(), headings_rad=[0.5, 0])
    drive(sim, {0: (duty, duty)}, 2.0)
    expected = 2 * speed_mm_s * np.array([math.cos(0.5), math.sin(0.5)])
    assert sim.world.positions_mm[0].tolist() == pytest.approx(expected.tolist(), abs=1e-9)
    assert sim.world.heading_rad[0] == pytest.approx(0.5, abs=1e-12)
    assert sim.world.positions_mm[1].tolist() == [500.0, 500.0]


def test_speed_parameter():
    params = exact_params({"motion.speed_mm_s": 4.0})
    sim = Simulation([[0, 0], [500, 0]], Kilobot, params, headings_rad=[0, 0])
    drive(sim, {0: STRAIGHT}, 5.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([20.0, 0.0], abs=1e-9)


@pytest.mark.parametrize(("motors", "sign"), [(LEFT, 1.0), (RIGHT, -1.0)])
def test_one_motor_pivots_about_its_rear_leg_as_kilolib_turns(motors, sign):
    # kilolib: set_motors(kilo_turn_left, 0) turns left, counter-clockwise, at 45 deg/s.
    heading = 1.0
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[heading, 0])
    drive(sim, {0: motors}, 1.0)
    assert sim.world.heading_rad[0] == pytest.approx(heading + sign * math.pi / 4, abs=1e-12)
    leg = rotate((LEG[0], sign * LEG[1]), heading)  # the leg on the turning side stays put
    expected = leg + rotate(-leg, sign * math.pi / 4)
    assert sim.world.positions_mm[0].tolist() == pytest.approx(expected.tolist(), abs=1e-9)
    moved = float(np.hypot(*sim.world.positions_mm[0]))
    assert moved == pytest.approx(2 * 16.5 * math.sin(math.pi / 8), abs=1e-9)  # a chord, 12.6 mm


def test_a_full_turn_on_one_motor_brings_the_centre_back_along_a_circle():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[0.0, 0])
    sim.start()
    bot = sim.robots[0]
    bot.spinup_motors()
    bot.set_motors(bot.kilo_turn_left, 0)
    leg = np.array(LEG)
    gaps = []
    for _ in range(16):
        sim.run(sim.env.now + 0.5)
        sim.motion.set_motors(0, *sim.motion.motors[0].duty)  # integrate up to now
        gaps.append(float(np.hypot(*(sim.world.positions_mm[0] - leg))))
    assert gaps == pytest.approx([16.5] * 16, abs=1e-9)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([0.0, 0.0], abs=1e-9)  # 8 s, 360°


def test_stronger_left_motor_curves_the_robot_left():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[0.0, 0])
    drive(sim, {0: (78, 72)}, 2.0)  # drives 1.2 and 0.8: yaw 0.5 * 45 deg/s * 0.4 = 9 deg/s
    assert math.degrees(sim.world.heading_rad[0]) == pytest.approx(18.0, abs=1e-9)
    x, y = sim.world.positions_mm[0]
    radius = 10.0 / math.radians(9.0)  # 10 mm/s on a circle: the chord of 18 degrees
    assert (x, y) == pytest.approx(
        (radius * math.sin(math.radians(18)), radius * (1 - math.cos(math.radians(18)))), abs=1e-9
    )


def test_heading_wraps_to_0_2pi():
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params(), headings_rad=[0.1, 0])
    drive(sim, {0: RIGHT}, 1.0)
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
    drive(sim, dict.fromkeys(range(n), STRAIGHT), 1.0)
    travelled = sim.world.positions_mm[:, 1]
    np.testing.assert_allclose(travelled, speeds, atol=1e-9)
    np.testing.assert_allclose(
        sim.world.positions_mm[:, 0], [100.0 * k for k in range(n)], atol=1e-9
    )
    drive(sim, dict.fromkeys(range(n), LEFT), 1.0)
    np.testing.assert_allclose(sim.world.heading_rad, math.pi / 2 + turns, atol=1e-9)
    # Same seed, same robots: the errors are part of the reproducible run.
    again = Simulation(positions, Kilobot, params, headings_rad=[math.pi / 2] * n)
    np.testing.assert_array_equal(again.motion.speed_mm_s, speeds)


@pytest.mark.parametrize("bad", [(-1, 0), (0, 256), (1.5, 0)])
def test_set_motors_refuses_values_outside_a_byte(bad):
    sim = Simulation([[0, 0], [500, 0]], Kilobot, exact_params())
    with pytest.raises(ValueError, match="0-255"):
        sim.robots[0].set_motors(*bad)


# ------------------------------------------------------------------------ bodies slide along


def _min_distance_while_driving(sim, motors, seconds, dt=0.02) -> float:
    """Drive and return the smallest centre distance seen at every ``dt``."""
    sim.start()
    for robot, (left, right) in motors.items():
        sim.robots[robot].spinup_motors()
        sim.robots[robot].set_motors(left, right)
    closest = math.inf
    end = sim.env.now + seconds
    while sim.env.now < end - 1e-9:
        sim.run(sim.env.now + dt)
        for robot in motors:  # integrate the poses up to now before looking
            sim.motion.set_motors(robot, *sim.motion.motors[robot].duty)
        closest = min(closest, float(pdist(sim.world.positions_mm).min()))
    return closest


def test_a_head_on_move_stops_at_contact():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    closest = _min_distance_while_driving(sim, {0: STRAIGHT}, 3.0)
    assert closest >= 33.0 - 1e-9
    assert sim.world.positions_mm[0].tolist() == pytest.approx([17.0, 0.0], abs=1e-9)
    assert sim.motion.blocked_count[0] > 0
    poses = sim.trace.poses_frame()
    assert np.hypot(poses["x_mm"] - 50.0, poses["y_mm"]).min() >= 33.0 - 1e-9


def test_head_on_robots_stop_at_contact():
    sim = Simulation([[0, 0], [60, 0]], Kilobot, exact_params(), headings_rad=[0, math.pi])
    closest = _min_distance_while_driving(sim, {0: STRAIGHT, 1: STRAIGHT}, 3.0)
    assert closest >= 33.0 - 1e-9
    assert float(pdist(sim.world.positions_mm)[0]) == pytest.approx(33.0, abs=1e-9)


def test_a_glancing_move_slides_along_the_other_body_and_goes_on():
    # Robot 0 drives along y = 20 at robot 1 at (60, 0): their discs meet off-centre, and it
    # slides round robot 1 instead of sticking there.
    sim = Simulation([[0, 20], [60, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    closest = _min_distance_while_driving(sim, {0: STRAIGHT}, 12.0)
    assert closest >= 33.0 - 1e-9
    x, y = sim.world.positions_mm[0]
    assert x > 60.0 + 33.0  # past robot 1, 120 mm of driving less what the slide cost
    assert y >= 33.0 - 1e-6  # pushed out to the side of robot 1's body
    assert sim.motion.blocked_count[0] > 0
    assert sim.world.positions_mm[1].tolist() == [60.0, 0.0]  # the other body does not move


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**16), st.lists(st.sampled_from([STRAIGHT, LEFT, RIGHT]), min_size=6,
                                         max_size=6))  # fmt: skip
def test_a_crowd_driving_at_random_never_overlaps(seed, motors):
    positions = hex_lattice(6, spacing_mm=36.0, jitter_mm=1.0, rng=np.random.default_rng(seed))
    sim = Simulation(positions, Kilobot, exact_params(seed=seed))
    closest = _min_distance_while_driving(sim, dict(enumerate(motors)), 4.0, dt=0.1)
    assert closest >= 33.0 - 1e-6


# ------------------------------------------------------------- the medium follows motion


class Talker(Kilobot):
    """Robot 0 listens; every other robot offers a message at every opportunity."""

    def __init__(self, log: list) -> None:
        self.journal = log

    def message_tx(self) -> Message | None:
        return None if self.kilo_uid == 0 else Message(b"\x01")

    def message_tx_success(self) -> None:
        self.journal.append(("tx", self.kilo_uid, self._kenv.now))

    def message_rx(self, message: Message, distance_mm: int) -> None:
        self.journal.append(("rx", self.kilo_uid, self._kenv.now, distance_mm))


def test_robot_driving_out_of_range_stops_being_heard():
    # The talker drives away from 50 mm at 10 mm/s and leaves the 85 mm range at 3.5 s.
    log: list = []
    params = exact_params({**DISC, "ranging.sigma_mm": 0.0, "robot.tx_period_s": 0.2})
    sim = Simulation([[0, 0], [50, 0]], lambda i: Talker(log), params, headings_rad=[0, 0])
    drive(sim, {1: STRAIGHT}, 6.0)
    rx = [(t, d) for name, _, t, *rest in log if name == "rx" for d in rest]
    last = max(t for t, _ in rx)
    assert 3.2 <= last <= 3.5 + 0.05 + sim.medium.airtime_s + 1e-9
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
    params = exact_params({**DISC, "ranging.sigma_mm": 0.0, "robot.tx_period_s": 0.2})
    sim = Simulation([[0, 0], [150, 0]], lambda i: Talker(log), params, headings_rad=[0, math.pi])
    drive(sim, {1: STRAIGHT}, 15.0)
    rx = [t for name, _, t, *_ in log if name == "rx"]
    assert 6.5 - 0.05 <= min(rx) <= 6.5 + 0.25
    assert sim.world.positions_mm[1].tolist() == pytest.approx([33.0, 0.0], abs=1e-9)
    assert sim.medium.receivers_of(1) == [0]


def test_line_of_sight_follows_a_moving_blocker():
    # A blocker drives across the line between talker and listener and out again.
    log: list = []
    positions = [[0, 0], [80, 0], [40, -40]]
    params = exact_params({"motion.speed_mm_s": 10.0, "medium.occlusion": "block"})
    sim = Simulation(
        positions,
        lambda i: Talker(log) if i < 2 else Kilobot(),
        params,
        headings_rad=[0, 0, math.pi / 2],
    )
    drive(sim, {2: STRAIGHT}, 8.0)  # y from -40 to +40: blocks while |y| < 16.5
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
    sim.robots[0].spinup_motors()
    sim.robots[0].set_motors(*STRAIGHT)
    sim.run(3.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([10.0, 0.0], abs=1e-9)
    sim.robots[0].spinup_motors()  # a stopped robot ignores its motors
    sim.robots[0].set_motors(*STRAIGHT)
    sim.run(4.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([10.0, 0.0], abs=1e-9)


def test_removed_robot_is_no_obstacle():
    sim = Simulation([[0, 0], [50, 0]], Kilobot, exact_params(), headings_rad=[0, 0])
    sim.faults.remove_at(1, 0.5)
    drive(sim, {0: STRAIGHT}, 8.0)
    assert sim.world.positions_mm[0].tolist() == pytest.approx([80.0, 0.0], abs=1e-9)
    assert sim.motion.blocked_count[0] == 0


def test_motor_command_listeners_hear_every_command_of_running_robots():
    commands: list = []

    class Driver(Kilobot):
        def setup(self):
            self.spinup_motors()
            self.set_motors(self.kilo_straight_left, self.kilo_straight_right)

        def loop(self):
            if self.kilo_ticks == 31:
                self.set_motors(0, 0)

    sim = Simulation([[0, 0], [200, 0]], Driver, Params(seed=1))
    sim.motion.watch(lambda robot, left, right: commands.append((sim.env.now, robot, left, right)))
    sim.faults.crash_at(1, 0.5)
    sim.run(2.0)
    straight = [(r.kilo_straight_left, r.kilo_straight_right) for r in sim.robots]
    assert commands[:4] == [
        (0.0, 0, 255, 255), (0.0, 0, *straight[0]), (0.0, 1, 255, 255), (0.0, 1, *straight[1]),
    ]  # fmt: skip
    # Robot 0 stops its motors in its loop at tick 31; robot 1 crashed before its tick 31.
    (stop,) = commands[4:]
    tick_31_s = (31.5 - sim.clocks.phase[0]) / sim.clocks.rate_hz(0)  # loops run mid-tick
    assert stop == (pytest.approx(tick_31_s), 0, 0, 0)
