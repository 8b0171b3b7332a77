"""The global-coordinate-system protocol, phase by phase, against ground truth.

Small swarms run in the default suite; the issue's full-size runs (100–300 robots, loss) are
marked slow (``pytest -m slow``), each beside a smaller default-tier twin with its assertions.
"""

from __future__ import annotations

import functools
import itertools
import json

import networkx as nx
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kilonet import scenarios
from kilonet.protocols.common.alignment import half_map, procrustes_rmse
from kilonet.protocols.gcs.base import GcsParams
from kilonet.protocols.gcs.phase1_unique_ids import ID
from kilonet.protocols.gcs.phase6_merging import TF_ROT, quaternion_fields, rotation_from_fields
from kilonet.protocols.gcs.program import phase_windows_s
from kilonet.scenarios.neighbourhood import trusted_links

GCS = scenarios.get("gcs")
#: The full-size runs check the pipeline's machinery, so they take well-conditioned references:
#: with bodies that do not block, the thesis's largest-angle rule picks references up to 175°
#: apart, whose frames reject every fix as a mirror ambiguity (docs/gcs.md, "On the robot
#: model"); that failure case has its own tests.
WELL_CONDITIONED = {"gcs.reference_rule": "best_conditioned"}
#: kilonet's old medium: an 85 mm hard radius and iid Gaussian ranging noise, which isolates a
#: phase's arithmetic from the real robots' per-link systematic error (issue #29).
IDEALISED = {"medium.reach": "disc", "ranging.model": "gaussian"}


def run(robots: int, until: str, seed: int = 1, **overrides):
    settings = {"placement.robots": robots, "gcs.until": until, **overrides}
    return scenarios.run(GCS, settings, seed=seed)


#: A reception's noise moves its estimate by under 2 mm (ranging.intensity_noise 1.5 %).
NOISE_MARGIN_MM = 2.0


def assert_ids_locally_unique(result) -> None:
    """No robot hears two neighbours, or a neighbour and itself, with one ID: neighbours are the
    robots whose every reception reads within gcs.neighbour_max_mm (the protocol ignores the
    rest; real robots hear farther than that)."""
    sim = result.sim
    graph = trusted_links(sim, sim.params.scenario.neighbour_max_mm, NOISE_MARGIN_MM)
    uids = [r.uid for r in sim.robots]
    for node in graph:
        around = [uids[k] for k in graph.predecessors(node)] + [uids[node]]
        assert len(around) == len(set(around)), f"robot {node} sees a duplicate ID"
    assert result.summary["ids_duplicate_neighbours"] == 0


def test_phase_windows_follow_the_parameters():
    p = GcsParams(ids_s=5, elect_s=2, check_s=1, reelections=1, until="seeds")
    assert phase_windows_s(p) == [("ids", 0.0, 5.0), ("seeds", 5.0, 5.0 + 2 * 3 + 1 * 2)]


def test_phase1_ids_unique_among_neighbours_with_8_bit_ids():
    result = run(200, "ids", **{"gcs.id_bits": 8})
    assert_ids_locally_unique(result)
    # 8-bit IDs in 200 robots must have collided at first and been redrawn.
    assert result.summary["ids_redraws"] > 0


def test_phase1_ids_unique_with_20_percent_loss():
    result = run(200, "ids", **{"medium.loss_prob": 0.2, "gcs.ids_s": 12})
    assert_ids_locally_unique(result)


def test_id_message_fits_and_round_trips():
    msg = ID.pack(sender=513, salt=7, previous=2)
    assert len(msg.data) <= 9
    assert ID.unpack(msg) == ID.record(513, 7, 2)


def test_phase2_seed_conditions_hold_on_a_dense_lattice():
    result = run(60, "seeds")
    robots = result.sim.robots
    graph = result.sim.medium.graph()
    seeds = {i for i, r in enumerate(robots) if r.is_seed}
    assert seeds
    for i in graph:
        in_view = len(seeds & set(graph[i]))
        assert in_view >= (1 if i in seeds else 2), f"robot {i} sees {in_view} seeds"
    assert result.summary["seed_check_failed"] == 0


