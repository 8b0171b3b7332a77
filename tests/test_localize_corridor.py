"""``localize`` in long corridors: the convergecast waits for the far end.

The termination's convergecast climbs the tree of parents (:func:`toward_root`). In a 5 m
corridor (seed 3) the root declared the swarm done at 42.4 s while the frame's front was 2.8 m
from it and 131 robots beyond stayed unplaced: every robot from 1.25 m on hung below parent
cycles, which no robot on the root's side waited for (the hop count rose and fell as
neighbours went unheard), and once cycles were ruled out, below robots whose parent never
heard them (docs/localize.md, the frame's tree). The rules of :func:`toward_root` are tested
here on their own; the issue's corridors run end to end in tests/test_localize_shapes.py
(slow).
"""

from __future__ import annotations

import numpy as np
import pytest

import kilonet.protocols.localize.program as localize_module
from kilonet import scenarios
from kilonet.protocols.localize.base import (
    LOCALIZED,
    MAX_HOPS,
    NBR,
    NO_ID,
    Neighbour,
    choose_parent,
    toward_root,
)
from kilonet.protocols.localize.phase1_election import ELECT
from kilonet.protocols.localize.phase2_spread import POS

LOCALIZE = scenarios.get("localize")


# ------------------------------------------------------------------------- the rule alone


def _recomputed(hops: int, parent: int, fresh: list[Neighbour]) -> tuple[int, int]:
    """The rule before: the count recomputed from the neighbours heard recently, every round."""
    hops = min(MAX_HOPS, 1 + min((n.hops for n in fresh), default=MAX_HOPS))
    return hops, choose_parent(parent, hops, fresh)


def _cycles(parents: dict[int, int]) -> int:
    """Robots whose parents lead round in a circle rather than to the root (robot 0)."""
    cyclic = 0
    for start in parents:
        seen, robot = set(), start
        while robot in parents and robot not in seen:
            seen.add(robot)
            robot = parents[robot]
        cyclic += robot in seen
    return cyclic


def _corridor_tree(rule, seed: int) -> tuple[int, dict[int, int], dict[int, int]]:
    """60 robots along a 1.2 m x 60 mm corridor, the root at one end, 80 mm reach. In every round
    each robot hears each neighbour with probability 0.6 (the others count as unheard) and
    records a neighbour's current hop count with probability 0.5 (otherwise it keeps an older
    one): ``rule`` (hops, parent, fresh) -> (hops, parent) then runs on every robot in turn.
    Returns the most robots in cycles in any round, and the last hop counts and parents."""
    rng = np.random.default_rng(seed)
    n = 60
    xy = np.column_stack([20.0 * np.arange(n) + rng.uniform(-5, 5, n), rng.uniform(0, 60, n)])
    near = {
        i: [j for j in range(n) if j != i and np.hypot(*(xy[i] - xy[j])) < 80.0] for i in range(n)
    }
    hops = {i: 0 if i == 0 else MAX_HOPS for i in range(n)}
    parents = {i: NO_ID for i in range(1, n)}
    records = {i: {j: Neighbour(j) for j in near[i]} for i in range(n)}
    for table in records.values():
        for rec in table.values():
            rec.reported_mm, rec.samples = 60.0, int(rng.integers(5, 50))
    worst = 0
    for _ in range(200):
        for i in rng.permutation(n):
            for j, rec in records[i].items():
                if rng.random() < 0.5:
                    rec.hops = hops[j]
            if i == 0:
                continue
            fresh = [rec for rec in records[i].values() if rng.random() < 0.6]
            hops[i], parents[i] = rule(hops[i], parents[i], fresh)
        worst = max(worst, _cycles({i: p for i, p in parents.items() if p != NO_ID}))
    return worst, hops, parents


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_parents_never_form_a_cycle_while_neighbours_come_and_go(seed):
    worst, hops, parents = _corridor_tree(toward_root, seed)
    assert worst == 0
    # Every robot ends with a parent one hop nearer the root, and every chain reaches it.
    assert all(hops[p] == hops[i] - 1 for i, p in parents.items())
    assert all(hops[i] < MAX_HOPS for i in parents)


def test_the_recomputed_count_formed_cycles_in_the_same_corridor():
    # The same corridor with the rule before: robots end up in cycles of parents.
    assert max(_corridor_tree(_recomputed, seed)[0] for seed in (1, 2, 3)) > 0


def test_a_robot_keeps_its_count_and_parent_when_the_parent_is_unheard():
    parent, sibling = Neighbour(1), Neighbour(2)
    parent.hops, sibling.hops = 4, 5
    parent.samples, sibling.samples = 10, 50
    parent.reported_mm = sibling.reported_mm = 60.0
    assert toward_root(5, 1, [sibling]) == (5, 1)  # the rule before: (6, 2)
    assert _recomputed(5, 1, [sibling]) == (6, 2)
    nearer = Neighbour(3)
    nearer.hops, nearer.samples, nearer.reported_mm = 2, 3, 70.0
    assert toward_root(5, 1, [parent, sibling, nearer]) == (3, 3)
    assert toward_root(MAX_HOPS, NO_ID, []) == (MAX_HOPS, NO_ID)


def test_only_a_neighbour_that_hears_the_robot_becomes_its_parent():
    deaf, hearing = Neighbour(1), Neighbour(2)
    deaf.hops, hearing.hops = 3, 4
    deaf.samples, hearing.samples = 90, 10  # the deaf one is heard far more often
    assert toward_root(MAX_HOPS, NO_ID, [deaf, hearing]) == (MAX_HOPS, NO_ID)
    hearing.reported_mm = 61.5  # it reported its distance to this robot: it hears it
    assert toward_root(MAX_HOPS, NO_ID, [deaf, hearing]) == (5, 2)
    deaf.reported_mm = 58.0
    assert toward_root(5, 2, [deaf, hearing]) == (4, 1)


def _robot(seed: int) -> localize_module.LocalizeRobot:
    sim = scenarios.run(LOCALIZE, {"placement.robots": 5}, seed=1).sim
    robot = localize_module.LocalizeRobot(sim.robots[0].params)
    robot._attach(sim, 0, np.random.default_rng(seed))
    robot.setup()
    return robot


def test_entering_the_frame_forgets_the_elections_hop_counts():
    robot = _robot(5)
    # While electing it heard robot 20 on a better key of its own, 0 hops to itself.
    robot.message_rx(ELECT.pack(sender=20, key=5, hops=0, parent=NO_ID), 50)
    assert (robot.root_key, robot.hops) == (5, 1)
    position = {"x_mm": 400.0, "y_mm": 0.0, "hops": 7, "flags": LOCALIZED, "windings": 0}
    robot.message_rx(POS.pack(sender=10, **position), 45)  # the frame: robot 10 is 7 hops out
    for sender in (10, 20):
        robot.message_rx(NBR.pack(sender=sender, neighbour=robot.uid, distance_mm=50.0), 50)
    robot.loop()
    assert (robot.stage, robot.hops, robot.parent) == ("localize", 8, 10)
    # An ELECT from the frame's phase announces a parent; its hop count is not the frame's.
    robot.message_rx(ELECT.pack(sender=20, key=5, hops=0, parent=77), 50)
    robot._next_round = 0
    robot.loop()
    assert (robot.hops, robot.parent) == (8, 10)
    assert robot.neighbours[20].parent == 77


# ------------------------------------------------------------------------ the runs
