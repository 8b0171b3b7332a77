"""The composed GCS program's seams: message layouts (sender first), the phase sequence, the
smaller phase rules and the per-robot outcome a run is reported from."""

from __future__ import annotations

import math
import typing

import pytest

from kilonet import scenarios
from kilonet.message import PayloadError
from kilonet.protocols.common.layouts import discover
from kilonet.protocols.common.neighbours import NeighbourTable
from kilonet.protocols.gcs.base import LAYOUTS as GCS_LAYOUTS
from kilonet.protocols.gcs.base import PHASES, GcsParams, GcsStage, Phase, gcs_layout, sender_of
from kilonet.protocols.gcs.phase1_unique_ids import is_duplicate
from kilonet.protocols.gcs.phase2_seed_election import seed_condition_met
from kilonet.protocols.gcs.phase4_localization import fix_anchors, worth_a_fix
from kilonet.protocols.gcs.program import (
    OPEN_ENDED,
    PHASE_SEQUENCE,
    RECOVERY_SEQUENCE,
    GcsRobot,
    led_colour,
    phase_windows_s,
)
from kilonet.protocols.gcs.recovery import adopts_epoch
from kilonet.protocols.gcs.split_detection import distance_mismatch_mm
from kilonet.scenarios.gcs import estimates_frame, run_outcomes

#: Every layout of the protocol, as its modules register them (phase 7's GPOS types and the
#: refinement's DIST included).
LAYOUTS = list(GCS_LAYOUTS)


def test_every_layout_starts_with_the_sender_and_sender_of_reads_it():
    assert list(discover("kilonet.protocols.gcs")) == LAYOUTS  # nothing built outside gcs_layout
    assert len({layout.type for layout in LAYOUTS}) == len(LAYOUTS)
    for layout in LAYOUTS:
        names = layout.record._fields
        assert names[0] == "sender" and "sender" not in names[1:], layout.name
        message = layout.pack(sender=40_000, **dict.fromkeys(names[1:], 0))
        assert sender_of(message) == 40_000, layout.name
        assert len(message.data) <= 9


def test_gcs_layout_refuses_fields_beyond_the_payload():
    with pytest.raises(PayloadError, match="needs 10 bytes"):
        gcs_layout("big", type=99, fields=[("a", "I"), ("b", "I")])


# -- phases ----------------------------------------------------------------------------------
def test_the_phase_sequence_is_the_named_phases_and_gcs_until_offers_them():
    assert tuple(cls.name for cls in PHASE_SEQUENCE) == PHASES
    until = typing.get_type_hints(GcsParams)["until"]
    assert typing.get_args(until) == PHASES
    for cls in {*PHASE_SEQUENCE, *RECOVERY_SEQUENCE}:
        assert "window_s" in vars(cls) or callable(cls.window_s), cls.name
    assert not hasattr(Phase, "window_s")  # each phase defines its own (checked at definition)


def test_open_ended_phases_are_declared_and_have_no_window_end():
    """A phase that ends by itself says so (``open_ended``): the program's ``OPEN_ENDED`` and
    the gcs scenario's stop rule read that declaration."""
    p = GcsParams(refine=True)
    declared = {cls.name for cls in {*PHASE_SEQUENCE, *RECOVERY_SEQUENCE} if cls.open_ended}
    assert declared == OPEN_ENDED == {GcsStage.MERGE, GcsStage.REFINE}
    for cls in {*PHASE_SEQUENCE, *RECOVERY_SEQUENCE}:  # a closed phase's window closes
        assert math.isfinite(cls.window_s(p)) or cls.open_ended, cls.name
    # From the first open-ended phase on, no window has a known end.
    windows = phase_windows_s(p)
    first = next(k for k, (name, _, _) in enumerate(windows) if name in OPEN_ENDED)
    assert all(math.isinf(end) for _, _, end in windows[first:])
    assert all(math.isfinite(end) for _, _, end in windows[:first])
    assert [s.number for s in GcsStage] == list(range(1, len(PHASES) + 1))


def test_phase_windows_come_from_each_phase():
    p = GcsParams(ids_s=4, elect_s=1, check_s=0.5, reelections=0, frames_s=10, localization_s=6)
    assert phase_windows_s(p) == [
        ("ids", 0.0, 4.0),
        ("seeds", 4.0, 6.5),
        ("frames", 6.5, 16.5),
        ("localization", 16.5, 22.5),
        ("groups", 22.5, 25.5),
        ("merge", 25.5, math.inf),
    ]
    assert [cls.window_s(p) for cls in RECOVERY_SEQUENCE] == [1, 10, 6, 3, math.inf]


