"""kilonet.testing's swarm in one call and its Hypothesis strategies."""

from __future__ import annotations

import networkx as nx
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kilonet.message import KILOLIB, THESIS, Layout, Message
from kilonet.params import Params
from kilonet.robot import Kilobot
from kilonet.scenarios.placement import hex_lattice
from kilonet.testing import ScriptError, run_swarm
from kilonet.testing.strategies import (
    channel_settings,
    connected_placements,
    loss_settings,
    messages,
    noise_settings,
    payloads,
    raw_messages,
)
from kilonet.visibility import LinkModel, communication_graph

HOPS = Layout("hops", type=1, fields=[("hops", "B")])


class Hops(Kilobot):
    """Hop count from robot 0; logs each improvement."""

    def __init__(self, source: bool) -> None:
        self.hops = 0 if source else 255

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if HOPS.unpack(message).hops + 1 < self.hops:
            self.hops = HOPS.unpack(message).hops + 1
            self.log("hops", hops=self.hops)

    def message_tx(self) -> Message | None:
        return HOPS.pack(hops=self.hops) if self.hops < 255 else None


def hops(i: int) -> Hops:
    return Hops(source=i == 0)


def all_known(programs) -> bool:
    return all(p.hops < 255 for p in programs)


# ------------------------------------------------------------------------------ run_swarm


@pytest.mark.parametrize(("layout", "robots"), [("hex", 7), ("line", 5), ("random", 12)])
def test_named_layouts_use_the_kernels_generators_and_the_placement_stream(layout, robots):
    params = {"placement.density_per_m2": 150.0}
    a = run_swarm(hops, layout, robots=robots, params=params, seed=3, until_s=1.0)
    b = run_swarm(hops, layout, robots=robots, params=params, seed=3, until_s=1.0)
    assert len(a.robots) == robots
    assert a.robots[["x0_mm", "y0_mm"]].equals(b.robots[["x0_mm", "y0_mm"]])
    if layout == "random":
        c = run_swarm(hops, layout, robots=robots, params=params, seed=4, until_s=1.0)
        assert not a.robots.x0_mm.equals(c.robots.x0_mm)


def test_a_swarm_stops_when_its_condition_holds_and_hands_back_tables_and_states():
    result = run_swarm(hops, hex_lattice(7, spacing_mm=40.0), stop_when=all_known, until_s=30)
    assert result.stopped and result.t_s < 30
    assert [p.hops for p in result.programs] == [0, 1, 1, 1, 1, 1, 1]
    assert set(result.tables) == {
        "battery",
        "led",
        "events",
        "poses",
        "stops",
        "messages",
        "estimates",
    }
    assert sorted(result.tables["events"].robot) == [1, 2, 3, 4, 5, 6]
    assert result.robots.sent.sum() > 0
    assert result.final[3] == {"hops": 1}
    assert result.state_frame().columns.tolist() == ["robot", "hops"]
    assert result.program(0).hops == 0

    never = run_swarm(
        lambda i: Hops(source=False), "line", robots=3, stop_when=all_known, until_s=2
    )
    assert not never.stopped and never.t_s == 2.0


def test_assert_each_names_the_robots_that_fail_with_their_state():
    result = run_swarm(hops, "line", robots=4, params={"placement.spacing_mm": 50}, until_s=0.1)
    with pytest.raises(AssertionError) as failure:
        result.assert_each(lambda i, p: p.hops == i, what="hops equal index")
    text = str(failure.value)
    assert text.startswith("hops equal index fails for 3 of 4 robots at 0.100 s:")
    assert "robot 2 at (100.0, 0.0) mm: hops=255" in text
    result.assert_each(lambda i, p: p.hops in (0, 255))


def test_swarm_misuse_is_refused():
    with pytest.raises(ScriptError, match=r"layout 'hex' needs a size: robots=N"):
        run_swarm(hops, "hex")
    with pytest.raises(ScriptError, match="robots=3 but the placement has 2 robots"):
        run_swarm(hops, [[0, 0], [40, 0]], robots=3)
    with pytest.raises(ValueError, match="unknown layout 'spiral'"):
        run_swarm(hops, "spiral", robots=3)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ScriptError, match="until_s must be a positive number of seconds"):
            run_swarm(hops, "line", robots=2, until_s=bad)
    result = run_swarm(hops, "line", robots=2, until_s=0.1)
    with pytest.raises(ScriptError, match=r"robot 5 is not in this swarm of 2 robots \(0-1\)"):
        result.program(5)


