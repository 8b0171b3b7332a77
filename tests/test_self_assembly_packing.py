"""The packed start of the self-assembly scenario never places two bodies overlapping, at any
swarm size (the jitter once brought neighbours of a 1,024-robot start 32.98 mm together)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from kilonet.params import Params
from kilonet.scenarios.self_assembly import BODY_MM, JITTER_MM, PACKED_MM, _generate


@pytest.mark.parametrize("robots", [5, 100, 256, 1024, 2000])
def test_the_packed_start_keeps_every_body_apart(robots):
    # 20 draws: 4 of them bring two jittered neighbours under a body apart at 1,024 robots.
    for seed in range(20):
        positions = _generate(Params(), robots, np.random.default_rng(seed))
        assert positions.shape == (robots, 2)
        distance, _ = cKDTree(positions).query(positions, k=2)
        assert distance[:, 1].min() >= BODY_MM, seed


def test_a_robot_on_its_spot_and_a_jittered_neighbour_stay_apart():
    # The pair's members go back to their spots; a neighbour pushed towards one of them by the
    # largest jitter on both axes still leaves a gap.
    assert PACKED_MM - np.sqrt(2) * JITTER_MM > BODY_MM


def test_a_start_without_a_close_pair_is_as_drawn():
    rng = np.random.default_rng(1)
    positions = _generate(Params(), 100, rng)
    again = np.random.default_rng(1)
    spots = positions[4:] - again.uniform(-JITTER_MM, JITTER_MM, (96, 2))
    # Every robot moved by its own draw from a lattice spot 34 mm from its row neighbours.
    assert np.allclose(np.diff(spots[:10, 0]), -PACKED_MM)
