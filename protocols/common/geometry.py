"""Plane geometry the robots compute with: frames of three, trilateration, multilateration.

Pure functions on millimetres. Robots call them on their measured distances; metrics call
them on ground truth. Degenerate inputs are reported, never silently accepted.

- Frames: :func:`place_references` (the frame of three robots: the thesis's phase 3 and the
  follower seed's frame) and :func:`angle_at` (law of cosines).
- Choosing the references: :func:`choose_references_max_angle` (the thesis's rule) and
  :func:`choose_references_best_conditioned` (the widest triangle).
- Degeneracy: :func:`collinear` (do points lie too close to one line?).
- Positions from ranges: :func:`trilaterate_linear` (the seeds' closed form for three
  anchors), :func:`linear_position` (the linearised least squares over k anchors) and
  :func:`multilaterate` (least squares over k anchors that says why it rejects a fix).
- What is achievable: :func:`crlb_rmse_mm`, the anchor-free Cramér–Rao bound of a measurement
  graph.

Why these are hand-written rather than scipy calls, and what each costs: ``docs/math.md``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Hashable, Mapping
from dataclasses import dataclass

import numpy as np

__all__ = [
    "FIX_REASONS",
    "MIRROR_SIGMAS",
    "Fix",
    "GeometryError",
    "angle_at",
    "choose_references_best_conditioned",
    "choose_references_max_angle",
    "circle_intersections",
    "circle_pair",
    "collinear",
    "linear_position",
    "multilaterate",
    "place_references",
    "robust_height",
    "rotate",
    "trilaterate_linear",
    "wrap_angle",
]


class GeometryError(ValueError):
    """The distances or anchors do not determine a position (degenerate or inconsistent)."""


def collinear(points_mm: np.ndarray, *, min_width_mm: float) -> bool:
    """Whether all points lie within ``min_width_mm`` of one line.

    The line is the points' total-least-squares line: through their centroid along their
    first principal axis. The points' width is the largest distance of one of them from it.
    Every fix from ranges and every rotation fitted between frames needs points that are not
    collinear: ranges to anchors on one line cannot tell its two sides apart, and points on
    one line leave the rotation about it undetermined. Which width is too small is the
    caller's decision: a guard against dividing by rounding noise (1e-6 mm) or a bound set
    by the measurement noise (a range's standard deviation).

    Parameters
    ----------
    points_mm : (k, 2) or (k, 3) array
        Points, mm.
    min_width_mm : float
        Points whose width is below this count as collinear, mm (non-negative).

    Returns
    -------
    bool
        True when the width is below ``min_width_mm``; always True for fewer than three points.

    Raises
    ------
    ValueError
        If ``points_mm`` is not a (k, 2) or (k, 3) array of finite values, or
        ``min_width_mm`` is negative.

    Examples
    --------
    The best-fit line of this bend is y = 1/3 mm, and the middle point is 2/3 mm off it:

    >>> bend = np.array([[0.0, 0.0], [40.0, 1.0], [80.0, 0.0]])
    >>> collinear(bend, min_width_mm=1.0), collinear(bend, min_width_mm=0.5)
    (True, False)
    """
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or not np.isfinite(pts).all():
        raise ValueError(
            f"points_mm must be a finite (k, 2) or (k, 3) array; got shape {pts.shape}"
        )
    if not min_width_mm >= 0:
        raise ValueError(f"min_width_mm must be non-negative; got {min_width_mm}")
    if len(pts) < 3:
        return True
    return _best_fit_line(pts.tolist())[1] < min_width_mm


def _best_fit_line(points: list[list[float]]) -> tuple[tuple[float, ...], float]:
    """The total-least-squares line of k ≥ 1 points of 2 or 3 coordinates, mm.

    It passes through the centroid. Returns its unit direction (the principal axis: the
    eigenvector of the largest eigenvalue of the scatter matrix) and the points' width (the
    largest distance from the line, mm). Plain floats in closed form, because a merging-group member
    checks both frames of every answer (``docs/math.md``); the tests check it against NumPy's
    SVD. In 2-D the axis angle is ``atan2(2 sxy, sxx − syy) / 2``.
    In 3-D the largest eigenvalue λ comes from the trigonometric solution of the cubic and
    the axis from the largest cross product of two rows of ``S − λ I`` (all rows are
    orthogonal to it). Without a unique axis (all directions, or a plane of them, equally
    spread) any axis is a best-fit line; the x axis, or the one the rounding picks, is used.
    """
    k = len(points)
    if len(points[0]) == 2:
        cx, cy = sum(p[0] for p in points) / k, sum(p[1] for p in points) / k
        centred = [(x - cx, y - cy) for x, y in points]
        sxx = sum(x * x for x, _ in centred)
        sxy = sum(x * y for x, y in centred)
        syy = sum(y * y for _, y in centred)
        angle = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
        ux, uy = math.cos(angle), math.sin(angle)
        return (ux, uy), max(abs(ux * y - uy * x) for x, y in centred)
    cx, cy, cz = (sum(p[i] for p in points) / k for i in range(3))
    centred = [(x - cx, y - cy, z - cz) for x, y, z in points]
    sxx = sum(x * x for x, _, _ in centred)
    syy = sum(y * y for _, y, _ in centred)
    szz = sum(z * z for _, _, z in centred)
    sxy = sum(x * y for x, y, _ in centred)
    sxz = sum(x * z for x, _, z in centred)
    syz = sum(y * z for _, y, z in centred)
    mean = (sxx + syy + szz) / 3.0
    spread_sq = (sxx - mean) ** 2 + (syy - mean) ** 2 + (szz - mean) ** 2
    spread_sq += 2.0 * (sxy * sxy + sxz * sxz + syz * syz)
    axis = (1.0, 0.0, 0.0)
    if spread_sq > 0.0:
        # The eigenvalues are mean + 2 p cos((acos(det B / 2) + 2πj) / 3), B = (S − mean I) / p.
        p = math.sqrt(spread_sq / 6.0)
        bxx, byy, bzz = (sxx - mean) / p, (syy - mean) / p, (szz - mean) / p
        bxy, bxz, byz = sxy / p, sxz / p, syz / p
        det = bxx * (byy * bzz - byz * byz) - bxy * (bxy * bzz - byz * bxz)
        det += bxz * (bxy * byz - byy * bxz)
        largest = mean + 2.0 * p * math.cos(math.acos(min(1.0, max(-1.0, det / 2.0))) / 3.0)
        rows = (
            (sxx - largest, sxy, sxz),
            (sxy, syy - largest, syz),
            (sxz, syz, szz - largest),
        )
        best = 0.0
        for (a0, a1, a2), (b0, b1, b2) in itertools.combinations(rows, 2):
            cross = (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)
            norm_sq = cross[0] ** 2 + cross[1] ** 2 + cross[2] ** 2
            if norm_sq > best:
                best, axis = norm_sq, cross
        norm = math.sqrt(best) if best > 0.0 else 1.0
        axis = (axis[0] / norm, axis[1] / norm, axis[2] / norm)
    ux, uy, uz = axis
    width = max(
        math.sqrt((uy * z - uz * y) ** 2 + (uz * x - ux * z) ** 2 + (ux * y - uy * x) ** 2)
        for x, y, z in centred
    )
    return axis, width


def trilaterate_linear(
    anchors_mm: np.ndarray, ranges_mm: np.ndarray, *, min_width_mm: float = 1e-6
) -> tuple[float, float]:
    """Position from three anchors and the ranges to them, in closed form (the seeds' formula).

    Subtracting two range equations ``|p − aᵢ|² = rᵢ²`` leaves a line; the point where these
    lines meet is the answer. It is computed in the frame of the first two anchors (anchor 1
    at the origin, anchor 2 at (d₁₂, 0), anchor 3 at (u₃, v₃)), the follower seed's form:

    ``x = (r₁² − r₂² + d₁₂²) / (2 d₁₂)``, ``y = (r₁² − r₃² + u₃² + v₃²) / (2 v₃) − u₃ x / v₃``,

    then turned and shifted back. The maze seed's form (A…F, subtracting equations 1−2 and
    2−3) gives the same point. With exact ranges it is the position; with noisy ones it is
    not the least-squares fit (:func:`multilaterate`), only what the seeds' robots compute.

    Parameters
    ----------
    anchors_mm : (3, 2) array
        Anchor positions, mm.
    ranges_mm : (3,) array
        Ranges to them, mm.
    min_width_mm : float
        Anchors within this distance of one line (:func:`collinear`) are refused, mm. The
        default only guards against dividing by rounding noise.

    Returns
    -------
    x_mm, y_mm : float
        The position in the anchors' frame, mm.

    Raises
    ------
    GeometryError
        If the three anchors are collinear: no unique position.
    ValueError
        If the shapes are not (3, 2) and (3,).

    Examples
    --------
    >>> anchors = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    >>> truth = np.array([30.0, 40.0])
    >>> ranges = np.hypot(*(anchors - truth).T)
    >>> [round(v, 9) for v in trilaterate_linear(anchors, ranges)]
    [30.0, 40.0]

    The follower's frame of three (robot 3 at (x₃, y₃) from :func:`place_references`):

    >>> _, (x3, y3) = place_references(40.0, 40.0, 40.0)
    >>> frame = [(0.0, 0.0), (40.0, 0.0), (x3, y3)]
    >>> [round(v, 9) for v in trilaterate_linear(frame, np.hypot(*(np.array(frame) - [25, 10]).T))]
    [25.0, 10.0]
    """
    anchors = np.asarray(anchors_mm, dtype=float)
    ranges = np.asarray(ranges_mm, dtype=float)
    if anchors.shape != (3, 2) or ranges.shape != (3,):
        raise ValueError(
            f"anchors_mm must be (3, 2) and ranges_mm (3,); got {anchors.shape} and {ranges.shape}"
        )
    if collinear(anchors, min_width_mm=min_width_mm):
        raise GeometryError("the three anchors are collinear: no unique position")
    (x1, y1), (x2, y2), (x3, y3) = anchors.tolist()  # plain floats: robots call this per fix
    r1, r2, r3 = ranges.tolist()
    d12 = math.hypot(x2 - x1, y2 - y1)
    ex, ey = (x2 - x1) / d12, (y2 - y1) / d12  # the frame's x axis; its y axis is (−ey, ex)
    u3 = ex * (x3 - x1) + ey * (y3 - y1)
    v3 = ex * (y3 - y1) - ey * (x3 - x1)
    x = (r1**2 - r2**2 + d12**2) / (2 * d12)
    y = (r1**2 - r3**2 + u3**2 + v3**2) / (2 * v3) - u3 * x / v3
    return float(x1 + ex * x - ey * y), float(y1 + ey * x + ex * y)


def linear_position(anchors_mm: np.ndarray, ranges_mm: np.ndarray) -> tuple[np.ndarray, float]:
    """The least-squares point of the range equations made linear, and how well the anchors
    condition it.

    Each range equation ``|p − aᵢ|² = rᵢ²`` minus their mean leaves a linear one,
    ``2 (aᵢ − ā) · p = |aᵢ|² − mean|a|² − (rᵢ² − mean r²)`` (the ``|p|²`` term cancels); their
    least-squares solution is exact with exact ranges, and with noisy ones a start for the
    fit of the range residuals (:func:`multilaterate`). It also serves the island solve's
    rigid motions (:mod:`kilonet.protocols.localize.island_solve`), whose shift is such a point.

    Parameters
    ----------
    anchors_mm : (k, 2) array
        Anchor positions, mm (k ≥ 1).
    ranges_mm : (k,) array
        Ranges to them, mm.

    Returns
    -------
    point : (2,) array
        The least-squares solution, mm (the minimum-norm one when the system is singular).
    conditioning : float
        The system's smallest singular value over its largest, in [0, 1]: 0 when the anchors
        lie on one line (or coincide), small when nearly so and the point is unreliable.

    Examples
    --------
    >>> anchors = np.array([[0.0, 0.0], [60.0, 0.0], [10.0, 50.0], [70.0, 40.0]])
    >>> p, c = linear_position(anchors, np.hypot(*(anchors - [30.0, 20.0]).T))
    >>> p.round(9).tolist(), 0.5 < c <= 1.0
    ([30.0, 20.0], True)
    >>> linear_position(anchors[:, :1] * [1.0, 0.0], np.ones(4))[1]  # all on the x axis
    0.0
    """
    anchors = np.asarray(anchors_mm, dtype=float)
    ranges = np.asarray(ranges_mm, dtype=float)
    r2 = ranges**2
    a2 = (anchors**2).sum(axis=1)
    point, _, rank, singular = np.linalg.lstsq(
        2.0 * (anchors - anchors.mean(axis=0)), (a2 - a2.mean()) - (r2 - r2.mean()), rcond=None
    )
    conditioning = float(singular[-1] / singular[0]) if rank == 2 else 0.0
    return point, conditioning


# ----------------------------------------------------------------------------- local frames


def angle_at(a_to_b_mm: float, a_to_c_mm: float, b_to_c_mm: float) -> float:
    """Angle α = ∠BAC at robot A of the triangle ABC, from its three sides (law of cosines).

    ``cos α = (|AB|² + |AC|² − |BC|²) / (2 |AB| |AC|)``, clipped to [−1, 1]: measured
    distances that break the triangle inequality a little (noise) give 0 or π, not NaN.

    Parameters
    ----------
    a_to_b_mm, a_to_c_mm : float
        Distances from A to B and from A to C, mm; positive.
    b_to_c_mm : float
        Distance from B to C, mm; non-negative.

    Returns
    -------
    float
        α in radians, in [0, π].

    Raises
    ------
    GeometryError
        If a distance is not finite, a side from A is not positive (B or C sits on A, so
        there is no angle) or ``b_to_c_mm`` is negative.

    Examples
    --------
    >>> round(math.degrees(angle_at(3.0, 4.0, 5.0)), 9)
    90.0
    >>> round(math.degrees(angle_at(40.0, 40.0, 40.0)), 9)
    60.0
    >>> angle_at(10.0, 10.0, 25.0) == math.pi  # no such triangle: clipped to a straight angle
    True
    """
    _check_sides(a_to_b_mm, a_to_c_mm, b_to_c_mm)
    cos_a = (a_to_b_mm**2 + a_to_c_mm**2 - b_to_c_mm**2) / (2 * a_to_b_mm * a_to_c_mm)
    return math.acos(min(1.0, max(-1.0, cos_a)))


def _check_sides(a_to_b_mm: float, a_to_c_mm: float, b_to_c_mm: float) -> None:
    sides = (a_to_b_mm, a_to_c_mm, b_to_c_mm)
    if not all(math.isfinite(s) for s in sides):
        raise GeometryError(f"distances {sides} mm: not all finite")
    if a_to_b_mm <= 0 or a_to_c_mm <= 0 or b_to_c_mm < 0:
        raise GeometryError(
            f"distances |AB|={a_to_b_mm}, |AC|={a_to_c_mm}, |BC|={b_to_c_mm} mm: "
            "|AB| and |AC| must be positive and |BC| non-negative"
        )


def place_references(
    d_ab_mm: float, d_ac_mm: float, d_bc_mm: float, *, min_height_mm: float = 1.0
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The frame of three robots A, B, C from their distances: A at the origin, B on +x, C above.

    Thesis §4.3 (a seed A places its references B and C) and the follower seed's frame of
    robots 1, 2, 3: ``B = (|AB|, 0)`` and ``C = (x, y)`` with

    ``x = (|AC|² − |BC|² + |AB|²) / (2 |AB|)``, ``y = √(|AC|² − x²)``

    (the thesis writes the same point as ``(|AC| cos α, |AC| sin α)``, α = ∠BAC from
    :func:`angle_at`). y is taken positive, so the frame may be a mirror image of the floor.

    Parameters
    ----------
    d_ab_mm, d_ac_mm, d_bc_mm : float
        Measured distances A–B, A–C and B–C, mm.
    min_height_mm : float
        Smallest accepted distance of C from the x axis (line AB), mm. Below it the direction
        of the y axis is set by the distance noise rather than by the robots (with the
        Kilobot's ±2 mm ranges, 1 mm is already noise), and a position fixed from the three
        robots is no better.

    Returns
    -------
    (x_b, y_b), (x_c, y_c) : tuple of float pairs
        mm; ``y_b == 0.0`` and ``y_c >= min_height_mm``.

    Raises
    ------
    GeometryError
        If a distance is not finite, ``|AB|`` or ``|AC|`` is not positive or ``|BC|`` is
        negative, or the triangle is degenerate: the sides break the triangle inequality
        (noise; C is then put on line AB), or C lies within ``min_height_mm`` of AB.

    Examples
    --------
    >>> place_references(3.0, 4.0, 5.0)
    ((3.0, 0.0), (0.0, 4.0))
    >>> place_references(40.0, 40.0, 40.0)
    ((40.0, 0.0), (20.0, 34.64101615137755))
    >>> place_references(40.0, 40.0, 80.0)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    kilonet.protocols.common.geometry.GeometryError: ... from line AB (need >= 1.0 mm)
    """
    _check_sides(d_ab_mm, d_ac_mm, d_bc_mm)
    x_c = (d_ac_mm**2 - d_bc_mm**2 + d_ab_mm**2) / (2 * d_ab_mm)
    y_c = math.sqrt(max(0.0, d_ac_mm**2 - x_c**2))
    if not y_c >= min_height_mm:
        raise GeometryError(
            f"distances |AB|={d_ab_mm}, |AC|={d_ac_mm}, |BC|={d_bc_mm} mm form a degenerate "
            f"triangle: C is {y_c:.3g} mm from line AB (need >= {min_height_mm} mm)"
        )
    return (float(d_ab_mm), 0.0), (float(x_c), y_c)


