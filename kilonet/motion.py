"""Vibration-motor motion with per-robot speed and turn-rate errors, and no overlaps.

Both motors on: forward at ``speed_mm_s``; right motor only: pivot counter-clockwise (turn left)
at ``turn_deg_s``; left motor only: pivot clockwise. Each robot's true speed and turn rate are the
nominal ones times ``1 + N(0, speed_error)`` and ``1 + N(0, turn_error)`` (drawn once per robot),
and the battery slows both. A forward move that would make two discs overlap stops at contact.

The pose of a moving robot is integrated every ``step_s`` and whenever its motors change; only
moving robots have timers, and the medium's receiver sets are rebuilt only after a robot moved,
so a static swarm never pays for motion.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from simpy.events import Timeout

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = ["Motion", "contact_distance"]


def contact_distance(
    start_mm: np.ndarray, direction: np.ndarray, others_mm: np.ndarray, diameter_mm: float
) -> float:
    """How far a disc can travel from ``start_mm`` along unit ``direction`` before touching.

    Returns ``inf`` when no disc in ``others_mm`` is in the way.

    Examples
    --------
    >>> contact_distance(np.zeros(2), np.array([1.0, 0.0]), np.array([[50.0, 0.0]]), 33.0)
    17.0
    >>> contact_distance(np.zeros(2), np.array([-1.0, 0.0]), np.array([[50.0, 0.0]]), 33.0)
    inf
    """
    if len(others_mm) == 0:
        return math.inf
    w = others_mm - start_mm
    along = w @ direction
    disc = along**2 - np.einsum("ij,ij->i", w, w) + diameter_mm**2
    hits = (along > 0) & (disc >= 0)
    if not hits.any():
        return math.inf
    return float(max(0.0, np.min(along[hits] - np.sqrt(disc[hits]))))


class Motion:
    """Motor state and pose integration for all robots of a simulation."""

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        p = sim.params.motion
        self.params = p
        n = sim.n_robots
        rng = sim.stream("motion")
        self.speed_mm_s = p.speed_mm_s * np.clip(1 + rng.normal(0, p.speed_error, n), 0.1, None)
        self.turn_rad_s = np.radians(p.turn_deg_s) * np.clip(
            1 + rng.normal(0, p.turn_error, n), 0.1, None
        )
        self.motors = [(False, False)] * n
        self._last_update = [0.0] * n
        self._timer_on = [False] * n
        self.blocked_count = [0] * n

    def set_motors(self, robot: int, left: bool, right: bool) -> None:
        """Switch the motors of ``robot``; the pose is integrated up to now first."""
        if not self.sim.world.running[robot]:
            return
        self._integrate(robot)
        self.motors[robot] = (left, right)
        if (left or right) and not self._timer_on[robot]:
            self._timer_on[robot] = True
            self._schedule(robot)

    def stop(self, robot: int) -> None:
        """Stop the motors of ``robot`` (it crashed, was removed or its battery died)."""
        self._integrate(robot)
        self.motors[robot] = (False, False)

    def _schedule(self, robot: int) -> None:
        Timeout(self.sim.env, self.params.step_s).callbacks.append(lambda _e: self._tick(robot))

    def _tick(self, robot: int) -> None:
        self._integrate(robot)
        if any(self.motors[robot]):
            self._schedule(robot)
        else:
            self._timer_on[robot] = False

    def _integrate(self, robot: int) -> None:
        sim = self.sim
        now = sim.env.now
        dt = now - self._last_update[robot]
        self._last_update[robot] = now
        left, right = self.motors[robot]
        if dt <= 0 or not (left or right):
            return
        sim.battery.motor_s[robot] += dt * (left + right)
        factor = sim.battery.motor_factor[robot]
        world = sim.world
        if left and right:
            heading = world.heading_rad[robot]
            direction = np.array([math.cos(heading), math.sin(heading)])
            wanted = self.speed_mm_s[robot] * factor * dt
            others = np.flatnonzero(world.present)
            others = others[others != robot]
            free = contact_distance(
                world.positions_mm[robot], direction, world.positions_mm[others], world.diameter_mm
            )
            step = min(wanted, free)
            if step < wanted:
                self.blocked_count[robot] += 1
            world.positions_mm[robot] += step * direction
        else:
            sign = 1.0 if right else -1.0
            world.heading_rad[robot] = (
                world.heading_rad[robot] + sign * self.turn_rad_s[robot] * factor * dt
            ) % (2 * math.pi)
        sim.trace.pose(now, robot, *world.positions_mm[robot], world.heading_rad[robot])
        if left and right:
            sim.medium.rebuild_topology()
