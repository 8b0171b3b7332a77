"""Maze world, its sensors and drive, the maze robot's math, and the ``maze`` scenario."""

from __future__ import annotations

import json

import matplotlib.figure
import networkx as nx
import numpy as np
import pytest

from kilonet.params import ParamError, Params
from kilonet.protocols.common.geometry import GeometryError, trilaterate_linear
from kilonet.protocols.maze.hardware import (
    DIRECTIONS,
    Maze,
    MazeError,
    MazeKilobot,
    RangeSensor,
    WallSensor,
    generate_maze,
    parse_size,
)
from kilonet.protocols.maze.program import (
    bayes_step,
    locate,
    nearest_unvisited,
    predict,
    wall_likelihood,
)
from kilonet.scenarios.base import build_params, place, run, write_outputs
from kilonet.scenarios.maze import (
    SCENARIO,
    MazeParams,
    belief_accuracy_by_noise,
    belief_accuracy_summary,
    coverage_study,
    coverage_table,
    maze_for,
    step_table,
)
from kilonet.scenarios.maze_hardware import MazeHardware, fit_maze_hardware
from kilonet.simulation import Simulation

TWO_CELLS = """
+---+---+
|       |
+---+---+
"""

SQUARE = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 400.0], [0.0, 400.0]])


# -- the maze world -----------------------------------------------------------------------------
def test_maze_from_text_walls_neighbours_and_render_round_trip():
    text = """
+---+---+---+
| 0   1 | 2 |
+   +---+   +
| 3   4   5 |
+---+---+---+
"""
    maze = Maze.from_text(text, cell_mm=50.0)
    assert (maze.cols, maze.rows, maze.n_cells) == (3, 2, 6)
    assert maze.walls_of(1) == (False, True, True, True)
    assert maze.walls_of(2) == (True, True, True, False)
    assert maze.neighbour(0, "S") == 3 and maze.neighbour(1, "E") == 1
    assert maze.open_directions(4) == ["W", "E"]
    assert maze.direction_to(5, 2) == "N"
    assert maze.centre_mm(0).tolist() == [25.0, 75.0]
    assert maze.cell_at(149.9, 0.0) == 5 and maze.cell_at(150.1, 10.0) is None
    assert maze.nearest_cell(-30.0, 500.0) == 0
    assert set(maze.graph().edges) == {(0, 1), (0, 3), (3, 4), (4, 5), (2, 5)}
    assert Maze.from_text(maze.render()).walls.tolist() == maze.walls.tolist()
    assert maze.render({0, 4}).splitlines()[1] == "| X     |   |"


def test_maze_rejects_inconsistent_walls():
    walls = Maze.from_text(TWO_CELLS).walls.copy()
    walls[0, 2] = True  # cell 0 walls its east side, cell 1 its west side does not
    with pytest.raises(MazeError, match="disagree"):
        Maze(2, 1, walls)
    walls = Maze.from_text(TWO_CELLS).walls.copy()
    walls[0, 0] = False
    with pytest.raises(MazeError, match="boundary"):
        Maze(2, 1, walls)
    with pytest.raises(MazeError, match="direction"):
        Maze.from_text(TWO_CELLS).neighbour(0, "up")


@pytest.mark.parametrize("text", ["4", "4x", "0x3", "axb", "4x4x4"])
def test_parse_size_rejects(text):
    with pytest.raises(MazeError, match="WIDTHxHEIGHT"):
        parse_size(text)


@pytest.mark.parametrize("cols, rows", [(1, 1), (4, 4), (7, 3), (10, 10)])
def test_generated_perfect_mazes_are_spanning_trees(cols, rows):
    for seed in range(5):
        g = generate_maze(cols, rows, np.random.default_rng(seed)).graph()
        assert nx.is_tree(g) and g.number_of_nodes() == cols * rows


