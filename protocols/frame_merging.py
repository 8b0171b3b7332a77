"""Phase 6: merging the local frames into one (thesis §4.6, §5.3.2 "Phase 6"; finished here).

Every seed S keeps its frame's transform: a 3-D rotation R_S and a shift v_S with
``global = R_S · (x, y, 0) + v_S`` (3-D so that a frame that is the mirror image of another can
be turned into it: a 180° turn about an in-plane axis). Initially R_S = I, v_S = 0. Seeds
broadcast their transform (TF_ROT, TF_SHIFT) with an 8-bit version.

A round of seed I:

1. I picks a partner frame K — every other round the best-ranked partner it knows of (see
   ranks below), otherwise each partner in turn — and a robot X that registered a merging group
   (X, Y, Z) for (I, K), and sends ``QUERY(I → X, K, version, tag)``, repeating it until
   answered or until ``gcs.merge_round_s`` passes (then a new round starts). The tag numbers
   the round: the answer carries it, so an answer to an earlier round (perhaps about another
   partner, from the same member, for the same version) is never taken for this one's. Tags
   start at random, and the answer names the seed it is for (below).
2. X, once it holds I's transform of that version and K's latest transform, maps the three
   members' local positions into both "global" frames, finds the rigid map M from I's to K's
   (the least-squares rotation: Horn's closed form, the same optimum as Kabsch in
   ``scipy.spatial.transform.Rotation.align_vectors``), and takes **half** of it:
   R_H = Slerp(I, R_M)(½) and the shift that moves the members' centroid half way,
   t_H = (c_I + c_K)/2 − R_H c_I. It answers with the disagreement of the two transforms (the
   farthest M moves a member) and K's rank (ANS_ERROR, naming the seed), then R_H (a
   quaternion, ANS_ROT) and t_H (ANS_SHIFT). It answers one seed at a time, so the rotation and
   shift that follow an ANS_ERROR belong to it: without that, a seed took another seed's
   answer whose tag matched, and a merged frame's root leaked into frames never merged with it.
3. I applies the step: R_I ← R_H R_I, v_I ← R_H v_I + t_H, bumps its version and
   broadcasts the new transform. A seed that is a member of the group answers itself at
   once, and then waits a second before its next round (else it would step at every transmit
   opportunity, faster than its partner's transform is heard anew).

Which member: ``gcs.merge_member = "random"`` (default) asks a member drawn anew each round,
so the seed's half steps average the groups' estimates of the map; they differ by their
members' position errors, 1-5 mm some 15 frames from the root. ``"fixed"`` keeps one member
per partner while it answers: the seed no longer steps between estimates, fails the tolerance
less often and sends less wobble down to its children, at the price of one group's error.
Measured before the resume rule below (seed 1; 100 robots: seeds 1-3): 1,000 robots
285 → 229 simulated s, RMSE 2.9 → 4.3 mm; 300 robots 173 → 176 s, 1.5 → 2.1 mm; 100 robots
159/184/150 → 141/160/151 s, RMSE 1.1/0.8/0.6 → 1.4/1.1/2.7 mm.

Beyond the thesis — whole steps. When the parent (below) disagrees by more than
``gcs.merge_whole_step_mm``, the seed applies the half step twice: the whole rotation and,
but for the turn of the second half of the move, the whole shift. Near the parent, half steps
average the answers' noise away. Measured on 100 robots (seeds 1-3): merging 87/101/100 →
81/75/72 simulated s; 300 robots 168 → 127 s.

Beyond the thesis — a rank. Half steps alone are a diffusion: on a chain of L frames agreement
takes on the order of L² rounds, and with delayed, noisy answers it keeps ringing (we measured
disagreements of tens of millimetres that never settled). So every seed also carries a *rank*:
the smallest seed ID its frame has been aligned to (its root, initially its own ID) and its hops
from that root, broadcast in TF_ROOT and ordered (root, hops). The member always answers with
the half step and K's rank as it heard it; the seed, which alone knows its own rank for sure,
applies the half step (the thesis's step) only when K is its *parent* — the best-ranked partner
it has heard of, ties going to the smaller frame key — and takes rank(K) + 1 hop; toward any
other partner it stays (that partner follows a parent of its own). One parent, not every
better-ranked partner: two partners one hop nearer the root reach it along different chains
and differ by those chains' errors (5-7 mm on 300 robots), and a seed that stepped toward both
swung between them and never settled. We measured the alternatives on a 100-robot lattice
(before phase 3 checked that references see each other, which bent some frames): the thesis's
symmetric half steps kept disagreements of tens of millimetres; whole steps toward parents plus
half steps between equals left 22 mm RMSE; half steps toward parents only, 8.8 mm.
The smallest root spreads like a flood and each frame follows a parent one hop nearer to it, so
the frames lock together in a number of rounds that grows with the diameter, not its square,
and settle instead of ringing (see the measurements below).

Hints, also beyond the thesis. A seed learns a partner's rank only by asking about it, one
partner after another, so the flood crossed each frame in several rounds; meanwhile groups of
frames that had settled on a local root reported themselves done, the split check saw their
boundary with the advancing root as a split, and a needless recovery epoch restarted phases 3-6
(300 robots: detected 35 s into merging, 150 simulated s lost). But a group member hears both of
its seeds' ranks (TF_ROOT): when it sees partner K rank better than seed I could, it sends
``HINT(I, K)`` (at most once per pair and ``gcs.merge_round_s``), and I asks K through that
member in its next round, unless it already knows K as a parent; a running round that no hint
started ends at once. A seed whose rank improves sends TF_ROOT at its next opportunity. The
root thus crosses a frame in about 3 s instead of 5 (1,000 robots: 20 hops in 59 s instead of
101).

Termination, decided by each seed alone: when ``gcs.merge_stable_rounds`` answers in a row
agree and every partner has answered at least once, the seed is done (bit 7 of its version).
An answer agrees when the partner is not the parent (this seed does not move toward it), or
when the parent's disagreement is within ``gcs.merge_tolerance_mm``. The seed keeps running
rounds, so a smaller root arriving later, a parent more than ``gcs.merge_whole_step_mm`` off,
or two parent answers in a row beyond the tolerance revoke "done" until it agrees anew. One
stray answer does not: answers about one parent differ by 1-5 mm with the member asked some
15 frames from the root, and resuming on each sent waves of "resumed" down the tree (1,000
robots, seed 1: merging 196 → 126 simulated s, 308 → 177 s of CPU, RMSE 2.9 → 3.6 mm; 100 and
300 robots unchanged but for seed 1 of 100: 159 → 154 s). A partner that has never answered
stops holding up "done" after ``gcs.merge_silent_rounds`` rounds about it timed out (event
``merge_partner_silent``): a member located in both frames need not hear the partner's seed,
so it may never hold the transform it would answer with. A seed with no registered group is
isolated and done at once; a seed after ``gcs.merge_max_rounds`` rounds gives up if it is
not done, and otherwise stops its rounds, done as it was.

A robot's global position g is the mean, over the frames it is located in whose transform it
holds (and of its smallest root), of ``R_S (x, y, 0) + v_S``, expressed in 2-D in the common
plane laid flat (:func:`kilonet.alignment.level`: the turn that takes the plane's normal, on a
fixed side, to +z depends on the plane only, so mirror-image frames read the same axes).

Messages (rotations as the three int16 words of :func:`kilonet.alignment.pack_quaternion`;
shifts int16 in 0.25 mm)::

    type 60 TF_ROT     sender:uint16  version:uint8  q0 q1 q2:int16          9 bytes
    type 61 TF_SHIFT   sender:uint16  version:uint8  vx vy vz:int16          9 bytes
    type 62 QUERY      sender:uint16  member:uint16  partner:uint16  salt:uint8
                       version:uint8  tag:uint8                              9 bytes

Frames (partners, transforms) are named by frame keys: seed ID and salt
(:meth:`protocols.gcs.GcsRobot.frame_key`).
    type 63 ANS_ROT    sender:uint16  tag:uint8  q0 q1 q2:int16              9 bytes
    type 64 ANS_SHIFT  sender:uint16  tag:uint8  tx ty tz:int16              9 bytes
    type 65 ANS_ERROR  sender:uint16  tag:uint8  seed:uint8 (its ID's low byte)
                       error:uint8 (0.5 mm, saturating at 127.5)
                       partner_root:uint16  partner_root_salt:uint8
                       partner_hops:uint8                                    9 bytes
    type 66 TF_ROOT    sender:uint16  root:uint16  root_salt:uint8  hops:uint8   6 bytes
    type 67 HINT       sender:uint16  seed:uint16  partner:uint16  partner_salt:uint8
                                                                             7 bytes

A rank is the root's frame key (ID and salt: IDs alone repeat across a large swarm, and two
roots that share one would pull the frames apart forever) times 256 plus the hops.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from kilonet.alignment import (
    half_map,
    level_matrix,
    pack_quaternion,
    unpack_quaternion,
    words_matrix,
)
from kilonet.geometry import GeometryError
from kilonet.message import Layout, Message
from protocols.gcs_base import Phase
from protocols.split_detection import SplitCheck

__all__ = [
    "HINT",
    "FrameMerging",
    "Transform",
    "quaternion_fields",
    "rotation_from_fields",
]

_Q = [("q0", "h"), ("q1", "h"), ("q2", "h")]  # kilonet.alignment.pack_quaternion words
_V = [("vx_mm", "h", 0.25), ("vy_mm", "h", 0.25), ("vz_mm", "h", 0.25)]
TF_ROT = Layout("tf_rot", type=60, fields=[("sender", "H"), ("version", "B"), *_Q])
TF_SHIFT = Layout("tf_shift", type=61, fields=[("sender", "H"), ("version", "B"), *_V])
QUERY = Layout(
    "query",
    type=62,
    fields=[
        ("sender", "H"),
        ("member", "H"),
        ("partner", "H"),
        ("partner_salt", "B"),
        ("version", "B"),
        ("tag", "B"),
    ],
)
ANS_ROT = Layout("ans_rot", type=63, fields=[("sender", "H"), ("tag", "B"), *_Q])
ANS_SHIFT = Layout("ans_shift", type=64, fields=[("sender", "H"), ("tag", "B"), *_V])
ANS_ERROR = Layout(
    "ans_error",
    type=65,
    fields=[
        ("sender", "H"),
        ("tag", "B"),
        ("seed", "B"),
        ("error_mm", "B", 0.5),
        ("partner_root", "H"),
        ("partner_root_salt", "B"),
        ("partner_hops", "B"),
    ],
)
TF_ROOT = Layout(
    "tf_root",
    type=66,
    fields=[("sender", "H"), ("root", "H"), ("root_salt", "B"), ("hops", "B")],
)
HINT = Layout(
    "hint",
    type=67,
    fields=[("sender", "H"), ("seed", "H"), ("partner", "H"), ("partner_salt", "B")],
)
#: The two halves of a broadcast transform, by message type.
_TRANSFORM_PARTS = {TF_ROT.type: (TF_ROT, "rot"), TF_SHIFT.type: (TF_SHIFT, "shift")}
_DONE = 0x80
_EDGE_ROOT = 0x8000  # in the root's ID field: the root is an edge seed (ranks last)
_IDENTITY = Rotation.identity()
_OWN_ROUND_S = 1.0  # pause after a round the seed answered itself (about a round's length)


class Transform:
    """A seed's frame transform as a robot holds it: ``global = rotation · (x, y, 0) + shift``.

    A heard transform keeps the three message words and decodes the rotation on first use:
    robots hear many more transforms than they ever use, and decoding is the costly part.

    Parameters
    ----------
    shift : (3,) array
        mm.
    version : int
        The version byte as broadcast (bit 7: the seed is done).
    rotation : Rotation, optional
        The rotation itself (a seed's own transform) ...
    words : tuple of three int, optional
        ... or its :func:`quaternion_fields` words (a heard one).
    """

    __slots__ = ("_affine", "_flat", "_matrix", "_rotation", "_words", "shift", "version")

    def __init__(
        self,
        shift: np.ndarray,
        version: int,
        *,
        rotation: Rotation | None = None,
        words: tuple[int, int, int] | None = None,
    ) -> None:
        if (rotation is None) == (words is None):
            raise ValueError("give a Transform either its rotation or its words")
        self._rotation, self._words = rotation, words
        self.shift, self.version = shift, version
        self._matrix: np.ndarray | None = None
        self._flat: np.ndarray | None = None
        self._affine: tuple[float, ...] | None = None  # apply_point's matrix columns and shift

    @property
    def words(self) -> tuple[int, int, int] | None:
        """The message words it was heard as (``None`` for a seed's own)."""
        return self._words

    @property
    def rotation(self) -> Rotation:
        if self._rotation is None:
            self._rotation = unpack_quaternion(self._words)
        return self._rotation

    def apply_point(self, x_mm: float, y_mm: float) -> tuple[float, float, float]:
        """One local point (x, y, 0), mm, in the seed's "global" coordinates, mm (a robot asks
        this many times a second: plain floats, not NumPy or a scipy ``Rotation.apply``)."""
        if self._affine is None:
            (a, b, _), (c, d, _), (e, f, _) = self.matrix.tolist()
            self._affine = (a, b, c, d, e, f, *(float(v) for v in self.shift))
        a, b, c, d, e, f, sx, sy, sz = self._affine
        return a * x_mm + b * y_mm + sx, c * x_mm + d * y_mm + sy, e * x_mm + f * y_mm + sz

    @property
    def matrix(self) -> np.ndarray:
        """The rotation as a 3×3 matrix (computed once, from the words when heard)."""
        if self._matrix is None:
            words = self._words
            self._matrix = self.rotation.as_matrix() if words is None else words_matrix(words)
        return self._matrix

    @property
    def flat(self) -> np.ndarray:
        """The 3×3 matrix of :func:`kilonet.alignment.level_turn` for this transform: global
        coordinates in the common plane laid flat are the first two of ``flat @ g``."""
        if self._flat is None:
            self._flat = level_matrix(self.matrix)
        return self._flat

    @property
    def done(self) -> bool:
        """Whether the seed reported itself done with this version."""
        return bool(self.version & _DONE)

    def apply(self, points_mm: np.ndarray) -> np.ndarray:
        """Local points, (n, 3) or (3,), mm, in the seed's "global" coordinates, mm."""
        return points_mm @ self.matrix.T + self.shift


def quaternion_fields(rotation: Rotation) -> dict[str, int]:
    """The message fields of a rotation: the three words of
    :func:`kilonet.alignment.pack_quaternion` (at most 0.0086° lost, also near 180°)."""
    q0, q1, q2 = pack_quaternion(rotation)
    return {"q0": q0, "q1": q1, "q2": q2}


def rotation_from_fields(q0: int, q1: int, q2: int) -> Rotation:
    """The rotation carried by three message words.

    Examples
    --------
    >>> r = Rotation.from_euler("x", 180, degrees=True)
    >>> back = rotation_from_fields(**quaternion_fields(r))
    >>> bool(np.degrees((back * r.inv()).magnitude()) < 0.01)
    True
    """
    return unpack_quaternion((q0, q1, q2))


class FrameMerging(Phase):
    """Phase 6 on one robot: seeds run rounds; members answer; everyone tracks transforms."""

    __slots__ = (  # see GcsRobot.__slots__: 38 attributes
        "answers",
        "asking",
        "disagreed",
        "done",
        "done_since",
        "final",
        "fresh_ticks",
        "heard_at",
        "hint",
        "hint_scanned",
        "hinted_at",
        "hinted_round",
        "key",
        "members",
        "next_round_tick",
        "outbox",
        "partner_ranks",
        "parts",
        "pending_query",
        "query_due",
        "rank",
        "rank_unpublished",
        "ranks",
        "received",
        "rotation",
        "round_start",
        "round_ticks",
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
    name = "merge"

    def start(self) -> None:
        r = self.robot
        tps = r.ticks_per_s
        self.round_ticks = round(self.params.merge_round_s * tps)
        # Transforms heard, by seed (a Transform each); their halves are collected by version.
        r.transforms = {}
        # Halves of the transform being heard, by seed: (version, {"rot"/"shift": message}).
        self.parts: dict[int, tuple[int | None, dict[str, object]]] = {}
        # When each transform was completed (ticks): versions are 7 bits and wrap after 128
        # updates, so only a recently heard transform may be matched by its version.
        self.heard_at: dict[int, int] = {}
        self.fresh_ticks = round(8 * self.params.merge_round_s * r.ticks_per_s)
        self.outbox: list[Message] = []
        # The last answer given to each seed: (round tag, messages). Only the latest is kept:
        # tags wrap after 256 rounds, and an answer to an old round must never be resent.
        self.answers: dict[int, tuple[int, list[Message]]] = {}
        self.turn = 0
        # When this robot last hinted each (seed, partner) pair of its groups (ticks).
        self.hinted_at: dict[tuple[int, int], int] = {}
        # (merge_state, tick) of the last scan that found no hint to send, and the tick from
        # which a pair held back then may go (see _hint).
        self.hint_scanned: tuple[int, float] = (-1, 0)
        # The latest query to this robot it could not answer yet: (seed, partner, version, tag).
        self.pending_query: tuple[int, int, int, int] | None = None
        # Rank of each seed heard, by frame key: root frame key · 256 + hops (smaller better).
        # Merging (again, after a recovery) starts afresh: transforms, ranks and the check.
        r.ranks = self.ranks = {}
        r.merge_state += 1
        r.merge_done = False
        r.check = SplitCheck(r)
        self.done_since: int | None = None
        if r.is_seed:
            self.rotation = _IDENTITY
            self.shift = np.zeros(3)
            self.version = 0
            # Every round has its own tag, carried by the query and its answers: versions
            # change only when a step is taken, so a round that timed out and a new one (maybe
            # about another partner, with the same member) would otherwise share answers.
            # Tags start at random: every seed starts its rounds at the same moment, and a
            # member that several seeds ask must not have its answer to one taken by another.
            self.tag = int(r.rand.integers(256))
            self.done = False
            self.final = False
            self.rounds = 0
            self.stable = 0
            self.disagreed = 0
            self.asking: tuple[int, int] | None = None
            self.hint: tuple[int, int] | None = None  # (member, partner) from a HINT
            self.members: dict[int, int] = {}  # partner -> the member asked about it
            self.hinted_round = False  # the running round was started by a hint
            self.query_due = False
            self.unpublished = 0
            self.rank_unpublished = False
            self.received: dict[str, object] = {}
            self.round_start = r.kilo_ticks
            self.next_round_tick = 0.0  # a round answered by the seed itself pauses the next
            # An edge seed's frame (protocols.recovery) ranks after every elected seed's: bit 15
            # of the root's ID field is free (IDs have at most 15 bits). Otherwise a new frame
            # that merges with nothing could win robots over from the frame they were in.
            self.rank = (r.frame_key(r.uid) << 8) | (_EDGE_ROOT << 16 if r.edge_seed else 0)
            self.partner_ranks: dict[int, int] = {}  # as the last answer about each reported
            self.unanswered: dict[int, int] = {}  # rounds timed out, per partner never answered
            self.turns = 0  # rounds started (answered or not)
            self.key = r.frame_key(r.uid)
            self._publish()
            if not r.partners:
                self._finish("isolated")

    # -- seed side ---------------------------------------------------------------------------
    def _finish(self, how: str) -> None:
        self.done = True
        self.final = how != "agreed"  # isolated or gave up: no more rounds
        r = self.robot
        r.merge_done = True
        self.done_since = r.kilo_ticks
        r.log("merge_done", how=how, rounds=self.rounds)
        self._publish()

    def _publish(self) -> None:
        r = self.robot
        r.transforms[self.key] = Transform(self.shift, self._version_byte(), rotation=self.rotation)
        self.ranks[self.key] = self.rank
        r.merge_state += 1

    def _version_byte(self) -> int:
        return (self.version & 0x7F) | (_DONE if self.done else 0)

    def _new_round(self) -> None:
        """Start a round: after a hint ask its member about its partner; otherwise every other
        round goes to the best-ranked partner known (the parent it follows), the others to each
        partner in turn: that is how better ranks are found without hints."""
        r = self.robot
        if self.asking is not None:  # the last round timed out: try another member next time
            asked = self.asking[1]
            self.members.pop(asked, None)
            if asked not in self.partner_ranks:
                self.unanswered[asked] = self.unanswered.get(asked, 0) + 1
                if self.unanswered[asked] == self.params.merge_silent_rounds:
                    r.log("merge_partner_silent", partner=asked >> 8)
        hinted, self.hint = self.hint, None
        if hinted is not None and self.partner_ranks.get(hinted[1], 1 << 40) < self.rank:
            hinted = None  # known already: a parent is asked every other round anyway
        self.hinted_round = hinted is not None
        if hinted is not None:
            member, partner = hinted
            r.log("merge_hint", partner=partner >> 8, member=member)
        else:
            partners = sorted(r.partners)
            parent = self._parent()
            self.turns += 1
            if parent is not None and self.turns % 2 == 0:
                partner = parent
            else:
                partner = partners[(self.turns // 2) % len(partners)]
            member = self.members.get(partner)
            if member is None:
                members = sorted(r.partners[partner])
                member = members[int(r.rand.integers(len(members)))]
                if self.params.merge_member == "fixed":
                    self.members[partner] = member
        self.asking = (member, partner)
        self.query_due = True
        self.tag = (self.tag + 1) & 0xFF
        self.received = {}
        self.round_start = r.kilo_ticks
        if member == r.uid:  # the seed is a member itself: no message needed
            answer = self._compute_answer(self.key, partner, self._version_byte())
            if answer is not None:
                self._apply(*answer)
                # An answer of its own comes at once; without a pause the seed would run a
                # round at every transmit opportunity, stepping again before its partner's
                # transform was heard anew, and use up gcs.merge_max_rounds in a minute.
                self.next_round_tick = r.kilo_ticks + _OWN_ROUND_S * r.ticks_per_s

    def _parent(self) -> int | None:
        """The partner this seed follows: the best rank it has heard of, ties going to the
        smaller frame key; ``None`` while no partner ranks better than the seed itself."""
        better = [(rank, key) for key, rank in self.partner_ranks.items() if rank < self.rank]
        return min(better)[1] if better else None

    def _apply(
        self, rotation: Rotation, shift: np.ndarray, error_mm: float, partner_rank: int
    ) -> None:
        r = self.robot
        asked = self.asking[1] if self.asking is not None else None
        if asked is not None:
            self.partner_ranks[asked] = partner_rank
        # The answer is the half step: take it toward the parent only, and only the parent
        # can be disagreed with. Every other partner follows a parent of its own, and their
        # disagreement is theirs: two partners one hop nearer the root reach it along
        # different chains and differ by the chains' errors (300 robots: 5-7 mm, more than
        # the tolerance), so following both kept a seed swinging between them and resuming
        # for 400 simulated seconds. Ranks only fall, so a partner rank the member heard a
        # while ago errs on the side of staying.
        follow = asked is not None and asked == self._parent()
        agreed = not follow or error_mm <= self.params.merge_tolerance_mm
        if follow:  # parent answers in a row beyond the tolerance (see the resume rule below)
            self.disagreed = 0 if agreed else self.disagreed + 1
        new_root = False
        if follow:
            if partner_rank + 1 < self.rank and partner_rank & 0xFF < 0xFF:
                self.rank = partner_rank + 1
                self.rank_unpublished = True
                new_root = True
            # Far off, the half step goes twice: the whole rotation and, but for the turn of
            # the remaining half move, the whole shift; near the parent, half steps average
            # the answers' noise away.
            for _ in range(2 if error_mm > self.params.merge_whole_step_mm else 1):
                self.rotation = rotation * self.rotation
                self.shift = rotation.apply(self.shift) + shift
            # A new version only when the transform moved: members that hold the current one
            # can answer the next round at once (rounds are told apart by their tags).
            self.version += 1
            self.unpublished = 2  # its two halves go out before anything else
        self.rounds += 1
        self.stable = self.stable + 1 if agreed else 0
        r.log(
            "merge_round",
            round=self.rounds,
            error_mm=round(error_mm, 3),
            root=self.rank >> 16,
            hops=self.rank & 0xFF,
            partner=self.asking[1] >> 8 if self.asking else -1,
            member=self.asking[0] if self.asking else -1,
            partner_hops=partner_rank & 0xFF,
            stepped=int(follow),
        )
        self.asking = None
        # A done seed resumes on a new rank, a far-off parent, or two answers in a row beyond
        # the tolerance: answers about one parent differ by a few mm with the member asked,
        # and resuming on each stray one sent waves of "resumed" through the frames below.
        far = error_mm > self.params.merge_whole_step_mm
        if self.done and not agreed and (new_root or far or self.disagreed >= 2):
            self.done = r.merge_done = False  # the parent disagrees again: keep merging
            self.done_since = None
            r.log("merge_resumed", rounds=self.rounds)
        # Done only once every partner has answered at least once: a partner never asked may
        # hold a better root, and a seed done before hearing of it would soon resume. Unless a
        # partner never answers: its only group members may not hear its seed (at 1,000
        # robots, seed 3, four seeds waited for such a partner until they gave up at 400
        # rounds, 815 simulated s of merging instead of about 150), or its seed crashed.
        silent = self.params.merge_silent_rounds
        heard_all = all(
            k in self.partner_ranks or self.unanswered.get(k, 0) >= silent for k in r.partners
        )
        if not self.done and heard_all and self.stable >= self.params.merge_stable_rounds:
            self._finish("agreed")
        elif self.rounds >= self.params.merge_max_rounds:
            if self.done:  # agreed already: only the watch for late news ends here
                self.final = True
            else:
                self._finish("gave_up")
        self._publish()

    def _seed_message(self) -> Message | None:
        r = self.robot
        now = r.kilo_ticks
        timed_out = now - self.round_start > self.round_ticks
        idle = self.asking is None and now >= self.next_round_tick
        if not self.final and r.partners and (idle or timed_out):
            self._new_round()
        self.turn += 1
        version = self._version_byte()
        if self.rank_unpublished or self.turn % 5 == 1:
            # A better rank goes out at once: members that hear it hint the next seeds, and
            # that is how the root spreads (at 1,000 robots it crosses 20 frames).
            self.rank_unpublished = False
            return TF_ROOT.pack(
                sender=r.uid,
                root=self.rank >> 16,
                root_salt=(self.rank >> 8) & 0xFF,
                hops=self.rank & 0xFF,
            )
        if self.unpublished:
            # A member cannot answer the next query before it holds both halves of the new
            # version: send them first.
            self.unpublished -= 1
            return self._transform_message(rotation=self.unpublished == 1)
        if self.asking is not None and not self.final and (self.query_due or self.turn % 3 == 0):
            self.query_due = False  # a new round's query goes out first, then every third turn
            member, partner = self.asking
            return QUERY.pack(
                sender=r.uid,
                member=member,
                partner=partner >> 8,
                partner_salt=partner & 0xFF,
                version=version,
                tag=self.tag,
            )
        return self._transform_message(rotation=self.turn % 2 == 0)

    def _transform_message(self, *, rotation: bool) -> Message:
        """One half of this seed's transform: TF_ROT or TF_SHIFT."""
        sender, version = self.robot.uid, self._version_byte()
        if rotation:
            return TF_ROT.pack(sender=sender, version=version, **quaternion_fields(self.rotation))
        vx, vy, vz = self.shift
        return TF_SHIFT.pack(sender=sender, version=version, vx_mm=vx, vy_mm=vy, vz_mm=vz)

    def _seed_receive(self, message: Message) -> None:
        if self.final:
            return
        r = self.robot
        if HINT.matches(message):
            self._take_hint(HINT.unpack(message))
            return
        if self.asking is None:
            return
        member, _ = self.asking
        # A member answers one seed at a time, ANS_ERROR first: it names the seed (an answer to
        # another seed that drew the same tag is refused), and the rotation and shift that
        # follow it from that member belong to the same answer.
        if ANS_ERROR.matches(message):
            m = ANS_ERROR.unpack(message)
            if m.sender == member and m.tag == self.tag and m.seed == r.uid & 0xFF:
                self.received = {"error": m}
        elif "error" in self.received:
            for layout, part in ((ANS_ROT, "rot"), (ANS_SHIFT, "shift")):
                if layout.matches(message):
                    m = layout.unpack(message)
                    if m.sender == member and m.tag == self.tag:
                        self.received[part] = m
        if len(self.received) == 3:
            rot, shift, error = (self.received[k] for k in ("rot", "shift", "error"))
            self._apply(
                rotation_from_fields(rot.q0, rot.q1, rot.q2),
                np.array([shift.vx_mm, shift.vy_mm, shift.vz_mm]),
                error.error_mm,
                (error.partner_root << 16) | (error.partner_root_salt << 8) | error.partner_hops,
            )

    def _take_hint(self, m) -> None:
        """A member says partner K ranks better than this seed: the next round asks K through
        that member, and a running round that no hint started ends now (a better root is
        what the whole swarm waits for; a hinted round is not cut short, or hints from
        several members would keep restarting it)."""
        r = self.robot
        partner = (m.partner << 8) | m.partner_salt
        if m.seed == r.uid and m.sender in r.partners.get(partner, ()):
            self.hint = (m.sender, partner)
            if not self.hinted_round and self.asking is not None and self.asking[1] != partner:
                self.asking = None  # its answers are refused by their tag from now on

    # -- member side -------------------------------------------------------------------------
    def _hint(self) -> Message | None:
        """A HINT for a seed of this robot's groups whose partner ranks better than it could
        know: both seeds broadcast their ranks (TF_ROOT) and this robot hears both, while the
        seed learns its partner's rank only by asking about it, one partner after another.
        At most one hint per pair and ``gcs.merge_round_s``."""
        r = self.robot
        now = r.kilo_ticks
        # Asked at every transmit opportunity: scan the groups again only once a rank has
        # changed or a pair held back by the time limit may go.
        if r.merge_state == self.hint_scanned[0] and now < self.hint_scanned[1]:
            return None
        own = getattr(self, "key", None)
        ranks = self.ranks
        due = float("inf")
        for pair in r.groups:
            for seed, partner in (pair, pair[::-1]):
                rank_seed, rank_partner = ranks.get(seed), ranks.get(partner)
                if rank_seed is None or rank_partner is None or rank_partner + 1 >= rank_seed:
                    continue
                if seed == own:
                    continue
                last = self.hinted_at.get((seed, partner))
                if last is not None and now - last < self.round_ticks:
                    due = min(due, last + self.round_ticks)
                    continue
                self.hinted_at[(seed, partner)] = now
                self.hint_scanned = (-1, 0)  # more pairs may be due: scan again next time
                return HINT.pack(
                    sender=r.uid, seed=seed >> 8, partner=partner >> 8, partner_salt=partner & 0xFF
                )
        self.hint_scanned = (r.merge_state, due)
        return None

    # -- member side: answers -------------------------------------------------------------------
    def _local_points(self, frame: int, members: tuple[int, ...]) -> np.ndarray | None:
        r = self.robot
        points = []
        for uid in members:
            xy = r.frames.get(frame) if uid == r.uid else r.announced.get(frame, {}).get(uid)
            if xy is None:
                return None
            points.append((xy[0], xy[1], 0.0))
        return np.array(points)

    def _compute_answer(
        self, seed: int, partner: int, version: int
    ) -> tuple[Rotation, np.ndarray, float, int] | None:
        r = self.robot
        rank_k = self.ranks.get(partner)
        key = (min(seed, partner), max(seed, partner))
        group = r.groups.get(key)
        tf_i, tf_k = r.transforms.get(seed), r.transforms.get(partner)
        if group is None or tf_i is None or tf_k is None or tf_i.version & 0x7F != version & 0x7F:
            return None
        heard = self.heard_at.get(seed, -(10**9))
        if seed != getattr(self, "key", None) and r.kilo_ticks - heard > self.fresh_ticks:
            return None
        members = (r.uid, *group)
        local_i, local_k = self._local_points(seed, members), self._local_points(partner, members)
        if local_i is None or local_k is None:
            return None
        if rank_k is None:
            return None
        global_i, global_k = tf_i.apply(local_i), tf_k.apply(local_k)
        try:
            return (*half_map(global_i, global_k), rank_k)
        except GeometryError:  # members nearly in a line: no rotation to learn from them
            return None

    def _answer(self, seed: int, partner: int, version: int, tag: int) -> bool:
        """Queue the answer to a query; ``False`` if this robot cannot answer it yet."""
        answer = self._compute_answer(seed, partner, version)
        if answer is None:
            return False
        rotation, shift, error, rank_k = answer
        r = self.robot
        tx, ty, tz = shift
        messages = [
            ANS_ERROR.pack(
                sender=r.uid,
                tag=tag,
                seed=(seed >> 8) & 0xFF,
                error_mm=min(error, 127.5),
                partner_root=rank_k >> 16,
                partner_root_salt=(rank_k >> 8) & 0xFF,
                partner_hops=rank_k & 0xFF,
            ),
            ANS_ROT.pack(sender=r.uid, tag=tag, **quaternion_fields(rotation)),
            ANS_SHIFT.pack(sender=r.uid, tag=tag, vx_mm=tx, vy_mm=ty, vz_mm=tz),
        ]
        self.answers[seed] = (tag, messages)
        self.outbox.extend(messages)
        return True

    def _track_root(self, message: Message) -> None:
        r = self.robot
        m = TF_ROOT.unpack(message)
        key, rank = r.frame_key(m.sender), (m.root << 16) | (m.root_salt << 8) | m.hops
        if self.ranks.get(key) != rank:
            self.ranks[key] = rank
            if key in r.frames:  # only frames it is located in shape its estimate and hints
                r.merge_state += 1

    def _track_transform(self, message: Message) -> None:
        r = self.robot
        layout, part = _TRANSFORM_PARTS[message.type]
        m = layout.unpack(message)
        if m.sender == r.uid:
            return
        key = r.frame_key(m.sender)
        version, parts = self.parts.get(key, (None, {}))
        if version != m.version & 0x7F:  # a newer version: older halves are void
            version, parts = m.version & 0x7F, {}
            self.parts[key] = (version, parts)
        parts[part] = m
        if len(parts) == 2:
            rot, shift = parts["rot"], parts["shift"]
            words = (rot.q0, rot.q1, rot.q2)
            shift_mm = [shift.vx_mm, shift.vy_mm, shift.vz_mm]
            held = r.transforms.get(key)
            # Seeds repeat each version many times: keep the object (and what robots cached
            # from it, see GcsRobot.global_position) unless something changed.
            if (
                held is None
                or held.version != m.version
                or held.words != words
                or held.shift.tolist() != shift_mm
            ):
                r.transforms[key] = Transform(np.array(shift_mm), m.version, words=words)
                if key in r.frames:
                    r.merge_state += 1
            self.heard_at[key] = r.kilo_ticks
            pending = self.pending_query
            answerable = pending is not None and key in pending[:2] and not self.outbox
            if answerable and self._answer(*pending):
                self.pending_query = None

    # -- phase interface ---------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        if self.outbox:
            return self.outbox.pop(0)
        hint = self._hint()
        if hint is not None:
            return hint
        if self.robot.is_seed:
            return self._seed_message()
        return None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        r = self.robot
        kind = message.type
        if kind in _TRANSFORM_PARTS:
            self._track_transform(message)
        elif kind == TF_ROOT.type:
            self._track_root(message)
        elif QUERY.matches(message):
            m = QUERY.unpack(message)
            if m.member == r.uid and not self.outbox:
                seed = r.frame_key(m.sender)
                tag, cached = self.answers.get(seed, (None, []))
                if tag == m.tag:
                    self.outbox.extend(cached)
                else:
                    query = (seed, (m.partner << 8) | m.partner_salt, m.version, m.tag)
                    # Not answerable yet (usually: the seed's new version is still on its way):
                    # answer the moment the missing transform is complete.
                    self.pending_query = None if self._answer(*query) else query
        if r.is_seed:
            self._seed_receive(message)

    def loop(self) -> None:
        r = self.robot
        waiting = r.is_seed and not self.final and r.partners and self.asking is not None
        if waiting and r.kilo_ticks - self.round_start > self.round_ticks:
            self._new_round()
