"""Self-assembly against the ranging model, message loss and swarm size (issue 47, item 4).

What Rubenstein, Cornejo and Nagpal (Science 345:795, 2014) could only observe on their robots,
measured on kilonet's medium: how much of the swarm joins the shape, how well the bodies cover
it (IoU), how far the joined robots' estimates are from where they stand, and how far the
frame they share is turned about the seeds (``frame_rotation_deg``, the warp), against

* the ranging model: kilolib's estimate on each receiver's calibration tables, whose error
  depends on the sender and receiver (a per-link bias that averaging cannot remove), or
  independent Gaussian noise per reception (``ranging.model = "gaussian"``, its default
  ``ranging.sigma_mm``);
* message loss: none, or 20 % of receptions lost independently (``medium.loss_prob``);
* swarm size: 24 and 48 robots on the 8 x 8 ``square``, its cells scaled so that each robot
  has the room it has in the hundred-robot run (48 mm cells for 100 robots).

The sweep (:data:`SWEEP`, seeds 1-3) runs through kilonet's sweep machinery into a results
directory, and the report is written from what that directory holds (``python -m
kilonet.experiments.publish self_assembly_study`` does both, into ``runs/publish``)::

    python -m kilonet.experiments.studies.self_assembly_study --out DIR \\
        [--report experiments/reports/self_assembly_study.md] [--workers N]

An interrupted study resumes with the same command.
"""

from __future__ import annotations

import argparse
import datetime as dt
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from kilonet.experiments.report import _markdown_table, load
from kilonet.experiments.runner import run_sweep
from kilonet.experiments.sweep import Sweep, parse_sweep

__all__ = ["AXES", "FIGURES", "SWEEP", "cell_table", "run_study", "write_report"]

#: The study's sweep: 2 ranging models x 2 loss levels x 2 swarm sizes, seeds 1-3 (24 runs).
SWEEP = """
name = "self_assembly_study"
description = "Self-assembly against the ranging model, message loss and swarm size (issue 47)"
scenario = "self-assembly"
seeds = 3

[fixed]
"self_assembly.shape" = "square"

[grid]
"ranging.model" = ["tables", "gaussian"]
"medium.loss_prob" = [0.0, 0.2]

[[cases]]
"placement.robots" = 24
"self_assembly.cell_mm" = 23.5
duration_s = 3000.0

[[cases]]
"placement.robots" = 48
"self_assembly.cell_mm" = 33.3
duration_s = 5000.0
"""

#: The swept parameters, in the order the report's table groups them.
AXES = ("placement.robots", "ranging.model", "medium.loss_prob")
#: The summary figures the report gives for each cell: mean over seeds, then min-max.
FIGURES = (
    "joined_fraction",
    "iou",
    "localization_error_median_mm",
    "localization_error_max_mm",
    "frame_rotation_deg",
    "jammed_robots",
    "lost",
)


def cell_table(results: pd.DataFrame) -> pd.DataFrame:
    """One row per cell of the :data:`AXES` the sweep swept (``results`` has a column for
    each): the runs that finished, and for each of :data:`FIGURES` the mean over them and
    their range (``"mean (min to max)"``, text).

    Raises
    ------
    ValueError
        If no run finished.
    """
    done = results[results["status"] == "ok"]
    if done.empty:
        raise ValueError("no run of the study finished: nothing to report")
    axes = [axis for axis in AXES if axis in done.columns]
    rows = []
    for cell, runs in done.groupby(axes, sort=True):
        row = dict(zip(axes, cell, strict=True))
        row["runs"] = len(runs)
        for figure in FIGURES:
            values = pd.to_numeric(runs[figure], errors="coerce").dropna().to_numpy()
            row[figure] = _mean_range(values, 3 if figure in SHARES else 1)
        rows.append(row)
    return pd.DataFrame(rows)


#: Figures that are shares (given to three decimals; the others to one).
SHARES = frozenset({"joined_fraction", "iou"})


def _mean_range(values: np.ndarray, digits: int) -> str:
    if not len(values):
        return "-"
    mean, lo, hi = values.mean(), values.min(), values.max()
    return f"{mean:.{digits}f} ({lo:.{digits}f} to {hi:.{digits}f})"


def run_study(directory: str | Path, sweep_text: str = SWEEP, workers: int | None = None) -> Sweep:
    """Run the study's sweep (``sweep_text``, TOML; :data:`SWEEP` by default) into
    ``directory``, resuming what it already holds; the sweep it ran.

    Raises
    ------
    kilonet.experiments.sweep.SweepError
        If ``sweep_text`` is not a valid sweep.
    kilonet.experiments.store.StoreError
        If ``directory`` holds another sweep or is in use.
    """
    sweep = parse_sweep(sweep_text, name="self_assembly_study")
    run_sweep(sweep, directory, workers=workers, progress=False, source=sweep_text)
    return sweep


