"""Recovering from a split global frame: the thesis's remedy (§7), finished here.

When :mod:`kilonet.protocols.gcs.split_detection` finds a robot on the boundary between two merged
frames that never merged (and ``gcs.recoveries`` are left), that robot starts a **recovery epoch**:

1. **Flood.** It broadcasts ``RECOVER(epoch, start tick)`` with a start ``gcs.recover_flood_s``
   ahead; every robot that hears a newer epoch (or the same epoch with an earlier start — two
   robots may ask at once) adopts it and repeats it until the start. Clocks run together (the
   whole protocol relies on that), so at the start tick every robot that heard the flood
   leaves merging together.
2. **Edge seeds** (phase ``edges``, ``gcs.elect_s``): the robots that were on a split
   boundary are the candidates; each broadcasts ``EDGE``, and a candidate that hears no
   candidate with a greater ID becomes a new seed — the thesis's "new seed election at the
   edges of each partial frame". A new seed sits where two partial frames touch, so its
   neighbours come from both.
3. Phases 3–6 run again: the new seeds build their frames (seeds that have one keep it), every
   robot localizes in the new frames too (keeping its old positions), merging groups now link
   the new frames with frames on both sides, and merging starts afresh over all frames.

Epochs are numbered; after ``gcs.recoveries`` of them a split is reported, not repaired
(some topologies cannot be repaired: thesis case 3 with no robot able to see both sides).

Messages::

    type 71 RECOVER  sender:uint16  epoch:uint8  start_tick:uint32        7 bytes
    type 72 EDGE     sender:uint16  epoch:uint8                           3 bytes
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from kilonet.message import Message
from kilonet.protocols.common.phases import Stage
from kilonet.protocols.gcs.base import GcsParams, Phase, gcs_layout

if TYPE_CHECKING:
    from kilonet.protocols.gcs.program import GcsRobot

__all__ = ["EDGE", "RECOVER", "EdgeSeeds", "RecoveryFlood", "adopts_epoch"]

RECOVER = gcs_layout("recover", type=71, fields=[("epoch", "B"), ("start_tick", "I")])
EDGE = gcs_layout("edge", type=72, fields=[("epoch", "B")])


def adopts_epoch(
    epoch: int,
    start_tick: int,
    *,
    own_epoch: int,
    own_start_tick: int | None,
    now_tick: int,
) -> bool:
    """Whether a robot adopts a heard announcement of recovery epoch ``epoch`` starting at
    ``start_tick``: it is newer than the robot's own epoch, or the same epoch announced to
    start earlier than the one it is spreading (``own_start_tick``, ``None`` if none is
    pending: two robots may ask at once), and its start is still ahead.

    Examples
    --------
    >>> adopts_epoch(1, 900, own_epoch=0, own_start_tick=None, now_tick=100)
    True
    >>> adopts_epoch(1, 900, own_epoch=1, own_start_tick=800, now_tick=100)
    False
    >>> adopts_epoch(1, 700, own_epoch=1, own_start_tick=800, now_tick=100)
    True
    """
    newer = epoch > own_epoch
    earlier = epoch == own_epoch and own_start_tick is not None and start_tick < own_start_tick
    return (newer or earlier) and start_tick > now_tick


class RecoveryFlood:
    """Starting and spreading recovery epochs on one robot (runs in every phase)."""

    def __init__(self, robot: GcsRobot) -> None:
        self.robot = robot
        self.start_tick: int | None = None  # of the epoch being spread, until it starts

    @property
    def pending(self) -> bool:
        """A recovery epoch has been announced and has not started yet."""
        return self.start_tick is not None and self.robot.kilo_ticks < self.start_tick

    def request(self) -> None:
        """Start the next epoch (this robot detected a split that persists)."""
        r = self.robot
        start = r.kilo_ticks + round(r.params.recover_flood_s * r.ticks_per_s)
        r.log("recovery_requested", epoch=r.epoch + 1)
        self._adopt(r.epoch + 1, start)

    def _adopt(self, epoch: int, start_tick: int) -> None:
        self.start_tick = start_tick
        self.robot.schedule_recovery(epoch, start_tick)

    def message_tx(self) -> Message | None:
        """Repeat the announcement until the epoch starts."""
        if not self.pending:
            return None
        r = self.robot
        return RECOVER.pack(sender=r.uid, epoch=r.epoch, start_tick=self.start_tick)

    def message_rx(self, message: Message) -> None:
        if not RECOVER.matches(message):
            return
        m = RECOVER.unpack(message)
        r = self.robot
        pending_start = self.start_tick if self.pending else None
        if adopts_epoch(
            m.epoch,
            m.start_tick,
            own_epoch=r.epoch,
            own_start_tick=pending_start,
            now_tick=r.kilo_ticks,
        ):
            self._adopt(m.epoch, m.start_tick)


class RecoveryStage(Stage):
    """The stage a recovery epoch adds before phases 3-6 run again."""

    EDGES = "edges"


class EdgeSeeds(Phase):
    """Phase ``edges`` of a recovery epoch: robots on a split boundary elect new seeds."""

    name = RecoveryStage.EDGES

    @staticmethod
    def window_s(p: GcsParams) -> float:
        """The phase's window, s: ``gcs.elect_s``, as long as one election."""
        return p.elect_s

    def start(self) -> None:
        r = self.robot
        self.candidate = not r.is_seed and r.check is not None and r.check.on_split_boundary
        self.beaten = False

    def message_tx(self) -> Message | None:
        if not self.candidate:
            return None
        r = self.robot
        return EDGE.pack(sender=r.uid, epoch=r.epoch)

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if self.candidate and EDGE.matches(message):
            m = EDGE.unpack(message)
            if m.epoch == self.robot.epoch and m.sender > self.robot.uid:
                self.beaten = True

    def finish(self) -> None:
        r = self.robot
        if self.candidate and not self.beaten:
            r.is_seed = True
            r.role = "seed"
            r.edge_seed = True
            r.log("edge_seed", epoch=r.epoch)
