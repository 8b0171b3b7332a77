"""The stages of ``localize`` on one robot, in order
(:class:`kilonet.protocols.common.phases.Stage`), and the phase that runs each
(:class:`kilonet.protocols.common.phases.Phase`, run by the robot's
:class:`~kilonet.protocols.common.phases.PhaseDriver`).

``election`` (phase 1, :mod:`kilonet.protocols.localize.phase1_election`), ``localize`` (the spread
and termination, phases 2 and 3), ``island`` (after DONE, for a robot of an island the spread left
out: phase 4, :mod:`kilonet.protocols.localize.phase4_island`) and ``done``. Members compare equal
to their names, which the trace's ``stage`` events carry.

A stage's phase says what the robot does in it: its round of work (:meth:`LocalizePhase.work`),
the message it offers (:meth:`LocalizePhase.message_tx`), the receive handlers it puts in place
of the program's (:meth:`~kilonet.protocols.common.phases.Phase.handlers`), when it is over and
what follows. The protocol's state lives in the phase modules' objects on the robot (the
election, the spread, the termination, the island), which outlast a stage: the spread runs on in
an island, the termination's DONE repeats after the robot is done. To add a stage: a member and a
phase here, and its state in a module of its own.

>>> LocalizeStage.names()
('election', 'localize', 'island', 'done')
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from kilonet.protocols.common.phases import Handler, Phase, Stage
from kilonet.protocols.localize.base import MAX_HOPS, UNKNOWN_HOPS, Neighbour, toward_root
from kilonet.protocols.localize.phase1_election import ELECT
from kilonet.protocols.localize.phase2_spread import CAND, POS, ROOT
from kilonet.protocols.localize.phase4_island import ISLAND_FULL, ISLAND_LINK, ISLAND_PAIR

if TYPE_CHECKING:
    from kilonet.message import Message
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = ["DonePhase", "ElectionPhase", "IslandPhase", "LocalizePhase", "LocalizeStage"]


class LocalizeStage(Stage):
    """Where a ``localize`` robot is: electing, localizing, placing its island, or done."""

    ELECTION = "election"
    LOCALIZE = "localize"
    ISLAND = "island"
    DONE = "done"


class LocalizePhase(Phase):
    """A stage of ``localize`` on one robot (``robot``). The program calls :meth:`work` at each
    round of work (and when a neighbour's news calls for updates), then lets its driver move on
    if :meth:`finished` says so."""

    #: Whether the robot still works, listens and keeps its LED lit (a done robot does not).
    awake = True

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot

    def work(self, tick: int, fresh: list[Neighbour], *, full: bool) -> None:
        """A round of work at ``tick`` from the neighbours heard lately (``fresh``), or with
        ``full`` false only the updates a neighbour's news calls for. Default: nothing."""

    def heard_own_id(self) -> None:
        """A message carried this robot's own ID as its sender. Default: ignored."""


class ElectionPhase(LocalizePhase):
    """Phase 1: electing a root (:class:`~kilonet.protocols.localize.phase1_election.Election`).
    Over when this robot has won, or when it hears the frame (ROOT, POS, CAND): the root has
    won elsewhere."""

    name = LocalizeStage.ELECTION

    def __init__(self, robot: LocalizeRobot) -> None:
        super().__init__(robot)
        self.frame_heard = False

    def work(self, tick: int, fresh: list[Neighbour], *, full: bool) -> None:
        self.robot.election.round(tick, fresh, full=full)

    def finished(self) -> bool:
        return self.robot.election.won or self.frame_heard

    def following(self) -> LocalizePhase:
        return LocalizingPhase(self.robot)

    def finish(self) -> None:
        if self.robot.election.won:
            self.robot.is_root = True

    def message_tx(self) -> Message | None:
        r = self.robot
        message = r.shared_message()
        return message if message is not None else r.election.message_tx()

    def heard_own_id(self) -> None:
        self.robot.election.heard_own_id()

    def handlers(self) -> Mapping[int, Handler]:
        return {
            ELECT.type: self.robot.election.message_rx,
            ROOT.type: self._frame_rx,
            POS.type: self._frame_rx,
            CAND.type: self._frame_rx,
        }

    def _frame_rx(self, n: Neighbour, message: Message) -> bool:
        """A phase-2 message: the root has won; move on to localizing, and take the message
        in as a localizing robot does."""
        r = self.robot
        self.frame_heard = True
        r.driver.advance(r.kilo_ticks)
        r.urgent = True
        return r.driver.handler(message.type)(n, message)


class LocalizingPhase(LocalizePhase):
    """Phases 2 and 3: the spread, the refinement and the termination's waves, until this robot
    is done; then the island stage if the island wakes it (it is unplaced among unplaced
    neighbours), else done."""

    name = LocalizeStage.LOCALIZE

    def __init__(self, robot: LocalizeRobot) -> None:
        super().__init__(robot)
        self.next_stage: LocalizeStage | None = None

    def start(self) -> None:
        r = self.robot
        r.log("stage", name="localize", hops=r.hops, root=r.is_root)
        if r.is_root:
            r.locate(0.0, 0.0)
            return
        r.reports = None  # only the root's choice of frame robots needs them
        # The hop count starts over from the frame's own messages (POS, ROOT), and from
        # here it only falls (toward_root). A count of the election would not do: it may be
        # one to another key's robot (a neighbour last heard before it switched keys
        # counts 0 hops to itself), or one over links whose other end does not hear.
        r.hops = MAX_HOPS
        for n in r.neighbours.known():
            n.hops = UNKNOWN_HOPS

    def work(self, tick: int, fresh: list[Neighbour], *, full: bool) -> None:
        r = self.robot
        if full:
            if not r.is_root:
                # The hop count falls to what the neighbours that hear this robot announce
                # and never rises, so every parent hears its child and is nearer the root:
                # the convergecasts reach the root from every robot (toward_root).
                r.hops, parent = toward_root(r.hops, r.parent, fresh)
                r.change_parent(parent)
            r.spread.round(tick, fresh)
            if r.position is not None:
                r.refine(fresh)
        r.termination.round(tick, fresh, full=full)
        if r.termination.done:
            wakes = r.island.wake(tick, fresh)
            self.next_stage = LocalizeStage.ISLAND if wakes else LocalizeStage.DONE
        else:
            r.show()

    def finished(self) -> bool:
        return self.next_stage is not None

    def following(self) -> LocalizePhase:
        if self.next_stage is LocalizeStage.ISLAND:
            return IslandPhase(self.robot)
        return DonePhase(self.robot)

    def finish(self) -> None:
        self.robot.log("stage", name=self.next_stage)

    def message_tx(self) -> Message | None:
        r = self.robot
        message = r.shared_message(announce_parent=not r.is_root)
        return message if message is not None else r.spread.message_tx()


class IslandPhase(LocalizePhase):
    """Phase 4, after DONE, for a robot of an island
    (:class:`~kilonet.protocols.localize.phase4_island.Island`): the spread's rules and the
    island's solve while unplaced, refinement and votes once placed (the frame around stands
    still now), until the island's work is over or the run's time-out."""

    name = LocalizeStage.ISLAND

    def __init__(self, robot: LocalizeRobot) -> None:
        super().__init__(robot)
        self.over = False

    def start(self) -> None:
        self.robot.show()

    def work(self, tick: int, fresh: list[Neighbour], *, full: bool) -> None:
        if not full:
            return
        r = self.robot
        known = r.neighbours.known()
        # Unplaced, the spread's rules; placed, rule 4's votes on neighbours' candidates (the
        # frame's robots are silent now, and a member placed here may be the only anchor
        # left awake to vote).
        r.spread.round(tick, known)
        r.island.round(tick, known)
        if r.position is not None:
            r.refine(known)
        self.over = r.island.finished(tick) or tick >= r.termination.run_timeout_tick

    def finished(self) -> bool:
        return self.over

    def following(self) -> LocalizePhase:
        return DonePhase(self.robot)

    def finish(self) -> None:
        r = self.robot
        r.termination.repeat_done()
        r.log("island_done", placed=r.position is not None)

    def message_tx(self) -> Message | None:
        r = self.robot
        message = r.shared_message()
        if message is None:
            message = r.island.message_tx()
        return message if message is not None else r.spread.message_tx()

    def handlers(self) -> Mapping[int, Handler]:
        island = self.robot.island
        return {
            ISLAND_PAIR.type: island.pair_rx,
            ISLAND_LINK.type: island.link_rx,
            ISLAND_FULL.type: island.full_rx,
        }


class DonePhase(LocalizePhase):
    """Done: the estimate is frozen and the robot silent but for the DONE messages it still
    owes its neighbours."""

    name = LocalizeStage.DONE
    awake = False

    def start(self) -> None:
        self.robot.show()

    def message_tx(self) -> Message | None:
        r = self.robot
        return r.spread.state_message() if r.termination.owes_done() else None
