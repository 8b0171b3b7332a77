"""The trilateration frame robots (kilonet.protocols.follower.follower's Origin, XAxisRobot,
ThirdRobot) on the test kit: what each announces, when it flags its coordinates, the seed's LED
colours; first hearing scripted reports, then beside the real frame robots in the real medium."""

from __future__ import annotations

import math

import pytest

from kilonet.message import LIMITS
from kilonet.params import MediumParams
from kilonet.protocols.common.geometry import place_references
from kilonet.protocols.follower.follower import (
    FRAME_BYTE,
    FRAME_WIDE,
    ORIGIN,
    THIRD,
    X_AXIS,
    FrameReport,
    Origin,
    ThirdRobot,
    XAxisRobot,
    encode,
)

_MEDIUM = MediumParams()
#: One message's airtime on the default medium: its bytes at the bit rate, plus the preamble.
AIRTIME_S = LIMITS["kilolib"].air_bytes * 8 / _MEDIUM.bitrate_bps + _MEDIUM.preamble_s
FROM_ORIGIN = encode(FrameReport(ORIGIN, True))
WHITE, BLUE, GREEN, YELLOW, PURPLE = (3, 3, 3), (0, 0, 3), (0, 3, 0), (3, 3, 0), (3, 0, 3)


def test_the_origin_announces_known_zero_coordinates_and_blinks_white(scripted_world):
    world = scripted_world(Origin(), layouts=[FRAME_BYTE])
    sent = world.assert_sent(FRAME_BYTE, within_s=1.0, sender=ORIGIN, known=1, x_mm=0, y_mm=0)
    assert world.robot.color == WHITE
    world.advance(0.2)  # blink_s = 0.1 s
    assert world.robot.color == (0, 0, 0)
    assert world.colors()[:2] == [
        (sent.t_s, WHITE),
        (pytest.approx(sent.t_s + 0.1, abs=0.04), (0, 0, 0)),
    ]


def test_the_x_axis_robot_averages_its_readings_of_the_origin(scripted_world):
    world = scripted_world(XAxisRobot(samples=4), layouts=[FRAME_BYTE])
    world.assert_sent(FRAME_BYTE, within_s=1.0, sender=X_AXIS, known=0)
    for k, distance in enumerate([58, 61, 60, 62]):
        world.hear(FROM_ORIGIN, at_s=1.0 + 0.5 * k, distance_mm=distance)
    world.hear(encode(FrameReport(THIRD, False)), at_s=1.2)  # not from the origin: ignored
    flagged = world.eventually(lambda: world.robot.known, within_s=3.0)
    assert flagged == pytest.approx(2.5 + AIRTIME_S)
    assert world.robot.d12_mm == 60.25
    assert [e.fields for e in world.events("frame")] == [
        {"x_mm": 60.25, "y_mm": 0.0, "d12_mm": 60.25}
    ]
    # The byte layout rounds to whole millimetres.
    world.assert_sent(FRAME_BYTE, within_s=1.0, sender=X_AXIS, known=1, x_mm=60, d12_mm=60)
    yellow = [c.t_s for c in world.colors() if c.value == YELLOW]
    assert yellow == pytest.approx([1.0 + 0.5 * k + AIRTIME_S for k in range(4)])
    assert BLUE in {c.value for c in world.colors()}


def test_the_x_axis_robot_keeps_its_first_frame(scripted_world):
    world = scripted_world(XAxisRobot(samples=2))
    world.hear_every(FROM_ORIGIN, period_s=0.5, until_s=1.0, distance_mm=50)
    world.hear_every(FROM_ORIGIN, period_s=0.5, from_s=1.0, until_s=4.0, distance_mm=80)
    world.advance(4.0)
    assert world.robot.d12_mm == 50.0 and len(world.events("frame")) == 1


def test_the_third_robot_solves_the_seeds_triangle(scripted_world):
    # d12 = 60, d13 = 80, d23 = 100: x3 = (6400 - 10000 + 3600) / 120 = 0, y3 = 80.
    world = scripted_world(
        ThirdRobot(samples=3), layouts=[FRAME_BYTE], params={"medium.range_mm": 120}
    )
    x_axis = encode(FrameReport(X_AXIS, True, 60.0, 0.0, 60.0))
    world.hear_every(FROM_ORIGIN, period_s=0.5, until_s=2.0, distance_mm=80, sender="origin")
    world.hear_every(x_axis, period_s=0.5, from_s=0.25, until_s=2.0, distance_mm=100, sender="x")
    world.eventually(lambda: world.robot.known, within_s=2.0)
    assert (world.robot.x_mm, world.robot.y_mm) == (0.0, 80.0)
    world.assert_sent(
        FRAME_BYTE,
        within_s=1.0,
        sender=THIRD,
        known=1,
        x_mm=0,
        y_mm=80,
        d12_mm=60,
        d13_mm=80,
        d23_mm=100,
    )
    colours = {c.value for c in world.colors()}
    assert {YELLOW, PURPLE, GREEN} <= colours


