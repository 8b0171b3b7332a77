"""The phased-protocol pattern: a protocol's stages as a typed enum, the phase object that
runs one stage on one robot, and the driver that holds the running phase.

Every protocol here that runs in stages names them in a :class:`Stage` subclass, in the order
they run: gcs (:class:`kilonet.protocols.gcs.base.GcsStage`, one :class:`Phase` per stage, each
in a window, run by a :class:`PhaseDriver`), ``localize``
(:class:`kilonet.protocols.localize.stages.LocalizeStage`, one phase per stage, run by a
:class:`PhaseDriver` too) and the maze robot
(:class:`kilonet.protocols.maze.program.MazeStage`). A member's value is its name:
the trace, the summaries and the parameters (``gcs.until``) write stages as those strings, and a
member compares equal to its name.

A :class:`Phase` declares its stage (``name``) and whether it is *open-ended*: it ends when the
robots agree it is over, not when a window closes. A run's stop rule and a robot's schedule
read that declaration instead of listing phase names.

A :class:`PhaseDriver` holds a robot's running phase and its receive handlers by message type
byte: the protocol's own, with the running phase's (:meth:`Phase.handlers`) in place of them for
the types it names. The table is rebuilt when a phase begins, so a reception costs one lookup,
not a call into every phase. A phase ends when its window closes (the ``until`` tick it was
entered with: by default its own :attr:`Phase.until`, which a protocol that runs its phases in
windows sets on each phase it makes) or when it reports itself :meth:`~Phase.finished`;
:meth:`PhaseDriver.advance` then starts the phase it hands on to (:meth:`Phase.following`).
A protocol that asks its phases whether they are over only at one point of its work advances
by windows alone elsewhere (``ask=False``), and one that logs or shows each phase it enters
gives the driver an ``entered`` callback.

Examples
--------
>>> class Walk(Stage):
...     LISTEN = "listen"
...     MOVE = "move"
>>> Walk.names(), Walk.MOVE.number, Walk.MOVE == "move"
(('listen', 'move'), 2, True)
>>> class Moving(Phase):
...     name = Walk.MOVE
...     open_ended = True
>>> Moving.name.number, Moving.open_ended, Phase.open_ended
(2, True, False)

A listening phase that ends by its window and hands on to a moving phase that ends when it
has moved three times; the listening phase takes over message type 7:

>>> class Listening(Phase):
...     name = Walk.LISTEN
...     def handlers(self): return {7: lambda m: f"heard {m} while listening"}
...     def following(self): return Counting()
>>> class Counting(Moving):
...     moves = 0
...     def finished(self): return self.moves >= 3
>>> driver = PhaseDriver({7: lambda m: f"heard {m}", 8: lambda m: "eight"})
>>> driver.enter(Listening(), until=100)
>>> str(driver.stage), driver.handler(7)("x"), driver.handler(8)("y"), driver.handler(9)
('listen', 'heard x while listening', 'eight', None)
>>> driver.advance(99), driver.advance(100), str(driver.stage), driver.handler(7)("x")
(False, True, 'move', 'heard x')
>>> driver.phase.moves = 3
>>> driver.advance(101), driver.phase, driver.stage
(True, None, '')
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from enum import StrEnum
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from kilonet.message import Message

__all__ = ["Handler", "Phase", "PhaseDriver", "Stage"]

#: A receive handler: the protocol decides its arguments (the message, and whatever it has
#: learned of the sender) and what it returns.
Handler = Callable[..., Any]


class Stage(StrEnum):
    """The stages of one protocol, in the order they run (subclass it with one member each).

    Members are strings (their names), so they are written to traces and summaries as such.
    Do not order members with ``<``: that compares the strings; use :attr:`number`.
    """

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """Every stage's name, in order."""
        return tuple(member.value for member in cls)

    @property
    def number(self) -> int:
        """The stage's place in its protocol's order, from 1."""
        return list(type(self)).index(self) + 1


