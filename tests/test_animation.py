"""Tests for kilonet.viz.animation and ``kilonet animate``: GIF and HTML of a real gradient run
(frame count, size, LED colours read back at the robots' centres), state sampled from event
tables, overlays, and user errors."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

import kilonet.app.cli as cli
from kilonet import scenarios
from kilonet.protocols.common.alignment import procrustes_rmse
from kilonet.viz.animation import (
    AnimationError,
    FrameRenderer,
    Replay,
    animate_run,
    frame_times,
    load_run,
)

_PATH_COLOUR = (31, 119, 180)

# ---------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def gradient_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real run: the gradient scenario, 20 robots, 5 s, with the message trace."""
    result = scenarios.run(
        scenarios.get("gradient"),
        {"placement.robots": 20, "duration_s": 5.0, "trace.messages": True},
        seed=3,
    )
    out = tmp_path_factory.mktemp("gradient") / "run"
    scenarios.write_outputs(result, out)
    return out


def _expected_levels(led: pd.DataFrame, robot: int, t_s: float) -> tuple[int, int, int]:
    """The trace's LED levels of ``robot`` at ``t_s``: the last change at or before it."""
    rows = led[(led["robot"] == robot) & (led["t_s"] <= t_s)]
    if rows.empty:
        return (0, 0, 0)
    last = rows.iloc[-1]
    return (int(last["r"]), int(last["g"]), int(last["b"]))


def _write_run(
    path: Path,
    robots: pd.DataFrame,
    *,
    led: Sequence[tuple] = (),
    poses: Sequence[tuple] = (),
    stops: Sequence[tuple] = (),
    events: Sequence[tuple] = (),
    messages: list[tuple] | None = None,
    duration_s: float = 4.0,
) -> Path:
    """A hand-made run directory with the tables ``kilonet.scenarios.write_outputs`` writes."""
    path.mkdir(parents=True)
    robots.to_csv(path / "robots.csv", index=False)
    tables = {
        "led": (led, ["t_s", "robot", "r", "g", "b"]),
        "poses": (poses, ["t_s", "robot", "x_mm", "y_mm", "heading_rad"]),
        "stops": (stops, ["t_s", "robot", "cause"]),
        "events": (events, ["t_s", "robot", "event", "data"]),
        "messages": (messages or [], ["t_s", "sender", "receivers", "delivered"]),
    }
    for name, (rows, columns) in tables.items():
        pd.DataFrame(list(rows), columns=columns).to_csv(path / f"{name}.csv", index=False)
    params = {
        "duration_s": duration_s,
        "medium.range_mm": 85.0,
        "medium.occlusion": "block",
        "motion.step_s": 0.05,
        "robot.tx_period_s": 0.2,
        "trace.messages": messages is not None,
    }
    (path / "params.json").write_text(json.dumps(params))
    (path / "summary.json").write_text(json.dumps({"scenario": "hand", "sim_time_s": duration_s}))
    return path


def _robots(xy: list[tuple[float, float]], **extra: list) -> pd.DataFrame:
    frame = pd.DataFrame(
        {
            "robot": range(len(xy)),
            "x0_mm": [p[0] for p in xy],
            "y0_mm": [p[1] for p in xy],
            "x_mm": [p[0] for p in xy],
            "y_mm": [p[1] for p in xy],
        }
    )
    for name, values in extra.items():
        frame[name] = values
    return frame


# ----------------------------------------------------------------- a real run, GIF + HTML


