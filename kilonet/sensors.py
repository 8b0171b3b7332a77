"""What a Kilobot's own analogue sensors read: ambient light, battery voltage, temperature.

All three are 10-bit ADC readings, as kilolib returns them (``get_ambientlight``,
``get_voltage``, ``get_temperature``; each returns -1 while a message is arriving, which the
robot API handles).

* **Ambient light** (``light.*``): ``ambient + I / (1 + (d / falloff)**2) * (1 - k * a / 180°)
  + N(0, noise_sd)``, clipped to 0-1023, for a source of intensity ``I`` at distance ``d`` from
  the robot; the source's share halves at ``falloff_mm``. The sensor sits on one side of the
  body, so what it reads of the source depends on the robot's heading: ``a`` is the angle
  between the bearing to the source and the direction the sensor sees best
  (``sensor_angle_deg``, counter-clockwise from the heading), and ``k`` is ``directionality``.
  The defaults are ARGoS's Kilobot light sensor (``kilobot_light_rotzonly_sensor.cpp``: the
  reading scales by ``1 - a / 180°``, best at 100° from the heading); ``directionality = 0``
  reads the same facing any way. kilolib documents no scale (the move-to-light lab uses
  thresholds of 300 and 600); the field is a scenario's choice. The lab's zigzag towards the
  light needs the heading dependence: with a reading that depends on position alone, a robot
  pivoting on one motor circles its leg and never crosses both thresholds.
* **Voltage**: ``round(169 * V + 6)``, the line through two calibration points of a kilolib
  fork (547 at 3.2 V, 716 at 4.2 V; kilolib's own battery display switches at 682, 648 and 614,
  which this maps to 4.0, 3.8 and 3.6 V).
* **Temperature**: the ATmega328P's sensor against its 1.1 V reference: the datasheet's typical
  242 / 314 / 380 mV at -45 / 25 / 85 °C, read as ``mV * 1024 / 1100`` counts (292 at 25 °C),
  plus a per-robot offset of ``N(0, 5)`` counts (the datasheet: ±10 °C before calibration).
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = ["Sensors", "temperature_mv", "voltage_reading"]

_TEMPERATURE_C = (-45.0, 25.0, 85.0)
_TEMPERATURE_MV = (242.0, 314.0, 380.0)


def voltage_reading(volts: float) -> int:
    """kilolib's ``get_voltage()`` reading at ``volts``.

    Examples
    --------
    >>> voltage_reading(3.2), voltage_reading(4.2), voltage_reading(4.0)
    (547, 716, 682)
    """
    return int(np.clip(round(169.0 * volts + 6.0), 0, 1023))


def temperature_mv(celsius: float) -> float:
    """The sensor's typical output at ``celsius`` (the datasheet's table, interpolated).

    Examples
    --------
    >>> temperature_mv(25.0), round(temperature_mv(55.0), 1)
    (314.0, 347.0)
    """
    return float(np.interp(celsius, _TEMPERATURE_C, _TEMPERATURE_MV))


class Sensors:
    """The analogue sensors of every robot of a simulation."""

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        self.light = sim.params.light
        self._sensor_angle = math.radians(self.light.sensor_angle_deg)
        self._rng = sim.stream("sensors")
        self.temperature_offset = np.rint(self._rng.normal(0.0, 5.0, sim.n_robots)).astype(int)

    def ambient_light(self, robot: int) -> int:
        """The light reading at ``robot``'s position and heading now."""
        p = self.light
        value = p.ambient
        if p.source_intensity > 0:
            world = self.sim.world
            x, y = world.positions_mm[robot]
            dx, dy = p.source_x_mm - float(x), p.source_y_mm - float(y)
            off = math.atan2(dy, dx) - float(world.heading_rad[robot]) - self._sensor_angle
            off = abs((off + math.pi) % (2 * math.pi) - math.pi)  # 0 to pi
            share = p.source_intensity / (1.0 + (math.hypot(dx, dy) / p.falloff_mm) ** 2)
            value += share * (1.0 - p.directionality * off / math.pi)
        if p.noise_sd > 0:
            value += p.noise_sd * float(self._rng.standard_normal())
        return min(max(round(value), 0), 1023)

    def voltage_reading(self, robot: int) -> int:
        """The battery reading of ``robot`` now."""
        return voltage_reading(self.sim.battery.voltage(robot))

    def temperature_reading(self, robot: int) -> int:
        """The temperature reading of ``robot``."""
        mv = temperature_mv(self.sim.params.robot.temperature_c)
        return int(np.clip(round(mv * 1024 / 1100) + self.temperature_offset[robot], 0, 1023))
