"""Checking the merged frame from inside the swarm: the thesis's detection (§7), finished here.

Once a robot is *settled* — it has a global position and every transform that position uses is
marked done by its seed — it broadcasts that position now and then::

    type 70 POS  sender:uint16  x:int16  y:int16 (0.5 mm)  root:uint16  root_salt:uint8  9 bytes

``root`` and ``root_salt`` name the root of the merged frame its estimate is in
(:class:`kilonet.protocols.gcs.frame_keys.Root`; bit 15 of ``root``: an edge or isolated
seed's frame). A settled robot
that hears a settled neighbour compares, as the thesis proposes, the distance computed from
both global positions with the distance it measures (the running mean of its neighbour table):

* the neighbour is in **another merged frame** (another root) — the two frames were never
  merged, and the computed distance means nothing: this robot is on the boundary of a split;
* same frame, but the two distances differ by more than ``gcs.check_tolerance_mm``: the merged
  frame is **inconsistent** here (a bad fix or a bad merge).

The flags describe the latest message from each neighbour, so they clear when merging goes
on and the frames meet after all. They also lapse: a neighbour's flag when it has sent no POS
for ``_FRESH_S`` (it is merging again), and all of them when this robot stops being settled
(its own frame is moving): a flag raised while the root is still flooding the swarm must not
outlive the moment both robots have joined that root. A robot that has been on a split boundary
for ``gcs.split_confirm_s`` without interruption asks for a recovery
(:mod:`kilonet.protocols.gcs.recovery`) — unless ``gcs.recoveries`` have been run already.

The comparison uses only what the robot heard: its neighbours' messages and its own ranging.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from kilonet.message import Message
from kilonet.protocols.gcs.base import gcs_layout
from kilonet.protocols.gcs.frame_keys import Root

if TYPE_CHECKING:
    from kilonet.protocols.gcs.program import GcsRobot

__all__ = ["POS", "SplitCheck", "distance_mismatch_mm"]

POS = gcs_layout(
    "pos",
    type=70,
    fields=[("x_mm", "h", 0.5), ("y_mm", "h", 0.5), ("root", "H"), ("root_salt", "B")],
)
_POS_EVERY = 4  # one message opportunity in this many carries a POS (others are free)
_LIMIT_MM = 16383.0  # int16 in 0.5 mm
_FRESH_S = 5.0  # a neighbour's flag lapses after this long without a POS from it


def distance_mismatch_mm(
    xy_mm: tuple[float, float], neighbour_xy_mm: tuple[float, float], measured_mm: float
) -> float:
    """How far the distance computed from two global positions is from the measured one, mm.

    Examples
    --------
    >>> distance_mismatch_mm((0.0, 0.0), (30.0, 40.0), 45.0)
    5.0
    """
    computed = math.hypot(neighbour_xy_mm[0] - xy_mm[0], neighbour_xy_mm[1] - xy_mm[1])
    return abs(computed - measured_mm)


class SplitCheck:
    """The check on one robot, run alongside merging (phase 6).

    Attributes
    ----------
    other_frame : dict[int, Root]
        Neighbour ID → root of the other merged frame it reported.
    inconsistent : dict[int, float]
        Neighbour ID → |computed − measured| distance, mm, where above the tolerance.
    boundary_since : int or None
        Tick since which the robot has been on a split boundary without interruption.
    """

    def __init__(self, robot: GcsRobot) -> None:
        self.robot = robot
        self.params = robot.params
        self.other_frame: dict[int, Root] = {}
        self.inconsistent: dict[int, float] = {}
        self.boundary_since: int | None = None
        self.pos_heard_at: dict[int, int] = {}  # neighbour ID -> tick of its latest POS
        self.turn = 0

    # -- own state ---------------------------------------------------------------------------
    @property
    def on_split_boundary(self) -> bool:
        """A neighbour's estimate is in another merged frame."""
        return bool(self.other_frame)

    def wants_recovery(self) -> bool:
        """On a split boundary for ``gcs.split_confirm_s`` and recoveries are left."""
        r = self.robot
        if self.boundary_since is None:
            return False
        self._lapse()
        if self.boundary_since is None or r.epoch >= self.params.recoveries:
            return False
        confirm = round(self.params.split_confirm_s * r.ticks_per_s)
        return r.kilo_ticks - self.boundary_since >= confirm

    def _lapse(self) -> None:
        """Drop flags that no longer describe the present (see the module docstring)."""
        r = self.robot
        if not r.estimate.settled():
            self.other_frame.clear()
            self.inconsistent.clear()
            self.pos_heard_at.clear()
        else:
            fresh_after = r.kilo_ticks - _FRESH_S * r.ticks_per_s
            for uid in [u for u, tick in self.pos_heard_at.items() if tick < fresh_after]:
                del self.pos_heard_at[uid]
                self.other_frame.pop(uid, None)
                self.inconsistent.pop(uid, None)
        self._update_boundary()

    def _update_boundary(self) -> None:
        r = self.robot
        if self.other_frame and self.boundary_since is None:
            self.boundary_since = r.kilo_ticks
            r.log("split_detected", neighbours=sorted(self.other_frame))
        elif not self.other_frame and self.boundary_since is not None:
            r.log("split_cleared", after_s=(r.kilo_ticks - self.boundary_since) / r.ticks_per_s)
            self.boundary_since = None

    # -- messages ----------------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        """A POS now and then, once settled."""
        self.turn += 1
        estimate = self.robot.estimate
        if self.turn % _POS_EVERY or not estimate.settled():
            return None
        x, y = estimate.position()
        if abs(x) > _LIMIT_MM or abs(y) > _LIMIT_MM:
            return None  # a frame still far off its partners' (it will not stay settled)
        root = estimate.root()
        return POS.pack(
            sender=self.robot.uid, x_mm=x, y_mm=y, root=root.wire_id, root_salt=root.key.salt
        )

    def message_rx(self, message: Message) -> None:
        """Compare a settled neighbour's POS with this robot's own estimate and ranging."""
        if not POS.matches(message):
            return
        r = self.robot
        m = POS.unpack(message)
        estimate = r.estimate
        if m.sender not in r.table or not estimate.settled():
            return
        root = Root.from_wire(m.root, m.root_salt)
        self.pos_heard_at[m.sender] = r.kilo_ticks
        self.other_frame.pop(m.sender, None)
        self.inconsistent.pop(m.sender, None)
        if root != estimate.root():
            self.other_frame[m.sender] = root
        else:
            xy = estimate.position()
            mismatch = distance_mismatch_mm(xy, (m.x_mm, m.y_mm), r.table.distance(m.sender))
            if mismatch > self.params.check_tolerance_mm:
                self.inconsistent[m.sender] = mismatch
        self._update_boundary()
