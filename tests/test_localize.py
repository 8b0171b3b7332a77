"""The ``localize`` protocol: each phase's rules with exact values, then whole runs.

Small swarms run in the default suite; the issue's random placements (150–300 robots, with and
without loss) are marked slow (``pytest -m slow``).
"""

from __future__ import annotations

import ast
import inspect
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given
from hypothesis import strategies as st

import kilonet.protocols.localize.program as localize_module
from kilonet import scenarios
from kilonet.message import Message
from kilonet.protocols.common import refinement
from kilonet.protocols.common.refinement import (
    DIST,
    SettleWindow,
    distance_code,
    gauss_newton_step,
    unwrap_distance,
)
from kilonet.protocols.localize import base as localize_base
from kilonet.protocols.localize import island_solve
from kilonet.protocols.localize import phase1_election as localize_election
from kilonet.protocols.localize import phase2_spread as localize_spread
from kilonet.protocols.localize import phase3_termination as localize_termination
from kilonet.protocols.localize import phase4_island as localize_island
from kilonet.protocols.localize.base import (
    COMPLETE,
    LOCALIZED,
    NBR,
    NO_ID,
    SETTLED,
    Neighbour,
    Neighbours,
    children_complete,
    choose_parent,
    distance_report,
)
from kilonet.protocols.localize.phase1_election import ELECT, Election, echo_complete, election_key
from kilonet.protocols.localize.phase2_spread import (
    CAND,
    POS,
    ROOT,
    VOTE,
    candidate_version,
    choose_frame,
    circle_candidates,
    consistent_subset_fix,
    fix_with_candidates,
    line_same_mm,
    mirror_candidates,
    overlap_vote,
)
from kilonet.protocols.localize.phase3_termination import gives_up, subtree_complete
from kilonet.protocols.localize.phase4_island import ISLAND_FULL, ISLAND_LINK, ISLAND_PAIR
from kilonet.protocols.localize.stages import LocalizingPhase
from kilonet.scenarios.neighbourhood import noise_free_estimate_mm, trusted_links

LOCALIZE = scenarios.get("localize")


#: The Cramér–Rao bound counts each link's systematic error (the model's effective per-link
#: error, kilonet.reception), which no averaging removes: no estimator on these receptions
#: beats it by much (the centralized optimum sits near it), and the protocol stays within this
#: factor of it.
NEAR_BOUND = 1.5
#: Independent ranging noise and no per-link error: what tests of averaging and of hand-built
#: geometries on the thesis's 85 mm disc assume.
IDEALISED = {"medium.reach": "disc", "ranging.model": "gaussian", "localize.link_error_mm": 0.0}
#: The kernel's message timing before kilolib's (commit 98afc77).
OLD_TIMING = {
    "robot.ticks_per_s": 31.0,
    "medium.bitrate_bps": 30_000.0,
    "medium.preamble_s": 0.0,
    "medium.backoff_max_s": 0.032,
    "medium.sense_delay_s": 0.0,
}
#: A reception's noise moves its estimate by under 2 mm (ranging.intensity_noise 1.5 %).
NOISE_MARGIN_MM = 2.0


def run(robots: int, seed: int = 1, **overrides):
    return scenarios.run(LOCALIZE, {"placement.robots": robots, **overrides}, seed=seed)


def _neighbour(uid, *, hops=0, flags=0, key=None, echo=False, parent=NO_ID, position=None):
    n = Neighbour(uid)
    n.hops, n.flags, n.key, n.echo, n.parent = hops, flags, key, echo, parent
    if position is not None:
        n.x_mm, n.y_mm = position
    return n


# ------------------------------------------------------------------------------- messages


@pytest.mark.parametrize(
    ("layout", "values"),
    [
        (ELECT, {"sender": 65534, "key": 0xFFFFFFFF, "hops": 0xFE, "parent": 0xFFFF}),
        (ROOT, {"sender": 3, "axis": 4, "third": 0xFFFF, "flags": 15}),
        (
            POS,
            {"sender": 3, "x_mm": -3276.7, "y_mm": 3276.7, "hops": 9, "flags": 5, "windings": 0xF1},
        ),
        (
            CAND,
            {"sender": 3, "x_mm": 12.3, "y_mm": -4.5, "index": 1, "version": 255, "windings": 7},
        ),
        (DIST, {"sender": 3, "x_mm": 1.5, "y_mm": 2.5, "neighbour": 9, "distance": 200}),
        (NBR, {"sender": 3, "neighbour": 9, "distance_mm": 255.0}),
        (VOTE, {"sender": 3, "target": 9, "index": 0, "version": 7}),
        (ISLAND_PAIR, {"sender": 3, "origin": 4, "neighbour": 9, "distance_mm": 84.37}),
        (ISLAND_LINK, {"sender": 3, "origin": 4, "x_mm": -3276.7, "y_mm": 1.5, "distance_mm": 255}),
        (ISLAND_FULL, {"sender": 3}),
    ],
)
def test_every_message_fits_kilolib_and_round_trips(layout, values):
    message = layout.pack(**values)
    assert len(message.data) <= 9
    decoded = layout.unpack(message)._asdict()
    assert decoded == pytest.approx(values)


def test_message_types_are_distinct():
    types = [
        m.type
        for m in (ELECT, ROOT, POS, DIST, CAND, NBR, VOTE, ISLAND_PAIR, ISLAND_LINK, ISLAND_FULL)
    ]
    assert len(set(types)) == len(types)


@given(st.floats(33.0, 255.0), st.floats(-12.7, 12.7))
def test_distance_code_unwraps_near_the_receivers_own_mean(distance, offset):
    recovered = unwrap_distance(distance_code(distance), distance + offset)
    assert recovered == pytest.approx(distance, abs=0.05 + 1e-9)


def test_distance_report_is_nbr_without_position_and_dist_with_one():
    n = Neighbour(9)
    n.distance_sum_mm, n.samples = 3 * 47.23, 3
    assert NBR.unpack(distance_report(1, None, n)).distance_mm == pytest.approx(47.23)
    m = DIST.unpack(distance_report(1, (-5.0, 7.0), n))
    assert (m.x_mm, m.y_mm, m.neighbour, m.distance) == (-5.0, 7.0, 9, 472 % 256)


