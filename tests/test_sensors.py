"""Tests for kilonet.sensors: what get_ambientlight() reads of the light field."""

from __future__ import annotations

import math

from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


class Reader(Kilobot):
    """Reads the light once, at the start."""

    def setup(self) -> None:
        self.light = self.get_ambientlight()


def readings(headings_deg, **light) -> list[int]:
    """The reading of a robot 300 mm east of the source at each heading (a second robot far
    away keeps the placement valid), without noise."""
    params = Params(seed=1).with_overrides(
        {
            "light.noise_sd": 0.0,
            "light.source_intensity": 600.0,
            "light.source_x_mm": 0.0,
            "light.source_y_mm": 0.0,
            "light.falloff_mm": 300.0,
            **{f"light.{k}": v for k, v in light.items()},
        }
    )
    out = []
    for heading in headings_deg:
        sim = Simulation(
            [[300.0, 0.0], [300.0, 500.0]], Reader, params, headings_rad=[math.radians(heading), 0]
        )
        sim.start()
        out.append(sim.robots[0].light)
    return out


def test_the_reading_depends_on_where_the_sensor_faces():
    # The source lies west (180°) of the robot; the sensor sees best 100° left of the heading.
    # Heading 80°: the source is 100° to the left, full share (600 / 2 = 300 above ambient 200).
    # Heading -100° (260°): the source is 80° to the right, 180° off: ambient only.
    # Heading 170°: the source is 10° to the left, 90° off: half the share.
    assert readings([80.0, 260.0, 170.0]) == [500, 200, 350]


def test_a_reading_without_directionality_ignores_the_heading():
    assert readings([0.0, 80.0, 260.0], directionality=0.0) == [500, 500, 500]


def test_the_sensor_angle_is_a_parameter():
    assert readings([180.0, 0.0], sensor_angle_deg=0.0) == [500, 200]
    assert readings([180.0], sensor_angle_deg=0.0, directionality=0.5) == [500]
    assert readings([0.0], sensor_angle_deg=0.0, directionality=0.5) == [350]