# ------------------------------------------------------------------------- plane geometry

#: A point or vector of the plane, mm (or any one unit).
Point = tuple[float, float]


def wrap_angle(angle_rad: float) -> float:
    """The angle in [−π, π), radians.

    >>> round(wrap_angle(3 * math.pi / 2), 9)
    -1.570796327
    """
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def rotate(u: Point, angle_rad: float) -> Point:
    """``u`` rotated counter-clockwise by ``angle_rad`` about the origin.

    >>> [round(c, 9) for c in rotate((1.0, 0.0), math.pi / 2)]
    [0.0, 1.0]
    """
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return (c * u[0] - s * u[1], s * u[0] + c * u[1])


def _chord(c1: Point, r1: float, c2: Point, r2: float) -> tuple[float, float, float, float]:
    """``(d, a, ex, ey)``: the distance of the centres, how far along the line of centres from
    ``c1`` the chord of the two circles crosses it, and the unit vector ``c1 → c2``. The law of
    cosines, as :func:`place_references` writes it. ``d`` must be positive."""
    dx, dy = c2[0] - c1[0], c2[1] - c1[1]
    d = math.hypot(dx, dy)
    return d, (r1**2 - r2**2 + d**2) / (2 * d), dx / d, dy / d


def circle_intersections(c1: Point, r1: float, c2: Point, r2: float) -> list[Point]:
    """The points at distance ``r1`` from ``c1`` and ``r2`` from ``c2`` (mm).

    Measured ranges need not meet exactly: circles that miss each other (noise) give their
    single closest point on the line of centres. Concentric circles give no point.

    Examples
    --------
    >>> sorted((round(x, 9), round(y, 9)) for x, y in circle_intersections((0, 0), 5, (8, 0), 5))
    [(4.0, -3.0), (4.0, 3.0)]
    >>> circle_intersections((0, 0), 2, (10, 0), 3)
    [(4.5, 0.0)]
    """
    if c1[0] == c2[0] and c1[1] == c2[1]:
        return []
    d, a, ex, ey = _chord(c1, r1, c2, r2)
    h_sq = r1**2 - a**2
    if h_sq <= 0:
        # Tangent or missing circles: the point on the line of centres between the two rims.
        if d > r1 + r2:
            a = r1 + (d - r1 - r2) / 2
        elif d < abs(r1 - r2):
            a = (r1 + d + r2) / 2 if r1 > r2 else (d - r1 - r2) / 2
        return [(c1[0] + a * ex, c1[1] + a * ey)]
    h = math.sqrt(h_sq)
    mx, my = c1[0] + a * ex, c1[1] + a * ey
    return [(mx - h * ey, my + h * ex), (mx + h * ey, my - h * ex)]


