"""Tests for kilonet.protocols.common.geometry: frames, reference choice, multilateration,
Cramér–Rao bound."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.linalg import lstsq, svdvals
from scipy.optimize import least_squares

from kilonet.protocols.common.alignment import procrustes_rmse
from kilonet.protocols.common.geometry import (
    FIX_REASONS,
    GeometryError,
    angle_at,
    choose_references_best_conditioned,
    choose_references_max_angle,
    circle_intersections,
    circle_pair,
    collinear,
    linear_position,
    multilaterate,
    place_references,
    rotate,
    trilaterate_linear,
    wrap_angle,
)
from kilonet.scenarios.bounds import crlb_rmse_mm
from kilonet.scenarios.placement import hex_lattice
from kilonet.visibility import pairs_in_range

coord = st.floats(-200.0, 200.0, allow_nan=False)
point = st.tuples(coord, coord)


def _dist(p, q) -> float:
    return math.hypot(p[0] - q[0], p[1] - q[1])


def _min_altitude(a, b, c) -> float:
    area2 = abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))
    return area2 / max(_dist(a, b), _dist(a, c), _dist(b, c), 1e-300)


# -------------------------------------------------------------------------------- collinear


def test_collinear_measures_the_width_across_the_best_fit_line():
    # The best-fit line of this symmetric bend is y = 1/3: the middle point is 2/3 mm off it.
    bent = np.array([[0.0, 0.0], [40.0, 1.0], [80.0, 0.0]])
    assert collinear(bent, min_width_mm=0.67)
    assert not collinear(bent, min_width_mm=0.66)
    assert collinear(np.array([[0.0, 0.0], [10.0, 5.0], [30.0, 15.0]]), min_width_mm=0.0) is False
    assert collinear(np.array([[0.0, 0.0], [10.0, 5.0], [30.0, 15.0]]), min_width_mm=1e-9)
    # Fewer than three points always lie on a line; so do coincident ones.
    assert collinear(np.array([[0.0, 0.0], [50.0, 50.0]]), min_width_mm=0.0) is True
    assert collinear(np.zeros((4, 2)), min_width_mm=1e-9)
    # 3-D points: the distance from the line counts in both directions across it.
    tilted = np.array([[0.0, 0.0, 0.0], [40.0, 0.3, 1.0], [80.0, 0.0, 0.0]])
    width = math.hypot(0.2, 2.0 / 3.0)  # off the line through (x, 0.1, 1/3)
    assert collinear(tilted, min_width_mm=width + 1e-9)
    assert not collinear(tilted, min_width_mm=width - 1e-9)
    # No unique best-fit line (a plane of directions, or all, equally spread): any is one, and
    # the width from it lies between the smallest and the largest possible, 0.87 R and R.
    turn = np.array([0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0])
    equilateral = np.column_stack([40.0 * np.cos(turn), 40.0 * np.sin(turn), np.full(3, 7.0)])
    assert not collinear(equilateral, min_width_mm=0.86 * 40.0)
    assert collinear(equilateral, min_width_mm=40.0 + 1e-9)
    octahedron = np.vstack([np.eye(3), -np.eye(3)]) * 25.0
    assert not collinear(octahedron, min_width_mm=24.9)
    assert collinear(octahedron, min_width_mm=25.0 + 1e-9)


def test_collinear_refuses_malformed_input():
    with pytest.raises(ValueError, match=r"\(k, 2\) or \(k, 3\)"):
        collinear(np.zeros((3, 4)), min_width_mm=1.0)
    with pytest.raises(ValueError, match="finite"):
        collinear(np.array([[0.0, 0.0], [1.0, np.nan], [2.0, 1.0]]), min_width_mm=1.0)
    with pytest.raises(ValueError, match="non-negative"):
        collinear(_TRIANGLE, min_width_mm=-1.0)


def _svd_width(points: np.ndarray) -> float:
    """The oracle: the largest distance from the principal axis numpy's SVD finds, mm."""
    centred = points - points.mean(axis=0)
    _, _, axes = np.linalg.svd(centred)
    across = centred @ axes[1:].T
    return float(np.sqrt((across * across).sum(axis=1)).max())


@settings(max_examples=150, deadline=None)
@given(
    st.integers(3, 8),
    st.sampled_from([2, 3]),
    st.floats(-6.0, 2.0),
    st.booleans(),
    st.integers(0, 2**32 - 1),
)
def test_collinear_measures_the_width_numpys_svd_finds(k, dims, log_noise, along_line, seed):
    """Random points, or points scattered across a line by 1e-6 to 100 mm, in 2-D and 3-D:
    the closed-form width agrees with the SVD's to 1e-9 of the points' scale."""
    rng = np.random.default_rng(seed)
    if along_line:
        direction = rng.normal(size=dims)
        direction /= np.linalg.norm(direction)
        points = np.outer(rng.uniform(-300.0, 300.0, k), direction)
        points += rng.normal(0.0, 10.0**log_noise, (k, dims)) + rng.uniform(-300.0, 300.0, dims)
    else:
        points = rng.uniform(-300.0, 300.0, (k, dims))
    width = _svd_width(points)
    tol = 1e-9 * (1.0 + np.abs(points).max())
    assert collinear(points, min_width_mm=width + tol)
    assert not collinear(points, min_width_mm=max(width - tol, 0.0)) or width <= tol


# ------------------------------------------------------------------- the seeds' closed forms


