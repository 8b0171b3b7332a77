"""The ``run``, ``scenarios`` and ``params`` sub-commands of ``kilonet``.

    kilonet run [SCENARIO|FILE.toml] [--program FILE.py[:CLASS]] [--placement F.csv]
                [--robots N] [--seed S] [--duration S] [--set KEY=VALUE ...]
                [--out DIR [--replace]] [--format csv|parquet] [--json] [--animate]
                [scenario options, e.g. --until PHASE]
    kilonet scenarios
    kilonet params [SCENARIO|SECTION] [--program FILE.py[:CLASS]]

Registered as entry points of ``kilonet.commands`` (``pyproject.toml``). Scenarios come from
the ``kilonet.scenarios`` entry points, and so do their own options (:class:`ScenarioOption`):
this module knows no scenario by name except the default.

Everything the user can get wrong is checked before the simulation starts: the scenario, every
parameter (a run file's bad key is reported with the file and line), the placement, the
program file, and the output directory (``--out`` must not exist unless ``--replace``; its
parent must be a writable directory). A run without ``--out`` says in one line that it writes
nothing (said after the run, so that an error stays the only line). A finished run is never
discarded by a failure after it (the scenario's figures, ``--animate``): it is written, its
summary printed, and the failure is one line with exit status 2.
"""

from __future__ import annotations

import argparse
import enum
import json
import re
import sys
import typing
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kilonet import scenarios
from kilonet.errors import UsageError, UserError
from kilonet.params import ParamError, Params, describe
from kilonet.scenarios.progress import MODES
from kilonet.watchdog import BUSY_CALL_S, check_watchdog_s

# What registering the commands imports stays light (no numpy, no scenario): `kilonet --help`
# registers every command. The scenarios' machinery is imported where a command runs.
if TYPE_CHECKING:
    from kilonet.scenarios.base import Scenario, ScenarioOption

__all__ = ["register_params", "register_run", "register_scenarios", "run_file_overrides"]

_EXAMPLES = """\
examples:
  kilonet run                                   the default scenario ({default}), seed 1
  kilonet run gradient --robots 300 --seed 2 --out runs/g300
  kilonet run gcs --until localization --set medium.loss_prob=0.2 --set ranging.sigma_mm=2
  kilonet run follower --placement my_four.csv --out runs/follower --replace
  kilonet run experiment.toml                   scenario = "gcs" and [medium], [gcs] sections
  kilonet run --program my_bot.py:Orbit --robots 2 --out runs/orbit

Every parameter, its default, type and allowed values: kilonet params [SCENARIO].
Output files and summary keys: docs/outputs.md.
"""


# -- run ----------------------------------------------------------------------------------------
def register_run(subparsers: Any) -> None:
    """Add ``kilonet run`` (its scenario options come from the registered scenarios)."""
    seed_default = Params().seed
    run = subparsers.add_parser(
        "run",
        help="run a scenario (or your own program) and print its summary",
        description="Run a scenario once and print its summary figures. "
        f"Scenarios: {', '.join(scenarios.names())} (default {scenarios.DEFAULT}).",
        epilog=_EXAMPLES.format(default=scenarios.DEFAULT),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    run.add_argument(
        "target",
        nargs="?",
        metavar="SCENARIO|FILE.toml",
        help=f"scenario name or run file (default: {scenarios.DEFAULT})",
    )
    run.add_argument(
        "--program",
        metavar="FILE.py[:CLASS]",
        help="run your own Kilobot subclass from FILE.py on every robot instead of a scenario "
        "(needs --placement or --robots)",
    )
    run.add_argument(
        "--placement",
        metavar="F.csv|NAME",
        help="CSV of start positions with columns x_mm,y_mm, or a named placement "
        "(thesis-7.1a, thesis-7.1b, thesis-7.1c: the thesis's failure cases)",
    )
    run.add_argument(
        "--robots",
        type=int,
        metavar="N",
        help="number of robots on the scenario's layout (placement.robots)",
    )
    run.add_argument("--seed", type=int, metavar="S", help=f"master seed (default: {seed_default})")
    run.add_argument(
        "--duration",
        type=float,
        metavar="SECONDS",
        help="simulated seconds at most (duration_s; default: the scenario's)",
    )
    run.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set a parameter; repeat for more (kilonet params lists every key)",
    )
    run.add_argument("--out", metavar="DIR", help="write tables, summary.json and figures to DIR")
    run.add_argument(
        "--replace", action="store_true", help="replace an existing --out DIR whole (never merged)"
    )
    run.add_argument(
        "--format", default="csv", choices=["csv", "parquet"], help="table format (default: csv)"
    )
    run.add_argument(
        "--json",
        action="store_true",
        help="print only the summary JSON on stdout (a program's print() goes to stderr)",
    )
    run.add_argument(
        "--progress",
        choices=MODES,
        default="auto",
        help="progress on stderr: a bar redrawn in place, whole lines (for a log), or none; "
        "auto: the bar on a terminal, none otherwise (default: auto)",
    )
    run.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress and no notes on stderr: only errors (and the summary on stdout)",
    )
    run.add_argument(
        "--watchdog",
        type=float,
        default=BUSY_CALL_S,
        metavar="SECONDS",
        help="stop the run when one call into a robot program runs this long (wall time) "
        f"while simulated time stands still; 0: never (default: {BUSY_CALL_S:g})",
    )
    run.add_argument(
        "--animate", action="store_true", help="also write DIR/animation.gif (needs --out)"
    )
    # Every scenario's options load every scenario and its protocol: only for `kilonet run`.
    run.defer(_add_scenario_options)
    run.set_defaults(func=_cmd_run)


