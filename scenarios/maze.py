"""``maze``: one robot localizes itself in a grid maze and visits every cell (the lab seed).

Robots: robot 0 is the maze robot (:class:`kilonet.protocols.maze.program.MazeRobot`), robots 1–4
the landmarks at the maze corners SW, SE, NE, NW
(:class:`kilonet.protocols.maze.program.LandmarkBeacon`). The maze is drawn from the run's placement
stream (a perfect maze, or with ``maze.loops`` > 0 one with loops), and so is the robot's start
cell.

``maze.landmarks = camera`` (default) ranges the landmarks with the robot's camera model; with
``infrared`` the landmarks are Kilobots broadcasting their coordinates and the robot ranges only
what it hears and ranges, so every cell centre must be within
:func:`kilonet.scenarios.neighbourhood.neighbourhood_mm` (a median link's reach, at most
``maze.neighbour_max_mm``) of at least three landmarks — for example::

    kilonet run maze --set maze.landmarks=infrared --set maze.size=2x2 --set maze.cell_mm=50

Summary figures against ground truth: ``cells``, ``cells_visited`` (true cells the robot stood
in), ``steps_to_cover`` (moves until it had truly stood in every cell; ``null`` if it never did),
``planner``, ``trilateration_rmse_mm`` (robot's position fixes vs its true position),
``belief_correct_fraction`` (share of steps after the first ``maze.burn_in_steps`` in which the
belief's most likely cell is the true cell). Outputs: ``maze_steps.csv`` (one row per step with
the truth beside the robot's estimates), ``maze_log.txt`` (the robot's verbose log: grid with
``X`` for visited cells, move and stay probabilities per step), ``maze_path.png``,
``maze_belief.png``.

Studies for the note: :func:`coverage_study` / :func:`coverage_table` (planner vs random walk
over many random mazes) and :func:`belief_accuracy_by_noise` (probability that the belief's
maximum is the true cell, per step, for several wall-sensor noise levels).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.params import ParamError, Params
from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.protocols.maze.hardware import (
    Maze,
    RangeSensor,
    WallSensor,
    corner_landmarks,
    generate_maze,
    parse_size,
)
from kilonet.protocols.maze.program import (
    LANDMARK_COLORS,
    LandmarkBeacon,
    MazeParams,
    MazeRobot,
    MazeStage,
)
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, Setup, run
from kilonet.scenarios.maze_hardware import MazeBody, MazeHardware, fit_maze_hardware
from kilonet.simulation import Simulation, stream_for

if TYPE_CHECKING:  # pandas and matplotlib are imported where used: listing scenarios is fast
    import pandas as pd
    from matplotlib.figure import Figure

__all__ = [
    "DEFAULT_NOISE_TABLES",
    "SCENARIO",
    "MazeParams",
    "belief_accuracy_by_noise",
    "belief_accuracy_summary",
    "coverage_study",
    "coverage_table",
    "maze_for",
    "step_table",
]

_ROBOT = 0
_LANDMARKS = (1, 2, 3, 4)


# -- world ------------------------------------------------------------------------------------
def maze_for(params: Params) -> Maze:
    """The true maze of a run: the first draws of its placement stream."""
    m = params.scenario
    cols, rows = parse_size(m.size)
    return generate_maze(
        cols, rows, stream_for(params.seed, "placement"), cell_mm=m.cell_mm, loops=m.loops
    )


def _placement(params: Params, n: int, rng: np.random.Generator) -> np.ndarray:
    m = params.scenario
    if n != 1 + len(_LANDMARKS):
        raise ValueError(f"the maze scenario has 5 robots (maze robot and 4 landmarks), not {n}")
    cols, rows = parse_size(m.size)
    maze = generate_maze(cols, rows, rng, cell_mm=m.cell_mm, loops=m.loops)  # = maze_for
    start = int(rng.integers(maze.n_cells))
    return np.vstack([maze.centre_mm(start), corner_landmarks(maze, m.landmark_offset_mm)])


def _check_infrared_reach(params: Params, maze: Maze, landmarks_mm: np.ndarray) -> None:
    from kilonet.scenarios.neighbourhood import neighbourhood_mm

    limit = min(params.scenario.neighbour_max_mm, float(params.ranging.max_mm))
    reach = neighbourhood_mm(params.medium, limit)
    for cell in range(maze.n_cells):
        d = np.hypot(*(landmarks_mm - maze.centre_mm(cell)).T)
        if int((d <= reach).sum()) < 3:
            raise ParamError(
                f"maze.landmarks = infrared: cell {cell} is within {reach:.0f} mm (the reach of "
                "a median link, at most maze.neighbour_max_mm and ranging.max_mm) of only "
                f"{int((d <= reach).sum())} landmarks; use a smaller maze (maze.size, "
                "maze.cell_mm)"
            )


def _program(params: Params, positions: np.ndarray):
    m = params.scenario
    maze = maze_for(params)
    if len(positions) != 1 + len(_LANDMARKS):
        raise ParamError(
            f"the maze scenario needs 5 robots (maze robot, 4 landmarks), got {len(positions)}"
        )
    start = maze.cell_at(*positions[_ROBOT])
    if start is None or np.hypot(*(positions[_ROBOT] - maze.centre_mm(start))) > 1.0:
        raise ParamError("maze: robot 0 must start at a cell centre of the maze")
    landmarks_mm = positions[list(_LANDMARKS)]
    for k, mark in enumerate(landmarks_mm):
        near = np.hypot(*(np.array([maze.centre_mm(c) for c in range(maze.n_cells)]) - mark).T)
        if near.min() < ROBOT_DIAMETER_MM:
            raise ParamError(
                f"maze: landmark {k} at ({mark[0]:.0f}, {mark[1]:.0f}) mm stands in the way of "
                f"cell {int(near.argmin())}; landmarks belong outside the cells (raise "
                "maze.cell_mm or maze.landmark_offset_mm)"
            )
    if m.landmarks == "infrared":
        _check_infrared_reach(params, maze, landmarks_mm)

    def build(i: int):
        if i == _ROBOT:
            return MazeRobot(m, maze, landmarks_mm)
        position = (float(positions[i, 0]), float(positions[i, 1]))
        return LandmarkBeacon(i - 1, position, broadcast=m.landmarks == "infrared")

    return build


def _hardware(
    params: Params, _positions: np.ndarray
) -> dict[str, Callable[[Simulation, int], MazeBody | None]]:
    """The maze robot's camera, wall sensor and drive in the true maze (the landmarks carry
    none)."""
    m = params.scenario
    spec = MazeHardware(
        maze_for(params),
        RangeSensor(m.sigma_mm, m.camera_range_mm, m.dropout_prob),
        WallSensor(m.wall_p_open, m.wall_p_wall),
        landmark_robots=_LANDMARKS,
        slip_prob=m.slip_prob,
    )
    return fit_maze_hardware(spec, robots=[_ROBOT])


def _stop_when(sim: Simulation) -> bool:
    return sim.robots[_ROBOT].state is MazeStage.DONE or not sim.world.running[_ROBOT]


# -- metrics ----------------------------------------------------------------------------------
def _true_positions(sim: Simulation, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the maze robot stood at each time: its last recorded pose, else its start."""
    poses = sim.trace.poses_frame()
    poses = poses[poses["robot"] == _ROBOT]
    x0, y0 = sim.initial_positions_mm[_ROBOT]
    xs = np.concatenate([[x0], poses["x_mm"].to_numpy()])
    ys = np.concatenate([[y0], poses["y_mm"].to_numpy()])
    index = np.searchsorted(poses["t_s"].to_numpy(), times_s, side="right")
    return xs[index], ys[index]


