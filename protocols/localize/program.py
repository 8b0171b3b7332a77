"""``localize``: one global frame for a whole swarm, as one Kilobot program.

The phases (one module each) follow one another on every robot as its local work is done,
not in fixed windows:

1. :mod:`kilonet.protocols.localize.phase1_election` — locally unique IDs, a root elected by
   flooding the smallest key, every robot's hop count to it, and an echo that tells the root
   everyone has heard it;
2. :mod:`kilonet.protocols.localize.phase2_spread` — the frame starts at the root (root, axis and
   third robot) and spreads outward by multilateration, with flip and collinearity checks and
   neighbours' candidate pairs where three anchors are missing;
3. :mod:`kilonet.protocols.common.refinement` — from the moment it has a position, every robot keeps
   improving it from its neighbours' announced positions and the distances both ends measured
   (:mod:`kilonet.protocols.common.refinement`'s DIST reports), while
   :mod:`kilonet.protocols.localize.phase3_termination` climbs settledness back to the root, which
   floods DONE; every robot then freezes its estimate and falls silent;
4. :mod:`kilonet.protocols.localize.phase4_island` — except robots the spread left out in groups
   none of which hears three placed robots: such an island stays awake after DONE and places itself
   as rigid bodies tied to the now still frame by their distances.

Each stage runs as a phase of :mod:`kilonet.protocols.localize.stages` (its work, its message,
its receive handlers, when it is over and what follows), which the robot's
:class:`~kilonet.protocols.common.phases.PhaseDriver` holds; this module keeps what every stage
shares: the rounds, the noise estimate, the distance reports, the refinement and the LED.

A robot learns only from what it receives: the messages and the distance estimate of each
reception. It keeps time with its own clock (``kilo_ticks``): a round of work every
``localize.round_s``, done from ``loop()``; ``message_tx()`` only packs the current state. It
runs with either receive mode (in polled mode, ``loop()`` drains the buffer first).

Messages (kilolib payloads of at most 9 bytes, the sender's ID first): ELECT (80), ROOT (81),
POS (82), DIST (83), CAND (84), NBR (85), VOTE (86), ISLAND_PAIR (87), ISLAND_LINK (88),
ISLAND_FULL (89) — layouts in the phase modules. One transmit opportunity in
``localize.dist_every`` carries a distance report (DIST or NBR), the others the phase's own
message.

LED: electing blue; the root white; located green; settled cyan; done off.
"""

from __future__ import annotations

import math
import struct

from kilonet.message import Message, PayloadError
from kilonet.protocols.common.phases import PhaseDriver
from kilonet.protocols.common.ranging_limit import trusted_range
from kilonet.protocols.common.refinement import DIST, Refiner, next_report
from kilonet.protocols.localize.base import (
    COMPLETE,
    DONE,
    LOCALIZED,
    MAX_COORDINATE_MM,
    NBR,
    NO_ID,
    SETTLED,
    LocalizeParams,
    Neighbour,
    Neighbours,
    distance_report,
    unwrap_coordinate,
)
from kilonet.protocols.localize.phase1_election import ELECT, Election
from kilonet.protocols.localize.phase2_spread import CAND, POS, ROOT, VOTE, Spread
from kilonet.protocols.localize.phase3_termination import Termination
from kilonet.protocols.localize.phase4_island import Island
from kilonet.protocols.localize.stages import ElectionPhase, LocalizeStage
from kilonet.robot import Kilobot

__all__ = ["LocalizeRobot"]

#: Every message's first field, the sender's ID (uint16).
_SENDER = struct.Struct("<H").unpack_from
_ROUNDING_SIGMA_MM = 1.0 / math.sqrt(12.0)
#: A robot re-estimates its ranging noise once the receptions behind the estimate have grown by
#: this factor: the estimate's standard error falls as 1/sqrt(receptions), so 10 % more moves it
#: by about 5 % of that error, while the estimate (a median over every neighbour) is costly to
#: re-make every round.
_NOISE_REESTIMATE_GROWTH = 1.1


