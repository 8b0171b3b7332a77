"""``kilonet sweep`` and ``kilonet report``: the command-line face of the experiments package.

    kilonet sweep SWEEP.toml --out DIR [--workers N | --scheduler ADDRESS
                  [--no-workers-timeout S]] [--resume] [--retry-failed] [--no-progress]
    kilonet report DIR --out REPORT.html|REPORT.md [--x KEY] [--metric NAME ...]
                   [--confidence 0.95]

Running ``kilonet sweep`` again with the same arguments resumes an interrupted sweep: only the
runs missing from DIR are run. ``--resume`` says so explicitly and lets the sweep file be left
out (DIR keeps the definition).

Exit status: 0 when the sweep finished (failed runs are stored, listed, and counted in the
message), 1 when it had to stop (a worker process died, the cluster is unreachable or has no
workers, the disk is full), 2 for a user error (including a damaged results store), 130 when
interrupted. Every error is one line on stderr.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

__all__ = ["register_report", "register_sweep"]


def register_sweep(subparsers: Any) -> None:
    """Add the ``sweep`` sub-command to ``kilonet``'s sub-parsers."""
    sweep = subparsers.add_parser(
        "sweep",
        help="run a parameter sweep (every cell and seed) into a results directory",
        description="Run every (parameters, seed) run of a sweep in parallel and store each "
        "result as it finishes; the same command resumes an interrupted sweep.",
    )
    sweep.add_argument("sweep_file", nargs="?", metavar="SWEEP.toml", help="sweep definition")
    sweep.add_argument("--out", required=True, metavar="DIR", help="results directory")
    sweep.add_argument(
        "--workers", type=int, metavar="N", help="local worker processes (default: all CPUs)"
    )
    sweep.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a Dask distributed cluster (e.g. tcp://host:8786) instead of locally",
    )
    sweep.add_argument(
        "--no-workers-timeout",
        type=float,
        default=300.0,
        metavar="S",
        help="with --scheduler: stop (and keep the stored runs) when the cluster has had no "
        "workers for S seconds (default: 300; inf: wait for workers however long)",
    )
    sweep.add_argument(
        "--resume",
        action="store_true",
        help="continue the sweep stored in DIR (SWEEP.toml may then be left out)",
    )
    sweep.add_argument(
        "--retry-failed", action="store_true", help="run the runs stored as failed again"
    )
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    sweep.set_defaults(func=_cmd_sweep)


def register_report(subparsers: Any) -> None:
    """Add the ``report`` sub-command to ``kilonet``'s sub-parsers."""
    report = subparsers.add_parser(
        "report",
        help="tables and figures of a sweep, aggregated over seeds (.html or .md)",
        description="Aggregate a sweep's runs over seeds (mean, std, confidence interval) and "
        "plot each figure against a swept parameter.",
    )
    report.add_argument("directory", metavar="DIR", help="results directory of a sweep")
    report.add_argument(
        "--out", required=True, metavar="FILE", help="report.html (self-contained) or report.md"
    )
    report.add_argument("--x", metavar="KEY", help="swept parameter on the x axis")
    report.add_argument(
        "--metric",
        action="append",
        default=[],
        metavar="NAME",
        help="summary figure to report (repeatable; default: the sweep's [report] metrics)",
    )
    report.add_argument(
        "--confidence", type=float, default=0.95, help="confidence level of the intervals"
    )
    report.set_defaults(func=_cmd_report)


def _cmd_sweep(args: argparse.Namespace) -> int:
    from kilonet.errors import UsageError
    from kilonet.experiments.runner import (
        SchedulerAddressError,
        SweepAborted,
        check_scheduler_address,
        run_sweep,
    )
    from kilonet.experiments.store import ResultStore, StoreError, is_sweep_dir
    from kilonet.experiments.sweep import SweepError, load_sweep
    from kilonet.scenarios.progress import resolve_mode

    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers must be at least 1, not {args.workers}")
    if args.workers is not None and args.scheduler is not None:
        raise UsageError("--workers is for the local pool; with --scheduler the cluster decides")
    if not args.no_workers_timeout > 0:  # also refuses nan
        raise UsageError(
            f"--no-workers-timeout must be a number of seconds > 0, not {args.no_workers_timeout}"
        )
    try:
        if args.scheduler is not None:
            check_scheduler_address(args.scheduler)
    except SchedulerAddressError as exc:
        raise UsageError(str(exc)) from None
    except SweepAborted as exc:
        print(f"kilonet: sweep stopped: {exc}", file=sys.stderr)
        return 1
    out = Path(args.out)
    if args.resume and not is_sweep_dir(out):
        raise UsageError(f"--resume: {out} holds no sweep to resume")
    source = None
    sweep = None
    try:
        if args.sweep_file is not None:
            sweep = load_sweep(args.sweep_file)
            source = Path(args.sweep_file).read_text()
        elif args.resume:
            with ResultStore.open(out, read_only=True) as store:
                sweep = store.sweep()
        else:
            raise UsageError("give a sweep file, or --resume to continue the sweep in --out DIR")
        outcome = run_sweep(
            sweep,
            out,
            workers=args.workers,
            scheduler=args.scheduler,
            retry_failed=args.retry_failed,
            # a bar only on a terminal, as `kilonet run` decides
            progress=not args.no_progress and resolve_mode("auto") == "bar",
            source=source,
            no_workers_timeout_s=args.no_workers_timeout,
        )
    except (SweepError, StoreError) as exc:
        raise UsageError(str(exc)) from None
    except SweepAborted as exc:
        print(f"kilonet: sweep stopped: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        total = f" of {len(sweep.runs())}" if sweep is not None else ""
        print(
            f"kilonet: sweep interrupted; {_stored(out)}{total} runs are stored in {out}; "
            "run the same command to resume",
            file=sys.stderr,
        )
        return 130
    done = outcome.ok + outcome.failed
    line = f"sweep {sweep.name}: {outcome.total} runs; {done} run now ({outcome.failed} failed)"
    if outcome.already_stored:
        line += f", {outcome.already_stored} already stored"
    print(f"{line}; results in {out}", file=sys.stderr)
    if outcome.failed:
        print(
            f"kilonet: {outcome.failed} runs failed; `kilonet report {out} --out report.html` "
            "lists their errors, --retry-failed runs them again",
            file=sys.stderr,
        )
    return 0


def _stored(out: Path) -> int:
    from kilonet.experiments.store import ResultStore, StoreError

    try:
        with ResultStore.open(out, read_only=True) as store:
            return sum(store.counts().values())
    except StoreError:
        return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from kilonet.errors import UsageError
    from kilonet.experiments.report import ReportError, write_report
    from kilonet.experiments.store import StoreError

    if not 0 < args.confidence < 1:
        raise UsageError(f"--confidence must be between 0 and 1, not {args.confidence}")
    try:
        written = write_report(
            args.directory,
            args.out,
            x=args.x,
            metrics=args.metric or None,
            confidence=args.confidence,
        )
    except (ReportError, StoreError) as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:  # a full disk, a directory we may not write
        print(f"kilonet: error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    figures = sum(1 for p in written if p.suffix == ".png")
    extra = f" and {figures} figures" if figures else ""
    print(f"wrote {written[0]}{extra}", file=sys.stderr)
    return 0
