"""The figures of ``examples/labs/README.md``: every lab run in its own world, measured by
``examples.labs.measures`` from the run's ground truth, written as the README's generated
blocks (``python -m kilonet.experiments.publish docs --block labs-seed-1`` and ``labs-seeds``).

* :func:`seed_one_block`: the table of the labs, what each does on kilonet with seed 1;
* :func:`seeds_block`: the labs that depend on chance over several seeds (and variants), one
  paragraph each, with the command that reproduces it.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["seed_one_block", "seeds_block"]

#: Seeds of the several-seed paragraphs.
SEEDS = tuple(range(1, 11))
#: Seeds of the variants (a longer range, perfect clocks).
VARIANT_SEEDS = tuple(range(1, 6))


#: Each lab's program (module, class) and measure (a function of ``examples.labs.measures``).
PROGRAMS = {
    "blink_led": ("blink_led", "BlinkLed", "blink_led"),
    "simple_movement": ("simple_movement", "SimpleMovement", "movement"),
    "nonblocked_movement": ("nonblocked_movement", "NonblockedMovement", "movement"),
    "speaker_listener": ("speaker_listener", "SpeakerListener", "speaker_listener"),
    "gradient_simple": ("gradient_simple", "GradientSimple", "gradient_simple"),
    "orbit": ("orbit", "Orbit", "orbit"),
    "move_to_light": ("move_to_light", "MoveToLight", "move_to_light"),
    "sync": ("sync", "Sync", "sync"),
    "disperse": ("disperse", "Disperse", "disperse"),
}


def _run(lab: str, seed: int = 1, **overrides: Any):
    """The lab's figures, the run's CPU seconds and the simulation."""
    import importlib

    from examples.labs import measures, world

    module, cls, measure = PROGRAMS[lab]
    program = getattr(importlib.import_module(f"examples.labs.{module}"), cls)
    sim = world.simulation(lab, program, seed=seed, overrides=overrides)
    started = time.process_time()
    sim.run()
    cpu_s = time.process_time() - started
    return getattr(measures, measure)(sim), cpu_s, sim


def _span(values: Sequence[float], fmt: str = ".1f", unit: str = "") -> str:
    """``a–b unit`` over ``values`` (``a unit`` when all are equal as shown)."""
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return f"{lo}{unit}" if lo == hi else f"{lo}–{hi}{unit}"


def _deg(value: float) -> str:
    """``+89.9°`` or ``−89.8°`` (a minus sign, not a hyphen)."""
    return f"{value:+.1f}°".replace("-", "−")


def _and(values: Sequence[float], fmt: str = ".1f") -> str:
    shown = [format(v, fmt) for v in values]
    return " and ".join(shown) if len(shown) < 3 else ", ".join(shown[:-1]) + ", " + shown[-1]


# -- the table, seed 1 -----------------------------------------------------------------------
def _blink() -> str:
    from examples.labs import measures

    _, _, sim = _run("blink_led")
    red, extra = [], []
    for robot in range(sim.n_robots):
        phases = measures.led_phases(sim, robot)
        mean = {
            c: float(np.mean([b - a for cc, a, b in phases if cc == c])) for c in ("red", "blue")
        }
        red.append(mean["red"])
        extra.append(1000 * (mean["blue"] - mean["red"]))
    blue = (
        "blue as long"
        if max(abs(e) for e in extra) < 0.5
        else f"blue {_span(extra, '.0f', ' ms')} longer"
    )
    return f"red for 0.5 s of each robot's own clock ({_and(red, '.4f')} s), {blue}"


def _movement(lab: str) -> dict[str, Any]:
    return _run(lab)[0]


def _simple_movement() -> str:
    m = _movement("simple_movement")
    return (
        f"forward {m['green']['moved_mm']:.1f} mm in 2 s, left {_deg(m['red']['turn_deg'])}, "
        f"right {_deg(m['blue']['turn_deg'])}, stop"
    )


def _nonblocked_movement() -> str:
    m = _movement("nonblocked_movement")
    return (
        f"left {_deg(m['red']['turn_deg'])} (counter-clockwise) per 64-tick state, the centre "
        f"moving {m['red']['moved_mm']:.1f} mm on its pivot circle; right "
        f"{_deg(m['blue']['turn_deg'])}, {m['blue']['moved_mm']:.1f} mm; forward "
        f"{m['green']['moved_mm']:.1f} mm, {_deg(m['green']['turn_deg'])}"
    )


def _speaker_listener() -> str:
    figures = _run("speaker_listener")[0]
    (speaker,) = [v for k, v in figures.items() if k.startswith("speaker")]
    listeners = [v for k, v in figures.items() if k.startswith("listener")]
    received = _span([v["received"] for v in listeners], "d")
    yellow = _span([v["yellow_blinks"] for v in listeners], "d")
    return (
        f"{speaker['sent']} messages sent in 60 s, {speaker['magenta_blinks']} magenta blinks; "
        f"each of {len(listeners)} listeners {received} received, {yellow} yellow blinks"
    )


def _gradient(seed: int = 1) -> dict[str, Any]:
    return _run("gradient_simple", seed)[0]


def _gradient_row() -> str:
    g = _gradient()
    return (
        f"{g['equal_to_hop_count']} of {g['robots']} robots hold their BFS hop count from the "
        f"seed (up to {g['max_hops']})"
    )


def _orbit(seed: int = 1) -> tuple[dict[str, Any], float]:
    figures, cpu_s, _ = _run("orbit", seed)
    (planet,) = figures.values()
    return planet, cpu_s


def _orbit_row() -> str:
    p, _ = _orbit()
    return (
        f"{p['laps_clockwise']:.2f} laps in 300 s at {p['distance_mean_mm']:.1f} mm on average "
        f"(5–95 %: {p['distance_p5_mm']:.1f}–{p['distance_p95_mm']:.1f} mm)"
    )


def _move_to_light(seed: int = 1) -> tuple[list[dict[str, Any]], float]:
    figures, cpu_s, _ = _run("move_to_light", seed)
    return list(figures.values()), cpu_s


def _move_to_light_row() -> str:
    robots, _ = _move_to_light()
    near = [r["within_50_mm_at_s"] for r in robots]
    reached = (
        f"within 50 mm after {_and(near)} s"
        if all(t is not None for t in near)
        else f"{sum(t is not None for t in near)} of {len(near)} within 50 mm"
    )
    return (
        f"both robots from {robots[0]['start_mm']:.0f} mm to "
        f"{_and([r['end_mm'] for r in robots])} mm, {reached}"
    )


def _sync(seed: int = 1, **overrides: Any) -> tuple[dict[str, Any], float]:
    return _run("sync", seed, **overrides)[:2]


def _sync_row() -> str:
    s, _ = _sync()
    return (
        f"flash spread {s['spread_start_s']:.2f} s at the start, {s['spread_end_s']:.2f} s at "
        f"the end ({s['end_over_start']:.2f} of it)"
    )


def _disperse(seed: int = 1) -> tuple[dict[str, Any], float]:
    return _run("disperse", seed)[:2]


def _disperse_row() -> str:
    d, _ = _disperse()
    alone = "all" if d["alone"] == d["robots"] else f"{d['alone']} of"
    after = d["all_out_of_range_at_s"]
    when = f" after {after:.0f} s" if after is not None else ""
    moving = "none moves" if d["still_moving"] == 0 else f"{d['still_moving']} still move"
    return f"{alone} {d['robots']} robots without a neighbour{when}; {moving} at the end"


#: The table's rows: lab, module, C original, world, and what the row's text comes from.
ROWS: tuple[tuple[str, str, str, str, Callable[[], str]], ...] = (
    ("0 blink", "blink_led", "`blink_led.c`", "`blink_led.csv`", _blink),
    (
        "1.1 movement",
        "simple_movement",
        "`simple_movement.c`",
        "`simple_movement.csv`, `.toml`",
        _simple_movement,
    ),
    (
        "1.2 non-blocked movement",
        "nonblocked_movement",
        "`nonblocked_movement.c`",
        "`nonblocked_movement.csv`, `.toml`",
        _nonblocked_movement,
    ),
    (
        "2 communication",
        "speaker_listener",
        "`test_speaker.c`, `test_listener.c`",
        "`speaker_listener.csv` (uid 0 speaks)",
        _speaker_listener,
    ),
    (
        "3 gradient",
        "gradient_simple",
        "`gradient_simple.c`",
        "`gradient_simple.csv` (30 robots, seed uid 42)",
        _gradient_row,
    ),
    (
        "4 orbit",
        "orbit",
        "`orbit_star.c`, `orbit_planet.c`",
        "`orbit.csv` (star uid 0, planet uid 1), `orbit.toml`",
        _orbit_row,
    ),
    (
        "5 move to light",
        "move_to_light",
        "`move_to_light.c`",
        "`move_to_light.csv`, `.toml` (the light)",
        _move_to_light_row,
    ),
    ("6 sync", "sync", "`sync.c`", "`sync.csv` (19 robots), `sync.toml`", _sync_row),
    (
        "7 disperse",
        "disperse",
        "`disperse.c`",
        "`disperse.csv` (20 robots touching)",
        _disperse_row,
    ),
)


def seed_one_block() -> str:
    """The README's table of the labs: what each does on kilonet with seed 1."""
    lines = [
        "| lab | module | C original | world | what it does on kilonet (seed 1) |",
        "|---|---|---|---|---|",
    ]
    for lab, module, original, world, text in ROWS:
        lines.append(f"| {lab} | `{module}` | {original} | {world} | {text()} |")
    return "\n".join(lines)