def _maze_seed_formula(anchors, ranges):
    """The maze lab's A…F form (DESIGN.md §3), as the seed writes it: the test's oracle."""
    (x1, y1), (x2, y2), (x3, y3) = anchors
    r1, r2, r3 = ranges
    a, b = 2 * (x2 - x1), 2 * (y2 - y1)
    c = r1**2 - r2**2 - x1**2 + x2**2 - y1**2 + y2**2
    d, e = 2 * (x3 - x2), 2 * (y3 - y2)
    f = r2**2 - r3**2 - x2**2 + x3**2 - y2**2 + y3**2
    return (c * e - f * b) / (e * a - b * d), (c * d - a * f) / (b * d - a * e)


def _follower_seed_formula(d1, d2, d3, d12, x3, y3):
    """The follower seed's x4, y4 in the frame of robots 1-3 (DESIGN.md §3)."""
    x4 = (d1**2 - d2**2 + d12**2) / (2 * d12)
    return x4, (d1**2 - d3**2 + x3**2 + y3**2) / (2 * y3) - x3 * x4 / y3


def test_follower_frames_exact_values():
    # d12 = 3, d13 = 4, d23 = 5: x3 = (16 - 25 + 9) / 6 = 0, y3 = 4.
    assert place_references(3.0, 4.0, 5.0)[1] == (0.0, 4.0)
    assert place_references(5.0, 4.0, 3.0)[1] == (3.2, pytest.approx(2.4))
    with pytest.raises(GeometryError, match="positive"):
        place_references(0.0, 4.0, 5.0)
    with pytest.raises(GeometryError, match="degenerate"):
        place_references(10.0, 10.0, 30.0)  # no triangle


def test_trilaterate_linear_refuses_collinear_anchors_and_bad_shapes():
    line = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    with pytest.raises(GeometryError, match="collinear"):
        trilaterate_linear(line, np.array([30.0, 20.0, 60.0]))
    with pytest.raises(GeometryError, match="collinear"):  # anchors 1 and 2 coincide
        trilaterate_linear([(0.0, 0.0), (0.0, 0.0), (10.0, 30.0)], [10.0, 10.0, 20.0])
    bent = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.5]])
    trilaterate_linear(bent, [50.0, 40.0, 60.0])  # 0.33 mm from a line: accepted by default...
    with pytest.raises(GeometryError, match="collinear"):  # ... but not with this threshold
        trilaterate_linear(bent, [50.0, 40.0, 60.0], min_width_mm=1.0)
    with pytest.raises(ValueError, match=r"\(3, 2\)"):
        trilaterate_linear(np.zeros((4, 2)), np.ones(4))


@settings(max_examples=80, deadline=None)
@given(point, point, point, point)
def test_closed_forms_recover_a_fourth_robot(p1, p2, p3, p4):
    assume(_min_altitude(p1, p2, p3) > 10.0)
    d12, d13, d23 = _dist(p1, p2), _dist(p1, p3), _dist(p2, p3)
    _, (x3, y3) = place_references(d12, d13, d23)
    frame = np.array([[0.0, 0.0], [d12, 0.0], [x3, y3]])
    ranges = [_dist(p4, p) for p in (p1, p2, p3)]
    x4, y4 = trilaterate_linear(frame, ranges)
    # The frame is the floor up to a rigid motion (perhaps mirrored): compare all distances.
    est = np.vstack([frame, [x4, y4]])
    true = np.array([p1, p2, p3, p4])
    assert procrustes_rmse(est, true)[1] < 1e-6 * (1 + np.abs(true).max())
    # On the floor's own coordinates it is the maze seed's A…F formula.
    x, y = trilaterate_linear(true[:3], ranges)
    want = _maze_seed_formula(true[:3].tolist(), ranges)
    assert (x, y) == (pytest.approx(want[0], abs=1e-6), pytest.approx(want[1], abs=1e-6))


@settings(max_examples=80, deadline=None)
@given(
    st.floats(20.0, 250.0),
    st.floats(-200.0, 200.0),
    st.floats(1.0, 200.0),
    st.lists(st.floats(0.0, 300.0), min_size=3, max_size=3),
)
def test_in_the_frame_of_three_it_is_the_follower_seeds_formula_bit_for_bit(d12, x3, y3, ranges):
    """With robot 1 at the origin and robot 2 on +x, the frame turn is exactly the identity,
    so the follower computes the very numbers of the seed's formula (its runs are unchanged)."""
    got = trilaterate_linear([(0.0, 0.0), (d12, 0.0), (x3, y3)], ranges)
    assert got == _follower_seed_formula(*ranges, d12, x3, y3)


