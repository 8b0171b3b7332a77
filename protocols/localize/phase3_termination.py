"""Phase 3 of ``localize``: the swarm decides by itself that it is done.

Located robots keep refining (:mod:`kilonet.protocols.common.refinement`) until each is *settled*:
it moved less than ``localize.settle_mm`` over its last ``localize.settle_rounds`` rounds (or it has
been located for ``localize.settle_timeout_s``). A robot that cannot place itself must not
hold the swarm up forever: it *gives up* (:func:`gives_up`) when its anchors and candidates
have not changed for ``localize.give_up_s`` and its located neighbours are all settled, or,
with no located neighbour, a neighbour has given up; it counts as settled from then on, and
takes a position after all if one turns up.

Settledness climbs the tree of parents as a convergecast (:func:`subtree_complete`): a robot
is *complete* when it is settled and every neighbour that names it parent reports complete.
The tree is the frame's (:func:`~kilonet.protocols.localize.base.toward_root`): every parent hears
its child and is nearer the root, so the root waits for every robot. When the root has been complete
for ``localize.done_confirm_rounds`` rounds it declares the swarm *done*; DONE floods outward (a
robot that hears the flag is done too), every robot freezes its estimate, sends
``localize.done_repeats`` more messages so its neighbours hear the flag, and falls silent. A
robot that hears no neighbour any more (for ``localize.stale_s``: they are done and it
missed every DONE they sent, or they crashed) is done too, and one that is still running
after ``localize.run_timeout_s`` declares itself done.

The flags travel in POS and ROOT messages (:mod:`kilonet.protocols.localize.phase2_spread`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

from kilonet.protocols.localize.base import COMPLETE, SETTLED, Neighbour, children_complete

if TYPE_CHECKING:
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = ["Termination", "gives_up", "settled_at", "subtree_complete"]


def settled_at(
    anchor: tuple[float, float] | None,
    position: tuple[float, float],
    window_settled: bool,
    unsettle_mm: float,
) -> tuple[float, float] | None:
    """Where a robot counts as settled, or None while it does not: settledness with
    hysteresis. It settles where the settle test (``window_settled``) first holds, and stays
    settled, whatever the test says, until it is ``unsettle_mm`` or farther from there.

    The settled wave needs every robot of a subtree settled at once. On kilolib's ranging the
    distances a robot fits keep changing by tenths of a millimetre (new samples, new reports
    of the far end's mean), and a robot that has converged still creeps past ``settle_mm``
    over a window now and then: without hysteresis each such moment would break the wave,
    and a swarm long placed would run until ``settle_timeout_s``.

    Examples
    --------
    >>> a = settled_at(None, (10.0, 0.0), True, 1.5)
    >>> a, settled_at(a, (11.0, 0.0), False, 1.5), settled_at(a, (11.6, 0.0), False, 1.5)
    ((10.0, 0.0), (10.0, 0.0), None)
    >>> settled_at(None, (12.0, 0.0), False, 1.5), settled_at(a, (11.0, 0.0), False, 0.0)
    (None, None)
    """
    if anchor is not None and math.dist(anchor, position) < unsettle_mm:
        return anchor
    return position if window_settled else None


def subtree_complete(settled: bool, uid: int, neighbours: Sequence[Neighbour]) -> bool:
    """Whether robot ``uid`` is complete: settled, and every neighbour that names it parent
    complete.

    Examples
    --------
    >>> a, b = Neighbour(1), Neighbour(2)
    >>> a.parent, (b.parent, b.flags) = 4, (2, COMPLETE)
    >>> subtree_complete(True, 2, [a, b]), subtree_complete(False, 2, [a, b])
    (True, False)
    >>> b.flags = SETTLED
    >>> subtree_complete(True, 2, [a, b])
    False
    """
    return settled and children_complete(uid, neighbours, _complete)


def _complete(n: Neighbour) -> bool:
    return bool(n.flags & COMPLETE)


def gives_up(neighbours: Sequence[Neighbour], quiet: bool) -> bool:
    """Whether a robot without a position gives up; ``quiet``: nothing it could use (anchors,
    candidates) has changed for a while.

    With located neighbours: when it is quiet and they are all settled. Without: when it is
    quiet and a neighbour has given up — so giving up spreads from the edge of the frame into
    a region that cannot be placed, and never starts ahead of a frame that is still growing
    (nobody there has given up). A robot with no neighbour at all gives up at once.

    Examples
    --------
    >>> a, b, c = Neighbour(1), Neighbour(2), Neighbour(3)
    >>> a.x_mm, a.y_mm, a.flags = 10.0, 0.0, SETTLED
    >>> gives_up([a, b], quiet=True), gives_up([a, b], quiet=False)
    (True, False)
    >>> gives_up([b, c], quiet=True)  # no neighbour has given up
    False
    >>> b.flags = SETTLED  # b has: c need not wait for its other neighbours
    >>> gives_up([b, c], quiet=True), gives_up([b, c], quiet=False), gives_up([], quiet=False)
    (True, False, True)
    """
    if not neighbours:
        return True
    located = [n for n in neighbours if n.x_mm is not None]
    if located:
        return quiet and all(n.flags & SETTLED for n in located)
    return quiet and any(n.flags & SETTLED for n in neighbours)


class Termination:
    """Phase 3 on one robot: whether it is settled, complete and done."""

    name = "termination"

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot
        p = robot.params
        tps = robot.ticks_per_s
        self.give_up_ticks = p.give_up_s * tps
        self.settle_ticks = p.settle_timeout_s * tps
        self.run_timeout_tick = p.run_timeout_s * tps
        self.child_rounds = math.ceil(p.child_stale_s / p.round_s)
        self.settled = False
        self.settled_at: tuple[float, float] | None = None
        self.complete = False
        self.done = False
        self.confirmed_rounds = 0
        self.repeats_left = p.done_repeats

    def round(self, tick: int, fresh: list[Neighbour], *, full: bool = True) -> None:
        """Update settled (in a ``full`` round) and complete; on the root, decide done (it
        counts only full rounds as confirming)."""
        r = self.robot
        # A child unheard for a few rounds in a crowded band is still a child: the wave waits
        # for it longer than the spread trusts a silent neighbour's record.
        children = r.neighbours.fresh(r.round_index, self.child_rounds)
        if not full:
            self.complete = subtree_complete(self.settled, r.uid, children)
            return
        if r.position is not None:
            self.settled_at = settled_at(
                self.settled_at, r.position, r.refiner.settled, r.params.unsettle_mm
            )
            self.settled = self.settled_at is not None or tick - r.located_tick >= self.settle_ticks
        else:
            quiet = tick - r.spread.news_tick >= self.give_up_ticks
            self.settled = gives_up(fresh, quiet)
        self.complete = subtree_complete(self.settled, r.uid, children)
        if r.is_root:
            self.confirmed_rounds = self.confirmed_rounds + 1 if self.complete else 0
            if self.confirmed_rounds >= r.params.done_confirm_rounds:
                self.finish("complete")
        if not fresh and r.neighbours.samples_total:
            # Every neighbour has fallen silent (done, with every DONE it sent lost, or
            # crashed): no one is left to hear DONE from, nor to localize with.
            self.finish("silent")
        if tick >= self.run_timeout_tick:
            self.finish("run_timeout")

    def finish(self, cause: str) -> None:
        """Declare this robot done (``cause``: complete, heard, silent, run_timeout)."""
        if not self.done:
            self.done = True
            self.robot.log("done", cause=cause)

    def owes_done(self) -> bool:
        """Whether a done robot still owes its neighbours a DONE message."""
        return self.repeats_left > 0

    def repeat_done(self) -> None:
        """Owe the neighbours ``localize.done_repeats`` more DONE messages: a robot that stayed
        awake after DONE (:mod:`kilonet.protocols.localize.phase4_island`) announces its final
        state."""
        self.repeats_left = self.robot.params.done_repeats

    def sent(self) -> None:
        """A message went on the air (after any carrier-sense back-off): count a DONE one."""
        if self.done:
            self.repeats_left -= 1