def circle_pair(
    c1: Point, r1: float, c2: Point, r2: float, *, tolerance_mm: float = 0.5
) -> tuple[Point, Point, float] | None:
    """The two points at ``r1`` from ``c1`` and ``r2`` from ``c2``: mirror images across the
    line of centres, and their distance from it (mm).

    Circles that miss each other by at most ``tolerance_mm`` (rounding of measured ranges)
    meet in one point on the line of centres, returned twice with distance 0. None if the
    centres coincide, a range is not positive, or the circles miss by more.

    Examples
    --------
    >>> p, q, h = circle_pair((0.0, 0.0), 50.0, (40.0, 0.0), 30.0)
    >>> [round(v, 9) for v in (*p, *q, h)]
    [40.0, 30.0, 40.0, -30.0, 30.0]
    >>> circle_pair((0.0, 0.0), 40.0, (100.0, 0.0), 40.0) is None
    True
    """
    length = math.hypot(c2[0] - c1[0], c2[1] - c1[1])
    if (
        length <= 0
        or not abs(r1 - r2) - tolerance_mm <= length <= r1 + r2 + tolerance_mm
        or not (math.isfinite(r1) and math.isfinite(r2) and r1 > 0 and r2 >= 0)
    ):
        return None
    _, x, ux, uy = _chord(c1, r1, c2, r2)
    h = math.sqrt(max(0.0, r1**2 - x**2))
    cx, cy = c1[0] + x * ux, c1[1] + x * uy
    return (cx - h * uy, cy + h * ux), (cx + h * uy, cy - h * ux), h


