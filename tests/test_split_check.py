"""The split check's flags (protocols.split_detection) describe the present: they lapse when a
neighbour stops reporting or the robot itself is merging again, and only a boundary that lasts
``gcs.split_confirm_s`` asks for a recovery.

The robot here is a stand-in exposing exactly what :class:`SplitCheck` reads of a
:class:`protocols.gcs.GcsRobot` (its clock, table, log and a real
:class:`~protocols.global_estimate.GlobalEstimate`); the end-to-end behaviour is covered by
tests/test_thesis_cases.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from protocols.frame_keys import FrameKey, Rank, Root
from protocols.frame_merging import Transform, version_byte
from protocols.gcs_base import GcsParams
from protocols.global_estimate import GlobalEstimate
from protocols.neighbours import NeighbourTable
from protocols.split_detection import POS, SplitCheck

OWN = FrameKey(3, 0)
OWN_ROOT = Root(False, OWN)
OTHER_ROOT = Root(False, FrameKey(9, 0))
TPS = 32


class StandInRobot:
    def __init__(self) -> None:
        self.params = GcsParams(split_confirm_s=20.0, recoveries=2)
        self.uid = 1
        self.kilo_ticks = 0
        self.ticks_per_s = TPS
        self.epoch = 0
        self.events: list[str] = []
        self.table = NeighbourTable()
        self.table.heard(5, 40.0)
        # Located at the origin of its own frame, which is the root and done merging.
        self.estimate = GlobalEstimate()
        self.estimate.locate(OWN, (0.0, 0.0))
        self.estimate.hear_rank(OWN, Rank.own(OWN, edge=False))
        self.merge_again(done=True)

    def merge_again(self, *, done: bool) -> None:
        """Its seed broadcasts a new version of the transform, done or not."""
        self.estimate.hear_transform(
            OWN, Transform(np.zeros(3), version_byte(1, done), rotation=Rotation.identity())
        )

    def log(self, event: str, **fields) -> None:
        self.events.append(event)


def _pos_from_5(root: Root, x_mm: float = 40.0):
    return POS.pack(sender=5, x_mm=x_mm, y_mm=0.0, root=root.wire_id, root_salt=root.key.salt)


@pytest.fixture
def robot_and_check():
    robot = StandInRobot()
    return robot, SplitCheck(robot)


def _advance(robot, seconds: float) -> None:
    robot.kilo_ticks += round(seconds * TPS)


def test_a_boundary_that_lasts_asks_for_recovery(robot_and_check):
    robot, check = robot_and_check
    for _ in range(22):  # a POS from the other frame every second
        check.message_rx(_pos_from_5(OTHER_ROOT))
        assert not check.wants_recovery() or robot.kilo_ticks >= 20 * TPS
        _advance(robot, 1.0)
    assert check.on_split_boundary
    assert check.wants_recovery()
    assert robot.events == ["split_detected"]


def test_a_neighbour_that_falls_silent_lapses(robot_and_check):
    robot, check = robot_and_check
    check.message_rx(_pos_from_5(OTHER_ROOT))
    assert check.on_split_boundary
    _advance(robot, 30.0)  # no POS since: the neighbour is merging again
    assert not check.wants_recovery()
    assert not check.on_split_boundary and check.boundary_since is None
    assert robot.events == ["split_detected", "split_cleared"]


def test_a_robot_merging_again_drops_its_flags(robot_and_check):
    robot, check = robot_and_check
    check.message_rx(_pos_from_5(OTHER_ROOT))
    _advance(robot, 1.0)
    robot.merge_again(done=False)  # its seed resumed merging
    assert not robot.estimate.settled()
    assert not check.wants_recovery()
    assert not check.on_split_boundary and check.boundary_since is None


def test_same_root_at_the_measured_distance_is_no_boundary(robot_and_check):
    _, check = robot_and_check
    check.message_rx(_pos_from_5(OWN_ROOT))
    assert not check.on_split_boundary and not check.inconsistent
    # 60 mm computed, 40 mm measured: more than check_tolerance_mm
    check.message_rx(_pos_from_5(OWN_ROOT, x_mm=60.0))
    assert check.inconsistent == {5: pytest.approx(20.0)}


def test_an_edge_root_is_another_frame(robot_and_check):
    # The same frame key as the robot's root, but an edge seed's: ranks order it last, so it
    # is another merged frame (bit 15 of the POS root field carries it).
    _, check = robot_and_check
    check.message_rx(_pos_from_5(Root(True, OWN)))
    assert check.other_frame == {5: Root(True, OWN)}
