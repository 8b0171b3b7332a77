"""Scheduling plain callbacks on the SimPy clock, at a fraction of a Timeout's cost.

The medium schedules two wake-ups per message and every robot one per loop period; a
``simpy.Timeout`` builds a full event for each. Here the queue entry is a bare object carrying
exactly what ``Environment.step`` reads (``callbacks``, ``_ok``, ``_value``), pushed onto the
environment's queue with the key a Timeout would get (time, NORMAL priority, insertion counter),
so ordering and determinism are SimPy's own. A :class:`Timer` is reusable: an entity with at
most one pending wake-up (a robot's next transmit opportunity) allocates nothing per wake-up.
The robots' loops share one :class:`LoopRound`, which runs them at the times and in the order
one Timer each would, mostly without going through the queue at all.

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

__all__ = ["LoopRound", "Timer", "push"]


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


class LoopRound:
    """Callbacks that each recur with one common period, at offsets of their own (every robot's
    ``loop()``), run exactly when and in the order separate :class:`Timer` s would run them, but
    with one entry in the event queue for all of them.

    Their order within a period never changes (adding the same period to two float times keeps
    their order), so the next one due is always known: after one runs, the round runs the next
    at once (moving the clock to its time) as long as it comes before everything queued, and
    queues itself only when something else comes first. At 1,000 robots with a 1/16 s loop,
    loops are two events in three; at 300 robots the round ran 830,400 loops from 289,876
    queue entries in a gcs run.

    Each callback keeps the queue key a Timer of its own would have: its times accumulate as
    ``t + period_s`` and it draws an insertion number from the environment when it is added and
    each time it runs (as rescheduling a Timer does), so even events due at the very same time
    run in SimPy's order.

    Examples
    --------
    >>> import simpy
    >>> env = simpy.Environment()
    >>> log = []
    >>> loops = LoopRound(env, 1.0)
    >>> for name, first in (("a", 0.5), ("b", 0.25)):
    ...     loops.add(first, lambda name=name: log.append((name, env.now)) or env.now < 2)
    >>> loops.start()
    >>> env.run(until=4)
    >>> log
    [('b', 0.25), ('a', 0.5), ('b', 1.25), ('a', 1.5), ('b', 2.25), ('a', 2.5)]
    """

    __slots__ = ("_added", "_callbacks", "_env", "_keys", "_next", "_period", "_timer")

    def __init__(self, env: simpy.Environment, period_s: float) -> None:
        self._env = env
        self._period = period_s
        # Loops added before start(); None once started.
        self._added: list[tuple[float, int, Callable[[], bool]]] | None = []
        self._keys: list[tuple[float, int, int]] = []
        self._callbacks: list[Callable[[], bool]] = []
        self._next = 0
        self._timer = Timer(env, self._run, None)

    def add(self, first_s: float, callback: Callable[[], bool]) -> None:
        """Run ``callback() -> bool`` first in ``first_s`` seconds (``0 <= first_s <
        period_s``), then every period until it returns ``False`` (a robot that stopped).

        Raises
        ------
        ValueError
            If ``first_s`` is outside ``[0, period_s)``.
        RuntimeError
            If the round has started.
        """
        if self._added is None:
            raise RuntimeError("loops can only be added to a LoopRound before it starts")
        if not 0 <= first_s < self._period:
            raise ValueError(f"a first time of {first_s} s is outside [0, {self._period}) s")
        env = self._env
        self._added.append((env._now + first_s, next(env._eid), callback))

    def start(self) -> None:
        """Queue the round (after the last :meth:`add`).

        Raises
        ------
        RuntimeError
            If it has started already.
        """
        if self._added is None:
            raise RuntimeError("a LoopRound starts only once")
        self._added.sort(key=lambda added: added[:2])
        self._keys = [(t, NORMAL, eid) for t, eid, _ in self._added]
        self._callbacks = [callback for *_, callback in self._added]
        self._added = None
        if self._keys:
            self._queue(0)

    def _queue(self, k: int) -> None:
        self._next = k
        self._timer.callbacks = self._timer._callbacks
        heappush(self._env._queue, (*self._keys[k], self._timer))

    def _run(self, _timer: Timer) -> None:
        env, keys, callbacks, period = self._env, self._keys, self._callbacks, self._period
        queue, eid = env._queue, env._eid
        k = self._next
        while True:
            t = keys[k][0]
            env._now = t
            try:
                again = callbacks[k]()
            except BaseException:
                # As with a Timer of its own, the loop that raised is not run again, and the
                # others go on if whoever runs the simulation carries on.
                del keys[k], callbacks[k]
                if keys:
                    self._queue(k % len(keys))
                raise
            if again:
                keys[k] = (t + period, NORMAL, next(eid))
                k += 1
            else:
                del keys[k], callbacks[k]
                if not keys:
                    return
            if k == len(keys):
                k = 0
            # Due before everything queued: run it now; otherwise queue the round behind it.
            if queue and queue[0] < keys[k]:
                break
        self._queue(k)
