"""Figures that several scenarios draw.

:func:`frames_figure` draws a swarm's estimates against the truth, one colour per frame, each
frame aligned to the truth on its own (rotation, shift and reflection; frames of fewer than
three robots at their true positions), with a red line from every robot's true position to its
aligned estimate.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from kilonet.central import pooled_aligned_rmse

__all__ = ["frames_figure"]


def frames_figure(
    truth_mm: np.ndarray,
    estimates: pd.DataFrame,
    marked: np.ndarray,
    marked_label: str,
    title: str,
    path: Path,
) -> None:
    """Write the estimates-against-truth figure to ``path`` (PNG).

    Parameters
    ----------
    truth_mm : (N, 2) array
        True positions, mm.
    estimates : DataFrame
        One row per robot: ``robot``, ``est_x_mm``, ``est_y_mm``, ``frame`` (label),
        ``localized`` (bool).
    marked : array of int
        Robots to mark with a cross (seeds, roots).
    marked_label, title : str
        Legend entry of the crosses; the figure's title.
    path : Path
        Where to write the PNG.
    """
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.scatter(
        truth_mm[:, 0], truth_mm[:, 1], s=40, facecolors="none", edgecolors="0.6", label="truth"
    )
    done = estimates[estimates.localized]
    cmap = plt.get_cmap("tab10")
    for k, (label, group) in enumerate(done.groupby("frame")):
        idx = group.robot.to_numpy()
        points = group[["est_x_mm", "est_y_mm"]].to_numpy()
        _, aligned = pooled_aligned_rmse(points, truth_mm[idx], np.zeros(len(idx), dtype=int))
        if np.isnan(aligned).all():
            aligned = truth_mm[idx]
        ax.scatter(aligned[:, 0], aligned[:, 1], s=12, color=cmap(k % 10), label=f"frame {label}")
        for (x0, y0), (x1, y1) in zip(truth_mm[idx], aligned, strict=True):
            ax.plot([x0, x1], [y0, y1], color="red", lw=0.8)
    ax.scatter(
        truth_mm[marked, 0], truth_mm[marked, 1], marker="x", s=30, c="k", label=marked_label
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(title)
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