def _least_squares_oracle(anchors, ranges, start):
    """scipy's least squares on the range residuals, to full precision, from ``start``.

    It solves for ``q = p − (start − 1 mm)`` from q = (1, 1) mm: scipy sizes its first step
    by the size of the start, so a start near the origin would stall it.
    """
    offset = np.asarray(start, dtype=float) - 1.0

    def residuals(q):
        return np.hypot(*(q + offset - anchors).T) - ranges

    def jacobian(q):
        diff = q + offset - anchors
        return diff / np.hypot(*diff.T)[:, None]

    fit = least_squares(residuals, np.ones(2), jac=jacobian, xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return fit.x + offset


@settings(max_examples=100, deadline=None)
@given(
    point,
    st.floats(30.0, 150.0),
    st.floats(0.0, 2.0 * math.pi),
    st.integers(3, 8),
    st.floats(0.0, 0.8),
    st.floats(0.0, 2.0),
    st.integers(0, 2**32 - 1),
)
def test_multilaterate_is_the_least_squares_fit_of_scipy(
    centre, radius_mm, heading, k, inside, sigma_mm, seed
):
    """Well-conditioned anchor sets (k anchors spread round a circle, the robot inside) with
    noisy ranges: the fix is the minimum scipy's Levenberg–Marquardt finds from the truth."""
    rng = np.random.default_rng(seed)
    angles = heading + 2.0 * math.pi * (np.arange(k) + rng.uniform(-0.2, 0.2, k)) / k
    anchors = np.array(centre) + radius_mm * np.column_stack([np.cos(angles), np.sin(angles)])
    truth = np.array(centre) + inside * radius_mm * np.array([math.cos(seed), math.sin(seed)])
    ranges = _ranges(anchors, truth) + rng.normal(0.0, sigma_mm, k)
    assume(ranges.min() > 5.0)
    fix = multilaterate(anchors, ranges, sigma_mm=max(sigma_mm, 0.1))
    want = _least_squares_oracle(anchors, ranges, truth)
    # multilaterate stops once a step is below 1e-9 of the problem's scale, which leaves an
    # error of about that step (5,000 random cases: at most 6.5e-10 of the scale).
    scale = 1.0 + np.abs(anchors).max() + ranges.max()
    assert math.dist((fix.x_mm, fix.y_mm), want) < 2e-9 * scale
    assert fix.rmse_mm == pytest.approx(
        math.sqrt(np.mean((_ranges(anchors, want) - ranges) ** 2)), abs=1e-9
    )


@settings(max_examples=100, deadline=None)
@given(
    st.lists(point, min_size=3, max_size=8, unique=True),
    point,
    st.floats(0.0, 3.0),
    st.integers(0, 2**32 - 1),
)
def test_linear_position_is_scipys_least_squares_of_the_squared_range_equations(
    anchor_list, truth, sigma_mm, seed
):
    """The oracle keeps ``|p|²`` as a free unknown w instead of subtracting the mean equation:
    scipy's least squares of ``2 aᵢ · p − w = |aᵢ|² − rᵢ²`` over (p, w) has the same p."""
    anchors = np.array(anchor_list)
    width = svdvals(anchors - anchors.mean(axis=0))
    assume(width[-1] > 1.0)  # anchors spread in both directions
    rng = np.random.default_rng(seed)
    ranges = np.abs(_ranges(anchors, truth) + rng.normal(0.0, sigma_mm, len(anchors)))
    p, conditioning = linear_position(anchors, ranges)
    system = np.column_stack([2.0 * anchors, -np.ones(len(anchors))])
    want, *_ = lstsq(system, (anchors**2).sum(axis=1) - ranges**2)
    scale = 1.0 + np.abs(anchors).max() + ranges.max()
    assert math.dist(p, want[:2]) < 1e-9 * scale / (width[-1] / width[0])
    assert conditioning == pytest.approx(width[-1] / width[0], rel=1e-9)
    if sigma_mm == 0.0:
        assert math.dist(p, truth) < 1e-7 * scale / (width[-1] / width[0])


def test_linear_position_says_when_the_anchors_lie_on_one_line():
    line = np.array([[0.0, 0.0], [40.0, 30.0], [80.0, 60.0], [-40.0, -30.0]])
    assert linear_position(line, np.full(4, 50.0))[1] < 1e-12  # 0 but for rounding
    bent = line + np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.05]])
    assert 0.0 < linear_position(bent, np.full(4, 50.0))[1] < 1e-3


# ----------------------------------------------------------------------------- local frames


def test_angle_at_exact_values():
    assert angle_at(3.0, 4.0, 5.0) == pytest.approx(math.pi / 2)
    assert angle_at(40.0, 40.0, 40.0) == pytest.approx(math.pi / 3)
    assert angle_at(40.0, 40.0, 40.0 * math.sqrt(3.0)) == pytest.approx(2 * math.pi / 3)
    assert angle_at(40.0, 40.0, 0.0) == 0.0


def test_angle_at_clips_noisy_sides_and_refuses_coincident_robots():
    assert angle_at(10.0, 10.0, 20.5) == math.pi  # triangle inequality broken by noise
    assert angle_at(10.0, 30.0, 19.0) == 0.0
    with pytest.raises(GeometryError, match="positive"):
        angle_at(0.0, 30.0, 19.0)
    with pytest.raises(GeometryError, match="non-negative"):
        angle_at(10.0, 30.0, -1.0)
    with pytest.raises(GeometryError, match="finite"):
        angle_at(10.0, math.nan, 19.0)


def test_place_references_exact_values():
    assert place_references(3.0, 4.0, 5.0) == ((3.0, 0.0), (0.0, 4.0))
    (xb, yb), (xc, yc) = place_references(40.0, 40.0, 40.0)
    assert (xb, yb) == (40.0, 0.0)
    assert (xc, yc) == (pytest.approx(20.0), pytest.approx(20.0 * math.sqrt(3.0)))
    # Obtuse at A: C lands at negative x (thesis: (|AC| cos α, |AC| sin α)).
    (_, _), (xc, yc) = place_references(40.0, 40.0, 40.0 * math.sqrt(3.0))
    assert (xc, yc) == (pytest.approx(-20.0), pytest.approx(20.0 * math.sqrt(3.0)))


