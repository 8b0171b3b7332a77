"""Tests of the trilateration follower: message, formulas, turn calibration and the scenario."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from kilonet.message import PayloadError
from kilonet.params import ParamError
from kilonet.placement import save_csv
from kilonet.protocols.common.geometry import place_references, trilaterate_linear
from kilonet.protocols.follower.follower import (
    FRAME_BYTE,
    FRAME_WIDE,
    FrameReport,
    circle_intersections,
    decode,
    encode,
    frame_direction,
    plan_direction,
    reachable_goal,
    turn_angle,
)
from kilonet.protocols.follower.turn_calibration import TurnCalibration
from kilonet.robot import Kilobot
from kilonet.scenarios.base import ScenarioError, build_params, run, write_outputs
from kilonet.scenarios.follower import (
    SCENARIO,
    calibrate_turns,
    frame_to_floor,
    run_many,
    trajectory,
)
from kilonet.simulation import Simulation

#: An equilateral frame with 75 mm sides, robot 3 on the left of the 1→2 axis.
FRAME = np.array([[0.0, 0.0], [75.0, 0.0], [37.5, 75.0 * math.sqrt(3) / 2]])
#: Motors without per-robot errors: the stored values turn at exactly 45 deg/s.
EXACT_MOTORS = {
    "motion.turn_error": 0.0,
    "motion.motor_offset_sd": 0.0,
    "motion.motor_gain_sd": 0.0,
    "motion.calibration_sd": 0.0,
}
GOAL = FRAME.mean(axis=0)


def _run(overrides=None, *, seed=1, placement=None):
    return run(SCENARIO, overrides or {}, seed=seed, placement=placement).summary


# ------------------------------------------------------------------------------ the message


def test_byte_layout_is_the_seeds_table():
    msg = encode(FrameReport(3, True, -12.0, 64.0, 75.0, 65.0, 96.0))
    assert msg.type == FRAME_BYTE.type == 8
    # data[0] ID, [1] flag, [2] X, [3] Y, [4] d12, [5] d13, [6] d23; 7 and 8 unused.
    assert list(msg.data) == [3, 1, 256 - 12, 64, 75, 65, 96]
    assert FRAME_BYTE.size_bytes == 7


def test_byte_layout_round_trip_rounds_to_whole_mm():
    report = FrameReport(2, True, 71.4, 0.0, 71.4)
    assert decode(encode(report)) == FrameReport(2, True, 71, 0, 71, 0, 0)


def test_byte_layout_refuses_coordinates_beyond_a_byte():
    with pytest.raises(PayloadError, match="x_mm"):
        encode(FrameReport(2, True, 130.0, 0.0, 130.0))


def test_wide_layout_round_trip_keeps_tenths_and_fits_nine_bytes():
    report = FrameReport(3, True, -12.34, 61.27, 75.06)
    got = decode(encode(report, wide=True))
    assert FRAME_WIDE.size_bytes <= 9
    assert (got.sender, got.known) == (3, True)
    assert got.x_mm == pytest.approx(-12.3) and got.y_mm == pytest.approx(61.3)
    assert got.d12_mm == pytest.approx(75.1)
    # d13 and d23 are not sent but follow from X, Y and d12.
    assert got.d13_mm == pytest.approx(math.hypot(-12.3, 61.3))
    assert got.d23_mm == pytest.approx(math.hypot(-12.3 - 75.1, 61.3))


def test_decode_ignores_other_messages():
    from kilonet.message import Message

    assert decode(Message(b"\x00\x01", type=1)) is None


# ------------------------------------------------------------------------------ formulas


def test_frame_of_three_hand_computed():
    # d12 = 6, d13 = d23 = 5: x3 = (25 - 25 + 36) / 12 = 3, y3 = sqrt(25 - 9) = 4.
    assert place_references(6.0, 5.0, 5.0) == ((6.0, 0.0), (3.0, 4.0))
    # d12 = 60, d13 = 80, d23 = 100: x3 = (6400 - 10000 + 3600) / 120 = 0, y3 = 80.
    assert place_references(60.0, 80.0, 100.0)[1] == (0.0, 80.0)


def test_trilateration_hand_computed():
    # Frame (0,0), (6,0), (3,4); follower at (3,1): d1 = d2 = √10, d3 = 3.
    # x4 = (10 - 10 + 36) / 12 = 3; y4 = (10 - 9 + 9 + 16) / 8 - 3·3/4 = 3.25 - 2.25 = 1.
    x4, y4 = trilaterate_linear([(0, 0), (6, 0), (3, 4)], [math.sqrt(10), math.sqrt(10), 3.0])
    assert (x4, y4) == pytest.approx((3.0, 1.0))
    # Frame (0,0), (60,0), (0,80); follower at the circumcentre (30,40): all distances 50.
    frame = [(0.0, 0.0), (60.0, 0.0), (0.0, 80.0)]
    assert trilaterate_linear(frame, [50.0, 50.0, 50.0]) == pytest.approx((30.0, 40.0))


def test_turn_angle_hand_computed():
    assert math.degrees(turn_angle((1, 0), (0, 1))) == pytest.approx(90.0)
    assert math.degrees(turn_angle((0, 1), (1, 0))) == pytest.approx(-90.0)
    assert math.degrees(turn_angle((1, 1), (1, 0))) == pytest.approx(-45.0)
    assert math.degrees(turn_angle((2, 0), (-3, 1e-12))) == pytest.approx(180.0)


def test_turn_direction_in_both_handedness_cases():
    alpha = turn_angle((1, 0), (0, 1))  # goal 90° counter-clockwise in the frame
    assert frame_direction(alpha, mirrored=False) == 1  # pivot left: kilolib's left motor
    assert frame_direction(alpha, mirrored=True) == -1  # mirrored frame: pivot right
    assert frame_direction(-alpha, mirrored=True) == 1
    assert frame_direction(0.0, mirrored=True) == 0


def test_kilolibs_left_turn_pivots_counter_clockwise_on_the_floor():
    """The convention frame_direction relies on: set_motors(kilo_turn_left, 0) turns left."""

    class Pivot(Kilobot):
        def setup(self):
            self.spinup_motors()
            self.set_motors(self.kilo_turn_left, 0)

    params = build_params(SCENARIO, {"duration_s": 1.0, **EXACT_MOTORS})
    sim = Simulation(
        [[0, 0], [200, 0]],
        lambda i: Pivot() if i == 0 else Kilobot(),
        params,
        headings_rad=[0.0, 0.0],
    )
    sim.run()
    sim.motion.stop(0)
    assert math.degrees(sim.world.heading_rad[0]) == pytest.approx(45.0, abs=0.01)


def test_circle_intersections_and_reachable_goal():
    points = sorted(circle_intersections((0, 0), 5, (8, 0), 5))
    assert points == [pytest.approx((4.0, -3.0)), pytest.approx((4.0, 3.0))]
    # A goal 30 mm from a robot's centre is moved out to 34 mm (contact plus clearance).
    assert reachable_goal((30.0, 0.0), [(0.0, 0.0)], 34.0) == pytest.approx((34.0, 0.0))


def test_planner_detours_round_a_body_on_the_path():
    # Far from the body a small correction suffices and commits to no side.
    (dx, dy), side = plan_direction((0.0, 0.0), (120.0, 0.0), [(60.0, 0.0)], 34.5, 20.0)
    assert side == 0 and 0.1 < abs(dy) <= math.sin(math.radians(20)) + 1e-9
    # Close to it, a detour: a side is chosen, and kept when asked to.
    (dx, dy), side = plan_direction((0.0, 0.0), (120.0, 0.0), [(40.0, 0.0)], 34.5, 20.0)
    assert side != 0 and abs(dy) > math.sin(math.radians(25))
    (dx, dy), kept = plan_direction((0.0, 0.0), (120.0, 0.0), [(40.0, 0.0)], 34.5, 20.0, -side)
    assert kept == -side and dy * side < 0
    (dx, dy), side = plan_direction((0.0, 0.0), (120.0, 0.0), [(60.0, 50.0)], 34.5, 20.0)
    assert (dx, dy, side) == (1.0, 0.0, 0)


def test_frame_to_floor_both_handedness():
    floor = frame_to_floor(FRAME, np.array([[37.5, 20.0]]))
    assert floor.tolist() == [pytest.approx([37.5, 20.0])]
    mirrored = FRAME * [1, -1]
    assert frame_to_floor(mirrored, np.array([[37.5, 20.0]])).tolist() == [
        pytest.approx([37.5, -20.0])
    ]


# ---------------------------------------------------------------------------- calibration


def test_calibration_fit_recovers_an_exact_line():
    angles = np.radians([30, 60, 90, 180])
    cal = TurnCalibration.fit(angles, 0.2 + 1.5 * angles)
    assert cal.s_per_rad == pytest.approx(1.5) and cal.offset_s == pytest.approx(0.2)
    with pytest.raises(ValueError, match="two distinct"):
        TurnCalibration.fit([1.0, 1.0], [2.0, 2.0])


def test_calibration_from_timed_turns_recovers_the_turn_rate():
    exact = calibrate_turns(build_params(SCENARIO, EXACT_MOTORS), seed=5, reading_sd_deg=0.0)
    assert exact.true_deg_s == pytest.approx(45.0)
    assert exact.calibration.deg_per_s == pytest.approx(45.0, rel=0.005)
    assert abs(exact.calibration.offset_s) < 0.02
    # A robot with its own rate error, read with 3° error per angle.
    noisy = calibrate_turns(build_params(SCENARIO), seed=2, reading_sd_deg=3.0)
    assert abs(noisy.true_deg_s - 45.0) > 0.1  # really another rate than nominal
    assert noisy.calibration.deg_per_s == pytest.approx(noisy.true_deg_s, rel=0.03)


# ------------------------------------------------------------------------------ placements


def test_placement_must_have_four_rows(tmp_path):
    path = tmp_path / "five.csv"
    save_csv(np.vstack([FRAME, [[37.5, 20.0], [300.0, 0.0]]]), path)
    with pytest.raises(ScenarioError, match="exactly 4 rows in role order"):
        run(SCENARIO, seed=1, placement=path)


def test_placement_with_a_deaf_follower_is_refused():
    far = np.vstack([FRAME, [[37.5, -100.0]]])  # 165 mm from robot 3
    with pytest.raises(
        ScenarioError,
        match=r"the follower stands 165.0 mm from robot 3, beyond the 148 mm a link reaches "
        r"\(medium.reach = argos\)",
    ):
        run(SCENARIO, seed=1, placement=far)
    disc = {"medium.reach": "disc"}  # one hard radius: medium.range_mm
    with pytest.raises(ScenarioError, match=r"135.0 mm from robot 3, beyond the 85 mm"):
        run(SCENARIO, disc, seed=1, placement=np.vstack([FRAME, [[37.5, -70.0]]]))


def test_placement_with_a_frame_too_wide_to_range_is_refused():
    wide = np.array([[0.0, 0.0], [110.0, 0.0], [55.0, 60.0], [55.0, 20.0]])
    with pytest.raises(ScenarioError, match=r"robot 2 stands 110.0 mm from robot 1, beyond the"):
        run(SCENARIO, {"follower.message": "wide"}, seed=1, placement=wide)


def test_collinear_frame_is_refused():
    line = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 2.0], [40.0, 40.0]])
    with pytest.raises(ScenarioError, match="nearly collinear"):
        run(SCENARIO, seed=1, placement=line)


def test_generator_needs_four_robots():
    with pytest.raises(ParamError, match="exactly 4 robots"):
        run(SCENARIO, {"placement.robots": 5}, seed=1)


def test_generated_placements_respect_the_geometry():
    from kilonet.scenarios.base import place
    from kilonet.scenarios.follower import ranging_mm

    for seed in range(1, 6):
        params = build_params(SCENARIO, {"follower.handedness": "right"}, seed=seed)
        pos = place(SCENARIO, params)
        sides = [np.linalg.norm(pos[a] - pos[b]) for a, b in ((0, 1), (0, 2), (1, 2))]
        assert all(60.0 <= s <= 80.0 for s in sides)
        assert np.linalg.norm(pos[:3] - pos[3], axis=1).min() >= 34.0
        # It starts where it ranges all three (follower.scenario's ranging_mm).
        assert np.linalg.norm(pos[:3] - pos[3], axis=1).max() <= ranging_mm(params) == 100.0
        (ax, ay), (bx, by) = pos[1] - pos[0], pos[2] - pos[0]
        assert ax * by - ay * bx < 0  # robot 3 on the right: a mirrored frame


# --------------------------------------------------------------------------- walking runs


@pytest.mark.parametrize(("seed", "handedness"), [(1, "left"), (2, "right"), (3, "random")])
def test_reaches_the_goal_from_generated_starts(seed, handedness):
    s = _run({"follower.handedness": handedness}, seed=seed)
    assert s["reached"] and s["outcome"] == "reached"
    assert s["final_distance_mm"] < 8.0
    assert s["sim_time_s"] < 600.0  # stop_when ended the run
    if s["handedness_settled"]:
        assert s["mirrored_frame"] == s["mirrored_frame_true"]


def test_the_default_run_walks_to_the_goal():
    """``kilonet run follower`` (seed 1, defaults) starts far enough to have to walk."""
    s = _run()
    assert s["straight_line_mm"] >= 20.0
    assert s["steps"] >= 3 and s["path_length_mm"] >= s["straight_line_mm"] - 8.0
    assert s["reached"] and s["final_distance_mm"] < 8.0


@pytest.mark.parametrize("handedness", ["left", "right"])
def test_mirrored_frame_is_detected(handedness):
    # Starts at least 20 mm from the goal, so the follower has to turn and step.
    s = _run({"follower.handedness": handedness, "follower.start_min_mm": 20.0}, seed=7)
    assert s["mirrored_frame_true"] == (handedness == "right")
    assert s["handedness_settled"]
    assert s["mirrored_frame"] == (handedness == "right")
    assert s["reached"]


def test_reaches_the_goal_from_outside_the_triangle_in_a_mirrored_frame():
    outside = np.vstack([FRAME * [1, -1], [[37.5, 20.0]]])  # beyond edge 1-2, frame mirrored
    s = _run(placement=outside, seed=3)
    assert s["mirrored_frame_true"] and s["mirrored_frame"]
    assert s["reached"] and s["final_distance_mm"] < 8.0
    assert s["straight_line_mm"] == pytest.approx(20.0 + 75.0 * math.sqrt(3) / 6, abs=1e-3)


@pytest.mark.parametrize("seed", [5, 6])
def test_works_with_twenty_percent_message_loss(seed):
    s = _run({"medium.loss_prob": 0.2, "follower.start_min_mm": 20.0}, seed=seed)
    assert s["reached"] and s["final_distance_mm"] < 8.0
    assert s["lost_random"] > 0


def test_goal_behind_the_robot():
    params = build_params(SCENARIO, seed=4)
    pos = np.vstack([FRAME, [[37.5, -25.0]]])  # 90 mm from robot 3: it ranges all three
    sim = Simulation(
        pos, SCENARIO.setup.program(params, pos), params, headings_rad=[0, 0, 0, -math.pi / 2]
    )
    sim.run(stop_when=lambda: SCENARIO.setup.stop_when(sim))
    follower = sim.robots[3]
    assert follower.outcome == "reached"
    assert np.linalg.norm(sim.world.positions_mm[3] - GOAL) < 8.0
    events = sim.trace.events_frame()
    moves = [json.loads(d) for d in events[events["event"] == "move"]["data"]]
    # The first move went away from the goal; the next turn was a large one.
    assert moves[0]["mode"] == "first"
    assert abs(moves[1]["turn_rad"]) > math.radians(60)


def test_longer_range_what_if():
    # A what-if of robots that range to 300 mm: one hard radius (the disc) and independent
    # noise (kilolib's tables end at 98 mm, so the follower must trust estimates up to 255 mm).
    what_if = {
        "medium.reach": "disc",
        "ranging.model": "gaussian",
        "follower.neighbour_max_mm": 255,
    }
    result = run(
        SCENARIO,
        {
            "medium.range_mm": 300,
            "follower.start_min_mm": 200,
            "follower.start_max_mm": 250,
            **what_if,
        },
        seed=2,
    )
    s = result.summary
    assert s["reached"] and s["final_distance_mm"] < 10.0
    assert 200 <= s["straight_line_mm"] <= 250
    # The walk is nearly straight. A pivot turn swings the centre round a rear leg (16.5 mm
    # out), so the path also holds an arc of 16.5 mm per radian turned, which turning in place
    # did not: that part is the turns', not the walk's.
    heading = np.unwrap(trajectory(result.sim)["heading_rad"].to_numpy())
    swings_mm = 16.5 * np.abs(np.diff(heading)).sum()
    assert s["path_length_mm"] - swings_mm < 1.5 * s["straight_line_mm"]


def test_saturated_distances_walk_to_the_nearest_robot_first():
    """At 90 mm beyond robot 3 the follower hears robots 1 and 2 (about 120 mm away) but reads
    them above follower.neighbour_max_mm, where kilolib's estimates saturate: no fix is
    possible, so the follower walks by the changes of its nearest distance."""
    params = build_params(SCENARIO, seed=3)
    pos = np.vstack([FRAME, [[GOAL[0], GOAL[1] + 90.0]]])
    sim = Simulation(pos, SCENARIO.setup.program(params, pos), params)
    follower = sim.robots[3]
    fixes = lambda: sim.trace.events_frame().query("robot == 3 and event == 'fix'")  # noqa: E731
    sim.run(120.0, stop_when=lambda: len(fixes()) > 0)
    events = sim.trace.events_frame()
    first_fix_s = fixes()["t_s"].iloc[0]
    moves = events[(events["event"] == "move") & (events["t_s"] < first_fix_s)]
    modes = [json.loads(d)["mode"] for d in moves["data"]]
    assert modes and set(modes) == {"approach"}
    first = json.loads(fixes()["data"].iloc[0])
    assert first["kind"] in ("three", "two")
    # It walked to where it ranges the robots its fix used (estimates within the limit stand
    # within a link's systematic error, under 10 mm, of the truth).
    limit = params.scenario.neighbour_max_mm
    assert np.linalg.norm(FRAME[:2] - pos[3], axis=1).min() > limit + 10
    distances = np.sort(np.linalg.norm(FRAME - sim.world.positions_mm[3], axis=1))
    ranged = 3 if first["kind"] == "three" else 2
    assert distances[ranged - 1] < limit + 10
    assert follower.outcome is None


def test_never_uses_readings_from_before_its_listening_window():
    params = build_params(SCENARIO, {"follower.start_min_mm": 20.0}, seed=1)
    from kilonet.scenarios.base import place

    pos = place(SCENARIO, params)
    sim = Simulation(pos, SCENARIO.setup.program(params, pos), params)
    follower = sim.robots[3]
    sim.start()
    while follower.phase != "step":
        sim.env.run(until=sim.env.now + 0.05)
    message = encode(FrameReport(1, True))
    before = {k: list(r) for k, r in follower._readings.items()}
    follower.message_rx(message, 40)  # heard while moving: dropped
    assert follower._readings == before
    while follower.phase == "step":
        sim.env.run(until=sim.env.now + 0.01)
    assert follower.phase == "listen" and follower.kilo_ticks < follower._listen_from_tick
    assert all(not r for r in follower._readings.values())  # the old window is gone
    follower.message_rx(message, 40)  # heard in the guard time after stopping: dropped
    assert all(not r for r in follower._readings.values())
    while follower.kilo_ticks < follower._listen_from_tick:
        sim.env.run(until=sim.env.now + 0.01)
    follower.message_rx(message, 40)  # after the guard: counted
    assert follower._readings[1][-1] == 40


def test_outputs_trajectory_figure_and_summary(tmp_path):
    result = run(SCENARIO, {"follower.start_min_mm": 20.0}, seed=8)
    write_outputs(result, tmp_path)
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in (
        "reached",
        "final_distance_mm",
        "steps",
        "sim_time_s",
        "path_length_mm",
        "mirrored_frame",
    ):
        assert key in summary
    assert isinstance(summary["reached"], bool) and isinstance(summary["mirrored_frame"], bool)
    traj = pd.read_csv(tmp_path / "trajectory.csv")
    assert list(traj.columns[:6]) == ["t_s", "x_mm", "y_mm", "heading_rad", "est_x_mm", "est_y_mm"]
    start = result.sim.initial_positions_mm[3]
    assert traj[["x_mm", "y_mm"]].iloc[0].tolist() == pytest.approx(start.tolist())
    final = result.sim.world.positions_mm[3]
    assert traj[["x_mm", "y_mm"]].iloc[-1].tolist() == pytest.approx(final.tolist())
    # The last estimate, mapped to the floor, is within a few mm of the true position.
    assert np.hypot(*(traj[["est_x_mm", "est_y_mm"]].iloc[-1] - final)) < 3.0
    assert (tmp_path / "follower.png").stat().st_size > 10_000
    # The seed's LED colours: origin white on send; x-axis blue / yellow; third green / yellow /
    # purple; the follower shows nothing and transmits nothing.
    led = result.sim.trace.led_frame()
    colours = {r: set(map(tuple, g[["r", "g", "b"]].to_numpy())) for r, g in led.groupby("robot")}
    assert colours[0] == {(3, 3, 3), (0, 0, 0)}
    assert colours[1] == {(0, 0, 3), (3, 3, 0), (0, 0, 0)}
    assert colours[2] == {(0, 3, 0), (3, 3, 0), (3, 0, 3), (0, 0, 0)}
    assert 3 not in colours
    assert result.sim.robots_frame()["sent"].tolist()[3] == 0
    assert summary["path_length_mm"] >= summary["straight_line_mm"] - summary["final_distance_mm"]


def test_start_heading_in_the_trajectory_is_the_true_one():
    result = run(SCENARIO, {"follower.start_min_mm": 20.0}, seed=8)
    traj = trajectory(result.sim)
    moves = result.sim.trace.events_frame().query("robot == 3 and event == 'move'")
    assert json.loads(moves["data"].iloc[0])["mode"] == "first"  # a straight first step
    assert traj["heading_rad"].iloc[0] == pytest.approx(traj["heading_rad"].iloc[1])


# ---------------------------------------------------------------------- the claims


# The default tier's twins run the first seeds of each claim's hundred (about 0.4 s of CPU a
# seed): 9 of 10 on the fitted medium (seed 8 misses), 5 of 5 on the 300 mm disc.


@pytest.mark.parametrize("seeds", [pytest.param(100, marks=pytest.mark.slow), 10])
def test_real_medium_success_rate(seeds):
    # docs/results/follower.md's second row. On the fitted medium each link keeps a systematic
    # ranging error of about 2 mm and the frame ranges only to 100 mm: 92 % of these seeds,
    # where the 85 mm disc with iid noise gave 97 %.
    table = run_many(range(1, seeds + 1), {"medium.loss_prob": 0.1})
    ok = (table["outcome"] == "reached") & (table["final_distance_mm"] <= 8.0)
    assert ok.mean() >= 0.90
    assert table["mirrored_frame_true"].any() and (~table["mirrored_frame_true"]).any()


@pytest.mark.parametrize("seeds", [pytest.param(100, marks=pytest.mark.slow), 5])
def test_long_range_success_rate(seeds):
    from kilonet.experiments.studies.follower_measured import CONDITIONS

    (what_if,) = (overrides for label, overrides in CONDITIONS if label.startswith("what-if"))
    # The 300 mm disc of docs/results/follower.md's table.
    table = run_many(range(1, seeds + 1), what_if)
    ok = (table["outcome"] == "reached") & (table["final_distance_mm"] <= 10.0)
    assert ok.mean() >= 0.95
