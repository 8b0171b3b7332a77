"""Scheduling plain callbacks on the SimPy clock, at a fraction of a Timeout's cost.

The medium schedules two wake-ups per message and every robot one per loop period; a
``simpy.Timeout`` builds a full event for each. Here the queue entry is a bare object carrying
exactly what ``Environment.step`` reads (``callbacks``, ``_ok``, ``_value``), pushed onto the
environment's queue with the key a Timeout would get (time, NORMAL priority, insertion counter),
so ordering and determinism are SimPy's own. A :class:`Timer` is reusable: an entity with at
most one pending wake-up (a robot's next loop, its next transmit opportunity) allocates nothing
per wake-up.

Examples
--------
>>> import simpy
>>> env = simpy.Environment()
>>> log = []
>>> timer = Timer(env, lambda t: log.append((env.now, t._value)), 7)
>>> timer.schedule(1.0)
>>> env.run()
>>> timer.schedule(0.5)
>>> env.run()
>>> log
[(1.0, 7), (1.5, 7)]
"""

from __future__ import annotations

from collections.abc import Callable
from heapq import heappush
from typing import Any

import simpy
from simpy.events import NORMAL

__all__ = ["Timer", "push"]


def push(env: simpy.Environment, at_s: float, event: Any) -> None:
    """Queue ``event`` (anything with ``callbacks``, ``_ok``, ``_value``) at time ``at_s``."""
    heappush(env._queue, (at_s, NORMAL, next(env._eid), event))


class Timer:
    """A reusable wake-up: ``callback(timer)`` runs each time a scheduled delay ends.

    Schedule it again only after it fired (``step()`` clears ``callbacks`` when it runs).
    """

    __slots__ = ("_callbacks", "_env", "_ok", "_value", "callbacks")

    def __init__(self, env: simpy.Environment, callback: Callable[[Timer], None], value: Any):
        self._env = env
        self._callbacks = [callback]  # step() only iterates it, so one list serves every run
        self.callbacks: list | None = None
        self._value = value
        self._ok = True

    def schedule(self, delay_s: float) -> None:
        """Fire after ``delay_s`` simulated seconds."""
        self.callbacks = self._callbacks
        env = self._env
        heappush(env._queue, (env._now + delay_s, NORMAL, next(env._eid), self))
