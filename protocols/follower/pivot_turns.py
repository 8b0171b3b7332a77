"""Pivot turns of a Kilobot as a program sees them: where a turn leaves the centre, which turn
aims the robot at a point, and what a turn seen between two step directions says about the
frame's handedness and the robot's real turn rate.

A Kilobot turning on one motor pivots about its rear leg on the side it turns to
(:data:`PIVOT_LEG_MM`: 16.5 mm from the centre at 125.5° from the heading, Kilombo from the PCB
design files), so the centre swings on an arc about that leg: a turn of τ moves it by
2 × 16.5 × sin(τ/2) mm, up to 33 mm for a half turn. Close to a goal that swing is larger than
the step after it, so a program that aims by turning toward the goal and stepping misses;
:func:`best_pivot_move` picks the turn and step expected to end nearest it.

Everything here is in the follower's frame (mm, radians, counter-clockwise positive), which may
be a mirror image of the floor: a frame turn τ always pivots about the leg on the side of τ
(a physical left turn in a mirrored frame is a frame right turn about the frame's right leg),
so the caller only maps physical turns to frame turns.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from kilonet.protocols.common.geometry import rotate, wrap_angle

__all__ = [
    "PIVOT_LEG_MM",
    "PivotMove",
    "best_pivot_move",
    "handedness_vote",
    "pivot_displacement",
    "segment_blocked",
    "swing_arc",
    "swing_turn_rad",
    "swing_vote",
    "turn_rate_ratio",
]

Point = tuple[float, float]

#: The Kilobot's left rear leg in its body frame (forward, left), mm: 16.5 mm out at 125.5° from
#: the heading (Kilombo, from the PCB design files). A one-motor turn pivots about the rear leg
#: on the side it turns to, which a program has to know to aim (:func:`pivot_displacement`).
PIVOT_LEG_MM = (16.5 * math.cos(math.radians(125.5)), 16.5 * math.sin(math.radians(125.5)))


def pivot_displacement(heading: Point, turn_rad: float, leg_mm: Point | None = None) -> Point:
    """How far a turn moves the robot's centre, in the frame's axes (mm).

    A Kilobot turning on one motor pivots about its rear leg on the side it turns to
    (:data:`PIVOT_LEG_MM`), so its centre swings round that leg. Seen in a frame, mirrored or
    not, the robot turns ``turn_rad`` about the leg on the side it turns toward: a physical
    left turn in a mirrored frame is a frame right turn about the frame's right-hand leg.

    Parameters
    ----------
    heading : (float, float)
        Unit heading before the turn, frame axes.
    turn_rad : float
        The turn as the frame sees it (counter-clockwise positive).
    leg_mm : (float, float), optional
        The left rear leg in the body frame (forward, left), mm; default the Kilobot's.

    Examples
    --------
    A quarter turn left, heading along +x, about a leg 10 mm back and 10 mm left:

    >>> [round(c, 9) for c in pivot_displacement((1.0, 0.0), math.pi / 2, (-10.0, 10.0))]
    [0.0, 20.0]
    >>> pivot_displacement((1.0, 0.0), 0.0)
    (0.0, 0.0)
    """
    if turn_rad == 0:
        return (0.0, 0.0)
    forward, left = leg_mm or PIVOT_LEG_MM
    side = 1.0 if turn_rad > 0 else -1.0
    ux, uy = heading
    ox, oy = forward * ux - side * left * uy, forward * uy + side * left * ux
    rx, ry = rotate((ox, oy), turn_rad)
    return (ox - rx, oy - ry)


#: Room the planner keeps between a swing and another body, mm (beyond ``radius_mm``): a
#: turn's real rate and the heading are a few per cent and degrees off, so the real arc
#: strays a few mm from the planned one, and a swing that touches a body slides along it.
SWING_MARGIN_MM = 3.0


def swing_arc(
    position: Point, heading: Point, turn_rad: float, leg_mm: Point = PIVOT_LEG_MM
) -> list[Point]:
    """Points along the arc a turn swings the centre on, every 30° or less, the end included
    (the arc strays under 0.6 mm from their chords), frame mm. A half turn to the left carries
    the centre up to 30 mm to the left:

    >>> [tuple(round(c, 1) for c in p) for p in swing_arc((0.0, 0.0), (1.0, 0.0), math.pi)]
    [(0.0, 0.0), (5.4, 6.6), (6.8, 15.0), (3.9, 23.0), (-2.7, 28.4), (-11.2, 29.9), (-19.2, 26.9)]
    """
    n = max(1, math.ceil(abs(turn_rad) / math.radians(30.0)))
    return [
        (
            position[0] + pivot_displacement(heading, turn_rad * k / n, leg_mm)[0],
            position[1] + pivot_displacement(heading, turn_rad * k / n, leg_mm)[1],
        )
        for k in range(n + 1)
    ]


class PivotMove(NamedTuple):
    """A move as the planner sees it: a frame turn, then a straight step.

    Attributes
    ----------
    turn_rad : float
        Frame turn, counter-clockwise positive (0: none).
    start : (float, float)
        Where the turn leaves the centre, frame mm.
    step_mm : float
        The straight step after it, mm (0: the turn alone).
    cost_mm : float
        The cost of the plan the move begins, mm: how far from the aim it is expected to end
        (the planned miss and the spread that turn and heading errors give it), plus what its
        turns and moves cost.
    final : bool
        Whether the move is the whole plan; else it is the first of two, and the caller should
        make the second (a one-move plan from where it ends) rather than plan two again: a
        first move re-planned every time can keep the robot stepping round the aim.
    """

    turn_rad: float
    start: Point
    step_mm: float
    cost_mm: float
    final: bool = True


#: Grid of the turns :func:`best_pivot_move` tries, radians: none, and 3° apart up to 270°
#: either way (a pivot can need more than a half turn to face a point behind the robot).
_TURNS = np.radians(np.concatenate([[0.0], np.arange(-270, 271, 3)]))
#: The first move of two-move plans: turns 15° apart up to 270° either way, and steps, mm.
_FIRST_TURNS = tuple(math.radians(d) for d in range(-270, 271, 15))
_FIRST_STEPS_MM = (0.0, 5.0, 10.0, 15.0, 20.0)


def segment_blocked(
    p: Point, direction: Point, length_mm: float, centre: Point, radius_mm: float
) -> bool:
    """Whether moving ``length_mm`` from ``p`` along unit ``direction`` enters the disc.

    A start already inside the disc (an estimate off by noise) only blocks moves that go
    noticeably deeper, so a robot at contact can always slide along or back out.

    >>> segment_blocked((0.0, 0.0), (1.0, 0.0), 30.0, (40.0, 0.0), 34.0)
    True
    >>> segment_blocked((0.0, 0.0), (-1.0, 0.0), 30.0, (40.0, 0.0), 34.0)
    False
    """
    wx, wy = centre[0] - p[0], centre[1] - p[1]
    along = max(0.0, min(length_mm, wx * direction[0] + wy * direction[1]))
    closest = math.hypot(
        p[0] + along * direction[0] - centre[0], p[1] + along * direction[1] - centre[1]
    )
    start = math.hypot(wx, wy)
    if start < radius_mm:
        return closest < start - 0.5
    return closest < radius_mm


def _second_moves(
    start: np.ndarray,
    heading: np.ndarray,
    aim: Point,
    max_step_mm: float,
    heading_sd_rad: float,
    turn_sd: float,
    turn_cost_mm_per_rad: float,
    leg_mm: Point,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every grid turn from each start: cost, turn, swing end (x, y) and step, broadcast over
    starts (leading axis) and turns (last axis)."""
    turns = _TURNS[None, :]
    side = np.where(turns < 0, -1.0, 1.0)
    forward, left = leg_mm
    ux, uy = heading[:, :1], heading[:, 1:]
    ox, oy = forward * ux - side * left * uy, forward * uy + side * left * ux
    c, s = np.cos(turns), np.sin(turns)
    sx = start[:, :1] + ox - (c * ox - s * oy)
    sy = start[:, 1:] + oy - (s * ox + c * oy)
    hx, hy = c * ux - s * uy, s * ux + c * uy
    wx, wy = aim[0] - sx, aim[1] - sy
    step = np.clip(hx * wx + hy * wy, 0.0, max_step_mm)
    planned_sq = (wx - step * hx) ** 2 + (wy - step * hy) ** 2
    turn_err = turn_sd * np.abs(turns)
    miss = np.sqrt(
        planned_sq
        + (math.hypot(*leg_mm) * turn_err) ** 2
        + step**2 * (heading_sd_rad**2 + turn_err**2)
    )
    cost = miss + turn_cost_mm_per_rad * np.abs(turns)
    return cost, np.broadcast_to(turns, cost.shape), sx, sy, step


