"""Time on the robots: each robot's own oscillator, and cheap recurring callbacks on SimPy's clock.

**Robot clocks.** A Kilobot counts ``kilo_ticks`` from the ATmega328P's internal RC oscillator,
nominally ``TICKS_PER_SEC`` = 31 a second (kilolib), and every robot's oscillator runs at a rate
of its own: after calibration (OSCCAL, stored per robot) the datasheet gives about ±1 % at one
voltage and temperature, and drift with both on top. :class:`RobotClocks` draws each robot's rate
factor ``1 + N(0, clock_sd)`` (the true rate is ``ticks_per_s * factor``) and the phase of its
first tick, so robots that start together on the overhead controller's signal still tick apart.
Everything a program sees runs on its own clock: ``kilo_ticks``, ``delay``, the loop rate and
the transmit period.

**Cheap callbacks.** The medium schedules two wake-ups per message and every robot's loop one
per tick; a ``simpy.Timeout`` builds a full event for each. Here the queue entry is a bare
object carrying exactly what ``Environment.step`` reads (``callbacks``, ``_ok``, ``_value``),
pushed onto the environment's queue with the key a Timeout would get (time, NORMAL priority,
insertion counter), so ordering and determinism are SimPy's own. A :class:`Timer` is reusable:
an entity with at most one pending wake-up (a robot's next transmit opportunity) allocates
nothing per wake-up. The robots' plain loops share one :class:`LoopSchedule`, which runs them at
the times and in the order one Timer each would, mostly without going through the queue.

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

import math
from collections.abc import Callable
from dataclasses import dataclass
from heapq import heapify, heappop, heappush, heapreplace
from typing import Any

import numpy as np
import simpy
from simpy.events import NORMAL

__all__ = ["LoopSchedule", "RobotClocks", "Timer", "push"]


def push(env: simpy.Environment, at_s: float, event: Any) -> None:
    """Queue ``event`` (anything with ``callbacks``, ``_ok``, ``_value``) at time ``at_s``."""
    heappush(env._queue, (at_s, NORMAL, next(env._eid), event))


@dataclass(frozen=True)
class RobotClocks:
    """The oscillators of a swarm: one tick rate and one start phase per robot.

    Robot ``i`` counts ``kilo_ticks(t) = floor(t * rate_hz[i] + phase[i])`` at true time ``t``
    (seconds since the run signal), so its ticks start at 0 and fall every ``1 / rate_hz[i]``
    seconds, shifted by its phase.

    Parameters
    ----------
    ticks_per_s : float
        Nominal rate, the ``TICKS_PER_SEC`` programs see (31 in kilolib).
    factor : (N,) array
        Each robot's true rate over the nominal one (1.01: its clock runs 1 % fast, its ticks,
        delays and transmit periods are 1 % shorter in true time).
    phase : (N,) array
        The fraction of a tick each robot's oscillator had run at the run signal, in [0, 1).

    Examples
    --------
    >>> clocks = RobotClocks(31.0, np.array([1.0, 1.02]), np.array([0.0, 0.5]))
    >>> clocks.ticks_at(1, 1.0), round(clocks.true_s(1, 1.02), 12)
    (32, 1.0)
    >>> round(clocks.first_mid_tick_s(1), 6)  # tick 0 of robot 1 ends 0.5 ticks after start
    0.0
    """

    ticks_per_s: float
    factor: np.ndarray
    phase: np.ndarray

    @classmethod
    def draw(
        cls, n: int, ticks_per_s: float, clock_sd: float, rng: np.random.Generator
    ) -> RobotClocks:
        """Rates ``ticks_per_s * (1 + N(0, clock_sd))`` (clipped to ±5 sd) and uniform phases.

        With ``clock_sd = 0`` every robot ticks at the nominal rate, and all in phase (perfect
        clocks, as in a simulator without oscillators).
        """
        if clock_sd == 0:
            return cls(ticks_per_s, np.ones(n), np.zeros(n))
        error = np.clip(rng.normal(0.0, clock_sd, n), -5 * clock_sd, 5 * clock_sd)
        return cls(ticks_per_s, 1.0 + error, rng.random(n))

    def rate_hz(self, robot: int) -> float:
        """True tick rate of ``robot``, ticks per (true) second."""
        return float(self.ticks_per_s * self.factor[robot])

    def ticks_at(self, robot: int, t_s: float) -> int:
        """``kilo_ticks`` of ``robot`` at true time ``t_s``."""
        return math.floor(t_s * self.rate_hz(robot) + float(self.phase[robot]))

    def true_s(self, robot: int, own_s: float) -> float:
        """True duration of ``own_s`` seconds as ``robot``'s clock measures them."""
        return own_s / float(self.factor[robot])

    def first_mid_tick_s(self, robot: int) -> float:
        """True time of the middle of ``robot``'s first tick at or after the start: where its
        loop first runs (mid-tick, so ``kilo_ticks`` there is exact despite float rounding)."""
        return ((0.5 - float(self.phase[robot])) % 1.0) / self.rate_hz(robot)


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


