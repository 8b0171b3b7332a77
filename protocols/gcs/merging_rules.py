"""The decisions of phase 6 (frame merging), as pure functions of what a robot knows.

:mod:`kilonet.protocols.gcs.phase6_merging` runs the rounds and the messages; every choice it makes
on the way is one of these functions, so each can be read and tested on its own. Ranks and frame
keys are :mod:`kilonet.protocols.gcs.frame_keys` values; smaller ranks are better. The design is
explained in ``docs/gcs.md`` ("Merging").

A seed's round, in the order the rules apply: pick a partner (:func:`next_partner`, or a
hinted one if :func:`hint_is_news`); when the answer comes, step only toward the parent
(:func:`parent`), a whole step when far off (:func:`half_steps`), taking the parent's rank one
hop further (:func:`rank_toward`); judge the answer (:func:`answer_agrees`); resume if done and
the parent moved away (:func:`resumes`, counting answers with :func:`beyond_resume`); end the
round as done, given up, stopped or running (:func:`round_end`, counting silent partners with
:func:`all_partners_heard`). A member hints a seed when its partner ranks better than the seed
could know (:func:`hint_due`).
"""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping, Sequence
from typing import Literal

from kilonet.protocols.gcs.frame_keys import MAX_HOPS, FrameKey, Rank

__all__ = [
    "all_partners_heard",
    "answer_agrees",
    "beyond_resume",
    "cuts_round",
    "half_steps",
    "hint_due",
    "hint_is_news",
    "next_partner",
    "parent",
    "rank_toward",
    "resumes",
    "round_end",
    "seed_message",
]

#: Parent answers in a row beyond the tolerance that make a done seed resume.
RESUME_AFTER_DISAGREEMENTS = 2


def parent(partner_ranks: Mapping[FrameKey, Rank], own: Rank) -> FrameKey | None:
    """The partner a seed follows: the best rank it has heard of among its partners, ties
    going to the smaller frame key; ``None`` while no partner ranks better than ``own``.

    One parent, not every better-ranked partner: two partners one hop nearer the root reach it
    along different chains and differ by those chains' errors, and a seed that stepped toward
    both would swing between them.

    Examples
    --------
    >>> a, b, c = FrameKey(4, 0), FrameKey(6, 0), FrameKey(9, 0)
    >>> root = Rank.own(FrameKey(1, 0), edge=False)
    >>> ranks = {a: root.one_hop_further(), b: root, c: root}
    >>> parent(ranks, Rank.own(FrameKey(5, 0), edge=False))
    FrameKey(uid=6, salt=0)
    >>> parent(ranks, root) is None
    True
    """
    better = [(rank, key) for key, rank in partner_ranks.items() if rank < own]
    return min(better)[1] if better else None


def answer_agrees(follows: bool, error_mm: float, tolerance_mm: float) -> bool:
    """Whether an answer counts as agreement: it is about a partner the seed does not follow
    (their disagreement is not this seed's to remove), or the parent disagrees by at most
    ``tolerance_mm``.

    Examples
    --------
    >>> [answer_agrees(f, e, 4.0) for f, e in [(False, 50.0), (True, 4.0), (True, 4.1)]]
    [True, True, False]
    """
    return not follows or error_mm <= tolerance_mm


def half_steps(error_mm: float, whole_step_mm: float) -> int:
    """How many times the answer's half step is applied toward the parent: twice (the whole
    step) when the parent disagrees by more than ``whole_step_mm``, else once. Near the parent,
    half steps average the answers' noise away; far off, they would only halve the distance
    round after round.

    Examples
    --------
    >>> half_steps(16.5, 16.0), half_steps(16.0, 16.0)
    (2, 1)
    """
    return 2 if error_mm > whole_step_mm else 1


def rank_toward(own: Rank, parent_rank: Rank) -> Rank | None:
    """The rank a seed takes when it steps toward a parent of ``parent_rank``: one hop further
    than the parent, if that is better than ``own`` and the hops still fit their byte;
    ``None`` to keep ``own``.

    Examples
    --------
    >>> root = Rank.own(FrameKey(1, 0), edge=False)
    >>> rank_toward(Rank.own(FrameKey(5, 0), edge=False), root)
    Rank(root=Root(edge=False, key=FrameKey(uid=1, salt=0)), hops=1)
    >>> rank_toward(root.one_hop_further(), root) is None  # it has that rank already
    True
    """
    if parent_rank.hops >= MAX_HOPS:
        return None
    further = parent_rank.one_hop_further()
    return further if further < own else None


