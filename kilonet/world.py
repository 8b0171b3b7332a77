"""Ground truth of a run: where the robots are, which are on the table and which run.

Its own module so that every part that reads it (medium, motion, sensors, battery) can name it
without importing :mod:`kilonet.simulation`, which imports them all.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from kilonet.placement import ROBOT_DIAMETER_MM

__all__ = ["World"]


@dataclass
class World:
    """Ground truth: where the robots are. Only the medium, motion, sensors and metrics read it."""

    positions_mm: np.ndarray
    heading_rad: np.ndarray
    diameter_mm: float = ROBOT_DIAMETER_MM
    present: np.ndarray = field(default=None)  # on the table (removal clears it)
    running: np.ndarray = field(default=None)  # executing its program

    def __post_init__(self) -> None:
        n = len(self.positions_mm)
        if self.present is None:
            self.present = np.ones(n, dtype=bool)
        if self.running is None:
            self.running = np.ones(n, dtype=bool)

    @property
    def radius_mm(self) -> float:
        """Body radius, mm."""
        return self.diameter_mm / 2
