"""Scheduling plain callbacks on the SimPy clock, at a fraction of a Timeout's cost.

The medium schedules two wake-ups per message; a ``simpy.Timeout`` builds a full event for each.
:func:`call_later` pushes a bare object that carries exactly what ``Environment.step`` reads
(``callbacks``, ``_ok``, ``_value``) onto the environment's queue with the same key a Timeout
would get (time, NORMAL priority, insertion counter), so ordering and determinism are SimPy's own.

Examples
--------
>>> import simpy
>>> env = simpy.Environment()
>>> log = []
>>> call_later(env, 2.0, lambda e: log.append(("b", env.now, e._value)), "x")
>>> call_later(env, 1.0, lambda e: log.append(("a", env.now, e._value)))
>>> env.run()
>>> log
[('a', 1.0, None), ('b', 2.0, 'x')]
"""

from __future__ import annotations

from collections.abc import Callable
from heapq import heappush
from typing import Any

import simpy
from simpy.events import NORMAL

__all__ = ["Wakeup", "call_later"]


class Wakeup:
    """A bare event: the minimum ``simpy.Environment.step`` needs to run its callbacks."""

    __slots__ = ("_ok", "_value", "callbacks")

    def __init__(self, callback: Callable[[Wakeup], None], value: Any) -> None:
        self.callbacks = [callback]
        self._value = value
        self._ok = True


def call_later(
    env: simpy.Environment, delay_s: float, callback: Callable[[Wakeup], None], value: Any = None
) -> None:
    """Call ``callback(wakeup)`` after ``delay_s`` simulated seconds; ``wakeup._value`` is
    ``value``. Ties with other events break by scheduling order, as in SimPy."""
    heappush(env._queue, (env._now + delay_s, NORMAL, next(env._eid), Wakeup(callback, value)))
