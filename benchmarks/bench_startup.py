"""Start-up cost: how long the listing commands take, and what a run pays before its first event.

1. ``kilonet --help``, ``kilonet scenarios``, ``kilonet params`` (as ``python -m kilonet``):
   wall and CPU time of the whole process, best of ``--repeat``.
2. ``kilonet run SCENARIO --robots N``, stopped at its first simulated event: wall time from
   starting the process to that event, the process's CPU time and peak memory then, and which
   heavy libraries (pandas, matplotlib, scipy, networkx, tqdm) it had imported by then. The run
   goes through the real command line (``kilonet.app.cli.main``); the child process replaces the
   kernel environment's ``run`` and ``step`` with a function that records the time and exits,
   so nothing of the run itself is measured. Best of ``--repeat`` (the least disturbed run).

``--source DIR`` measures another checkout of kilonet (its modules first on ``sys.path``), e.g.
an older commit unpacked with ``git archive``, to compare before and after.

    python benchmarks/bench_startup.py [--scenario gradient] [--robots 100] [--repeat 5]
                                       [--source DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

HEAVY = ("pandas", "matplotlib", "scipy", "networkx", "tqdm")

_CHILD = """
import json, os, resource, sys, time
import simpy
import kilonet.clock

def first_event(self, *args, **kwargs):
    usage = resource.getrusage(resource.RUSAGE_SELF)
    # sys.__stdout__: the run sends print() to stderr while it runs (stdout is the --json's)
    print(json.dumps({
        "at": time.time(),
        "cpu_s": usage.ru_utime + usage.ru_stime,
        "rss_mb": usage.ru_maxrss / 1024,
        "heavy": sorted(m for m in HEAVY_NAMES if m in sys.modules),
        "modules": len(sys.modules),
    }), file=sys.__stdout__, flush=True)
    os._exit(0)

if hasattr(kilonet.clock, "KernelEnvironment"):  # the kernel's own step loop
    kilonet.clock.KernelEnvironment.run = first_event
    kilonet.clock.KernelEnvironment.step = first_event
else:  # a checkout from before it
    simpy.Environment.step = first_event
try:
    from kilonet.app.cli import main
except ModuleNotFoundError:  # a checkout from before the application layer
    from kilonet.cli import main
main(sys.argv[1:])
""".replace("HEAVY_NAMES", repr(HEAVY))


def _env(source: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    if source is not None:
        env["PYTHONPATH"] = str(source)
    return env


def listing(argv: list[str], repeat: int, source: Path | None) -> dict[str, float]:
    """Best wall time of ``python -m kilonet ARGV`` and that run's CPU time (user + system)."""
    best = None
    for _ in range(repeat):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "kilonet", *argv],
            capture_output=True,
            check=True,
            env=_env(source),
            cwd=source or Path.cwd(),
        )
        wall = time.perf_counter() - started
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        if best is None or wall < best["wall_s"]:
            best = {"wall_s": wall, "cpu_s": cpu}
    return best


def first_event(scenario: str, robots: int, repeat: int, source: Path | None) -> dict:
    """Best time from process start to the first simulated event of ``kilonet run``."""
    best = None
    for _ in range(repeat):
        spawned = time.time()
        done = subprocess.run(
            [sys.executable, "-c", _CHILD, "run", scenario, "--robots", str(robots), "--json"],
            capture_output=True,
            text=True,
            env=_env(source),
            cwd=source or Path.cwd(),
        )
        lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
        if not lines:
            raise SystemExit(f"the run never reached its first event:\n{done.stderr}")
        report = json.loads(lines[-1])
        report["first_event_s"] = report.pop("at") - spawned
        if best is None or report["first_event_s"] < best["first_event_s"]:
            best = report
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="gradient")
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--source", type=Path, help="another kilonet checkout to measure")
    args = parser.parse_args()
    source = args.source.resolve() if args.source else None
    print(f"kilonet from {source or 'this environment'}; best of {args.repeat}")
    for argv in (["--help"], ["scenarios"], ["params"]):
        r = listing(argv, args.repeat, source)
        print(f"kilonet {' '.join(argv):<10} wall {r['wall_s']:.3f} s  cpu {r['cpu_s']:.3f} s")
    r = first_event(args.scenario, args.robots, args.repeat, source)
    print(
        f"kilonet run {args.scenario} --robots {args.robots}: first event after "
        f"{r['first_event_s']:.3f} s wall, {r['cpu_s']:.3f} s cpu, {r['rss_mb']:.0f} MB peak, "
        f"{r['modules']} modules; heavy libraries loaded: {', '.join(r['heavy']) or 'none'}"
    )


if __name__ == "__main__":
    main()
