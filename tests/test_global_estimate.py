"""A robot's global estimate (kilonet.protocols.gcs.global_estimate): derived from what it holds,
never stale, changed only through its methods."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kilonet.protocols.gcs.frame_keys import FrameKey, Rank, Root
from kilonet.protocols.gcs.global_estimate import GlobalEstimate
from kilonet.protocols.gcs.transforms import Transform, version_byte

A, B, C = FrameKey(3, 1), FrameKey(5, 2), FrameKey(8, 0)
ROOT_1 = Rank.own(FrameKey(1, 0), edge=False)


def transform(shift=(0.0, 0.0, 0.0), *, degrees: float = 0.0, done: bool = False) -> Transform:
    rotation = Rotation.from_euler("z", degrees, degrees=True)
    return Transform(np.array(shift), version_byte(1, done), rotation=rotation)


def located(*keys: FrameKey) -> GlobalEstimate:
    est = GlobalEstimate()
    for n, key in enumerate(keys):
        est.locate(key, (10.0 * n, 0.0))
    return est


def test_no_estimate_without_transform_and_rank():
    est = located(A)
    assert est.frames_used() == (None, ()) and est.position() is None and not est.settled()
    est.hear_transform(A, transform())
    assert est.position() is None  # the rank is missing still
    est.hear_rank(A, ROOT_1)
    assert est.frames_used() == (ROOT_1.root, (A,))
    assert est.position() == pytest.approx((0.0, 0.0))


def test_the_estimate_follows_every_change_of_what_it_is_computed_from():
    est = located(A)
    est.hear_rank(A, ROOT_1)
    est.hear_transform(A, transform((5.0, 0.0, 0.0)))
    assert est.position() == pytest.approx((5.0, 0.0))
    est.hear_transform(A, transform((7.0, 1.0, 0.0)))
    assert est.position() == pytest.approx((7.0, 1.0))
    est.hear_transform(A, transform((7.0, 1.0, 0.0), done=True))
    assert est.settled()
    est.forget_merging()
    assert est.position() is None and not est.settled()


def test_only_frames_of_the_smallest_root_are_averaged():
    est = located(A, B, C)  # at x = 0, 10, 20 in frames A, B, C
    for key in (A, B, C):
        est.hear_transform(key, transform(done=True))
    est.hear_rank(A, ROOT_1)
    est.hear_rank(B, ROOT_1.one_hop_further())
    est.hear_rank(C, Rank.own(FrameKey(2, 0), edge=False))  # another merged frame
    assert est.root() == ROOT_1.root
    assert est.frames_used() == (ROOT_1.root, (A, B))
    assert est.position() == pytest.approx((5.0, 0.0))
    assert est.settled()
    # An elected root beats any edge seed's root.
    est.hear_rank(A, Rank.own(FrameKey(0, 0), edge=True))
    est.hear_rank(B, Rank.own(FrameKey(0, 0), edge=True))
    assert est.frames_used() == (Root(False, FrameKey(2, 0)), (C,))


def test_settled_needs_every_frame_used_done():
    est = located(A, B)
    est.hear_rank(A, ROOT_1)
    est.hear_rank(B, ROOT_1)
    est.hear_transform(A, transform(done=True))
    est.hear_transform(B, transform(done=False))
    assert not est.settled()
    est.hear_transform(B, transform(done=True))
    assert est.settled()


def test_the_version_moves_only_for_changes_to_frames_the_robot_is_in():
    est = located(A)
    est.hear_transform(A, transform())
    v = est.version
    est.hear_transform(B, transform())
    assert est.hear_rank(B, ROOT_1) and est.version == v  # B is no frame of this robot
    est.hear_rank(A, ROOT_1)
    assert est.version == v + 1
    assert not est.hear_rank(A, ROOT_1) and est.version == v + 1  # nothing new
    est.locate(B, (1.0, 2.0))
    assert est.version == v + 2
    assert est.frames_used() == (ROOT_1.root, (A, B))  # B's earlier transform and rank count


def test_the_views_are_read_only():
    est = located(A)
    with pytest.raises(TypeError):
        est.frames[B] = (0.0, 0.0)
    with pytest.raises(TypeError):
        est.ranks[A] = ROOT_1
    with pytest.raises(TypeError):
        est.transforms[A] = transform()
    with pytest.raises(AttributeError):
        est.unknown = 1  # slots only


def test_a_mirror_image_frame_reads_the_same_flat_axes():
    # Frame B is turned over (a 180° turn about x): its robots' "global" points lie in the same
    # plane, and the estimate reads them in the same 2-D axes as frame A's.
    est_a, est_b = located(A), located(B)
    est_a.hear_rank(A, ROOT_1)
    est_b.hear_rank(B, ROOT_1)
    est_a.hear_transform(A, transform())
    flip = Transform(np.zeros(3), 0, rotation=Rotation.from_euler("x", 180, degrees=True))
    est_b.locate(B, (0.0, -10.0))
    est_a.locate(A, (0.0, 10.0))
    est_b.hear_transform(B, flip)
    assert est_a.position() == pytest.approx(est_b.position())