def beyond_resume(
    error_mm: float, *, rule: Literal["far", "drift"], tolerance_mm: float, whole_step_mm: float
) -> bool:
    """Whether a parent's answer counts toward resuming a done seed (:func:`resumes` counts
    them in a row): beyond ``whole_step_mm`` under rule ``"far"``, beyond ``tolerance_mm``
    (it does not agree) under ``"drift"``.

    Examples
    --------
    >>> kw = dict(tolerance_mm=4.0, whole_step_mm=16.0)
    >>> [beyond_resume(e, rule="drift", **kw) for e in (4.0, 6.0, 17.0)]
    [False, True, True]
    >>> [beyond_resume(e, rule="far", **kw) for e in (4.0, 6.0, 17.0)]
    [False, False, True]
    """
    return error_mm > (whole_step_mm if rule == "far" else tolerance_mm)


def resumes(
    *,
    done: bool,
    agreed: bool,
    new_rank: bool,
    error_mm: float,
    whole_step_mm: float,
    disagreed_in_row: int,
    rule: Literal["far", "drift"] = "drift",
) -> bool:
    """Whether a seed that was done goes back to merging after an answer that did not agree.

    Either rule resumes on a better rank (``new_rank``: a root is flooding the swarm) and on
    :data:`RESUME_AFTER_DISAGREEMENTS` parent answers in a row that :func:`beyond_resume`
    counts (``disagreed_in_row``). Rule ``"drift"`` counts every answer beyond the tolerance
    and also resumes on a single parent more than ``whole_step_mm`` off; rule ``"far"``
    counts only answers beyond ``whole_step_mm`` and never resumes on one. One stray answer
    does not resume a seed: answers about one parent differ by a few mm with the member asked,
    and resuming on each would send waves of resumes down the tree of frames. Under
    ``"drift"``, a seed whose members disagree by about the tolerance still resumes every few
    rounds (the run waits for every seed to be done at once); under ``"far"`` it keeps its done
    mark while it goes on stepping toward its parent, and resumes only when the parent has
    moved by more than a whole step.

    Examples
    --------
    >>> kw = dict(done=True, agreed=False, new_rank=False, whole_step_mm=16.0)
    >>> [resumes(**kw, error_mm=6.0, disagreed_in_row=n) for n in (1, 2)]
    [False, True]
    >>> resumes(**kw, error_mm=17.0, disagreed_in_row=1)
    True
    >>> [resumes(**kw, error_mm=17.0, disagreed_in_row=n, rule="far") for n in (1, 2)]
    [False, True]
    """
    if not done or agreed:
        return False
    again = disagreed_in_row >= RESUME_AFTER_DISAGREEMENTS
    if rule == "far":
        return new_rank or again
    return new_rank or error_mm > whole_step_mm or again


def all_partners_heard(
    partners: Iterable[FrameKey],
    answered: Collection[FrameKey],
    unanswered: Mapping[FrameKey, int],
    silent_rounds: int,
) -> bool:
    """Whether every partner has answered at least once, or stopped counting (the silent-
    partner rule): a partner whose rounds timed out ``silent_rounds`` times without a single
    answer no longer holds up "done". A member located in both frames need not hear the
    partner's seed, so it may never hold the transform it would answer with; or the partner's
    seed crashed.

    Examples
    --------
    >>> a, b = FrameKey(4, 0), FrameKey(6, 0)
    >>> all_partners_heard([a, b], {a}, {b: 2}, 3), all_partners_heard([a, b], {a}, {b: 3}, 3)
    (False, True)
    """
    return all(k in answered or unanswered.get(k, 0) >= silent_rounds for k in partners)


def round_end(
    *,
    done: bool,
    heard_all: bool,
    stable: int,
    stable_rounds: int,
    rounds: int,
    max_rounds: int,
) -> Literal["agreed", "gave_up", "stop"] | None:
    """What a finished round means for a seed: ``"agreed"`` (it is done now: every partner
    heard, ``stable_rounds`` agreeing answers in a row), ``"gave_up"`` (``max_rounds`` run
    without being done), ``"stop"`` (done already and out of rounds: it stops watching for
    late news, still done), or ``None`` (rounds go on).

    Examples
    --------
    >>> kw = dict(heard_all=True, stable_rounds=4, max_rounds=400)
    >>> [round_end(done=d, stable=4, rounds=10, **kw) for d in (False, True)]
    ['agreed', None]
    >>> [round_end(done=d, stable=1, rounds=400, **kw) for d in (False, True)]
    ['gave_up', 'stop']
    """
    if not done and heard_all and stable >= stable_rounds:
        return "agreed"
    if rounds >= max_rounds:
        return "stop" if done else "gave_up"
    return None


