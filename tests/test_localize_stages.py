"""localize on the phase driver (kilonet.protocols.localize.stages): each stage's phase does
the stage's work and names its own receive handlers, and the program dispatches on the driver
alone."""

from __future__ import annotations

import ast
import inspect
from pathlib import Path

import numpy as np
import pytest

import kilonet.protocols.localize.program as localize_module
from kilonet import scenarios
from kilonet.protocols.localize.base import LOCALIZED
from kilonet.protocols.localize.phase1_election import ELECT
from kilonet.protocols.localize.phase2_spread import POS
from kilonet.protocols.localize.phase4_island import ISLAND_FULL, ISLAND_PAIR
from kilonet.protocols.localize.stages import (
    DonePhase,
    ElectionPhase,
    IslandPhase,
    LocalizeStage,
    LocalizingPhase,
)

LOCALIZE = scenarios.get("localize")


@pytest.fixture(scope="module")
def sim():
    return scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim


def _robot(sim, index: int = 0) -> localize_module.LocalizeRobot:
    robot = localize_module.LocalizeRobot(sim.robots[0].params)
    robot._attach(sim, index, np.random.default_rng(index))
    robot.setup()
    return robot


def _pos(sender: int) -> object:
    return POS.pack(sender=sender, x_mm=400.0, y_mm=0.0, hops=3, flags=LOCALIZED, windings=0)


def test_program_py_compares_no_stage_and_names_no_stage():
    """No if/elif over stages: the program neither compares its stage nor names one."""
    tree = ast.parse(Path(inspect.getfile(localize_module)).read_text())
    names = set(LocalizeStage.names())
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            for o in (node.left, *node.comparators):
                assert not (isinstance(o, ast.Attribute) and o.attr == "stage"), node.lineno
                assert not (isinstance(o, ast.Constant) and o.value in names), node.lineno
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
            assert node.value.id != "LocalizeStage", f"line {node.lineno}"


def test_every_stage_has_a_phase_and_the_robot_starts_electing(sim):
    phases = (ElectionPhase, LocalizingPhase, IslandPhase, DonePhase)
    assert [cls.name for cls in phases] == list(LocalizeStage)
    robot = _robot(sim)
    assert robot.stage == "election"
    assert robot.driver.handler(ELECT.type) == robot.election.message_rx


def test_an_electing_robot_that_hears_the_frame_moves_on_before_taking_the_message_in(sim):
    robot = _robot(sim)
    robot.message_rx(_pos(10), 45)
    assert robot.stage == "localize"
    assert robot.urgent
    assert robot.reports is None  # only the root keeps its neighbours' reports
    n = robot.neighbours.by_id[10]
    # The hop counts started over before POS was read: the frame's count stands.
    assert (n.hops, n.x_mm, n.y_mm) == (3, 400.0, 0.0)
    assert robot.driver.handler(ELECT.type) == robot._parent_rx
    assert robot.driver.handler(POS.type) == robot._state_rx


def test_an_electing_robot_that_wins_becomes_the_root_at_the_origin(sim):
    robot = _robot(sim)
    robot.election.won = True
    robot._work(robot.kilo_ticks, [], full=False)
    assert (robot.stage, robot.is_root, robot.position, robot.urgent) == (
        "localize",
        True,
        (0.0, 0.0),
        True,
    )
    assert robot.reports == {}  # the root chooses its frame robots from them


def test_island_messages_are_handled_in_the_island_stage_only(sim):
    robot = _robot(sim)
    for kind in (ISLAND_PAIR.type, ISLAND_FULL.type):
        assert robot.driver.handler(kind) is None
    robot.driver.enter(IslandPhase(robot))
    assert robot.driver.handler(ISLAND_PAIR.type) == robot.island.pair_rx
    assert robot.driver.handler(ISLAND_FULL.type) == robot.island.full_rx
    robot.driver.enter(DonePhase(robot))
    assert robot.driver.handler(ISLAND_PAIR.type) is None


def test_a_done_robot_hears_nothing_and_sends_only_the_done_it_owes(sim):
    robot = _robot(sim)
    robot.driver.enter(DonePhase(robot))
    robot.message_rx(_pos(10), 45)
    assert 10 not in robot.neighbours.by_id
    robot.termination.repeats_left = 0
    assert robot.message_tx() is None
    robot.termination.repeat_done()
    message = robot.message_tx()
    assert message is not None and message.type == POS.type


def test_a_localizing_robot_that_is_done_logs_its_next_stage_and_goes_dark(sim):
    robot = _robot(sim)
    robot.driver.enter(LocalizingPhase(robot))
    robot.termination.finish("heard")
    robot._work(robot.kilo_ticks, [], full=False)
    # Unplaced among no unplaced neighbours: no island to wake for.
    assert robot.stage == "done"
    assert not robot.driver.phase.awake
    robot._next_round = 0
    robot.loop()  # a done robot does no more rounds
    assert robot.round_index == 0
