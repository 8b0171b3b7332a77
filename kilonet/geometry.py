"""Plane geometry the robots compute with: frames of three, trilateration, multilateration.

Pure functions on millimetres. Robots call them on their measured distances; metrics call
them on ground truth. Degenerate inputs are reported, never silently accepted.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "GeometryError",
    "frame_of_three",
    "trilaterate_in_frame",
    "trilaterate_linear",
]


class GeometryError(ValueError):
    """The distances or anchors do not determine a position (degenerate or inconsistent)."""


def frame_of_three(d12_mm: float, d13_mm: float, d23_mm: float) -> tuple[float, float]:
    """Coordinates of robot 3 in the frame with robot 1 at the origin and robot 2 on +x.

    ``x3 = (d13² − d23² + d12²) / (2 d12)``, ``y3 = √(d13² − x3²)`` (taken positive, so the
    frame may be a mirror image of the floor).

    Raises
    ------
    GeometryError
        If ``d12`` is zero, or the three distances violate the triangle inequality beyond
        rounding (``d13² < x3²`` by more than 1 mm²).

    Examples
    --------
    >>> frame_of_three(40.0, 40.0, 40.0)
    (20.0, 34.64101615137755)
    """
    if d12_mm <= 0:
        raise GeometryError(f"d12 = {d12_mm} mm: robots 1 and 2 coincide")
    x3 = (d13_mm**2 - d23_mm**2 + d12_mm**2) / (2 * d12_mm)
    y3_sq = d13_mm**2 - x3**2
    if y3_sq < -1.0:
        raise GeometryError(
            f"distances d12={d12_mm}, d13={d13_mm}, d23={d23_mm} mm form no triangle"
        )
    return float(x3), math.sqrt(max(0.0, y3_sq))


def trilaterate_in_frame(
    d1_mm: float, d2_mm: float, d3_mm: float, d12_mm: float, x3_mm: float, y3_mm: float
) -> tuple[float, float]:
    """Position of a fourth robot from its distances to robots 1, 2, 3 of a frame of three.

    ``x4 = (d1² − d2² + d12²) / (2 d12)``,
    ``y4 = (d1² − d3² + x3² + y3²) / (2 y3) − x3 x4 / y3``.

    Raises
    ------
    GeometryError
        If ``d12`` or ``y3`` is zero (robots 1, 2, 3 collinear: no frame).

    Examples
    --------
    >>> x3, y3 = frame_of_three(40.0, 40.0, 40.0)
    >>> frame = np.array([[0.0, 0.0], [40.0, 0.0], [x3, y3]])
    >>> d1, d2, d3 = np.hypot(*(frame - [25.0, 10.0]).T)
    >>> [round(v, 9) for v in trilaterate_in_frame(d1, d2, d3, 40.0, x3, y3)]
    [25.0, 10.0]
    """
    if d12_mm <= 0:
        raise GeometryError(f"d12 = {d12_mm} mm: robots 1 and 2 coincide")
    if abs(y3_mm) < 1e-9:
        raise GeometryError("robots 1, 2 and 3 are collinear (y3 = 0): no frame")
    x4 = (d1_mm**2 - d2_mm**2 + d12_mm**2) / (2 * d12_mm)
    y4 = (d1_mm**2 - d3_mm**2 + x3_mm**2 + y3_mm**2) / (2 * y3_mm) - x3_mm * x4 / y3_mm
    return float(x4), float(y4)


def trilaterate_linear(anchors_mm: np.ndarray, ranges_mm: np.ndarray) -> tuple[float, float]:
    """Position from three anchors at known points and the ranges to them (linear form).

    With anchors (xᵢ, yᵢ) and ranges rᵢ: A = 2(x₂−x₁), B = 2(y₂−y₁),
    C = r₁² − r₂² − x₁² + x₂² − y₁² + y₂², D = 2(x₃−x₂), E = 2(y₃−y₂),
    F = r₂² − r₃² − x₂² + x₃² − y₂² + y₃²; x = (CE − FB)/(EA − BD), y = (CD − AF)/(BD − AE).

    Raises
    ------
    GeometryError
        If the three anchors are collinear (``EA − BD = 0``).

    Examples
    --------
    >>> anchors = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 100.0]])
    >>> truth = np.array([30.0, 40.0])
    >>> ranges = np.hypot(*(anchors - truth).T)
    >>> [round(v, 9) for v in trilaterate_linear(anchors, ranges)]
    [30.0, 40.0]
    """
    (x1, y1), (x2, y2), (x3, y3) = np.asarray(anchors_mm, dtype=float)[:3]
    r1, r2, r3 = np.asarray(ranges_mm, dtype=float)[:3]
    a, b = 2 * (x2 - x1), 2 * (y2 - y1)
    c = r1**2 - r2**2 - x1**2 + x2**2 - y1**2 + y2**2
    d, e = 2 * (x3 - x2), 2 * (y3 - y2)
    f = r2**2 - r3**2 - x2**2 + x3**2 - y2**2 + y3**2
    det = e * a - b * d
    if abs(det) < 1e-9:
        raise GeometryError("the three anchors are collinear: no unique position")
    return float((c * e - f * b) / det), float((c * d - a * f) / (b * d - a * e))