def test_gif_of_gradient_run_shows_the_traced_led_colours(gradient_dir: Path, tmp_path: Path):
    out = animate_run(gradient_dir, tmp_path / "g.gif", fps=10, speed=1.0)
    assert out == tmp_path / "g.gif"
    times = frame_times(0.0, 5.0, fps=10, speed=1.0)
    assert len(times) == 51
    assert 20_000 < out.stat().st_size < 2_000_000
    assert [p.name for p in tmp_path.iterdir()] == ["g.gif"]  # no temporary file left behind

    run = load_run(gradient_dir)
    # Same layout as animate_run: the default overlays of a message-traced run, 640 px wide.
    renderer = FrameRenderer(Replay(run), {"messages"}, width_px=640)
    centres = renderer.pixel_xy(run.robots[["x_mm", "y_mm"]].to_numpy())
    seen = set()
    with Image.open(out) as gif:
        assert gif.n_frames == len(times)
        assert gif.size == renderer.size_px
        assert gif.info["duration"] == 100
        for k in (0, 1, 2, 3, 10, 50):
            gif.seek(k)
            frame = gif.convert("RGB")
            for robot in range(run.n_robots):
                levels = _expected_levels(run.led, robot, times[k])
                col, row = np.round(centres[robot]).astype(int)
                assert frame.getpixel((col, row)) == tuple(85 * v for v in levels), (k, robot)
                seen.add((k, levels))
    # Not vacuous: the frames show dark robots before the gradient reached them, and colours.
    assert (0, (0, 0, 0)) in seen
    assert len({levels for _, levels in seen}) >= 3


def test_html_replay_embeds_the_run_and_a_player(gradient_dir: Path, tmp_path: Path):
    out = animate_run(gradient_dir, tmp_path / "g.html", overlays=["edges", "messages"])
    page = out.read_text()
    for control in ('id="play"', 'id="scrub"', 'type="range"', 'id="speed"', "<canvas"):
        assert control in page
    assert "http://" not in page and "https://" not in page and "<script src" not in page
    match = re.search(r'<script id="kilonet-data" type="application/json">(.*?)</script>', page)
    data = json.loads(match.group(1))
    run = load_run(gradient_dir)
    assert len(data["x0"]) == run.n_robots == 20
    assert data["duration_s"] == 5.0
    assert data["overlays"] == ["edges", "messages"]
    assert len(data["led"]["t"]) == len(run.led)
    assert len(data["messages"]["t"]) == int((run.messages["delivered"] > 0).sum())
    assert len(data["edges"]["t"]) == 1  # a static swarm: one communication graph
    # Decoding the embedded LED rows as the player does gives the trace's colour.
    start, t, codes = data["led"]["start"], data["led"]["t"], data["led"]["c"]
    for robot in (0, 7, 19):
        rows = [k for k in range(start[robot], start[robot + 1]) if t[k] <= 2.5]
        c = codes[rows[-1]]
        assert ((c >> 4) & 3, (c >> 2) & 3, c & 3) == _expected_levels(run.led, robot, 2.5)


# The replay's own player run in node against a stub canvas: prints the fill colour of each
# robot body it draws at the times given on the command line.
_PLAYER_PROBE = r"""
const fs = require("fs");
const html = fs.readFileSync(process.argv[2], "utf8");
const data = html.match(/id="kilonet-data" type="application\/json">([\s\S]*?)<\/script>/)[1];
const code = html.match(/<script>\n([\s\S]*?)<\/script>/)[1];
let arcs = [], fills = [];
const ctx = {
  scale() {}, fillRect() {}, strokeRect() {}, beginPath() {}, moveTo() {}, lineTo() {},
  stroke() {}, fillText() {}, measureText: () => ({ width: 10 }),
  arc(x, y, r) { arcs.push([x, y, r]); },
  fill() { fills.push([...arcs[arcs.length - 1], this.fillStyle]); },
};
const elements = {};
const el = id => (elements[id] ||= {
  id, style: {}, value: "1", textContent: id === "kilonet-data" ? data : "",
  addEventListener() {}, appendChild() {}, append() {}, getContext: () => ctx, click() {},
});
let made = 0;
global.document = {
  getElementById: el, createElement: () => el("made" + made++), addEventListener() {},
};
global.window = { devicePixelRatio: 1 };
global.requestAnimationFrame = () => {};
eval(code + "\nglobalThis.__draw = draw; globalThis.__scale = scale;");
const out = {};
for (const t of process.argv.slice(3)) {
  fills = [];
  __draw(Number(t));
  const R = JSON.parse(data).radius_mm * __scale;
  out[t] = fills.filter(f => Math.abs(f[2] - R) < 1e-9).map(f => f[3]);
}
console.log(JSON.stringify(out));
"""


