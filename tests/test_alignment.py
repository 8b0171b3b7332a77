"""Tests for kilonet.protocols.common.alignment: the merging step, levelling, packing, Procrustes.

The fast plain-float code is checked against scipy, kept here as the oracle: the least-squares
rotation of ``Rotation.align_vectors`` (Kabsch), ``Slerp`` from the identity, and
``Rotation`` for matrices and compositions.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from kilonet.message import KILOLIB, Layout
from kilonet.protocols.common.alignment import (
    _LEVEL_UP,
    QUATERNION_MAX_ANGLE_ERROR_RAD,
    half_map,
    level_matrix,
    pack_quaternion,
    procrustes_rmse,
    unpack_quaternion,
    words_matrix,
)
from kilonet.protocols.common.geometry import GeometryError

coord = st.floats(-300.0, 300.0, allow_nan=False)
point = st.tuples(coord, coord)
point3 = st.tuples(coord, coord, coord)
point_sets = st.lists(point, min_size=3, max_size=10)
angle = st.floats(0.0, 2 * math.pi)
unit = st.floats(-1.0, 1.0)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: math.hypot(*q) > 0.1)


def _spread(points: np.ndarray) -> float:
    """The second singular value of the centred points, mm: how far they are from a line."""
    centred = points - points.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[1]) if len(points) > 1 else 0.0


def _orthogonal(turn: float, mirror: bool) -> np.ndarray:
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    return rot @ np.diag([1.0, -1.0]) if mirror else rot


def _flat(points: np.ndarray) -> np.ndarray:
    return np.column_stack([points, np.zeros(len(points))])


_TRIANGLE = np.array([[0.0, 0.0], [40.0, 0.0], [10.0, 30.0]])


# ------------------------------------------------------------------------------ the oracles


def _kabsch(points_i: np.ndarray, points_k: np.ndarray) -> Rotation:
    """scipy's least-squares rotation R with ``R (p − c_I) ≈ q − c_K``."""
    rotation, _ = Rotation.align_vectors(
        points_k - points_k.mean(axis=0), points_i - points_i.mean(axis=0)
    )
    return rotation


def _slerp_from_identity(rotation: Rotation, fraction: float) -> Rotation:
    return Slerp([0.0, 1.0], Rotation.concatenate([Rotation.identity(), rotation]))([fraction])[0]


def _oracle_half_map(points_i, points_k, fraction):
    """half_map's result through scipy: Kabsch, Slerp, and the centroid moved by ``fraction``."""
    full = _kabsch(points_i, points_k)
    c_i, c_k = points_i.mean(axis=0), points_k.mean(axis=0)
    partial = _slerp_from_identity(full, fraction)
    shift = c_i + fraction * (c_k - c_i) - partial.apply(c_i)
    disagreement = np.linalg.norm(full.apply(points_i - c_i) + c_k - points_i, axis=1).max()
    return full, partial, shift, float(disagreement)


def _then(step, transform):
    """Transform ``transform`` followed by ``step``: ``x ↦ S (R x + v) + s``."""
    (s, s_shift), (r, r_shift) = step, transform
    return s * r, s.apply(r_shift) + s_shift


def _apply(transform, points):
    rotation, shift = transform
    pts = np.asarray(points, dtype=float)
    return rotation.apply(_flat(pts) if pts.shape[1] == 2 else pts) + shift


# -------------------------------------------------------------------------------- half_map


@settings(max_examples=150, deadline=None)
@given(
    st.lists(point3, min_size=3, max_size=8),
    quaternions,
    point3,
    st.floats(0.0, 1.0),
    st.booleans(),
    st.floats(0.0, 3.0),
)
def test_half_map_is_scipys_slerp_of_the_kabsch_rotation(points, quat, shift, frac, flat, noise):
    """The fast step equals Slerp from the identity, at ``fraction``, of scipy's least-squares
    rotation, within 1e-9 rad, on well-spread points (a merging group is chosen wide)."""
    a = np.array(points)
    if flat:
        a[:, 2] = 0.0
    assume(_spread(a) > 20.0)
    # Frame K: turned and moved, plus a disagreement no rigid map removes (up to 3 mm).
    b = (
        Rotation.from_quat(quat).apply(a)
        + shift
        + noise * np.sin(np.arange(a.size)).reshape(a.shape)
    )
    full, want_rot, want_shift, want_disagreement = _oracle_half_map(a, b, frac)
    assume(full.magnitude() < math.pi - 1e-6)  # a half turn has two shortest arcs
    rot, v, disagreement = half_map(a, b, frac)
    assert (rot * want_rot.inv()).magnitude() < 1e-9
    assert v == pytest.approx(want_shift, abs=1e-9)
    assert disagreement == pytest.approx(want_disagreement, abs=1e-9)