# -- several seeds ---------------------------------------------------------------------------
def _loop(lab: str, seeds: Sequence[int]) -> str:
    numbers = " ".join(map(str, seeds))
    return f"`for s in {numbers}; do python -m examples.labs.{lab} --seed $s; done`"


def _orbit_paragraph() -> str:
    runs = [_orbit(s) for s in SEEDS]
    planets = [p for p, _ in runs]
    return (
        f"**Orbit** ({_loop('orbit', SEEDS)}, 300 s each, "
        f"{_span([c for _, c in runs])} s CPU): "
        f"{_span([p['laps_clockwise'] for p in planets], '.2f')} laps clockwise in 300 s over "
        f"the {len(SEEDS)} seeds, at a mean distance of "
        f"{_span([p['distance_mean_mm'] for p in planets], '.2f')} mm; 90 % of the time within "
        f"{min(p['distance_p5_mm'] for p in planets):.1f}–"
        f"{max(p['distance_p95_mm'] for p in planets):.1f} mm of the star, the closest "
        f"{min(p['distance_min_mm'] for p in planets):.1f} mm and the farthest "
        f"{max(p['distance_max_mm'] for p in planets):.1f} mm."
    )


def _gradient_paragraph() -> str:
    seeds = SEEDS[:5]
    runs = [_gradient(s) for s in seeds]
    exact = sum(g["equal_to_hop_count"] == g["robots"] for g in runs)
    return (
        f"**Gradient** ({_loop('gradient_simple', seeds)}, 60 s): in {exact} of {len(seeds)} "
        f"seeds all {runs[0]['robots']} robots hold the hop count from the seed robot (uid 42) "
        "computed by breadth-first search over the medium's own graph (`sim.medium.graph()`), "
        f"up to {_span([g['max_hops'] for g in runs], 'd')} hops."
    )