def test_the_third_robot_waits_for_a_flagged_d12(scripted_world):
    world = scripted_world(ThirdRobot(samples=2))
    unknown = encode(FrameReport(X_AXIS, False))
    world.hear_every(FROM_ORIGIN, period_s=0.5, until_s=3.0, distance_mm=60)
    world.hear_every(unknown, period_s=0.5, from_s=0.25, until_s=3.0, distance_mm=60)
    world.never(lambda: world.robot.known, for_s=3.0)


def test_the_third_robot_starts_over_on_readings_that_form_no_triangle(scripted_world):
    world = scripted_world(ThirdRobot(samples=2))
    x_axis = encode(FrameReport(X_AXIS, True, 80.0, 0.0, 80.0))
    world.hear_every(FROM_ORIGIN, period_s=0.5, until_s=1.0, distance_mm=35)
    world.hear_every(x_axis, period_s=0.5, from_s=0.25, until_s=1.0, distance_mm=35)  # 35+35 < 80
    world.advance(1.5)
    assert not world.robot.known
    (rejected,) = world.events("frame_rejected")
    assert rejected.fields == {
        "reason": "distances |AB|=80, |AC|=35.0, |BC|=35.0 mm form a degenerate triangle: C is "
        "0 mm from line AB (need >= 1.0 mm)"
    }
    # It started over: fresh readings alone make the frame (old ones would skew it).
    good = encode(FrameReport(X_AXIS, True, 45.0, 0.0, 45.0))
    world.hear_every(FROM_ORIGIN, period_s=0.5, until_s=2.5, distance_mm=60)
    world.hear_every(good, period_s=0.5, from_s=1.75, until_s=2.5, distance_mm=75)
    world.eventually(lambda: world.robot.known, within_s=1.5)
    assert (world.robot.x_mm, world.robot.y_mm) == pytest.approx((0.0, 60.0))


def test_the_wide_layout_carries_tenths(scripted_world):
    world = scripted_world(XAxisRobot(samples=2, wide=True), layouts=[FRAME_WIDE])
    world.hear(FROM_ORIGIN, at_s=0.1, distance_mm=60)
    world.hear(FROM_ORIGIN, at_s=0.6, distance_mm=61)
    world.eventually(lambda: world.robot.known, within_s=1.0)
    sent = world.assert_sent(FRAME_WIDE, within_s=1.0, sender=X_AXIS, known=1)
    assert sent.fields.x_mm == pytest.approx(60.5)


def test_the_frame_forms_beside_the_real_origin_and_x_axis_robot(scripted_world):
    """The third robot between the real robots 1 and 2, through the real medium (ranging
    noise 1 mm, averaged over 8 readings)."""
    # Independent noise (ranging.model = gaussian): the test checks the averaging; on the
    # default tables each link also has a systematic error of a few mm that no averaging
    # removes, and x3 = (d13² - d23² + d12²) / (2 d12) magnifies it.
    world = scripted_world(ThirdRobot(), seed=3, params={"ranging.model": "gaussian"})
    world.add_neighbour(Origin(), at_mm=(0.0, -60.0))  # d13 = 60
    world.add_neighbour(XAxisRobot(), at_mm=(45.0, -60.0))  # d12 = 45, d23 = 75
    world.eventually(lambda: world.robot.known, within_s=30.0)
    _, (x3, y3) = place_references(45.0, 60.0, 75.0)
    assert (x3, y3) == pytest.approx((0.0, 60.0))
    assert world.robot.x_mm == pytest.approx(x3, abs=2.0)
    assert world.robot.y_mm == pytest.approx(y3, abs=1.0)
    assert world.robot.d12_mm == pytest.approx(45.0, abs=1.0)  # robot 2's averaged reading
    heard_from = {h.sender for h in world.heard()}
    assert heard_from == {1, 2}
    assert math.isclose(world.robot.d13_mm, 60.0, abs_tol=1.0)