def step_table(sim: Simulation) -> pd.DataFrame:
    """One row per step of the maze robot: its estimates beside the truth.

    Columns: ``t_s, step, command, heard, x_mm, y_mm, method, cell, visited, walls,
    belief_cell, belief_max, p_moved, p_stayed, seed_move, seed_stay`` (the robot's),
    ``true_x_mm, true_y_mm, true_cell`` (where it really stood), ``error_mm`` (fix vs truth)
    and ``belief_correct``.
    """
    import pandas as pd

    events = sim.trace.events_frame()
    events = events[(events["robot"] == _ROBOT) & (events["event"] == "step")]
    rows = [
        {"t_s": t, **json.loads(data)}
        for t, data in zip(events["t_s"], events["data"], strict=True)
    ]
    columns = [
        "t_s", "step", "command", "heard", "x_mm", "y_mm", "method", "cell", "visited",
        "walls", "belief_cell", "belief_max", "p_moved", "p_stayed", "seed_move", "seed_stay",
    ]  # fmt: skip
    frame = pd.DataFrame(rows, columns=columns)  # the grid drawing stays in the log
    xs, ys = _true_positions(sim, frame["t_s"].to_numpy())
    maze = maze_for(sim.params)
    frame["true_x_mm"] = xs
    frame["true_y_mm"] = ys
    frame["true_cell"] = [maze.cell_at(x, y) for x, y in zip(xs, ys, strict=True)]
    frame["x_mm"] = frame["x_mm"].astype(float)
    frame["y_mm"] = frame["y_mm"].astype(float)
    frame["error_mm"] = np.hypot(frame["x_mm"] - xs, frame["y_mm"] - ys)
    frame["belief_correct"] = frame["belief_cell"] == frame["true_cell"]
    return frame


