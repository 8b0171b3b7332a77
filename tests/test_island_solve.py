"""The island solve of ``localize`` (kilonet.protocols.localize.island_solve): rigid bodies of
unplaced robots aligned to the frame through their links, only where that is unique."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kilonet.protocols.localize.island_solve import (
    RigidMotion,
    Tolerances,
    align_body,
    solve_island,
)
from kilonet.protocols.localize.phase4_island import IslandReports

RANGE_MM = 85.0
SHAPE = {"min_height_mm": 10.0, "overlap_mm": 28.0}


def tolerances(sigma_mm: float, max_rmse_mm: float) -> Tolerances:
    return Tolerances(sigma_mm=sigma_mm, max_rmse_mm=max_rmse_mm, **SHAPE)


def _island(truth: dict[int, tuple[float, float]], placed: list[tuple[float, float]], noise=None):
    """Pairs between the members and links to the placed points, within range."""
    rng = np.random.default_rng(0)

    def measure(p, q):
        d = math.dist(p, q)
        return d if noise is None else d + rng.normal(0.0, noise)

    members = sorted(truth)
    pairs = {
        (a, b): measure(truth[a], truth[b])
        for i, a in enumerate(members)
        for b in members[i + 1 :]
        if math.dist(truth[a], truth[b]) <= RANGE_MM
    }
    links = [
        (u, q, measure(truth[u], q))
        for u in members
        for q in placed
        if math.dist(truth[u], q) <= RANGE_MM
    ]
    return pairs, links


# A cluster like the one of the 100-robot random run (seed 1): four robots that all hear each
# other, two more placed only by two of them, and placed robots on one side, each heard by one
# or two members and no member hearing three.
CLUSTER = {
    1: (0.0, 0.0),
    2: (45.0, 5.0),
    3: (20.0, 40.0),
    4: (60.0, 45.0),
    5: (-30.0, 60.0),
    6: (95.0, 60.0),
}
SHORE = [(-50.0, -40.0), (40.0, -60.0), (110.0, -20.0), (-80.0, 45.0), (150.0, 40.0)]


def test_the_cluster_has_no_robot_with_three_placed_neighbours():
    _, links = _island(CLUSTER, SHORE)
    per_member = {u: sum(1 for v, _, _ in links if v == u) for u in CLUSTER}
    assert max(per_member.values()) <= 2
    assert len(links) >= 5


@pytest.mark.parametrize("own", sorted(CLUSTER))
def test_every_member_of_a_rigid_cluster_places_it_from_its_links(own):
    pairs, links = _island(CLUSTER, SHORE, noise=0.5)
    found = solve_island(own, pairs, links, tolerances(0.5, 2.0))
    assert own in found
    errors = [math.dist(found[u], CLUSTER[u]) for u in found]
    assert max(errors) < 3.0


def test_a_cluster_tied_by_links_of_one_member_only_stays_unplaced():
    pairs, _ = _island(CLUSTER, SHORE)
    # Four links, all from member 1: it is placed, and the rest, which reach the frame only
    # through it, could turn about it.
    shore = [(-50.0, -40.0), (40.0, -60.0), (-80.0, 0.0), (0.0, -80.0)]
    links = [(1, q, math.dist(CLUSTER[1], q)) for q in shore]
    found = solve_island(3, pairs, links, tolerances(0.5, 2.0))
    assert set(found) == {1}
    assert math.dist(found[1], CLUSTER[1]) < 1e-6


def test_a_cluster_whose_links_fit_its_mirror_image_as_well_stays_unplaced():
    # A square tied only to points on its own symmetry axis y = 20: the mirror image across
    # that axis fits every link exactly.
    square = {1: (0.0, 0.0), 2: (40.0, 0.0), 3: (40.0, 40.0), 4: (0.0, 40.0)}
    pairs, _ = _island(square, [])
    axis = [(-60.0, 20.0), (100.0, 20.0), (-50.0, 20.0), (90.0, 20.0)]
    links = [(u, q, math.dist(square[u], q)) for u in square for q in axis]
    assert solve_island(1, pairs, links, tolerances(0.5, 2.0)) == {}


def test_a_body_that_can_pivot_onto_a_second_exact_fit_stays_unplaced():
    # The reports robot 19 solved with in the study's sparse swarm (150 robots at 300 per m²,
    # seed 2; the robots' own IDs, frame coordinates, links in whole millimetres): a body of
    # robots 19, 24, 114 and 131, whose member 131 two links fix, and whose other two links go
    # from 19 and 24 to one placed robot. Turned about 131, the body fits all four links a
    # second time, 130 mm from the truth; a search that started from the centroids found only
    # that fit and placed the body there (three of its robots 78-131 mm off).
    r19, r24, r114, r131 = 46197, 48020, 20588, 61675
    pairs = {(r19, r24): 52.88, (r114, r19): 70.16, (r114, r24): 33.75}
    pairs |= {(r24, r131): 66.82, (r114, r131): 72.01}
    links = [
        (r19, (2.2, 202.1), 70.0),
        (r131, (-60.7, 323.8), 82.0),
        (r131, (-25.9, 304.8), 46.0),
        (r24, (2.2, 202.1), 72.0),
    ]
    sigma = 1.0866
    found = solve_island(r19, pairs, links, tolerances(sigma, 4 * sigma))
    assert found == {}


def test_links_that_fit_no_rigid_motion_are_refused():
    pairs, links = _island(CLUSTER, SHORE)
    links = [(u, q, d + (15.0 if k % 2 else -15.0)) for k, (u, q, d) in enumerate(links)]
    assert solve_island(1, pairs, links, tolerances(0.5, 2.0)) == {}


def test_an_island_too_large_is_not_solved():
    pairs, links = _island(CLUSTER, SHORE)
    found = solve_island(1, pairs, links, tolerances(0.5, 2.0), max_members=5)
    assert found == {}


def test_align_body_finds_the_mirrored_motion_and_needs_four_links():
    body = np.array([[0.0, 0.0], [40.0, 0.0], [20.0, 35.0]])
    truth = RigidMotion(True, -2.0, -400.0, 250.0)
    outside = np.array([[-40.0, -20.0], [80.0, -20.0], [20.0, 90.0], [60.0, 50.0]])
    rows = [0, 1, 2, 2]
    ranges = np.hypot(*(body[rows] - outside).T)
    _, motion = align_body(
        [body], rows, truth.apply(outside), ranges, sigma_mm=0.5, max_rmse_mm=2.0
    )
    assert motion.mirrored
    np.testing.assert_allclose(motion.apply(body), truth.apply(body), atol=1e-6)
    three = align_body(
        [body], rows[:3], truth.apply(outside[:3]), ranges[:3], sigma_mm=0.5, max_rmse_mm=2.0
    )
    assert three is None


def _scatter(rng, count: int, radius: tuple[float, float], apart_mm: float) -> np.ndarray:
    """``count`` points in the ring ``radius`` (mm), at least ``apart_mm`` from each other."""
    points: list[np.ndarray] = []
    while len(points) < count:
        r, a = math.sqrt(rng.uniform(radius[0] ** 2, radius[1] ** 2)), rng.uniform(0, 2 * math.pi)
        p = np.array([r * math.cos(a), r * math.sin(a)])
        if all(math.dist(p, q) >= apart_mm for q in points):
            points.append(p)
    return np.array(points)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    members=st.integers(4, 7),
    shore=st.integers(3, 7),
    angle=st.floats(0.0, 2 * math.pi),
    mirrored=st.booleans(),
)
def test_what_the_solve_places_it_places_right(seed, members, shore, angle, mirrored):
    # Random islands of exact distances in a random pose: members (33 mm bodies) within
    # 60 mm of a centre, placed robots 70-120 mm out, so few members hear three. The solve may
    # leave robots out, but every position it returns is the truth.
    rng = np.random.default_rng(seed)
    motion = RigidMotion(mirrored, angle, 500.0, -300.0)
    inner = motion.apply(_scatter(rng, members, (0.0, 60.0), 33.0))
    outer = motion.apply(_scatter(rng, shore, (70.0, 120.0), 33.0))
    truth = {u: tuple(p) for u, p in enumerate(inner)}
    pairs, links = _island(truth, [tuple(p) for p in outer])
    found = solve_island(0, pairs, links, tolerances(0.3, 1.2))
    for u, p in found.items():
        assert math.dist(p, truth[u]) < 0.05, (u, p, truth[u])


def test_reports_are_stored_once_and_count_against_the_capacity():
    reports = IslandReports(capacity=2)
    assert reports.link(7, 100.0, 50.0, 60.0)
    # The same placed robot, refined since, passed on by another member: not news, and the
    # first value stays (a replaced value could come back round the island as news).
    assert not reports.link(7, 102.0, 50.0, 61.0)
    assert reports.links == [(7, (100.0, 50.0), 60.0)]
    assert reports.pair(7, 9, 44.0)
    assert not reports.pair(9, 7, 45.0)
    assert not reports.pair(3, 9, 40.0)
    assert reports.full
    assert reports.pairs == {(7, 9): 44.0}
