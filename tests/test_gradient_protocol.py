"""The hop-count gradient (kilonet.protocols.gradient), on the test kit: one robot hearing scripted
gradients, both update rules, its LED and messages, and the whole protocol on drawn swarms."""

from __future__ import annotations

import networkx as nx
import pytest
from hypothesis import given, settings

from kilonet.message import LIMITS
from kilonet.params import MediumParams
from kilonet.protocols.gradient import GRADIENT, UNKNOWN, Gradient
from kilonet.testing.strategies import connected_placements, loss_settings
from kilonet.visibility import LinkModel, communication_graph

_MEDIUM = MediumParams()
#: One message's airtime on the default medium: its bytes at the bit rate, plus the preamble.
AIRTIME_S = LIMITS["kilolib"].air_bytes * 8 / _MEDIUM.bitrate_bps + _MEDIUM.preamble_s


def test_adopts_one_more_than_the_smallest_gradient_heard(scripted_world):
    world = scripted_world(Gradient(), layouts=[GRADIENT])
    world.hear(GRADIENT.pack(gradient=4), at_s=0.5, distance_mm=70)
    world.hear(GRADIENT.pack(gradient=2), at_s=1.0, distance_mm=45)
    world.hear(GRADIENT.pack(gradient=6), at_s=1.5, distance_mm=45)
    world.advance(2.0)
    assert world.robot.gradient == 3
    assert [(round(e.t_s, 4), e.fields) for e in world.events("gradient")] == [
        (round(0.5 + AIRTIME_S, 4), {"value": 5}),
        (round(1.0 + AIRTIME_S, 4), {"value": 3}),
    ]
    world.assert_sent(GRADIENT, gradient=3)


def test_stays_silent_and_dark_until_it_knows_its_gradient(scripted_world):
    world = scripted_world(Gradient(), layouts=[GRADIENT])
    world.hear(GRADIENT.pack(gradient=UNKNOWN), at_s=0.2)  # a neighbour that does not know
    world.never(lambda: world.sent() or world.robot.color != (0, 0, 0), for_s=3.0)
    # kilolib asked it at every tick since its first opportunity (in the first 0.5 s).
    assert world.robot.gradient == UNKNOWN and world.opportunities[0] >= 2.5 * 31
    world.hear(GRADIENT.pack(gradient=0))
    world.advance(1.0)
    assert world.colors() == [(pytest.approx(3.0 + AIRTIME_S), (0, 3, 0))]  # 1: green
    assert {s.fields.gradient for s in world.sent(GRADIENT)} == {1}


def test_the_source_holds_zero_whatever_it_hears(scripted_world):
    world = scripted_world(Gradient(is_source=True), layouts=[GRADIENT])
    world.hear_every(GRADIENT.pack(gradient=0), period_s=0.3, until_s=3.0)
    world.advance(3.0)
    assert world.robot.gradient == 0 and world.robot.color == (3, 3, 3)
    assert {s.fields.gradient for s in world.sent(GRADIENT)} == {0}
    assert world.events() == []


def test_ignores_other_message_types(scripted_world):
    from kilonet.message import Message

    world = scripted_world(Gradient())
    world.hear(Message(b"\x00\x00", type=GRADIENT.type + 1), at_s=0.1)
    world.never(lambda: world.robot.gradient != UNKNOWN, for_s=1.0)


def test_the_monotone_rule_never_rises_when_its_neighbour_does(scripted_world):
    world = scripted_world(Gradient())
    world.hear(GRADIENT.pack(gradient=1), at_s=0.1)
    world.hear_every(GRADIENT.pack(gradient=5), period_s=0.5, from_s=1.0, until_s=10.0)
    world.advance(0.5)
    world.never(lambda: world.robot.gradient != 2, for_s=10.0)


def test_the_self_healing_rule_forgets_a_neighbour_that_falls_silent(scripted_world):
    world = scripted_world(Gradient(refresh_s=2.0), layouts=[GRADIENT])
    world.hear_every(GRADIENT.pack(gradient=1), period_s=0.5, until_s=4.0)
    world.eventually(lambda: world.robot.gradient == 2, within_s=1.0)
    world.advance(3.0)
    assert world.robot.gradient == 2
    # The neighbour went silent at 4 s: the window that saw nothing ends by 8 s.
    gone = world.eventually(lambda: world.robot.gradient == UNKNOWN, within_s=5.0)
    assert 4.0 < gone <= 8.0
    assert world.events("gradient")[-1].fields == {"value": UNKNOWN}


def test_the_self_healing_rule_rises_to_what_it_hears_now(scripted_world):
    world = scripted_world(Gradient(refresh_s=2.0))
    world.hear_every(GRADIENT.pack(gradient=1), period_s=0.5, until_s=3.0)
    world.hear_every(GRADIENT.pack(gradient=4), period_s=0.5, from_s=3.25, until_s=12.0)
    world.eventually(lambda: world.robot.gradient == 5, within_s=10.0)
    assert world.now_s > 3.25


def test_forms_along_a_line_of_real_neighbours(scripted_world):
    # The robot under test at the end of a line 40 mm apart: source, relay, then it. 80 mm is
    # within range, so it hears the source itself and takes gradient 1.
    world = scripted_world(Gradient(), layouts=[GRADIENT])
    world.add_neighbour(Gradient(is_source=True), at_mm=(-80, 0))
    world.add_neighbour(Gradient(), at_mm=(-40, 0))
    world.eventually(lambda: world.robot.gradient == 1, within_s=3.0)
    assert {h.sender for h in world.heard(GRADIENT) if h.fields.gradient == 0} == {1}


@settings(max_examples=20, deadline=None)
@given(connected_placements(min_robots=3, max_robots=10), loss_settings(max_loss_prob=0.3))
def test_every_robot_ends_at_its_hop_distance_from_the_source(xy, lossy):
    from kilonet.testing import run_swarm

    # The placements' hop counts are over one 85 mm radius: the disc medium (real robots' links
    # reach per sender, farther; kilonet.scenarios.gradient.hop_distances counts over those).
    hops = nx.single_source_shortest_path_length(communication_graph(xy, LinkModel(85.0)), 0)
    result = run_swarm(
        lambda i: Gradient(is_source=i == 0),
        xy,
        params={**lossy, "medium.reach": "disc"},
        until_s=60.0,
        stop_when=lambda robots: all(r.gradient == hops[i] for i, r in enumerate(robots)),
    )
    result.assert_each(lambda i, r: r.gradient == hops[i], what="gradient == hop distance")