def test_phase2_reports_an_impossible_topology_and_still_ends():
    # A triangle of robots and one robot 300 mm away: the lone robot hears nobody, so it can
    # neither see two seeds nor, as a seed, another seed.
    positions = np.array([[0.0, 0.0], [40.0, 0.0], [20.0, 35.0], [300.0, 0.0]])
    result = scenarios.run(GCS, {"gcs.until": "seeds"}, placement=positions)
    end = phase_windows_s(result.params.scenario)[-1][2]
    assert result.sim.env.now == pytest.approx(end + 1.0)
    assert result.summary["seed_check_failed"] >= 1
    events = result.sim.trace.events_frame()
    failed = events[events.event == "seed_check_failed"]
    assert 3 in set(failed.robot)


@pytest.mark.parametrize(
    ("robots", "seed"),
    [
        (40, 1),
        # IDs are unique only among neighbours: here a reference's table held another robot
        # with the other reference's ID (see
        # kilonet.protocols.gcs.phase3_local_frames.reference_candidates).
        (100, 3),
    ],
)
def test_phase3_frames_match_the_truth_within_three_sigma(robots, seed):
    result = run(robots, "frames", seed=seed)
    sim = result.sim
    truth = sim.world.positions_mm
    # Robots the seed may have heard within gcs.neighbour_max_mm (a reception's noise included).
    graph = trusted_links(sim, sim.params.scenario.neighbour_max_mm, -NOISE_MARGIN_MM)
    seeds = [i for i, r in enumerate(sim.robots) if r.is_seed]
    assert result.summary["seeds_with_frame"] == len(seeds)

    def neighbour(a: int, uid: int) -> np.ndarray:
        # The seed's neighbour of that ID (IDs repeat across the swarm, not among the robots it
        # ranges; one at the limit's edge that it may never have heard is farther).
        near = [k for k in graph.predecessors(a) if sim.robots[k].uid == uid]
        return truth[min(near, key=lambda k: np.linalg.norm(truth[k] - truth[a]))]

    for a in seeds:
        (b, xb, yb), (c, xc, yc) = sim.robots[a].references
        pb, pc = neighbour(a, b), neighbour(a, c)
        est = np.array([[0.0, 0.0], [xb, yb], [xc, yc]])
        # The frame is the truth up to a rigid motion (maybe a reflection): compare distances.
        # Each is one link's mean estimate: three of the model's effective per-link errors
        # (systematic plus averaged noise), plus 0.5 mm for TABLE's whole millimetres.
        for (p, q), (u, v) in [
            ((0, 1), (truth[a], pb)),
            ((0, 2), (truth[a], pc)),
            ((1, 2), (pb, pc)),
        ]:
            d = np.linalg.norm(u - v)
            sigma = sim.medium.reception.effective_sigma_mm(np.array([d]), 10.0)[0]
            assert abs(np.linalg.norm(est[p] - est[q]) - d) <= 3 * sigma + 0.5
        assert yb == 0.0 and yc > 0


def _local_rmse_per_frame(result) -> list[float]:
    sim = result.sim
    truth = sim.world.positions_mm
    errors = []
    for r in sim.robots:
        if not r.is_seed:
            continue
        key = r.own_key
        members = [i for i, q in enumerate(sim.robots) if key in q.estimate.frames]
        if len(members) >= 3:
            est = np.array([sim.robots[i].estimate.frames[key] for i in members])
            errors.append(procrustes_rmse(est, truth[members])[0])
    return errors


@pytest.mark.parametrize("rx_mode", ["callback", "polled"])
def test_phase4_localizes_small_swarm_in_both_receive_modes(rx_mode):
    overrides = {"robot.rx_mode": rx_mode}
    if rx_mode == "polled":
        overrides["robot.loop_ticks"] = 1  # poll at every tick, as the thesis's loop did
    result = run(40, "localization", **overrides)
    assert_ids_locally_unique(result)
    assert result.summary["locally_localized_fraction"] >= 0.95
    # Three of the model's effective per-link errors at the neighbourhood's edge (each link's
    # systematic error plus averaged noise: fixes cannot average the first away).
    sigma = result.sim.medium.reception.effective_sigma_mm(np.array([85.0]), 10.0)[0]
    assert max(_local_rmse_per_frame(result)) <= 3 * sigma


