"""Named scenarios: a placement, parameters and robot programs, glued into a runnable whole.

A :class:`Scenario` is three parts: what builds a run (:class:`Setup`: which program each robot
runs, its own parameter section, its default swarm size and duration, its placement, when it
stops, its ``kilonet run`` options), what reports it (:class:`Reporting`: the metrics against
ground truth, the robots table's columns, what the progress display says) and what draws it
(:class:`Drawing`: its figures). :func:`build_params` builds a run's parameters once;
:func:`run_with_params` places the robots, runs the simulation and returns a :class:`RunResult`
(:func:`run` does both); :func:`write_outputs` writes a run directory. The command line and the
sweep runner call these.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.errors import UserError
from kilonet.params import ParamError, Params
from kilonet.placement import PlacementError, load_csv, read_placement
from kilonet.robot import Kilobot
from kilonet.scenarios.output_dir import OutputDir
from kilonet.scenarios.placement import generate_from
from kilonet.scenarios.progress import RunProgress
from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS, PREMISE

if TYPE_CHECKING:
    import pandas as pd

    from kilonet.simulation import Simulation

__all__ = [
    "AfterRunError",
    "Drawing",
    "Reporting",
    "RunResult",
    "Scenario",
    "ScenarioError",
    "ScenarioOption",
    "Setup",
    "after_the_run",
    "build_params",
    "json_safe",
    "place",
    "placement_uids",
    "run",
    "run_with_params",
    "write_outputs",
    "write_run_files",
]


class ScenarioError(UserError, ValueError):
    """A scenario name, file or option is unusable; the message says which and why."""


class AfterRunError(UserError):
    """A step after a finished run (the scenario's figures, the animation) failed; the run's
    tables and summary are written all the same. The message says which step and why."""


@contextmanager
def after_the_run(directory: str | Path, what: str) -> Iterator[None]:
    """A step after a finished run that must not cost the run: if the block fails, what it
    left in ``directory`` is removed and :class:`AfterRunError` raised, so that the caller
    can keep the run and report the failure in one line.

    Parameters
    ----------
    directory : path
        The run directory the step writes into.
    what : str
        The step's output in words, first in the message (``"animation.gif"``).

    Raises
    ------
    AfterRunError
        If the block raised: for an ``OSError`` (a full or read-only disk) the system's reason,
        for a :class:`~kilonet.errors.UserError` its message, for anything else (a bug, chained
        as the cause) the exception's type and message.
    """
    directory = Path(directory)
    before = set(directory.iterdir())
    try:
        yield
    except Exception as exc:
        for left in set(directory.iterdir()) - before:
            if left.is_dir() and not left.is_symlink():
                shutil.rmtree(left, ignore_errors=True)
            else:
                left.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            why = exc.strerror or str(exc)
        elif isinstance(exc, UserError):
            why = str(exc)
        else:
            why = f"{type(exc).__name__}: {exc}"
        raise AfterRunError(f"{what} not written ({why}); the run itself is written") from exc


@dataclass(frozen=True)
class ScenarioOption:
    """An option of ``kilonet run`` that a scenario declares: ``flag`` sets parameter ``key``.

    ``kilonet run --until frames`` is ``--set gcs.until=frames``; the allowed values and the
    default come from the parameter's declaration, and other scenarios refuse the option.
    """

    flag: str
    key: str
    help: str


ProgramFactory = Callable[[int], Kilobot]


@dataclass(frozen=True)
class Setup:
    """What builds a run of a scenario: its programs, parameters and placement.

    Parameters
    ----------
    program : callable
        ``program(params, positions_mm) -> (index -> Kilobot)``: the programs to flash.
    hardware : callable, optional
        ``hardware(params, positions_mm) -> {name: fit}``: extra hardware the robots carry
        (a maze robot's camera, wall sensor and drive), the ``hardware`` argument of
        :class:`~kilonet.simulation.Simulation`; called after ``program``.
    section : type, optional
        Frozen dataclass of the scenario's own parameters (class attribute ``section_name``).
    robots : int
        Default swarm size.
    defaults : dict
        Kernel parameter defaults this scenario changes (dotted keys), e.g. its duration.
    supports : dict
        Parameters whose values its programs are written for, each with those values
        (dotted key -> tuple); any other value is refused when the parameters are built. E.g.
        ``{"medium.message_format": ("kilolib",)}``: the thesis's 23 bits hold no type byte
        and too few bytes for the messages; ``{"robot.rx_mode": ("callback",)}``: a program
        that only implements ``message_rx`` hears nothing from a polled buffer.
    placement : callable, optional
        ``placement(params, n, rng) -> positions_mm`` used when ``placement.kind`` is
        ``scenario`` (default: a jittered hex lattice).
    stop_when : callable, optional
        ``stop_when(sim) -> bool`` ends the run early (checked every simulated second).
    options : tuple of ScenarioOption
        Options of ``kilonet run`` that set this scenario's parameters (``--until``).
    """

    program: Callable[[Params, np.ndarray], ProgramFactory]
    hardware: (
        Callable[[Params, np.ndarray], Mapping[str, Callable[[Simulation, int], Any]]] | None
    ) = None
    section: type | None = None
    robots: int = 100
    defaults: dict[str, Any] = field(default_factory=dict)
    supports: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    placement: Callable[[Params, int, np.random.Generator], np.ndarray] | None = None
    stop_when: Callable[[Simulation], bool] | None = None
    options: tuple[ScenarioOption, ...] = ()


@dataclass(frozen=True)
class Reporting:
    """What reports a run of a scenario: its figures in the summary and the robots table, and
    what the progress display says while it runs.

    Parameters
    ----------
    metrics : callable, optional
        ``metrics(sim) -> dict`` of scenario figures against ground truth, added to the summary.
    robot_columns : callable, optional
        ``robot_columns(sim) -> DataFrame`` with a ``robot`` column: scenario columns joined
        to the robots table (one named like a kernel column, ``uid``, replaces it).
    expected_end_s : callable, optional
        ``expected_end_s(params) -> float or None``: the simulated time the run will end at,
        when the scenario knows it before the run (``None``: only ``stop_when`` will tell).
        Without it a run is expected to last ``duration_s`` unless it has a ``stop_when``.
    ends_when : str
        What ``stop_when`` waits for, in words, for the progress display
        ("the follower arrives or gives up").
    progress_note : callable, optional
        ``progress_note(sim) -> str``: where the run is (the current phase), for the progress
        display.
    """

    metrics: Callable[[Simulation], dict[str, Any]] | None = None
    robot_columns: Callable[[Simulation], Any] | None = None
    expected_end_s: Callable[[Params], float | None] | None = None
    ends_when: str = ""
    progress_note: Callable[[Simulation], str] | None = None


@dataclass(frozen=True)
class Drawing:
    """What draws a finished run of a scenario.

    Parameters
    ----------
    figures : callable, optional
        ``figures(result, out_dir)`` writes the scenario's own files into the run directory
        (figures, extra tables); a failure costs only these (:func:`after_the_run`).
    """

    figures: Callable[[RunResult, Path], None] | None = None


@dataclass(frozen=True)
class Scenario:
    """A runnable experiment setting: what builds a run, what reports it and what draws it.

    Parameters
    ----------
    name, summary : str
        Name on the command line and a one-line description.
    setup : Setup
        Its programs, parameters and placement.
    reporting : Reporting
        Its summary figures, robots table columns and progress display.
    drawing : Drawing
        Its figures.
    """

    name: str
    summary: str
    setup: Setup
    reporting: Reporting = field(default_factory=Reporting)
    drawing: Drawing = field(default_factory=Drawing)


@dataclass
class RunResult:
    """A finished run: its scenario, parameters, simulation and summary figures."""

    scenario: Scenario
    params: Params
    sim: Simulation
    summary: dict[str, Any]


def build_params(
    scenario: Scenario,
    overrides: dict[str, Any] | None = None,
    *,
    seed: int | None = None,
    placement: str | Path | np.ndarray | None = None,
) -> Params:
    """Default parameters, then the scenario's defaults, then ``overrides`` (dotted keys): the
    parameters of a run, built once and passed to :func:`run_with_params`.

    A ``placement`` that names one of :data:`~kilonet.scenarios.thesis_placements.NAMED_PLACEMENTS`
    brings the thesis's premise along (:data:`~kilonet.scenarios.thesis_placements.PREMISE`,
    under ``overrides``): its cases assume it.

    Raises
    ------
    kilonet.params.ParamError
        For an unknown key or an invalid value, or a value the scenario's programs are not
        written for (:attr:`Setup.supports`).
    """
    if isinstance(placement, str) and placement in NAMED_PLACEMENTS:
        overrides = {**PREMISE, **(overrides or {})}
    setup = scenario.setup
    params = Params(scenario=setup.section() if setup.section else None)
    params = params.with_overrides(setup.defaults)
    params = params.with_overrides(dict(overrides or {}))
    if seed is not None:
        params = params.with_overrides({"seed": seed})
    flat = params.to_flat_dict()
    for key, allowed in setup.supports.items():
        if flat[key] not in allowed:
            raise ParamError(
                f"{key} = {flat[key]!r}: the {scenario.name} scenario's programs are written "
                f"for {' or '.join(map(repr, allowed))} only"
            )
    return params


def place(
    scenario: Scenario, params: Params, placement: str | Path | np.ndarray | None = None
) -> np.ndarray:
    """The robots' start positions (mm): a named placement, file or array if given, else a
    generator. A string that names a placement of
    :data:`kilonet.scenarios.thesis_placements.NAMED_PLACEMENTS` (``"thesis-7.1a"``) is that
    placement, whether or not a file of that name exists.

    Raises
    ------
    kilonet.placement.PlacementError
        If the file or array is not a valid placement.
    kilonet.params.ParamError
        If a generator cannot place the robots with its parameters (density too high), or
        ``placement.robots`` is set and differs from the number of robots in ``placement``
        (the two would contradict each other).
    """
    if placement is not None:
        positions = _given_placement(placement)
        wanted = params.placement.robots
        if wanted and wanted != len(positions):
            raise ParamError(
                f"placement.robots = {wanted} but the placement {_name(placement)} "
                f"has {len(positions)} robots; give one or the other"
            )
        return positions
    from kilonet.simulation import stream_for

    p = params.placement
    n = p.robots or scenario.setup.robots
    rng = stream_for(params.seed, "placement")
    try:
        if p.kind == "scenario" and scenario.setup.placement is not None:
            return scenario.setup.placement(params, n, rng)
        return generate_from(p, "hex" if p.kind == "scenario" else p.kind, n, rng)
    except ParamError:
        raise  # already names the parameters
    except ValueError as exc:  # a generator refusing its parameters is the user's to fix
        raise ParamError(f"placement ({p.kind}, {n} robots): {exc}") from None


def _given_placement(placement: str | Path | np.ndarray) -> np.ndarray:
    if isinstance(placement, str) and placement in NAMED_PLACEMENTS:
        return NAMED_PLACEMENTS[placement]()
    if isinstance(placement, str | Path):
        return load_csv(placement)
    return np.asarray(placement, dtype=float)


def placement_uids(placement: str | Path | np.ndarray | None) -> tuple[int, ...] | None:
    """The hardware UIDs a placement file gives in its ``uid`` column (``None`` for a file
    without one, a named or generated placement, or an array).

    Raises
    ------
    kilonet.placement.PlacementError
        If the file is not a valid placement, or gives one uid to two robots.
    """
    if isinstance(placement, str) and placement in NAMED_PLACEMENTS:
        return None
    if isinstance(placement, str | Path):
        uids = read_placement(placement).uids
        if uids is not None:
            first: dict[int, int] = {}
            for row, uid in enumerate(uids):
                if uid in first:
                    raise PlacementError(
                        f"{placement}: uid {uid} is given to data rows {first[uid] + 1} and "
                        f"{row + 1}; each robot's kilo_uid must be its own (leave the uid "
                        "column out for uids 0, 1, 2, ... in row order)"
                    )
                first[uid] = row
        return uids
    return None


def _name(placement: str | Path | np.ndarray) -> str:
    return str(placement) if isinstance(placement, str | Path) else "array"


def run(
    scenario: Scenario,
    overrides: dict[str, Any] | None = None,
    *,
    seed: int | None = None,
    placement: str | Path | np.ndarray | None = None,
    progress: bool | str = False,
) -> RunResult:
    """Run ``scenario`` once and return its result: :func:`build_params`, then
    :func:`run_with_params`.

    Parameters
    ----------
    scenario : Scenario
        What to run.
    overrides : dict, optional
        Dotted parameter keys to set (``{"medium.loss_prob": 0.2}``).
    seed : int, optional
        Master seed (overrides ``seed`` in ``overrides``).
    placement : name, path or (N, 2) array, optional
        Start positions in mm instead of the scenario's generator.
    progress : bool or str
        Show on stderr what the set-up is doing, then the run's progress in simulated seconds
        (:class:`kilonet.scenarios.progress.RunProgress`): a mode of
        :data:`kilonet.scenarios.progress.MODES`, ``True`` for the bar, ``False`` for nothing.
    """
    params = build_params(scenario, overrides, seed=seed, placement=placement)
    return run_with_params(scenario, params, placement=placement, progress=progress)


def run_with_params(
    scenario: Scenario,
    params: Params,
    *,
    placement: str | Path | np.ndarray | None = None,
    progress: bool | str = False,
) -> RunResult:
    """Run ``scenario`` once with ``params`` as :func:`build_params` built them (for the same
    ``placement``), so that a caller that checks them first (``kilonet run``) builds them once.

    ``placement`` and ``progress`` are :func:`run`'s.

    Raises
    ------
    kilonet.placement.PlacementError, kilonet.params.ParamError
        If the placement is not valid or does not fit the parameters (:func:`place`).
    """
    from kilonet.simulation import Simulation

    # A placement given is read (and refused) before anything is shown; a generated one is a
    # set-up stage, which can be long for a large swarm.
    positions = None if placement is None else place(scenario, params, placement)
    uids = placement_uids(placement)
    with RunProgress(
        scenario.name,
        expected_end_s=_expected_end_s(scenario, params),
        cap_s=params.duration_s,
        ends_when=scenario.reporting.ends_when,
        enabled=progress,
    ) as bar:
        if positions is None:
            bar.stage("placing robots")
            positions = place(scenario, params)
        bar.stage(f"building {len(positions):,} robots")
        setup = scenario.setup
        program = setup.program(params, positions)
        hardware = setup.hardware(params, positions) if setup.hardware else None
        sim = Simulation(positions, program, params, uids=uids, hardware=hardware)
        bar.stage("starting")
        sim.start()  # every robot's setup(), also for a run of zero seconds
        bar.stage("running")
        _run(sim, scenario, params.duration_s, bar)
        bar.stage("scoring")  # the summary and the scenario's metrics take long for a big swarm
        summary = {"scenario": scenario.name, **sim.summary()}
        if scenario.reporting.metrics is not None:
            summary.update(scenario.reporting.metrics(sim))
    return RunResult(scenario, params, sim, summary)


def _expected_end_s(scenario: Scenario, params: Params) -> float | None:
    if scenario.reporting.expected_end_s is not None:
        end = scenario.reporting.expected_end_s(params)
    else:
        end = None if scenario.setup.stop_when is not None else params.duration_s
    return None if end is None else min(end, params.duration_s)


def _run(sim: Simulation, scenario: Scenario, duration_s: float, bar: RunProgress) -> None:
    stop_when = scenario.setup.stop_when
    note = scenario.reporting.progress_note
    # Check the stop condition every simulated second; otherwise update about 200 times.
    step = 1.0 if stop_when is not None else max(duration_s / 200, 0.5)
    while sim.env.now < duration_s:
        sim.run(min(duration_s, sim.env.now + step))
        bar.update(sim.env.now, note(sim) if note is not None else "")
        if stop_when is not None and stop_when(sim):
            break


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by ``None``, so that the
    JSON written is valid JSON (``null``) rather than Python's ``NaN``.

    Examples
    --------
    >>> json_safe({"rmse_mm": float("nan"), "frames": [1, float("inf")], "ok": 2.5})
    {'rmse_mm': None, 'frames': [1, None], 'ok': 2.5}
    """
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


def write_run_files(
    result: RunResult,
    directory: str | Path,
    *,
    fmt: str = "csv",
    stage: Callable[[str], None] | None = None,
) -> list[Path]:
    """Write a run's files into ``directory`` (which exists): tables (CSV or Parquet),
    ``summary.json``, ``params.json``, then the scenario's own files (figures). Returns the
    paths written.

    Parameters
    ----------
    stage : callable, optional
        Called with each step's name (``"writing tables"``) before it starts, for a progress
        display (:class:`kilonet.scenarios.progress.StageProgress`).

    Raises
    ------
    ScenarioError
        If ``fmt`` is not ``csv`` or ``parquet``.
    OSError
        If a table or the summary cannot be written.
    AfterRunError
        If the scenario's own files cannot be written (:func:`after_the_run`: those it left
        are removed); the tables and the summary are written.
    """
    if fmt not in ("csv", "parquet"):
        raise ScenarioError(f"--format must be csv or parquet, not {fmt!r}")
    stage = stage or (lambda _what: None)
    out = Path(directory)
    sim = result.sim
    stage("writing tables")
    robots = sim.robots_frame()
    robots.insert(1, "uid", _final_uids(sim))
    robot_columns = result.scenario.reporting.robot_columns
    if robot_columns is not None:
        robots = _with_scenario_columns(robots, robot_columns(sim))
    traces = sim.trace.frames()
    if not result.params.trace.messages:
        del traces["messages"]  # recorded only with trace.messages: an empty table misleads
    tables = {"robots": robots, **traces, "led_key": sim.led_key_frame()}
    for name, frame in tables.items():
        if fmt == "csv":
            frame.to_csv(out / f"{name}.csv", index=False)
        else:
            frame.to_parquet(out / f"{name}.parquet", index=False)
    (out / "summary.json").write_text(json.dumps(json_safe(result.summary), indent=2) + "\n")
    flat = result.params.to_flat_dict()
    (out / "params.json").write_text(json.dumps(flat, indent=2, default=str) + "\n")
    figures = result.scenario.drawing.figures
    if figures is not None:
        stage(f"writing the {result.scenario.name} scenario's figures")
        with after_the_run(out, f"the {result.scenario.name} scenario's figures"):
            figures(result, out)
    return sorted(out.iterdir())


def _with_scenario_columns(robots: pd.DataFrame, extra: pd.DataFrame) -> pd.DataFrame:
    """The robots table with a scenario's columns (``robot_columns``) joined on ``robot``.

    A scenario column named like a kernel column takes that column's place instead of
    beside it (a merge would give ``uid_x`` and ``uid_y``): gcs and localize robots have no
    ``kilo_uid`` (``robot.hardware_uids = false``) and their ``uid`` is the ID each robot
    chose for itself.
    """
    shared = [c for c in extra.columns if c != "robot" and c in robots.columns]
    joined = robots.merge(extra, on="robot", how="left", suffixes=("", "_scenario"))
    for column in shared:
        joined[column] = joined.pop(f"{column}_scenario")
    return joined


def _final_uids(sim: Simulation) -> list[int | None]:
    """Each robot's ``kilo_uid`` at the end of the run (the placement's, its index, or what
    the program set), ``None`` where it has none (``robot.hardware_uids = false``)."""
    out: list[int | None] = []
    for robot in sim.robots:
        try:
            out.append(robot.kilo_uid)
        except AttributeError:
            out.append(None)
    return out


def write_outputs(
    result: RunResult, out_dir: str | Path, *, fmt: str = "csv", replace: bool = False
) -> list[Path]:
    """Write a run directory whole (:func:`write_run_files` into a staging directory that
    :class:`kilonet.scenarios.output_dir.OutputDir` then puts in place): a failure leaves nothing
    behind, and an existing directory is never merged into.

    Returns the paths written.

    Raises
    ------
    ScenarioError
        If ``fmt`` is not ``csv`` or ``parquet``.
    AfterRunError
        If the scenario's own files (figures) cannot be written: the run directory is put in
        place without them first.
    kilonet.scenarios.output_dir.OutputDirError
        If ``out_dir`` exists and is not empty (without ``replace``), is not a directory, or
        cannot be created or written.
    """
    if fmt not in ("csv", "parquet"):
        raise ScenarioError(f"--format must be csv or parquet, not {fmt!r}")
    with OutputDir(out_dir, replace=replace) as out:
        try:
            names = [p.name for p in write_run_files(result, out.staging, fmt=fmt)]
        except AfterRunError:
            out.publish()  # a finished run is kept when its figures fail
            raise
        target = out.publish()
    return [target / name for name in names]
