"""What the labs' behaviour is measured by: pure functions on times and positions, and one
``LAB(sim) -> dict`` per lab with the figures its test asserts and its README section reports.

Every figure comes from the run's ground truth (true positions, the trace of LEDs and poses, the
medium's counters and graph), never from what the robots believe.
"""

from __future__ import annotations

import math
from collections import Counter
from itertools import pairwise
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from kilonet.simulation import Simulation

__all__ = [
    "COLOURS",
    "blink_led",
    "circular_range",
    "closest_pair_mm",
    "colour_times",
    "disperse",
    "flash_spread_s",
    "gradient_simple",
    "led_phases",
    "move_to_light",
    "movement",
    "orbit",
    "pose_tracks",
    "positions_at",
    "revolutions",
    "speaker_listener",
    "sync",
]

#: The LED colours the labs use, by name: kilolib's ``RGB(r, g, b)`` channels.
COLOURS = {
    "off": (0, 0, 0),
    "red": (1, 0, 0),
    "green": (0, 1, 0),
    "blue": (0, 0, 1),
    "yellow": (1, 1, 0),
    "magenta": (1, 0, 1),
    "white": (1, 1, 1),
}

Track = tuple[np.ndarray, np.ndarray, np.ndarray]


# -- pure functions ----------------------------------------------------------------------------
def revolutions(center_mm: np.ndarray, path_mm: np.ndarray) -> float:
    """Net turns of the bearing from ``center_mm`` to the points of ``path_mm`` (in order),
    counter-clockwise positive: 1.0 is one full lap around the centre.

    ``path_mm`` is (K, 2), its points close enough that the bearing moves less than half a
    turn from one to the next.
    """
    rel = np.asarray(path_mm, dtype=float) - np.asarray(center_mm, dtype=float)
    if len(rel) == 0:
        return 0.0
    bearing = np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]))
    return float((bearing[-1] - bearing[0]) / (2 * math.pi))


def circular_range(times_s: np.ndarray, period_s: float) -> float:
    """The shortest stretch of a ``period_s`` cycle that holds every one of ``times_s`` (taken
    modulo the period), s: 0 when all fall at the same phase, nearly the period when they are
    spread all round.
    """
    phases = np.sort(np.mod(np.asarray(times_s, dtype=float), period_s))
    if len(phases) < 2:
        return 0.0
    gaps = np.diff(np.append(phases, phases[0] + period_s))
    return float(period_s - gaps.max())


def flash_spread_s(flashes: list[np.ndarray], at_s: float, period_s: float) -> float:
    """How far apart the robots' flashes are at ``at_s``: the :func:`circular_range` of every
    robot's last flash at or before ``at_s`` (``flashes[robot]``: sorted times, s).

    Raises
    ------
    ValueError
        If some robot has not flashed by ``at_s``.
    """
    last = []
    for robot, times in enumerate(flashes):
        k = int(np.searchsorted(times, at_s, side="right"))
        if k == 0:
            raise ValueError(f"robot {robot} has not flashed by {at_s} s")
        last.append(times[k - 1])
    return circular_range(np.array(last), period_s)


def closest_pair_mm(xy: np.ndarray) -> float:
    """The shortest distance between two of the centres ``xy`` ((N, 2), N >= 2), mm."""
    xy = np.asarray(xy, dtype=float)
    gaps = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    return float(gaps.min())


def positions_at(tracks: list[Track], at_s: float) -> np.ndarray:
    """Every robot's centre at ``at_s`` on its track (:func:`pose_tracks`): the last pose
    recorded at or before then, (N, 2) mm."""
    return np.array([xy[np.searchsorted(t, at_s, side="right") - 1] for t, xy, _ in tracks])


# -- what a run recorded -------------------------------------------------------------------------
def pose_tracks(sim: Simulation) -> list[Track]:
    """Every robot's poses from the start: per robot, times (s), centres ((K, 2) mm) and
    headings (rad, unwrapped: a turn of 400° reads as 400°)."""
    poses = sim.trace.poses_frame()
    tracks = []
    for robot in range(sim.n_robots):
        mine = poses[poses.robot == robot]
        t = np.concatenate([[0.0], mine.t_s.to_numpy()])
        xy = np.vstack([sim.initial_positions_mm[robot], mine[["x_mm", "y_mm"]].to_numpy()])
        heading = np.concatenate([[sim.initial_headings_rad[robot]], mine.heading_rad])
        tracks.append((t, xy, np.unwrap(heading)))
    return tracks