def test_place_references_refuses_degenerate_triangles():
    with pytest.raises(GeometryError, match="degenerate"):
        place_references(40.0, 40.0, 80.0)  # C straight behind A
    with pytest.raises(GeometryError, match="degenerate"):
        place_references(40.0, 80.0, 40.0)  # B between A and C
    with pytest.raises(GeometryError, match="degenerate"):
        place_references(40.0, 40.0, 90.0)  # no triangle at all
    flat = math.pi - math.asin(0.5 / 40.0)  # C 0.5 mm off line AB, behind A
    d_bc = math.sqrt(2 * 40.0**2 * (1.0 - math.cos(flat)))
    with pytest.raises(GeometryError, match=r"C is 0\.5 mm from line AB \(need >= 1\.0 mm\)"):
        place_references(40.0, 40.0, d_bc)
    # The threshold is a parameter: the same triangle is a frame with a lower one.
    _, (_, yc) = place_references(40.0, 40.0, d_bc, min_height_mm=0.1)
    assert yc == pytest.approx(0.5)
    with pytest.raises(GeometryError, match="positive"):
        place_references(0.0, 40.0, 40.0)


@settings(max_examples=80, deadline=None)
@given(point, point, point)
def test_place_references_reproduces_the_triangle(a, b, c):
    assume(_min_altitude(a, b, c) > 2.0)
    d_ab, d_ac, d_bc = _dist(a, b), _dist(a, c), _dist(b, c)
    (xb, yb), (xc, yc) = place_references(d_ab, d_ac, d_bc)
    assert yb == 0.0 and xb == d_ab and yc > 0.0
    tol = 1e-7 * (1.0 + max(d_ab, d_ac, d_bc))
    assert math.hypot(xc, yc) == pytest.approx(d_ac, abs=tol)
    assert math.hypot(xc - xb, yc) == pytest.approx(d_bc, abs=tol)


# ------------------------------------------------------------------ choosing the references


def test_max_angle_rule_takes_the_widest_angle_at_the_seed():
    candidates = {
        ("b1", "c1"): (40.0, 40.0, 40.0),  # 60°
        ("b2", "c2"): (40.0, 40.0, 69.0),  # ≈ 119.2°
        ("b3", "c3"): (40.0, 40.0, 56.6),  # ≈ 90°
    }
    pair, alpha = choose_references_max_angle(candidates)
    assert pair == ("b2", "c2")
    assert alpha == pytest.approx(angle_at(40.0, 40.0, 69.0))


def test_best_conditioned_rule_takes_the_widest_triangle():
    candidates = {
        (1, 2): (40.0, 40.0, 69.0),  # width 20.2 mm
        (3, 4): (69.0, 69.0, 69.0),  # equilateral, width 59.8 mm
        (5, 6): (40.0, 40.0, 40.0),  # equilateral, smaller: width 34.6 mm
    }
    pair, width = choose_references_best_conditioned(candidates)
    assert pair == (3, 4)
    assert width == pytest.approx(69.0 * math.sqrt(3.0) / 2)
    # Scale matters: of two similar triangles the larger wins; the thesis's rule cannot tell.
    similar = {(5, 6): (40.0, 40.0, 40.0), (3, 4): (69.0, 69.0, 69.0)}
    assert choose_references_best_conditioned(similar)[0] == (3, 4)
    assert choose_references_max_angle(similar)[0] == (5, 6)  # tie: the first pair


def test_rules_skip_degenerate_pairs_and_fail_when_none_is_left():
    candidates = {(1, 2): (40.0, 40.0, 80.0), (1, 3): (40.0, 40.0, 40.0)}  # (1, 2): 180°
    assert choose_references_max_angle(candidates)[0] == (1, 3)
    assert choose_references_best_conditioned(candidates)[0] == (1, 3)
    for rule in (choose_references_max_angle, choose_references_best_conditioned):
        with pytest.raises(GeometryError, match="none of 1 candidate"):
            rule({(1, 2): (40.0, 40.0, 80.0)})
        with pytest.raises(GeometryError, match="none of 0 candidate"):
            rule({})


@settings(max_examples=40, deadline=None)
@given(point, point, point)
def test_best_conditioned_score_is_the_smallest_altitude(a, b, c):
    assume(_min_altitude(a, b, c) > 2.0)
    sides = (_dist(a, b), _dist(a, c), _dist(b, c))
    _, width = choose_references_best_conditioned({("b", "c"): sides})
    assert width == pytest.approx(_min_altitude(a, b, c), rel=1e-7, abs=1e-7)


def test_best_conditioned_frames_localise_a_noisy_neighbourhood_better():
    """The seed in a hex lattice (40 mm, range 85 mm, σ = 1 mm) builds its frame by each rule
    and locates its neighbours from A, B, C; error after alignment, averaged over draws."""
    pos = hex_lattice(61)
    i, j, _ = pairs_in_range(pos, 85.0)
    sees = {(int(a), int(b)) for a, b in zip(i, j, strict=True)}
    sees |= {(b, a) for a, b in sees}
    seed = int(np.argmin(np.hypot(*(pos - pos.mean(axis=0)).T)))
    neighbours = sorted(b for a, b in sees if a == seed)
    rng = np.random.default_rng(1)
    errors = {"max_angle": [], "best_conditioned": []}
    rules = {
        "max_angle": choose_references_max_angle,
        "best_conditioned": choose_references_best_conditioned,
    }
    for _ in range(40):
        noise = {}

        def measured(a, b, noise=noise):
            key = (min(a, b), max(a, b))
            if key not in noise:
                noise[key] = _dist(pos[a], pos[b]) + rng.normal(0.0, 1.0)
            return noise[key]

        candidates = {
            (b, c): (measured(seed, b), measured(seed, c), measured(b, c))
            for b in neighbours
            for c in neighbours
            if (b, c) in sees
        }
        for name, rule in rules.items():
            (b, c), _ = rule(candidates)
            frame = np.array([(0.0, 0.0), *place_references(*candidates[(b, c)])])
            est, true = list(frame), [pos[seed], pos[b], pos[c]]
            for r in neighbours:
                if r not in (b, c):
                    ranges = [measured(r, x) for x in (seed, b, c)]
                    fix = multilaterate(frame, np.array(ranges))
                    if fix.ok:
                        est.append((fix.x_mm, fix.y_mm))
                        true.append(pos[r])
            errors[name].append(procrustes_rmse(np.array(est), np.array(true))[0])
    thesis, ours = np.mean(errors["max_angle"]), np.mean(errors["best_conditioned"])
    assert ours < 0.9 * thesis, (ours, thesis)


