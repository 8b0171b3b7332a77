"""Phase 1 of the global coordinate system, locally unique IDs
(kilonet.protocols.gcs.phase1_unique_ids), on one real GcsRobot: scripted messages for its own
rules, and scripted neighbours in the real medium that announce a duplicate ID."""

from __future__ import annotations

import pytest

from kilonet import scenarios
from kilonet.protocols.gcs.phase1_unique_ids import CONFLICT, ID
from kilonet.protocols.gcs.program import GcsRobot
from kilonet.scenarios.base import build_params

GCS = scenarios.get("gcs")
LAYOUTS = [ID, CONFLICT]


def phase_one(overrides: dict | None = None, *, seed: int = 1):
    """The gcs scenario's parameters, phase 1 only."""
    return build_params(GCS, {"gcs.until": "ids", **(overrides or {})}, seed=seed)


def gcs_world(scripted_world, **overrides):
    params = phase_one(overrides)
    world = scripted_world(GcsRobot(params.scenario), params=params, layouts=LAYOUTS)
    world.start()
    return world


def announced(world, **fields) -> list:
    return [s for s in world.sent(ID) if all(getattr(s.fields, k) == v for k, v in fields.items())]


def test_it_draws_an_id_and_announces_it_with_its_salt(scripted_world):
    world = gcs_world(scripted_world)
    robot = world.robot
    assert world.events("phase") == [(0.0, "phase", {"name": "ids"})]
    assert 0 <= robot.uid < 256  # gcs.id_bits = 8
    world.advance(2.0)
    sent = world.sent(ID)
    assert len(sent) == pytest.approx(2.0 / 0.2, abs=1.5)  # one every 200 ms +- 20 ms
    assert {s.fields for s in sent} == {ID.record(robot.uid, robot.salt, robot.uid)}


def test_hearing_its_own_id_makes_it_draw_again_and_announce_the_old_one(scripted_world):
    world = gcs_world(scripted_world)
    old = world.robot.uid
    world.hear(ID.pack(sender=old, salt=(world.robot.salt + 1) % 256, previous=old), at_s=1.0)
    world.advance(3.0)
    new = world.robot.uid
    assert new != old
    assert [e.fields for e in world.events("id")] == [{"uid": new, "previous": old}]
    # The next three ID messages carry the old ID, so neighbours drop it; then the new alone.
    after = [s.fields for s in world.sent(ID) if s.t_s > 1.0]
    assert [f.previous for f in after[:4]] == [old, old, old, new]
    assert {f.sender for f in after} == {new}


def test_a_conflict_for_its_id_makes_it_draw_again_and_others_are_forgotten(scripted_world):
    world = gcs_world(scripted_world)
    old = world.robot.uid
    other = (old + 7) % 256
    world.hear(ID.pack(sender=other, salt=3, previous=other), at_s=0.5, distance_mm=40)
    world.hear(CONFLICT.pack(sender=99, duplicate=other), at_s=1.0)
    world.advance(1.5)
    assert other not in world.robot.table and world.robot.uid == old
    world.hear(CONFLICT.pack(sender=99, duplicate=old), at_s=2.0)
    world.eventually(lambda: world.robot.uid != old, within_s=1.0)
    assert world.events("id")[0].fields["previous"] == old


def test_one_id_heard_at_distances_far_apart_is_two_robots(scripted_world):
    world = gcs_world(scripted_world)
    uid = (world.robot.uid + 1) % 256
    same = ID.pack(sender=uid, salt=9, previous=uid)
    world.hear(same, at_s=0.5, distance_mm=40)
    world.hear(same, at_s=1.0, distance_mm=41)
    # 11.5 mm from the mean of 40.5 so far: within gcs.duplicate_distance_mm = 12, still one.
    world.hear(same, at_s=1.5, distance_mm=52)
    world.advance(2.0)
    assert world.events("duplicate") == []
    world.hear(same, at_s=2.0, distance_mm=70)
    world.advance(1.0)
    assert [e.fields for e in world.events("duplicate")] == [{"uid": uid}]
    world.assert_sent(CONFLICT, sender=world.robot.uid, duplicate=uid)
    # The table forgot the two robots' mixed readings and starts again from the latest.
    assert (world.robot.table[uid].samples, world.robot.table.distance(uid)) == (1, 70.0)


def test_neighbours_announcing_one_id_with_two_salts_are_reported_three_times(scripted_world):
    """Two scripted neighbours in the real medium both announce ID 5; the robot between them
    tells them apart by their salts and broadcasts a CONFLICT for 5 at three opportunities."""
    params = phase_one(seed=2)
    world = scripted_world(GcsRobot(params.scenario), params=params, layouts=LAYOUTS)
    from kilonet.testing import Replay

    first = world.add_neighbour(Replay.every(ID.pack(sender=5, salt=1, previous=5)), distance_mm=45)
    second = world.add_neighbour(
        Replay.every(ID.pack(sender=5, salt=2, previous=5), from_s=2.0), at_mm=(-45.0, 10.0)
    )
    world.start()
    assert world.robot.uid != 5  # seed 2 draws another ID
    world.advance(1.9)
    assert world.events("duplicate") == [] and 5 in world.robot.table
    world.eventually(lambda: world.events("duplicate"), within_s=2.0)
    assert world.events("duplicate")[0].fields == {"uid": 5}
    world.advance(2.0)
    conflicts = world.sent(CONFLICT)
    assert len(conflicts) >= 3
    assert {c.fields for c in conflicts[:3]} == {CONFLICT.record(world.robot.uid, 5)}
    # Both neighbours' messages went through the medium and reached the robot.
    assert {h.sender for h in world.heard(ID)} == {first, second}
