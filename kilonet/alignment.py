"""Rigid transforms between robot frames: estimating, halving, composing, packing them.

The math of phase 6 (frame merging) and of the position metrics. A frame transform is a pair
``(rotation, shift)``: a :class:`scipy.spatial.transform.Rotation` in 3-D and a shift vector of
3 millimetres, acting as ``x_global = R x_local + v`` on points of the table embedded at
z = 0. The thesis writes a seed's transform as ``R (x − v_thesis)``; the two forms are the
same transform with ``v = −R v_thesis``.

Why 3-D: a local frame may be the mirror image of another (each seed takes its C with y > 0).
No plane rotation turns one into the other, but a 180° rotation about an axis in the plane
does, and rotations interpolate (SLERP), so seeds can move halfway towards each other round
after round. While frames converge they may tilt out of the table's plane; :func:`level`
turns a converged transform back into plane coordinates.

- Estimating: :func:`rotation_between_frames` (Kabsch), :func:`procrustes_rmse` (metrics).
- Moving: :func:`half_map` (a merging step), :func:`half_step`, :func:`compose`,
  :func:`invert`, :func:`apply_3d`, :func:`apply_2d`, :func:`level`, :func:`transform_distance`.
- Messages: :func:`pack_quaternion`, :func:`unpack_quaternion` (three int16 words).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from kilonet.geometry import GeometryError

__all__ = [
    "QUATERNION_MAX_ANGLE_ERROR_RAD",
    "apply_2d",
    "apply_3d",
    "compose",
    "half_map",
    "half_step",
    "invert",
    "level",
    "level_matrix",
    "level_turn",
    "pack_quaternion",
    "procrustes_rmse",
    "rotation_between_frames",
    "transform_distance",
    "unpack_quaternion",
    "words_matrix",
]


def _points3(points_mm: np.ndarray, name: str) -> np.ndarray:
    """(k, 2) or (k, 3) points as (k, 3) floats (z = 0 for plane points)."""
    pts = np.asarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise ValueError(f"{name} must be a (k, 2) or (k, 3) array; got shape {pts.shape}")
    if pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    return pts


def _shift3(shift_mm: np.ndarray) -> np.ndarray:
    v = np.asarray(shift_mm, dtype=float).ravel()
    if v.shape not in ((2,), (3,)):
        raise ValueError(f"shift must have 2 or 3 components; got shape {v.shape}")
    return np.append(v, 0.0) if len(v) == 2 else v


def _width_across_line(points: np.ndarray) -> float:
    """Largest distance of the points from their best-fit line, mm."""
    centred = points - points.mean(axis=0)
    _, axes = np.linalg.eigh(centred.T @ centred)
    along = centred @ axes[:, -1]  # the principal direction: largest eigenvalue
    return float(np.sqrt(((centred - np.outer(along, axes[:, -1])) ** 2).sum(axis=1)).max())


# --------------------------------------------------------------------------------- estimate


def rotation_between_frames(
    points_a: np.ndarray, points_b: np.ndarray, *, min_width_mm: float = 1e-6
) -> tuple[Rotation, np.ndarray]:
    """The rigid 3-D transform that maps frame-a coordinates of robots onto their frame-b ones.

    Finds ``(R, v)`` minimising ``Σ |R aᵢ + v − bᵢ|²`` over proper rotations (Kabsch, with
    :meth:`Rotation.align_vectors` on the centred points) and ``v = b̄ − R ā``. Plane points
    are embedded at z = 0; because ``R`` is a 3-D rotation, frames that are mirror images of
    each other are matched too, by a 180° rotation about an axis in the plane.

    The thesis proposes TRIAD instead: build an orthonormal triad from two of the three
    members' difference vectors in each frame and take the rotation between the triads. It
    uses only two directions and trusts the first exactly; Kabsch weighs all k points and is
    the least-squares optimum, and equals TRIAD for noiseless points.

    Parameters
    ----------
    points_a, points_b : (k, 2) or (k, 3) arrays
        The same k ≥ 3 robots in frame a and in frame b, mm (3-D when the frames are already
        tilted by earlier merging rounds).
    min_width_mm : float
        The points of either frame must stray at least this far from a line, mm; collinear
        points leave the rotation about that line undetermined.

    Returns
    -------
    rotation : scipy.spatial.transform.Rotation
    shift : (3,) array
        mm; ``points_b ≈ rotation.apply(points_a) + shift``.

    Raises
    ------
    GeometryError
        If fewer than 3 points are given or the points of a frame are collinear.
    ValueError
        If the arrays' shapes differ or are not (k, 2) / (k, 3).

    Examples
    --------
    Frame b is frame a turned by 90° and shifted by (5, 0):

    >>> a = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0]])
    >>> b = a @ np.array([[0.0, 1.0], [-1.0, 0.0]]) + [5.0, 0.0]
    >>> rot, shift = rotation_between_frames(a, b)
    >>> round(float(np.degrees(rot.magnitude())), 6), (shift.round(6) + 0.0).tolist()
    (90.0, [5.0, 0.0, 0.0])

    A mirror image (y → −y) is turned over about the x axis:

    >>> rot, shift = rotation_between_frames(a, a * [1.0, -1.0])
    >>> (rot.as_rotvec().round(6) + 0.0).tolist()
    [3.141593, 0.0, 0.0]
    """
    a, b = _points3(points_a, "points_a"), _points3(points_b, "points_b")
    if a.shape != b.shape:
        raise ValueError(f"points_a and points_b differ in shape: {a.shape} vs {b.shape}")
    if len(a) < 3:
        raise GeometryError(f"{len(a)} points cannot fix a rotation (need at least 3)")
    for name, pts in (("a", a), ("b", b)):
        width = _width_across_line(pts)
        if width < min_width_mm:
            raise GeometryError(
                f"the points of frame {name} are collinear (within {width:.3g} mm of a line; "
                f"need {min_width_mm} mm): the rotation about that line is undetermined"
            )
    centre_a, centre_b = a.mean(axis=0), b.mean(axis=0)
    rotation = _horn_rotation(a - centre_a, b - centre_b)
    return rotation, centre_b - rotation.apply(centre_a)


def _horn_rotation(a: np.ndarray, b: np.ndarray) -> Rotation:
    """The proper rotation R minimising ``Σ |R aᵢ − bᵢ|²`` for centred (k, 3) points.

    Horn's closed form (J. Opt. Soc. Am. A 4, 1987): the best unit quaternion is the top
    eigenvector of a symmetric 4×4 matrix built from ``Σ aᵢ bᵢᵀ``. Same optimum as Kabsch
    (``Rotation.align_vectors``) at a tenth of its cost, which matters because every merging
    round computes one.
    """
    w, x, y, z = _horn_quaternion((a.T @ b).tolist())
    return Rotation.from_quat([x, y, z, w])


def _horn_quaternion(s: list[list[float]]) -> tuple[float, float, float, float]:
    """Horn's best unit quaternion ``(w, x, y, z)``, ``w ≥ 0``, from ``Σ aᵢ bᵢᵀ`` (3×3)."""
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = s
    n = np.array(
        [
            [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
            [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
            [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
            [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
        ]
    )
    _, vectors = np.linalg.eigh(n)
    w, x, y, z = vectors[:, -1].tolist()
    return (w, x, y, z) if w >= 0 else (-w, -x, -y, -z)


def _quaternion_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The 3×3 matrix of the unit quaternion ``(w, x, y, z)``."""
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


_MIN_WIDTH_MM = 1e-6  # half_map's collinearity threshold, as rotation_between_frames's default


def _dot(u: list[float], v: list[float]) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _centroid(points: list[list[float]]) -> list[float]:
    return [sum(c) / len(points) for c in zip(*points, strict=True)]


def _centred(points: list[list[float]], centre: list[float]) -> list[list[float]]:
    return [[c - m for c, m in zip(p, centre, strict=True)] for p in points]


def _width_across_centroid_line(centred: list[list[float]]) -> float:
    """The largest distance of centred points from the line through the centroid and the
    farthest point, mm: zero exactly when all lie on one line."""
    far = max(centred, key=lambda p: _dot(p, p))
    far_sq = _dot(far, far)
    if far_sq == 0.0:
        return 0.0
    fx, fy, fz = far
    cross_sq = max(
        (y * fz - z * fy) ** 2 + (z * fx - x * fz) ** 2 + (x * fy - y * fx) ** 2
        for x, y, z in centred
    )
    return math.sqrt(cross_sq / far_sq)


def half_map(
    points_i: np.ndarray, points_k: np.ndarray, fraction: float = 0.5
) -> tuple[Rotation, np.ndarray, float]:
    """A fraction (default half) of the rigid map taking points in frame I onto the same
    robots in frame K: the merging step of phase 6.

    The same as :func:`half_step` of :func:`rotation_between_frames`, turning about the
    points' centroid in frame I, but computed on the quaternion directly: a merging-group
    member computes one per query, and this is a tenth of the cost of going through
    ``Rotation`` objects.

    Parameters
    ----------
    points_i, points_k : (k, 2) or (k, 3) arrays
        The same k ≥ 3 robots' "global" positions through I's and K's transforms, mm.
    fraction : float
        0 stays, 0.5 goes half way (the thesis), 1 goes all the way.

    Returns
    -------
    rotation, shift, disagreement_mm
        ``R_H`` (the fraction of the rotation, SLERP from the identity), ``t_H`` moving the
        centroid by the same fraction, and the disagreement of the two transforms: the
        farthest the full rigid map moves one of the robots. (Not the largest distance between
        a robot's two positions: that also holds the members' own position errors, which no
        transform removes, so it would never fall below them.)

    Raises
    ------
    GeometryError
        If fewer than 3 points are given or the points of a frame are collinear.
    ValueError
        If the arrays' shapes differ or are not (k, 2) / (k, 3), or ``fraction`` is outside
        [0, 1].

    Examples
    --------
    A frame K that is I turned by 90° about z and shifted by 10 mm along x:

    >>> p_i = np.array([[0.0, 0, 0], [40, 0, 0], [0, 40, 0]])
    >>> turn = Rotation.from_euler("z", 90, degrees=True)
    >>> p_k = turn.apply(p_i) + [10.0, 0, 0]
    >>> r_h, t_h, err = half_map(p_i, p_k)
    >>> round(float(np.degrees(r_h.magnitude())), 6), round(err, 3)
    (45.0, 50.0)
    """
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1]; got {fraction}")
    a, b = _points3(points_i, "points_i"), _points3(points_k, "points_k")
    if a.shape != b.shape:
        raise ValueError(f"points_i and points_k differ in shape: {a.shape} vs {b.shape}")
    if len(a) < 3:
        raise GeometryError(f"{len(a)} points cannot fix a rotation (need at least 3)")
    # A handful of points: plain floats cost a fraction of NumPy's per-call overhead.
    pa, pb = a.tolist(), b.tolist()
    centre_a, centre_b = _centroid(pa), _centroid(pb)
    ac, bc = _centred(pa, centre_a), _centred(pb, centre_b)
    for name, pts in (("I", ac), ("K", bc)):
        width = _width_across_centroid_line(pts)
        if width < _MIN_WIDTH_MM:
            raise GeometryError(
                f"the points of frame {name} are collinear (within {width:.3g} mm of a line)"
            )
    corr = [
        [sum(p[r] * q[c] for p, q in zip(ac, bc, strict=True)) for c in range(3)] for r in range(3)
    ]
    w, x, y, z = _horn_quaternion(corr)
    # The full map moves a point p to R (p − c_a) + c_b.
    full = _quaternion_matrix(w, x, y, z).tolist()
    disagreement = max(
        math.dist([_dot(row, p) + c for row, c in zip(full, centre_b, strict=True)], q)
        for p, q in zip(ac, pa, strict=True)
    )
    # SLERP from the identity: the same axis, `fraction` of the angle (w ≥ 0: the short arc).
    sin_half = math.sqrt(x * x + y * y + z * z)
    angle = fraction * math.atan2(sin_half, w)
    scale = math.sin(angle) / sin_half if sin_half > 0 else 0.0
    quat = (math.cos(angle), x * scale, y * scale, z * scale)
    partial = _quaternion_matrix(*quat).tolist()
    shift = np.array(
        [
            ca + fraction * (cb - ca) - _dot(row, centre_a)
            for row, ca, cb in zip(partial, centre_a, centre_b, strict=True)
        ]
    )
    return Rotation.from_quat([*quat[1:], quat[0]]), shift, disagreement


def procrustes_rmse(
    estimated_mm: np.ndarray, true_mm: np.ndarray, *, allow_reflection: bool = True
) -> tuple[float, float, np.ndarray]:
    """Position error after the best rigid alignment of estimated positions onto the truth.

    Finds the orthogonal map Q (a rotation, or also a reflection when allowed) and shift t
    minimising ``Σ |Q eᵢ + t − pᵢ|²`` (no scaling: distances are measured, so scale is
    known), then reports the residual distances.

    Parameters
    ----------
    estimated_mm : (N, 2) array
        Estimated positions in any frame, mm.
    true_mm : (N, 2) array
        True positions of the same robots, mm.
    allow_reflection : bool
        Whether Q may be a reflection (a local frame may be a mirror image of the floor).

    Returns
    -------
    rmse_mm : float
        ``sqrt(mean |aligned − true|²)``, mm.
    max_mm : float
        Largest single distance, mm.
    aligned : (N, 2) array
        The estimates after alignment, mm.

    Raises
    ------
    ValueError
        If the shapes differ, are not (N, 2), N is 0, or a value is not finite.

    Examples
    --------
    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0]])
    >>> mirrored = truth * [-1.0, 1.0] + [100.0, 7.0]
    >>> rmse, worst, aligned = procrustes_rmse(mirrored, truth)
    >>> round(rmse, 9), round(worst, 9)
    (0.0, 0.0)
    >>> [round(v, 3) for v in procrustes_rmse(mirrored, truth, allow_reflection=False)[:2]]
    [22.219, 30.624]
    """
    est = np.asarray(estimated_mm, dtype=float)
    true = np.asarray(true_mm, dtype=float)
    if est.ndim != 2 or est.shape[1] != 2 or est.shape != true.shape or len(est) == 0:
        raise ValueError(
            f"estimated_mm and true_mm must both be (N, 2) with N > 0; got {est.shape} and "
            f"{true.shape}"
        )
    if not (np.isfinite(est).all() and np.isfinite(true).all()):
        raise ValueError("estimated_mm and true_mm must be finite")
    centre_e, centre_t = est.mean(axis=0), true.mean(axis=0)
    e, t = est - centre_e, true - centre_t
    u, _, vt = np.linalg.svd(t.T @ e)
    if not allow_reflection and np.linalg.det(u @ vt) < 0:
        u[:, -1] = -u[:, -1]
    q = u @ vt  # maps centred estimates onto centred truth
    aligned = e @ q.T + centre_t
    dist = np.sqrt(((aligned - true) ** 2).sum(axis=1))
    return float(np.sqrt((dist**2).mean())), float(dist.max()), aligned


# ------------------------------------------------------------------------------------- move


def half_step(
    rotation: Rotation,
    shift_mm: np.ndarray,
    fraction: float = 0.5,
    *,
    about_mm: np.ndarray | None = None,
) -> tuple[Rotation, np.ndarray]:
    """A fraction of a rigid transform: SLERP from the identity and the same share of the move.

    The thesis's merging step. A merging-group member measures the correction ``(D, d)``
    that maps seed I's global coordinates of its group onto seed K's
    (:func:`rotation_between_frames` on the members' positions through both seeds'
    transforms). Applying all of it would make I and K swap places round after round, since
    K moves towards I at the same time; instead I applies ``(S, s) = half_step(D, d)``
    after its own transform::

        R_I, v_I = compose(S, s, R_I, v_I)   # x_global = S (R_I x_local + v_I) + s

    ``S`` is the rotation a ``fraction`` of the way from the identity to ``D`` along the
    shortest arc (:class:`scipy.spatial.transform.Slerp`), so its angle is ``fraction``
    times D's. With ``about_mm=None`` the shift is ``fraction · d`` — the thesis's
    ``v_shift / 2`` — and S turns about the global origin. With ``about_mm = c`` (say the
    centroid of the group's points in I's global coordinates) S turns about c instead and c
    moves exactly ``fraction`` of the way to its image ``D c + d``: ``s = c + fraction ·
    (D c + d − c) − S c``. Turning about the group avoids swinging distant frames about a
    far-away origin. Either way ``fraction = 1`` gives ``(D, d)`` and ``0`` the identity.

    Parameters
    ----------
    rotation : Rotation
        The full rotation D.
    shift_mm : (2,) or (3,) array
        The full shift d, mm.
    fraction : float
        Share of the transform to apply, in [0, 1].
    about_mm : (2,) or (3,) array, optional
        Point to turn about, mm; default the origin.

    Returns
    -------
    rotation : Rotation
    shift : (3,) array
        mm.

    Raises
    ------
    ValueError
        If ``fraction`` is outside [0, 1] or a vector has the wrong length.

    Examples
    --------
    >>> rot, shift = half_step(Rotation.from_euler("z", 90, degrees=True), [10.0, 0.0])
    >>> round(float(np.degrees(rot.magnitude())), 6), shift.tolist()
    (45.0, [5.0, 0.0, 0.0])

    Half of turning a mirror image over (180° about the x axis) stands the frame on edge:

    >>> rot, _ = half_step(Rotation.from_rotvec([np.pi, 0.0, 0.0]), [0.0, 0.0])
    >>> rot.apply([0.0, 1.0, 0.0]).round(6).tolist()
    [0.0, 0.0, 1.0]
    """
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1]; got {fraction}")
    full_shift = _shift3(shift_mm)
    # Slerp from the identity to D, evaluated at `fraction`: the same turn about D's axis by
    # `fraction` of D's angle (shortest arc; tested against scipy's Slerp). Scaling the
    # rotation vector costs a fiftieth of building a Slerp, and merging does it every round.
    partial = Rotation.from_rotvec(fraction * rotation.as_rotvec())
    if about_mm is None:
        return partial, fraction * full_shift
    centre = _shift3(about_mm)
    target = rotation.as_matrix() @ centre + full_shift
    return partial, centre + fraction * (target - centre) - partial.as_matrix() @ centre


def compose(
    rotation_1: Rotation, shift_1: np.ndarray, rotation_2: Rotation, shift_2: np.ndarray
) -> tuple[Rotation, np.ndarray]:
    """Transform 2 followed by transform 1: ``x ↦ R₁ (R₂ x + v₂) + v₁``.

    The same order as ``rotation_1 * rotation_2`` in scipy (the right one acts first).

    Returns
    -------
    rotation : Rotation
        ``R₁ R₂``.
    shift : (3,) array
        ``R₁ v₂ + v₁``, mm.

    Examples
    --------
    >>> quarter = Rotation.from_euler("z", 90, degrees=True)
    >>> rot, shift = compose(quarter, [0.0, 0.0], Rotation.identity(), [10.0, 0.0])
    >>> shift.round(9).tolist()
    [0.0, 10.0, 0.0]
    """
    return rotation_1 * rotation_2, rotation_1.apply(_shift3(shift_2)) + _shift3(shift_1)


def invert(rotation: Rotation, shift_mm: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """The inverse transform: ``x ↦ R⁻¹ (x − v)``.

    Examples
    --------
    >>> rot = Rotation.from_euler("z", 30, degrees=True)
    >>> back, back_shift = invert(rot, [3.0, 4.0])
    >>> apply_2d(back, back_shift, apply_2d(rot, [3.0, 4.0], [[1.0, 1.0]])).round(9).tolist()
    [[1.0, 1.0]]
    """
    inverse = rotation.inv()
    return inverse, -inverse.apply(_shift3(shift_mm))


def apply_3d(rotation: Rotation, shift_mm: np.ndarray, points_mm: np.ndarray) -> np.ndarray:
    """Transform points: ``R p + v``, plane points embedded at z = 0.

    Parameters
    ----------
    rotation : Rotation
    shift_mm : (2,) or (3,) array
        mm.
    points_mm : (k, 2) or (k, 3) array
        mm.

    Returns
    -------
    (k, 3) array
        mm.

    Examples
    --------
    >>> quarter_about_x = Rotation.from_rotvec([np.pi / 2, 0.0, 0.0])
    >>> (apply_3d(quarter_about_x, [0.0, 0.0], [[0.0, 10.0]]).round(9) + 0.0).tolist()
    [[0.0, 0.0, 10.0]]
    """
    return rotation.apply(_points3(points_mm, "points_mm")) + _shift3(shift_mm)


def apply_2d(
    rotation: Rotation,
    shift_mm: np.ndarray,
    points_mm: np.ndarray,
    *,
    z_tol_mm: float | None = 1e-6,
) -> np.ndarray:
    """Transform plane points and return their x, y; refuse if they leave the plane.

    Parameters
    ----------
    rotation : Rotation
    shift_mm : (2,) or (3,) array
        mm.
    points_mm : (k, 2) or (k, 3) array
        mm.
    z_tol_mm : float or None
        Largest accepted |z| of a transformed point, mm; ``None`` drops z unchecked (use
        :func:`apply_3d` to keep it, :func:`level` to bring a tilted frame back down).

    Returns
    -------
    (k, 2) array
        mm.

    Raises
    ------
    GeometryError
        If a transformed point lies more than ``z_tol_mm`` off the plane z = 0.

    Examples
    --------
    >>> quarter = Rotation.from_euler("z", 90, degrees=True)
    >>> apply_2d(quarter, [1.0, 0.0], [[10.0, 0.0]]).round(9).tolist()
    [[1.0, 10.0]]
    >>> apply_2d(Rotation.from_euler("x", 90, degrees=True), [0.0, 0.0], [[0.0, 10.0]])
    Traceback (most recent call last):
    ...
    kilonet.geometry.GeometryError: transformed points leave the plane: |z| up to 10 mm ...
    """
    moved = apply_3d(rotation, shift_mm, points_mm)
    if z_tol_mm is not None and len(moved):
        worst = float(np.abs(moved[:, 2]).max())
        if worst > z_tol_mm:
            raise GeometryError(
                f"transformed points leave the plane: |z| up to {worst:.3g} mm "
                f"(tolerance {z_tol_mm} mm)"
            )
    return moved[:, :2]


#: Reference direction for :func:`level`'s choice of which side of a plane is up. Generic on
#: purpose: merged mirror-image frames end standing on edge, with normals in the table's
#: plane, and a normal perpendicular to the reference would make the choice ill-defined.
_LEVEL_UP = np.array([0.26726124191242440, 0.53452248382484879, 0.80178372573727319])


def level_turn(rotation: Rotation) -> Rotation:
    """The turn Q of :func:`level`: the shortest rotation taking the normal of the plane that
    ``rotation`` maps z = 0 onto, on the side of a fixed generic direction, to +z.

    Global coordinates ``g`` read in the plane laid flat are ``(Q g)[:2]`` (up to the plane's
    height in ``(Q g)[2]``). :func:`level_matrix` gives Q's matrix from ``rotation``'s.

    Examples
    --------
    >>> q = level_turn(Rotation.from_euler("x", -90, degrees=True))
    >>> q.apply([0.0, 1.0, 0.0]).round(9).tolist()  # the tilted plane's normal, laid upright
    [0.0, 0.0, 1.0]
    """
    return Rotation.from_matrix(level_matrix(rotation.as_matrix()))


def level_matrix(matrix: np.ndarray) -> np.ndarray:
    """The 3×3 matrix of :func:`level_turn` for the rotation with 3×3 ``matrix``.

    Plain floats (Rodrigues' formula about ``n × e_z``): robots lay their estimate flat for
    every transform they hear, and this takes 5 µs against 116 µs through ``Rotation`` (timeit).

    Examples
    --------
    >>> m = Rotation.from_euler("x", -90, degrees=True).as_matrix()
    >>> (level_matrix(m) @ m[:, 2]).round(9).tolist()
    [0.0, 0.0, 1.0]
    """
    nx, ny, nz = matrix[:, 2].tolist()  # the plane's normal: where z goes
    if nx * _LEVEL_UP[0] + ny * _LEVEL_UP[1] + nz * _LEVEL_UP[2] < 0:
        nx, ny, nz = -nx, -ny, -nz
    # Axis n × e_z = (ny, -nx, 0); its length is the sine of the angle to e_z, nz the cosine.
    sin = math.hypot(nx, ny)
    if sin == 0.0:
        return np.eye(3)
    kx, ky = ny / sin, -nx / sin
    cos = nz / math.hypot(sin, nz)
    sin /= math.hypot(sin, nz)
    c1 = 1.0 - cos
    return np.array(
        [
            [cos + c1 * kx * kx, c1 * kx * ky, sin * ky],
            [c1 * kx * ky, cos + c1 * ky * ky, -sin * kx],
            [-sin * ky, sin * kx, cos],
        ]
    )


def level(rotation: Rotation, shift_mm: np.ndarray) -> tuple[Rotation, np.ndarray]:
    """Lay a (possibly tilted) frame transform back onto the table plane z = 0.

    Merging rounds turn frames out of the plane; when they have converged, every frame maps
    onto one common plane, though not necessarily z = 0. This composes the transform with
    the shortest rotation Q that takes that plane's normal to +z (and drops the plane's
    height), so plane coordinates can be read with :func:`apply_2d`. Q depends on the
    plane only, not on which side the frame faces: of the normals ``±R e_z`` the one on the
    side of a fixed generic direction is used. Frames that agree on the plane therefore get
    the same Q and keep agreeing (mirror-image frames included, whose normals are opposite).
    The result maps the plane z = 0 onto itself: ``R' e_z = ±e_z``.

    Parameters
    ----------
    rotation : Rotation
    shift_mm : (2,) or (3,) array
        mm.

    Returns
    -------
    rotation : Rotation
    shift : (3,) array
        mm, with z = 0.

    Examples
    --------
    A frame stood on edge (turned by −90° about x and shifted: it lies in the plane y = 2)
    comes back flat, distances kept:

    >>> tilted = Rotation.from_euler("x", -90, degrees=True)
    >>> rot, shift = level(tilted, [1.0, 2.0, 7.0])
    >>> apply_2d(rot, shift, [[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]).round(9).tolist()
    [[1.0, -7.0], [11.0, -7.0], [1.0, 3.0]]
    """
    flat_rotation, flat_shift = compose(level_turn(rotation), np.zeros(3), rotation, shift_mm)
    flat_shift[2] = 0.0
    return flat_rotation, flat_shift


def transform_distance(
    rotation_1: Rotation, shift_1: np.ndarray, rotation_2: Rotation, shift_2: np.ndarray
) -> tuple[float, float]:
    """How far apart two transforms are: the angle between the rotations and between shifts.

    For a convergence test of frame merging compare what should agree: the correction
    between two frames (from :func:`rotation_between_frames` on shared robots' global
    coordinates) against the identity. Comparing two seeds' own transforms is meaningless
    for mirror-image frames, which differ by a 180° turn even when fully merged. The shift
    part depends on where the origin is; it is the displacement of the origin.

    Returns
    -------
    angle_rad : float
        Angle of ``R₁⁻¹ R₂``, radians in [0, π].
    shift_mm : float
        ``|v₁ − v₂|``, mm.

    Examples
    --------
    >>> r1 = Rotation.from_euler("z", 10, degrees=True)
    >>> r2 = Rotation.from_euler("z", 40, degrees=True)
    >>> angle, shift = transform_distance(r1, [0.0, 0.0], r2, [3.0, 4.0])
    >>> round(float(np.degrees(angle)), 9), shift
    (30.0, 5.0)
    """
    angle = float((rotation_1.inv() * rotation_2).magnitude())
    return angle, float(np.linalg.norm(_shift3(shift_1) - _shift3(shift_2)))


# -------------------------------------------------------------------------------- messages

_QUAT_LEVELS = 16383  # 15-bit signed magnitude per component
_QUAT_STEP = 1.0 / (_QUAT_LEVELS * math.sqrt(2.0))  # one level of a component

#: Largest angle between a rotation and its :func:`pack_quaternion` /
#: :func:`unpack_quaternion` round trip, radians (≈ 1.5e-4 rad ≈ 0.0086°). Derivation: each
#: of the three stored components is off by at most half a level, δ = _QUAT_STEP / 2; the
#: dropped one, at least 1/2 in size, is recomputed from them, which stretches the error by at
#: most a factor 2 on the unit sphere; the rotation angle is twice the quaternion angle:
#: 2 · 2 · √3 · δ.
QUATERNION_MAX_ANGLE_ERROR_RAD = 4.0 * math.sqrt(3.0) * _QUAT_STEP / 2.0


def pack_quaternion(rotation: Rotation) -> tuple[int, int, int]:
    """Three int16 words that carry a rotation ("smallest three" quaternion encoding).

    A unit quaternion's largest component (in magnitude) is at least 1/2 and the others at
    most 1/√2. The quaternion is signed so that the largest component is positive (q and −q
    are the same rotation); the largest is dropped and recomputed from the unit norm on
    unpacking, and the other three, in x, y, z, w order, are stored as 15-bit signed values
    scaled by ``16383 · √2``. Each word is ``2 · value + bit``: the low bits of words 0 and 1
    hold the dropped component's index (0–3 for x, y, z, w), word 2's low bit is 0. The three
    words fit 6 bytes of a message (struct code ``"hhh"``), leaving 3 for other fields.

    Precision: at most :data:`QUATERNION_MAX_ANGLE_ERROR_RAD` (1.5e-4 rad, 0.0086°) for every
    rotation (measured: 1.2e-4 rad over 20,000 random rotations). The plainer encoding —
    x, y, z as int16 and w ≥ 0 recomputed — loses up to 0.8° near 180° turns (where w ≈ 0
    is recomputed as the root of a small difference), and 180° turns are exactly how
    mirror-image frames are merged.

    Parameters
    ----------
    rotation : Rotation
        A single rotation.

    Returns
    -------
    tuple of three int
        Each in [−32768, 32767].

    Examples
    --------
    A 60° turn about z is the quaternion (0, 0, 1/2, √3/2): w is dropped (index 3, low bits
    1 and 1) and z = 1/2 is stored as round(16383 · √2 / 2) = 11585:

    >>> words = pack_quaternion(Rotation.from_euler("z", 60, degrees=True))
    >>> words
    (1, 1, 23170)
    >>> round(float(np.degrees(unpack_quaternion(words).magnitude())), 2)
    60.0
    """
    quat = np.asarray(rotation.as_quat(), dtype=float)
    if quat.shape != (4,):
        raise ValueError(f"pack_quaternion takes a single rotation; got shape {quat.shape}")
    q = quat.tolist()  # four numbers: plain floats are several times faster than NumPy here
    dropped = max(range(4), key=lambda i: abs(q[i]))  # the first largest, as np.argmax
    sign = -1.0 if q[dropped] < 0 else 1.0
    kept = [sign * c for i, c in enumerate(q) if i != dropped]
    values = [min(max(round(c / _QUAT_STEP), -_QUAT_LEVELS), _QUAT_LEVELS) for c in kept]
    bits = (dropped & 1, dropped >> 1, 0)
    return tuple(2 * v + b for v, b in zip(values, bits, strict=True))


def unpack_quaternion(words: tuple[int, int, int]) -> Rotation:
    """The rotation carried by three words from :func:`pack_quaternion`.

    Raises
    ------
    ValueError
        If there are not three words, a word is outside int16, word 2's low bit is set, or
        the stored components are too large for a unit quaternion.

    Examples
    --------
    >>> rot = Rotation.from_rotvec([np.pi, 0.0, 0.0])  # turning a mirror image over
    >>> back = unpack_quaternion(pack_quaternion(rot))
    >>> bool((back.inv() * rot).magnitude() <= QUATERNION_MAX_ANGLE_ERROR_RAD)
    True
    """
    return Rotation.from_quat(_words_quaternion(words))


def words_matrix(words: tuple[int, int, int]) -> np.ndarray:
    """The 3×3 matrix of :func:`unpack_quaternion`'s rotation, without building a
    ``Rotation`` (robots turn every transform they hear into a matrix: 8 µs against 34 µs).

    Raises
    ------
    ValueError
        As :func:`unpack_quaternion`.

    Examples
    --------
    >>> words = pack_quaternion(Rotation.from_euler("z", 90, degrees=True))
    >>> words_matrix(words).round(3).tolist()
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    x, y, z, w = _words_quaternion(words)
    return _quaternion_matrix(w, x, y, z)


def _words_quaternion(words: tuple[int, int, int]) -> list[float]:
    """The unit quaternion ``[x, y, z, w]`` (scalar last, as scipy) of three packed words."""
    words = tuple(int(w) for w in words)
    if len(words) != 3 or not all(-32768 <= w <= 32767 for w in words):
        raise ValueError(f"expected three int16 words; got {words}")
    if words[2] & 1:
        raise ValueError(f"word 2 of a packed quaternion must be even; got {words}")
    dropped = (words[0] & 1) | ((words[1] & 1) << 1)
    quat = [(w >> 1) * _QUAT_STEP for w in words]  # plain floats: this runs per message
    rest = 1.0 - sum(c * c for c in quat)
    if rest < 0.25 - 1e-3:  # the dropped (largest) component is at least 1/2, ± rounding
        raise ValueError(f"words {words} do not encode a unit quaternion")
    quat.insert(dropped, math.sqrt(max(rest, 0.0)))
    return quat