# --------------------------------------------------------------------------- multilateration

_TRIANGLE = np.array([[0.0, 0.0], [60.0, 0.0], [10.0, 50.0]])


def _ranges(anchors, p):
    return np.hypot(*(np.asarray(anchors) - p).T)


def test_multilaterate_exact_on_a_triangle_and_agrees_with_the_linear_formula():
    fix = multilaterate(_TRIANGLE, _ranges(_TRIANGLE, [30.0, 20.0]))
    assert fix.ok and fix.reason == "" and fix.anchors == 3
    assert (fix.x_mm, fix.y_mm) == (pytest.approx(30.0), pytest.approx(20.0))
    assert fix.rmse_mm == pytest.approx(0.0, abs=1e-9)
    assert 1.0 < fix.gdop < 2.0
    ranges = _ranges(_TRIANGLE, [-15.0, 70.0])
    fix = multilaterate(_TRIANGLE, ranges)
    linear = trilaterate_linear(_TRIANGLE, ranges)
    assert (fix.x_mm, fix.y_mm) == (pytest.approx(linear[0]), pytest.approx(linear[1]))


def test_multilaterate_with_the_seed_as_an_anchor():
    """The thesis's case: seed S at the origin plus two robots located in S's frame."""
    (xb, yb), (xc, yc) = place_references(40.0, 45.0, 50.0)
    anchors = np.array([[0.0, 0.0], [xb, yb], [xc, yc]])
    fix = multilaterate(anchors, _ranges(anchors, [50.0, -30.0]))
    assert fix.ok
    assert (fix.x_mm, fix.y_mm) == (pytest.approx(50.0), pytest.approx(-30.0))


def test_multilaterate_least_squares_with_noise():
    rng = np.random.default_rng(3)
    anchors = np.array([[0, 0], [80, 0], [0, 80], [80, 80], [40, -30], [-30, 40]], dtype=float)
    truth = np.array([35.0, 45.0])
    errors = []
    for _ in range(200):
        fix = multilaterate(anchors, _ranges(anchors, truth) + rng.normal(0, 1.0, len(anchors)))
        assert fix.ok, fix
        errors.append(math.hypot(fix.x_mm - truth[0], fix.y_mm - truth[1]))
        # k − 2 degrees of freedom: the residual RMSE is about σ √((k − 2) / k).
        assert fix.rmse_mm < 3.0
    rms = math.sqrt(np.mean(np.square(errors)))
    assert rms == pytest.approx(fix.gdop * 1.0, rel=0.2)  # error ≈ σ · GDOP


def test_multilaterate_rejects_too_few_and_collinear_anchors():
    fix = multilaterate(_TRIANGLE[:2], _ranges(_TRIANGLE[:2], [30.0, 20.0]))
    assert (fix.ok, fix.reason, fix.anchors) == (False, "too_few_anchors", 2)
    assert math.isnan(fix.x_mm) and math.isnan(fix.y_mm)
    line = np.array([[0.0, 0.0], [40.0, 0.3], [80.0, 0.0], [120.0, 0.1]])
    fix = multilaterate(line, _ranges(line, [50.0, 40.0]))
    assert (fix.ok, fix.reason) == (False, "collinear_anchors")
    # The width threshold follows sigma_mm unless given.
    assert multilaterate(line, _ranges(line, [50.0, 40.0]), sigma_mm=0.01).reason != (
        "collinear_anchors"
    )
    assert multilaterate(
        _TRIANGLE, _ranges(_TRIANGLE, [30.0, 20.0]), min_anchor_width_mm=100.0
    ).reason == ("collinear_anchors")


def test_multilaterate_detects_the_mirror_image_of_nearly_collinear_anchors():
    anchors = np.array([[0.0, 0.0], [40.0, 2.0], [80.0, 0.0]])  # 1.3 mm off their line
    truth = np.array([40.0, 30.0])
    fix = multilaterate(anchors, _ranges(anchors, truth))
    assert (fix.ok, fix.reason) == (False, "mirror_ambiguity")
    # The better of the two fits is still reported, with its rival's residual.
    assert (fix.x_mm, fix.y_mm) == (pytest.approx(40.0), pytest.approx(30.0))
    assert 0.0 < fix.mirror_rmse_mm < 3.0 / math.sqrt(3.0)
    # Bent enough (20 mm), the mirror image no longer fits: accepted.
    bent = np.array([[0.0, 0.0], [40.0, 20.0], [80.0, 0.0]])
    fix = multilaterate(bent, _ranges(bent, truth))
    assert fix.ok and fix.mirror_rmse_mm > 3.0
    # A looser margin accepts the nearly collinear case; a tighter one rejects the bent one.
    assert multilaterate(anchors, _ranges(anchors, truth), mirror_sigmas=0.5).ok
    assert multilaterate(bent, _ranges(bent, truth), mirror_sigmas=20.0).reason == (
        "mirror_ambiguity"
    )


