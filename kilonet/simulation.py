"""One simulation run: SimPy environment, seeded random streams, world, medium and robots.

Examples
--------
>>> from kilonet.message import Message
>>> class Hello(Kilobot):
...     def message_tx(self):
...         return Message(b"hi")
...     def message_rx(self, message, distance_mm):
...         self.heard = distance_mm
>>> sim = Simulation([[0, 0], [50, 0]], Hello, Params(seed=3, duration_s=1.0))
>>> sim.run()
>>> sim.robots[0].heard in range(47, 54)
True
"""

from __future__ import annotations

import inspect
import math
import time
from collections.abc import Callable, Generator, Mapping, Sequence
from numbers import Real
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.battery import Battery
from kilonet.clock import KernelEnvironment, RobotClocks
from kilonet.counters import LOSS_CAUSES
from kilonet.errors import ProgramRuntimeError, ProgramTypeError, shown
from kilonet.faults import FaultInjector
from kilonet.medium import InfraredMedium
from kilonet.message import Message
from kilonet.motion import Motion
from kilonet.params import Params
from kilonet.placement import validate_positions
from kilonet.port import ReceivePorts
from kilonet.radio import Transceivers, reach_of
from kilonet.ranging import calibration_tables, read_calibration
from kilonet.reception import ModelContext, reception_model
from kilonet.robot import (
    Kilobot,
    RobotServices,
    callback_place,
    check_kernel_names,
    check_program_class,
)
from kilonet.sensors import Sensors
from kilonet.trace import Trace
from kilonet.world import World

if TYPE_CHECKING:
    import pandas as pd

    from kilonet.reception import ReceptionModel
    from kilonet.visibility import LinkModel

__all__ = ["ESTIMATE_CHANGE_MM", "STREAMS", "Simulation", "stream_for"]

#: A held position estimate is recorded again once it has moved this far (mm): finer steps
#: (a refinement's last digits) would not show in an animation and would fill the table.
ESTIMATE_CHANGE_MM = 0.05

#: Independent random streams of a run, spawned from its seed in this order.
STREAMS = (
    "medium",
    "ranging",
    "battery",
    "faults",
    "motion",
    "placement",
    "clock",
    "sensors",
    "calibration",
    "radio",
)


def stream_for(seed: int, name: str) -> np.random.Generator:
    """The random stream ``name`` that a simulation with ``seed`` uses (e.g. to draw its
    placement before the simulation exists).

    Examples
    --------
    >>> float(stream_for(7, "placement").random()) == float(stream_for(7, "placement").random())
    True
    """
    model_seq, _ = np.random.SeedSequence(seed).spawn(2)
    return np.random.Generator(np.random.PCG64(model_seq.spawn(len(STREAMS))[STREAMS.index(name)]))


