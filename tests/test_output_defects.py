"""Output defects of ``kilonet run``, ``animate``, ``analyze`` and ``report`` (issue 43 item 4,
issue 45 item 2): one ``uid`` column, phase names in the summary, progress after the run, a
finished run kept when its figures or animation fail, frame counts checked before allocating,
and one-line errors that say what is wrong."""

from __future__ import annotations

import errno
import math
import tracemalloc
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from kilonet import scenarios
from kilonet.app.cli import main
from kilonet.scenarios.base import run, write_outputs

GRADIENT = ["run", "gradient", "--robots", "6", "--duration", "3"]
ROOT = Path(__file__).resolve().parents[1]


def last_line(err: str) -> str:
    """The last line on stderr (after an erased progress bar)."""
    return err.split("\r")[-1].rstrip("\n").split("\n")[-1]


def no_staging(parent: Path) -> bool:
    return not [p for p in parent.iterdir() if p.name.startswith(".")]


# -- robots.csv: one uid ------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "extra"), [("gcs", {"gcs.until": "ids"}), ("localize", {})])
def test_robots_csv_has_one_uid_column_the_ids_the_robots_chose(tmp_path, name, extra):
    result = run(scenarios.get(name), {"placement.robots": 8, "duration_s": 5, **extra})
    write_outputs(result, tmp_path / name)
    robots = pd.read_csv(tmp_path / name / "robots.csv")
    assert list(robots.columns[:2]) == ["robot", "uid"]
    assert [c for c in robots.columns if c.startswith("uid")] == ["uid"]
    assert robots.uid.tolist() == [r.uid for r in result.sim.robots]


