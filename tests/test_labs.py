"""The Kilobotics labs (examples/labs/) do on kilonet what they do on the robots.

Each test runs a lab's own world (its placement CSV and parameter file) with the lab's program
and asserts the behaviour the lab describes, with values; the figures come from
``examples.labs.measures``. The long runs (several seeds, variants) are marked slow.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from examples.labs import measures, world
from examples.labs.blink_led import BlinkLed
from examples.labs.disperse import Disperse
from examples.labs.gradient_simple import SEED_ID, GradientSimple
from examples.labs.move_to_light import MoveToLight
from examples.labs.nonblocked_movement import NonblockedMovement
from examples.labs.orbit import DESIRED_DISTANCE, Orbit
from examples.labs.simple_movement import SimpleMovement
from examples.labs.speaker_listener import SpeakerListener
from examples.labs.sync import Sync, c_div, c_mod
from kilonet.robot import Kilobot
from kilonet.scenarios.gradient import hop_distances


def run(lab: str, program: type[Kilobot], *, seed: int = 1, **overrides):
    sim = world.simulation(lab, program, seed=seed, overrides=overrides)
    sim.run()
    return sim


def over_seeds(short_s: float | None = None) -> list:
    """``(seed, duration_s)`` for the over-seeds claims: seeds 2-6 at the lab's full length
    (slow), and seed 2 in the default tier as their twin, cut to ``short_s`` simulated seconds
    where the claim already holds by then (None: the full length)."""
    slow = [pytest.param(seed, None, marks=pytest.mark.slow) for seed in (2, 3, 4, 5, 6)]
    return [*slow, pytest.param(2, short_s, id=f"2-{short_s or 'full'}-twin")]


def lasting(duration_s: float | None) -> dict:
    """The run's overrides for a length in simulated seconds (None: the lab's own)."""
    return {} if duration_s is None else {"duration_s": duration_s}


# -------------------------------------------------------------------------------- measures


def test_revolutions_count_signed_laps_around_the_centre():
    a = np.linspace(0, 4 * math.pi, 400)
    circle = np.c_[60 * np.cos(a), 60 * np.sin(a)] + [10, -5]
    assert measures.revolutions([10, -5], circle) == pytest.approx(2.0)
    assert measures.revolutions([10, -5], circle[::-1]) == pytest.approx(-2.0)
    assert measures.revolutions([500, 0], circle) == pytest.approx(0.0, abs=1e-9)


def test_circular_range_wraps_around_the_period():
    assert measures.circular_range([0.1, 0.2, 0.15], 1.0) == pytest.approx(0.1)
    assert measures.circular_range([0.95, 0.05, 1.02], 1.0) == pytest.approx(0.1)
    assert measures.circular_range([0.0, 0.25, 0.5, 0.75], 1.0) == pytest.approx(0.75)
    assert measures.circular_range([3.3], 1.0) == 0.0


def test_flash_spread_uses_each_robots_last_flash():
    flashes = [np.array([0.1, 1.1, 2.1]), np.array([0.5, 1.15, 2.15])]
    assert measures.flash_spread_s(flashes, 1.12, 1.0) == pytest.approx(0.4)
    assert measures.flash_spread_s(flashes, 2.2, 1.0) == pytest.approx(0.05)
    with pytest.raises(ValueError, match=r"robot 1 has not flashed by 0\.2 s"):
        measures.flash_spread_s(flashes, 0.2, 1.0)


def test_c_division_and_remainder_truncate_towards_zero():
    assert [c_div(a, b) for a, b in ((7, 2), (-7, 2), (7, -2), (-7, -2))] == [3, -3, -3, 3]
    assert [c_mod(a, b) for a, b in ((7, 2), (-7, 2), (-20, 50), (70, 50))] == [1, -1, -20, 20]
    # sync.c: a discrepancy of 30 ticks (>= PERIOD / 2: the neighbour is 20 ticks ahead)
    # moves the reset by -(PERIOD - 30) % PERIOD, which is -20 in C and +30 in Python.
    assert c_mod(-(50 - 30), 50) == -20 and -(50 - 30) % 50 == 30


# ------------------------------------------------------------------------------ the worlds


def test_lab_worlds_carry_the_uids_the_labs_need():
    assert world.load("orbit").uids == [0, 1]
    uids = world.load("gradient_simple").uids
    assert uids.count(SEED_ID) == 1 and len(set(uids)) == len(uids) == 30
    assert world.load("disperse").uids is None


def test_the_cli_runs_a_lab_file_on_its_placement_with_the_uids_it_gives(tmp_path):
    # kilonet run --program examples/labs/gradient_simple.py --placement .../gradient_simple.csv
    from kilonet import scenarios
    from kilonet.scenarios.program import program_scenario

    lab = Path(world.__file__).parent
    spec = str(lab / "gradient_simple.py")
    result = scenarios.run(
        program_scenario(spec), {"duration_s": 30.0}, placement=lab / "gradient_simple.csv"
    )
    robots = result.sim.robots
    seed = next(i for i, r in enumerate(robots) if r.kilo_uid == SEED_ID)
    assert robots[seed].own_gradient == 0
    # Hops over the medium's links from sender to receiver (real robots' links reach per sender).
    hops = hop_distances(result.sim, seed)
    assert [r.own_gradient for r in robots] == [hops[i] for i in range(len(robots))]


def test_main_prints_the_figures_and_refuses_a_bad_parameter(capsys):
    world.main(
        "gradient_simple", GradientSimple, measures.gradient_simple, ["--set", "duration_s=5"]
    )
    out = capsys.readouterr().out
    assert out.startswith("gradient_simple: 30 robots, 5 simulated s, seed 1\n")
    assert "  equal_to_hop_count: 30\n" in out
    with pytest.raises(SystemExit) as exc:
        world.main("orbit", Orbit, measures.orbit, ["--set", "medium.range=9"])
    assert exc.value.code == 2
    assert "unknown parameter 'medium.range'" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("lab", "classes", "program"),
    [
        ("disperse", ["Disperse"], "Disperse"),
        ("orbit", ["OrbitStar", "OrbitPlanet", "Orbit"], "Orbit"),
    ],
)
def test_a_lab_file_runs_when_loaded_on_its_own(monkeypatch, lab, classes, program):
    """As ``kilonet run --program examples/labs/LAB.py`` loads it: a module of its own name,
    its folder on sys.path (for its neighbours lab_common.py, speaker_listener.py), no package
    around it."""
    path = world.LABS_DIR / f"{lab}.py"
    monkeypatch.syspath_prepend(str(path.parent))
    spec = importlib.util.spec_from_file_location(f"kilonet_program_{lab}", path)
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)
    spec.loader.exec_module(module)
    own = [
        c.__name__
        for c in vars(module).values()
        if isinstance(c, type) and issubclass(c, Kilobot) and c.__module__ == spec.name
    ]
    assert own == classes
    sim = run(lab, getattr(module, program), duration_s=5.0)
    assert len(sim.trace.poses_frame()) > 0  # it moved: the program ran


# --------------------------------------------------------------------------------- the labs


def test_blink_led_blinks_red_and_blue_half_a_second_of_each_robots_own_clock():
    sim = run("blink_led", BlinkLed, duration_s=10.0)
    for robot in range(sim.n_robots):
        red = [b - a for colour, a, b in measures.led_phases(sim, robot) if colour == "red"]
        assert len(red) >= 9
        assert red == pytest.approx([0.5 / sim.clocks.factor[robot]] * len(red), abs=1e-9)


def test_simple_movement_goes_forward_then_turns_left_then_right():
    figures = measures.movement(run("simple_movement", SimpleMovement))
    green, red, blue, off = (figures[c] for c in ("green", "red", "blue", "off"))
    assert green["stretches"] == red["stretches"] == blue["stretches"] == 6
    assert 14.0 < green["moved_mm"] < 26.0 and abs(green["turn_deg"]) < 15.0  # ~10 mm/s
    assert 60.0 < red["turn_deg"] < 120.0  # ~45 deg/s counter-clockwise
    assert -120.0 < blue["turn_deg"] < -60.0
    assert off["moved_mm"] == 0.0 and off["turn_deg"] == 0.0


def test_nonblocked_left_turns_counter_clockwise_and_moves_the_centre_about_a_leg():
    sim = run("nonblocked_movement", NonblockedMovement)
    figures = measures.movement(sim)
    left, right = figures["red"], figures["blue"]
    assert left["stretches"] == right["stretches"] == 6
    assert 60.0 < left["turn_deg"] < 130.0
    assert -130.0 < right["turn_deg"] < -60.0
    # The centre moves on a circle about the rear leg (16.5 mm out): a chord of that circle.
    radius = sim.params.motion.pivot_radius_mm
    for turn in (left, right):
        chord = 2 * radius * math.sin(math.radians(abs(turn["turn_deg"])) / 2)
        assert turn["moved_mm"] == pytest.approx(chord, rel=0.1)


def test_speaker_and_listeners_blink_once_per_message():
    sim = run("speaker_listener", SpeakerListener, duration_s=30.0)
    figures = measures.speaker_listener(sim)
    speaker = figures.pop("speaker 0")
    assert speaker["magenta_blinks"] == speaker["sent"]
    # kilolib's transmit period: 16 ticks of its 30.52 Hz clock (0.524 s).
    assert abs(speaker["sent"] - 30.0 / sim.params.robot.tx_period_s) <= 2
    assert len(figures) == 3
    for listener in figures.values():
        assert listener["yellow_blinks"] == listener["received"] == speaker["sent"]


def test_gradient_equals_the_hop_count_over_the_mediums_graph():
    figures = measures.gradient_simple(run("gradient_simple", GradientSimple, duration_s=20.0))
    assert figures["equal_to_hop_count"] == figures["robots"] == 30
    assert figures["differing"] == []
    assert figures["max_hops"] >= 4  # several hops (real robots' links reach about 148 mm)


def test_gradient_counts_what_the_medium_graph_says_when_it_differs():
    """The measure is not the program's own opinion: a seed that hears nobody (range
    below every spacing) leaves every other robot at GRADIENT_MAX, hop count none."""
    figures = measures.gradient_simple(
        run(
            "gradient_simple",
            GradientSimple,
            duration_s=5.0,
            **{"medium.reach": "disc", "medium.range_mm": 33.0},  # one hard radius: nobody hears
        )
    )
    assert figures["max_hops"] == 0 and figures["equal_to_hop_count"] == 30


def test_orbit_planet_circles_the_star_at_the_desired_distance():
    (planet,) = measures.orbit(run("orbit", Orbit)).values()
    assert planet["laps_clockwise"] >= 1.0  # in 300 simulated s
    assert planet["distance_mean_mm"] == pytest.approx(DESIRED_DISTANCE, abs=5.0)
    assert planet["distance_p5_mm"] > 48.0 and planet["distance_p95_mm"] < 72.0


@pytest.mark.parametrize(("seed", "duration_s"), over_seeds())
def test_orbit_over_seeds(seed, duration_s):
    (planet,) = measures.orbit(run("orbit", Orbit, seed=seed, **lasting(duration_s))).values()
    assert planet["laps_clockwise"] >= 5.0
    assert planet["distance_mean_mm"] == pytest.approx(DESIRED_DISTANCE, abs=3.0)
    assert planet["distance_p5_mm"] > 48.0 and planet["distance_p95_mm"] < 72.0


@pytest.mark.twin_of("test_disperse_over_seeds")
def test_disperse_ends_with_nobody_in_range_of_anybody():
    sim = run("disperse", Disperse)
    figures = measures.disperse(sim)
    assert figures["alone"] == figures["robots"] == 20
    assert figures["still_moving"] == 0
    assert figures["all_out_of_range_at_s"] < sim.params.duration_s


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2, 3, 4, 5, 6])
def test_disperse_over_seeds(seed):
    # Its twin is the seed-1 test above (the same assertions; a run takes 9 s of CPU).
    figures = measures.disperse(run("disperse", Disperse, seed=seed))
    assert figures["alone"] == 20 and figures["still_moving"] == 0


def test_move_to_light_gets_closer_to_the_light():
    for robot in measures.move_to_light(
        run("move_to_light", MoveToLight, duration_s=40.0)
    ).values():
        assert robot["start_mm"] == pytest.approx(250.0)
        assert robot["end_mm"] < 50.0
        assert robot["within_50_mm_at_s"] < 35.0


@pytest.mark.parametrize(("seed", "duration_s"), over_seeds(short_s=40.0))
def test_move_to_light_over_seeds(seed, duration_s):
    sim = run("move_to_light", MoveToLight, seed=seed, **lasting(duration_s))
    for robot in measures.move_to_light(sim).values():
        assert robot["end_mm"] < 50.0 and robot["within_50_mm_at_s"] < 40.0


def test_move_to_light_needs_a_sensor_that_reads_the_heading():
    """With a reading that depends on position alone, the one-motor pivots circle a leg and
    never cross both thresholds: the robots stay where they were."""
    figures = measures.move_to_light(
        run("move_to_light", MoveToLight, duration_s=15.0, **{"light.directionality": 0.0})
    )
    for robot in figures.values():
        assert robot["closest_mm"] > 250.0 - 2 * 16.5 - 1e-9


def test_sync_flashes_fall_together_with_drifting_clocks():
    sim = run("sync", Sync, duration_s=90.0)
    assert sim.params.robot.clock_sd == 0.01  # kilonet's default drift
    figures = measures.sync(sim)
    assert figures["spread_start_s"] > 0.6  # random delays of up to 2.55 s at the start
    assert figures["spread_end_s"] < 0.45
    assert figures["end_over_start"] < 0.45
    assert figures["moved_mean_mm"] == 0.0


@pytest.mark.parametrize(("seed", "duration_s"), over_seeds(short_s=90.0))
def test_sync_over_seeds(seed, duration_s):
    figures = measures.sync(run("sync", Sync, seed=seed, **lasting(duration_s)))
    assert figures["spread_start_s"] > 0.6
    assert figures["spread_end_s"] < 0.45 and figures["end_over_start"] < 0.45


@pytest.mark.parametrize("duration_s", [pytest.param(None, marks=pytest.mark.slow), 90.0])
def test_sync_is_tighter_when_every_robot_hears_every_other(duration_s):
    """sync.c's adjustment is the summed discrepancy over 120 per period: with all 18
    neighbours in range (the table's reach in ARGoS's data, 14 cm) it corrects more per
    period, and the flashes fall closer together (the default tier's twin: by 90 s)."""
    figures = measures.sync(run("sync", Sync, **{"medium.range_mm": 140.0}, **lasting(duration_s)))
    assert figures["spread_end_s"] < 0.25
