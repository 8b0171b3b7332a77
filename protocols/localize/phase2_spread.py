"""Phase 2 of ``localize``: the frame starts at the root and spreads outward by
multilateration, with collinearity and flip (mirror) checks.

**Start.** The root is the origin. From its neighbours' NBR reports it knows which of its
neighbours hear each other and how far apart they are, so it chooses the frame's other two
robots itself (:func:`~kilonet.protocols.localize.spread_rules.choose_frame`): an *axis* robot B
and a *third* robot C that see each other, form a triangle at least ``localize.min_height_mm``
high even when each of its three distances is off by the ranging noise the root has measured (a
nearly collinear triple, whose height the noise makes up, would start the frame from a line and
set its handedness by chance), and share the most common neighbours with the root (each of those
can place itself from R, B and C at once). ROOT messages name them. B places itself at
``(|RB|, 0)``; C, once it has heard B's position, at ``(x, +y)`` from ``|RC|``, ``|BC|`` and B's x
(:func:`~kilonet.protocols.common.geometry.place_references`; the positive root of y picks the
frame's
handedness). If B or C is not placed within ``localize.bootstrap_timeout_s`` the root names
another pair without them; a B or C that placed itself from the old naming after all (its
position had not yet reached the root) gives its position up when it hears the new one, so the
frame never holds two axis robots.

**Spreading.** Every other robot, at each round, fixes its position from its neighbours that
have one, by rules 1-4 of :mod:`kilonet.protocols.localize.spread_rules` (multilateration with
collinearity and mirror checks; candidate pairs; neighbours' candidates; votes that bodies do
not overlap). This module holds the phase on one robot (:class:`Spread`): its messages, its
attempts and its candidates.

Messages::

    ROOT (81)  sender:uint16  axis:uint16  third:uint16  flags:uint8             7 bytes
               the root, at (0, 0), hop 0; axis/third 0xFFFF while not chosen
    POS  (82)  sender:uint16  x:int16  y:int16 (0.1 mm)  hops:uint8  flags:uint8
               windings:uint8                                                    9 bytes
               every other robot; x, y are 0 while the LOCALIZED flag is clear
    CAND (84)  sender:uint16  x:int16  y:int16 (0.1 mm)  index:uint8  version:uint8
               windings:uint8                                                    9 bytes
               one of a robot's two candidates (index + FROM_LINE when they come from
               three or more anchors); the version changes with its anchors and after
               the candidates lapsed (never back to an earlier one)

x and y travel modulo 6,553.6 mm, with both winding numbers in ``windings``
(:func:`~kilonet.protocols.localize_base.wrapped_position`): a frame up to 49 m from its root fits.
    VOTE (86)  sender:uint16  target:uint16  index:uint8  version:uint8              6 bytes
               the candidate of ``target``'s pair (of that version) that is possible

``flags`` are :mod:`kilonet.protocols.localize.base`'s LOCALIZED, SETTLED, COMPLETE, DONE.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from kilonet.message import Layout, Message
from kilonet.protocols.common.geometry import GeometryError, multilaterate, place_references
from kilonet.protocols.localize.base import (
    LOCALIZED,
    MAX_COORDINATE_MM,
    NO_ID,
    SETTLED,
    Neighbour,
    absolute_position,
    wrapped_position,
)
from kilonet.protocols.localize.spread_rules import (
    Point,
    anchors_fresh,
    candidate_version,
    choose_frame,
    circle_candidates,
    consistent_subset_fix,
    fix_with_candidates,
    line_same_mm,
    mirror_candidates,
    overlap_vote,
    separation,
    side_is_clear,
)

if TYPE_CHECKING:
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = ["CAND", "FROM_LINE", "POS", "ROOT", "VOTE", "Spread"]

ROOT = Layout(
    "root",
    type=81,
    fields=[("sender", "H"), ("axis", "H"), ("third", "H"), ("flags", "B")],
)
POS = Layout(
    "pos",
    type=82,
    fields=[
        ("sender", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("hops", "B"),
        ("flags", "B"),
        ("windings", "B"),
    ],
)
CAND = Layout(
    "cand",
    type=84,
    fields=[
        ("sender", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("index", "B"),
        ("version", "B"),
        ("windings", "B"),
    ],
)
VOTE = Layout(
    "vote",
    type=86,
    fields=[("sender", "H"), ("target", "H"), ("index", "B"), ("version", "B")],
)

#: CAND's ``index`` plus this: the candidates come from three or more anchors on (nearly) one
#: line, each within :func:`line_same_mm` of as far from both candidates (rule 2).
FROM_LINE = 2


class Spread:
    """Phase 2 on one robot: the frame's start (root, axis, third) and rules 1-4.

    The robot's position (``robot.position``) lives on the robot; this holds the attempt
    bookkeeping, the robot's own candidates and, on the root, the frame robots it named.
    """

    name = "spread"

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot
        p = robot.params
        tps = robot.ticks_per_s
        self.retry_ticks = p.retry_s * tps
        self.bootstrap_ticks = p.bootstrap_timeout_s * tps
        self.fresh_anchor_ticks = p.fresh_anchor_s * tps
        self.attempt: tuple = ()  # what the last attempt used
        self.next_retry = 0.0
        self.news_tick = robot.kilo_ticks  # last change of anchors or candidates
        # This robot's candidates: (version, [p0, p1]) or None, and the anchors they use.
        self.candidates: tuple[int, list[Point]] | None = None
        self.candidate_anchors: tuple[int, ...] | None = None
        self.candidate_version = -1  # the last version announced (-1: none yet)
        self.candidates_from_line = False  # from three or more anchors (CAND index + FROM_LINE)
        self.cand_turn = 0
        # The frame's start, as the root named it (on every robot that heard ROOT).
        self.axis = NO_ID
        self.third = NO_ID
        self.root_uid = NO_ID
        self.named_tick = 0.0
        self.excluded: set[int] = set()  # the root's frame robots that stayed silent
        self.frame_started = False  # on the root: its axis robot has placed itself
        # Rule 4: votes to send, (target, index, version); votes sent, by (target, version);
        # votes received for this robot's current candidates, {index: set of voters}.
        self.votes_out: list[tuple[int, int, int]] = []
        self.voted: dict[tuple[int, int], float] = {}
        self.votes_in: dict[int, set[int]] = {}

    # -- messages ------------------------------------------------------------------------------
    def message_tx(self) -> Message:
        """A VOTE if one is due; else ROOT on the root; otherwise CAND, CAND and POS in turn
        while holding candidates, else POS."""
        r = self.robot
        if self.votes_out:
            target, index, version = self.votes_out.pop()
            return VOTE.pack(sender=r.uid, target=target, index=index, version=version)
        if self.candidates is not None and r.position is None:
            self.cand_turn = (self.cand_turn + 1) % 3
            if self.cand_turn < 2:
                version, points = self.candidates
                x, y, windings = wrapped_position(*points[self.cand_turn])
                return CAND.pack(
                    sender=r.uid,
                    x_mm=x,
                    y_mm=y,
                    index=self.cand_turn + (FROM_LINE if self.candidates_from_line else 0),
                    version=version,
                    windings=windings,
                )
        return self.state_message()

    def state_message(self) -> Message:
        """ROOT on the root, else POS: position, hop count and flags."""
        r = self.robot
        if r.is_root:
            return ROOT.pack(sender=r.uid, axis=self.axis, third=self.third, flags=r.flags)
        x, y, windings = wrapped_position(*r.position) if r.position is not None else (0, 0, 0)
        return POS.pack(sender=r.uid, x_mm=x, y_mm=y, hops=r.hops, flags=r.flags, windings=windings)

    def root_rx(self, n: Neighbour, message: Message) -> None:
        m = ROOT.unpack(message)
        n.x_mm, n.y_mm, n.hops, n.flags = 0.0, 0.0, 0, m.flags | LOCALIZED
        n.placed_tick = -math.inf  # the origin by definition: never fresh
        r = self.robot
        named, renamed = (self.axis, self.third), (m.axis, m.third)
        if r.position is not None and r.uid in named and r.uid not in renamed:
            r.unlocate("renamed")  # the root started the frame without this robot
        self.root_uid, self.axis, self.third = m.sender, m.axis, m.third

    def pos_rx(self, n: Neighbour, message: Message) -> None:
        m = POS.unpack(message)
        n.hops, n.flags = m.hops, m.flags
        if m.flags & LOCALIZED:
            if n.x_mm is None:
                n.placed_tick = self.robot.kilo_ticks
            n.x_mm, n.y_mm = absolute_position(m.x_mm, m.y_mm, m.windings)
            n.candidates = None
        else:
            n.x_mm = n.y_mm = None
            n.placed_tick = None

    def cand_rx(self, n: Neighbour, message: Message) -> None:
        m = CAND.unpack(message)
        if n.candidates is None or n.candidates[0] != m.version:
            n.candidates = (m.version, [None, None])
        n.candidates_from_line = m.index >= FROM_LINE
        n.candidates[1][m.index % FROM_LINE] = absolute_position(m.x_mm, m.y_mm, m.windings)
        n.x_mm = n.y_mm = None
        n.placed_tick = None

    def vote_rx(self, n: Neighbour, message: Message) -> None:
        m = VOTE.unpack(message)
        if m.target != self.robot.uid:
            return
        # A vote is about one version of the candidates: an index means a side of one anchor
        # pair's line, and of another pair's it means nothing.
        if self.candidates is None or m.version != self.candidates[0]:
            return
        self.votes_in.setdefault(m.index, set()).add(m.sender)

    # -- rounds --------------------------------------------------------------------------------
    def round(self, tick: int, fresh: list[Neighbour]) -> None:
        """The root names its frame robots; the others try to fix their position."""
        r = self.robot
        if r.is_root:
            self._name_frame(tick, fresh)
        elif r.position is None:
            self._locate(tick, fresh)
        if r.position is not None:
            self._vote(tick, fresh)

    def _vote(self, tick: int, fresh: list[Neighbour]) -> None:
        """Rule 4: vote on the candidate pairs of neighbours (again after ``retry_s``)."""
        others = None
        for n in fresh:
            held = n.candidates
            if held is None or None in held[1] or n.x_mm is not None:
                continue
            key = (n.uid, held[0])
            if tick < self.voted.get(key, -1.0):
                continue
            self.voted[key] = tick + self.retry_ticks
            if others is None:
                others = [(m.x_mm, m.y_mm) for m in fresh if m.x_mm is not None]
                settled = [
                    (m.x_mm, m.y_mm) for m in fresh if m.x_mm is not None and m.flags & SETTLED
                ]
            p = self.robot.params
            index = overlap_vote(
                tuple(held[1]),
                others,
                p.overlap_mm,
                settled=settled,
                heard_mm=p.heard_mm,
                same_mm=line_same_mm(p.min_height_mm) if n.candidates_from_line else 5.0,
            )
            if index is not None:
                self.votes_out.append((n.uid, index, held[0]))

    def _name_frame(self, tick: int, fresh: list[Neighbour]) -> None:
        by_id = {n.uid: n for n in fresh}
        placed = [by_id.get(u) for u in (self.axis, self.third)]
        self.frame_started |= placed[0] is not None and placed[0].x_mm is not None
        if all(n is not None and n.x_mm is not None for n in placed):
            return
        if self.axis != NO_ID and tick - self.named_tick < self.bootstrap_ticks:
            return
        axis_placed = placed[0] is not None and placed[0].x_mm is not None
        if self.axis != NO_ID:  # the named robots did not all place themselves in time
            self.excluded.add(self.third)
            if not axis_placed:
                self.excluded.add(self.axis)
        usable = {n.uid: n.range_mm for n in fresh if n.uid not in self.excluded}
        reports = {u: self.robot.reports.get(u, {}) for u in usable}
        chosen = choose_frame(
            usable,
            reports,
            self.robot.params.min_height_mm,
            axis=self.axis if axis_placed else None,
            margin_mm=self.robot.sigma_mm,
        )
        if chosen is not None:
            self.axis, self.third = chosen
            self.named_tick = tick
            self.robot.log("frame_named", axis=self.axis, third=self.third)

    def _locate(self, tick: int, fresh: list[Neighbour]) -> None:
        """One attempt of an unplaced robot (not the root) to fix its position from the
        neighbours heard this round (``fresh``), at ``tick`` on its clock.

        A named axis or third robot first tries the frame's start. Otherwise the attempt waits
        while exactly three anchors include one placed moments ago (rule 1's patience), and
        runs only when its anchors or neighbours' candidate pairs changed or ``retry_s`` has
        passed; it then tries rule 1 (all anchors, then a consistent subset), rule 3 (with
        neighbours' candidates, when allowed), and failing those holds rule 2's candidates and
        takes one if rule 4's votes single it out. Why each rule is trusted:
        :mod:`kilonet.protocols.localize.spread_rules`."""
        r = self.robot
        uid = r.uid
        if uid == self.axis or uid == self.third:
            self._start_frame(fresh)
            if r.position is not None:
                return
        anchors = [n for n in fresh if n.x_mm is not None]
        if anchors_fresh([n.placed_tick for n in anchors], tick, self.fresh_anchor_ticks):
            self.news_tick = tick  # an anchor placed moments before is news: not quiet
            return
        pairs = [
            n
            for n in fresh
            if n.x_mm is None and n.candidates is not None and None not in n.candidates[1]
        ]
        attempt = (
            tuple(n.uid for n in anchors),
            tuple((n.uid, n.candidates[0]) for n in pairs),
        )
        if attempt != self.attempt:
            self.attempt = attempt
            self.news_tick = tick
        elif tick < self.next_retry:
            return
        self.next_retry = tick + self.retry_ticks
        points = [(n.x_mm, n.y_mm) for n in anchors]
        ranges = [n.range_mm for n in anchors]
        sigma = r.sigma_mm
        max_rmse = r.params.max_residual_sigmas * sigma
        side_in_doubt = False
        if len(anchors) >= 3:
            fix = multilaterate(
                np.array(points),
                np.array(ranges),
                sigma_mm=sigma,
                max_rmse_mm=max_rmse,
                min_anchor_width_mm=r.params.min_height_mm,
            )
            if fix.ok and side_is_clear(fix, sigma):
                self.place(fix.x_mm, fix.y_mm, "anchors", len(anchors), anchors)
                return
            if fix.reason == "large_residual":
                found = consistent_subset_fix(
                    points,
                    ranges,
                    sigma_mm=sigma,
                    max_rmse_mm=max_rmse,
                    min_width_mm=r.params.min_height_mm,
                )
                if found is not None:
                    fix, kept = found
                    used = [anchors[k] for k in kept]
                    dropped = [
                        [
                            n.uid,
                            round(
                                math.dist((fix.x_mm, fix.y_mm), (n.x_mm, n.y_mm)) - n.range_mm, 1
                            ),
                        ]
                        for k, n in enumerate(anchors)
                        if k not in kept
                    ]
                    self.place(fix.x_mm, fix.y_mm, "subset", len(used), used, dropped=dropped)
                    return
            # Anchors that fix all but the side (one line, or a mirror image that fits within
            # the noise): the two sides are candidates, as with two anchors. Not a fix whose
            # side only its large residuals put in doubt: its anchors disagree, and candidates
            # from them would be no better.
            side_in_doubt = fix.reason in ("collinear_anchors", "mirror_ambiguity")
        if pairs and r.params.max_candidate_neighbours:
            # The pairs farthest apart discriminate best.
            pairs.sort(key=lambda n: -separation(n.candidates[1]))
            pairs = pairs[: r.params.max_candidate_neighbours]
            fix = fix_with_candidates(
                points,
                ranges,
                [tuple(n.candidates[1]) for n in pairs],
                [n.range_mm for n in pairs],
                sigma_mm=sigma,
                max_rmse_mm=max_rmse,
                min_width_mm=r.params.min_height_mm,
            )
            if fix is not None:
                self.place(fix.x_mm, fix.y_mm, "candidates", len(anchors) + len(pairs), anchors)
                return
        self._update_candidates(anchors, side_in_doubt)
        self._take_vote(anchors)

    def _take_vote(self, anchors: list[Neighbour]) -> None:
        """Rule 4: take the candidate the votes allow, if they allow exactly one."""
        if self.candidates is None:
            return
        allowed = [k for k in (0, 1) if self.votes_in.get(k)]
        if len(allowed) == 1:
            x, y = self.candidates[1][allowed[0]]
            self.place(x, y, "vote", len(anchors), anchors)

    def _start_frame(self, fresh: list[Neighbour]) -> None:
        """Place the axis robot on +x, or the third robot above it."""
        by_id = {n.uid: n for n in fresh}
        root = by_id.get(self.root_uid)
        if root is None:
            return
        r = self.robot
        if r.uid == self.axis:
            self.place(root.range_mm, 0.0, "axis", 1)
            return
        axis = by_id.get(self.axis)
        if axis is None or axis.x_mm is None:
            return
        try:
            _, (x, y) = place_references(axis.x_mm, root.range_mm, axis.range_mm)
        except GeometryError:
            return
        self.place(x, y, "third", 2)

    def _update_candidates(self, anchors: list[Neighbour], side_in_doubt: bool = False) -> None:
        """With exactly two anchors, or three or more that fix all but the side
        (``side_in_doubt``: rule 1 refused them as one line or for a mirror image that fits as
        well), hold (and announce) the two candidate positions (:func:`mirror_candidates`)."""
        found = None
        if len(anchors) == 2:
            a, b = anchors
            found = circle_candidates((a.x_mm, a.y_mm), (b.x_mm, b.y_mm), a.range_mm, b.range_mm)
            key = (a.uid, b.uid)
        elif side_in_doubt and len(anchors) >= 3:
            p = self.robot.params
            got = mirror_candidates(
                [(n.x_mm, n.y_mm) for n in anchors],
                [n.range_mm for n in anchors],
                max_rmse_mm=p.max_residual_sigmas * self.robot.sigma_mm,
                max_skew_mm=line_same_mm(p.min_height_mm),
            )
            if got is not None:
                found = got[:3]
                i, j = got[3]
                # The pair orients the indices: a new pair is a new version.
                key = (*(n.uid for n in anchors), anchors[i].uid, anchors[j].uid)
        if found is None or found[2] < self.robot.params.min_height_mm:
            self.candidates = None
            self.candidate_anchors = None
            return
        version = candidate_version(self.candidate_version, self.candidate_anchors, key)
        if version != self.candidate_version:
            self.votes_in = {}  # votes about other candidates
        self.candidate_version = version
        self.candidate_anchors = key
        self.candidates = (version, [found[0], found[1]])
        self.candidates_from_line = len(anchors) > 2

    def place(
        self,
        x_mm: float,
        y_mm: float,
        rule: str,
        anchors: int,
        references: Sequence[Neighbour] = (),
        **extra: object,
    ) -> None:
        """Take the position (x, y) in the frame, mm, found by ``rule`` from ``anchors``
        placed points; one beyond the messages' coordinate range is refused.

        The ``located`` event logs the rule, the count and ``references``: the placed
        neighbours the fix used, ``[uid, x_mm, y_mm]`` each as this robot held them (0.1 mm),
        so that a run's analysis can tell a wrong fix from a right fix on wrong anchors."""
        if abs(x_mm) > MAX_COORDINATE_MM or abs(y_mm) > MAX_COORDINATE_MM:
            self.robot.log("out_of_frame", x_mm=x_mm, y_mm=y_mm)
            return
        self.candidates = None
        self.robot.locate(x_mm, y_mm)
        held = [[n.uid, round(n.x_mm, 1), round(n.y_mm, 1)] for n in references]
        self.robot.log(
            "located", rule=rule, anchors=anchors, x_mm=x_mm, y_mm=y_mm, references=held, **extra
        )
