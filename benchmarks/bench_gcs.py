"""The global coordinate system end to end: phases 1-6 on jittered hex lattices.

Prints, per size: wall time, CPU time, simulated time (and each phase's share), merging rounds
(all seeds together and the most any seed ran), final frames, localized share, RMSE after the
best rigid alignment and the Cramér-Rao bound for the same measurement graph. Issue 5's target:
1,000 robots in at most 60 s of wall time on the 2-core development machine.

    python benchmarks/bench_gcs.py [--sizes 100 1000] [--seed 1] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import json
import os
import time

import scenarios

FIELDS = (
    "robots",
    "wall_time_s",
    "sim_time_s",
    "merge_rounds",
    "merge_rounds_max_per_seed",
    "seeds",
    "frames",
    "localized_fraction",
    "rmse_mm",
    "crlb_rmse_mm",
    "phase_times_s",
)


def run_one(n: int, seed: int, overrides: dict[str, str]) -> dict:
    """One gcs run of ``n`` robots; the summary's headline figures, the CPU time it took (less
    disturbed than wall time by other work on the machine) and the load average."""
    cpu = time.process_time()
    result = scenarios.run(
        scenarios.get("gcs"), {"placement.robots": n, **overrides}, seed=seed, progress=True
    )
    figures = {key: result.summary.get(key) for key in FIELDS}
    figures["cpu_time_s"] = round(time.process_time() - cpu, 1)
    figures["load_average_1min"] = os.getloadavg()[0]
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    overrides = dict(item.split("=", 1) for item in args.set)
    for n in args.sizes:
        print(json.dumps(run_one(n, args.seed, overrides)), flush=True)


if __name__ == "__main__":
    main()
