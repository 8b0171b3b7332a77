"""A run's progress on stderr that tells the truth about where the run will end.

Before the simulation exists, the display names the set-up stage (placing robots, building
them, starting), so a large swarm's long set-up is not silent. Then:

* when the run's end is known before it starts (a fixed duration, or phase windows that end
  it), a bar to that end: ``gradient  42% |####      | 13/30 sim s [00:01<00:02]``;
* when only a stop condition will end it, no bar and no made-up percentage: the simulated
  seconds so far, the rate, what the run waits for and the cap ``duration_s``:
  ``follower  154 sim s [00:03, 45.2 sim s/s] until the follower arrives or gives up
  (at most 600 s)``.

A note from the scenario (the current phase) follows either form.
"""

from __future__ import annotations

import sys
from types import TracebackType
from typing import Any

__all__ = ["RunProgress"]


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
    enabled : bool
        Show anything at all.
    """

    def __init__(
        self,
        name: str,
        *,
        expected_end_s: float | None,
        cap_s: float,
        ends_when: str = "",
        enabled: bool = True,
    ) -> None:
        self.name = name
        self.expected_end_s = expected_end_s
        self._bar: Any = None
        if not enabled:
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
                "{desc}  {n:.0f} sim s [{elapsed}, {rate_fmt}]"
                + f"{until} (at most {cap_s:g} s)".replace("{", "{{").replace("}", "}}")
                + "{postfix}"
            )
        self._bar = tqdm(total=total, unit="sim s", file=sys.stderr, bar_format=layout, desc=name)

    def stage(self, what: str) -> None:
        """Show the set-up stage (``"placing robots"``) until the next update."""
        if self._bar is not None:
            self._bar.set_description_str(
                self.name if what == "running" else f"{self.name}: {what}"
            )

    def update(self, now_s: float, note: str = "") -> None:
        """The run has reached simulated time ``now_s``; ``note`` says where it is."""
        bar = self._bar
        if bar is None:
            return
        if bar.total is not None and now_s > bar.total:
            bar.total = round(now_s, 3)  # ran past the expected end: never show more than 100 %
        bar.set_postfix_str(note, refresh=False)
        bar.update(round(now_s - bar.n, 3))

    def close(self) -> None:
        """End the display (the cursor moves to a new line)."""
        if self._bar is not None:
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
        self.close()
