"""``follower``: three robots build a frame, a fourth trilaterates itself and walks to their
centroid (the seed ``trilateration-with-kilobots``).

Four robots in role order: row 0 the origin (ID 1), row 1 the x-axis robot (ID 2), row 2 the
third robot (ID 3), row 3 the follower (ID 4); a placement file must have exactly these four
rows. A placement is refused when the frame robots stand beyond ranging distance of each other
(:func:`ranging_mm`: the radio's reach, but at most ``follower.neighbour_max_mm``, beyond which
kilolib's estimates saturate) or the follower beyond a median link's reach of one of them (it
may start where it hears but cannot range a robot: it then walks nearer); a link that
occlusion weakens or blocks (``medium.occlusion``) is the follower's to deal with, as on the
robots: it listens, makes its small first move and listens again for fresh messages.

The generated placements draw the frame's sides from ``[side_min_mm, side_max_mm]``, put robot 3
on the ``handedness`` side of the 1→2 axis (``right`` makes the follower's frame a mirror image
of the floor) and the follower at ``[start_min_mm, start_max_mm]`` from the goal
(``start_max_mm`` 0: anywhere it ranges all three), not touching any robot. ``start_min_mm``
defaults to 20 mm: a follower that starts within a few millimetres of the goal has nothing to
show: it would reach the goal without a step. With
``direct_start`` (default) the straight line from the start to the goal must be passable (clear
of the robots' bodies and of line-of-sight shadows): with the hardware range the follower then
starts beside an edge long enough to pass or inside the triangle, never behind a robot.

The follower turns with a linear calibration ``t = f(angle)`` fitted by :func:`calibrate_turns`
on another simulated robot (``calibration_seed``), as the seed's author timed one Kilobot by
hand; the follower's own turn rate differs (``motion.turn_error``).

Summary figures (against ground truth): ``reached`` (the follower declared arrival and is within
``success_mm`` of the true centroid), ``outcome``, ``final_distance_mm``, ``steps``,
``path_length_mm`` and ``straight_line_mm`` (start to goal), ``mirrored_frame`` (what the follower
concluded) and ``mirrored_frame_true``, ``final_estimate_error_mm``, the calibration's and the
follower's true turn rates. Files: ``trajectory.csv`` (:func:`trajectory`) and ``follower.png``.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.params import BatteryParams, MotionParams, ParamError, Params, RobotParams
from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.protocols.follower.follower import (
    Follower,
    FollowerParams,
    Origin,
    ThirdRobot,
    XAxisRobot,
    reachable_goal,
)
from kilonet.protocols.follower.turn_calibration import TimedTurns, TurnCalibration
from kilonet.scenarios.base import (
    Drawing,
    Reporting,
    RunResult,
    Scenario,
    ScenarioError,
    Setup,
    run,
)
from kilonet.simulation import Simulation, stream_for
from kilonet.visibility import LinkModel

if TYPE_CHECKING:  # pandas and matplotlib are imported where used: listing scenarios is fast
    import pandas as pd

__all__ = [
    "ROLES",
    "SCENARIO",
    "CalibrationRun",
    "FollowerParams",
    "calibrate_turns",
    "check_placement",
    "frame_to_floor",
    "path_length_mm",
    "ranging_mm",
    "run_many",
    "trajectory",
]

ROLES = ("origin", "x-axis robot", "third robot", "follower")
FOLLOWER_INDEX = 3
#: Turn durations of the calibration run, s (about 20° to 180° at the nominal 45°/s).
CALIBRATION_DURATIONS_S = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
_BYTE_LAYOUT_MAX_SIDE_MM = 120.0  # |x| of robots 2 and 3 (plus noise) must fit an int8 (mm)
_MIN_FRAME_HEIGHT_MM = 10.0  # robot 3 this far from the 1→2 line, or the frame is degenerate


# --------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class CalibrationRun:
    """A turn calibration and how it was made.

    Attributes
    ----------
    calibration : TurnCalibration
        The fitted ``t = f(angle)``.
    true_deg_s : float
        The calibrated robot's real turn rate, degrees per second (ground truth).
    angles_rad, times_s : tuple of float
        The angles as read (with reading error) and the motor-on times of each turn.
    """

    calibration: TurnCalibration
    true_deg_s: float
    angles_rad: tuple[float, ...]
    times_s: tuple[float, ...]


def calibrate_turns(
    params: Params,
    *,
    seed: int = 1,
    durations_s: tuple[float, ...] = CALIBRATION_DURATIONS_S,
    reading_sd_deg: float = 3.0,
) -> CalibrationRun:
    """Time a simulated robot through turns and fit ``t = f(angle)``, as the seed's author did.

    One robot (the motion, robot and battery models of ``params``, master seed ``seed``) pivots
    for each duration in turn; the observer reads the angle each pulse turned off the run's poses
    (ground truth, as the author read it off the table) with a Gaussian reading error of
    ``reading_sd_deg``, and fits a least-squares line.

    Raises
    ------
    ValueError
        If fewer than two distinct durations are given.
    """
    return _calibrate(
        params.motion, params.robot, params.battery, seed, tuple(durations_s), reading_sd_deg
    )


@functools.lru_cache(maxsize=64)
def _calibrate(
    motion: MotionParams,
    robot: RobotParams,
    battery: BatteryParams,
    seed: int,
    durations_s: tuple[float, ...],
    reading_sd_deg: float,
) -> CalibrationRun:
    pause_s = 0.5
    duration = sum(durations_s) + pause_s * (len(durations_s) + 2)
    cal_params = Params(seed=seed, duration_s=duration, motion=motion, robot=robot, battery=battery)
    sim = Simulation(
        [[0.0, 0.0], [500.0, 0.0]],  # a second, idle robot far away: a placement needs two
        lambda i: TimedTurns(durations_s if i == 0 else (), pause_s=pause_s),
        cal_params,
        headings_rad=[0.0, 0.0],
    )
    sim.run()
    poses = sim.trace.poses_frame()
    poses = poses[poses["robot"] == 0]
    times = np.concatenate([[0.0], poses["t_s"].to_numpy()])
    heading = np.unwrap(np.concatenate([[0.0], poses["heading_rad"].to_numpy()]))
    events = sim.trace.events_frame()
    ends = events[events["event"] == "timed_turn"]
    turned, motor_s, previous = [], [], 0.0
    for t_s, data in zip(ends["t_s"], ends["data"], strict=True):
        at_end = float(heading[np.searchsorted(times, t_s + 1e-9) - 1])
        turned.append(at_end - previous)
        motor_s.append(json.loads(data)["duration_s"])
        previous = at_end
    # The observer's reading error; this run draws no placement, so that stream is free.
    reading = stream_for(seed, "placement").normal(0.0, math.radians(reading_sd_deg), len(turned))
    angles = np.asarray(turned) + reading
    return CalibrationRun(
        calibration=TurnCalibration.fit(angles, motor_s),
        true_deg_s=math.degrees(sim.motion.pivot_rate_rad_s(0, 0, sim.robots[0].kilo_turn_left)),
        angles_rad=tuple(float(a) for a in angles),
        times_s=tuple(float(t) for t in motor_s),
    )


# ----------------------------------------------------------------------------- placement


def _frame_height_mm(positions: np.ndarray) -> float:
    """Signed distance of robot 3 from the line 1→2 (positive on the left), mm."""
    p0, p1, p2 = positions[:3]
    ex = (p1 - p0) / np.linalg.norm(p1 - p0)
    return float(ex[0] * (p2 - p0)[1] - ex[1] * (p2 - p0)[0])


def check_placement(positions: np.ndarray, params: Params) -> None:
    """Refuse a placement the follower cannot work with.

    Raises
    ------
    ScenarioError
        If there are not exactly four robots, robots 1–3 are (nearly) collinear, two of them
        stand beyond :func:`ranging_mm` of each other, the follower beyond a median link's
        reach of one of them, or a frame side is too long for the byte message.
    """
    pos = np.asarray(positions, dtype=float)
    if pos.shape != (4, 2):
        raise ScenarioError(
            f"follower: the placement has {len(pos)} robots; it needs exactly 4 rows in role "
            f"order ({', '.join(ROLES)})"
        )
    height = _frame_height_mm(pos)
    if abs(height) < _MIN_FRAME_HEIGHT_MM:
        raise ScenarioError(
            f"follower: robots 1-3 are nearly collinear (robot 3 is {abs(height):.1f} mm from "
            f"the line 1->2, need >= {_MIN_FRAME_HEIGHT_MM:g} mm): they form no frame"
        )
    from kilonet.radio import reach_of

    frame_mm, hearing_mm = ranging_mm(params), reach_of(params.medium).median_mm
    for a, b in ((0, 1), (0, 2), (1, 2), (0, 3), (1, 3), (2, 3)):
        d = float(np.linalg.norm(pos[a] - pos[b]))
        if b == 3 and d > hearing_mm:
            raise ScenarioError(
                f"follower: the follower stands {d:.1f} mm from robot {a + 1}, beyond the "
                f"{hearing_mm:g} mm a link reaches ({_ranging_source(params).split(',')[0]}); "
                "the follower needs messages from all three frame robots"
            )
        if b < 3 and d > frame_mm:
            raise ScenarioError(
                f"follower: robot {b + 1} stands {d:.1f} mm from robot {a + 1}, beyond the "
                f"{frame_mm:g} mm it can range ({_ranging_source(params)}); the frame robots "
                "need distances to each other"
            )
    if params.scenario.message == "byte":
        side = max(float(np.linalg.norm(pos[a] - pos[b])) for a, b in ((0, 1), (0, 2), (1, 2)))
        if side > _BYTE_LAYOUT_MAX_SIDE_MM:
            raise ScenarioError(
                f"follower: a frame side is {side:.1f} mm, too long for the byte message "
                f"(coordinates are int8 mm, sides <= {_BYTE_LAYOUT_MAX_SIDE_MM:g}); set "
                "follower.message=wide"
            )


def _generate(params: Params, n: int, rng: np.random.Generator) -> np.ndarray:
    """A random placement as the module docstring describes (robots in role order)."""
    if n != 4:
        raise ParamError(f"the follower scenario has exactly 4 robots, not {n}")
    f = params.scenario
    reach_mm = ranging_mm(params)
    links = LinkModel.from_params(params.medium, range_mm=reach_mm)
    if f.message == "byte" and f.side_max_mm > _BYTE_LAYOUT_MAX_SIDE_MM:
        raise ParamError(
            f"follower.side_max_mm = {f.side_max_mm:g} is too long for the byte message (sides "
            f"<= {_BYTE_LAYOUT_MAX_SIDE_MM:g} mm); set follower.message=wide"
        )
    radius = ROBOT_DIAMETER_MM + f.clearance_mm
    r_max = f.start_max_mm or reach_mm
    if f.start_min_mm > r_max:  # an empty start band (and numpy's "high - low < 0")
        raise ParamError(
            f"follower.start_min_mm = {f.start_min_mm:g} is beyond the farthest start, "
            f"{r_max:g} mm from the goal (follower.start_max_mm = {f.start_max_mm:g}; 0: as far "
            f"as it ranges, {_ranging_source(params)}); lower follower.start_min_mm"
        )
    for _ in range(200):
        d12, d13, d23 = rng.uniform(f.side_min_mm, f.side_max_mm, 3)
        x3 = (d13**2 - d23**2 + d12**2) / (2 * d12)
        if d13**2 - x3**2 < _MIN_FRAME_HEIGHT_MM**2:
            continue
        y3 = math.sqrt(d13**2 - x3**2)
        right = rng.random() < 0.5 if f.handedness == "random" else f.handedness == "right"
        frame = np.array([[0.0, 0.0], [d12, 0.0], [x3, -y3 if right else y3]])
        phi = rng.uniform(0, 2 * math.pi)
        rot = np.array([[math.cos(phi), -math.sin(phi)], [math.sin(phi), math.cos(phi)]])
        frame = frame @ rot.T
        goal = frame.mean(axis=0)
        target = np.array(reachable_goal(tuple(goal), [tuple(p) for p in frame], radius))
        for _ in range(200):
            r = math.sqrt(rng.uniform(f.start_min_mm**2, r_max**2))
            theta = rng.uniform(0, 2 * math.pi)
            start = goal + r * np.array([math.cos(theta), math.sin(theta)])
            pos = np.vstack([frame, start])
            gaps = np.linalg.norm(frame - start, axis=1)
            if gaps.min() < ROBOT_DIAMETER_MM + 1.0 or gaps.max() > reach_mm:
                continue  # touching or out of range: the cheap tests first
            if not _hears_all(pos, links):
                continue
            if f.direct_start and not _passable(start, target, frame, radius, links):
                continue
            try:
                check_placement(pos, params)
            except ScenarioError:
                continue
            return pos
    raise ParamError(
        "follower placement: found no follower start that hears all three robots with "
        f"follower.start_min_mm={f.start_min_mm:g}, start_max_mm={f.start_max_mm:g} and "
        f"the {reach_mm:g} mm it can range ({_ranging_source(params)}); widen the start band "
        "or the range"
    )


def ranging_mm(params: Params) -> float:
    """How far apart the four robots may stand, mm: as far as a median link reaches (the disc's
    ``medium.range_mm``, else the preset's median reach, :func:`kilonet.radio.reach_of`), but
    at most ``follower.neighbour_max_mm``, beyond which the follower cannot range (kilolib's
    estimates saturate). The follower plans its moves to stay within it.

    Examples
    --------
    >>> from kilonet.scenarios.base import build_params
    >>> ranging_mm(build_params(SCENARIO))
    100.0
    >>> ranging_mm(build_params(SCENARIO, {"medium.reach": "disc"}))
    85.0
    """
    from kilonet.scenarios.neighbourhood import neighbourhood_mm

    return neighbourhood_mm(params.medium, params.scenario.neighbour_max_mm)


def _ranging_source(params: Params) -> str:
    """The parameters :func:`ranging_mm` comes from, for messages."""
    m = params.medium
    hearing = (
        f"medium.range_mm = {m.range_mm:g}" if m.reach == "disc" else f"medium.reach = {m.reach}"
    )
    return f"{hearing}, follower.neighbour_max_mm = {params.scenario.neighbour_max_mm:g}"


def _hears_all(pos: np.ndarray, links: LinkModel) -> bool:
    """Whether all four robots have links to each other (range and occlusion)."""
    return len(links.links(pos)) == 6


def _follower_hears(pos: np.ndarray, links: LinkModel) -> bool:
    """Whether the follower (row 3) has links to all three frame robots."""
    found = links.links(pos)
    return int((found.j == FOLLOWER_INDEX).sum()) == 3


def _passable(
    start: np.ndarray, target: np.ndarray, frame: np.ndarray, radius: float, links: LinkModel
) -> bool:
    """Straight line start→target clear of the frame robots' bodies (plus clearance), and the
    follower hears all three all along it."""
    seg = target - start
    length = float(np.linalg.norm(seg))
    if length == 0:
        return True
    u = seg / length
    along = np.clip((frame - start) @ u, 0.0, length)
    closest = start + along[:, None] * u
    if (np.linalg.norm(closest - frame, axis=1) < radius + 0.5).any():
        return False
    for s in np.arange(0.0, length, 5.0):
        if not _follower_hears(np.vstack([frame, start + s * u]), links):
            return False
    return True


# --------------------------------------------------------------------------------- program


def _program(params: Params, positions: np.ndarray):
    check_placement(positions, params)
    f = params.scenario
    cal = calibrate_turns(
        params, seed=f.calibration_seed, reading_sd_deg=f.calibration_sd_deg
    ).calibration
    wide = f.message == "wide"
    frame_roles = (Origin, XAxisRobot, ThirdRobot)

    def build(i: int):
        if i < 3:
            return frame_roles[i](samples=f.frame_samples, wide=wide)
        return Follower(
            f,
            cal,
            speed_mm_s=params.motion.speed_mm_s,  # the data sheet's figure, not this robot's
            saturation_mm=params.ranging.max_mm,
            body_mm=ROBOT_DIAMETER_MM,
            # The planner stays where it can range all three; a robot unheard is farther.
            hearing_mm=ranging_mm(params),
        )

    return build


def _stop_when(sim: Simulation) -> bool:
    return sim.robots[FOLLOWER_INDEX].outcome is not None


# ---------------------------------------------------------------------- metrics and files


def frame_to_floor(positions_mm: np.ndarray, frame_xy_mm: np.ndarray) -> np.ndarray:
    """Map points from the frame of robots 1–3 (as the robots build it) to the floor, mm.

    The frame has robot 1 at the origin, robot 2 on +x and robot 3 at y > 0, so when robot 3
    stands on the right of the 1→2 axis its y axis points to the right on the floor.

    Examples
    --------
    >>> pos = np.array([[10.0, 0.0], [10.0, 50.0], [-30.0, 20.0]])
    >>> frame_to_floor(pos, np.array([[50.0, 40.0]])).round(9).tolist()
    [[-30.0, 50.0]]
    >>> mirrored = pos * [-1, 1]
    >>> frame_to_floor(mirrored, np.array([[50.0, 40.0]])).round(9).tolist()
    [[30.0, 50.0]]
    """
    p0, p1 = positions_mm[0], positions_mm[1]
    ex = (p1 - p0) / np.linalg.norm(p1 - p0)
    ey = np.array([-ex[1], ex[0]]) * (1.0 if _frame_height_mm(positions_mm) > 0 else -1.0)
    xy = np.atleast_2d(np.asarray(frame_xy_mm, dtype=float))
    return p0 + xy[:, :1] * ex + xy[:, 1:2] * ey


def _follower_poses(sim: Simulation) -> pd.DataFrame:
    """True poses of the follower over time, starting with its start pose at t = 0."""
    import pandas as pd

    poses = sim.trace.poses_frame()
    poses = poses[poses["robot"] == FOLLOWER_INDEX].drop(columns="robot")
    # The start heading is not traced (nothing moved yet). Without a record of it on the
    # simulation, it is the first draw of the run's motion stream, where Simulation takes its
    # headings from when none are given (as in kilonet.scenarios.run).
    heading0 = getattr(sim, "initial_headings_rad", None)
    if heading0 is None:
        heading0 = stream_for(sim.params.seed, "motion").uniform(0, 2 * np.pi, sim.n_robots)
    x0, y0 = sim.initial_positions_mm[FOLLOWER_INDEX]
    start = pd.DataFrame(
        {"t_s": [0.0], "x_mm": [x0], "y_mm": [y0], "heading_rad": [heading0[FOLLOWER_INDEX]]}
    )
    return pd.concat([start, poses], ignore_index=True).astype(float)


def _fixes(sim: Simulation) -> pd.DataFrame:
    """The follower's position estimates: time, frame coordinates and floor coordinates."""
    import pandas as pd

    events = sim.trace.events_frame()
    events = events[(events["robot"] == FOLLOWER_INDEX) & (events["event"] == "fix")]
    data = [json.loads(d) for d in events["data"]]
    frame_xy = np.array([[d["x_mm"], d["y_mm"]] for d in data]).reshape(-1, 2)
    floor = frame_to_floor(sim.initial_positions_mm, frame_xy) if len(data) else frame_xy
    return pd.DataFrame(
        {
            "t_s": events["t_s"].to_numpy(dtype=float),
            "est_x_mm": floor[:, 0],
            "est_y_mm": floor[:, 1],
            "frame_x_mm": frame_xy[:, 0],
            "frame_y_mm": frame_xy[:, 1],
        }
    )


def trajectory(sim: Simulation) -> pd.DataFrame:
    """The follower's walk: one row per traced pose and per position fix.

    Columns: ``t_s``; the true pose ``x_mm, y_mm, heading_rad`` at that time; the follower's
    latest estimate mapped to the floor, ``est_x_mm, est_y_mm`` (empty before its first fix);
    and the same estimate in the robot's own frame, ``frame_x_mm, frame_y_mm``.
    """
    import pandas as pd

    poses = _follower_poses(sim)
    fixes = _fixes(sim)
    times = pd.DataFrame({"t_s": np.union1d(poses["t_s"], fixes["t_s"])})
    out = pd.merge_asof(times, poses, on="t_s", direction="backward")
    out = pd.merge_asof(out, fixes, on="t_s", direction="backward")
    return out


def path_length_mm(sim: Simulation) -> float:
    """Length of the follower's true path, mm."""
    poses = _follower_poses(sim)
    return float(np.hypot(*np.diff(poses[["x_mm", "y_mm"]].to_numpy(), axis=0).T).sum())


def _turn_deg_s(sim: Simulation, motor: int, duty: int) -> float:
    """The follower's true pivot rate on ``motor`` (0 left, 1 right) at ``duty``, deg/s."""
    return math.degrees(sim.motion.pivot_rate_rad_s(FOLLOWER_INDEX, motor, duty))


def _metrics(sim: Simulation) -> dict[str, Any]:
    import pandas as pd

    start = sim.initial_positions_mm
    goal = start[:3].mean(axis=0)  # the frame robots never move
    follower = sim.robots[FOLLOWER_INDEX]
    final_distance = float(np.linalg.norm(sim.world.positions_mm[FOLLOWER_INDEX] - goal))
    success_mm = sim.params.scenario.success_mm
    fixes = _fixes(sim)
    estimate_error = None
    if len(fixes):
        poses = _follower_poses(sim)
        last = fixes.iloc[[-1]]
        at = pd.merge_asof(last[["t_s"]], poses, on="t_s", direction="backward").iloc[0]
        estimate_error = float(
            math.hypot(last["est_x_mm"].iloc[0] - at["x_mm"], last["est_y_mm"].iloc[0] - at["y_mm"])
        )
    events = sim.trace.events_frame()
    done = events[(events["robot"] == FOLLOWER_INDEX) & (events["event"] == follower.outcome)]
    return {
        "reached": bool(follower.outcome == "reached" and final_distance <= success_mm),
        "outcome": follower.outcome or "timeout",
        "final_distance_mm": round(final_distance, 3),
        "steps": follower.steps,
        "path_length_mm": round(path_length_mm(sim), 3),
        "straight_line_mm": round(float(np.linalg.norm(start[FOLLOWER_INDEX] - goal)), 3),
        "finish_time_s": float(done["t_s"].iloc[0]) if len(done) else None,
        "mirrored_frame": bool(follower.mirrored),
        "mirrored_frame_true": bool(_frame_height_mm(start) < 0),
        "handedness_settled": bool(follower.handedness_settled),
        "final_estimate_error_mm": None if estimate_error is None else round(estimate_error, 3),
        "calibration_deg_s": round(follower.calibration.deg_per_s, 3),
        "follower_turn_deg_s": round(_turn_deg_s(sim, 0, follower.kilo_turn_left), 3),
        "follower_turn_right_deg_s": round(_turn_deg_s(sim, 1, follower.kilo_turn_right), 3),
        "follower_turn_gain": round(follower.turn_gains[1], 3),
        "follower_turn_gain_right": round(follower.turn_gains[-1], 3),
    }


def _outputs(result: RunResult, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    sim = result.sim
    traj = trajectory(sim)
    traj.to_csv(out_dir / "trajectory.csv", index=False)
    start = sim.initial_positions_mm
    goal = start[:3].mean(axis=0)
    fig, ax = plt.subplots(figsize=(6, 6))
    radius = sim.world.radius_mm
    for k in range(3):
        ax.add_patch(Circle(start[k], radius, fc="0.85", ec="k"))
        ax.annotate(str(k + 1), start[k], ha="center", va="center", fontsize=11)
    ax.add_patch(Circle(start[3], radius, fc="none", ec="tab:blue", ls="--", label="start"))
    ax.add_patch(Circle(sim.world.positions_mm[3], radius, fc="none", ec="tab:blue", label="end"))
    ax.plot(traj["x_mm"], traj["y_mm"], color="tab:blue", lw=1.5, label="path (true)")
    fixes = _fixes(sim)
    ax.plot(fixes["est_x_mm"], fixes["est_y_mm"], "x", color="tab:orange", label="estimates")
    ax.plot(*goal, "*", ms=14, color="tab:red", label="goal (centroid of 1-3)")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.margins(0.15)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    s = result.summary
    ax.set_title(
        f"follower: {s['outcome']}, {s['final_distance_mm']:.1f} mm from goal, "
        f"{s['steps']} steps, {'mirrored' if s['mirrored_frame'] else 'floor'} frame"
    )
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / "follower.png", dpi=100)
    plt.close(fig)


SCENARIO = Scenario(
    name="follower",
    summary="trilateration: three robots build a frame, a fourth walks to their centroid",
    setup=Setup(
        program=_program,
        section=FollowerParams,
        robots=4,
        defaults={"duration_s": 600.0},
        supports={
            "medium.message_format": ("kilolib",),
            "robot.rx_distance": ("estimate",),
        },
        placement=_generate,
        stop_when=_stop_when,
    ),
    reporting=Reporting(
        metrics=_metrics,
        ends_when="the follower arrives or gives up",
    ),
    drawing=Drawing(
        figures=_outputs,
    ),
)


def run_many(seeds: range | list[int], overrides: dict[str, Any] | None = None) -> pd.DataFrame:
    """Run the scenario once per seed (generated placements) and return one summary per row,
    e.g. ``run_many(range(1, 101), {"medium.loss_prob": 0.1})["reached"].mean()``."""
    import pandas as pd

    rows = [run(SCENARIO, overrides, seed=s).summary for s in seeds]
    return pd.DataFrame(rows)
