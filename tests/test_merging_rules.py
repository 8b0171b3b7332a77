"""Phase 6's decision rules (kilonet.protocols.gcs.merging_rules), each on its own, with exact
values."""

from __future__ import annotations

import pytest

from kilonet.protocols.gcs.frame_keys import MAX_HOPS, FrameKey, Rank, Root
from kilonet.protocols.gcs.merging_rules import (
    all_partners_heard,
    answer_agrees,
    cuts_round,
    half_steps,
    hint_due,
    hint_is_news,
    next_partner,
    parent,
    rank_toward,
    resumes,
    round_end,
    seed_message,
)

A, B, C, D = FrameKey(2, 7), FrameKey(4, 1), FrameKey(4, 9), FrameKey(9, 0)


def rank(uid: int, h: int = 0, *, salt: int = 0, edge: bool = False) -> Rank:
    return Rank(Root(edge, FrameKey(uid, salt)), h)


# -- which parent ----------------------------------------------------------------------------
def test_parent_is_the_best_ranked_partner_better_than_the_seed():
    ranks = {A: rank(1, 3), B: rank(1, 2), C: rank(3, 0)}
    assert parent(ranks, rank(5)) == B
    assert parent(ranks, rank(1, 2)) is None  # nobody is better than the seed itself
    assert parent(ranks, rank(1, 3)) == B


def test_parent_ties_go_to_the_smaller_frame_key():
    assert parent({C: rank(1, 1), B: rank(1, 1), D: rank(1, 1)}, rank(5)) == B


def test_parent_prefers_any_elected_root_to_an_edge_root():
    assert parent({A: rank(9, 40), B: rank(1, 0, edge=True)}, rank(20)) == A
    assert parent({}, rank(20)) is None


# -- stepping --------------------------------------------------------------------------------
def test_answers_about_other_partners_always_agree():
    assert answer_agrees(False, 1e6, 4.0)
    assert answer_agrees(True, 4.0, 4.0)
    assert not answer_agrees(True, 4.000001, 4.0)


@pytest.mark.parametrize(("error_mm", "steps"), [(0.0, 1), (16.0, 1), (16.01, 2), (500.0, 2)])
def test_whole_step_beyond_the_threshold(error_mm, steps):
    assert half_steps(error_mm, 16.0) == steps


def test_a_whole_step_threshold_of_128_never_takes_one():
    # ANS_ERROR's field saturates at 127.5 mm
    assert half_steps(127.5, 128.0) == 1


def test_rank_toward_takes_the_parents_rank_one_hop_further_if_better():
    assert rank_toward(rank(5), rank(1, 3)) == rank(1, 4)
    assert rank_toward(rank(1, 4), rank(1, 3)) is None  # the same rank: nothing new
    assert rank_toward(rank(1, 2), rank(1, 3)) is None  # the seed is nearer the root already
    assert rank_toward(rank(1, 9), rank(1, 3)) == rank(1, 4)  # a shorter way to the same root
    assert rank_toward(rank(3, 0, edge=True), rank(9, 3)) == rank(9, 4)


def test_rank_toward_refuses_hops_beyond_their_byte():
    assert rank_toward(rank(5), rank(1, MAX_HOPS)) is None
    assert rank_toward(rank(5), rank(1, MAX_HOPS - 1)) == rank(1, MAX_HOPS)


# -- done, resumed, given up -----------------------------------------------------------------
def _resumes(**kw):
    base = dict(
        done=True,
        agreed=False,
        new_rank=False,
        error_mm=5.0,
        whole_step_mm=16.0,
        disagreed_in_row=1,
    )
    return resumes(**{**base, **kw})


def test_one_stray_answer_does_not_resume_a_done_seed():
    assert not _resumes()


@pytest.mark.parametrize(
    "change",
    [{"new_rank": True}, {"error_mm": 16.5}, {"disagreed_in_row": 2}, {"disagreed_in_row": 5}],
)
def test_a_new_rank_a_far_parent_or_two_disagreements_resume_it(change):
    assert _resumes(**change)