def next_partner(partners: Sequence[FrameKey], parent_key: FrameKey | None, turns: int) -> FrameKey:
    """The partner a round without a hint asks about: on even ``turns`` the parent (if any),
    otherwise each of ``partners`` (sorted) in turn. Asking the others is how a seed learns
    of better ranks that no hint brought.

    Examples
    --------
    >>> ks = [FrameKey(2, 0), FrameKey(4, 0), FrameKey(6, 0)]
    >>> [next_partner(ks, FrameKey(6, 0), t).uid for t in range(1, 7)]
    [2, 6, 4, 6, 6, 6]
    >>> [next_partner(ks, None, t).uid for t in range(1, 7)]
    [2, 4, 4, 6, 6, 2]
    """
    if parent_key is not None and turns % 2 == 0:
        return parent_key
    return partners[(turns // 2) % len(partners)]


def hint_is_news(partner: FrameKey, partner_ranks: Mapping[FrameKey, Rank], own: Rank) -> bool:
    """Whether a hint about ``partner`` is followed: not if the seed already knows it ranks
    better than itself (it asks its parent every other round anyway).

    Examples
    --------
    >>> k, own = FrameKey(4, 0), Rank.own(FrameKey(5, 0), edge=False)
    >>> hint_is_news(k, {}, own), hint_is_news(k, {k: Rank.own(k, edge=False)}, own)
    (True, False)
    """
    known = partner_ranks.get(partner)
    return known is None or not known < own


def hint_due(seed_rank: Rank | None, partner_rank: Rank | None) -> bool:
    """Whether a member of a group of seeds I and K hints I about K: it has heard both ranks
    and K's, one hop further, would still be better than I's. The seed learns a partner's
    rank only by asking about it, partner after partner; the member hears both seeds' ranks.

    Examples
    --------
    >>> i, k = Rank.own(FrameKey(5, 0), edge=False), Rank.own(FrameKey(1, 0), edge=False)
    >>> hint_due(i, k), hint_due(k.one_hop_further(), k), hint_due(None, k)
    (True, False, False)
    """
    if seed_rank is None or partner_rank is None:
        return False
    # partner_rank.one_hop_further() < seed_rank, without building that rank (a member scans
    # its groups at every transmit opportunity after a rank changed)
    root, seed_root = partner_rank.root, seed_rank.root
    return root < seed_root or (root == seed_root and partner_rank.hops + 1 < seed_rank.hops)


def cuts_round(hinted_round: bool, asking: FrameKey | None, hinted: FrameKey) -> bool:
    """Whether a hint about partner ``hinted`` ends the running round (about ``asking``) at
    once: a better root is what the whole swarm waits for. A round that a hint started is not
    cut short, or hints from several members would keep restarting it.

    Examples
    --------
    >>> k, other = FrameKey(4, 0), FrameKey(6, 0)
    >>> cuts_round(False, other, k), cuts_round(True, other, k), cuts_round(False, k, k)
    (True, False, False)
    """
    return not hinted_round and asking is not None and asking != hinted


def seed_message(
    turn: int, *, rank_due: bool, halves_due: bool, querying: bool, query_due: bool
) -> Literal["rank", "half", "query", "rotation", "shift"]:
    """What a seed sends at its ``turn``-th transmit opportunity while merging.

    ``"rank"`` (TF_ROOT) when its rank improved or every fifth turn: members that hear a better
    rank hint the next seeds, which is how the root spreads; ``"half"`` (the next half of a new
    transform version, which a member needs both of before it can answer); ``"query"`` when a
    round's query is new or every third turn while a round runs; otherwise its transform,
    rotation and shift in turn.

    Examples
    --------
    >>> kw = dict(rank_due=False, halves_due=False, query_due=False)
    >>> [seed_message(t, querying=True, **kw) for t in (1, 2, 3, 4)]
    ['rank', 'rotation', 'query', 'rotation']
    >>> seed_message(2, rank_due=False, halves_due=True, querying=True, query_due=True)
    'half'
    """
    if rank_due or turn % 5 == 1:
        return "rank"
    if halves_due:
        return "half"
    if querying and (query_due or turn % 3 == 0):
        return "query"
    return "rotation" if turn % 2 == 0 else "shift"
