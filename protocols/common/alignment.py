"""Rigid transforms between robot frames: the merging step, levelling, packing, Procrustes.

The math of phase 6 (frame merging, :mod:`kilonet.protocols.gcs.phase6_merging`) and of the position
metrics. A frame transform acts as ``x_global = R x_local + v`` on points of the table
embedded at z = 0, with R a 3-D rotation (a :class:`scipy.spatial.transform.Rotation` where a
rotation is handed over) and v a shift of 3 millimetres. The thesis writes a seed's transform
as ``R (x − v_thesis)``; the two forms are the same transform with ``v = −R v_thesis``.

Why 3-D: a local frame may be the mirror image of another (each seed takes its C with y > 0).
No plane rotation turns one into the other, but a 180° rotation about an axis in the plane
does, and rotations interpolate (SLERP), so seeds can move halfway towards each other round
after round. While frames converge they may tilt out of the table's plane; :func:`level_matrix`
lays the common plane flat again.

- The merging step: :func:`half_map`.
- Reading a tilted plane: :func:`level_matrix`.
- Messages: :func:`pack_quaternion`, :func:`unpack_quaternion`, :func:`words_matrix` (three
  int16 words).
- Metrics: :func:`rigid_fit` (the best rigid map of one point set onto another) and
  :func:`procrustes_rmse`.

Robots call the first three on every query, transform heard and message, so they are written
on plain floats; the tests check them against scipy's ``Rotation``, ``Slerp`` and
``Rotation.align_vectors``. ``docs/math.md`` says what that saves.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from kilonet.protocols.common.geometry import GeometryError, collinear

__all__ = [
    "QUATERNION_MAX_ANGLE_ERROR_RAD",
    "half_map",
    "level_matrix",
    "pack_quaternion",
    "procrustes_rmse",
    "rigid_fit",
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


#: half_map's collinearity threshold, mm: a guard against rounding only, since merging
#: groups are chosen wide in the first place (``gcs.min_group_width_mm``).
_MIN_WIDTH_MM = 1e-6


def _dot(u: list[float], v: list[float]) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _centroid(points: list[list[float]]) -> list[float]:
    return [sum(c) / len(points) for c in zip(*points, strict=True)]


def _centred(points: list[list[float]], centre: list[float]) -> list[list[float]]:
    return [[c - m for c, m in zip(p, centre, strict=True)] for p in points]


def half_map(
    points_i: np.ndarray, points_k: np.ndarray, fraction: float = 0.5
) -> tuple[Rotation, np.ndarray, float]:
    """A fraction (default half) of the rigid map taking points in frame I onto the same
    robots in frame K: the merging step of phase 6.

    The full map M is the least-squares rigid transform: the proper rotation ``R_M``
    minimising ``Σ |R (pᵢ − c_I) − (qᵢ − c_K)|²`` over the centred points (Kabsch's optimum,
    found with Horn's quaternion, J. Opt. Soc. Am. A 4, 1987), then ``x ↦ R_M (x − c_I) +
    c_K``. Because R is a 3-D rotation, frames that are mirror images of each other are
    matched too, by a 180° turn about an axis in the plane. The thesis proposes TRIAD
    instead, which uses only two of the members' difference vectors and trusts the first
    exactly; the least-squares rotation weighs all k points and equals TRIAD's for noiseless
    points.

    The step applied is ``fraction`` of M, turning about the centroid c_I so that distant
    frames do not swing about a far-away origin: ``R_H`` is the SLERP from the identity to
    ``R_M`` at ``fraction`` (the same axis, that share of the angle, along the shorter arc),
    and ``t_H = c_I + fraction · (c_K − c_I) − R_H c_I`` moves the centroid that share of the
    way. Applying all of M at once would make I and K swap places round after round, since K
    moves towards I at the same time.

    Parameters
    ----------
    points_i, points_k : (k, 2) or (k, 3) arrays
        The same k ≥ 3 robots' "global" positions through I's and K's transforms, mm.
    fraction : float
        0 stays, 0.5 goes half way (the thesis), 1 goes all the way.

    Returns
    -------
    rotation : Rotation
        ``R_H``.
    shift : (3,) array
        ``t_H``, mm.
    disagreement_mm : float
        How far apart the two transforms are: the farthest the full map M moves one of the
        robots, mm. (Not the largest distance between a robot's two positions: that also
        holds the members' own position errors, which no transform removes, so it would never
        fall below them.)

    Raises
    ------
    GeometryError
        If fewer than 3 points are given or the points of a frame are collinear (within
        1e-6 mm of a line, :func:`kilonet.protocols.common.geometry.collinear`: the rotation about
        that line is undetermined).
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

    A mirror image (y → −y) is turned over about the x axis (one way or the other: both are
    shortest); half of that stands it on edge, its y axis along ±z:

    >>> mirrored = p_i * [1.0, -1.0, 1.0]
    >>> full, _, _ = half_map(p_i, mirrored, 1.0)
    >>> (np.abs(full.as_rotvec()).round(6) + 0.0).tolist()
    [3.141593, 0.0, 0.0]
    >>> half, _, _ = half_map(p_i, mirrored)
    >>> (np.abs(half.apply([0.0, 1.0, 0.0])).round(6) + 0.0).tolist()
    [0.0, 0.0, 1.0]
    """
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1]; got {fraction}")
    a, b = _points3(points_i, "points_i"), _points3(points_k, "points_k")
    if a.shape != b.shape:
        raise ValueError(f"points_i and points_k differ in shape: {a.shape} vs {b.shape}")
    if len(a) < 3:
        raise GeometryError(f"{len(a)} points cannot fix a rotation (need at least 3)")
    for name, pts in (("I", a), ("K", b)):
        if collinear(pts, min_width_mm=_MIN_WIDTH_MM):
            raise GeometryError(
                f"the points of frame {name} are collinear (within {_MIN_WIDTH_MM} mm of a line)"
            )
    # A handful of points: plain floats cost a fraction of NumPy's per-call overhead.
    pa, pb = a.tolist(), b.tolist()
    centre_a, centre_b = _centroid(pa), _centroid(pb)
    ac, bc = _centred(pa, centre_a), _centred(pb, centre_b)
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


def rigid_fit(
    source_mm: np.ndarray, target_mm: np.ndarray, *, handedness: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """The orthogonal map Q and shift t that best map ``source_mm`` rows onto ``target_mm``'s
    (Kabsch): they minimise ``Σ |Q sᵢ + t − tᵢ|²``; no scaling, since distances fix the scale.

    Parameters
    ----------
    source_mm, target_mm : (N, 2) arrays
        The same points in two frames, mm (N ≥ 1; with N = 1 Q is the identity or, for
        ``handedness = -1``, the reflection across the x axis).
    handedness : int
        0: Q is a rotation or a reflection, whichever fits better; +1: a rotation only;
        -1: a reflection only (a frame known to be the mirror image of the other).

    Returns
    -------
    q : (2, 2) array
        The map; ``source @ q.T + t`` is the source moved onto the target.
    t : (2,) array
        The shift, mm.

    Examples
    --------
    >>> target = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0]])
    >>> source = target * [1.0, -1.0] + 5.0
    >>> q, t = rigid_fit(source, target)
    >>> np.round(source @ q.T + t, 9).tolist() == target.tolist(), round(np.linalg.det(q))
    (True, -1)
    >>> q, t = rigid_fit(source, target, handedness=1)
    >>> round(float(np.linalg.det(q)))
    1
    """
    if handedness not in (-1, 0, 1):
        raise ValueError(f"handedness must be -1, 0 or 1; got {handedness!r}")
    centre_s, centre_t = source_mm.mean(axis=0), target_mm.mean(axis=0)
    u, _, vt = np.linalg.svd((target_mm - centre_t).T @ (source_mm - centre_s))
    sign = 1.0 if np.linalg.det(u @ vt) >= 0 else -1.0
    if handedness and sign != handedness:
        u[:, -1] = -u[:, -1]
    q = u @ vt
    return q, centre_t - centre_s @ q.T


def procrustes_rmse(
    estimated_mm: np.ndarray, true_mm: np.ndarray, *, allow_reflection: bool = True
) -> tuple[float, float, np.ndarray]:
    """Position error after the best rigid alignment of estimated positions onto the truth.

    Finds the orthogonal map Q (a rotation, or also a reflection when allowed) and shift t
    minimising ``Σ |Q eᵢ + t − pᵢ|²`` (:func:`rigid_fit`), then reports the residual distances.

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
    q, t = rigid_fit(est, true, handedness=0 if allow_reflection else 1)
    aligned = est @ q.T + t
    dist = np.sqrt(((aligned - true) ** 2).sum(axis=1))
    return float(np.sqrt((dist**2).mean())), float(dist.max()), aligned