def test_loops_remove_walls_and_keep_every_cell_reachable():
    perfect = generate_maze(6, 6, np.random.default_rng(3))
    loopy = generate_maze(6, 6, np.random.default_rng(3), loops=0.5)
    assert loopy.graph().number_of_edges() > perfect.graph().number_of_edges()
    assert nx.is_connected(loopy.graph())
    # same draws, then walls removed: the perfect maze's openings stay open
    assert set(perfect.graph().edges) <= set(loopy.graph().edges)


# -- sensors -----------------------------------------------------------------------------------
def test_range_sensor_noise_dropouts_and_range():
    rng = np.random.default_rng(0)
    sensor = RangeSensor(sigma_mm=5.0, range_mm=300.0, dropout_prob=0.25)
    landmarks = np.array([[100.0, 0.0], [0.0, 200.0], [400.0, 0.0]])
    scans = np.array([sensor.read(np.zeros(2), landmarks, rng) for _ in range(4000)])
    assert np.isnan(scans[:, 2]).all()  # beyond range
    seen = scans[:, :2]
    assert abs(np.isnan(seen).mean() - 0.25) < 0.02
    assert abs(np.nanmean(seen[:, 0]) - 100.0) < 0.3
    assert abs(np.nanstd(seen[:, 1]) - 5.0) < 0.2


def test_wall_sensor_follows_its_table():
    rng = np.random.default_rng(1)
    sensor = WallSensor(p_open=0.7, p_wall=0.9)
    readings = np.array([sensor.read((True, False, True, False), rng) for _ in range(5000)])
    assert abs(readings[:, [0, 2]].mean() - 0.9) < 0.015  # p(z=1 | s=1)
    assert abs(1 - readings[:, [1, 3]].mean() - 0.7) < 0.015  # p(z=0 | s=0)


# -- the drive: walls stop it, moves take the Kilobot's time ------------------------------------
class _Bumper(MazeKilobot):
    """Drives west into the boundary wall, then east into the neighbouring cell."""

    def setup(self):
        self.plan = ["W", "E"]
        self.done_at = []

    def loop(self):
        if not self.driving and self.plan:
            if self.done_at or self.kilo_ticks > 0:
                self.done_at.append(self.kilo_ticks / self.ticks_per_s)
            self.drive(self.plan.pop(0))


class _Still(MazeKilobot):
    pass


def _drive_sim(slip_prob=0.0, other_mm=(-100.0, 0.0)):
    maze = Maze.from_text(TWO_CELLS, cell_mm=100.0)
    hardware = MazeHardware(maze, landmark_robots=(1,), slip_prob=slip_prob)
    params = Params(seed=2, duration_s=60.0).with_overrides(
        {"motion.speed_error": 0, "motion.turn_error": 0, "battery.enabled": "false"}
    )
    sim = Simulation(
        [[50.0, 50.0], list(other_mm)],
        lambda i: _Bumper() if i == 0 else _Still(),
        params,
        headings_rad=[np.pi, 0.0],  # facing west: the first move needs no turn
        hardware=fit_maze_hardware(hardware),
    )
    sim.run()
    return sim


def test_drive_stops_at_walls_and_takes_turn_plus_straight_time():
    sim = _drive_sim()
    assert sim.world.positions_mm[0].tolist() == [150.0, 50.0]
    poses = sim.trace.poses_frame()
    poses = poses[poses["robot"] == 0]
    # move W: no turn, 100 mm at 10 mm/s, bumps and stays; move E: 180° at 45°/s, then 10 s
    t = poses["t_s"].to_numpy()
    assert t[1] - t[0] == pytest.approx(0.0)
    assert t[2] - t[1] == pytest.approx(10.0)
    assert poses["x_mm"].iloc[2] == 50.0
    assert t[4] - t[3] == pytest.approx(4.0)
    assert t[5] - t[4] == pytest.approx(10.0)
    assert poses["x_mm"].iloc[5] == 150.0


def test_drive_slips_leave_the_robot_in_place():
    sim = _drive_sim(slip_prob=1.0)
    assert sim.world.positions_mm[0].tolist() == [50.0, 50.0]


