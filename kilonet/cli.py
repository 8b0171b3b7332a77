"""The ``kilonet`` command line.

    kilonet run [SCENARIO|FILE.toml] [--placement F.csv] [--robots N] [--seed S]
                [--duration S] [--set key=value ...] [--out DIR] [--format csv|parquet] [--json]
    kilonet scenarios
    kilonet params [SCENARIO]

User errors (unknown scenario or parameter, bad placement file, bad value) print one line on
stderr and exit with status 2, leaving no partial output behind.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from kilonet.params import ParamError, Params, describe
from kilonet.placement import PlacementError

__all__ = ["main"]

USER_ERRORS = (ParamError, PlacementError)

#: Modules that add sub-commands: each has ``register(subparsers)``, which adds its parsers
#: with ``set_defaults(func=handler)``; a handler returns the exit status and raises
#: :class:`UsageError` (or another user error) for bad input.
_PLUGINS: list[str] = ["kilonet.animate_cli", "experiments.cli", "scenarios.analyze"]


class UsageError(Exception):
    """A user error the CLI reports in one line (exit status 2)."""


def _parse_set(items: Sequence[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--set expects key=value, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _resolve(target: str | None) -> tuple[Any, dict[str, Any]]:
    """Scenario and file overrides for ``kilonet run TARGET``."""
    import scenarios

    if target is None:
        return scenarios.get(scenarios.DEFAULT), {}
    if target.endswith(".toml"):
        name, overrides = Params.read_toml(target)
        return scenarios.get(name or scenarios.DEFAULT), overrides
    return scenarios.get(target), {}


def _cmd_run(args: argparse.Namespace) -> int:
    import scenarios

    scenario, overrides = _resolve(args.target)
    overrides.update(_parse_set(args.set))
    if args.robots is not None:
        overrides["placement.robots"] = args.robots
    if args.duration is not None:
        overrides["duration_s"] = args.duration
    if args.until is not None:
        if scenario.name != "gcs":
            raise UsageError(f"--until applies to the gcs scenario, not {scenario.name!r}")
        overrides["gcs.until"] = args.until
    if args.animate and args.out is None:
        raise UsageError("--animate needs --out DIR: the animation is drawn from the run directory")
    if args.placement is not None and not Path(args.placement).exists():
        from scenarios.thesis_placements import NAMED_PLACEMENTS

        if args.placement not in NAMED_PLACEMENTS:
            raise UsageError(
                f"{args.placement}: no such placement file or named placement "
                f"(named: {', '.join(NAMED_PLACEMENTS)})"
            )
    result = scenarios.run(
        scenario, overrides, seed=args.seed, placement=args.placement, progress=not args.json
    )
    if args.out is not None:
        written = scenarios.write_outputs(result, args.out, fmt=args.format)
        if not args.json:
            print(f"wrote {len(written)} files to {args.out}", file=sys.stderr)
        if args.animate:
            from kilonet.animation import AnimationError, animate_run

            try:
                movie = animate_run(Path(args.out))
            except AnimationError as exc:
                raise UsageError(str(exc)) from None
            if not args.json:
                print(f"wrote {movie}", file=sys.stderr)
    if args.json:
        print(json.dumps(result.summary, indent=2))
    else:
        _print_summary(result.summary)
    return 0


def _print_summary(summary: dict[str, Any]) -> None:
    """One line per figure; nested sections flattened to dotted names, long lists shortened
    (``--json`` prints everything)."""
    flat: dict[str, Any] = {}

    def walk(section: dict[str, Any], prefix: str) -> None:
        for key, value in section.items():
            if isinstance(value, dict):
                walk(value, f"{prefix}{key}.")
            else:
                flat[f"{prefix}{key}"] = value

    walk(summary, "")
    width = max(len(k) for k in flat)
    for key, value in flat.items():
        if isinstance(value, float):
            shown = f"{value:.4g}"
        elif isinstance(value, list) and len(value) > 8:
            shown = f"{len(value)} items: {', '.join(map(str, value[:6]))}, ..."
        else:
            shown = value
        print(f"{key:<{width}}  {shown}")


def _cmd_scenarios(_args: argparse.Namespace) -> int:
    import scenarios

    for name, scenario in sorted(scenarios.SCENARIOS.items()):
        marker = " (default)" if name == scenarios.DEFAULT else ""
        print(f"{name:<12} {scenario.summary}{marker}")
    return 0


def _cmd_params(args: argparse.Namespace) -> int:
    import scenarios
    from scenarios.base import build_params

    scenario = scenarios.get(args.scenario or scenarios.DEFAULT)
    for key, value, doc in describe(build_params(scenario)):
        print(f"{key:<32} {value!s:<12} {doc}")
    return 0


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="kilonet", description="Discrete-event simulator for Kilobot swarms."
    )
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a scenario and print its summary")
    run.add_argument("target", nargs="?", help="scenario name or run file (.toml)")
    run.add_argument(
        "--placement",
        help="CSV of start positions with columns x_mm,y_mm, or a named placement "
        "(thesis-7.1a, thesis-7.1b, thesis-7.1c: the thesis's failure cases)",
    )
    run.add_argument("--robots", type=int, help="number of robots (placement.robots)")
    run.add_argument("--seed", type=int, help="master seed")
    run.add_argument("--duration", type=float, help="simulated seconds (duration_s)")
    run.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="set a parameter"
    )
    run.add_argument(
        "--until",
        choices=["ids", "seeds", "frames", "localization", "groups", "merge"],
        help="gcs scenario: stop after this phase (gcs.until)",
    )
    run.add_argument("--out", help="directory for tables, summary.json and figures")
    run.add_argument("--format", default="csv", choices=["csv", "parquet"], help="table format")
    run.add_argument("--json", action="store_true", help="print only the summary JSON on stdout")
    run.add_argument(
        "--animate", action="store_true", help="also write DIR/animation.gif (needs --out)"
    )
    run.set_defaults(func=_cmd_run)
    sub.add_parser("scenarios", help="list the named scenarios").set_defaults(func=_cmd_scenarios)
    params = sub.add_parser("params", help="list every parameter with its default")
    params.add_argument("scenario", nargs="?")
    params.set_defaults(func=_cmd_params)
    for module in _PLUGINS:
        importlib.import_module(module).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``kilonet`` console script; returns the exit status."""
    from scenarios.base import ScenarioError

    args = _parser().parse_args(argv)
    try:
        return args.func(args)
    except (*USER_ERRORS, ScenarioError, UsageError) as exc:
        print(f"kilonet: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("kilonet: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