# ------------------------------------------------------------------------------ neighbours


def test_neighbour_range_is_the_mean_of_both_ends():
    nbs = Neighbours(duplicate_mm=6.0, stale_rounds=5)
    for d in (50, 51, 52):
        n = nbs.heard(4, d, 1)
    assert n.range_mm == 51.0
    nbs.report(n, distance_code(52.6))
    assert n.reported_mm == pytest.approx(52.6)
    assert n.range_mm == pytest.approx(51.8)


def test_two_robots_behind_one_id_make_it_ambiguous_only_when_far_apart():
    nbs = Neighbours(duplicate_mm=6.0, stale_rounds=5)
    for d in (50, 50, 50, 55):  # 5 mm off: one robot, noisy
        nbs.heard(4, d, 1)
    assert not nbs[4].ambiguous
    nbs.heard(4, 58, 1)  # 6.75 mm off the mean of 51.25
    assert nbs[4].ambiguous
    assert nbs.fresh(1) == []


def test_children_complete_only_waits_for_the_robots_that_name_it_parent():
    a, b, c = (_neighbour(1, parent=9), _neighbour(2, parent=5), _neighbour(3, parent=5))
    assert children_complete(9, [a, b, c], lambda n: n.uid == 1)
    assert not children_complete(5, [a, b, c], lambda n: n.uid == 2)
    assert children_complete(5, [a, b, c], lambda n: n.uid in (2, 3))
    assert children_complete(4, [a, b, c], lambda n: False)  # nobody's parent: a leaf


def test_parent_is_the_best_heard_neighbour_one_hop_nearer_and_sticks():
    near_weak, near_strong, same = (_neighbour(1, hops=2), _neighbour(2, hops=2), _neighbour(3))
    same.hops = 3
    near_weak.samples, near_strong.samples, same.samples = 10, 15, 99
    neighbours = [near_weak, near_strong, same]
    assert choose_parent(NO_ID, 3, neighbours) == 2  # not the sibling heard 99 times
    assert choose_parent(1, 3, neighbours) == 1  # 15 < 2 x 10: the parent stays
    near_strong.samples = 21
    assert choose_parent(1, 3, neighbours) == 2
    near_strong.hops = 3  # no longer nearer: the other one, however weak
    assert choose_parent(2, 3, neighbours) == 1
    assert choose_parent(1, 0, neighbours) == NO_ID  # the root
    assert choose_parent(1, 5, neighbours) == NO_ID  # nobody at 4 hops


# ------------------------------------------------------------------------------- election


def test_election_key_prefers_more_neighbours_then_the_salt():
    assert election_key(10, 0xFFFFFF) < election_key(9, 0)
    assert election_key(10, 1) < election_key(10, 2)
    assert election_key(300, 5) == election_key(255, 5) == 5
    assert election_key(0, 1 << 24) == 0xFF000000  # the salt keeps its 24 bits


def test_echo_needs_every_neighbour_on_the_key_and_children_complete():
    parent = _neighbour(1, hops=2, key=7, parent=0)
    sibling = _neighbour(2, hops=3, key=7, parent=1)
    child = _neighbour(3, hops=4, key=7, parent=4)
    assert not echo_complete(7, 4, [parent, sibling, child])
    child.echo = True
    assert echo_complete(7, 4, [parent, sibling, child])
    sibling.key = 8  # not switched to key 7 yet
    assert not echo_complete(7, 4, [parent, sibling, child])
    assert echo_complete(7, 4, [])  # a robot alone


def test_elect_carries_hops_echo_and_parent():
    n = Neighbour(3)
    message = ELECT.pack(sender=3, key=12, hops=0x80 | 5, parent=77)
    assert Election.record(n, message)  # all news to an empty record
    assert (n.key, n.hops, n.echo, n.parent) == (12, 5, True, 77)
    assert not Election.record(n, message)  # the same again: nothing new
    assert Election.record(n, ELECT.pack(sender=3, key=12, hops=5, parent=77))
    assert (n.hops, n.echo) == (5, False)


# -------------------------------------------------------------------------------- spread


def test_choose_frame_takes_the_pair_with_most_common_neighbours():
    # Root at the origin of a hex patch; neighbours at 40 mm on the six directions.
    angles = np.radians(np.arange(6) * 60.0)
    ring = {k + 1: (40 * math.cos(a), 40 * math.sin(a)) for k, a in enumerate(angles)}
    ranges = {u: 40.0 for u in ring}
    reports = {
        u: {v: math.dist(p, q) for v, q in ring.items() if v != u and math.dist(p, q) < 50}
        for u, p in ring.items()
    }
    # Ring neighbours see only their two ring neighbours: no adjacent pair has a common
    # neighbour besides the root, all triangles are 34.6 mm high, so the smallest IDs win.
    assert choose_frame(ranges, reports, 10.0) == (1, 2)
    # Let robot 4 see robots 1 and 2 as well: 2 and 4 now have two common neighbours, 1 and 3
    # (1 and 4 are on one line through the root: no triangle).
    reports[4].update({1: 80.0, 2: 69.3})
    assert choose_frame(ranges, reports, 10.0) == (2, 4)
    assert choose_frame(ranges, reports, 10.0, axis=1) == (1, 2)
    assert choose_frame(ranges, reports, 40.0) is None  # every triangle is 34.6 mm high


def test_circle_candidates_are_mirror_images():
    p, q, h = circle_candidates((10.0, 10.0), (10.0, 60.0), 30.0, 40.0)
    assert h == pytest.approx(24.0)
    assert p == pytest.approx((-14.0, 28.0))
    assert q == pytest.approx((34.0, 28.0))
    assert circle_candidates((0.0, 0.0), (0.0, 0.0), 5.0, 5.0) is None
    assert circle_candidates((0.0, 0.0), (100.0, 0.0), 20.0, 20.0) is None


