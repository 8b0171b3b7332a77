"""Frames grown round a hole, and the C (issue 33), end to end, as they stand since rule 1
waits for fresh anchors. The two fronts of a ring meet bent apart and the rules misplace
robots where they meet; the C no longer folds in these seeds (docs/localize.md, Limits: *A C
bends at its tips*, *A ring's fronts*).

The small rings and C (90 robots, 3-10 s each) run by default, each the default tier's twin of
a slow test; the rings and Cs of 300 robots take 40-60 s each and are marked slow
(``pytest -m slow``). The cases that fold are strict
xfails: a fix that mends one shows up as an unexpected pass. Every number in a comment was
measured.
"""

from __future__ import annotations

import numpy as np
import pytest

from kilonet import scenarios
from kilonet.scenarios.placement import c_shape

LOCALIZE = scenarios.get("localize")

#: The issue's disc with a large hole: 300 robots between radii 400 and 650 mm.
RING = {
    "placement.kind": "ring",
    "placement.outer_radius_mm": 650,
    "placement.inner_radius_mm": 400,
    "placement.robots": 300,
}
#: The issue's C: radii 450-700 mm less 90 degrees about +x, 300 robots.
C_SHAPE = {
    "placement.kind": "c_shape",
    "placement.outer_radius_mm": 700,
    "placement.inner_radius_mm": 450,
    "placement.opening_deg": 90,
    "placement.robots": 300,
}

#: Where the two fronts of a ring meet 25-30 degrees apart in rotation (hundreds of mm on the
#: 300-robot ring), seam fixes and the refinement fold the frame (docs/localize.md, Limits).
SEAM = pytest.mark.xfail(
    strict=True, reason="the fronts of a ring meet far apart and fold (docs/localize.md, Limits)"
)


# -- end to end --------------------------------------------------------------------------------
def _small(seed: int, opening_deg: float = 0.0) -> dict:
    """A ring (or, with an opening, a C) of 90 robots between radii 150 and 280 mm."""
    positions = c_shape(
        90,
        outer_radius_mm=280.0,
        inner_radius_mm=150.0,
        opening_deg=opening_deg,
        rng=np.random.default_rng(seed),
    )
    return scenarios.run(LOCALIZE, {}, seed=seed, placement=positions).summary


def assert_a_ring_ends_at_the_optimum(s: dict) -> None:
    """One frame that places at least 95 % of the robots, at the optimum."""
    assert s["frames"] == 1
    assert s["at_optimum_over_central"] >= 0.95
    assert s["localized_fraction"] >= 0.95


def assert_a_c_ends_at_the_optimum(s: dict) -> None:
    """One frame at the optimum, no fix misplaced, within twice the solver's error."""
    assert s["frames"] == 1
    assert s["at_optimum_over_central"] >= 0.95
    assert s["misplaced_fixes"] == {}
    assert s["rmse_mm"] <= 2.0 * s["central_rmse_mm"]


@pytest.mark.twin_of("test_a_ring_with_a_large_hole_ends_at_the_optimum")
@pytest.mark.parametrize("seed", [1, 3])
def test_a_small_ring_closes_without_folding(seed):
    # 1.000 and 1.000 at 4.3 and 1.8 mm (the solver 4.3 and 3.7 mm).
    assert_a_ring_ends_at_the_optimum(_small(seed))


@pytest.mark.twin_of("test_a_ring_with_a_large_hole_ends_at_the_optimum")
@SEAM
def test_a_small_ring_whose_fronts_meet_two_anchors_each_still_folds():
    # Robot 49 at 20.8 s took a fix from two anchors of each front (residual RMS 4.2 mm; the
    # fronts 27 degrees apart in rotation), 50 mm off; robot 19 its mirror image by a vote at
    # 23.4 s: 0.067, 47.6 mm (the solver 4.7 mm).
    assert_a_ring_ends_at_the_optimum(_small(2))


@pytest.mark.twin_of("test_a_c_ends_at_the_optimum")
def test_a_small_c_ends_at_the_optimum():
    # Seed 1: 1.000 at 15.5 mm (the solver 8.8 mm), no fix misplaced.
    assert_a_c_ends_at_the_optimum(_small(1, opening_deg=90.0))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [pytest.param(1, marks=SEAM), pytest.param(2, marks=SEAM), 3])
def test_a_ring_with_a_large_hole_ends_at_the_optimum(seed):
    # Seed 3: 1.000 at 20.2 mm (the solver 8.8 mm). Seeds 1 and 2 fold where the fronts meet:
    # 0.475 and 0.072 (19.6 and 71.7 mm, the solver 7.0 and 9.0 mm), at robot 294's fix from
    # three anchors at 110.3 s and robot 63's at 96.8 s. Before rule 1 waited for fresh
    # anchors seed 1 closed (0.960, 40.2 mm) and seed 3 stopped at 73.8 mm.
    assert_a_ring_ends_at_the_optimum(scenarios.run(LOCALIZE, RING, seed=seed).summary)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_c_ends_at_the_optimum(seed):
    # 1.000, 0.997 and 1.000 at 25.2, 20.0 and 35.6 mm (the solver 21.5, 18.4 and 23.6 mm), no
    # fix misplaced. Before rule 1 waited for fresh anchors seed 3 folded (0.857, 109.0 mm)
    # at robot 70's vote on candidates that had moved (docs/localize.md, Limits).
    assert_a_c_ends_at_the_optimum(scenarios.run(LOCALIZE, C_SHAPE, seed=seed).summary)