def colour_times(sim: Simulation, colour: str) -> list[np.ndarray]:
    """Per robot, the times (s) its LED turned ``colour`` (a name in :data:`COLOURS`)."""
    led = sim.trace.led_frame()
    r, g, b = COLOURS[colour]
    on = led[(led.r == r) & (led.g == g) & (led.b == b)]
    return [on.t_s[on.robot == robot].to_numpy() for robot in range(sim.n_robots)]


def led_phases(sim: Simulation, robot: int) -> list[tuple[str, float, float]]:
    """The stretches of time ``robot``'s LED kept one colour, ``(colour name, start_s,
    end_s)``, each begun and ended by a change (the one still lit at the end is left out)."""
    names = {rgb: name for name, rgb in COLOURS.items()}
    led = sim.trace.led_frame()
    mine = led[led.robot == robot]
    changes = [
        (float(t), names.get((int(r), int(g), int(b)), f"rgb{(r, g, b)}"))
        for t, r, g, b in zip(mine.t_s, mine.r, mine.g, mine.b, strict=True)
    ]
    return [(name, a, b) for (a, name), (b, _) in pairwise(changes)]


def _robot_with_uid(sim: Simulation, uid: int) -> int:
    return next(i for i, robot in enumerate(sim.robots) if robot.kilo_uid == uid)


# -- the labs ------------------------------------------------------------------------------------
def blink_led(sim: Simulation) -> dict[str, Any]:
    """The blink lab: per LED colour, how many complete stretches of it the robots showed and
    how long one lasted on average, s."""
    lengths: dict[str, list[float]] = {}
    for robot in range(sim.n_robots):
        for colour, a, b in led_phases(sim, robot):
            lengths.setdefault(colour, []).append(b - a)
    return {
        colour: {"stretches": len(lasted), "mean_s": float(np.mean(lasted))}
        for colour, lasted in lengths.items()
    }


def movement(sim: Simulation) -> dict[str, Any]:
    """simple_movement and nonblocked_movement: per LED colour (one colour per motion), how
    many complete stretches of it the robots showed, their mean turn (degrees,
    counter-clockwise positive) and the mean distance the centre moved in one, mm."""
    turns: dict[str, list[float]] = {}
    moves: dict[str, list[float]] = {}
    for robot, (t, xy, heading) in enumerate(pose_tracks(sim)):
        for colour, a, b in led_phases(sim, robot):
            i, j = np.searchsorted(t, [a, b], side="right") - 1
            turns.setdefault(colour, []).append(math.degrees(heading[j] - heading[i]))
            moves.setdefault(colour, []).append(float(np.hypot(*(xy[j] - xy[i]))))
    return {
        colour: {
            "stretches": len(turns[colour]),
            "turn_deg": float(np.mean(turns[colour])),
            "moved_mm": float(np.mean(moves[colour])),
        }
        for colour in turns
    }


def orbit(sim: Simulation, star_uid: int = 0) -> dict[str, Any]:
    """The orbit lab: for every planet, its laps around the star (clockwise positive, the way
    the lab's planet goes: the star on its right) and its distance to the star over the run
    (mean, 5th and 95th percentiles, min, max; mm)."""
    star = _robot_with_uid(sim, star_uid)
    centre = sim.initial_positions_mm[star]
    out: dict[str, Any] = {}
    for planet, (_, path, _) in enumerate(pose_tracks(sim)):
        if planet == star:
            continue
        distance = np.hypot(*(path - centre).T)
        p5, p95 = np.percentile(distance, [5, 95])
        out[f"planet {planet}"] = {
            "laps_clockwise": -revolutions(centre, path),
            "distance_mean_mm": float(distance.mean()),
            "distance_p5_mm": float(p5),
            "distance_p95_mm": float(p95),
            "distance_min_mm": float(distance.min()),
            "distance_max_mm": float(distance.max()),
        }
    return out


def speaker_listener(sim: Simulation, speaker_uid: int = 0) -> dict[str, Any]:
    """The communication lab: messages the speaker sent and its magenta blinks; messages each
    listener received and its yellow blinks."""
    speaker = _robot_with_uid(sim, speaker_uid)
    counters = sim.medium.counters
    magenta, yellow = colour_times(sim, "magenta"), colour_times(sim, "yellow")
    out: dict[str, Any] = {
        f"speaker {speaker}": {
            "sent": counters["sent"][speaker],
            "magenta_blinks": len(magenta[speaker]),
        }
    }
    for robot in range(sim.n_robots):
        if robot != speaker:
            out[f"listener {robot}"] = {
                "received": counters["received"][robot],
                "yellow_blinks": len(yellow[robot]),
            }
    return out