def test_fix_with_candidates_finds_the_only_consistent_choice():
    truth = (25.0, 35.0)
    anchors = [(0.0, 0.0), (50.0, 0.0)]
    # Two neighbours, each placed by two other anchors: their pairs hold the truth and a mirror.
    pair_a = ((80.0, 40.0), (40.0, 80.0))  # true (80, 40), mirrored across y = x
    pair_b = ((-30.0, 60.0), (-30.0, -40.0))  # true (-30, 60), mirrored across y = 10
    points = [*anchors, pair_a[0], pair_b[0]]
    ranges = [math.dist(truth, p) for p in points]
    fix = fix_with_candidates(
        anchors,
        ranges[:2],
        [pair_a, pair_b],
        ranges[2:],
        sigma_mm=1.0,
        max_rmse_mm=4.0,
        min_width_mm=10.0,
    )
    assert (fix.x_mm, fix.y_mm) == pytest.approx(truth, abs=1e-6)
    # The pairs listed the other way round: the same fix.
    swapped = [pair_a[::-1], pair_b[::-1]]
    again = fix_with_candidates(
        anchors, ranges[:2], swapped, ranges[2:], sigma_mm=1.0, max_rmse_mm=4.0, min_width_mm=10.0
    )
    assert (again.x_mm, again.y_mm) == pytest.approx(truth, abs=1e-6)


def test_fix_with_candidates_refuses_when_a_wrong_choice_fits_as_well():
    anchors = [(0.0, 0.0), (50.0, 0.0)]
    pair = ((20.0, 60.0), (20.0, -60.0))  # mirrored across the anchors' own line
    truth = (25.0, 30.0)
    ranges = [math.dist(truth, p) for p in (*anchors, pair[0])]
    assert (
        fix_with_candidates(
            anchors, ranges[:2], [pair], ranges[2:], sigma_mm=1, max_rmse_mm=4, min_width_mm=10
        )
        is None
    )


def test_overlap_vote_keeps_the_candidate_clear_of_bodies():
    pair = ((0.0, 50.0), (0.0, -50.0))
    assert overlap_vote(pair, [(10.0, -45.0)], 28.0) == 0
    assert overlap_vote(pair, [(10.0, 45.0)], 28.0) == 1
    assert overlap_vote(pair, [(10.0, 45.0), (10.0, -45.0)], 28.0) is None
    assert overlap_vote(pair, [(0.0, 78.5)], 28.0) is None  # 28.5 mm away: clear


# ---------------------------------------------------------------------------- refinement


def test_candidate_version_names_one_anchor_pair_and_never_comes_back():
    assert candidate_version(-1, None, (7, 9)) == 0
    assert candidate_version(4, (7, 9), (7, 9)) == 4  # the same ordered pair, held throughout
    assert candidate_version(4, (7, 9), (9, 7)) == 5  # reversed: the indices swap sides
    assert candidate_version(4, (7, 9), (7, 3)) == 5
    # Candidates that lapsed and come back, even from the same pair, are a new version: the
    # anchors may have moved meanwhile, and a vote's index must mean what the voter saw.
    assert candidate_version(4, None, (7, 9)) == 5
    assert candidate_version(255, None, (7, 9)) == 0


def _heard(robot, uid, distance_mm, position=None):
    """Robot ``uid`` heard 20 times at ``distance_mm``, placed (long ago) at ``position`` (mm)
    or not."""
    for _ in range(20):
        n = robot.neighbours.heard(uid, distance_mm, 1)
    n.x_mm, n.y_mm = position if position is not None else (None, None)
    n.placed_tick = -math.inf if position is not None else None
    return n


def test_a_vote_for_a_lapsed_candidate_pair_is_not_taken_for_the_next_one():
    # Measured (400 sparse robots, 20 % loss, seed 1; a C of 300, seed 2): a robot's
    # candidates lapsed and came back from another anchor pair with version 0 again, and
    # the votes cast for the old pair's index 1 placed it at the new pair's index 1, the
    # mirror side (119 and 131 mm off); the frames grown from it folded.
    sim = run(5).sim
    robot = localize_module.LocalizeRobot(sim.robots[0].params)
    robot._attach(sim, 0, np.random.default_rng(5))
    robot.setup()
    robot.driver.enter(LocalizingPhase(robot))
    spread = robot.spread

    def attempt():
        spread.next_retry = 0
        spread.round(robot.kilo_ticks, robot.neighbours.fresh(1))

    # The truth is (30, 40), 50 mm from anchors 11 at (0, 0) and 12 at (60, 0).
    _heard(robot, 11, 50.0, (0.0, 0.0))
    twelve = _heard(robot, 12, 50.0, (60.0, 0.0))
    attempt()
    old, points = spread.candidates
    assert spread.candidate_anchors == (11, 12)
    assert np.round(points, 6).tolist() == [[30.0, 40.0], [30.0, -40.0]]
    robot.message_rx(VOTE.pack(sender=12, target=robot.uid, index=0, version=old), 50)
    # Before the robot's next attempt 12 is no anchor any more (it gave its position up):
    # the candidates lapse; then 13 at (-20, 40) makes a pair with 11, whose index 0 is the
    # mirror image (-50, 0).
    twelve.x_mm = twelve.y_mm = None
    attempt()
    assert spread.candidates is None and robot.position is None
    _heard(robot, 13, 50.0, (-20.0, 40.0))
    robot.message_rx(VOTE.pack(sender=11, target=robot.uid, index=0, version=old), 50)
    attempt()
    new, points = spread.candidates
    assert spread.candidate_anchors == (11, 13)
    assert np.round(points, 6).tolist() == [[-50.0, 0.0], [30.0, 40.0]]
    assert new != old
    assert robot.position is None  # the votes for the old pair name nothing now
    robot.message_rx(VOTE.pack(sender=11, target=robot.uid, index=1, version=new), 50)
    attempt()
    assert robot.position == pytest.approx((30.0, 40.0))


SEAM_TRUTH = (30.0, 20.0)
#: Four anchors where they should be and a fifth from across a seam, 30 mm off its distance.
SEAM_ANCHORS = [(0.0, 0.0), (60.0, 0.0), (10.0, 60.0), (-20.0, 50.0), (80.0, 50.0)]


def _seam_ranges(offset_mm=30.0):
    ranges = [math.dist(SEAM_TRUTH, a) for a in SEAM_ANCHORS]
    ranges[4] += offset_mm
    return ranges


