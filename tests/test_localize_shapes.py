"""``localize`` and the centralized reference on shapes beyond discs and lattices: long
corridors (coordinates beyond one int16 field), sparse random swarms and non-convex C shapes.

The coordinate rules and small runs are in the default suite; the issue's swarms (300–600
robots, with and without loss) are marked slow (``pytest -m slow``), each beside a smaller
default-tier twin with its assertions.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import kilonet.protocols.localize.program as localize_module
from kilonet import scenarios
from kilonet.protocols.common.refinement import DIST
from kilonet.protocols.localize.base import (
    COORDINATE_PERIOD_MM,
    MAX_COORDINATE_MM,
    absolute_position,
    distance_report,
    unwrap_coordinate,
    wrapped_position,
)
from kilonet.protocols.localize.phase2_spread import CAND, POS
from kilonet.protocols.localize.stages import LocalizingPhase
from kilonet.scenarios.localize import estimates_frame

LOCALIZE = scenarios.get("localize")

coordinate = st.floats(-MAX_COORDINATE_MM, MAX_COORDINATE_MM)


# ----------------------------------------------------------------------------- coordinates


@given(coordinate, coordinate)
def test_every_position_a_robot_can_hold_fits_pos_and_comes_back(x, y):
    wx, wy, windings = wrapped_position(x, y)
    message = POS.pack(sender=1, x_mm=wx, y_mm=wy, hops=3, flags=1, windings=windings)
    m = POS.unpack(message)
    assert absolute_position(m.x_mm, m.y_mm, m.windings) == pytest.approx((x, y), abs=0.05 + 1e-9)


@given(coordinate, st.floats(-3200.0, 3200.0))
def test_a_wrapped_coordinate_unwraps_near_any_position_within_3_2_m(x, offset):
    wx, _, _ = wrapped_position(x, 0.0)
    assert unwrap_coordinate(wx, x + offset) == pytest.approx(x, abs=0.05 + 1e-9)


def test_the_period_is_the_int16_field_of_tenths():
    assert COORDINATE_PERIOD_MM == 65536 * 0.1
    assert wrapped_position(3276.7, -3276.8)[:2] == (3276.7, -3276.8)
    assert wrapped_position(3276.8, 0.0)[:2] == (-3276.8, 0.0)


def _robot(sim, index: int) -> localize_module.LocalizeRobot:
    robot = localize_module.LocalizeRobot(sim.robots[0].params)
    robot._attach(sim, index, np.random.default_rng(index))
    robot.setup()
    robot.driver.enter(LocalizingPhase(robot))
    return robot


def test_robots_tens_of_metres_from_the_root_talk_in_whole_positions():
    sim = scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim
    far, near = _robot(sim, 0), _robot(sim, 1)
    far.locate(20_000.0, -7_123.4)  # 20 m east, 7 m south of the root
    far.hops = 90
    near.message_rx(far.spread.state_message(), 60)
    record = near.neighbours[far.uid]
    assert record.position == pytest.approx((20_000.0, -7_123.4))
    # DIST carries no winding numbers: the receiver unwraps them near what it knows.
    record.x_mm, record.y_mm = 19_990.0, -7_100.0
    moved = far.neighbours.heard(near.uid, 60, 1)
    far.locate(20_004.5, -7_120.0)
    near.message_rx(distance_report(far.uid, far.position, moved), 60)
    assert record.position == pytest.approx((20_004.5, -7_120.0))
    # An unplaced robot's candidates are far from the root too.
    far.position = None
    far.spread.candidates = (3, [(-15_000.0, 4_000.0), (-15_040.0, 4_060.0)])
    for _ in range(8):  # CAND, CAND and POS in turn, between distance reports
        message = far.message_tx()
        if message.type == CAND.type:
            near.message_rx(message, 60)
    assert record.candidates == (3, [(-15_000.0, 4_000.0), (-15_040.0, 4_060.0)])


def test_a_position_beyond_the_coordinates_is_refused_and_counted():
    sim = scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim
    robot = _robot(sim, 0)
    robot.spread.place(MAX_COORDINATE_MM + 1.0, 0.0, "anchors", 3)
    assert robot.position is None
    events = sim.trace.events_frame()
    assert (events.event == "out_of_frame").sum() == 1


def test_a_message_that_cannot_be_packed_is_counted_not_raised():
    sim = scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim
    robot = _robot(sim, 0)
    robot.hops = 300  # beyond POS's hop byte: a protocol bug, which must not end the run
    robot.locate(10.0, 0.0)
    robot._turn = 1
    assert robot.message_tx() is None
    assert robot.unsendable == 1
    events = sim.trace.events_frame()
    assert "does not fit" in events.data[events.event == "unsendable"].iloc[0]


def test_dist_layout_is_unchanged_by_wrapping():
    n = localize_module.Neighbour(9)
    n.distance_sum_mm, n.samples = 60.0, 1
    m = DIST.unpack(distance_report(1, (10_000.0, -5.0), n))
    assert (m.x_mm, m.y_mm) == pytest.approx((10_000.0 - COORDINATE_PERIOD_MM * 2, -5.0))


# ------------------------------------------------------------------ a robot is not deaf


def test_a_candidate_near_a_settled_robot_it_does_not_hear_is_impossible():
    from kilonet.protocols.localize.phase2_spread import overlap_vote

    anchors = [(-30.0, 0.0), (30.0, 0.0)]
    pair = ((0.0, 40.0), (0.0, -40.0))
    # A settled robot 50 mm from the second candidate: a robot there would hear it.
    assert overlap_vote(pair, anchors, 28.0, settled=[(30.0, -80.0)], heard_mm=55.0) == 0
    assert overlap_vote(pair, anchors, 28.0, settled=[(30.0, 80.0)], heard_mm=55.0) == 1
    # 56 mm away: a robot there may not hear it; the anchors are as far from both.
    assert overlap_vote(pair, anchors, 28.0, settled=[(0.0, -96.0)], heard_mm=55.0) is None
    assert overlap_vote(pair, anchors, 28.0, settled=anchors, heard_mm=55.0) is None
    assert overlap_vote(pair, anchors, 28.0, settled=[(30.0, -80.0)], heard_mm=0.0) is None


def test_the_spread_alone_places_the_island_that_multilateration_left_out():
    # The 100 random robots of seed 1 whose island tests/test_localize.py places after DONE:
    # with the rule, the frame itself reaches every robot, islands off.
    overrides = {
        "placement.kind": "random",
        "placement.area": "disc",
        "placement.density_per_m2": 400,
        "placement.robots": 100,
        "localize.island_max_reports": 0,
    }
    s = scenarios.run(LOCALIZE, overrides, seed=1).summary
    assert s["localized_fraction"] == 1.0
    # On the real-robot medium each link keeps its own systematic error, which no averaging
    # removes: the run sits near the bound of that error (kilonet.reception's
    # effective_sigma_mm), not below it as on iid noise.
    assert s["max_error_mm"] < 3 * s["crlb_rmse_mm"]
    assert s["rmse_mm"] < 1.5 * s["crlb_rmse_mm"]


def test_a_robot_whose_neighbours_all_fell_silent_is_done():
    # It missed every DONE its neighbours sent (collisions at the edge of a sparse swarm) and
    # ran on alone until the run's time-out; now it stops once no neighbour is fresh.
    sim = scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim
    robot = _robot(sim, 0)
    robot.neighbours.heard(7, 50, 0)  # one neighbour, heard once, long ago
    robot.locate(10.0, 0.0)
    robot._round = 100  # far beyond localize.stale_s
    robot.termination.round(robot.kilo_ticks, robot.neighbours.fresh(robot._round))
    assert robot.termination.done
    events = sim.trace.events_frame()
    assert '"silent"' in events.data[events.event == "done"].iloc[-1]


def test_a_run_that_leaves_robots_out_says_which_and_why():
    # A lattice patch, a robot 2 m away (a lone root is no frame) and a row of three beyond
    # it: whatever the reach, the lone robot and the row hold no placed neighbour.
    from kilonet.scenarios.placement import hex_lattice

    positions = np.vstack(
        [hex_lattice(19), [[2000.0, 0.0]], [[4000.0, 0.0], [4040.0, 0.0], [4080.0, 0.0]]]
    )
    result = scenarios.run(LOCALIZE, {}, seed=1, placement=positions)
    s = result.summary
    unplaced = [i for i, r in enumerate(result.sim.robots) if not r.in_frame]
    assert set(unplaced) >= {19, 20, 21, 22}
    assert s["unplaced_robots"] == unplaced
    assert sum(s["unplaced_why"].values()) == len(unplaced)
    table = estimates_frame(result.sim).set_index("robot")
    keys = ["no_anchor", "one_anchor", "two_anchors", "anchors_rejected"]
    for i in unplaced:  # each reason counts the placed neighbours the robot knew
        anchors = sum(n.x_mm is not None for n in result.sim.robots[i].neighbours.known())
        assert table.why_unplaced[i].split("+")[0] == keys[min(anchors, 3)]
    assert table.why_unplaced[19] == "no_anchor"
    assert (table.why_unplaced[table.localized] == "").all()


# -------------------------------------------------------------------- the issue's swarms

SPARSE = {
    "placement.kind": "random",
    "placement.area": "disc",
    "placement.density_per_m2": 350,
    "placement.robots": 400,
}


def _sound(s):
    """What every run must say, whatever the swarm: no value it could not send, every robot
    done, and a reference that places nearly every robot right among its neighbours."""
    assert s["unsendable_messages"] == 0
    assert s["out_of_frame_robots"] == 0
    assert s["done_fraction"] == 1.0
    assert s["central_localized_fraction"] >= 0.95


def _reference_is_the_optimum(result):
    """The solver's positions are the minimum that least squares from the truth ends in, on
    the run's own measurements (kilolib's ranging, each link with its systematic error)."""
    from kilonet.scenarios.central import central_reference, optimum_agreement_mm
    from kilonet.scenarios.reference import measured_distances

    sim = result.sim
    truth = sim.world.positions_mm
    pairs, means, samples = measured_distances(sim, [r.neighbours for r in sim.robots])
    ref = central_reference(truth, pairs, means, samples)
    # (The solver's own result, to the precision least squares stops at along slow modes.)
    assert ref.rmse_mm == pytest.approx(result.summary["central_rmse_mm"], rel=1e-2)
    agreement = optimum_agreement_mm(truth, ref.aligned_mm, pairs, means, samples)
    if np.nanmax(agreement) >= 1.0:
        # A valley too flat for positions to agree (the 5 m corridor of seed 2: 18 mm apart):
        # then the solver's cost is no higher than where least squares from the truth stops,
        # to 0.01 % (there 2.1e-6 above it; a folded frame's cost is tens of % above).
        from scipy.optimize import least_squares
        from scipy.sparse import lil_matrix

        sparsity = lil_matrix((len(pairs), truth.size), dtype=int)
        for k, (i, j) in enumerate(pairs):
            sparsity[k, [2 * i, 2 * i + 1, 2 * j, 2 * j + 1]] = 1

        def residuals(flat):
            p = flat.reshape(-1, 2)
            d = np.hypot(*(p[pairs[:, 0]] - p[pairs[:, 1]]).T)
            return np.sqrt(samples) * (d - means)

        from_truth = least_squares(residuals, truth.ravel(), jac_sparsity=sparsity).x
        cost = float((residuals(ref.aligned_mm.ravel()) ** 2).sum())
        assert cost <= float((residuals(from_truth) ** 2).sum()) * (1 + 1e-4)


@pytest.mark.parametrize(
    ("robots", "seed", "loss"),
    [
        *(
            pytest.param(400, seed, loss, marks=pytest.mark.slow)
            for seed in (1, 2, 3, 4)
            for loss in (0.0, 0.2)
        ),
        # The default tier's twin. 40 robots are too few: the disc's edge thins them to 5.75
        # neighbours (seed 1). 60 robots hold every claim; without loss their central
        # reference costs 11 s of CPU, with loss 1 s.
        (60, 1, 0.2),
    ],
)
def test_sparse_swarms_reach_the_central_reference(robots, seed, loss):
    overrides = {**SPARSE, "placement.robots": robots, "medium.loss_prob": loss}
    s = scenarios.run(LOCALIZE, overrides, seed=seed).summary
    assert 6.0 <= s["mean_neighbours"] <= 7.5
    assert s["frames"] == 1
    # The issue's measure: the largest frame places at the optimum at least 95 % of the
    # robots the solver localizes (a folded or bent part is not at the optimum).
    assert s["at_optimum_over_central"] >= 0.95
    assert s["rmse_mm"] <= 1.5 * s["central_rmse_mm"]
    _sound(s)


def _spread_robot(max_candidate_neighbours: int) -> localize_module.LocalizeRobot:
    """A robot with two placed neighbours and an unplaced one holding a candidate pair
    that only one of its own mirror positions fits (rule 3's doctest, as neighbour records)."""
    sim = scenarios.run(
        LOCALIZE,
        {"placement.robots": 5, "localize.max_candidate_neighbours": max_candidate_neighbours},
        seed=1,
    ).sim
    robot = _robot(sim, 0)
    truth = np.array([30.0, 20.0])
    for uid, (x, y), pair in (
        (11, (0.0, 0.0), None),
        (12, (60.0, 0.0), None),
        (13, (50.0, 60.0), [(50.0, 60.0), (70.0, 60.0)]),
    ):
        d = float(np.hypot(*(truth - (x, y))))
        for _ in range(20):
            n = robot.neighbours.heard(uid, d, 1)
        if pair is None:
            n.x_mm, n.y_mm = x, y
        else:
            n.candidates = (0, pair)
    return robot


def test_rule_3_is_off_unless_asked_for():
    # On by parameter, the robot takes the one choice that fits; by default it holds its
    # own two candidates and waits for rule 4's votes or three anchors.
    on = _spread_robot(3)
    on.spread.round(on.kilo_ticks, on.neighbours.fresh(1))
    assert on.position == pytest.approx((30.0, 20.0), abs=0.5)
    off = _spread_robot(0)
    off.spread.round(off.kilo_ticks, off.neighbours.fresh(1))
    assert off.position is None
    assert off.spread.candidates is not None
    assert sorted(np.round(off.spread.candidates[1], 1).tolist()) == [[30.0, -20.0], [30.0, 20.0]]


def _reaches_the_root(sim) -> float:
    """Share of robots whose parents (each ID resolved to the nearest robot holding it) lead
    to the root, read when the run ends (the tree as it stood when each robot was done)."""
    robots = sim.robots
    xy = sim.initial_positions_mm  # localize robots do not move
    by_uid: dict[int, list[int]] = {}
    for i, r in enumerate(robots):
        by_uid.setdefault(r.uid, []).append(i)
    reached = 0
    for start in range(len(robots)):
        seen, i = set(), start
        while not robots[i].is_root and i not in seen:
            seen.add(i)
            holders = by_uid.get(robots[i].parent, [])
            if not holders:
                break
            i = min(holders, key=lambda j, i=i: np.hypot(*(xy[j] - xy[i])))
        reached += robots[i].is_root
    return reached / len(robots)


@pytest.mark.parametrize(
    ("robots", "length_mm", "seed"),
    [
        *(pytest.param(600, 5000.0, seed, marks=pytest.mark.slow) for seed in (1, 2, 3)),
        (120, 1000.0, 1),  # the default tier's twin: the same density, a fifth of the length
    ],
)
def test_the_issues_corridor_runs_to_the_end_in_one_frame(robots, length_mm, seed):
    # 600 robots, 5 m x 0.2 m: the corridor whose runs ended in a PayloadError. Seed 3 then
    # ended with 131 robots unplaced (localized 0.78, DONE at 42.4 s while the front was
    # 2.8 m out: robots hung below parent cycles; test_localize_corridor.py). Seed 2 twisted
    # at a three-anchor fix from an anchor placed 0.16 s before (249 fixes misplaced); since
    # rule 1 waits for fresh anchors no seed misplaces a fix. at_optimum_over_central is
    # not asserted here: 0.583, 0.630 and 0.657, yet least squares from seed 3's frame ends
    # at a cost of 5,855,019 against the solver's 5,855,046 (38.6 mm from the truth against
    # 34.1): one flat valley, along which least squares stops wherever it starts, more than
    # 5 mm apart (docs/localize.md, Limits).
    from kilonet.scenarios.placement import corridor

    positions = corridor(robots, length_mm=length_mm, width_mm=200.0, rng=np.random.default_rng(5))
    result = scenarios.run(LOCALIZE, {}, seed=seed, placement=positions)
    s = result.summary
    _sound(s)
    assert s["frames"] == 1
    assert s["localized_fraction"] >= 0.95
    assert s["misplaced_fixes"] == {}
    assert _reaches_the_root(result.sim) >= 0.95
    assert sum(s["unplaced_why"].values()) == round(robots * (1 - s["localized_fraction"]))
    _reference_is_the_optimum(result)


@pytest.mark.parametrize(
    ("robots", "length_mm", "seed"),
    [
        *(pytest.param(400, 3400.0, seed, marks=pytest.mark.slow) for seed in (1, 2, 3)),
        (80, 680.0, 1),  # the default tier's twin: the same density, a fifth of the length
    ],
)
def test_the_studys_corridor_is_placed_to_its_far_end(robots, length_mm, seed):
    overrides = {
        "placement.kind": "corridor",
        "placement.length_mm": length_mm,
        "placement.width_mm": 200.0,
        "placement.robots": robots,
    }
    s = scenarios.run(LOCALIZE, overrides, seed=seed).summary
    _sound(s)
    assert s["frames"] == 1
    assert s["localized_fraction"] >= 0.95
    assert s["at_optimum_over_central"] >= 0.95


def test_a_frame_grows_past_one_coordinate_field():
    # 7 m: the frame reaches beyond one int16 field of tenths (±3,276.7 mm) from its root
    # and its messages still pack.
    from kilonet.scenarios.placement import corridor

    positions = corridor(600, length_mm=7000.0, width_mm=160.0, rng=np.random.default_rng(7))
    result = scenarios.run(LOCALIZE, {}, seed=1, placement=positions)
    s = result.summary
    _sound(s)
    table = estimates_frame(result.sim)
    located = table[table.localized]
    assert np.abs(located[["est_x_mm", "est_y_mm"]].to_numpy()).max() > 3276.8
    assert s["localized_fraction"] >= 0.95
    # (No fix misplaced; 37.2 mm, the solver 86.8 mm. at_optimum_over_central, 0.097, cannot
    # tell a fold in a valley this flat: docs/localize.md, Limits.)
    assert s["misplaced_fixes"] == {}


@pytest.mark.parametrize(
    ("robots", "outer_mm", "inner_mm", "seed"),
    [
        *(pytest.param(300, 700.0, 450.0, seed, marks=pytest.mark.slow) for seed in (1, 2)),
        # The default tier's twin, denser (683 robots/m² against 443): at the issue's density
        # a small C (75 robots, radii 350 and 225 mm, seed 1) places only 77 % at the optimum.
        (90, 280.0, 150.0, 1),
    ],
)
def test_a_c_shape_localizes_and_its_reference_is_the_optimum(robots, outer_mm, inner_mm, seed):
    from kilonet.scenarios.placement import c_shape

    positions = c_shape(
        robots, outer_radius_mm=outer_mm, inner_radius_mm=inner_mm, rng=np.random.default_rng(33)
    )
    result = scenarios.run(LOCALIZE, {}, seed=seed, placement=positions)
    s = result.summary
    _sound(s)
    assert s["central_localized_fraction"] >= 0.98
    assert s["at_optimum_over_central"] >= 0.95
    _reference_is_the_optimum(result)