def test_drive_never_moves_a_robot_onto_another():
    sim = _drive_sim(other_mm=(150.0, 50.0))  # a robot in the next cell blocks the move E
    assert sim.world.positions_mm[0].tolist() == [50.0, 50.0]


# -- trilateration -------------------------------------------------------------------------------
def test_linear_trilateration_matches_hand_computed_values():
    # Landmarks (0,0), (400,0), (0,400); ranges 150, 300, 320 mm:
    # A = 800, B = 0, C = 150² − 300² + 400² = 92500, D = −800, E = 800,
    # F = 300² − 320² − 400² + 400² = −12400;
    # x = (CE − FB)/(EA − BD) = 74 000 000 / 640 000 = 115.625,
    # y = (CD − AF)/(BD − AE) = (−74 000 000 + 9 920 000)/(−640 000) = 100.125.
    anchors = np.array([[0.0, 0.0], [400.0, 0.0], [0.0, 400.0]])
    assert trilaterate_linear(anchors, [150.0, 300.0, 320.0]) == (115.625, 100.125)
    # The robot's locate() uses the same formula when it has exactly three landmarks...
    corners = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 400.0], [0.0, 400.0]])
    fix = locate(corners[[0, 1, 3]], [150.0, 300.0, 320.0])
    assert (fix.x_mm, fix.y_mm, fix.method) == (115.625, 100.125, "linear")
    # ...and ignores the fourth with fit = "linear", as the seed ignores its yellow cylinder.
    ranges = [np.hypot(100, 300), np.hypot(300, 300), np.hypot(300, 100), 1.0]  # NW: garbage
    fix = locate(corners, ranges, "linear")
    assert (round(fix.x_mm, 9), round(fix.y_mm, 9), fix.landmarks) == (100.0, 300.0, 3)


def test_least_squares_beats_the_three_landmark_formula_with_noise():
    rng = np.random.default_rng(4)
    linear_err, lsq_err = [], []
    for _ in range(200):
        truth = rng.uniform(50, 350, 2)
        ranges = np.hypot(*(SQUARE - truth).T) + rng.normal(0, 10.0, 4)
        linear = locate(SQUARE, ranges, "linear")
        lsq = locate(SQUARE, ranges, "lsq")
        assert lsq.method == "lsq" and lsq.landmarks == 4
        linear_err.append(np.hypot(linear.x_mm - truth[0], linear.y_mm - truth[1]))
        lsq_err.append(np.hypot(lsq.x_mm - truth[0], lsq.y_mm - truth[1]))
    assert np.sqrt(np.mean(np.square(lsq_err))) < 0.8 * np.sqrt(np.mean(np.square(linear_err)))


def test_degenerate_landmarks_are_reported():
    line = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 0.0], [300.0, 0.0]])
    with pytest.raises(GeometryError, match="collinear"):
        locate(line, [50.0, 60.0, 150.0, 250.0])
    with pytest.raises(GeometryError, match="collinear"):
        locate(line, [50.0, 60.0, 150.0, np.nan])
    assert locate(SQUARE, [10.0, np.nan, np.nan, 20.0]) is None


