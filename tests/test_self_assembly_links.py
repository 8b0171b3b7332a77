"""The medium follows moving robots by rebuilding only the links of those that moved
(``InfraredMedium.rebuild_topology``): the links must be those a full build gives."""

from __future__ import annotations

import numpy as np
import pytest

from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


def _links(medium) -> list[list[list]]:
    return [
        [a.tolist() for a in arrays]
        for arrays in (medium._link_r, medium._link_d, medium._link_reach, medium._link_loss)
    ] + [medium._rx_r]


@pytest.mark.parametrize("reach", ["disc", "argos"])
def test_links_rebuilt_for_the_robots_that_moved_equal_a_full_build(reach):
    rng = np.random.default_rng(3)
    grid = np.stack(np.meshgrid(np.arange(8), np.arange(8)), axis=-1).reshape(-1, 2)
    positions = grid[:60] * 45.0 + rng.uniform(-5, 5, (60, 2))
    sim = Simulation(
        positions, lambda i: Kilobot(), Params().with_overrides({"medium.reach": reach})
    )
    medium, world = sim.medium, sim.world
    assert medium.radio.reach.per_robot == (reach != "disc")
    world.running[7] = False  # a stopped robot still sends, and is no receiver
    medium.forget_receiver(7)
    changed = 0
    for _ in range(30):
        moved = rng.choice(60, size=rng.integers(1, 8), replace=False)
        world.positions_mm[moved] += rng.normal(0, 15, (len(moved), 2))
        before = _links(medium)
        medium.rebuild_topology()  # only positions changed: the robots that moved
        incremental = _links(medium)
        changed += incremental != before
        medium._rebuild_all()
        assert _links(medium) == incremental
    assert changed == 30