def _owners() -> dict[str, list[tuple[Scenario, ScenarioOption]]]:
    """Each scenario option's flag and the scenarios that declare it."""
    owners: dict[str, list[tuple[Scenario, ScenarioOption]]] = {}
    for name in scenarios.names():
        scenario = scenarios.get(name)
        for option in scenario.setup.options:
            owners.setdefault(option.flag, []).append((scenario, option))
    return owners


def _field_of(scenario: Scenario, key: str):
    section, _, name = key.partition(".")
    own = scenario.setup.section
    if own is None or getattr(own, "section_name", "") != section:
        raise TypeError(f"scenario {scenario.name}: option key {key!r} is not in its section")
    return next(f for f in fields(own) if f.name == name)


def _add_scenario_options(run: argparse.ArgumentParser) -> None:
    group = run.add_argument_group("options of one scenario (declared by the scenario)")
    for flag, declared in _owners().items():
        helps, choices = [], None
        for scenario, option in declared:
            f = _field_of(scenario, option.key)
            helps.append(f"{scenario.name}: {option.help} ({option.key}, default {f.default})")
            tp = typing.get_type_hints(scenario.setup.section)[f.name]
            if len(declared) == 1 and typing.get_origin(tp) is typing.Literal:
                choices = list(typing.get_args(tp))
        group.add_argument(flag, dest=_dest(flag), choices=choices, help="; ".join(helps))


def _dest(flag: str) -> str:
    return "option" + flag.replace("-", "_")


def _scenario_options(args: argparse.Namespace, scenario: Scenario) -> dict[str, Any]:
    """The parameters the scenario options given on the command line set.

    Raises
    ------
    UsageError
        If an option belongs to other scenarios only.
    """
    out = {}
    for flag, declared in _owners().items():
        value = getattr(args, _dest(flag), None)
        if value is None:
            continue
        keys = [option.key for s, option in declared if s.name == scenario.name]
        if not keys:
            names = ", ".join(s.name for s, _ in declared)
            raise UsageError(f"{flag} is an option of the {names} scenario, not of {scenario.name}")
        out[keys[0]] = value
    return out


def parse_set(items: list[str]) -> dict[str, str]:
    """Turn ``--set KEY=VALUE`` arguments into a mapping of key to the value's text; the
    values are checked later, against the scenario's parameters.

    Raises
    ------
    UsageError
        If an item has no ``=`` or an empty key.
    """
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--set expects KEY=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def run_file_overrides(scenario: Scenario, path: str | Path, overrides: dict[str, Any]) -> None:
    """Check a run file's parameters on their own, so that an error names the file and, for
    one bad key, its line (``run.toml:4: unknown parameter 'medium.los'; ...``). ``kilonet
    run`` calls it only when the run's parameters cannot be built, to say where the fault is.

    Raises
    ------
    ParamError
        If a key is unknown or a value invalid.
    """
    from kilonet.scenarios.base import build_params

    try:
        build_params(scenario, overrides)
    except ParamError as whole:
        text = Path(path).read_text()
        for key, value in overrides.items():
            try:
                build_params(scenario, {key: value})
            except ParamError as exc:
                line = toml_line(text, key)
                where = f"{path}:{line}" if line else str(path)
                raise ParamError(f"{where}: {exc}") from None
        raise ParamError(f"{path}: {whole}") from None


