"""Tests for kilonet.alignment: frame rotations, half steps, levelling, packing, Procrustes."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation, Slerp

from kilonet.alignment import (
    _LEVEL_UP,
    QUATERNION_MAX_ANGLE_ERROR_RAD,
    apply_2d,
    apply_3d,
    compose,
    half_map,
    half_step,
    invert,
    level,
    level_matrix,
    pack_quaternion,
    procrustes_rmse,
    rotation_between_frames,
    transform_distance,
    unpack_quaternion,
    words_matrix,
)
from kilonet.geometry import GeometryError
from kilonet.message import KILOLIB, Layout

coord = st.floats(-300.0, 300.0, allow_nan=False)
point = st.tuples(coord, coord)
point_sets = st.lists(point, min_size=3, max_size=10)
angle = st.floats(0.0, 2 * math.pi)
unit = st.floats(-1.0, 1.0)
quaternions = st.tuples(unit, unit, unit, unit).filter(lambda q: math.hypot(*q) > 0.1)


def _spread(points: np.ndarray) -> float:
    """Root-sum-square distance of the points from their best-fit line, mm."""
    centred = points - points.mean(axis=0)
    return float(np.linalg.svd(centred, compute_uv=False)[-1]) if len(points) > 1 else 0.0


def _orthogonal(turn: float, mirror: bool) -> np.ndarray:
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    return rot @ np.diag([1.0, -1.0]) if mirror else rot


_TRIANGLE = np.array([[0.0, 0.0], [40.0, 0.0], [10.0, 30.0]])


# ------------------------------------------------------------------ rotation_between_frames


@settings(max_examples=80, deadline=None)
@given(point_sets, angle, st.booleans(), point)
def test_rigid_motions_and_mirror_images_are_recovered(points, turn, mirror, shift):
    a = np.array(points)
    assume(_spread(a) > 5.0)
    m = _orthogonal(turn, mirror)
    b = a @ m.T + shift
    rot, v = rotation_between_frames(a, b)
    assert np.abs(apply_2d(rot, v, a) - b).max() < 1e-6
    # A mirror image is turned over: the table's normal flips.
    normal = rot.apply([0.0, 0.0, 1.0])
    assert normal == pytest.approx([0.0, 0.0, -1.0 if mirror else 1.0], abs=1e-9)
    assert rot.as_matrix()[:2, :2] == pytest.approx(m, abs=1e-9)
    assert v[2] == pytest.approx(0.0, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(point_sets, quaternions, st.tuples(coord, coord, coord))
def test_tilted_frames_are_recovered_in_3d(points, quat, shift):
    a = np.array(points)
    assume(_spread(a) > 5.0)
    true_rot = Rotation.from_quat(quat)
    b = apply_3d(true_rot, shift, a)
    rot, v = rotation_between_frames(a, b)
    assert (rot.inv() * true_rot).magnitude() < 1e-7
    assert v == pytest.approx(np.array(shift), abs=1e-6)
    # Between two tilted images of the same robots, too.
    other = Rotation.from_euler("xyz", [0.3, -1.2, 2.0])
    c = apply_3d(other, [1.0, 2.0, 3.0], a)
    rot, v = rotation_between_frames(b, c)
    assert np.abs(apply_3d(rot, v, b) - c).max() < 1e-6


def test_rotation_between_frames_exact_values():
    b = _TRIANGLE @ _orthogonal(math.pi / 2, False).T + [5.0, -3.0]
    rot, v = rotation_between_frames(_TRIANGLE, b)
    assert rot.magnitude() == pytest.approx(math.pi / 2)
    assert rot.as_rotvec() == pytest.approx([0.0, 0.0, math.pi / 2])
    assert v == pytest.approx([5.0, -3.0, 0.0])
    rot, v = rotation_between_frames(_TRIANGLE, _TRIANGLE * [-1.0, 1.0])  # mirror x → −x
    assert rot.as_rotvec() == pytest.approx([0.0, math.pi, 0.0], abs=1e-9) or (
        rot.as_rotvec() == pytest.approx([0.0, -math.pi, 0.0], abs=1e-9)
    )
    assert v == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)


def test_rotation_between_frames_is_least_squares_like_procrustes():
    rng = np.random.default_rng(5)
    truth = rng.uniform(-100.0, 100.0, (12, 2))
    local = (truth @ _orthogonal(1.0, True).T + [20.0, 30.0]) + rng.normal(0.0, 1.0, (12, 2))
    rot, v = rotation_between_frames(local, truth)
    _, _, aligned = procrustes_rmse(local, truth)
    assert apply_2d(rot, v, local) == pytest.approx(aligned, abs=1e-9)


@settings(max_examples=80, deadline=None)
@given(point_sets, quaternions, st.floats(0.0, 3.0))
def test_rotation_between_frames_is_the_kabsch_optimum_of_align_vectors(points, quat, noise):
    # The closed form (Horn's quaternion) must find the rotation scipy's Kabsch finds.
    a = np.column_stack([np.array(points), np.zeros(len(points))])
    assume(_spread(a[:, :2]) > 1.0)
    rng = np.random.default_rng(len(points))
    b = Rotation.from_quat(quat).apply(a) + rng.normal(0.0, noise, a.shape)
    assume(_spread(b) > 1.0)
    rot, _ = rotation_between_frames(a, b)
    kabsch, _ = Rotation.align_vectors(b - b.mean(axis=0), a - a.mean(axis=0))
    assert (rot * kabsch.inv()).magnitude() == pytest.approx(0.0, abs=1e-6)


def test_rotation_between_frames_refuses_collinear_and_malformed_input():
    line = np.array([[0.0, 0.0], [40.0, 0.0], [80.0, 0.0]])
    with pytest.raises(GeometryError, match="frame a are collinear"):
        rotation_between_frames(line, _TRIANGLE)
    with pytest.raises(GeometryError, match="frame b are collinear"):
        rotation_between_frames(_TRIANGLE, line)
    with pytest.raises(GeometryError, match="need at least 3"):
        rotation_between_frames(_TRIANGLE[:2], _TRIANGLE[:2])
    with pytest.raises(ValueError, match="differ in shape"):
        rotation_between_frames(_TRIANGLE, np.vstack([_TRIANGLE, [[5.0, 5.0]]]))
    with pytest.raises(ValueError, match=r"\(k, 2\) or \(k, 3\)"):
        rotation_between_frames(np.zeros(6), np.zeros(6))
    nearly = line + np.array([[0.0, 0.0], [0.0, 0.5], [0.0, 0.0]])
    rotation_between_frames(nearly, nearly)  # 0.33 mm off its line: accepted by default
    with pytest.raises(GeometryError, match="collinear"):
        rotation_between_frames(nearly, nearly, min_width_mm=1.0)


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


def test_procrustes_refuses_malformed_input():
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        procrustes_rmse(np.zeros((0, 2)), np.zeros((0, 2)))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        procrustes_rmse(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="finite"):
        procrustes_rmse(np.array([[np.nan, 0.0]]), np.zeros((1, 2)))


# -------------------------------------------------------------------------------- half_step


def test_half_step_of_the_thesis_halves_angle_and_shift():
    full = Rotation.from_euler("z", 120, degrees=True)
    rot, v = half_step(full, [10.0, -4.0])
    assert rot.as_rotvec() == pytest.approx([0.0, 0.0, math.radians(60.0)])
    assert v == pytest.approx([5.0, -2.0, 0.0])
    rot, v = half_step(full, [10.0, -4.0], fraction=0.25)
    assert rot.magnitude() == pytest.approx(math.radians(30.0))
    assert v == pytest.approx([2.5, -1.0, 0.0])


@settings(max_examples=40, deadline=None)
@given(quaternions, st.tuples(coord, coord, coord), st.floats(0.0, 1.0), point)
def test_half_step_interpolates_between_identity_and_the_transform(quat, shift, frac, about):
    full = Rotation.from_quat(quat)
    for centre in (None, about):
        rot, v = half_step(full, shift, frac, about_mm=centre)
        assert rot.magnitude() == pytest.approx(frac * full.magnitude(), abs=1e-9)
        if rot.magnitude() > 1e-6:  # same axis (shortest arc)
            assert rot.as_rotvec() / rot.magnitude() == pytest.approx(
                full.as_rotvec() / full.magnitude(), abs=1e-6
            )
        c = np.zeros(3) if centre is None else np.append(centre, 0.0)
        target = full.apply(c) + shift
        assert apply_3d(rot, v, c[None, :2])[0] == pytest.approx(c + frac * (target - c), abs=1e-6)
        # The ends: nothing, and everything.
        r0, v0 = half_step(full, shift, 0.0, about_mm=centre)
        assert r0.magnitude() == pytest.approx(0.0, abs=1e-12)
        assert v0 == pytest.approx(np.zeros(3), abs=1e-9)
        r1, v1 = half_step(full, shift, 1.0, about_mm=centre)
        assert transform_distance(r1, v1, full, shift)[0] == pytest.approx(0.0, abs=1e-7)
        assert transform_distance(r1, v1, full, shift)[1] == pytest.approx(0.0, abs=1e-6)


@given(quaternions, st.floats(0.0, 1.0))
def test_half_step_turns_exactly_as_scipy_slerp_from_the_identity(quat, frac):
    full = Rotation.from_quat(quat)
    slerp = Slerp([0.0, 1.0], Rotation.concatenate([Rotation.identity(), full]))([frac])[0]
    rot, _ = half_step(full, [0.0, 0.0], frac)
    assert (rot * slerp.inv()).magnitude() == pytest.approx(0.0, abs=1e-7)


@settings(max_examples=20, deadline=None)
@given(quaternions, st.tuples(coord, coord, coord), st.one_of(st.none(), point))
def test_halving_the_remainder_converges(quat, shift, about):
    target = (Rotation.from_quat(quat), np.array(shift))
    current = (Rotation.identity(), np.zeros(3))
    angles = []
    for _ in range(36):
        remainder = compose(*target, *invert(*current))
        angles.append(remainder[0].magnitude())
        current = compose(*half_step(*remainder, 0.5, about_mm=about), *current)
    for before, after in itertools.pairwise(angles):
        assert after == pytest.approx(before / 2, abs=1e-9)
    angle_left, shift_left = transform_distance(*current, *target)
    assert angle_left < 1e-9
    assert shift_left < 1e-6


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.tuples(coord, coord, coord), min_size=3, max_size=6),
    quaternions,
    st.tuples(coord, coord, coord),
    st.floats(0.0, 1.0),
    st.booleans(),
)
def test_half_map_is_the_half_step_of_the_best_fit_transform(points, quat, shift, frac, flat):
    a = np.array(points)
    if flat:
        a[:, 2] = 0.0
    assume(_spread(a) > 1.0)
    # Frame K: turned and moved, plus a little disagreement no rigid map removes.
    b = Rotation.from_quat(quat).apply(a) + shift + np.sin(np.arange(a.size)).reshape(a.shape)
    rot, v, disagreement = half_map(a, b, frac)
    full, full_shift = rotation_between_frames(a, b)
    want_rot, want_v = half_step(full, full_shift, frac, about_mm=a.mean(axis=0))
    assert (rot * want_rot.inv()).magnitude() == pytest.approx(0.0, abs=1e-7)
    assert v == pytest.approx(want_v, abs=1e-6)
    moved = full.apply(a) + full_shift
    assert disagreement == pytest.approx(np.linalg.norm(moved - a, axis=1).max(), abs=1e-6)


def test_half_map_refuses_collinear_points_and_bad_fractions():
    line = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 0.0], [30.0, 15.0, 0.0]])
    with pytest.raises(GeometryError, match="frame I are collinear"):
        half_map(line, _TRIANGLE)
    with pytest.raises(GeometryError, match="frame K are collinear"):
        half_map(_TRIANGLE, line)
    with pytest.raises(ValueError, match="fraction"):
        half_map(_TRIANGLE, _TRIANGLE, 1.5)


def test_half_step_of_a_mirror_merge_stands_the_frame_on_edge():
    flip = Rotation.from_rotvec([0.0, math.pi, 0.0])  # turns x → −x, z → −z
    rot, v = half_step(flip, [0.0, 0.0, 0.0])
    assert rot.apply([0.0, 0.0, 1.0]) == pytest.approx([1.0, 0.0, 0.0])
    with pytest.raises(GeometryError, match="leave the plane"):
        apply_2d(rot, v, _TRIANGLE)


def test_half_step_refuses_bad_fractions_and_vectors():
    for bad in (-0.1, 1.5, math.nan):
        with pytest.raises(ValueError, match="fraction"):
            half_step(Rotation.identity(), [0.0, 0.0], bad)
    with pytest.raises(ValueError, match="2 or 3 components"):
        half_step(Rotation.identity(), [0.0, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("about_group", [False, True])
def test_two_mirror_image_frames_merge_by_half_steps(about_group):
    """Seeds I and K see the same five robots; K's frame is I's mirrored, turned and moved.
    Each round both apply half of the correction towards the other; their global views of the
    shared robots converge, and levelled they give the same plane coordinates."""
    local_i = np.array([[0.0, 0.0], [40.0, 0.0], [10.0, 35.0], [60.0, 30.0], [-20.0, 50.0]])
    local_k = local_i @ _orthogonal(2.0, True).T + [300.0, -120.0]
    t_i = (Rotation.identity(), np.zeros(3))
    t_k = (Rotation.identity(), np.zeros(3))
    gaps = []
    for _ in range(12):
        g_i, g_k = apply_3d(*t_i, local_i), apply_3d(*t_k, local_k)
        gaps.append(float(np.abs(g_i - g_k).max()))
        to_k = rotation_between_frames(g_i, g_k)
        to_i = rotation_between_frames(g_k, g_i)
        about_i = g_i.mean(axis=0) if about_group else None
        about_k = g_k.mean(axis=0) if about_group else None
        t_i = compose(*half_step(*to_k, about_mm=about_i), *t_i)
        t_k = compose(*half_step(*to_i, about_mm=about_k), *t_k)
    assert gaps[0] > 100.0
    assert gaps[-1] < 1e-6
    assert all(b <= a + 1e-9 for a, b in itertools.pairwise(gaps[2:]))
    flat_i, flat_k = level(*t_i), level(*t_k)
    xy_i = apply_2d(*flat_i, local_i, z_tol_mm=1e-6)
    xy_k = apply_2d(*flat_k, local_k, z_tol_mm=1e-6)
    assert xy_i == pytest.approx(xy_k, abs=1e-6)
    assert procrustes_rmse(xy_i, local_i)[0] < 1e-6  # distances kept


# ------------------------------------------------------------ compose, invert, apply, level


@settings(max_examples=40, deadline=None)
@given(
    quaternions,
    st.tuples(coord, coord, coord),
    quaternions,
    st.tuples(coord, coord, coord),
    point_sets,
)
def test_compose_and_invert_act_as_function_composition(q1, v1, q2, v2, points):
    t1, t2 = (Rotation.from_quat(q1), v1), (Rotation.from_quat(q2), v2)
    pts = np.array(points)
    both = apply_3d(*compose(*t1, *t2), pts)
    assert both == pytest.approx(apply_3d(*t1, apply_3d(*t2, pts)), abs=1e-6)
    back = apply_3d(*invert(*t1), apply_3d(*t1, pts))
    assert back == pytest.approx(np.column_stack([pts, np.zeros(len(pts))]), abs=1e-6)
    angle_left, shift_left = transform_distance(
        *compose(*t1, *invert(*t1)), Rotation.identity(), np.zeros(3)
    )
    assert angle_left < 1e-9 and shift_left < 1e-9


def test_apply_checks_the_plane_and_shapes():
    tilt = Rotation.from_euler("x", 1.0, degrees=True)
    pts = np.array([[0.0, 0.0], [0.0, 100.0]])
    with pytest.raises(GeometryError, match=r"\|z\| up to 1\.75 mm"):
        apply_2d(tilt, [0.0, 0.0], pts)
    assert apply_2d(tilt, [0.0, 0.0], pts, z_tol_mm=2.0)[1, 1] == pytest.approx(
        100.0 * math.cos(math.radians(1.0))
    )
    assert apply_2d(tilt, [0.0, 0.0], pts, z_tol_mm=None).shape == (2, 2)
    assert apply_3d(tilt, [1.0, 2.0, 3.0], pts)[0] == pytest.approx([1.0, 2.0, 3.0])
    assert apply_2d(tilt, [0.0, 0.0], np.zeros((0, 2))).shape == (0, 2)
    with pytest.raises(ValueError, match=r"\(k, 2\) or \(k, 3\)"):
        apply_3d(tilt, [0.0, 0.0], np.zeros((3, 4)))
    with pytest.raises(ValueError, match="2 or 3 components"):
        apply_3d(tilt, [0.0], pts)


def test_transform_distance_exact_values():
    r1 = Rotation.from_euler("z", 10, degrees=True)
    r2 = Rotation.from_euler("z", 40, degrees=True)
    angle_12, shift_12 = transform_distance(r1, [0.0, 0.0], r2, [3.0, 4.0])
    assert (angle_12, shift_12) == (pytest.approx(math.radians(30.0)), 5.0)
    assert transform_distance(r2, [3.0, 4.0], r1, [0.0, 0.0])[0] == pytest.approx(angle_12)
    flip = Rotation.from_rotvec([math.pi, 0.0, 0.0])
    assert transform_distance(Rotation.identity(), [0, 0], flip, [0, 0])[0] == pytest.approx(
        math.pi
    )


@settings(max_examples=60, deadline=None)
@given(quaternions, st.tuples(coord, coord, coord), point_sets)
def test_level_lays_any_frame_flat_keeping_distances(quat, shift, points):
    rot = Rotation.from_quat(quat)
    flat_rot, flat_shift = level(rot, shift)
    assert abs(flat_rot.apply([0.0, 0.0, 1.0])[2]) == pytest.approx(1.0, abs=1e-9)
    assert flat_shift[2] == 0.0
    pts = np.array(points)
    flat = apply_2d(flat_rot, flat_shift, pts, z_tol_mm=1e-6)
    tilted = apply_3d(rot, shift, pts)
    dist = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    dist_tilted = np.linalg.norm(tilted[:, None] - tilted[None], axis=-1)
    assert dist == pytest.approx(dist_tilted, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(quaternions, st.tuples(coord, coord, coord), angle, point, point_sets)
def test_level_agrees_for_mirror_image_frames_on_one_plane(quat, shift, turn, move, points):
    """Frames I and K show the same robots in one global plane, K's local frame mirrored:
    their seeds' rotations differ by a flip, yet levelling gives the same plane coordinates."""
    rot_i = Rotation.from_quat(quat)
    normal = rot_i.apply([0.0, 0.0, 1.0])
    assume(abs(normal @ _LEVEL_UP) > 0.05)  # away from the rule's (measure-zero) seam
    local_i = np.array(points)
    m = _orthogonal(turn, True)
    local_k = local_i @ m.T + move
    # K's transform: undo K's local map (mirror as a 3-D flip), then I's transform.
    to_i = rotation_between_frames(local_k, local_i) if _spread(local_i) > 5 else None
    assume(to_i is not None)
    t_k = compose(rot_i, shift, *to_i)
    assert apply_3d(*t_k, local_k) == pytest.approx(apply_3d(rot_i, shift, local_i), abs=1e-6)
    xy_i = apply_2d(*level(rot_i, shift), local_i)
    xy_k = apply_2d(*level(*t_k), local_k)
    assert xy_i == pytest.approx(xy_k, abs=1e-6)


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
