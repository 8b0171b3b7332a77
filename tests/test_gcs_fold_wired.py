"""The fold rule run by a real GcsRobot (kilonet.protocols.gcs.split_detection, ``gcs.fold``): a
settled robot whose same-frame neighbours disagree with it, by a majority, for
``gcs.fold_confirm_s`` leaves its frame (a split) or takes the refit position (a repair), and
what it broadcasts and reports follows.

The robot under test is settled in a scripted world beside six real GcsRobots (a 40 mm hex
lattice), as in tests/test_split_check.py. Then seven robots the others never hear (IDs 300 and
up) report POS in the robot's own merged frame, each 40 mm (measured, exactly) from a point
``offset_mm`` east of where the robot said it is: to them the robot is at that point. The six real
neighbours still agree with where the robot is, so no point fits all thirteen when the offset is
large (a split) and one between the two fits them all within the tolerance when it is small (a
repair). The double ring of issue 46 is the end-to-end case (tests/test_gcs_fold_measure.py).
"""

from __future__ import annotations

import math

import pytest

from kilonet import scenarios
from kilonet.protocols.gcs.frame_keys import Root
from kilonet.protocols.gcs.program import GcsRobot, phase_windows_s
from kilonet.protocols.gcs.split_detection import POS
from kilonet.scenarios.base import build_params
from kilonet.scenarios.placement import hex_lattice

GCS = scenarios.get("gcs")
FIRST_STRANGER = 300  # IDs no robot here draws (gcs.id_bits = 8)
CONFIRM_S = 10.0


def _settled(scripted_world, fold: bool):
    """A world whose robot 0, not a seed, is settled in the merged frame (``gcs.fold``)."""
    overrides = {
        "gcs.frames_s": 10,
        "gcs.localization_s": 6,
        "gcs.fold": fold,
        "gcs.fold_confirm_s": CONFIRM_S,
    }
    params = build_params(GCS, overrides, seed=3)
    world = scripted_world(GcsRobot(params.scenario), params=params, layouts=[POS])
    for xy in hex_lattice(7, spacing_mm=40.0)[1:]:
        world.add_neighbour(GcsRobot(params.scenario), at_mm=tuple(xy))
    world.run_until(phase_windows_s(params.scenario)[-1][1])  # merging starts
    world.assert_sent(POS, within_s=30.0)
    world.advance(5.0)
    assert not world.robot.is_seed
    return world


def _strangers(world, own, offset_mm: float, angles_deg: tuple[float, ...], seconds: float):
    """Every second for ``seconds``, a POS from each stranger: 40 mm from ``offset_mm`` east of
    ``own`` (the robot's POS fields), at ``angles_deg``, measured at 40 mm exactly."""
    for _ in range(round(seconds)):
        for k, angle in enumerate(angles_deg):
            a = math.radians(angle)
            message = POS.pack(
                sender=FIRST_STRANGER + k,
                x_mm=own.x_mm + offset_mm + 40.0 * math.cos(a),
                y_mm=own.y_mm + 40.0 * math.sin(a),
                root=own.root,
                root_salt=own.root_salt,
            )
            world.hear(message, distance_mm=40, sender=f"stranger{k}", sense_carrier=True)
            world.advance(0.05)
        world.advance(1.0 - 0.05 * len(angles_deg))


#: Stranger bearings: each disagrees with the robot's own position by more than 8 mm.
FAR = (0.0, 30.0, -30.0, 60.0, -60.0, 90.0, -90.0)  # offset 60 mm: 12.9 to 60 mm
NEAR = (0.0, 25.0, -25.0, 180.0, 155.0, -155.0, 10.0)  # offset 14 mm: 11.5 to 14 mm


def test_a_robot_no_point_fits_leaves_its_frame(scripted_world):
    world = _settled(scripted_world, fold=True)
    robot = world.robot
    own = world.sent(POS)[-1].fields
    _strangers(world, own, 60.0, FAR, seconds=CONFIRM_S - 3)
    assert robot.check.outlier_since is not None and world.events("fold_split") == []
    _strangers(world, own, 60.0, FAR, seconds=6)
    (split,) = world.events("fold_split")
    own_root = Root(True, robot.own_key)
    assert split.fields["root"] == own_root.label
    assert set(range(FIRST_STRANGER, FIRST_STRANGER + 7)) <= set(split.fields["neighbours"])
    # A frame of one: the robot keeps its position, in a frame of its own, and stops
    # announcing it (its neighbours would see a split boundary and ask for a recovery).
    x, y, label = robot.position_estimate()
    assert (x, y) == pytest.approx((own.x_mm, own.y_mm), abs=0.5) and label == own_root.label
    assert robot.outcome().root == own_root
    sent = len(world.sent(POS))
    world.advance(10.0)
    assert len(world.sent(POS)) == sent
    assert world.events("fold_repaired") == [] and len(world.events("fold_split")) == 1


def test_a_robot_a_point_fits_takes_it(scripted_world):
    world = _settled(scripted_world, fold=True)
    robot = world.robot
    own = world.sent(POS)[-1].fields
    root_label = robot.position_estimate()[2]
    _strangers(world, own, 14.0, NEAR, seconds=CONFIRM_S + 4)
    (repair,) = world.events("fold_repaired")
    fixed = (repair.fields["x_mm"], repair.fields["y_mm"])
    # Between where the robot was and where the strangers put it, on the east-west line.
    assert 2.0 < fixed[0] - own.x_mm < 12.0 and abs(fixed[1] - own.y_mm) < 3.0
    x, y, label = robot.position_estimate()
    assert (x, y) == pytest.approx(fixed) and label == root_label
    assert robot.outcome().position == pytest.approx(fixed)
    world.advance(8.0)
    now = world.sent(POS)[-1].fields  # what it announces: the repaired position, 0.5 mm steps
    assert (now.x_mm, now.y_mm) == pytest.approx(fixed, abs=0.25)
    assert world.events("fold_split") == []


def test_with_the_rule_off_nothing_moves(scripted_world):
    world = _settled(scripted_world, fold=False)
    robot = world.robot
    own = world.sent(POS)[-1].fields
    before = robot.position_estimate()
    _strangers(world, own, 60.0, FAR, seconds=CONFIRM_S + 6)
    assert robot.check.outlier_since is not None  # the robot still sees the disagreement
    assert world.events("fold_split") == [] and world.events("fold_repaired") == []
    x, y, label = robot.position_estimate()  # merging's own small moves only
    assert (x, y) == pytest.approx(before[:2], abs=1.0) and label == before[2]
    assert not robot.awaiting_fold()
