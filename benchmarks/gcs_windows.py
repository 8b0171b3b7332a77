"""How much of the global coordinate system's fixed phase windows the robots use.

Runs phases 1-4 of the ``gcs`` scenario and prints, per run, the window of each phase and
when, in simulated seconds from the window's start, the last thing in it happened: the last
ID redraw or duplicate report (phase 1), the last frame built or given up (phase 3) and the
last robot located (phase 4). A window much longer than its last event is time the swarm
waits; one barely longer risks cutting the phase short on another placement or channel.

    python benchmarks/gcs_windows.py [--sizes 100 300] [--seeds 1 2 3] [--set key=value ...]
"""

from __future__ import annotations

import argparse
import json

import scenarios
from protocols.gcs import phase_windows_s

#: The events that mark progress in each phase.
PHASE_EVENTS = {
    "ids": ("id", "duplicate"),
    "frames": ("frame", "frame_failed"),
    "localization": ("located",),
}


def last_events(n: int, seed: int, overrides: dict[str, str]) -> dict:
    """One run of ``n`` robots up to localization: per phase, its window and the time of its
    last progress event from the window's start (``None`` if nothing happened), s."""
    result = scenarios.run(
        scenarios.get("gcs"),
        {"placement.robots": n, **overrides, "gcs.until": "localization"},
        seed=seed,
    )
    events = result.sim.trace.events_frame()
    row: dict = {"robots": n, "seed": seed}
    for name, start, end in phase_windows_s(result.params.scenario):
        if name not in PHASE_EVENTS:
            continue
        inside = events[(events.t_s >= start) & (events.t_s < end)]
        times = inside.t_s[inside.event.isin(PHASE_EVENTS[name])]
        last = round(float(times.max()) - start, 2) if len(times) else None
        row[name] = {"window_s": end - start, "last_s": last}
    return row


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
