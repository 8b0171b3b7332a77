"""The infrared broadcast channel: the simulator's hot path, composed of four documented parts.

* **Links** (:class:`kilonet.visibility.LinkModel`): who hears whom, from true positions, range
  and occlusion; recomputed only when a robot moves, stops or is removed, so a static swarm
  never pays for geometry again.
* **Reception model** (:class:`kilonet.reception.ReceptionModel`): what becomes of each clean
  reception, its distance estimate or its loss by cause; drawn ahead in blocks per sender.
* **Channel** (:class:`kilonet.mac.Channel`): carrier sense and collisions, per receiver.
* **Counters** (:class:`kilonet.counters.MediumCounters`): per-robot counts by cause.

The medium itself is the event flow that joins them, with kilolib's transmit semantics:

* **Offers.** Every robot gets a transmit opportunity every ``robot.tx_period_s ±
  U(robot.tx_jitter_s)`` of *its own* clock (kilolib v2: ``kilo_tx_period`` = 3906 timer counts,
  0.5 s; the thesis's library: 0.2 s); the first falls at ``U(0, period)``, after the robot's
  ``setup()`` returned.
* **Carrier sense first.** At an opportunity a robot that senses a carrier (a reception in
  progress at it) does not call ``message_tx()`` at all and tries again after ``U(0,
  medium.backoff_max_s)`` of its clock (kilolib: at a later timer interrupt, at most a tick).
  Otherwise it calls ``message_tx()``; ``None`` means nothing to send, and it is asked again at
  its next tick (``robot.tx_retry = "tick"``, kilolib) or its next period (``"period"``).
* **Airtime.** A message occupies the channel for ``bits / medium.bitrate_bps``; every
  reception that overlaps another at a receiver is corrupted there.
* **CRC.** A message whose ``crc`` is wrong goes on the air (it occupies the channel and
  collides) but every receiver drops it, counted as ``lost_crc``.
* **Delivery.** At the end of the airtime each reception that is neither lost nor collided
  goes to its receiver's port (:mod:`kilonet.port`), which owns the rest of the way to the
  program: a receiver fault's delay, watchers, ranging and the receive mode (``callback``:
  ``message_rx``; ``polled``: a buffer of ``robot.rx_buffer`` messages that drops the oldest).
  The medium calls each robot's ``ports.entries[robot]`` and never writes it.

Why it is fast: two SimPy events per transmission (the offer and the end of airtime, both
callbacks on pre-bound functions, no processes); receiver and handler lists precomputed per
sender; the random part of every reception drawn by NumPy in blocks of rows per sender ahead of
time. Delivering a clean transmission is then one C-level ``map`` over the sender's handlers;
per-receiver delivery counts of such transmissions are folded in from a per-sender count.
"""

from __future__ import annotations

import operator
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from itertools import chain, compress, repeat
from typing import TYPE_CHECKING

import numpy as np

from kilonet.clock import Timer
from kilonet.counters import LOSS_CAUSES, MediumCounters
from kilonet.mac import Channel
from kilonet.message import LIMITS, Message, PayloadLimit
from kilonet.radio import MIN_RECEPTION, reception_probability
from kilonet.reception import CAUSES, LossShares, ReceptionModel
from kilonet.visibility import LinkModel

if TYPE_CHECKING:
    import networkx as nx

    from kilonet.clock import KernelEnvironment, RobotClocks
    from kilonet.params import MediumParams, RobotParams
    from kilonet.port import ReceivePorts
    from kilonet.radio import Transceivers
    from kilonet.trace import Trace
    from kilonet.world import World

__all__ = ["LOSS_CAUSES", "InfraredMedium", "RandomBlock", "directed_links"]

_BLOCK = 1 << 11
_MAX_ROWS_PER_REFILL = 64
_CRC = max(CAUSES) + 1  # the loss code of a reception dropped for a wrong CRC
_CODE_CAUSE = {**CAUSES, _CRC: "crc"}
_CAUSE_CODE = {cause: code for code, cause in _CODE_CAUSE.items()}
#: Least ``medium.backoff_max_s`` (s): one count of kilolib's 8 MHz / 1024 = 7,812.5 Hz timer,
#: the shortest wait its ``OCR0A = rand() & 0xFF`` retry can make (its longest: 255 counts,
#: 32.6 ms); the parameter's lower bound.
BACKOFF_MAX_FLOOR_S = 1 / 7812.5


