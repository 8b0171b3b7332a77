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

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import simpy

from kilonet.battery import Battery
from kilonet.clock import LoopRound
from kilonet.faults import FaultInjector
from kilonet.medium import LOSS_CAUSES, InfraredMedium
from kilonet.message import Message
from kilonet.motion import Motion
from kilonet.params import Params
from kilonet.placement import ROBOT_DIAMETER_MM, validate_positions
from kilonet.robot import Kilobot
from kilonet.trace import Trace

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["STREAMS", "Simulation", "World", "stream_for"]

#: Independent random streams of a run, spawned from its seed in this order.
STREAMS = ("medium", "ranging", "battery", "faults", "motion", "placement", "schedule")


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


@dataclass
class World:
    """Ground truth: where the robots are. Only the medium, motion and metrics read it."""

    positions_mm: np.ndarray
    heading_rad: np.ndarray
    diameter_mm: float = ROBOT_DIAMETER_MM
    present: np.ndarray = field(default=None)  # on the table (removal clears it)
    running: np.ndarray = field(default=None)  # executing its program

    def __post_init__(self) -> None:
        n = len(self.positions_mm)
        if self.present is None:
            self.present = np.ones(n, dtype=bool)
        if self.running is None:
            self.running = np.ones(n, dtype=bool)

    @property
    def radius_mm(self) -> float:
        """Body radius, mm."""
        return self.diameter_mm / 2


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

    Raises
    ------
    kilonet.placement.PlacementError
        If the positions are not a valid placement (too few robots, overlaps, non-finite).
    """

    def __init__(
        self,
        positions_mm: Any,
        program: Callable[[int], Kilobot],
        params: Params | None = None,
        *,
        headings_rad: Sequence[float] | None = None,
    ) -> None:
        self.params = params or Params()
        positions = validate_positions(positions_mm, source="positions")
        n = len(positions)
        self.n_robots = n
        self.env = simpy.Environment()
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
        self.trace = Trace()
        self.robots: list[Kilobot] = []
        build = program if not _is_program_class(program) else (lambda _i: program())
        for i in range(n):
            robot = build(i)
            if not isinstance(robot, Kilobot):
                raise TypeError(f"program({i}) returned {type(robot).__name__}, not a Kilobot")
            robot._attach(self, i, robot_rngs[i])
            self.robots.append(robot)
        self.medium = InfraredMedium(self)
        self.battery = Battery(self)
        self.motion = Motion(self)
        self.faults = FaultInjector(self)
        self.stop_causes: dict[int, str] = {}
        self.wall_time_s = 0.0
        self._started = False
        polled = self.params.robot.rx_mode == "polled"
        self.medium.set_handlers(
            [self._buffer_push(i) if polled else r.message_rx for i, r in enumerate(self.robots)]
        )

    def stream(self, name: str) -> np.random.Generator:
        """The run's random stream ``name`` (one of :data:`STREAMS`)."""
        return self._streams[name]

    # -- running -------------------------------------------------------------------------------
    def start(self) -> None:
        """Call every robot's ``setup()`` and schedule its timers (done by :meth:`run`)."""
        if self._started:
            return
        self._started = True
        self.faults.start()
        self.battery.start()
        loop_period = self.params.robot.loop_period_s
        loop_rng = self.stream("schedule")
        loops = LoopRound(self.env, loop_period)
        for i, robot in enumerate(self.robots):
            robot.setup()
            self.medium.start(i)
            # An empty loop() has no effect on a robot; skipping it keeps idle programs cheap.
            if type(robot).loop is not Kilobot.loop:
                loops.add(float(loop_rng.uniform(0, loop_period)), self._loop_call(i))
        loops.start()

    def _loop_call(self, i: int) -> Callable[[], bool]:
        """Robot ``i``'s turn in the loop round: its ``loop()`` while it runs."""
        loop = self.robots[i].loop
        running = self.world.running

        def call() -> bool:
            if running[i]:
                loop()
                return True
            return False

        return call

    def run(
        self, until_s: float | None = None, *, stop_when: Callable[[], bool] | None = None
    ) -> None:
        """Run to simulated time ``until_s`` (default ``params.duration_s``).

        With ``stop_when``, the run also ends as soon as that predicate (checked every simulated
        second) is true.
        """
        self.start()
        until = self.params.duration_s if until_s is None else until_s
        started = time.perf_counter()
        if stop_when is None:
            self.env.run(until=until)
        else:
            while self.env.now < until and not stop_when():
                self.env.run(until=min(until, self.env.now + 1.0))
        self.wall_time_s += time.perf_counter() - started

    # -- receptions and stops ------------------------------------------------------------------
    def _buffer_push(self, i: int) -> Callable[[Message, int], None]:
        buffer = self.robots[i]._rx_buffer
        size = buffer.maxlen
        medium = self.medium

        def push(message: Message, distance_mm: int) -> None:
            if len(buffer) == size:
                medium.count_overflow(i)
            buffer.append((message, distance_mm))

        return push

    def deliver(self, robot: int, message: Message, distance_mm: int) -> None:
        """Hand a (possibly delayed) reception to ``robot`` as its receive mode says."""
        if not self.world.running[robot]:
            return
        if self.params.robot.rx_mode == "polled":
            self._buffer_push(robot)(message, distance_mm)
        else:
            self.robots[robot].message_rx(message, distance_mm)

    def stop_robot(self, robot: int, cause: str, *, remove: bool = False) -> None:
        """Stop ``robot`` (``cause``: crash, removed, battery); ``remove`` lifts it off the
        table."""
        if not self.world.running[robot] and not remove:
            return
        self.motion.stop(robot)
        self.world.running[robot] = False
        if remove:
            self.world.present[robot] = False
        self.stop_causes.setdefault(robot, cause)
        self.trace.stop(self.env.now, robot, cause)
        self.medium.forget_receiver(robot)

    # -- results -------------------------------------------------------------------------------
    def robots_frame(self) -> pd.DataFrame:
        """One row per robot: start and final pose, state, LED, battery and message counters."""
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
            "messages_offered": c["offered"],
            "messages_sent": c["sent"],
            "backoffs": c["backoffs"],
            "bytes_sent": c["bytes_sent"],
            "receptions_delivered": c["received"],
            **lost,
            "robots_stopped": int((~self.world.running).sum()),
        }


def _is_program_class(program: object) -> bool:
    return isinstance(program, type) and issubclass(program, Kilobot)