class LocalizeRobot(Kilobot):
    """The ``localize`` program of one robot.

    Parameters
    ----------
    params : LocalizeParams
        The protocol's parameters.

    Attributes
    ----------
    driver : PhaseDriver
        The running stage's phase (:mod:`kilonet.protocols.localize.stages`) and the receive
        handlers by message type.
    position : (float, float) or None
        This robot's estimate in the frame, mm.
    root_key : int
        The election key of this robot's root (its frame's label).
    sigma_mm : float
        The ranging error per reception this robot assumes (mm): the noise it has measured
        and ``localize.link_error_mm``, which no spread of readings shows.
    """

    LED_KEY = (
        ((0, 0, 2), "electing, or not located yet"),
        ((3, 3, 3), "root"),
        ((0, 3, 0), "located"),
        ((0, 3, 3), "settled"),
        ((0, 0, 0), "done"),
    )

    def __init__(self, params: LocalizeParams) -> None:
        self.params = params

    # -- kilolib callbacks ---------------------------------------------------------------------
    def setup(self) -> None:
        p = self.params
        tps = self.ticks_per_s
        self._polled = self.polled  # fixed for a run; loop() asks many times a second
        self.uid = int(self.rand.integers(NO_ID))
        self.neighbours = Neighbours(
            duplicate_mm=p.duplicate_sigmas * p.sigma_mm,
            stale_rounds=math.ceil(p.stale_s / p.round_s),
            duplicate_after=p.duplicate_after,
        )
        # Neighbours' NBR reports about each other, while electing and on the root (None once
        # no longer needed).
        self.reports: dict[int, dict[int, float]] | None = {}
        # Ranging error per reception, as this robot measures it, with the per-link error.
        self.sigma_mm = math.hypot(p.sigma_mm, p.link_error_mm)
        self.position: tuple[float, float] | None = None
        self.is_root = False
        self.located_tick = 0
        self.hops = 0
        self.parent = NO_ID  # the neighbour this robot reports to in the convergecasts
        self._parent_repeats = 0  # ELECT messages still owed after a change of parent
        self._parent_round = 0  # the round of work that last changed the parent
        self.root_key = 0
        self.election = Election(self)
        self.spread = Spread(self)
        self.island = Island(self)
        self.termination = Termination(self)
        self.refiner = Refiner(
            huber_mm=p.huber_mm,
            max_step_mm=p.max_step_mm,
            momentum=p.momentum,
            settle_mm=p.settle_mm,
            settle_rounds=p.settle_rounds,
        )
        self._round_ticks = p.round_s * tps
        self._next_round = 0.0
        self._noise_due = 0.0  # receptions recorded when the noise is next re-estimated
        self._round = 0  # rounds of work done: the neighbour records' time stamps
        self._news = False  # a neighbour's echo or flags changed since the last work
        self.urgent = False  # this robot's own state changed: send it next
        self._turn = 0
        self.unsendable = 0  # messages message_tx could not pack (a counted event)
        # The handlers of every stage; a stage's phase puts its own in place of some.
        self.driver = PhaseDriver(
            {
                ELECT.type: self._parent_rx,
                DIST.type: self._dist_rx,
                NBR.type: self._nbr_rx,
                ROOT.type: self._state_rx,
                POS.type: self._state_rx,
                CAND.type: self._cand_rx,
                VOTE.type: self.spread.vote_rx,
            }
        )
        self.driver.enter(ElectionPhase(self))
        self.set_color(0, 0, 2)

    def loop(self) -> None:
        if self._polled:
            self.drain_messages()
        if not self.driver.phase.awake:
            return
        tick = self.kilo_ticks
        if tick >= self._next_round:
            self._next_round = tick + self._round_ticks
            self._round += 1
            p = self.params
            # Estimates come in whole millimetres: their rounding alone has a spread of
            # 1/sqrt(12) mm, the least noise a robot can measure.
            neighbours = self.neighbours
            if neighbours.samples_total >= self._noise_due:
                self._noise_due = neighbours.samples_total * _NOISE_REESTIMATE_GROWTH
                noise = neighbours.noise_mm(p.noise_samples, p.sigma_mm)
                self.sigma_mm = math.hypot(max(noise, _ROUNDING_SIGMA_MM), p.link_error_mm)
                neighbours.duplicate_mm = p.duplicate_sigmas * self.sigma_mm
            self._work(tick, self.neighbours.fresh(self._round), full=True)
        elif self._news:
            # A neighbour's echo or flags changed: pass it on now, not at the next round, so
            # the echo, the settled wave and DONE cross the swarm at the pace of messages.
            self._work(tick, self.neighbours.fresh(self._round), full=False)
        self._news = False

    def _work(self, tick: int, fresh: list[Neighbour], *, full: bool) -> None:
        """A round of work (``full``), or only the updates a neighbour's news calls for, by the
        running stage's phase; then the next stage if that one is over."""
        before = (self.stage, self.election.echo, self.flags, self.parent)
        self.driver.phase.work(tick, fresh, full=full)
        self.driver.advance(tick)
        if (self.stage, self.election.echo, self.flags, self.parent) != before:
            self.urgent = True

    def message_tx(self) -> Message | None:
        try:
            return self._message_tx()
        except PayloadError as exc:
            # A value the protocol cannot pack is a counted event, never a crash of the run.
            self.unsendable += 1
            self.log("unsendable", error=str(exc))
            return None

    def _message_tx(self) -> Message | None:
        return self.driver.phase.message_tx()

    def shared_message(self, *, announce_parent: bool = False) -> Message | None:
        """What an awake robot sends before its stage's own message, if anything: its parent
        (``announce_parent``, after the election) when owed or now and then, else at times a
        distance report, unless its own state changed (``urgent``: the stage's message goes
        out at once). Counts the transmit opportunity."""
        self._turn += 1
        if announce_parent:
            # Announce the parent after it changed, and now and then anyway: a lost
            # announcement would leave this robot out of its parent's convergecasts. A new
            # parent is announced once it has lasted a round of work: while the hop count still
            # falls, round after round, announcing each parent on the way would waste the air
            # (the parent before still counts this robot until it hears of the new one).
            owed = self._parent_repeats and self._round > self._parent_round
            if owed or self._turn % self.params.parent_every == 0:
                self._parent_repeats = max(0, self._parent_repeats - 1)
                return self.election.message_tx()
        if self.urgent:  # a change of state goes out at once
            self.urgent = False
        elif self._turn % self.params.dist_every == 0:
            return self._dist_tx()
        return None

    def message_tx_success(self) -> None:
        self.termination.sent()

    def message_rx(self, message: Message, distance_mm: int) -> None:
        phase = self.driver.phase
        if not phase.awake or not trusted_range(distance_mm, self.params.neighbour_max_mm):
            return  # a robot measured beyond the tables' range is none of its neighbours
        (sender,) = _SENDER(message.data)
        if sender == self.uid:
            phase.heard_own_id()
            return
        n = self.neighbours.heard(sender, distance_mm, self._round)
        handler = self.driver.handler(message.type)
        # A handler returns whether the sender's echo, flags, key or parent changed.
        if handler is not None and handler(n, message):
            self._news = True

    # -- state ---------------------------------------------------------------------------------
    @property
    def stage(self) -> LocalizeStage:
        """``"election"``, ``"localize"``, ``"island"`` (after DONE, for an island:
        :mod:`kilonet.protocols.localize.phase4_island`) or ``"done"``."""
        return self.driver.phase.name

    @property
    def round_index(self) -> int:
        """Rounds of work done: the time stamps of the neighbour records."""
        return self._round

    @property
    def in_frame(self) -> bool:
        """Whether this robot holds a position in a frame: a located robot, or a root whose
        axis robot has placed itself (a lone root's origin is no frame)."""
        if self.is_root:
            return self.spread.frame_started
        return self.position is not None

    @property
    def frame_label(self) -> str:
        """The name of the frame this robot is in: ``root`` and the root's election key in
        hex (as in ``robots.csv``)."""
        return f"root{self.root_key:08x}"

    def position_estimate(self) -> tuple[float, float, str] | None:
        """Its position in the frame now (``None`` until it holds one), for the run's estimates
        table."""
        return (*self.position, self.frame_label) if self.in_frame else None

    @property
    def flags(self) -> int:
        """This robot's state flags as POS and ROOT announce them."""
        t = self.termination
        return (
            (LOCALIZED if self.position is not None else 0)
            | (SETTLED if t.settled else 0)
            | (COMPLETE if t.complete else 0)
            | (DONE if t.done else 0)
        )

    def locate(self, x_mm: float, y_mm: float) -> None:
        """Take a position in the frame (the spread's rules or the root's origin)."""
        self.position = (x_mm, y_mm)
        self.located_tick = self.kilo_ticks
        self.refiner.reset()

    def unlocate(self, cause: str) -> None:
        """Give the position up (``cause`` goes to the event log): it was taken from a frame
        start the root has since replaced."""
        self.position = None
        self.refiner.reset()
        self.log("unlocated", cause=cause)

    def change_parent(self, parent: int) -> None:
        """Report to ``parent`` in the convergecasts from now on; a new one is owed
        ``localize.parent_repeats`` announcements."""
        if parent != self.parent:
            self.parent = parent
            self._parent_repeats = self.params.parent_repeats
            self._parent_round = self._round

    # -- refinement ----------------------------------------------------------------------------
    def refine(self, fresh: list[Neighbour]) -> None:
        """A step of refinement of the position from the placed neighbours among ``fresh``
        (the root holds its origin)."""
        x, y = self.position
        if self.is_root:
            self.refiner.hold(x, y)
            return
        links = [(n.x_mm, n.y_mm, n.range_mm) for n in fresh if n.x_mm is not None]
        x, y = self.refiner.step(x, y, links, fix_y=self.uid == self.spread.axis)
        # Positions beyond MAX_COORDINATE_MM cannot be sent: the frame ends there.
        x = min(max(x, -MAX_COORDINATE_MM), MAX_COORDINATE_MM)
        y = min(max(y, -MAX_COORDINATE_MM), MAX_COORDINATE_MM)
        self.position = (x, y)

    # -- distance reports ----------------------------------------------------------------------
    def _dist_tx(self) -> Message | None:
        """A distance report about the neighbour :func:`next_report` picks (never about an ID
        two robots share), or None with no neighbour yet."""
        n = next_report(self.neighbours.by_id.values())
        if n is None:
            return None
        n.sent_round = self._round
        return distance_report(self.uid, self.position, n)

    def reference_position(self, n: Neighbour | None = None) -> tuple[float, float]:
        """A position known whole near neighbour ``n``, to unwrap the coordinates of messages
        without winding numbers (DIST, ISLAND_LINK) near: its last, else this robot's, else
        any neighbour's, else the root's (0, 0) — a robot that knows no position at all
        takes them as they come, as a swarm within 3.2 m of its root always may."""
        if n is not None and n.x_mm is not None:
            return n.x_mm, n.y_mm
        if self.position is not None:
            return self.position
        for other in self.neighbours.known():
            if other.x_mm is not None:
                return other.x_mm, other.y_mm
        return 0.0, 0.0

    def _dist_rx(self, n: Neighbour, message: Message) -> None:
        m = DIST.unpack(message)
        near_x, near_y = self.reference_position(n)
        if n.x_mm is None:
            n.placed_tick = self.kilo_ticks
        n.x_mm = unwrap_coordinate(m.x_mm, near_x)
        n.y_mm = unwrap_coordinate(m.y_mm, near_y)
        if m.neighbour == self.uid:
            self.neighbours.report(n, m.distance)

    def _nbr_rx(self, n: Neighbour, message: Message) -> None:
        m = NBR.unpack(message)
        if m.neighbour == self.uid:
            n.reported_mm = m.distance_mm
            return
        n.near.add(m.neighbour)
        if self.reports is not None:
            # A root chooses its frame robots from its neighbours' distances to each other.
            self.reports.setdefault(m.sender, {})[m.neighbour] = m.distance_mm

    def _parent_rx(self, n: Neighbour, message: Message) -> bool:
        """ELECT after the election: a neighbour announcing its parent."""
        # Its hop count here may be the election's, which can be lower than the one it takes
        # in the frame: POS and ROOT carry that one.
        hops = n.hops
        news = Election.record(n, message)
        n.hops = hops
        return news

    def _state_rx(self, n: Neighbour, message: Message) -> bool:
        """ROOT or POS: the sender's state; whether its flags changed (a DONE among them ends
        this robot's work too)."""
        before = n.flags
        spread = self.spread
        (spread.root_rx if message.type == ROOT.type else spread.pos_rx)(n, message)
        if n.flags == before:
            return False
        if n.flags & DONE:
            self.termination.finish("heard")
        return True

    def _cand_rx(self, n: Neighbour, message: Message) -> bool:
        self.spread.cand_rx(n, message)
        return False

    # -- LED -----------------------------------------------------------------------------------
    def show(self) -> None:
        """Set the LED to this robot's state (:attr:`LED_KEY`)."""
        if not self.driver.phase.awake:
            self.set_color(0, 0, 0)
        elif self.is_root:
            self.set_color(3, 3, 3)
        elif self.termination.settled and self.position is not None:
            self.set_color(0, 3, 3)
        elif self.position is not None:
            self.set_color(0, 3, 0)
        else:
            self.set_color(0, 0, 2)
