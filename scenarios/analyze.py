"""Predict the global coordinate system's failure cases before a full run.

Runs phases 1–2 (IDs and seed election) on the placement, then predicts phases 3–5 from the
distances the robots will hold (each link's noise-free estimate, within
``gcs.neighbour_max_mm``: :mod:`kilonet.scenarios.prediction`): each seed takes the reference pair
its rule would choose from them; robots join a seed's frame when they see the seed and at least two
robots already in that frame and their fix passes (repeated until nothing changes, as
localization spreads); merging groups are found as the robots would find them. The frame
graph's components are the global frames merging can reach.

:func:`predict` predicts from the links of the simulated run's own robots (deterministic);
:func:`predict_draws` from many draws of the robots and their links
(:mod:`kilonet.scenarios.link_draws`, ``docs/analyze.md``), as a median and a 90 % interval.
``kilonet analyze`` (:mod:`kilonet.app.analyze`) prints both and draws the deterministic one.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet import scenarios

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from kilonet.protocols.gcs.frame_keys import FrameKey
    from kilonet.simulation import Simulation

__all__ = ["predict", "predict_draws", "prediction_figure", "spread"]


def predict(
    placement: str | Path | np.ndarray | None, seed: int = 1, overrides: dict | None = None
) -> dict[str, Any]:
    """Run phases 1–2 on ``placement`` (``None``: the ``placement`` parameters') and predict
    the failure cases of phases 3–6 from the links of the run's own robots (deterministic).

    Returns the failure cases (robot indices), the rigidity facts, the seeds and the
    predicted frames per robot (:func:`kilonet.scenarios.prediction.predict_from_seeds`).

    Raises
    ------
    kilonet.params.ParamError
        If ``overrides`` name an unknown parameter or a bad value.
    """
    from kilonet.scenarios.neighbourhood import held_estimates_mm
    from kilonet.scenarios.prediction import predict_from_seeds

    sim, seeds, keys = _elect(placement, seed, overrides)
    estimates = held_estimates_mm(sim, sim.params.scenario.neighbour_max_mm)
    return predict_from_seeds(estimates, sim.params, seeds, keys)


def predict_draws(
    placement: str | Path | np.ndarray | None,
    seed: int = 1,
    overrides: dict | None = None,
    draws: int = 200,
) -> dict[str, Any]:
    """Run phases 1–2 on ``placement`` and predict phases 3–6 on ``draws`` draws of the
    robots and their links (:func:`kilonet.scenarios.link_draws.draw_held_estimates`), with
    the seeds phase 2 elected.

    The draws come from a stream of their own, seeded by ``seed``: the same call gives the
    same draws.

    Returns
    -------
    dict
        ``draws``; ``final_frames`` and ``unlocalizable`` (how many robots cannot localize),
        each as :func:`spread` of the draws' values; ``deterministic``: :func:`predict`'s
        report, the run's own links.

    Raises
    ------
    ValueError
        If ``draws`` is below 1.
    kilonet.params.ParamError
        If ``overrides`` name an unknown parameter or a bad value.
    """
    from kilonet.scenarios.link_draws import draw_held_estimates, messages_before_frames
    from kilonet.scenarios.neighbourhood import held_estimates_mm
    from kilonet.scenarios.prediction import predict_from_seeds

    if draws < 1:
        raise ValueError(f"draws must be at least 1, got {draws}")
    sim, seeds, keys = _elect(placement, seed, overrides)
    params = sim.params
    deterministic = predict_from_seeds(
        held_estimates_mm(sim, params.scenario.neighbour_max_mm), params, seeds, keys
    )
    rng = np.random.default_rng([_DRAW_STREAM, seed])
    messages = messages_before_frames(params)
    finals, unlocalizable = [], []
    for _ in range(draws):
        estimates = draw_held_estimates(
            sim.world.positions_mm, params, rng, radius_mm=sim.world.radius_mm, messages=messages
        )
        report = predict_from_seeds(estimates, params, seeds, keys)
        finals.append(report["final_frames"])
        unlocalizable.append(len(report["unlocalizable"]))
    return {
        "draws": draws,
        "messages_per_link": messages,
        "final_frames": spread(finals),
        "unlocalizable": spread(unlocalizable),
        "deterministic": deterministic,
    }


#: Mixed into the draws' seed so that they share no stream with a run of the same seed.
_DRAW_STREAM = 46


def spread(values: list[int], level: float = 0.9) -> dict[str, int]:
    """The median and central ``level`` interval of integer ``values``: ``median``, ``low``,
    ``high``, each a value drawn (the smallest whose share at or below it reaches 0.5,
    ``(1 - level) / 2`` and ``(1 + level) / 2``), so at least ``level`` of the values lie in
    ``[low, high]``.

    Examples
    --------
    >>> spread([3] * 5 + [4] * 90 + [5] * 5)
    {'median': 4, 'low': 3, 'high': 4}
    >>> spread([7])
    {'median': 7, 'low': 7, 'high': 7}
    """
    tail = (1.0 - level) / 2
    at = np.quantile(np.asarray(values), [0.5, tail, 1.0 - tail], method="inverted_cdf")
    median, low, high = (int(v) for v in at)
    return {"median": median, "low": low, "high": high}


def _elect(
    placement: str | Path | np.ndarray | None, seed: int, overrides: dict | None
) -> tuple[Simulation, list[int], dict[int, FrameKey]]:
    """Phases 1–2 run on ``placement``: the simulation, the elected seeds and their frame
    keys (the merged frame's root is the smallest, :mod:`kilonet.protocols.gcs.phase6_merging`)."""
    result = scenarios.run(
        scenarios.get("gcs"),
        {**(overrides or {}), "gcs.until": "seeds"},
        seed=seed,
        placement=placement,
    )
    sim = result.sim
    seeds = [i for i, r in enumerate(sim.robots) if r.is_seed]
    return sim, seeds, {i: sim.robots[i].own_key for i in seeds}


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
