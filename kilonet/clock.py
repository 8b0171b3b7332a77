"""Time on the robots: each robot's own oscillator, and cheap recurring callbacks on SimPy's clock.

**Robot clocks.** A Kilobot counts ``kilo_ticks`` from the ATmega328P's internal RC oscillator,
nominally ``TICKS_PER_SEC`` = 31 a second (kilolib), and every robot's oscillator runs at a rate
of its own: after calibration (OSCCAL, stored per robot) the datasheet gives about ±1 % at one
voltage and temperature, and drift with both on top. :class:`RobotClocks` draws each robot's rate
factor ``1 + N(0, clock_sd)`` (the true rate is ``ticks_per_s * factor``) and the phase of its
first tick, so robots that start together on the overhead controller's signal still tick apart.
Everything a program sees runs on its own clock: ``kilo_ticks``, ``delay``, the loop rate and
the transmit period.

**The kernel's environment.** :class:`KernelEnvironment` is a documented subclass of
``simpy.Environment`` that keeps its own event queue and clock behind SimPy's public interface
(``now``, ``schedule``, ``peek``, ``step``, ``run``), so SimPy's processes, timeouts and
conditions run on it unchanged and nothing here reads or writes SimPy's private state. Three
things it adds, all for the hot path:

* a negative delay is refused where it would be queued (an event in the past would run the
  clock backwards);
* :meth:`KernelEnvironment.schedule_at` queues at an absolute time (no ``at - now + now``
  rounding), and the queue takes any object with the event protocol its step loop reads
  (``callbacks``, ``ok``, ``defused``, ``value``), so a :class:`Timer` is a reusable queue entry
  that allocates nothing per wake-up;
* recurring calls (every robot's plain ``loop()``, each on its own clock) cost no event: the
  step loop takes them from a window, every pending run within the shortest period sorted by
  NumPy at once, merged with the queue by key, so they run exactly when and in the order one
  Timer each would (the key such a Timer would have: time accumulated as ``t + period_s``,
  NORMAL priority, an insertion number drawn when added and each time it runs).

Examples
--------
>>> env = KernelEnvironment()
>>> log = []
>>> timer = Timer(env, lambda t: log.append((env.now, t.value)), 7)
>>> timer.schedule(1.0)
>>> env.run()
>>> timer.schedule(0.5)
>>> env.run()
>>> log
[(1.0, 7), (1.5, 7)]
>>> env.schedule(env.event(), delay=-0.1)
Traceback (most recent call last):
...
ValueError: an event cannot be scheduled in the past: delay -0.1 s at 1.5 s
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from heapq import heappop, heappush
from itertools import count
from typing import Any

import numpy as np
import simpy
from simpy.core import EmptySchedule, StopSimulation
from simpy.events import NORMAL, URGENT, Event

__all__ = ["KernelEnvironment", "RobotClocks", "Timer"]


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
    """A reusable wake-up on a :class:`KernelEnvironment`: ``callback(timer)`` runs each time a
    scheduled delay ends; ``value`` is whatever the owner wants the callback to see.

    Schedule it again only after it fired (the step loop clears ``callbacks`` when it runs).
    """

    __slots__ = ("_callbacks", "_env", "callbacks", "value")
    ok = True  # the event protocol of KernelEnvironment's step loop: never a failed event
    defused = False

    def __init__(
        self, env: KernelEnvironment, callback: Callable[[Timer], None], value: Any
    ) -> None:
        self._env = env
        self._callbacks = [callback]  # the step loop only iterates it: one list serves every run
        self.callbacks: list | None = None
        self.value = value

    def schedule(self, delay_s: float) -> None:
        """Fire after ``delay_s`` simulated seconds.

        Raises
        ------
        ValueError
            If ``delay_s`` is negative.
        """
        if not delay_s >= 0:
            self._env.schedule(self, NORMAL, delay_s)  # raises
        self.callbacks = self._callbacks
        env = self._env
        heappush(env._kqueue, (env._kt + delay_s, NORMAL, next(env._kids), self))


class KernelEnvironment(simpy.Environment):
    """A ``simpy.Environment`` with its own queue, refusing events in the past, taking
    reusable entries, and running recurring callbacks without events (see the module
    docstring).

    It overrides SimPy's public interface (``now``, ``schedule``, ``peek``, ``step``, ``run``)
    and nothing else, so SimPy's own events and processes run on it as on SimPy's
    environment. A queue entry is any object with ``callbacks`` (a list, cleared to ``None``
    when it runs), ``ok``, ``defused`` and ``value``: every SimPy event, and :class:`Timer`.

    Parameters
    ----------
    initial_time : float
        The clock at the start, s.
    """

    def __init__(self, initial_time: float = 0) -> None:
        super().__init__(initial_time)
        self._kt = initial_time
        self._kqueue: list[tuple[float, int, int, Any]] = []
        self._kids = count()
        # Recurring calls. A window holds every pending run within the shortest period of the
        # earliest, in key order, consumed from `_kpos` on; each runs once in it, so the next
        # runs of those consumed are filled in with one NumPy addition when the window ends.
        self._kcalls: list[Callable[[], Any]] = []
        self._kperiods = np.empty(0)
        self._knext = np.empty(0)  # each call's next run, as of the window's start (inf: none)
        self._keids: list[int] = []  # insertion number of each call's pending run
        self._kalive: list[bool] = []
        self._kcancelled: list[int] = []  # cancelled or raised since the window was built
        self._kmin_period = math.inf
        self._kwin_t: list[float] = []
        self._kwin_k: list[int] = []
        self._kwin_t_arr = np.empty(0)
        self._kwin_k_arr = np.empty(0, dtype=np.intp)
        self._kpos = 0
        self._kdirty = False  # every() added a call: the window must be rebuilt
        self._kidle = True  # no recurring call pending: no window to build

    @property
    def now(self) -> float:
        """The current simulation time, s."""
        return self._kt

    def schedule(self, event: Any, priority: int = NORMAL, delay: float = 0) -> None:
        """Queue ``event`` ``delay`` seconds from now.

        Raises
        ------
        ValueError
            If ``delay`` is negative or not a number (the clock would run backwards).
        """
        if not delay >= 0:
            raise ValueError(
                f"an event cannot be scheduled in the past: delay {delay} s at {self._kt} s"
            )
        heappush(self._kqueue, (self._kt + delay, priority, next(self._kids), event))

    def schedule_at(self, event: Any, at_s: float, priority: int = NORMAL) -> None:
        """Queue ``event`` at simulated time ``at_s`` (exactly that float).

        Raises
        ------
        ValueError
            If ``at_s`` is before now.
        """
        if not at_s >= self._kt:
            raise ValueError(
                f"an event cannot be scheduled in the past: at {at_s} s, now {self._kt} s"
            )
        heappush(self._kqueue, (at_s, priority, next(self._kids), event))

    def every(self, first_s: float, period_s: float, callback: Callable[[], Any]) -> int:
        """Call ``callback()`` first ``first_s`` seconds from now and then every ``period_s``,
        until :meth:`cancel` (a robot that stopped) or until it raises (it is then not called
        again, and the others go on if the caller runs on); the handle for :meth:`cancel`.

        Raises
        ------
        ValueError
            If ``first_s`` is negative or ``period_s`` is not positive.
        """
        if not (first_s >= 0 and period_s > 0):
            raise ValueError(
                f"a recurring call needs first_s >= 0 and period_s > 0, got {first_s} s and "
                f"{period_s} s"
            )
        k = len(self._kcalls)  # appended: the window's indices stay valid until it is rebuilt
        self._kcalls.append(callback)
        self._kperiods = np.append(self._kperiods, period_s)
        self._knext = np.append(self._knext, self._kt + first_s)
        self._keids.append(next(self._kids))
        self._kalive.append(True)
        self._kmin_period = min(self._kmin_period, period_s)
        self._kdirty = True
        self._kidle = False
        return k

    def cancel(self, handle: int) -> None:
        """Call the recurring call ``handle`` never again (from now on, even within a call)."""
        if self._kalive[handle]:
            self._kalive[handle] = False
            self._kcancelled.append(handle)

    def _close_window(self) -> None:
        """Note the next runs of the calls the window has run, and drop the rest of it (their
        pending runs stay as they are)."""
        pos = self._kpos
        if pos:
            ran = self._kwin_k_arr[:pos]
            self._knext[ran] = self._kwin_t_arr[:pos] + self._kperiods[ran]
        if self._kcancelled:
            self._knext[self._kcancelled] = math.inf
            self._kcancelled = []
        self._kwin_t, self._kwin_k, self._kpos = [], [], 0
        self._kwin_t_arr = self._kwin_t_arr[:0]
        self._kwin_k_arr = self._kwin_k_arr[:0]

    def _window(self) -> None:
        """Close the window and build the next: every pending run within the shortest period
        of the earliest, ordered by (time, insertion number) as the queue would order them.
        None of them comes round again within it, so it stays valid while it is consumed."""
        self._close_window()
        self._kdirty = False
        nexts = self._knext
        start = nexts.min() if len(nexts) else math.inf
        if start == math.inf:
            self._kidle = True
            return
        chosen = np.flatnonzero(nexts < start + self._kmin_period)
        times = nexts[chosen]
        order = np.argsort(times, kind="stable")
        ordered = times[order]
        if len(ordered) > 1 and (ordered[1:] == ordered[:-1]).any():  # ties: by insertion
            order = np.lexsort((np.array(self._keids)[chosen], times))
            ordered = times[order]
        self._kwin_t_arr, self._kwin_k_arr = ordered, chosen[order]
        self._kwin_t, self._kwin_k = ordered.tolist(), self._kwin_k_arr.tolist()

    def _next_recurring(self) -> tuple[float, int, int] | None:
        """The next live recurring run as (time, insertion number, call), or None."""
        while True:
            if self._kdirty or self._kpos == len(self._kwin_k):
                if self._kidle and not self._kdirty:
                    return None
                self._window()
                continue
            pos = self._kpos
            k = self._kwin_k[pos]
            if self._kalive[k]:
                return self._kwin_t[pos], self._keids[k], k
            self._kpos = pos + 1  # cancelled

    def _recur(self, t: float, k: int) -> None:
        """Run recurring call ``k`` due at ``t`` (the window's next)."""
        self._kpos += 1
        self._kt = t
        try:
            self._kcalls[k]()
        except BaseException:
            self.cancel(k)
            raise
        if self._kalive[k]:
            self._keids[k] = next(self._kids)

    def peek(self) -> float:
        """Time of the next event or recurring call (``inf`` if there is none)."""
        recurring, queue = self._next_recurring(), self._kqueue
        if recurring is not None and (not queue or recurring < queue[0][:3]):
            return recurring[0]
        return queue[0][0] if queue else math.inf

    def step(self) -> None:
        """Process the next event or recurring call.

        Raises
        ------
        simpy.core.EmptySchedule
            If nothing is queued.
        """
        recurring, queue = self._next_recurring(), self._kqueue
        if recurring is not None and (not queue or (recurring[0], NORMAL, recurring[1]) < queue[0]):
            self._recur(recurring[0], recurring[2])
            return
        try:
            self._kt, _, _, event = heappop(queue)
        except IndexError:
            raise EmptySchedule from None
        callbacks, event.callbacks = event.callbacks, None
        try:
            for callback in callbacks:
                callback(event)
        except StopSimulation:
            event.callbacks = callbacks[callbacks.index(callback) + 1 :]
            self.schedule(event, URGENT - 1)
            raise
        if not event.ok and not event.defused:
            _raise_failed(event)

    def run(self, until: float | Event | None = None) -> Any:
        """Run until simulated time ``until`` (events due then are left for the next run, as
        SimPy's ``run`` leaves them), until the event ``until`` has happened, or, with
        ``None``, until nothing is queued.

        Raises
        ------
        ValueError
            If ``until`` is a time not after now.
        """
        if until is None or isinstance(until, Event):
            return super().run(until)
        at = until if isinstance(until, int) else float(until)
        if at <= self._kt:
            raise ValueError(f"until ({at}) must be greater than the current simulation time")
        try:
            self._run_to(at)
        except StopSimulation as stop:
            return stop.args[0]
        self._kt = at
        return None

    def _run_to(self, at: float) -> None:
        """The step loop of :meth:`step` inline, up to (not including) time ``at``: the window
        of recurring calls and the queue merged by key.

        An event is processed in place (its time becomes now, its callbacks run). Recurring
        calls run back to back from the window's position while they fall strictly before the
        queue's next event and ``at`` (the first of them has won against the queue's head by
        key, ties included); a call that raises is cancelled, then the exception goes on. Both
        are inline rather than methods because this loop runs once per tick of every robot:
        a method call and its set-up per run of calls cost as much as the calls' own
        bookkeeping."""
        queue, eids, ids = self._kqueue, self._keids, self._kids
        calls, alive = self._kcalls, self._kalive  # appended to, never replaced
        while True:
            pos, win_k = self._kpos, self._kwin_k
            if pos == len(win_k) or self._kdirty:
                if self._kidle and not self._kdirty:
                    if self._run_queue_alone(at):
                        return
                    continue  # an event added a recurring call: build its window
                self._window()
                continue
            win_t = self._kwin_t
            t = win_t[pos]
            if queue:
                head = queue[0]
                if head[0] < t or (head[0] == t and head < (t, NORMAL, eids[win_k[pos]])):
                    if head[0] >= at:
                        return
                    self._kt, _, _, event = heappop(queue)
                    callbacks, event.callbacks = event.callbacks, None
                    for callback in callbacks:
                        callback(event)
                    if not event.ok and not event.defused:
                        _raise_failed(event)
                    continue
                limit = head[0] if head[0] < at else at
            else:
                limit = at
            if t >= at:
                return
            n_win = len(win_k)
            k = -1
            try:
                while True:
                    k = win_k[pos]
                    pos += 1
                    if alive[k]:
                        self._kt = t
                        calls[k]()
                        if alive[k]:
                            eids[k] = next(ids)
                        if self._kdirty:
                            break
                        if queue and queue[0][0] < limit:
                            limit = queue[0][0]
                    if pos == n_win:
                        break
                    t = win_t[pos]
                    if t >= limit:
                        break
            except BaseException:
                self.cancel(k)
                raise
            finally:
                if self._kwin_k is win_k:  # a call may have rebuilt the window (peek)
                    self._kpos = pos

    def _run_queue_alone(self, at: float) -> bool:
        """Process queued events before ``at`` while no recurring call is pending: True when
        done (``at`` or an empty queue reached), False as soon as an event adds a recurring
        call."""
        queue = self._kqueue
        while queue and queue[0][0] < at:
            self._fire(heappop(queue))
            if self._kdirty:
                return False
        return True

    def _fire(self, entry: tuple[float, int, int, Any]) -> None:
        """Process one event taken off the queue: its time becomes now, its callbacks run."""
        self._kt, _, _, event = entry
        callbacks, event.callbacks = event.callbacks, None
        for callback in callbacks:
            callback(event)
        if not event.ok and not event.defused:
            _raise_failed(event)


def _raise_failed(event: Any) -> None:
    """Raise the exception of a failed event nobody defused, as SimPy's step does: a copy
    whose ``__cause__`` is the original (with the traceback of where it was raised, in a
    process's generator); the original itself when its class cannot be rebuilt from its
    ``args`` (a constructor that wants other arguments)."""
    error = event.value
    try:
        exc = type(error)(*error.args)
    except Exception:  # whatever the program's constructor raises
        raise error from None
    exc.__cause__ = error
    raise exc