# -- the Bayes filter ---------------------------------------------------------------------------
def test_one_bayes_update_matches_a_hand_computed_posterior():
    # Two cells in a row: cell 0 walled W, N, S; cell 1 walled N, E, S. Prior (0.5, 0.5); the
    # robot commands E and then reads (W, N, E, S) = (no wall, wall, wall, wall).
    maze = Maze.from_text(TWO_CELLS)
    # p(z | cell 0) = p(z=0|s=1)·p(z=1|s=1)·p(z=1|s=0)·p(z=1|s=1) = 0.1·0.9·0.3·0.9 = 0.0243
    # p(z | cell 1) = p(z=0|s=0)·0.9·0.9·0.9 = 0.7·0.729 = 0.5103
    # predicted: move 0→1 with 0.8·0.5 = 0.4; stay in 0 with 0.2·0.5 = 0.1; cell 1 has a wall to
    # the east, so it stays with 1·0.5 = 0.5.
    # move branch: 0.4·0.5103 = 0.20412; stay branch: 0.1·0.0243 + 0.5·0.5103 = 0.25758;
    # normaliser 0.4617.
    reading = (False, True, True, True)
    assert wall_likelihood(maze.walls, reading, 0.7, 0.9).tolist() == [0.0243, 0.5103]
    assert predict(np.array([0.5, 0.5]), maze.neighbours, "E", 0.8) == pytest.approx([0.1, 0.9])
    step = bayes_step(np.array([0.5, 0.5]), maze, "E", reading, p_move=0.8, p_open=0.7, p_wall=0.9)
    assert step.belief == pytest.approx([0.00243 / 0.4617, 0.45927 / 0.4617], abs=1e-12)
    assert step.p_moved == pytest.approx(0.20412 / 0.4617, abs=1e-12)
    assert step.p_stayed == pytest.approx(0.25758 / 0.4617, abs=1e-12)


def test_bayes_step_without_a_move_is_the_correction_alone():
    maze = Maze.from_text(TWO_CELLS)
    step = bayes_step(np.array([0.5, 0.5]), maze, None, (True, True, False, True), p_wall=0.9)
    # p(z | cell 0) = 0.9·0.9·0.7·0.9 = 0.5103; p(z | cell 1) = 0.3·0.9·0.1·0.9 = 0.0243
    assert step.belief == pytest.approx([0.5103 / 0.5346, 0.0243 / 0.5346])
    assert (step.p_moved, step.p_stayed) == (0.0, 1.0)


def test_impossible_reading_under_a_perfect_sensor_model_raises():
    maze = Maze.from_text(TWO_CELLS)
    with pytest.raises(ValueError, match="impossible"):
        bayes_step(np.array([0.5, 0.5]), maze, None, (False,) * 4, p_open=1.0, p_wall=1.0)


def test_nearest_unvisited_is_breadth_first():
    maze = Maze.from_text(
        """
+---+---+---+
|           |
+   +---+---+
|           |
+---+---+---+
"""
    )
    g = maze.graph()
    assert nearest_unvisited(g, 0, {0}) == [0, 1]  # ties: lowest cell (1 and 3 are one away)
    assert nearest_unvisited(g, 2, {0, 1, 2, 3}) == [2, 1, 0, 3, 4]
    assert nearest_unvisited(g, 2, set(range(6))) is None


# -- the scenario -------------------------------------------------------------------------------
def test_default_run_covers_trilaterates_and_localizes(tmp_path):
    result = run(SCENARIO, seed=3)
    s = result.summary
    assert s["cells"] == s["cells_visited"] == 16
    assert s["planner"] == "bfs" and s["robot_reports_covered"]
    assert 15 <= s["steps_to_cover"] <= s["steps"]
    assert 2.0 < s["trilateration_rmse_mm"] < 15.0  # camera sigma 5 mm
    assert s["belief_correct_fraction"] >= 0.8
    steps = step_table(result.sim)
    assert steps["step"].tolist() == list(range(len(steps)))
    assert (steps["true_cell"] == steps["cell"]).all()  # 5 mm noise never misplaces a cell
    assert np.allclose(steps["p_moved"] + steps["p_stayed"], 1.0)
    written = {p.name for p in write_outputs(result, tmp_path / "run")}
    assert {"summary.json", "maze_steps.csv", "maze_log.txt", "maze_path.png"} <= written
    assert "maze_belief.png" in written
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    for key in ("cells", "cells_visited", "steps_to_cover", "planner", "trilateration_rmse_mm"):
        assert key in summary
    log = (tmp_path / "run" / "maze_log.txt").read_text()
    assert "move p = " in log and "stay p = " in log
    lines = log.splitlines()
    end = next(i for i, line in enumerate(lines) if "covered:" in line)
    last_grid = lines[end - 10 : end - 1]  # 4x4 cells: 9 lines, then a blank line
    assert last_grid[0].startswith("+---") and last_grid[-1].startswith("+---")
    assert sum(line.count("X") for line in last_grid) == 16