# -- smaller rules ---------------------------------------------------------------------------
def test_duplicate_id_rule():
    assert is_duplicate(7, 8, 40.0, 9, 40.0, 12.0)  # another salt
    assert is_duplicate(7, 7, 40.0, 2, 52.5, 12.0)  # the thesis's distance rule
    assert not is_duplicate(7, 7, 40.0, 2, 52.0, 12.0)
    assert not is_duplicate(7, 7, 40.0, 1, 90.0, 12.0)  # one reading is not a mean yet
    assert not is_duplicate(7, 7, None, 0, 90.0, 12.0)


def test_seed_condition():
    assert [seed_condition_met(n, is_seed=False) for n in (0, 1, 2, 3)] == [
        False,
        False,
        True,
        True,
    ]
    assert [seed_condition_met(n, is_seed=True) for n in (0, 1, 2)] == [False, True, True]


def test_fix_anchors_and_when_to_try_a_fix():
    table = NeighbourTable()
    for uid, d in ((1, 40), (2, 42), (3, 39)):
        table.heard(uid, d)
    anchors, ranges = fix_anchors(1, {3: (1.0, 2.0), 1: (9.0, 9.0), 2: (3.0, 4.0)}, table)
    assert anchors == [(0.0, 0.0), (1.0, 2.0), (3.0, 4.0)]  # the seed's own entry is skipped
    assert ranges == [40.0, 39.0, 42.0]
    assert [worth_a_fix(n, 0) for n in (2, 3)] == [False, True]
    assert [worth_a_fix(n, 3) for n in (3, 4)] == [False, True]


def test_recovery_epoch_adoption():
    kw = dict(own_epoch=1, now_tick=100)
    assert adopts_epoch(2, 500, own_start_tick=300, **kw)  # newer
    assert not adopts_epoch(2, 100, own_start_tick=None, **kw)  # its start is past
    assert not adopts_epoch(1, 500, own_start_tick=None, **kw)  # started already
    assert adopts_epoch(1, 299, own_start_tick=300, **kw)
    assert not adopts_epoch(0, 900, own_start_tick=None, **kw)


def test_distance_mismatch():
    assert distance_mismatch_mm((1.0, 1.0), (4.0, 5.0), 5.0) == 0.0
    assert distance_mismatch_mm((0.0, 0.0), (0.0, 30.0), 40.0) == 10.0


def test_led_colours():
    kw = dict(seed=False, merged=False, located=False, reference=False)
    assert led_colour("merge", **{**kw, "seed": True, "merged": True}) == (3, 0, 0)
    assert led_colour("", **kw) == led_colour("ids", **kw) == (1, 1, 1)
    assert led_colour("seeds", **{**kw, "merged": True}) == (0, 0, 2)
    assert led_colour("merge", **{**kw, "merged": True, "located": True}) == (0, 3, 3)
    assert led_colour("groups", **{**kw, "located": True, "reference": True}) == (0, 3, 0)
    assert led_colour("frames", **{**kw, "reference": True}) == (3, 3, 0)
    assert led_colour("frames", **kw) == (0, 0, 1)


# -- the outcome a run is reported from ------------------------------------------------------
def test_outcomes_are_read_once_and_agree_with_the_robots():
    result = scenarios.run(scenarios.get("gcs"), {"placement.robots": 40}, seed=2)
    sim = result.sim
    outcomes = run_outcomes(sim)
    assert run_outcomes(sim) is outcomes  # the summary, robots.csv and the figure share it
    assert estimates_frame(sim) is outcomes.estimates
    for robot, o in zip(sim.robots, outcomes.robots, strict=True):
        assert isinstance(robot, GcsRobot)
        assert (o.uid, o.is_seed, o.own_key) == (robot.uid, robot.is_seed, robot.own_key)
        # The merged estimate, or what the fold rule made of it (gcs.fold).
        assert (o.position, o.root) == robot.check.held()
        if robot.check.fold is None:
            assert (o.position, o.root) == (robot.estimate.position(), robot.estimate.root())
        assert dict(o.local_positions) == dict(robot.estimate.frames)
        assert o.merge_rounds == (robot.phase.seed.rounds if robot.is_seed else 0)
    seeds = [o for o in outcomes.robots if o.is_seed]
    assert result.summary["seeds_done"] == sum(o.merge_done for o in seeds) == len(seeds)
    assert result.summary["merge_rounds_max_per_seed"] == max(o.merge_rounds for o in seeds)
    labels = {f"root{o.root.number}" for o in outcomes.robots if o.root is not None}
    assert labels == set(outcomes.estimates.frame[outcomes.estimates.localized])
    assert result.summary["frames"] == len(labels)
    sim.run(sim.env.now + 1.0)  # the run goes on: a new read
    assert run_outcomes(sim) is not outcomes
