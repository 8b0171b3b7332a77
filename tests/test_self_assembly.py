"""The self-assembly scenario: shapes from files, what a wrong one says, a robot that loses its
neighbours, and a small swarm that assembles (values against ground truth)."""

from __future__ import annotations

import numpy as np
import pytest

import kilonet.app.cli
from kilonet import scenarios
from kilonet.protocols.self_assembly.program import (
    ASSEMBLY,
    LOST_AFTER_S,
    AssemblyStage,
    SelfAssembly,
)
from kilonet.scenarios.self_assembly import (
    SEEDS,
    ShapeError,
    iou,
    load_shape,
    read_bitmap,
    shipped_shapes,
)
from kilonet.testing import ScriptedWorld


def _kilonet(argv: list[str], capsys) -> tuple[int, str]:
    status = kilonet.app.cli.main(argv)
    return status, capsys.readouterr().err


def _one_line(err: str) -> str:
    assert err.startswith("kilonet: error: "), err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.removeprefix("kilonet: error: ").rstrip("\n")


# -- shapes ------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["square", "starfish", "k"])
@pytest.mark.parametrize("cell_mm", [40.0, 80.0])
def test_the_shipped_shapes_hold_the_seeds_at_any_scale(name, cell_mm):
    shape = load_shape(name, cell_mm)
    assert all(shape.contains(x, y) for x, y in SEEDS)
    assert shape.cell_mm == cell_mm and shape.mask.sum() >= 4


def test_the_paper_shapes_are_shipped():
    assert {"starfish", "k", "square"} <= set(shipped_shapes())


def test_a_png_shape_is_its_dark_pixels(tmp_path):
    import matplotlib.pyplot as plt

    mask = read_bitmap("##..\n####\n####\n", "inline")
    picture = np.where(np.pad(mask, 2)[..., None], 0.0, 1.0) * np.ones(3)  # white margin
    plt.imsave(tmp_path / "shape.png", picture)
    shape = load_shape(str(tmp_path / "shape.png"), 40.0)
    assert shape.mask.tolist() == mask.tolist()


def test_a_bitmap_with_a_stray_character_is_refused_naming_file_line_and_column(tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text("; comment\n####\n##x#\n")
    with pytest.raises(ShapeError, match=r"bad\.txt:3:3: 'x' is not a bitmap cell"):
        load_shape(str(path), 40.0)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("....\n....\n", "no cell of the shape is inside"),
        ("....####\n....####\n", r"seed robot\(s\) \[0, 1, 2, 3\] at .* lie outside the shape"),
    ],
)
def test_a_shape_without_cells_or_without_the_seeds_is_refused(tmp_path, content, message):
    path = tmp_path / "s.txt"
    path.write_text(content)
    with pytest.raises(ShapeError, match=message):
        load_shape(str(path), 40.0)


@pytest.mark.parametrize(
    ("shape", "expected"),
    [
        ("nowhere.txt", "nowhere.txt: no such shape file"),
        ("nowhere.png", "nowhere.png: no such shape file"),
        (
            "circle",
            "self_assembly.shape = 'circle': not a shipped shape (k, square, starfish) "
            "nor a .txt or .png file",
        ),
    ],
)
def test_the_command_line_refuses_a_missing_shape_in_one_line_and_writes_nothing(
    tmp_path, capsys, shape, expected
):
    out = tmp_path / "out"
    argv = ["run", "self-assembly", "--duration", "1", "--set", f"self_assembly.shape={shape}"]
    status, err = _kilonet([*argv, "--out", str(out)], capsys)
    assert status == 2
    assert _one_line(err).endswith(expected)
    assert not out.exists()


def test_the_command_line_names_the_line_of_a_broken_bitmap(tmp_path, capsys):
    bitmap = tmp_path / "broken.txt"
    bitmap.write_text("####\n#?##\n")
    out = tmp_path / "out"
    argv = ["run", "self-assembly", "--duration", "1", "--set", f"self_assembly.shape={bitmap}"]
    status, err = _kilonet([*argv, "--out", str(out)], capsys)
    assert status == 2
    assert (
        _one_line(err)
        == f"{bitmap}:2:2: '?' is not a bitmap cell ('#' or '1' inside, '.' or '0' outside)"
    )
    assert not out.exists()


def test_iou_of_a_disc_in_its_square_and_of_nothing():
    square = load_shape("square", 40.0)
    assert iou(square, np.empty((0, 2)), 33.0) == 0.0
    one = read_bitmap("#\n", "inline")
    from kilonet.protocols.self_assembly.rules import Shape

    cell = Shape(one, 33.0, (-16.5, -16.5))
    assert iou(cell, np.array([[0.0, 0.0]]), 33.0, 0.1) == pytest.approx(np.pi / 4, abs=0.005)
    # the same disc half outside: intersection ~ half the disc, union grows
    half = iou(cell, np.array([[33.0, 0.0]]), 33.0, 0.1)
    assert half < 0.05


# -- one robot ---------------------------------------------------------------------------------
def test_a_moving_robot_that_loses_its_neighbours_stops_and_says_so():
    world = ScriptedWorld(SelfAssembly(load_shape("square", 40.0)), uid=50)
    wait = AssemblyStage.WAIT.number
    for uid, at_s in ((7, 0.1), (8, 0.35)):  # two waiting neighbours of gradient 1, to 10 s
        world.hear_every(
            ASSEMBLY.pack(uid=uid, gradient=1, stage=wait, age=0, x=0, y=0),
            period_s=0.5,
            from_s=at_s,
            until_s=10.0,
            distance_mm=34,
        )
    world.run_until(40.0)
    (start,) = world.events("start")
    (lost,) = world.events("lost")
    assert start.fields == {"gradient": 2}
    assert 4.0 <= start.t_s < 6.0  # after the start-up time, on the edge and the highest
    assert 10.0 + LOST_AFTER_S <= lost.t_s < 10.0 + LOST_AFTER_S + 2.0
    last = world.motor_commands()[-1]
    assert last.value == (0, 0) and last.t_s <= lost.t_s
    assert world.robot.stage is AssemblyStage.LOST
    assert world.robot.color == (3, 0, 3)


