"""The split check's flags (protocols.split_detection) describe the present: they lapse when a
neighbour stops reporting or the robot itself is merging again, and only a boundary that lasts
``gcs.split_confirm_s`` asks for a recovery.

The robot here is a stand-in exposing exactly what :class:`SplitCheck` reads of a
:class:`protocols.gcs.GcsRobot` (its clock, table, frames and log); the end-to-end behaviour is
covered by tests/test_thesis_cases.py.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from protocols.gcs_base import GcsParams
from protocols.neighbours import NeighbourTable
from protocols.split_detection import POS, SplitCheck

OWN_ROOT = 3 << 8
OTHER_ROOT = 9 << 8
TPS = 32


class StandInRobot:
    def __init__(self) -> None:
        self.params = GcsParams(split_confirm_s=20.0, recoveries=2)
        self.kilo_ticks = 0
        self.ticks_per_s = TPS
        self.epoch = 0
        # As GcsRobot: merge_state moves whenever what global_frames() reads changes.
        self.merge_state = 0
        self.frames = {OWN_ROOT: (0.0, 0.0)}
        self.settled = True
        self.events: list[str] = []
        self.table = NeighbourTable()
        self.table.heard(5, 40.0)
        self.transforms = {OWN_ROOT: SimpleNamespace(done=True)}

    @property
    def settled(self) -> bool:
        return self._settled

    @settled.setter
    def settled(self, value: bool) -> None:
        self._settled = value
        self.merge_state += 1

    @property
    def estimate_state(self):
        return self.merge_state, len(self.frames)

    def global_frames(self):
        return (OWN_ROOT, [OWN_ROOT]) if self.settled else (None, [])

    @property
    def global_root(self):
        return self.global_frames()[0]

    def global_position(self):
        return (0.0, 0.0)

    def log(self, event: str, **fields) -> None:
        self.events.append(event)


def _pos_from_5(root: int):
    return POS.pack(sender=5, x_mm=40.0, y_mm=0.0, root=root >> 8, root_salt=root & 0xFF)


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
    robot.settled = False  # one of its seeds resumed merging
    assert not check.wants_recovery()
    assert not check.on_split_boundary and check.boundary_since is None


def test_same_root_at_the_measured_distance_is_no_boundary(robot_and_check):
    _, check = robot_and_check
    check.message_rx(_pos_from_5(OWN_ROOT))
    assert not check.on_split_boundary and not check.inconsistent
    check.message_rx(
        POS.pack(sender=5, x_mm=60.0, y_mm=0.0, root=OWN_ROOT >> 8, root_salt=0)
    )  # 60 mm computed, 40 mm measured: more than check_tolerance_mm
    assert check.inconsistent == {5: pytest.approx(20.0)}
