"""Issue 47, the jams: edge-following as the paper's supplement gives it, with its two
go-straight cases (too close but getting farther, too far but getting closer), a trend only
beyond the readings' noise (``TREND_MM``), and a moving robot that decides afresh only on a new
reading of its nearest stationary robot."""

from __future__ import annotations

from kilonet.protocols.self_assembly.program import ASSEMBLY, AssemblyStage, SelfAssembly
from kilonet.protocols.self_assembly.rules import DESIRED_MM, TREND_MM, edge_turn
from kilonet.scenarios.self_assembly import load_shape
from kilonet.testing import ScriptedWorld


def test_too_close_turns_away_unless_already_getting_farther():
    assert edge_turn(DESIRED_MM - 4.0, DESIRED_MM - 6.0) == "straight"
    assert edge_turn(DESIRED_MM - 4.0, DESIRED_MM - 2.0) == "left"
    assert edge_turn(DESIRED_MM - 4.0, DESIRED_MM - 4.0) == "left"  # no trend: turn
    assert edge_turn(DESIRED_MM - 4.0) == "left"  # no reading before


def test_too_far_turns_towards_unless_already_getting_closer():
    assert edge_turn(DESIRED_MM + 10.0, DESIRED_MM + 12.0) == "straight"
    assert edge_turn(DESIRED_MM + 10.0, DESIRED_MM + 8.0) == "right"
    assert edge_turn(DESIRED_MM + 10.0, DESIRED_MM + 10.0) == "right"
    assert edge_turn(DESIRED_MM) == "right"  # at the desired distance counts as far
    assert edge_turn(DESIRED_MM, DESIRED_MM + TREND_MM) == "straight"


def test_a_change_within_the_noise_is_no_trend():
    close, far = DESIRED_MM - 4.0, DESIRED_MM + 10.0
    assert edge_turn(close, close - TREND_MM) == "straight"
    assert edge_turn(close, close - TREND_MM + 1.0) == "left"  # pressed into a pocket: noise
    assert edge_turn(far, far + TREND_MM) == "straight"
    assert edge_turn(far, far + TREND_MM - 1.0) == "right"


def _moving_robot(distances_mm: list[float]) -> ScriptedWorld:
    """A robot edge-following one stationary (waiting) robot whose successive readings are
    ``distances_mm``, one every 0.5 s from t = 1 s."""
    world = ScriptedWorld(SelfAssembly(load_shape("square", 40.0)), uid=50)
    world.advance(0.5)
    robot = world.robot
    robot.gradient = 3
    robot._set_stage(AssemblyStage.MOVE_OUTSIDE)
    waiting = ASSEMBLY.pack(uid=7, gradient=2, stage=AssemblyStage.WAIT.number, age=0, x=0, y=0)
    for k, d in enumerate(distances_mm):
        world.hear(waiting, at_s=1.0 + 0.5 * k, distance_mm=d)
    return world


def test_a_moving_robot_goes_straight_while_a_far_edge_comes_closer():
    world = _moving_robot([60.0, 55.0, 50.0, 52.0])
    robot = world.robot
    straight = (robot.kilo_straight_left, robot.kilo_straight_right)
    right = (0, robot.kilo_turn_right)
    world.run_until(1.45)
    assert robot.edge_action == "right"  # the first reading: no trend yet
    world.run_until(2.45)
    assert robot.edge_action == "straight"  # 60 -> 55 -> 50: getting closer
    assert world.motor_commands()[-1].value == straight
    world.run_until(2.95)
    assert robot.edge_action == "right"  # 50 -> 52: farther again
    assert world.motor_commands()[-1].value == right
    # between readings it keeps its action: one decision per reading, not per control cycle
    assert [c.value for c in world.motor_commands()].count(straight) == 1
