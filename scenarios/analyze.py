"""Predict the global coordinate system's failure cases before a full run.

Runs phases 1–2 (IDs and seed election) on the placement, then predicts phases 3–5 from the
distances the robots will hold (each link's noise-free estimate, within
``gcs.neighbour_max_mm``: :mod:`kilonet.scenarios.prediction`): each seed takes the reference pair
its rule would choose from them; robots join a seed's frame when they see the seed and at least two
robots already in that frame and their fix passes (repeated until nothing changes, as
localization spreads); merging groups are found as the robots would find them. The frame
graph's components are the global frames merging can reach. ``kilonet analyze``
(:mod:`kilonet.app.analyze`) prints the prediction and draws it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet import scenarios

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["predict", "prediction_figure"]


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
