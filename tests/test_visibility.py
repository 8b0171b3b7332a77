"""Tests for kilonet.visibility: visible pairs against an O(N^3) brute force."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from kilonet.visibility import communication_graph, visible_pairs

RADIUS_MM = 16.5
TIE_MM = 1e-6  # configurations this close to a range or blocking boundary are skipped


def segment_gap(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from point ``p`` to the segment ``a``–``b``."""
    ab, ap = b - a, p - a
    t = min(1.0, max(0.0, float(ap @ ab) / float(ab @ ab)))
    return math.hypot(*(ap - t * ab))


def brute_force(pos, range_mm, radius_mm, line_of_sight, present):
    """Visible pairs by checking every pair against every third robot, and the smallest
    margin to a decision boundary seen (to skip ties that rounding may decide either way)."""
    pairs, margin = [], math.inf
    n = len(pos)
    for i in range(n):
        for j in range(i + 1, n):
            if not (present[i] and present[j]):
                continue
            d = math.hypot(*(pos[j] - pos[i]))
            margin = min(margin, abs(d - range_mm))
            if d > range_mm:
                continue
            blocked = False
            if line_of_sight:
                for k in range(n):
                    if k in (i, j) or not present[k]:
                        continue
                    gap = segment_gap(pos[k], pos[i], pos[j])
                    margin = min(margin, abs(gap - radius_mm))
                    blocked = blocked or gap < radius_mm
            if not blocked:
                pairs.append((i, j, d))
    return pairs, margin


@st.composite
def placements(draw):
    """2–14 non-overlapping robots: distinct cells of a 40 mm grid, jittered by up to 3 mm
    (so centres stay >= 34 mm apart), which makes many nearly collinear triples."""
    cells = draw(
        st.lists(
            st.tuples(st.integers(0, 6), st.integers(0, 6)), min_size=2, max_size=14, unique=True
        )
    )
    jitter = draw(
        st.lists(
            st.tuples(st.floats(-3, 3), st.floats(-3, 3)), min_size=len(cells), max_size=len(cells)
        )
    )
    return np.array(cells, dtype=float) * 40.0 + np.array(jitter)


@settings(max_examples=100, deadline=None)
@given(
    pos=placements(),
    range_mm=st.floats(33.0, 250.0),
    radius_mm=st.sampled_from([RADIUS_MM, 10.0, 19.0]),
    line_of_sight=st.booleans(),
    data=st.data(),
)
def test_visible_pairs_equals_brute_force(pos, range_mm, radius_mm, line_of_sight, data):
    present = np.array(data.draw(st.lists(st.booleans(), min_size=len(pos), max_size=len(pos))))
    if data.draw(st.booleans()):
        present[:] = True
    expected, margin = brute_force(pos, range_mm, radius_mm, line_of_sight, present)
    assume(margin > TIE_MM)
    i, j, d = visible_pairs(
        pos, range_mm, radius_mm=radius_mm, line_of_sight=line_of_sight, present=present
    )
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == [(a, b) for a, b, _ in expected]
    np.testing.assert_allclose(d, [dist for _, _, dist in expected], rtol=1e-12)


@settings(max_examples=40, deadline=None)
@given(pos=placements(), range_mm=st.floats(33.0, 250.0))
def test_communication_graph_matches_visible_pairs(pos, range_mm):
    expected, margin = brute_force(pos, range_mm, RADIUS_MM, True, np.ones(len(pos), bool))
    assume(margin > TIE_MM)
    g = communication_graph(pos, range_mm)
    assert set(g.nodes) == set(range(len(pos)))
    assert sorted(tuple(sorted(e)) for e in g.edges) == [(a, b) for a, b, _ in expected]
    for a, b, dist in expected:
        assert math.isclose(g.edges[a, b]["distance_mm"], dist, rel_tol=1e-12)


def test_exact_cases():
    pos = np.array([[0.0, 0.0], [80.0, 0.0], [40.0, 16.4], [40.0, -16.5]])
    i, j, _ = visible_pairs(pos, 85.0)
    pairs = list(zip(i.tolist(), j.tolist(), strict=True))
    assert (0, 1) not in pairs  # robot 2's disc crosses the segment; robot 3's only touches
    assert pairs == [(0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    pos[2] = [40.0, 16.5]  # now both only touch the line
    i, j, _ = visible_pairs(pos, 85.0)
    assert (0, 1) in list(zip(i.tolist(), j.tolist(), strict=True))


def test_absent_robots_neither_hear_nor_block():
    pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    i, j, d = visible_pairs(pos, 85.0, present=np.array([True, False, True]))
    assert (i.tolist(), j.tolist(), d.tolist()) == ([0], [2], [80.0])
    i, j, _ = visible_pairs(pos, 85.0, present=np.array([True, False, False]))
    assert len(i) == 0


def test_no_pairs_in_range():
    i, j, d = visible_pairs(np.array([[0.0, 0.0], [200.0, 0.0]]), 85.0)
    assert len(i) == len(j) == len(d) == 0
    assert nx.number_of_edges(communication_graph(np.array([[0.0, 0.0], [200.0, 0.0]]), 85.0)) == 0