def test_multilaterate_reports_the_better_side_when_the_start_is_mirrored():
    """Nearly collinear anchors and noise: whichever side the linear start lands on, the
    reported fit is the better of the two."""
    anchors = np.array([[0.0, 0.0], [40.0, 4.0], [80.0, 0.0]])
    rng = np.random.default_rng(11)
    for _ in range(50):
        ranges = _ranges(anchors, [40.0, 30.0]) + rng.normal(0.0, 1.0, 3)
        fix = multilaterate(anchors, ranges, mirror_sigmas=0.0)
        if math.isfinite(fix.mirror_rmse_mm):
            assert fix.rmse_mm <= fix.mirror_rmse_mm


def test_multilaterate_rejects_inconsistent_ranges_and_poor_geometry():
    anchors = np.array([[0.0, 0.0], [80.0, 0.0], [0.0, 80.0], [80.0, 80.0]])
    ranges = _ranges(anchors, [30.0, 40.0])
    ranges[2] += 20.0  # a wrong range (or an anchor not where it claims to be)
    fix = multilaterate(anchors, ranges)
    assert (fix.ok, fix.reason) == (False, "large_residual")
    assert fix.rmse_mm > 3.0 and math.isfinite(fix.x_mm)
    assert multilaterate(anchors, ranges, max_rmse_mm=50.0).ok
    far = multilaterate(_TRIANGLE, _ranges(_TRIANGLE, [1000.0, 1000.0]))
    assert (far.ok, far.reason) == (False, "poor_geometry")
    assert far.gdop > 5.0
    assert (far.x_mm, far.y_mm) == (pytest.approx(1000.0), pytest.approx(1000.0))
    assert multilaterate(_TRIANGLE, _ranges(_TRIANGLE, [1000.0, 1000.0]), max_gdop=100.0).ok


def test_multilaterate_refuses_malformed_input_and_fix_is_frozen():
    with pytest.raises(ValueError, match=r"\(k, 2\)"):
        multilaterate(_TRIANGLE, np.ones(2))
    with pytest.raises(ValueError, match="non-negative"):
        multilaterate(_TRIANGLE, np.array([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="finite"):
        multilaterate(_TRIANGLE, np.array([1.0, np.inf, 1.0]))
    with pytest.raises(ValueError, match="sigma_mm"):
        multilaterate(_TRIANGLE, np.ones(3), sigma_mm=0.0)
    fix = multilaterate(_TRIANGLE, _ranges(_TRIANGLE, [30.0, 20.0]))
    with pytest.raises(dataclasses.FrozenInstanceError):
        fix.x_mm = 0.0  # type: ignore[misc]


anchor_sets = st.lists(point, min_size=3, max_size=8)


@settings(max_examples=60, deadline=None)
@given(anchor_sets, point)
def test_multilaterate_recovers_noiseless_positions(anchor_list, truth):
    anchors = np.array(anchor_list)
    ranges = _ranges(anchors, truth)
    assume(ranges.min() > 1.0)
    fix = multilaterate(anchors, ranges)
    assert fix.reason in FIX_REASONS or fix.reason == ""
    assert fix.reason != "large_residual"
    if fix.reason in ("", "mirror_ambiguity"):
        assert (fix.x_mm, fix.y_mm) == (
            pytest.approx(truth[0], abs=1e-6),
            pytest.approx(truth[1], abs=1e-6),
        )
    if fix.reason == "":
        assert fix.rmse_mm < 1e-6


@settings(max_examples=40, deadline=None)
@given(
    point,
    st.floats(20.0, 150.0),
    st.floats(0.0, 2.0 * math.pi),
    st.lists(st.floats(-0.25, 0.25), min_size=3, max_size=3),
    st.floats(0.05, 0.95),
    st.floats(0.05, 0.95),
)
def test_multilaterate_accepts_points_inside_a_well_shaped_triangle(
    centre, radius_mm, heading, wobble, s, t
):
    # Built well shaped rather than filtered: vertices near an equilateral triangle's, each
    # moved up to 0.25 rad around the circumcircle (an elongated triangle seen from near a sharp
    # corner has a GDOP above 5, which multilaterate rightly refuses). Random triangles that pass
    # such a filter are rare enough that Hypothesis's health check failed the test.
    angles = heading + np.array([0.0, 2.0, 4.0]) * math.pi / 3.0 + np.array(wobble)
    anchors = np.array(centre) + radius_mm * np.column_stack([np.cos(angles), np.sin(angles)])
    longest = max(math.dist(p, q) for p, q in itertools.combinations(anchors, 2))
    assert _min_altitude(*anchors) > 0.6 * longest  # the construction is what it claims
    s, t = min(s, t), max(s, t)  # barycentric-style draw strictly inside the triangle
    truth = anchors[0] * s + anchors[1] * (t - s) + anchors[2] * (1.0 - t)
    assume(_ranges(anchors, truth).min() > 5.0)
    fix = multilaterate(anchors, _ranges(anchors, truth))
    assert fix.ok, fix
    assert (fix.x_mm, fix.y_mm) == (pytest.approx(truth[0]), pytest.approx(truth[1]))


@settings(max_examples=40, deadline=None)
@given(
    point,
    st.floats(0.0, math.pi),
    st.lists(st.floats(-150.0, 150.0), min_size=3, max_size=6, unique=True),
    st.lists(st.floats(-0.45, 0.45), min_size=6, max_size=6),
    point,
)
def test_collinear_anchors_are_rejected(origin, heading, along, across, truth):
    direction = np.array([math.cos(heading), math.sin(heading)])
    normal = np.array([-direction[1], direction[0]])
    anchors = np.array(
        [origin + a * direction + w * normal for a, w in zip(along, across, strict=False)]
    )
    assume(np.ptp(along) > 10.0)
    fix = multilaterate(anchors, _ranges(anchors, truth))
    assert (fix.ok, fix.reason) == (False, "collinear_anchors")


# ----------------------------------------------------------------------- Cramér–Rao bound

_EQUILATERAL = np.array([[0.0, 0.0], [40.0, 0.0], [20.0, 20.0 * math.sqrt(3.0)]])
_SIDES = [(0, 1), (0, 2), (1, 2)]


def _crlb_by_pinv(pos, edges, sigma):
    """The definition, computed the slow way: a dense J and numpy's pseudo-inverse."""
    n = len(pos)
    info = np.zeros((2 * n, 2 * n))
    for i, j in edges:
        u = (pos[i] - pos[j]) / np.linalg.norm(pos[i] - pos[j])
        block = np.outer(u, u) / sigma**2
        for a, b, sign in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
            info[2 * a : 2 * a + 2, 2 * b : 2 * b + 2] += sign * block
    return math.sqrt(np.trace(np.linalg.pinv(info, rcond=1e-9, hermitian=True)) / n)


def test_crlb_of_a_rigid_triangle_is_sigma_sqrt5_over_3():
    assert crlb_rmse_mm(_EQUILATERAL, _SIDES, 1.0) == pytest.approx(math.sqrt(5.0) / 3.0)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.01, 10.0), st.floats(0.0, 2 * math.pi), point, st.booleans())
