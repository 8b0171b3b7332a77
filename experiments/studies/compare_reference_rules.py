"""Compare the two reference-selection rules of phase 3 by the accuracy of phase 4.

For each seed, the ``gcs`` scenario runs to the end of localization once with the thesis's rule
(``max_angle``: the largest angle at the seed) and once with ``best_conditioned`` (the widest
triangle), on the same placement and the same random streams; the table gives, per rule, the
mean, median and standard deviation over seeds of the per-frame RMSE after the best rigid alignment,
the share of robots located, and the fixes rejected.

    python -m kilonet.experiments.studies.compare_reference_rules [--seeds 20] [--robots 100]
    [--workers 2]
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import pandas as pd

from kilonet import scenarios

__all__ = ["compare", "run_one"]

RULES = ("max_angle", "best_conditioned")


def run_one(rule: str, seed: int, robots: int) -> dict[str, Any]:
    """One run of phases 1–4 with ``rule``; its phase-4 figures."""
    result = scenarios.run(
        scenarios.get("gcs"),
        {"gcs.until": "localization", "gcs.reference_rule": rule, "placement.robots": robots},
        seed=seed,
    )
    s = result.summary
    return {
        "rule": rule,
        "seed": seed,
        "local_rmse_mm": s["local_rmse_mm"],
        "located_fraction": s["locally_localized_fraction"],
        "fix_rejections": s["fix_rejections"],
    }


def compare(seeds: int = 20, robots: int = 100, workers: int = 2) -> pd.DataFrame:
    """Per rule: mean, median and standard deviation over ``seeds`` runs of each figure (the
    median too, because one bad frame in a run dominates that run's mean)."""
    jobs = [(rule, seed, robots) for seed in range(1, seeds + 1) for rule in RULES]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        rows = list(pool.map(run_one, *zip(*jobs, strict=True)))
    runs = pd.DataFrame(rows)
    return runs.groupby("rule")[["local_rmse_mm", "located_fraction", "fix_rejections"]].agg(
        ["mean", "median", "std"]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--robots", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    table = compare(args.seeds, args.robots, args.workers)
    print(table.round(3).to_string())


if __name__ == "__main__":
    main()
