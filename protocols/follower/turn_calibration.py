"""Turning by timed motor pulses: the linear calibration ``t = f(angle)`` and the timed turns
it is fitted from.

A Kilobot has no compass, so it turns by running one motor for a time. The seed's author
timed one robot through several known angles and fitted a straight line
``t = offset_s + s_per_rad * angle`` by hand; other robots then used that line. Here the robot
side of that procedure is :class:`TimedTurns` (a program that pivots for a list of durations
and logs each pulse), and the fit is :meth:`TurnCalibration.fit` (least squares). Measuring the
angle each pulse actually turned is the observer's job
(``kilonet.scenarios.follower.calibrate_turns`` reads it from the run's poses, as the author read it
off the table).

Examples
--------
>>> cal = TurnCalibration.fit([math.pi / 2, math.pi], [2.5, 4.5])
>>> round(cal.s_per_rad, 6), round(cal.offset_s, 6)
(1.27324, 0.5)
>>> round(cal.turn_time_s(math.pi / 4), 6)
1.5
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.robot import Kilobot

__all__ = ["TimedTurns", "TurnCalibration"]


@dataclass(frozen=True)
class TurnCalibration:
    """A linear turn-time calibration ``t = offset_s + s_per_rad * |angle|``.

    Parameters
    ----------
    s_per_rad : float
        Seconds of one-motor pivoting per radian turned (> 0).
    offset_s : float
        Time at zero angle, s (motor spin-up on a real robot; about 0 in the simulator).
    """

    s_per_rad: float
    offset_s: float = 0.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.s_per_rad) and self.s_per_rad > 0):
            raise ValueError(f"s_per_rad = {self.s_per_rad} must be a positive number")
        if not math.isfinite(self.offset_s):
            raise ValueError(f"offset_s = {self.offset_s} is not finite")

    @classmethod
    def nominal(cls, turn_deg_s: float) -> TurnCalibration:
        """The calibration of a robot that turns exactly ``turn_deg_s`` degrees per second.

        >>> round(TurnCalibration.nominal(45.0).turn_time_s(math.pi), 9)
        4.0
        """
        return cls(s_per_rad=1.0 / math.radians(turn_deg_s))

    @classmethod
    def fit(cls, angles_rad: Sequence[float], times_s: Sequence[float]) -> TurnCalibration:
        """Least-squares line ``t = offset + slope * angle`` through timed turns.

        Parameters
        ----------
        angles_rad : sequence of float
            Angles turned (as measured), radians; their magnitudes are used.
        times_s : sequence of float
            Motor-on time of each turn, s.

        Raises
        ------
        ValueError
            If fewer than two turns or fewer than two distinct angles are given, or the
            fitted slope is not positive.
        """
        a = np.abs(np.asarray(angles_rad, dtype=float))
        t = np.asarray(times_s, dtype=float)
        if a.shape != t.shape or a.ndim != 1:
            raise ValueError(f"angles and times must be equal-length 1-D ({a.shape}, {t.shape})")
        if len(np.unique(a)) < 2:
            raise ValueError("a turn calibration needs at least two distinct angles")
        slope, offset = np.polyfit(a, t, 1)
        if not slope > 0:
            raise ValueError(f"fitted slope {slope:.3g} s/rad is not positive")
        return cls(s_per_rad=float(slope), offset_s=float(offset))

    def turn_time_s(self, angle_rad: float) -> float:
        """Motor-on time for a turn of ``|angle_rad|``, s (never negative)."""
        return max(0.0, self.offset_s + self.s_per_rad * abs(angle_rad))

    @property
    def deg_per_s(self) -> float:
        """The turn rate this calibration assumes, degrees per second (ignoring the offset)."""
        return math.degrees(1.0 / self.s_per_rad)


class TimedTurns(Kilobot):
    """Pivot counter-clockwise for each duration in turn, pausing in between.

    Each pulse is logged as event ``timed_turn`` with ``index``, ``start_tick``, ``stop_tick``
    and ``duration_s`` (the motor-on time the robot's clock measured, whole ticks).

    Parameters
    ----------
    durations_s : sequence of float
        Motor-on time of each turn, s.
    pause_s : float
        Rest between turns, s (lets an observer read the angle).
    """

    def __init__(self, durations_s: Sequence[float], *, pause_s: float = 1.0) -> None:
        self.durations_s = [float(d) for d in durations_s]
        self.pause_s = pause_s

    def setup(self) -> None:
        self.index = 0
        self.turning = False
        self.next_tick = round(self.pause_s * self.ticks_per_s)
        self.start_tick = 0
        self.done = not self.durations_s

    def loop(self) -> None:
        if self.done or self.kilo_ticks < self.next_tick:
            return
        now = self.kilo_ticks
        if not self.turning:
            self.turning = True
            self.start_tick = now
            self.next_tick = now + max(1, round(self.durations_s[self.index] * self.ticks_per_s))
            self.spinup_motors()
            self.set_motors(self.kilo_turn_left, 0)  # kilolib: the left motor turns left
            return
        self.set_motors(0, 0)
        self.turning = False
        self.log(
            "timed_turn",
            index=self.index,
            start_tick=self.start_tick,
            stop_tick=now,
            duration_s=(now - self.start_tick) / self.ticks_per_s,
        )
        self.index += 1
        self.done = self.index >= len(self.durations_s)
        self.next_tick = now + round(self.pause_s * self.ticks_per_s)