@pytest.mark.skipif(shutil.which("node") is None, reason="needs node to run the player")
def test_html_player_draws_the_traced_led_colours(gradient_dir: Path, tmp_path: Path):
    out = animate_run(gradient_dir, tmp_path / "g.html")
    probe = tmp_path / "probe.js"
    probe.write_text(_PLAYER_PROBE)
    times = ["0", "0.2", "2.5"]
    drawn = json.loads(
        subprocess.run(
            ["node", str(probe), str(out), *times], capture_output=True, text=True, check=True
        ).stdout
    )
    led = load_run(gradient_dir).led
    for t in times:
        expected = [
            "rgb({},{},{})".format(*(85 * v for v in _expected_levels(led, robot, float(t))))
            for robot in range(20)
        ]
        assert drawn[t] == expected, t
    assert drawn["0"] != drawn["2.5"]


def test_parquet_run_directories_read_the_same(gradient_dir: Path, tmp_path: Path):
    for table in gradient_dir.glob("*.csv"):
        pd.read_csv(table).to_parquet(tmp_path / f"{table.stem}.parquet", index=False)
    for extra in ("params.json", "summary.json"):
        (tmp_path / extra).write_bytes((gradient_dir / extra).read_bytes())
    from_csv, from_parquet = load_run(gradient_dir), load_run(tmp_path)
    for name in ("robots", "led", "events", "messages"):
        pd.testing.assert_frame_equal(getattr(from_csv, name), getattr(from_parquet, name))
    assert Replay(from_parquet).leds(2.0).tolist() == Replay(from_csv).leds(2.0).tolist()


# ------------------------------------------------------------------ state over time


def test_replay_leds_take_the_last_change_and_can_go_back(tmp_path: Path):
    run_dir = _write_run(
        tmp_path / "run",
        _robots([(0, 0), (50, 0)]),
        led=[(0.0, 0, 3, 0, 0), (1.0, 0, 0, 3, 0), (1.0, 0, 0, 0, 3), (2.0, 1, 1, 2, 3)],
    )
    replay = Replay(load_run(run_dir))
    assert replay.leds(0.5).tolist() == [[3, 0, 0], [0, 0, 0]]
    assert replay.leds(1.0).tolist() == [[0, 0, 3], [0, 0, 0]]  # same time: the later row
    assert replay.leds(3.0).tolist() == [[0, 0, 3], [1, 2, 3]]
    assert replay.leds(0.0).tolist() == [[3, 0, 0], [0, 0, 0]]  # back in time


def test_replay_positions_rest_until_one_step_before_the_next_pose(tmp_path: Path):
    # Robot 1 rests at (100, 0) until 1.0 s, then moves 0.5 mm per 50 ms step along x.
    poses = [(1.0 + 0.05 * k, 1, 100.0 + 0.5 * k, 0.0, 0.0) for k in range(1, 21)]
    run_dir = _write_run(tmp_path / "run", _robots([(0, 0), (100, 0)]), poses=poses)
    replay = Replay(load_run(run_dir))
    assert replay.moving.tolist() == [1]
    np.testing.assert_allclose(replay.positions(0.9), [[0, 0], [100, 0]])
    np.testing.assert_allclose(replay.positions(1.0), [[0, 0], [100, 0]])
    np.testing.assert_allclose(replay.positions(1.525)[1], [105.25, 0.0])
    np.testing.assert_allclose(replay.positions(9.0)[1], [110.0, 0.0])
    np.testing.assert_allclose(replay.path(1, 1.1), [[100, 0], [100, 0], [100.5, 0], [101, 0]])


def test_replay_stops_phases_and_senders(tmp_path: Path):
    run_dir = _write_run(
        tmp_path / "run",
        _robots([(0, 0), (50, 0), (100, 0)]),
        stops=[(1.0, 1, "crash"), (2.0, 2, "removed")],
        events=[
            (0.0, 0, "phase", json.dumps({"phase": "ids"})),
            (0.5, 0, "gradient", json.dumps({"value": 1})),
            (1.5, 2, "phase", json.dumps({"name": "election"})),
        ],
        messages=[(0.10, 0, 2, 2), (0.25, 1, 2, 0), (0.30, 2, 1, 1), (0.45, 0, 2, 1)],
    )
    replay = Replay(load_run(run_dir), window_s=0.2)
    assert replay.stopped(1.5).tolist() == [False, True, False]
    assert replay.present(1.5).tolist() == [True, True, True]
    assert replay.present(2.0).tolist() == [True, True, False]
    assert replay.phase(-1.0) is None
    assert replay.phase(1.0) == "ids"
    assert replay.phase(1.5) == "election"
    assert replay.senders(0.30).tolist() == [0, 2]  # (0.1, 0.3]: robot 1 delivered nothing
    assert replay.senders(0.45).tolist() == [0, 2]
    assert replay.senders(0.6).tolist() == [0]
    pairs = replay.edges(replay.positions(2.0), replay.present(2.0))
    assert pairs.tolist() == [[0, 1]]


