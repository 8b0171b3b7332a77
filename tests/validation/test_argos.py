"""kilonet's medium against the real Kilobots of the ARGoS communication experiment.

The data beside this file (``data/argos``, its README says what and whence) holds 50 runs of 25
real Kilobots on a 5 cm grid. Each test re-runs the experiment's firmware in kilonet
(:mod:`kilonet.experiments.studies.validation`) and asserts one statistic within the tolerance
stated beside it.
"""

from __future__ import annotations

import numpy as np
import pytest

from kilonet.experiments.studies import validation as v

#: Largest accepted |kilonet - real| of the mean reception rate per distance bin (mm). The
#: bins beyond 141 mm hold links at the edge of their reach, where a few runs of 25 robots
#: swing the mean; 150 and 158 mm are pooled (the data's 150 mm links, through two bodies in
#: line, are dead and its 158 mm links alive in 16 %; kilonet's reach depends on distance only).
BIN_TOLERANCE = {50.0: 0.03, 70.7: 0.03, 100.0: 0.03, 111.8: 0.03, 141.4: 0.08, 180.3: 0.05}
POOLED_TOLERANCE = 0.08


@pytest.fixture(scope="module")
def majority():
    """Real and kilonet rates of the majority series (kilonet: 8 runs, both periods)."""
    counts = v.simulate_series("majority", 8)
    return v.rates_of(v.load_counts("majority")), v.rates_of(counts), counts


@pytest.fixture(scope="module")
def long_reach():
    """Real and kilonet rates of the long-reach series, ``medium.reach = argos-long``."""
    counts = v.simulate_series("long", 4)
    return v.rates_of(v.load_counts("long")), v.rates_of(counts), counts


def _pooled(rb: dict[float, float]) -> float:
    return (rb[150.0] * 800 + rb[158.1] * 1280) / 2080  # weighted by the data's link counts


def test_the_data_is_what_its_readme_says():
    counts = v.load_counts("majority")
    assert counts.shape == (40, 25, 25)
    assert v.load_counts("long").shape == (10, 25, 25)
    assert 280 <= v.sends_per_run(counts) <= 300


@pytest.mark.parametrize("bin_mm", sorted(BIN_TOLERANCE))
def test_reception_per_distance_matches_the_majority_series(majority, bin_mm):
    real, sim, _ = majority
    r, s = v.reception_by_distance(real)[bin_mm], v.reception_by_distance(sim)[bin_mm]
    assert abs(s - r) <= BIN_TOLERANCE[bin_mm], (bin_mm, r, s)


def test_reception_falls_off_at_the_edge_as_on_the_robots(majority):
    real, sim, _ = majority
    rr, rs = v.reception_by_distance(real), v.reception_by_distance(sim)
    assert abs(_pooled(rs) - _pooled(rr)) <= POOLED_TOLERANCE
    # Falling, not a step: 141 mm still mostly heard, 150-158 mostly not, nothing at 200.
    assert rs[111.8] > rs[141.4] > _pooled(rs) > rs[200.0] == 0.0


@pytest.mark.parametrize("bin_mm", [50.0, 111.8, 141.4, 180.3, 200.0])
def test_the_long_reach_preset_matches_the_long_series(long_reach, bin_mm):
    real, sim, _ = long_reach
    r, s = v.reception_by_distance(real)[bin_mm], v.reception_by_distance(sim)[bin_mm]
    assert abs(s - r) <= (0.12 if bin_mm == 200.0 else 0.04), (bin_mm, r, s)


def test_each_sender_has_its_own_reach(majority):
    real, sim, _ = majority
    rq = np.percentile(v.sender_reach_mm(real), [5, 50, 95])
    sq = np.percentile(v.sender_reach_mm(sim), [5, 50, 95])
    assert np.abs(sq - rq).max() <= 15.0, (rq, sq)  # within a grid step of the real spread
    assert sq[2] - sq[0] >= 30.0  # senders differ: not one radius for all


def test_some_links_are_one_way(majority):
    real, sim, _ = majority
    assert abs(v.asymmetric_share(sim) - v.asymmetric_share(real)) <= 0.04


def test_more_audible_transmitters_mean_more_collisions(majority):
    real, sim, _ = majority
    slope = v.audible_slope(sim)
    assert slope < 0
    assert abs(slope - v.audible_slope(real)) <= 0.5


@pytest.mark.parametrize(("prefix", "real_sends"), [("tau000", 298.3), ("tau0.5", 281.7)])
def test_sends_per_4800_ticks(prefix, real_sends):
    # kilolib offers every 16 ticks; the 0.5 s firmware waits 17 between its messages.
    real = v.sends_per_run(v.load_counts(prefix))
    assert real == pytest.approx(real_sends, abs=0.1)
    counts = v.simulate([1, 2], {"medium.reach": "argos"}, period_ticks=v.PERIOD_TICKS[prefix])
    assert abs(v.sends_per_run(counts) - real) <= 4.0
