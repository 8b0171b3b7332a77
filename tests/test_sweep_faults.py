"""Sweeps and reports under faults: a damaged or edited store, a full disk, two sweeps on one
directory, a stale lock, a killed parent, a cluster without workers, a shadowing working
directory. Each failure must be one line on stderr and leave the stored runs intact."""

from __future__ import annotations

import json
import os
import resource
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from test_experiments import SMALL  # four runs of 20 robots for 5 s

import kilonet.app.cli
from kilonet.experiments.runner import WorkerWatch, run_sweep
from kilonet.experiments.store import (
    DB_NAME,
    ResultStore,
    RunRecord,
    StoreError,
    lock_directory,
    row_checksum,
)
from kilonet.experiments.sweep import parse_sweep

_CLI = "import sys, kilonet.app.cli as c; sys.exit(c.main(sys.argv[1:]))"


def _one_line_error(err: str, needle: str) -> None:
    assert err.startswith("kilonet: error: "), err
    assert err.count("\n") == 1, err
    assert needle in err, err


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished four-run sweep directory (copied by tests that damage it)."""
    out = tmp_path_factory.mktemp("finished") / "out"
    run_sweep(parse_sweep(SMALL, name="small"), out, workers=1, progress=False, source=SMALL)
    return out


def _copy(finished: Path, to: Path) -> Path:
    to.mkdir()
    for name in (DB_NAME, "sweep.toml"):
        (to / name).write_bytes((finished / name).read_bytes())
    return to


def _record(run_id: str, value: float) -> RunRecord:
    return RunRecord(
        run_id=run_id,
        cell={"medium.loss_prob": value},
        seed=1,
        status="ok",
        error=None,
        wall_s=0.5,
        worker="here:1",
        finished_at="2026-01-01T00:00:00+00:00",
        summary={"hits": value, "t_s": {"ids": 8.0}},
    )


# ---------------------------------------------------------------------------- damaged stores


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
@pytest.mark.parametrize("command", ["sweep", "resume", "report"])
def test_a_damaged_store_is_one_line_exit_2(tmp_path, finished, capsys, damage, command):
    out = _copy(finished, tmp_path / "out")
    data = (finished / DB_NAME).read_bytes()
    (out / DB_NAME).write_bytes(
        {"truncated": data[:3000], "garbage": b"not sqlite " * 400, "empty": b""}[damage]
    )
    (tmp_path / "s.toml").write_text(SMALL)
    argv = {
        "sweep": ["sweep", str(tmp_path / "s.toml"), "--out", str(out), "--no-progress"],
        "resume": ["sweep", "--resume", "--out", str(out), "--no-progress"],
        "report": ["report", str(out), "--out", str(tmp_path / "r.html")],
    }[command]
    assert kilonet.app.cli.main(argv) == 2
    err = capsys.readouterr().err
    _one_line_error(err, f"{out / DB_NAME}: not a readable sweep store")
    assert not (tmp_path / "r.html").exists()


def test_an_edited_digit_in_a_summary_is_refused_not_reported(tmp_path, finished, capsys):
    out = _copy(finished, tmp_path / "out")
    with sqlite3.connect(out / DB_NAME) as db:
        run_id, summary = db.execute("SELECT run_id, summary FROM runs LIMIT 1").fetchone()
        figures = json.loads(summary)
        figures["messages_sent"] += 1
        db.execute("UPDATE runs SET summary = ? WHERE run_id = ?", (json.dumps(figures), run_id))
    assert kilonet.app.cli.main(["report", str(out), "--out", str(tmp_path / "r.html")]) == 2
    _one_line_error(capsys.readouterr().err, f"row of run {run_id} does not match its checksum")
    assert not (tmp_path / "r.html").exists()
    # resuming on top of a changed row is refused too
    assert kilonet.app.cli.main(["sweep", "--resume", "--out", str(out), "--no-progress"]) == 2
    _one_line_error(capsys.readouterr().err, "does not match its checksum")


def test_a_schema_1_store_is_upgraded_and_then_checked(tmp_path):
    # the tables an older kilonet made: no checksum column
    out = tmp_path / "old"
    out.mkdir()
    sweep = parse_sweep(SMALL, name="small")
    with sqlite3.connect(out / DB_NAME) as db:
        db.executescript(
            "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);"
            "CREATE TABLE runs (run_id TEXT PRIMARY KEY, cell TEXT NOT NULL, seed INTEGER NOT "
            "NULL, status TEXT NOT NULL, error TEXT, wall_s REAL, worker TEXT NOT NULL, "
            "finished_at TEXT NOT NULL, summary TEXT);"
        )
        db.execute("INSERT INTO meta VALUES ('schema', '1')")
        db.execute("INSERT INTO meta VALUES ('sweep', ?)", (json.dumps(sweep.to_dict()),))
        db.execute(
            "INSERT INTO runs VALUES ('r1', '{\"medium.loss_prob\": 0.0}', 1, 'ok', NULL, 0.5, "
            "'h:1', '2026-01-01T00:00:00+00:00', '{\"hits\": 3}')"
        )
    with ResultStore.open(out) as store:
        (rec,) = store.records()
        assert (rec.run_id, rec.summary) == ("r1", {"hits": 3})
    with sqlite3.connect(out / DB_NAME) as db:
        meta = dict(db.execute("SELECT key, value FROM meta"))
        assert (meta["schema"], meta["upgraded_from_schema"]) == ("3", "1")
        db.execute("UPDATE runs SET summary = '{\"hits\": 4}'")
    with ResultStore.open(out) as store, pytest.raises(StoreError, match="checksum"):
        store.records()


def test_row_checksum_covers_every_stored_column(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    with ResultStore.create_or_open(tmp_path, sweep) as store:
        store.append(_record("a", 0.0))
    with sqlite3.connect(tmp_path / DB_NAME) as db:
        columns = db.execute(
            "SELECT run_id, cell, seed, status, error, wall_s, worker, finished_at, summary, "
            "checksum FROM runs"
        ).fetchone()
    assert columns[-1] == row_checksum(columns[:-1])
    for i, changed in enumerate(["b", "{}", 2, "failed", "x", 0.6, "h:2", "2027", '{"hits": 1}']):
        assert row_checksum((*columns[:i], changed, *columns[i + 1 : -1])) != columns[-1]


# ---------------------------------------------------------------------------- full disk


def _limited(limit_bytes: int):
    """A child whose files cannot grow past ``limit_bytes``: writes fail as on a full disk."""

    def preexec() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return preexec


def _kilonet(argv: list[str], limit_bytes: int, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", _CLI, *argv],
        preexec_fn=_limited(limit_bytes),
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def test_a_new_sweep_on_a_full_disk_leaves_nothing_behind(tmp_path):
    (tmp_path / "s.toml").write_text(SMALL)
    argv = ["sweep", "s.toml", "--out", "out", "--workers", "1", "--no-progress"]
    done = _kilonet(argv, 0, tmp_path)
    assert done.returncode == 2
    _one_line_error(done.stderr, "out: cannot create the results store")
    assert not (tmp_path / "out").exists()
    # with space again the same command works: no half-made store blocks the directory
    assert (
        kilonet.app.cli.main(["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out")])
        == 0
    )


def test_a_disk_filling_mid_sweep_stops_with_one_line_and_resumes(tmp_path):
    (tmp_path / "s.toml").write_text(SMALL.replace("seeds = 2", "seeds = 6"))
    argv = ["sweep", "s.toml", "--out", "out", "--workers", "1", "--no-progress"]
    # room for the store and a few rows, not for the write-ahead log of twelve
    done = _kilonet(argv, 60_000, tmp_path)
    assert done.returncode == 1, done.stderr
    assert done.stderr.startswith("kilonet: sweep stopped: ") and done.stderr.count("\n") == 1
    assert "cannot store run" in done.stderr and "run the same command to resume" in done.stderr
    with ResultStore.open(tmp_path / "out") as store:
        kept = store.records()
    assert 0 < len(kept) < 12
    assert not (tmp_path / "out" / ".sweep.lock").exists()
    outcome = run_sweep(
        parse_sweep((tmp_path / "s.toml").read_text(), name="s"), tmp_path / "out", workers=1
    )
    assert (outcome.already_stored, outcome.ok) == (len(kept), 12 - len(kept))


def test_a_report_on_a_full_disk_is_one_line_and_leaves_no_file(tmp_path, finished):
    out = _copy(finished, tmp_path / "out")
    done = _kilonet(["report", str(out), "--out", "r.html"], 100_000, tmp_path)
    assert done.returncode == 1
    assert done.stderr == "kilonet: error: cannot write r.html: File too large\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ---------------------------------------------------------------------------- the lock


def test_a_refused_second_sweep_changes_nothing_of_the_running_one(tmp_path, capsys):
    out = tmp_path / "out"
    (tmp_path / "s.toml").write_text(SMALL)
    assert kilonet.app.cli.main(["sweep", str(tmp_path / "s.toml"), "--out", str(out)]) == 0
    capsys.readouterr()
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with ResultStore.open(out) as store:
        meta_before = (store.sweep(), store.source())
    (tmp_path / "v2.toml").write_text('description = "v2"\n' + SMALL + '[report]\nxscale = "log"\n')
    with lock_directory(out):  # the running sweep
        argv = ["sweep", str(tmp_path / "v2.toml"), "--out", str(out), "--no-progress"]
        assert kilonet.app.cli.main(argv) == 2
    _one_line_error(capsys.readouterr().err, f"{out} is in use by a running sweep (pid ")
    with ResultStore.open(out) as store:
        assert (store.sweep(), store.source()) == meta_before
    assert (out / "sweep.toml").read_bytes() == before["sweep.toml"]


def test_the_lock_file_goes_with_the_sweep(tmp_path):
    out = tmp_path / "out"
    run_sweep(parse_sweep(SMALL, name="small"), out, workers=1, progress=False)
    assert sorted(p.name for p in out.iterdir()) == [DB_NAME]
    # a lock file a killed sweep left behind does not make the directory foreign
    (tmp_path / "new").mkdir()
    (tmp_path / "new" / ".sweep.lock").write_text("pid 99999\n")
    outcome = run_sweep(parse_sweep(SMALL, name="small"), tmp_path / "new", workers=1)
    assert outcome.ok == 4 and not (tmp_path / "new" / ".sweep.lock").exists()


def test_an_unfinished_store_of_a_killed_creator_is_removed_a_live_ones_kept(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        capture_output=True,
        text=True,
        check=True,
    )
    out = tmp_path / "new"
    out.mkdir()
    stale = out / f".{DB_NAME}.{int(dead.stdout)}.tmp"
    live = out / f".{DB_NAME}.{os.getppid()}.tmp"
    for path in (stale, Path(f"{stale}-journal"), live):
        path.write_bytes(b"half a database")
    outcome = run_sweep(parse_sweep(SMALL, name="small"), out, workers=1, progress=False)
    assert outcome.ok == 4
    assert sorted(p.name for p in out.iterdir()) == sorted([DB_NAME, live.name])


def test_a_refused_sweep_into_a_new_directory_leaves_no_directory(tmp_path):
    with lock_directory(tmp_path / "a" / "b"):
        with (
            pytest.raises(StoreError, match="in use by a running sweep"),
            lock_directory(tmp_path / "a" / "b"),
        ):
            pass
        assert (tmp_path / "a" / "b").is_dir()
    assert not (tmp_path / "a" / "b").exists()


def test_sweeps_started_at_the_same_instant_one_wins_the_others_say_in_use(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    out = tmp_path / "out"
    barrier = threading.Barrier(6)
    errors: list[str] = []
    wins: list[int] = []

    def start(i: int) -> None:
        barrier.wait()
        try:
            with lock_directory(out), ResultStore.create_or_open(out, sweep, source=SMALL):
                wins.append(i)
                time.sleep(0.3)  # the winner is still writing when the others try
        except StoreError as exc:
            errors.append(str(exc))

    for _ in range(5):
        threads = [threading.Thread(target=start, args=(i,)) for i in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert len(wins) >= 5 and len(wins) + len(errors) == 30
    assert all("is in use by a running sweep" in e for e in errors), errors
    with ResultStore.open(out) as store:
        assert store.sweep() == sweep


def test_a_store_created_by_another_process_meanwhile_is_opened(tmp_path, monkeypatch):
    # the other sweep links its store in between our look and our link
    import kilonet.experiments.store as store_module

    sweep = parse_sweep(SMALL, name="small")
    original = store_module._create_database

    def racing(path: Path, sweep_: object) -> None:
        original(path, sweep_)  # "theirs"
        original(path, sweep_)  # ours: must find theirs, not overwrite it

    monkeypatch.setattr(store_module, "_create_database", racing)
    with ResultStore.create_or_open(tmp_path, sweep) as store:
        assert store.sweep() == sweep
    assert sorted(p.name for p in tmp_path.iterdir()) == [DB_NAME]


# ---------------------------------------------------------------------------- processes


def _descendants(pid: int) -> set[int]:
    """Every live process below ``pid`` (from /proc), e.g. a sweep's fork server, resource
    tracker and workers."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            parents[int(entry.name)] = int(stat.rpartition(")")[2].split()[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_kill_9_of_a_sweep_leaves_no_process_behind(tmp_path):
    sweep_file = tmp_path / "long.toml"
    sweep_file.write_text(
        SMALL.replace("seeds = 2", "seeds = 20").replace("duration_s = 5.0", "duration_s = 60.0")
    )
    out = tmp_path / "out"
    argv = [sys.executable, "-c", _CLI, "sweep", str(sweep_file), "--out", str(out)]
    process = subprocess.Popen([*argv, "--workers", "2", "--no-progress"], stderr=subprocess.PIPE)
    try:
        db = out / DB_NAME
        helpers: set[int] = set()
        deadline = time.monotonic() + 120
        # two workers, the fork server and the resource tracker, and a first run stored
        while process.poll() is None and time.monotonic() < deadline:
            helpers = _descendants(process.pid)
            if len(helpers) >= 4 and db.exists() and _rows(db) >= 1:
                break
            time.sleep(0.05)
        assert process.poll() is None, process.stderr.read()
        assert len(helpers) >= 4, helpers
        process.kill()
        process.wait()
        deadline = time.monotonic() + 60
        while any(_alive(p) for p in helpers) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = sorted(p for p in helpers if _alive(p))
    finally:
        for pid in _descendants(process.pid) | helpers:  # only ours, by pid
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
        process.kill()
        process.wait()
    assert left == [], f"processes left behind: {left}"
    assert 1 <= len(stored_runs(out)) < 40  # the rows stored before the kill are intact


