"""One robot program in a world the test scripts, on the real kernel: :class:`ScriptedWorld`
(the program under test, its neighbours, the script, the records and the assertions).

See :mod:`kilonet.testing` for how the pieces fit.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Callable, Hashable, Iterable, Mapping
from typing import Any

from simpy.events import URGENT, Event

from kilonet.message import LIMITS, Layout, Message, PayloadError, message_crc
from kilonet.params import Params
from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.radio import farthest_mm
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation
from kilonet.testing.errors import ScriptError
from kilonet.testing.explain import condition_text, describe, fields_text
from kilonet.testing.outside import arrive
from kilonet.testing.record import (
    Change,
    Heard,
    LoggedEvent,
    ScriptedReception,
    Sent,
    program_state,
)
from kilonet.watchdog import BUSY_CALL_S, busy_watchdog

__all__ = ["ScriptedWorld", "build_params"]

#: How often (simulated s) eventually() and never() check at least, besides after every event.
CHECK_S = 0.01
#: How often (simulated s) they note the program's state for a failure message.
STATE_S = 0.1
#: Entries of each list a failure message shows.
SHOWN = 8


def build_params(params: Params | Mapping[str, Any] | None, seed: int | None) -> Params:
    """The run's parameters: ``params`` as given (a :class:`Params`), or the kernel's defaults
    with ``params``' dotted overrides; ``seed`` (if given) replaces the seed.

    Examples
    --------
    >>> p = build_params({"medium.loss_prob": 0.1}, 7)
    >>> p.medium.loss_prob, p.seed
    (0.1, 7)
    """
    out = params if isinstance(params, Params) else Params().with_overrides(dict(params or {}))
    return out if seed is None else out.with_overrides({"seed": seed})


class _OnTable:
    """A robot of the world: its program, start pose and UID (``None``: its index)."""

    def __init__(
        self, program: Kilobot, at_mm: tuple[float, float], heading_rad: float, uid: int | None
    ) -> None:
        self.program = program
        self.at_mm = at_mm
        self.heading_rad = heading_rad
        self.uid = uid


class ScriptedWorld:
    """One robot program in a world the test scripts: what it hears and when, who stands
    beside it, and how far time goes.

    The program under test is robot 0, at the origin. Nothing happens until the test moves
    time (:meth:`advance`, :meth:`run_until`, :meth:`eventually`, :meth:`never`); the world
    is built then, on a real :class:`~kilonet.simulation.Simulation`.

    Parameters
    ----------
    program : Kilobot or Kilobot subclass
        The program under test (an instance, or a class to instantiate).
    seed : int, optional
        Seed of the run (default: the parameters' own, 1 for the kernel's defaults). The same
        seed and script give the same run.
    params : Params or dict, optional
        A :class:`~kilonet.params.Params`, or dotted overrides of the kernel's defaults
        (``{"robot.rx_mode": "polled"}``).
    uid : int, optional
        The robot's ``kilo_uid`` (default 0, with ``robot.hardware_uids``).
    heading_rad : float
        Its heading, counter-clockwise from +x.
    layouts : iterable of Layout
        Message layouts to decode messages with in failure messages.
    watchdog_s : float
        Wall-clock seconds one call into the program may run while simulated time stands
        still (a ``while True`` in ``loop``) before
        :class:`~kilonet.watchdog.BusyCallError` stops it (default 30; 0: never).

    Attributes
    ----------
    params : Params
        The run's parameters.
    sim : Simulation or None
        The simulation, once the world has started.
    script : list of ScriptedReception
        Every reception the test scripted, with its fate.
    opportunities : list of int
        Transmit opportunities at which each robot was asked for a message so far.

    Examples
    --------
    >>> from kilonet.message import Layout
    >>> PING = Layout("ping", type=2, fields=[("n", "B")])
    >>> class Echo(Kilobot):
    ...     def setup(self):
    ...         self.reply = None
    ...     def message_rx(self, message, distance_mm):
    ...         self.reply = PING.pack(n=PING.unpack(message).n + 1)
    ...     def message_tx(self):
    ...         return self.reply
    >>> world = ScriptedWorld(Echo(), layouts=[PING])
    >>> entry = world.hear(PING.pack(n=4), at_s=0.5, distance_mm=60)
    >>> world.advance(2.0)
    >>> world.sent(PING)[0].fields
    Ping(n=5)
    >>> [(round(h.t_s, 4), h.distance) for h in world.heard()], entry.fate
    ([(0.5044, 60)], 'delivered')
    """

    def __init__(
        self,
        program: Kilobot | type[Kilobot],
        *,
        seed: int | None = None,
        params: Params | Mapping[str, Any] | None = None,
        uid: int | None = None,
        heading_rad: float = 0.0,
        layouts: Iterable[Layout] = (),
        watchdog_s: float = BUSY_CALL_S,
    ) -> None:
        self.params = build_params(params, seed)
        self.watchdog_s = watchdog_s
        self._robots = [_OnTable(_instance(program, "program"), (0.0, 0.0), heading_rad, uid)]
        self.layouts = list(layouts)
        self.script: list[ScriptedReception] = []
        self.sim: Simulation | None = None
        self._by_message: dict[int, ScriptedReception] = {}
        self._on_air: dict[int, deque] = {}
        self._sent: list[list[Sent]] = []
        self._heard: list[list[Heard]] = []
        self._motors: list[list[Change]] = []
        self._colors: list[list[Change]] = []
        self._events: list[list[LoggedEvent]] = []
        self._trace_seen = (0, 0)  # LED changes and events of the trace sorted in so far
        self.opportunities: list[int] = []
        self._states: deque = deque(maxlen=SHOWN)

    # -- building the world ------------------------------------------------------------------
    @property
    def robot(self) -> Kilobot:
        """The program under test (robot 0)."""
        return self._robots[0].program

    @property
    def n_robots(self) -> int:
        """Robots in the world: the program under test and its neighbours."""
        return len(self._robots)

    def add_neighbour(
        self,
        program: Kilobot | type[Kilobot],
        *,
        at_mm: tuple[float, float] | None = None,
        distance_mm: float | None = None,
        bearing_deg: float = 0.0,
        heading_rad: float = 0.0,
        uid: int | None = None,
    ) -> int:
        """Put another robot on the table, running ``program`` (e.g. a :class:`Replay`), at
        ``at_mm`` or at ``distance_mm`` and ``bearing_deg`` (counter-clockwise from +x) from
        the robot under test; return its index (1, 2, ...).

        Raises
        ------
        ScriptError
            After the world has started, or without exactly one of ``at_mm`` and
            ``distance_mm``. (Overlapping bodies are refused when the world starts.)
        """
        if self.sim is not None:
            raise ScriptError(
                f"add_neighbour() at {self.now_s:.3f} s: neighbours stand on the table from the "
                "start; add them before the first advance()"
            )
        if (at_mm is None) == (distance_mm is None):
            raise ScriptError("add_neighbour() needs at_mm=(x, y) or distance_mm=, not both")
        if at_mm is None:
            angle = math.radians(bearing_deg)  # rounded so that 90 degrees gives x = 0
            at_mm = (
                round(distance_mm * math.cos(angle), 9),
                round(distance_mm * math.sin(angle), 9),
            )
        name = f"neighbour {len(self._robots)}"
        self._robots.append(
            _OnTable(_instance(program, name), (float(at_mm[0]), float(at_mm[1])), heading_rad, uid)
        )
        return len(self._robots) - 1

    def start(self) -> Simulation:
        """Build the simulation and call every robot's ``setup()`` (at 0 s); the first
        :meth:`advance` does this by itself. Returns the simulation."""
        if self.sim is not None:
            return self.sim
        programs = [r.program for r in self._robots]
        if len({id(p) for p in programs}) != len(programs):
            raise ScriptError("one program instance cannot run on two robots; pass one each")
        uids = [i if r.uid is None else r.uid for i, r in enumerate(self._robots)]
        sim = Simulation(
            [r.at_mm for r in self._robots],
            lambda i: programs[i],
            self.params,
            headings_rad=[r.heading_rad for r in self._robots],
            uids=uids,
        )
        self.sim = sim
        for i in range(sim.n_robots):
            self._sent.append([])
            self._heard.append([])
            self._motors.append([])
            self._colors.append([])
            self._events.append([])
            self.opportunities.append(0)
            sim.medium.set_tx_source(i, self._offer_source(i))
            sim.watch_receptions(i, self._reception_listener(i))
        sim.motion.watch(self._motor_listener)
        sim.start()
        for entry in self.script:
            self._schedule(entry)
        return sim

    def _offer_source(self, i: int) -> Callable[[], Message | None]:
        sim = self.sim
        program, env, limit = sim.robots[i], sim.env, sim.medium.limit
        ask, sent, airtime = program.message_tx, self._sent[i], sim.medium.airtime_s
        counts = self.opportunities

        def offer() -> Message | None:
            message = ask()
            counts[i] += 1
            if message is not None:
                try:
                    limit.check(message)
                except PayloadError as exc:
                    raise PayloadError(
                        f"robot {i} ({type(program).__name__}) offered a message at "
                        f"{env.now:.3f} s that does not fit: {exc}"
                    ) from None
                sent.append(Sent(env.now, message))
                self._on_air.setdefault(id(message), deque(maxlen=8)).append((env.now + airtime, i))
            return message

        return offer

    def _reception_listener(self, i: int) -> Callable[[Message, Any], None]:
        env, heard = self.sim.env, self._heard[i]

        def listen(message: Message, distance: Any) -> None:
            now = env.now
            scripted = self._by_message.get(id(message))
            if scripted is not None and i == 0:
                scripted.fate = "delivered"
                sender = scripted.sender
            else:
                sender = self._sender_of(message, now)
            heard.append(Heard(now, message, distance, sender))

        return listen

    def _sender_of(self, message: Message, now_s: float) -> int | None:
        """The robot whose transmission of this very message object ended last by now."""
        best = None
        for end_s, robot in self._on_air.get(id(message), ()):
            if end_s <= now_s + 1e-9 and (best is None or end_s >= best[0]):
                best = (end_s, robot)
        return None if best is None else best[1]

    def _motor_listener(self, robot: int, left: int, right: int) -> None:
        changes = self._motors[robot]
        if not changes or changes[-1].value != (left, right):
            changes.append(Change(self.sim.env.now, (left, right)))

    # -- the script --------------------------------------------------------------------------
    def hear(
        self,
        message: Message,
        *,
        at_s: float | None = None,
        distance_mm: float = 50.0,
        sender: Hashable = "scripted",
        lost: bool = False,
        corrupt: bool = False,
        noise: bool = False,
        sense_carrier: bool = False,
    ) -> ScriptedReception:
        """Make the robot under test hear ``message`` from ``sender`` at ``distance_mm``.

        The message begins arriving at ``at_s`` (default: now) and takes the airtime; it goes
        through the medium's own reception path (:func:`kilonet.testing.outside.arrive`):
        the robot senses the carrier meanwhile, it collides with whatever else arrives then,
        and at the end of the airtime the program gets it through its receive mode (callback
        or polled buffer, estimate or raw readings), with the distance estimate
        ``round(distance_mm)`` exactly, or drawn by the run's reception model with ``noise``.
        The medium's loss probability and the robot's battery and faults apply as to any
        reception.

        Parameters
        ----------
        message : Message
            What it hears (``LAYOUT.pack(...)`` or a raw :class:`Message`).
        at_s : float, optional
            When it begins arriving, simulated s (default: now).
        distance_mm : float
            Distance of the sender, centre to centre, mm.
        sender : hashable
            A label for the sender, for the records.
        lost : bool
            Lose this reception (the robot still senses the carrier).
        corrupt : bool
            Send it with a wrong CRC: it occupies the channel and is dropped.
        noise : bool
            Draw the distance estimate from the run's reception model.
        sense_carrier : bool
            Begin only once the robot's channel is free, as a neighbour sensing the carrier
            would (``at_s`` is then the earliest time): in a busy world, the message does not
            collide with one already arriving, nor with the robot's own transmission.

        Returns
        -------
        ScriptedReception
            The entry; its ``fate`` tells what became of it.

        Raises
        ------
        ScriptError
            If ``at_s`` is in the past, or no sender could be heard from ``distance_mm``
            (closer than a body diameter, or beyond the farthest any link of the run reaches:
            ``medium.range_mm`` with ``medium.reach = disc``).
        kilonet.message.PayloadError
            If the message does not fit the payload limit.
        """
        now = self.now_s
        at = now if at_s is None else float(at_s)
        where = f"hear() at {at:.3f} s from {sender!r}"
        if not at >= now:
            raise ScriptError(f"{where}: that is before now ({now:.3f} s); time only moves forward")
        range_mm = farthest_mm(self.params.medium)
        if not ROBOT_DIAMETER_MM <= distance_mm <= range_mm:
            raise ScriptError(
                f"{where}: distance_mm={distance_mm} is outside the {ROBOT_DIAMETER_MM:g} mm body "
                f"diameter to the {range_mm:g} mm the farthest link of this run reaches "
                f"(medium.reach = {self.params.medium.reach}); no robot could be heard from there"
            )
        if not isinstance(message, Message):
            raise ScriptError(f"{where}: {message!r} is not a Message (use LAYOUT.pack(...))")
        limit = LIMITS[self.params.medium.message_format]
        try:
            limit.check(message)
        except PayloadError as exc:
            raise PayloadError(f"{where}: {exc}") from None
        crc = message_crc(message) ^ 0xFFFF if corrupt else message.crc
        entry = ScriptedReception(
            at, Message(message.data, message.type, crc), float(distance_mm), sender,
            lost, corrupt, noise, sense_carrier,
        )  # fmt: skip
        self.script.append(entry)
        self._by_message[id(entry.message)] = entry
        if self.sim is not None:
            self._schedule(entry)
        return entry

    def hear_every(
        self,
        message: Message,
        *,
        period_s: float,
        until_s: float,
        from_s: float | None = None,
        **options: Any,
    ) -> list[ScriptedReception]:
        """:meth:`hear` ``message`` every ``period_s`` from ``from_s`` (default now) until
        before ``until_s``; ``options`` as for :meth:`hear`.

        Raises
        ------
        ScriptError
            If ``period_s`` is not positive or ``until_s`` not finite.
        """
        if not period_s > 0 or not math.isfinite(until_s):
            raise ScriptError(
                f"hear_every(): needs period_s > 0 and a finite until_s, got {period_s}, {until_s}"
            )
        start = self.now_s if from_s is None else float(from_s)
        count = max(0, math.ceil((until_s - start) / period_s - 1e-9))
        return [self.hear(message, at_s=start + k * period_s, **options) for k in range(count)]

    def _schedule(self, entry: ScriptedReception) -> None:
        sim = self.sim
        timeout = sim.env.timeout(entry.at_s - sim.env.now)
        timeout.callbacks.append(lambda _event: self._arrive(entry))

    def _arrive(self, entry: ScriptedReception) -> None:
        medium, now = self.sim.medium, self.sim.env.now
        if entry.sense_carrier and medium.channel.busy_until[0] > now:  # sensed or not yet
            wait = medium.channel.busy_until[0] - now
            self.sim.env.timeout(wait).callbacks.append(lambda _event: self._arrive(entry))
            return
        entry.at_s = now
        estimate = None if entry.noise else min(255, round(entry.distance_mm))
        cause = arrive(
            self.sim, 0, entry.message, entry.distance_mm, estimate_mm=estimate, lose=entry.lost
        )
        entry.end_s = self.sim.env.now + medium.airtime_s
        entry.fate = "on air" if cause is None else "lost" if entry.lost else cause
        if cause is None:
            # Queued after the medium's end of airtime: by then the program has it, or not.
            self.sim.env.timeout(medium.airtime_s).callbacks.append(
                lambda _event: self._missed(entry)
            )

    def _missed(self, entry: ScriptedReception) -> None:
        if entry.fate == "on air":
            entry.fate = "collision" if self.sim.world.running[0] else "stopped"

    # -- time --------------------------------------------------------------------------------
    @property
    def now_s(self) -> float:
        """Simulated time, s (0 before the world starts)."""
        return float(self.sim.env.now) if self.sim is not None else 0.0

    def advance(self, dt_s: float) -> None:
        """Let ``dt_s`` simulated seconds pass.

        Raises
        ------
        ScriptError
            If ``dt_s`` is negative (or not a number).
        """
        if not dt_s >= 0:
            raise ScriptError(f"advance({dt_s}): time only moves forward; give a duration >= 0 s")
        self.run_until(self.now_s + dt_s)

    def run_until(self, t_s: float) -> None:
        """Let time pass until simulated time ``t_s``; events due exactly at ``t_s`` happen
        in the next step, as with SimPy's ``run(until=...)``.

        Raises
        ------
        ScriptError
            If ``t_s`` is before now.
        """
        self.start()
        now = self.now_s
        if not t_s >= now:
            raise ScriptError(
                f"run_until({t_s}) is before now ({now:.3f} s); time only moves forward"
            )
        if t_s > now:
            with busy_watchdog(self.watchdog_s):
                self.sim.env.run(until=t_s)

    def _first_time(self, condition: Callable[[], bool], until_s: float) -> float | None:
        """Advance toward ``until_s``, checking ``condition`` after every event and at least
        every :data:`CHECK_S`; the time it first holds (time stops there), or ``None`` (time
        is then ``until_s``)."""
        sim = self.start()
        env = sim.env
        self._note_state()
        if condition():
            return self.now_s
        noted = env.now
        with busy_watchdog(self.watchdog_s):
            while env.now < until_s:
                # A marker at the end of the slice, as SimPy's run(until=...) places one: the
                # robots' loop schedule never runs loops past it in one step.
                marker = Event(env)
                marker._ok, marker._value = True, None
                env.schedule(marker, URGENT, min(until_s, env.now + CHECK_S) - env.now)
                while marker.callbacks is not None:
                    env.step()
                    if condition():
                        self._note_state()
                        return self.now_s
                if env.now - noted >= STATE_S or env.now >= until_s:
                    self._note_state()
                    noted = env.now
            return None

    def _note_state(self) -> None:
        state = {k: fields_text({k: v}, self.layouts) for k, v in program_state(self.robot).items()}
        if not self._states or self._states[-1][1] != state:
            self._states.append((self.now_s, state))

    # -- assertions --------------------------------------------------------------------------
    def eventually(
        self, condition: Callable[[], bool], *, within_s: float, what: str | None = None
    ) -> float:
        """Let time pass until ``condition()`` holds, at most ``within_s`` simulated seconds;
        return the time it first held (time stops there). Checked now, after every event and
        at least every 10 ms.

        Raises
        ------
        AssertionError
            If it never held; the message shows the robot's last states and what it heard,
            sent and logged up to the deadline.
        ScriptError
            If ``within_s`` is negative.
        """
        __tracebackhide__ = True  # pytest shows the test's line, not the kit's
        if not within_s >= 0:
            raise ScriptError(f"eventually(within_s={within_s}): give a duration >= 0 s")
        start = self.now_s
        held = self._first_time(condition, start + within_s)
        if held is None:
            raise AssertionError(
                f"{what or condition_text(condition)} did not hold within {within_s:g} s "
                f"(from {start:.3f} to {self.now_s:.3f} s)\n{self.explain()}"
            )
        return held

    def never(
        self, condition: Callable[[], bool], *, for_s: float, what: str | None = None
    ) -> None:
        """Let ``for_s`` simulated seconds pass, checking that ``condition()`` never holds
        (now, after every event and at least every 10 ms).

        Raises
        ------
        AssertionError
            At the first time it held; the message shows what led there.
        """
        __tracebackhide__ = True  # pytest shows the test's line, not the kit's
        if not for_s >= 0:
            raise ScriptError(f"never(for_s={for_s}): give a duration >= 0 s")
        start = self.now_s
        held = self._first_time(condition, start + for_s)
        if held is not None:
            raise AssertionError(
                f"{what or condition_text(condition)} held at {held:.3f} s "
                f"({held - start:.3f} s into the {for_s:g} s from {start:.3f} s)\n"
                f"{self.explain()}"
            )

    def assert_sent(
        self,
        what: Layout | int,
        /,
        *,
        within_s: float | None = None,
        since_s: float | None = None,
        robot: int = 0,
        **fields: Any,
    ) -> Sent:
        """Assert that ``robot`` sent a message of layout (or type byte) ``what`` whose fields
        equal ``fields`` (values compare with ``==``, so ``pytest.approx`` works). Returns the
        first such message (decoded with the layout).

        Without ``within_s``: among what it sent so far (since ``since_s``, default the
        start). With ``within_s``: a window, from now (or ``since_s``) to ``within_s`` from
        now; time passes until such a message goes on the air or the window ends, and a
        message sent before the window does not count.

        Raises
        ------
        AssertionError
            If it sent none; the message lists what it sent instead.
        ScriptError
            For fields without a layout or that the layout lacks, an unknown robot, or a
            negative ``within_s``.
        """
        __tracebackhide__ = True  # pytest shows the test's line, not the kit's
        if within_s is not None and not within_s >= 0:
            raise ScriptError(f"assert_sent(within_s={within_s}): give a duration >= 0 s")
        if since_s is None:
            since_s = self.now_s if within_s is not None else 0.0
        matching, layout, kind = self._matcher(what, robot, fields, since_s, "assert_sent")
        if within_s is not None:
            self._first_time(lambda: matching() is not None, self.now_s + within_s)
        found = matching()
        if found is None:
            wanted = layout.name if layout else f"type {kind}"
            if fields:
                wanted += " with " + ", ".join(f"{k}={v!r}" for k, v in fields.items())
            window = f" from {since_s:.3f} s" if since_s > 0 else ""
            of_kind = [s for s in self.sent(robot=robot) if s.message.type == kind]
            raise AssertionError(
                f"robot {robot} sent no {wanted}{window} by {self.now_s:.3f} s; it sent "
                f"{len(of_kind)} of type {kind} and "
                f"{len(self.sent(robot=robot)) - len(of_kind)} of other types\n"
                f"{self.explain(robot)}"
            )
        return found

    def assert_not_sent(
        self,
        what: Layout | int,
        /,
        *,
        for_s: float,
        robot: int = 0,
        **fields: Any,
    ) -> None:
        """Assert that ``robot`` sends no message of layout (or type byte) ``what`` with
        ``fields`` in the next ``for_s`` simulated seconds (time passes that long, or stops
        at the first such message).

        Raises
        ------
        AssertionError
            At the first such message; the message shows what led there.
        ScriptError
            As :meth:`assert_sent`, or for a negative ``for_s``.
        """
        __tracebackhide__ = True  # pytest shows the test's line, not the kit's
        if not for_s >= 0:
            raise ScriptError(f"assert_not_sent(for_s={for_s}): give a duration >= 0 s")
        start = self.now_s
        matching, layout, kind = self._matcher(what, robot, fields, start, "assert_not_sent")
        self._first_time(lambda: matching() is not None, start + for_s)
        found = matching()
        if found is not None:
            wanted = layout.name if layout else f"type {kind}"
            raise AssertionError(
                f"robot {robot} sent {wanted} {describe(found.message, self.layouts)} at "
                f"{found.t_s:.3f} s ({found.t_s - start:.3f} s into the {for_s:g} s from "
                f"{start:.3f} s)\n{self.explain(robot)}"
            )

    def _matcher(
        self, what: Layout | int, robot: int, fields: dict[str, Any], since_s: float, name: str
    ) -> tuple[Callable[[], Sent | None], Layout | None, int]:
        """The first message ``robot`` sent from ``since_s`` on of ``what`` with ``fields``."""
        self._check_robot(robot)
        layout = what if isinstance(what, Layout) else None
        if fields and layout is None:
            raise ScriptError(f"{name}(): matching fields needs the message's Layout")
        if layout is not None:
            names = [field for field, _, _ in layout.fields]
            unknown = sorted(set(fields) - set(names))
            if unknown:
                raise ScriptError(
                    f"{name}(): layout {layout.name!r} has no field {', '.join(unknown)}; "
                    f"it has {', '.join(names)}"
                )
        kind = layout.type if layout is not None else int(what)

        def matching() -> Sent | None:
            for s in self.sent(layout, robot=robot) if layout else self.sent(robot=robot):
                if (
                    s.t_s >= since_s
                    and s.message.type == kind
                    and all(getattr(s.fields, k) == v for k, v in fields.items())
                ):
                    return s
            return None

        return matching, layout, kind

    # -- records -----------------------------------------------------------------------------
    def _check_robot(self, robot: int) -> None:
        if not (isinstance(robot, int) and 0 <= robot < len(self._robots)):
            others = len(self._robots) - 1
            raise ScriptError(
                f"robot {robot!r} is not in this world: robot 0 is the program under test and "
                f"there {'is' if others == 1 else 'are'} {others} neighbour"
                f"{'' if others == 1 else 's'}" + (f" (1-{others})" if others else "")
            )

    def _decode(self, records: list, layout: Layout | None) -> list:
        if layout is None:
            return list(records)
        return [
            r._replace(fields=layout.unpack(r.message))
            for r in records
            if layout.matches(r.message)
        ]

    def sent(self, layout: Layout | None = None, *, robot: int = 0) -> list[Sent]:
        """What ``robot`` put on the air, in order; with ``layout``, only messages of its type,
        decoded (``.fields``)."""
        self._check_robot(robot)
        return self._decode(self._sent[robot] if self.sim else [], layout)

    def heard(self, layout: Layout | None = None, *, robot: int = 0) -> list[Heard]:
        """What ``robot``'s program was handed, in order; with ``layout``, only messages of
        its type, decoded."""
        self._check_robot(robot)
        return self._decode(self._heard[robot] if self.sim else [], layout)

    def _follow_trace(self) -> None:
        """Sort the trace's new LED changes and events into the robots' records."""
        trace = self.sim.trace
        new_led = trace.led_since(self._trace_seen[0])
        new_events = trace.events_since(self._trace_seen[1])
        self._trace_seen = (
            self._trace_seen[0] + len(new_led),
            self._trace_seen[1] + len(new_events),
        )
        for t_s, robot, r, g, b in new_led:
            self._colors[robot].append(Change(t_s, (r, g, b)))
        for t_s, robot, name, data in new_events:
            self._events[robot].append(LoggedEvent(t_s, name, json.loads(data)))

    def colors(self, *, robot: int = 0) -> list[Change]:
        """LED colour changes ``(r, g, b)`` of ``robot``, in order."""
        self._check_robot(robot)
        if self.sim is None:
            return []
        self._follow_trace()
        return list(self._colors[robot])

    def motor_commands(self, *, robot: int = 0) -> list[Change]:
        """Changes of ``robot``'s motor duty ``(left, right)``, in order."""
        self._check_robot(robot)
        return list(self._motors[robot]) if self.sim else []

    def events(self, name: str | None = None, *, robot: int = 0) -> list[LoggedEvent]:
        """Events ``robot``'s program logged (only those called ``name``), in order."""
        self._check_robot(robot)
        if self.sim is None:
            return []
        self._follow_trace()
        return [e for e in self._events[robot] if name is None or e.name == name]

    def pose(self, *, robot: int = 0) -> tuple[float, float, float]:
        """``robot``'s true pose now: ``(x_mm, y_mm, heading_rad)``, the robot under test
        starting at the origin (the world starts if it has not)."""
        self._check_robot(robot)
        world = self.start().world
        x, y = world.positions_mm[robot]
        return float(x), float(y), float(world.heading_rad[robot])

    @property
    def kilo_ticks(self) -> int:
        """The robot under test's ``kilo_ticks`` now."""
        self.start()
        return self.robot.kilo_ticks

    def frames(self, *, robot: int = 0) -> dict[str, Any]:
        """``robot``'s records as DataFrames: ``sent``, ``heard``, ``led``, ``motors``,
        ``events`` (times in simulated s, messages as type and hex payload), and ``script``
        (the scripted receptions and their fates)."""
        import pandas as pd

        def messages(records: list, extra: list[str]) -> pd.DataFrame:
            rows = [
                {"t_s": r.t_s, "type": r.message.type, "data": r.message.data.hex(),
                 "crc_ok": r.message.crc_ok, **{k: getattr(r, k) for k in extra}}
                for r in records
            ]  # fmt: skip
            return pd.DataFrame(rows, columns=["t_s", "type", "data", "crc_ok", *extra])

        script = pd.DataFrame(
            [
                {"at_s": e.at_s, "sender": e.sender, "distance_mm": e.distance_mm,
                 "type": e.message.type, "data": e.message.data.hex(), "fate": e.fate}
                for e in self.script
            ],
            columns=["at_s", "sender", "distance_mm", "type", "data", "fate"],
        )  # fmt: skip
        return {
            "sent": messages(self.sent(robot=robot), []),
            "heard": messages(self.heard(robot=robot), ["distance", "sender"]),
            "led": pd.DataFrame(
                [(c.t_s, *c.value) for c in self.colors(robot=robot)],
                columns=["t_s", "r", "g", "b"],
            ),
            "motors": pd.DataFrame(
                [(c.t_s, *c.value) for c in self.motor_commands(robot=robot)],
                columns=["t_s", "left", "right"],
            ),
            "events": pd.DataFrame(
                [(e.t_s, e.name, e.fields) for e in self.events(robot=robot)],
                columns=["t_s", "event", "fields"],
            ),
            "script": script,
        }

    # -- telling what happened ---------------------------------------------------------------
    def explain(self, robot: int = 0, *, last: int = SHOWN) -> str:
        """What ``robot`` is and did, as lines for a failure message: its clock, LED, motors
        and state now, its latest state changes, and the last ``last`` messages it heard and
        sent, scripted receptions that did not reach it, and events it logged."""
        self._check_robot(robot)
        if self.sim is None:
            return f"the world has not started (robot 0: {type(self.robot).__name__})"
        program = self.sim.robots[robot]
        layouts = self.layouts
        motors = self._motors[robot][-1].value if self._motors[robot] else (0, 0)
        running = "running" if self.sim.world.running[robot] else "stopped"
        lines = [
            f"robot {robot} ({type(program).__name__}) at {self.now_s:.3f} s: kilo_ticks "
            f"{program.kilo_ticks}, LED {program.color}, motors {motors}, {running}",
            "  state: " + fields_text(program_state(program), layouts),
        ]
        if robot == 0 and len(self._states) > 1:
            lines.append("  state changes:")
            for (_, before), (t_s, after) in zip(
                self._states, list(self._states)[1:], strict=False
            ):
                changed = [v for k, v in after.items() if before.get(k) != v]
                lines.append(f"    {t_s:8.3f} s  {', '.join(changed)}")

        def section(title: str, items: list, line: Callable[[Any], str]) -> None:
            shown = items[-last:]
            more = f", last {len(shown)}" if len(items) > len(shown) else ""
            lines.append(f"  {title} ({len(items)}{more}):" if items else f"  {title}: none")
            lines.extend(f"    {line(item)}" for item in shown)

        section(
            "heard",
            self._heard[robot],
            lambda h: (
                f"{h.t_s:8.3f} s  from {h.sender!r} at {h.distance}  {describe(h.message, layouts)}"
            ),
        )
        if robot == 0:
            missed = [e for e in self.script if e.fate not in ("delivered", "scheduled", "on air")]
            if missed:
                section(
                    "scripted but not delivered",
                    missed,
                    lambda e: (
                        f"{e.at_s:8.3f} s  from {e.sender!r}  {describe(e.message, layouts)}"
                        f"  [{e.fate}]"
                    ),
                )
        section(
            "sent",
            self._sent[robot],
            lambda s: f"{s.t_s:8.3f} s  {describe(s.message, layouts)}",
        )
        section(
            "events",
            self.events(robot=robot),
            lambda e: f"{e.t_s:8.3f} s  {e.name} {fields_text(e.fields)}",
        )
        if robot == 0:
            for k, r in enumerate(self._robots[1:], start=1):
                lines.append(
                    f"  neighbour {k} ({type(r.program).__name__}) at ({r.at_mm[0]:g}, "
                    f"{r.at_mm[1]:g}) mm: sent {len(self._sent[k])}, heard {len(self._heard[k])}"
                )
        return "\n".join(lines)


def _instance(program: Kilobot | type[Kilobot], what: str) -> Kilobot:
    if isinstance(program, type) and issubclass(program, Kilobot):
        return program()
    if not isinstance(program, Kilobot):
        raise ScriptError(f"{what}: {program!r} is not a Kilobot program (instance or subclass)")
    return program