def toml_line(text: str, key: str) -> int | None:
    """The line (1-based) of TOML ``text`` that sets the dotted ``key``, if one plainly does
    (``key = ...`` under its ``[section]``, or ``section.key = ...`` at the top).

    Examples
    --------
    >>> toml_line('scenario = "gcs"\\n[medium]\\nloss_prob = 0.2\\nlos = 1\\n', "medium.los")
    4
    >>> toml_line('seed = 3\\nmedium.range_mm = 90\\n', "medium.range_mm")
    2
    """
    head, _, name = key.rpartition(".")
    section = ""
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        header = re.fullmatch(r"\[\s*([^\[\]]+?)\s*\]\s*(#.*)?", stripped)
        if header:
            section = header.group(1)
            continue
        assigned = re.match(r"([A-Za-z0-9_.\"' -]+?)\s*=", stripped)
        if assigned is None:
            continue
        written = assigned.group(1).replace('"', "").replace("'", "").replace(" ", "")
        full = f"{section}.{written}" if section else written
        if full == key or (not head and section == "" and written == name):
            return number
    return None


def _resolve(args: argparse.Namespace) -> tuple[Scenario, dict[str, Any], Path | None]:
    """The scenario to run, the run file's overrides, and the run file (if any)."""
    target = args.target
    if args.program is not None:
        from kilonet.scenarios.program import program_scenario

        if target is not None and not target.endswith(".toml"):
            raise UsageError(
                f"--program runs your own program, not the scenario {target!r}; leave one out"
            )
        overrides: dict[str, Any] = {}
        if target is not None:
            named, overrides = Params.read_toml(target)
            if named is not None:
                raise UsageError(
                    f"{target}: names scenario {named!r}, but --program runs your own program; "
                    "remove the scenario key or --program"
                )
        settings = {
            k[len("program.") :]: v for k, v in overrides.items() if k.startswith("program.")
        }
        overrides = {k: v for k, v in overrides.items() if not k.startswith("program.")}
        given = parse_set(args.set)
        settings |= {k[len("program.") :]: v for k, v in given.items() if k.startswith("program.")}
        text = Path(target).read_text() if target is not None else ""

        def where(name: str) -> str:
            if f"program.{name}" in given:
                return f"--set program.{name}"
            line = toml_line(text, f"program.{name}")
            return f"{target}:{line}" if line else str(target)

        scenario = program_scenario(args.program, settings, where)
        return scenario, overrides, Path(target) if target else None
    if target is None:
        return scenarios.get(scenarios.DEFAULT), {}, None
    if target.endswith(".toml"):
        name, overrides = Params.read_toml(target)
        return scenarios.get(name or scenarios.DEFAULT), overrides, Path(target)
    return scenarios.get(target), {}, None


def _check_placement(args: argparse.Namespace) -> None:
    if args.placement is None:
        return
    if args.robots is not None:
        raise UsageError(
            f"--robots {args.robots} and --placement {args.placement} both give the swarm; "
            "the placement has its own robots (leave out --robots)"
        )
    if not Path(args.placement).exists():
        from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS

        if args.placement not in NAMED_PLACEMENTS:
            raise UsageError(
                f"{args.placement}: no such placement file or named placement "
                f"(named: {', '.join(NAMED_PLACEMENTS)})"
            )


