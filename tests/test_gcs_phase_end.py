"""When a gcs phase is over (issue 44): the rules that let merging end once its work is done.

A done seed keeps stepping toward its parent; ``gcs.merge_resume`` decides only when it drops
its done mark. Under ``"drift"`` two parent answers in a row beyond the tolerance do it, so a
seed whose members disagree by about the tolerance resumes every few rounds and the run, which
waits for every seed to be done at once, waits for hundreds of rounds; under ``"far"`` (the
default) only a better rank or two answers in a row beyond a whole step do.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kilonet import scenarios
from kilonet.protocols.gcs.merging_rules import (
    RESUME_AFTER_DISAGREEMENTS,
    beyond_resume,
    resumes,
)
from kilonet.protocols.gcs.phase6_merging import FrameMerging

KW = dict(tolerance_mm=4.0, whole_step_mm=16.0)


@pytest.mark.parametrize(
    ("error_mm", "drift", "far"),
    [(0.0, False, False), (4.0, False, False), (4.5, True, False), (16.0, True, False),
     (16.5, True, True)],
)  # fmt: skip
def test_which_parent_answers_count_toward_resuming(error_mm, drift, far):
    assert beyond_resume(error_mm, rule="drift", **KW) is drift
    assert beyond_resume(error_mm, rule="far", **KW) is far


def _resumes(rule: str, **kw) -> bool:
    base = dict(done=True, agreed=False, new_rank=False, error_mm=6.0, whole_step_mm=16.0)
    return resumes(**{**base, **kw}, rule=rule)


@pytest.mark.parametrize("rule", ["far", "drift"])
def test_either_rule_resumes_on_a_better_rank_and_never_a_seed_not_done(rule):
    assert _resumes(rule, new_rank=True, disagreed_in_row=0)
    assert not _resumes(rule, done=False, new_rank=True, disagreed_in_row=5)
    assert not _resumes(rule, agreed=True, disagreed_in_row=0)


def test_far_resumes_only_on_answers_in_a_row_it_counted():
    # Under "far" the caller counts only answers beyond a whole step (beyond_resume).
    assert not _resumes("far", error_mm=40.0, disagreed_in_row=RESUME_AFTER_DISAGREEMENTS - 1)
    assert _resumes("far", error_mm=40.0, disagreed_in_row=RESUME_AFTER_DISAGREEMENTS)


def test_drift_resumes_on_one_far_answer_or_disagreements_in_a_row():
    assert _resumes("drift", error_mm=16.5, disagreed_in_row=1)
    assert not _resumes("drift", error_mm=6.0, disagreed_in_row=RESUME_AFTER_DISAGREEMENTS - 1)
    assert _resumes("drift", error_mm=6.0, disagreed_in_row=RESUME_AFTER_DISAGREEMENTS)


@pytest.fixture(scope="module")
def done_seeds():
    """The seeds of a 40-robot run merged to the end that are done, run rounds and follow a
    parent: each test below takes its own (it changes the seed's state)."""
    result = scenarios.run(scenarios.get("gcs"), {"placement.robots": 40}, seed=2)
    assert result.summary["seeds_done"] == result.summary["seeds"]
    found = []
    for robot in result.sim.robots:
        phase = robot.phase
        seed = phase.seed if isinstance(phase, FrameMerging) else None
        if seed is not None and seed.done and not seed.final and seed._parent() is not None:
            found.append(seed)
    assert len(found) >= 4
    return found


@pytest.mark.parametrize(
    ("which", "rule", "error_mm", "done_after"),
    [(0, "far", 6.0, [True, True]), (1, "far", 17.0, [True, False]),
     (2, "drift", 6.0, [True, False]), (3, "drift", 17.0, [False, False])],
)  # fmt: skip
def test_a_done_seed_drops_its_mark_as_its_rule_says(done_seeds, which, rule, error_mm, done_after):
    seed = done_seeds[which]
    seed.params = dataclasses.replace(seed.params, merge_resume=rule)
    parent = seed._parent()
    rank = seed.partner_ranks[parent]
    member = min(seed.robot.partners[parent])
    seed.disagreed = 0
    after = []
    for _ in done_after:
        seed.asking = (member, parent)
        seed._apply(Rotation.identity(), np.zeros(3), error_mm, rank)
        after.append(seed.done)
        assert seed.robot.merge_done is seed.done
    assert after == done_after
