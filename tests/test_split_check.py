"""The split check (protocols.split_detection) on a real GcsRobot: its flags describe the
present, they lapse when a neighbour stops reporting or the robot's own frame moves again, and
only a boundary that lasts ``gcs.split_confirm_s`` asks for a recovery.

The robot under test runs the whole protocol in a scripted world, beside six real GcsRobots
(a 40 mm hex lattice, so all seven hear each other), until it is settled in the merged frame.
Then the test scripts what a neighbour in another merged frame would say: POS messages from a
robot the others never hear (ID 300, beyond the 8-bit IDs they draw), at an exact distance.
The end-to-end behaviour is covered by tests/test_thesis_cases.py.
"""

from __future__ import annotations

import pytest

import scenarios
from kilonet.placement import hex_lattice
from protocols.frame_merging import TF_ROT, TF_SHIFT
from protocols.gcs import GcsRobot, phase_windows_s
from protocols.recovery import RECOVER
from protocols.split_detection import POS
from scenarios.base import build_params

GCS = scenarios.get("gcs")
STRANGER = 300  # an ID no robot here draws (gcs.id_bits = 8)
AT_MM = 40


@pytest.fixture
def settled(scripted_world):
    """A world whose robot 0, not a seed, is settled in the swarm's merged frame."""
    overrides = {"gcs.frames_s": 10, "gcs.localization_s": 6, "gcs.split_confirm_s": 20}
    params = build_params(GCS, overrides, seed=3)
    world = scripted_world(GcsRobot(params.scenario), params=params, layouts=[POS, RECOVER])
    for xy in hex_lattice(7, spacing_mm=40.0)[1:]:
        world.add_neighbour(GcsRobot(params.scenario), at_mm=tuple(xy))
    world.run_until(phase_windows_s(params.scenario)[-1][1])  # merging starts
    robot = world.robot
    world.eventually(lambda: robot.check is not None and robot.check.settled(), within_s=30)
    world.advance(5.0)
    assert not robot.is_seed and robot.check.settled() and robot.global_root is not None
    return world


def pos(world, *, root: int | None = None, dx_mm: float = AT_MM):
    """A POS from the stranger, ``dx_mm`` east of the robot, in frame ``root`` (default the
    robot's own merged frame)."""
    robot = world.robot
    x, y = robot.global_position()
    root = robot.global_root if root is None else root
    return POS.pack(sender=STRANGER, x_mm=x + dx_mm, y_mm=y, root=root >> 8, root_salt=root & 0xFF)


def other_root(world) -> int:
    return world.robot.global_root ^ (1 << 12)  # another seed ID, same salt


def report_every_second(world, seconds: int, **options) -> None:
    for _ in range(seconds):
        world.hear(pos(world, **options), distance_mm=AT_MM, sender="stranger", sense_carrier=True)
        world.advance(1.0)


def test_a_boundary_that_lasts_asks_for_recovery(settled):
    world, check = settled, settled.robot.check
    report_every_second(world, 2, root=other_root(world))  # the first only makes it a neighbour
    assert check.on_split_boundary and check.other_frame == {STRANGER: other_root(world)}
    (detected,) = world.events("split_detected")
    assert detected.fields == {"neighbours": [STRANGER]}
    for _ in range(18):
        report_every_second(world, 1, root=other_root(world))
        assert world.events("recovery_requested") == []  # 20 s have not passed
    report_every_second(world, 3, root=other_root(world))
    (requested,) = world.events("recovery_requested")
    own_s = 20.0 / world.sim.clocks.factor[0]  # 20 s of the robot's own clock
    assert requested.t_s - detected.t_s == pytest.approx(own_s, abs=0.1)
    world.assert_sent(RECOVER, within_s=1.0, sender=world.robot.uid, epoch=1)


def test_a_neighbour_that_falls_silent_lapses(settled):
    world, check = settled, settled.robot.check
    report_every_second(world, 2, root=other_root(world))
    assert check.on_split_boundary
    world.eventually(lambda: not check.on_split_boundary, within_s=6.0)  # _FRESH_S = 5 s
    assert check.boundary_since is None
    cleared = world.events("split_cleared")
    assert [e.fields["after_s"] for e in cleared] == [pytest.approx(5.0, abs=0.1)]
    world.never(lambda: world.events("recovery_requested"), for_s=30.0)


def test_a_robot_whose_frame_moves_again_drops_its_flags(settled):
    world, robot = settled, settled.robot
    report_every_second(world, 2, root=other_root(world))
    assert robot.check.on_split_boundary
    # Its seed announces its transform again, no longer done (bit 7 of the version clear):
    # the last TF_ROT and TF_SHIFT the robot heard from that seed, resent without the bit.
    seed = robot.global_frames()[1][0] >> 8
    for layout in (TF_ROT, TF_SHIFT):
        last = [h.fields for h in world.heard(layout) if h.fields.sender == seed][-1]
        assert last.version & 0x80  # it was done
        again = layout.pack(**{**last._asdict(), "version": last.version & 0x7F})
        world.hear(again, at_s=world.now_s + 0.01, distance_mm=AT_MM, sense_carrier=True)
    world.eventually(lambda: not robot.check.settled(), within_s=0.1)
    world.eventually(lambda: robot.check.boundary_since is None, within_s=0.1)
    assert not robot.check.on_split_boundary and robot.check.other_frame == {}
    assert len(world.events("split_cleared")) == 1


def test_same_root_at_the_measured_distance_is_no_boundary(settled):
    world, check = settled, settled.robot.check
    report_every_second(world, 2)
    assert not check.on_split_boundary and not check.inconsistent
    # 60 mm computed from the positions, 40 mm measured: more than check_tolerance_mm.
    report_every_second(world, 1, dx_mm=60.0)
    assert check.inconsistent == {STRANGER: pytest.approx(20.0, abs=0.5)}
    assert not check.on_split_boundary and world.events("split_detected") == []
