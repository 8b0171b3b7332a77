"""The infrared broadcast channel: the simulator's hot path.

Model (all parameters in :class:`kilonet.params.MediumParams` and ``RobotParams``):

* **Range and line of sight.** A transmission reaches every present, running robot within
  ``range_mm`` (centre to centre) whose line of sight to the sender no third disc blocks. The
  receiver sets are precomputed (``scipy.spatial.cKDTree``) and rebuilt only when a robot moves,
  stops or is removed, so a static swarm never pays for geometry again.
* **Offers.** Every robot gets a transmit opportunity every ``tx_period_s ± U(tx_jitter_s)``; the
  first one falls at ``U(0, tx_period_s)`` so robots are not synchronised.
* **CSMA/CA.** A robot that senses a carrier (some reception in progress at it) backs off
  ``U(0, backoff_max_s)`` and tries again. Carrier sense only hears what reaches the robot, so
  hidden terminals exist.
* **Airtime and collisions.** A message occupies the channel for its airtime (bits / bitrate).
  Two receptions that overlap in time at a receiver corrupt each other *there*; a robot that
  starts transmitting while receiving ruins that reception (half duplex). Corrupted messages
  fail the CRC and are never delivered.
* **Loss.** Each clean reception is lost independently with ``loss_prob``, plus the receiver's
  battery and fault shares; each loss is counted by cause.
* **Distance.** Each delivery carries ``round(true distance + receiver bias + N(0, sigma))``,
  clipped to ``[min_mm, max_mm]`` (kilolib's uint8 estimate).
* **Receive modes.** ``callback``: ``message_rx`` is called on arrival. ``polled``: the message
  joins a buffer of ``rx_buffer`` messages that drops the oldest on overflow.

Why it is fast: two SimPy events per transmission (the offer and the end of airtime, both
callbacks on pre-bound methods, no processes), precomputed receiver lists, and random numbers
drawn from NumPy in blocks, so the per-delivery work is a few list look-ups and one call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from simpy.events import Timeout

from kilonet.message import KILOLIB, THESIS, Message, PayloadLimit
from kilonet.visibility import visible_pairs

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = ["LOSS_CAUSES", "InfraredMedium", "RandomBlock"]

#: Causes a reception can be lost to, as counted per receiving robot.
LOSS_CAUSES = ("random", "collision", "overflow", "battery", "fault")

_BLOCK = 1 << 15


class RandomBlock:
    """Random draws from a Generator, fetched in blocks and served one at a time.

    Drawing one float at a time from NumPy costs about a microsecond; serving it from a
    pre-drawn Python list costs a few tens of nanoseconds. The sequence is the generator's own,
    so runs stay reproducible.
    """

    __slots__ = ("_draw", "_pos", "_values")

    def __init__(self, draw: Callable[[int], np.ndarray]) -> None:
        self._draw = draw
        self._values: list[float] = []
        self._pos = 0

    def take(self, k: int) -> list[float]:
        """The next ``k`` draws as a list (``k`` at most the block size)."""
        if self._pos + k > len(self._values):
            self._values = self._values[self._pos :] + self._draw(_BLOCK).tolist()
            self._pos = 0
        out = self._values[self._pos : self._pos + k]
        self._pos += k
        return out

    def next(self) -> float:
        """The next draw."""
        if self._pos >= len(self._values):
            self._values = self._draw(_BLOCK).tolist()
            self._pos = 0
        value = self._values[self._pos]
        self._pos += 1
        return value


class _Transmission:
    """One message on the air: who sent it, who hears it, and which receptions collided."""

    __slots__ = ("corrupted", "dists", "message", "receivers", "sender")

    def __init__(self, sender: int, message: Message, receivers: list, dists: list) -> None:
        self.sender = sender
        self.message = message
        self.receivers = receivers
        self.dists = dists
        self.corrupted: set[int] | None = None


class InfraredMedium:
    """The shared infrared channel of one simulation.

    Parameters
    ----------
    sim : Simulation
        The simulation; the medium reads its environment, world, parameters, robots, trace and
        the ``medium`` and ``ranging`` random streams.
    """

    def __init__(self, sim: Simulation) -> None:
        self.sim = sim
        self.env = sim.env
        p = sim.params.medium
        self.params = p
        self.limit: PayloadLimit = KILOLIB if p.message_format == "kilolib" else THESIS
        self.airtime_s = p.airtime_s or self.limit.air_bytes * 8 / p.bitrate_bps
        rp = sim.params.robot
        self._period = rp.tx_period_s
        self._jitter = rp.tx_jitter_s
        self._csma = p.csma
        self._backoff_max = p.backoff_max_s
        rg = sim.params.ranging
        self._min_mm, self._max_mm = rg.min_mm, rg.max_mm
        n = sim.n_robots
        self.n = n

        self._uniform = RandomBlock(sim.stream("medium").random)
        ranging = sim.stream("ranging")
        sigma = rg.sigma_mm
        self._noise = RandomBlock(lambda k: sigma * ranging.standard_normal(k) + 0.5)
        self.bias_mm = ranging.normal(0.0, rg.bias_sigma_mm, n) if rg.bias_sigma_mm else np.zeros(n)

        # Per-robot state as Python lists: scalar access is what the hot path does.
        self._busy_until = [0.0] * n
        self._range_factor = [1.0] * n
        self._loss_battery = [0.0] * n
        self._loss_fault = [0.0] * n
        self._loss_total = [p.loss_prob] * n
        self._any_loss = p.loss_prob > 0
        self._handlers: list[Callable[[Message, int], None]] = [_drop] * n
        self._last_checked: list[Message | None] = [None] * n
        self._active: dict[int, _Transmission] = {}
        self._last_rx: list[_Transmission | None] = [None] * n  # latest reception at each robot

        self.counters = {
            name: [0] * n
            for name in (
                "offered",
                "sent",
                "backoffs",
                "bytes_sent",
                "received",
                *(f"lost_{c}" for c in LOSS_CAUSES),
            )
        }
        self._full_r: list[list[int]] = [[] for _ in range(n)]
        self._full_d: list[list[float]] = [[] for _ in range(n)]
        self._rx_r: list[list[int]] = [[] for _ in range(n)]
        self._rx_d: list[list[float]] = [[] for _ in range(n)]
        self._tx_timer = [self._make_tx_callback(i) for i in range(n)]
        self.rebuild_topology()

    # -- topology ----------------------------------------------------------------------------
    def rebuild_topology(self) -> None:
        """Recompute who hears whom from the world's present positions and running robots."""
        world = self.sim.world
        i, j, d = visible_pairs(
            world.positions_mm,
            self.params.range_mm,
            radius_mm=world.radius_mm,
            line_of_sight=self.params.line_of_sight,
            present=world.present,
        )
        running = world.running
        full_r: list[list[int]] = [[] for _ in range(self.n)]
        full_d: list[list[float]] = [[] for _ in range(self.n)]
        bias = self.bias_mm
        for a, b, dist in zip(i.tolist(), j.tolist(), d.tolist(), strict=True):
            if running[b]:
                full_r[a].append(b)
                full_d[a].append(dist + bias[b])
            if running[a]:
                full_r[b].append(a)
                full_d[b].append(dist + bias[a])
        self._full_r, self._full_d = full_r, full_d
        self._true_d = {}
        for a, b, dist in zip(i.tolist(), j.tolist(), d.tolist(), strict=True):
            self._true_d[a, b] = self._true_d[b, a] = dist
        for s in range(self.n):
            self._apply_range(s)

    def _apply_range(self, s: int) -> None:
        factor = self._range_factor[s]
        if factor >= 1.0:
            self._rx_r[s], self._rx_d[s] = self._full_r[s], self._full_d[s]
            return
        limit = self.params.range_mm * factor
        keep = [
            k for k, r in enumerate(self._full_r[s]) if self._true_d[s, r] <= limit
        ]
        self._rx_r[s] = [self._full_r[s][k] for k in keep]
        self._rx_d[s] = [self._full_d[s][k] for k in keep]

    def receivers_of(self, sender: int) -> list[int]:
        """Robots that currently hear ``sender`` (range, line of sight, battery range)."""
        return list(self._rx_r[sender])

    # -- degradation hooks (battery, faults) -------------------------------------------------
    def set_range_factor(self, robot: int, factor: float) -> None:
        """Scale the transmit range of ``robot`` (battery); ``1`` is the full range."""
        if factor != self._range_factor[robot]:
            self._range_factor[robot] = factor
            self._apply_range(robot)

    def set_extra_loss(
        self, robot: int, *, battery: float | None = None, fault: float | None = None
    ) -> None:
        """Set the receiver's extra loss shares from its battery and from a receiver fault."""
        if battery is not None:
            self._loss_battery[robot] = battery
        if fault is not None:
            self._loss_fault[robot] = fault
        total = self.params.loss_prob + self._loss_battery[robot] + self._loss_fault[robot]
        self._loss_total[robot] = total
        if total > 0:
            self._any_loss = True

    def set_handler(self, robot: int, handler: Callable[[Message, int], None]) -> None:
        """Route deliveries to ``robot`` through ``handler(message, distance_mm)``."""
        self._handlers[robot] = handler

    def start(self, robot: int) -> None:
        """Schedule the first transmit opportunity of ``robot`` at ``U(0, tx_period_s)``."""
        Timeout(self.env, self._uniform.next() * self._period).callbacks.append(
            self._tx_timer[robot]
        )

    # -- the hot path ------------------------------------------------------------------------
    def _make_tx_callback(self, i: int) -> Callable[[object], None]:
        return lambda _event: self._offer(i)

    def _offer(self, s: int) -> None:
        sim = self.sim
        if not sim.world.running[s]:
            return
        env = self.env
        now = env.now
        message = sim.robots[s].message_tx()
        counters = self.counters
        if message is None:
            delay = self._period + (2 * self._uniform.next() - 1) * self._jitter
        else:
            if message is not self._last_checked[s]:
                self.limit.check(message)
                self._last_checked[s] = message
            counters["offered"][s] += 1
            if self._csma and self._busy_until[s] > now:
                counters["backoffs"][s] += 1
                delay = self._uniform.next() * self._backoff_max
            else:
                self._transmit(s, message, now)
                delay = self._period + (2 * self._uniform.next() - 1) * self._jitter
        Timeout(env, delay).callbacks.append(self._tx_timer[s])

    def _transmit(self, s: int, message: Message, now: float) -> None:
        busy = self._busy_until
        last = self._last_rx
        receivers = self._rx_r[s]
        tx = _Transmission(s, message, receivers, self._rx_d[s])
        end = now + self.airtime_s
        if busy[s] > now:  # half duplex: the sender's own reception in progress is ruined
            _corrupt(last[s], s)
        busy[s] = end
        for r in receivers:
            if busy[r] > now:
                # Overlap at r. Earlier overlapping receptions at r were already marked when
                # the second of them began, so only the latest one needs marking now.
                _corrupt(last[r], r)
                _corrupt(tx, r)
            busy[r] = end
            last[r] = tx
        self._active[id(tx)] = tx
        counters = self.counters
        counters["sent"][s] += 1
        counters["bytes_sent"][s] += message.size_bytes
        Timeout(self.env, self.airtime_s, tx).callbacks.append(self._end_of_airtime)
        self.sim.robots[s].message_tx_success()

    def _end_of_airtime(self, event: Timeout) -> None:
        tx: _Transmission = event._value
        del self._active[id(tx)]
        message = tx.message
        receivers = tx.receivers
        # Distance noise for every receiver, already scaled by sigma and shifted by 0.5 so
        # that int() rounds to whole millimetres as kilolib reports them.
        noise = self._noise.take(len(receivers))
        received = self.counters["received"]
        handlers = self._handlers
        lo, hi = self._min_mm, self._max_mm
        if tx.corrupted is None and not self._any_loss:
            for r, d, z in zip(receivers, tx.dists, noise, strict=True):
                est = int(d + z)
                if est > hi:
                    est = hi
                elif est < lo:
                    est = lo
                received[r] += 1
                handlers[r](message, est)
            return
        corrupted = tx.corrupted or ()
        lost_collision = self.counters["lost_collision"]
        loss = self._loss_total
        uniform = self._uniform.next
        for r, d, z in zip(receivers, tx.dists, noise, strict=True):
            if r in corrupted:
                lost_collision[r] += 1
                continue
            if loss[r] > 0.0:
                u = uniform()
                if u < loss[r]:
                    self._count_loss(r, u)
                    continue
            est = int(d + z)
            if est > hi:
                est = hi
            elif est < lo:
                est = lo
            received[r] += 1
            handlers[r](message, est)

    def _count_loss(self, r: int, u: float) -> None:
        if u < self.params.loss_prob:
            cause = "random"
        elif u < self.params.loss_prob + self._loss_battery[r]:
            cause = "battery"
        else:
            cause = "fault"
        self.counters[f"lost_{cause}"][r] += 1

    def forget_receiver(self, robot: int) -> None:
        """Take a stopped robot out of the receptions still on the air and of the topology."""
        for tx in self._active.values():
            if robot in tx.receivers:
                keep = [k for k, r in enumerate(tx.receivers) if r != robot]
                tx.receivers = [tx.receivers[k] for k in keep]
                tx.dists = [tx.dists[k] for k in keep]
        self._handlers[robot] = _drop
        self.rebuild_topology()

    def count_overflow(self, robot: int) -> None:
        """Count a message dropped from ``robot``'s full receive buffer."""
        self.counters["lost_overflow"][robot] += 1


def _corrupt(tx: _Transmission | None, receiver: int) -> None:
    """Mark the reception of ``tx`` at ``receiver`` as failing its CRC."""
    if tx is None:
        return
    if tx.corrupted is None:
        tx.corrupted = {receiver}
    else:
        tx.corrupted.add(receiver)


def _drop(message: Message, distance_mm: int) -> None:
    """Handler of a robot that has not started: the message reaches nobody."""
