"""The centralized reference: least-squares positions from measured distances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.protocols.common.alignment import procrustes_rmse
from kilonet.scenarios.bounds import crlb_rmse_mm
from kilonet.scenarios.central import central_reference, optimum_agreement_mm, solve_positions
from kilonet.scenarios.placement import c_shape, corridor, hex_lattice, random_uniform
from kilonet.visibility import pairs_in_range


def _measured(pos, i, j):
    return np.hypot(*(pos[i] - pos[j]).T)


def test_noise_free_lattice_is_recovered_exactly():
    pos = hex_lattice(37, spacing_mm=40.0, jitter_mm=2.0, rng=np.random.default_rng(3))
    i, j, d = pairs_in_range(pos, 85.0)
    solved = solve_positions(len(pos), np.column_stack([i, j]), d)
    assert procrustes_rmse(solved, pos)[0] < 1e-6
    ref = central_reference(pos, np.column_stack([i, j]), d)
    assert ref.rmse_mm < 1e-6
    assert ref.localized_fraction == 1.0
    assert np.abs(ref.aligned_mm - pos).max() < 1e-6


def test_noise_free_sparse_random_placement_is_recovered_exactly():
    # Mean degree about 6 with line of sight: MDS alone folds parts of it; least squares
    # must still find the exact shape.
    pos = random_uniform(150, density_per_m2=400, area="disc", rng=np.random.default_rng(4))
    i, j, d = pairs_in_range(pos, 85.0)
    ref = central_reference(pos, np.column_stack([i, j]), d)
    assert ref.localized_fraction >= 0.98
    assert np.median(np.hypot(*(ref.aligned_mm - pos).T)) < 1e-6


def test_each_component_is_aligned_on_its_own_and_small_ones_are_left_out():
    square = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    pos = np.vstack([square, square + np.array([500.0, 0.0]), [[900.0, 0.0], [940.0, 0.0]]])
    sides = [(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)]
    pairs = np.array(sides + [(a + 4, b + 4) for a, b in sides] + [(8, 9)])
    ref = central_reference(pos, pairs, _measured(pos, pairs[:, 0], pairs[:, 1]))
    assert ref.localized.tolist() == [True] * 8 + [False, False]
    assert ref.localized_fraction == 0.8
    assert ref.rmse_mm == pytest.approx(0.0, abs=1e-9)
    assert np.isnan(ref.aligned_mm[8:]).all()
    assert np.isnan(solve_positions(10, pairs, _measured(pos, pairs[:, 0], pairs[:, 1]))[8:]).all()


def test_repeated_measurements_count_by_their_weights():
    # One side measured twice, 40 mm with weight 3 and 44 mm with weight 1: a triangle fits
    # every measurement pair exactly, so that side comes out at the weighted mean, 41 mm.
    pairs = np.array([(0, 1), (0, 1), (1, 2), (0, 2)])
    d = np.array([40.0, 44.0, 30.0, 35.0])
    p = solve_positions(3, pairs, d, np.array([3.0, 1.0, 1.0, 1.0]))
    assert math.dist(p[0], p[1]) == pytest.approx(41.0, abs=1e-6)
    assert math.dist(p[1], p[2]) == pytest.approx(30.0, abs=1e-6)
    assert math.dist(p[0], p[2]) == pytest.approx(35.0, abs=1e-6)


def test_noisy_lattice_error_is_near_the_cramer_rao_bound():
    rng = np.random.default_rng(11)
    pos = hex_lattice(91, spacing_mm=40.0, jitter_mm=2.0, rng=rng)
    i, j, d = pairs_in_range(pos, 85.0)
    pairs = np.concatenate([np.column_stack([i, j]), np.column_stack([j, i])])
    measured = np.concatenate([d, d]) + rng.normal(0.0, 1.0, 2 * len(d))
    ref = central_reference(pos, pairs, measured)
    bound = crlb_rmse_mm(pos, pairs, 1.0)
    assert 0.7 * bound < ref.rmse_mm < 1.3 * bound
    assert ref.localized_fraction == 1.0


def test_a_robot_farther_than_within_mm_of_its_neighbours_is_not_localized():
    square = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)])
    d = _measured(square, pairs[:, 0], pairs[:, 1])
    ref = central_reference(square, pairs, d, within_mm=5.0)
    assert ref.localized.all()
    assert np.nanmax(ref.local_error_mm) < 1e-6
    # Both diagonals measured 30 mm long: no shape fits, and no robot sits where its
    # neighbours' truth puts it.
    ref = central_reference(square, pairs, d + np.array([0, 0, 0, 0, 30.0, 30.0]), within_mm=5.0)
    assert (ref.local_error_mm > 5.0).all()
    assert not ref.localized.any()


def test_a_shape_its_measurements_bend_is_localized_where_the_optimum_puts_it():
    # A 2 m row of robots two wide, measured as if it lay on an arc of 2 m radius (a bias
    # that grows along a long shape): the optimum is the arc, tens of millimetres from the
    # truth at the ends after the best alignment, but every robot is right among its
    # neighbours, and counts as localized; within 5 mm of the truth, a third would.
    k = np.arange(50)
    row = np.concatenate(
        [
            np.column_stack([40.0 * k, np.zeros(50)]),
            np.column_stack([40.0 * k + 20.0, np.full(50, 35.0)]),
        ]
    )
    angle = row[:, 0] / 2000.0
    radius = 2000.0 - row[:, 1]
    arc = np.column_stack([radius * np.sin(angle), 2000.0 - radius * np.cos(angle)])
    i, j, _ = pairs_in_range(row, 85.0)
    pairs = np.column_stack([i, j])
    ref = central_reference(row, pairs, _measured(arc, i, j))
    assert ref.rmse_mm > 20.0
    assert np.mean(np.hypot(*(ref.aligned_mm - row).T) <= 5.0) < 0.5
    assert ref.localized_fraction == 1.0
    assert np.nanmax(ref.local_error_mm) < 2.0


def test_a_frame_in_the_optimums_basin_agrees_with_it_and_a_folded_part_does_not():
    rng = np.random.default_rng(6)
    pos = hex_lattice(61, spacing_mm=40.0, jitter_mm=2.0, rng=rng)
    pairs, d = _noisy_measurements(pos, rng, sigma_mm=1.0)
    optimum = solve_positions(len(pos), pairs, d)
    # A frame short of the optimum by a few millimetres, turned and shifted: in its basin.
    near = (optimum + rng.normal(0.0, 3.0, optimum.shape)) @ np.array([[0.0, -1.0], [1.0, 0.0]])
    assert np.nanmax(optimum_agreement_mm(near + 500.0, optimum, pairs, d)) < 0.01
    # A flap beyond x = 60 mm tied to the rest through two robots only: mirrored across
    # their line, it fits every measurement as well, and stays there.
    flap = pos[:, 0] > 60.0
    hinge = np.flatnonzero(~flap)[np.argsort(-pos[~flap, 0])[:2]]
    i, j, true_d = pairs_in_range(pos, 85.0)
    crossing = flap[i] != flap[j]
    keep = ~crossing | np.isin(np.where(flap[i], j, i), hinge)
    pairs, d = np.column_stack([i, j])[keep], true_d[keep]
    (ax, ay), (bx, by) = pos[hinge]
    u = np.array([bx - ax, by - ay]) / math.dist(pos[hinge[0]], pos[hinge[1]])
    folded = pos.copy()
    rel = folded[flap] - pos[hinge[0]]
    folded[flap] = pos[hinge[0]] + 2 * (rel @ u)[:, None] * u - rel
    agreement = optimum_agreement_mm(folded, pos, pairs, d)
    assert np.nanmax(agreement[~flap]) < 0.5  # flap robots near the line agree too
    assert np.mean(agreement[flap] > 5.0) > 0.8
    # Robots without an estimate have no agreement.
    folded[0] = np.nan
    assert np.isnan(optimum_agreement_mm(folded, pos, pairs, d)[0])


@pytest.mark.parametrize(
    ("pairs", "d", "w", "match"),
    [
        ([(0, 1)], [1.0, 2.0], None, "one entry per measurement"),
        ([(0, 3)], [1.0], None, "out of range"),
        ([(1, 1)], [1.0], None, "self-loop"),
        ([(0, 1)], [0.0], None, "positive"),
        ([(0, 1)], [np.nan], None, "positive"),
        ([(0, 1)], [1.0], [-1.0], "non-negative"),
    ],
)
def test_bad_measurements_are_refused(pairs, d, w, match):
    with pytest.raises(ValueError, match=match):
        solve_positions(3, np.array(pairs), np.array(d), None if w is None else np.array(w))


def test_truth_must_be_n_by_2():
    with pytest.raises(ValueError, match=r"\(n, 2\)"):
        central_reference(np.zeros((3, 3)), np.array([(0, 1)]), np.array([1.0]))


def _stress(pos, pairs, d):
    return float((((np.hypot(*(pos[pairs[:, 0]] - pos[pairs[:, 1]]).T)) - d) ** 2).sum())


def _noisy_measurements(pos, rng, sigma_mm=0.2):
    i, j, d = pairs_in_range(pos, 85.0)
    return np.column_stack([i, j]), d + rng.normal(0.0, sigma_mm, len(d))


@pytest.mark.parametrize("seed", [1, 2])
def test_a_c_shape_is_solved_at_its_optimum_not_bent(seed):
    # Shortest paths run round the inside of the C, longer than the straight distances
    # across it: MDS of them bends the C, and least squares from there stopped in a local
    # minimum (62 % and 28 % of the robots within 5 mm, RMSE 36 and 43 mm).
    rng = np.random.default_rng(seed)
    pos = c_shape(150, outer_radius_mm=450.0, inner_radius_mm=280.0, rng=rng)
    pairs, d = _noisy_measurements(pos, rng)
    ref = central_reference(pos, pairs, d)
    assert ref.localized_fraction >= 0.98
    # The optimum fits the measurements at least as well as the truth does, and it is the
    # minimum that least squares from the truth ends in: no other lies nearer the truth.
    assert _stress(ref.aligned_mm, pairs, d) <= _stress(pos, pairs, d)
    # (Least squares stops within a millimetre of a minimum along a long shape's slow modes.)
    assert np.nanmax(optimum_agreement_mm(pos, ref.aligned_mm, pairs, d)) < 1.0
    assert ref.rmse_mm < 5.0


def test_a_long_corridor_is_solved_at_its_optimum():
    # 600 robots in a 5 m x 0.2 m corridor: MDS of the zig-zagging shortest paths folded it
    # (11 % within 5 mm, RMSE 25 mm, with sigma 0.18 mm).
    rng = np.random.default_rng(2)
    pos = corridor(600, length_mm=5000.0, width_mm=200.0, rng=rng)
    pairs, d = _noisy_measurements(pos, rng, sigma_mm=1.0 / math.sqrt(30.0))
    ref = central_reference(pos, pairs, d)
    assert ref.localized_fraction >= 0.98
    assert _stress(ref.aligned_mm, pairs, d) <= _stress(pos, pairs, d)
    assert np.nanmax(optimum_agreement_mm(pos, ref.aligned_mm, pairs, d)) < 1.0
    assert ref.rmse_mm < 5.0
