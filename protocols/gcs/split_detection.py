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

The check also runs the fold rule (:mod:`kilonet.protocols.gcs.fold_rule`, ``gcs.fold = true``):
it keeps every same-frame comparison, consistent or not, with the neighbour's position and the
measured distance, and how long the robot has been inconsistent with a majority of them (the
*outlier*). A robot compares its estimate with settled neighbours of its own root even before it
is settled itself, so that the run can wait for it (:meth:`SplitCheck.awaiting_fold`): one that
holds a transform without its done mark (from a seed at the edge of its range) is not settled,
and its estimate may disagree with its neighbours' until it hears the mark. It acts only once
settled: an estimate not settled is still moved by merging, and a robot that re-placed itself
against its neighbours then could be left behind when their frame moved. A split boundary is
still judged by settled robots only. Once the outlier has lasted ``gcs.fold_confirm_s`` (its
merged estimate not moving meanwhile), :meth:`SplitCheck.fold_step` acts on
:func:`~kilonet.protocols.gcs.fold_rule.fold_decision`: a **repair** replaces the robot's global
position by the refit one, a **split** takes the robot out of the frame into a frame of its own
(:func:`split_root`), and either is logged (``fold_repaired``, ``fold_split``). What the robot
holds then (:meth:`SplitCheck.held`) is what it broadcasts and compares here and what the run
reads as its estimate. A split robot sends no POS and compares nothing (it only watches the
neighbours it was judged against): it left the frame on purpose, and a POS naming its own frame
would put its neighbours on a split boundary and ask for a recovery. The action holds while the
merged estimate keeps its root and stays within ``gcs.check_tolerance_mm`` of where it was, and
while the neighbours it was judged against report positions within that of the ones it used: a
settled frame may still be moved by merging (a seed done merging may resume, and move its
frame), and a robot re-placed against neighbours that then move is left behind. A void action is
logged (``fold_void``). Otherwise the robot acts at most once per root, so a fold the rule
cannot mend does not keep the run waiting. A recovery epoch starts a new check, and with it
the rule.

The comparison uses only what the robot heard: its neighbours' messages and its own ranging.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Literal, NamedTuple

from kilonet.message import Message
from kilonet.protocols.gcs.base import gcs_layout
from kilonet.protocols.gcs.fold_rule import FoldDecision, fold_decision, is_outlier
from kilonet.protocols.gcs.frame_keys import Root

if TYPE_CHECKING:
    from kilonet.protocols.gcs.program import GcsRobot

__all__ = ["POS", "Fold", "SplitCheck", "distance_mismatch_mm", "split_root"]

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


class Fold(NamedTuple):
    """What the fold rule did on a robot: ``action`` (``"repaired"`` or ``"split"``), the
    ``position`` (mm) and ``root`` it holds since, the merged estimate it acted on (``merged``:
    position, mm, and root), and the neighbours it was judged against (``anchors``: ID →
    broadcast position and measured distance, mm)."""

    action: Literal["repaired", "split"]
    position: tuple[float, float]
    root: Root
    merged: tuple[tuple[float, float], Root]
    anchors: dict[int, tuple[float, float, float]]


def split_root(robot: GcsRobot) -> Root:
    """The frame of one a robot leaves its merged frame into (the fold rule's split): its own
    frame key, ranked as an edge seed's, after every elected seed's root, so that it wins no
    robot over from a merged frame. The run counts it as a frame of its own."""
    return Root(True, robot.own_key)


