"""``kilonet analyze``: predict the global coordinate system's failure cases before a full run.

Runs phases 1–2 (IDs and seed election) on the placement, then predicts phases 3–5 from the
distances the robots will hold (each link's noise-free estimate, within
``gcs.neighbour_max_mm``: :mod:`kilonet.scenarios.prediction`): each seed takes the reference pair
its rule would choose from them; robots join a seed's frame when they see the seed and at least two
robots already in that frame and their fix passes (repeated until nothing changes, as
localization spreads); merging groups are found as the robots would find them. The frame
graph's components are the global frames merging can reach.

``kilonet analyze PLACEMENT`` prints the prediction and writes nothing unless asked:
``--out F.png`` draws it.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet import scenarios
from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["predict", "prediction_figure", "register"]


def predict(
    placement: str | Path | np.ndarray, seed: int = 1, overrides: dict | None = None
) -> dict[str, Any]:
    """Run phases 1–2 on ``placement`` and predict the failure cases of phases 3–6.

    Returns the failure cases (robot indices), the rigidity facts, the seeds and the
    predicted frames per robot.
    """
    from kilonet.scenarios.neighbourhood import held_estimates_mm
    from kilonet.scenarios.prediction import predict_from_seeds

    result = scenarios.run(
        scenarios.get("gcs"),
        {**(overrides or {}), "gcs.until": "seeds"},
        seed=seed,
        placement=placement,
    )
    sim = result.sim
    seeds = [i for i, r in enumerate(sim.robots) if r.is_seed]
    estimates = held_estimates_mm(sim, sim.params.scenario.neighbour_max_mm)
    return predict_from_seeds(estimates, sim.params, seeds)


def prediction_figure(pos: np.ndarray, report: dict[str, Any]) -> Figure:
    """The prediction drawn: each robot (``pos``, mm) filled with the colour of the global
    frame it will report (grey: none), seeds as squares, and rings around the robots on a
    frame boundary and the other failure cases ``report`` (:func:`predict`) lists."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 6), layout="tight")
    ax = fig.add_subplot()
    final = report["final_frame"]
    unplaced = [i for i in range(len(pos)) if final.get(i) is None]
    if unplaced:
        ax.scatter(*pos[unplaced].T, s=40, c="0.75", label="in no frame")
    palette = colormaps["tab10"].colors
    seeds = set(report["seeds"])
    for k in range(len(report["frames"])):
        members = [i for i in range(len(pos)) if final.get(i) == k]
        if not members:
            continue  # a component no robot reports (merged into another)
        colour = palette[k % len(palette)]
        plain = [i for i in members if i not in seeds]
        ax.scatter(*pos[plain].reshape(-1, 2).T, s=40, color=colour, label=f"frame {k + 1}")
        own = [i for i in members if i in seeds]
        ax.scatter(*pos[own].reshape(-1, 2).T, s=60, color=colour, marker="s", edgecolors="k")
    if seeds:
        ax.scatter([], [], s=60, marker="s", facecolors="none", edgecolors="k", label="seeds")
    for key, color, size, label in (
        ("boundary", "tab:purple", 150, "on a frame boundary"),
        ("unlocalizable", "tab:red", 90, "cannot localize"),
        ("isolated_seeds", "tab:orange", 90, "isolated seed"),
        ("articulation_points", "k", 90, "articulation point"),
    ):
        if report[key]:
            ax.scatter(
                *pos[report[key]].T, s=size, facecolors="none", edgecolors=color, label=label
            )
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"predicted global frames: {report['final_frames']}")
    ax.legend(fontsize=7)
    return fig


def _cmd(args: argparse.Namespace) -> int:
    from kilonet.cli import UsageError
    from kilonet.placement import load_csv

    if args.placement in NAMED_PLACEMENTS:
        positions = NAMED_PLACEMENTS[args.placement]()
    elif Path(args.placement).exists():
        positions = load_csv(args.placement)
    else:
        named = ", ".join(sorted(NAMED_PLACEMENTS))
        raise UsageError(
            f"{args.placement}: no such placement file or named placement (named: {named})"
        )
    figure = None if args.out is None else _figure_target(args.out, args.replace)
    named = args.placement in NAMED_PLACEMENTS  # a name brings the thesis's premise along
    report = predict(args.placement if named else positions, seed=args.seed)
    if figure is not None:
        _write_figure(positions, report, figure)
    if args.json:
        print(json.dumps({k: v for k, v in report.items() if k != "located_in"}, indent=2))
        return 0
    print(f"robots                 {report['robots']}")
    print(f"seeds                  {len(report['seeds'])}")
    print(f"cannot localize        {len(report['unlocalizable'])}  {report['unlocalizable']}")
    print(f"isolated seeds         {len(report['isolated_seeds'])}  {report['isolated_seeds']}")
    sizes = [len(c) for c in report["frames"]]
    print(f"frame graph components {len(report['frames'])}  sizes {sizes}")
    print(f"final global frames    {report['final_frames']}  (as robots will report them)")
    print(f"on a frame boundary    {len(report['boundary'])}  {report['boundary']}")
    print(f"articulation points    {report['articulation_points']}")
    print(f"fewer than 3 neighbours {report['low_degree']}")
    if figure is not None:
        print(f"figure                 {figure}", file=sys.stderr)
    return 0


def _figure_target(out: str, replace: bool) -> Path:
    """``--out`` checked before the phases run: a PNG path in a writable directory, not there
    yet unless ``--replace``."""
    from kilonet.cli import UsageError

    path = Path(out)
    if path.suffix.lower() != ".png":
        raise UsageError(f"--out {out}: the figure is a PNG; give a file name ending in .png")
    if path.is_dir():
        raise UsageError(f"--out {out} is a directory; give a file name ending in .png")
    if path.exists() and not replace:
        raise UsageError(f"{out} already exists; choose another --out or pass --replace")
    if not path.parent.is_dir():
        raise UsageError(f"--out {out}: {path.parent} is not a directory")
    if not os.access(path.parent, os.W_OK | os.X_OK):
        raise UsageError(f"--out {out}: cannot write in {path.parent}")
    return path


def _write_figure(pos: np.ndarray, report: dict[str, Any], path: Path) -> None:
    """Draw into a temporary file beside ``path`` and rename it into place, so a failure
    leaves nothing behind."""
    from kilonet.cli import UsageError

    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.png")
    try:
        prediction_figure(pos, report).savefig(tmp, dpi=100)
        tmp.replace(path)
    except OSError as exc:
        raise UsageError(f"{path}: cannot write the figure ({exc.strerror})") from None
    finally:
        tmp.unlink(missing_ok=True)


def register(subparsers: Any) -> None:
    """Add ``kilonet analyze PLACEMENT [--seed S] [--json] [--out F.png [--replace]]``."""
    parser = subparsers.add_parser(
        "analyze", help="predict the global coordinate system's failure cases for a placement"
    )
    parser.add_argument(
        "placement", help="CSV with columns x_mm,y_mm, or a named placement (thesis-7.1a, ...)"
    )
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", action="store_true", help="print the prediction as JSON")
    parser.add_argument(
        "--out", metavar="F.png", help="also draw the prediction into F.png (default: no file)"
    )
    parser.add_argument("--replace", action="store_true", help="overwrite an existing F.png")
    parser.set_defaults(func=_cmd)