def test_a_seam_robot_takes_the_fix_of_the_anchors_that_agree():
    ranges = _seam_ranges()
    fix, kept = consistent_subset_fix(
        SEAM_ANCHORS, ranges, sigma_mm=2.0, max_rmse_mm=8.0, min_width_mm=10.0
    )
    assert kept == (0, 1, 2, 3)
    assert (fix.x_mm, fix.y_mm) == pytest.approx(SEAM_TRUTH, abs=1e-6)
    assert fix.rmse_mm == pytest.approx(0.0, abs=1e-6)
    # Anchors that all agree are rule 1's, not this rule's: every subset is smaller.
    exact = [math.dist(SEAM_TRUTH, a) for a in SEAM_ANCHORS]
    fix, kept = consistent_subset_fix(
        SEAM_ANCHORS, exact, sigma_mm=2.0, max_rmse_mm=8.0, min_width_mm=10.0
    )
    assert len(kept) == 4
    # Three that agree are not enough (one distance to check them), and so is no budget.
    assert (
        consistent_subset_fix(
            SEAM_ANCHORS[1:], ranges[1:], sigma_mm=2.0, max_rmse_mm=8.0, min_width_mm=10.0
        )
        is None
    )
    assert (
        consistent_subset_fix(
            SEAM_ANCHORS, ranges, sigma_mm=2.0, max_rmse_mm=8.0, min_width_mm=10.0, max_fits=0
        )
        is None
    )
    # Two anchors off: the largest agreeing subset is left, if it keeps four.
    two_off = [*SEAM_ANCHORS, (40.0, 70.0)]
    r = [*ranges, math.dist(SEAM_TRUTH, (40.0, 70.0)) - 25.0]
    fix, kept = consistent_subset_fix(two_off, r, sigma_mm=2.0, max_rmse_mm=8.0, min_width_mm=10.0)
    assert kept == (0, 1, 2, 3)


def test_a_subset_whose_side_is_in_doubt_is_not_taken():
    # Four agreeing anchors nearly on one line (within min_width_mm) and one off: no subset
    # of four passes (one line), and the one-line subset is never taken.
    anchors = [(0.0, 0.0), (30.0, 1.0), (60.0, 0.0), (90.0, 2.0), (40.0, 60.0)]
    ranges = [math.dist(SEAM_TRUTH, a) for a in anchors]
    ranges[4] += 30.0
    assert (
        consistent_subset_fix(anchors, ranges, sigma_mm=1.0, max_rmse_mm=4.0, min_width_mm=10.0)
        is None
    )


def test_mirror_candidates_of_anchors_on_one_line_are_its_two_sides():
    anchors = [(0.0, 0.0), (45.0, 0.0), (60.0, 0.0)]
    truth = (30.0, 40.0)
    ranges = [math.dist(truth, a) for a in anchors]
    p0, p1, height, pair = mirror_candidates(anchors, ranges)
    assert pair == (0, 2)  # the two farthest apart orient the indices
    assert p0 == pytest.approx((30.0, 40.0)) and p1 == pytest.approx((30.0, -40.0))
    assert height == pytest.approx(40.0)
    # Reversed, index 0 is still left of the line from the first of the pair to the second.
    p0, p1, _, pair = mirror_candidates(anchors[::-1], ranges[::-1])
    assert pair == (0, 2)
    assert p0 == pytest.approx((30.0, -40.0)) and p1 == pytest.approx((30.0, 40.0))
    # A little off the line, each candidate is the least-squares fit on its side.
    bent = [(0.0, 0.0), (45.0, 4.0), (60.0, 0.0)]
    p0, p1, _, _ = mirror_candidates(bent, [math.dist(truth, a) for a in bent])
    assert p0 == pytest.approx(truth, abs=1e-6)
    assert p1[1] < 0.0
    # Anchors that disagree beyond the residual bound give no candidates.
    off = [ranges[0], ranges[1] + 15.0, ranges[2]]
    assert mirror_candidates(anchors, off, max_rmse_mm=4.0) is None
    assert mirror_candidates(anchors, off) is not None
    assert mirror_candidates(anchors, [10.0, 10.0, 10.0]) is None  # the circles never meet
    # An anchor far off the line is much nearer one candidate than the other: a voter could
    # not tell it from a robot the holder does not hear, so no candidates beyond line_same_mm.
    wide = [(0.0, 0.0), (30.0, 12.0), (60.0, 0.0)]  # 12.1 mm nearer the truth than its mirror
    r = [math.dist(truth, a) for a in wide]
    assert line_same_mm(10.0) == 25.0
    assert mirror_candidates(wide, r, max_skew_mm=line_same_mm(10.0)) is not None
    assert mirror_candidates(wide, r, max_skew_mm=10.0) is None


def _spread_robot(seed=5):
    sim = run(5).sim
    robot = localize_module.LocalizeRobot(sim.robots[0].params)
    robot._attach(sim, 0, np.random.default_rng(seed))
    robot.setup()
    robot.driver.enter(LocalizingPhase(robot))
    return robot


def _attempt(robot):
    robot.spread.next_retry = 0
    robot.spread.round(robot.kilo_ticks, robot.neighbours.fresh(1))


def test_three_anchors_on_one_line_give_candidates_that_a_vote_resolves():
    # Before, a robot refused by rule 1 for three anchors on one line held no candidates and
    # waited for a fourth anchor: in a C only 250 mm wide the frame stalled there (34 % of
    # 300 robots placed, seed 2) once stale votes no longer placed such robots by chance.
    robot = _spread_robot()
    truth = (30.0, 40.0)
    for uid, a in ((11, (0.0, 0.0)), (12, (45.0, 0.0)), (13, (60.0, 0.0))):
        _heard(robot, uid, math.dist(truth, a), a)
    _attempt(robot)
    assert robot.position is None
    version, points = robot.spread.candidates
    assert robot.spread.candidate_anchors == (11, 12, 13, 11, 13)
    assert np.round(points, 1).tolist() == [[30.0, 40.0], [30.0, -40.0]]
    # Announced as candidates from a line: index + FROM_LINE, so that voters know an anchor
    # may be up to line_same_mm nearer one candidate than the other.
    sent = [robot.spread.message_tx() for _ in range(3)]
    assert sorted(CAND.unpack(m).index for m in sent if m.type == CAND.type) == [2, 3]
    voter = _spread_robot(seed=6)
    for m in sent:
        voter.message_rx(m, 60)
    record = voter.neighbours[robot.uid]
    assert record.candidates_from_line
    assert np.round(record.candidates[1], 1).tolist() == [[30.0, 40.0], [30.0, -40.0]]
    robot.message_rx(VOTE.pack(sender=12, target=robot.uid, index=0, version=version), 45)
    _attempt(robot)
    assert robot.position == pytest.approx(truth, abs=0.1)