@pytest.mark.parametrize("loss", [0.0, 0.2])
@pytest.mark.parametrize("robots", [pytest.param(100, marks=pytest.mark.slow), 40])
def test_phase4_on_the_idealised_medium(robots, loss):
    # The fixes' arithmetic at scale (100 robots, slow; 40 in the default tier) and under loss,
    # given iid noise, which fixes average: on the idealised medium. On the real-robot medium
    # each link keeps its systematic error, which no fix can average away (seed 1: 4.6 mm,
    # 4.8 mm with loss); the small swarm's test above holds that medium to three effective
    # per-link errors.
    overrides = {"medium.loss_prob": loss, **WELL_CONDITIONED, **IDEALISED}
    if loss:
        overrides.update({"gcs.frames_s": 90, "gcs.localization_s": 40})
    result = run(robots, "localization", **overrides)
    assert result.summary["locally_localized_fraction"] >= 0.95
    assert max(_local_rmse_per_frame(result)) <= 3.0


def test_half_map_steps_merge_mirror_image_frames():
    # Frame K is the mirror image of frame I (y flipped) and shifted: only a 3-D rotation
    # (a flip about an in-plane axis) turns one into the other.
    rng = np.random.default_rng(3)
    local = np.column_stack([rng.uniform(0, 80, 3), rng.uniform(0, 80, 3), np.zeros(3)])
    mirrored = local * [1, -1, 1] + [30.0, 5.0, 0.0]
    gi, gk = local.copy(), mirrored.copy()
    errors = []
    for _ in range(12):
        h_i, t_i, err = half_map(gi, gk)
        h_k, t_k, _ = half_map(gk, gi)
        gi, gk = h_i.apply(gi) + t_i, h_k.apply(gk) + t_k
        errors.append(err)
    assert errors[-1] < 1e-6 * errors[0]
    assert np.allclose(gi, gk, atol=1e-6)
    # As the protocol runs it: the child frame takes half steps toward its parent, which stays.
    gi, gk = local.copy(), mirrored.copy()
    errors = []
    for _ in range(20):
        h_i, t_i, err = half_map(gi, gk)
        gi = h_i.apply(gi) + t_i
        errors.append(err)
    assert all(b < a for a, b in itertools.pairwise(errors))  # shrinks every round
    assert np.allclose(gi, gk, atol=1e-3)


@pytest.mark.parametrize("rotvec", [[0.3, -1.2, 2.0], [np.pi, 0.0, 0.0], [0.0, 2.0, 2.2]])
def test_transform_messages_carry_rotations_within_a_hundredth_degree(rotvec):
    rotation = Rotation.from_rotvec(rotvec)
    message = TF_ROT.pack(sender=1, version=3, **quaternion_fields(rotation))
    fields = TF_ROT.unpack(message)
    back = rotation_from_fields(fields.q0, fields.q1, fields.q2)
    assert len(message.data) == 9
    assert np.degrees((back * rotation.inv()).magnitude()) < 0.01


def _merged(result):
    s = result.summary
    return s["frames"], s["localized_fraction"], s["rmse_mm"]


def _member_switches(result) -> float:
    """Share of a seed's consecutive rounds about one partner that asked another member."""
    events = result.sim.trace.events_frame()
    rounds = events[events.event == "merge_round"]
    last, same, switched = {}, 0, 0
    for robot, data in zip(rounds.robot, rounds.data, strict=True):
        fields = json.loads(data)
        key = (robot, fields["partner"])
        if key in last:
            same += last[key] == fields["member"]
            switched += last[key] != fields["member"]
        last[key] = fields["member"]
    return switched / (same + switched)


def test_fixed_member_rule_keeps_asking_one_member_per_partner():
    # "random" draws a member each round; "fixed" keeps one until a round times out (hints
    # name their own member, so a few switches remain).
    drawn = run(40, "merge", **{"gcs.merge_member": "random"})
    kept = run(40, "merge", **{"gcs.merge_member": "fixed"})
    assert _member_switches(drawn) > 0.4
    assert _member_switches(kept) < 0.2
    assert kept.summary["frames"] == 1
    assert kept.summary["rmse_mm"] <= 5.0