# -- the text summary ---------------------------------------------------------------------------
def test_the_summary_prints_phase_names_not_enum_members(capsys):
    assert main(["run", "gcs", "--robots", "8", "--until", "seeds", "--quiet"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("phases_run ")]
    assert [ln.split(None, 1)[1] for ln in lines] == ["['ids', 'seeds']"]


# -- progress after the run ---------------------------------------------------------------------
def test_scoring_and_writing_show_as_lines_after_the_run(tmp_path, capsys):
    assert main([*GRADIENT, "--progress", "lines", "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err.splitlines()
    names = [ln.split(": ", 1)[1] for ln in err if ln.startswith("gradient: ")]
    after = names[names.index("scoring") - 1 :]
    assert after[0].startswith("100% 3 sim s, ") and after[1] == "scoring"
    after = after[1:]
    assert after[1].startswith("done at 3 sim s in ")
    assert after[2:4] == ["writing tables", "writing the gradient scenario's figures"]
    assert after[4].startswith("written in ") and after[4].endswith(" s")
    assert err[-1] == f"wrote 11 files to {tmp_path / 'r'}"


def test_on_a_terminal_the_stages_after_the_run_show_and_are_erased(tmp_path, monkeypatch):
    import io
    import sys

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    monkeypatch.setattr(sys, "stdout", io.StringIO())
    assert main([*GRADIENT, "--out", str(tmp_path / "r")]) == 0
    shown = terminal.getvalue()
    run_bar, after = shown.split("\n", 1)
    assert "\rgradient: scoring  100% |" in run_bar  # scoring shows on the bar
    assert run_bar.split("\r")[-1].startswith("gradient  100% |##########| 3.0/3.0 sim s")
    drawn = after.split("\r")
    assert drawn[1].startswith("gradient: writing tables [")
    assert drawn[2].startswith("gradient: writing the gradient scenario's figures [")
    assert drawn[-2].strip() == "" and drawn[-1] == f"wrote 11 files to {tmp_path / 'r'}\n"


@pytest.mark.parametrize("flags", [["--quiet", "--progress", "lines"], []])
def test_no_progress_after_the_run_when_quiet_or_into_a_file(tmp_path, capsys, flags):
    assert main([*GRADIENT, *flags, "--out", str(tmp_path / "r")]) == 0
    err = capsys.readouterr().err
    assert err == ("" if flags else f"wrote 11 files to {tmp_path / 'r'}\n")


# -- a finished run is never discarded ----------------------------------------------------------
def fill_the_disk_while_writing_gifs(monkeypatch) -> None:
    """The GIF writer writes part of the file, then the disk is full (ENOSPC)."""
    from kilonet.viz import video

    def finish(self):
        Path(self.outfile).write_bytes(b"GIF89a partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(video._PaletteGifWriter, "finish", finish)


def test_a_run_whose_animation_fills_the_disk_is_kept(tmp_path, capsys, monkeypatch):
    fill_the_disk_while_writing_gifs(monkeypatch)
    out = tmp_path / "r"
    assert main([*GRADIENT, "--animate", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert last_line(captured.err) == (
        f"kilonet: error: {out}: animation.gif not written (No space left on device); "
        "the run itself is written"
    )
    assert captured.err.count("\n") == 2  # "wrote 11 files to ..." and the error
    assert "gradient_correct_fraction" in captured.out  # the summary is printed
    names = sorted(p.name for p in out.iterdir())
    assert "animation.gif" not in names and "robots.csv" in names and "summary.json" in names
    assert not [n for n in names if "partial" in n or n.startswith(".")]
    assert no_staging(tmp_path)


@pytest.fixture
def small_disk(tmp_path):
    """A 128 KiB tmpfs: room for a short run's tables, not for its animation (needs root)."""
    import os
    import subprocess

    disk = tmp_path / "disk"
    disk.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small file system needs root")
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=128k", "tmpfs", str(disk)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", str(disk)], check=True)


#: The default tier's twin animates 10 s: a 104 KB animation, which still overflows the 128 KiB
#: disk once the run's tables are written.
@pytest.mark.parametrize("duration", [pytest.param("30", marks=pytest.mark.slow), "10"])
def test_a_run_whose_animation_fills_a_real_disk_is_kept(duration, small_disk, capsys):
    out = small_disk / "r"
    argv = ["run", "gradient", "--robots", "6", "--duration", duration, "--quiet", "--animate"]
    assert main([*argv, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"kilonet: error: {out}: animation.gif not written (No space left on device); "
        "the run itself is written\n"
    )
    assert pd.read_csv(out / "robots.csv").robot.tolist() == list(range(6))
    assert sorted(p.name for p in small_disk.iterdir()) == ["r"]
    assert not (out / "animation.gif").exists()


def test_a_run_whose_figures_fail_is_kept(tmp_path, capsys, monkeypatch):
    from matplotlib.figure import Figure

    def savefig(self, fname, *args, **kwargs):
        Path(fname).write_bytes(b"\x89PNG partial")
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(Figure, "savefig", savefig)
    out = tmp_path / "r"
    assert main([*GRADIENT, "--quiet", "--out", str(out)]) == 2
    assert last_line(capsys.readouterr().err) == (
        f"kilonet: error: {out}: the gradient scenario's figures not written "
        "(Read-only file system); the run itself is written"
    )
    names = sorted(p.name for p in out.iterdir())
    assert "gradient.png" not in names and {"robots.csv", "summary.json"} <= set(names)
    assert no_staging(tmp_path)


def test_a_bug_in_the_animation_keeps_its_traceback_and_the_run(tmp_path, monkeypatch):
    from kilonet.viz import video

    def finish(self):
        raise RuntimeError("a bug")

    monkeypatch.setattr(video._PaletteGifWriter, "finish", finish)
    out = tmp_path / "r"
    with pytest.raises(RuntimeError, match="a bug"):
        main([*GRADIENT, "--quiet", "--animate", "--out", str(out)])
    assert (out / "robots.csv").exists() and not (out / "animation.gif").exists()
    assert no_staging(tmp_path)


# -- kilonet animate ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("animate") / "run"
    assert main([*GRADIENT, "--quiet", "--out", str(out)]) == 0
    return out


def test_animate_on_a_full_disk_is_one_line_and_leaves_nothing(run_dir, capsys, monkeypatch):
    fill_the_disk_while_writing_gifs(monkeypatch)
    before = sorted(p.name for p in run_dir.iterdir())
    assert main(["animate", str(run_dir)]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"kilonet: error: {run_dir / 'animation.gif'}: cannot write the animation "
        "(No space left on device)\n"
    )
    assert sorted(p.name for p in run_dir.iterdir()) == before


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs a /proc file system")
def test_animate_into_proc_says_what_is_wrong(run_dir, capsys):
    assert main(["animate", str(run_dir), "--out", "/proc/kilonet-test.gif"]) == 2
    assert capsys.readouterr().err == (
        "kilonet: error: /proc/kilonet-test.gif: cannot write the animation (the file system "
        "there takes no new files, e.g. /proc or /sys)\n"
    )


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (
            ["--fps", "1e9", "--out", "{dir}/a.html"],
            "3,000,000,001 frames (3 s at speed 1, 1e+09 fps) is more than 20,000; "
            "raise --speed or lower --fps",
        ),
        (
            ["--speed", "1e-9"],
            "30,000,000,001 frames (3 s at speed 1e-09, 10 fps) is more than 20,000; "
            "raise --speed or lower --fps",
        ),
        (
            ["--fps", "0.001"],
            "--fps 0.001: a GIF plays 0.0015 to 100 frames per second (a frame lasts 0.01 s to "
            "655.35 s); write a .mp4 or .html for another rate",
        ),
        (
            ["--fps", "1000"],
            "--fps 1000: a GIF plays 0.0015 to 100 frames per second (a frame lasts 0.01 s to "
            "655.35 s); write a .mp4 or .html for another rate",
        ),
    ],
)
def test_animate_refuses_frame_counts_and_rates_before_allocating(
    run_dir, tmp_path, capsys, flags, message
):
    flags = [f.replace("{dir}", str(tmp_path)) for f in flags]
    tracemalloc.start()
    try:
        assert main(["animate", str(run_dir), *flags]) == 2
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert capsys.readouterr().err == f"kilonet: error: {message}\n"
    assert peak < 200 * 2**20  # the frames' times alone: 22 to 224 GiB
    assert list(tmp_path.iterdir()) == [] and not (run_dir / "animation.gif").exists()


def test_a_slow_gif_within_the_limits_is_written(run_dir, tmp_path, capsys):
    out = tmp_path / "slow.gif"
    assert main(["animate", str(run_dir), "--fps", "0.002", "--speed", "1", "--out", str(out)]) == 0
    from PIL import Image

    with Image.open(out) as gif:
        assert gif.n_frames == 1 and gif.info["duration"] == 500_000


# -- option validation --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--duration", "-5"], "duration_s = -5.0 is out of range: give a finite number >= 0.0"),
        (["--duration", "inf"], "duration_s = inf is not a finite number"),
        (["--robots", "0"], "--robots 0: give the number of robots (at least 1)"),
        (
            ["--out", "/proc/kilonet-test"],
            "--out /proc/kilonet-test: cannot write in /proc (the file system there takes no new "
            "files, e.g. /proc or /sys)",
        ),
    ],
)
def test_bad_options_say_what_is_wrong(capsys, flags, message):
    if "/proc/kilonet-test" in flags and not Path("/proc/self").is_dir():
        pytest.skip("needs a /proc file system")
    assert main(["run", "gradient", *flags]) == 2
    assert capsys.readouterr() == ("", f"kilonet: error: {message}\n")


def test_a_follower_start_band_beyond_its_range_names_the_keys(capsys):
    assert main(["run", "follower", "--set", "follower.start_min_mm=9999.99"]) == 2
    assert capsys.readouterr().err == (
        "kilonet: error: follower.start_min_mm = 9999.99 is beyond the farthest start, 100 mm "
        "from the goal (follower.start_max_mm = 0; 0: as far as it ranges, medium.reach = "
        "argos, follower.neighbour_max_mm = 100); lower follower.start_min_mm\n"
    )


def test_the_suggested_class_of_a_two_program_file_is_the_one_that_runs_both(capsys):
    orbit = ROOT / "examples" / "labs" / "orbit.py"
    argv = ["run", "--program", str(orbit), "--robots", "2", "--duration", "1", "--quiet"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.endswith(f"name one: --program {orbit}:Orbit\n")
    suggested = err.rsplit("--program ", 1)[1].strip()
    assert main([*argv[:2], suggested, *argv[3:]]) == 0


def test_a_one_robot_placement_runs(tmp_path, capsys):
    placement = tmp_path / "one.csv"
    placement.write_text("x_mm,y_mm\n0,0\n")
    out = tmp_path / "r"
    argv = ["run", "gradient", "--placement", str(placement), "--duration", "2", "--quiet"]
    assert main([*argv, "--out", str(out)]) == 0
    robots = pd.read_csv(out / "robots.csv")
    assert robots.robot.tolist() == [0] and robots.uid.tolist() == [0]


# -- the report's bands ---------------------------------------------------------------------------
def test_the_band_of_a_time_stops_at_zero_and_other_bands_are_unchanged():
    from kilonet.experiments.report import aggregate

    times = [0.1, 0.2, 9.0]
    runs = pd.DataFrame(
        {
            "p": [1] * 3,
            "status": ["ok"] * 3,
            "done_s": times,
            "follower_turn_deg_s": [-5.0, 0.0, 1.0],
            "ok_fraction": [0.0, 0.0, 0.9],
        }
    )
    table = aggregate(runs, ["p"], ["done_s", "follower_turn_deg_s", "ok_fraction"])
    rows = table.set_index("metric")
    half = stats.t.ppf(0.975, 2) * np.std(times, ddof=1) / math.sqrt(3)
    assert np.mean(times) - half < 0  # the Student-t interval would go below zero
    assert rows.loc["done_s", "ci_low"] == 0.0
    assert rows.loc["done_s", "ci_high"] == pytest.approx(np.mean(times) + half)
    assert rows.loc["follower_turn_deg_s", "ci_low"] < -5  # a rate may be negative
    assert rows.loc["ok_fraction", "ci_low"] == 0.0


# -- kilonet analyze's figure -------------------------------------------------------------------
def test_the_analyze_figure_draws_the_frames_and_the_boundary_robots():
    from matplotlib.colors import to_rgba

    from kilonet.scenarios.analyze import predict, prediction_figure
    from kilonet.scenarios.thesis_placements import NAMED_PLACEMENTS

    pos = NAMED_PLACEMENTS["thesis-7.1c"]()
    report = predict("thesis-7.1c")
    assert report["final_frames"] == 2 and report["boundary"]
    (ax,) = prediction_figure(pos, report).axes
    drawn = {c.get_label(): c for c in ax.collections}
    boundary = drawn["on a frame boundary"]
    assert boundary.get_offsets().tolist() == pos[report["boundary"]].tolist()
    for k in range(2):
        members = sorted(i for i, f in report["final_frame"].items() if f == k)
        colour = drawn[f"frame {k + 1}"].get_facecolor()[0]
        filled = [
            xy
            for c in ax.collections
            if len(c.get_facecolor()) and np.allclose(c.get_facecolor()[0], colour)
            for xy in c.get_offsets().tolist()
        ]
        assert sorted(map(tuple, filled)) == sorted(map(tuple, pos[members].tolist()))
        assert not np.allclose(colour, to_rgba("0.75"))