class Phase:
    """One stage of a protocol on one robot, with kilolib's callbacks.

    A subclass sets ``name`` (a member of its protocol's :class:`Stage`) and, if the phase
    ends by itself rather than when its window closes, ``open_ended = True``; the protocol's
    program creates it when the stage begins, calls :meth:`start`, then the callbacks, then
    :meth:`finish`.
    """

    __slots__ = ()
    #: The stage this phase runs ("" on the base class).
    name: ClassVar[Stage | str] = ""
    #: Whether the phase ends by itself (the robots agree it is over), not by a window.
    open_ended: ClassVar[bool] = False
    #: The tick at which this phase's window closes, as the protocol that made it set it
    #: (``inf``, the default: it has none, it ends when it reports itself finished); the
    #: driver enters a phase with it unless told otherwise.
    until: float = math.inf

    def start(self) -> None:
        """Called when the phase begins on this robot."""

    def finished(self) -> bool:
        """Whether the phase is over on this robot before its window closes. Default: never,
        the window decides."""
        return False

    def finish(self) -> None:
        """Called when the phase ends (before the next one starts)."""

    def message_tx(self) -> Message | None:
        """The message to offer now, or ``None``."""
        return None

    def message_rx(self, message: Message, distance_mm: int) -> None:
        """A reception, of any type, with the measured distance to its sender, mm."""

    def loop(self) -> None:
        """Called from the robot's loop while the phase runs."""

    def handlers(self) -> Mapping[int, Handler]:
        """This phase's receive handlers by message type byte, in place of the protocol's own
        for those types while it runs (:class:`PhaseDriver`). Default: none."""
        return {}

    def following(self) -> Phase | None:
        """The phase that runs once this one is over (``None``: none; the driver then holds no
        phase). Called once, just before :meth:`finish`."""
        return None


class PhaseDriver:
    """The running phase of one robot's protocol, its receive handlers, and its transitions.

    Parameters
    ----------
    handlers : mapping
        The protocol's receive handlers by message type byte, for every phase; a phase's own
        (:meth:`Phase.handlers`) replace them for the types it names while it runs.
    entered : callable, optional
        Called with each phase the driver enters, once the phase before it has finished and
        before the new one starts (a protocol logs its phases there).

    Attributes
    ----------
    phase : Phase or None
        The running phase (``None`` before the first and after the last).
    until : float
        The tick at which the running phase's window closes (``inf``: it ends only when it
        reports itself finished).
    handler : callable
        ``handler(kind)``: the receive handler for message type ``kind`` now, or ``None`` for
        a type nobody handles. The table's own ``get``, rebound when a phase begins: a
        reception looks its handler up without a Python call.
    """

    __slots__ = ("_common", "_entered", "handler", "phase", "until")

    def __init__(
        self,
        handlers: Mapping[int, Handler],
        *,
        entered: Callable[[Phase], None] | None = None,
    ) -> None:
        self._common: dict[int, Handler] = dict(handlers)
        self._set_table(self._common)
        self._entered = entered
        self.phase: Phase | None = None
        self.until = math.inf

    @property
    def stage(self) -> Stage | str:
        """The running phase's stage ("" when no phase runs)."""
        return self.phase.name if self.phase is not None else ""

    def _set_table(self, table: dict[int, Handler]) -> None:
        """Receive by ``table`` from now on (:attr:`handler` is its ``get``)."""
        self.handler: Callable[[int], Handler | None] = table.get

    def enter(self, phase: Phase | None, *, until: float | None = None) -> None:
        """Finish the running phase, if any, and start ``phase`` (``None``: run none), whose
        window closes at tick ``until`` (default: the phase's own :attr:`Phase.until`)."""
        if self.phase is not None:
            self.phase.finish()
        self.phase = phase
        if phase is None:
            self.until = math.inf
            self._set_table(self._common)
            return
        self.until = phase.until if until is None else until
        self._set_table({**self._common, **phase.handlers()})
        if self._entered is not None:
            self._entered(phase)
        phase.start()

    def advance(self, tick: float, *, ask: bool = True) -> bool:
        """At ``tick``, move on from every phase whose window has closed or (``ask``) that
        reports itself finished, to the phase it hands on to, with that phase's own window
        (:attr:`Phase.until`); whether the phase changed. With ``ask`` false only windows end
        phases: a protocol whose phases may be asked only at one point of its work (asking
        can cost, or count time) passes it everywhere else."""
        moved = False
        while self.phase is not None and (tick >= self.until or (ask and self.phase.finished())):
            self.enter(self.phase.following())
            moved = True
        return moved

    def reschedule(self, until: float) -> None:
        """The running phase's window closes at tick ``until`` instead (a protocol that plans
        its phases again while one runs, as gcs's recovery epochs do)."""
        self.until = until
