"""``kilonet analyze``: predict the global coordinate system's failure cases before a full run.

``kilonet analyze PLACEMENT`` prints the prediction over draws of the robots and their links
(:func:`kilonet.scenarios.analyze.predict_draws`): the median and 90 % interval of the final
global frames and of the robots that cannot localize, then the deterministic prediction from
the links of the run's own robots (:func:`kilonet.scenarios.analyze.predict`). It writes
nothing unless asked: ``--out F.png`` draws the deterministic prediction
(:func:`kilonet.scenarios.analyze.prediction_figure`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kilonet.app.commands import parse_set
from kilonet.errors import UsageError

if TYPE_CHECKING:
    import numpy as np

__all__ = ["register"]

#: How many draws ``--draws`` makes unless told.
DRAWS = 200


def _cmd(args: argparse.Namespace) -> int:
    # Imported here, not with the module: `kilonet --help` registers this command too, and
    # the prediction (numpy, the gcs protocol) is for `kilonet analyze` alone.
    from kilonet.placement import load_csv
    from kilonet.scenarios.analyze import predict_draws
    from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS

    if args.placement in NAMED_PLACEMENTS:
        positions = NAMED_PLACEMENTS[args.placement]()
    elif Path(args.placement).exists():
        positions = load_csv(args.placement)
    else:
        named = ", ".join(sorted(NAMED_PLACEMENTS))
        raise UsageError(
            f"{args.placement}: no such placement file or named placement (named: {named})"
        )
    if args.draws < 1:
        raise UsageError(f"--draws {args.draws}: give at least 1 draw")
    overrides = parse_set(args.set)  # the keys and values are checked by the run
    figure = None if args.out is None else _figure_target(args.out, args.replace)
    named = args.placement in NAMED_PLACEMENTS  # a name brings the thesis's premise along
    drawn = predict_draws(
        args.placement if named else positions, args.seed, overrides, draws=args.draws
    )
    report = drawn["deterministic"]
    if figure is not None:
        _write_figure(positions, report, figure)
    if args.json:
        out = {k: v for k, v in report.items() if k != "located_in"}
        out["link_draws"] = {k: v for k, v in drawn.items() if k != "deterministic"}
        print(json.dumps(out, indent=2))
        return 0
    frames, lost = drawn["final_frames"], drawn["unlocalizable"]
    print(f"robots                 {report['robots']}")
    print(f"seeds                  {len(report['seeds'])}")
    print(f"over {drawn['draws']} draws of the robots and their links (median, 90 % interval):")
    print(f"final global frames    {frames['median']}  [{frames['low']}, {frames['high']}]")
    print(f"cannot localize        {lost['median']}  [{lost['low']}, {lost['high']}]")
    print(f"deterministic, the links of seed {args.seed}'s robots:")
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
    from kilonet.scenarios.analyze import prediction_figure

    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp.png")
    try:
        prediction_figure(pos, report).savefig(tmp, dpi=100)
        tmp.replace(path)
    except OSError as exc:
        raise UsageError(f"{path}: cannot write the figure ({exc.strerror})") from None
    finally:
        tmp.unlink(missing_ok=True)


def register(subparsers: Any) -> None:
    """Add ``kilonet analyze PLACEMENT [--seed S] [--set KEY=VALUE ...] [--draws N] [--json]
    [--out F.png [--replace]]``."""
    parser = subparsers.add_parser(
        "analyze", help="predict the global coordinate system's failure cases for a placement"
    )
    parser.add_argument(
        "placement", help="CSV with columns x_mm,y_mm, or a named placement (thesis-7.1a, ...)"
    )
    parser.add_argument("--seed", type=int, default=1, help="master seed of phases 1-2's run")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="set a parameter as kilonet run does; repeat for more (kilonet params gcs)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=DRAWS,
        metavar="N",
        help=f"draws of the robots and their links (default: {DRAWS})",
    )
    parser.add_argument("--json", action="store_true", help="print the prediction as JSON")
    parser.add_argument(
        "--out", metavar="F.png", help="also draw the prediction into F.png (default: no file)"
    )
    parser.add_argument("--replace", action="store_true", help="overwrite an existing F.png")
    parser.set_defaults(func=_cmd)