def robust_height(d_ab_mm: float, d_ac_mm: float, d_bc_mm: float, margin_mm: float) -> float:
    """The least height of C above line AB when each distance may be off by ``margin_mm``:
    the smallest height over the eight corners of the box of distances (0 where a corner
    forms no triangle), mm.

    Near collinearity the height is ill-conditioned: a triple on one line, 40 + 40 = 80 mm,
    measured 1 mm short, looks 12.5 mm high.

    Examples
    --------
    >>> round(robust_height(40.0, 40.0, 79.0, 0.0), 1), robust_height(40.0, 40.0, 79.0, 1.0)
    (12.5, 0.0)
    >>> round(robust_height(40.0, 40.0, 40.0, 1.0), 1)  # equilateral: 34.6 mm at no margin
    33.2
    """
    least = math.inf
    for da, db, dc in itertools.product((-margin_mm, margin_mm), repeat=3):
        try:
            _, (_, height) = place_references(
                d_ab_mm + da, d_ac_mm + db, d_bc_mm + dc, min_height_mm=0.0
            )
        except GeometryError:
            return 0.0
        least = min(least, height)
    return least


# ------------------------------------------------------------------ choosing the references

#: Candidate reference pairs of one seed A: ``{(b, c): (d_ab_mm, d_ac_mm, d_bc_mm)}``, listing
#: only pairs that see each other (the thesis's condition). ``b`` would go on the +x axis.
ReferenceCandidates = Mapping[tuple[Hashable, Hashable], tuple[float, float, float]]


