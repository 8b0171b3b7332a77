"""How much of the global coordinate system's fixed phase windows the robots use.

Runs phases 1-4 of the ``gcs`` scenario and prints, per run, the window of each phase and
when, in simulated seconds from the window's start, the last thing in it happened: the last
ID redraw or duplicate report (phase 1), the last frame built or given up (phase 3) and the
last robot located (phase 4). A window much longer than its last event is time the swarm
waits; one barely longer risks cutting the phase short on another placement or channel.

    python benchmarks/gcs_windows.py [--sizes 100 300] [--seeds 1 2 3] [--set key=value ...]

docs/results/gcs.md's table of the same is made by ``python -m kilonet.experiments.publish docs
--block gcs-windows`` (:func:`kilonet.experiments.studies.gcs_measured.windows_block`).
"""

from __future__ import annotations

import argparse
import json

from kilonet.experiments.studies.gcs_measured import last_events


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 300])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    overrides = dict(item.split("=", 1) for item in args.set)
    for n in args.sizes:
        for seed in args.seeds:
            print(json.dumps(last_events(n, seed, overrides)), flush=True)


if __name__ == "__main__":
    main()