# --------------------------------------------------------------------------- overlays


def test_frames_estimates_and_paths_are_drawn(tmp_path: Path):
    robots = _robots(
        [(0, 0), (60, 0), (0, 60), (60, 60)],
        est_x_mm=[5.0, 60.0, np.nan, 110.0],
        est_y_mm=[-20.0, -30.0, np.nan, 95.0],
        frame=[7, 7, 2, -1],
    )
    poses = [(0.05 * k, 3, 60.0 + 1.0 * k, 60.0, 0.0) for k in range(1, 41)]
    run_dir = _write_run(
        tmp_path / "run",
        robots,
        led=[(0.0, r, 3, 3, 0) for r in range(4)],
        poses=poses,
        stops=[(1.0, 1, "crash")],
    )
    out = animate_run(
        run_dir, tmp_path / "o.gif", fps=10, speed=1.0, end_s=2.0, align_estimates=False
    )
    run = load_run(run_dir)
    replay = Replay(run, align_estimates=False)
    renderer = FrameRenderer(replay, {"estimates", "frames", "paths"}, width_px=640)
    with Image.open(out) as gif:
        assert gif.n_frames == 21
        gif.seek(20)
        frame = gif.convert("RGB")

    def pixel(x: float, y: float) -> tuple[int, int, int]:
        col, row = np.round(renderer.pixel_xy([[x, y]])[0]).astype(int)
        return frame.getpixel((col, row))

    def near(x: float, y: float, colour: tuple[int, int, int]) -> bool:
        col, row = np.round(renderer.pixel_xy([[x, y]])[0]).astype(int)
        around = [(col + dc, row + dr) for dc in range(-2, 3) for dr in range(-2, 3)]
        return any(frame.getpixel(p) == colour for p in around)

    table, yellow, purple = (240, 240, 240), (255, 255, 0), (148, 103, 189)
    # Halos in the frame's colour just outside the body: frame 2 ranks first, frame 7 second.
    halo = 16.5 + 1.5
    assert pixel(-halo, 0) == pixel(60 + halo, 0) == (255, 127, 14)  # robots 0, 1: frame 7
    # Robot 1 crashed: a red ring around it, on top of its halo; robot 0 has none.
    assert pixel(60 + 20, 0) == (214, 39, 40)
    assert pixel(-20, 0) != (214, 39, 40)
    assert pixel(-halo, 60) == (31, 119, 180)  # robot 2: frame 2
    assert pixel(100, 60 + halo) == table  # robot 3: no frame
    # Robot 3 moved 40 mm: its disc is there, its path behind it, and its start is empty.
    assert pixel(100, 60) == yellow
    assert pixel(60, 60) == pixel(75, 60) == _PATH_COLOUR
    # Estimates: a cross at robot 0's estimate with its error segment; none for robot 2.
    assert near(5, -20, purple) and near(4.5, -18, purple)
    assert not near(0, 60 + 25, purple)
    # Robot 0 and 1 have LEDs set; their bodies are yellow.
    assert pixel(0, 0) == pixel(60, 0) == yellow
    assert pixel(30, 30) == table