def choose_references_max_angle(
    candidates: ReferenceCandidates, *, min_height_mm: float = 1.0
) -> tuple[tuple[Hashable, Hashable], float]:
    """The thesis's rule: the pair (B, C) that maximises the angle α = ∠BAC at the seed.

    Pairs whose triangle is degenerate for :func:`place_references` (C within
    ``min_height_mm`` of line AB, or no triangle at all) are skipped: they cannot make a
    frame. Ties go to the first such pair in the mapping's order.

    The rule favours obtuse triangles: as α grows towards π the angles at B and C shrink,
    and C's position, fixed by two circles that then cross at a shallow angle, becomes
    sensitive to distance noise. :func:`choose_references_best_conditioned` avoids that.

    Parameters
    ----------
    candidates : mapping ``{(b, c): (d_ab_mm, d_ac_mm, d_bc_mm)}``
        Measured distances of each pair of the seed's neighbours that see each other, mm.
    min_height_mm : float
        As in :func:`place_references`.

    Returns
    -------
    pair : tuple
        The chosen key ``(b, c)``.
    score : float
        Its angle α, radians.

    Raises
    ------
    GeometryError
        If no candidate forms a non-degenerate triangle (the seed can build no frame).

    Examples
    --------
    >>> candidates = {(1, 2): (40.0, 40.0, 40.0), (1, 3): (40.0, 40.0, 69.0)}
    >>> pair, alpha = choose_references_max_angle(candidates)
    >>> pair, round(math.degrees(alpha), 1)
    ((1, 3), 119.2)
    """
    return _choose_references(candidates, min_height_mm, _angle_score)