#: The report's comparison with the paper, and what explains the gaps (design, not figures).
PAPER = """\
## Beside the paper

What the paper reports of its robots, and where this study stands. The paper itself is not in
the project's seeds: its figures below are those issue 47 and the paper's abstract and
editor's summary give, and its shape accuracy is taken as the issue words it (no per-robot
figure of the paper is quoted here).

| | the paper's robots | this study |
|---|---|---|
| robots | 1,024, four of them seeds | 24 and 48, four of them seeds |
| time to assemble | about 12 hours a shape | `assembled_s`, simulated |
| communication | about three body diameters | links to about 148 mm, ranging to 80 mm |
| shape accuracy | warped, error growing outward | IoU, error per robot, frame turn |

The gaps, explained (read them against the table above):

* **Scale.** A turn of the robots' shared frame moves a robot in proportion to its distance
  from the seeds, and errors that add up ring by ring grow with the number of rings: a shape
  of 1,024 robots at the same spacing reaches about four and a half times as far from its
  seeds as one of 48. The frame's turn, which does not depend on the size, is what to set beside
  the paper's warped outlines; the localization error in mm is not.
* **Ranging.** On kilolib's tables a robot's estimate of a neighbour is off by an amount fixed
  by the pair (the sender's emitter strength is not in the receiver's calibration), so standing
  still and refining does not average it away, and each robot hands it on to the robots that
  localize against it. Independent noise per reception does average away. The paper's robots
  range the first way, so the `tables` rows are the ones to set beside them; where the two
  models part, the tables' errors are the larger and grow with the swarm.
* **Loss.** A lost message is a reading late, never a wrong one. At 24 robots 20 % loss moves
  no figure beyond the seeds' spread; at 48 it lowers the IoU under both ranging models, on
  the tables also the joined share, and the study's largest error and largest turn of the
  frame are there: a moving robot ranges with fewer fresh readings (at most 0.6 s old), so
  the per-link biases of the few it has average out less.
* **Jams and the bodies' cover.** Bodies at the packing's spacing cover at most about 0.6 of a
  shape, so an IoU near 0.6 would be a full shape. Robots that jam round the start, and the
  run's end 600 s after the last join (`STALLED_S`), keep the joined share of some runs below
  1; the design note names the jams as not done.
"""


def write_report(directory: str | Path, out: str | Path, stamp: str | None = None) -> Path:
    """Write the study's Markdown report on the runs stored in ``directory`` to the file
    ``out``: the sweep, the table of :func:`cell_table`, the comparison with the paper, the
    runs' summed wall time and ``stamp`` (what made it; by default this module's command, the
    date and the machine). Returns ``out``.

    Raises
    ------
    kilonet.experiments.store.StoreError
        If ``directory`` holds no sweep results.
    ValueError
        If no run finished.
    """
    sweep, results = load(directory)
    table = cell_table(results)
    failed = int((results["status"] != "ok").sum())
    lines = [
        "# Self-assembly: ranging model, message loss and swarm size",
        "",
        f"Sweep `{sweep.name}`: {len(results)} runs stored "
        f"({failed} failed), seeds {', '.join(str(s) for s in sweep.seeds)}, on the 8 x 8 "
        "`square` with the cells scaled to the swarm (`self_assembly.cell_mm`). Each figure is "
        "the mean over the seeds, then the smallest and the largest; `frame_rotation_deg` is "
        "the turn of the robots' shared frame about the seeds (counter-clockwise positive), "
        "the warp.",
        "",
        *([sweep.description, ""] if sweep.description else []),
        *_markdown_table(table),
        "",
        PAPER,
        f"The runs took {results['wall_s'].sum():.0f} s of wall time in all.",
        "",
        f"*{stamp or _stamp(directory)}*",
        "",
    ]
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines))
    return out


def _stamp(directory: str | Path) -> str:
    return (
        f"Generated by `python -m kilonet.experiments.studies.self_assembly_study --out "
        f"{Path(directory).name}` on {dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC "
        f"({platform.system()} {platform.machine()}, Python {platform.python_version()})."
    )


def main(argv: list[str] | None = None) -> int:
    """Run the study (or resume it) and write its report; the exit status."""
    parser = argparse.ArgumentParser(prog="self_assembly_study", description=__doc__.split("\n")[0])
    parser.add_argument("--out", required=True, help="the sweep's results directory")
    parser.add_argument(
        "--report",
        default="experiments/reports/self_assembly_study.md",
        help="the Markdown report to write",
    )
    parser.add_argument("--workers", type=int, default=None, help="local worker processes")
    args = parser.parse_args(argv)
    run_study(args.out, workers=args.workers)
    print(write_report(args.out, args.report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
