"""``gradient``: the hop-count gradient from one source robot across a swarm.

Metrics against ground truth: the share of robots whose gradient lies between their hop
distances from the source over every link the medium can deliver over and over its reliable
links (:func:`hop_distances`, :func:`gradient_consistent`), when the last robot settled, and
the largest gradient.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.params import ParamError, param
from kilonet.protocols.gradient import UNKNOWN, Gradient
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, Setup

if TYPE_CHECKING:  # the rest is imported where used, so that listing scenarios stays fast
    from kilonet.simulation import Simulation

__all__ = ["SCENARIO", "GradientParams", "gradient_consistent", "hop_distances"]


@dataclass(frozen=True)
class GradientParams:
    """Parameters of the gradient scenario."""

    section_name = "gradient"
    source: int = param(0, lo=0, doc="index of the source robot (0: the lattice centre)")
    refresh_s: float = param(0.0, lo=0.0, hi=3600.0, doc="self-healing window; 0 = monotone")


def hop_distances(sim: Simulation, source: int, min_probability: float = 0.5) -> dict[int, int]:
    """Hops from ``source`` over the medium's own links among the running robots, each link
    from its sender to the robots that hear it (:meth:`~kilonet.medium.InfraredMedium.
    receivers_of`), where it delivers at least ``min_probability`` of its messages apart from
    collisions and random loss (:meth:`~kilonet.medium.InfraredMedium.link_delivery`: the soft
    edge of the sender's battery-shrunk reach, occlusion, the receiver's battery and faults; by
    default half, the links a robot hears reliably): a robot adopts one more than the smallest
    gradient it hears, so a one-way link counts in its own direction (real robots' links reach
    per sender, :mod:`kilonet.radio`)."""
    import networkx as nx

    running = sim.world.running
    graph = nx.DiGraph()
    graph.add_nodes_from(np.flatnonzero(running).tolist())
    for sender in list(graph):
        heard, share = sim.medium.link_delivery(sender)
        keep = (share >= min_probability) & running[heard]
        graph.add_edges_from((sender, int(r)) for r in heard[keep])
    if source not in graph:
        return {}
    return nx.single_source_shortest_path_length(graph, source)


def gradient_consistent(value: int, hops_every_link: int, hops_reliable: int) -> bool:
    """Whether a robot's gradient is one the medium allows: at least its hop count over every
    link that can deliver (a message over a link in the soft edge of its reach arrives now and
    then, and the robot keeps the smallest value it hears) and at most its hop count over the
    links that deliver at least half their messages (a robot above that has not heard a
    neighbour it hears reliably: lost to collisions, as behind hidden terminals, or not yet
    settled). Unreachable is :data:`kilonet.protocols.gradient.UNKNOWN` on either side.

    Examples
    --------
    >>> gradient_consistent(3, 3, 4), gradient_consistent(4, 3, 4), gradient_consistent(5, 3, 4)
    (True, True, False)
    """
    return hops_every_link <= value <= hops_reliable


def _program(params: Any, positions: np.ndarray):
    g = params.scenario
    if g.source >= len(positions):
        raise ParamError(f"gradient.source = {g.source} but there are only {len(positions)} robots")
    return lambda i: Gradient(is_source=i == g.source, refresh_s=g.refresh_s)


def _metrics(sim: Simulation) -> dict[str, Any]:
    from kilonet.radio import MIN_RECEPTION

    source = sim.params.scenario.source
    hops = hop_distances(sim, source)
    every = hop_distances(sim, source, MIN_RECEPTION)
    values = [r.gradient for r in sim.robots]
    running = sim.world.running
    correct = [
        gradient_consistent(values[i], every.get(i, UNKNOWN), hops.get(i, UNKNOWN))
        for i in range(sim.n_robots)
        if running[i]
    ]
    events = sim.trace.events_frame()
    settled = float(events["t_s"].max()) if len(events) else 0.0
    known = [v for v in values if v != UNKNOWN]
    return {
        "gradient_correct_fraction": float(np.mean(correct)) if correct else 0.0,
        "gradient_max": max(known) if known else None,
        "reachable_robots": len(hops),
        "last_change_s": settled,
    }


def _figure(result: RunResult, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = result.sim
    pos = sim.world.positions_mm
    values = np.array([r.gradient for r in sim.robots], dtype=float)
    values[values == UNKNOWN] = np.nan
    fig, ax = plt.subplots(figsize=(6, 6))
    sc = ax.scatter(pos[:, 0], pos[:, 1], c=values, cmap="viridis", s=60, edgecolors="k")
    src = sim.params.scenario.source
    ax.scatter(*pos[src], marker="*", s=250, c="red", label="source")
    fig.colorbar(sc, ax=ax, label="gradient (hops)")
    ax.set_aspect("equal")
    # Limits a body diameter beyond the outermost robots: a swarm whose extent is (nearly)
    # zero in x or y (a line at y = 0 and 1e-30) would otherwise make a singular transform.
    lo, hi = pos.min(axis=0) - 33.0, pos.max(axis=0) + 33.0
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    s = result.summary
    ax.set_title(
        f"gradient: {s['gradient_correct_fraction']:.0%} within the hop counts "
        f"(t = {s['sim_time_s']:.0f} s)"
    )
    ax.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(out_dir / "gradient.png", dpi=100)
    plt.close(fig)


SCENARIO = Scenario(
    name="gradient",
    summary="hop-count gradient from one source robot (Kilobot self-assembly building block)",
    setup=Setup(
        program=_program,
        section=GradientParams,
        robots=100,
        defaults={"duration_s": 30.0},
        supports={"medium.message_format": ("kilolib",)},
    ),
    reporting=Reporting(
        metrics=_metrics,
    ),
    drawing=Drawing(
        figures=_figure,
    ),
)