@pytest.mark.parametrize("change", [{"done": False}, {"agreed": True, "new_rank": True}])
def test_only_a_done_seed_with_a_disagreeing_answer_resumes(change):
    assert not _resumes(**change, error_mm=40.0)


def test_silent_partners_stop_holding_up_done_after_their_rounds():
    partners = [A, B, C]
    assert not all_partners_heard(partners, {A: 1}, {B: 3, C: 2}, 3)
    assert all_partners_heard(partners, {A: 1}, {B: 3, C: 4}, 3)
    assert all_partners_heard(partners, {A: 1, B: 1, C: 1}, {}, 3)
    assert all_partners_heard([], {}, {}, 3)  # an isolated seed has no one to wait for


def _end(**kw):
    base = dict(done=False, heard_all=True, stable=4, stable_rounds=4, rounds=10, max_rounds=400)
    return round_end(**{**base, **kw})


def test_round_end():
    assert _end() == "agreed"
    assert _end(stable=3) is None
    assert _end(heard_all=False) is None
    assert _end(done=True) is None  # done already: rounds go on, watching for a better root
    assert _end(stable=3, rounds=400) == "gave_up"
    assert _end(rounds=400) == "agreed"  # agreeing on the last round counts as agreeing
    assert _end(done=True, rounds=400) == "stop"
    assert _end(done=True, rounds=401) == "stop"


# -- partners, hints -------------------------------------------------------------------------
def test_next_partner_alternates_the_parent_with_each_partner_in_turn():
    partners = [A, B, C, D]
    assert [next_partner(partners, D, t) for t in range(1, 9)] == [A, D, B, D, C, D, D, D]
    assert [next_partner(partners, None, t) for t in range(1, 9)] == [A, B, B, C, C, D, D, A]


def test_a_hint_about_a_partner_known_to_rank_better_is_no_news():
    own = rank(5, 2)
    assert hint_is_news(A, {}, own)
    assert hint_is_news(A, {A: rank(5, 2)}, own)  # as good as the seed: the hint may be newer
    assert hint_is_news(A, {A: rank(7)}, own)
    assert not hint_is_news(A, {A: rank(5, 1)}, own)


def test_a_member_hints_when_the_partner_one_hop_further_still_ranks_better():
    assert hint_due(rank(5), rank(1, 3))
    assert hint_due(rank(1, 5), rank(1, 3))
    assert not hint_due(rank(1, 4), rank(1, 3))  # the seed follows that partner already
    assert not hint_due(rank(1, 3), rank(1, 3))
    assert not hint_due(rank(1), rank(5))
    assert not hint_due(None, rank(1)) and not hint_due(rank(1), None)
    assert hint_due(rank(2, edge=True), rank(9, 30))


def test_a_hint_cuts_a_running_round_about_another_partner_unless_hinted_itself():
    assert cuts_round(False, A, B)
    assert not cuts_round(False, B, B)
    assert not cuts_round(True, A, B)
    assert not cuts_round(False, None, B)


# -- what a seed sends -----------------------------------------------------------------------
def test_seed_messages_in_turn():
    idle = dict(rank_due=False, halves_due=False, querying=False, query_due=False)
    assert [seed_message(t, **idle) for t in range(1, 11)] == [
        "rank",
        "rotation",
        "shift",
        "rotation",
        "shift",
        "rank",
        "shift",
        "rotation",
        "shift",
        "rotation",
    ]
    asking = {**idle, "querying": True}
    assert [seed_message(t, **asking) for t in range(1, 8)] == [
        "rank",
        "rotation",
        "query",
        "rotation",
        "shift",
        "rank",
        "shift",
    ]
    assert seed_message(2, **{**asking, "query_due": True}) == "query"
    assert seed_message(2, **{**asking, "query_due": True, "halves_due": True}) == "half"
    assert seed_message(2, **{**asking, "halves_due": True, "rank_due": True}) == "rank"