def choose_references_best_conditioned(
    candidates: ReferenceCandidates, *, min_height_mm: float = 1.0
) -> tuple[tuple[Hashable, Hashable], float]:
    """The widest triangle: the pair (B, C) that maximises the smallest altitude of ABC.

    The score is the triangle's width, its smallest altitude ``2 · area / longest side``
    (mm): the narrowest strip that holds A, B and C. Why this measures how well the frame
    will serve:

    - every robot of the seed's neighbourhood is first located from A, B and C, and a fix
      from ranges is worst across the direction in which its anchors are thinnest; a robot
      at distance r from the triangle inherits an error of about ``σ · r / width`` across
      it (the frame's axes tilt by σ over a lever arm of the width);
    - the width is small exactly when some angle of ABC is small, i.e. when a vertex is
      fixed by circles crossing at a shallow angle (C's error grows as 1/sin ∠ACB), which
      is the weakness of the thesis's maximal angle at A;
    - unlike the smallest angle or ``area / longest²``, it is not scale-free: of two
      similar triangles the larger wins, because the lever arms (the neighbourhood's
      radius) stay the same.

    Pairs whose triangle is degenerate for :func:`place_references` are skipped; ties go to
    the first such pair in the mapping's order.

    Parameters
    ----------
    candidates : mapping ``{(b, c): (d_ab_mm, d_ac_mm, d_bc_mm)}``
        Measured distances of each pair of the seed's neighbours that see each other, mm.
    min_height_mm : float
        As in :func:`place_references`.

    Returns
    -------
    pair : tuple
        The chosen key ``(b, c)``.
    score : float
        Its smallest altitude, mm.

    Raises
    ------
    GeometryError
        If no candidate forms a non-degenerate triangle (the seed can build no frame).

    Examples
    --------
    The thesis's rule takes the obtuse 40–40–69 triangle (α ≈ 119°, width 20 mm); this rule
    takes the equilateral one of side 69 mm (width 59.8 mm):

    >>> candidates = {(1, 2): (40.0, 40.0, 69.0), (3, 4): (69.0, 69.0, 69.0)}
    >>> pair, width = choose_references_best_conditioned(candidates)
    >>> pair, round(width, 1)
    ((3, 4), 59.8)
    >>> round(choose_references_best_conditioned({(1, 2): (40.0, 40.0, 69.0)})[1], 1)
    20.2
    """
    return _choose_references(candidates, min_height_mm, _width_score)


def _angle_score(d_ab: float, d_ac: float, d_bc: float, y_c: float) -> float:
    return angle_at(d_ab, d_ac, d_bc)


def _width_score(d_ab: float, d_ac: float, d_bc: float, y_c: float) -> float:
    # Area = |AB| · y_C / 2, so the smallest altitude 2·area/longest = |AB| · y_C / longest.
    return d_ab * y_c / max(d_ab, d_ac, d_bc)


def _choose_references(candidates, min_height_mm, score_of):
    best_pair, best_score = None, -math.inf
    for pair, (d_ab, d_ac, d_bc) in candidates.items():
        try:
            _, (_, y_c) = place_references(d_ab, d_ac, d_bc, min_height_mm=min_height_mm)
        except GeometryError:
            continue
        score = score_of(d_ab, d_ac, d_bc, y_c)
        if score > best_score:
            best_pair, best_score = pair, score
    if best_pair is None:
        raise GeometryError(
            f"none of {len(candidates)} candidate reference pairs forms a non-degenerate "
            f"triangle with the seed (min_height_mm={min_height_mm})"
        )
    return best_pair, float(best_score)


# --------------------------------------------------------------------------- multilateration

#: Why :func:`multilaterate` rejects a fix (``Fix.reason``), in the order it checks.
FIX_REASONS = (
    "too_few_anchors",
    "collinear_anchors",
    "large_residual",
    "poor_geometry",
    "mirror_ambiguity",
)

_TINY_MM = 1e-12
#: The mirror test's margin, in noise deviations: a competing fit must be worse by more
#: than (this · sigma)² in its sum of squared residuals (:func:`multilaterate`).
MIRROR_SIGMAS = 3.0