# ---------------------------------------------------------------------------- levelling

#: Reference direction for :func:`level_matrix`'s choice of which side of a plane is up.
#: Generic on purpose: merged mirror-image frames end standing on edge, with normals in the
#: table's plane, and a normal perpendicular to the reference would make the choice
#: ill-defined.
_LEVEL_UP = np.array([0.26726124191242440, 0.53452248382484879, 0.80178372573727319])


def level_matrix(matrix: np.ndarray) -> np.ndarray:
    """The turn Q that lays the plane a frame transform maps the table onto back flat.

    Merging rounds turn frames out of the table's plane; once they agree, every frame maps
    the table onto one common plane, though not necessarily z = 0. Q is the shortest
    rotation taking that plane's normal to +z, where of the normals ``±R e_z`` the one on the
    side of a fixed generic direction is used. Q therefore depends on the plane only, not on
    which side the frame faces, so frames that agree on the plane (mirror-image frames
    included, whose normals are opposite) read the same plane coordinates: global
    coordinates ``g`` in the plane laid flat are ``(Q g)[:2]``, up to the plane's height
    ``(Q g)[2]``. Computed with Rodrigues' formula about ``n × e_z`` on plain floats: robots
    lay flat every transform they hear.

    Parameters
    ----------
    matrix : (3, 3) array
        The frame transform's rotation matrix R.

    Returns
    -------
    (3, 3) array
        Q's matrix.

    Examples
    --------
    A frame stood on edge (turned by −90° about x: its plane is y = const):

    >>> m = Rotation.from_euler("x", -90, degrees=True).as_matrix()
    >>> (level_matrix(m) @ m[:, 2]).round(9).tolist()  # the plane's normal, laid upright
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
    rotation. The plainer encoding — x, y, z as int16 and w ≥ 0 recomputed — is worst near
    180° turns, where w ≈ 0 is recomputed as the root of a small difference, and 180° turns
    are exactly how mirror-image frames are merged (``docs/math.md`` compares the two).

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
    q = quat.tolist()  # four numbers: plain floats, not NumPy (seeds pack at every TF_ROT)
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
    ``Rotation``: robots turn every transform they hear into a matrix.

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
