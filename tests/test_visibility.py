"""Tests for kilonet.visibility: links (range, bodies crossing, the three occlusion modes)
against an O(N^3) brute force."""

from __future__ import annotations

import math

import networkx as nx
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from kilonet.visibility import LinkModel, communication_graph, pairs_in_range

RADIUS_MM = 16.5
TIE_MM = 1e-6  # configurations this close to a range or blocking boundary are skipped


def segment_gap(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Distance from point ``p`` to the segment ``a``–``b``."""
    ab, ap = b - a, p - a
    t = min(1.0, max(0.0, float(ap @ ab) / float(ab @ ab)))
    return math.hypot(*(ap - t * ab))


def brute_force(pos, range_mm, radius_mm, occlusion, present, factor=0.9, loss=0.1):
    """Links by checking every pair against every third robot, ``(i, j, d, bodies, loss)``,
    and the smallest margin to a decision boundary seen (to skip ties that rounding may decide
    either way)."""
    links, margin = [], math.inf
    n = len(pos)
    for i in range(n):
        for j in range(i + 1, n):
            if not (present[i] and present[j]):
                continue
            d = math.hypot(*(pos[j] - pos[i]))
            margin = min(margin, abs(d - range_mm))
            if d > range_mm:
                continue
            bodies = 0
            if occlusion != "none":
                for k in range(n):
                    if k in (i, j) or not present[k]:
                        continue
                    gap = segment_gap(pos[k], pos[i], pos[j])
                    margin = min(margin, abs(gap - radius_mm))
                    bodies += gap < radius_mm
            if occlusion == "block" and bodies:
                continue
            if occlusion == "graded":
                reach = range_mm * factor**bodies
                margin = min(margin, abs(d - reach))
                if d > reach:
                    continue
            links.append(
                (i, j, d, bodies, 1 - (1 - loss) ** bodies if occlusion == "graded" else 0.0)
            )
    return links, margin


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


@settings(max_examples=120, deadline=None)
@given(
    pos=placements(),
    range_mm=st.floats(33.0, 250.0),
    radius_mm=st.sampled_from([RADIUS_MM, 10.0, 19.0]),
    occlusion=st.sampled_from(["none", "block", "graded"]),
    data=st.data(),
)
def test_links_equal_brute_force(pos, range_mm, radius_mm, occlusion, data):
    present = np.array(data.draw(st.lists(st.booleans(), min_size=len(pos), max_size=len(pos))))
    if data.draw(st.booleans()):
        present[:] = True
    expected, margin = brute_force(pos, range_mm, radius_mm, occlusion, present)
    assume(margin > TIE_MM)
    links = LinkModel(range_mm, occlusion, 0.9, 0.1, radius_mm).links(pos, present)
    pairs = list(zip(links.i.tolist(), links.j.tolist(), strict=True))
    assert pairs == [(a, b) for a, b, *_ in expected]
    np.testing.assert_allclose(links.distance_mm, [e[2] for e in expected], rtol=1e-12)
    assert links.bodies.tolist() == [e[3] for e in expected]
    np.testing.assert_allclose(links.loss, [e[4] for e in expected], rtol=1e-12)


@settings(max_examples=40, deadline=None)
@given(pos=placements(), range_mm=st.floats(33.0, 250.0))
def test_communication_graph_matches_the_links(pos, range_mm):
    expected, margin = brute_force(pos, range_mm, RADIUS_MM, "block", np.ones(len(pos), bool))
    assume(margin > TIE_MM)
    g = communication_graph(pos, LinkModel(range_mm, "block"))
    assert set(g.nodes) == set(range(len(pos)))
    assert sorted(tuple(sorted(e)) for e in g.edges) == [(a, b) for a, b, *_ in expected]
    for a, b, dist, *_ in expected:
        assert math.isclose(g.edges[a, b]["distance_mm"], dist, rel_tol=1e-12)


def test_exact_cases():
    pos = np.array([[0.0, 0.0], [80.0, 0.0], [40.0, 16.4], [40.0, -16.5]])
    links = LinkModel(85.0, "block").links(pos)
    pairs = list(zip(links.i.tolist(), links.j.tolist(), strict=True))
    assert (0, 1) not in pairs  # robot 2's disc crosses the segment; robot 3's only touches
    assert pairs == [(0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    pos[2] = [40.0, 16.5]  # now both only touch the line
    links = LinkModel(85.0, "block").links(pos)
    assert (0, 1) in list(zip(links.i.tolist(), links.j.tolist(), strict=True))


def test_graded_occlusion_shortens_the_reach_and_loses_receptions_per_body():
    # Robots 0 and 3 are 120 mm apart with two bodies between them.
    pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0], [120.0, 0.0]])
    far = LinkModel(150.0, "graded", range_factor=0.9, loss_per_body=0.2).links(pos)
    got = {(a, b): (k, q) for a, b, k, q in zip(far.i, far.j, far.bodies, far.loss, strict=True)}
    assert got[(0, 3)] == (2, pytest.approx(1 - 0.8**2))  # 120 <= 150 * 0.81
    assert got[(0, 2)] == (1, pytest.approx(0.2)) and got[(0, 1)] == (0, 0.0)
    near = LinkModel(140.0, "graded", range_factor=0.85, loss_per_body=0.2).links(pos)
    pairs = set(zip(near.i.tolist(), near.j.tolist(), strict=True))
    assert (0, 3) not in pairs  # 120 > 140 * 0.85**2


def test_the_default_is_no_occlusion():
    pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    assert LinkModel(85.0).occlusion == "none"
    assert len(LinkModel(85.0).links(pos)) == 3


def test_absent_robots_neither_hear_nor_block():
    pos = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    links = LinkModel(85.0, "block").links(pos, np.array([True, False, True]))
    assert (links.i.tolist(), links.j.tolist(), links.distance_mm.tolist()) == ([0], [2], [80.0])
    assert len(LinkModel(85.0, "block").links(pos, np.array([True, False, False]))) == 0


def test_no_pairs_in_range():
    i, j, d = pairs_in_range(np.array([[0.0, 0.0], [200.0, 0.0]]), 85.0)
    assert len(i) == len(j) == len(d) == 0
    graph = communication_graph(np.array([[0.0, 0.0], [200.0, 0.0]]), LinkModel(85.0))
    assert nx.number_of_edges(graph) == 0
