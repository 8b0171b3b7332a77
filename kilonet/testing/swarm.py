"""A small swarm in one call: :func:`run_swarm` and the :class:`SwarmResult` it returns."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import LAYOUTS, generate_from
from kilonet.simulation import Simulation, stream_for
from kilonet.testing.errors import ScriptError
from kilonet.testing.explain import condition_text, short_repr
from kilonet.testing.record import program_state
from kilonet.testing.world import build_params
from kilonet.watchdog import BUSY_CALL_S, busy_watchdog

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["SwarmResult", "run_swarm"]


@dataclass(frozen=True)
class SwarmResult:
    """What a swarm run by :func:`run_swarm` did.

    Attributes
    ----------
    sim : Simulation
        The run itself, for anything the attributes below do not give.
    stopped : bool
        Whether the stop condition held when the run ended (``False`` without one).
    watchdog_s : float
        Wall-clock seconds one call into a program may run before
        :class:`~kilonet.watchdog.BusyCallError` stops it, here and in :meth:`eventually` and
        :meth:`never` (0: never).
    """

    sim: Simulation
    stopped: bool
    watchdog_s: float = BUSY_CALL_S

    @property
    def t_s(self) -> float:
        """Simulated time at the end of the run, s."""
        return float(self.sim.env.now)

    @property
    def robots(self) -> pd.DataFrame:
        """One row per robot (:meth:`~kilonet.simulation.Simulation.robots_frame`): start and
        final pose, clock, LED, battery and message counters."""
        return self.sim.robots_frame()

    @property
    def tables(self) -> dict[str, pd.DataFrame]:
        """The trace's tables by name (``led``, ``events``, ``poses``, ``stops``,
        ``messages``, ``battery``, ``estimates``)."""
        return self.sim.trace.frames()

    @property
    def programs(self) -> list[Kilobot]:
        """Every robot's program, by robot index."""
        return list(self.sim.robots)

    def program(self, robot: int) -> Kilobot:
        """Robot ``robot``'s program.

        Raises
        ------
        ScriptError
            If there is no such robot.
        """
        n = self.sim.n_robots
        if not (isinstance(robot, int | np.integer) and 0 <= robot < n):
            raise ScriptError(f"robot {robot!r} is not in this swarm of {n} robots (0-{n - 1})")
        return self.sim.robots[robot]

    @property
    def final(self) -> list[dict[str, Any]]:
        """Each robot's final program state (:func:`~kilonet.testing.program_state`)."""
        return [program_state(r) for r in self.sim.robots]

    def state_frame(self) -> pd.DataFrame:
        """The final states as a table: a ``robot`` column and one column per attribute
        whose value is a number, string or ``None`` on every robot."""
        import pandas as pd

        rows = self.final
        scalar = (int, float, str, bool, np.integer, np.floating, type(None))
        names = [k for k in rows[0] if all(isinstance(r.get(k, ()), scalar) for r in rows)]
        return pd.DataFrame(
            [{"robot": i, **{k: r[k] for k in names}} for i, r in enumerate(rows)],
            columns=["robot", *names],
        )

    def assert_each(
        self, predicate: Callable[[int, Kilobot], bool], what: str | None = None
    ) -> None:
        """Assert ``predicate(index, program)`` for every robot.

        Raises
        ------
        AssertionError
            Naming the robots it fails for (up to ten), each with its position and state.
        """
        __tracebackhide__ = True  # pytest shows the test's line, not the kit's
        failing = [i for i, r in enumerate(self.sim.robots) if not predicate(i, r)]
        if not failing:
            return
        raise AssertionError(
            f"{what or condition_text(predicate)} fails for {len(failing)} of "
            f"{self.sim.n_robots} robots at {self.t_s:.3f} s:\n{self.explain(failing)}"
        )

    def explain(self, robots: Sequence[int] | None = None, *, last: int = 3) -> str:
        """What robots did, as lines for a failure message: for each of ``robots`` (default
        all; at most ten shown) its position, LED, messages sent and received, its program
        state, and the last ``last`` events it logged."""
        sim = self.sim
        chosen = list(range(sim.n_robots) if robots is None else robots)
        pos = sim.world.positions_mm
        counters = sim.medium.counters
        events = sim.trace.events_frame()
        lines = []
        for i in chosen[:10]:
            program = sim.robots[i]
            running = "running" if sim.world.running[i] else "stopped"
            state = ", ".join(f"{k}={short_repr(v, 40)}" for k, v in program_state(program).items())
            lines.append(f"  robot {i} at ({pos[i, 0]:.1f}, {pos[i, 1]:.1f}) mm: {state or '-'}")
            lines.append(
                f"    {type(program).__name__}, {running}, LED {program.color}, "
                f"sent {counters['sent'][i]}, received {counters['received'][i]}"
            )
            mine = events[events.robot == i].tail(last) if len(events) else events
            for row in mine.itertuples(index=False):
                lines.append(f"    {row.t_s:8.3f} s  {row.event} {row.data}")
        if len(chosen) > 10:
            lines.append(f"  ... and {len(chosen) - 10} more")
        return "\n".join(lines)

    def _first_time(
        self, condition: Callable[[list[Kilobot]], bool], until_s: float, check_s: float
    ) -> float | None:
        sim = self.sim
        programs = sim.robots
        if condition(programs):
            return self.t_s
        with busy_watchdog(self.watchdog_s):
            while sim.env.now < until_s:
                sim.run(min(until_s, sim.env.now + check_s))
                if condition(programs):
                    return self.t_s
        return None

    def eventually(
        self,
        condition: Callable[[list[Kilobot]], bool],
        *,
        within_s: float,
        check_s: float = 0.1,
        what: str | None = None,
    ) -> float:
        """Run the swarm on until ``condition(programs)`` holds, at most ``within_s`` more
        simulated seconds, checking every ``check_s``; return the time it first held (the run
        stops there).

        Raises
        ------
        AssertionError
            If it never held; the message shows every robot's state (:meth:`explain`).
        ScriptError
            If ``within_s`` is negative or ``check_s`` not positive.
        """
        __tracebackhide__ = True
        _check_durations("eventually", within_s, check_s)
        start = self.t_s
        held = self._first_time(condition, start + within_s, check_s)
        if held is None:
            raise AssertionError(
                f"{what or condition_text(condition)} did not hold within {within_s:g} s "
                f"(from {start:.3f} to {self.t_s:.3f} s)\n{self.explain()}"
            )
        return held

    def never(
        self,
        condition: Callable[[list[Kilobot]], bool],
        *,
        for_s: float,
        check_s: float = 0.1,
        what: str | None = None,
    ) -> None:
        """Run the swarm on for ``for_s`` simulated seconds, checking every ``check_s`` that
        ``condition(programs)`` never holds.

        Raises
        ------
        AssertionError
            At the first check it held; the message shows every robot's state then.
        ScriptError
            If ``for_s`` is negative or ``check_s`` not positive.
        """
        __tracebackhide__ = True
        _check_durations("never", for_s, check_s)
        start = self.t_s
        held = self._first_time(condition, start + for_s, check_s)
        if held is not None:
            raise AssertionError(
                f"{what or condition_text(condition)} held at {held:.3f} s "
                f"({held - start:.3f} s into the {for_s:g} s from {start:.3f} s)\n"
                f"{self.explain()}"
            )


