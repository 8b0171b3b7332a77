"""The spread's rules (kilonet.protocols.localize.spread_rules) as pure functions: they read
no robot, and their edge cases hold on numbers alone."""

from __future__ import annotations

import ast
import inspect
import math
from pathlib import Path

from kilonet.protocols.common.geometry import Fix
from kilonet.protocols.localize import phase2_spread, spread_rules
from kilonet.protocols.localize.spread_rules import (
    anchors_fresh,
    candidate_version,
    choose_frame,
    circle_candidates,
    consistent_subset_fix,
    fix_with_candidates,
    line_same_mm,
    mirror_candidates,
    overlap_vote,
    separation,
    side_is_clear,
)


def test_the_rules_module_imports_no_robot_and_no_message():
    tree = ast.parse(Path(inspect.getfile(spread_rules)).read_text())
    imported = {
        node.module
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and node.level == 0
    }
    imported |= {
        alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.Import)
        for alias in node.names
    }
    assert imported == {
        "__future__",
        "collections.abc",
        "itertools",
        "math",
        "numpy",
        "kilonet.protocols.common.geometry",
        "kilonet.protocols.common.refinement",
    }


def test_every_public_rule_is_a_plain_function():
    for name in spread_rules.__all__:
        if name == "Point":
            continue
        assert inspect.isfunction(getattr(spread_rules, name)), name


def test_the_phase_uses_the_rules_module_and_keeps_no_geometry_of_its_own():
    functions = [
        node.name
        for node in ast.parse(Path(inspect.getfile(phase2_spread)).read_text()).body
        if isinstance(node, ast.FunctionDef)
    ]
    assert functions == []
    assert phase2_spread.choose_frame is spread_rules.choose_frame


def test_separation_is_the_distance_between_the_pair():
    assert separation([(1.0, 1.0), (4.0, 5.0)]) == 5.0
    assert separation([(2.0, 2.0), (2.0, 2.0)]) == 0.0


def test_anchors_fresh_waits_for_an_unheard_placement_and_only_with_three():
    assert anchors_fresh([100, None, 250], tick=300, fresh_ticks=31)
    assert not anchors_fresh([None, None], tick=300, fresh_ticks=31)  # two: no fix to wait on
    assert not anchors_fresh([100, 200, 269], tick=300, fresh_ticks=31)  # exactly old enough


def test_candidate_version_moves_on_and_wraps():
    assert candidate_version(5, (1, 2), (1, 2)) == 5
    assert candidate_version(5, (1, 2), (2, 1)) == 6  # the order names the sides
    assert candidate_version(255, None, (1, 2)) == 0


def test_choose_frame_needs_reports_between_neighbours_of_the_root():
    ranges = {1: 40.0, 2: 40.0}
    assert choose_frame(ranges, {}, 10.0) is None
    assert choose_frame(ranges, {1: {9: 40.0}}, 10.0) is None  # 9 is no neighbour of the root
    assert choose_frame(ranges, {1: {2: 40.0}}, 10.0, axis=5) is None  # the axis is not in it


def test_circle_candidates_none_when_the_circles_miss_or_anchors_coincide():
    assert circle_candidates((0.0, 0.0), (100.0, 0.0), 30.0, 30.0) is None
    assert circle_candidates((0.0, 0.0), (0.0, 0.0), 30.0, 30.0) is None


def test_mirror_candidates_needs_two_anchors_and_agreeing_residuals():
    assert mirror_candidates([(0.0, 0.0)], [10.0]) is None
    anchors = [(0.0, 0.0), (45.0, 0.0), (60.0, 0.0)]
    ranges = [math.dist((30.0, 40.0), a) for a in anchors]
    ranges[1] += 20.0
    assert mirror_candidates(anchors, ranges, max_rmse_mm=2.0) is None


def test_consistent_subset_fix_keeps_to_its_budget():
    anchors = [(0.0, 0.0), (60.0, 0.0), (10.0, 60.0), (-20.0, 50.0), (80.0, 50.0)]
    ranges = [math.dist((30.0, 20.0), a) for a in anchors]
    ranges[4] += 30.0
    kwargs = {"sigma_mm": 2.0, "max_rmse_mm": 8.0, "min_width_mm": 10.0}
    assert consistent_subset_fix(anchors, ranges, max_fits=0, **kwargs) is None
    _, kept = consistent_subset_fix(anchors, ranges, max_fits=1, **kwargs)
    assert kept == (0, 1, 2, 3)  # the first subset tried
    assert consistent_subset_fix(anchors[:4], ranges[:4], **kwargs) is None  # no subset of four


def test_fix_with_candidates_needs_a_pair_and_three_points():
    kwargs = {"sigma_mm": 1.0, "max_rmse_mm": 4.0, "min_width_mm": 10.0}
    assert fix_with_candidates([(0.0, 0.0), (60.0, 0.0)], [36.0, 36.0], [], [], **kwargs) is None
    pair = ((50.0, 60.0), (70.0, 60.0))
    assert fix_with_candidates([(0.0, 0.0)], [36.0], [pair], [40.0], **kwargs) is None


def test_overlap_vote_none_when_both_candidates_clash():
    candidates = ((0.0, 40.0), (0.0, -40.0))
    assert overlap_vote(candidates, [(0.0, 35.0), (0.0, -35.0)], 28.0) is None
    assert overlap_vote(candidates, [(0.0, 35.0)], 28.0) == 1


def test_side_is_clear_without_a_mirror_fit_and_line_same_mm():
    assert side_is_clear(Fix(0.0, 0.0, 9.0, 1.0, math.inf, 3, True, ""), 1.0)
    assert line_same_mm(0.0) == 5.0
