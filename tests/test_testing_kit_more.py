"""The test kit as a protocol tester's second hour needs it: uids and headings for a swarm,
assertions over time for swarms, windows for assert_sent, never-sends, the robot's pose, the
user's own line in a failing assert_each, the kit under Hypothesis, layouts the strategies take."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kilonet.message import FIELD_CODES, Layout, Message, PayloadError
from kilonet.robot import Kilobot
from kilonet.testing import ScriptedWorld, ScriptError, run_swarm
from kilonet.testing.strategies import payloads

PING = Layout("ping", type=2, fields=[("n", "B")])


class Counter(Kilobot):
    """Sends PING(n) at every opportunity, n counting what it sent; stops at 3."""

    def setup(self) -> None:
        self.n = 0

    def message_tx(self) -> Message | None:
        return PING.pack(n=self.n) if self.n < 3 else None

    def message_tx_success(self) -> None:
        self.n += 1


class Uid(Kilobot):
    def setup(self) -> None:
        self.uid = self.kilo_uid


def test_run_swarm_takes_uids_and_headings():
    result = run_swarm(Uid, "line", robots=3, uids=[42, 7, 9], headings_rad=[0.0, 1.0, 2.0],
                       until_s=0.1)  # fmt: skip
    assert [p.uid for p in result.programs] == [42, 7, 9]
    assert result.robots.heading_rad.tolist() == [0.0, 1.0, 2.0]
    with pytest.raises(ScriptError, match="uids gives 2 values for 3 robots"):
        run_swarm(Uid, "line", robots=3, uids=[1, 2])


def test_a_swarm_runs_on_until_a_condition_holds_or_says_what_happened():
    result = run_swarm(Counter, "line", robots=2, until_s=0.1)
    t_s = result.eventually(lambda programs: all(p.n == 3 for p in programs), within_s=5.0)
    assert 1.0 < t_s < 2.0 and result.t_s == t_s  # three messages, one per 0.5 s
    with pytest.raises(AssertionError) as failure:
        result.eventually(lambda programs: programs[0].n > 3, within_s=1.0)
    text = str(failure.value)
    assert text.startswith("condition `programs[0].n > 3` did not hold within 1 s")
    assert "robot 0 at (0.0, 0.0) mm: n=3" in text and "sent 3, received 3" in text
    result.never(lambda programs: programs[1].n > 3, for_s=1.0)
    with pytest.raises(AssertionError, match=r"n is 3 held at .* \(0.000 s into the 1 s"):
        result.never(lambda programs: programs[1].n == 3, for_s=1.0, what="n is 3")


def test_assert_sent_within_is_a_window_and_since_starts_one():
    world = ScriptedWorld(Counter(), layouts=[PING])
    world.advance(0.6)
    first = world.assert_sent(PING, n=0)  # so far, from the start
    assert first.t_s < 0.6
    with pytest.raises(AssertionError, match=r"robot 0 sent no ping with n=0 from 0\.600 s"):
        world.assert_sent(PING, within_s=2.0, n=0)  # sent before the window: does not count
    assert world.assert_sent(PING, since_s=0.6, n=1).t_s >= 0.6
    world.assert_not_sent(PING, for_s=5.0, n=7)
    with pytest.raises(AssertionError, match=r"robot 0 sent ping Ping\(n=0\) at"):
        ScriptedWorld(Counter(), layouts=[PING]).assert_not_sent(PING, for_s=1.0)


def test_the_pose_of_the_robot_under_test_and_of_a_neighbour():
    world = ScriptedWorld(Counter(), heading_rad=0.5)
    world.add_neighbour(Counter, distance_mm=60, bearing_deg=90)
    assert world.pose() == (0.0, 0.0, 0.5)
    x, y, _ = world.pose(robot=1)
    assert (x, y) == (0.0, 60.0)


@settings(max_examples=10, database=None)
@given(st.integers(0, 2))
def test_a_scripted_world_built_inside_given(n):
    # the documented way under Hypothesis: a world per example, not the fixture
    world = ScriptedWorld(Counter(), seed=n)
    world.advance(2.0)
    assert [s.fields.n for s in world.sent(PING)] == [0, 1, 2]


def test_a_layout_refuses_a_code_the_strategies_cannot_draw():
    with pytest.raises(PayloadError, match=r"field x has struct code 'f'; a field is one of B, b"):
        Layout("bad", type=1, fields=[("x", "f")])
    for code in FIELD_CODES:  # every code a layout takes, the strategies draw
        payloads(Layout("good", type=1, fields=[("x", code)]))


def test_a_failing_assert_each_points_at_the_test_not_the_kit(pytester):
    pytester.makepyfile(
        """
        from kilonet.robot import Kilobot
        from kilonet.testing import run_swarm


        def test_mine():
            result = run_swarm(Kilobot, "line", robots=2, until_s=0.1)
            result.assert_each(lambda i, p: i == 0, what="only robot 0")
        """
    )
    outcome = pytester.runpytest("-p", "no:cacheprovider")
    outcome.assert_outcomes(failed=1)
    text = outcome.stdout.str()
    assert '>       result.assert_each(lambda i, p: i == 0, what="only robot 0")' in text
    assert "raise AssertionError(" not in text
    assert "only robot 0 fails for 1 of 2 robots" in text


def test_the_pose_heading_is_in_radians():
    world = ScriptedWorld(Counter(), heading_rad=math.pi)
    assert world.pose()[2] == pytest.approx(math.pi)
