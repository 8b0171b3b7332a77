"""Phase 6: merging the local frames into one (thesis §4.6, §5.3.2 "Phase 6"; finished here).

Every seed S keeps its frame's transform: a 3-D rotation R_S and a shift v_S with
``global = R_S · (x, y, 0) + v_S`` (3-D so that a frame that is the mirror image of another can
be turned into it: a 180° turn about an in-plane axis). Initially R_S = I, v_S = 0. Seeds
broadcast their transform (TF_ROT, TF_SHIFT) with a 7-bit version (bit 7: the seed is done)
and their rank (TF_ROOT; :class:`kilonet.protocols.gcs.frame_keys.Rank`: the root their frame has
been aligned to and their hops from it, smaller is better).

A round of seed I (:class:`SeedRounds`; every choice is a rule of
:mod:`kilonet.protocols.gcs.merging_rules`):

1. I picks a partner frame K — after a hint the hinted one, otherwise every other round its
   parent (the best-ranked partner it knows) and each partner in turn between — and a robot X
   that registered a merging group (X, Y, Z) for (I, K): a new one each round
   (``gcs.merge_member = "random"``) or one kept while it answers (``"fixed"``). It sends
   ``QUERY(I → X, K, version, tag)`` until answered or until ``gcs.merge_round_s`` passes. The
   tag (random at first, then counting) numbers the round, so an answer to an earlier round is
   never taken for this one's.
2. X, once it holds I's transform of that version and K's latest transform, maps the three
   members' local positions into both "global" frames, finds the rigid map M from I's to K's
   (:func:`kilonet.protocols.common.alignment.half_map`: Horn's closed form) and takes **half** of
   it:
   R_H = Slerp(I, R_M)(½) and t_H = (c_I + c_K)/2 − R_H c_I. It answers with the disagreement
   (the farthest M moves a member) and K's rank (ANS_ERROR, naming the seed), then R_H
   (ANS_ROT) and t_H (ANS_SHIFT), to one seed at a time. A seed that is a member itself
   answers its own query at once and pauses ``_OWN_ROUND_S`` before its next round.
3. I applies the step only if K is its parent: R_I ← R_H R_I, v_I ← R_H v_I + t_H, twice when
   the parent is more than ``gcs.merge_whole_step_mm`` off (the whole step); it takes the
   parent's rank one hop further if that is better, bumps its version and broadcasts.

A member that hears partner K rank better than seed I could know sends ``HINT(I, K)`` (at most
once per pair and ``gcs.merge_round_s``), and I asks K through it in its next round. A seed is
done when ``gcs.merge_stable_rounds`` answers in a row agree and every partner has answered
(or timed out ``gcs.merge_silent_rounds`` rounds without ever answering); it keeps running
rounds and resumes on a new rank or a parent that moved away (``gcs.merge_resume``). A seed with no
partner is isolated and done at once, its root ranked last; after ``gcs.merge_max_rounds``
rounds it gives up, or stops its rounds if done. ``docs/gcs.md`` says why each rule is there.

Messages (rotations as the three int16 words of
:func:`kilonet.protocols.common.alignment.pack_quaternion`;
shifts int16 in 0.25 mm; frames by their seed's ID and salt,
:class:`~kilonet.protocols.gcs.frame_keys.FrameKey`; ranks as
:meth:`~kilonet.protocols.gcs.frame_keys.Rank.wire`)::

    type 60 TF_ROT     sender:uint16  version:uint8  q0 q1 q2:int16          9 bytes
    type 61 TF_SHIFT   sender:uint16  version:uint8  vx vy vz:int16          9 bytes
    type 62 QUERY      sender:uint16  member:uint16  partner:uint16  partner_salt:uint8
                       version:uint8  tag:uint8                              9 bytes
    type 63 ANS_ROT    sender:uint16  tag:uint8  q0 q1 q2:int16              9 bytes
    type 64 ANS_SHIFT  sender:uint16  tag:uint8  tx ty tz:int16              9 bytes
    type 65 ANS_ERROR  sender:uint16  tag:uint8  seed:uint8 (its ID's low byte)
                       error:uint8 (0.5 mm, saturating at 127.5)
                       partner_root:uint16  partner_root_salt:uint8
                       partner_hops:uint8                                    9 bytes
    type 66 TF_ROOT    sender:uint16  root:uint16  root_salt:uint8  hops:uint8   6 bytes
    type 67 HINT       sender:uint16  seed:uint16  partner:uint16  partner_salt:uint8
                                                                             7 bytes
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from kilonet.message import Message
from kilonet.protocols.common.alignment import (
    half_map,
)
from kilonet.protocols.common.geometry import GeometryError
from kilonet.protocols.common.phases import Handler
from kilonet.protocols.gcs.base import SENDER, GcsParams, GcsStage, Phase, gcs_layout
from kilonet.protocols.gcs.frame_keys import FrameKey, Rank
from kilonet.protocols.gcs.merging_rules import (
    all_partners_heard,
    answer_agrees,
    beyond_resume,
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
from kilonet.protocols.gcs.replacement_wave import PLACED_TYPES, PlacedNeighbours
from kilonet.protocols.gcs.split_detection import POS, SplitCheck
from kilonet.protocols.gcs.transforms import (
    Transform,
    quaternion_fields,
    rotation_from_fields,
    version_byte,
    version_number,
)

__all__ = [
    "ANS_ERROR",
    "ANS_ROT",
    "ANS_SHIFT",
    "HINT",
    "QUERY",
    "TF_ROOT",
    "TF_ROT",
    "TF_SHIFT",
    "FrameMerging",
    "SeedRounds",
    "Transform",
    "quaternion_fields",
    "rotation_from_fields",
    "version_byte",
    "version_number",
]

_Q = [
    ("q0", "h"),
    ("q1", "h"),
    ("q2", "h"),
]  # kilonet.protocols.common.alignment.pack_quaternion words
_V = [("vx_mm", "h", 0.25), ("vy_mm", "h", 0.25), ("vz_mm", "h", 0.25)]
_PARTNER = [("partner", "H"), ("partner_salt", "B")]
TF_ROT = gcs_layout("tf_rot", type=60, fields=[("version", "B"), *_Q])
TF_SHIFT = gcs_layout("tf_shift", type=61, fields=[("version", "B"), *_V])
QUERY = gcs_layout(
    "query", type=62, fields=[("member", "H"), *_PARTNER, ("version", "B"), ("tag", "B")]
)
ANS_ROT = gcs_layout("ans_rot", type=63, fields=[("tag", "B"), *_Q])
ANS_SHIFT = gcs_layout("ans_shift", type=64, fields=[("tag", "B"), *_V])
ANS_ERROR = gcs_layout(
    "ans_error",
    type=65,
    fields=[
        ("tag", "B"),
        ("seed", "B"),
        ("error_mm", "B", 0.5),
        ("partner_root", "H"),
        ("partner_root_salt", "B"),
        ("partner_hops", "B"),
    ],
)
TF_ROOT = gcs_layout("tf_root", type=66, fields=[("root", "H"), ("root_salt", "B"), ("hops", "B")])
HINT = gcs_layout("hint", type=67, fields=[("seed", "H"), *_PARTNER])
#: The two halves of a broadcast transform, and of an answer, by message type.
_TRANSFORM_PARTS = {TF_ROT.type: (TF_ROT, "rot"), TF_SHIFT.type: (TF_SHIFT, "shift")}
_ANSWER_PARTS = {ANS_ROT.type: (ANS_ROT, "rot"), ANS_SHIFT.type: (ANS_SHIFT, "shift")}
_ERROR_LIMIT_MM = 127.5  # ANS_ERROR's error field saturates here
_UNHEARD = (None, None)  # (version, halves) of a frame none of whose halves is heard yet
_read_sender = SENDER.unpack_from  # the sender's ID of any message, without a Python call
_IDENTITY = Rotation.identity()
_OWN_ROUND_S = 1.0  # pause after a round the seed answered itself (about a round's length)


def _seed_byte(uid: int) -> int:
    """How ANS_ERROR names the seed it answers: the low byte of its ID."""
    return uid & 0xFF


#: A member's answer: the half step's rotation and shift (mm), the disagreement (mm) and the
#: partner's rank as the member heard it.
Answer = tuple[Rotation, np.ndarray, float, Rank]


class FrameMerging(Phase):
    """Phase 6 on one robot: everyone tracks transforms and ranks, members answer queries and
    hint their seeds, and a seed also runs its rounds (:attr:`seed`).

    Attributes
    ----------
    seed : SeedRounds or None
        The seed side, on seeds only.
    """

    __slots__ = (  # see GcsRobot.__slots__
        "answers",
        "finish_ticks",
        "fresh_ticks",
        "heard_at",
        "hint_scanned",
        "hinted_at",
        "outbox",
        "parts",
        "pending_query",
        "placed",
        "repeated",
        "round_ticks",
        "seed",
        "settled_since",
    )
    name = GcsStage.MERGE
    open_ended = True  # rounds until the seeds agree

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window: none (``inf``), merging ends when the seeds agree."""
        return float("inf")

    def start(self) -> None:
        r = self.robot
        tps = r.ticks_per_s
        self.round_ticks = round(self.params.merge_round_s * tps)
        # Merging (again, after a recovery) starts afresh: transforms, ranks and the check.
        r.estimate.forget_merging()
        # Halves of the transform being heard, by frame: (version, {"rot"/"shift": (unpacked,
        # message)}).
        self.parts: dict[FrameKey, tuple[int | None, dict[str, tuple[object, Message]]]] = {}
        # By sender ID: the two messages of the transform last completed, of one version byte,
        # and its frame key (see _track_transform).
        self.repeated: dict[int, tuple[Message, Message, FrameKey]] = {}
        # When each transform was completed (ticks): versions are 7 bits and wrap after 128
        # updates, so only a recently heard transform may be matched by its version.
        self.heard_at: dict[FrameKey, int] = {}
        self.fresh_ticks = round(8 * self.params.merge_round_s * tps)
        self.outbox: list[Message] = []
        # The last answer given to each seed: (round tag, messages). Only the latest is kept:
        # tags wrap after 256 rounds, and an answer to an old round must never be resent.
        self.answers: dict[FrameKey, tuple[int, list[Message]]] = {}
        # When this robot last hinted each (seed, partner) pair of its groups (ticks).
        self.hinted_at: dict[tuple[FrameKey, FrameKey], int] = {}
        # (estimate version, tick) of the last scan that found no hint to send, and the tick
        # from which a pair held back then may go (see _hint).
        self.hint_scanned: tuple[int, float] = (-1, 0)
        # The latest query to this robot it could not answer yet: (seed, partner, version, tag).
        self.pending_query: tuple[FrameKey, FrameKey, int, int] | None = None
        r.merge_done = False
        r.refined = r.refined_root = None  # an estimate refined before a recovery is void
        r.merging = self
        self.settled_since: int | None = None
        self.finish_ticks = self.params.refine_after_s * tps
        r.check = SplitCheck(r)
        # Neighbours the refinement's wave has placed (phase 7, gcs.refine): see finished().
        self.placed = PlacedNeighbours(tps)
        self.seed: SeedRounds | None = SeedRounds(self) if r.is_seed else None
        if self.seed is not None:
            self.seed.start()

    def handlers(self) -> Mapping[int, Handler]:
        """While merging (only), a settled neighbour's POS goes to the split check too
        (:mod:`kilonet.protocols.gcs.split_detection`)."""
        return {POS.type: self._check_position}

    def _check_position(self, message: Message) -> None:
        self.robot.check.message_rx(message)

    def finished(self) -> bool:
        """Whether merging is over for this robot, so that the refinement (phase 7) may start:
        for ``gcs.refine_after_s`` its estimate has been settled (or it is located in no frame
        at all, and merging can give it none: the refinement's wave may place it) and the seed
        of every frame it is located in done (a robot stays a member for a frame whose seed
        still merges), no recovery is announced or awaited, and a seed's own rounds are done.
        Or at once, when the refinement's re-placement wave has reached it
        (:func:`~kilonet.protocols.gcs.replacement_wave.wave_reached`): the wave places it, whatever
        holds merging back (the refinement keeps merging going, and a recovery still ends it).
        """
        r = self.robot
        estimate = r.estimate
        if self.placed.reached(estimate.root(), r.kilo_ticks):
            return True
        transforms = estimate.transforms
        over = (
            (estimate.settled() or not estimate.frames)
            and all(k in transforms and transforms[k].done for k in estimate.frames)
            and not r.awaiting_recovery()
            and (self.seed is None or self.seed.done)
        )
        if not over:
            self.settled_since = None
            return False
        now = r.kilo_ticks
        if self.settled_since is None:
            self.settled_since = now
        return now - self.settled_since >= self.finish_ticks

    def _own_frame(self) -> FrameKey | None:
        """The frame this robot merges as a seed (``None`` on non-seeds)."""
        return self.seed.key if self.seed is not None else None

    # -- member side: hints --------------------------------------------------------------------
    def _hint(self) -> Message | None:
        """A HINT for a seed of this robot's groups whose partner ranks better than it could
        know (:func:`~kilonet.protocols.gcs.merging_rules.hint_due`), at most one per pair and
        ``gcs.merge_round_s``."""
        r = self.robot
        now = r.kilo_ticks
        version = r.estimate.version
        # Asked at every transmit opportunity: scan the groups again only once a rank has
        # changed or a pair held back by the time limit may go.
        if version == self.hint_scanned[0] and now < self.hint_scanned[1]:
            return None
        own = self._own_frame()
        ranks = r.estimate.ranks
        due = float("inf")
        for pair in r.groups:
            for seed, partner in (pair, pair[::-1]):
                if seed == own or not hint_due(ranks.get(seed), ranks.get(partner)):
                    continue
                last = self.hinted_at.get((seed, partner))
                if last is not None and now - last < self.round_ticks:
                    due = min(due, last + self.round_ticks)
                    continue
                self.hinted_at[(seed, partner)] = now
                self.hint_scanned = (-1, 0)  # more pairs may be due: scan again next time
                return HINT.pack(
                    sender=r.uid, seed=seed.uid, partner=partner.uid, partner_salt=partner.salt
                )
        self.hint_scanned = (version, due)
        return None

    # -- member side: answers ------------------------------------------------------------------
    def _local_points(self, frame: FrameKey, members: tuple[int, ...]) -> np.ndarray | None:
        r = self.robot
        points = []
        for uid in members:
            if uid == r.uid:
                xy = r.estimate.frames.get(frame)
            else:
                xy = r.announced.get(frame, {}).get(uid)
            if xy is None:
                return None
            points.append((xy[0], xy[1], 0.0))
        return np.array(points)

    def compute_answer(self, seed: FrameKey, partner: FrameKey, version: int) -> Answer | None:
        """This robot's answer to seed ``seed``'s query about ``partner`` for the seed's
        transform version byte ``version``; ``None`` while it cannot answer: it registered no
        group for the pair, lacks a transform, holds another version of the seed's (or one
        heard too long ago to trust a wrapped version number), misses a member's position or
        the partner's rank, or the members are nearly in a line."""
        r = self.robot
        rank_k = r.estimate.ranks.get(partner)
        group = r.groups.get((min(seed, partner), max(seed, partner)))
        transforms = r.estimate.transforms
        tf_i, tf_k = transforms.get(seed), transforms.get(partner)
        if group is None or tf_i is None or tf_k is None:
            return None
        if version_number(tf_i.version) != version_number(version):
            return None
        heard = self.heard_at.get(seed, -(10**9))
        if seed != self._own_frame() and r.kilo_ticks - heard > self.fresh_ticks:
            return None
        members = (r.uid, *group)
        local_i, local_k = self._local_points(seed, members), self._local_points(partner, members)
        if local_i is None or local_k is None or rank_k is None:
            return None
        global_i, global_k = tf_i.apply(local_i), tf_k.apply(local_k)
        try:
            return (*half_map(global_i, global_k), rank_k)
        except GeometryError:  # members nearly in a line: no rotation to learn from them
            return None

    def _answer(self, seed: FrameKey, partner: FrameKey, version: int, tag: int) -> bool:
        """Queue the answer to a query; ``False`` if this robot cannot answer it yet."""
        answer = self.compute_answer(seed, partner, version)
        if answer is None:
            return False
        rotation, shift, error, rank_k = answer
        r = self.robot
        tx, ty, tz = shift
        root, root_salt, hops = rank_k.wire()
        messages = [
            ANS_ERROR.pack(
                sender=r.uid,
                tag=tag,
                seed=_seed_byte(seed.uid),
                error_mm=min(error, _ERROR_LIMIT_MM),
                partner_root=root,
                partner_root_salt=root_salt,
                partner_hops=hops,
            ),
            ANS_ROT.pack(sender=r.uid, tag=tag, **quaternion_fields(rotation)),
            ANS_SHIFT.pack(sender=r.uid, tag=tag, vx_mm=tx, vy_mm=ty, vz_mm=tz),
        ]
        self.answers[seed] = (tag, messages)
        self.outbox.extend(messages)
        return True

    def _take_query(self, message: Message) -> None:
        r = self.robot
        m = QUERY.unpack(message)
        if m.member != r.uid or self.outbox:
            return
        seed = r.frame_key(m.sender)
        tag, cached = self.answers.get(seed, (None, []))
        if tag == m.tag:
            self.outbox.extend(cached)
            return
        query = (seed, FrameKey.from_wire(m.partner, m.partner_salt), m.version, m.tag)
        # Not answerable yet (usually: the seed's new version is still on its way): answer
        # the moment the missing transform is complete.
        self.pending_query = None if self._answer(*query) else query

    # -- everyone: tracking ----------------------------------------------------------------------
    def _track_root(self, message: Message) -> None:
        r = self.robot
        m = TF_ROOT.unpack(message)
        r.estimate.hear_rank(r.frame_key(m.sender), Rank.from_wire(m.root, m.root_salt, m.hops))

    def _track_transform(self, message: Message) -> None:
        """A TF_ROT or TF_SHIFT heard: the sender's transform is complete once both halves of
        one version are, and is held (and answers waiting for it go) from then on.

        A seed sends the very message objects of its current transform again and again
        (:meth:`SeedRounds._transform_message`): one of the pair last completed, both of one
        version byte, changes nothing held, so it only marks the transform heard now."""
        repeated = self.repeated.get(_read_sender(message.data)[0])
        if repeated is not None and (message is repeated[0] or message is repeated[1]):
            key = repeated[2]
        else:
            key = self._take_half(message)
            if key is None:
                return
        r = self.robot
        self.heard_at[key] = r.kilo_ticks
        pending = self.pending_query
        answerable = pending is not None and key in pending[:2] and not self.outbox
        if answerable and self._answer(*pending):
            self.pending_query = None

    def _take_half(self, message: Message) -> FrameKey | None:
        """Keep a transform half; the sender's frame key once the transform is complete
        (``None`` while it is not, or for this robot's own)."""
        r = self.robot
        layout, part = _TRANSFORM_PARTS[message.type]
        m = layout.unpack(message)
        if m.sender == r.uid:
            return None
        self.repeated.pop(m.sender, None)
        key = r.frame_key(m.sender)
        version, parts = self.parts.get(key, _UNHEARD)
        number = version_number(m.version)
        if version != number:  # a newer version: older halves are void
            version, parts = number, {}
            self.parts[key] = (version, parts)
        parts[part] = (m, message)
        if len(parts) < 2:
            return None
        (rot, rot_message), (shift, shift_message) = parts["rot"], parts["shift"]
        words = (rot.q0, rot.q1, rot.q2)
        shift_mm = [shift.vx_mm, shift.vy_mm, shift.vz_mm]
        held = r.estimate.transforms.get(key)
        # Seeds repeat each version many times: keep the object (and what robots cached from
        # it) unless something changed.
        if (
            held is None
            or held.version != m.version
            or held.words != words
            or held.shift.tolist() != shift_mm
        ):
            r.estimate.hear_transform(key, Transform(np.array(shift_mm), m.version, words=words))
        if rot.version == shift.version:  # either half again: the held transform as it is
            self.repeated[m.sender] = (rot_message, shift_message, key)
        return key

    # -- phase interface -----------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        if self.outbox:
            return self.outbox.pop(0)
        hint = self._hint()
        if hint is not None:
            return hint
        if self.seed is not None:
            return self.seed.message_tx()
        return None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        kind = message.type
        if kind in PLACED_TYPES:  # rare: every other reception skips the call and the clock
            self.placed.take(message, self.robot.kilo_ticks)
        if kind in _TRANSFORM_PARTS:
            self._track_transform(message)
        elif kind == TF_ROOT.type:
            self._track_root(message)
        elif kind == QUERY.type:
            self._take_query(message)
        if self.seed is not None:
            self.seed.message_rx(message)

    def loop(self) -> None:
        if self.seed is not None:
            self.seed.loop()


