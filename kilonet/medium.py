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
callbacks on pre-bound functions, no processes); receiver and handler lists precomputed per
sender; and the random part of every reception (distance estimate, loss and its cause) drawn by
NumPy in blocks of rows per sender ahead of time. Delivering a clean transmission is then one
C-level ``map`` over the sender's handlers; per-receiver delivery counts of such transmissions are
folded in from a per-sender count whenever the receiver lists change.
"""

from __future__ import annotations

import operator
from collections import deque
from collections.abc import Callable
from itertools import repeat
from typing import TYPE_CHECKING

import numpy as np

from kilonet.clock import Timer, push
from kilonet.message import KILOLIB, THESIS, Message, PayloadLimit
from kilonet.robot import Kilobot
from kilonet.visibility import visible_pairs

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = ["LOSS_CAUSES", "InfraredMedium", "RandomBlock"]

#: Causes a reception can be lost to, as counted per receiving robot.
LOSS_CAUSES = ("random", "collision", "overflow", "battery", "fault")

_BLOCK = 1 << 11


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

    def next(self) -> float:
        """The next draw."""
        if self._pos >= len(self._values):
            self._values = self._draw(_BLOCK).tolist()
            self._pos = 0
        value = self._values[self._pos]
        self._pos += 1
        return value


class _Transmission:
    """One message on the air and the fate of each of its receptions.

    ``estimates`` holds the distance estimate (mm) per receiver, ``losses`` a loss code per
    receiver (see :data:`_LOSS_CODES`) or ``None`` when nothing is lost; ``epoch`` tells whether
    receiver lists changed while the message was on the air. The object is also its own
    end-of-airtime event on the SimPy queue (``callbacks``, ``_ok``, ``_value``: see
    :mod:`kilonet.clock`), which saves an allocation per message.
    """

    __slots__ = (
        "_ok",
        "_value",
        "callbacks",
        "corrupted",
        "epoch",
        "estimates",
        "handlers",
        "losses",
        "message",
        "receivers",
        "sender",
    )

    def __init__(
        self,
        sender: int,
        message: Message,
        receivers: list[int],
        handlers: list[Callable[[Message, int], None]],
        estimates: bytes,
        losses: bytes | None,
        epoch: int,
        callbacks: list,
    ) -> None:
        self.sender = sender
        self.message = message
        self.receivers = receivers
        self.handlers = handlers
        self.estimates = estimates
        self.losses = losses
        self.epoch = epoch
        self.corrupted: set[int] | None = None
        self.callbacks = callbacks
        self._ok = True
        self._value = None  # step() reads it only for failed events; no self-reference cycle


#: Loss codes in an outcome row, by cause (0: delivered).
_RANDOM, _BATTERY, _FAULT = 1, 2, 3
_LOSS_CODES = {_RANDOM: "random", _BATTERY: "battery", _FAULT: "fault"}
_MAX_ROWS_PER_REFILL = 64


class InfraredMedium:
    """The shared infrared channel of one simulation.

    Parameters
    ----------
    sim : Simulation
        The simulation; the medium reads its environment, world, parameters, robots and the
        ``medium`` and ``ranging`` random streams.
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
        self._ranging = sim.params.ranging
        n = sim.n_robots
        self.n = n
        self._ids = list(range(n))  # one int object per robot, shared by every list

        self._medium_rng = sim.stream("medium")
        self._uniform = RandomBlock(self._medium_rng.random)
        self._ranging_rng = sim.stream("ranging")
        bias_sigma = self._ranging.bias_sigma_mm
        self.bias_mm = self._ranging_rng.normal(0.0, bias_sigma, n) if bias_sigma else np.zeros(n)

        # Receiver-side loss shares (battery, fault), per robot.
        self._loss_battery = np.zeros(n)
        self._loss_fault = np.zeros(n)
        # Per-robot channel state as Python lists: scalar access is what the hot path does.
        # Channel state per robot: until when it is busy (the latest reception to begin there,
        # or its own transmission; all messages share one airtime, so the latest ends last),
        # and that latest reception, to mark it on a collision.
        self._busy_until = [-np.inf] * n
        self._last_rx: list[_Transmission | None] = [None] * n
        self._any_extra_loss = False  # some receiver has a battery or fault loss share
        self._trace_messages = sim.params.trace.messages
        self._running = [True] * n
        robots = sim.robots
        self._message_tx = [r.message_tx for r in robots]
        # An empty message_tx_success() has no effect; not calling it saves a call per message.
        self._tx_success = [
            None
            if type(r).message_tx_success is Kilobot.message_tx_success
            else r.message_tx_success
            for r in robots
        ]
        self._range_factor = [1.0] * n
        self._handlers: list[Callable[[Message, int], None]] = [_drop] * n
        self._last_checked: list[Message | None] = [None] * n
        self._epoch = 0  # bumped whenever receiver lists change; in-flight messages then
        # take the careful delivery path
        self._sink: deque = deque(maxlen=0)

        self._counters = {
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
        self._lost_by_code = {
            code: self._counters[f"lost_{cause}"] for code, cause in _LOSS_CODES.items()
        }
        self._clean_tx = [0] * n  # fully delivered transmissions not yet folded into "received"
        self._offered = self._counters["offered"]
        self._sent = self._counters["sent"]
        self._bytes_sent = self._counters["bytes_sent"]
        self._backoffs = self._counters["backoffs"]
        self._message_bytes = [0] * n
        # One reusable queue entry per robot for its next transmit opportunity (a robot has at
        # most one pending), and one shared callback list for ends of airtime.
        self._offer_timers = [Timer(sim.env, self._offer, i) for i in range(n)]
        self._end_callbacks = [self._end_of_airtime]

        # Per-sender links at full range, and the derived lists the hot path reads.
        self._link_r: list[np.ndarray] = []
        self._link_d: list[np.ndarray] = []
        self._rx_r: list[list[int]] = [[] for _ in range(n)]
        self._rx_idx: list[np.ndarray] = [np.empty(0, dtype=np.intp)] * n
        self._rx_d: list[np.ndarray] = [np.empty(0)] * n
        self._rx_h: list[list[Callable[[Message, int], None]]] = [[] for _ in range(n)]
        # Outcomes drawn ahead per sender: row k of the block is its k-th next transmission.
        self._estimates: list[bytes] = [b""] * n  # distance estimate per receiver, mm
        self._losses: list[bytes] = [b""] * n  # loss code per receiver
        self._lossy_rows: list[list[bool] | None] = [None] * n  # None: no row has a loss
        self._row_next = [0] * n
        self._row_count = [0] * n
        self._refill_rows = [4] * n
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
        sender = np.concatenate([i, j])
        receiver = np.concatenate([j, i])
        dist = np.concatenate([d, d])
        keep = world.running[receiver]
        sender, receiver, dist = sender[keep], receiver[keep], dist[keep]
        order = np.lexsort((receiver, sender))
        sender, receiver, dist = sender[order], receiver[order], dist[order]
        bounds = np.searchsorted(sender, np.arange(self.n + 1))
        self._link_r = np.split(receiver, bounds[1:-1])
        self._link_d = np.split(dist, bounds[1:-1])
        self._fold_received()
        for s in range(self.n):
            self._derive(s)

    def _derive(self, s: int) -> None:
        """Rebuild sender ``s``'s receiver, distance and handler lists; drop its drawn rows."""
        self._fold_received(s)
        self._epoch += 1
        r, d = self._link_r[s], self._link_d[s]
        factor = self._range_factor[s]
        if factor < 1.0:
            near = d <= self.params.range_mm * factor
            r, d = r[near], d[near]
        self._rx_idx[s] = r
        self._rx_d[s] = d + self.bias_mm[r]
        ids = self._ids
        self._rx_r[s] = [ids[k] for k in r.tolist()]
        self._rx_h[s] = [self._handlers[k] for k in self._rx_r[s]]
        self._row_count[s] = self._row_next[s] = 0  # rows drawn for the old lists are void

    def _senders_reaching(self, robot: int) -> list[int]:
        """Senders whose receiver lists may contain ``robot`` (links are symmetric)."""
        return self._link_r[robot].tolist()

    def receivers_of(self, sender: int) -> list[int]:
        """Robots that currently hear ``sender`` (range, line of sight, battery range)."""
        return list(self._rx_r[sender])

    # -- degradation hooks (battery, faults) -------------------------------------------------
    def set_range_factor(self, robot: int, factor: float) -> None:
        """Scale the transmit range of ``robot`` (battery); ``1`` is the full range."""
        if factor != self._range_factor[robot]:
            self._range_factor[robot] = factor
            self._derive(robot)

    def set_extra_loss(
        self, robot: int, *, battery: float | None = None, fault: float | None = None
    ) -> None:
        """Set the receiver's extra loss shares from its battery and from a receiver fault."""
        if battery is not None:
            self._loss_battery[robot] = battery
        if fault is not None:
            self._loss_fault[robot] = fault
        self._any_extra_loss = bool(self._loss_battery.any() or self._loss_fault.any())
        for s in self._senders_reaching(robot):
            self._row_count[s] = self._row_next[s] = 0  # redraw with the new loss shares

    def set_handlers(self, handlers: list[Callable[[Message, int], None]]) -> None:
        """Route deliveries to every robot at once (``handlers[robot](message, distance_mm)``)."""
        self._handlers = list(handlers)
        for s in range(self.n):
            self._derive(s)

    def set_handler(self, robot: int, handler: Callable[[Message, int], None]) -> None:
        """Route deliveries to ``robot`` through ``handler(message, distance_mm)``."""
        self._handlers[robot] = handler
        for s in self._senders_reaching(robot):
            self._derive(s)

    def start(self, robot: int) -> None:
        """Schedule the first transmit opportunity of ``robot`` at ``U(0, tx_period_s)``."""
        self._schedule_offer(robot, self._uniform.next() * self._period)

    def _schedule_offer(self, robot: int, delay_s: float) -> None:
        self._offer_timers[robot].schedule(delay_s)

    # -- reception outcomes, drawn ahead in blocks ---------------------------------------------
    def _refill(self, s: int) -> None:
        """Draw the outcomes of the next transmissions of ``s``.

        Row k is the k-th next transmission: the distance estimate (whole mm, one byte) for
        every receiver, and a loss-code byte per receiver. Bytes rather than lists: slicing a
        row is cheap and the garbage collector never has to walk them.
        """
        receivers = self._rx_idx[s]
        # Draw few rows for a sender's first messages and more as it keeps sending, so short
        # runs do not draw what they never use.
        n_rows = self._refill_rows[s] = min(2 * self._refill_rows[s], _MAX_ROWS_PER_REFILL)
        shape = (n_rows, len(receivers))
        rg = self._ranging
        est = self._ranging_rng.standard_normal(shape)
        est *= rg.sigma_mm
        est += self._rx_d[s] + 0.5  # + 0.5, then truncation: rounding to whole mm
        np.clip(est, rg.min_mm, rg.max_mm + 0.5, out=est)
        self._estimates[s] = est.astype(np.uint8).tobytes()
        random_p = self.params.loss_prob
        if random_p > 0 or self._any_extra_loss:
            u = self._medium_rng.random(shape)
            to_battery = random_p + self._loss_battery[receivers]
            to_fault = to_battery + self._loss_fault[receivers]
            codes = np.zeros(shape, dtype=np.uint8)
            codes[u < to_fault] = _FAULT
            codes[u < to_battery] = _BATTERY
            codes[u < random_p] = _RANDOM
            self._lossy_rows[s] = codes.any(axis=1).tolist()
            self._losses[s] = codes.tobytes()
        else:
            self._lossy_rows[s] = None
        self._row_next[s] = 0
        self._row_count[s] = n_rows

    def _fold_received(self, sender: int | None = None) -> None:
        """Add the fully delivered transmissions of ``sender`` (all if None) to its receivers."""
        received = self._counters["received"]
        clean = self._clean_tx
        for s in range(self.n) if sender is None else (sender,):
            if clean[s]:
                for r in self._rx_r[s]:
                    received[r] += clean[s]
                clean[s] = 0

    @property
    def counters(self) -> dict[str, list[int]]:
        """Per-robot counters (lists indexed by robot): offered, sent, backoffs, bytes_sent,
        received, and lost_<cause> as a receiver for each cause in :data:`LOSS_CAUSES`."""
        self._fold_received()
        return self._counters

    # -- the hot path ------------------------------------------------------------------------
    def _offer(self, timer: Timer) -> None:
        s = timer._value
        if not self._running[s]:
            return
        now = self.env._now
        message = self._message_tx[s]()
        if message is None:
            delay = self._period + (2 * self._uniform.next() - 1) * self._jitter
        else:
            if message is not self._last_checked[s]:
                self.limit.check(message)
                self._last_checked[s] = message
                self._message_bytes[s] = message.size_bytes
            self._offered[s] += 1
            if self._csma and self._busy_until[s] > now:
                self._backoffs[s] += 1
                delay = self._uniform.next() * self._backoff_max
            else:
                self._transmit(s, message, now)
                delay = self._period + (2 * self._uniform.next() - 1) * self._jitter
        self._schedule_offer(s, delay)

    def _transmit(self, s: int, message: Message, now: float) -> None:
        k = self._row_next[s]
        if k == self._row_count[s]:
            self._refill(s)
            k = 0
        self._row_next[s] = k + 1
        receivers = self._rx_r[s]
        n = len(receivers)
        lossy = self._lossy_rows[s]
        tx = _Transmission(
            s,
            message,
            receivers,
            self._rx_h[s],
            self._estimates[s][k * n : k * n + n],
            self._losses[s][k * n : k * n + n] if lossy is not None and lossy[k] else None,
            self._epoch,
            self._end_callbacks,
        )
        busy = self._busy_until
        last = self._last_rx
        if busy[s] > now:  # half duplex: the sender's own reception in progress is ruined
            _corrupt(last[s], s)
        end = now + self.airtime_s
        clashes = None
        for r in receivers:
            if busy[r] > now:
                # Overlap at r: both receptions fail there. Earlier overlapping receptions at r
                # were marked when the second of them began, so only the latest needs marking.
                _corrupt(last[r], r)
                if clashes is None:
                    clashes = {r}
                else:
                    clashes.add(r)
            busy[r] = end
            last[r] = tx
        tx.corrupted = clashes
        # Half duplex the other way round: while s transmits, whatever starts arriving at s
        # overlaps its channel and is lost there.
        if end > busy[s]:
            busy[s] = end
        self._sent[s] += 1
        self._bytes_sent[s] += self._message_bytes[s]
        push(self.env, end, tx)
        success = self._tx_success[s]
        if success is not None:
            success()

    def _end_of_airtime(self, tx: _Transmission) -> None:
        # Called by Environment.step with the event, which is the transmission itself.
        message = tx.message
        if tx.losses is None and tx.corrupted is None and tx.epoch == self._epoch:
            self._sink.extend(map(operator.call, tx.handlers, repeat(message), tx.estimates))
            self._clean_tx[tx.sender] += 1
            if self._trace_messages:
                n = len(tx.receivers)
                self.sim.trace.message(self.env._now, tx.sender, n, n)
            return
        corrupted = tx.corrupted or ()
        counters = self._counters
        received = counters["received"]
        lost_collision = counters["lost_collision"]
        lost_by_code = self._lost_by_code
        stale = tx.epoch != self._epoch
        running = self._running
        losses = tx.losses or repeat(0)
        delivered = 0
        for r, handler, estimate, loss in zip(
            tx.receivers, tx.handlers, tx.estimates, losses, strict=False
        ):
            if r in corrupted:
                lost_collision[r] += 1
            elif loss:
                lost_by_code[loss][r] += 1
            elif stale and not running[r]:
                continue  # the receiver stopped while the message was on the air
            else:
                received[r] += 1
                delivered += 1
                handler(message, estimate)
        if self._trace_messages:
            self.sim.trace.message(self.env._now, tx.sender, len(tx.receivers), delivered)

    def forget_receiver(self, robot: int) -> None:
        """Take a stopped robot out of the topology (and so of the messages still on the air)."""
        self._handlers[robot] = _drop
        self._running[robot] = False
        self.rebuild_topology()

    def count_overflow(self, robot: int) -> None:
        """Count a message dropped from ``robot``'s full receive buffer."""
        self._counters["lost_overflow"][robot] += 1


def _corrupt(tx: _Transmission | None, receiver: int) -> None:
    """Mark the reception of ``tx`` at ``receiver`` as failing its CRC."""
    if tx is None:
        return
    if tx.corrupted is None:
        tx.corrupted = {receiver}
    else:
        tx.corrupted.add(receiver)


def _drop(message: Message, distance_mm: int) -> None:
    """Handler of a robot that has stopped or not started: the message reaches nobody."""