def _metrics(sim: Simulation) -> dict[str, Any]:
    m = sim.params.scenario
    maze = maze_for(sim.params)
    steps = step_table(sim)
    seen: set[int] = set()
    steps_to_cover = None
    for step, cell in zip(steps["step"], steps["true_cell"], strict=True):
        seen.add(cell)
        if steps_to_cover is None and len(seen) == maze.n_cells:
            steps_to_cover = int(step)
    seen.add(maze.cell_at(*sim.initial_positions_mm[_ROBOT]))
    seen.add(maze.cell_at(*sim.world.positions_mm[_ROBOT]))  # a move the run ended after
    fixes = steps["error_mm"].dropna()
    settled = steps[steps["step"] > m.burn_in_steps]
    events = sim.trace.events_frame()
    mine = events[events["robot"] == _ROBOT]["event"]
    return {
        "cells": maze.n_cells,
        "cells_visited": len(seen),
        "steps_to_cover": steps_to_cover,
        "planner": m.planner,
        "landmarks": m.landmarks,
        "steps": int(steps["step"].max()) if len(steps) else 0,
        "robot_reports_covered": bool((mine == "covered").any()),
        "steps_without_fix": int(steps["x_mm"].isna().sum()),
        "trilateration_rmse_mm": float(np.sqrt(np.mean(fixes**2))) if len(fixes) else None,
        "belief_correct_fraction": float(settled["belief_correct"].mean())
        if len(settled)
        else None,
    }


# -- outputs ----------------------------------------------------------------------------------
def _verbose_log(sim: Simulation) -> str:
    events = sim.trace.events_frame()
    events = events[events["robot"] == _ROBOT]
    lines = []
    for t, name, data in zip(events["t_s"], events["event"], events["data"], strict=True):
        d = json.loads(data)
        if name == "step":
            where = (
                f"trilaterated ({d['x_mm']:.1f}, {d['y_mm']:.1f}) mm [{d['method']}, "
                f"{d['heard']} landmarks]"
                if d["x_mm"] is not None
                else f"no fix ({d['heard']} landmarks)"
            )
            lines += [
                f"t = {t:.1f} s  step {d['step']}  after move {d['command'] or '-'}: {where} "
                f"-> cell {d['cell']}; walls sensed [{d['walls']}]",
                f"  move p = {d['p_moved']:.4f}  stay p = {d['p_stayed']:.4f}  "
                f"belief max {d['belief_max']:.3f} at cell {d['belief_cell']}",
            ]
            if d.get("seed_move") is not None:
                lines.append(
                    f"  from the believed cell: move 0.8-branch {d['seed_move']:.6f}, "
                    f"stay branch {d['seed_stay']:.6f} (unnormalised, as the seed prints them)"
                )
            lines += [d["grid"], ""]
        elif name == "few_landmarks":
            lines.append(
                f"t = {t:.1f} s  step {d['step']}: heard {d['heard']} landmarks, fewer than three"
            )
        else:
            lines.append(f"t = {t:.1f} s  {name}: {d}")
    return "\n".join(lines) + "\n"


def _draw_maze(ax: Any, maze: Maze) -> None:
    c = maze.cell_mm
    for cell in range(maze.n_cells):
        x0, y0 = maze.centre_mm(cell) - c / 2
        w, n, e, s = maze.walls_of(cell)
        segments = [
            (w, [x0, x0], [y0, y0 + c]),
            (n, [x0, x0 + c], [y0 + c, y0 + c]),
            (e, [x0 + c, x0 + c], [y0, y0 + c]),
            (s, [x0, x0 + c], [y0, y0]),
        ]
        for wall, xs, ys in segments:
            if wall:
                ax.plot(xs, ys, color="k", lw=2.5, solid_capstyle="round")
        ax.text(x0 + 4, y0 + c - 4, str(cell), fontsize=7, va="top", color="0.5")