class LoopSchedule:
    """Callbacks that each recur with a period of their own (every robot's ``loop()`` on its
    own clock), run exactly when and in the order separate :class:`Timer` s would run them, but
    with one entry in the event queue for all of them.

    The schedule keeps its own heap of next calls. After one runs, it runs the next at once
    (moving the clock to its time) as long as that comes before everything in SimPy's queue,
    and queues itself only when something else comes first; at 1,000 robots loops are about two
    events in three, and most of them then never touch SimPy's queue.

    Each callback keeps the queue key a Timer of its own would have: its times accumulate as
    ``t + period_s`` and it draws an insertion number from the environment when it is added and
    each time it runs (as rescheduling a Timer does), so even events due at the very same time
    run in SimPy's order.

    Examples
    --------
    >>> import simpy
    >>> env = simpy.Environment()
    >>> log = []
    >>> loops = LoopSchedule(env)
    >>> for name, first, period in (("a", 0.5, 1.0), ("b", 0.25, 0.75)):
    ...     loops.add(first, period, lambda name=name: log.append((name, env.now)) or env.now < 2)
    >>> loops.start()
    >>> env.run(until=4)
    >>> log
    [('b', 0.25), ('a', 0.5), ('b', 1.0), ('a', 1.5), ('b', 1.75), ('a', 2.5), ('b', 2.5)]
    """

    __slots__ = ("_callbacks", "_env", "_heap", "_periods", "_started", "_timer")

    def __init__(self, env: simpy.Environment) -> None:
        self._env = env
        self._heap: list[tuple[float, int, int, int]] = []
        self._callbacks: list[Callable[[], bool]] = []
        self._periods: list[float] = []
        self._started = False
        self._timer = Timer(env, self._run, None)

    def add(self, first_s: float, period_s: float, callback: Callable[[], bool]) -> None:
        """Run ``callback() -> bool`` first in ``first_s`` seconds, then every ``period_s``
        until it returns ``False`` (a robot that stopped).

        Raises
        ------
        ValueError
            If ``first_s`` is negative or ``period_s`` is not positive.
        RuntimeError
            If the schedule has started.
        """
        if self._started:
            raise RuntimeError("loops can only be added to a LoopSchedule before it starts")
        if first_s < 0 or not period_s > 0:
            raise ValueError(
                f"a loop needs first_s >= 0 and period_s > 0, got {first_s} s and {period_s} s"
            )
        env = self._env
        k = len(self._callbacks)
        self._heap.append((env._now + first_s, NORMAL, next(env._eid), k))
        self._callbacks.append(callback)
        self._periods.append(period_s)

    def start(self) -> None:
        """Queue the schedule (after the last :meth:`add`).

        Raises
        ------
        RuntimeError
            If it has started already.
        """
        if self._started:
            raise RuntimeError("a LoopSchedule starts only once")
        self._started = True
        heapify(self._heap)
        if self._heap:
            self._queue()

    def _queue(self) -> None:
        timer = self._timer
        timer.callbacks = timer._callbacks
        t, priority, eid, _ = self._heap[0]
        heappush(self._env._queue, (t, priority, eid, timer))

    def _run(self, _timer: Timer) -> None:
        env, heap, callbacks, periods = self._env, self._heap, self._callbacks, self._periods
        queue, eid = env._queue, env._eid
        while True:
            t, _, _, k = heap[0]
            env._now = t
            try:
                again = callbacks[k]()
            except BaseException:
                # As with a Timer of its own, the loop that raised is not run again, and the
                # others go on if whoever runs the simulation carries on.
                heappop(heap)
                if heap:
                    self._queue()
                raise
            if again:
                heapreplace(heap, (t + periods[k], NORMAL, next(eid), k))
            else:
                heappop(heap)
                if not heap:
                    return
            # Due before everything queued: run it now; otherwise queue the schedule behind it.
            # Insertion numbers are unique, so the comparison never reaches the last items.
            if queue and queue[0] < heap[0]:
                break
        self._queue()
