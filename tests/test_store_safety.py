"""The sweep store and run directories never lose data (issue 45): a run cannot replace a
directory a sweep holds, an edited definition is refused, readers never write, a store that
could not be made is not left behind, and each bad input is one line, exit 2, no hang, nothing
left behind."""

from __future__ import annotations

import concurrent.futures as cf
import fcntl
import json
import os
import pty
import shutil
import sqlite3
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest
from test_experiments import SMALL  # four runs of 20 robots for 5 s
from test_sweep_faults import _kilonet

import kilonet.app.cli
from kilonet.experiments.runner import _terminate_local, run_sweep
from kilonet.experiments.store import DB_NAME, ResultStore, lock_directory
from kilonet.experiments.sweep import parse_sweep
from kilonet.scenarios.output_dir import DirectoryInUse, OutputDir, OutputDirError

_CLI = "import sys, kilonet.app.cli as c; sys.exit(c.main(sys.argv[1:]))"
#: Two runs of 10 robots for 2 s: a sweep that finishes in a moment.
TINY = 'scenario = "gradient"\nseeds = 2\n[fixed]\nduration_s = 2.0\n"placement.robots" = 10\n'


def _one_line_error(err: str, needle: str) -> None:
    assert err.startswith("kilonet: error: "), err
    assert err.count("\n") == 1, err
    assert needle in err, err


def _snapshot(directory: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(directory.iterdir())}


