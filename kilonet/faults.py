"""Fault injection: crashes, removals and faulty receivers, by time or by probability.

* **crash** — the robot stops running (no loop, no transmit, no receive) but its body stays on
  the table and still blocks line of sight.
* **removal** — the robot is lifted off the table: it stops and no longer blocks anything.
* **faulty receiver** — the robot drops a share of its receptions and delays a share of the
  rest by ``U(0, delay_s)``, as the thesis observed on some real robots.

Random faults (``faults.*_fraction``) pick robots with the run's ``faults`` stream; scenarios and
tests can also call :meth:`FaultInjector.crash_at`, :meth:`FaultInjector.remove_at` and
:meth:`FaultInjector.faulty_receiver` directly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from simpy.events import Timeout

if TYPE_CHECKING:
    import numpy as np
    import simpy

    from kilonet.medium import InfraredMedium
    from kilonet.params import FaultParams
    from kilonet.port import ReceivePorts

__all__ = ["FaultInjector"]


class FaultInjector:
    """Schedules the faults of one simulation.

    Parameters
    ----------
    params : FaultParams
        What to inject (``faults.*``).
    env : simpy.Environment
        The run's clock, where faults are scheduled.
    rng : numpy.random.Generator
        The ``faults`` stream.
    n_robots : int
        Robots in the swarm.
    stop : callable
        ``stop(robot, cause, remove=False)``: stop a robot (crash) or lift it off the table.
    medium : InfraredMedium
        Whose receiver losses a faulty receiver raises.
    ports : ReceivePorts
        The robots' receive ports, where a faulty receiver's delays plug in.
    """

    def __init__(
        self,
        params: FaultParams,
        env: simpy.Environment,
        rng: np.random.Generator,
        n_robots: int,
        *,
        stop: Callable[..., None],
        medium: InfraredMedium,
        ports: ReceivePorts,
    ) -> None:
        self.params, self.env, self.rng, self.n_robots = params, env, rng, n_robots
        self._stop, self._medium, self._ports = stop, medium, ports
        self.faulty_receivers: set[int] = set()

    def start(self) -> None:
        """Draw and schedule the random faults that the parameters ask for."""
        p = self.params
        for fraction, lo, hi, action in (
            (p.crash_fraction, p.crash_from_s, p.crash_to_s, self.crash_at),
            (p.remove_fraction, p.remove_from_s, p.remove_to_s, self.remove_at),
        ):
            for robot in self._pick(fraction):
                action(robot, float(self.rng.uniform(lo, max(lo, hi))))
        for robot in self._pick(p.faulty_rx_fraction):
            self.faulty_receiver(
                robot,
                drop_prob=p.faulty_rx_drop_prob,
                delay_prob=p.faulty_rx_delay_prob,
                delay_s=p.faulty_rx_delay_s,
            )

    def _pick(self, fraction: float) -> list[int]:
        n = self.n_robots
        count = round(fraction * n)
        return sorted(self.rng.choice(n, size=count, replace=False).tolist()) if count else []

    def crash_at(self, robot: int, t_s: float) -> None:
        """Crash ``robot`` at simulated time ``t_s``."""
        self._at(t_s, lambda: self._stop(robot, "crash"))

    def remove_at(self, robot: int, t_s: float) -> None:
        """Lift ``robot`` off the table at simulated time ``t_s``."""
        self._at(t_s, lambda: self._stop(robot, "removed", remove=True))

    def _at(self, t_s: float, action: Callable[[], None]) -> None:
        delay = max(0.0, t_s - self.env.now)
        Timeout(self.env, delay).callbacks.append(lambda _e: action())

    def faulty_receiver(
        self, robot: int, *, drop_prob: float, delay_prob: float, delay_s: float
    ) -> None:
        """Make ``robot``'s receiver drop ``drop_prob`` of its receptions (counted as fault
        losses) and delay ``delay_prob`` of the others by ``U(0, delay_s)`` seconds."""
        self.faulty_receivers.add(robot)
        self._medium.set_extra_loss(robot, fault=drop_prob)
        if delay_prob > 0 and delay_s > 0:
            self._ports.delay(robot, delay_prob, delay_s, self.rng)