def test_runs_are_reproducible_and_mazes_differ_by_seed():
    a = run(SCENARIO, {"maze.size": "3x3"}, seed=5).summary
    b = run(SCENARIO, {"maze.size": "3x3"}, seed=5).summary
    assert {k: v for k, v in a.items() if k != "wall_time_s"} == {
        k: v for k, v in b.items() if k != "wall_time_s"
    }
    one, two = (maze_for(build_params(SCENARIO, seed=seed)) for seed in (1, 2))
    assert one.walls.tolist() != two.walls.tolist()


def test_infrared_beacons_on_the_medium():
    small = {"maze.landmarks": "infrared", "maze.size": "2x2", "maze.cell_mm": 50.0}
    s = run(SCENARIO, small, seed=2).summary
    assert s["messages_sent"] > 0 and s["receptions_delivered"] > 0
    assert s["cells_visited"] == 4 and s["steps_without_fix"] == 0
    # Each beacon's median estimate carries its link's systematic error (a few mm at 35-80 mm,
    # kilonet.reception) and whole-mm rounding: fixes from three of them stay within 5 mm.
    assert s["trilateration_rmse_mm"] < 5.0


def test_infrared_robot_says_when_it_hears_fewer_than_three():
    lossy = {
        "maze.landmarks": "infrared",
        "maze.size": "2x2",
        "maze.cell_mm": 50.0,
        "medium.loss_prob": 0.9,
        "maze.listen_s": 0.3,
    }
    result = run(SCENARIO, lossy, seed=1)
    events = result.sim.trace.events_frame()
    few = events[events["event"] == "few_landmarks"]
    assert len(few) > 0
    assert all(json.loads(d)["heard"] < 3 for d in few["data"])
    assert result.summary["steps_without_fix"] == len(few)


def test_infrared_maze_too_large_for_the_medium_is_a_user_error():
    with pytest.raises(ParamError, match=r"of only [012] landmarks"):
        run(SCENARIO, {"maze.landmarks": "infrared"}, seed=1)


@pytest.mark.parametrize(
    "overrides, message",
    [
        ({"maze.size": "4by4"}, "WIDTHxHEIGHT"),
        ({"maze.planner": "astar"}, "not one of"),
        ({"placement.robots": 3}, "5 robots"),
        ({"maze.cell_mm": 40.0}, "landmark 0 at \\(0, 0\\) mm stands in the way of cell 12"),
    ],
)
def test_bad_settings_are_one_line_user_errors(overrides, message):
    with pytest.raises(ParamError, match=message):
        run(SCENARIO, overrides, seed=1)


def test_slipping_robot_stays_and_gives_up_at_the_step_limit():
    s = run(SCENARIO, {"maze.slip_prob": 1.0, "maze.max_steps": 6}, seed=1).summary
    assert s["cells_visited"] == 1 and s["steps"] == 6 and not s["robot_reports_covered"]
    assert s["steps_to_cover"] is None


def test_navigating_by_belief_alone_covers_a_loopy_maze():
    s = run(SCENARIO, {"maze.navigate_by": "belief", "maze.loops": 0.3}, seed=4).summary
    assert s["cells_visited"] == 16 and s["robot_reports_covered"]
    assert s["belief_correct_fraction"] > 0.7


# -- the studies (fast versions; the full ones are marked slow) ---------------------------------
def test_planner_covers_every_maze_and_beats_the_random_walk_fast():
    study = coverage_study(4, overrides={"maze.size": "3x3"})
    table = coverage_table(study)
    assert table.loc["bfs", "covered_all"] == 4
    assert table.loc["bfs", "max_steps"] <= 2 * 8  # a depth-first tour of 9 cells: ≤ 2·(9 − 1)
    assert table.loc["bfs", "mean_steps"] < table.loc["random", "mean_steps"]