def test_rule_1_waits_until_its_three_anchors_were_placed_a_moment_ago():
    # The 5 m corridor of seed 2 twisted at robot 85's fix from three anchors, one of them
    # placed 0.16 s before and about 20 mm off (docs/localize.md, rule 1).
    robot = _spread_robot()
    truth = (30.0, 20.0)
    anchors = {11: (0.0, 0.0), 12: (60.0, 0.0), 13: (10.0, 70.0), 14: (70.0, 50.0)}
    position = {"hops": 1, "flags": LOCALIZED, "windings": 0}

    def placed(uid):
        a, d = anchors[uid], math.dist(truth, anchors[uid])
        _heard(robot, uid, d)
        robot.message_rx(POS.pack(sender=uid, x_mm=a[0], y_mm=a[1], **position), d)
        return robot.neighbours[uid]

    records = [placed(uid) for uid in (11, 12, 13)]
    assert [n.placed_tick for n in records] == [robot.kilo_ticks] * 3  # heard placed now
    _attempt(robot)
    assert robot.position is None
    wait = robot.params.fresh_anchor_s * robot.ticks_per_s
    assert wait > 0
    records[0].placed_tick -= wait
    records[1].placed_tick -= wait
    _attempt(robot)
    assert robot.position is None  # anchor 13 is still fresh
    records[2].placed_tick -= wait - 1
    _attempt(robot)
    assert robot.position is None  # one tick short
    records[2].placed_tick -= 1
    _attempt(robot)
    assert robot.position == pytest.approx(truth, abs=0.5)
    # A robot that hears an anchor's candidates again forgets when it was placed.
    robot.message_rx(CAND.pack(sender=13, version=0, index=0, x_mm=1.0, y_mm=2.0, windings=0), 50)
    assert records[2].x_mm is None and records[2].placed_tick is None


def test_four_anchors_do_not_wait_for_a_fresh_one():
    robot = _spread_robot()
    truth = (30.0, 20.0)
    anchors = {11: (0.0, 0.0), 12: (60.0, 0.0), 13: (10.0, 70.0), 14: (70.0, 50.0)}
    for uid, a in anchors.items():
        _heard(robot, uid, math.dist(truth, a), a)
    robot.neighbours[14].placed_tick = robot.kilo_ticks
    _attempt(robot)
    assert robot.position == pytest.approx(truth, abs=0.5)


def test_a_seam_robot_places_itself_from_the_anchors_that_agree_and_logs_them():
    robot = _spread_robot()
    logged = []
    robot.log = lambda event, **fields: logged.append((event, fields))
    for uid, a, r in zip(range(11, 16), SEAM_ANCHORS, _seam_ranges(), strict=True):
        _heard(robot, uid, r, a)
    _attempt(robot)
    assert robot.position == pytest.approx(SEAM_TRUTH, abs=0.1)
    ((_, fields),) = [e for e in logged if e[0] == "located"]
    assert fields["rule"] == "subset" and fields["anchors"] == 4
    assert [u for u, _, _ in fields["references"]] == [11, 12, 13, 14]
    assert fields["dropped"] == [[15, pytest.approx(-30.0, abs=0.2)]]


def test_gauss_newton_converges_on_exact_distances():
    truth = (31.0, -12.0)
    anchors = [(0.0, 0.0), (70.0, 5.0), (20.0, 60.0), (-30.0, -50.0)]
    links = [(*a, math.dist(truth, a)) for a in anchors]
    x, y = 10.0, 10.0
    for _ in range(10):
        x, y, rms = gauss_newton_step(x, y, links, huber_mm=3.0, max_step_mm=100.0)
    assert (x, y) == pytest.approx(truth, abs=1e-9)
    assert rms == pytest.approx(0.0, abs=1e-6)


def test_gauss_newton_fixed_y_moves_along_x_only():
    # The truth is (40, 0); a neighbour above it at 25 mm pulls along y, which is fixed.
    links = [(0.0, 0.0, 40.0), (80.0, 0.0, 40.0), (40.0, 30.0, 25.0)]
    x, y = 35.0, 0.0
    for _ in range(8):
        x, y, _ = gauss_newton_step(x, y, links, huber_mm=10.0, max_step_mm=10.0, fix_y=True)
        assert y == 0.0
    assert x == pytest.approx(40.0, abs=1e-6)


def test_gauss_newton_bounds_the_pull_of_a_wrong_neighbour():
    truth = (0.0, 0.0)
    good = [(40.0, 0.0), (-40.0, 0.0), (0.0, 40.0), (0.0, -40.0)]
    links = [(*p, 40.0) for p in good] + [(28.0, 28.0, 10.0)]  # 29.6 mm too short
    plain = gauss_newton_step(*truth, links, huber_mm=1e9, max_step_mm=100.0)
    robust = gauss_newton_step(*truth, links, huber_mm=3.0, max_step_mm=100.0)
    assert math.hypot(*plain[:2]) == pytest.approx(29.6 / 3.0, rel=1e-3)
    assert math.hypot(*robust[:2]) == pytest.approx(3.0 / 2.1, rel=1e-3)


def test_settle_window_looks_at_the_displacement_over_the_window():
    w = SettleWindow(settle_mm=0.2, rounds=2)
    # Steps of 0.15 mm: each is below 0.2 mm, but two of them are not.
    assert [w.add(0.15 * k, 0.0) for k in range(4)] == [False] * 4
    # Then steps of 0.05 mm: 0.30 -> 0.50 over the window is 0.2 mm (not below), 0.45 -> 0.55 is.
    assert [w.add(0.45 + 0.05 * k, 0.0) for k in range(1, 4)] == [False, True, True]
    w.reset()
    assert not w.settled
    assert w.add(0.6, 0.0) is False


# --------------------------------------------------------------------------- termination


