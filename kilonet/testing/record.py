"""What the test kit records of a robot: plain value types (named tuples and one small
dataclass) that a test can compare, index and turn into DataFrames, and a program's own state
(:func:`program_state`).
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any, NamedTuple

from kilonet.message import Message
from kilonet.ranging import DistanceMeasurement
from kilonet.robot import Kilobot

__all__ = [
    "Change",
    "Heard",
    "LoggedEvent",
    "ScriptedReception",
    "Sent",
    "program_state",
]


class Sent(NamedTuple):
    """A message a robot put on the air.

    Attributes
    ----------
    t_s : float
        When it went on the air (the transmit opportunity at which the program offered it;
        kilolib senses the carrier before it asks, so every message offered is sent at once).
    message : Message
        The message as offered.
    fields : named tuple or None
        Its fields, when the record was asked for with the message's :class:`Layout`.
    """

    t_s: float
    message: Message
    fields: Any = None


class Heard(NamedTuple):
    """A reception handed to a robot's program.

    Attributes
    ----------
    t_s : float
        When the program got it (the end of the airtime, later with a delaying receiver fault).
    message : Message
        The message.
    distance : int or DistanceMeasurement
        The distance as the program got it (mm, or kilolib's raw readings).
    sender : hashable or None
        The scripted sender's label, or the index of the robot that sent it (``None`` if the
        kit cannot tell).
    fields : named tuple or None
        Its fields, when asked for with a :class:`Layout`.
    """

    t_s: float
    message: Message
    distance: int | DistanceMeasurement
    sender: Hashable | None
    fields: Any = None


class Change(NamedTuple):
    """A new value of an output (LED colour ``(r, g, b)`` or motor duty ``(left, right)``)."""

    t_s: float
    value: tuple[int, ...]


class LoggedEvent(NamedTuple):
    """A protocol event the program logged with ``self.log(name, **fields)``."""

    t_s: float
    name: str
    fields: dict[str, Any]


@dataclass
class ScriptedReception:
    """One reception a test scripted, and what became of it.

    Attributes
    ----------
    at_s : float
        When it begins arriving (its airtime starts; the program gets it at the end).
    message : Message
        What arrives (a copy of the test's message, with a wrong CRC if ``corrupt``).
    distance_mm : float
        The sender's distance, mm (the estimate the program gets, unless ``noise``).
    sender : hashable
        The label the test gave the sender.
    lost, corrupt, noise, sense_carrier : bool
        Lost for sure; sent with a wrong CRC; distance estimate from the run's reception
        model instead of exactly ``distance_mm``; waits for a free channel (``at_s`` is then
        when it began).
    fate : str
        ``"scheduled"``, ``"on air"``, then ``"delivered"``, ``"lost"`` (scripted), or what
        the medium lost it to: ``"collision"``, ``"crc"``, ``"random"``, ``"battery"``,
        ``"fault"``, ``"stopped"`` (the robot had stopped).
    end_s : float or None
        End of its airtime, once it is on the air.
    """

    at_s: float
    message: Message
    distance_mm: float
    sender: Hashable
    lost: bool = False
    corrupt: bool = False
    noise: bool = False
    sense_carrier: bool = False
    fate: str = "scheduled"
    end_s: float | None = None


def program_state(program: Kilobot) -> dict[str, Any]:
    """A program's own state: the public attributes its classes set (not the kernel's handles
    nor its calibration values), from its instance dict and its slots.

    Examples
    --------
    >>> class Counter(Kilobot):
    ...     def setup(self):
    ...         self.count, self._cache = 0, None
    >>> robot = Counter()
    >>> robot.setup()
    >>> program_state(robot)
    {'count': 0}
    """
    names: list[str] = []
    for cls in reversed(type(program).__mro__):
        if issubclass(Kilobot, cls):
            continue  # Kilobot itself and what it derives from: the kernel's attributes
        names.extend(s for s in cls.__dict__.get("__slots__", ()) if s not in names)
    names.extend(k for k in getattr(program, "__dict__", {}) if k not in names)
    return {n: getattr(program, n) for n in names if not n.startswith("_") and hasattr(program, n)}