#: The default tier's twins run 1 maze (a study of 4×4 mazes costs about 2.5 s of CPU a maze,
#: most of it the random walk's) and 10 runs of the belief filter.
@pytest.mark.parametrize("mazes", [pytest.param(50, marks=pytest.mark.slow), 1])
def test_planner_covers_all_cells_in_random_mazes(mazes):
    study = coverage_study(mazes)
    table = coverage_table(study)
    assert table.loc["bfs", "covered_all"] == mazes
    assert (study.loc[study["planner"] == "bfs", "cells_visited"] == 16).all()
    assert table.loc["bfs", "mean_steps"] < 0.3 * table.loc["random", "mean_steps"]


def test_belief_accuracy_by_noise_fast():
    frame, fig = belief_accuracy_by_noise(((0.95, 0.95), (0.6, 0.6)), runs=4)
    assert isinstance(fig, matplotlib.figure.Figure)
    assert list(frame.columns) == ["p_open", "p_wall", "step", "runs", "p_correct"]
    assert frame["p_correct"].between(0, 1).all() and (frame["runs"] <= 4).all()
    summary = belief_accuracy_summary(frame).set_index(["p_open", "p_wall"])
    accurate = summary.loc[(0.95, 0.95), "p_correct_after_burn_in"]
    noisy = summary.loc[(0.6, 0.6), "p_correct_after_burn_in"]
    assert accurate > 0.9 and noisy < accurate


@pytest.mark.parametrize("runs", [pytest.param(50, marks=pytest.mark.slow), 10])
def test_default_sensor_model_localizes_in_90_percent_of_steps_after_the_first_five(runs):
    default = MazeParams()
    assert default.wall_p_open == 0.7  # the seed's p(z=0 | s=0)
    assert default.filter_table == (default.wall_p_open, default.wall_p_wall)
    frame, _fig = belief_accuracy_by_noise(((default.wall_p_open, default.wall_p_wall),), runs=runs)
    assert frame.loc[frame["step"] == 0, "runs"].item() == runs
    summary = belief_accuracy_summary(frame, burn_in_steps=5)
    assert summary["p_correct_after_burn_in"].item() >= 0.9


def test_the_filter_can_assume_another_wall_sensor_than_the_true_one():
    base = {"maze.size": "3x3", "maze.wall_p_open": 0.6}
    mismatch = {**base, "maze.filter_p_open": 0.9}
    params = build_params(SCENARIO, mismatch, seed=3)
    positions = place(SCENARIO, params)
    sim = Simulation(
        positions,
        SCENARIO.setup.program(params, positions),
        params,
        hardware=SCENARIO.setup.hardware(params, positions),
    )
    robot = sim.robots[0]
    assert robot.hardware("maze").spec.wall_sensor == WallSensor(p_open=0.6, p_wall=0.95)
    assert robot.params.filter_table == (0.9, 0.95)  # what the filter assumes
    same = step_table(run(SCENARIO, base, seed=3).sim)
    other = step_table(run(SCENARIO, mismatch, seed=3).sim)
    # Same maze, same path (it navigates by landmarks), same sensor draws: the walls read are
    # the same, the filter weighs them differently.
    assert len(same) == len(other) > 5
    assert same["walls"].tolist() == other["walls"].tolist()
    assert same["p_moved"].tolist() != other["p_moved"].tolist()
    # By default the filter assumes the true table.
    assert build_params(SCENARIO, base).scenario.filter_table == (0.6, 0.95)


def test_directions_are_the_seeds_order():
    assert DIRECTIONS == ("W", "N", "E", "S")


def test_cli_run_writes_the_summary_and_figures(tmp_path, capsys):
    from kilonet.app.cli import main

    out = tmp_path / "run"
    assert main(["run", "maze", "--set", "maze.size=3x3", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["cells"] == summary["cells_visited"] == 9
    assert json.loads((out / "summary.json").read_text()) == summary
    assert (out / "maze_path.png").exists() and (out / "maze_belief.png").exists()
    assert main(["run", "maze", "--set", "maze.size=4by4", "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "maze.size" in err and not (tmp_path / "bad").exists()