@dataclass(frozen=True, slots=True)
class Fix:
    """A position estimated from ranges, with the evidence for trusting it.

    Attributes
    ----------
    x_mm, y_mm : float
        The estimate in the anchors' frame, mm; NaN when none was computed (too few or
        collinear anchors).
    rmse_mm : float
        Root mean square of the range residuals ``|p − aᵢ| − rᵢ`` at the estimate, mm.
    gdop : float
        Geometric dilution of precision at the estimate, ``sqrt(trace((HᵀH)⁻¹))`` with the
        rows of H the unit vectors from the anchors to the estimate: with independent range
        noise σ the estimate's RMS error is about ``σ · gdop``. ``inf`` when the anchors see
        the point along one line only.
    mirror_rmse_mm : float
        ``rmse_mm`` of the best estimate on the other side of the anchors' best-fit line when
        that side holds a distinct local fit, mm; NaN when it holds none.
    anchors : int
        Number of anchors used.
    ok : bool
        Whether the fix passed every check.
    reason : str
        ``""`` when ``ok``, otherwise the first failed check, one of :data:`FIX_REASONS`.
    """

    x_mm: float
    y_mm: float
    rmse_mm: float
    gdop: float
    mirror_rmse_mm: float
    anchors: int
    ok: bool
    reason: str


def multilaterate(
    anchors_mm: np.ndarray,
    ranges_mm: np.ndarray,
    *,
    sigma_mm: float = 1.0,
    max_rmse_mm: float | None = None,
    max_gdop: float = 5.0,
    min_anchor_width_mm: float | None = None,
    mirror_sigmas: float = MIRROR_SIGMAS,
) -> Fix:
    """Least-squares position from ranges to k anchors, rejected with a reason when unreliable.

    The linearised system (:func:`linear_position`) gives the start; Levenberg–Marquardt on
    the range residuals ``|p − aᵢ| − rᵢ`` refines it. The fix is then checked, in this order:

    1. ``too_few_anchors``: fewer than 3 anchors.
    2. ``collinear_anchors``: all anchors lie within ``min_anchor_width_mm`` of one line
       (their total-least-squares line), so the ranges cannot tell the two sides apart.
    3. ``large_residual``: residual RMSE above ``max_rmse_mm`` (ranges inconsistent with
       any point: an outlier, or an anchor that is not where it claims to be).
    4. ``poor_geometry``: GDOP above ``max_gdop`` (anchors seen from nearly one direction).
    5. ``mirror_ambiguity``: the reflection of the estimate across the anchors' best-fit line
       starts a second, distinct local fit (more than ``sigma_mm`` away) whose residual sum of
       squares exceeds the best's by less than ``(mirror_sigmas · sigma_mm)²`` — a likelihood
       ratio the noise could produce. This is the near-collinear case: with exactly three
       nearly collinear anchors the mirror image fits almost equally well. Whichever of the
       two fits better is reported.

    The thesis's localisation ("a robot that sees seed S and ≥ 2 robots located in S's
    frame"): the seed is an anchor too, at (0, 0) in its own frame, so there are ≥ 3 anchors
    in total; pass it with the others.

    Parameters
    ----------
    anchors_mm : (k, 2) array
        Anchor positions in one frame, mm.
    ranges_mm : (k,) array
        Measured distances to them, mm (non-negative).
    sigma_mm : float
        Standard deviation of a range measurement, mm (positive). Sets the defaults below.
    max_rmse_mm : float, optional
        Largest accepted residual RMSE, mm; default ``3 · sigma_mm``.
    max_gdop : float
        Largest accepted GDOP (dimensionless; about 1.15 inside a well-spread triangle).
    min_anchor_width_mm : float, optional
        Anchors within this distance of one line count as collinear, mm; default
        ``sigma_mm`` (the anchors' own positions are no better than that).
    mirror_sigmas : float
        Margin of the mirror test, in units of ``sigma_mm``.

    Returns
    -------
    Fix
        The estimate and its evidence; ``ok`` and ``reason`` say whether to use it.

    Raises
    ------
    ValueError
        If the shapes disagree, a value is not finite, a range is negative or a threshold
        is not positive (programming errors, not bad geometry).

    Examples
    --------
    >>> anchors = np.array([[0.0, 0.0], [60.0, 0.0], [10.0, 50.0]])
    >>> ranges = np.hypot(*(anchors - [30.0, 20.0]).T)
    >>> fix = multilaterate(anchors, ranges)
    >>> round(fix.x_mm, 6), round(fix.y_mm, 6), fix.ok, fix.reason
    (30.0, 20.0, True, '')
    >>> line = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    >>> multilaterate(line, np.hypot(*(line - [30.0, 20.0]).T)).reason
    'collinear_anchors'
    >>> multilaterate(anchors[:2], ranges[:2]).reason
    'too_few_anchors'
    """
    anchors = np.asarray(anchors_mm, dtype=float)
    ranges = np.asarray(ranges_mm, dtype=float)
    if anchors.ndim != 2 or anchors.shape[1] != 2 or ranges.shape != (len(anchors),):
        raise ValueError(
            f"anchors_mm must be (k, 2) and ranges_mm (k,); got {anchors.shape} and {ranges.shape}"
        )
    if not (np.isfinite(anchors).all() and np.isfinite(ranges).all()):
        raise ValueError("anchors_mm and ranges_mm must be finite")
    if (ranges < 0).any():
        raise ValueError(f"ranges_mm must be non-negative; got {ranges.tolist()}")
    if not sigma_mm > 0:
        raise ValueError(f"sigma_mm must be positive; got {sigma_mm}")
    max_rmse = 3.0 * sigma_mm if max_rmse_mm is None else max_rmse_mm
    min_width = sigma_mm if min_anchor_width_mm is None else min_anchor_width_mm
    k = len(anchors)

    def reject(reason, p=(math.nan, math.nan), rmse=math.nan, gdop=math.inf, mirror=math.nan):
        return Fix(float(p[0]), float(p[1]), rmse, gdop, mirror, k, False, reason)

    if k < 3:
        return reject("too_few_anchors")
    if collinear(anchors, min_width_mm=min_width):
        return reject("collinear_anchors")
    centre = anchors.mean(axis=0)
    (ux, uy), _ = _best_fit_line(anchors.tolist())  # the line collinear() measured
    normal = np.array([-uy, ux])

    scale = 1.0 + float(np.abs(anchors).max()) + float(ranges.max())
    tol = 1e-9 * scale
    start, _ = linear_position(anchors, ranges)
    best, best_ssr = _refine_position(anchors, ranges, start, tol)

    mirror_ssr = math.nan
    reflected = best - 2.0 * ((best - centre) @ normal) * normal
    if np.hypot(*(reflected - best)) > sigma_mm:
        other, other_ssr = _refine_position(anchors, ranges, reflected, tol)
        if np.hypot(*(other - best)) > sigma_mm:
            if other_ssr < best_ssr:
                best, best_ssr, other_ssr = other, other_ssr, best_ssr
            mirror_ssr = other_ssr

    rmse = math.sqrt(best_ssr / k)
    mirror_rmse = math.sqrt(mirror_ssr / k) if math.isfinite(mirror_ssr) else math.nan
    gdop = _gdop(anchors, best)
    args = {"p": best, "rmse": rmse, "gdop": gdop, "mirror": mirror_rmse}
    if rmse > max_rmse:
        return reject("large_residual", **args)
    if gdop > max_gdop:
        return reject("poor_geometry", **args)
    if math.isfinite(mirror_ssr) and mirror_ssr - best_ssr < (mirror_sigmas * sigma_mm) ** 2:
        return reject("mirror_ambiguity", **args)
    return Fix(float(best[0]), float(best[1]), rmse, gdop, mirror_rmse, k, True, "")