def _figures(result: RunResult, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sim = result.sim
    maze = maze_for(result.params)
    steps = step_table(sim)
    steps.to_csv(out_dir / "maze_steps.csv", index=False)
    (out_dir / "maze_log.txt").write_text(_verbose_log(sim))

    fig, ax = plt.subplots(figsize=(6, 6))
    _draw_maze(ax, maze)
    poses = sim.trace.poses_frame()
    poses = poses[poses["robot"] == _ROBOT]
    start = sim.initial_positions_mm[_ROBOT]
    path = np.vstack([start, poses[["x_mm", "y_mm"]].to_numpy()])
    ax.plot(path[:, 0], path[:, 1], color="tab:blue", lw=1.5, alpha=0.6, label="true path")
    ax.plot(*start, "o", color="tab:blue", ms=10, label="start")
    ax.scatter(steps["x_mm"], steps["y_mm"], s=12, color="tab:orange", label="trilaterated")
    for k, i in enumerate(_LANDMARKS):
        ax.scatter(
            *sim.initial_positions_mm[i],
            s=150,
            color=np.array(LANDMARK_COLORS[k]) / 3,
            edgecolors="k",
            zorder=3,
        )
    s = result.summary
    ax.set_title(
        f"maze {maze.cols}x{maze.rows}, planner {s['planner']}: {s['cells_visited']}/{s['cells']} "
        f"cells, steps to cover {s['steps_to_cover']}"
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, fontsize=8)
    fig.tight_layout()
    fig.savefig(out_dir / "maze_path.png", dpi=100)
    plt.close(fig)

    history = np.array(sim.robots[_ROBOT].belief_history).reshape(-1, maze.n_cells)
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    if len(history):
        image = top.imshow(
            history.T, aspect="auto", origin="lower", cmap="magma", vmin=0, vmax=1,
            extent=(-0.5, len(history) - 0.5, -0.5, maze.n_cells - 0.5),
        )  # fmt: skip
        fig.colorbar(image, ax=top, label="belief")
        top.plot(steps["step"], steps["true_cell"], "c.", ms=6, label="true cell")
        top.legend(loc="upper right", fontsize=8)
        true_belief = history[np.arange(len(steps)), steps["true_cell"].to_numpy()]
        bottom.plot(steps["step"], true_belief, label="belief on the true cell")
        bottom.plot(steps["step"], steps["belief_max"], "--", label="largest belief")
        bottom.scatter(
            steps["step"][~steps["belief_correct"]],
            true_belief[~steps["belief_correct"].to_numpy()],
            color="red",
            zorder=3,
            label="max is not the true cell",
        )
        bottom.legend(loc="lower right", fontsize=8)
    top.set_ylabel("cell")
    bottom.set_ylabel("probability")
    bottom.set_xlabel("step")
    bottom.set_ylim(0, 1.02)
    top.set_title("belief over cells per step")
    fig.tight_layout()
    fig.savefig(out_dir / "maze_belief.png", dpi=100)
    plt.close(fig)


SCENARIO = Scenario(
    name="maze",
    summary="a robot trilaterates, covers a grid maze and localizes from walls (lab seed)",
    setup=Setup(
        program=_program,
        hardware=_hardware,
        section=MazeParams,
        robots=1 + len(_LANDMARKS),
        defaults={"duration_s": 20_000.0},
        supports={"robot.rx_distance": ("estimate",)},
        placement=_placement,
        stop_when=_stop_when,
    ),
    reporting=Reporting(
        metrics=_metrics,
        ends_when="the robot covers the maze or gives up",
    ),
    drawing=Drawing(
        figures=_figures,
    ),
)


# -- studies ----------------------------------------------------------------------------------
def coverage_study(
    runs: int = 50,
    planners: Sequence[str] = ("bfs", "random"),
    *,
    seed: int = 1,
    overrides: dict[str, Any] | None = None,
) -> pd.DataFrame:
    """Run every planner in the same ``runs`` random mazes (seeds ``seed … seed + runs − 1``).

    Returns one row per run: ``planner, seed, cells, cells_visited, steps_to_cover, covered,
    sim_time_s``.
    """
    import pandas as pd

    rows = []
    for planner in planners:
        for s in range(seed, seed + runs):
            summary = run(SCENARIO, {**(overrides or {}), "maze.planner": planner}, seed=s).summary
            rows.append(
                {
                    "planner": planner,
                    "seed": s,
                    "cells": summary["cells"],
                    "cells_visited": summary["cells_visited"],
                    "steps_to_cover": summary["steps_to_cover"],
                    "covered": summary["steps_to_cover"] is not None,
                    "sim_time_s": summary["sim_time_s"],
                }
            )
    return pd.DataFrame(rows)


def coverage_table(study: pd.DataFrame) -> pd.DataFrame:
    """Per planner: runs, runs that covered every cell, and mean / median / max steps to cover
    (over the covering runs)."""
    import pandas as pd

    grouped = study.groupby("planner", sort=False)
    return pd.DataFrame(
        {
            "runs": grouped.size(),
            "covered_all": grouped["covered"].sum(),
            "mean_steps": grouped["steps_to_cover"].mean(),
            "median_steps": grouped["steps_to_cover"].median(),
            "max_steps": grouped["steps_to_cover"].max(),
            "mean_sim_time_s": grouped["sim_time_s"].mean(),
        }
    )


#: Wall-sensor tables ``(p(z=0|s=0), p(z=1|s=1))`` from nearly exact to very noisy; the third
#: is the scenario's default.
DEFAULT_NOISE_TABLES = (
    (0.95, 0.95),
    (0.9, 0.9),
    (0.7, 0.95),
    (0.7, 0.9),
    (0.8, 0.8),
    (0.7, 0.7),
    (0.6, 0.6),
)


def belief_accuracy_by_noise(
    tables: Sequence[tuple[float, float]] = DEFAULT_NOISE_TABLES,
    runs: int = 50,
    *,
    seed: int = 1,
    overrides: dict[str, Any] | None = None,
) -> tuple[pd.DataFrame, Figure]:
    """Probability that the belief's maximum is the true cell, per step, for each wall-sensor
    table (the sensor's true table, which the filter assumes too unless ``overrides`` set
    ``maze.filter_p_open`` or ``maze.filter_p_wall``).

    Every table runs in the same ``runs`` random mazes (seeds ``seed … seed + runs − 1``).

    Returns
    -------
    frame : DataFrame
        One row per table and step: ``p_open, p_wall, step, runs`` (runs that reached the
        step), ``p_correct`` (share of them whose belief's maximum was the true cell).
    figure : matplotlib Figure
        ``p_correct`` against step, one line per table, for the steps at least half the runs
        reached.
    """
    import matplotlib
    import pandas as pd

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parts = []
    for p_open, p_wall in tables:
        for s in range(seed, seed + runs):
            values = {**(overrides or {}), "maze.wall_p_open": p_open, "maze.wall_p_wall": p_wall}
            steps = step_table(run(SCENARIO, values, seed=s).sim)
            parts.append(
                pd.DataFrame(
                    {
                        "p_open": p_open,
                        "p_wall": p_wall,
                        "seed": s,
                        "step": steps["step"],
                        "correct": steps["belief_correct"].astype(float),
                    }
                )
            )
    frame = (
        pd.concat(parts)
        .groupby(["p_open", "p_wall", "step"], sort=False)["correct"]
        .agg(runs="count", p_correct="mean")
        .reset_index()
    )
    fig, ax = plt.subplots(figsize=(7, 4))
    for (p_open, p_wall), part in frame.groupby(["p_open", "p_wall"], sort=False):
        part = part[part["runs"] >= max(1, runs // 2)]  # later steps: too few runs to show
        label = f"p(z=0|s=0) {p_open}, p(z=1|s=1) {p_wall}"
        ax.plot(part["step"], part["p_correct"], marker=".", label=label)
    ax.set_xlabel("step")
    ax.set_ylabel("P(belief max = true cell)")
    ax.set_ylim(0, 1.02)
    ax.set_title(f"wall-based localization vs sensor noise ({runs} mazes per table)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return frame, fig


def belief_accuracy_summary(frame: pd.DataFrame, burn_in_steps: int = 5) -> pd.DataFrame:
    """Per table: the share of (run, step) pairs after the first ``burn_in_steps`` steps whose
    belief's maximum was the true cell, from :func:`belief_accuracy_by_noise`'s frame."""
    late = frame[frame["step"] > burn_in_steps].assign(hits=lambda f: f["p_correct"] * f["runs"])
    grouped = late.groupby(["p_open", "p_wall"], sort=False)[["hits", "runs"]].sum()
    return (grouped["hits"] / grouped["runs"]).rename("p_correct_after_burn_in").reset_index()
