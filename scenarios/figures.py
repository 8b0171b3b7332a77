"""Figures that several scenarios draw.

:func:`frames_figure` draws a swarm's estimates against the truth: every robot as a body at its
true position, and for every robot of a frame that can be aligned (three robots or more) an
error vector from its true position towards its aligned estimate (``robots.csv``'s
``aligned_x_mm``, ``aligned_y_mm``: :func:`kilonet.scenarios.estimates.with_alignment`), magnified
by the factor :func:`error_magnification` picks and the legend states, since errors of a
millimetre would not show at the scale of a swarm. One colour per frame, frames numbered by size
(frame 1 is the largest) and named by their root robot. The figure takes the swarm's aspect
ratio and the legend sits below the axes, so it never covers a robot.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

__all__ = ["MAX_LEGEND_FRAMES", "error_magnification", "frame_legend_labels", "frames_figure"]

#: Frames named one by one in the legend; smaller ones share one entry.
MAX_LEGEND_FRAMES = 8

#: The magnified errors are drawn about this long (mm): half a robot's body, so that a vector
#: stays beside its robot rather than reaching the next one.
_DRAWN_ERROR_MM = 16.5

#: Free table around the outermost bodies, mm.
_MARGIN_MM = 10.0

#: The largest side of the axes, inches.
_AXES_IN = 6.4


def error_magnification(errors_mm: np.ndarray, drawn_mm: float = _DRAWN_ERROR_MM) -> float:
    """How much to magnify error vectors so that they show: the largest round factor (1, 2 or 5
    times a power of ten) that draws the 90th percentile of ``errors_mm`` no longer than
    ``drawn_mm``; never below 1 (errors are never drawn shorter than they are).

    The 90th percentile rather than the largest error, so that one robot that is far off does
    not hide everyone else's errors (its vector is drawn long, and clipped at the axes).

    Examples
    --------
    >>> error_magnification(np.array([0.5, 1.0, 1.2, np.nan]))
    10.0
    >>> error_magnification(np.array([0.05, 0.08]))
    200.0
    >>> error_magnification(np.array([30.0])), error_magnification(np.array([np.nan]))
    (1.0, 1.0)
    """
    finite = np.asarray(errors_mm, dtype=float)
    finite = finite[np.isfinite(finite)]
    typical = float(np.percentile(finite, 90)) if len(finite) else 0.0
    if typical <= 0 or typical >= drawn_mm:
        return 1.0
    limit = drawn_mm / typical
    power = 10.0 ** math.floor(math.log10(limit))
    return max(f * power for f in (1.0, 2.0, 5.0) if f * power <= limit)


def frame_legend_labels(estimates: pd.DataFrame) -> list[tuple[str, str]]:
    """The frames of the localized robots, largest first (ties: by root robot), each as ``(label in
    estimates.frame, legend text)``: ``"frame 1 (root: robot 12), 95 robots"``.

    Examples
    --------
    >>> import pandas as pd
    >>> table = pd.DataFrame({"frame": ["root9", "root4", "root4", ""],
    ...                       "root_robot": [7, 2, 2, -1], "localized": [True, True, True, False]})
    >>> frame_legend_labels(table)
    [('root4', 'frame 1 (root: robot 2), 2 robots'), ('root9', 'frame 2 (root: robot 7), 1 robot')]
    """
    done = estimates[estimates.localized]
    sizes = done.groupby("frame").size()
    roots = done.groupby("frame").root_robot.first()
    order = sorted(sizes.index, key=lambda label: (-sizes[label], roots[label], label))
    out = []
    for k, label in enumerate(order, start=1):
        root, n = int(roots[label]), int(sizes[label])
        who = f"root: robot {root}" if root >= 0 else "root not in the swarm"
        out.append((label, f"frame {k} ({who}), {n} robot{'s' if n != 1 else ''}"))
    return out


def frames_figure(
    truth_mm: np.ndarray,
    estimates: pd.DataFrame,
    marked: np.ndarray,
    marked_label: str,
    title: str,
    path: Path,
) -> Figure:
    """Write the estimates-against-truth figure to ``path`` (PNG) and return it.

    Parameters
    ----------
    truth_mm : (N, 2) array
        True positions, mm.
    estimates : DataFrame
        One row per robot: ``robot``, ``frame`` (label), ``root_robot``, ``localized`` (bool),
        ``aligned_x_mm``, ``aligned_y_mm``, ``error_mm`` (as
        :func:`kilonet.scenarios.estimates.with_alignment` adds them).
    marked : array of int
        Robots to mark with a cross (seeds, roots).
    marked_label, title : str
        Legend entry of the crosses; the figure's title.
    path : Path
        Where to write the PNG.
    """
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    from kilonet.placement import ROBOT_DIAMETER_MM

    truth = np.asarray(truth_mm, dtype=float)
    rows = estimates.robot.to_numpy()
    margin = ROBOT_DIAMETER_MM / 2 + _MARGIN_MM
    lo, hi = truth.min(axis=0) - margin, truth.max(axis=0) + margin
    span = hi - lo
    in_per_mm = _AXES_IN / span.max()
    ax_w, ax_h = span * in_per_mm
    fig = Figure(figsize=(ax_w + 1.2, ax_h + 1.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_axes(
        (0.9 / (ax_w + 1.2), 0.6 / (ax_h + 1.0), ax_w / (ax_w + 1.2), ax_h / (ax_h + 1.0))
    )
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    body_pt = ROBOT_DIAMETER_MM * in_per_mm * 72  # a robot's diameter in points
    handles: list[Line2D] = []

    localized = estimates.localized.to_numpy(dtype=bool)
    aligned = estimates[["aligned_x_mm", "aligned_y_mm"]].to_numpy(dtype=float)
    alignable = localized & np.isfinite(aligned).all(axis=1)
    ax.scatter(
        truth[rows[localized], 0],
        truth[rows[localized], 1],
        s=body_pt**2,
        facecolors="none",
        edgecolors="0.6",
        linewidths=0.8,
        zorder=1,
    )
    if localized.any():
        handles.append(_handle("robot (true position, to scale)", "o", "none", "0.6", 9))
    if (~localized).any():
        ax.scatter(
            truth[rows[~localized], 0],
            truth[rows[~localized], 1],
            s=body_pt**2,
            facecolors="none",
            edgecolors="tab:red",
            linewidths=1.2,
            linestyle="--",
            zorder=1,
        )
        handles.append(
            _handle(f"not localized ({int((~localized).sum())})", "o", "none", "tab:red", 9)
        )
    unaligned = localized & ~alignable
    if unaligned.any():
        ax.scatter(truth[rows[unaligned], 0], truth[rows[unaligned], 1], s=12, c="0.4", zorder=3)
        handles.append(
            _handle(
                f"in a frame of < 3 robots, not aligned ({int(unaligned.sum())})",
                "o",
                "0.4",
                "0.4",
                4,
            )
        )

    factor = error_magnification(estimates.error_mm[alignable].to_numpy(dtype=float))
    start = truth[rows[alignable]]
    end = start + factor * (aligned[alignable] - start)
    ax.add_collection(
        LineCollection(np.stack([start, end], axis=1), colors="tab:red", linewidths=1.0, zorder=2)
    )
    if alignable.any():
        error = estimates.error_mm[alignable]
        vector = f"error × {factor:g}" if factor != 1 else "error (true scale)"
        label = f"{vector}: true position → aligned estimate (RMS {_rms(error):.2f} mm)"
        handles.append(Line2D([], [], color="tab:red", lw=1.0, label=label))

    cmap = colormaps["tab10"]
    frames = frame_legend_labels(estimates[alignable])
    frame_of = estimates.frame[alignable].to_numpy()
    for k, (label, text) in enumerate(frames):
        members = frame_of == label
        colour = cmap(k % 10)
        ax.scatter(end[members, 0], end[members, 1], s=10, color=colour, zorder=4)
        if k < MAX_LEGEND_FRAMES:
            handles.append(_handle(text, "o", colour, colour, 4))
    if len(frames) > MAX_LEGEND_FRAMES:
        rest = len(frames) - MAX_LEGEND_FRAMES
        handles.append(
            _handle(f"{rest} smaller frame{'s' if rest > 1 else ''}", "o", "0.5", "0.5", 4)
        )

    marked = np.asarray(marked, dtype=int)
    if len(marked):
        ax.scatter(truth[marked, 0], truth[marked, 1], marker="x", s=30, c="k", zorder=5)
        handles.append(_handle(marked_label, "x", "k", "k", 6))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title, fontsize=10)
    # Below the axes, outside them: a legend inside would cover robots wherever it went.
    ax.legend(
        handles=handles,
        loc="upper left",
        bbox_to_anchor=(0.0, -0.5 / ax_h),  # 0.5 inch down: below the x label
        fontsize=8,
        frameon=False,
        ncol=1,
    )
    fig.savefig(path, dpi=100, bbox_inches="tight")
    return fig


def _handle(label: str, marker: str, face: str | tuple, edge: str | tuple, size: float):
    from matplotlib.lines import Line2D

    return Line2D(
        [], [], linestyle="none", marker=marker, markersize=size, markerfacecolor=face,
        markeredgecolor=edge, color=edge, label=label,
    )  # fmt: skip


def _rms(values: pd.Series) -> float:
    finite = values.to_numpy(dtype=float)
    finite = finite[np.isfinite(finite)]
    return math.sqrt(float(np.mean(finite**2))) if len(finite) else math.nan
