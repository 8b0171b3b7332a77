"""The phased-protocol pattern: a protocol's stages as a typed enum, and the phase object that
runs one stage on one robot.

Every protocol here that runs in stages names them in a :class:`Stage` subclass, in the order
they run: gcs (:class:`kilonet.protocols.gcs.base.GcsStage`, one :class:`Phase` object per stage,
run from a window table), ``localize`` (:class:`kilonet.protocols.localize.base.LocalizeStage`) and
the maze robot (:class:`kilonet.protocols.maze.program.MazeStage`). A member's value is its name:
the trace, the summaries and the parameters (``gcs.until``) write stages as those strings, and a
member compares equal to its name.

A :class:`Phase` declares its stage (``name``) and whether it is *open-ended*: it ends when the
robots agree it is over, not when a window closes. A run's stop rule and a robot's schedule
read that declaration instead of listing phase names.

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
"""

from __future__ import annotations

from enum import StrEnum
from typing import TYPE_CHECKING, ClassVar

if TYPE_CHECKING:
    from kilonet.message import Message

__all__ = ["Phase", "Stage"]


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