def test_estimates_are_aligned_per_frame_onto_the_truth(tmp_path: Path):
    truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 40.0], [40.0, 40.0], [200, 0], [240, 0]])
    # Frame "a": the truth mirrored, turned 30 degrees and shifted; frame "b": two robots.
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    est = (truth * [-1.0, 1.0]) @ np.array([[c, s], [-s, c]]) + [300.0, 20.0]

    def replay_of(estimates: np.ndarray, name: str, **options) -> Replay:
        robots = _robots(
            [tuple(p) for p in truth],
            est_x_mm=estimates[:, 0],
            est_y_mm=estimates[:, 1],
            frame=["a", "a", "a", "a", "b", "b"],
        )
        return Replay(load_run(_write_run(tmp_path / name, robots)), **options)

    replay = replay_of(est, "exact")
    assert replay.frame_rank.tolist() == [0, 0, 0, 0, 1, 1]
    assert replay.frame_count == 2
    np.testing.assert_allclose(replay.estimates_mm[:4], truth[:4], atol=1e-9)
    assert np.isnan(replay.estimates_mm[4:]).all()  # two robots cannot fix an alignment
    assert replay.estimate_rmse_mm < 1e-9
    np.testing.assert_allclose(replay_of(est, "raw", align_estimates=False).estimates_mm, est)

    # One estimate 5 mm off: the drawn error is the metric's (Procrustes) error, which beats
    # shifting alone (RMSE 2.165 mm).
    noisy = est.copy()
    noisy[3, 0] -= 5.0
    replay = replay_of(noisy, "noisy")
    rmse, _, _ = procrustes_rmse(noisy[:4], truth[:4])
    np.testing.assert_allclose(replay.estimate_rmse_mm, rmse)
    assert 0.5 < replay.estimate_rmse_mm < 2.165


# ------------------------------------------------------------------------ user errors