def test_subtree_complete_and_give_up_rules():
    child = _neighbour(1, hops=3, flags=SETTLED, parent=5)
    parent = _neighbour(2, hops=1)
    assert not subtree_complete(True, 5, [child, parent])
    assert subtree_complete(True, 6, [child, parent])  # not its parent
    child.flags |= COMPLETE
    assert subtree_complete(True, 5, [child, parent])
    located = _neighbour(3, position=(1.0, 2.0), flags=SETTLED)
    unsettled = _neighbour(4, position=(5.0, 2.0))
    assert gives_up([located], quiet=True)
    assert not gives_up([located, unsettled], quiet=True)
    assert not gives_up([_neighbour(5), _neighbour(6)], quiet=True)
    assert gives_up([_neighbour(5), _neighbour(6, flags=SETTLED)], quiet=True)
    assert not gives_up([_neighbour(5), _neighbour(6, flags=SETTLED)], quiet=False)


# ------------------------------------------------------------------------------ whole runs


def test_small_lattice_ends_in_one_frame_near_the_optimum():
    result = run(40)
    s = result.summary
    assert s["frames"] == 1
    assert s["localized_fraction"] == 1.0
    assert s["done_fraction"] == 1.0
    assert s["within_5mm_fraction"] == 1.0
    assert s["rmse_mm"] < NEAR_BOUND * s["crlb_rmse_mm"]
    assert s["rmse_mm"] < 3 * s["central_rmse_mm"]
    assert s["central_localized_fraction"] == 1.0
    # On independent noise (IDEALISED) this is about 15: settling follows soon after the last
    # fix. On the default tables the two ends' means of one link differ by their emitters'
    # biases (a few mm), so a robot's fit still moves whenever a neighbour's DIST report first
    # arrives, which takes one report round per neighbour (about 10 s), not one message per hop.
    assert s["done_over_hop_limit"] <= 50
    # The swarm stopped by itself: every robot is done well before the time limit.
    assert s["sim_time_s"] < 60
    assert set(s["phase_times_s"]) == {"elected", "last_located", "root_done", "all_done"}
    # Every fix was right given its anchors: nothing to audit.
    assert s["misplaced_fixes"] == {} and s["first_misplaced"] is None
    robots = result.sim.robots
    assert sum(r.is_root for r in robots) == 1
    assert len({r.root_key for r in robots}) == 1


@pytest.mark.parametrize(
    "overrides",
    [
        {"medium.loss_prob": 0.2},
        {"medium.occlusion": "none"},
        {"medium.occlusion": "block"},
        {"robot.rx_mode": "polled"},
    ],
)
def test_small_lattice_with_loss_with_and_without_occlusion_and_polled(overrides):
    s = run(30, **overrides).summary
    assert s["frames"] == 1
    assert s["localized_fraction"] == 1.0
    assert s["done_fraction"] == 1.0
    assert s["rmse_mm"] < s["crlb_rmse_mm"]


def test_robots_measure_their_own_ranging_noise():
    # Nobody tells the robots that the noise is 3 mm, not the 1 mm they start by assuming.
    # Independent noise (ranging.model = gaussian): a spread robots can measure.
    result = run(40, **{**IDEALISED, "ranging.sigma_mm": 3.0})
    s = result.summary
    estimates = [r.sigma_mm for r in result.sim.robots]
    # Each robot's median spread, plus the whole-millimetre rounding (1/12 mm²).
    assert np.median(estimates) == pytest.approx(math.sqrt(9 + 1 / 12), rel=0.05)
    assert s["frames"] == 1
    assert s["localized_fraction"] == 1.0
    assert s["rmse_mm"] < 0.5 * s["crlb_rmse_mm"]
    assert not any(n.ambiguous for r in result.sim.robots for n in r.neighbours.by_id.values())


def test_crashed_robots_do_not_hold_the_swarm_up():
    overrides = {"faults.crash_fraction": 0.1, "faults.crash_from_s": 3, "faults.crash_to_s": 8}
    result = run(60, **overrides)
    s = result.summary
    assert s["robots_stopped"] == 6
    assert s["done_fraction"] == 1.0  # every robot still running decided it was done
    assert s["frames"] == 1
    assert s["localized_fraction"] >= 0.9
    assert s["rmse_mm"] < NEAR_BOUND * s["crlb_rmse_mm"]


def test_an_island_that_no_robot_can_place_alone_places_itself():
    # 100 robots at random, seed 1: seven robots (four of them all in range of each other)
    # reach the frame through five links, and none hears more than two placed robots; an
    # eighth hears three placed robots on one line. Multilateration alone stops at 92 %. A
    # geometry of the thesis's 85 mm disc with independent noise: the island is its property.
    # It also needs the timing it was found with (31 ticks/s, 3.2 ms airtime, no sense delay):
    # on kilolib's timing (the defaults) three of its robots stay unplaced at this seed
    # (localized 0.97; an open weakness of localize_island, not of the geometry).
    # (Without localize.heard_mm, the rule that a robot is not deaf, multilateration places
    # them all: tests/test_localize_shapes.py.)
    overrides = {
        **IDEALISED,
        **OLD_TIMING,
        "placement.kind": "random",
        "placement.area": "disc",
        "placement.density_per_m2": 400,
        "placement.robots": 100,
        "localize.heard_mm": 0.0,
        # Rule 3 (neighbours' candidates), off by default on kilolib's ranging, where its
        # choices folded sparse frames; the island was found with it, on independent noise.
        "localize.max_candidate_neighbours": 3,
    }
    result = scenarios.run(LOCALIZE, overrides, seed=1)
    s = result.summary
    # Since rule 2 gives candidates from three anchors on one line, the eighth robot (74) is
    # placed in the spread, by a vote at 14.4 s (0.3 mm off); the island's course changes and
    # two of its robots (42, 99) are done before the members that could place them solve
    # (99 done at 25.7 s, the first solve that places at 26.8 s): 0.98, 1.0 before.
    assert s["localized_fraction"] >= 0.98
    assert s["frames"] == 1
    assert s["max_error_mm"] < 5.0
    assert s["rmse_mm"] < s["crlb_rmse_mm"]
    assert s["done_over_hop_limit"] <= 20
    events = result.sim.trace.events_frame()
    located = events.query("event == 'located'")
    by_island = [json.loads(d)["rule"] == "island" for d in located["data"]]
    assert any(by_island)
    # The island works after DONE, when the frame stands still: its robots are placed after
    # the root declared the swarm done, and the run ends when they are done too.
    phases = s["phase_times_s"]
    assert located[by_island].t_s.min() > phases["root_done"]
    island_done = events.query("event == 'island_done'")
    assert len(island_done) >= 7
    assert phases["all_done"] == pytest.approx(island_done.t_s.max(), abs=1e-3)
    # Without islands (localize.island_max_reports = 0) the same run stops short (at 0.92
    # before robot 74 was placed in the spread).
    alone = scenarios.run(LOCALIZE, {**overrides, "localize.island_max_reports": 0}, seed=1)
    assert alone.summary["localized_fraction"] == pytest.approx(0.93)
    assert not len(alone.sim.trace.events_frame().query("event == 'island_done'"))


