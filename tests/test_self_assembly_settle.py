"""Issue 47, warping: a robot that stopped in the shape serves as a localization anchor only
once its estimate settled standing still (``rules.settled``), so the lag of a moving robot's
estimate is not handed on ring by ring (it turned the 100-robot square about the seeds)."""

from __future__ import annotations

import math

from kilonet.protocols.self_assembly.program import ASSEMBLY, AssemblyStage, SelfAssembly
from kilonet.protocols.self_assembly.rules import (
    SETTLE_MAX_S,
    SETTLE_MM,
    SETTLE_S,
    settled,
)
from kilonet.scenarios.self_assembly import SEEDS, load_shape
from kilonet.testing import ScriptedWorld


def test_a_robot_settles_after_standing_long_enough_with_a_small_last_step():
    assert not settled(SETTLE_S - 0.01, 0.0)  # too soon, however still its estimate
    assert settled(SETTLE_S, SETTLE_MM - 0.01)
    assert not settled(SETTLE_S + 5.0, SETTLE_MM)  # its estimate still moves
    assert not settled(SETTLE_S + 5.0, None)  # no update since it stopped
    # a robot that never settles (too few anchors in range) joins after SETTLE_MAX_S
    assert not settled(SETTLE_MAX_S - 0.01, None)
    assert settled(SETTLE_MAX_S, 12.0) and settled(SETTLE_MAX_S, None)


TRUE_MM = (40.0, 65.0)  # where the robot under test stands, in the seeds' frame


def _settling_robot() -> ScriptedWorld:
    """A robot that stopped in the shape with an estimate 14 mm off, hearing the four seeds at
    their true distances from it."""
    world = ScriptedWorld(SelfAssembly(load_shape("square", 40.0)), uid=50)
    seed = AssemblyStage.SEED.number
    for uid, (x, y) in enumerate(SEEDS):
        world.hear_every(
            ASSEMBLY.pack(
                uid=uid, gradient=int(uid > 0), stage=seed, age=0, x=round(x), y=round(y)
            ),
            period_s=0.5,
            from_s=0.05 + 0.1 * uid,
            until_s=30.0,
            distance_mm=math.hypot(TRUE_MM[0] - x, TRUE_MM[1] - y),
        )
    world.advance(1.0)
    robot = world.robot
    robot.gradient = 2
    robot.estimate = (TRUE_MM[0] - 10.0, TRUE_MM[1] + 10.0)
    robot._stop("shape_edge")  # what the stop rules call on a moving robot
    return world


def test_a_stopped_robot_settles_on_its_anchors_before_it_joins():
    world = _settling_robot()
    (stopped,) = world.events("stopped")
    assert stopped.fields["rule"] == "shape_edge" and stopped.fields["x"] == TRUE_MM[0] - 10.0
    assert world.robot.stage is AssemblyStage.SETTLE
    world.advance(0.9)
    # while it settles it says so: a moving robot does not range with it yet
    assert ASSEMBLY.unpack(world.sent()[-1].message).stage == AssemblyStage.SETTLE.number
    world.run_until(15.0)
    (joined,) = world.events("joined")
    assert joined.fields["rule"] == "shape_edge"
    assert SETTLE_S <= joined.t_s - stopped.t_s < SETTLE_MAX_S
    # integer distance estimates: the settled estimate is within a millimetre of the truth
    error = math.hypot(joined.fields["x"] - TRUE_MM[0], joined.fields["y"] - TRUE_MM[1])
    assert error < 1.0, joined.fields
    assert world.robot.stage is AssemblyStage.JOINED
    world.advance(1.0)
    assert ASSEMBLY.unpack(world.sent()[-1].message).stage == AssemblyStage.JOINED.number
