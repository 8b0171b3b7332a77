"""The rule that keeps saturated distance estimates out of the protocols' ranging."""

from __future__ import annotations

import numpy as np
import pytest

from kilonet.protocols.common.ranging_limit import TABLES_END_MM, trusted_range
from kilonet.protocols.follower.follower import FollowerParams
from kilonet.protocols.gcs.base import GcsParams
from kilonet.protocols.localize.base import LocalizeParams
from kilonet.robot import Kilobot
from kilonet.simulation import Simulation


def test_an_estimate_up_to_the_limit_is_trusted_and_one_above_is_not():
    assert trusted_range(85, 85.0) and trusted_range(33, 85.0)
    assert not trusted_range(86, 85.0)
    assert trusted_range(100, 100.0) and not trusted_range(101, 100.0)


def test_the_defaults_stay_within_kilolibs_tables_or_the_thesiss_range():
    assert GcsParams().neighbour_max_mm == 85.0  # the thesis's range
    assert LocalizeParams().neighbour_max_mm < TABLES_END_MM  # a margin inside the tables
    # The follower's frame sides are 60-80 mm: it ranges as far as the tables go.
    assert TABLES_END_MM <= FollowerParams().neighbour_max_mm <= TABLES_END_MM + 2


def _noise_free_estimates(n_robots: int = 12) -> np.ndarray:
    """(true distance, noise-free estimate) of every link of a default swarm at 35-200 mm."""
    sim = Simulation(np.c_[np.arange(n_robots) * 40.0, np.zeros(n_robots)], lambda i: Kilobot())
    model = sim.medium.reception
    distances = np.arange(35.0, 200.0, 2.0)
    rows = [
        (d, model.systematic_mm(s, r, d))
        for s in range(n_robots)
        for r in range(n_robots)
        if s != r
        for d in distances
    ]
    return np.array(rows)


@pytest.mark.parametrize(("limit", "worst_mm"), [(85.0, 8.0), (90.0, 9.0), (100.0, 10.0)])
def test_estimates_the_rule_trusts_are_near_the_truth_and_saturated_ones_are_not(limit, worst_mm):
    # On the default medium (per-sender emitter strength against the receiver's tables) a link's
    # systematic error is a few mm inside the tables; beyond them the estimate saturates, so a
    # robot 180 mm away reads about 130 mm. The rule keeps only the first kind.
    rows = _noise_free_estimates()
    true, est = rows[:, 0], rows[:, 1]
    trusted = np.array([trusted_range(e, limit) for e in est])
    assert np.abs(est - true)[trusted].max() <= worst_mm
    assert np.abs(est - true)[~trusted].max() > 40.0
    assert true[trusted].max() <= limit + worst_mm + 2