def test_two_separate_swarms_make_two_frames():
    left = np.array([[x * 40.0 + (y % 2) * 20.0, y * 34.6] for x in range(4) for y in range(4)])
    positions = np.vstack([left, left + np.array([1000.0, 0.0])])
    result = scenarios.run(LOCALIZE, {}, seed=2, placement=positions)
    s = result.summary
    assert s["frames"] == 2
    assert s["localized_fraction"] == 1.0
    assert s["largest_frame_fraction"] == 0.5
    assert s["done_fraction"] == 1.0
    assert sum(r.is_root for r in result.sim.robots) == 2


def test_a_lone_robot_is_done_without_a_frame():
    result = scenarios.run(LOCALIZE, {}, seed=1, placement=np.array([[0.0, 0.0], [500.0, 0.0]]))
    s = result.summary
    assert s["frames"] == 0
    assert s["localized_fraction"] == 0.0
    assert s["done_fraction"] == 1.0


def test_both_ends_of_a_pair_fit_the_same_distance():
    # Each end fits the mean of the two ends' last reports (kilonet.protocols.common.refinement):
    # where both last reports arrived, the two numbers are the same, however old the reports are.
    # (Their age does not matter: with 17 neighbours and a report every 0.6 s, a neighbour is
    # reported about once in a 10 s run, and a mean of the first few samples may lie 1 mm from the
    # end's final mean.)
    result = run(30)
    robots = result.sim.robots
    by_uid = {r.uid: r for r in robots}
    assert len(by_uid) == len(robots)
    delivered, agree = [], []
    for r in robots:
        for uid, n in r.neighbours.by_id.items():
            other = by_uid[uid].neighbours[r.uid]
            arrived = (
                n.reported_mm is not None
                and other.reported_mm is not None
                and abs(n.reported_mm - other.sent_mm) < 1e-9
                and abs(other.reported_mm - n.sent_mm) < 1e-9
            )
            delivered.append(arrived)
            if arrived:
                agree.append(abs(n.range_mm - other.range_mm))
    assert len(delivered) > 300
    assert np.mean(delivered) > 0.5
    assert max(agree) < 1e-9


def test_measured_distances_are_receptions_of_real_links():
    from kilonet.scenarios.reference import measured_distances

    result = run(30)
    sim = result.sim
    pairs, means, samples = measured_distances(sim, [r.neighbours for r in sim.robots])
    truth = sim.world.positions_mm
    limit = sim.params.scenario.neighbour_max_mm
    heard = {(s, r) for r, s in pairs.tolist()}  # pairs are (receiver, sender)
    # Robots range the links whose estimates fall within localize.neighbour_max_mm: every link
    # whose every reception does, and none that no reception can.
    assert heard <= set(trusted_links(sim, limit, -NOISE_MARGIN_MM).edges)
    assert set(trusted_links(sim, limit, NOISE_MARGIN_MM).edges) <= heard
    true_d = np.hypot(*(truth[pairs[:, 0]] - truth[pairs[:, 1]]).T)
    # Each mean is the link's noise-free estimate (its systematic error included) within 5
    # standard errors of a reception's noise (under 1 mm), plus 1 mm: the noise-free estimate
    # is itself a whole millimetre.
    expected = [
        noise_free_estimate_mm(sim, s, r, d)
        for (r, s), d in zip(pairs.tolist(), true_d, strict=True)
    ]
    assert np.all(np.abs(means - expected) < 5 / np.sqrt(samples) + 1.0)


def test_run_directory_has_the_gcs_columns_and_figures(tmp_path):
    result = run(30)
    scenarios.write_outputs(result, tmp_path)
    robots = pd.read_csv(tmp_path / "robots.csv")
    for column in ("est_x_mm", "est_y_mm", "frame", "localized"):
        assert column in robots
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in (
        "frames",
        "localized_fraction",
        "largest_frame_fraction",
        "rmse_mm",
        "crlb_rmse_mm",
        "central_rmse_mm",
        "central_localized_fraction",
        "rmse_over_crlb",
        "sim_time_s",
        "wall_time_s",
        "messages_sent",
        "phase_times_s",
    ):
        assert key in summary
    assert (tmp_path / "localize.png").stat().st_size > 0


# ------------------------------------------------------------------------ no ground truth

_PROTOCOL_MODULES = (
    island_solve,
    localize_module,
    localize_base,
    localize_election,
    localize_island,
    localize_spread,
    localize_termination,
    refinement,
)


def test_protocol_modules_import_only_the_robot_api_and_math():
    allowed = {
        "kilonet.message",
        "kilonet.robot",
        "kilonet.params",
        "kilonet.protocols.common.geometry",
    }
    for module in _PROTOCOL_MODULES:
        tree = ast.parse(Path(inspect.getfile(module)).read_text())
        for node in ast.walk(tree):
            if not isinstance(node, ast.ImportFrom) or node.module.startswith("kilonet.protocols"):
                continue
            if node.module.startswith("kilonet"):
                assert node.module in allowed, f"{module.__name__} imports {node.module}"


def test_protocol_runs_on_the_robot_api_alone():
    from kilonet.scenarios.base import build_params, place
    from kilonet.simulation import Simulation

    params = build_params(LOCALIZE, {"placement.robots": 25})
    positions = place(LOCALIZE, params)
    sim = Simulation(positions, LOCALIZE.setup.program(params, positions), params)
    # A robot holds no simulation (tests/test_simulation.py), so all it reaches is its API.
    sim.run(60.0, stop_when=lambda: LOCALIZE.setup.stop_when(sim))
    assert all(r.stage == "done" for r in sim.robots)
    assert all(r.in_frame for r in sim.robots)