class SeedRounds:
    """The seed side of phase 6 on one seed: its transform, its rank and its rounds.

    Attributes
    ----------
    key : FrameKey
        The seed's own frame.
    rank : Rank
        Its rank (its root and hops from it).
    rotation : Rotation
        R_S of its transform.
    shift : (3,) array
        v_S of its transform, mm.
    done : bool
        It reported itself done (its parent agrees).
    final : bool
        It runs no more rounds (isolated, gave up, or out of rounds when done).
    done_since : int or None
        Tick at which it last became done.
    rounds : int
        Rounds answered so far.
    """

    __slots__ = (
        "_halves",
        "asking",
        "disagreed",
        "done",
        "done_since",
        "final",
        "hint",
        "hinted_round",
        "key",
        "members",
        "merging",
        "next_round_tick",
        "params",
        "partner_ranks",
        "query_due",
        "rank",
        "rank_unpublished",
        "received",
        "robot",
        "rotation",
        "round_start",
        "rounds",
        "shift",
        "stable",
        "tag",
        "turn",
        "turns",
        "unanswered",
        "unpublished",
        "version",
    )

    def __init__(self, merging: FrameMerging) -> None:
        r = merging.robot
        self.merging, self.robot, self.params = merging, r, merging.params
        self.key = r.own_key
        self.rotation = _IDENTITY
        self.shift = np.zeros(3)
        self.version = 0
        # Every round has its own tag, carried by the query and its answers: versions change
        # only when a step is taken, so a round that timed out and a new one (maybe about
        # another partner, with the same member) would otherwise share answers. Tags start at
        # random: every seed starts its rounds at the same moment, and a member that several
        # seeds ask must not have its answer to one taken by another.
        self.tag = int(r.rand.integers(256))
        self.done = False
        self.final = False
        self.done_since: int | None = None
        self.rounds = 0
        self.stable = 0  # agreeing answers in a row
        self.disagreed = 0  # parent answers in a row toward resuming (beyond_resume)
        self.asking: tuple[int, FrameKey] | None = None  # (member, partner) of the round
        self.hint: tuple[int, FrameKey] | None = None  # (member, partner) from a HINT
        self.members: dict[FrameKey, int] = {}  # partner -> the member kept ("fixed")
        self.hinted_round = False  # the running round was started by a hint
        self.query_due = False
        self.unpublished = 0  # halves of a new transform version not sent yet
        self.rank_unpublished = False
        self.received: dict[str, object] = {}  # the answer's messages so far
        self.round_start = r.kilo_ticks
        self.next_round_tick = 0.0  # a round answered by the seed itself pauses the next
        self.rank = Rank.own(self.key, edge=r.edge_seed)
        self.partner_ranks: dict[FrameKey, Rank] = {}  # as the last answer about each said
        self.unanswered: dict[FrameKey, int] = {}  # rounds timed out, per partner never heard
        self.turns = 0  # rounds started without a hint
        self.turn = 0  # transmit opportunities
        # The last TF_ROT (key True) and TF_SHIFT (False) sent, with what they were packed
        # from: (sender, version byte, rotation or shift object, message). A seed repeats its
        # transform many times between steps; a step assigns new rotation and shift objects.
        self._halves: dict[bool, tuple[int, int, object, Message]] = {}

    def start(self) -> None:
        """Publish the initial transform; a seed without partners is isolated, done at once.

        An isolated seed's root ranks last, as an edge seed's: its frame merges with nothing,
        so it must not win over a robot located in a merged frame too (with the smaller key it
        took its seed and references out of the merged frame).
        """
        isolated = not self.robot.partners
        if isolated:
            self.rank = Rank.own(self.key, edge=True)
        self._publish()
        if isolated:
            self._finish("isolated")

    # -- state ---------------------------------------------------------------------------------
    def _finish(self, how: str) -> None:
        self.done = True
        self.final = how != "agreed"  # isolated or gave up: no more rounds
        r = self.robot
        r.merge_done = True
        self.done_since = r.kilo_ticks
        r.log("merge_done", how=how, rounds=self.rounds)
        self._publish()

    def _resume(self) -> None:
        r = self.robot
        self.done = r.merge_done = False
        self.done_since = None
        r.log("merge_resumed", rounds=self.rounds)

    def _publish(self) -> None:
        estimate = self.robot.estimate
        estimate.hear_transform(
            self.key, Transform(self.shift, self._version_byte(), rotation=self.rotation)
        )
        estimate.hear_rank(self.key, self.rank)

    def _version_byte(self) -> int:
        return version_byte(self.version, self.done)

    # -- rounds --------------------------------------------------------------------------------
    def _count_timeout(self) -> None:
        """The running round timed out: ask another member next time, and count a partner
        that has never answered toward the silent-partner rule."""
        asked = self.asking[1]
        self.members.pop(asked, None)
        if asked not in self.partner_ranks:
            self.unanswered[asked] = self.unanswered.get(asked, 0) + 1
            if self.unanswered[asked] == self.params.merge_silent_rounds:
                self.robot.log("merge_partner_silent", partner=asked.uid)

    def _choose(self) -> tuple[int, FrameKey]:
        """The (member, partner) of a new round: a hint's, if news; otherwise the partner of
        :func:`~kilonet.protocols.gcs.merging_rules.next_partner` and one of its members."""
        r = self.robot
        hinted, self.hint = self.hint, None
        if hinted is not None and not hint_is_news(hinted[1], self.partner_ranks, self.rank):
            hinted = None
        self.hinted_round = hinted is not None
        if hinted is not None:
            member, partner = hinted
            r.log("merge_hint", partner=partner.uid, member=member)
            return member, partner
        self.turns += 1
        partner = next_partner(sorted(r.partners), self._parent(), self.turns)
        member = self.members.get(partner)
        if member is None:
            members = sorted(r.partners[partner])
            member = members[int(r.rand.integers(len(members)))]
            if self.params.merge_member == "fixed":
                self.members[partner] = member
        return member, partner

    def _new_round(self) -> None:
        r = self.robot
        if self.asking is not None:
            self._count_timeout()
        member, partner = self._choose()
        self.asking = (member, partner)
        self.query_due = True
        self.tag = (self.tag + 1) % 256
        self.received = {}
        self.round_start = r.kilo_ticks
        if member == r.uid:  # the seed is a member itself: no message needed
            answer = self.merging.compute_answer(self.key, partner, self._version_byte())
            if answer is not None:
                self._apply(*answer)
                # An answer of its own comes at once; without a pause the seed would run a
                # round at every transmit opportunity, stepping again before its partner's
                # transform was heard anew.
                self.next_round_tick = r.kilo_ticks + _OWN_ROUND_S * r.ticks_per_s

    def _parent(self) -> FrameKey | None:
        return parent(self.partner_ranks, self.rank)

    def _step(self, rotation: Rotation, shift: np.ndarray, error_mm: float, rank: Rank) -> bool:
        """Step toward the parent (of rank ``rank``) by the answer's half step, or twice it;
        return whether this seed's rank improved."""
        better = rank_toward(self.rank, rank)
        if better is not None:
            self.rank = better
            self.rank_unpublished = True
        for _ in range(half_steps(error_mm, self.params.merge_whole_step_mm)):
            self.rotation = rotation * self.rotation
            self.shift = rotation.apply(self.shift) + shift
        # A new version only when the transform moved: members that hold the current one
        # can answer the next round at once (rounds are told apart by their tags).
        self.version += 1
        self.unpublished = 2  # its two halves go out before anything else
        return better is not None

    def _apply(self, rotation: Rotation, shift: np.ndarray, error_mm: float, rank: Rank) -> None:
        """Take an answer (the half step, the disagreement in mm, the partner's rank) and end
        the round by the rules of :mod:`kilonet.protocols.gcs.merging_rules`."""
        r, p = self.robot, self.params
        asked = self.asking[1] if self.asking is not None else None
        if asked is not None:
            self.partner_ranks[asked] = rank
        follows = asked is not None and asked == self._parent()
        agreed = answer_agrees(follows, error_mm, p.merge_tolerance_mm)
        new_rank = False
        if follows:
            beyond = beyond_resume(
                error_mm,
                rule=p.merge_resume,
                tolerance_mm=p.merge_tolerance_mm,
                whole_step_mm=p.merge_whole_step_mm,
            )
            self.disagreed = self.disagreed + 1 if beyond else 0
            new_rank = self._step(rotation, shift, error_mm, rank)
        self.rounds += 1
        self.stable = self.stable + 1 if agreed else 0
        self._log_round(error_mm, rank, follows)
        self.asking = None
        if resumes(
            done=self.done,
            agreed=agreed,
            new_rank=new_rank,
            error_mm=error_mm,
            whole_step_mm=p.merge_whole_step_mm,
            disagreed_in_row=self.disagreed,
            rule=p.merge_resume,
        ):
            self._resume()
        end = round_end(
            done=self.done,
            heard_all=all_partners_heard(
                r.partners, self.partner_ranks, self.unanswered, p.merge_silent_rounds
            ),
            stable=self.stable,
            stable_rounds=p.merge_stable_rounds,
            rounds=self.rounds,
            max_rounds=p.merge_max_rounds,
        )
        if end == "stop":
            self.final = True
        elif end is not None:
            self._finish(end)
        self._publish()

    def _log_round(self, error_mm: float, rank: Rank, stepped: bool) -> None:
        member, partner = self.asking if self.asking else (-1, None)
        self.robot.log(
            "merge_round",
            round=self.rounds,
            error_mm=round(error_mm, 3),
            root=self.rank.root.wire_id,
            hops=self.rank.hops,
            partner=partner.uid if partner is not None else -1,
            member=member,
            partner_hops=rank.hops,
            stepped=int(stepped),
        )

    # -- messages ------------------------------------------------------------------------------
    def message_tx(self) -> Message:
        """The seed's message at a transmit opportunity
        (:func:`~kilonet.protocols.gcs.merging_rules.seed_message`); a new round starts first when
        one is due."""
        r = self.robot
        now = r.kilo_ticks
        timed_out = now - self.round_start > self.merging.round_ticks
        idle = self.asking is None and now >= self.next_round_tick
        if not self.final and r.partners and (idle or timed_out):
            self._new_round()
        self.turn += 1
        kind = seed_message(
            self.turn,
            rank_due=self.rank_unpublished,
            halves_due=self.unpublished > 0,
            querying=self.asking is not None and not self.final,
            query_due=self.query_due,
        )
        if kind == "rank":
            self.rank_unpublished = False
            root, root_salt, hops = self.rank.wire()
            return TF_ROOT.pack(sender=r.uid, root=root, root_salt=root_salt, hops=hops)
        if kind == "half":
            self.unpublished -= 1
            return self._transform_message(rotation=self.unpublished == 1)
        if kind == "query":
            self.query_due = False
            member, partner = self.asking
            return QUERY.pack(
                sender=r.uid,
                member=member,
                partner=partner.uid,
                partner_salt=partner.salt,
                version=self._version_byte(),
                tag=self.tag,
            )
        return self._transform_message(rotation=kind == "rotation")

    def _transform_message(self, *, rotation: bool) -> Message:
        """One half of this seed's transform: TF_ROT or TF_SHIFT. The message sent last for
        that half when nothing it was packed from changed (messages are immutable; packing
        the rotation's quaternion is the costly part)."""
        sender, version = self.robot.uid, self._version_byte()
        source = self.rotation if rotation else self.shift
        last = self._halves.get(rotation)
        if last is not None and last[0] == sender and last[1] == version and last[2] is source:
            return last[3]
        if rotation:
            message = TF_ROT.pack(sender=sender, version=version, **quaternion_fields(source))
        else:
            vx, vy, vz = source
            message = TF_SHIFT.pack(sender=sender, version=version, vx_mm=vx, vy_mm=vy, vz_mm=vz)
        self._halves[rotation] = (sender, version, source, message)
        return message

    def message_rx(self, message: Message) -> None:
        """Hints, and the parts of the running round's answer."""
        if self.final:
            return
        if HINT.matches(message):
            self._take_hint(HINT.unpack(message))
        elif self.asking is not None and self._collect(message):
            rot, shift, error = (self.received[k] for k in ("rot", "shift", "error"))
            self._apply(
                rotation_from_fields(rot.q0, rot.q1, rot.q2),
                np.array([shift.vx_mm, shift.vy_mm, shift.vz_mm]),
                error.error_mm,
                Rank.from_wire(error.partner_root, error.partner_root_salt, error.partner_hops),
            )

    def _collect(self, message: Message) -> bool:
        """Keep ``message`` if it is part of the running round's answer; ``True`` once the
        answer is complete.

        A member answers one seed at a time, ANS_ERROR first: it names the seed (an answer to
        another seed that drew the same tag is refused), and the rotation and shift that
        follow it from that member belong to the same answer.
        """
        member, _ = self.asking
        kind = message.type
        if kind == ANS_ERROR.type:
            m = ANS_ERROR.unpack(message)
            if m.sender == member and m.tag == self.tag and m.seed == _seed_byte(self.robot.uid):
                self.received = {"error": m}
        elif kind in _ANSWER_PARTS and "error" in self.received:
            layout, part = _ANSWER_PARTS[kind]
            m = layout.unpack(message)
            if m.sender == member and m.tag == self.tag:
                self.received[part] = m
        return len(self.received) == 3

    def _take_hint(self, m) -> None:
        """A member says partner K ranks better than this seed: the next round asks K through
        that member, and the running round may end now
        (:func:`~kilonet.protocols.gcs.merging_rules.cuts_round`)."""
        r = self.robot
        partner = FrameKey.from_wire(m.partner, m.partner_salt)
        if m.seed == r.uid and m.sender in r.partners.get(partner, ()):
            self.hint = (m.sender, partner)
            asking = self.asking[1] if self.asking is not None else None
            if cuts_round(self.hinted_round, asking, partner):
                self.asking = None  # its answers are refused by their tag from now on

    def loop(self) -> None:
        """A round whose answer is overdue ends, and the next starts."""
        r = self.robot
        waiting = not self.final and r.partners and self.asking is not None
        if waiting and r.kilo_ticks - self.round_start > self.merging.round_ticks:
            self._new_round()