@settings(max_examples=80, deadline=None)
@given(point_sets, angle, st.booleans(), point)
def test_the_full_map_recovers_rigid_motions_and_mirror_images(points, turn, mirror, shift):
    a = np.array(points)
    assume(_spread(a) > 5.0)
    m = _orthogonal(turn, mirror)
    b = a @ m.T + shift
    rot, v, disagreement = half_map(a, b, 1.0)
    assert np.abs(_apply((rot, v), a)[:, :2] - b).max() < 1e-6
    assert np.abs(_apply((rot, v), a)[:, 2]).max() < 1e-6
    # A mirror image is turned over: the table's normal flips.
    normal = rot.apply([0.0, 0.0, 1.0])
    assert normal == pytest.approx([0.0, 0.0, -1.0 if mirror else 1.0], abs=1e-9)
    assert rot.as_matrix()[:2, :2] == pytest.approx(m, abs=1e-9)
    assert disagreement == pytest.approx(np.linalg.norm(b - a, axis=1).max(), abs=1e-6)


def test_half_map_exact_values():
    b = _TRIANGLE @ _orthogonal(math.pi / 2, False).T + [5.0, -3.0]
    rot, v, _ = half_map(_TRIANGLE, b, 1.0)
    assert rot.as_rotvec() == pytest.approx([0.0, 0.0, math.pi / 2])
    assert v == pytest.approx([5.0, -3.0, 0.0])
    # Half of it: 45°, and the centroid (50/3, 10) moves half way to its image.
    rot, v, _ = half_map(_TRIANGLE, b)
    assert rot.as_rotvec() == pytest.approx([0.0, 0.0, math.pi / 4])
    centroid = _TRIANGLE.mean(axis=0)
    image = np.array([-centroid[1] + 5.0, centroid[0] - 3.0])
    moved = rot.apply([*centroid, 0.0]) + v
    assert moved == pytest.approx([*(centroid + image) / 2, 0.0])
    # Nothing at all: fraction 0 is the identity whatever the frames.
    rot, v, _ = half_map(_TRIANGLE, b, 0.0)
    assert rot.magnitude() == 0.0 and v == pytest.approx([0.0, 0.0, 0.0])


def test_half_map_of_a_mirror_merge_stands_the_frame_on_edge():
    mirrored = _TRIANGLE * [-1.0, 1.0]  # x → −x: a half turn about the y axis
    full, _, _ = half_map(_TRIANGLE, mirrored, 1.0)
    assert full.magnitude() == pytest.approx(math.pi)
    rot, _, _ = half_map(_TRIANGLE, mirrored)
    assert np.abs(rot.apply([0.0, 0.0, 1.0])) == pytest.approx([1.0, 0.0, 0.0])


def test_half_map_refuses_collinear_points_and_bad_input():
    line = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 0.0], [30.0, 15.0, 0.0]])
    with pytest.raises(GeometryError, match="frame I are collinear"):
        half_map(line, _TRIANGLE)
    with pytest.raises(GeometryError, match="frame K are collinear"):
        half_map(_TRIANGLE, line)
    with pytest.raises(GeometryError, match="need at least 3"):
        half_map(_TRIANGLE[:2], _TRIANGLE[:2])
    with pytest.raises(ValueError, match="differ in shape"):
        half_map(_TRIANGLE, np.vstack([_TRIANGLE, [[5.0, 5.0]]]))
    with pytest.raises(ValueError, match=r"\(k, 2\) or \(k, 3\)"):
        half_map(np.zeros(6), np.zeros(6))
    for bad in (-0.1, 1.5, math.nan):
        with pytest.raises(ValueError, match="fraction"):
            half_map(_TRIANGLE, _TRIANGLE, bad)
    # 0.33 mm off a line is still a frame: the threshold only guards against rounding.
    nearly = np.array([[0.0, 0.0], [40.0, 0.5], [80.0, 0.0]])
    half_map(nearly, nearly)