def test_a_message_from_a_robot_with_my_id_makes_me_draw_another():
    result = run(12)
    robot = result.sim.robots[0]
    # A fresh robot program, electing, hears its own ID from another robot.
    fresh = localize_module.LocalizeRobot(robot.params)
    fresh._attach(result.sim, 0, np.random.default_rng(5))
    fresh.setup()
    old = fresh.uid
    fresh.message_rx(ELECT.pack(sender=old, key=1, hops=0, parent=NO_ID), 50)
    assert fresh.uid != old
    assert isinstance(fresh.message_tx(), Message)


def test_a_robot_tells_a_new_parent_in_elect_after_the_election():
    result = run(12)
    fresh = localize_module.LocalizeRobot(result.sim.robots[0].params)
    fresh._attach(result.sim, 0, np.random.default_rng(5))
    fresh.setup()
    position = {"x_mm": 40.0, "y_mm": 0.0, "hops": 1, "flags": LOCALIZED, "windings": 0}
    fresh.message_rx(POS.pack(sender=10, **position), 40)  # the frame exists: phase 2
    # Robots 10 and 11 report their distances to it: they hear it, so either can be its parent.
    for sender in (10, 11):
        fresh.message_rx(NBR.pack(sender=sender, neighbour=fresh.uid, distance_mm=40.0), 40)
    fresh.loop()  # a round of work: 2 hops, parent 10
    assert (fresh.stage, fresh.hops, fresh.parent) == ("localize", 2, 10)
    # It announces a new parent once the parent has lasted a round of work.
    assert fresh.message_tx().type != ELECT.type
    fresh._next_round = 0  # its next round is due
    fresh.loop()
    sent = [fresh.message_tx() for _ in range(4)]
    elect = [ELECT.unpack(m) for m in sent if m.type == ELECT.type]
    assert [m.parent for m in elect] == [10, 10, 10]  # localize.parent_repeats
    assert all(m.hops & 0x7F == 2 for m in elect)
    # Then one opportunity in localize.parent_every (10) announces it again.
    later = [fresh.message_tx() for _ in range(5, 25)]
    assert [m.type for m in later].count(ELECT.type) == 2
    for _ in range(30):  # robot 11, also 1 hop out, is heard far more often
        fresh.message_rx(POS.pack(sender=11, **position), 45)
    fresh._next_round = 0
    fresh.loop()
    assert fresh.parent == 11
    fresh._next_round = 0
    fresh.loop()
    assert ELECT.unpack(fresh.message_tx()).parent == 11


def test_an_axis_robot_placed_after_the_root_renamed_the_frame_gives_its_position_up():
    result = run(12)
    fresh = localize_module.LocalizeRobot(result.sim.robots[0].params)
    fresh._attach(result.sim, 0, np.random.default_rng(5))
    fresh.setup()
    fresh.message_rx(ROOT.pack(sender=10, axis=fresh.uid, third=20, flags=0), 40)
    fresh.loop()  # placed as the axis robot, at the root's distance on +x
    assert fresh.position == pytest.approx((40.0, 0.0))
    fresh.message_rx(ROOT.pack(sender=10, axis=fresh.uid, third=21, flags=0), 40)
    assert fresh.position is not None  # still the axis: only the third robot changed
    fresh.message_rx(ROOT.pack(sender=10, axis=30, third=21, flags=0), 40)
    assert fresh.position is None  # the frame started without it
    assert not fresh.flags & LOCALIZED


# -------------------------------------------------------------------- the targets


#: On the real-robot medium (issue #29: soft-edged reach to ~148 mm, per-link systematic ranging
#: error) the protocol misses these targets: 150 random robots, seeds 1/3/5 without loss give
#: rmse_over_crlb 15.6 (past 1.5), done_over_hop_limit 50.0 (past 20), rmse_over_crlb 6.1;
#: with 20 % loss done_over_hop_limit 51.3 and 68.5, rmse_over_crlb 42.4; 300 robots with loss
#: rmse_over_crlb 46.8. Suspected: refinement never settles (links at the soft edge come and
#: go, restarting settle windows) and per-link systematic errors that refinement cannot average
#: away. protocols/localize is not this test's owner's to change: reported, not loosened.
REAL_MEDIUM_MISSES = pytest.mark.xfail(
    strict=True,
    reason="localize misses rmse_over_crlb <= 1.5 / done_over_hop_limit <= 20 on the "
    "issue-29 medium (soft edge, systematic per-link error); see REAL_MEDIUM_MISSES",
)


#: The default tier's twins of the two tests below: smaller random swarms miss the same
#: targets (seed 1: 40 robots end at done_over_hop_limit 29.2, 31.1 with 20 % loss; 60 robots
#: with loss 38.3), so they stay strict xfails.
SMALL_RANDOM_SWARM = 40


@REAL_MEDIUM_MISSES
@pytest.mark.parametrize(
    ("robots", "seed", "loss"),
    [
        *(
            pytest.param(150, seed, loss, marks=pytest.mark.slow)
            for seed in (1, 3, 5)
            for loss in (0.0, 0.2)
        ),
        (SMALL_RANDOM_SWARM, 1, 0.0),
        (SMALL_RANDOM_SWARM, 1, 0.2),
    ],
)
def test_random_placements_reach_the_targets(robots, seed, loss):
    s = run(robots, seed, **{"placement.kind": "random", "medium.loss_prob": loss}).summary
    assert s["mean_neighbours"] >= 6
    assert s["at_optimum_over_central"] >= 0.95
    assert s["rmse_over_crlb"] <= 1.5
    assert s["done_over_hop_limit"] <= 20


@REAL_MEDIUM_MISSES
@pytest.mark.parametrize("robots", [pytest.param(300, marks=pytest.mark.slow), 60])
def test_random_robots_with_loss_reach_the_targets_in_one_frame(robots):
    s = run(robots, 1, **{"placement.kind": "random", "medium.loss_prob": 0.2}).summary
    assert s["frames"] == 1
    assert s["at_optimum_over_central"] >= 0.95
    assert s["rmse_over_crlb"] <= 1.5
    assert s["done_over_hop_limit"] <= 20
