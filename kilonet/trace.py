"""What a run records: LED changes, protocol events, poses of moving robots, robot stops,
and what programs estimated their positions to be.

Everything is stored as events (not per frame), so a long run stays small; the tables come
out as tidy pandas DataFrames with times in simulated seconds.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["Trace"]


def _table(rows: list[tuple], columns: list[str]) -> pd.DataFrame:
    """A DataFrame of ``rows``; pandas is imported here, when a run's tables are wanted, not
    before the run starts."""
    import pandas as pd

    return pd.DataFrame(rows, columns=columns)


class Trace:
    """Append-only event log of one simulation."""

    def __init__(self) -> None:
        self._led: list[tuple[float, int, int, int, int]] = []
        self._events: list[tuple[float, int, str, str]] = []
        self._poses: list[tuple[float, int, float, float, float]] = []
        self._stops: list[tuple[float, int, str]] = []
        self._messages: list[tuple[float, int, int, int]] = []
        self._battery: list[tuple[float, int, float, float, float]] = []
        self._estimates: list[tuple[float, int, float, float, str]] = []

    def led(self, t_s: float, robot: int, color: tuple[int, int, int]) -> None:
        """Record that ``robot`` set its LED to ``color`` (kilolib 0–3 per channel)."""
        self._led.append((t_s, robot, *color))

    def event(self, t_s: float, robot: int, name: str, fields: dict[str, Any]) -> None:
        """Record a protocol event; ``fields`` must be JSON-serialisable."""
        self._events.append((t_s, robot, name, json.dumps(fields, sort_keys=True)))

    def pose(self, t_s: float, robot: int, x_mm: float, y_mm: float, heading_rad: float) -> None:
        """Record the pose of a moving robot."""
        self._poses.append((t_s, robot, float(x_mm), float(y_mm), float(heading_rad)))

    def stop(self, t_s: float, robot: int, cause: str) -> None:
        """Record that ``robot`` stopped (crash, removal, battery)."""
        self._stops.append((t_s, robot, cause))

    def message(self, t_s: float, sender: int, receivers: int, delivered: int) -> None:
        """Record a transmission that ended at ``t_s``: receivers in range, and deliveries."""
        self._messages.append((t_s, sender, receivers, delivered))

    def battery(
        self, t_s: float, robot: int, voltage_v: float, level: float, led_factor: float
    ) -> None:
        """Record a change of ``robot``'s battery degradation ``level`` (0 fine, 1 cut-off) and
        the LED brightness factor that goes with it (animations dim the LED by it)."""
        self._battery.append((t_s, robot, float(voltage_v), float(level), float(led_factor)))

    def estimate(self, t_s: float, robot: int, x_mm: float, y_mm: float, frame: str) -> None:
        """Record the position ``robot`` holds from ``t_s`` on, in the coordinates of its
        ``frame`` (NaN and ``""``: it no longer has one)."""
        self._estimates.append((t_s, robot, float(x_mm), float(y_mm), frame))

    def led_since(self, start: int) -> list[tuple[float, int, int, int, int]]:
        """LED changes from the ``start``-th on, as recorded: ``(t_s, robot, r, g, b)`` (for
        readers that follow a run as it goes, as :mod:`kilonet.testing` does)."""
        return self._led[start:]

    def events_since(self, start: int) -> list[tuple[float, int, str, str]]:
        """Protocol events from the ``start``-th on, as recorded: ``(t_s, robot, event, JSON
        data)``."""
        return self._events[start:]

    def led_frame(self) -> pd.DataFrame:
        """LED changes: ``t_s, robot, r, g, b``."""
        return _table(self._led, ["t_s", "robot", "r", "g", "b"])

    def events_frame(self) -> pd.DataFrame:
        """Protocol events: ``t_s, robot, event, data`` (data as a JSON object string)."""
        return _table(self._events, ["t_s", "robot", "event", "data"])

    def poses_frame(self) -> pd.DataFrame:
        """Poses of moving robots: ``t_s, robot, x_mm, y_mm, heading_rad``."""
        return _table(self._poses, ["t_s", "robot", "x_mm", "y_mm", "heading_rad"])

    def stops_frame(self) -> pd.DataFrame:
        """Robot stops: ``t_s, robot, cause``."""
        return _table(self._stops, ["t_s", "robot", "cause"])

    def messages_frame(self) -> pd.DataFrame:
        """Transmissions (only with ``trace.messages``): ``t_s, sender, receivers, delivered``,
        where ``t_s`` is the end of airtime."""
        return _table(self._messages, ["t_s", "sender", "receivers", "delivered"])

    def battery_frame(self) -> pd.DataFrame:
        """Battery degradation changes: ``t_s, robot, voltage_v, level, led_factor``."""
        return _table(self._battery, ["t_s", "robot", "voltage_v", "level", "led_factor"])

    def estimates_frame(self) -> pd.DataFrame:
        """Position estimates as programs held them (``trace.estimates_period_s``), one row
        per change: ``t_s, robot, x_mm, y_mm, frame``."""
        return _table(self._estimates, ["t_s", "robot", "x_mm", "y_mm", "frame"])

    def frames(self) -> dict[str, pd.DataFrame]:
        """All tables by name."""
        return {
            "battery": self.battery_frame(),
            "led": self.led_frame(),
            "events": self.events_frame(),
            "poses": self.poses_frame(),
            "stops": self.stops_frame(),
            "messages": self.messages_frame(),
            "estimates": self.estimates_frame(),
        }