def test_crlb_scales_with_sigma_and_ignores_rigid_motions(sigma, turn, shift, mirror):
    pos = hex_lattice(12, jitter_mm=3.0, rng=np.random.default_rng(0))
    i, j, _ = pairs_in_range(pos, 85.0)
    edges = np.column_stack([i, j])
    base = crlb_rmse_mm(pos, edges, 1.0)
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    moved = (pos * [1.0, -1.0 if mirror else 1.0]) @ rot.T + shift
    assert crlb_rmse_mm(moved, edges, sigma) == pytest.approx(sigma * base, rel=1e-6)


def test_crlb_matches_the_pseudo_inverse_definition():
    pos = hex_lattice(19, jitter_mm=3.0, rng=np.random.default_rng(1))
    i, j, _ = pairs_in_range(pos, 85.0)
    edges = np.column_stack([i, j])
    assert crlb_rmse_mm(pos, edges, 1.5) == pytest.approx(_crlb_by_pinv(pos, edges, 1.5))
    # Disconnected (two triangles) and flexible (a square without diagonals) graphs take the
    # eigenvalue path; their extra null directions are dropped, as the definition's pinv does.
    two = np.vstack([_EQUILATERAL, _EQUILATERAL + np.array([500.0, 0.0])])
    two_edges = [*_SIDES, (3, 4), (3, 5), (4, 5)]
    assert crlb_rmse_mm(two, two_edges, 1.0) == pytest.approx(math.sqrt(5.0) / 3.0)
    square = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    ring = [(0, 1), (1, 2), (2, 3), (3, 0)]
    assert crlb_rmse_mm(square, ring, 1.0) == pytest.approx(_crlb_by_pinv(square, ring, 1.0))
    for pos_, edges_ in ((two, two_edges), (square, ring)):
        with pytest.raises(GeometryError, match="not rigid"):
            crlb_rmse_mm(pos_, edges_, 1.0, require_rigid=True)
    assert crlb_rmse_mm(_EQUILATERAL, _SIDES, 1.0, require_rigid=True) > 0


def test_crlb_decreases_when_edges_are_added():
    pos = hex_lattice(37, jitter_mm=3.0, rng=np.random.default_rng(2))
    i, j, _ = pairs_in_range(pos, 85.0)
    edges = np.column_stack([i, j])
    near = edges[np.hypot(*(pos[i] - pos[j]).T) < 50.0]  # first neighbours: rigid already
    previous = crlb_rmse_mm(pos, near, 1.0)
    extra = [e for e in edges.tolist() if e not in near.tolist()]
    for k in range(0, len(extra), 10):
        bound = crlb_rmse_mm(pos, np.vstack([near, extra[: k + 10]]), 1.0)
        assert bound <= previous + 1e-12
        previous = bound
    assert previous < 0.9 * crlb_rmse_mm(pos, near, 1.0)
    # Measuring every pair twice (both directions) halves the variance.
    assert crlb_rmse_mm(pos, np.vstack([edges, edges]), 1.0) == pytest.approx(
        crlb_rmse_mm(pos, edges, 1.0) / math.sqrt(2.0)
    )


def test_crlb_of_lattices_against_a_bare_triangle():
    """Hex lattices (40 mm): a denser graph lowers the bound a lot; the network's size only
    a little (errors pile up over hops, about as √log N in the plane)."""

    def bound(n, range_mm):
        pos = hex_lattice(n)
        i, j, _ = pairs_in_range(pos, range_mm)
        return crlb_rmse_mm(pos, np.column_stack([i, j]), 1.0)

    triangle = crlb_rmse_mm(_EQUILATERAL, _SIDES, 1.0)
    assert triangle == pytest.approx(0.745356, abs=1e-6)
    # A centre and its six neighbours, 5 measurements per robot instead of 2.
    assert bound(7, 85.0) < triangle
    # First neighbours only (about 5 per robot) against second ones too (about 9).
    assert bound(37, 85.0) < 0.7 * bound(37, 45.0)
    # Six times the robots, under a tenth more error per robot.
    assert 1.0 < bound(120, 85.0) / bound(19, 85.0) < 1.1


