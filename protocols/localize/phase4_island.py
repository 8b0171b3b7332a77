"""Phase 4 of ``localize``: after DONE, an island of robots the spread left out places itself.

Multilateration (:mod:`kilonet.protocols.localize.phase2_spread`) places a robot once it hears three
placed neighbours, or two and a neighbour's candidates. Where the frame meets a group of robots that
each hear at most two placed ones, it stops — though the group is often rigid as a whole and
tied to the frame by enough distances to fix where it stands. Such a group, an *island*,
places itself once the swarm is done, when the frame stands still and the channel is free
(before, its traffic would slow a frame still growing elsewhere):

1. **Staying awake.** A robot that is unplaced when DONE reaches it stays awake (stage
   ``"island"``) if a neighbour is unplaced too. It joins at once if two unplaced neighbours
   hear each other (:func:`in_unplaced_triangle`: an island needs a triangle to place itself),
   or when it hears an island report; else it is done after ``localize.island_quiet_s``.
2. **Reports.** A member reports, once each, every distance it has to another unplaced robot
   (the one of the two with the lower ID does) and to a placed one, with that robot's last
   position. Every member stores the reports it hears and passes each new one on once, so the
   reports flood the island and stop at its shore (placed robots are done and silent). A
   member stores at most ``localize.island_max_reports``: once it has heard more, the island
   is too large to solve; the member stops passing reports on and says so (ISLAND_FULL),
   and a member that hears that stops too.
3. **Solving.** When a member's reports have not changed for ``island_quiet_s`` it solves the
   island itself (:func:`~kilonet.protocols.localize.island_solve.solve_island`: rigid bodies of
   members aligned to the frame through their links, each only where it is unique) and, if that
   places it, takes the position. The spread's rules keep running too, so its neighbours can
   multilaterate from it.
4. **Finishing** (:meth:`Island.finished`). A placed member refines against its neighbours
   until it has settled and passed on what its unplaced neighbours may need; an unplaced one
   is done once it has solved with every report it holds and heard nothing new for twice
   ``island_quiet_s``. It announces its last state ``localize.done_repeats`` times and falls
   silent.

Messages (the sender first, then the member that measured the distance)::

    ISLAND_PAIR (87)  sender:uint16  origin:uint16  neighbour:uint16
                      distance:uint16 (0.01 mm)                               8 bytes
    ISLAND_LINK (88)  sender:uint16  origin:uint16  x:int16  y:int16 (0.1 mm)
                      distance:uint8 (mm)                                     9 bytes
    ISLAND_FULL (89)  sender:uint16                                           2 bytes

A link's x and y travel modulo 6,553.6 mm
(:func:`~kilonet.protocols.localize_base.wrapped_position`) and a member unwraps them near a
position it knows whole, its placed neighbours' (an island is far smaller than 3.2 m;
:meth:`~kilonet.protocols.localize.LocalizeRobot.reference_position`).

A link's distance is carried in whole millimetres, as kilolib's ``estimate_distance`` returns
it: links longer than 255 mm are not reported, and the solve counts the rounding (a spread of
1/√12 mm) into its noise. A link is known by its origin and the placed robot's position: a
report within ``_SAME_POINT_MM`` of a stored one from the same origin is the same link. Every
report is stored once and passed on once: the flood ends.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING

from kilonet.message import Layout, Message
from kilonet.protocols.localize.base import Neighbour, unwrap_coordinate, wrapped_position
from kilonet.protocols.localize.island_solve import Tolerances, solve_island

if TYPE_CHECKING:
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = [
    "ISLAND_FULL",
    "ISLAND_LINK",
    "ISLAND_PAIR",
    "Island",
    "IslandReports",
    "in_unplaced_triangle",
]

ISLAND_PAIR = Layout(
    "island_pair",
    type=87,
    fields=[
        ("sender", "H"),
        ("origin", "H"),
        ("neighbour", "H"),
        ("distance_mm", "H", 0.01),
    ],
)
ISLAND_LINK = Layout(
    "island_link",
    type=88,
    fields=[
        ("sender", "H"),
        ("origin", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("distance_mm", "B"),
    ],
)
ISLAND_FULL = Layout("island_full", type=89, fields=[("sender", "H")])

#: Two link reports of one origin this close (mm) are about the same placed robot.
_SAME_POINT_MM = 3.0
#: ISLAND_FULL messages a robot sends when its island turns out too large.
_FULL_NOTICES = 2
#: Longest link a report carries (uint8 millimetres).
_MAX_LINK_MM = 255.0
_ROUNDING_VARIANCE_MM2 = 1.0 / 12.0

Point = tuple[float, float]


def in_unplaced_triangle(neighbours: Iterable[Neighbour]) -> bool:
    """Whether two unplaced ``neighbours`` hear each other (one reported the other in NBR):
    with this robot they form a triangle of unplaced robots, the seed of a rigid body
    (:func:`~kilonet.protocols.localize.island_solve.solve_island` places nothing in an island
    without one that multilateration could not place already).

    Examples
    --------
    >>> a, b, c = Neighbour(1), Neighbour(2), Neighbour(3)
    >>> a.near, c.x_mm, c.y_mm = {2, 3}, 0.0, 0.0
    >>> in_unplaced_triangle([a, b, c]), in_unplaced_triangle([a, c])  # c is placed
    (True, False)
    """
    unplaced = {n.uid: n for n in neighbours if n.x_mm is None}
    return any(v != n.uid and v in unplaced for n in unplaced.values() for v in n.near)


class IslandReports:
    """The island's distances as one member has heard them. A report is stored once and never
    replaced: passing on a newer value would let an older one, still on its way round the
    island, come back as news, and the two would circle for ever.

    Examples
    --------
    >>> r = IslandReports(capacity=3)
    >>> r.pair(1, 2, 40.0), r.pair(2, 1, 40.4)  # the second is the same pair
    (True, False)
    >>> r.link(1, 100.0, 0.0, 60.0), r.link(1, 102.5, 0.3, 60.0), r.link(1, 300.0, 0.0, 50.0)
    (True, False, True)
    >>> r.link(2, 0.0, 0.0, 50.0), r.full  # a fourth report does not fit
    (False, True)
    >>> r.pairs, r.links
    ({(1, 2): 40.0}, [(1, (100.0, 0.0), 60.0), (1, (300.0, 0.0), 50.0)])
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.pairs: dict[tuple[int, int], float] = {}
        self._links: dict[int, list[tuple[float, float, float]]] = {}
        self.size = 0
        self.full = False

    def pair(self, a: int, b: int, distance_mm: float) -> bool:
        """Store the distance between unplaced robots a and b; whether it is new."""
        key = (min(a, b), max(a, b))
        if key in self.pairs or not self._room():
            return False
        self.pairs[key] = distance_mm
        return True

    def link(self, origin: int, x_mm: float, y_mm: float, distance_mm: float) -> bool:
        """Store the distance from ``origin`` to the placed robot at (x, y); whether it is
        new."""
        held = self._links.setdefault(origin, [])
        if any(math.hypot(x - x_mm, y - y_mm) < _SAME_POINT_MM for x, y, _ in held):
            return False
        if not self._room():
            return False
        held.append((x_mm, y_mm, distance_mm))
        return True

    @property
    def links(self) -> list[tuple[int, Point, float]]:
        """Every link as (origin, (x_mm, y_mm), distance_mm)."""
        return [(u, (x, y), d) for u, held in self._links.items() for x, y, d in held]

    def _room(self) -> bool:
        if self.size >= self.capacity:
            self.full = True
            return False
        self.size += 1
        return True