def _rows(db: Path) -> int:
    try:
        with sqlite3.connect(db) as conn:
            return conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


def stored_runs(out: Path) -> list[RunRecord]:
    with ResultStore.open(out) as store:
        return store.records()


def test_a_cluster_without_workers_stops_the_sweep_with_one_line(tmp_path, capsys):
    from distributed import LocalCluster

    sweep_file = tmp_path / "small.toml"
    sweep_file.write_text(SMALL)
    out = tmp_path / "out"
    with LocalCluster(n_workers=0, processes=True, dashboard_address=None) as cluster:
        argv = ["sweep", str(sweep_file), "--out", str(out), "--no-progress"]
        argv += ["--scheduler", cluster.scheduler_address, "--no-workers-timeout", "1.5"]
        assert kilonet.app.cli.main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith(
        f"kilonet: sweep stopped: the Dask cluster at {cluster.scheduler_address} has had no "
        "workers for 1.5 s (4 runs waiting); start workers, then run the same command"
    )
    assert not out.exists()  # a sweep that stored no run leaves no empty store behind


def test_worker_watch_resets_when_workers_come_back():
    watch = WorkerWatch(5.0)
    states = []
    for now, workers in [(0, 2), (1, 0), (3, 0), (5, 1), (6, 0), (10, 0), (11, 0)]:
        watch = watch.observe(workers, now)
        states.append((watch.empty_since_s, watch.expired(now)))
    assert states == [
        (None, False),
        (1, False),
        (1, False),
        (None, False),
        (6, False),
        (6, False),
        (6, True),
    ]


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_no_workers_timeout_must_be_positive(tmp_path, capsys, value):
    (tmp_path / "s.toml").write_text(SMALL)
    argv = ["sweep", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out")]
    assert kilonet.app.cli.main([*argv, "--no-workers-timeout", value]) == 2
    _one_line_error(capsys.readouterr().err, "--no-workers-timeout must be a number of seconds")
    assert not (tmp_path / "out").exists()


def test_a_folder_named_like_a_package_in_the_working_directory_shadows_nothing(tmp_path):
    # what the `kilonet` console script does: the working directory is not on the sweep's path
    script = Path(sys.executable).with_name("kilonet")
    if not script.exists():
        pytest.skip("the kilonet console script is not installed beside this Python")
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "__init__.py").write_text('"""my own scenario notes"""\n')
    (tmp_path / "s.toml").write_text(SMALL)
    argv = [str(script), "sweep", "s.toml", "--out", "out", "--workers", "2", "--no-progress"]
    done = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert {r.status for r in stored_runs(tmp_path / "out")} == {"ok"}
    assert len(stored_runs(tmp_path / "out")) == 4