@settings(max_examples=20, deadline=None)
@given(st.lists(point3, min_size=3, max_size=6), quaternions, point3)
def test_halving_the_remainder_converges(points, quat, shift):
    """A frame that applies half of the remaining map each round closes the gap to a fixed
    frame: the angle left halves every round."""
    a = np.array(points)
    assume(_spread(a) > 20.0)
    target = Rotation.from_quat(quat).apply(a) + shift
    current = (Rotation.identity(), np.zeros(3))
    angles = []
    for _ in range(36):
        seen = _apply(current, a)
        angles.append(_kabsch(seen, target).magnitude())
        current = _then(half_map(seen, target)[:2], current)
    assume(angles[0] < math.pi - 1e-3)
    for before, after in itertools.pairwise(angles):
        assert after == pytest.approx(before / 2, abs=1e-9)
    assert np.abs(_apply(current, a) - target).max() < 1e-6


@pytest.mark.parametrize("both_move", [False, True])
def test_two_mirror_image_frames_merge_by_half_maps(both_move):
    """Seeds I and K see the same five robots; K's frame is I's mirrored, turned and moved.
    Each round I (and K too, or K stays, as the protocol's child and parent) applies half of
    the map towards the other; their global views of the shared robots converge, and laid flat
    (level_matrix) they give the same plane coordinates."""
    local_i = np.array([[0.0, 0.0], [40.0, 0.0], [10.0, 35.0], [60.0, 30.0], [-20.0, 50.0]])
    local_k = local_i @ _orthogonal(2.0, True).T + [300.0, -120.0]
    t_i = (Rotation.identity(), np.zeros(3))
    t_k = (Rotation.identity(), np.zeros(3))
    gaps = []
    for _ in range(40 if not both_move else 14):
        g_i, g_k = _apply(t_i, local_i), _apply(t_k, local_k)
        gaps.append(float(np.abs(g_i - g_k).max()))
        step_i, step_k = half_map(g_i, g_k)[:2], half_map(g_k, g_i)[:2]
        t_i = _then(step_i, t_i)
        if both_move:
            t_k = _then(step_k, t_k)
    assert gaps[0] > 100.0
    assert gaps[-1] < 1e-6
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(gaps[2:]))
    xy = []
    for (rot, shift), local in ((t_i, local_i), (t_k, local_k)):
        flat = level_matrix(rot.as_matrix())
        xy.append((_apply((rot, shift), local) @ flat.T)[:, :2])
    assert xy[0] == pytest.approx(xy[1], abs=1e-6)
    assert procrustes_rmse(xy[0], local_i)[0] < 1e-6  # distances kept


# --------------------------------------------------------------------------- procrustes_rmse


@settings(max_examples=80, deadline=None)
@given(st.lists(point, min_size=1, max_size=12), angle, st.booleans(), point)
def test_procrustes_undoes_rigid_motions_with_reflection(points, turn, mirror, shift):
    truth = np.array(points)
    est = truth @ _orthogonal(turn, mirror).T + shift
    rmse, worst, aligned = procrustes_rmse(est, truth)
    assert rmse < 1e-6 and worst < 1e-6
    assert aligned == pytest.approx(truth, abs=1e-6)
    if not mirror:
        assert procrustes_rmse(est, truth, allow_reflection=False)[0] < 1e-6


