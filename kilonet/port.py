"""Each robot's receive port: the one chain between the infrared medium and a robot's program.

As an ns-3 NetDevice sits between a channel and its node, a port takes what the medium delivers
to a robot (a message and its distance estimate, at the end of its airtime, after the medium's
losses and collisions) and hands it on through these stages, in this order:

1. **receiver fault** — a faulty receiver delays a share of its receptions by ``U(0, delay_s)``
   (:meth:`ReceivePorts.delay`); a late reception reaches only a robot still running.
2. **watchers** — listeners that see every reception the program is about to get
   (:meth:`ReceivePorts.watch`; :mod:`kilonet.testing` records runs with them).
3. **ranging** — with ``robot.rx_distance = "measurement"`` the estimate becomes the raw
   :class:`~kilonet.ranging.DistanceMeasurement` of the robot's calibration tables.
4. **reception mode** — ``callback``: the program's ``message_rx``; ``polled``: its receive
   buffer, which drops the oldest message on overflow (counted by the medium).

The ports alone write the entry each robot's deliveries go through (:attr:`ReceivePorts.entries`);
the medium only reads it, and is told through the callback it registers with
:meth:`ReceivePorts.on_reroute` when an entry changes, to rebuild its per-sender lists.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

from simpy.events import Timeout

from kilonet.ranging import measurement_for

if TYPE_CHECKING:
    from collections import deque

    import numpy as np

    from kilonet.clock import KernelEnvironment
    from kilonet.message import Message
    from kilonet.params import RobotParams
    from kilonet.ranging import CalibrationTables

__all__ = ["Handler", "ReceivePorts"]

#: A stage of the chain: ``handler(message, distance)``.
Handler = Callable[["Message", Any], None]


class ReceivePorts:
    """The receive ports of one simulation's robots.

    Parameters
    ----------
    params : RobotParams
        The run's ``robot`` section (``rx_mode``, ``rx_distance``).
    env : KernelEnvironment
        The run's clock (a faulty receiver's delays are scheduled on it).
    running : numpy.ndarray of bool
        Which robots run, one per robot (the world's; read when a delayed reception is due).
    calibration_tables : sequence of CalibrationTables
        Each robot's calibration (ranging to a raw measurement).
    """

    def __init__(
        self,
        params: RobotParams,
        env: KernelEnvironment,
        running: np.ndarray,
        calibration_tables: Sequence[CalibrationTables],
    ) -> None:
        n = len(running)
        self._params = params
        self._env = env
        self._running = running
        self._tables = calibration_tables
        #: What the medium calls to deliver to each robot; only this class writes it.
        self.entries: list[Handler] = [_drop] * n
        self._programs: list[Handler] = [_drop] * n
        self._watchers: list[list[Handler]] = [[] for _ in range(n)]
        self._delays: list[tuple[float, float, np.random.Generator] | None] = [None] * n
        self._stopped = [False] * n
        self._rerouted: Callable[[int | None], None] = _ignore

    def on_reroute(self, rerouted: Callable[[int | None], None]) -> None:
        """Call ``rerouted(robot)`` whenever ``robot``'s entry changes (``None``: every
        robot's did). The medium registers here to rebuild the handler lists it reads."""
        self._rerouted = rerouted

    # -- the stages ------------------------------------------------------------------------------
    def connect(
        self,
        message_rx: Sequence[Handler],
        buffers: Sequence[deque[tuple[Message, Any]]],
        count_overflow: Callable[[int], None],
    ) -> None:
        """Connect every robot's port to its program: its ``message_rx`` (callback mode) or
        its receive buffer (polled mode), which calls ``count_overflow(robot)`` for every
        message its overflow drops."""
        for i, (rx, buffer) in enumerate(zip(message_rx, buffers, strict=True)):
            self._programs[i] = self._ranging(i, self._mode(i, rx, buffer, count_overflow))
            self.entries[i] = self._compose(i)
        self._rerouted(None)

    def watch(self, robot: int, listener: Handler) -> None:
        """Call ``listener(message, distance)`` with every reception handed to ``robot``'s
        program, just before the program gets it: after the medium's losses and collisions
        and any receiver fault's delay, with the medium's distance estimate (before ranging)."""
        self._watchers[robot].append(listener)
        self._reroute(robot)

    def delay(
        self, robot: int, probability: float, delay_s: float, rng: np.random.Generator
    ) -> None:
        """Make ``robot``'s receiver delay ``probability`` of its receptions by ``U(0,
        delay_s)`` seconds, drawing from ``rng`` (a receiver fault)."""
        self._delays[robot] = (probability, delay_s, rng)
        self._reroute(robot)

    def stop(self, robot: int) -> None:
        """Close ``robot``'s port: it has stopped and hears nothing from now on."""
        self._stopped[robot] = True
        self._reroute(robot)

    # -- composing the chain -----------------------------------------------------------------
    def _reroute(self, robot: int) -> None:
        self.entries[robot] = self._compose(robot)
        self._rerouted(robot)

    def _compose(self, robot: int) -> Handler:
        """Robot ``robot``'s entry: its stages joined, an absent stage costing no call."""
        if self._stopped[robot]:
            return _drop
        program = self._programs[robot]
        watchers = tuple(self._watchers[robot])
        if watchers:
            inner = program

            def program(message: Message, distance: Any) -> None:
                for listener in watchers:
                    listener(message, distance)
                inner(message, distance)

        delay = self._delays[robot]
        if delay is None:
            return program
        probability, delay_s, rng = delay
        env, running = self._env, self._running

        def late(message: Message, distance: Any) -> None:
            if running[robot]:
                program(message, distance)

        def delaying(message: Message, distance: Any) -> None:
            if rng.random() < probability:
                Timeout(env, float(rng.uniform(0, delay_s))).callbacks.append(
                    lambda _e: late(message, distance)
                )
            else:
                late(message, distance)

        return delaying

    def _mode(
        self,
        robot: int,
        message_rx: Handler,
        buffer: deque[tuple[Message, Any]],
        count_overflow: Callable[[int], None],
    ) -> Handler:
        """The reception-mode stage: ``message_rx`` itself, or a push into ``buffer``."""
        if self._params.rx_mode != "polled":
            return message_rx
        size = buffer.maxlen

        def push(message: Message, distance: Any) -> None:
            if len(buffer) == size:
                count_overflow(robot)
            buffer.append((message, distance))

        return push

    def _ranging(self, robot: int, deliver: Handler) -> Handler:
        """The ranging stage: the estimate as it is, or as the robot's raw measurement."""
        if self._params.rx_distance == "estimate":
            return deliver
        tables = self._tables[robot]
        return lambda message, estimate_mm: deliver(message, measurement_for(estimate_mm, tables))


def _drop(message: Message, distance: Any) -> None:
    """Entry of a robot that has stopped or not been connected: the message reaches nobody."""


def _ignore(robot: int | None) -> None:
    """The reroute callback before a medium registers one."""
