"""The rules by which a ``localize`` robot fixes its position in the frame (phase 2,
:mod:`kilonet.protocols.localize.phase2_spread`), as pure functions of what the robot holds:
its placed neighbours' positions, its distances to them, its neighbours' candidate pairs and
its noise. None reads or changes a robot, so each is tested on numbers alone; the phase
(:class:`~kilonet.protocols.localize.phase2_spread.Spread`) gathers the inputs each round and
acts on the answers.

**Spreading.** Every other robot, at each round, fixes its position from its neighbours that
have one (their announced positions, the distances both ends agree on):

1. *Three or more anchors*: least squares
   (:func:`~kilonet.protocols.common.geometry.multilaterate`), rejected if the anchors lie within
   ``localize.min_height_mm`` of one line (the anchors' positions
   carry errors of their own, which the mirror test below does not see), the residuals are
   too large (``localize.max_residual_sigmas`` noise deviations), the geometry is poor, or the
   mirror image across the anchors' line fits nearly as well — the flip that a noisy
   near-collinear triple allows (Savvides et al. 2001; Moore et al. 2004). Anchors refused
   for their residuals may still place the robot from the largest subset of four or more of
   them that passes every check (:func:`consistent_subset_fix`, rule ``subset``): at a seam,
   where a frame grown round a gap meets itself, so that the refinement gets the links
   across it. A robot waits with a fix from exactly three anchors until each of them has
   been placed for ``localize.fresh_anchor_s`` (:func:`anchors_fresh`): an anchor placed
   moments before has not been refined against its own neighbours and may lie tens of
   millimetres off, which three anchors leave no residual to show, and a fix from it lands
   farther off still. With four or more the residuals tell.
2. *Two anchors*, or three or more that fix all but the side (refused by rule 1 as one line
   or for a mirror image that fits as well): two candidate positions, mirror images across
   the anchors' line (:func:`circle_candidates`, :func:`mirror_candidates`). The robot
   announces both (CAND messages) unless they lie closer than ``2 · min_height_mm``; their
   version (:func:`candidate_version`) names the anchors they come from, and changes
   whenever those do or the candidates lapse.
3. *Anchors and neighbours' candidates* (off unless ``localize.max_candidate_neighbours`` is
   set: a candidate from two anchors carries their errors magnified, and on kilolib's ranging,
   with a systematic error on every link, the rule chooses mirror images that fold sparse
   frames; docs/localize.md): a robot combines its anchors with the candidate pairs
   of up to ``localize.max_candidate_neighbours`` neighbours and tries every choice of one
   candidate each (:func:`fix_with_candidates`); a pair mirrored across (nearly) the robot's
   own anchor line tells the robot's two mirror positions apart no better than its anchors
   do, and is not used. It takes the fix only if exactly one choice
   passes every check of rule 1 and every choice placing it elsewhere fits worse by more than
   the mirror test's margin. Two robots that each see only two anchors thus place each other
   (and a robot next to three such robots places itself and then them): the sparse swarms
   where three anchors each are rare.

4. *Bodies do not overlap*: a located robot that hears a neighbour's candidate pair checks
   both candidates against the positions of its own located neighbours. A candidate closer
   than ``localize.overlap_mm`` to one of them would put two Kilobots (33 mm across) on top of
   each other, so it is impossible; when exactly one candidate is, the located robot sends a
   VOTE for the other (:func:`overlap_vote`), and a robot that holds votes for one of its
   current candidates (their version) and none for the other takes it. *Nor is a robot
   deaf*: a candidate closer than ``localize.heard_mm`` to a settled robot (other than the
   two anchors) is impossible too,
   since the robot there would hear it and hold three anchors. The mirror image of a robot at
   the frame's edge usually points back into the frame, among robots it does not hear. This
   breaks the mirror ambiguity of robots that only two anchors reach — at the swarm's edge,
   and where the frame has to squeeze through a gap — with the knowledge of robots two hops
   away.

A robot that fails retries when its anchors or candidates change, or every
``localize.retry_s``. Candidates come from anchors only, never from other candidates, so no
choice depends on itself.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from kilonet.protocols.common.geometry import (
    MIRROR_SIGMAS,
    Fix,
    circle_pair,
    collinear,
    multilaterate,
    robust_height,
)
from kilonet.protocols.common.refinement import gauss_newton_step

__all__ = [
    "Point",
    "anchors_fresh",
    "candidate_version",
    "choose_frame",
    "circle_candidates",
    "consistent_subset_fix",
    "fix_with_candidates",
    "line_same_mm",
    "mirror_candidates",
    "overlap_vote",
    "separation",
    "side_is_clear",
]

#: A point in the frame, (x, y) mm.
Point = tuple[float, float]


def choose_frame(
    ranges_mm: Mapping[int, float],
    reports: Mapping[int, Mapping[int, float]],
    min_height_mm: float,
    *,
    axis: int | None = None,
    margin_mm: float = 0.0,
) -> tuple[int, int] | None:
    """The root's axis and third robot, or None if no pair qualifies.

    Parameters
    ----------
    ranges_mm : mapping
        The root's distance to each neighbour, mm, by ID.
    reports : mapping
        ``reports[b][c]``: neighbour b's reported distance to c, mm.
    min_height_mm : float
        Least height of the third robot above the root–axis line.
    axis : int, optional
        The axis robot already placed: only a third robot is chosen.
    margin_mm : float
        How far each of the triangle's three distances may be off, mm: the triangle must be
        ``min_height_mm`` high at every corner of that box (:func:`robust_height`).

    Returns
    -------
    (axis, third) : IDs of two neighbours that see each other, whose triangle with the root is
    at least ``min_height_mm`` high, with the most other neighbours of the root adjacent to
    both (ties: the higher triangle, to 0.1 mm, then the smaller IDs).

    Examples
    --------
    Neighbours 1, 2, 3 of the root see each other; every pair has one common neighbour, and
    robot 3 stands 45 mm above the root–1 line, higher than any other third robot:

    >>> ranges = {1: 40.0, 2: 40.0, 3: 60.0}
    >>> reports = {1: {2: 40.0, 3: 45.0}, 2: {1: 40.0, 3: 45.0}, 3: {1: 45.0, 2: 45.0}}
    >>> choose_frame(ranges, reports, 10.0)
    (1, 3)
    >>> choose_frame(ranges, reports, 10.0, axis=3)
    (3, 1)
    >>> choose_frame(ranges, {1: {2: 80.0}}, 10.0) is None  # 1, root, 2 on one line
    True

    Measured 1.2 mm short, that line looks like a triangle 13.6 mm high; with a margin of 1.5 mm
    it is seen for what it is:

    >>> choose_frame({1: 40.0, 2: 40.0}, {1: {2: 78.8}}, 10.0)
    (1, 2)
    >>> choose_frame({1: 40.0, 2: 40.0}, {1: {2: 78.8}}, 10.0, margin_mm=1.5) is None
    True
    """
    adjacent: dict[int, set[int]] = {u: set() for u in ranges_mm}
    lengths: dict[tuple[int, int], list[float]] = {}
    for b, row in reports.items():
        for c, d in row.items():
            if b in adjacent and c in adjacent and b != c:
                adjacent[b].add(c)
                adjacent[c].add(b)
                lengths.setdefault((min(b, c), max(b, c)), []).append(d)
    best: tuple | None = None
    for (low, high), ds in sorted(lengths.items()):
        d_bc = sum(ds) / len(ds)
        orders = [(low, high), (high, low)] if axis is None else [(axis, low + high - axis)]
        for b, c in orders:
            if axis is not None and axis not in (low, high):
                continue
            height = robust_height(ranges_mm[b], ranges_mm[c], d_bc, margin_mm)
            if height < min_height_mm:
                continue
            score = (len(adjacent[b] & adjacent[c]), round(height, 1), -b, -c)
            if best is None or score > best[0]:
                best = (score, b, c)
    return None if best is None else (best[1], best[2])


def circle_candidates(
    a: Point, b: Point, range_a_mm: float, range_b_mm: float
) -> tuple[Point, Point, float] | None:
    """The two points at ``range_a_mm`` from ``a`` and ``range_b_mm`` from ``b``: mirror
    images across the line ab, and their distance from it (mm). None if the anchors coincide
    or the ranges form no triangle with them.

    Examples
    --------
    >>> p, q, h = circle_candidates((0.0, 0.0), (40.0, 0.0), 50.0, 30.0)
    >>> [round(v, 9) for v in (*p, *q, h)]
    [40.0, 30.0, 40.0, -30.0, 30.0]
    """
    return circle_pair(a, range_a_mm, b, range_b_mm, tolerance_mm=0.5)


def anchors_fresh(placed_ticks: Sequence[float | None], tick: float, fresh_ticks: float) -> bool:
    """Rule 1's patience: True when a fix must wait because it has exactly three anchors and
    one of them was heard placed less than ``fresh_ticks`` before ``tick`` (None: its
    placement not yet heard). Ticks are the robot's own clock (``kilo_ticks``).

    Examples
    --------
    >>> anchors_fresh([100, 200, 250], tick=300, fresh_ticks=31)
    False
    >>> anchors_fresh([100, 200, 290], tick=300, fresh_ticks=31)
    True
    >>> anchors_fresh([100, 200, 290, 295], tick=300, fresh_ticks=31)  # four: residuals tell
    False
    """
    return len(placed_ticks) == 3 and any(t is None or tick - t < fresh_ticks for t in placed_ticks)


def candidate_version(
    last_version: int, held_pair: tuple[int, ...] | None, pair: tuple[int, ...]
) -> int:
    """The version a robot announces its candidate pair with (CAND's ``version``), and rule 4's
    votes name.

    A vote's index means a side of one anchor pair's line: index 0 lies left of the line from
    the first anchor to the second (:func:`circle_candidates`). So the version stays
    ``last_version`` only while the robot holds candidates from the same ordered ``pair``
    without a break (``held_pair``: the pair of the candidates it holds now, None when it holds
    none), and otherwise moves on from the last version it ever announced (``last_version``,
    -1 for none), modulo 256 — never back to a number that named another pair's sides: a
    robot whose candidates lapse (a third anchor for a moment, one anchor gone stale) and
    come back from another pair must not take votes cast for the earlier pair's version,
    which choose a side of another line (docs/localize.md, rule 4).

    Examples
    --------
    >>> candidate_version(-1, None, (7, 9))  # the first candidates
    0
    >>> candidate_version(0, (7, 9), (7, 9))  # the same pair, held throughout
    0
    >>> candidate_version(0, (7, 9), (7, 4)), candidate_version(0, None, (7, 9))
    (1, 1)
    >>> candidate_version(255, (7, 9), (9, 7))
    0
    """
    if held_pair is not None and pair == held_pair:
        return last_version
    return (last_version + 1) % 256


def consistent_subset_fix(
    anchors: Sequence[Point],
    ranges_mm: Sequence[float],
    *,
    sigma_mm: float,
    max_rmse_mm: float,
    min_width_mm: float,
    min_anchors: int = 4,
    max_fits: int = 64,
) -> tuple[Fix, tuple[int, ...]] | None:
    """Rule 1's fix from the largest subset of the anchors that agree, when all of them do not.

    Where a frame grown round a gap meets itself, the two sides disagree by tens of
    millimetres (each grew from anchors not yet refined), and a robot at the seam holds anchors
    of both: no point fits them all, rule 1 refuses the fix for its residuals, and without the
    robots of the seam no link ties the two sides together, so the refinement cannot pull them
    into one frame. A subset of at least ``min_anchors`` anchors that does pass every check of
    rule 1 (:func:`~kilonet.protocols.common.geometry.multilaterate`'s, and :func:`side_is_clear`),
    and in which no anchor alone decides the side (the others, less any one, do not lie within
    ``min_width_mm`` of one line: an anchor off its distance beside three on one line would
    otherwise fit the mirror image), places the robot right relative to those anchors; its
    links to the others then carry the seam's stress into the refinement, which closes it
    (docs/localize.md, rule 1). Three anchors are not enough: they leave one distance to
    check the fit, and three anchors of a seam can meet near a wrong point within the
    residual bound.

    Subsets are tried from the largest (one anchor left out) down to ``min_anchors``, at most
    ``max_fits`` multilaterations in all; of the largest size with a passing fix, the one of
    least residual RMS is returned with the indices of its anchors (ascending). None when no
    subset passes (always with fewer than ``min_anchors + 1`` anchors).

    Parameters
    ----------
    anchors : sequence of (x, y)
        The placed neighbours' positions, mm.
    ranges_mm : sequence of float
        The distances to them, mm.
    sigma_mm : float
        The robot's ranging noise, mm (the checks' scale).
    max_rmse_mm : float
        Largest residual RMS a fix may have, mm.
    min_width_mm : float
        Anchors within this distance of one line are refused, mm.
    min_anchors : int
        Fewest anchors a subset may keep.
    max_fits : int
        Multilaterations allowed (the robot's budget per attempt).

    Examples
    --------
    The truth is (30, 20); anchors 0-3 are where they should be, anchor 4 stands 30 mm from
    where its distance puts it (the far side of a seam):

    >>> anchors = [(0.0, 0.0), (60.0, 0.0), (10.0, 60.0), (-20.0, 50.0), (80.0, 50.0)]
    >>> ranges = [math.dist((30.0, 20.0), a) for a in anchors]
    >>> ranges[4] += 30.0
    >>> multilaterate(np.array(anchors), np.array(ranges), sigma_mm=2.0, max_rmse_mm=8.0,
    ...               min_anchor_width_mm=10.0).reason
    'large_residual'
    >>> fix, kept = consistent_subset_fix(anchors, ranges, sigma_mm=2.0, max_rmse_mm=8.0,
    ...                                   min_width_mm=10.0)
    >>> round(fix.x_mm, 6), round(fix.y_mm, 6), kept
    (30.0, 20.0, (0, 1, 2, 3))
    >>> consistent_subset_fix(anchors[1:], ranges[1:], sigma_mm=2.0, max_rmse_mm=8.0,
    ...                       min_width_mm=10.0) is None  # three agree: not enough
    True
    """
    k = len(anchors)
    points = np.asarray(anchors, dtype=float)
    ranges = np.asarray(ranges_mm, dtype=float)
    fits = 0
    for size in range(k - 1, max(min_anchors, 3) - 1, -1):
        best: tuple[Fix, tuple[int, ...]] | None = None
        for subset in itertools.combinations(range(k), size):
            if fits >= max_fits:
                return best
            fits += 1
            index = list(subset)
            fix = multilaterate(
                points[index],
                ranges[index],
                sigma_mm=sigma_mm,
                max_rmse_mm=max_rmse_mm,
                min_anchor_width_mm=min_width_mm,
            )
            good = (
                fix.ok
                and side_is_clear(fix, sigma_mm)
                and _every_anchor_checked(points[index], min_width_mm)
            )
            if good and (best is None or fix.rmse_mm < best[0].rmse_mm):
                best = (fix, subset)
        if best is not None:
            return best
    return None


def line_same_mm(min_height_mm: float) -> float:
    """How much nearer one of a robot's two candidates may be to one of its anchors than the
    other is, when the candidates come from three or more anchors (mm): rule 2 announces them
    only within it, and rule 4's hearing test then treats any settled robot within it as one
    of the anchors. Two anchors lie on the candidates' mirror line, exactly as far from both;
    an anchor ``min_height_mm`` off that line is up to twice that nearer one, and 5 mm more
    allows for the fits' residuals.

    >>> line_same_mm(10.0)
    25.0
    """
    return 2.0 * min_height_mm + 5.0


def _every_anchor_checked(points: np.ndarray, min_width_mm: float) -> bool:
    """Whether the anchors less any one of them still span more than one line: no single
    anchor decides the side (an anchor off its distance, the others on one line, would)."""
    return not any(
        collinear(np.delete(points, k, axis=0), min_width_mm=min_width_mm)
        for k in range(len(points))
    )


def mirror_candidates(
    anchors: Sequence[Point],
    ranges_mm: Sequence[float],
    *,
    max_rmse_mm: float = math.inf,
    max_skew_mm: float = math.inf,
    iterations: int = 20,
) -> tuple[Point, Point, float, tuple[int, int]] | None:
    """Rule 2's two candidates from three or more anchors that leave the side in doubt.

    Anchors nearly on one line (or whose fit's mirror image fits about as well) fix a robot's
    distance from their line but not its side, as two anchors do. The candidates are the
    least-squares fits on either side: each of the two circle intersections of the two anchors
    farthest apart (``pair``, indices ``i < j``), refined by Gauss–Newton steps
    (:func:`~kilonet.protocols.common.refinement.gauss_newton_step`, no down-weighting) against
    every anchor. Index 0 lies left of the line from anchor ``i`` to anchor ``j``, as
    :func:`circle_candidates` orders two anchors' candidates.

    Returns
    -------
    (p0, p1, height, pair) : the candidates (mm), the smaller of their distances from the line
    through the pair (mm), and the pair's indices; None if the pair's circles do not meet, the
    refined candidates no longer lie on opposite sides of that line, either fits the anchors
    with a residual RMS above ``max_rmse_mm`` (rule 1's bound: anchors that disagree give no
    candidates worth a vote), or an anchor is nearer one candidate than the other by more than
    ``max_skew_mm`` (rule 4's voters could not tell it from a robot the candidate's holder
    does not hear: :func:`line_same_mm`).

    Examples
    --------
    Three anchors on the x axis, the truth at (30, 40):

    >>> anchors = [(0.0, 0.0), (45.0, 0.0), (60.0, 0.0)]
    >>> ranges = [math.dist((30.0, 40.0), a) for a in anchors]
    >>> p0, p1, height, pair = mirror_candidates(anchors, ranges)
    >>> [round(v, 6) for v in (*p0, *p1, height)], pair
    ([30.0, 40.0, 30.0, -40.0, 40.0], (0, 2))
    """
    k = len(anchors)
    if k < 2:
        return None
    i, j = max(
        itertools.combinations(range(k), 2),
        key=lambda ij: math.dist(anchors[ij[0]], anchors[ij[1]]),
    )
    found = circle_candidates(anchors[i], anchors[j], ranges_mm[i], ranges_mm[j])
    if found is None:
        return None
    links = [(a[0], a[1], r) for a, r in zip(anchors, ranges_mm, strict=True)]
    refined = []
    for x, y in found[:2]:
        for _ in range(iterations):
            x, y, _ = gauss_newton_step(x, y, links, huber_mm=math.inf, max_step_mm=math.inf)
        rms = math.sqrt(
            sum((math.dist((x, y), a) - r) ** 2 for a, r in zip(anchors, ranges_mm, strict=True))
            / k
        )
        if rms > max_rmse_mm:
            return None
        refined.append((x, y))
    (ax, ay), (bx, by) = anchors[i], anchors[j]
    length = math.dist(anchors[i], anchors[j])
    side = [((bx - ax) * (y - ay) - (by - ay) * (x - ax)) / length for x, y in refined]
    if not (side[0] > 0.0 > side[1]):
        return None
    p0, p1 = refined
    if any(abs(math.dist(p0, a) - math.dist(p1, a)) > max_skew_mm for a in anchors):
        return None
    return p0, p1, min(side[0], -side[1]), (i, j)


def side_is_clear(fix: Fix, sigma_mm: float, *, sigmas: float = MIRROR_SIGMAS) -> bool:
    """Whether a fix's side of its anchors' line is beyond doubt, on the fix's own evidence.

    :func:`~kilonet.protocols.common.geometry.multilaterate` rejects a fix whose mirror image fits
    within ``(sigmas · sigma_mm)²`` of its sum of squared residuals. That margin trusts the anchors'
    positions to the ranging noise; but residuals larger than the noise say the anchors are
    off by more (positions not yet refined, kilolib's per-link errors on long links), and
    the mirror fit's excess is then no better evidence than the residuals themselves. So the
    margin here scales with the larger of ``sigma_mm`` and the fix's residual RMS
    (``fix.rmse_mm``), mm. A fix without a distinct mirror fit is clear.

    Examples
    --------
    Three anchors whose best fit leaves 5.5 mm of residual RMS and whose mirror fit 7.0 mm: by
    the noise alone (σ = 2.2 mm) the side looks certain, by the residuals not:

    >>> from dataclasses import replace
    >>> fix = Fix(0.0, 0.0, 5.5, 1.2, 7.0, 3, True, "")
    >>> side_is_clear(fix, 2.2), side_is_clear(replace(fix, rmse_mm=1.0, mirror_rmse_mm=6.0), 2.2)
    (False, True)
    """
    if not math.isfinite(fix.mirror_rmse_mm):
        return True
    scale = max(sigma_mm, fix.rmse_mm)
    excess = fix.anchors * (fix.mirror_rmse_mm**2 - fix.rmse_mm**2)
    return excess >= (sigmas * scale) ** 2


def fix_with_candidates(
    anchors: Sequence[Point],
    ranges_mm: Sequence[float],
    candidates: Sequence[tuple[Point, Point]],
    candidate_ranges_mm: Sequence[float],
    *,
    sigma_mm: float,
    max_rmse_mm: float,
    min_width_mm: float,
) -> Fix | None:
    """A fix from anchors and neighbours' candidate pairs, if exactly one choice fits.

    When the anchors lie within ``min_width_mm`` of one line (two anchors always do), the
    robot's own mirror ambiguity is the reflection across that line, and a pair that this
    reflection maps onto itself (within ``min_width_mm``) cannot resolve it: such pairs are
    dropped. Every choice of one candidate per remaining pair is then multilaterated with the
    anchors (:func:`~kilonet.protocols.common.geometry.multilaterate`). The best fix that passes
    every check is
    returned when every choice that puts the robot more than ``3 · sigma_mm`` away from it has
    a sum of squared residuals larger by more than ``(3 · sigma_mm)²``; otherwise (or with
    fewer than three points, or if any choice is degenerate, so its fit cannot be compared)
    None.

    Examples
    --------
    The truth is (30, 20), with two anchors on the x axis; a neighbour at (50, 60) placed by
    two other anchors on the line x = 60 holds its position and the mirror image across that
    line, (70, 60):

    >>> truth = np.array([30.0, 20.0])
    >>> anchors = [(0.0, 0.0), (60.0, 0.0)]
    >>> pair = ((50.0, 60.0), (70.0, 60.0))
    >>> r = [float(np.hypot(*(truth - p))) for p in (*anchors, pair[0])]
    >>> fix = fix_with_candidates(anchors, r[:2], [pair], r[2:], sigma_mm=1.0, max_rmse_mm=4.0,
    ...                           min_width_mm=10.0)
    >>> round(fix.x_mm, 6), round(fix.y_mm, 6)
    (30.0, 20.0)

    Had the neighbour been placed by the same two anchors, its candidates would be mirror
    images across the robot's own mirror line: no choice.

    >>> fix_with_candidates(anchors, r[:2], [((50.0, 60.0), (50.0, -60.0))], r[2:],
    ...                     sigma_mm=1.0, max_rmse_mm=4.0, min_width_mm=10.0) is None
    True
    """
    line = _line_through(anchors)
    if line is not None and line[2] < min_width_mm:
        kept = [
            (pair, r)
            for pair, r in zip(candidates, candidate_ranges_mm, strict=True)
            if math.dist(_reflect(pair[0], line), pair[1]) >= min_width_mm
        ]
        candidates = [pair for pair, _ in kept]
        candidate_ranges_mm = [r for _, r in kept]
    if not candidates or len(anchors) + len(candidates) < 3:
        return None
    fits = []
    for choice in itertools.product((0, 1), repeat=len(candidates)):
        points = [*anchors, *(pair[k] for pair, k in zip(candidates, choice, strict=True))]
        fix = multilaterate(
            np.array(points),
            np.array([*ranges_mm, *candidate_ranges_mm]),
            sigma_mm=sigma_mm,
            max_rmse_mm=max_rmse_mm,
        )
        if math.isnan(fix.x_mm):
            return None
        fits.append((fix.rmse_mm**2 * fix.anchors, fix))
    good = [(ssr, fix) for ssr, fix in fits if fix.ok]
    if not good:
        return None
    best_ssr, best = min(good, key=lambda t: t[0])
    margin = (MIRROR_SIGMAS * sigma_mm) ** 2
    for ssr, fix in fits:
        apart = math.hypot(fix.x_mm - best.x_mm, fix.y_mm - best.y_mm)
        if apart > MIRROR_SIGMAS * sigma_mm and ssr - best_ssr <= margin:
            return None
    return best


def _line_through(points: Sequence[Point]) -> tuple[Point, Point, float] | None:
    """The total-least-squares line of two or more points: (centre, unit normal, the largest
    distance of a point from it); None for fewer than two points."""
    if len(points) < 2:
        return None
    cx = sum(p[0] for p in points) / len(points)
    cy = sum(p[1] for p in points) / len(points)
    sxx = sum((p[0] - cx) ** 2 for p in points)
    syy = sum((p[1] - cy) ** 2 for p in points)
    sxy = sum((p[0] - cx) * (p[1] - cy) for p in points)
    angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # direction of largest spread
    nx, ny = -math.sin(angle), math.cos(angle)
    width = max(abs((p[0] - cx) * nx + (p[1] - cy) * ny) for p in points)
    return (cx, cy), (nx, ny), width


def _reflect(p: Point, line: tuple[Point, Point, float]) -> Point:
    (cx, cy), (nx, ny), _ = line
    d = (p[0] - cx) * nx + (p[1] - cy) * ny
    return p[0] - 2.0 * d * nx, p[1] - 2.0 * d * ny


def overlap_vote(
    candidates: tuple[Point, Point],
    others: Sequence[Point],
    overlap_mm: float,
    *,
    settled: Sequence[Point] = (),
    heard_mm: float = 0.0,
    same_mm: float = 5.0,
) -> int | None:
    """The index of the only possible candidate, or None when both or neither are.

    A candidate is impossible when it lies closer than ``overlap_mm`` to a robot in
    ``others`` (two bodies in one place), or closer than ``heard_mm`` to a robot in
    ``settled`` that is not about as far (within ``same_mm``) from both candidates: a robot
    there would hear that placed robot and hold three anchors, not two candidates. The
    candidates' own two anchors lie on their mirror line, as far from both, and never count;
    ``settled`` robots have held their positions long enough for every robot near them to
    have heard them.

    Examples
    --------
    >>> overlap_vote(((0.0, 40.0), (0.0, -40.0)), [(5.0, -30.0), (80.0, 0.0)], 28.0)
    0
    >>> overlap_vote(((0.0, 40.0), (0.0, -40.0)), [(80.0, 0.0)], 28.0) is None
    True

    A settled robot 50 mm from the second candidate, which the candidates' holder would hear
    there (the anchors at (±30, 0) are as far from both and tell nothing):

    >>> anchors = [(-30.0, 0.0), (30.0, 0.0)]
    >>> overlap_vote(((0.0, 40.0), (0.0, -40.0)), anchors, 28.0,
    ...              settled=[*anchors, (30.0, -80.0)], heard_mm=55.0)
    0
    """
    clash = [
        any(math.hypot(cx - x, cy - y) < overlap_mm for x, y in others) for cx, cy in candidates
    ]
    if heard_mm > 0.0:
        (ax, ay), (bx, by) = candidates
        for x, y in settled:
            da, db = math.hypot(ax - x, ay - y), math.hypot(bx - x, by - y)
            if abs(da - db) >= same_mm:
                clash[0] |= da < heard_mm
                clash[1] |= db < heard_mm
    if clash[0] == clash[1]:
        return None
    return 1 if clash[0] else 0


def separation(points: Sequence[Point]) -> float:
    """How far apart a candidate pair's two points lie, mm: rule 3 tries the pairs farthest
    apart first, as they tell the choices apart best.

    >>> separation([(0.0, 0.0), (30.0, 40.0)])
    50.0
    """
    (x0, y0), (x1, y1) = points
    return math.hypot(x1 - x0, y1 - y0)