def test_merge_small_swarm_ends_by_itself_in_one_frame_per_group_component():
    result = run(40, "merge")
    sim = result.sim
    assert all(r.merge_done for r in sim.robots if r.is_seed)
    frames, localized, rmse = _merged(result)
    assert localized >= 0.95
    assert rmse <= 5.0
    # The swarm checked itself and found nothing to repair.
    assert result.summary["recoveries"] == 0
    assert result.summary["detected"]["split_boundary"] == []
    # Disagreement reported by merging rounds falls: late rounds agree far better than early.
    events = sim.trace.events_frame()
    rounds = events[events.event == "merge_round"]
    errors = np.array([json.loads(d)["error_mm"] for d in rounds.data])
    early, late = errors[: len(errors) // 4], errors[-len(errors) // 4 :]
    assert np.median(late) < 0.5 * np.median(early)
    # Frames merge exactly within the components of the merging-group graph (thesis case 3):
    # robots' final frames are as many as the components their roots lie in.
    groups = nx.Graph()
    keys = {r.own_key: i for i, r in enumerate(sim.robots) if r.is_seed}
    groups.add_nodes_from(keys.values())
    for r in sim.robots:
        for a, b in r.groups:
            if a in keys and b in keys:
                groups.add_edge(keys[a], keys[b])
    component = {i: k for k, c in enumerate(nx.connected_components(groups)) for i in c}
    roots = {o.root for o in (r.outcome() for r in sim.robots) if o.root is not None}
    assert frames == len(roots) == len({component[keys[root.key]] for root in roots})


def test_robot_and_merging_state_sit_in_slots():
    """GcsRobot and FrameMerging keep every attribute in __slots__ (more than 30 attributes in
    an instance dict cost measurable time at 1,000 robots): an attribute added without its
    slot lands in the instance dict and fails here (SeedRounds has no dict at all)."""
    result = run(40, "merge")
    for robot in result.sim.robots:
        assert vars(robot) == {}
        assert type(robot.phase).__name__ == "FrameMerging"
        assert vars(robot.phase) == {}
        assert (robot.phase.seed is not None) == robot.is_seed


def test_an_isolated_seeds_root_ranks_last_so_it_wins_no_robot_of_a_merged_frame():
    """Without occlusion the thesis's reference rule leaves isolated seeds on a 40-robot lattice
    (docs/gcs.md, "On the robot model"). Their roots rank last, as edge seeds' do: a robot whose
    frames include one that can merge never takes an isolated seed's root (before, the smaller
    key won, and an isolated seed's references left the merged frame with it)."""
    from kilonet import Simulation
    from kilonet.scenarios.base import build_params, place

    # Seed 4: isolated seeds with smaller keys than the frames their references share.
    params = build_params(GCS, {"placement.robots": 40}, seed=4)
    positions = place(GCS, params, None)
    sim = Simulation(positions, GCS.setup.program(params, positions), params)
    sim.run(phase_windows_s(params.scenario)[-1][1] + 10.0)  # 10 s into merging
    isolated = {r.own_key for r in sim.robots if r.is_seed and not r.partners}
    assert len(isolated) >= 3
    for r in sim.robots:
        if r.is_seed and r.own_key in isolated:
            assert r.phase.seed.rank.root.edge and r.merge_done
    taken = 0
    for r in sim.robots:
        held = [
            k for k in r.estimate.frames if k in r.estimate.ranks and k in r.estimate.transforms
        ]
        if any(k in isolated for k in held) and not all(k in isolated for k in held):
            taken += 1
            assert r.estimate.root().key not in isolated
    assert taken >= 3  # robots in an isolated frame and a merged one: the case was exercised


def test_a_partner_that_never_answers_stops_holding_up_done():
    """A seed crashes just before merging, so no member ever holds its transform: rounds
    about it time out, and after gcs.merge_silent_rounds of them its partners are done
    without it (before, they ran rounds until gcs.merge_max_rounds and the run never ended)."""
    from kilonet import Simulation
    from kilonet.scenarios.base import build_params, place

    # The thesis's premise (bodies block links) keeps every other seed's partners answering.
    settings = {"placement.robots": 40, "gcs.merge_max_rounds": 300, "medium.occlusion": "block"}
    params = build_params(GCS, settings, seed=1)
    positions = place(GCS, params, None)
    sim = Simulation(positions, GCS.setup.program(params, positions), params)
    merge_start = phase_windows_s(params.scenario)[-1][1]
    sim.run(merge_start - 0.5)
    seeds = [i for i, r in enumerate(sim.robots) if r.is_seed]
    crashed = max(seeds, key=lambda i: len(sim.robots[i].partners))
    crashed_key = sim.robots[crashed].own_key
    waiting = [i for i in seeds if crashed_key in sim.robots[i].partners]
    assert waiting
    sim.faults.crash_at(crashed, merge_start - 0.4)
    sim.run(merge_start + 600.0, stop_when=lambda: GCS.setup.stop_when(sim))
    assert sim.env.now < merge_start + 600.0  # the swarm ended merging by itself
    events = sim.trace.events_frame()
    silent = events[events.event == "merge_partner_silent"]
    about = [json.loads(d)["partner"] == crashed_key.uid for d in silent.data]
    # Every seed that waited for it gave up on it (others registered it late: clocks drift, so
    # robots close phase 5 at slightly different times).
    assert set(waiting) <= set(silent.robot[about])
    done = events[events.event == "merge_done"]
    assert {json.loads(d)["how"] for d in done.data} == {"agreed"}
    assert all(sim.robots[i].merge_done for i in seeds if i != crashed)


def test_a_done_seed_that_uses_up_its_rounds_stays_done_and_is_not_reported_as_giving_up():
    # Done seeds keep running rounds (a better root may still come); at gcs.merge_max_rounds
    # they stop. Before, they logged merge_done how="gave_up" there although they had agreed.
    result = run(40, "merge", **{"gcs.merge_max_rounds": 20})
    events = result.sim.trace.events_frame()
    outcomes = events[events.event.isin(["merge_done", "merge_resumed"])]
    last: dict[int, str] = {}
    for row in outcomes.itertuples():
        how = json.loads(row.data).get("how", "resumed")
        assert not (how == "gave_up" and last.get(row.robot) == "agreed"), row.robot
        last[row.robot] = how
    seeds = [r for r in result.sim.robots if r.is_seed]
    capped = [r for r in seeds if r.phase.seed.rounds >= 20]
    # Some seeds reached the cap: the case was exercised (on the real medium's neighbourhood,
    # gcs.neighbour_max_mm, most seeds agree within fewer rounds; two of 15 reach 20 here).
    assert len(capped) >= 2
    assert all(r.phase.seed.final and r.merge_done for r in capped)


@pytest.mark.parametrize(
    ("robots", "loss"),
    [
        pytest.param(100, 0.0, marks=pytest.mark.slow),
        pytest.param(100, 0.2, marks=pytest.mark.slow),
        # The default tier's twin takes the harder case, with loss (without loss, 40 robots
        # merge in test_merge_small_swarm_ends_by_itself_in_one_frame_per_group_component).
        (40, 0.2),
    ],
)
def test_merge_into_one_frame(robots, loss):
    overrides = {"medium.loss_prob": loss, **WELL_CONDITIONED}
    if loss:
        overrides.update({"gcs.frames_s": 90, "gcs.localization_s": 40})
    result = run(robots, "merge", **overrides)
    frames, localized, rmse = _merged(result)
    assert frames == 1
    assert localized >= 0.95
    # Against the centralized optimum on the same receptions: chaining local frames through
    # half-map steps compounds each link's systematic error, which the optimum spreads over the
    # whole graph. Measured rmse / central_rmse_mm on 100 robots: 4.95, 4.75, 5.73, 6.12
    # (seeds 1-4) and 5.01, 6.92, 6.49 (seeds 1-3, 20 % loss); 8 sits above the worst seed
    # (40 robots with loss, seed 1: 2.36).
    assert rmse <= 8.0 * result.summary["central_rmse_mm"]


@functools.cache
def merged(robots: int):
    """The merge run of this many robots, once per session (300 robots take 4 minutes on a
    loaded machine), shared by the tests below."""
    return run(robots, "merge", **WELL_CONDITIONED)


@pytest.mark.parametrize("robots", [pytest.param(300, marks=pytest.mark.slow), 40])
def test_merge_floods_one_root_without_a_needless_recovery(robots):
    """Before members hinted their seeds of better-ranked partners, frames settled on local
    roots while the global root was still flooding; their boundary looked like a split and set
    off a recovery epoch (150 simulated s lost) although the swarm ended in one frame.

    That happened on 300 robots (slow); the default tier's 40 robots make the same assertions
    (hints sent, one frame, no recovery) on a swarm whose root floods it quickly."""
    result = merged(robots)
    frames, localized, _ = _merged(result)
    assert (frames, result.summary["recoveries"]) == (1, 0)
    assert localized >= 0.95
    events = result.sim.trace.events_frame()
    assert (events.event == "merge_hint").any()


@pytest.mark.xfail(
    strict=True,
    reason="on the issue-29 medium the 300-robot merge ends 49.1 mm rms from the truth against "
    "a central optimum of 1.64 mm (local frames 3.0 mm; the fold rule splits 30 robots off): "
    "suspected, each link's systematic error compounding along the chain of half-map merges "
    "across the swarm",
)
def test_merge_300_robots_ends_near_the_central_optimum():
    # The same bound as the 100-robot merge's (8 x the centralized optimum). Not slow although
    # it takes about 110 s of CPU: smaller swarms hold the bound (150 robots 6.4, 3.4, 4.2 and
    # 7.4 x the optimum on seeds 1-4, 200 robots 3.0 x), so no smaller run can twin it.
    result = merged(300)
    assert result.summary["rmse_mm"] <= 8.0 * result.summary["central_rmse_mm"]


def test_failures_section_names_the_lone_robot_and_its_isolated_frame():
    from kilonet.scenarios.placement import hex_lattice

    swarm = hex_lattice(19, spacing_mm=40.0)
    positions = np.vstack([swarm, [[500.0, 0.0]]])  # robot 19 hears nobody
    result = scenarios.run(GCS, {"gcs.until": "groups"}, placement=positions)
    failures = result.summary["failures"]
    assert 19 in failures["unlocalizable"]
    assert 19 in failures["isolated_seeds"]
    assert [19] in failures["frame_components"]  # the lone seed's frame is a component
    # ... but no robot is located in it alone (not even the seed, which has no frame), so it
    # splits no global frame: the thesis's case 2, not case 3
    # (kilonet.scenarios.gcs.own_components).
    assert failures["split_frames"] == 0
    assert 19 in failures["robots_with_fewer_than_3_neighbours"]


def test_analyze_predicts_the_lone_robot_before_a_full_run(tmp_path, capsys):
    from kilonet.app.cli import main
    from kilonet.placement import save_csv
    from kilonet.scenarios.placement import hex_lattice

    placement = tmp_path / "swarm.csv"
    save_csv(np.vstack([hex_lattice(19, spacing_mm=40.0), [[500.0, 0.0]]]), placement)
    assert main(["analyze", str(placement), "--json", "--out", str(tmp_path / "a.png")]) == 0
    report = json.loads(capsys.readouterr().out)
    # The lone robot, whatever else: on a perfect lattice a seed's neighbours on opposite sides
    # are exactly collinear with it, so whether it takes such a pair (and holds a frame of three)
    # is left to sub-millimetre differences between the robots' estimates.
    assert 19 in report["unlocalizable"] and len(report["unlocalizable"]) <= 3
    assert 19 in report["isolated_seeds"]
    assert [len(c) for c in report["frames"]][-1] == 1 and report["split"]
    assert (tmp_path / "a.png").stat().st_size > 1000


def test_a_phase_class_without_a_window_is_refused_when_it_is_defined():
    from kilonet.protocols.gcs.base import Phase

    with pytest.raises(TypeError, match="phase Unbounded must define window_s"):

        class Unbounded(Phase):
            name = "unbounded"
