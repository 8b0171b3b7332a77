"""The follower's plane decisions, as pure functions: the turn from one heading to another, which
way to pivot in a frame that may be mirrored, a goal moved out of obstacles, a direction
around them."""

from __future__ import annotations

import math

from kilonet.protocols.common.geometry import (
    rotate,
)
from kilonet.protocols.follower.pivot_turns import (
    segment_blocked,
)

Point = tuple[float, float]


# ------------------------------------------------------------------------- plane geometry


def turn_angle(u: Point, v: Point) -> float:
    """The seed's α = atan2(u₁v₂ − u₂v₁, u₁v₁ + u₂v₂): the signed angle from u to v, radians.

    Positive when v lies counter-clockwise of u in the frame's own axes.

    Examples
    --------
    >>> round(math.degrees(turn_angle((1.0, 0.0), (0.0, 2.0))), 9)
    90.0
    >>> round(math.degrees(turn_angle((1.0, 1.0), (1.0, 0.0))), 9)
    -45.0
    >>> round(math.degrees(turn_angle((1.0, 0.0), (-1.0, 0.0))), 9)
    180.0
    """
    (u1, u2), (v1, v2) = u, v
    return math.atan2(u1 * v2 - u2 * v1, u1 * v1 + u2 * v2)


def frame_direction(alpha_rad: float, mirrored: bool) -> int:
    """Which way to pivot for a turn of ``alpha_rad`` in the frame: +1 counter-clockwise (left,
    kilolib's ``set_motors(kilo_turn_left, 0)``), −1 clockwise (right), 0 for no turn.

    In a frame that is a mirror image of the floor, counter-clockwise in the frame is clockwise
    on the floor.

    >>> frame_direction(0.5, False), frame_direction(0.5, True), frame_direction(-0.5, True)
    (1, -1, 1)
    """
    if alpha_rad == 0:
        return 0
    side = 1 if alpha_rad > 0 else -1
    return -side if mirrored else side


def reachable_goal(goal: Point, obstacles: list[Point], radius_mm: float) -> Point:
    """The goal moved out of any obstacle disc it lies in (to the disc's rim), mm.

    >>> reachable_goal((10.0, 0.0), [(0.0, 0.0)], 34.0)
    (34.0, 0.0)
    >>> reachable_goal((50.0, 0.0), [(0.0, 0.0)], 34.0)
    (50.0, 0.0)
    """
    x, y = goal
    for _ in range(4):  # pushing out of one disc can (rarely) push into another
        moved = False
        for cx, cy in obstacles:
            d = math.hypot(x - cx, y - cy)
            if d < radius_mm - 1e-9:
                if d == 0:
                    x, y = cx + radius_mm, cy
                else:
                    x, y = cx + (x - cx) * radius_mm / d, cy + (y - cy) * radius_mm / d
                moved = True
        if not moved:
            break
    return (x, y)


_SMALL_DETOUR_STEPS = 2  # rotations up to 20° are corrections, not detours


def plan_direction(
    position: Point,
    target: Point,
    obstacles: list[Point],
    radius_mm: float,
    step_mm: float,
    side: int = 0,
) -> tuple[Point, int]:
    """Direction of the next step toward ``target`` around disc obstacles.

    The straight line is taken when it is clear all the way. Otherwise the goal direction is
    rotated in 10° steps until a step of ``step_mm`` is clear. A rotation of up to 20° is a
    correction; a larger one is a detour, and goes to ``side`` (+1 counter-clockwise, −1
    clockwise) if a detour chose one before, so that the robot keeps going round the obstacles
    instead of dithering; 0 lets the first clear rotation choose.

    Returns the unit direction and the side to remember (0 for the line or a correction).

    Examples
    --------
    >>> plan_direction((0.0, 0.0), (100.0, 0.0), [], 34.0, 20.0)
    ((1.0, 0.0), 0)
    >>> (dx, dy), side = plan_direction((0.0, 0.0), (100.0, 0.0), [(50.0, 0.0)], 34.0, 20.0)
    >>> side != 0 and abs(math.degrees(math.atan2(dy, dx))) >= 10
    True
    """
    px, py = position
    gx, gy = target[0] - px, target[1] - py
    dist = math.hypot(gx, gy)
    if dist == 0:
        return (1.0, 0.0), 0
    goal_dir = (gx / dist, gy / dist)
    if not any(segment_blocked(position, goal_dir, dist, c, radius_mm) for c in obstacles):
        return goal_dir, 0
    look = min(dist, step_mm)

    def clear(s: int, k: int) -> Point | None:
        d = rotate(goal_dir, s * math.radians(10 * k))
        blocked = any(segment_blocked(position, d, look, c, radius_mm) for c in obstacles)
        return None if blocked else d

    def closeness(d: Point) -> float:
        return math.hypot(px + look * d[0] - target[0], py + look * d[1] - target[1])

    for k in range(1, 19):
        found = [(s != side, closeness(d), s, d) for s in (1, -1) if (d := clear(s, k)) is not None]
        if not found:
            continue
        _, _, s, d = min(found)  # the remembered side first, then the one ending nearer
        if k <= _SMALL_DETOUR_STEPS:
            return d, 0  # a small correction commits to no side
        if side == 0 or s == side:
            return d, s
        break
    if side:
        for k in range(1, 19):  # keep going round the same way while that is possible
            if (d := clear(side, k)) is not None:
                return d, side
    return goal_dir, side  # boxed in: go straight and let contact stop the move
