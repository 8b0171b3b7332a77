"""When does the global coordinate system end with one global frame? (issue 6)

Reads a finished run of the sweep ``experiments/topology.toml`` (``kilonet sweep
experiments/topology.toml --out DIR``) and writes a Markdown report with:

* the confusion table of the predicted number of final frames (geometry and phase 2's
  election, :mod:`kilonet.scenarios.prediction`) against the observed number, runs without recovery;
* the share of runs ending with one global frame without and with recovery
  (:mod:`kilonet.protocols.gcs.recovery`), over the same placements;
* the swarm's split detection (:mod:`kilonet.protocols.gcs.split_detection`) judged against the
  run's truth (robots with a neighbour whose estimate ended in another final frame): precision and
  recall, pooled over runs;
* a figure: the probability of one global frame against the mean neighbour count.

    python -m kilonet.experiments.studies.topology_study DIR [--out experiments/reports]

With ``--coverage DRAWS`` it checks ``kilonet analyze``'s prediction over link draws instead
(:func:`draw_coverage`): how often each run's observation lies in the 90 % interval.

    python -m kilonet.experiments.studies.topology_study DIR --coverage 200
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from kilonet.experiments.report import _markdown_table, load

__all__ = [
    "coverage_block",
    "coverage_shares",
    "detection_scores",
    "draw_coverage",
    "one_frame_shares",
    "prediction_confusion",
    "write_report",
]

RECOVERY = "gcs.recoveries"
#: The sweep's range axis: how far a robot's gcs takes its neighbours, mm.
RANGE = "gcs.neighbour_max_mm"


def _done(results: pd.DataFrame) -> pd.DataFrame:
    return results[results.status == "ok"].copy()


def prediction_confusion(results: pd.DataFrame) -> tuple[pd.DataFrame, float]:
    """Predicted against observed final frames (runs without recovery) and the share of runs
    where they are equal."""
    runs = _done(results)
    runs = runs[runs[RECOVERY] == 0]
    table = pd.crosstab(
        runs["predicted.final_frames"].astype(int).rename("predicted"),
        runs["frames"].astype(int).rename("observed"),
    )
    equal = float((runs["predicted.final_frames"] == runs["frames"]).mean())
    return table, equal


def one_frame_shares(results: pd.DataFrame) -> pd.DataFrame:
    """Share of runs ending with one global frame, without and with recovery, by neighbour
    range (``gcs.neighbour_max_mm``) and density and overall."""
    runs = _done(results)
    runs["one_frame"] = runs["frames"] == 1
    by = [RANGE, "placement.density_per_m2"]
    cells = runs.pivot_table(index=by, columns=RECOVERY, values="one_frame", aggfunc="mean")
    cells.loc[("all", "all"), :] = runs.groupby(RECOVERY)["one_frame"].mean()
    neighbours = runs.groupby(by)["mean_neighbours"].mean()
    cells.insert(0, "mean_neighbours", neighbours)
    cells.loc[("all", "all"), "mean_neighbours"] = runs["mean_neighbours"].mean()
    return cells.rename(columns={0: "without recovery", 2: "with recovery"})


def detection_scores(results: pd.DataFrame) -> dict[str, float]:
    """Pooled precision and recall of the swarm's split-boundary flags against the run's truth
    (robots next to another final frame), runs without recovery."""
    runs = _done(results)
    runs = runs[runs[RECOVERY] == 0]
    hits = flagged = truth = 0
    for detected, actual in zip(
        runs["detected.split_boundary"], runs["failures.boundary"], strict=True
    ):
        d, a = set(json.loads(detected)), set(json.loads(actual))
        hits += len(d & a)
        flagged += len(d)
        truth += len(a)
    return {
        "precision": hits / flagged if flagged else float("nan"),
        "recall": hits / truth if truth else float("nan"),
        "flagged": flagged,
        "boundary_robots": truth,
    }


def draw_coverage(
    sweep_dir: str | Path,
    draws: int = 200,
    *,
    workers: int = 1,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> pd.DataFrame:
    """``kilonet analyze``'s prediction over draws of the robots and their links
    (:func:`kilonet.scenarios.analyze.predict_draws`) for every finished run without recovery
    of the sweep in ``sweep_dir``, at the run's placement parameters and seed, next to what the
    run observed; ``workers`` processes share the runs, ``progress`` is called with each row
    as it is made (in run order).

    Returns one row per run: the grid's values and ``seed``; ``frames`` and ``unlocalizable``
    (observed: final global frames, robots in no frame); ``predicted`` (the in-run point
    prediction of the final frames); ``frames_median``, ``frames_low``, ``frames_high`` and
    ``unlocalizable_median``, ``unlocalizable_low``, ``unlocalizable_high`` (the draws'
    median and 90 % interval); ``frames_inside`` and ``unlocalizable_inside``."""
    from concurrent.futures import ProcessPoolExecutor

    sweep, results = load(sweep_dir)
    done = _done(results).set_index("run_id")
    jobs = [
        (run.cell, run.overrides, run.seed, done.loc[run.run_id].to_dict(), draws)
        for run in sweep.runs()
        if run.overrides.get(RECOVERY) == 0 and run.run_id in done.index
    ]
    rows = []
    with ProcessPoolExecutor(workers) if workers > 1 else nullcontext() as pool:
        for row in pool.map(_coverage_row, jobs) if pool else map(_coverage_row, jobs):
            if progress is not None:
                progress(row)
            rows.append(row)
    return pd.DataFrame(rows)


def _coverage_row(job: tuple[dict, dict, int, dict, int]) -> dict[str, Any]:
    """One row of :func:`draw_coverage`: ``job`` is the run's cell, overrides and seed, its
    stored results and the number of draws."""
    from kilonet.scenarios.analyze import predict_draws

    cell, overrides, seed, seen, draws = job
    drawn = predict_draws(None, seed, overrides, draws=draws)
    row = {**cell, "seed": seed, "frames": int(seen["frames"])}
    row["unlocalizable"] = len(json.loads(seen["failures.unlocalizable"]))
    row["predicted"] = int(seen["predicted.final_frames"])
    for name in ("frames", "unlocalizable"):
        spread = drawn["final_frames" if name == "frames" else name]
        for key in ("median", "low", "high"):
            row[f"{name}_{key}"] = spread[key]
        row[f"{name}_inside"] = spread["low"] <= row[name] <= spread["high"]
    return row


def coverage_shares(table: pd.DataFrame) -> dict[str, float]:
    """From :func:`draw_coverage`'s table: the share of runs whose observed final frames
    (``frames``) and unlocalizable robots (``unlocalizable``) lie in the draws' 90 % interval,
    and the share where the in-run point prediction equals the observed final frames
    (``point_equal``), over ``runs`` runs."""
    return {
        "runs": len(table),
        "frames": float(table["frames_inside"].mean()),
        "unlocalizable": float(table["unlocalizable_inside"].mean()),
        "point_equal": float((table["predicted"] == table["frames"]).mean()),
    }


def coverage_block(sweep_dir: str | Path, draws: int = 200) -> str:
    """The check of ``kilonet analyze``'s intervals on the sweep in ``sweep_dir``
    (:func:`draw_coverage`, :func:`coverage_shares`) as Markdown: the shares overall and by
    cell (``docs/results/analyze.md``'s block ``analyze-coverage``)."""
    table = draw_coverage(sweep_dir, draws)
    shares = coverage_shares(table)
    cells = (
        table.groupby([RANGE, "placement.density_per_m2"])
        .agg(
            runs=("seed", "size"),
            frames_inside=("frames_inside", "mean"),
            unlocalizable_inside=("unlocalizable_inside", "mean"),
        )
        .reset_index()
        .round(2)
    )
    return "\n".join(
        [
            f"{shares['runs']} runs without recovery, {draws} draws each: the observed final "
            f"frames lie in the 90 % interval in **{shares['frames']:.0%}** of runs, the "
            f"robots that cannot localize in {shares['unlocalizable']:.0%}; the in-run point "
            f"prediction equals the observed final frames in {shares['point_equal']:.0%}.",
            "",
            *_markdown_table(cells),
        ]
    )


def _figure(results: pd.DataFrame, path: Path) -> None:
    runs = _done(results)
    runs["one_frame"] = runs["frames"] == 1
    edges = np.arange(np.floor(runs.mean_neighbours.min()), runs.mean_neighbours.max() + 1, 1.0)
    runs["bin"] = pd.cut(runs.mean_neighbours, edges)
    fig, ax = plt.subplots(figsize=(6, 4))
    for recoveries, label in ((0, "without recovery"), (2, "with recovery")):
        part = runs[runs[RECOVERY] == recoveries].groupby("bin", observed=True)
        share, count = part["one_frame"].mean(), part["one_frame"].size()
        centres = [b.mid for b in share.index]
        # The binomial standard error of each share: enough to show which bins are thin.
        err = np.sqrt(share * (1 - share) / count)
        ax.errorbar(centres, share, yerr=err, marker="o", capsize=3, label=label)
    ax.set_xlabel("mean neighbour count (within gcs.neighbour_max_mm)")
    ax.set_ylabel("P(one global frame)")
    ax.set_ylim(-0.05, 1.05)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title("Global coordinate system: one frame against density and neighbour range")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_report(sweep_dir: str | Path, out_dir: str | Path, *, stamp: str | None = None) -> Path:
    """Write ``topology.md`` and ``topology_files/one_frame.png`` under ``out_dir``; ``stamp``
    is its last line (default: the command that makes it)."""
    sweep, results = load(sweep_dir)
    out = Path(out_dir)
    files = out / "topology_files"
    files.mkdir(parents=True, exist_ok=True)
    confusion, equal = prediction_confusion(results)
    shares = one_frame_shares(results)
    scores = detection_scores(results)
    _figure(results, files / "one_frame.png")
    runs = _done(results)
    placements = runs[runs[RECOVERY] == 0]
    lines = [
        "# Topology: one global frame or several",
        "",
        sweep.description,
        "",
        f"{len(runs)} runs finished ({len(placements)} placements); "
        f"{int((results.status != 'ok').sum())} failed.",
        "",
        "## Predicted against observed final frames (without recovery)",
        "",
        f"Equal in **{equal:.0%}** of runs.",
        "",
        *_markdown_table(confusion.reset_index().rename(columns={"predicted": "predicted"})),
        "",
        "## Share of runs ending with one global frame",
        "",
        *_markdown_table(shares.reset_index()),
        "",
        "## Split detection in the swarm (without recovery)",
        "",
        f"Precision {scores['precision']:.2f}, recall {scores['recall']:.2f} "
        f"({scores['flagged']} robots flagged, {scores['boundary_robots']} on a boundary).",
        "",
        "![P(one global frame) against mean neighbour count](topology_files/one_frame.png)",
        "",
        stamp
        or f"Generated by `python -m kilonet.experiments.studies.topology_study {sweep_dir}`.",
        "",
    ]
    path = out / "topology.md"
    path.write_text("\n".join(lines))
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", help="output directory of kilonet sweep topology.toml")
    parser.add_argument("--out", default="experiments/reports")
    parser.add_argument(
        "--coverage",
        type=int,
        metavar="DRAWS",
        help="instead of the report, check kilonet analyze's 90 %% intervals over DRAWS draws "
        "against the runs without recovery and print each run and the shares inside",
    )
    parser.add_argument("--workers", type=int, default=1, help="processes for --coverage")
    args = parser.parse_args()
    if args.coverage is None:
        print(write_report(args.sweep_dir, args.out))
        return
    table = draw_coverage(
        args.sweep_dir,
        args.coverage,
        workers=args.workers,
        progress=lambda row: print(json.dumps(row), flush=True),
    )
    print(json.dumps(coverage_shares(table)))


if __name__ == "__main__":
    main()