def best_pivot_move(
    position: Point,
    heading: Point,
    aim: Point,
    max_step_mm: float,
    *,
    turn_sd: float = 0.1,
    heading_sd_rad: float = 0.1,
    turn_cost_mm_per_rad: float = 0.5,
    move_cost_mm: float = 5.0,
    obstacles: tuple[Point, ...] | list[Point] = (),
    radius_mm: float = 0.0,
    within_mm: float = math.inf,
    two_moves: bool = True,
    leg_mm: Point = PIVOT_LEG_MM,
) -> PivotMove:
    """The next move (a turn, then a step of at most ``max_step_mm``) of the plan of at most
    two such moves expected to end nearest the aim, the pivots' swings included.

    A move is judged by its expected miss: the planned miss, the swing's error (the pivot
    radius times ``turn_sd`` of the turn), and the step's error (its length times the heading
    error, ``heading_sd_rad`` plus ``turn_sd`` of the turn), added in quadrature; turning also
    costs ``turn_cost_mm_per_rad`` per radian (its time, and a tie-breaker toward small
    turns). One-move plans try every turn on a 3° grid (up to 270° either way, or none) with
    the step ending nearest the aim. Two-move plans (unless ``two_moves`` is False) take a
    first turn on a 15° grid and a first step of 0-20 mm, then the best second move; the first
    move's errors add to the second's, and the second move costs ``move_cost_mm`` more (the
    fix in between takes time). Two moves are what an aim close to the robot needs: a Kilobot
    cannot back up, and a point within the swing of a leg cannot be faced by a short turn of
    that side (the heading points out of the circle the centre swings on), so the robot steps
    or swings away first and comes round.

    A single move not expected to end nearer the aim than the robot is now is never chosen
    (the caller is further from it than it wants to be); then a two-move plan is, even when
    ``two_moves`` is False. Moves whose
    swing ends in, or whose step enters, a disc of ``radius_mm`` round one of ``obstacles``,
    or that end further than ``within_mm`` from one of them (and further than the robot is
    from it now: the robots it must keep hearing), are left out unless every move is (the
    plan's second move is not checked).

    Examples
    --------
    An aim 20 mm straight ahead: no turn, a full step:

    >>> move = best_pivot_move((0.0, 0.0), (1.0, 0.0), (20.0, 0.0), 20.0)
    >>> move.turn_rad, move.start, move.step_mm
    (0.0, (0.0, 0.0), 20.0)

    An aim 50 mm to the left needs a bit more than a quarter turn, since the pivot itself
    carries the centre 23 mm left and 4 mm forward:

    >>> move = best_pivot_move((0.0, 0.0), (1.0, 0.0), (0.0, 50.0), 40.0)
    >>> round(math.degrees(move.turn_rad)), round(move.step_mm, 1)
    (96, 25.8)

    An aim 6 mm behind cannot be faced by any turn of up to 270°: the plan swings round
    (150° to the right, which carries the centre 32 mm away) and steps, to face it from there:

    >>> move = best_pivot_move((0.0, 0.0), (1.0, 0.0), (-6.0, 0.0), 20.0, turn_sd=0.02)
    >>> round(math.degrees(move.turn_rad)), move.step_mm
    (-150, 5.0)
    """
    pos = np.array([position], dtype=float)
    head = np.array([heading], dtype=float)
    args = (aim, max_step_mm, heading_sd_rad, turn_sd, turn_cost_mm_per_rad, leg_mm)
    cost1, turns1, sx, sy, step1 = (a[0] for a in _second_moves(pos, head, *args))
    # Two-move plans: the first move on a coarse grid, then the best second move.
    firsts = [(t, s) for t in _FIRST_TURNS for s in _FIRST_STEPS_MM if s <= max_step_mm]
    t1 = np.array([t for t, _ in firsts])
    s1 = np.array([s for _, s in firsts])
    side = np.where(t1 < 0, -1.0, 1.0)
    forward, left = leg_mm
    ux, uy = heading
    ox, oy = forward * ux - side * left * uy, forward * uy + side * left * ux
    c, s = np.cos(t1), np.sin(t1)
    ax = position[0] + ox - (c * ox - s * oy)
    ay = position[1] + oy - (s * ox + c * oy)
    hx, hy = c * ux - s * uy, s * ux + c * uy
    mid = np.stack([ax + s1 * hx, ay + s1 * hy], axis=1)
    err1 = turn_sd * np.abs(t1)
    cost2, _, _, _, _ = _second_moves(
        mid,
        np.stack([hx, hy], axis=1),
        aim,
        max_step_mm,
        float(math.hypot(heading_sd_rad, turn_sd * math.pi / 2)),
        turn_sd,
        turn_cost_mm_per_rad,
        leg_mm,
    )
    first_err = np.hypot(math.hypot(*leg_mm) * err1, s1 * np.hypot(heading_sd_rad, err1))
    cost2 = (
        np.hypot(cost2.min(axis=1), first_err) + turn_cost_mm_per_rad * np.abs(t1) + move_cost_mm
    )

    # The caller is further from the aim than it wants to be: a single move that is not
    # expected to end nearer is no plan (staying put, or a wiggle in place); a two-move plan
    # whose first move does nothing is the one-move plan.
    here = math.dist(position, aim)
    ones = [
        (float(cost1[k]), float(turns1[k]), (float(sx[k]), float(sy[k])), float(step1[k]), True)
        for k in range(len(cost1))
    ]
    twos = [
        (float(cost2[k]), float(t1[k]), (float(ax[k]), float(ay[k])), float(s1[k]), False)
        for k in range(len(t1))
        if t1[k] != 0.0 or s1[k] > 0.0
    ]
    # Judged by the miss alone (the turn's cost is time, not distance).
    nearer = [m for m in ones if m[0] - turn_cost_mm_per_rad * abs(m[1]) < here]
    candidates = nearer + (twos if two_moves else [])
    if not candidates:  # no single move gets nearer: two moves after all
        candidates = twos
    candidates.sort(key=lambda m: m[0])
    reach = [max(within_mm, math.dist(position, c)) for c in obstacles]

    def allowed(turn: float, start: Point, step: float, _final: bool) -> bool:
        h = rotate(heading, turn)
        end = (start[0] + step * h[0], start[1] + step * h[1])
        arc = swing_arc(position, heading, turn, leg_mm)
        return not any(
            min(math.dist(p, c) for p in arc[1:]) < radius_mm + SWING_MARGIN_MM
            or segment_blocked(start, h, step, c, radius_mm)
            or max(math.dist(start, c), math.dist(end, c)) > r
            for c, r in zip(obstacles, reach, strict=True)
        )

    cost, turn, start, step, final = next((m for m in candidates if allowed(*m[1:])), candidates[0])
    return PivotMove(0.0 if abs(turn) < 1e-12 else turn, start, step, cost, final)