class Simulation:
    """A Kilobot swarm running programs on an infrared medium.

    Parameters
    ----------
    positions_mm : (N, 2) array-like
        True start positions, mm.
    program : Kilobot subclass or callable
        A ``Kilobot`` subclass (every robot runs it), or ``program(index) -> Kilobot``, which
        builds the program of robot ``index`` (as flashing different robots differently).
    params : Params
        All model parameters, including the seed.
    headings_rad : (N,) array-like, optional
        Start headings; drawn uniformly from the ``motion`` stream if omitted.
    uids : (N,) array-like of int, optional
        Hardware UIDs (``kilo_uid``); default: each robot's index. Ignored without
        ``robot.hardware_uids``.
    links : kilonet.visibility.LinkModel, optional
        Range and occlusion of the medium (default: from ``params.medium``).
    reception : kilonet.reception.ReceptionModel, optional
        The medium's reception model (default: Gaussian ranging, independent losses).
    hardware : mapping of str to callable, optional
        Extra hardware the robots carry, beyond a Kilobot's (a maze robot's camera, wall sensor
        and cell drive): ``name -> fit``, where ``fit(sim, index)`` returns robot ``index``'s
        part, or ``None`` if it carries none. A part is a sensor and actuator model: ``fit``
        hands it the ground truth, streams and services it uses, once the run is wired, and a
        program reaches it through :meth:`~kilonet.robot.Kilobot.hardware`.

    Raises
    ------
    kilonet.placement.PlacementError
        If the positions are not a valid placement (no robot, overlaps, non-finite); one
        robot alone is a valid swarm.
    ValueError
        If ``uids`` does not give one uint16 per robot.
    """

    def __init__(
        self,
        positions_mm: Any,
        program: Callable[[int], Kilobot],
        params: Params | None = None,
        *,
        headings_rad: Sequence[float] | None = None,
        uids: Sequence[int] | None = None,
        links: LinkModel | None = None,
        reception: ReceptionModel | None = None,
        hardware: Mapping[str, Callable[[Simulation, int], Any]] | None = None,
    ) -> None:
        self.params = params or Params()
        positions = validate_positions(positions_mm, source="positions", min_robots=1)
        n = len(positions)
        self.n_robots = n
        self.env = KernelEnvironment()
        model_seq, robot_seq = np.random.SeedSequence(self.params.seed).spawn(2)
        self._streams = {
            name: np.random.Generator(np.random.PCG64(s))
            for name, s in zip(STREAMS, model_seq.spawn(len(STREAMS)), strict=True)
        }
        robot_rngs = [np.random.Generator(np.random.PCG64(s)) for s in robot_seq.spawn(n)]
        if headings_rad is None:
            headings = self.stream("motion").uniform(0, 2 * np.pi, n)
        else:
            headings = np.asarray(headings_rad, dtype=float)
        self.world = World(positions.copy(), headings.copy())
        self.initial_positions_mm = positions.copy()
        self.initial_headings_rad = headings.copy()
        self.uids = _uids(uids, n) if self.params.robot.hardware_uids else None
        self.trace = Trace()
        rp = self.params.robot
        self.clocks = RobotClocks.draw(n, rp.ticks_per_s, rp.clock_sd, self.stream("clock"))
        self.calibration_tables = calibration_tables(n, self.stream("calibration"))
        if self.params.ranging.calibration_file:
            self.calibration_tables = read_calibration(self.params.ranging.calibration_file, n)
        mp = self.params.medium
        self.transceivers = Transceivers.draw(
            n, reach_of(mp), mp.tx_strength_sd, self.stream("radio")
        )
        self.motion = Motion(
            self.params.motion, self.env, self.world, self.trace, self.stream("motion")
        )
        self.robots: list[Kilobot] = []
        build = program if not _is_program_class(program) else (lambda _i: program())
        checked: set[type] = set()
        for i in range(n):
            robot = build(i)
            if not isinstance(robot, Kilobot):
                raise TypeError(f"program({i}) returned {type(robot).__name__}, not a Kilobot")
            if type(robot) not in checked:
                check_program_class(type(robot))
                checked.add(type(robot))
            self.robots.append(robot)
        # The wiring: each component gets the parts of the run it uses, built in this order.
        self.reception = reception or reception_model(
            ModelContext(
                self.params,
                n,
                self.stream("ranging"),
                self.stream("medium"),
                self.calibration_tables,
                self.transceivers,
            )
        )
        self.ports = ReceivePorts(rp, self.env, self.world.running, self.calibration_tables)
        self.medium = InfraredMedium(
            self.params.medium,
            rp,
            self.env,
            self.world,
            self.clocks,
            self.transceivers,
            [r.message_tx for r in self.robots],
            # An empty message_tx_success() has no effect: the medium need not call it.
            [
                None
                if type(r).message_tx_success is Kilobot.message_tx_success
                else r.message_tx_success
                for r in self.robots
            ],
            self.ports,
            self.reception,
            self.stream("medium"),
            self.trace,
            links=links,
            trace_messages=self.params.trace.messages,
        )
        self.battery = Battery(
            self.params.battery,
            self.env,
            self.world,
            self.medium,
            self.trace,
            stop=self.stop_robot,
        )
        self.motion.connect(self.battery, self.medium.rebuild_topology)
        self.sensors = Sensors(
            self.params.light,
            rp.temperature_c,
            self.world,
            self.battery.voltage,
            self.stream("sensors"),
        )
        self.faults = FaultInjector(
            self.params.faults,
            self.env,
            self.stream("faults"),
            n,
            stop=self.stop_robot,
            medium=self.medium,
            ports=self.ports,
        )
        self.robot_services = RobotServices(
            self.env,
            rp,
            self.clocks,
            self.calibration_tables,
            self.uids,
            self.trace,
            self.medium,
            self.motion,
            self.sensors,
        )
        fits = dict(hardware or {})
        for i, robot in enumerate(self.robots):
            parts = {name: fit(self, i) for name, fit in fits.items()}
            parts = {name: part for name, part in parts.items() if part is not None}
            robot._attach(self, i, robot_rngs[i], parts)
        self.stop_causes: dict[int, str] = {}
        self._loops: dict[int, int] = {}  # robot -> its loop's handle in the environment
        self.wall_time_s = 0.0
        self._started = False
        self._estimating: list[int] = []  # robots whose position_estimate() is sampled
        self._held: dict[int, tuple[float, float, str]] = {}  # what each held when last sampled
        self.ports.connect(
            [r.message_rx for r in self.robots],
            [r._krx for r in self.robots],
            self.medium.count_overflow,
        )

    def stream(self, name: str) -> np.random.Generator:
        """The run's random stream ``name`` (one of :data:`STREAMS`)."""
        return self._streams[name]

    # -- running -------------------------------------------------------------------------------
    def start(self) -> None:
        """Call every robot's ``setup()`` and schedule its loop and transmissions (done by
        :meth:`run`). A robot whose ``setup`` or ``loop`` is a generator runs as a SimPy process
        of its own; it starts transmitting once its setup has returned, as on kilolib."""
        if self._started:
            return
        self._started = True
        self.faults.start()
        self.battery.start()
        loop_ticks = self.params.robot.loop_ticks
        polled = self.params.robot.rx_mode == "polled"
        for i, robot in enumerate(self.robots):
            cls = type(robot)
            # In polled mode a program with a message_rx gets what its loop leaves in the
            # buffer through it after each loop call (see Kilobot.drain_messages).
            drains = polled and cls.message_rx is not Kilobot.message_rx
            has_loop = cls.loop is not Kilobot.loop or drains
            if inspect.isgeneratorfunction(cls.setup) or inspect.isgeneratorfunction(cls.loop):
                robot._kprocess = True
                self.env.process(self._program(i, has_loop, drains))
                continue
            robot.setup()
            self._check_kernel_names(i)
            self.medium.start(i)
            # An empty loop() has no effect on a robot; skipping it keeps idle programs cheap.
            if has_loop:
                period = loop_ticks / self.clocks.rate_hz(i)
                first = self.clocks.first_mid_tick_s(i)
                self._loops[i] = self.env.every(first, period, self._loop_call(i, drains))
        self._sample_estimates()

    def _check_kernel_names(self, i: int) -> None:
        """Refuse robot ``i``'s program if its setup set a kernel name (see
        :func:`kilonet.robot.check_kernel_names`)."""
        slots = {
            "_kenv": self.env,
            "_kindex": i,
            "_krate": self.clocks.rate_hz(i),
            "_ktheta": float(self.clocks.phase[i]),
        }
        check_kernel_names(self.robots[i], i, slots)

    def _check_all_kernel_names(self, failure: BaseException | None = None) -> None:
        """:meth:`_check_kernel_names` of every robot; a refusal raised while the run was
        failing with ``failure`` chains it."""
        for i in range(self.n_robots):
            try:
                self._check_kernel_names(i)
            except ProgramTypeError as refusal:
                raise refusal from failure

    def _sample_estimates(self) -> None:
        """Every ``trace.estimates_period_s`` from the start, and whenever :meth:`run` returns,
        record each running robot's :meth:`~kilonet.robot.Kilobot.position_estimate` where it
        changed (by more than :data:`ESTIMATE_CHANGE_MM`, or to another frame, or to none);
        robots whose program does not override it are not asked. The sampler only reads, so
        the run is the same with it or without it."""
        period = self.params.trace.estimates_period_s
        self._estimating = [
            i
            for i, r in enumerate(self.robots)
            if type(r).position_estimate is not Kilobot.position_estimate
        ]
        if period <= 0 or not self._estimating:
            self._estimating = []
            return

        def every_period() -> Generator[Any, Any, None]:
            while True:
                self._record_estimates()
                yield self.env.timeout(period)

        self.env.process(every_period())

    def _record_estimates(self) -> None:
        """One sample of :meth:`_sample_estimates`."""
        running, held, now = self.world.running, self._held, self.env.now
        for i in self._estimating:
            if not running[i]:
                continue
            estimate = self.robots[i].position_estimate()
            if estimate is not None:
                try:
                    x, y, frame = estimate
                except (TypeError, ValueError):
                    x = y = frame = None
                if not (isinstance(x, Real) and isinstance(y, Real) and isinstance(frame, str)):
                    raise ProgramTypeError(
                        f"robot {i}'s position_estimate() returned {shown(estimate)}, not "
                        "(x_mm, y_mm, frame) or None",
                        *callback_place(type(self.robots[i]), "position_estimate"),
                    )
            last = held.get(i)
            if estimate is None:
                if last is not None:
                    del held[i]
                    self.trace.estimate(now, i, math.nan, math.nan, "")
            elif (
                last is None
                or estimate[2] != last[2]
                or math.hypot(estimate[0] - last[0], estimate[1] - last[1]) > ESTIMATE_CHANGE_MM
            ):
                held[i] = estimate
                self.trace.estimate(now, i, *estimate)

    def _loop_call(self, i: int, drains: bool) -> Callable[[], None]:
        """Robot ``i``'s turn in the loop schedule: its ``loop()`` (and, with ``drains``, its
        polled buffer into ``message_rx`` after it); :meth:`stop_robot` cancels it."""
        robot = self.robots[i]
        if not drains:
            return robot.loop
        loop, drain, running = robot.loop, robot.drain_messages, self.world.running
        if type(robot).loop is Kilobot.loop:
            return drain

        def call() -> None:
            loop()
            if running[i]:
                drain()

        return call

    def _program(self, i: int, has_loop: bool, drains: bool) -> Generator[Any, Any, None]:
        """Robot ``i``'s program as a SimPy process: setup, then its loop, each call allowed to
        block in ``yield self.delay(ms)``. A call that blocked is followed by the next at once
        (kilolib calls ``loop()`` back to back); one that did not, at the middle of the tick
        ``robot.loop_ticks`` ticks after the tick it ran in (nothing a program reads changes in
        between but its receptions). With ``drains``, the polled buffer goes to
        ``message_rx`` after each call."""
        robot, running = self.robots[i], self.world.running
        yield from self._blocking(i, robot.setup)
        if not running[i]:
            return
        self._check_kernel_names(i)
        self.medium.start(i)
        if not has_loop:
            return
        rate, theta = self.clocks.rate_hz(i), float(self.clocks.phase[i])
        loop_ticks = self.params.robot.loop_ticks
        plain_loop = type(robot).loop is Kilobot.loop
        # The first call falls mid-tick, in the tick under way if its middle is still ahead.
        position = self.env.now * rate + theta
        tick = math.floor(position)
        if position - tick > 0.5:
            tick += 1
        blocked = False
        while True:
            started = self.env.now
            if not blocked:
                # Ticks are counted, not times compared: a float comparison of two times that
                # name the same mid-tick would skip a tick now and then.
                yield self.env.timeout(max(0.0, (tick + 0.5 - theta) / rate - started))
                if not running[i]:
                    return
                started, call_tick = self.env.now, tick
            else:
                call_tick = None  # right after a call that blocked: not on a tick's middle
            if not plain_loop:
                yield from self._blocking(i, robot.loop)
                if not running[i]:
                    return
            if drains:
                robot.drain_messages()
            blocked = self.env.now > started
            if call_tick is not None:
                tick = call_tick + loop_ticks
            else:  # the middle of a tick at or after `loop_ticks` ticks from `started`
                position = started * rate + theta + loop_ticks
                tick = math.floor(position)
                if position - tick > 0.5:
                    tick += 1

    def _blocking(self, i: int, callback: Callable[[], Any]) -> Generator[Any, Any, None]:
        """Run a program call, ``callback()``, that may be a generator of delays (see
        :meth:`Kilobot.delay`).

        Raises
        ------
        kilonet.errors.ProgramTypeError
            (a ``TypeError``) If the program yields anything but ``self.delay(ms)``: at the
            line of that ``yield``.
        kilonet.errors.ProgramRuntimeError
            (a ``RuntimeError``) If it called ``delay`` without yielding it, and returned:
            at the line of the callback.
        """
        robot = self.robots[i]
        result = callback()
        if inspect.isgenerator(result):
            for event in result:
                if event is None or event is not robot._kdelay:
                    frame = result.gi_frame
                    code, line = frame.f_code, frame.f_lineno
                    result.close()
                    raise ProgramTypeError(
                        f"robot {i}'s {code.co_name} yielded {shown(event)}; a program may only "
                        "yield self.delay(ms)",
                        code.co_filename,
                        line,
                    )
                robot._kdelay = None
                yield event
                if not self.world.running[i]:
                    result.close()
                    return
        if robot._kdelay is not None:
            robot._kdelay = None
            name = callback.__name__
            raise ProgramRuntimeError(
                f"robot {i}'s {name} called delay() without `yield`: it blocks only as "
                "`yield self.delay(ms)`",
                *callback_place(type(robot), name),
            )

    def run(
        self, until_s: float | None = None, *, stop_when: Callable[[], bool] | None = None
    ) -> None:
        """Run to simulated time ``until_s`` (default ``params.duration_s``).

        With ``stop_when``, the run also ends as soon as that predicate (checked every simulated
        second) is true.

        Raises
        ------
        kilonet.errors.ProgramTypeError
            If a program set a kernel name (see :func:`kilonet.robot.check_kernel_names`)
            during the run: checked when it stops, and when it fails (a program that overwrote
            the kernel's state may have failed for that reason).
        """
        self.start()
        until = self.params.duration_s if until_s is None else until_s
        started = time.perf_counter()
        try:
            if stop_when is None:
                self.env.run(until=until)
            else:
                while self.env.now < until and not stop_when():
                    self.env.run(until=min(until, self.env.now + 1.0))
        except Exception as exc:
            self._check_all_kernel_names(exc)
            raise
        self._check_all_kernel_names()
        if self._estimating:
            self._record_estimates()  # what the robots hold where the run stops
        self.wall_time_s += time.perf_counter() - started

    # -- receptions and stops ------------------------------------------------------------------
    def watch_receptions(self, robot: int, listener: Callable[[Message, Any], None]) -> None:
        """Call ``listener(message, distance)`` with every reception handed to ``robot``'s
        program (see :meth:`kilonet.port.ReceivePorts.watch`). :mod:`kilonet.testing` records
        runs with it.

        Raises
        ------
        RuntimeError
            If the simulation has started: rerouting a robot's deliveries voids the reception
            outcomes the medium drew ahead, so a run watched from midway would not be the run
            it watches.
        """
        if self._started:
            raise RuntimeError("watch_receptions() must be called before the simulation starts")
        self.ports.watch(robot, listener)

    def stop_robot(self, robot: int, cause: str, *, remove: bool = False) -> None:
        """Stop ``robot`` (``cause``: crash, removed, battery); ``remove`` lifts it off the
        table."""
        if not self.world.running[robot] and not remove:
            return
        self.motion.stop(robot)
        self.world.running[robot] = False
        if robot in self._loops:
            self.env.cancel(self._loops[robot])
        if remove:
            self.world.present[robot] = False
        self.stop_causes.setdefault(robot, cause)
        self.trace.stop(self.env.now, robot, cause)
        self.ports.stop(robot)
        self.medium.forget_receiver(robot)

    # -- results -------------------------------------------------------------------------------
    def led_key_frame(self) -> pd.DataFrame:
        """What the LED colours of this run's programs mean (:attr:`Kilobot.LED_KEY`):
        ``r, g, b, meaning``, one row per colour in the order the programs list them (programs
        of several kinds: the first robot's first; one colour meaning two things says both)."""
        import pandas as pd

        meanings: dict[tuple[int, int, int], list[str]] = {}
        for cls in dict.fromkeys(type(r) for r in self.robots):
            for colour, meaning in cls.LED_KEY:
                said = meanings.setdefault(tuple(colour), [])
                if meaning not in said:
                    said.append(meaning)
        rows = [(*colour, " / ".join(said)) for colour, said in meanings.items()]
        return pd.DataFrame(rows, columns=["r", "g", "b", "meaning"])

    def robots_frame(self) -> pd.DataFrame:
        """One row per robot: start and final pose, clock, state, LED, battery and message
        counters."""
        import pandas as pd

        w = self.world
        frame = pd.DataFrame(
            {
                "robot": np.arange(self.n_robots),
                "x0_mm": self.initial_positions_mm[:, 0],
                "y0_mm": self.initial_positions_mm[:, 1],
                "x_mm": w.positions_mm[:, 0],
                "y_mm": w.positions_mm[:, 1],
                "heading_rad": w.heading_rad,
                "clock_factor": self.clocks.factor,
                "running": w.running,
                "present": w.present,
                "stop_cause": [self.stop_causes.get(i, "") for i in range(self.n_robots)],
                "voltage_v": self.battery.voltages(),
                "led_factor": self.battery.led_factor,
                "led_r": [r.color[0] for r in self.robots],
                "led_g": [r.color[1] for r in self.robots],
                "led_b": [r.color[2] for r in self.robots],
            }
        )
        for name, values in self.medium.counters.items():
            frame[name] = values
        return frame

    def summary(self) -> dict[str, Any]:
        """Run-level figures: time, robots and message totals (JSON-serialisable)."""
        c = {k: int(sum(v)) for k, v in self.medium.counters.items()}
        lost = {f"lost_{cause}": c[f"lost_{cause}"] for cause in LOSS_CAUSES}
        return {
            "robots": self.n_robots,
            "seed": self.params.seed,
            "sim_time_s": float(self.env.now),
            "wall_time_s": round(self.wall_time_s, 3),
            "messages_sent": c["sent"],
            "backoffs": c["backoffs"],
            "bytes_sent": c["bytes_sent"],
            "receptions_delivered": c["received"],
            **lost,
            "robots_stopped": int((~self.world.running).sum()),
        }


def _is_program_class(program: object) -> bool:
    return isinstance(program, type) and issubclass(program, Kilobot)


def _uids(uids: Sequence[int] | None, n: int) -> list[int]:
    if uids is None:
        return list(range(n))
    out = [int(u) for u in uids]
    if len(out) != n or any(not 0 <= u <= 0xFFFF for u in out):
        raise ValueError(f"uids must give one integer 0-65535 per robot ({n}), got {uids!r}")
    return out