# -- a swarm -----------------------------------------------------------------------------------
def _overlaps(positions: np.ndarray, diameter_mm: float) -> int:
    d = np.hypot(*(positions[:, None] - positions[None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    return int((d < diameter_mm - 1e-6).sum() // 2)


def _overlaps_over_time(sim, step_s: float = 2.0) -> int:
    """Pairs of bodies closer than a diameter at any sample of the run (every ``step_s``),
    each robot where its last recorded pose put it."""
    poses = sim.trace.poses_frame()
    times = np.arange(0.0, sim.env.now + step_s, step_s)
    where = np.repeat(sim.initial_positions_mm[None], len(times), axis=0)
    for robot, mine in poses.groupby("robot"):
        at = np.searchsorted(mine["t_s"].to_numpy(), times, side="right") - 1
        seen = at >= 0
        where[seen, robot] = mine[["x_mm", "y_mm"]].to_numpy()[at[seen]]
    return sum(_overlaps(p, sim.world.diameter_mm) for p in where)


SMALL_SHAPE = "; 4 x 4 cells of 40 mm: room for the sixteen robots that move\n" + "####\n" * 4


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    shape = tmp_path_factory.mktemp("shape") / "small.txt"
    shape.write_text(SMALL_SHAPE)
    overrides = {"placement.robots": 20, "self_assembly.shape": str(shape), "duration_s": 2400.0}
    return scenarios.run(scenarios.get("self-assembly"), overrides, seed=1)


def assert_assembled(
    result, *, joined: float, iou: float, lost: int, moving: int, step_s: float
) -> None:
    """At least ``joined`` of the robots joined, the bodies cover ``iou`` of the shape, at most
    ``lost`` robots stopped lost, at least ``moving`` moved at once, and no two bodies
    overlapped at the end or at any sample ``step_s`` apart."""
    s, sim = result.summary, result.sim
    assert s["joined_fraction"] >= joined, s
    assert s["iou"] >= iou, s
    assert s["lost"] <= lost, s
    assert s["moving_at_once_max"] >= moving, s
    assert _overlaps(sim.world.positions_mm, sim.world.diameter_mm) == 0
    assert _overlaps_over_time(sim, step_s=step_s) == 0


@pytest.mark.twin_of("test_a_hundred_robots_assemble_the_square")
def test_twenty_robots_assemble_the_small_shape(small_run):
    """The 100-robot run's assertions on 20 robots, with floors for the small shape: bodies
    cover at most ~0.6 of a shape at the packing's spacing, 1 lost robot is the 100-robot run's
    5 %, and robots move one after another, overlapping."""
    assert_assembled(small_run, joined=0.8, iou=0.45, lost=1, moving=2, step_s=2.0)
    s = small_run.summary
    sim = small_run.sim
    # the frame the robots share is not turned about the seeds (before the settle rule: 7 deg,
    # median error 13.6 mm; tests/test_self_assembly_settle.py)
    assert s["localization_error_median_mm"] <= 10.0, s
    assert abs(s["frame_rotation_deg"]) <= 4.0, s
    assert s["sim_time_s"] < 2400.0, s  # every robot joined or stopped lost before the cap
    stages = [r.stage for r in sim.robots]
    assert stages[:4] == [AssemblyStage.SEED] * 4
    assert set(stages[4:]) <= {AssemblyStage.JOINED, AssemblyStage.LOST}
    events = sim.trace.events_frame()
    assert (events["event"] == "joined").sum() == s["joined"]


def test_the_run_directory_holds_the_figure_and_a_replay(small_run, tmp_path, capsys):
    from kilonet.scenarios.base import write_outputs

    out = tmp_path / "run"
    write_outputs(small_run, out)
    robots = (out / "robots.csv").read_text().splitlines()
    assert robots[0].split(",")[-4:] == ["stage", "est_x_mm", "est_y_mm", "localization_error_mm"]
    assert (out / "self_assembly.png").stat().st_size > 10_000
    assert kilonet.app.cli.main(["animate", str(out), "--out", str(out / "replay.html")]) == 0
    page = (out / "replay.html").read_text()
    assert "<title>self-assembly — kilonet replay</title>" in page


#: Floors of the 100-robot run, below its seed-1 result (every robot joined, IoU 0.52; before
#: edge-following's straight cases robots jammed round the start: 0.81 joined, IoU 0.43).
JOINED_100, IOU_100 = 0.95, 0.45


@pytest.mark.slow
def test_a_hundred_robots_assemble_the_square():
    """The 100-robot run of issue 47 (about 100 s of CPU: every robot joins by some 2,600
    simulated seconds, and every motion step recomputes the links round the robots that moved,
    docs/self_assembly.md), and its shape not warped: before the settle rule its frame was
    turned 15 deg about the seeds and its median localization error was 69 mm."""
    overrides = {"placement.robots": 100, "self_assembly.cell_mm": 48.0, "duration_s": 6000.0}
    result = scenarios.run(scenarios.get("self-assembly"), overrides, seed=1)
    assert_assembled(result, joined=JOINED_100, iou=IOU_100, lost=5, moving=5, step_s=10.0)
    s = result.summary
    assert s["localization_error_median_mm"] <= 10.0 and s["localization_error_max_mm"] <= 25.0, s
    assert abs(s["frame_rotation_deg"]) <= 3.0, s
