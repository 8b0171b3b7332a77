"""Named scenarios: a placement, parameters and robot programs, glued into a runnable whole.

A :class:`Scenario` says which program each robot runs, its own parameter section, its default
swarm size and duration, and the metrics it reports against ground truth. :func:`run` builds
the parameters and the placement, runs the simulation and returns a :class:`RunResult`;
:func:`write_outputs` writes a run directory. The CLI and the sweep runner call these.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from kilonet.params import ParamError, Params
from kilonet.placement import generate, load_csv
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation, stream_for
from scenarios.thesis_placements import NAMED_PLACEMENTS, PREMISE

__all__ = [
    "RunResult",
    "Scenario",
    "ScenarioError",
    "build_params",
    "place",
    "run",
    "write_outputs",
]


class ScenarioError(ValueError):
    """A scenario name, file or option is unusable; the message says which and why."""


ProgramFactory = Callable[[int], Kilobot]


@dataclass(frozen=True)
class Scenario:
    """A runnable experiment setting.

    Parameters
    ----------
    name, summary : str
        Name on the command line and a one-line description.
    program : callable
        ``program(params, positions_mm) -> (index -> Kilobot)``: the programs to flash.
    section : type, optional
        Frozen dataclass of the scenario's own parameters (class attribute ``section_name``).
    robots : int
        Default swarm size.
    defaults : dict
        Kernel parameter defaults this scenario changes (dotted keys), e.g. its duration.
    placement : callable, optional
        ``placement(params, n, rng) -> positions_mm`` used when ``placement.kind`` is
        ``scenario`` (default: a jittered hex lattice).
    metrics : callable, optional
        ``metrics(sim) -> dict`` of scenario figures against ground truth, added to the summary.
    stop_when : callable, optional
        ``stop_when(sim) -> bool`` ends the run early (checked every simulated second).
    outputs : callable, optional
        ``outputs(result, out_dir)`` writes scenario files (figures, extra tables).
    robot_columns : callable, optional
        ``robot_columns(sim) -> DataFrame`` with a ``robot`` column: scenario columns joined
        to the robots table.
    """

    name: str
    summary: str
    program: Callable[[Params, np.ndarray], ProgramFactory]
    section: type | None = None
    robots: int = 100
    defaults: dict[str, Any] = field(default_factory=dict)
    placement: Callable[[Params, int, np.random.Generator], np.ndarray] | None = None
    metrics: Callable[[Simulation], dict[str, Any]] | None = None
    stop_when: Callable[[Simulation], bool] | None = None
    outputs: Callable[[RunResult, Path], None] | None = None
    robot_columns: Callable[[Simulation], Any] | None = None


@dataclass
class RunResult:
    """A finished run: its scenario, parameters, simulation and summary figures."""

    scenario: Scenario
    params: Params
    sim: Simulation
    summary: dict[str, Any]


def build_params(
    scenario: Scenario, overrides: dict[str, Any] | None = None, *, seed: int | None = None
) -> Params:
    """Default parameters, then the scenario's defaults, then ``overrides`` (dotted keys).

    Raises
    ------
    kilonet.params.ParamError
        For an unknown key or an invalid value.
    """
    params = Params(scenario=scenario.section() if scenario.section else None)
    params = params.with_overrides(scenario.defaults)
    params = params.with_overrides(dict(overrides or {}))
    if seed is not None:
        params = params.with_overrides({"seed": seed})
    return params


def place(
    scenario: Scenario, params: Params, placement: str | Path | np.ndarray | None = None
) -> np.ndarray:
    """The robots' start positions (mm): a named placement, file or array if given, else a
    generator. A string that names a placement of
    :data:`scenarios.thesis_placements.NAMED_PLACEMENTS` (``"thesis-7.1a"``) is that placement,
    whether or not a file of that name exists.

    Raises
    ------
    kilonet.placement.PlacementError
        If the file or array is not a valid placement.
    kilonet.params.ParamError
        If a generator cannot place the robots with its parameters (density too high).
    """
    if isinstance(placement, str) and placement in NAMED_PLACEMENTS:
        return NAMED_PLACEMENTS[placement]()
    if isinstance(placement, str | Path):
        return load_csv(placement)
    if placement is not None:
        return np.asarray(placement, dtype=float)
    p = params.placement
    n = p.robots or scenario.robots
    rng = stream_for(params.seed, "placement")
    try:
        if p.kind == "scenario" and scenario.placement is not None:
            return scenario.placement(params, n, rng)
        return generate(
            "hex" if p.kind == "scenario" else p.kind,
            n,
            rng=rng,
            spacing_mm=p.spacing_mm,
            jitter_mm=p.jitter_mm,
            density_per_m2=p.density_per_m2,
            area=p.area,
        )
    except ValueError as exc:  # a generator refusing its parameters is the user's to fix
        raise ParamError(f"placement ({p.kind}, {n} robots): {exc}") from None


def run(
    scenario: Scenario,
    overrides: dict[str, Any] | None = None,
    *,
    seed: int | None = None,
    placement: str | Path | np.ndarray | None = None,
    progress: bool = False,
) -> RunResult:
    """Run ``scenario`` once and return its result.

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
    progress : bool
        Show a progress bar on stderr (simulated seconds).
    """
    if isinstance(placement, str) and placement in NAMED_PLACEMENTS:
        overrides = {**PREMISE, **(overrides or {})}  # the thesis's cases assume it
    params = build_params(scenario, overrides, seed=seed)
    positions = place(scenario, params, placement)
    sim = Simulation(positions, scenario.program(params, positions), params)
    stop_when = (lambda: scenario.stop_when(sim)) if scenario.stop_when else None
    _run_with_progress(sim, params.duration_s, stop_when, progress)
    summary = {"scenario": scenario.name, **sim.summary()}
    if scenario.metrics is not None:
        summary.update(scenario.metrics(sim))
    return RunResult(scenario, params, sim, summary)


def _run_with_progress(
    sim: Simulation, duration_s: float, stop_when: Callable[[], bool] | None, progress: bool
) -> None:
    with tqdm(
        total=round(duration_s, 3),
        unit="sim s",
        file=sys.stderr,
        disable=not progress,
        bar_format="{l_bar}{bar}| {n:.0f}/{total:.0f} sim s [{elapsed}<{remaining}]",
    ) as bar:
        # Check the stop condition every simulated second; otherwise update about 200 times.
        step = 1.0 if stop_when is not None else max(duration_s / 200, 0.5)
        while sim.env.now < duration_s:
            sim.run(min(duration_s, sim.env.now + step))
            bar.update(round(sim.env.now - bar.n, 3))
            if stop_when is not None and stop_when():
                break


def write_outputs(result: RunResult, out_dir: str | Path, *, fmt: str = "csv") -> list[Path]:
    """Write a run directory: tables (CSV or Parquet), ``summary.json``, ``params.json`` and
    the scenario's own files. Written to a temporary directory first and moved into place, so a
    failure leaves no partial output.

    Returns the paths written.

    Raises
    ------
    ScenarioError
        If ``fmt`` is not ``csv`` or ``parquet``, or ``out_dir`` exists and is not a directory.
    """
    if fmt not in ("csv", "parquet"):
        raise ScenarioError(f"--format must be csv or parquet, not {fmt!r}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ScenarioError(f"{out} exists and is not a directory")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        sim = result.sim
        robots = sim.robots_frame()
        if result.scenario.robot_columns is not None:
            robots = robots.merge(result.scenario.robot_columns(sim), on="robot", how="left")
        tables = {"robots": robots, **sim.trace.frames()}
        for name, frame in tables.items():
            if fmt == "csv":
                frame.to_csv(tmp / f"{name}.csv", index=False)
            else:
                frame.to_parquet(tmp / f"{name}.parquet", index=False)
        (tmp / "summary.json").write_text(json.dumps(result.summary, indent=2) + "\n")
        flat = {k: v for k, v in result.params.to_flat_dict().items()}
        (tmp / "params.json").write_text(json.dumps(flat, indent=2, default=str) + "\n")
        if result.scenario.outputs is not None:
            result.scenario.outputs(result, tmp)
        out.mkdir(exist_ok=True)
        written = []
        for path in sorted(tmp.iterdir()):
            target = out / path.name
            if target.is_dir():
                shutil.rmtree(target)
            path.replace(target)
            written.append(target)
        return written
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