def test_procrustes_exact_values():
    # Two robots 10 mm apart estimated 12 mm apart: each end is 1 mm off after alignment.
    rmse, worst, aligned = procrustes_rmse(np.array([[0.0, 0.0], [12.0, 0.0]]), [[5, 5], [5, 15]])
    assert (rmse, worst) == (pytest.approx(1.0), pytest.approx(1.0))
    assert aligned == pytest.approx(np.array([[5.0, 4.0], [5.0, 16.0]]))
    # A mirror image cannot be undone by a rotation alone.
    mirrored = _TRIANGLE * [1.0, -1.0]
    assert procrustes_rmse(mirrored, _TRIANGLE)[0] == pytest.approx(0.0, abs=1e-9)
    assert procrustes_rmse(mirrored, _TRIANGLE, allow_reflection=False)[0] > 10.0
    # A single robot is always perfectly aligned.
    assert procrustes_rmse(np.array([[3.0, 4.0]]), np.array([[-1.0, 9.0]]))[:2] == (0.0, 0.0)


def test_procrustes_and_the_full_map_are_the_same_least_squares_fit():
    """In the plane, a reflection is a 3-D half turn: Procrustes with reflections and the
    full rigid map of half_map align noisy estimates identically."""
    rng = np.random.default_rng(5)
    truth = rng.uniform(-100.0, 100.0, (12, 2))
    local = (truth @ _orthogonal(1.0, True).T + [20.0, 30.0]) + rng.normal(0.0, 1.0, (12, 2))
    rot, v, _ = half_map(local, truth, 1.0)
    _, _, aligned = procrustes_rmse(local, truth)
    assert _apply((rot, v), local) == pytest.approx(_flat(aligned), abs=1e-9)


