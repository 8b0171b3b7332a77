"""A watchdog for robot programs stuck in one call.

Simulated time passes only between calls into a program, so a ``loop()`` that waits for
something (``while self.get_ambientlight() < 500: pass``) never returns and a run hangs.
:func:`busy_watchdog` stops such a call with :class:`BusyCallError`, naming the robot, the
callback and the line; ``kilonet run --watchdog`` and the test kit's
:func:`kilonet.testing.run_swarm` use it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from kilonet.errors import UserError

if TYPE_CHECKING:
    from kilonet.robot import Kilobot

__all__ = [
    "BUSY_CALL_S",
    "MAX_WATCHDOG_S",
    "BusyCallError",
    "WatchdogValueError",
    "busy_watchdog",
    "check_watchdog_s",
    "describe_call",
    "robot_frame",
]

#: Wall-clock seconds one call into a program may run, with simulated time standing still,
#: before :func:`busy_watchdog` stops the run (``kilonet run --watchdog``).
BUSY_CALL_S = 30.0

#: The longest watchdog period, wall-clock seconds (a day): the system's interval timer takes
#: no period beyond what its clock counts, and no call needs longer.
MAX_WATCHDOG_S = 86400.0


class BusyCallError(UserError):
    """One call into a robot program ran too long while simulated time stood still."""


class WatchdogValueError(UserError, ValueError):
    """A watchdog period that is not 0 (off) or a number of seconds the timer can count."""


def check_watchdog_s(seconds: float, where: str = "watchdog_s") -> float:
    """``seconds`` if it is a watchdog period :func:`busy_watchdog` can set: 0 (off) or a
    number of wall-clock seconds in (0, :data:`MAX_WATCHDOG_S`].

    ``where`` names where the value came from, for the error (``--watchdog``).

    Raises
    ------
    WatchdogValueError
        (a ``ValueError``) For a negative, infinite or NaN period, or one above a day.

    Examples
    --------
    >>> check_watchdog_s(0.5)
    0.5
    >>> check_watchdog_s(float("inf"), "--watchdog")
    Traceback (most recent call last):
    ...
    kilonet.watchdog.WatchdogValueError: --watchdog inf: give 0 (no watchdog) or seconds up to 86400
    """
    if not 0 <= seconds <= MAX_WATCHDOG_S:
        raise WatchdogValueError(
            f"{where} {seconds:g}: give 0 (no watchdog) or seconds up to {MAX_WATCHDOG_S:g}"
        )
    return seconds


def robot_frame(frame: FrameType | None) -> tuple[Kilobot, FrameType] | None:
    """The outermost frame of ``frame``'s stack that runs a method of a robot program (its
    ``self`` is a :class:`Kilobot`): the callback the simulation called, and its robot.
    (The robot module, and numpy with it, is imported here, not with this module: the
    command line reads :data:`BUSY_CALL_S` for its help.)"""
    from kilonet.robot import Kilobot

    found = None
    while frame is not None:
        robot = frame.f_locals.get("self")
        if isinstance(robot, Kilobot) and hasattr(robot, "_kindex"):
            found = (robot, frame)
        frame = frame.f_back
    return found


def describe_call(robot: Kilobot, frame: FrameType, innermost: FrameType | None = None) -> str:
    """``robot 4's loop (my_bot.py:12)``: the robot, the callback, and the line of the
    program's file it runs now (the innermost frame in that file, not kilonet's own inside a
    ``kilo_ticks`` it reads)."""
    at = innermost or frame
    while (
        at is not frame
        and at.f_back is not None
        and (at.f_code.co_filename != frame.f_code.co_filename)
    ):
        at = at.f_back
    return (
        f"robot {robot._kindex}'s {frame.f_code.co_name} "
        f"({Path(at.f_code.co_filename).name}:{at.f_lineno})"
    )


@contextmanager
def busy_watchdog(seconds: float = BUSY_CALL_S) -> Iterator[None]:
    """Stop a run whose program is stuck in one call (``while True: pass`` in ``loop``).

    Every ``seconds`` of wall time a timer signal (``SIGALRM``) looks at what runs: if the same
    call into the same robot's program was running at the previous look, and simulated time
    has not moved, the call has run at least ``seconds`` without returning, and
    :class:`BusyCallError` is raised inside it, naming the robot, the callback and the line.
    Nothing runs between looks, so a run pays nothing for it. Off (a no-op) when ``seconds``
    is 0, outside the main thread, or where the system has no ``SIGALRM``.

    Raises
    ------
    BusyCallError
        From inside the stuck call.
    WatchdogValueError
        If ``seconds`` is not a period the timer can count (:func:`check_watchdog_s`).
    """
    import signal
    import threading

    check_watchdog_s(seconds)

    if (
        seconds <= 0
        or not hasattr(signal, "SIGALRM")
        or threading.current_thread() is not (threading.main_thread())
    ):
        yield
        return
    last: list[Any] = [None]

    def look(_signum: int, frame: FrameType | None) -> None:
        found = robot_frame(frame)
        if found is None:
            last[0] = None
            return
        robot, call = found
        now = robot._kenv.now
        if last[0] is not None and last[0][0] is call and last[0][1] == now:
            last[0] = None
            raise BusyCallError(
                f"{describe_call(robot, call, frame)} has run {seconds:g} s of wall time "
                f"without returning, at {now:.3f} simulated s: simulated time passes only "
                "between calls, so a loop that waits for something (a sensor, a message, "
                "kilo_ticks) never sees it change; return from the callback and check again "
                "at its next call, or write it as a generator and `yield self.delay(ms)`"
            )
        last[0] = (call, now)

    previous = signal.signal(signal.SIGALRM, look)
    signal.setitimer(signal.ITIMER_REAL, seconds, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
