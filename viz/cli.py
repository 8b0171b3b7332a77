"""The ``kilonet animate`` sub-command: render a finished run directory.

    kilonet animate DIR [--out FILE.gif|.mp4|.html] [--fps N] [--speed X]
                        [--overlay NAME ...] [--start S] [--end S] [--window S] [--size PX]
                        [--raw-estimates]

Registered as the ``animate`` entry point of ``kilonet.commands``; the work is done by
:func:`kilonet.viz.animation.animate_run`, which ``kilonet run --animate`` calls too.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from kilonet.errors import UsageError

__all__ = ["animate_after_run", "register"]


def register(subparsers: Any) -> None:
    """Add the ``animate`` sub-command to ``subparsers`` (from ``add_subparsers``)."""
    p = subparsers.add_parser(
        "animate",
        help="render a run directory as a GIF, MP4 or HTML replay",
        description="Render a run directory (kilonet run --out DIR) as an animated GIF, an MP4 "
        "(needs ffmpeg) or a self-contained HTML replay.",
    )
    p.add_argument("run_dir", metavar="DIR", help="run directory written by kilonet run --out")
    p.add_argument("--out", help="output file .gif, .mp4 or .html (default: DIR/animation.gif)")
    p.add_argument("--fps", type=float, default=10.0, help="video frames per second (10)")
    p.add_argument(
        "--speed",
        type=float,
        help="simulated seconds per video second (default: the run in at most 20 s)",
    )
    overlay = p.add_argument(
        "--overlay",
        action="extend",
        nargs="+",
        metavar="NAME",
        help="any of %(overlays)s, or none (default: those the run has data for, except edges)",
    )
    overlay.overlays = _OverlayNames()  # read only when the help is shown
    p.add_argument("--start", type=float, default=0.0, help="first simulated second shown")
    p.add_argument("--end", type=float, help="last simulated second shown (default: run end)")
    p.add_argument(
        "--window",
        type=float,
        help="messages overlay: senders of the last S seconds (default: one frame, at most "
        "one transmit period)",
    )
    p.add_argument("--size", type=int, default=640, help="frame width in pixels (640)")
    p.add_argument(
        "--raw-estimates",
        action="store_true",
        help="draw estimates as recorded, not aligned per frame onto the truth",
    )
    p.set_defaults(func=_cmd_animate)


class _OverlayNames:
    """The overlay names for the help text, from :data:`kilonet.viz.animation.OVERLAYS`: imported
    only when the help is printed, so that registering the command stays cheap."""

    def __str__(self) -> str:
        from kilonet.viz.animation import OVERLAYS

        return ", ".join(OVERLAYS)


def _cmd_animate(args: argparse.Namespace) -> int:
    from kilonet.scenarios.output_dir import why_not_written
    from kilonet.viz.animation import AnimationError, animate_run

    try:
        written = animate_run(
            args.run_dir,
            args.out,
            fps=args.fps,
            speed=args.speed,
            start_s=args.start,
            end_s=args.end,
            overlays=args.overlay,
            window_s=args.window,
            width_px=args.size,
            align_estimates=not args.raw_estimates,
        )
    except AnimationError as exc:
        raise UsageError(str(exc)) from None
    except OSError as exc:  # a read-only or full disk: the partial file is already removed
        target = Path(args.out) if args.out is not None else Path(args.run_dir) / "animation.gif"
        why = why_not_written(exc, target.parent)
        raise UsageError(f"{target}: cannot write the animation ({why})") from None
    print(f"wrote {written} ({written.stat().st_size / 1024:,.0f} kB)", file=sys.stderr)
    return 0


def animate_after_run(run_dir: Path) -> None:
    """Draw ``run_dir/animation.gif`` with the defaults (``kilonet run --animate``).

    Raises
    ------
    UsageError
        If the run directory cannot be animated (:class:`~kilonet.viz.animation.AnimationError`).
    """
    from kilonet.viz.animation import AnimationError, animate_run

    try:
        animate_run(run_dir)
    except AnimationError as exc:
        raise UsageError(str(exc)) from None