def _check_durations(name: str, span_s: float, check_s: float) -> None:
    if not span_s >= 0:
        raise ScriptError(f"{name}(): give a duration >= 0 s, got {span_s}")
    if not check_s > 0:
        raise ScriptError(f"{name}(check_s={check_s}): give a check period > 0 s")


def run_swarm(
    program: type[Kilobot] | Callable[[int], Kilobot],
    placement: str | Sequence[Sequence[float]] | np.ndarray = "hex",
    *,
    robots: int | None = None,
    params: Params | Mapping[str, Any] | None = None,
    seed: int | None = None,
    until_s: float | None = None,
    stop_when: Callable[[list[Kilobot]], bool] | None = None,
    uids: Sequence[int] | None = None,
    headings_rad: Sequence[float] | None = None,
    watchdog_s: float = BUSY_CALL_S,
) -> SwarmResult:
    """Run a small swarm and hand back what it did.

    Parameters
    ----------
    program : Kilobot subclass or callable
        Every robot runs the class, or ``program(index)`` builds robot ``index``'s program.
    placement : str or (N, 2) array-like
        Start positions in mm, or a layout of :data:`kilonet.scenarios.placement.LAYOUTS`
        (``"hex"``,
        ``"line"``, ``"random"``) generated by the scenarios' generators with the parameters'
        ``placement.*`` values (spacing, jitter, density, area) from the run's placement
        stream, as scenarios place robots.
    robots : int, optional
        Number of robots of a named layout (default ``placement.robots``).
    params : Params or dict, optional
        A :class:`~kilonet.params.Params`, or dotted overrides of the kernel's defaults.
    seed : int, optional
        Seed of the run (default: the parameters' own).
    until_s : float, optional
        Simulated time to run to (default ``duration_s``, 60 s).
    stop_when : callable, optional
        ``stop_when(programs) -> bool``, checked every simulated second; the run ends as soon
        as it holds.
    uids : sequence of int, optional
        Each robot's ``kilo_uid`` (default: its index), as a placement's ``uid`` column.
    headings_rad : sequence of float, optional
        Each robot's start heading, counter-clockwise from +x (default: drawn at random from
        the run's seed, as scenarios start).
    watchdog_s : float
        Wall-clock seconds one call into a program may run while simulated time stands still
        (a ``while True`` in ``loop``) before it is stopped (default 30; 0: never).

    Raises
    ------
    ScriptError
        If a named layout has no size, ``robots`` disagrees with the placement given,
        ``uids`` or ``headings_rad`` do not give one value per robot, or ``until_s`` is not a
        positive number of seconds.
    BusyCallError
        If a call into a program runs ``watchdog_s`` of wall time without returning.
    ValueError
        If the layout's generator refuses its parameters (e.g. robots that would overlap).

    Examples
    --------
    >>> from kilonet.message import Layout
    >>> HOPS = Layout("hops", type=1, fields=[("hops", "B")])
    >>> class Hops(Kilobot):
    ...     def __init__(self, source):
    ...         self.hops = 0 if source else 255
    ...     def message_rx(self, message, distance_mm):
    ...         self.hops = min(self.hops, HOPS.unpack(message).hops + 1)
    ...     def message_tx(self):
    ...         return HOPS.pack(hops=self.hops) if self.hops < 255 else None
    >>> result = run_swarm(lambda i: Hops(source=i == 0), "line", robots=4,
    ...                    params={"placement.spacing_mm": 100},  # 200 mm: beyond reach
    ...                    stop_when=lambda programs: all(p.hops < 255 for p in programs))
    >>> result.stopped, [p.hops for p in result.programs]
    (True, [0, 1, 2, 3])
    >>> result.state_frame().hops.tolist()
    [0, 1, 2, 3]
    """
    if until_s is not None and not until_s > 0:
        raise ScriptError(
            f"run_swarm(): until_s must be a positive number of seconds, got {until_s}"
        )
    p = build_params(params, seed)
    if isinstance(placement, str):
        n = robots or p.placement.robots
        if not n:
            raise ScriptError(
                f"run_swarm(): layout {placement!r} needs a size: robots=N "
                f"(layouts: {', '.join(LAYOUTS)})"
            )
        positions = generate_from(p.placement, placement, n, stream_for(p.seed, "placement"))
    else:
        positions = np.asarray(placement, dtype=float)
        if robots is not None and robots != len(positions):
            raise ScriptError(
                f"run_swarm(): robots={robots} but the placement has {len(positions)} robots"
            )
    for name, values in (("uids", uids), ("headings_rad", headings_rad)):
        if values is not None and len(values) != len(positions):
            raise ScriptError(
                f"run_swarm(): {name} gives {len(values)} values for {len(positions)} robots"
            )
    sim = Simulation(positions, program, p, uids=uids, headings_rad=headings_rad)
    stop = None if stop_when is None else (lambda: stop_when(sim.robots))
    with busy_watchdog(watchdog_s):
        sim.run(until_s, stop_when=stop)
    return SwarmResult(sim, stopped=stop is not None and bool(stop()), watchdog_s=watchdog_s)
