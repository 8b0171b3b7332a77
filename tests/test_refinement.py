"""kilonet.protocols.common.refinement: the symmetric distance reports, the momentum refiner and the
local stopping rule, with exact values."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from kilonet.protocols.common.refinement import (
    Refiner,
    agreed_range_mm,
    gauss_newton_step,
    neighbourhood_settled,
    next_report,
)


def _record(uid, mean_mm, *, sent_mm=None, sent_round=-1, samples=5, ambiguous=False):
    return SimpleNamespace(
        uid=uid,
        mean_mm=mean_mm,
        samples=samples,
        ambiguous=ambiguous,
        sent_mm=sent_mm,
        sent_round=sent_round,
    )


def test_both_ends_fit_the_mean_of_the_two_reports():
    # i measured 50.3 and last reported 50.2 to j; j measured 50.9 and reported 50.8 to i.
    at_i = agreed_range_mm(50.3, 50.2, 50.8)
    at_j = agreed_range_mm(50.9, 50.8, 50.2)
    assert at_i == at_j == pytest.approx(50.5)
    # Before any report arrives each end fits its own mean; after one, the mean of the two.
    assert agreed_range_mm(50.3, None, None) == 50.3
    assert agreed_range_mm(50.3, None, 50.8) == pytest.approx(50.55)


def test_next_report_prefers_the_largest_drift_then_the_oldest_report():
    records = [
        _record(1, 40.00, sent_mm=40.0, sent_round=9),
        _record(2, 50.26, sent_mm=50.0, sent_round=3),  # drifted 0.26 mm: 3 steps
        _record(3, 60.12, sent_mm=60.0, sent_round=1),  # 1 step
        _record(4, 70.0, ambiguous=True),  # never about an ID two robots share
        _record(5, 80.0, samples=0),
    ]
    assert next_report(records).uid == 2
    records[1].sent_mm = 50.26
    assert next_report(records).uid == 3
    records[2].sent_mm = 60.12
    # No drift left anywhere: the oldest report goes first.
    records[2].sent_round = 10
    assert next_report(records).uid == 2
    assert next_report([records[3], records[4]]) is None


def test_refiner_adds_momentum_to_the_gauss_newton_step_and_caps_it():
    # One neighbour pair that fixes the robot at x = 30 on the x axis (y held).
    links = [(0.0, 0.0, 30.0), (60.0, 0.0, 30.0)]
    plain = Refiner(huber_mm=10.0, max_step_mm=100.0, momentum=0.0, settle_mm=0.1, settle_rounds=2)
    heavy = Refiner(huber_mm=10.0, max_step_mm=100.0, momentum=0.5, settle_mm=0.1, settle_rounds=2)
    assert plain.step(20.0, 0.0, links, fix_y=True) == pytest.approx((30.0, 0.0))
    # The first step has no previous step to add; the second adds half of the first (10 mm).
    assert heavy.step(20.0, 0.0, links, fix_y=True) == pytest.approx((30.0, 0.0))
    assert heavy.step(30.0, 0.0, links, fix_y=True) == pytest.approx((35.0, 0.0))
    # Then the Gauss–Newton step (-5) and half the previous (+2.5).
    assert heavy.step(35.0, 0.0, links, fix_y=True) == pytest.approx((32.5, 0.0))
    capped = Refiner(huber_mm=10.0, max_step_mm=4.0, momentum=0.5, settle_mm=0.1, settle_rounds=2)
    assert capped.step(20.0, 0.0, links, fix_y=True) == pytest.approx((24.0, 0.0))
    capped.reset()
    assert capped.step(24.0, 0.0, links, fix_y=True) == pytest.approx((28.0, 0.0))


def test_refiner_settles_relative_to_an_origin():
    links = [(0.0, 0.0, 30.0), (60.0, 0.0, 30.0), (30.0, 40.0, 40.0)]
    r = Refiner(huber_mm=3.0, max_step_mm=5.0, momentum=0.0, settle_mm=0.01, settle_rounds=2)
    # The neighbourhood moves 1 mm a round along x and the robot with it: settled against it.
    for k in range(4):
        shifted = [(x + k, y, d) for x, y, d in links]
        r.step(30.0 + k, 0.0, shifted, origin=(30.0 + k, 13.0))
    assert r.settled
    r.reset()
    for k in range(4):
        r.step(30.0 + k, 0.0, [(x + k, y, d) for x, y, d in links])
    assert not r.settled


def test_refiner_hold_keeps_the_position_and_counts_toward_settling():
    r = Refiner(huber_mm=3.0, max_step_mm=5.0, momentum=0.5, settle_mm=0.1, settle_rounds=2)
    for _ in range(3):
        r.hold(0.0, 0.0)
    assert r.settled


def test_neighbourhood_settled():
    assert neighbourhood_settled(True, iter([True, True]))
    assert not neighbourhood_settled(True, [True, False])
    assert not neighbourhood_settled(False, [True])


def test_gauss_newton_without_links_or_directions_stays():
    assert gauss_newton_step(1.0, 2.0, [], huber_mm=3.0, max_step_mm=5.0)[:2] == (1.0, 2.0)
    assert math.isnan(gauss_newton_step(1.0, 2.0, [], huber_mm=3.0, max_step_mm=5.0)[2])