def handedness_vote(
    commanded_rad: float,
    seen_floor_rad: float,
    seen_mirror_rad: float,
    *,
    min_turn_rad: float = math.radians(25.0),
    margin_rad: float = math.radians(20.0),
) -> bool | None:
    """Whether a turn says the frame is a mirror image of the floor (``None``: it cannot tell).

    A physical turn τ shows in a floor-handed frame as a rotation of +τ between the step
    directions before and after it, in a mirrored one as −τ. ``seen_floor_rad`` and
    ``seen_mirror_rad`` are that rotation as seen under each handedness (they differ when the
    pivot's displacement had to be taken out of a step, which depends on the handedness).
    Turns under ``min_turn_rad``, turns seen near a half turn (either sign fits) and verdicts
    whose errors differ by less than ``margin_rad`` (a calibration off by a fifth, a noisy
    heading) say nothing.

    Examples
    --------
    >>> handedness_vote(math.radians(90), math.radians(-85), math.radians(-85))
    True
    >>> handedness_vote(math.radians(90), math.radians(75), math.radians(75))
    False
    >>> handedness_vote(math.radians(10), math.radians(-10), math.radians(-10)) is None
    True
    """
    if abs(commanded_rad) < min_turn_rad:
        return None
    if max(abs(seen_floor_rad), abs(seen_mirror_rad)) > math.radians(165):
        return None
    floor_err = abs(wrap_angle(seen_floor_rad - commanded_rad))
    mirror_err = abs(wrap_angle(seen_mirror_rad + commanded_rad))
    if abs(floor_err - mirror_err) < margin_rad:
        return None
    return mirror_err < floor_err


