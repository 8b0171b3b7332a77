"""The split check (kilonet.protocols.gcs.split_detection) on a real GcsRobot: its flags describe
the present, they lapse when a neighbour stops reporting or the robot's own frame moves again, and
only a boundary that lasts ``gcs.split_confirm_s`` asks for a recovery.

The robot under test runs the whole protocol in a scripted world, beside six real GcsRobots
(a 40 mm hex lattice, so all seven hear each other), until it is settled in the merged frame
(it broadcasts its position: POS). Then the test scripts what a neighbour in another merged
frame would say: POS messages from a robot the others never hear (ID 300, beyond the 8-bit IDs
they draw), at an exact distance. Everything scripted is built from messages the robot itself
sent or heard, so the test reads no protocol state beyond the check's flags. The end-to-end
behaviour is covered by tests/test_thesis_cases.py.
"""

from __future__ import annotations

import pytest

from kilonet import scenarios
from kilonet.protocols.gcs.phase6_merging import TF_ROT, TF_SHIFT
from kilonet.protocols.gcs.program import GcsRobot, phase_windows_s
from kilonet.protocols.gcs.recovery import RECOVER
from kilonet.protocols.gcs.split_detection import POS
from kilonet.scenarios.base import build_params
from kilonet.scenarios.placement import hex_lattice

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
    world.assert_sent(POS, within_s=30.0)  # settled: it announces its global position
    world.advance(5.0)
    assert not world.robot.is_seed
    return world


def pos(world, *, other_frame: bool = False, dx_mm: float = AT_MM):
    """A POS from the stranger, ``dx_mm`` east of where the robot last said it is, in the
    robot's merged frame or (``other_frame``) another one: the root's ID with bit 12 flipped."""
    own = world.sent(POS)[-1].fields
    root = own.root ^ (1 << 12) if other_frame else own.root
    return POS.pack(
        sender=STRANGER, x_mm=own.x_mm + dx_mm, y_mm=own.y_mm, root=root, root_salt=own.root_salt
    )


def report(world, seconds: float, **options) -> None:
    """The stranger's POS every half second for ``seconds``. It waits for a free channel at
    the robot, but the neighbours cannot hear it (a hidden terminal), so now and then one of
    them starts sending into it and the two collide: the flags must not hang on one message."""
    for _ in range(round(seconds / 0.5)):
        world.hear(pos(world, **options), distance_mm=AT_MM, sender="stranger", sense_carrier=True)
        world.advance(0.5)


def test_a_boundary_that_lasts_asks_for_recovery(settled):
    world, check = settled, settled.robot.check
    report(world, 2.0, other_frame=True)  # the first delivered only makes it a neighbour
    assert check.on_split_boundary and set(check.other_frame) == {STRANGER}
    (detected,) = world.events("split_detected")
    assert detected.fields == {"neighbours": [STRANGER]}
    for _ in range(17):
        report(world, 1.0, other_frame=True)
        assert world.events("recovery_requested") == []  # 20 s have not passed
    report(world, 4.0, other_frame=True)
    (requested,) = world.events("recovery_requested")
    own_s = 20.0 / world.sim.clocks.factor[0]  # 20 s of the robot's own clock
    assert requested.t_s - detected.t_s == pytest.approx(own_s, abs=0.1)
    world.assert_sent(RECOVER, within_s=1.0, sender=world.robot.uid, epoch=1)
    assert len(world.events("split_cleared")) == 0  # it never lapsed meanwhile


def test_a_neighbour_that_falls_silent_lapses(settled):
    world, check = settled, settled.robot.check
    report(world, 2.0, other_frame=True)
    assert check.on_split_boundary
    world.eventually(lambda: not check.on_split_boundary, within_s=6.0)  # _FRESH_S = 5 s
    assert check.boundary_since is None
    (cleared,) = world.events("split_cleared")
    last_heard = [h.t_s for h in world.heard(POS) if h.sender == "stranger"][-1]
    detected = world.events("split_detected")[0].t_s
    assert cleared.fields["after_s"] == pytest.approx(last_heard - detected + 5.0, abs=0.15)
    world.never(lambda: world.events("recovery_requested"), for_s=30.0)


def test_a_robot_whose_frame_moves_again_drops_its_flags(settled):
    world, robot = settled, settled.robot
    report(world, 2.0, other_frame=True)
    assert robot.check.on_split_boundary
    # The seeds announce their transforms again, no longer done (bit 7 of the version clear):
    # the last TF_ROT and TF_SHIFT the robot heard from each, resent without the bit. The
    # robot's own estimate then moves, and it is no longer settled.
    for layout in (TF_ROT, TF_SHIFT):
        last = {h.fields.sender: h.fields for h in world.heard(layout) if h.fields.version & 0x80}
        assert last  # they were done
        for fields in last.values():
            again = layout.pack(**{**fields._asdict(), "version": fields.version & 0x7F})
            world.hear(again, distance_mm=AT_MM, sense_carrier=True)
    world.eventually(lambda: robot.check.boundary_since is None, within_s=0.5)
    assert not robot.check.on_split_boundary and robot.check.other_frame == {}
    assert len(world.events("split_cleared")) == 1
    assert world.events("split_cleared")[0].t_s - world.now_s < 0.1


def test_same_root_at_the_measured_distance_is_no_boundary(settled):
    world, check = settled, settled.robot.check
    report(world, 2.0)
    assert not check.on_split_boundary and not check.inconsistent
    # 60 mm computed from the positions, 40 mm measured: more than check_tolerance_mm.
    report(world, 1.0, dx_mm=60.0)
    assert check.inconsistent == {STRANGER: pytest.approx(20.0, abs=0.5)}
    assert not check.on_split_boundary and world.events("split_detected") == []
