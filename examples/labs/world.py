"""The world each lab runs in, and the one command that runs a lab now.

A lab ``NAME`` has its placement in ``NAME.csv`` beside this file (columns ``x_mm,y_mm`` and,
where the lab needs particular robots, ``uid``: the robot's ``kilo_uid``) and, where it needs
parameters other than the defaults, ``NAME.toml`` (sections of dotted keys, as ``kilonet run``
reads them, without a ``scenario`` key). ``python -m examples.labs.NAME`` runs the lab through
:func:`main`, which prints the figures the lab's README section reports.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from kilonet.params import ParamError, Params
from kilonet.placement import PlacementError, read_placement
from kilonet.simulation import Simulation

__all__ = ["LABS_DIR", "LabWorld", "load", "main", "simulation"]

#: Where the labs' placement and parameter files are.
LABS_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class LabWorld:
    """A lab's placement and parameters.

    Attributes
    ----------
    positions_mm : (N, 2) ndarray
        Start positions, mm.
    uids : list of int or None
        ``kilo_uid`` of each robot (the CSV's ``uid`` column), or ``None`` (each robot's index).
    overrides : dict
        Dotted-key parameters from the lab's TOML file (empty without one).
    """

    positions_mm: np.ndarray
    uids: list[int] | None
    overrides: dict[str, Any]


def load(lab: str) -> LabWorld:
    """The placement (``LAB.csv``) and parameters (``LAB.toml``, if any) of ``lab``.

    Raises
    ------
    PlacementError
        If the placement file is missing or invalid.
    ParamError
        If the parameter file is not valid TOML.
    """
    placement = read_placement(LABS_DIR / f"{lab}.csv")
    toml = LABS_DIR / f"{lab}.toml"
    overrides = Params.read_toml(toml)[1] if toml.exists() else {}
    uids = list(placement.uids) if placement.uids is not None else None
    return LabWorld(placement.positions_mm, uids, overrides)


def simulation(
    lab: str,
    program: Callable[[int], Any],
    *,
    seed: int = 1,
    overrides: dict[str, Any] | None = None,
) -> Simulation:
    """A simulation of ``lab``'s world running ``program`` (a Kilobot subclass) on every robot.

    ``overrides`` (dotted keys) apply on top of the lab's own parameter file.

    Raises
    ------
    ParamError
        For an unknown parameter or a bad value.
    """
    world = load(lab)
    params = Params(seed=seed).with_overrides({**world.overrides, **(overrides or {})})
    return Simulation(world.positions_mm, program, params, uids=world.uids)


def main(
    lab: str,
    program: Callable[[int], Any],
    figures: Callable[[Simulation], dict[str, Any]],
    argv: Sequence[str] | None = None,
) -> None:
    """Run ``lab`` and print its figures, one ``name: value`` a line, and the CPU time.

    Command line: ``--seed N`` and any number of ``--set KEY=VALUE`` (e.g. ``--set
    duration_s=600``). A bad option or parameter is reported in one line, exit status 2.
    """
    parser = argparse.ArgumentParser(prog=f"python -m examples.labs.{lab}")
    parser.add_argument("--seed", type=int, default=1, help="the run's seed (default 1)")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="a parameter"
    )
    args = parser.parse_args(argv)
    try:
        overrides = dict(_key_value(item) for item in args.set)
        sim = simulation(lab, program, seed=args.seed, overrides=overrides)
    except (ParamError, PlacementError, ValueError) as exc:
        print(f"{parser.prog}: {exc}", file=sys.stderr)
        raise SystemExit(2) from None
    started = time.process_time()
    sim.run()
    cpu_s = time.process_time() - started
    print(f"{lab}: {sim.n_robots} robots, {sim.env.now:g} simulated s, seed {args.seed}")
    for name, value in figures(sim).items():
        print(f"  {name}: {_text(value)}")
    print(f"  cpu_s: {cpu_s:.2f}")


def _text(value: Any) -> str:
    """A figure as printed: floats to 4 significant digits, dicts as ``key=value`` lists."""
    if isinstance(value, dict):
        return ", ".join(f"{k}={_text(v)}" for k, v in value.items())
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _key_value(item: str) -> tuple[str, str]:
    key, sep, value = item.partition("=")
    if not sep or not key:
        raise ValueError(f"--set {item!r}: expected KEY=VALUE")
    return key.strip(), value.strip()
