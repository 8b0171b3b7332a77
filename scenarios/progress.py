"""A run's progress on stderr that tells the truth about where the run will end.

Before the simulation exists, the display names the set-up stage (placing robots, building
them, starting), so a large swarm's long set-up is not silent. Then:

* when the run's end is known before it starts (a fixed duration, or phase windows that end
  it), a bar to that end: ``gradient  42% |####      | 13/30 sim s [00:01<00:02]``;
* when only a stop condition will end it, no bar and no made-up percentage: the simulated
  seconds so far, the rate, the scenario's note, what the run waits for and the cap
  ``duration_s``: ``follower  154 sim s [00:03, 45.2 sim s/s] until the follower arrives or
  gives up (at most 600 s)``.

A note from the scenario (the current phase) comes right after the figures, so it shows in
80 columns.

Three modes (:data:`MODES`): ``bar`` redraws one line in place (``tqdm``, for a terminal);
``lines`` writes whole lines, one per stage, per tenth of the run (or per change of the note,
or per 30 s of wall time without one), and one at the end, for a log file or a pipe; ``none``
writes nothing. ``auto`` is ``bar`` when stderr is a terminal, else ``none``: carriage returns
in a log are noise, and an error stays the only line a failed run leaves.
"""

from __future__ import annotations

import sys
import time
from types import TracebackType
from typing import Any

__all__ = ["MODES", "RunProgress", "StageProgress", "resolve_mode"]

#: The progress modes, as ``kilonet run --progress`` takes them.
MODES = ("auto", "bar", "lines", "none")


def resolve_mode(mode: str | bool, stream: Any = None) -> str:
    """The mode to show: ``bar``, ``lines`` or ``none``. ``True`` is ``bar``, ``False``
    ``none``; ``auto`` is ``bar`` if ``stream`` (default stderr) is a terminal, else ``none``.

    Raises
    ------
    ValueError
        For a mode not in :data:`MODES`.

    Examples
    --------
    >>> import io
    >>> resolve_mode("auto", io.StringIO()), resolve_mode(True), resolve_mode("lines")
    ('none', 'bar', 'lines')
    """
    if mode is True or mode is False:
        return "bar" if mode else "none"
    if mode not in MODES:
        raise ValueError(f"progress mode {mode!r} is not one of {', '.join(MODES)}")
    if mode == "auto":
        stream = sys.stderr if stream is None else stream
        isatty = getattr(stream, "isatty", None)
        return "bar" if isatty is not None and isatty() else "none"
    return mode


class RunProgress:
    """Progress display of one run (``tqdm`` on stderr; nothing at all when disabled).

    Parameters
    ----------
    name : str
        The scenario, shown first.
    expected_end_s : float or None
        Simulated time the run will end at, if known; ``None`` for an indeterminate display.
    cap_s : float
        The run's ``duration_s``: it ends there at the latest.
    ends_when : str
        What the stop condition waits for, in words (indeterminate display).
    enabled : bool or str
        A mode of :data:`MODES` (``True``: ``bar``; ``False``: ``none``).
    """

    def __init__(
        self,
        name: str,
        *,
        expected_end_s: float | None,
        cap_s: float,
        ends_when: str = "",
        enabled: bool | str = True,
    ) -> None:
        self.name = name
        self.expected_end_s = expected_end_s
        self._bar: Any = None
        self._lines: _Lines | None = None
        mode = resolve_mode(enabled)
        if mode == "lines":
            self._lines = _Lines(name, expected_end_s, cap_s, ends_when)
        if mode != "bar":
            return
        from tqdm import tqdm

        if expected_end_s is not None:
            total = round(expected_end_s, 3)
            digits = 0 if total >= 10 else 1  # a 0.5 s run is not "0/0 sim s"
            layout = (
                f"{{desc}}  {{percentage:3.0f}}% |{{bar}}| {{n:.{digits}f}}/{{total:.{digits}f}} "
                "sim s [{elapsed}<{remaining}]{postfix}"
            )
        else:
            total = None
            until = f" until {ends_when}" if ends_when else ""
            layout = (
                "{desc}  {n:.0f} sim s [{elapsed}, {rate_fmt}]{postfix}"
                + f"{until} (at most {cap_s:g} s)".replace("{", "{{").replace("}", "}}")
            )
        self._bar = tqdm(total=total, unit="sim s", file=sys.stderr, bar_format=layout, desc=name)

    def stage(self, what: str) -> None:
        """Show the set-up stage (``"placing robots"``) until the next update."""
        if self._lines is not None:
            self._lines.stage(what)
        if self._bar is not None:
            self._bar.set_description_str(
                self.name if what == "running" else f"{self.name}: {what}"
            )

    def update(self, now_s: float, note: str = "") -> None:
        """The run has reached simulated time ``now_s``; ``note`` says where it is."""
        if self._lines is not None:
            self._lines.update(now_s, note)
        bar = self._bar
        if bar is None:
            return
        if bar.total is not None and now_s > bar.total:
            bar.total = round(now_s, 3)  # ran past the expected end: never show more than 100 %
        bar.set_postfix_str(note, refresh=False)
        bar.update(round(now_s - bar.n, 3))

    def close(self) -> None:
        """End the display (the cursor moves to a new line)."""
        if self._lines is not None:
            self._lines.close()
            self._lines = None
        if self._bar is not None:
            self._bar.set_description_str(self.name, refresh=False)  # not a last stage's name
            self._bar.close()

    def __enter__(self) -> RunProgress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and self._bar is not None:
            self._bar.leave = False  # erase the bar: the error message is what remains
        if exc_type is not None:
            self._lines = None  # no "done" line for a run that failed
        self.close()