def test_params_may_be_a_params_object_or_overrides_with_a_seed():
    a = run_swarm(hops, "line", robots=2, params=Params(seed=9), until_s=0.1)
    b = run_swarm(hops, "line", robots=2, params={"seed": 9}, until_s=0.1)
    c = run_swarm(hops, "line", robots=2, seed=9, until_s=0.1)
    assert a.sim.params.seed == b.sim.params.seed == c.sim.params.seed == 9
    assert a.robots.clock_factor.equals(c.robots.clock_factor)


# ------------------------------------------------------------------------------ strategies


@settings(max_examples=25, deadline=None)
@given(
    connected_placements(min_robots=3, max_robots=10, kind="random", min_neighbours=2),
)
def test_random_placements_are_connected_with_enough_neighbours(xy):
    graph = communication_graph(xy, LinkModel(85.0))
    assert 3 <= len(xy) <= 10 and nx.is_connected(graph)
    assert min(d for _, d in graph.degree) >= 2
    assert np.min(np.hypot(*(xy[:, None] - xy[None]).T)[~np.eye(len(xy), dtype=bool)]) >= 33.0


@settings(max_examples=25, deadline=None)
@given(connected_placements(kind="lattice", range_mm=60.0, max_neighbours=2))
def test_lattice_placements_respect_the_neighbour_bounds(xy):
    graph = communication_graph(xy, LinkModel(60.0))
    assert nx.is_connected(graph) and max(d for _, d in graph.degree) <= 2


def test_placement_strategy_bounds_are_checked():
    with pytest.raises(ValueError, match="min_robots"):
        connected_placements(min_robots=1)
    with pytest.raises(ValueError, match="kind must be"):
        connected_placements(kind="grid")
    with pytest.raises(ValueError, match="max_neighbours=1 is below"):
        connected_placements(min_neighbours=2, max_neighbours=1)


EVERY_CODE = Layout(
    "every",
    type=5,
    fields=[("a", "B"), ("b", "b"), ("c", "H"), ("d", "h", 0.5), ("e", "?")],
)
WIDE = Layout("wide", type=6, fields=[("u", "I"), ("s", "i", 0.1)])


@settings(max_examples=60)
@given(st.one_of(payloads(EVERY_CODE), payloads(WIDE)))
def test_payloads_fit_their_layout_and_round_trip(values):
    layout = EVERY_CODE if "a" in values else WIDE
    back = layout.unpack(layout.pack(**values))._asdict()
    assert back == pytest.approx(values)


@settings(max_examples=60)
@given(messages(EVERY_CODE), raw_messages(KILOLIB), raw_messages(THESIS))
def test_messages_pass_the_payload_limits(packed, raw, thesis):
    KILOLIB.check(packed)
    KILOLIB.check(raw)
    THESIS.check(thesis)
    assert thesis.type == 0 and packed.type == EVERY_CODE.type


def test_payloads_refuse_codes_no_layout_field_uses():
    with pytest.raises(ValueError, match="struct code 'f'"):
        payloads(Layout("float", type=1, fields=[("x", "f")]))


@settings(max_examples=30)
@given(loss_settings(), noise_settings(), channel_settings(max_loss_prob=0.1))
def test_settings_are_valid_parameter_overrides(loss, noise, both):
    p = Params().with_overrides({**loss, **noise})
    assert 0 <= p.medium.loss_prob <= 0.3 and p.ranging.sigma_mm <= 3.0
    assert set(both) == {"medium.loss_prob", "ranging.sigma_mm", "ranging.bias_sigma_mm"}
    assert Params().with_overrides(both).medium.loss_prob <= 0.1


class _Spin(Kilobot):
    """Waits in loop() for kilo_ticks to move, which it never does inside one call."""

    def loop(self):
        start = self.kilo_ticks
        while self.kilo_ticks == start:
            pass


def test_a_busy_loop_stops_the_swarm_naming_the_robot_and_line():
    from kilonet.testing import ScriptedWorld
    from kilonet.watchdog import BusyCallError

    with pytest.raises(
        BusyCallError, match=r"robot 0's loop \(test_testing_swarm.py:\d+\) has run 0.2 s"
    ):
        run_swarm(_Spin, [[0, 0], [40, 0]], until_s=1.0, watchdog_s=0.2)
    world = ScriptedWorld(_Spin, watchdog_s=0.2)
    with pytest.raises(BusyCallError, match="kilo_ticks"):
        world.advance(1.0)
    with pytest.raises(BusyCallError, match=r"has run 0\.2 s of wall time"):
        ScriptedWorld(_Spin, watchdog_s=0.2).eventually(lambda: False, within_s=1.0)
