"""Sweep definitions: which scenario, which parameters fixed, which swept, over which seeds.

A sweep file is TOML::

    name = "loss"                        # optional; default: the file's stem
    description = "Gradient under message loss"
    scenario = "gradient"                # a name from ``kilonet scenarios``, or instead:
    # program = "leader.py:Leader"       # your own program (path relative to this file)
    seeds = 20                           # 1..20; or [3, 5, 8]; or {first = 100, count = 20}

    [fixed]                              # parameters of every run (dotted keys or sub-tables)
    duration_s = 30.0
    "placement.robots" = 100

    [grid]                               # every combination of these values (Cartesian product)
    "medium.loss_prob" = {start = 0.0, stop = 0.4, num = 9}    # or {start, stop, step}
    "medium.range_mm" = [70.0, 85.0]     # or an explicit list

    [[cases]]                            # optional: explicit parameter sets, each crossed with
    "placement.kind" = "hex"             # the grid (for parameters that must change together)

    [report]                             # optional: what ``kilonet report`` plots
    x = "medium.loss_prob"               # x axis (default: the first swept parameter)
    metrics = ["gradient_correct_fraction", "last_change_s"]
    xscale = "linear"                    # or "log"

A program file (``program = "FILE.py[:ClassName]"``, ``scenario`` left out or ``"program"``)
is swept like a scenario: its declared settings are the keys ``program.NAME``
(``"program.patience_ticks" = [31, 62]``), and ``placement.robots`` must give the swarm. The
sweep stores it as ``program:/absolute/FILE.py:ClassName@SHA256``
(:func:`kilonet.scenarios.program.program_key`): every worker, local or on a Dask cluster,
loads the file by that path and refuses it if it changed since.

A *cell* is one combination of swept values; a *run* is a cell with one seed. Every parameter
value is checked against the scenario's parameters before anything runs, and every error names
the file and the key. A sweep has at most :data:`MAX_RUNS` runs.

Examples
--------
>>> sweep = parse_sweep('''
... scenario = "gradient"
... seeds = 2
... [fixed]
... duration_s = 5.0
... [grid]
... "medium.loss_prob" = {start = 0.0, stop = 0.2, num = 3}
... ''', name="demo")
>>> sweep.grid
{'medium.loss_prob': [0.0, 0.1, 0.2]}
>>> len(sweep.cells()), len(sweep.runs())
(3, 6)
>>> sweep.runs()[1].overrides
{'duration_s': 5.0, 'medium.loss_prob': 0.1}
>>> parse_sweep('scenario = "gradient"\\n[grid]\\n"medium.loss_prob" = [0.5, 2.0]', name="bad")
Traceback (most recent call last):
...
kilonet.experiments.sweep.SweepError: bad: [grid] medium.loss_prob = 2.0 is out of range [0.0, 1.0]
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

__all__ = ["MAX_RUNS", "MAX_SEED", "Run", "Sweep", "SweepError", "load_sweep", "parse_sweep"]

_TOP_KEYS = (
    "name",
    "description",
    "scenario",
    "program",
    "seeds",
    "fixed",
    "grid",
    "cases",
    "report",
)
_RANGE_KEYS = frozenset({"start", "stop", "num", "step", "log"})
_REPORT_KEYS = ("x", "metrics", "xscale")
#: Grid values are rounded to this many significant digits so that 0.1 + 0.2 is stored as 0.3.
_SIGNIFICANT_DIGITS = 12
#: Most runs a sweep may have (and values a range or seed count may give): a range with a tiny
#: step would otherwise build billions of values before anything is checked.
MAX_RUNS = 100_000
#: Largest seed a sweep may have: the results store keeps seeds as SQLite (signed 64-bit)
#: integers.
MAX_SEED = 2**63 - 1


class SweepError(ValueError):
    """A sweep file is missing, malformed or names an invalid parameter; the message says
    which file and which key."""


@dataclass(frozen=True)
class Run:
    """One simulation of a sweep: a cell's parameters with one seed.

    Attributes
    ----------
    run_id : str
        Stable identity of the run (a hash of scenario, overrides and seed); the results store's
        key, so the same run is never stored twice.
    scenario : str
        Scenario name.
    cell : dict
        The swept parameters' values of this run (dotted keys).
    overrides : dict
        Every parameter this run sets: the fixed ones, then the cell's.
    seed : int
        Master seed.
    """

    run_id: str
    scenario: str
    cell: dict[str, Any]
    overrides: dict[str, Any]
    seed: int


@dataclass(frozen=True)
class ReportSpec:
    """What a report plots: the x-axis parameter, the metrics (empty: all that vary), the
    x scale."""

    x: str | None = None
    metrics: tuple[str, ...] = ()
    xscale: str = "linear"


@dataclass(frozen=True)
class Sweep:
    """A validated sweep definition; see the module docstring for the file format."""

    name: str
    scenario: str
    seeds: tuple[int, ...]
    fixed: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list[Any]] = field(default_factory=dict)
    cases: tuple[dict[str, Any], ...] = ()
    description: str = ""
    report: ReportSpec = field(default_factory=ReportSpec)

    @property
    def swept(self) -> list[str]:
        """The swept parameters (case keys first, then grid keys), in file order."""
        keys: list[str] = []
        for case in self.cases:
            keys.extend(k for k in case if k not in keys)
        keys.extend(k for k in self.grid if k not in keys)
        return keys

    def cells(self) -> list[dict[str, Any]]:
        """Every combination of swept values: each case crossed with the grid."""
        names = list(self.grid)
        combos = [dict(zip(names, v, strict=True)) for v in itertools.product(*self.grid.values())]
        return [{**case, **combo} for case in (self.cases or ({},)) for combo in combos]

    def runs(self) -> list[Run]:
        """Every run, seed-major: all cells with the first seed, then the second, ... so that a
        partial sweep already covers every cell."""
        cells = self.cells()
        return [
            Run(
                run_id=run_id(self.scenario, {**self.fixed, **cell}, seed),
                scenario=self.scenario,
                cell=cell,
                overrides={**self.fixed, **cell},
                seed=seed,
            )
            for seed in self.seeds
            for cell in cells
        ]

    def definition(self) -> dict[str, Any]:
        """What determines the runs (scenario, fixed, grid, cases, seeds), as JSON-able data.
        Two sweeps with equal definitions run the same runs."""
        return {
            "scenario": self.scenario,
            "fixed": self.fixed,
            "grid": self.grid,
            "cases": list(self.cases),
            "seeds": list(self.seeds),
        }

    def to_dict(self) -> dict[str, Any]:
        """The whole sweep as JSON-able data (inverse: :meth:`from_dict`)."""
        return {
            "name": self.name,
            "description": self.description,
            **self.definition(),
            "report": {
                "x": self.report.x,
                "metrics": list(self.report.metrics),
                "xscale": self.report.xscale,
            },
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Sweep:
        """Rebuild a sweep stored with :meth:`to_dict` (no re-validation)."""
        report = data.get("report") or {}
        return cls(
            name=data["name"],
            scenario=data["scenario"],
            seeds=tuple(data["seeds"]),
            fixed=dict(data["fixed"]),
            grid={k: list(v) for k, v in data["grid"].items()},
            cases=tuple(dict(c) for c in data["cases"]),
            description=data.get("description", ""),
            report=ReportSpec(
                x=report.get("x"),
                metrics=tuple(report.get("metrics", ())),
                xscale=report.get("xscale", "linear"),
            ),
        )

    def differences(self, other: Sweep) -> list[str]:
        """The definition keys (``fixed``, ``grid``, ``cases``, ``seeds``, ``scenario``) in which
        ``other`` runs different runs than this sweep."""
        mine, theirs = _canonical(self.definition()), _canonical(other.definition())
        return [k for k in mine if json.dumps(mine[k]) != json.dumps(theirs[k])]


def run_id(scenario: str, overrides: dict[str, Any], seed: int) -> str:
    """Stable 16-hex-digit identity of a run, independent of key order.

    >>> run_id("gradient", {"b": 1, "a": 0.5}, 3) == run_id("gradient", {"a": 0.5, "b": 1}, 3)
    True
    >>> run_id("gradient", {"a": 0.5}, 3) == run_id("gradient", {"a": 0.5}, 4)
    False
    """
    text = json.dumps([scenario, _canonical(overrides), seed], sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _canonical(value: Any) -> Any:
    return json.loads(json.dumps(value, sort_keys=True))


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file.

    Raises
    ------
    SweepError
        If the file is missing, not TOML, or any key or value is invalid.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise SweepError(f"{path}: no such sweep file") from None
    except (IsADirectoryError, UnicodeDecodeError) as exc:
        raise SweepError(f"{path}: cannot read sweep file ({exc})") from None
    return parse_sweep(text, name=path.stem, where=str(path), folder=path.parent)


def parse_sweep(
    text: str, *, name: str, where: str | None = None, folder: str | Path = "."
) -> Sweep:
    """Parse and validate sweep TOML ``text``; ``name`` is the default sweep name, ``where``
    (default ``name``) prefixes every error message, and a ``program`` file is relative to
    ``folder`` (the sweep file's).

    Raises
    ------
    SweepError
        For invalid TOML, an unknown or missing key, a bad value, or a parameter the scenario
        rejects (the message names the key, e.g. ``[grid] medium.loss_prob``).
    """
    where = where or name
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SweepError(f"{where}: not valid TOML ({exc})") from None
    return _Validator(where, Path(folder)).sweep(data, name)


class _Validator:
    """Turns parsed TOML into a :class:`Sweep`, raising :class:`SweepError` naming the key."""

    def __init__(self, where: str, folder: Path = Path(".")) -> None:
        self.where = where
        self.folder = folder

    def fail(self, message: str) -> SweepError:
        return SweepError(f"{self.where}: {message}")

    def sweep(self, data: dict[str, Any], default_name: str) -> Sweep:
        unknown = [k for k in data if k not in _TOP_KEYS]
        if unknown:
            raise self.fail(f"unknown key {unknown[0]!r}; a sweep has: {', '.join(_TOP_KEYS)}")
        name = self.text(data, "name", default_name)
        description = self.text(data, "description", "")
        scenario_key, scenario = self.scenario(data)
        seeds = self.seeds(data.get("seeds", 1))
        fixed = self.flat_table(data, "fixed")
        if "seed" in fixed:
            raise self.fail("[fixed] seed: set the seeds with the top-level key 'seeds'")
        grid = self.grid(data.get("grid", {}))
        cases = self.cases(data.get("cases", []))
        for key in grid:
            if key == "seed":
                raise self.fail("[grid] seed: sweep seeds with the top-level key 'seeds'")
            if key in fixed:
                raise self.fail(f"{key} is both in [fixed] and in [grid]; keep one")
        for i, case in enumerate(cases):
            for key in case:
                if key in fixed or key in grid or key == "seed":
                    raise self.fail(f"[[cases]] #{i + 1} {key} is also in [fixed] or [grid]")
        runs = len(seeds) * max(len(cases), 1) * math.prod(len(v) for v in grid.values())
        if runs > MAX_RUNS:
            raise self.fail(f"{runs} runs (cells x seeds); a sweep has at most {MAX_RUNS}")
        self.check_params(scenario, fixed, grid, cases)
        sweep = Sweep(
            name=name,
            scenario=scenario_key,
            seeds=seeds,
            fixed=fixed,
            grid=grid,
            cases=tuple(cases),
            description=description,
        )
        report = self.report(data.get("report", {}), sweep.swept)
        return replace(sweep, report=report)

    def text(self, data: dict[str, Any], key: str, default: str) -> str:
        value = data.get(key, default)
        if not isinstance(value, str):
            raise self.fail(f"{key} must be a string, not {value!r}")
        return value

    def scenario(self, data: dict[str, Any]) -> tuple[str, Any]:
        """The name the sweep stores for its scenario, and the scenario: a registered one, or
        the ``program`` file's (:func:`kilonet.scenarios.program.program_key`)."""
        from kilonet import scenarios
        from kilonet.scenarios.program import program_key

        if "program" in data:
            spec = self.text(data, "program", "")
            if data.get("scenario", "program") != "program":
                raise self.fail(
                    f"scenario = {data['scenario']!r} and program = {spec!r}: a sweep runs "
                    "one; leave one out"
                )
            try:
                key = program_key(spec, self.folder)
                return key, scenarios.get(key)
            except scenarios.ScenarioError as exc:
                raise self.fail(f"program: {exc}") from None
        if "scenario" not in data:
            raise self.fail(
                f"missing key 'scenario' (one of: {', '.join(scenarios.names())}) or "
                "'program' (FILE.py:ClassName)"
            )
        name = self.text(data, "scenario", "")
        if name == "program":
            raise self.fail(
                'scenario = "program" needs program = "FILE.py:ClassName" (relative to the '
                "sweep file)"
            )
        try:
            return name, scenarios.get(name)
        except scenarios.ScenarioError as exc:
            raise self.fail(f"scenario: {exc}") from None

    def seeds(self, raw: Any) -> tuple[int, ...]:
        if isinstance(raw, bool):
            raise self.fail(f"seeds must be a count, a list or {{first, count}}, not {raw!r}")
        if isinstance(raw, int):
            if raw < 1:
                raise self.fail(f"seeds = {raw}: need at least one seed")
            if raw > MAX_RUNS:
                raise self.fail(f"seeds = {raw}: at most {MAX_RUNS} seeds")
            return tuple(range(1, raw + 1))
        if isinstance(raw, dict):
            extra = set(raw) - {"first", "count"}
            if extra or not {"first", "count"} <= set(raw):
                raise self.fail(f"seeds table needs exactly 'first' and 'count', got {raw!r}")
            first, count = raw["first"], raw["count"]
            if not all(isinstance(v, int) and not isinstance(v, bool) for v in (first, count)):
                raise self.fail(f"seeds.first and seeds.count must be integers, got {raw!r}")
            if first < 0 or count < 1:
                raise self.fail(f"seeds = {raw!r}: need first >= 0 and count >= 1")
            if count > MAX_RUNS:
                raise self.fail(f"seeds = {raw!r}: at most {MAX_RUNS} seeds")
            if first + count - 1 > MAX_SEED:
                raise self.fail(
                    f"seeds = {raw!r}: the last seed {first + count - 1} is out of range; "
                    f"seeds are integers from 0 to {MAX_SEED}"
                )
            return tuple(range(first, first + count))
        if isinstance(raw, list):
            if not raw:
                raise self.fail("seeds = []: need at least one seed")
            for s in raw:
                if isinstance(s, bool) or not isinstance(s, int) or s < 0:
                    raise self.fail(f"seeds: {s!r} is not a non-negative integer")
                if s > MAX_SEED:
                    raise self.fail(
                        f"seeds: {s} is out of range; seeds are integers from 0 to {MAX_SEED}"
                    )
            if len(set(raw)) != len(raw):
                raise self.fail(f"seeds: {raw!r} repeats a seed")
            return tuple(raw)
        raise self.fail(f"seeds must be a count, a list or {{first, count}}, not {raw!r}")

    def flat_table(self, data: dict[str, Any], key: str) -> dict[str, Any]:
        table = data.get(key, {})
        if not isinstance(table, dict):
            raise self.fail(f"{key} must be a table of parameters, not {table!r}")
        return _flatten(table)

    def grid(self, table: Any) -> dict[str, list[Any]]:
        if not isinstance(table, dict):
            raise self.fail(f"grid must be a table of parameters, not {table!r}")
        out: dict[str, list[Any]] = {}
        for key, raw in _flatten(table, leaf=_is_range).items():
            if isinstance(raw, dict):
                values = self.range_values(key, raw)
            elif isinstance(raw, list):
                values = raw
            else:
                raise self.fail(
                    f"[grid] {key} must be a list of values or a range "
                    f"{{start, stop, num|step}}, not {raw!r}"
                )
            if not values:
                raise self.fail(f"[grid] {key} has no values")
            if len({json.dumps(v) for v in values}) != len(values):
                raise self.fail(f"[grid] {key} repeats a value: {values!r}")
            out[key] = values
        return out

    def range_values(self, key: str, spec: dict[str, Any]) -> list[float]:
        self.check_range(key, spec)
        start, stop, log = spec["start"], spec["stop"], spec.get("log", False)
        if "num" in spec:
            values = self.num_values(key, start, stop, spec["num"], log)
        else:
            values = self.step_values(key, start, stop, spec["step"], log)
        # Integer bounds that give whole values stay integers (swarm sizes, counts).
        integral = all(isinstance(spec.get(p, 0), int) for p in ("start", "stop", "step"))
        if integral and all(_round(v).is_integer() for v in values):
            return [round(v) for v in values]
        return [_round(v) for v in values]

    def check_range(self, key: str, spec: dict[str, Any]) -> None:
        """Refuse a range table whose keys or values are not a range's."""
        unknown = set(spec) - _RANGE_KEYS
        if unknown:
            raise self.fail(f"[grid] {key}: unknown range key {sorted(unknown)[0]!r}")
        if "start" not in spec or "stop" not in spec:
            raise self.fail(f"[grid] {key}: a range needs 'start' and 'stop'")
        if ("num" in spec) == ("step" in spec):
            raise self.fail(f"[grid] {key}: a range needs exactly one of 'num' and 'step'")
        for part in ("start", "stop", "step"):
            v = spec.get(part, 0.0)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise self.fail(f"[grid] {key}: range {part} = {v!r} is not a finite number")
        if not isinstance(spec.get("log", False), bool):
            raise self.fail(f"[grid] {key}: range log must be true or false")

    def num_values(self, key: str, start: float, stop: float, num: Any, log: bool) -> list:
        """``num`` values from ``start`` to ``stop``, evenly or (``log``) geometrically."""
        if isinstance(num, bool) or not isinstance(num, int) or num < 1:
            raise self.fail(f"[grid] {key}: range num = {num!r} is not a positive integer")
        if num > MAX_RUNS:
            raise self.fail(f"[grid] {key}: range num = {num}: at most {MAX_RUNS} values")
        if log and (start <= 0 or stop <= 0):
            raise self.fail(f"[grid] {key}: a log range needs start and stop > 0")
        fractions = [i / (num - 1) if num > 1 else 0.0 for i in range(num)]
        if log:
            return [start * (stop / start) ** f for f in fractions]
        return [start + (stop - start) * f for f in fractions]

    def step_values(self, key: str, start: float, stop: float, step: float, log: bool) -> list:
        """Values from ``start`` by ``step`` up to ``stop`` (inclusive)."""
        if log:
            raise self.fail(f"[grid] {key}: log ranges take 'num', not 'step'")
        if step == 0 or (stop - start) / step < 0:
            raise self.fail(f"[grid] {key}: step {step} never reaches stop {stop} from {start}")
        steps = (stop - start) / step
        if not steps < MAX_RUNS:  # also catches an overflow to inf
            raise self.fail(
                f"[grid] {key}: step {step} from {start} to {stop} gives more than "
                f"{MAX_RUNS} values"
            )
        count = math.floor(steps + 1e-9) + 1
        return [start + i * step for i in range(count)]

    def cases(self, raw: Any) -> list[dict[str, Any]]:
        if not isinstance(raw, list) or not all(isinstance(c, dict) for c in raw):
            raise self.fail("cases must be an array of tables ([[cases]])")
        return [_flatten(c) for c in raw]

    def check_params(
        self, scenario: Any, fixed: dict[str, Any], grid: dict[str, list[Any]], cases: list
    ) -> None:
        """Build the parameters of every value on its own, then of every cell, so an error
        names the first offending key and value."""
        from kilonet.params import ParamError
        from kilonet.scenarios.base import build_params

        def check(section: str, overrides: dict[str, Any]) -> Any:
            try:
                return build_params(scenario, overrides)
            except ParamError as exc:
                raise self.fail(f"{section}{exc}") from None

        check("[fixed] ", fixed)
        for i, case in enumerate(cases):
            check(f"[[cases]] #{i + 1} ", {**fixed, **case})
        for key, values in grid.items():
            for value in values:
                check("[grid] ", {**fixed, key: value})
        for case in cases or [{}]:
            for values in itertools.product(*grid.values()):
                cell = {**case, **dict(zip(grid, values, strict=True))}
                params = check(f"cell {json.dumps(cell)}: ", {**fixed, **cell})
                if not (params.placement.robots or scenario.setup.robots):
                    raise self.fail(
                        f"cell {json.dumps(cell)}: placement.robots is not set and "
                        f"{scenario.summary} has no swarm of its own; set it in [fixed] or "
                        "[grid]"
                    )

    def report(self, table: Any, swept: list[str]) -> ReportSpec:
        if not isinstance(table, dict):
            raise self.fail("report must be a table")
        unknown = [k for k in table if k not in _REPORT_KEYS]
        if unknown:
            raise self.fail(
                f"[report] unknown key {unknown[0]!r}; known: {', '.join(_REPORT_KEYS)}"
            )
        x = table.get("x")
        if x is not None and x not in swept:
            raise self.fail(f"[report] x = {x!r} is not a swept parameter; swept: {swept}")
        metrics = table.get("metrics", [])
        if not isinstance(metrics, list) or not all(isinstance(m, str) for m in metrics):
            raise self.fail("[report] metrics must be a list of summary names")
        xscale = table.get("xscale", "linear")
        if xscale not in ("linear", "log"):
            raise self.fail(f"[report] xscale = {xscale!r} is not 'linear' or 'log'")
        return ReportSpec(x=x, metrics=tuple(metrics), xscale=xscale)


def _is_range(value: Any) -> bool:
    return isinstance(value, dict) and bool(value) and set(value) <= _RANGE_KEYS


def _flatten(table: dict[str, Any], prefix: str = "", leaf=lambda v: False) -> dict[str, Any]:
    """``{"medium": {"loss_prob": 0.1}}`` → ``{"medium.loss_prob": 0.1}`` (values for which
    ``leaf`` is true are kept whole)."""
    out: dict[str, Any] = {}
    for key, value in table.items():
        if isinstance(value, dict) and not leaf(value):
            out.update(_flatten(value, f"{prefix}{key}.", leaf))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _round(value: float) -> float:
    return float(f"{value:.{_SIGNIFICANT_DIGITS}g}")
