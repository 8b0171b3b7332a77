"""``kilonet analyze``: predict the global coordinate system's failure cases before a full run.

``kilonet analyze PLACEMENT`` prints the prediction (:func:`kilonet.scenarios.analyze.predict`)
and writes nothing unless asked: ``--out F.png`` draws it
(:func:`kilonet.scenarios.analyze.prediction_figure`).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kilonet.errors import UsageError
from kilonet.scenarios.analyze import predict, prediction_figure
from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS

if TYPE_CHECKING:
    import numpy as np

__all__ = ["register"]


def _cmd(args: argparse.Namespace) -> int:
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
