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
    from collections.abc import Callable

    from kilonet.params import LightParams
    from kilonet.world import World

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
    """The analogue sensors of every robot of a simulation.

    Parameters
    ----------
    light : LightParams
        The light on the table (``light.*``).
    temperature_c : float
        Air temperature, degrees C (``robot.temperature_c``).
    world : World
        Where the robots stand and face (read at each light reading).
    voltage_v : callable
        ``voltage_v(robot)``: the battery voltage of ``robot`` now, V.
    rng : numpy.random.Generator
        The ``sensors`` stream: each robot's temperature offset, then the light noise.
    """

    def __init__(
        self,
        light: LightParams,
        temperature_c: float,
        world: World,
        voltage_v: Callable[[int], float],
        rng: np.random.Generator,
    ) -> None:
        self.light = light
        self._world = world
        self._voltage_v = voltage_v
        self._temperature_mv = temperature_mv(temperature_c)
        self._sensor_angle = math.radians(self.light.sensor_angle_deg)
        self._rng = rng
        n = len(world.positions_mm)
        self.temperature_offset = np.rint(self._rng.normal(0.0, 5.0, n)).astype(int)

    def ambient_light(self, robot: int) -> int:
        """The light reading at ``robot``'s position and heading now."""
        p = self.light
        value = p.ambient
        if p.source_intensity > 0:
            world = self._world
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
        return voltage_reading(self._voltage_v(robot))

    def temperature_reading(self, robot: int) -> int:
        """The temperature reading of ``robot``."""
        mv = self._temperature_mv
        return int(np.clip(round(mv * 1024 / 1100) + self.temperature_offset[robot], 0, 1023))