def _own_files(directory: Path) -> dict[str, bytes]:
    """The store's own files: a read-only SQLite reader of a healthy store may leave the
    empty write-ahead-log files beside it (documented in kilonet.experiments.store)."""
    return {k: v for k, v in _snapshot(directory).items() if not k.endswith(("-wal", "-shm"))}


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished four-run sweep directory (copied by tests that change it)."""
    out = tmp_path_factory.mktemp("finished") / "out"
    run_sweep(parse_sweep(SMALL, name="small"), out, workers=1, progress=False, source=SMALL)
    return out


def _copy(finished: Path, to: Path) -> Path:
    shutil.copytree(finished, to)
    return to


# ---------------------------------------------------------------------------- a running sweep


@pytest.mark.parametrize("replace", [True, False])
def test_a_run_never_replaces_the_directory_of_a_running_sweep(tmp_path, finished, capsys, replace):
    out = _copy(finished, tmp_path / "D")
    argv = ["run", "gradient", "--robots", "10", "--duration", "2", "--out", str(out)]
    with lock_directory(out):  # the running sweep
        before = _snapshot(out)
        assert kilonet.app.cli.main(argv + (["--replace"] if replace else [])) == 2
        _one_line_error(
            capsys.readouterr().err,
            f"{out} is in use by a running sweep (pid {os.getpid()}) holding its lock "
            f"{out / '.sweep.lock'}",
        )
        assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]  # no staging left beside it


def test_a_sweep_that_starts_during_the_run_is_not_swapped_out(tmp_path, finished):
    out = _copy(finished, tmp_path / "D")
    with OutputDir(out, replace=True) as run:
        (run.staging / "summary.json").write_text("{}")
        with lock_directory(out):  # the sweep starts while the run simulates
            before = _snapshot(out)
            with pytest.raises(DirectoryInUse, match=r"in use by a running sweep \(pid \d+\)"):
                run.publish()
            assert _snapshot(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]


def test_without_replace_a_directory_that_appeared_during_the_run_is_kept(tmp_path):
    target = tmp_path / "D"
    with OutputDir(target) as run:
        (run.staging / "summary.json").write_text('{"new": true}')
        target.mkdir()
        (target / "results.sqlite").write_text("theirs")
        with pytest.raises(OutputDirError, match="D appeared during the run and is not empty"):
            run.publish()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]
    assert (target / "results.sqlite").read_text() == "theirs"


def test_replace_of_a_finished_sweep_leaves_no_lock_behind(tmp_path, finished):
    out = _copy(finished, tmp_path / "D")
    with OutputDir(out, replace=True) as run:
        (run.staging / "summary.json").write_text("{}")
        run.publish()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["D"]
    assert sorted(p.name for p in out.iterdir()) == ["summary.json"]


# ---------------------------------------------------------------------------- run directories


def test_a_relative_out_survives_a_chdir_during_the_run(tmp_path, monkeypatch):
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path)
    with OutputDir("runs/one") as run:
        monkeypatch.chdir(tmp_path / "elsewhere")  # a robot program's os.chdir()
        (run.staging / "summary.json").write_text("{}")
        assert run.publish() == tmp_path / "runs" / "one"
    assert (tmp_path / "runs" / "one" / "summary.json").exists()
    assert sorted(p.name for p in (tmp_path / "elsewhere").iterdir()) == []
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["one"]


def test_staging_left_by_a_killed_run_is_cleared_a_live_ones_and_others_kept(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    stale = tmp_path / f".out.{int(dead.stdout)}.ab12cd34"
    live = tmp_path / f".out.{os.getppid()}.ab12cd34"
    other = tmp_path / ".out.notes"  # not named like a staging directory: not ours
    for path in (stale, live, other):
        path.mkdir()
        (path / "robots.csv").write_text("robot\n0\n")
    with OutputDir(tmp_path / "out") as run:
        (run.staging / "summary.json").write_text("{}")
        run.publish()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out", live.name, other.name])


def test_a_run_killed_outright_leaves_staging_the_next_run_clears(tmp_path):
    code = (
        "import os, sys; from kilonet.scenarios.output_dir import OutputDir; "
        "OutputDir(sys.argv[1]); os._exit(9)"  # dies like kill -9: no clean-up runs
    )
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "out")], check=False)
    (left,) = tmp_path.iterdir()
    assert left.name.startswith(".out.")
    with OutputDir(tmp_path / "out") as run:
        run.publish()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ---------------------------------------------------------------------------- store trust


@pytest.mark.parametrize(
    "edit",
    [
        lambda d: {**d, "seeds": [-12, *d["seeds"][1:]]},
        lambda d: {**d, "scenario": "follower"},
    ],
    ids=["seed", "scenario"],
)
@pytest.mark.parametrize("command", ["resume", "sweep", "report"])
def test_an_edited_definition_is_refused_in_one_line(tmp_path, finished, capsys, edit, command):
    out = _copy(finished, tmp_path / "out")
    with sqlite3.connect(out / DB_NAME) as db:
        (text,) = db.execute("SELECT value FROM meta WHERE key = 'sweep'").fetchone()
        edited = json.dumps(edit(json.loads(text)))
        db.execute("UPDATE meta SET value = ? WHERE key = 'sweep'", (edited,))
    db.close()
    before = _snapshot(out)
    (tmp_path / "s.toml").write_text(SMALL)
    argv = {
        "resume": ["sweep", "--resume", "--out", str(out), "--no-progress"],
        "sweep": ["sweep", str(tmp_path / "s.toml"), "--out", str(out), "--no-progress"],
        "report": ["report", str(out), "--out", str(tmp_path / "r.html")],
    }[command]
    assert kilonet.app.cli.main(argv) == 2
    _one_line_error(
        capsys.readouterr().err,
        f"{out / DB_NAME}: the stored sweep definition does not match its checksum",
    )
    assert _own_files(out) == before
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("damage", ["empty", "truncated"])
@pytest.mark.parametrize("command", ["sweep", "resume", "report"])
def test_a_damaged_store_is_refused_without_a_byte_written(tmp_path, finished, damage, command):
    out = _copy(finished, tmp_path / "out")
    data = (out / DB_NAME).read_bytes()
    (out / DB_NAME).write_bytes({"empty": b"", "truncated": data[:3000]}[damage])
    before = _snapshot(out)
    (tmp_path / "s.toml").write_text(SMALL)
    argv = {
        "sweep": ["sweep", str(tmp_path / "s.toml"), "--out", str(out), "--no-progress"],
        "resume": ["sweep", "--resume", "--out", str(out), "--no-progress"],
        "report": ["report", str(out), "--out", str(tmp_path / "r.html")],
    }[command]
    assert kilonet.app.cli.main(argv) == 2
    assert _snapshot(out) == before  # same bytes, and no -wal / -shm beside it


def test_report_reads_a_store_on_a_read_only_file_system(tmp_path, finished):
    mount = tmp_path / "ro"
    mount.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(mount)], capture_output=True
    )
    if made.returncode != 0:
        pytest.skip("mounting a file system needs root")
    try:
        out = _copy(finished, mount / "out")
        subprocess.run(["mount", "-o", "remount,ro", str(mount)], check=True)
        done = subprocess.run(
            [sys.executable, "-c", _CLI, "report", str(out), "--out", str(tmp_path / "r.md")],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        assert "4 in 2 cells: 4 ok, 0 failed" in (tmp_path / "r.md").read_text()
    finally:
        subprocess.run(["umount", str(mount)], check=True)


def test_a_store_that_could_not_be_made_whole_is_not_left_behind(tmp_path):
    # file-size limits that fail the store at each step of its making and first use
    limits = [4_000, 12_000, 24_000, 40_000]
    for limit in limits:
        work = tmp_path / str(limit)
        work.mkdir()
        (work / "s.toml").write_text(SMALL)
        argv = ["sweep", "s.toml", "--out", "out", "--workers", "1", "--no-progress"]
        done = _kilonet(argv, limit, work)
        assert done.returncode in (1, 2) and done.stderr.count("\n") == 1, (limit, done.stderr)
        if (work / "out").exists():  # a store is kept only with a stored run
            with ResultStore.open(work / "out", read_only=True) as store:
                assert store.records(), (limit, sorted(os.listdir(work / "out")))
        assert sorted(p.name for p in work.iterdir() if p.name != "out") == ["s.toml"]


# ---------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("address", ["not a url", "tcp://127.0.0.1:notaport"])
def test_a_bad_scheduler_address_is_one_line_no_hang_nothing_left(tmp_path, address):
    (tmp_path / "s.toml").write_text(TINY)
    done = subprocess.run(
        [sys.executable, "-c", _CLI, "sweep", "s.toml", "--out", "out", "--scheduler", address],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=60,
    )
    assert done.returncode == 2
    _one_line_error(done.stderr, f"--scheduler {address!r}: ")
    assert "give [tcp://]HOST:PORT" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


@pytest.mark.parametrize(
    ("seeds", "needle"),
    [
        ("[18446744073709551617]", "seeds: 18446744073709551617 is out of range"),
        (
            "{first = 9223372036854775807, count = 2}",
            "the last seed 9223372036854775808 is out of range",
        ),
    ],
)
def test_a_seed_beyond_the_store_is_refused_before_running(tmp_path, capsys, seeds, needle):
    (tmp_path / "s.toml").write_text(TINY.replace("seeds = 2", f"seeds = {seeds}"))
    argv = ["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out")]
    assert kilonet.app.cli.main(argv) == 2
    err = capsys.readouterr().err
    _one_line_error(err, needle)
    assert err.endswith("; seeds are integers from 0 to 9223372036854775807\n"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.toml"]


def test_the_largest_seed_is_stored_and_read_back(tmp_path):
    sweep = parse_sweep(TINY.replace("seeds = 2", "seeds = [9223372036854775807]"), name="t")
    outcome = run_sweep(sweep, tmp_path / "out", workers=1, progress=False)
    assert outcome.ok == 1
    with ResultStore.open(tmp_path / "out", read_only=True) as store:
        assert [r.seed for r in store.records()] == [2**63 - 1]


def test_a_metric_that_is_not_a_number_is_refused(tmp_path, finished, capsys):
    argv = ["report", str(finished), "--out", str(tmp_path / "r.html"), "--metric", "scenario"]
    assert kilonet.app.cli.main(argv) == 2
    err = capsys.readouterr().err
    _one_line_error(err, "--metric 'scenario' is not a numeric result (a run reports 'gradient')")
    assert "numeric results: " in err and "last_change_s" in err
    assert not (tmp_path / "r.html").exists()


# ---------------------------------------------------------------------------- the process


def _sweep_stderr(tmp_path: Path, stderr: int) -> None:
    """Run the tiny sweep in ``tmp_path`` (made here) with stderr on file descriptor
    ``stderr``."""
    tmp_path.mkdir()
    (tmp_path / "s.toml").write_text(TINY)
    subprocess.run(
        [sys.executable, "-c", _CLI, "sweep", "s.toml", "--out", "out", "--workers", "1"],
        stderr=stderr,
        stdout=subprocess.DEVNULL,
        cwd=tmp_path,
        timeout=120,
        check=True,
    )


def test_the_progress_bar_goes_to_a_terminal_only(tmp_path):
    with open(tmp_path / "err.txt", "w") as err:
        _sweep_stderr(tmp_path / "file", err.fileno())
    assert (tmp_path / "err.txt").read_text() == (
        "sweep s: 2 runs; 2 run now (0 failed); results in out\n"
    )
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 80, 0, 0))  # 80 columns
    try:
        _sweep_stderr(tmp_path / "tty", child)
        os.close(child)
        child = -1
        seen = b""
        while True:
            try:
                chunk = os.read(main, 4096)
            except OSError:  # the terminal's other end is closed: all read
                break
            if not chunk:
                break
            seen += chunk
    finally:
        os.close(main)
        if child != -1:
            os.close(child)
    assert b"2/2 runs" in seen and b"results in out" in seen


def test_terminating_the_local_pool_leaves_no_manager_thread_for_exit_to_race():
    executor = cf.ProcessPoolExecutor(1)
    executor.submit(time.sleep, 30)
    time.sleep(0.2)
    manager = executor._executor_manager_thread
    assert manager is not None and manager.is_alive()
    _terminate_local(executor)
    assert not manager.is_alive()
