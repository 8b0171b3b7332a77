"""The large end-to-end runs through the command line: 1,000-robot gcs and localize.

Each run is ``python -m kilonet run SCENARIO --robots N --seed S --json`` in a child process,
stopped by ``--timeout`` (seconds of wall time, default 1,800). Prints one JSON line per run:
whether it finished, its wall time and CPU time (the child's user + system), and from its
summary the simulated seconds, messages sent and, where the scenario reports it, the share of
robots localized.

    python benchmarks/bench_large.py [--runs gcs localize] [--robots 1000] [--seed 1]
                                     [--timeout 1800]
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

ROOT = Path(__file__).resolve().parent.parent

#: Summary fields reported beside the times, when the scenario's summary has them.
FIELDS = ("sim_time_s", "messages_sent", "receptions_delivered", "localized_fraction", "frames")


def run_cli(scenario: str, robots: int, seed: int, timeout_s: float) -> dict:
    """Run one scenario through the command line; its times and summary figures."""
    argv = [sys.executable, "-m", "kilonet", "run", scenario, "--robots", str(robots)]
    argv += ["--seed", str(seed), "--json"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    try:
        done = subprocess.run(
            argv, cwd=ROOT, capture_output=True, text=True, timeout=timeout_s, check=False
        )
        finished, output = done.returncode == 0, done.stdout
    except subprocess.TimeoutExpired:
        finished, output = False, ""
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    figures = {
        "scenario": scenario,
        "robots": robots,
        "seed": seed,
        "finished": finished,
        "wall_s": round(wall, 1),
        "cpu_s": round((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), 1),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    if finished:
        summary = json.loads(output)
        figures.update({k: summary[k] for k in FIELDS if k in summary})
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", nargs="+", default=["gcs", "localize"])
    parser.add_argument("--robots", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=1800.0)
    args = parser.parse_args()
    for scenario in args.runs:
        print(json.dumps(run_cli(scenario, args.robots, args.seed, args.timeout)), flush=True)


if __name__ == "__main__":
    main()