def directed_links(
    link_model: LinkModel,
    radio: Transceivers,
    positions_mm: np.ndarray,
    present: np.ndarray | None = None,
    running: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every directed link among the ``present`` robots at ``positions_mm`` (mm) to a
    ``running`` receiver (default: all), as the medium builds its receiver lists: ``sender``,
    ``receiver`` (sorted by sender, then receiver), true ``distance_mm``, ``reach_mm`` (the
    radio's reach of the link, shortened by each body on its line of sight under ``"graded"``
    occlusion) and the occlusion's ``loss`` share. A link's reception probability is
    :func:`kilonet.radio.reception_probability` of its distance and reach; the medium drops
    links below :data:`kilonet.radio.MIN_RECEPTION`."""
    links = link_model.links(positions_mm, present)
    sender = np.concatenate([links.i, links.j])
    receiver = np.concatenate([links.j, links.i])
    dist = np.concatenate([links.distance_mm, links.distance_mm])
    loss = np.concatenate([links.loss, links.loss])
    bodies = np.concatenate([links.bodies, links.bodies])
    if running is not None:
        keep = running[receiver]
        sender, receiver, dist, loss = sender[keep], receiver[keep], dist[keep], loss[keep]
        bodies = bodies[keep]
    order = np.lexsort((receiver, sender))
    sender, receiver, dist, loss = sender[order], receiver[order], dist[order], loss[order]
    reach = radio.link_reach_mm(sender, receiver)
    if link_model.occlusion == "graded":  # each body crossed shortens the reach
        reach = reach * link_model.range_factor ** bodies[order]
    return sender, receiver, dist, reach, loss


class RandomBlock:
    """Random draws from a Generator, fetched in blocks and served one at a time.

    Drawing one float at a time from NumPy costs about a microsecond; serving it from a
    pre-drawn Python list costs a few tens of nanoseconds. The sequence is the generator's own,
    and a block is drawn only when the previous one is used up (the generator may serve other
    draws in between), so runs stay reproducible. Iterating it gives the same draws through
    one C-level ``next()`` each, without a Python call: the medium's hot path reads it so.

    Examples
    --------
    >>> rng = np.random.default_rng(5)
    >>> block = RandomBlock(np.random.default_rng(5).random)
    >>> [block.next(), next(iter(block))] == rng.random(2).tolist()
    True
    """

    __slots__ = ("_draws",)

    def __init__(self, draw: Callable[[int], np.ndarray]) -> None:
        # iter(f, None) calls f for each block (never None); chain takes the next block only
        # when a draw is asked for after the last one was served.
        self._draws = chain.from_iterable(iter(lambda: draw(_BLOCK).tolist(), None))

    def next(self) -> float:
        """The next draw."""
        return next(self._draws)

    def __iter__(self) -> Iterator[float]:
        """The draws from the next on, shared with :meth:`next` (one stream)."""
        return self._draws


class _Transmission:
    """One message on the air and the fate of each of its receptions.

    ``estimates`` holds the distance estimate (mm) per receiver, ``losses`` a loss code per
    receiver or ``None`` when nothing is lost, ``lost_at`` the positions in ``receivers`` whose
    code is not 0 (``None`` with ``losses``); ``epoch`` tells whether receiver lists changed
    while the message was on the air. The object is also its own end-of-airtime event on the
    kernel's queue (``callbacks``, ``ok``, ``defused``, ``value``: see :mod:`kilonet.clock`),
    which saves an allocation per message.
    """

    __slots__ = (
        "callbacks",
        "corrupted",
        "epoch",
        "estimates",
        "handlers",
        "losses",
        "lost_at",
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
        lost_at: Sequence[int] | None,
        epoch: int,
        callbacks: list,
    ) -> None:
        self.sender = sender
        self.message = message
        self.receivers = receivers
        self.handlers = handlers
        self.estimates = estimates
        self.losses = losses
        self.lost_at = lost_at
        self.epoch = epoch
        self.corrupted: set[int] | None = None
        self.callbacks = callbacks

    ok = True  # the kernel queue's event protocol: a transmission never fails
    defused = False
    value = None


class InfraredMedium:
    """The shared infrared channel of one simulation.

    Parameters
    ----------
    params : MediumParams
        The run's ``medium`` section.
    robot : RobotParams
        The run's ``robot`` section (transmit period, jitter and retry, the tick rate).
    env : KernelEnvironment
        The run's clock and queue.
    world : World
        Where the robots are and which run (the links follow them).
    clocks : RobotClocks
        Each robot's oscillator (its transmit timing runs on it).
    radio : Transceivers
        Each robot's emitter strength and receiver sensitivity.
    message_tx : sequence of callable
        Per robot, what it calls at a transmit opportunity (the program's ``message_tx``):
        a :class:`~kilonet.message.Message` or ``None``.
    tx_success : sequence of callable or None
        Per robot, what it calls after a message went on the air (the program's
        ``message_tx_success``), or ``None`` where that has no effect (saves a call per
        message).
    ports : ReceivePorts
        The robots' receive ports: a delivery to robot ``r`` is a call of
        ``ports.entries[r](message, distance_mm)``.
    reception : ReceptionModel
        Distance estimates and losses of the receptions.
    rng : numpy.random.Generator
        The run's ``medium`` stream: transmit phases and back-offs.
    trace : Trace
        Where messages are recorded with ``trace.messages``.
    links : LinkModel, optional
        Range and occlusion (default: from ``params``).
    trace_messages : bool
        Record every transmission in ``trace`` (``trace.messages``).
    """

    def __init__(
        self,
        params: MediumParams,
        robot: RobotParams,
        env: KernelEnvironment,
        world: World,
        clocks: RobotClocks,
        radio: Transceivers,
        message_tx: Sequence[Callable[[], Message | None]],
        tx_success: Sequence[Callable[[], None] | None],
        ports: ReceivePorts,
        reception: ReceptionModel,
        rng: np.random.Generator,
        trace: Trace,
        *,
        links: LinkModel | None = None,
        trace_messages: bool = False,
    ) -> None:
        self.env = env
        p = params
        self.params = p
        self._robot_params = robot
        self._world = world
        self._trace = trace
        n = len(message_tx)
        self.n = n
        self.radio = radio
        self._edge_mm = self.radio.reach.edge_mm
        self.link_model = links or LinkModel.from_params(
            p, world.radius_mm, range_mm=self.radio.max_distance_mm
        )
        self.reception = reception
        # One channel slot per robot and one more, the last, for senders outside the swarm
        # (a test's scripted messages, see hear_from_outside()): it is a sender's slot only, never
        # a receiver's.
        self.channel = Channel(n + 1, p.sense_delay_s)
        self._outside = n
        self._busy_until = self.channel.busy_until
        self._sensed_from = self.channel.sensed_from
        self.counts = MediumCounters(n)
        self._lost_by_code = {code: self.counts.lost(c) for code, c in _CODE_CAUSE.items()}
        self.limit: PayloadLimit = LIMITS[p.message_format]
        self.airtime_s = p.airtime_s or self.limit.air_bytes * 8 / p.bitrate_bps + p.preamble_s

        # Timing per robot in true seconds: each robot's clock runs at its own rate.
        rp = robot
        factor = self._factor = clocks.factor.tolist()
        self._period = [rp.tx_period_s / f for f in factor]
        self._jitter = [rp.tx_jitter_s / f for f in factor]
        # never below kilolib's least wait (parameters forced past validation): a back-off
        # near 0 would re-sense a busy channel without end
        self._backoff = [max(p.backoff_max_s, BACKOFF_MAX_FLOOR_S) / f for f in factor]
        self._tick = [1.0 / (rp.ticks_per_s * f) for f in factor]
        self._retry_tick = rp.tx_retry == "tick"
        self._csma = p.csma
        self._uniform = iter(RandomBlock(rng.random))  # next(self._uniform): a draw in [0, 1)
        self._ids = list(range(n))  # one int object per robot, shared by every list

        # Receiver-side loss shares (battery, fault), per robot.
        self._loss_battery = np.zeros(n)
        self._loss_fault = np.zeros(n)
        self._trace_messages = trace_messages
        self._running = [True] * n
        self._message_tx = list(message_tx)
        self._tx_success = list(tx_success)
        self._range_factor = [1.0] * n
        self._entries = ports.entries  # read only: the ports write it and tell _reroute
        self._last_checked: list[Message | None] = [None] * n
        self._crc_ok = [True] * n
        self._message_bytes = [0] * n
        self._epoch = 0  # bumped whenever receiver lists change; in-flight messages then
        # take the careful delivery path
        self._sink: deque = deque(maxlen=0)
        # One reusable queue entry per robot for its next transmit opportunity (a robot has at
        # most one pending), and one shared callback list for ends of airtime.
        self._offer_timers = [Timer(env, self._offer, i) for i in range(n)]
        self._end_callbacks = [self._end_of_airtime]

        # Per-sender links at full range (receiver, distance, reach, occlusion loss), and the
        # derived lists the hot path reads.
        self._link_r: list[np.ndarray] = []
        self._link_d: list[np.ndarray] = []
        self._link_reach: list[np.ndarray] = []
        self._link_loss: list[np.ndarray] = []
        self._rx_r: list[list[int]] = [[] for _ in range(n)]
        self._rx_at: list[dict[int, int]] = [{} for _ in range(n)]  # receiver -> its position
        self._rx_idx: list[np.ndarray] = [np.empty(0, dtype=np.intp)] * n
        self._rx_d: list[np.ndarray] = [np.empty(0)] * n
        self._rx_loss: list[np.ndarray] = [np.empty(0)] * n
        self._rx_signal: list[np.ndarray] = [np.empty(0)] * n
        self._rx_h: list[list[Callable[[Message, int], None]]] = [[] for _ in range(n)]
        # Outcomes drawn ahead per sender: row k of the block is its k-th next transmission.
        self._estimates: list[bytes] = [b""] * n  # distance estimate per receiver, mm
        self._losses: list[bytes] = [b""] * n  # loss code per receiver
        # Per row, the positions of the receptions it loses ([] for none); None: no row has a loss
        self._lossy_rows: list[list[list[int]] | None] = [None] * n
        self._row_next = [0] * n
        self._row_count = [0] * n
        self._refill_rows = [4] * n
        # Each sender's loss shares while its receiver list and their shares stand (the
        # reception model may keep what it derives from them while they are the same object).
        self._shares: list[LossShares | None] = [None] * n
        # (positions, present, running) at the last build of the links, copies
        self._built: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self.rebuild_topology()
        ports.on_reroute(self._reroute)

    # -- topology ----------------------------------------------------------------------------
    def rebuild_topology(self) -> None:
        """Recompute who hears whom from the world's present positions and running robots;
        a sender whose links stay as they were keeps its lists and the outcomes drawn ahead
        for them (a moving robot changes only its own links and its neighbours').

        When only positions changed since the last build and links ignore bodies in between
        (``medium.occlusion = "none"``), only the links of the robots that moved are
        recomputed (:meth:`_rebuild_moved`), the same links a full build gives: a moving swarm
        would otherwise pay for every pair at every motion step."""
        world = self._world
        built = self._built
        if (
            built is None
            or self.link_model.occlusion != "none"
            or not np.array_equal(built[1], world.present)
            or not np.array_equal(built[2], world.running)
        ):
            self._rebuild_all()
        else:
            moved = np.flatnonzero((world.positions_mm != built[0]).any(axis=1))
            if len(moved):
                self._rebuild_moved(moved, built[0])
        self._built = (world.positions_mm.copy(), world.present.copy(), world.running.copy())

    def _rebuild_all(self) -> None:
        """Every sender's links from scratch (see :meth:`rebuild_topology`)."""
        world = self._world
        sender, receiver, dist, reach, loss = directed_links(
            self.link_model, self.radio, world.positions_mm, world.present, world.running
        )
        cuts = np.searchsorted(sender, np.arange(self.n + 1))[1:-1]
        links = [np.split(a, cuts) for a in (receiver, dist, reach, loss)]
        before = self._link_r, self._link_d, self._link_reach, self._link_loss
        self._link_r, self._link_d, self._link_reach, self._link_loss = links
        if not before[0]:  # the first build
            for s in range(self.n):
                self._derive(s)
            return
        for s in range(self.n):
            if not all(
                np.array_equal(new[s], old[s]) for new, old in zip(links, before, strict=True)
            ):
                # A sender whose links change at every step of a robot's motion uses one row
                # of a block: draw blocks from small again.
                self._refill_rows[s] = 1
                self._derive(s)

    def _rebuild_moved(self, moved: np.ndarray, was_mm: np.ndarray) -> None:
        """The links of the robots in ``moved`` (positions changed since ``was_mm``, nothing
        else), and of the robots in range of them before or now, as :meth:`_rebuild_all` would
        build them: a link is a pair of present robots whose squared distance is at most the
        squared range (the k-d tree's test), its distance the ``hypot`` of their difference,
        its reach from the radio, and no occlusion loss; a sender lists its running receivers
        in ascending order."""
        world = self._world
        pos, present, running = world.positions_mm, world.present, world.running
        r2 = self.link_model.range_mm**2
        now = pos[None, :, :] - pos[moved][:, None, :]  # (moved, robot, xy)
        was = was_mm[None, :, :] - was_mm[moved][:, None, :]
        near = now[..., 0] * now[..., 0] + now[..., 1] * now[..., 1] <= r2
        near &= present[None, :] & present[moved][:, None]
        near[np.arange(len(moved)), moved] = False
        was_near = was[..., 0] * was[..., 0] + was[..., 1] * was[..., 1] <= r2
        is_moved = np.zeros(self.n, dtype=bool)
        is_moved[moved] = True
        row_of = {m: k for k, m in enumerate(moved.tolist())}
        affected = np.flatnonzero((near | was_near).any(axis=0) | is_moved)
        link_r, link_d, link_reach, link_loss = (
            self._link_r,
            self._link_d,
            self._link_reach,
            self._link_loss,
        )
        for s in affected.tolist():
            if is_moved[s]:
                k = row_of[s]
                receivers = np.flatnonzero(near[k] & running)
                dist = np.hypot(now[k, receivers, 0], now[k, receivers, 1])
            else:
                old_r = link_r[s]
                stay = ~is_moved[old_r]
                hears = near[:, s] & running[moved]
                receivers = np.concatenate([old_r[stay], moved[hears]])
                dist = np.concatenate(
                    [link_d[s][stay], np.hypot(now[hears, s, 0], now[hears, s, 1])]
                )
                order = np.argsort(receivers, kind="stable")
                receivers, dist = receivers[order], dist[order]
            reach = self.radio.link_reach_mm(np.full(len(receivers), s), receivers)
            loss = np.zeros(len(receivers))
            if not (
                np.array_equal(receivers, link_r[s])
                and np.array_equal(dist, link_d[s])
                and np.array_equal(reach, link_reach[s])
            ):
                link_r[s], link_d[s], link_reach[s], link_loss[s] = receivers, dist, reach, loss
                self._refill_rows[s] = 1  # as in _rebuild_all
                self._derive(s)

    def _derive(self, s: int, *, relist: bool = False) -> None:
        """Rebuild sender ``s``'s receiver, distance and handler lists; drop its drawn rows.

        When its receivers stay the same (a neighbour moved, the battery shrank the reach a
        little) only the distances and signal shares change: the receiver and handler lists,
        the counters folded over them and the messages on the air keep standing, so the
        in-flight messages keep the fast delivery path (what they deliver is the same).
        ``relist`` rebuilds the lists anyway (a receiver's handler changed)."""
        r, d, loss = self._link_r[s], self._link_d[s], self._link_loss[s]
        p = reception_probability(d, self._link_reach[s] * self._range_factor[s], self._edge_mm)
        heard = p >= MIN_RECEPTION
        if not heard.all():
            r, d, loss, p = r[heard], d[heard], loss[heard], p[heard]
        self._rx_d[s] = d
        self._rx_loss[s] = loss
        self._rx_signal[s] = 1.0 - p
        self._row_count[s] = self._row_next[s] = 0  # rows drawn for the old links are void
        self._shares[s] = None
        if not relist and np.array_equal(r, self._rx_idx[s]):
            return
        self.counts.fold(s, self._rx_r[s])
        self._epoch += 1
        self._rx_idx[s] = r
        ids = self._ids
        self._rx_r[s] = [ids[k] for k in r.tolist()]
        self._rx_at[s] = {rx: at for at, rx in enumerate(self._rx_r[s])}
        self._rx_h[s] = [self._entries[k] for k in self._rx_r[s]]

    def _senders_reaching(self, robot: int) -> list[int]:
        """Senders whose receiver lists may contain ``robot`` (links are symmetric)."""
        return self._link_r[robot].tolist()

    def receivers_of(self, sender: int) -> list[int]:
        """Robots that currently hear ``sender`` (range, occlusion, battery range)."""
        return list(self._rx_r[sender])

    def link_delivery(self, sender: int) -> tuple[np.ndarray, np.ndarray]:
        """The robots that hear ``sender`` now (indices, as :meth:`receivers_of`) and the share
        of its messages each link delivers, collisions and the independent
        ``medium.loss_prob`` apart: the soft edge of the sender's reach (shrunk by its
        battery), bodies on the line of sight, and the receiver's own battery and faults."""
        receivers = self._rx_idx[sender]
        share = (1.0 - self._rx_signal[sender]) * (1.0 - self._rx_loss[sender])
        share = share * (1.0 - self._loss_battery[receivers]) * (1.0 - self._loss_fault[receivers])
        return receivers.copy(), share

    def graph(self) -> nx.Graph:
        """The medium's own communication graph now: an edge between every two robots that
        hear each other (both directions: battery range can make a link one-way, then the
        edge is missing), with ``distance_mm`` and occlusion ``loss``; stopped robots are
        nodes without edges."""
        import networkx as nx

        g = nx.Graph()
        g.add_nodes_from(range(self.n))
        for s in range(self.n):
            for r, d, q in zip(
                self._rx_r[s], self._rx_d[s].tolist(), self._rx_loss[s].tolist(), strict=True
            ):
                if s < r and s in self._rx_r[r]:
                    g.add_edge(s, r, distance_mm=d, loss=q)
        return g

    # -- degradation hooks (battery, faults) and the robot's own settings ---------------------
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
        for s in self._senders_reaching(robot):
            self._row_count[s] = self._row_next[s] = 0  # redraw with the new loss shares
            self._shares[s] = None

    def tx_period_own_s(self, robot: int) -> float:
        """``robot``'s transmit period in seconds of its own clock."""
        return self._period[robot] * self._factor[robot]

    def set_tx_period(self, robot: int, period_s: float) -> None:
        """Set ``robot``'s transmit period to ``period_s`` seconds of its own clock (a program
        writing kilolib's ``kilo_tx_period``); it applies from its next opportunity.

        Raises
        ------
        ValueError
            If ``period_s`` is not above ``robot.tx_jitter_s`` (an offer would fall before the
            one it follows).
        """
        jitter_s = self._robot_params.tx_jitter_s
        if not period_s > jitter_s:
            raise ValueError(
                f"robot {robot}: a transmit period of {period_s} s must exceed "
                f"robot.tx_jitter_s = {jitter_s} s"
            )
        self._period[robot] = period_s / self._factor[robot]

    def _reroute(self, robot: int | None) -> None:
        """The ports changed ``robot``'s entry (``None``: every robot's): rebuild the handler
        lists of the senders that reach it."""
        for s in range(self.n) if robot is None else self._senders_reaching(robot):
            self._derive(s, relist=True)

    def set_tx_source(self, robot: int, source: Callable[[], Message | None]) -> None:
        """Ask ``source()`` instead of ``robot``'s ``message_tx()`` at its transmit
        opportunities (:mod:`kilonet.testing` calls the program's own method from there to
        record what it offers)."""
        self._message_tx[robot] = source

    def start(self, robot: int) -> None:
        """Schedule the first transmit opportunity of ``robot`` at ``U(0, period)`` (the phase
        of its transmit counter at the start is random)."""
        self._offer_timers[robot].schedule(next(self._uniform) * self._period[robot])

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
        shares = self._shares[s]
        if shares is None:
            shares = self._shares[s] = LossShares(
                self.params.loss_prob,
                self._rx_loss[s],
                self._loss_battery[receivers],
                self._loss_fault[receivers],
                self._rx_signal[s],
            )
        outcomes = self.reception.draw(s, receivers, self._rx_d[s], shares, n_rows)
        self._estimates[s] = outcomes.estimates.tobytes()
        if outcomes.losses is None:
            self._lossy_rows[s] = None
        else:
            self._lossy_rows[s] = [
                np.flatnonzero(row).tolist() if lossy else []
                for row, lossy in zip(
                    outcomes.losses, outcomes.losses.any(axis=1).tolist(), strict=True
                )
            ]
            self._losses[s] = outcomes.losses.tobytes()
        self._row_next[s] = 0
        self._row_count[s] = n_rows

    @property
    def counters(self) -> dict[str, list[int]]:
        """Per-robot counters (lists indexed by robot), as :data:`kilonet.counters.COUNTERS`
        names them."""
        for s in range(self.n):
            self.counts.fold(s, self._rx_r[s])
        return self.counts.as_dict()

    # -- the hot path ------------------------------------------------------------------------
    def _offer(self, timer: Timer) -> None:
        s = timer.value
        if not self._running[s]:
            return
        now = self.env._kt  # the kernel's clock (KernelEnvironment.now without the call)
        if self._csma and self._busy_until[s] > now >= self._sensed_from[s]:
            self.counts.backoffs[s] += 1
            delay = next(self._uniform) * self._backoff[s]
        else:
            message = self._message_tx[s]()
            if message is None:
                delay = (
                    self._tick[s]
                    if self._retry_tick
                    else self._period[s] + (2 * next(self._uniform) - 1) * self._jitter[s]
                )
            else:
                if message is not self._last_checked[s]:
                    self.limit.check(message, s)
                    self._last_checked[s] = message
                    self._message_bytes[s] = message.size_bytes
                    self._crc_ok[s] = message.crc_ok
                self._transmit(s, message, now)
                delay = self._period[s] + (2 * next(self._uniform) - 1) * self._jitter[s]
        self._offer_timers[s].schedule(delay)

    def _transmit(self, s: int, message: Message, now: float) -> None:
        k = self._row_next[s]
        if k == self._row_count[s]:
            self._refill(s)
            k = 0
        self._row_next[s] = k + 1
        receivers = self._rx_r[s]
        n = len(receivers)
        lossy = self._lossy_rows[s]
        if not self._crc_ok[s]:
            losses, lost_at = bytes([_CRC]) * n, range(n)
        elif lossy is not None and lossy[k]:
            losses, lost_at = self._losses[s][k * n : k * n + n], lossy[k]
        else:
            losses = lost_at = None
        tx = _Transmission(
            s,
            message,
            receivers,
            self._rx_h[s],
            self._estimates[s][k * n : k * n + n],
            losses,
            lost_at,
            self._epoch,
            self._end_callbacks,
        )
        end = now + self.airtime_s
        self.channel.occupy(tx, s, receivers, now, end)
        counters = self.counts
        counters.sent[s] += 1
        counters.bytes_sent[s] += self._message_bytes[s]
        self.env.schedule_at(tx, end)
        success = self._tx_success[s]
        if success is not None:
            success()

    def _end_of_airtime(self, tx: _Transmission) -> None:
        # Called by the step loop with the event, which is the transmission itself.
        message = tx.message
        corrupted, lost_at = tx.corrupted, tx.lost_at
        if tx.epoch != self._epoch or tx.sender < 0:
            self._deliver_carefully(tx)
            return
        counters = self.counts
        if lost_at is None and corrupted is None:
            self._sink.extend(map(operator.call, tx.handlers, repeat(message), tx.estimates))
            counters.clean_delivery(tx.sender)
            if self._trace_messages:
                n = len(tx.receivers)
                self._trace.message(self.env.now, tx.sender, n, n)
            return
        # Some receptions fail (collided or lost): deliver the others, in receiver order, by
        # one C-level map over the receivers a mask keeps, count the transmission as clean and
        # take the failed receptions back out of `received` (the collided ones a batch of
        # messages at a time, see MediumCounters.collided). A collided reception costs its
        # mask byte: no sort, no slice, no call, no count of its own.
        receivers, handlers = tx.receivers, tx.handlers
        keep = bytearray(b"\x01" * len(receivers))  # 1: deliver
        if lost_at is not None:
            for at in lost_at:
                keep[at] = 0
        if corrupted is not None:
            rx_at = self._rx_at[tx.sender]
            for r in corrupted:
                keep[rx_at[r]] = 0
        self._sink.extend(
            map(
                operator.call,
                compress(handlers, keep),
                repeat(message),
                compress(tx.estimates, keep),
            )
        )
        counters.clean_delivery(tx.sender)
        if corrupted is not None:
            # A collision counts before any other cause. The set goes to the counters as it
            # is, so the message lets go of it: a robot's own transmission keeps its channel
            # busy past the last reception there, and the channel may mark that reception,
            # long over, again (into a new set, counted by no one).
            tx.corrupted = None
            counters.collided(corrupted)
        if lost_at is not None:
            received = counters.received
            lost_by_code, losses, corrupted = self._lost_by_code, tx.losses, corrupted or ()
            for at in lost_at:
                r = receivers[at]
                if r not in corrupted:
                    received[r] -= 1
                    lost_by_code[losses[at]][r] += 1
        if self._trace_messages:
            n = len(receivers)
            self._trace.message(self.env.now, tx.sender, n, n - keep.count(0))

    def _deliver_carefully(self, tx: _Transmission) -> None:
        """End of airtime of a message whose receiver lists changed while it was on the air,
        or that came from outside the swarm (:meth:`hear_from_outside`): receiver by receiver."""
        message = tx.message
        corrupted = tx.corrupted or ()
        counters = self.counts
        received = counters.received
        lost_collision = counters.lost("collision")
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
            self._trace.message(self.env.now, tx.sender, len(tx.receivers), delivered)

    def outside_shares(self, receiver: int) -> LossShares:
        """The loss shares of a reception at ``receiver`` from a sender outside the swarm
        (:mod:`kilonet.testing`'s scripted messages): the medium's loss probability and the
        receiver's battery and fault shares; no link of its own, so no occlusion and a full
        signal."""
        at = np.array([receiver])
        return LossShares(
            self.params.loss_prob,
            np.zeros(1),
            self._loss_battery[at],
            self._loss_fault[at],
            np.zeros(1),
        )

    def hear_from_outside(
        self, receiver: int, message: Message, estimate_mm: int, cause: str | None
    ) -> None:
        """Put ``message``, from a sender outside the swarm, on the air at ``receiver`` now,
        its reception's fate decided by the caller: the distance estimate (whole mm, 0-255)
        and the cause it is lost to (a :data:`LOSS_CAUSES` name or ``"crc"``), or ``None``.
        It occupies the receiver's channel for the airtime, collides there as any reception,
        and at the end of the airtime reaches the receiver's port unless lost or collided,
        counted (and traced, with sender -1) as any reception."""
        code = _CAUSE_CODE[cause] if cause else 0
        now = self.env.now
        tx = _Transmission(
            -1,
            message,
            [self._ids[receiver]],
            [self._entries[receiver]],
            bytes([estimate_mm]),
            bytes([code]),
            [0] if code else [],
            self._epoch,
            self._end_callbacks,
        )
        self.channel.occupy(tx, self._outside, tx.receivers, now, now + self.airtime_s)
        self.env.schedule_at(tx, now + self.airtime_s)

    def forget_receiver(self, robot: int) -> None:
        """Take a stopped robot out of the topology (and so of the messages still on the air)."""
        self._running[robot] = False
        self.rebuild_topology()

    def count_overflow(self, robot: int) -> None:
        """Count a message dropped from ``robot``'s full receive buffer."""
        self.counts.lost("overflow")[robot] += 1

    def receiving(self, robot: int) -> bool:
        """Whether a reception is in progress at ``robot`` now (kilolib's ``rx_busy``)."""
        return self.channel.busy(robot, self.env.now)