@contextmanager
def _ended_by_signals() -> Iterator[None]:
    """SIGTERM and SIGHUP end the run as Ctrl-C does: the exception unwinds the run, so the
    staging directory of ``--out`` is removed, and kilonet exits with 128 + the signal."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def end(signum: int, _frame: Any) -> None:
        print(f"kilonet: stopped by {signal.Signals(signum).name}", file=sys.stderr)
        raise SystemExit(128 + signum)

    wanted = [getattr(signal, name) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)]
    previous = {sig: signal.signal(sig, end) for sig in wanted}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def _cmd_run(args: argparse.Namespace) -> int:
    with _ended_by_signals():
        return _run_command(args)


def _run_command(args: argparse.Namespace) -> int:
    from kilonet.scenarios.base import AfterRunError, after_the_run, json_safe, write_run_files
    from kilonet.scenarios.output_dir import OutputDir
    from kilonet.scenarios.progress import StageProgress

    scenario, file_overrides, run_file = _resolve(args)
    given = parse_set(args.set)
    if args.program is not None:  # program.* keys are the program's own settings (_resolve)
        given = {k: v for k, v in given.items() if not k.startswith("program.")}
    overrides = {**file_overrides, **given, **_scenario_options(args, scenario)}
    if args.robots is not None:
        if args.robots < 1:
            raise UsageError(f"--robots {args.robots}: give the number of robots (at least 1)")
        overrides["placement.robots"] = args.robots
    if args.duration is not None:
        overrides["duration_s"] = args.duration
    if args.animate and args.out is None:
        raise UsageError("--animate needs --out DIR: the animation is drawn from the run directory")
    if args.replace and args.out is None:
        raise UsageError("--replace needs --out DIR: it replaces that directory")
    _check_placement(args)
    params = _run_params(scenario, overrides, args, run_file, file_overrides)
    check_watchdog_s(args.watchdog, "--watchdog")
    if args.program is not None and args.placement is None and not params.placement.robots:
        raise UsageError("--program needs --placement F.csv or --robots N (a hex lattice)")
    progress = "none" if args.json or args.quiet else args.progress
    reserved = OutputDir(args.out, replace=args.replace) if args.out is not None else None
    failed: AfterRunError | None = None  # a step after the run, reported after its summary
    with reserved or nullcontext() as out:
        result = _guarded(args)(scenario, params, placement=args.placement, progress=progress)
        if args.out is not None:
            with StageProgress(scenario.name, enabled=progress) as display:
                try:
                    write_run_files(result, out.staging, fmt=args.format, stage=display.stage)
                    if args.animate:
                        display.stage("drawing animation.gif")
                        with after_the_run(out.staging, "animation.gif"):
                            _animator()(out.staging)
                except AfterRunError as exc:
                    failed = exc  # the run is finished and written: keep it
                except OSError as exc:
                    raise UsageError(f"{args.out}: cannot write the run ({exc.strerror})") from None
            written = sorted(p.name for p in out.staging.iterdir())
            out.publish()
            if not (args.json or args.quiet):
                extra = " and animation.gif" if "animation.gif" in written else ""
                files = len(written) - bool(extra)
                print(f"wrote {files} files{extra} to {args.out}", file=sys.stderr)
    if args.out is None and not args.quiet:
        print("kilonet: no --out DIR given, so nothing was written", file=sys.stderr)
    if args.json:
        print(json.dumps(json_safe(result.summary), indent=2))
    else:
        _print_summary(result.summary)
    if failed is not None:
        sys.stdout.flush()  # the summary first, then the one line of the failure
        cause = failed.__cause__
        if not isinstance(cause, OSError | UserError):
            raise cause  # a bug in the step: its traceback (the run is kept)
        raise AfterRunError(f"{args.out}: {failed}")
    return 0


def _run_params(
    scenario: Scenario,
    overrides: dict[str, Any],
    args: argparse.Namespace,
    run_file: Path | None,
    file_overrides: dict[str, Any],
) -> Params:
    """The run's parameters, every value checked before the run and built once: the run gets
    them as they are (:func:`kilonet.scenarios.base.run_with_params`).

    Raises
    ------
    ParamError
        If they cannot be built; a fault of the run file names the file and, for one key, its
        line (:func:`run_file_overrides`).
    """
    from kilonet.scenarios.base import build_params

    try:
        return build_params(scenario, overrides, seed=args.seed, placement=args.placement)
    except ParamError:
        if run_file is not None:
            run_file_overrides(scenario, run_file, file_overrides)
        raise


def _animator():
    """``kilonet run --animate``'s animator (``kilonet.viz.cli.animate_after_run``): the
    ``gif`` entry point of ``kilonet.animators``. The pictures' layer (``kilonet.viz``) sits
    above the scenarios, so the run command finds it there instead of importing it."""
    from importlib.metadata import entry_points

    found = list(entry_points(group="kilonet.animators", name="gif"))
    if not found:
        raise UsageError("--animate: no animator installed (reinstall kilonet: pip install .)")
    return found[0].load()


def _guarded(args: argparse.Namespace):
    """``kilonet.scenarios.base.run_with_params`` under the busy-call watchdog (``--watchdog``),
    with ``print()`` of a program sent to stderr under ``--json``, a Ctrl-C naming the robot and
    callback it stopped, and a user program's exceptions reported as one-line errors."""
    from contextlib import ExitStack, redirect_stdout

    from kilonet.scenarios.base import run_with_params
    from kilonet.scenarios.program import parse_spec, reported_as_user_errors
    from kilonet.watchdog import busy_watchdog, describe_call, robot_frame

    def guarded(*a: Any, **k: Any):
        with ExitStack() as stack:
            if args.program is not None:
                stack.enter_context(reported_as_user_errors(parse_spec(args.program)[0]))
            if args.json:
                stack.enter_context(redirect_stdout(sys.stderr))  # stdout is the JSON's
            stack.enter_context(busy_watchdog(args.watchdog))
            try:
                return run_with_params(*a, **k)
            except KeyboardInterrupt as exc:
                tb = exc.__traceback__
                while tb is not None and tb.tb_next is not None:
                    tb = tb.tb_next
                found = robot_frame(tb.tb_frame if tb is not None else None)
                if found is None:
                    raise
                robot, call = found
                raise KeyboardInterrupt(
                    f"in {describe_call(robot, call, tb.tb_frame)} at "
                    f"{robot._kenv.now:.3f} simulated s"
                ) from None

    return guarded


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
        value = _plain(value)
        if isinstance(value, float):
            shown = f"{value:.4g}"
        elif isinstance(value, list) and len(value) > 8:
            shown = f"{len(value)} items: {', '.join(map(str, value[:6]))}, ..."
        else:
            shown = value
        print(f"{key:<{width}}  {shown}")


