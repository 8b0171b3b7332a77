"""The centralized reference: least-squares positions from measured distances."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kilonet.alignment import procrustes_rmse
from kilonet.bounds import crlb_rmse_mm
from kilonet.central import central_reference, solve_positions
from kilonet.placement import hex_lattice, random_uniform
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


def test_a_robot_farther_than_within_mm_is_not_localized():
    square = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    pairs = np.array([(0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3)])
    d = _measured(square, pairs[:, 0], pairs[:, 1])
    ref = central_reference(square, pairs, d, within_mm=5.0)
    assert ref.localized.all()
    ref = central_reference(square, pairs, d + np.array([0, 0, 0, 0, 30.0, 30.0]), within_mm=5.0)
    assert ref.rmse_mm > 5.0
    assert not ref.localized.all()


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