class _Lines:
    """The ``lines`` mode: whole lines on stderr, each one flushed."""

    #: Wall seconds after which a line is written even if nothing else calls for one.
    QUIET_S = 30.0

    def __init__(
        self, name: str, expected_end_s: float | None, cap_s: float, ends_when: str
    ) -> None:
        self.name = name
        self.end_s = expected_end_s
        self.cap_s = cap_s
        self.ends_when = ends_when
        self.start = self.last_line = time.monotonic()
        self.next_tenth = 1
        self.note = ""
        self.now_s = 0.0

    def write(self, text: str) -> None:
        print(f"{self.name}: {text}", file=sys.stderr, flush=True)
        self.last_line = time.monotonic()

    def stage(self, what: str) -> None:
        if what == "running":
            if self.end_s is not None:
                self.write(f"running to {self.end_s:g} sim s")
            else:
                until = f" until {self.ends_when}," if self.ends_when else ""
                self.write(f"running{until} at most {self.cap_s:g} sim s")
        else:
            self.write(what)

    def update(self, now_s: float, note: str) -> None:
        self.now_s = now_s
        reason = note != self.note
        if self.end_s:
            while now_s >= self.next_tenth * self.end_s / 10 and self.next_tenth <= 10:
                self.next_tenth += 1
                reason = True
        if reason or time.monotonic() - self.last_line >= self.QUIET_S:
            self.note = note
            self.write(self._figures())

    def _figures(self) -> str:
        elapsed = time.monotonic() - self.start
        share = f"{min(100.0, 100 * self.now_s / self.end_s):3.0f}% " if self.end_s else ""
        note = f", {self.note}" if self.note else ""
        return f"{share}{self.now_s:g} sim s, {elapsed:.1f} s elapsed{note}"

    def close(self) -> None:
        elapsed = time.monotonic() - self.start
        self.write(f"done at {self.now_s:g} sim s in {elapsed:.1f} s")


class StageProgress:
    """Progress of the work after a run (writing its tables, figures, the animation) on
    stderr, by the rules of :class:`RunProgress`: ``bar`` shows the current stage on one line
    redrawn in place and erased at the end (the summary follows); ``lines`` writes one line per
    stage and one at the end; ``none`` writes nothing.

    Parameters
    ----------
    name : str
        The scenario, shown first.
    enabled : bool or str
        A mode of :data:`MODES` (``True``: ``bar``; ``False``: ``none``).
    """

    def __init__(self, name: str, *, enabled: bool | str = True) -> None:
        self.name = name
        self._mode = resolve_mode(enabled)
        self._start = time.monotonic()
        self._bar: Any = None

    def stage(self, what: str) -> None:
        """Show that the work is now ``what`` (``"writing tables"``)."""
        if self._mode == "lines":
            print(f"{self.name}: {what}", file=sys.stderr, flush=True)
        elif self._mode == "bar":
            if self._bar is None:
                from tqdm import tqdm

                self._bar = tqdm(
                    total=None,
                    file=sys.stderr,
                    bar_format="{desc} [{elapsed}]",
                    desc=f"{self.name}: {what}",
                    leave=False,
                )
            else:
                self._bar.set_description_str(f"{self.name}: {what}")

    def close(self) -> None:
        """End the display: the bar is erased; ``lines`` says how long the work took."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        if self._mode == "lines":
            elapsed = time.monotonic() - self._start
            print(f"{self.name}: written in {elapsed:.1f} s", file=sys.stderr, flush=True)
            self._mode = "none"

    def __enter__(self) -> StageProgress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is not None and self._mode == "lines":
            self._mode = "none"  # no "written" line for work that failed
        self.close()
