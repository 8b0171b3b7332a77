"""The rules of Rubenstein, Cornejo and Nagpal's self-assembly (Science 345:795, 2014), each a
pure function of what one robot knows: its neighbours' messages, its distance estimates to
them and its own state. :mod:`kilonet.protocols.self_assembly.program` runs them on a robot.

Distances are centre to centre in millimetres; a Kilobot's body is a 33 mm disc. The distances
are those public re-implementations of the paper's supplement use, multiples of the body
radius, scaled here to a Kilobot's (``docs/self_assembly.md`` gives each and its reason).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from kilonet.protocols.common.geometry import linear_position

__all__ = [
    "DESIRED_MM",
    "EDGE_MAX_NEIGHBOURS",
    "EDGE_MM",
    "GRADIENT_MM",
    "MIN_CONDITIONING",
    "SETTLE_MAX_S",
    "SETTLE_MM",
    "SETTLE_S",
    "TREND_MM",
    "YIELD_MM",
    "Heard",
    "Shape",
    "about_to_leave",
    "edge_turn",
    "first_fix",
    "gradient_from",
    "localize_step",
    "may_start",
    "meets_own_gradient",
    "must_yield",
    "on_edge",
    "settled",
]

#: Edge-following keeps the nearest stationary robot this far, centre to centre (2.3 body
#: radii, DESIRED_DISTANCE): a gap of about 5 mm between the bodies.
DESIRED_MM = 38.0
#: A stationary robot counts for the gradient only within this distance (3 body radii,
#: GRADIENT_DISTANCE): the hop count then follows the packing, not the radio reach.
GRADIENT_MM = 49.5
#: A moving robot waits while a moving robot ahead of it is within this distance (3.5 body
#: radii, YIELD_DISTANCE).
YIELD_MM = 58.0
#: Edge-following counts the nearest robot as getting closer or farther only when its distance
#: changed by at least this much since the reading before, mm: a robot pressed against the group
#: reads distances that move by their noise alone, and would go straight into it half the time.
TREND_MM = 2.0
#: Neighbours within this distance are a robot's ring of touching robots (between the first
#: and second ring of a packing 34 mm apart: 34 and 59 mm).
EDGE_MM = 47.0
#: A robot with at most this many robots in its ring is on the group's edge (a packed robot
#: inside the group has six).
EDGE_MAX_NEIGHBOURS = 4
#: The first fix needs anchors that condition the linear solve at least this well
#: (:func:`kilonet.protocols.common.geometry.linear_position`); fewer or nearly collinear
#: anchors wait.
MIN_CONDITIONING = 0.15
#: A robot that stopped in the shape serves as a localization anchor only after standing this
#: long (its estimate then rests on readings taken where it stands, s) ...
SETTLE_S = 1.5
#: ... and once a localization update moved its estimate less than this, mm;
SETTLE_MM = 0.5
#: or, if it never gets there (too few anchors in range), after this long, s.
SETTLE_MAX_S = 10.0


@dataclass(frozen=True)
class Heard:
    """What a robot knows of one neighbour: its id, gradient, whether it moves, and the last
    distance estimate to it, mm."""

    uid: int
    gradient: int
    moving: bool
    distance_mm: float


@dataclass(frozen=True, eq=False)
class Shape:
    """The target shape every robot holds: a bitmap in the seeds' frame.

    Parameters
    ----------
    mask : (rows, cols) bool array
        ``True`` where a cell is part of the shape; row 0 is the top row, as written.
    cell_mm : float
        Side of one cell, mm.
    origin_mm : (float, float)
        Where the bitmap's bottom-left corner lies in the seeds' frame, mm.
    """

    mask: np.ndarray
    cell_mm: float
    origin_mm: tuple[float, float] = (0.0, 0.0)

    def contains(self, x_mm: float, y_mm: float) -> bool:
        """Whether the point lies in a cell of the shape.

        >>> s = Shape(np.array([[True, False], [True, True]]), 10.0)
        >>> s.contains(5, 5), s.contains(15, 15), s.contains(5, 15), s.contains(-1, 5)
        (True, False, True, False)
        """
        col = math.floor((x_mm - self.origin_mm[0]) / self.cell_mm)
        row = math.floor((y_mm - self.origin_mm[1]) / self.cell_mm)
        rows, cols = self.mask.shape
        return 0 <= col < cols and 0 <= row < rows and bool(self.mask[rows - 1 - row, col])

    @property
    def extent_mm(self) -> tuple[float, float, float, float]:
        """``(x_min, y_min, x_max, y_max)`` of the bitmap, mm."""
        rows, cols = self.mask.shape
        x0, y0 = self.origin_mm
        return x0, y0, x0 + cols * self.cell_mm, y0 + rows * self.cell_mm


def gradient_from(distances_mm: Sequence[float], gradients: Sequence[int]) -> int | None:
    """One more than the smallest gradient among stationary neighbours within
    :data:`GRADIENT_MM`; ``None`` when none is that close (the robot keeps what it had).

    >>> gradient_from([35.0, 40.0, 80.0], [3, 2, 0]), gradient_from([60.0], [1])
    (3, None)
    """
    near = [g for d, g in zip(distances_mm, gradients, strict=True) if d <= GRADIENT_MM]
    return min(near) + 1 if near else None


def on_edge(ring_distances_mm: Iterable[float]) -> bool:
    """Whether a stationary robot is on its group's edge: at most
    :data:`EDGE_MAX_NEIGHBOURS` stationary robots within :data:`EDGE_MM` (a robot inside a
    packed group has six). A robot knows distances, not bearings; this is what it can count.

    >>> on_edge([34.0] * 6), on_edge([34.0] * 4 + [60.0] * 3)
    (False, True)
    """
    return sum(d <= EDGE_MM for d in ring_distances_mm) <= EDGE_MAX_NEIGHBOURS


def may_start(edge: bool, gradient: int, uid: int, neighbours: Iterable[Heard]) -> bool:
    """The start rule: a waiting robot starts to move when it is on the group's edge, no
    neighbour moves, and its gradient is the highest among its stationary neighbours (on a
    tie, the higher uid starts).

    >>> a, b = Heard(7, 4, False, 34.0), Heard(9, 5, False, 34.0)
    >>> may_start(True, 5, 8, [a, b]), may_start(True, 5, 10, [a, b])
    (False, True)
    >>> may_start(False, 6, 10, [a]), may_start(True, 6, 10, [Heard(3, 1, True, 80.0)])
    (False, False)
    """
    if not edge:
        return False
    for n in neighbours:
        if n.moving or n.gradient > gradient or (n.gradient == gradient and n.uid > uid):
            return False
    return True


def must_yield(age: int, uid: int, moving: Iterable[tuple[int, int, float]]) -> bool:
    """Whether a moving robot waits: a moving neighbour ``(age, uid, distance_mm)`` within
    :data:`YIELD_MM` has moved longer (``age``, seconds of motion it reports) and so is
    ahead of it on the edge; on equal age the higher uid goes first.

    >>> must_yield(3, 5, [(9, 2, 50.0)]), must_yield(3, 5, [(9, 2, 70.0)])
    (True, False)
    >>> must_yield(9, 5, [(3, 2, 40.0)]), must_yield(3, 5, [(3, 6, 40.0)])
    (False, True)
    """
    return any(d <= YIELD_MM and (a > age or (a == age and u > uid)) for a, u, d in moving)


def edge_turn(nearest_mm: float, previous_mm: float | None = None) -> str:
    """Edge-following, clockwise round the group (the group on the robot's right), as the
    paper's supplement gives it: while the nearest stationary robot is closer than
    :data:`DESIRED_MM`, go ``"straight"`` if it is getting farther (``previous_mm``, the
    nearest distance of the reading before, was smaller by at least :data:`TREND_MM`), else turn
    ``"left"``, away from the group; while it is at or beyond :data:`DESIRED_MM`, go
    ``"straight"`` if it is getting closer (by at least :data:`TREND_MM`), else turn
    ``"right"``, towards it. Without a previous reading the trend is unknown and the robot
    turns. A Kilobot pivots on one motor about a rear leg, so the alternating
    turns carry it forward; the straight cases let it close a gap to the group, which pivoting
    towards the group on the spot does not.

    >>> edge_turn(30.0), edge_turn(45.0)
    ('left', 'right')
    >>> edge_turn(30.0, 28.0), edge_turn(30.0, 29.0), edge_turn(45.0, 47.0), edge_turn(45.0, 46.0)
    ('straight', 'left', 'straight', 'right')
    """
    if previous_mm is None:
        return "left" if nearest_mm < DESIRED_MM else "right"
    if nearest_mm < DESIRED_MM:
        return "straight" if nearest_mm - previous_mm >= TREND_MM else "left"
    return "straight" if previous_mm - nearest_mm >= TREND_MM else "right"


def first_fix(anchors_mm: np.ndarray, ranges_mm: np.ndarray) -> tuple[float, float] | None:
    """A first position from three or more localized stationary robots (the least-squares
    point of the linearized range equations); ``None`` with fewer, or with anchors too near
    one line to tell the point from its mirror image (:data:`MIN_CONDITIONING`).

    >>> a = np.array([[0.0, 0.0], [36.0, 0.0], [18.0, 31.0]])
    >>> first_fix(a, np.hypot(*(a - [50.0, 60.0]).T))
    (50.0, 60.0)
    >>> first_fix(a[:2], np.array([10.0, 30.0])) is None
    True
    """
    if len(anchors_mm) < 3:
        return None
    point, conditioning = linear_position(anchors_mm, ranges_mm)
    if conditioning < MIN_CONDITIONING:
        return None
    return round(float(point[0]), 9), round(float(point[1]), 9)


def localize_step(
    estimate_mm: tuple[float, float], anchors_mm: np.ndarray, ranges_mm: np.ndarray, steps: int = 1
) -> tuple[float, float]:
    """``steps`` steps of the supplement's localization: for each localized stationary
    neighbour, the point at the measured range from it on the line to the current estimate;
    the estimate moves a quarter of the way to their mean. Repeated, it descends the squared
    range error, and it follows a robot that moves.

    >>> a = np.array([[0.0, 0.0], [36.0, 0.0], [18.0, 31.0]])
    >>> p = localize_step((40.0, 40.0), a, np.hypot(*(a - [50.0, 60.0]).T), 1000)
    >>> round(p[0], 1), round(p[1], 1)
    (50.0, 60.0)
    """
    est = np.array(estimate_mm, dtype=float)
    count = len(anchors_mm)
    for _ in range(steps):
        away = est - anchors_mm
        length = np.hypot(away[:, 0], away[:, 1])
        length[length < 1e-9] = 1e-9
        targets = anchors_mm + away * (ranges_mm / length)[:, None]
        est = est + (targets.sum(axis=0) / count - est) / 4.0
    return float(est[0]), float(est[1])


def about_to_leave(
    shape: Shape, estimate_mm: tuple[float, float], ahead_mm: tuple[float, float]
) -> bool:
    """The first stop rule: a robot inside the shape stops when it is about to leave it,
    i.e. its position estimate is in the shape and the point it is heading for
    (``ahead_mm``, its estimate carried on along its recent motion) is not; or it has already
    left it.

    >>> s = Shape(np.ones((2, 2), dtype=bool), 10.0)
    >>> about_to_leave(s, (5, 5), (8, 5)), about_to_leave(s, (15, 5), (21, 5))
    (False, True)
    >>> about_to_leave(s, (25, 5), (26, 5))
    True
    """
    return not (shape.contains(*estimate_mm) and shape.contains(*ahead_mm))


def meets_own_gradient(gradient: int, nearest: Heard | None) -> bool:
    """The second stop rule: a robot inside the shape stops when the stationary robot it
    follows, within :data:`DESIRED_MM` and a tolerance of a few mm, holds its own gradient.

    >>> same, lower = Heard(2, 4, False, 39.0), Heard(2, 3, False, 39.0)
    >>> meets_own_gradient(4, same), meets_own_gradient(4, lower)
    (True, False)
    >>> meets_own_gradient(4, Heard(2, 4, False, 60.0)), meets_own_gradient(4, None)
    (False, False)
    """
    return (
        nearest is not None
        and not nearest.moving
        and nearest.distance_mm <= DESIRED_MM + 5.0
        and nearest.gradient == gradient
    )


def settled(stood_s: float, last_step_mm: float | None) -> bool:
    """Whether a robot that stopped in the shape ``stood_s`` seconds ago may serve the robots
    still to come as a localization anchor: it has stood :data:`SETTLE_S` and its last
    localization update moved its estimate less than :data:`SETTLE_MM` (``None``: no update
    since it stopped), or it has stood :data:`SETTLE_MAX_S`.

    A moving robot's estimate lags behind it along its path (its readings are up to
    0.6 s old, and the descent follows the motion a step behind). Edge-following runs
    clockwise, so every robot that stopped with such an estimate believes itself a little
    counter-clockwise of where it stands; the robots that localize against it inherit that
    turn and add their own, and the whole shape comes out rotated about the seeds by an angle
    that grows ring by ring. Standing still first, a robot's estimate settles on its anchors
    before anyone ranges with it.

    >>> settled(0.5, 0.1), settled(2.0, 3.0), settled(2.0, 0.2), settled(2.0, None)
    (False, False, True, False)
    >>> settled(10.0, None)
    True
    """
    if stood_s >= SETTLE_MAX_S:
        return True
    return stood_s >= SETTLE_S and last_step_mm is not None and last_step_mm < SETTLE_MM
