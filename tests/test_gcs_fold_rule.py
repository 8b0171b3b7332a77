"""The fold rule (kilonet.protocols.gcs.fold_rule): who acts on a disagreement, and how."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.protocols.gcs.fold_rule import FoldDecision, fold_decision, is_outlier, refit

TOLERANCE_MM, SIGMA_MM = 8.0, 2.5
#: The rule's settings in every decision below: confirm time s, tolerance and ranging sigma mm.
RULE = {"confirm_s": 10.0, "tolerance_mm": TOLERANCE_MM, "sigma_mm": SIGMA_MM}


def _patch(bad_offset_mm: tuple[float, float], noise_mm: float = 1.5, seed: int = 1):
    """A hexagonal patch (spacing 40 mm), robot 0 in the middle: its true neighbours within
    85 mm, their true positions, measured distances with noise, and robot 0's estimate moved
    by ``bad_offset_mm`` (a bad fix)."""
    rng = np.random.default_rng(seed)
    pts = [
        (40.0 * (i + 0.5 * (j % 2)), 40.0 * math.sqrt(3) / 2 * j)
        for j in range(-2, 3)
        for i in range(-2, 3)
    ]
    truth = {k: np.array(p) for k, p in enumerate(sorted(pts, key=lambda p: math.hypot(*p)))}
    own = truth[0]
    anchors, mismatches = {}, {}
    estimate = own + np.array(bad_offset_mm)
    for k, p in truth.items():
        d = float(np.hypot(*(p - own)))
        if k == 0 or d > 85.0:
            continue
        measured = d + rng.normal(0.0, noise_mm)
        anchors[k] = (float(p[0]), float(p[1]), measured)
        mismatches[k] = abs(float(np.hypot(*(p - estimate))) - measured)
    return truth, anchors, mismatches


def test_a_bad_fix_is_the_outlier_and_is_repaired_near_its_true_position():
    truth, anchors, mismatches = _patch((117.0, 0.0))
    assert is_outlier(mismatches, TOLERANCE_MM)
    decision = fold_decision(anchors, mismatches, outlier_for_s=20.0, **RULE)
    assert decision.action == "repair"
    assert math.hypot(*(np.array(decision.position) - truth[0])) < 3.0


def test_a_good_fix_is_kept():
    _, anchors, mismatches = _patch((1.0, -1.0))
    decision = fold_decision(anchors, mismatches, outlier_for_s=None, **RULE)
    assert decision == FoldDecision("keep")


def test_a_neighbour_of_the_bad_fix_does_not_act():
    """The bad fix's neighbour disagrees with it alone: one in several is no majority."""
    _, _, mismatches = _patch((1.0, 0.0))
    mismatches[1] = 117.0  # its neighbour 1 is the bad fix
    assert len(mismatches) >= 4
    assert not is_outlier(mismatches, TOLERANCE_MM)


@pytest.mark.parametrize(
    ("mismatches", "expected"),
    [
        ({1: 9.0, 2: 9.0}, True),  # two of two
        ({1: 9.0, 2: 9.0, 3: 1.0, 4: 1.0}, False),  # half is no majority
        ({1: 9.0, 2: 9.0, 3: 9.0, 4: 1.0}, True),
        ({1: 8.0, 2: 8.0, 3: 8.0}, False),  # at the tolerance: agreeing
        ({}, False),
    ],
)
def test_the_majority_needs_more_than_half_and_two(mismatches, expected):
    assert is_outlier(mismatches, TOLERANCE_MM) is expected


def test_the_robot_waits_for_the_confirm_time():
    _, anchors, mismatches = _patch((117.0, 0.0))
    assert fold_decision(anchors, mismatches, outlier_for_s=9.9, **RULE).action == "wait"
    assert fold_decision(anchors, mismatches, outlier_for_s=None, **RULE).action == "wait"
    assert fold_decision(anchors, mismatches, outlier_for_s=10.0, **RULE).action == "repair"


def test_neighbours_no_point_fits_make_it_split():
    """Distances that disagree with the neighbours' positions beyond the tolerance (a fold
    among the neighbours themselves): no refit, the robot leaves the frame."""
    _, anchors, mismatches = _patch((117.0, 0.0))
    anchors = {k: (x, y, d + (40.0 if k % 2 else -20.0)) for k, (x, y, d) in anchors.items()}
    assert refit(anchors, tolerance_mm=TOLERANCE_MM, sigma_mm=SIGMA_MM) is None
    decision = fold_decision(anchors, mismatches, outlier_for_s=20.0, **RULE)
    assert decision == FoldDecision("split")


def test_fewer_than_three_neighbours_cannot_refit():
    _, anchors, _ = _patch((117.0, 0.0))
    two = dict(list(anchors.items())[:2])
    assert refit(two, tolerance_mm=TOLERANCE_MM, sigma_mm=SIGMA_MM) is None


def test_two_neighbours_disagreeing_are_no_ground_to_act():
    """Two circles meet in two points: a position fitting both exists, ambiguous, so the robot
    neither refits nor leaves; it keeps its position however long it disagrees."""
    _, anchors, mismatches = _patch((117.0, 0.0))
    two = dict(list(anchors.items())[:2])
    assert is_outlier({k: mismatches[k] for k in two}, TOLERANCE_MM)
    decision = fold_decision(two, {k: mismatches[k] for k in two}, outlier_for_s=99.0, **RULE)
    assert decision == FoldDecision("keep")