def test_crlb_is_attained_by_the_exact_triangle_solution():
    """Three sides fix a triangle exactly, so solving them is efficient to first order: the
    Monte Carlo RMSE after alignment matches the bound for small noise."""
    rng = np.random.default_rng(4)
    sigma = 0.05
    true_sides = [_dist(_EQUILATERAL[a], _EQUILATERAL[b]) for a, b in _SIDES]
    sq = []
    for _ in range(1500):
        d01, d02, d12 = np.array(true_sides) + rng.normal(0.0, sigma, 3)
        est = np.array([(0.0, 0.0), *place_references(d01, d02, d12)])
        sq.append(procrustes_rmse(est, _EQUILATERAL)[0] ** 2)
    assert math.sqrt(np.mean(sq)) == pytest.approx(
        crlb_rmse_mm(_EQUILATERAL, _SIDES, sigma), rel=0.05
    )


def test_crlb_refuses_bad_graphs():
    with pytest.raises(GeometryError, match="no measured pairs"):
        crlb_rmse_mm(_EQUILATERAL, np.empty((0, 2), dtype=int), 1.0)
    with pytest.raises(GeometryError, match="coincident"):
        crlb_rmse_mm(np.zeros((2, 2)), [(0, 1)], 1.0)
    with pytest.raises(ValueError, match="self-loop"):
        crlb_rmse_mm(_EQUILATERAL, [(0, 0)], 1.0)
    with pytest.raises(ValueError, match="out of range"):
        crlb_rmse_mm(_EQUILATERAL, [(0, 3)], 1.0)
    with pytest.raises(ValueError, match="sigma_mm"):
        crlb_rmse_mm(_EQUILATERAL, _SIDES, 0.0)


# -- plane geometry: scipy as the oracle --------------------------------------------------------
_coord = st.floats(-300.0, 300.0)
_range = st.floats(5.0, 200.0)


@settings(max_examples=200, deadline=None)
@given(_coord, _coord, _coord, _coord, _range, _range)
def test_circle_intersections_solve_both_range_equations_as_scipy_does(x1, y1, x2, y2, r1, r2):
    """Where the circles meet, each point returned satisfies both range equations, and scipy's
    least squares started from it stays there; where they miss, the one point is scipy's
    minimum of the squared range residuals on the line of centres."""
    d = math.hypot(x2 - x1, y2 - y1)
    assume(d > 1.0)
    c1, c2 = np.array([x1, y1]), np.array([x2, y2])

    def residuals(p):
        return [np.hypot(*(p - c1)) - r1, np.hypot(*(p - c2)) - r2]

    points = circle_intersections((x1, y1), r1, (x2, y2), r2)
    if abs(r1 - r2) + 1e-6 < d < r1 + r2 - 1e-6:
        assert len(points) == 2
        apart = math.dist(*points)
        for p in points:
            assert np.abs(residuals(np.array(p))).max() < 1e-6 * (1 + r1 + r2)
            if apart > 2.0:  # an isolated root: scipy's solver from nearby converges to it
                start = np.array(p) + 0.1 * (np.array(p) - np.mean(points, axis=0)) / apart
                solved = least_squares(residuals, start, xtol=1e-14, ftol=1e-14).x
                assert np.hypot(*(solved - p)) < 1e-4
        pair = circle_pair((x1, y1), r1, (x2, y2), r2)
        assert pair is not None
        assert np.allclose([pair[0], pair[1]], points, atol=1e-9)
        # the distance of each from the line of centres
        u = (c2 - c1) / d
        assert pair[2] == pytest.approx(
            abs(u[0] * (pair[0][1] - y1) - u[1] * (pair[0][0] - x1)), abs=1e-6
        )
    elif d > r1 + r2 + 1e-6 or d < abs(r1 - r2) - 1e-6:
        (p,) = points
        u = (c2 - c1) / d
        # scipy: the point t along the line of centres nearest both rims
        best = least_squares(lambda s: residuals(c1 + s[0] * u), [d / 2]).x[0]
        assert np.allclose(p, c1 + best * u, atol=1e-5)
        if d > r1 + r2 + 0.5 or d < abs(r1 - r2) - 0.5:
            assert circle_pair((x1, y1), r1, (x2, y2), r2) is None


def test_circle_pair_takes_circles_that_miss_by_rounding_as_touching():
    p, q, h = circle_pair((0.0, 0.0), 40.0, (80.4, 0.0), 40.0)
    assert p == q == (40.2, 0.0) and h == 0.0
    assert circle_pair((0.0, 0.0), 40.0, (80.6, 0.0), 40.0) is None
    assert circle_intersections((1.0, 1.0), 3.0, (1.0, 1.0), 4.0) == []
    assert circle_pair((1.0, 1.0), 3.0, (1.0, 1.0), 3.0) is None


@settings(max_examples=100, deadline=None)
@given(st.floats(-50.0, 50.0), _coord, _coord)
def test_rotate_and_wrap_agree_with_scipy_rotation(angle, x, y):
    from scipy.spatial.transform import Rotation

    expected = Rotation.from_euler("z", angle).apply([x, y, 0.0])[:2]
    assert np.allclose(rotate((x, y), angle), expected, atol=1e-9)
    wrapped = wrap_angle(angle)
    assert -math.pi <= wrapped < math.pi
    # the same rotation: scipy's rotation vectors of both angles agree
    assert np.allclose(
        Rotation.from_euler("z", wrapped).as_matrix(), Rotation.from_euler("z", angle).as_matrix()
    )