#: Turn-rate ratios (real / commanded) :func:`swing_vote` fits a swing with.
_SWING_RATIOS = tuple(0.6 + 0.05 * k for k in range(21))


def swing_vote(
    heading: Point,
    physical_turn_rad: float,
    moved_mm: Point,
    *,
    margin_mm: float = 5.0,
    leg_mm: Point = PIVOT_LEG_MM,
) -> bool | None:
    """Whether the swing of a turn says the frame is a mirror image of the floor (``None``:
    it cannot tell).

    A physical left turn swings the centre about the left rear leg: seen in a floor-handed
    frame that is a counter-clockwise swing about the frame's left leg, in a mirrored frame a
    clockwise one about its right leg, whose displacements are mirror images about the
    heading (a quarter turn: 23 mm to one side or the other). ``moved_mm`` (the fix after the
    turn minus the one before) is compared with both, each at the real turn that fits best
    (0.6 to 1.6 times the commanded one: the rate is not known yet). The verdict needs the
    better fit to be ``margin_mm`` better than the other and close (within 4 mm plus 15 % of
    the swing: a robot that touched a body while turning swung differently).

    Examples
    --------
    A quarter turn to the left, heading +x in the frame, seen in a floor-handed frame and in
    a mirrored one:

    >>> floor = pivot_displacement((1.0, 0.0), math.pi / 2)
    >>> swing_vote((1.0, 0.0), math.pi / 2, floor)
    False
    >>> swing_vote((1.0, 0.0), math.pi / 2, (floor[0], -floor[1]))
    True
    >>> swing_vote((1.0, 0.0), math.pi / 2, (floor[0], 0.0)) is None
    True
    """
    misfit = {}
    for mirrored in (False, True):
        frame_turn = -physical_turn_rad if mirrored else physical_turn_rad
        misfit[mirrored] = min(
            math.dist(moved_mm, pivot_displacement(heading, frame_turn * g, leg_mm))
            for g in _SWING_RATIOS
        )
    best = min(misfit.values())
    if abs(misfit[True] - misfit[False]) < margin_mm or best > 4.0 + 0.15 * math.hypot(*moved_mm):
        return None
    return misfit[True] < misfit[False]


