"""Scripted neighbours: :class:`Replay` robots that offer a schedule of messages."""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Iterable

from kilonet.message import Message
from kilonet.robot import Kilobot
from kilonet.testing.errors import ScriptError

__all__ = ["Replay"]


class Replay(Kilobot):
    """A scripted neighbour: offers the messages of a schedule at its transmit opportunities,
    under the medium's real rules (its own clock's period, carrier sense, collisions, loss,
    distance noise).

    Parameters
    ----------
    schedule : iterable of (from_s, Message or None)
        Simulated times (the test's clock, not the robot's) and messages.
    repeat : bool
        ``True``: at each opportunity offer the latest message due (``None`` in the schedule
        falls silent), as robots broadcast their state. ``False``: offer each message once,
        in order, at the first opportunity at or after its time.

    Raises
    ------
    ScriptError
        If a time is negative or not a number, or an entry is not a Message or None.

    Examples
    --------
    >>> from kilonet.message import Message
    >>> hello = Message(b"hi", 1)
    >>> Replay([(1.0, hello), (3.0, None)]).due(2.0) is hello
    True
    >>> Replay([(1.0, hello), (3.0, None)]).due(3.5) is None
    True
    """

    def __init__(
        self, schedule: Iterable[tuple[float, Message | None]], *, repeat: bool = True
    ) -> None:
        entries = []
        for entry in schedule:
            t_s, message = entry
            if not (isinstance(t_s, int | float) and t_s >= 0):
                raise ScriptError(f"Replay: schedule time {t_s!r} must be a number >= 0 s")
            if message is not None and not isinstance(message, Message):
                raise ScriptError(f"Replay: {message!r} at {t_s} s is not a Message or None")
            entries.append((float(t_s), message))
        entries.sort(key=lambda e: e[0])  # stable: equal times keep their order
        self.schedule = entries
        self._times = [t_s for t_s, _ in entries]
        self.repeat = repeat
        self._next = 0  # repeat=False: the next entry to send

    @classmethod
    def every(cls, message: Message, *, from_s: float = 0.0, until_s: float = math.inf) -> Replay:
        """A neighbour that offers ``message`` at every opportunity from ``from_s`` until
        ``until_s`` (simulated s)."""
        schedule = [(from_s, message)] + ([(until_s, None)] if math.isfinite(until_s) else [])
        return cls(schedule)

    def due(self, now_s: float) -> Message | None:
        """The message to offer at ``now_s`` (see ``repeat``); ``repeat=False`` counts it as
        sent."""
        if self.repeat:
            k = bisect_right(self._times, now_s)
            return self.schedule[k - 1][1] if k else None
        while self._next < len(self.schedule) and self.schedule[self._next][0] <= now_s:
            message = self.schedule[self._next][1]
            self._next += 1
            if message is not None:
                return message
        return None

    def message_tx(self) -> Message | None:
        return self.due(self._kenv.now)
