"""Phase 2 of ``localize``: the frame starts at the root and spreads outward by
multilateration, with collinearity and flip (mirror) checks.

**Start.** The root is the origin. From its neighbours' NBR reports it knows which of its
neighbours hear each other and how far apart they are, so it chooses the frame's other two
robots itself (:func:`choose_frame`): an *axis* robot B and a *third* robot C that see each
other, form a triangle at least ``localize.min_height_mm`` high even when each of its three
distances is off by the ranging noise the root has measured (a nearly collinear triple, whose
height the noise makes up, would start the frame from a line and set its handedness by
chance), and share the most common neighbours with the root (each of those can place itself
from R, B and C at once). ROOT
messages name them. B places itself at ``(|RB|, 0)``; C, once it has heard B's position, at
``(x, +y)`` from ``|RC|``, ``|BC|`` and B's x (:func:`~kilonet.geometry.place_references`; the
positive root of y picks the frame's handedness). If B or C is not placed within
``localize.bootstrap_timeout_s`` the root names another pair without them; a B or C that
placed itself from the old naming after all (its position had not yet reached the root) gives
its position up when it hears the new one, so the frame never holds two axis robots.

**Spreading.** Every other robot, at each round, fixes its position from its neighbours that
have one (their announced positions, the distances both ends agree on):

1. *Three or more anchors*: least squares (:func:`~kilonet.geometry.multilaterate`), rejected
   if the anchors lie within ``localize.min_height_mm`` of one line (the anchors' positions
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
   with a systematic error on every link, the rule chose mirror images that folded sparse
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

Messages::

    ROOT (81)  sender:uint16  axis:uint16  third:uint16  flags:uint8             7 bytes
               the root, at (0, 0), hop 0; axis/third 0xFFFF while not chosen
    POS  (82)  sender:uint16  x:int16  y:int16 (0.1 mm)  hops:uint8  flags:uint8
               windings:uint8                                                    9 bytes
               every other robot; x, y are 0 while the LOCALIZED flag is clear
    CAND (84)  sender:uint16  x:int16  y:int16 (0.1 mm)  index:uint8  version:uint8
               windings:uint8                                                    9 bytes
               one of a robot's two candidates (index + FROM_LINE when they come from
               three or more anchors); the version changes with its anchors and after
               the candidates lapsed (never back to an earlier one)

x and y travel modulo 6,553.6 mm, with both winding numbers in ``windings``
(:func:`~kilonet.protocols.localize_base.wrapped_position`): a frame up to 49 m from its root fits.
    VOTE (86)  sender:uint16  target:uint16  index:uint8  version:uint8              6 bytes
               the candidate of ``target``'s pair (of that version) that is possible

``flags`` are :mod:`kilonet.protocols.localize.base`'s LOCALIZED, SETTLED, COMPLETE, DONE.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from kilonet.protocols.common.refinement import gauss_newton_step
from kilonet.protocols.localize.base import (
    LOCALIZED,
    MAX_COORDINATE_MM,
    NO_ID,
    SETTLED,
    Neighbour,
    absolute_position,
    wrapped_position,
)

from kilonet.geometry import (
    MIRROR_SIGMAS,
    Fix,
    GeometryError,
    circle_pair,
    collinear,
    multilaterate,
    place_references,
    robust_height,
)
from kilonet.message import Layout, Message

if TYPE_CHECKING:
    from kilonet.protocols.localize.program import LocalizeRobot

__all__ = [
    "CAND",
    "FROM_LINE",
    "POS",
    "ROOT",
    "VOTE",
    "Spread",
    "anchors_fresh",
    "candidate_version",
    "choose_frame",
    "circle_candidates",
    "consistent_subset_fix",
    "fix_with_candidates",
    "line_same_mm",
    "mirror_candidates",
    "overlap_vote",
    "robust_height",
]

ROOT = Layout(
    "root",
    type=81,
    fields=[("sender", "H"), ("axis", "H"), ("third", "H"), ("flags", "B")],
)
POS = Layout(
    "pos",
    type=82,
    fields=[
        ("sender", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("hops", "B"),
        ("flags", "B"),
        ("windings", "B"),
    ],
)
CAND = Layout(
    "cand",
    type=84,
    fields=[
        ("sender", "H"),
        ("x_mm", "h", 0.1),
        ("y_mm", "h", 0.1),
        ("index", "B"),
        ("version", "B"),
        ("windings", "B"),
    ],
)
VOTE = Layout(
    "vote",
    type=86,
    fields=[("sender", "H"), ("target", "H"), ("index", "B"), ("version", "B")],
)

Point = tuple[float, float]

#: CAND's ``index`` plus this: the candidates come from three or more anchors on (nearly) one
#: line, each within :func:`line_same_mm` of as far from both candidates (rule 2).
FROM_LINE = 2


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
    -1 for none), modulo 256 — never back to a number that named another pair's sides. Before,
    a robot whose candidates lapsed (a third anchor for a moment, one anchor gone stale) began
    again at 0, and votes cast for an earlier pair's version 0 chose a side of the new pair's
    line: the vote that folded a sparse swarm and a C (docs/localize.md, rule 4).

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
    rule 1 (:func:`~kilonet.geometry.multilaterate`'s, and :func:`side_is_clear`), and in
    which no anchor alone decides the side (the others, less any one, do not lie within
    ``min_width_mm`` of one line: an anchor off its distance beside three on one line would
    otherwise fit the mirror image), places the robot right relative to those anchors; its
    links to the others then carry the seam's stress into the refinement, which closes it
    (docs/localize.md, rule 1). Three anchors are not enough: they leave one distance to
    check the fit, and three anchors of a seam can meet near a wrong point within the
    residual bound (measured: subsets of three folded the sparse swarm of 400 robots with
    20 % loss, seed 1).

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

    :func:`~kilonet.geometry.multilaterate` rejects a fix whose mirror image fits within
    ``(sigmas · sigma_mm)²`` of its sum of squared residuals. That margin trusts the anchors'
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
    anchors (:func:`~kilonet.geometry.multilaterate`). The best fix that passes every check is
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


class Spread:
    """Phase 2 on one robot: the frame's start (root, axis, third) and rules 1-4.

    The robot's position (``robot.position``) lives on the robot; this holds the attempt
    bookkeeping, the robot's own candidates and, on the root, the frame robots it named.
    """

    name = "spread"

    def __init__(self, robot: LocalizeRobot) -> None:
        self.robot = robot
        p = robot.params
        tps = robot.ticks_per_s
        self.retry_ticks = p.retry_s * tps
        self.bootstrap_ticks = p.bootstrap_timeout_s * tps
        self.fresh_anchor_ticks = p.fresh_anchor_s * tps
        self.attempt: tuple = ()  # what the last attempt used
        self.next_retry = 0.0
        self.news_tick = robot.kilo_ticks  # last change of anchors or candidates
        # This robot's candidates: (version, [p0, p1]) or None, and the anchors they use.
        self.candidates: tuple[int, list[Point]] | None = None
        self.candidate_anchors: tuple[int, ...] | None = None
        self.candidate_version = -1  # the last version announced (-1: none yet)
        self.candidates_from_line = False  # from three or more anchors (CAND index + FROM_LINE)
        self.cand_turn = 0
        # The frame's start, as the root named it (on every robot that heard ROOT).
        self.axis = NO_ID
        self.third = NO_ID
        self.root_uid = NO_ID
        self.named_tick = 0.0
        self.excluded: set[int] = set()  # the root's frame robots that stayed silent
        self.frame_started = False  # on the root: its axis robot has placed itself
        # Rule 4: votes to send, (target, index, version); votes sent, by (target, version);
        # votes received for this robot's current candidates, {index: set of voters}.
        self.votes_out: list[tuple[int, int, int]] = []
        self.voted: dict[tuple[int, int], float] = {}
        self.votes_in: dict[int, set[int]] = {}

    # -- messages ------------------------------------------------------------------------------
    def message_tx(self) -> Message:
        """A VOTE if one is due; else ROOT on the root; otherwise CAND, CAND and POS in turn
        while holding candidates, else POS."""
        r = self.robot
        if self.votes_out:
            target, index, version = self.votes_out.pop()
            return VOTE.pack(sender=r.uid, target=target, index=index, version=version)
        if self.candidates is not None and r.position is None:
            self.cand_turn = (self.cand_turn + 1) % 3
            if self.cand_turn < 2:
                version, points = self.candidates
                x, y, windings = wrapped_position(*points[self.cand_turn])
                return CAND.pack(
                    sender=r.uid,
                    x_mm=x,
                    y_mm=y,
                    index=self.cand_turn + (FROM_LINE if self.candidates_from_line else 0),
                    version=version,
                    windings=windings,
                )
        return self.state_message()

    def state_message(self) -> Message:
        """ROOT on the root, else POS: position, hop count and flags."""
        r = self.robot
        if r.is_root:
            return ROOT.pack(sender=r.uid, axis=self.axis, third=self.third, flags=r.flags)
        x, y, windings = wrapped_position(*r.position) if r.position is not None else (0, 0, 0)
        return POS.pack(sender=r.uid, x_mm=x, y_mm=y, hops=r.hops, flags=r.flags, windings=windings)

    def root_rx(self, n: Neighbour, message: Message) -> None:
        m = ROOT.unpack(message)
        n.x_mm, n.y_mm, n.hops, n.flags = 0.0, 0.0, 0, m.flags | LOCALIZED
        n.placed_tick = -math.inf  # the origin by definition: never fresh
        r = self.robot
        named, renamed = (self.axis, self.third), (m.axis, m.third)
        if r.position is not None and r.uid in named and r.uid not in renamed:
            r.unlocate("renamed")  # the root started the frame without this robot
        self.root_uid, self.axis, self.third = m.sender, m.axis, m.third

    def pos_rx(self, n: Neighbour, message: Message) -> None:
        m = POS.unpack(message)
        n.hops, n.flags = m.hops, m.flags
        if m.flags & LOCALIZED:
            if n.x_mm is None:
                n.placed_tick = self.robot.kilo_ticks
            n.x_mm, n.y_mm = absolute_position(m.x_mm, m.y_mm, m.windings)
            n.candidates = None
        else:
            n.x_mm = n.y_mm = None
            n.placed_tick = None

    def cand_rx(self, n: Neighbour, message: Message) -> None:
        m = CAND.unpack(message)
        if n.candidates is None or n.candidates[0] != m.version:
            n.candidates = (m.version, [None, None])
        n.candidates_from_line = m.index >= FROM_LINE
        n.candidates[1][m.index % FROM_LINE] = absolute_position(m.x_mm, m.y_mm, m.windings)
        n.x_mm = n.y_mm = None
        n.placed_tick = None

    def vote_rx(self, n: Neighbour, message: Message) -> None:
        m = VOTE.unpack(message)
        if m.target != self.robot.uid:
            return
        # A vote is about one version of the candidates: an index means a side of one anchor
        # pair's line, and of another pair's it means nothing.
        if self.candidates is None or m.version != self.candidates[0]:
            return
        self.votes_in.setdefault(m.index, set()).add(m.sender)

    # -- rounds --------------------------------------------------------------------------------
    def round(self, tick: int, fresh: list[Neighbour]) -> None:
        """The root names its frame robots; the others try to fix their position."""
        r = self.robot
        if r.is_root:
            self._name_frame(tick, fresh)
        elif r.position is None:
            self._locate(tick, fresh)
        if r.position is not None:
            self._vote(tick, fresh)

    def _vote(self, tick: int, fresh: list[Neighbour]) -> None:
        """Rule 4: vote on the candidate pairs of neighbours (again after ``retry_s``)."""
        others = None
        for n in fresh:
            held = n.candidates
            if held is None or None in held[1] or n.x_mm is not None:
                continue
            key = (n.uid, held[0])
            if tick < self.voted.get(key, -1.0):
                continue
            self.voted[key] = tick + self.retry_ticks
            if others is None:
                others = [(m.x_mm, m.y_mm) for m in fresh if m.x_mm is not None]
                settled = [
                    (m.x_mm, m.y_mm) for m in fresh if m.x_mm is not None and m.flags & SETTLED
                ]
            p = self.robot.params
            index = overlap_vote(
                tuple(held[1]),
                others,
                p.overlap_mm,
                settled=settled,
                heard_mm=p.heard_mm,
                same_mm=line_same_mm(p.min_height_mm) if n.candidates_from_line else 5.0,
            )
            if index is not None:
                self.votes_out.append((n.uid, index, held[0]))

    def _name_frame(self, tick: int, fresh: list[Neighbour]) -> None:
        by_id = {n.uid: n for n in fresh}
        placed = [by_id.get(u) for u in (self.axis, self.third)]
        self.frame_started |= placed[0] is not None and placed[0].x_mm is not None
        if all(n is not None and n.x_mm is not None for n in placed):
            return
        if self.axis != NO_ID and tick - self.named_tick < self.bootstrap_ticks:
            return
        axis_placed = placed[0] is not None and placed[0].x_mm is not None
        if self.axis != NO_ID:  # the named robots did not all place themselves in time
            self.excluded.add(self.third)
            if not axis_placed:
                self.excluded.add(self.axis)
        usable = {n.uid: n.range_mm for n in fresh if n.uid not in self.excluded}
        reports = {u: self.robot.reports.get(u, {}) for u in usable}
        chosen = choose_frame(
            usable,
            reports,
            self.robot.params.min_height_mm,
            axis=self.axis if axis_placed else None,
            margin_mm=self.robot.sigma_mm,
        )
        if chosen is not None:
            self.axis, self.third = chosen
            self.named_tick = tick
            self.robot.log("frame_named", axis=self.axis, third=self.third)

    def _locate(self, tick: int, fresh: list[Neighbour]) -> None:
        r = self.robot
        uid = r.uid
        if uid == self.axis or uid == self.third:
            self._start_frame(fresh)
            if r.position is not None:
                return
        anchors = [n for n in fresh if n.x_mm is not None]
        if anchors_fresh([n.placed_tick for n in anchors], tick, self.fresh_anchor_ticks):
            self.news_tick = tick  # an anchor placed moments before is news: not quiet
            return
        pairs = [
            n
            for n in fresh
            if n.x_mm is None and n.candidates is not None and None not in n.candidates[1]
        ]
        attempt = (
            tuple(n.uid for n in anchors),
            tuple((n.uid, n.candidates[0]) for n in pairs),
        )
        if attempt != self.attempt:
            self.attempt = attempt
            self.news_tick = tick
        elif tick < self.next_retry:
            return
        self.next_retry = tick + self.retry_ticks
        points = [(n.x_mm, n.y_mm) for n in anchors]
        ranges = [n.range_mm for n in anchors]
        sigma = r.sigma_mm
        max_rmse = r.params.max_residual_sigmas * sigma
        side_in_doubt = False
        if len(anchors) >= 3:
            fix = multilaterate(
                np.array(points),
                np.array(ranges),
                sigma_mm=sigma,
                max_rmse_mm=max_rmse,
                min_anchor_width_mm=r.params.min_height_mm,
            )
            if fix.ok and side_is_clear(fix, sigma):
                self.place(fix.x_mm, fix.y_mm, "anchors", len(anchors), anchors)
                return
            if fix.reason == "large_residual":
                found = consistent_subset_fix(
                    points,
                    ranges,
                    sigma_mm=sigma,
                    max_rmse_mm=max_rmse,
                    min_width_mm=r.params.min_height_mm,
                )
                if found is not None:
                    fix, kept = found
                    used = [anchors[k] for k in kept]
                    dropped = [
                        [
                            n.uid,
                            round(
                                math.dist((fix.x_mm, fix.y_mm), (n.x_mm, n.y_mm)) - n.range_mm, 1
                            ),
                        ]
                        for k, n in enumerate(anchors)
                        if k not in kept
                    ]
                    self.place(fix.x_mm, fix.y_mm, "subset", len(used), used, dropped=dropped)
                    return
            # Anchors that fix all but the side (one line, or a mirror image that fits within
            # the noise): the two sides are candidates, as with two anchors. Not a fix whose
            # side only its large residuals put in doubt: its anchors disagree, and candidates
            # from them would be no better.
            side_in_doubt = fix.reason in ("collinear_anchors", "mirror_ambiguity")
        if pairs and r.params.max_candidate_neighbours:
            # The pairs farthest apart discriminate best.
            pairs.sort(key=lambda n: -_separation(n.candidates[1]))
            pairs = pairs[: r.params.max_candidate_neighbours]
            fix = fix_with_candidates(
                points,
                ranges,
                [tuple(n.candidates[1]) for n in pairs],
                [n.range_mm for n in pairs],
                sigma_mm=sigma,
                max_rmse_mm=max_rmse,
                min_width_mm=r.params.min_height_mm,
            )
            if fix is not None:
                self.place(fix.x_mm, fix.y_mm, "candidates", len(anchors) + len(pairs), anchors)
                return
        self._update_candidates(anchors, side_in_doubt)
        self._take_vote(anchors)

    def _take_vote(self, anchors: list[Neighbour]) -> None:
        """Rule 4: take the candidate the votes allow, if they allow exactly one."""
        if self.candidates is None:
            return
        allowed = [k for k in (0, 1) if self.votes_in.get(k)]
        if len(allowed) == 1:
            x, y = self.candidates[1][allowed[0]]
            self.place(x, y, "vote", len(anchors), anchors)

    def _start_frame(self, fresh: list[Neighbour]) -> None:
        """Place the axis robot on +x, or the third robot above it."""
        by_id = {n.uid: n for n in fresh}
        root = by_id.get(self.root_uid)
        if root is None:
            return
        r = self.robot
        if r.uid == self.axis:
            self.place(root.range_mm, 0.0, "axis", 1)
            return
        axis = by_id.get(self.axis)
        if axis is None or axis.x_mm is None:
            return
        try:
            _, (x, y) = place_references(axis.x_mm, root.range_mm, axis.range_mm)
        except GeometryError:
            return
        self.place(x, y, "third", 2)

    def _update_candidates(self, anchors: list[Neighbour], side_in_doubt: bool = False) -> None:
        """With exactly two anchors, or three or more that fix all but the side
        (``side_in_doubt``: rule 1 refused them as one line or for a mirror image that fits as
        well), hold (and announce) the two candidate positions (:func:`mirror_candidates`)."""
        found = None
        if len(anchors) == 2:
            a, b = anchors
            found = circle_candidates((a.x_mm, a.y_mm), (b.x_mm, b.y_mm), a.range_mm, b.range_mm)
            key = (a.uid, b.uid)
        elif side_in_doubt and len(anchors) >= 3:
            p = self.robot.params
            got = mirror_candidates(
                [(n.x_mm, n.y_mm) for n in anchors],
                [n.range_mm for n in anchors],
                max_rmse_mm=p.max_residual_sigmas * self.robot.sigma_mm,
                max_skew_mm=line_same_mm(p.min_height_mm),
            )
            if got is not None:
                found = got[:3]
                i, j = got[3]
                # The pair orients the indices: a new pair is a new version.
                key = (*(n.uid for n in anchors), anchors[i].uid, anchors[j].uid)
        if found is None or found[2] < self.robot.params.min_height_mm:
            self.candidates = None
            self.candidate_anchors = None
            return
        version = candidate_version(self.candidate_version, self.candidate_anchors, key)
        if version != self.candidate_version:
            self.votes_in = {}  # votes about other candidates
        self.candidate_version = version
        self.candidate_anchors = key
        self.candidates = (version, [found[0], found[1]])
        self.candidates_from_line = len(anchors) > 2

    def place(
        self,
        x_mm: float,
        y_mm: float,
        rule: str,
        anchors: int,
        references: Sequence[Neighbour] = (),
        **extra: object,
    ) -> None:
        """Take the position (x, y) in the frame, mm, found by ``rule`` from ``anchors``
        placed points; one beyond the messages' coordinate range is refused.

        The ``located`` event logs the rule, the count and ``references``: the placed
        neighbours the fix used, ``[uid, x_mm, y_mm]`` each as this robot held them (0.1 mm),
        so that a run's analysis can tell a wrong fix from a right fix on wrong anchors."""
        if abs(x_mm) > MAX_COORDINATE_MM or abs(y_mm) > MAX_COORDINATE_MM:
            self.robot.log("out_of_frame", x_mm=x_mm, y_mm=y_mm)
            return
        self.candidates = None
        self.robot.locate(x_mm, y_mm)
        held = [[n.uid, round(n.x_mm, 1), round(n.y_mm, 1)] for n in references]
        self.robot.log(
            "located", rule=rule, anchors=anchors, x_mm=x_mm, y_mm=y_mm, references=held, **extra
        )


def _separation(points: list[Point]) -> float:
    (x0, y0), (x1, y1) = points
    return math.hypot(x1 - x0, y1 - y0)
