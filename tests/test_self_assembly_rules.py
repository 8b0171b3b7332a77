"""The self-assembly rules, each a pure function, on the cases that decide them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.protocols.self_assembly.rules import (
    DESIRED_MM,
    EDGE_MM,
    GRADIENT_MM,
    YIELD_MM,
    Heard,
    Shape,
    about_to_leave,
    edge_turn,
    first_fix,
    gradient_from,
    localize_step,
    may_start,
    meets_own_gradient,
    must_yield,
    on_edge,
)

ANCHORS = np.array([[0.0, 0.0], [36.0, 0.0], [18.0, 31.18], [54.0, 31.18]])


def test_the_gradient_is_one_more_than_the_smallest_near_neighbour():
    assert gradient_from([34.0, 36.0, 48.0], [4, 3, 5]) == 4
    # a robot beyond GRADIENT_MM does not count, however low its gradient
    assert gradient_from([34.0, GRADIENT_MM + 0.5], [4, 0]) == 5
    assert gradient_from([GRADIENT_MM], [2]) == 3
    assert gradient_from([], []) is None
    assert gradient_from([70.0], [0]) is None


def test_a_packed_robot_is_inside_and_a_robot_with_an_open_side_on_the_edge():
    inside = [34.0] * 6 + [59.0] * 6
    assert not on_edge(inside)
    assert on_edge([34.0] * 4 + [59.0] * 5)
    assert on_edge([])
    assert not on_edge([EDGE_MM] * 5)
    assert on_edge([EDGE_MM + 0.1] * 5)


def test_a_robot_starts_only_on_the_edge_highest_and_with_no_neighbour_moving():
    low, high = Heard(1, 3, False, 34.0), Heard(2, 5, False, 34.0)
    assert may_start(True, 5, 3, [low, high])  # ties by uid: 3 beats 2
    assert not may_start(True, 5, 1, [low, high])  # 2 beats 1
    assert not may_start(True, 4, 9, [low, high])  # a neighbour is higher
    assert not may_start(False, 9, 9, [low])  # not on the edge
    assert not may_start(True, 9, 9, [low, Heard(7, 0, True, 90.0)])  # someone moves
    assert may_start(True, 9, 9, [])


def test_a_moving_robot_yields_to_the_one_ahead_within_the_yield_distance():
    assert must_yield(10, 4, [(20, 1, YIELD_MM)])
    assert not must_yield(10, 4, [(20, 1, YIELD_MM + 1)])
    assert not must_yield(20, 4, [(10, 1, 40.0)])
    assert must_yield(10, 4, [(10, 5, 40.0)]) and not must_yield(10, 6, [(10, 5, 40.0)])
    assert not must_yield(10, 4, [])


def test_edge_following_turns_away_when_close_and_towards_when_far():
    assert edge_turn(DESIRED_MM - 0.1) == "left"
    assert edge_turn(DESIRED_MM) == "right"
    assert edge_turn(80.0) == "right"


def test_the_first_fix_is_the_range_solution_and_refuses_too_few_or_collinear_anchors():
    truth = np.array([70.0, 55.0])
    ranges = np.hypot(*(ANCHORS - truth).T)
    assert first_fix(ANCHORS, ranges) == pytest.approx(tuple(truth), abs=1e-6)
    assert first_fix(ANCHORS[:2], ranges[:2]) is None
    line = np.array([[0.0, 0.0], [30.0, 0.0], [60.0, 0.1]])
    assert first_fix(line, np.hypot(*(line - truth).T)) is None


def test_localization_steps_converge_from_nearby_and_reduce_the_range_error():
    truth = np.array([-20.0, 60.0])
    ranges = np.hypot(*(ANCHORS - truth).T)
    estimate = (0.0, 40.0)

    def error(p):
        return float(np.sum((np.hypot(*(ANCHORS - p).T) - ranges) ** 2))

    before = error(estimate)
    for _ in range(300):
        estimate = localize_step(estimate, ANCHORS, ranges)
    assert error(estimate) < before * 1e-6
    assert math.dist(estimate, truth) < 0.01


def test_the_shape_holds_its_cells_in_the_seeds_frame():
    # row 0 is the top row as written: an L
    shape = Shape(np.array([[True, False], [True, True]]), 20.0, (-10.0, -10.0))
    assert shape.contains(0.0, 0.0) and shape.contains(20.0, 0.0) and shape.contains(0.0, 20.0)
    assert not shape.contains(20.0, 20.0)
    assert not shape.contains(-10.1, 0.0) and not shape.contains(0.0, 30.1)
    assert shape.extent_mm == (-10.0, -10.0, 30.0, 30.0)


def test_a_robot_stops_when_about_to_leave_the_shape_or_already_out():
    shape = Shape(np.ones((3, 3), dtype=bool), 10.0)
    assert not about_to_leave(shape, (15.0, 15.0), (18.0, 15.0))
    assert about_to_leave(shape, (25.0, 15.0), (31.0, 15.0))
    assert about_to_leave(shape, (35.0, 15.0), (34.0, 15.0))


def test_a_robot_stops_against_a_stationary_robot_of_its_own_gradient_close_by():
    assert meets_own_gradient(6, Heard(3, 6, False, DESIRED_MM + 5.0))
    assert not meets_own_gradient(6, Heard(3, 6, False, DESIRED_MM + 5.1))
    assert not meets_own_gradient(6, Heard(3, 5, False, DESIRED_MM))
    assert not meets_own_gradient(6, Heard(3, 6, True, DESIRED_MM))
    assert not meets_own_gradient(6, None)