def _plain(value: Any) -> Any:
    """``value`` with every enum member as its value, lists and tuples as lists: what
    ``--json`` prints (``['ids', 'seeds']``, not ``[<GcsStage.IDS: 'ids'>, ...]``).

    Examples
    --------
    >>> import enum
    >>> class Stage(str, enum.Enum):
    ...     IDS = "ids"
    >>> _plain([Stage.IDS, (1, Stage.IDS)])
    ['ids', [1, 'ids']]
    """
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


# -- scenarios and params ------------------------------------------------------------------------
def register_scenarios(subparsers: Any) -> None:
    """Add ``kilonet scenarios``."""
    subparsers.add_parser(
        "scenarios", help="list the registered scenarios", description="List the scenarios."
    ).set_defaults(func=_cmd_scenarios)


def _cmd_scenarios(_args: argparse.Namespace) -> int:
    for name in scenarios.names():
        scenario = scenarios.get(name)
        marker = " (default)" if name == scenarios.DEFAULT else ""
        print(f"{name:<12} {scenario.summary}{marker}")
    return 0


def register_params(subparsers: Any) -> None:
    """Add ``kilonet params [SCENARIO|program|SECTION]``."""
    params = subparsers.add_parser(
        "params",
        help="list every parameter with its default, type and allowed values",
        description="List every parameter of a scenario (default: "
        f"{scenarios.DEFAULT}): dotted key, default, type and allowed values, description. "
        "Set one with `kilonet run --set KEY=VALUE` or in a run file's [section].",
    )
    params.add_argument(
        "scenario",
        nargs="?",
        help=f"one of {', '.join(scenarios.names())} (default: {scenarios.DEFAULT}); "
        "'program' for kilonet run --program; or a section (medium, ranging, ...): its keys "
        f"as {scenarios.DEFAULT} sets them",
    )
    params.add_argument(
        "--program",
        metavar="FILE.py[:CLASS]",
        help="the parameters kilonet run --program FILE.py[:CLASS] runs with: the kernel's "
        "defaults and the program's own settings (program.NAME, the class attributes it "
        "declares); with a section name, that section only",
    )
    params.set_defaults(func=_cmd_params)


def _cmd_params(args: argparse.Namespace) -> int:
    from kilonet.scenarios.base import build_params

    name = args.scenario or scenarios.DEFAULT
    section = None
    if args.program is not None:
        from kilonet.scenarios.program import program_scenario

        if args.scenario is not None and args.scenario in scenarios.names():
            raise UsageError(
                f"--program lists your program's parameters, not the scenario "
                f"{args.scenario!r}; leave one out"
            )
        params = build_params(program_scenario(args.program))
        section = args.scenario
        if section not in (None, "program") and not any(
            key.startswith(f"{section}.") for key, *_ in describe(params)
        ):
            raise UsageError(
                f"{section!r} is not a section of parameters (program, medium, ranging, ...)"
            )
    elif name == "program":  # kilonet run --program: the kernel's defaults, no scenario's
        params = Params()
    elif name in scenarios.names():
        params = build_params(scenarios.get(name))
    else:
        params = build_params(scenarios.get(scenarios.DEFAULT))
        if not any(key.startswith(f"{name}.") for key, *_ in describe(params)):
            scenarios.get(name)  # the unknown-scenario error, listing the scenarios
        section = name  # a section of parameters: its keys, as the default scenario sets them
    rows = [
        (key, str(value), kind, doc)
        for key, value, kind, doc in describe(params)
        if section is None or key.startswith(f"{section}.")
    ]
    head = ("key", "default", "type and allowed values")
    widths = [max([len(head[k]), *(len(r[k]) for r in rows)]) for k in range(3)]
    print("  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True)) + "  description")
    for row in rows:
        print("  ".join(c.ljust(w) for c, w in zip(row[:3], widths, strict=True)) + f"  {row[3]}")
    return 0