def _disperse_paragraph() -> str:
    runs = [_disperse(s) for s in SEEDS]
    figures = [d for d, _ in runs]
    every = sum(d["alone"] == d["robots"] and d["still_moving"] == 0 for d in figures)
    apart = [d["all_out_of_range_at_s"] for d in figures if d["all_out_of_range_at_s"] is not None]
    return (
        f"**Disperse** ({_loop('disperse', SEEDS)}, 300 s each, "
        f"{_span([c for _, c in runs])} s CPU): the {figures[0]['robots']} robots of the "
        f"touching clump end without a neighbour, none still moving, in {every} of "
        f"{len(SEEDS)} seeds; every two robots stood farther apart than the range after "
        f"{_span(apart, '.0f')} s, the closest two ending "
        f"{_span([d['closest_centres_mm'] for d in figures])} mm apart."
    )


def _move_to_light_paragraph() -> str:
    runs = [_move_to_light(s) for s in SEEDS]
    robots = [r for rs, _ in runs for r in rs]
    near = [r["within_50_mm_at_s"] for r in robots]
    every = sum(all(r["within_50_mm_at_s"] is not None for r in rs) for rs, _ in runs)
    reached = [t for t in near if t is not None]
    return (
        f"**Move to light** ({_loop('move_to_light', SEEDS)}, 60 s each, "
        f"{_span([c for _, c in runs])} s CPU): both robots come within 50 mm of the light in "
        f"{every} of {len(SEEDS)} seeds, after {_span(reached)} s, and end "
        f"{_span([r['end_mm'] for r in robots])} mm from it."
    )


def _sync_paragraph() -> str:
    base = [_sync(s)[0] for s in SEEDS]
    near = [_sync(s, **{"medium.reach": "disc"})[0] for s in VARIANT_SEEDS]
    exact = [_sync(s, **{"robot.clock_sd": 0})[0] for s in VARIANT_SEEDS]
    ticks = [s["spread_end_s"] * 30.52 for s in base]
    return (
        f"**Sync** ({_loop('sync', SEEDS)}, 300 s each): the flash spread falls from "
        f"{_span([s['spread_start_s'] for s in base], '.2f')} s once every robot has flashed to "
        f"{_span([s['spread_end_s'] for s in base], '.2f')} s "
        f"({_span([s['end_over_start'] for s in base], '.2f')} of the start; "
        f"{_span(ticks, '.0f')} ticks). Each robot hearing only its neighbours within 85 mm "
        f"(`--set medium.reach=disc`, seeds {VARIANT_SEEDS[0]}–{VARIANT_SEEDS[-1]}): "
        f"{_span([s['spread_end_s'] for s in near], '.2f')} s at the end "
        f"({_span([s['end_over_start'] for s in near], '.2f')} of the start). Perfect clocks "
        f"(`--set robot.clock_sd=0`, seeds {VARIANT_SEEDS[0]}–{VARIANT_SEEDS[-1]}): "
        f"{_and(sorted(s['spread_end_s'] for s in exact), '.2f')} s at the end."
    )


def seeds_block() -> str:
    """The README's several-seed paragraphs (orbit, gradient, disperse, move to light, sync)."""
    paragraphs = [
        _orbit_paragraph(),
        _gradient_paragraph(),
        _disperse_paragraph(),
        _move_to_light_paragraph(),
        _sync_paragraph(),
    ]
    return "\n\n".join(paragraphs)
