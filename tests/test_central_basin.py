"""The cost-based basin test (``compare_with_optimum``) and the solver's extra starts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.protocols.common.alignment import procrustes_rmse
from kilonet.scenarios.central import (
    BASIN_EXCESS,
    central_reference,
    compare_with_optimum,
    solve_positions,
)
from kilonet.scenarios.placement import hex_lattice
from kilonet.visibility import pairs_in_range


def _lattice(seed: int = 6, sigma_mm: float = 1.0):
    rng = np.random.default_rng(seed)
    pos = hex_lattice(61, spacing_mm=40.0, jitter_mm=2.0, rng=rng)
    i, j, d = pairs_in_range(pos, 85.0)
    return pos, np.column_stack([i, j]), d + rng.normal(0.0, sigma_mm, len(d)), rng


def _mirrored(pos: np.ndarray, part: np.ndarray, hinge: np.ndarray) -> np.ndarray:
    """``pos`` with the robots of ``part`` mirrored across the line of the two ``hinge``
    robots."""
    (ax, ay), (bx, by) = pos[hinge]
    u = np.array([bx - ax, by - ay]) / math.hypot(bx - ax, by - ay)
    out = pos.copy()
    rel = out[part] - pos[hinge[0]]
    out[part] = pos[hinge[0]] + 2 * (rel @ u)[:, None] * u - rel
    return out


def _row_and_arc(radius_mm: float):
    """A straight row of 21 robots 40 mm apart, measured exactly between neighbours and
    next-neighbours, and the same row bent along an arc of ``radius_mm``."""
    k = np.arange(21)
    row = np.column_stack([40.0 * k, np.zeros(21)])
    angle = 40.0 * k / radius_mm
    arc = radius_mm * np.column_stack([np.sin(angle), 1 - np.cos(angle)])
    pairs = np.array([(i, i + 1) for i in range(20)] + [(i, i + 2) for i in range(19)])
    return row, arc, pairs, np.hypot(*(row[pairs[:, 0]] - row[pairs[:, 1]]).T)


def test_a_slightly_perturbed_optimum_is_in_its_basin_in_any_frame():
    pos, pairs, d, rng = _lattice()
    optimum = solve_positions(len(pos), pairs, d)
    turned = (optimum + rng.normal(0.0, 3.0, optimum.shape)) @ np.array([[0, -1.0], [1, 0]])
    result = compare_with_optimum(turned + 500.0, optimum, pairs, d)
    assert result.in_basin
    assert abs(result.basin_excess) < 1e-3
    # Short of the floor: its own cost is far above the optimum's, the polished one is not.
    assert result.run_excess > 100.0
    # Noise of 1 mm per measurement, weight 1: about 1 mm² per unit weight.
    assert 0.7 < result.noise_mm2 < 1.3


def test_a_folded_toy_frame_is_not_in_the_basin():
    # The part of the lattice beyond x = 60 mm mirrored across the line of the two robots
    # nearest it: every link that crosses into the part is now tens of mm off.
    pos, pairs, d, _ = _lattice()
    optimum = solve_positions(len(pos), pairs, d)
    part = pos[:, 0] > 60.0
    hinge = np.flatnonzero(~part)[np.argsort(-pos[~part, 0])[:2]]
    result = compare_with_optimum(_mirrored(pos, part, hinge), optimum, pairs, d)
    assert not result.in_basin
    assert result.basin_excess > 100 * BASIN_EXCESS


def test_a_mirror_the_measurements_cannot_tell_is_in_the_basin():
    # The same part tied to the rest through its two hinge robots only: its mirror image fits
    # every measurement as well, and the cost cannot tell it from the optimum (the position
    # test can: the two lie tens of mm apart).
    pos, _, _, rng = _lattice()
    part = pos[:, 0] > 60.0
    hinge = np.flatnonzero(~part)[np.argsort(-pos[~part, 0])[:2]]
    i, j, d = pairs_in_range(pos, 85.0)
    crossing = part[i] != part[j]
    keep = ~crossing | np.isin(np.where(part[i], j, i), hinge)
    pairs, d = np.column_stack([i, j])[keep], d[keep] + rng.normal(0.0, 1.0, keep.sum())
    optimum = solve_positions(len(pos), pairs, d)
    folded = _mirrored(optimum, part, hinge)
    result = compare_with_optimum(folded, optimum, pairs, d)
    assert result.in_basin
    assert np.mean(result.agreement_mm[part] > 5.0) > 0.8


@pytest.mark.parametrize("radius_mm", [2000.0, 600.0])
def test_a_flat_valley_is_in_the_basin_by_cost_though_far_by_position(radius_mm):
    # A row bent along an arc stretches its next-neighbour links by a few micrometres
    # (2 m radius) to a few tenths (0.6 m): least squares from there barely moves, so the
    # position test puts it tens of mm from the straight optimum; by cost it is the optimum.
    row, arc, pairs, d = _row_and_arc(radius_mm)
    result = compare_with_optimum(arc, row, pairs, d)
    assert np.nanmax(result.agreement_mm) > 25.0
    assert result.in_basin
    assert result.basin_excess < 0.1 * BASIN_EXCESS


def test_the_basin_test_needs_estimates_and_measurements_among_them():
    row, arc, pairs, d = _row_and_arc(2000.0)
    arc[:] = np.nan
    arc[:2] = row[:2]
    result = compare_with_optimum(arc, row, pairs, d)
    assert not result.in_basin
    assert math.isnan(result.basin_excess) and math.isnan(result.run_excess)
    assert np.isnan(result.agreement_mm).all()


def test_a_start_replaces_the_solvers_fit_only_at_a_lower_cost():
    # On the lattice the solver's own fit is the optimum: a start at it (a tie) and a start
    # with too few robots leave the answer where it was.
    pos, pairs, d, _ = _lattice()
    plain = solve_positions(len(pos), pairs, d)
    few = np.full_like(pos, np.nan)
    few[:2] = pos[:2]
    for start in (plain + 100.0, few):
        again = solve_positions(len(pos), pairs, d, starts=[start])
        assert procrustes_rmse(again, plain)[0] < 1e-3
    # A noisy row is a flat valley: least squares from the solver's own starts stops short
    # of its floor, and from its own answer it goes on to a lower cost, which is kept; the
    # row bent along an arc costs more, and is not.
    row, arc, pairs, d = _row_and_arc(600.0)
    d = d + np.random.default_rng(1).normal(0.0, 0.5, len(d))
    plain = solve_positions(len(row), pairs, d)
    assert _cost(solve_positions(len(row), pairs, d, starts=[plain + 100.0]), pairs, d) < (
        _cost(plain, pairs, d) * (1 - 1e-6)
    )
    assert procrustes_rmse(solve_positions(len(row), pairs, d, starts=[arc]), plain)[0] < 1e-3


def test_a_start_fills_the_robots_it_lacks_and_reaches_the_reference():
    pos, pairs, d, rng = _lattice(sigma_mm=0.5)
    start = pos + rng.normal(0.0, 1.0, pos.shape)
    start[:10] = np.nan
    ref = central_reference(pos, pairs, d, starts=[start])
    assert ref.localized_fraction == 1.0
    assert ref.rmse_mm < 2.0


def test_a_start_of_the_wrong_shape_is_refused():
    row, _, pairs, d = _row_and_arc(600.0)
    with pytest.raises(ValueError, match=r"a start must be \(21, 2\)"):
        solve_positions(len(row), pairs, d, starts=[row[:5]])


def _cost(pos: np.ndarray, pairs: np.ndarray, d: np.ndarray) -> float:
    return float(((np.hypot(*(pos[pairs[:, 0]] - pos[pairs[:, 1]]).T) - d) ** 2).sum())


def test_a_localize_summary_reports_the_basin_test_by_cost():
    # 40 robots on the default lattice: one frame at the optimum, in its basin by cost too,
    # its own cost above the optimum's (the refinement stops short of the floor).
    from kilonet import scenarios

    s = scenarios.run(scenarios.get("localize"), {"placement.robots": 40}, seed=1).summary
    assert s["at_optimum_over_central"] == 1.0
    assert s["in_optimum_basin"] is True
    assert abs(s["basin_excess_over_central"]) <= BASIN_EXCESS
    assert s["run_cost_excess_over_central"] > BASIN_EXCESS