def gradient_simple(sim: Simulation, seed_uid: int = 42, unreached: int = 255) -> dict[str, Any]:
    """The gradient lab: how many robots hold a gradient equal to their hop count from the
    seed over the medium's own links, each from its sender to its receivers
    (:func:`kilonet.scenarios.gradient.hop_distances`; a robot the seed cannot reach should still
    hold ``unreached``), the largest hop count, and the robots that differ as
    ``(robot, gradient, hops)``."""
    from kilonet.scenarios.gradient import hop_distances

    hops = hop_distances(sim, _robot_with_uid(sim, seed_uid))
    wrong = [
        (robot, program.own_gradient, hops.get(robot))
        for robot, program in enumerate(sim.robots)
        if program.own_gradient != hops.get(robot, unreached)
    ]
    return {
        "robots": sim.n_robots,
        "equal_to_hop_count": sim.n_robots - len(wrong),
        "max_hops": max(hops.values()),
        "differing": wrong,
    }


def disperse(sim: Simulation) -> dict[str, Any]:
    """The disperse lab: how many robots have how many neighbours at the end (on the medium's
    own graph), the closest two centres (mm), how many robots still move, and the first whole
    second at which every two robots stood beyond their link's reach, soft edge included
    (:mod:`kilonet.radio`: each sender reaches its own distance; ``medium.range_mm`` on the
    disc)."""
    from kilonet.radio import MIN_RECEPTION

    degrees = [d for _, d in sim.medium.graph().degree()]
    radio = sim.transceivers
    sender, receiver = np.nonzero(~np.eye(sim.n_robots, dtype=bool))
    reach = radio.link_reach_mm(sender, receiver)
    if radio.reach.edge_mm:  # where a link still delivers MIN_RECEPTION of its messages
        reach = reach + radio.reach.edge_mm * math.log(1.0 / MIN_RECEPTION - 1.0)

    def out_of_range(positions: np.ndarray) -> bool:
        return bool(np.all(np.hypot(*(positions[sender] - positions[receiver]).T) > reach))

    tracks = pose_tracks(sim)
    seconds = np.arange(0.0, sim.env.now + 1e-9, 1.0)
    apart = (float(t) for t in seconds if out_of_range(positions_at(tracks, t)))
    return {
        "robots": sim.n_robots,
        "robots_by_neighbour_count": dict(sorted(Counter(degrees).items())),
        "alone": degrees.count(0),
        "closest_centres_mm": closest_pair_mm(sim.world.positions_mm),
        "still_moving": sum(any(m.running) for m in sim.motion.motors),
        "all_out_of_range_at_s": next(apart, None),
    }


def move_to_light(sim: Simulation, near_mm: float = 50.0) -> dict[str, Any]:
    """The move-to-light lab: every robot's distance to the light source at the start, at the
    end and at its closest (mm), and when it first came within ``near_mm`` (s, or None)."""
    light = sim.params.light
    source = np.array([light.source_x_mm, light.source_y_mm])
    out: dict[str, Any] = {}
    for robot, (t, xy, _) in enumerate(pose_tracks(sim)):
        distance = np.hypot(*(xy - source).T)
        near = np.flatnonzero(distance <= near_mm)
        out[f"robot {robot}"] = {
            "start_mm": float(distance[0]),
            "end_mm": float(distance[-1]),
            "closest_mm": float(distance.min()),
            f"within_{near_mm:g}_mm_at_s": float(t[near[0]]) if len(near) else None,
        }
    return out


def sync(sim: Simulation, period_ticks: int = 50, window_s: float = 20.0) -> dict[str, Any]:
    """The sync lab: the spread of the white flashes (:func:`flash_spread_s` over the nominal
    period, ``period_ticks / robot.ticks_per_s``) when every robot has flashed once, its
    median over the last ``window_s`` of the run (sampled every 0.1 s), their ratio, and how
    far the robots moved on average (mm)."""
    period_s = period_ticks / sim.params.robot.ticks_per_s
    flashes = colour_times(sim, "white")
    all_flashed_s = max(float(times[0]) for times in flashes)
    start = flash_spread_s(flashes, all_flashed_s, period_s)
    window = np.arange(sim.env.now - window_s, sim.env.now, 0.1)
    end = float(np.median([flash_spread_s(flashes, t, period_s) for t in window]))
    moved = np.hypot(*(sim.world.positions_mm - sim.initial_positions_mm).T)
    return {
        "period_s": period_s,
        "all_flashed_at_s": all_flashed_s,
        "spread_start_s": start,
        "spread_end_s": end,
        "end_over_start": end / start,
        "moved_mean_mm": float(moved.mean()),
    }