class SplitCheck:
    """The check on one robot, run alongside merging (phase 6).

    Attributes
    ----------
    other_frame : dict[int, Root]
        Neighbour ID → root of the other merged frame it reported.
    inconsistent : dict[int, float]
        Neighbour ID → |computed − measured| distance, mm, where above the tolerance (compared
        while this robot is settled: the flags the run reports).
    compared : dict[int, tuple[float, float, float]]
        Neighbour ID → ``(x_mm, y_mm, measured_mm)`` for each settled same-frame neighbour
        heard, whether this robot is settled or not: its latest broadcast position and the
        distance measured to it (the fold rule's input, :meth:`mismatches`).
    boundary_since : int or None
        Tick since which the robot has been on a split boundary without interruption.
    outlier_since : int or None
        Tick since which the robot has been the fold rule's outlier without interruption.
    fold : Fold or None
        The fold rule's action on this robot, while it holds (:meth:`held`).
    """

    def __init__(self, robot: GcsRobot) -> None:
        self.robot = robot
        self.params = robot.params
        self.other_frame: dict[int, Root] = {}
        self.inconsistent: dict[int, float] = {}
        self.compared: dict[int, tuple[float, float, float]] = {}
        self.boundary_since: int | None = None
        self.outlier_since: int | None = None
        self._outlier_from = (0.0, 0.0)  # the merged estimate when outlier_since was set, mm
        self.fold: Fold | None = None
        self.fold_roots: set[Root] = set()  # merged roots the rule has acted in
        self.pos_heard_at: dict[int, int] = {}  # neighbour ID -> tick of its latest POS
        self.turn = 0

    # -- own state ---------------------------------------------------------------------------
    @property
    def on_split_boundary(self) -> bool:
        """A neighbour's estimate is in another merged frame."""
        return bool(self.other_frame)

    def held(self) -> tuple[tuple[float, float], Root] | None:
        """The global position, mm, and root this robot holds while merging: the fold rule's
        repair or split while it stands (see the module docstring), else the merged estimate;
        ``None`` without one."""
        estimate = self.robot.estimate
        position = estimate.position()
        if position is None:
            return None
        root = estimate.root()
        fold = self.fold
        if fold is not None:
            (x, y), merged_root = fold.merged
            moved = math.hypot(position[0] - x, position[1] - y)
            if merged_root == root and moved <= self.params.check_tolerance_mm:
                return fold.position, fold.root
            self.fold = None  # merging moved the estimate on: the rule judges it anew
        return position, root

    def awaiting_fold(self) -> bool:
        """The fold rule will act on this robot once its disagreement is confirmed."""
        return (
            self.params.fold
            and self.outlier_since is not None
            and self.robot.estimate.root() not in self.fold_roots
            and self._decision(0.0).action == "wait"
        )

    def _decision(self, outlier_for_s: float) -> FoldDecision:
        """The fold rule on what this robot compared, the outlier for ``outlier_for_s``."""
        return fold_decision(
            self.compared,
            self.mismatches(),
            outlier_for_s=outlier_for_s,
            confirm_s=self.params.fold_confirm_s,
            tolerance_mm=self.params.check_tolerance_mm,
            sigma_mm=self.params.sigma_mm,
        )

    def fold_step(self) -> None:
        """Act on the fold rule (``gcs.fold``) once settled: called while merging, cheap unless
        the robot is the outlier. A repair or split is logged and held (:meth:`held`)."""
        r = self.robot
        if self.outlier_since is None or not self.params.fold or not r.estimate.settled():
            return
        root = r.estimate.root()
        if root in self.fold_roots:
            return
        decision = self._decision((r.kilo_ticks - self.outlier_since) / r.ticks_per_s)
        if decision.action in ("keep", "wait"):
            return
        self.fold_roots.add(root)
        self.outlier_since = None
        merged = (r.estimate.position(), root)
        anchors = dict(self.compared)
        neighbours = sorted(anchors)
        self.compared.clear()  # judged against the position it held: compare afresh
        if decision.action == "repair":
            position = decision.position
            self.fold = Fold("repaired", position, root, merged, anchors)
            r.log("fold_repaired", x_mm=position[0], y_mm=position[1], neighbours=neighbours)
        else:
            own = split_root(r)
            self.fold = Fold("split", merged[0], own, merged, anchors)
            r.log("fold_split", root=own.label, neighbours=neighbours)

    def _anchor_moved(self, uid: int, xy_mm: tuple[float, float], root: Root) -> None:
        """Neighbour ``uid`` now reports ``xy_mm`` in ``root``: if it was one the rule acted
        against and has moved by more than the tolerance, or left the frame, merging moved
        the frame after all; the action is void and the robot is judged anew (it may act again
        in this root)."""
        fold = self.fold
        anchor = fold.anchors.get(uid)
        if anchor is None:
            return
        moved = math.hypot(xy_mm[0] - anchor[0], xy_mm[1] - anchor[1])
        if root != fold.merged[1] or moved > self.params.check_tolerance_mm:
            self.fold = None
            self.fold_roots.discard(fold.merged[1])
            self.robot.log("fold_void", action=fold.action, neighbour=uid)

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
            self.compared.clear()
            self.pos_heard_at.clear()
        else:
            fresh_after = r.kilo_ticks - _FRESH_S * r.ticks_per_s
            for uid in [u for u, tick in self.pos_heard_at.items() if tick < fresh_after]:
                del self.pos_heard_at[uid]
                self.other_frame.pop(uid, None)
                self.inconsistent.pop(uid, None)
                self.compared.pop(uid, None)
        self._update_boundary()
        self._update_outlier()

    def _left_frame(self) -> bool:
        """The fold rule split this robot off (while the split holds, :meth:`held`)."""
        self.held()  # lapses a fold that no longer holds
        return self.fold is not None and self.fold.action == "split"

    def mismatches(self) -> dict[int, float]:
        """Neighbour ID → |computed − measured| distance, mm, for each neighbour of
        :attr:`compared`, computed from the position this robot holds now (:meth:`held`)."""
        held = self.held()
        if held is None:
            return {}
        xy = held[0]
        return {u: distance_mismatch_mm(xy, (x, y), d) for u, (x, y, d) in self.compared.items()}

    def _update_outlier(self) -> None:
        """Start, go on timing, or stop the outlier's disagreement. The time starts again when
        the merged estimate moves by more than ``gcs.merge_tolerance_mm``: a robot still
        merging (not settled) is judged only once its estimate has stopped moving."""
        if not is_outlier(self.mismatches(), self.params.check_tolerance_mm):
            self.outlier_since = None
            return
        merged = self.robot.estimate.position()
        start = self._outlier_from
        if (
            self.outlier_since is None
            or math.hypot(merged[0] - start[0], merged[1] - start[1])
            > self.params.merge_tolerance_mm
        ):
            self.outlier_since, self._outlier_from = self.robot.kilo_ticks, merged

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
        if self.turn % _POS_EVERY or not self.robot.estimate.settled():
            return None
        (x, y), root = self.held()
        if abs(x) > _LIMIT_MM or abs(y) > _LIMIT_MM:
            return None  # a frame still far off its partners' (it will not stay settled)
        if self._left_frame():
            return None  # the fold rule split it off its frame (see the module docstring)
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
        if m.sender not in r.table or estimate.root() is None:
            return
        root = Root.from_wire(m.root, m.root_salt)
        if self.fold is not None:
            self._anchor_moved(m.sender, (m.x_mm, m.y_mm), root)
        if self._left_frame():
            return
        xy, own_root = self.held()
        settled = estimate.settled()
        if settled:  # a boundary, and the flags the run reports, are judged by settled robots
            self.pos_heard_at[m.sender] = r.kilo_ticks
            self.other_frame.pop(m.sender, None)
            self.inconsistent.pop(m.sender, None)
            if root != own_root:
                self.other_frame[m.sender] = root
            self._update_boundary()
        if root != own_root:
            self.compared.pop(m.sender, None)
        else:
            measured = r.table.distance(m.sender)
            self.compared[m.sender] = (m.x_mm, m.y_mm, measured)
            mismatch = distance_mismatch_mm(xy, (m.x_mm, m.y_mm), measured)
            if settled and mismatch > self.params.check_tolerance_mm:
                self.inconsistent[m.sender] = mismatch
        self._update_outlier()
