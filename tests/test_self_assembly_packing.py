"""The packed start of the self-assembly scenario never places two bodies overlapping, at any
swarm size (the jitter once brought neighbours of a 1,024-robot start 32.98 mm together)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from kilonet.params import Params
from kilonet.scenarios.self_assembly import JITTER_MM, PACKED_MM, _generate


@pytest.mark.parametrize("robots", [5, 100, 256, 1024, 2000])
def test_the_packed_start_keeps_every_body_apart(robots):
    # 20 draws: with a jitter of 0.4 mm per axis 4 of them overlap at 1,024 robots.
    for seed in range(20):
        positions = _generate(Params(), robots, np.random.default_rng(seed))
        assert positions.shape == (robots, 2)
        distance, _ = cKDTree(positions).query(positions, k=2)
        assert distance[:, 1].min() > 33.0, seed


def test_the_worst_case_jitter_still_leaves_a_gap():
    # Two lattice neighbours pushed towards each other by the largest jitter on both axes.
    assert PACKED_MM - 2 * np.sqrt(2) * JITTER_MM > 33.0
