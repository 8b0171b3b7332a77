"""Phase 7 of the global coordinate system (``gcs.refine = true``): the swarm refines its merged
estimates, as ``localize`` does.

Merging (phase 6) leaves every robot with a global estimate made of local fixes and half-way
transforms; its errors compound from frame to frame. Here each robot starts from that estimate
and keeps improving it from its neighbours' broadcast global positions and the distances both
ends measured, by the refinement of :mod:`kilonet.protocols.common.refinement` (robust Gauss–Newton
steps with momentum, the symmetric DIST reports): the swarm descends on the least-squares stress of
every measured pair. Nothing is anchored: the stress does not change under a rigid motion of the
whole frame, so the frame keeps where merging put it, up to a small drift.

**Entering.** Merging's window never closes; a robot enters this phase when merging is
over *for it* (:meth:`kilonet.protocols.gcs.phase6_merging.FrameMerging.finished`): its estimate has
been settled, and the seed of every frame it is located in done, for ``gcs.refine_after_s``, no
recovery is announced or awaited, and, on a seed, its own rounds are done. A robot without a
settled estimate keeps merging — until the re-placement wave (below) reaches it: a merging
robot that hears three placed neighbours in one frame at least as good as its own
(:func:`wave_reached`) enters at once, whatever holds its merging back, and the wave places
it. Without this, robots that a recovery epoch sent back to merging and whose estimate never
settled there (it disagreed with the neighbours', so the split check kept flagging them) kept
merged estimates hundreds of mm off beside a placed swarm.

**Merging goes on**, its split check does not (:mod:`kilonet.protocols.gcs.split_detection`: the
placed positions replace the estimates it compares). A refining robot keeps its part in merging: it
still tracks the seeds' transforms and ranks and answers their queries, and a seed still runs
its rounds (every other transmit opportunity is merging's). When merging moves the merged
estimate of a robot not yet placed by more than ``_FOLLOW_MM``, its estimate moves by as much;
when merging aligns its frame to a better root, the robot takes the new merged estimate,
unplaced, and waits for that root's wave. Without this, robots that entered the refinement
early kept estimates of an older version of their frame, and merging lost the members that
answer its queries.

**The re-placement wave.** Merging's estimate carries errors that compound from frame to
frame (per-hop rotation errors); a refinement started from it removes their long wavelengths
only slowly. So the refinement starts over from the root: a robot located in its merged root's
own local frame (the root's seed and that frame's members) takes its position from that frame
alone and is *placed*; every other robot keeps its merged estimate, unrefined, until it hears
three placed neighbours in its frame, and then places itself from their positions and its
measured distances by multilateration (:func:`~kilonet.protocols.common.geometry.multilaterate`,
with phase 4's collinearity, residual and mirror checks) — the spread of ``localize``, outward from
the root at the pace of messages. Only placed robots refine, and only against placed neighbours
(their GPOS_PLACED and GPOS_SETTLED messages). A robot the wave cannot place keeps its merged
estimate and stops once the placed robots around it have.

**Neighbours.** Only neighbours whose estimate is in the same merged frame (the same root)
count: their GPOS messages name the root. A neighbour still merging that broadcasts a settled
position (split detection's POS, with the same root, in 0.5 mm) will usually join shortly, and
holds a robot's stopping back — for the first ``2 · gcs.refine_after_s`` of the robot's
refinement only: a settled robot that has not left merging by then is held there by something
else (a split awaiting its recovery) and may never come.

**Joining a better frame.** Merging may leave the swarm in several frames. A refining robot
that hears at least three placed neighbours whose estimates lie in a frame with a better root
(:class:`~kilonet.protocols.gcs.frame_keys.Root` order, the one merging uses) places itself in that
frame by multilateration from their positions and its measured distances
(:func:`~kilonet.protocols.common.geometry.multilaterate`, with the collinearity, residual and
mirror checks
phase 4 uses) and refines there from then on (:func:`frame_to_join` picks the frame). A robot
that merging left without an estimate joins the same way. Roots only get better, so the frames
are absorbed one robot at a time into the best root that a rigid chain of neighbours reaches,
and no robot joins back and forth.

**Stopping.** A robot is *settled* when it moved less than ``gcs.refine_settle_mm`` over its last
``gcs.refine_settle_rounds`` rounds, relative to the centroid of its neighbours (a small frame
drifting as a whole never stops moving on the table, but its robots stop moving against each
other); with no hop structure to climb, it stops (*done*: its
estimate frozen, still announced as settled) when it and every neighbour it refines
against have been settled for ``_CONFIRM_ROUNDS`` rounds in a row and no settled merging
neighbour is still to join (:func:`~kilonet.protocols.common.refinement.neighbourhood_settled`). A
robot that does not stop within ``gcs.refine_timeout_s`` stops anyway (the phase's window).

Messages (one transmit opportunity in ``_DIST_EVERY`` carries a DIST report of
:mod:`kilonet.protocols.common.refinement`, with the global position, 0.1 mm)::

    type 73 GPOS          sender:uint16  x:int16  y:int16 (0.1 mm)  root:uint16  salt:uint8
    type 75 GPOS_PLACED   the same, from a robot the wave has placed               9 bytes
    type 74 GPOS_SETTLED  the same, from a placed robot that has settled or is done

``root`` and ``salt`` are the wire ID and salt of the merged frame's root
(:meth:`kilonet.protocols.gcs.frame_keys.Root.from_wire`): the whole root, so a robot that joins a
frame names it as merging does. Coordinates span ±3,276.7 mm: a robot whose estimate lies beyond
stays silent.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from kilonet.message import Message
from kilonet.protocols.common.geometry import multilaterate
from kilonet.protocols.common.refinement import (
    DIST,
    DISTANCE_STEP_MM,
    Refiner,
    agreed_range_mm,
    distance_code,
    neighbourhood_settled,
    next_report,
    unwrap_distance,
)
from kilonet.protocols.gcs.base import LAYOUTS, SENDER, GcsParams, GcsStage, Phase
from kilonet.protocols.gcs.frame_keys import Root
from kilonet.protocols.gcs.replacement_wave import (
    GPOS,
    GPOS_PLACED,
    GPOS_SETTLED,
    STALE_S,
    PlacedNeighbours,
    wave_reached,
)
from kilonet.protocols.gcs.split_detection import POS

if TYPE_CHECKING:
    from collections.abc import Iterable

    from kilonet.protocols.common.neighbours import Neighbour

__all__ = [
    "GPOS",
    "GPOS_PLACED",
    "GPOS_SETTLED",
    "GlobalRefinement",
    "Peer",
    "PlacedNeighbours",
    "frame_to_join",
    "wave_reached",
]

LAYOUTS.add(DIST)  # the refinement's distance reports are the protocol's too
#: Largest coordinate GPOS and DIST carry, mm.
_LIMIT_MM = 3276.7
#: One transmit opportunity in this many carries a DIST report.
_DIST_EVERY = 3
#: Rounds that the stopping rule must hold in a row.
_CONFIRM_ROUNDS = 3
#: The refined estimate follows a move of the merged one in the same frame once it exceeds
#: this, mm: smaller ones are merging's jitter about its agreed transforms, which the
#: refinement corrects anyway (following each restarted the settling).
_FOLLOW_MM = 2.0
#: A robot that failed to join a frame tries again with the same anchors after this many
#: rounds (their positions are being refined meanwhile).
_JOIN_RETRY_ROUNDS = 10
#: The refinement's robustness: residuals beyond this count less, mm; and its largest step, mm.
_HUBER_MM = 3.0
_MAX_STEP_MM = 5.0


def frame_to_join(
    own: Root | None, anchors: Iterable[tuple[Root, float, float, float]]
) -> tuple[Root, list[tuple[float, float, float]]] | None:
    """The frame a refining robot in frame ``own`` (``None``: it has no estimate) should try to
    join, and its anchors there: of the frames with a better root than ``own`` that at least
    three of ``anchors`` — ``(root, x_mm, y_mm, range_mm)`` of each neighbour with an estimate —
    lie in, the best; ``None`` if there is none. The best, not the one with most anchors: every
    robot then heads for the same frame, and roots only get better.

    Examples
    --------
    >>> from kilonet.protocols.gcs.frame_keys import FrameKey
    >>> a, b = Root(False, FrameKey(3, 9)), Root(False, FrameKey(5, 1))
    >>> heard = [(a, 0.0, 0.0, 40.0), (a, 40.0, 0.0, 40.0), (b, 0.0, 9.0, 30.0)]
    >>> frame_to_join(b, heard) is None  # two anchors in the better frame: not enough
    True
    >>> root, links = frame_to_join(b, [*heard, (a, 20.0, 35.0, 38.0)])
    >>> root == a, len(links)
    (True, 3)
    >>> frame_to_join(a, [*heard, (a, 20.0, 35.0, 38.0)]) is None  # already in the best
    True
    """
    by_root: dict[Root, list[tuple[float, float, float]]] = {}
    for root, x_mm, y_mm, range_mm in anchors:
        if own is None or root < own:
            by_root.setdefault(root, []).append((x_mm, y_mm, range_mm))
    joinable = [root for root, links in by_root.items() if len(links) >= 3]
    if not joinable:
        return None
    best = min(joinable)
    return best, by_root[best]


class Peer:
    """What a refining robot knows about one neighbour: its announced global position, root and
    whether it has settled, and the distance reports between the two (the interface
    :func:`~kilonet.protocols.common.refinement.next_report` reads).

    Parameters
    ----------
    uid : int
        The neighbour's ID.
    record : kilonet.protocols.common.neighbours.Neighbour
        The robot's neighbour-table record of it (the mean distance, from every reception).
    """

    __slots__ = (
        "ambiguous",
        "heard_tick",
        "joining",
        "placed",
        "record",
        "reported_mm",
        "root",
        "sent_mm",
        "sent_round",
        "settled",
        "uid",
        "x_mm",
        "y_mm",
    )

    def __init__(self, uid: int, record: Neighbour) -> None:
        self.uid = uid
        self.record = record
        self.ambiguous = False
        self.x_mm: float | None = None
        self.y_mm: float | None = None
        self.root: Root | None = None
        self.settled = False  # settled or done
        self.placed = False  # placed by the re-placement wave
        self.joining = False  # merging, with a settled position (POS)
        self.heard_tick = 0
        self.sent_mm: float | None = None
        self.sent_round = -1
        self.reported_mm: float | None = None

    @property
    def samples(self) -> int:
        """Receptions the mean distance averages."""
        return self.record.samples

    @property
    def mean_mm(self) -> float:
        """This robot's mean measured distance to the neighbour, mm."""
        return self.record.mean_mm

    @property
    def range_mm(self) -> float:
        """The distance both ends fit
        (:func:`~kilonet.protocols.common.refinement.agreed_range_mm`), mm."""
        return agreed_range_mm(self.record.mean_mm, self.sent_mm, self.reported_mm)


