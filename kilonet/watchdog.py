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
from typing import Any

from kilonet.errors import UserError
from kilonet.robot import Kilobot

__all__ = ["BUSY_CALL_S", "BusyCallError", "busy_watchdog", "describe_call", "robot_frame"]

#: Wall-clock seconds one call into a program may run, with simulated time standing still,
#: before :func:`busy_watchdog` stops the run (``kilonet run --watchdog``).
BUSY_CALL_S = 30.0


class BusyCallError(UserError):
    """One call into a robot program ran too long while simulated time stood still."""


def robot_frame(frame: FrameType | None) -> tuple[Kilobot, FrameType] | None:
    """The outermost frame of ``frame``'s stack that runs a method of a robot program (its
    ``self`` is a :class:`Kilobot`): the callback the simulation called, and its robot."""
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
    """
    import signal
    import threading

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