def swing_turn_rad(moved_mm: Point, leg_mm: Point = PIVOT_LEG_MM) -> float:
    """How far a turn turned, told by how far its swing moved the centre: the chord of the
    circle the centre swings on, 2 r sin(τ/2), r the leg's distance (radians, 0 to π).

    It needs neither the heading nor the frame's handedness; a fix error of 1 mm is about 5°
    on a quarter turn, more toward a half turn, where the chord stops growing.

    >>> round(math.degrees(swing_turn_rad(pivot_displacement((0.0, 1.0), math.radians(-80)))), 6)
    80.0
    """
    chord = math.hypot(*moved_mm) / (2 * math.hypot(*leg_mm))
    return 2 * math.asin(min(1.0, chord))


def turn_rate_ratio(commanded_rad: float, seen_physical_rad: float) -> float:
    """How much more the robot turned than commanded: the seen physical turn, taken as the
    angle nearest the commanded one (a turn commanded 170° and seen as −175° turned 185°),
    over the commanded turn.

    >>> round(turn_rate_ratio(math.radians(170), math.radians(-175)), 4)
    1.0882
    >>> round(turn_rate_ratio(math.radians(-90), math.radians(-72)), 4)
    0.8
    """
    turned = commanded_rad + wrap_angle(seen_physical_rad - commanded_rad)
    return turned / commanded_rad
