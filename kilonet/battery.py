"""Battery voltage of every robot, and what a low battery does to it.

Voltage falls linearly with time (``idle_drain_v_per_h``) and with motor use
(``motor_drain_v_per_h`` per running motor). Below ``degrade_v`` a robot degrades in proportion
to ``f = (degrade_v - V) / (degrade_v - cutoff_v)`` (0 at ``degrade_v``, 1 at ``cutoff_v``):

* reception loss rises by ``f * loss_at_cutoff``;
* transmit range shrinks to ``1 - f * (1 - range_factor_at_cutoff)`` of its full value;
* motors slow to ``1 - f * (1 - motor_factor_at_cutoff)`` of their speed;
* the LED dims to ``1 - f * (1 - led_factor_at_cutoff)`` of its brightness.

At ``cutoff_v`` the robot stops. Degradation is re-evaluated every ``update_s`` simulated seconds
(one vectorised step for the whole swarm), and only scheduled at all when the battery model is on.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from simpy.events import Timeout

if TYPE_CHECKING:
    import simpy

    from kilonet.medium import InfraredMedium
    from kilonet.params import BatteryParams
    from kilonet.trace import Trace
    from kilonet.world import World

__all__ = ["Battery", "degradation"]


def degradation(voltage_v: np.ndarray, degrade_v: float, cutoff_v: float) -> np.ndarray:
    """Degradation level in [0, 1]: 0 at or above ``degrade_v``, 1 at or below ``cutoff_v``.

    Examples
    --------
    >>> degradation(np.array([4.2, 3.6, 3.4, 3.2, 3.0]), 3.6, 3.2).round(2).tolist()
    [0.0, 0.0, 0.5, 1.0, 1.0]
    """
    return np.clip((degrade_v - voltage_v) / (degrade_v - cutoff_v), 0.0, 1.0)


class Battery:
    """The batteries of all robots of a simulation (one vectorised model).

    Parameters
    ----------
    params : BatteryParams
        The run's ``battery`` section.
    env : simpy.Environment
        The run's clock and queue.
    world : World
        Which robots run (a flat battery stops only running robots; the model stops
        re-evaluating once none runs).
    medium : InfraredMedium
        Where a low battery shortens the transmit range and loses receptions.
    trace : Trace
        Where each change of a robot's degradation is recorded.
    stop : callable
        ``stop(robot, "battery")`` stops a robot whose battery is flat.
    """

    def __init__(
        self,
        params: BatteryParams,
        env: simpy.Environment,
        world: World,
        medium: InfraredMedium,
        trace: Trace,
        *,
        stop: Callable[[int, str], None],
    ) -> None:
        self.params, self.env, self._world = params, env, world
        self._medium, self._trace, self._stop = medium, trace, stop
        n = len(world.running)
        self.initial_v = np.full(n, self.params.initial_v)
        self.motor_s = np.zeros(n)  # motor-seconds used so far (two motors count twice)
        self.level = np.zeros(n)  # degradation level applied last
        self.motor_factor = np.ones(n)
        self.led_factor = np.ones(n)

    def start(self) -> None:
        """Apply the initial degradation and schedule the periodic re-evaluation."""
        if self.params.enabled:
            self._update()

    def voltages(self) -> np.ndarray:
        """Voltage of every robot now, V."""
        if not self.params.enabled:
            return self.initial_v.copy()
        p = self.params
        hours = self.env.now / 3600.0
        motor_h = self.motor_s / 3600.0
        return self.initial_v - p.idle_drain_v_per_h * hours - p.motor_drain_v_per_h * motor_h

    def voltage(self, robot: int) -> float:
        """Voltage of one robot now, V."""
        if not self.params.enabled:
            return float(self.initial_v[robot])
        p = self.params
        hours = self.env.now / 3600.0
        return float(
            self.initial_v[robot]
            - p.idle_drain_v_per_h * hours
            - p.motor_drain_v_per_h * self.motor_s[robot] / 3600.0
        )

    def _update(self, _event: object = None) -> None:
        p = self.params
        volts = self.voltages()
        level = degradation(volts, p.degrade_v, p.cutoff_v)
        changed = np.flatnonzero(level != self.level)
        medium = self._medium
        for r in changed.tolist():
            f = float(level[r])
            medium.set_extra_loss(r, battery=f * p.loss_at_cutoff)
            medium.set_range_factor(r, 1.0 - f * (1.0 - p.range_factor_at_cutoff))
        self.level = level
        self.motor_factor = 1.0 - level * (1.0 - p.motor_factor_at_cutoff)
        self.led_factor = 1.0 - level * (1.0 - p.led_factor_at_cutoff)
        now = self.env.now
        for r in changed.tolist():
            self._trace.battery(now, r, volts[r], level[r], self.led_factor[r])
        world = self._world
        for r in np.flatnonzero((volts <= p.cutoff_v) & world.running).tolist():
            self._stop(r, "battery")
        if world.running.any():
            Timeout(self.env, p.update_s).callbacks.append(self._update)
