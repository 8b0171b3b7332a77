"""Tests of the pivot-turn rules the follower plans and learns with (pure functions)."""

from __future__ import annotations

import math

import pytest

from kilonet.motion import pose_after
from kilonet.protocols.follower.pivot_turns import (
    PIVOT_LEG_MM,
    best_pivot_move,
    handedness_vote,
    pivot_displacement,
    segment_blocked,
    swing_arc,
    swing_turn_rad,
    swing_vote,
    turn_rate_ratio,
)

LEG_RADIUS_MM = math.hypot(*PIVOT_LEG_MM)


def _after(position, heading, move):
    """Where a move (turn, then step) leaves the robot by the planner's own kinematics."""
    h = (
        math.cos(move.turn_rad) * heading[0] - math.sin(move.turn_rad) * heading[1],
        math.sin(move.turn_rad) * heading[0] + math.cos(move.turn_rad) * heading[1],
    )
    return (move.start[0] + move.step_mm * h[0], move.start[1] + move.step_mm * h[1])


@pytest.mark.parametrize("turn_deg", [30.0, 90.0, -90.0, 180.0, -250.0])
def test_pivot_displacement_is_the_kernels_pivot(turn_deg):
    """The program's model of its swing is the simulator's: a left pivot about the left leg,
    a right one about the right leg, from any heading."""
    heading = 0.7
    turn = math.radians(turn_deg)
    rate = math.radians(45.0)
    x, y, _ = pose_after(
        10.0, -5.0, heading, 1.0 if turn > 0 else 0.0, 1.0 if turn < 0 else 0.0,
        abs(turn) / rate, speed_mm_s=10.0, turn_rad_s=rate, pivot_mm=PIVOT_LEG_MM,
        drift_gain=0.5,
    )  # fmt: skip
    dx, dy = pivot_displacement((math.cos(heading), math.sin(heading)), turn)
    assert (10.0 + dx, -5.0 + dy) == pytest.approx((x, y), abs=1e-9)
    assert math.hypot(dx, dy) == pytest.approx(2 * LEG_RADIUS_MM * abs(math.sin(turn / 2)))


def test_swing_arc_stays_on_the_legs_circle():
    arc = swing_arc((3.0, 4.0), (0.0, 1.0), math.radians(-200))
    assert len(arc) == 8 and arc[0] == (3.0, 4.0)
    # A right turn pivots about the right leg: heading +y, right is +x.
    leg = (3.0 + PIVOT_LEG_MM[1], 4.0 + PIVOT_LEG_MM[0])
    assert all(math.dist(p, leg) == pytest.approx(LEG_RADIUS_MM) for p in arc)


def test_best_move_faces_a_far_aim_and_reaches_a_near_one():
    position, heading = (0.0, 0.0), (1.0, 0.0)
    for aim in [(60.0, 0.0), (0.0, 60.0), (-40.0, -30.0), (25.0, -25.0)]:
        move = best_pivot_move(position, heading, aim, 100.0, turn_sd=0.02, heading_sd_rad=0.02)
        assert move.final
        assert math.dist(_after(position, heading, move), aim) < 1.0
    # Steps of at most 20 mm: the move gets the robot well on its way, never further.
    move = best_pivot_move(position, heading, (0.0, 60.0), 20.0, turn_sd=0.02)
    assert move.step_mm <= 20.0
    assert math.dist(_after(position, heading, move), (0.0, 60.0)) < 45.0


def test_best_move_never_stays_put_and_goes_round_for_an_aim_behind():
    position, heading = (0.0, 0.0), (1.0, 0.0)
    move = best_pivot_move(position, heading, (-6.0, 0.0), 20.0, turn_sd=0.02)
    assert not move.final  # no single move gets there: the first of two
    assert move.turn_rad != 0.0 or move.step_mm > 0.0
    move = best_pivot_move(position, heading, (-6.0, 0.0), 20.0, two_moves=False)
    assert move.turn_rad != 0.0 or move.step_mm > 0.0


def test_best_move_keeps_clear_of_bodies_and_within_hearing():
    position, heading = (0.0, 0.0), (1.0, 0.0)
    # A body right on the line to the aim: the step must not enter its disc.
    body = (45.0, 0.0)
    move = best_pivot_move(position, heading, (100.0, 0.0), 60.0, obstacles=[body], radius_mm=34.5)
    h = (math.cos(move.turn_rad), math.sin(move.turn_rad))
    assert not segment_blocked(move.start, h, move.step_mm, body, 34.5)
    # A robot it must keep hearing 70 mm behind: no move ends more than 75 mm from it.
    far = (-70.0, 0.0)
    move = best_pivot_move(position, heading, (60.0, 0.0), 40.0, obstacles=[far], within_mm=75.0)
    assert math.dist(_after(position, heading, move), far) <= 75.0 + 1e-9


@pytest.mark.parametrize("turn_deg", [35.0, 90.0, -120.0])
@pytest.mark.parametrize("rate", [0.7, 1.0, 1.4])
def test_swing_vote_tells_the_handedness_from_the_swing(turn_deg, rate):
    heading = (math.cos(1.0), math.sin(1.0))
    turn = math.radians(turn_deg)
    floor = pivot_displacement(heading, turn * rate)
    mirror = pivot_displacement(heading, -turn * rate)
    assert swing_vote(heading, turn, floor) is False
    assert swing_vote(heading, turn, mirror) is True
    # A turn that did not swing at all (stuck against a body): no verdict.
    assert swing_vote(heading, turn, (0.0, 0.0)) is None


def test_handedness_vote_and_turn_rate_ratio():
    ninety = math.radians(90)
    assert handedness_vote(ninety, math.radians(80), math.radians(80)) is False
    assert handedness_vote(ninety, math.radians(-95), math.radians(-95)) is True
    assert handedness_vote(ninety, math.radians(170), math.radians(170)) is None  # either way
    assert handedness_vote(math.radians(15), 0.3, 0.3) is None  # too small to tell
    assert turn_rate_ratio(ninety, math.radians(72)) == pytest.approx(0.8)
    assert turn_rate_ratio(math.radians(-170), math.radians(175)) == pytest.approx(185 / 170)


@pytest.mark.parametrize("turn_deg", [40.0, 90.0, -135.0])
def test_swing_length_tells_the_turn_whatever_the_heading(turn_deg):
    for heading_rad in (0.0, 2.0, -2.5):
        heading = (math.cos(heading_rad), math.sin(heading_rad))
        moved = pivot_displacement(heading, math.radians(turn_deg))
        assert math.degrees(swing_turn_rad(moved)) == pytest.approx(abs(turn_deg))
    assert swing_turn_rad((40.0, 0.0)) == pytest.approx(math.pi)  # beyond the longest chord
