"""Tests for the gradient scenario on the robot model: its metric against the medium's own
graph, and what clocks that drift apart do to repeated hidden-terminal collisions."""

from __future__ import annotations

import networkx as nx
import pytest

import scenarios

GRADIENT = scenarios.get("gradient")


def _run(robots: int, seed: int, **overrides):
    settings = {"placement.robots": robots, "duration_s": 30.0, **overrides}
    return scenarios.run(GRADIENT, settings, seed=seed)


def test_the_gradient_equals_hop_counts_over_the_mediums_own_graph():
    result = _run(100, seed=3)
    sim = result.sim
    hops = nx.single_source_shortest_path_length(sim.medium.graph(), 0)
    assert [r.gradient for r in sim.robots] == [hops[i] for i in range(sim.n_robots)]
    assert result.summary["gradient_correct_fraction"] == 1.0


@pytest.mark.parametrize("seed", [1, 2])
def test_drifting_clocks_end_the_hidden_terminal_collisions_that_identical_clocks_repeat(seed):
    # kilolib offers a message every 0.5 s of a robot's own clock, without jitter: on identical
    # clocks two hidden terminals that collided once collide at every period, forever, and the
    # robots behind them never hear the lower gradient. Each robot's own rate ends that.
    perfect = _run(200, seed, **{"robot.clock_sd": 0.0}).summary
    drifting = _run(200, seed).summary
    assert perfect["gradient_correct_fraction"] < 0.9
    assert drifting["gradient_correct_fraction"] == 1.0
    assert drifting["lost_collision"] < 0.5 * perfect["lost_collision"]