class GlobalRefinement(Phase):
    """Phase 7 on one robot: refine the global estimate until the neighbourhood has settled,
    joining a better frame when one is in reach.

    Attributes
    ----------
    position : (float, float) or None
        The refined estimate, mm (None: the robot has no estimate yet).
    root : Root or None
        The merged frame the estimate is in.
    done : bool
        The robot has stopped refining.
    """

    __slots__ = (
        "_base",
        "_confirmed",
        "_join_until",
        "_next_round",
        "_round",
        "_round_ticks",
        "_stale_ticks",
        "_tried",
        "_turn",
        "done",
        "merging",
        "peers",
        "placed",
        "position",
        "refiner",
        "root",
    )
    name = GcsStage.REFINE
    open_ended = True  # until the robots settle

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's time-out, ``gcs.refine_timeout_s``: it ends earlier by itself."""
        return p.refine_timeout_s

    def start(self) -> None:
        r, p = self.robot, self.params
        tps = r.ticks_per_s
        self.peers: dict[int, Peer] = {}
        self.position = r.estimate.position()
        self.root = r.estimate.root() if self.position is not None else None
        self.merging = r.merging  # merging goes on beside the refinement
        # The merged estimate the refined one follows: (position, root).
        self._base = (self.position, self.root)
        self.refiner = Refiner(
            huber_mm=_HUBER_MM,
            max_step_mm=_MAX_STEP_MM,
            momentum=p.refine_momentum,
            settle_mm=p.refine_settle_mm,
            settle_rounds=p.refine_settle_rounds,
        )
        self._round_ticks = p.refine_round_s * tps
        self._stale_ticks = STALE_S * tps
        self._join_until = r.kilo_ticks + 2 * p.refine_after_s * tps
        self._next_round = 0.0
        self._round = 0
        self._turn = 0
        self._confirmed = 0
        # The last attempt to place this robot in each frame: {root: (anchors, round)}.
        self._tried: dict[Root, tuple[int, int]] = {}
        self.done = self.position is None
        self.placed = False
        r.refined = self.position
        r.refined_root = self.root
        self._start_wave()

    def finish(self) -> None:
        if not self.done:
            self._stop("timeout")

    def _stop(self, cause: str) -> None:
        self.done = True
        self.robot.log("refine_done", cause=cause, rounds=self._round)

    # -- rounds ----------------------------------------------------------------------------
    def loop(self) -> None:
        r = self.robot
        if self.merging is not None:
            self.merging.loop()
        tick = r.kilo_ticks
        if tick < self._next_round:
            return
        self._next_round = tick + self._round_ticks
        self._round += 1
        self._follow_merging()
        oldest = tick - self._stale_ticks
        fresh = [n for n in self.peers.values() if n.heard_tick >= oldest]
        self._join(fresh)
        if not self.placed:
            self._place(fresh)
        if self.done:
            return
        root = self.root
        same = [n for n in fresh if n.placed and n.root == root and n.x_mm is not None]
        if self.placed:
            x, y = self.position
            links = [(n.x_mm, n.y_mm, n.range_mm) for n in same]
            # Nothing anchors the frame: settled means still against the neighbours.
            origin = (
                (sum(n.x_mm for n in same) / len(same), sum(n.y_mm for n in same) / len(same))
                if same
                else (0.0, 0.0)
            )
            self.position = self.refiner.step(x, y, links, origin=origin)
            r.refined = self.position
            settled = self.refiner.settled
        else:
            # One the wave cannot place keeps its merged estimate and stops with the placed
            # robots around it (it is placed after all if more of them turn up).
            settled = bool(same)
        joining = tick < self._join_until and any(n.joining for n in fresh)
        stop = neighbourhood_settled(settled, (n.settled for n in same))
        self._confirmed = self._confirmed + 1 if stop and not joining else 0
        if self._confirmed >= _CONFIRM_ROUNDS:
            self._stop("settled")

    def _follow_merging(self) -> None:
        """Move with the merged estimate: by as much as merging moved it in the same frame, or
        to it when merging put it in a better frame than the refined one's."""
        estimate = self.robot.estimate
        merged = estimate.position()
        if merged is None:
            return
        root = estimate.root()
        base, base_root = self._base
        if root == base_root and base is not None:
            dx, dy = merged[0] - base[0], merged[1] - base[1]
            if dx * dx + dy * dy < _FOLLOW_MM**2:
                return  # merging's own jitter, which the refinement corrects
        self._base = (merged, root)
        if self.root is None or root < self.root:
            self._move(merged, root, "merged", placed=False)
            self._start_wave()
        elif root == self.root == base_root and base is not None and not self.placed:
            x, y = self.position
            self.position = (x + dx, y + dy)
            self.robot.refined = self.position
            self.refiner.reset()
            self._confirmed = 0
            self.done = False

    def _move(self, position: tuple[float, float], root: Root, how: str, *, placed: bool) -> None:
        """The estimate is now ``position`` in frame ``root`` (joined, placed, or merged
        there); ``placed``: by the re-placement wave."""
        r = self.robot
        r.log("refine_moved", how=how, root=root.label, x_mm=position[0], y_mm=position[1])
        self.position, self.root, self.placed = position, root, placed
        self.refiner.reset()
        self._confirmed = 0
        self._tried.clear()
        self.done = False
        r.refined, r.refined_root = position, root

    def _start_wave(self) -> None:
        """A robot located in its merged root's own frame (the root's seed and the members of
        its local frame) starts the re-placement wave: it takes its position from that frame
        alone, free of the transforms merging compounded."""
        if self.root is None:
            return
        own = self.robot.estimate.position_in(self.root.key)
        if own is not None:
            self.position, self.placed = own, True
            self.robot.refined = own

    def _place(self, fresh: list[Peer]) -> None:
        """The re-placement wave: with three placed neighbours in its frame, a robot places
        itself from their positions and its measured distances, as ``localize`` spreads."""
        if self.root is None:
            return
        links = [
            (n.x_mm, n.y_mm, n.range_mm)
            for n in fresh
            if n.placed and n.root == self.root and n.x_mm is not None
        ]
        fix = self._fix(self.root, links, "place_rejected")
        if fix is not None:
            self._move(fix, self.root, "placed", placed=True)

    def _join(self, fresh: list[Peer]) -> None:
        """Move into the best frame :func:`frame_to_join` names from its placed robots, if
        the fix passes its checks."""
        heard = (
            (n.root, n.x_mm, n.y_mm, n.range_mm) for n in fresh if n.placed and n.root is not None
        )
        choice = frame_to_join(self.root, heard)
        if choice is None:
            return
        root, links = choice
        fix = self._fix(root, links, "join_rejected")
        if fix is not None:
            self._move(fix, root, "joined", placed=True)

    def _fix(
        self, root: Root, links: list[tuple[float, float, float]], rejected: str
    ) -> tuple[float, float] | None:
        """Multilaterate in frame ``root`` from ``links`` (x, y, range, mm) with phase 4's
        checks; ``None`` with fewer than three, when they fail (logged as ``rejected``), or
        while a failed attempt waits for more anchors or ``_JOIN_RETRY_ROUNDS``."""
        if len(links) < 3:
            return None
        tried = self._tried.get(root)
        if (
            tried is not None
            and len(links) <= tried[0]
            and self._round - tried[1] < _JOIN_RETRY_ROUNDS
        ):
            return None
        self._tried[root] = (len(links), self._round)
        p = self.params
        points = np.array(links)
        fix = multilaterate(
            points[:, :2], points[:, 2], sigma_mm=p.sigma_mm, max_rmse_mm=p.max_rmse_mm
        )
        if not fix.ok:
            self.robot.log(rejected, root=root.label, reason=fix.reason, anchors=len(links))
            return None
        return fix.x_mm, fix.y_mm

    # -- messages --------------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        self._turn += 1
        merging = self.merging
        if merging is not None and (merging.seed is None or self._turn % 2):
            message = merging.message_tx()  # answers and hints are rare; a seed's are not
            if message is not None:
                return message
        if self.position is None:
            return None
        x, y = self.position
        if abs(x) > _LIMIT_MM or abs(y) > _LIMIT_MM:
            return None
        r = self.robot
        if self._turn % _DIST_EVERY == 0:
            n = next_report(self.peers.values())
            if n is not None:
                n.sent_mm = round(n.mean_mm / DISTANCE_STEP_MM) * DISTANCE_STEP_MM
                n.sent_round = self._round
                return DIST.pack(
                    sender=r.uid,
                    x_mm=x,
                    y_mm=y,
                    neighbour=n.uid,
                    distance=distance_code(n.mean_mm),
                )
        if not self.placed:
            layout = GPOS
        else:
            layout = GPOS_SETTLED if self.done or self.refiner.settled else GPOS_PLACED
        root = self.root
        return layout.pack(sender=r.uid, x_mm=x, y_mm=y, root=root.wire_id, salt=root.key.salt)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if self.merging is not None:
            self.merging.message_rx(message, distance_mm)
        kind = message.type
        if kind not in _HEARD:
            return
        r = self.robot
        (sender,) = SENDER.unpack_from(message.data)
        if sender == r.uid:
            return
        n = self.peers.get(sender)
        if n is None:
            record = r.table.get(sender)
            if record is None:  # not heard before: the table records it after this call
                return
            n = self.peers[sender] = Peer(sender, record)
        if kind == POS.type:  # merging, settled: a fixed position, and it may join
            m = POS.unpack(message)
            n.x_mm, n.y_mm = m.x_mm, m.y_mm
            n.root, n.settled = Root.from_wire(m.root, m.root_salt), True
            n.joining, n.placed = True, False
        elif kind == DIST.type:
            m = DIST.unpack(message)
            if n.root is not None:  # its root is known from a GPOS: the position is usable
                n.x_mm, n.y_mm = m.x_mm, m.y_mm
            if m.neighbour == r.uid:
                n.reported_mm = unwrap_distance(m.distance, n.mean_mm)
        else:
            m = _GPOS_LAYOUTS[kind].unpack(message)
            n.x_mm, n.y_mm = m.x_mm, m.y_mm
            n.root, n.settled = Root.from_wire(m.root, m.salt), kind == GPOS_SETTLED.type
            n.joining, n.placed = False, kind != GPOS.type
        n.heard_tick = r.kilo_ticks


#: The global positions by message type.
_GPOS_LAYOUTS = {layout.type: layout for layout in (GPOS, GPOS_PLACED, GPOS_SETTLED)}
#: The messages a refining robot reads.
_HEARD = frozenset((*_GPOS_LAYOUTS, DIST.type, POS.type))