def _range_residuals(anchors, ranges, x, y):
    dx, dy = x - anchors[:, 0], y - anchors[:, 1]
    dist = np.sqrt(dx * dx + dy * dy)
    res = dist - ranges
    return dx, dy, dist, res, float(res @ res)


def _refine_position(
    anchors: np.ndarray, ranges: np.ndarray, start: np.ndarray, tol_mm: float
) -> tuple[np.ndarray, float]:
    """Levenberg–Marquardt on the range residuals from ``start``; returns (p, SSR in mm²).

    The 2×2 normal equations are solved in closed form: this runs once or twice per fix
    and per robot, so numpy's per-call overhead would dominate.
    (The island solve's fit of a rigid motion, three unknowns, is its own:
    :mod:`kilonet.protocols.localize.island_solve`.)
    """
    x, y = float(start[0]), float(start[1])
    dx, dy, dist, res, ssr = _range_residuals(anchors, ranges, x, y)
    damping = 1e-6
    for _ in range(100):
        inv = 1.0 / np.maximum(dist, _TINY_MM)
        jx, jy = dx * inv, dy * inv
        hxx, hxy, hyy = float(jx @ jx), float(jx @ jy), float(jy @ jy)
        gx, gy = float(jx @ res), float(jy @ res)
        level = 0.5 * (hxx + hyy) + _TINY_MM
        while True:
            axx, ayy = hxx + damping * level, hyy + damping * level
            det = axx * ayy - hxy * hxy
            if det > 0:
                sx = (-gx * ayy + gy * hxy) / det
                sy = (-gy * axx + gx * hxy) / det
                t_dx, t_dy, t_dist, t_res, t_ssr = _range_residuals(anchors, ranges, x + sx, y + sy)
                if t_ssr <= ssr:
                    break
            damping *= 10.0
            if damping > 1e12:  # no descent direction left: (x, y) is a minimum to rounding
                return np.array([x, y]), ssr
        x, y, dx, dy, dist, res, ssr = x + sx, y + sy, t_dx, t_dy, t_dist, t_res, t_ssr
        damping = max(damping / 10.0, 1e-12)
        if math.hypot(sx, sy) < tol_mm:
            break
    return np.array([x, y]), ssr


def _gdop(anchors: np.ndarray, p: np.ndarray) -> float:
    diff = p - anchors
    units = diff / np.maximum(np.sqrt((diff * diff).sum(axis=1)), _TINY_MM)[:, None]
    info = units.T @ units
    det = float(np.linalg.det(info))
    trace = float(np.trace(info))
    if det <= 1e-12 * trace * trace:
        return math.inf
    return math.sqrt(trace / det)  # trace of the inverse of a 2×2 matrix
