"""Phase 7 of the global coordinate system (``gcs.refine = true``): the swarm refines its merged
estimates, as ``localize`` does.

Merging (phase 6) leaves every robot with a global estimate made of local fixes and half-way
transforms; its errors compound from frame to frame. Here each robot starts from that estimate
and keeps improving it from its neighbours' broadcast global positions and the distances both
ends measured, by the refinement of :mod:`protocols.refinement` (robust Gauss–Newton steps with
momentum, the symmetric DIST reports): the swarm descends on the least-squares stress of every
measured pair. Nothing is anchored: the stress does not change under a rigid motion of the
whole frame, so the frame keeps where merging put it, up to a small drift.

**Entering.** Merging's window never closes; a robot leaves it for this phase when merging is
over *for it* (:meth:`protocols.frame_merging.FrameMerging.finished`): its estimate has been
settled, and the seed of every frame it is located in done, for ``gcs.refine_after_s``, no
recovery is announced or awaited, and, on a seed, its own rounds are done. A robot without a
settled estimate never refines (it keeps merging).

**Neighbours.** Only neighbours whose estimate is in the same merged frame (the same root)
count: their GPOS messages name the root. A neighbour still merging that broadcasts a settled
position (split detection's POS, with the same root, in 0.5 mm) counts as a fixed one: the
refined robots stay tied to the estimates merging left around them (without it, the refined
part of a frame could drift as a whole against the rest, and the frame's error would grow).
It will usually join shortly, and holds a robot's stopping back — for the first
``2 · gcs.refine_after_s`` of the robot's refinement only: a settled robot that has not left
merging by then is held there by something else (a split awaiting its recovery) and may never
come.

**Stopping.** A robot is *settled* when it moved less than ``gcs.refine_settle_mm`` over its last
``gcs.refine_settle_rounds`` rounds, relative to the centroid of its neighbours (a small frame
drifting as a whole never stops moving on the table, but its robots stop moving against each
other); with no hop structure to climb, it stops (*done*: its
estimate frozen, still announced with the DONE flag) when it and every neighbour it refines
against have been settled for ``_CONFIRM_ROUNDS`` rounds in a row and no settled merging
neighbour is still to join (:func:`~protocols.refinement.neighbourhood_settled`). A robot that
does not stop within ``gcs.refine_timeout_s`` stops anyway (the phase's window).

Messages (one transmit opportunity in ``_DIST_EVERY`` carries a DIST report of
:mod:`protocols.refinement`, with the global position, 0.1 mm)::

    type 73 GPOS  sender:uint16  x:int16  y:int16 (0.1 mm)  root:uint16  flags:uint8   9 bytes

``root`` is the wire ID of the merged frame's root (:class:`protocols.frame_keys.Root`); the low
two bits of ``flags`` are SETTLED (1) and DONE (2), the other six the low six bits of the root's
salt. Coordinates span ±3,276.7 mm: a robot whose estimate lies beyond stays silent.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from kilonet.message import Message
from protocols.gcs_base import SENDER, GcsParams, Phase, gcs_layout
from protocols.refinement import (
    DIST,
    DISTANCE_STEP_MM,
    Refiner,
    agreed_range_mm,
    distance_code,
    neighbourhood_settled,
    next_report,
    unwrap_distance,
)
from protocols.split_detection import POS

if TYPE_CHECKING:
    from protocols.frame_keys import Root
    from protocols.neighbours import Neighbour

__all__ = ["DONE", "GPOS", "SETTLED", "GlobalRefinement", "Peer", "root_tag"]

GPOS = gcs_layout(
    "gpos",
    type=73,
    fields=[("x_mm", "h", 0.1), ("y_mm", "h", 0.1), ("root", "H"), ("flags", "B")],
)
#: GPOS flags: the sender has settled; the sender is done (its estimate is frozen).
SETTLED = 1
DONE = 2
_FLAG_BITS = 0b11
#: Largest coordinate GPOS and DIST carry, mm.
_LIMIT_MM = 3276.7
#: One transmit opportunity in this many carries a DIST report.
_DIST_EVERY = 3
#: Rounds that the stopping rule must hold in a row.
_CONFIRM_ROUNDS = 3
#: A neighbour silent this long is left out, s (it crashed, was removed, or merges again).
_STALE_S = 3.0
#: The refinement's robustness: residuals beyond this count less, mm; and its largest step, mm.
_HUBER_MM = 3.0
_MAX_STEP_MM = 5.0


def root_tag(root: Root) -> tuple[int, int]:
    """How GPOS names a merged frame's root: its wire ID and the low six bits of its salt.

    Examples
    --------
    >>> from protocols.frame_keys import FrameKey, Root
    >>> root_tag(Root(edge=False, key=FrameKey(7, 0xC5)))
    (7, 5)
    """
    return root.wire_id, root.key.salt & 0x3F


class Peer:
    """What a refining robot knows about one neighbour: its announced global position, root and
    flags, and the distance reports between the two (the interface
    :func:`~protocols.refinement.next_report` reads).

    Parameters
    ----------
    uid : int
        The neighbour's ID.
    record : protocols.neighbours.Neighbour
        The robot's neighbour-table record of it (the mean distance, from every reception).
    """

    __slots__ = (
        "ambiguous",
        "flags",
        "heard_tick",
        "joining",
        "record",
        "reported_mm",
        "root",
        "sent_mm",
        "sent_round",
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
        self.root: tuple[int, int] | None = None
        self.flags = 0
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
        return self.record.distance_mm

    @property
    def range_mm(self) -> float:
        """The distance both ends fit (:func:`~protocols.refinement.agreed_range_mm`), mm."""
        return agreed_range_mm(self.record.distance_mm, self.sent_mm, self.reported_mm)


class GlobalRefinement(Phase):
    """Phase 7 on one robot: refine the global estimate until the neighbourhood has settled.

    Attributes
    ----------
    position : (float, float) or None
        The refined estimate, mm (None: the robot had no estimate to refine).
    done : bool
        The robot has stopped refining.
    """

    __slots__ = (
        "_confirmed",
        "_join_until",
        "_next_round",
        "_round",
        "_round_ticks",
        "_stale_ticks",
        "_turn",
        "done",
        "peers",
        "position",
        "refiner",
        "root",
        "tag",
    )
    name = "refine"

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's time-out, ``gcs.refine_timeout_s``: it ends earlier by itself."""
        return p.refine_timeout_s

    def start(self) -> None:
        r, p = self.robot, self.params
        tps = r.ticks_per_s
        self.peers: dict[int, Peer] = {}
        self.position = r.estimate.position()
        self.root = r.estimate.root()
        self.tag = root_tag(self.root) if self.root is not None else None
        self.refiner = Refiner(
            huber_mm=_HUBER_MM,
            max_step_mm=_MAX_STEP_MM,
            momentum=p.refine_momentum,
            settle_mm=p.refine_settle_mm,
            settle_rounds=p.refine_settle_rounds,
        )
        self._round_ticks = p.refine_round_s * tps
        self._stale_ticks = _STALE_S * tps
        self._join_until = r.kilo_ticks + 2 * p.refine_after_s * tps
        self._next_round = 0.0
        self._round = 0
        self._turn = 0
        self._confirmed = 0
        self.done = self.position is None
        r.refined = self.position

    def finish(self) -> None:
        if not self.done:
            self._stop("timeout")

    def _stop(self, cause: str) -> None:
        self.done = True
        self.robot.log("refine_done", cause=cause, rounds=self._round)

    # -- rounds ----------------------------------------------------------------------------
    def loop(self) -> None:
        r = self.robot
        tick = r.kilo_ticks
        if self.done or tick < self._next_round:
            return
        self._next_round = tick + self._round_ticks
        self._round += 1
        oldest = tick - self._stale_ticks
        fresh = [n for n in self.peers.values() if n.heard_tick >= oldest]
        same = [n for n in fresh if n.root == self.tag and n.x_mm is not None]
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
        joining = tick < self._join_until and any(n.joining for n in fresh)
        stop = neighbourhood_settled(
            self.refiner.settled, (bool(n.flags & (SETTLED | DONE)) for n in same)
        )
        self._confirmed = self._confirmed + 1 if stop and not joining else 0
        if self._confirmed >= _CONFIRM_ROUNDS:
            self._stop("settled")

    # -- messages --------------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        if self.position is None:
            return None
        x, y = self.position
        if abs(x) > _LIMIT_MM or abs(y) > _LIMIT_MM:
            return None
        r = self.robot
        self._turn += 1
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
        flags = (SETTLED if self.refiner.settled else 0) | (DONE if self.done else 0)
        root, salt = self.tag
        return GPOS.pack(sender=r.uid, x_mm=x, y_mm=y, root=root, flags=flags | salt << 2)

    def message_rx(self, message: Message, distance_mm: int) -> None:
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
            n.root, n.flags = (m.root, m.root_salt & 0x3F), SETTLED
            n.joining = True
        elif kind == GPOS.type:
            m = GPOS.unpack(message)
            n.x_mm, n.y_mm = m.x_mm, m.y_mm
            n.root, n.flags = (m.root, m.flags >> 2), m.flags & _FLAG_BITS
            n.joining = False
        else:
            m = DIST.unpack(message)
            if n.root is not None:  # its root is known from a GPOS: the position is usable
                n.x_mm, n.y_mm = m.x_mm, m.y_mm
            if m.neighbour == r.uid:
                n.reported_mm = unwrap_distance(m.distance, n.mean_mm)
        n.heard_tick = r.kilo_ticks


#: The messages a refining robot reads.
_HEARD = frozenset((GPOS.type, DIST.type, POS.type))