class Island:
    """Phase 4 on one robot: staying awake after DONE, reporting and passing on, solving."""

    name = "island"

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot
        p = robot.params
        tps = robot.ticks_per_s
        self.quiet_ticks = p.island_quiet_s * tps
        self.awake = False  # unplaced with an unplaced neighbour when DONE came
        self.active = False  # a member: reports, passes on and solves
        self.awake_tick = 0.0
        self.unplaced_near = False  # a neighbour was unplaced at the last round
        self.reports = IslandReports(p.island_max_reports)
        self.outbox: deque[Message] = deque()
        self.changed_tick = 0.0
        self.version = 0
        self.solved_version = 0
        self.reported: set[tuple[bool, int]] = set()  # (placed?, neighbour) reported
        self.full_notices = 0  # ISLAND_FULL messages still to send
        self.closed = False  # the island is too large: this robot has stopped talking of it

    def wake(self, tick: int, fresh: list[Neighbour]) -> bool:
        """At DONE: whether this robot stays awake for an island (it is unplaced, and so is a
        neighbour); it joins at once if two unplaced neighbours hear each other. A robot
        placed moments before DONE reached it, and not yet settled, stays awake too and
        finishes as a placed member does (:meth:`finished`): a robot placed after the root's
        DONE, from an island's new positions, hears DONE a round later, and frozen then it would
        keep a fix only a refinement step or two old."""
        r = self.robot
        self.unplaced_near = any(n.x_mm is None for n in fresh)
        if self.reports.capacity == 0:
            return False
        refining = r.position is not None and not r.termination.settled
        if not refining and (r.position is not None or not self.unplaced_near):
            return False
        self.awake, self.awake_tick, self.changed_tick = True, tick, tick
        if refining or in_unplaced_triangle(fresh):
            self._join()
        return True

    def _join(self) -> None:
        self.active = True
        self.robot.log("island_joined", reports=self.reports.size)
        self.outbox.extend(self._stored_messages())

    # -- messages ------------------------------------------------------------------------------
    def message_tx(self) -> Message | None:
        """The next report to send or pass on, while a member; else None. A member that has
        placed itself passes reports on while a neighbour is still unplaced (the rest of its
        island may hear them only through it), and then drops them."""
        if self.full_notices:
            self.full_notices -= 1
            return ISLAND_FULL.pack(sender=self.robot.uid)
        if not self.active or not self.outbox or self.closed:
            return None
        if self.robot.position is not None and not self.unplaced_near:
            self.outbox.clear()
            return None
        return self.outbox.popleft()

    def pair_rx(self, n: Neighbour, message: Message) -> None:
        m = ISLAND_PAIR.unpack(message)
        if m.origin != self.robot.uid:
            self._heard(self.reports.pair(m.origin, m.neighbour, m.distance_mm), ISLAND_PAIR, m)

    def link_rx(self, n: Neighbour, message: Message) -> None:
        m = ISLAND_LINK.unpack(message)
        if m.origin != self.robot.uid:
            near = self.robot.reference_position()
            x = unwrap_coordinate(m.x_mm, near[0])
            y = unwrap_coordinate(m.y_mm, near[1])
            news = self.reports.link(m.origin, x, y, m.distance_mm)
            self._heard(news, ISLAND_LINK, m)

    def full_rx(self, n: Neighbour, message: Message) -> None:
        """A neighbour's store overflowed: this island is too large for this robot too."""
        if self.awake and not self.closed:
            self.reports.full = True
            self._overflowed()

    def _overflowed(self) -> None:
        """Stop talking about an island too large to solve, and say so (ISLAND_FULL, sent
        ``_FULL_NOTICES`` times before any report) so the whole island stops soon."""
        self.closed = True
        self.outbox.clear()
        self.full_notices = _FULL_NOTICES
        self.robot.log("island_full", reports=self.reports.size)

    def _heard(self, news: bool, layout: Layout, report) -> None:
        """A neighbour's report, ``news`` if it is new to the store: an awake robot joins,
        and a member passes it on."""
        if not self.awake or self.closed:
            return
        if not self.active:
            self._join()
        if news:
            self._changed(self.robot.kilo_ticks)
            self.outbox.append(layout.pack(**{**report._asdict(), "sender": self.robot.uid}))
        elif self.reports.full:
            self._overflowed()

    # -- rounds --------------------------------------------------------------------------------
    def round(self, tick: int, known: list[Neighbour]) -> None:
        """Report this robot's own distances, and solve once the reports are quiet."""
        self.unplaced_near = any(n.x_mm is None for n in known)
        if not self.active or self.robot.position is not None:
            return
        self._report(tick, known)
        if tick - self.changed_tick >= self.quiet_ticks and self.version != self.solved_version:
            self._solve()

    def finished(self, tick: int) -> bool:
        """Whether this robot's island work is over: it heard no report within
        ``island_quiet_s`` of waking; or it placed itself, its position has settled and it has
        passed on what its unplaced neighbours may need (nothing, once the island is closed
        as too large) and the votes it owes them; or, unplaced, it has solved with
        every report it holds and heard nothing new for twice ``island_quiet_s``."""
        r = self.robot
        if not self.active:
            return tick - self.awake_tick >= self.quiet_ticks
        if r.position is not None:
            # A closed island's outbox is never sent (message_tx): nothing to wait for.
            pending = self.outbox and self.unplaced_near and not self.closed
            return r.refiner.settled and not pending and not r.spread.votes_out
        solved = self.closed or self.version == self.solved_version
        return solved and tick - self.changed_tick >= 2 * self.quiet_ticks

    def _report(self, tick: int, fresh: list[Neighbour]) -> None:
        r = self.robot
        uid = r.uid
        for n in fresh:
            key = (n.x_mm is not None, n.uid)
            if n.samples == 0 or key in self.reported:
                continue
            self.reported.add(key)
            d = n.range_mm
            if n.x_mm is None:
                if uid < n.uid and self.reports.pair(uid, n.uid, d):
                    self._changed(tick)
                    self.outbox.append(
                        ISLAND_PAIR.pack(sender=uid, origin=uid, neighbour=n.uid, distance_mm=d)
                    )
            elif d <= _MAX_LINK_MM:
                d = round(d)
                if self.reports.link(uid, n.x_mm, n.y_mm, float(d)):
                    self._changed(tick)
                    self.outbox.append(_link_message(uid, uid, (n.x_mm, n.y_mm), d))
        if self.reports.full and not self.closed:
            self._overflowed()

    def _changed(self, tick: float) -> None:
        self.version += 1
        self.changed_tick = tick

    def _stored_messages(self) -> list[Message]:
        """Every stored report, to pass on when this robot joins."""
        uid = self.robot.uid
        out = [
            ISLAND_PAIR.pack(sender=uid, origin=a, neighbour=b, distance_mm=d)
            for (a, b), d in self.reports.pairs.items()
        ]
        out += [_link_message(uid, o, p, round(d)) for o, p, d in self.reports.links]
        return out

    def _solve(self) -> None:
        r = self.robot
        self.solved_version = self.version
        if self.reports.full:
            return
        p = r.params
        sigma = math.sqrt(r.sigma_mm**2 + _ROUNDING_VARIANCE_MM2)
        tolerances = Tolerances(
            sigma_mm=sigma,
            min_height_mm=p.min_height_mm,
            max_rmse_mm=p.max_residual_sigmas * sigma,
            overlap_mm=p.overlap_mm,
        )
        found = solve_island(r.uid, self.reports.pairs, self.reports.links, tolerances)
        r.log("island_solved", members=len(found), placed=r.uid in found)
        if r.uid in found:
            x, y = found[r.uid]
            r.spread.place(x, y, "island", len(found))


def _link_message(sender: int, origin: int, position: Point, distance_mm: int) -> Message:
    """ISLAND_LINK: ``origin``'s distance to the placed robot at ``position`` (wrapped)."""
    x, y, _ = wrapped_position(*position)
    return ISLAND_LINK.pack(sender=sender, origin=origin, x_mm=x, y_mm=y, distance_mm=distance_mm)