def test_user_errors_are_one_line_with_nothing_written(
    gradient_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys
):
    no_messages = _write_run(tmp_path / "quiet", _robots([(0, 0)]))
    cases = [
        ([str(tmp_path / "nowhere")], "no such run directory"),
        ([str(gradient_dir), "--out", str(tmp_path / "a.avi")], "unknown animation format"),
        ([str(gradient_dir), "--overlay", "wind"], "unknown overlay 'wind'"),
        ([str(gradient_dir), "--overlay", "estimates"], "'estimates' needs an estimates table"),
        ([str(no_messages), "--overlay", "messages"], "--set trace.messages=true"),
        ([str(gradient_dir), "--fps", "0"], "--fps must be a positive number"),
        ([str(gradient_dir), "--start", "4", "--end", "2"], "0 <= start <= end"),
        ([str(gradient_dir), "--speed", "0.0001"], "raise --speed or lower --fps"),
    ]
    for argv, message in cases:
        before = sorted(p.name for p in tmp_path.rglob("*"))
        assert cli.main(["animate", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, (argv, err)
        assert sorted(p.name for p in tmp_path.rglob("*")) == before
    assert not (gradient_dir / "animation.gif").exists()


def test_mp4_without_ffmpeg_says_so(
    gradient_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    import matplotlib.animation

    monkeypatch.setattr(
        matplotlib.animation.FFMpegWriter, "isAvailable", classmethod(lambda c: False)
    )
    with pytest.raises(AnimationError, match="needs ffmpeg on the PATH"):
        animate_run(gradient_dir, tmp_path / "a.mp4")
    assert not (tmp_path / "a.mp4").exists()


def test_cli_writes_the_default_file(gradient_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys):
    out = gradient_dir / "animation.gif"
    try:
        assert cli.main(["animate", str(gradient_dir), "--end", "0.5", "--size", "200"]) == 0
        with Image.open(out) as gif:
            assert gif.n_frames == 6
            assert gif.size[0] == 200
        assert f"wrote {out}" in capsys.readouterr().err
    finally:
        out.unlink(missing_ok=True)


# ------------------------------------------------------------- estimates held over time


def _held_run(path: Path) -> Path:
    """Four robots; robots 0-2 get estimates in frame "a" at 1 s (shifted 200 mm: aligned
    back exactly), robot 0 moves 3 mm at 2 s; robot 3 never has one. Final estimates in the
    robots table are far off, so drawing them would show."""
    truth = [(0.0, 0.0), (60.0, 0.0), (0.0, 60.0), (60.0, 60.0)]
    robots = _robots(truth, est_x_mm=[500.0] * 4, est_y_mm=[500.0] * 4, frame=["z", "z", "z", ""])
    run_dir = _write_run(path, robots, led=[(0.0, r, 3, 3, 0) for r in range(4)])
    rows = [(1.0, r, truth[r][0] + 200.0, truth[r][1], "a") for r in range(3)]
    rows.append((2.0, 0, 203.0, 0.0, "a"))
    columns = ["t_s", "robot", "x_mm", "y_mm", "frame"]
    pd.DataFrame(rows, columns=columns).to_csv(run_dir / "estimates.csv", index=False)
    return run_dir


def test_estimates_are_drawn_as_held_at_each_moment(tmp_path: Path):
    run_dir = _held_run(tmp_path / "run")
    replay = Replay(load_run(run_dir))
    steps = replay.steps
    assert steps.held and steps.t_s.tolist() == [1.0, 2.0]
    assert steps.index(0.5) == -1 and steps.note(-1) == "estimates held: none yet"
    np.testing.assert_allclose(steps.xy_mm[0, :3], [[0, 0], [60, 0], [0, 60]], atol=1e-9)
    assert np.isnan(steps.xy_mm[:, 3]).all()
    assert steps.frame.tolist() == [[0, 0, 0, -1], [0, 0, 0, -1]]
    # At 2 s robot 0's estimate is 3 mm off: the alignment spreads it over the frame.
    rmse, _, _ = procrustes_rmse(np.array([[203.0, 0], [260, 0], [200, 60]]), steps.xy_mm[0, :3])
    assert steps.rmse_mm[1] == pytest.approx(rmse)
    assert steps.note(1) == f"estimates held, aligned per frame: RMSE {rmse:.1f} mm"

    out = animate_run(run_dir, tmp_path / "o.gif", fps=2, speed=1.0, end_s=2.0)
    renderer = FrameRenderer(replay, {"estimates", "frames"}, width_px=640)
    yellow, blue = (255, 255, 0), (31, 119, 180)

    def at(frame: Image.Image, x: float, y: float) -> tuple[int, int, int]:
        col, row = np.round(renderer.pixel_xy([[x, y]])[0]).astype(int)
        return frame.getpixel((col, row))

    def crossed(frame: Image.Image, x: float, y: float) -> bool:
        """An estimate's cross on the yellow body at (x, y): its centre is not yellow."""
        return at(frame, x, y) != yellow

    with Image.open(out) as gif:
        frames = []
        for k in range(gif.n_frames):
            gif.seek(k)
            frames.append(gif.convert("RGB"))
    assert len(frames) == 5  # 0, 0.5, 1, 1.5, 2 s
    halo = 16.5 + 1.5
    # Before 1 s: no estimate cross and no frame halo anywhere, final or not.
    for frame in frames[:2]:
        assert not crossed(frame, 0, 0) and at(frame, -halo, 0) != blue
    # From 1 s: robots 0-2 show their aligned estimates (on the truth until 2 s, when robot
    # 0's 3 mm step moves every aligned estimate off it) in frame "a"'s colour.
    for frame in frames[2:4]:
        assert crossed(frame, 0, 0) and crossed(frame, 60, 0)
    assert not crossed(frames[4], 0, 0)
    for frame in frames[2:]:
        assert at(frame, -halo, 0) == blue and at(frame, 60 + halo, 60) != blue
    assert not any(crossed(frame, 60, 60) for frame in frames)


def test_the_html_replay_carries_the_estimates_as_steps(tmp_path: Path):
    run_dir = _held_run(tmp_path / "run")
    out = animate_run(run_dir, tmp_path / "r.html", speed=1.0)
    text = out.read_text()
    data = json.loads(re.search(r'id="kilonet-data"[^>]*>(.*?)</script>', text, re.S)[1])
    est = data["estimates"]
    assert est["t"] == [1.0, 2.0] and est["before"] == "estimates held: none yet"
    assert est["x"][0] == [0.0, 60.0, 0.0, None] and est["y"][0] == [0.0, 0.0, 60.0, None]
    assert data["frames"] == {
        "t": [1.0, 2.0],
        "rank": [[0, 0, 0, -1], [0, 0, 0, -1]],
        "label": "frames",
        "colours": data["frames"]["colours"],
    }


def test_a_real_run_records_what_robots_held_without_changing_the_run(tmp_path: Path):
    runs = {}
    for period in (0.0, 1.0):
        overrides = {"placement.robots": 14, "trace.estimates_period_s": period}
        runs[period] = scenarios.run(scenarios.get("localize"), overrides, seed=4)
    quiet, sampled = runs[0.0], runs[1.0]
    assert quiet.sim.trace.estimates_frame().empty
    table = sampled.sim.trace.estimates_frame()
    assert len(table) >= 14
    for name in ("led", "events", "poses", "messages"):
        pd.testing.assert_frame_equal(
            quiet.sim.trace.frames()[name], sampled.sim.trace.frames()[name]
        )
    # The run is the same bit for bit (the frames above); the centralized solver that scores
    # it after the run may differ in the last digits (NumPy's SIMD sums depend on how arrays
    # happen to be aligned in memory).
    scored = {k for k in quiet.summary if k.startswith("central_") or k.endswith("_central")}
    assert {k: v for k, v in quiet.summary.items() if k not in scored | {"wall_time_s"}} == {
        k: v for k, v in sampled.summary.items() if k not in scored | {"wall_time_s"}
    }
    assert {k: quiet.summary[k] for k in scored} == pytest.approx(
        {k: sampled.summary[k] for k in scored}, rel=1e-6
    )
    # Samples start at 0 s, one a second, and one where the run stopped: the last row of each
    # robot is what it ended with (within the recording threshold), in robots.csv's frame.
    end = sampled.sim.env.now
    assert set(np.round(table.t_s[table.t_s < end] % 1.0, 9)) == {0.0}
    last = table.groupby("robot").last()
    final = scenarios.get("localize").reporting.robot_columns(sampled.sim).set_index("robot")
    np.testing.assert_allclose(last.x_mm, final.est_x_mm[last.index], atol=0.05)
    np.testing.assert_allclose(last.y_mm, final.est_y_mm[last.index], atol=0.05)
    assert (last.frame == final.frame[last.index]).all()


# ------------------------------------------------------------------------------ LED key


def test_the_gif_has_a_key_of_the_led_colours(tmp_path: Path):
    result = scenarios.run(scenarios.get("localize"), {"placement.robots": 14}, seed=4)
    scenarios.write_outputs(result, tmp_path / "run")
    key = pd.read_csv(tmp_path / "run" / "led_key.csv")
    assert key.meaning.tolist() == [m for _, m in type(result.sim.robots[0]).LED_KEY]
    out = animate_run(tmp_path / "run", tmp_path / "o.gif", fps=1, speed=100.0, overlays=["none"])
    renderer = FrameRenderer(Replay(load_run(tmp_path / "run")), set(), width_px=640)
    assert [m for _, m, _ in renderer.key_entries] == key.meaning.tolist()
    with Image.open(out) as gif:
        assert gif.size == renderer.size_px
        frame = gif.convert("RGB")
    for levels, _, (col, row) in renderer.key_entries:
        expected = tuple(int(v) * 85 for v in levels)
        assert frame.getpixel((round(col), round(row))) == expected
        assert row > renderer.size_px[1] - 30  # along the bottom edge, below the swarm
    # The key's strip is below every robot.
    lowest = renderer.pixel_xy(result.sim.world.positions_mm)[:, 1].max() + 16.5
    assert lowest < min(row for _, _, (_, row) in renderer.key_entries) - 5


def test_a_run_without_a_key_draws_none(tmp_path: Path):
    run_dir = _write_run(tmp_path / "run", _robots([(0, 0), (60, 0)]))
    renderer = FrameRenderer(Replay(load_run(run_dir)), set(), width_px=640)
    assert renderer.key_entries == []


def test_the_replay_template_ships_with_the_package():
    """CI installs non-editable: every file of ``viz/`` that is not Python must be
    package data in pyproject.toml, or ``pip install .`` leaves it behind."""
    import fnmatch
    import tomllib
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    config = tomllib.loads((root / "pyproject.toml").read_text())
    globs = config["tool"]["setuptools"]["package-data"]["kilonet.viz"]
    data = [p.name for p in (root / "viz").iterdir() if p.is_file() and p.suffix != ".py"]
    assert "replay.html" in data
    assert all(any(fnmatch.fnmatch(name, g) for g in globs) for name in data), (data, globs)