def test_procrustes_refuses_malformed_input():
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        procrustes_rmse(np.zeros((0, 2)), np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        procrustes_rmse(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="finite"):
        procrustes_rmse(np.array([[np.nan, 0.0]]), np.zeros((1, 2)))


# ---------------------------------------------------------------------------- level_matrix


@settings(max_examples=60, deadline=None)
@given(quaternions)
def test_level_matrix_lays_any_frame_flat(quat):
    matrix = Rotation.from_quat(quat).as_matrix()
    flat = level_matrix(matrix)
    assert flat @ flat.T == pytest.approx(np.eye(3), abs=1e-12)  # a rotation...
    assert np.linalg.det(flat) == pytest.approx(1.0)
    assert abs((flat @ matrix)[2, 2]) == pytest.approx(1.0, abs=1e-12)  # ...onto z = 0


@settings(max_examples=60, deadline=None)
@given(quaternions, angle)
def test_level_matrix_depends_on_the_plane_not_on_the_side(quat, turn):
    """A mirror-image frame on the same plane (its transform turned over about an in-plane
    axis first) is laid flat by the same turn, so both read the same plane coordinates."""
    rot = Rotation.from_quat(quat)
    assume(abs(rot.apply([0.0, 0.0, 1.0]) @ _LEVEL_UP) > 0.05)  # off the rule's seam
    flip = Rotation.from_rotvec([math.pi * math.cos(turn), math.pi * math.sin(turn), 0.0])
    mirrored = (rot * flip).as_matrix()
    assert level_matrix(mirrored) == pytest.approx(level_matrix(rot.as_matrix()), abs=1e-9)


@settings(max_examples=100, deadline=None)
@given(quaternions)
def test_level_matrix_is_the_shortest_turn_of_the_normal_to_z(quat):
    """Against the construction from the definition: axis n × e_z, angle between n and e_z,
    n the plane's normal on the side of the reference direction."""
    matrix = Rotation.from_quat(quat).as_matrix()
    normal = matrix[:, 2] if matrix[:, 2] @ _LEVEL_UP >= 0 else -matrix[:, 2]
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    assume(np.linalg.norm(axis) > 1e-9)
    expected = Rotation.from_rotvec(
        axis / np.linalg.norm(axis) * math.atan2(np.linalg.norm(axis), normal[2])
    ).as_matrix()
    got = level_matrix(matrix)
    assert got == pytest.approx(expected, abs=1e-12)
    assert got @ normal == pytest.approx([0.0, 0.0, 1.0], abs=1e-12)


def test_level_matrix_of_a_flat_frame_is_the_identity_on_either_side():
    assert level_matrix(np.eye(3)).tolist() == np.eye(3).tolist()
    flip = Rotation.from_rotvec([math.pi, 0.0, 0.0]).as_matrix()  # normal -z: the same plane
    assert level_matrix(flip) == pytest.approx(np.eye(3), abs=1e-12)


# ---------------------------------------------------------------------- quaternion packing


def test_pack_quaternion_exact_words():
    assert pack_quaternion(Rotation.identity()) == (1, 1, 0)  # w dropped, x = y = z = 0
    assert unpack_quaternion((1, 1, 0)).magnitude() == 0.0
    # 180° about x: x is the largest component (index 0: low bits 0, 0).
    assert pack_quaternion(Rotation.from_rotvec([math.pi, 0.0, 0.0])) == (0, 0, 0)
    assert unpack_quaternion((0, 0, 0)).as_rotvec() == pytest.approx([math.pi, 0.0, 0.0])
    # 180° about z: z is dropped (index 2: low bits 0, 1).
    assert pack_quaternion(Rotation.from_rotvec([0.0, 0.0, math.pi])) == (0, 1, 0)


@settings(max_examples=150, deadline=None)
@given(quaternions)
def test_quaternion_round_trip_error_is_bounded(quat):
    rot = Rotation.from_quat(quat)
    words = pack_quaternion(rot)
    assert all(isinstance(w, int) and -32768 <= w <= 32767 for w in words)
    assert words[2] % 2 == 0
    back = unpack_quaternion(words)
    assert (back.inv() * rot).magnitude() <= QUATERNION_MAX_ANGLE_ERROR_RAD
    # The sign of the quaternion does not matter.
    assert pack_quaternion(Rotation.from_quat(-np.array(quat))) == words


@settings(max_examples=100, deadline=None)
@given(quaternions)
def test_words_matrix_is_the_unpacked_rotations_matrix(quat):
    words = pack_quaternion(Rotation.from_quat(quat))
    assert words_matrix(words) == pytest.approx(unpack_quaternion(words).as_matrix(), abs=1e-12)


def test_quaternion_error_bound_is_tight_and_holds_for_mirror_turns():
    rots = Rotation.random(1500, random_state=np.random.default_rng(9))
    axes = np.random.default_rng(10).normal(size=(300, 3))
    flips = Rotation.from_rotvec(axes / np.linalg.norm(axes, axis=1)[:, None] * math.pi)
    errors = [
        (unpack_quaternion(pack_quaternion(r)).inv() * r).magnitude()
        for batch in (rots, flips)
        for r in batch
    ]
    assert max(errors) <= QUATERNION_MAX_ANGLE_ERROR_RAD
    assert max(errors) > 0.5 * QUATERNION_MAX_ANGLE_ERROR_RAD
    assert math.degrees(QUATERNION_MAX_ANGLE_ERROR_RAD) < 0.01


def test_packed_quaternion_fits_a_message_with_room_to_spare():
    layout = Layout(
        "merge_rotation", type=40, fields=[("seed", "B"), ("q0", "h"), ("q1", "h"), ("q2", "h")]
    )
    rot = Rotation.from_euler("xyz", [170.0, -20.0, 33.0], degrees=True)
    q0, q1, q2 = pack_quaternion(rot)
    msg = layout.pack(seed=12, q0=q0, q1=q1, q2=q2)
    KILOLIB.check(msg)
    assert len(msg.data) == 7
    got = layout.unpack(msg)
    back = unpack_quaternion((got.q0, got.q1, got.q2))
    assert (back.inv() * rot).magnitude() <= QUATERNION_MAX_ANGLE_ERROR_RAD


def test_unpack_quaternion_refuses_bad_words():
    with pytest.raises(ValueError, match="three int16"):
        unpack_quaternion((1, 2))
    with pytest.raises(ValueError, match="three int16"):
        unpack_quaternion((40000, 0, 0))
    with pytest.raises(ValueError, match="must be even"):
        unpack_quaternion((0, 0, 1))
    with pytest.raises(ValueError, match="unit quaternion"):
        unpack_quaternion((32766, 32766, 32766))
    with pytest.raises(ValueError, match="must be even"):
        words_matrix((0, 0, 1))
    with pytest.raises(ValueError, match="single rotation"):
        pack_quaternion(Rotation.random(2, random_state=np.random.default_rng(0)))
