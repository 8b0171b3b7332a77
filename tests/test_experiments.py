"""Tests for experiments: sweep files, the results store, the runner (local pool, interrupts,
resume, Dask), reports and the ``sweep`` / ``report`` sub-commands."""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import dask
import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure
from scipy import stats

import kilonet.app.cli
from kilonet import scenarios
from kilonet.experiments import cli as experiments_cli
from kilonet.experiments.report import (
    ReportError,
    aggregate,
    failures,
    load,
    metrics_of,
    plot,
    write_report,
)
from kilonet.experiments.runner import _record_of, execute_run, run_sweep
from kilonet.experiments.store import DB_NAME, ResultStore, RunRecord, StoreError
from kilonet.experiments.sweep import SweepError, load_sweep, parse_sweep

# Small and short runs: 20 robots, 5 simulated seconds (a few hundredths of a second each).
SMALL = """
scenario = "gradient"
seeds = 2
[fixed]
duration_s = 5.0
"placement.robots" = 20
[grid]
"medium.loss_prob" = [0.0, 0.3]
"""

# Half of the cells fail inside the worker: source 30 of 20 robots is rejected at run time.
FLAKY = """
name = "flaky"
scenario = "gradient"
seeds = 3
[fixed]
duration_s = 5.0
"placement.robots" = 20
[grid]
"gradient.source" = [0, 30]
"medium.loss_prob" = [0.0, 0.3]
[report]
x = "medium.loss_prob"
metrics = ["receptions_delivered", "last_change_s"]
"""


def stored_ids(directory: Path) -> list[str]:
    with ResultStore.open(directory) as store:
        return [r.run_id for r in store.records()]


# ---------------------------------------------------------------------------- sweep files


def test_sweep_expands_grid_cases_and_seeds_in_seed_major_order():
    sweep = parse_sweep(
        """
        scenario = "gradient"
        seeds = {first = 7, count = 2}
        [fixed.medium]
        range_mm = 90.0
        [grid]
        "placement.robots" = {start = 10, stop = 30, step = 10}
        [[cases]]
        "placement.kind" = "hex"
        [[cases]]
        "placement.kind" = "line"
        """,
        name="demo",
    )
    assert sweep.name == "demo"
    assert sweep.fixed == {"medium.range_mm": 90.0}
    assert sweep.grid == {"placement.robots": [10, 20, 30]}
    assert sweep.swept == ["placement.kind", "placement.robots"]
    cells = sweep.cells()
    assert cells[0] == {"placement.kind": "hex", "placement.robots": 10}
    assert cells[-1] == {"placement.kind": "line", "placement.robots": 30}
    runs = sweep.runs()
    assert len(runs) == 12
    assert [r.seed for r in runs] == [7] * 6 + [8] * 6
    assert runs[4].overrides == {
        "medium.range_mm": 90.0,
        "placement.kind": "line",
        "placement.robots": 20,
    }
    assert len({r.run_id for r in runs}) == 12
    # identities depend on the run, not on the file: parsing again gives the same ids
    assert [r.run_id for r in sweep.runs()] == [r.run_id for r in runs]


def test_sweep_ranges_round_and_keep_integers():
    sweep = parse_sweep(
        """
        scenario = "gradient"
        [grid]
        "medium.loss_prob" = {start = 0.0, stop = 0.3, step = 0.1}
        "placement.robots" = {start = 50, stop = 800, num = 5, log = true}
        "ranging.sigma_mm" = {start = 0.5, stop = 0.5, num = 1}
        """,
        name="r",
    )
    assert sweep.grid["medium.loss_prob"] == [0.0, 0.1, 0.2, 0.3]
    assert sweep.grid["placement.robots"] == [50, 100, 200, 400, 800]
    assert sweep.grid["ranging.sigma_mm"] == [0.5]
    assert sweep.seeds == (1,)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('scenario = "gradient"\nseed = 3', "unknown key 'seed'"),
        ("seeds = 2", "missing key 'scenario'"),
        ('scenario = "nope"', "unknown scenario 'nope'"),
        ('scenario = "gradient"\nseeds = 0', "seeds = 0"),
        ('scenario = "gradient"\nseeds = [1, 1]', "repeats a seed"),
        (
            'scenario = "gradient"\n[grid]\n"medium.los" = [1]',
            "[grid] unknown parameter 'medium.los'",
        ),
        (
            'scenario = "gradient"\n[grid]\n"medium.loss_prob" = [0.5, 2.0]',
            "[grid] medium.loss_prob = 2.0 is out of range",
        ),
        (
            'scenario = "gradient"\n[grid]\n"medium.loss_prob" = 0.5',
            "[grid] medium.loss_prob must be",
        ),
        (
            'scenario = "gradient"\n[grid]\n"medium.loss_prob" = []',
            "[grid] medium.loss_prob has no",
        ),
        (
            'scenario = "gradient"\n[grid]\n"medium.loss_prob" = {start = 0, stop = 1}',
            "exactly one of 'num' and 'step'",
        ),
        (
            'scenario = "gradient"\n[grid]\n"medium.loss_prob" = '
            "{start = 0.5, stop = 0.1, step = 0.1}",
            "never reaches stop",
        ),
        ('scenario = "gradient"\n[fixed]\nseed = 4', "[fixed] seed"),
        (
            'scenario = "gradient"\n[fixed]\nduration_s = 1.0\n[grid]\nduration_s = [1.0, 2.0]',
            "duration_s is both in [fixed] and in [grid]",
        ),
        ('scenario = "gradient"\n[fixed]\n"robot.rx_mode" = "radio"', "[fixed] robot.rx_mode"),
        (
            'scenario = "gradient"\n[grid]\n"battery.cutoff_v" = [3.0, 3.7]',
            "battery.cutoff_v (3.7) must be below",
        ),
        (
            'scenario = "gradient"\n[report]\nx = "medium.loss_prob"',
            "[report] x = 'medium.loss_prob'",
        ),
        ('scenario = "gradient"\n[report]\nxscale = "cubic"', "[report] xscale"),
        ('scenario = "gradient"\n[grid', "not valid TOML"),
    ],
)
def test_sweep_errors_name_file_and_key(text, message):
    with pytest.raises(SweepError) as info:
        parse_sweep(text, name="s.toml")
    assert str(info.value).startswith("s.toml: ")
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_load_sweep_missing_file(tmp_path):
    with pytest.raises(SweepError, match=r"no such sweep file"):
        load_sweep(tmp_path / "none.toml")


def test_shipped_sweeps_are_valid():
    shipped = sorted(Path(experiments_cli.__file__).parent.glob("*.toml"))
    assert len(shipped) >= 5
    for path in shipped:
        sweep = load_sweep(path)
        assert sweep.name == path.stem
        assert sweep.description
        assert sweep.report.metrics
        # every cell runs once per seed, and each sweep has more than one cell
        assert len(sweep.runs()) == len(sweep.cells()) * len(sweep.seeds) >= 20


# ---------------------------------------------------------------------------- store


def record(run_id: str, status: str = "ok", value: float = 1.0) -> RunRecord:
    return RunRecord(
        run_id=run_id,
        cell={"medium.loss_prob": value},
        seed=1,
        status=status,
        error=None if status == "ok" else "RuntimeError: boom",
        wall_s=0.5,
        worker="here:1",
        finished_at="2026-01-01T00:00:00+00:00",
        summary=(
            {"seed": 1, "wall_s": 9.0, "hits": value, "t_s": {"ids": 8.0}, "ran": ["ids"]}
            if status == "ok"
            else None
        ),
    )


def test_store_never_duplicates_and_replaces_only_failures(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    with ResultStore.create_or_open(tmp_path / "d", sweep, source=SMALL) as store:
        assert store.append(record("a", "failed"))
        assert store.append(record("b", "ok", 2.0))
        assert not store.append(record("b", "ok", 3.0))  # an ok run is final
        assert store.append(record("a", "ok", 4.0))  # a retried failure is replaced
        assert not store.append(record("a", "failed"))
        assert store.counts() == {"ok": 2, "failed": 0}
        frame = store.frame()
    assert list(frame["run_id"]) == ["a", "b"]
    assert list(frame["hits"]) == [4.0, 2.0]
    # a summary figure named like a meta column is kept under a prefix; its seed is dropped
    assert list(frame["summary.wall_s"]) == [9.0, 9.0]
    # nested figures become columns: mappings by dotted name, lists as JSON text
    assert list(frame["t_s.ids"]) == [8.0, 8.0] and list(frame["ran"]) == ['["ids"]'] * 2
    assert list(frame.columns[:2]) == ["medium.loss_prob", "run_id"]
    assert (tmp_path / "d" / "sweep.toml").read_text() == SMALL


def test_store_refuses_another_sweep_and_foreign_directories(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    ResultStore.create_or_open(tmp_path / "d", sweep).close()
    other = parse_sweep(SMALL.replace("seeds = 2", "seeds = 3"), name="small")
    with pytest.raises(StoreError, match=r"different seeds; use another --out"):
        ResultStore.create_or_open(tmp_path / "d", other)
    # the same runs under a new description and [report]: the newer presentation is kept
    renamed = parse_sweep('description = "v2"\n' + SMALL, name="small")
    ResultStore.create_or_open(tmp_path / "d", renamed, source="v2").close()
    with ResultStore.open(tmp_path / "d") as store:
        assert (store.sweep().description, store.source()) == ("v2", "v2")
    (tmp_path / "e").mkdir()
    (tmp_path / "e" / "notes.txt").write_text("mine")
    with pytest.raises(StoreError, match=r"not empty and holds no sweep"):
        ResultStore.create_or_open(tmp_path / "e", sweep)
    with pytest.raises(StoreError, match=r"no sweep results here"):
        ResultStore.open(tmp_path / "e")


def test_store_lock_excludes_a_second_sweep(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    with ResultStore.create_or_open(tmp_path, sweep) as first, first.lock():
        second = ResultStore.open(tmp_path)
        with pytest.raises(StoreError, match=r"in use by a running sweep \(pid \d+\)"):
            second.lock().__enter__()
        second.close()
    with ResultStore.open(tmp_path) as again, again.lock():
        pass


# ---------------------------------------------------------------------------- runner


def test_execute_run_matches_a_direct_run_and_records_failures():
    sweep = parse_sweep(FLAKY, name="flaky")
    good, bad = sweep.runs()[0], sweep.runs()[2]
    assert good.cell["gradient.source"] == 0 and bad.cell["gradient.source"] == 30
    rec = execute_run(good)
    direct = scenarios.run(scenarios.get("gradient"), good.overrides, seed=good.seed).summary
    assert rec.status == "ok" and rec.error is None
    assert {k: v for k, v in rec.summary.items() if k != "wall_time_s"} == {
        k: v for k, v in direct.items() if k != "wall_time_s"
    }
    failed = execute_run(bad)
    assert failed.status == "failed" and failed.summary is None
    assert failed.error.startswith("ParamError: gradient.source = 30 but there are only 20 robots")
    assert "(at scenarios/gradient.py:" in failed.error


def test_failing_runs_are_stored_and_resume_runs_only_what_is_missing(tmp_path):
    sweep = parse_sweep(FLAKY, name="flaky")
    outcome = run_sweep(sweep, tmp_path, workers=2, progress=False)
    assert (outcome.total, outcome.already_stored, outcome.ok, outcome.failed) == (12, 0, 6, 6)
    _, results = load(tmp_path)
    assert sorted(results["run_id"]) == sorted(r.run_id for r in sweep.runs())
    failed = results[results["status"] == "failed"]
    assert set(failed["gradient.source"]) == {30}
    assert failed["error"].str.startswith("ParamError: gradient.source = 30").all()
    assert results.loc[results["status"] == "ok", "receptions_delivered"].gt(0).all()

    again = run_sweep(sweep, tmp_path, workers=2, progress=False)
    assert (again.already_stored, again.ok, again.failed) == (12, 0, 0)
    retried = run_sweep(sweep, tmp_path, workers=1, retry_failed=True, progress=False)
    assert (retried.already_stored, retried.ok, retried.failed) == (6, 0, 6)
    assert sorted(stored_ids(tmp_path)) == sorted(r.run_id for r in sweep.runs())


def test_sigterm_mid_sweep_then_resume_stores_each_run_once(tmp_path, monkeypatch):
    sweep = parse_sweep(FLAKY, name="flaky")
    original = ResultStore.append

    def append_then_terminate(self, rec):
        written = original(self, rec)
        if self.counts()["ok"] + self.counts()["failed"] == 4:
            os.kill(os.getpid(), signal.SIGTERM)  # delivered while the sweep waits for more
        return written

    monkeypatch.setattr(ResultStore, "append", append_then_terminate)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, tmp_path, workers=2, progress=False)
    monkeypatch.setattr(ResultStore, "append", original)
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # the sweep's handler is gone
    with ResultStore.open(tmp_path) as store:
        before = {r.run_id: r for r in store.records()}
    assert len(before) == 4

    outcome = run_sweep(sweep, tmp_path, workers=2, progress=False)
    assert outcome.already_stored == 4 and outcome.ok + outcome.failed == 8
    with ResultStore.open(tmp_path) as store:
        after = store.records()
    assert sorted(r.run_id for r in after) == sorted(r.run_id for r in sweep.runs())
    assert all(before[r.run_id] == r for r in after if r.run_id in before)  # rows untouched


def test_a_task_lost_by_the_executor_is_stored_as_failed(tmp_path):
    sweep = parse_sweep(SMALL, name="small")
    run = sweep.runs()[0]
    lost = cf.Future()
    lost.set_exception(RuntimeError("worker tcp://10.0.0.7:4000 died"))
    rec = _record_of(lost, run)
    assert (rec.status, rec.wall_s, rec.worker, rec.summary) == ("failed", None, "lost", None)
    assert rec.error.startswith("RuntimeError: worker tcp://10.0.0.7:4000 died")
    with ResultStore.create_or_open(tmp_path, sweep) as store:
        assert store.append(rec)
        assert store.records() == [rec]


_CLI = "import sys, kilonet.app.cli as c; sys.exit(c.main(sys.argv[1:]))"


def _as_from_a_terminal() -> None:
    """Give the child the signal state a shell gives a command: Ctrl-C unblocked and handled
    by default. Inside a long pytest run the parent's state can differ (in the full suite
    SIGINT never reached the child); a user's terminal does not pass that on."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_cli_sweep_interrupted_by_ctrl_c_then_resumed(tmp_path):
    sweep_file = tmp_path / "many.toml"
    # Runs long enough (about 0.2 s each) that a busy machine cannot finish all 40 between the
    # third stored run and the interrupt.
    sweep_file.write_text(
        SMALL.replace("seeds = 2", "seeds = 20").replace("duration_s = 5.0", "duration_s = 30.0")
    )
    sweep = load_sweep(sweep_file)
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-c", _CLI, "sweep", str(sweep_file), "--out", str(out), "--workers", "2"],
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=_as_from_a_terminal,
    )
    db = out / DB_NAME
    while process.poll() is None and _rows(db) < 3:
        time.sleep(0.02)
    assert process.poll() is None, "the sweep ended before it could be interrupted"
    process.send_signal(signal.SIGINT)
    _, err = process.communicate()
    assert process.returncode == 130
    assert "sweep interrupted;" in err and "run the same command to resume" in err
    assert "Traceback" not in err
    with ResultStore.open(out) as store:
        before = {r.run_id: r for r in store.records()}
    assert 3 <= len(before) < 40

    outcome = run_sweep(sweep, out, workers=2, progress=False)  # what the same command does
    assert (outcome.already_stored, outcome.ok) == (len(before), 40 - len(before))
    with ResultStore.open(out) as store:
        after = store.records()
    assert sorted(r.run_id for r in after) == sorted(r.run_id for r in sweep.runs())
    assert all(before[r.run_id] == r for r in after if r.run_id in before)


def _rows(db: Path) -> int:
    if not db.exists():
        return 0
    try:
        with sqlite3.connect(db) as conn:
            return conn.execute("SELECT COUNT(*) FROM runs").fetchone()[0]
    except sqlite3.OperationalError:  # created but its tables not committed yet
        return 0


def _stored_results(directory: Path) -> dict[str, tuple]:
    """Each stored run by id: what a sweep computes (cell, seed, status, error, summary), not
    where or how fast (worker, wall times, finish time)."""
    with ResultStore.open(directory) as store:
        records = store.records()
    return {
        r.run_id: (
            r.cell,
            r.seed,
            r.status,
            r.error,
            {k: v for k, v in (r.summary or {}).items() if k != "wall_time_s"},
        )
        for r in records
    }


def test_sweep_on_a_local_dask_cluster_stores_what_the_local_pool_stores(tmp_path, capsys):
    # The real path of `kilonet sweep --scheduler ADDRESS`: a scheduler and two worker processes
    # on this machine, tasks and records pickled across processes as on a cluster.
    from distributed import LocalCluster

    sweep_file = tmp_path / "small.toml"
    sweep_file.write_text(SMALL)
    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        argv = ["sweep", str(sweep_file), "--out", str(tmp_path / "dask"), "--no-progress"]
        assert kilonet.app.cli.main([*argv, "--scheduler", cluster.scheduler_address]) == 0
        with ResultStore.open(tmp_path / "dask") as store:
            workers = {r.worker for r in store.records()}
    assert "sweep small: 4 runs; 4 run now (0 failed)" in capsys.readouterr().err
    assert all(int(w.rpartition(":")[2]) != os.getpid() for w in workers)  # not in this process
    local = ["sweep", str(sweep_file), "--out", str(tmp_path / "local"), "--no-progress"]
    assert kilonet.app.cli.main([*local, "--workers", "2"]) == 0
    on_dask, on_pool = _stored_results(tmp_path / "dask"), _stored_results(tmp_path / "local")
    assert sorted(on_dask) == sorted(r.run_id for r in parse_sweep(SMALL, name="small").runs())
    assert on_dask == on_pool
    assert {s[2] for s in on_dask.values()} == {"ok"}
    assert all(s[4]["messages_sent"] > 0 for s in on_dask.values())


def test_sweep_with_an_unreachable_scheduler_stops_with_one_line(tmp_path, capsys):
    sweep_file = tmp_path / "small.toml"
    sweep_file.write_text(SMALL)
    argv = ["sweep", str(sweep_file), "--out", str(tmp_path / "out"), "--no-progress"]
    # A port nothing listens on; the client retries for its connect time-out (30 s by default).
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):
        assert kilonet.app.cli.main([*argv, "--scheduler", "tcp://127.0.0.1:9"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("kilonet: sweep stopped: cannot reach the Dask scheduler at tcp://")
    assert "Traceback" not in err


# ---------------------------------------------------------------------------- report


def test_aggregate_mean_std_and_student_t_interval():
    runs = pd.DataFrame(
        {
            "p": [0.1, 0.1, 0.1, 0.2, 0.2, 0.3],
            "status": ["ok", "ok", "ok", "ok", "failed", "ok"],
            "y": [1.0, 2.0, 6.0, 4.0, np.nan, 7.0],
        }
    )
    table = aggregate(runs, ["p"], ["y"], confidence=0.9)
    first = table.iloc[0]
    assert (first["runs"], first["mean"]) == (3, 3.0)
    assert first["std"] == pytest.approx(math.sqrt(7.0))
    half = stats.t.ppf(0.95, 2) * math.sqrt(7.0) / math.sqrt(3)
    assert (first["ci_low"], first["ci_high"]) == pytest.approx((3.0 - half, 3.0 + half))
    single = table.iloc[1]  # the failed run does not count
    assert (single["runs"], single["mean"]) == (1, 4.0)
    assert math.isnan(single["std"]) and math.isnan(single["ci_low"])
    assert list(table["p"]) == [0.1, 0.2, 0.3]


def test_plot_draws_a_line_and_band_per_other_parameter():
    agg = pd.DataFrame(
        {
            "q": ["a", "a", "b", "b"],
            "p": [0.2, 0.1, 0.1, 0.2],
            "metric": ["y"] * 4,
            "runs": [3] * 4,
            "mean": [2.0, 1.0, 5.0, 6.0],
            "std": [1.0] * 4,
            "ci_low": [1.5, 0.5, 4.5, 5.5],
            "ci_high": [2.5, 1.5, 5.5, 6.5],
        }
    )
    fig = plot(agg, "p", "y")
    assert isinstance(fig, Figure)
    (ax,) = fig.axes
    assert [line.get_label() for line in ax.lines] == ["q = a", "q = b"]
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), [0.1, 0.2])  # sorted by x
    np.testing.assert_array_equal(ax.lines[0].get_ydata(), [1.0, 2.0])
    assert len(ax.collections) == 2  # one confidence band per line
    with pytest.raises(KeyError, match="no aggregated rows"):
        plot(agg, "p", "z")


def test_report_html_and_markdown_from_a_sweep(tmp_path):
    sweep = parse_sweep(FLAKY, name="flaky")
    run_sweep(sweep, tmp_path / "d", workers=2, progress=False)
    stored, results = load(tmp_path / "d")
    assert metrics_of(results, stored) == ["receptions_delivered", "last_change_s"]
    table = failures(results, stored.swept)
    assert list(table["runs"]) == [3, 3] and list(table["seeds"]) == ["1, 2, 3", "1, 2, 3"]

    (html_path,) = write_report(tmp_path / "d", tmp_path / "r.html")
    text = html_path.read_text()
    assert text.count('src="data:image/png;base64,') == 2
    assert "<h2>receptions_delivered</h2>" in text and "<h2>Failed runs</h2>" in text
    assert "12 in 4 cells: 6 ok, 6 failed" in text
    written = write_report(tmp_path / "d", tmp_path / "r.md", metrics=["messages_sent"])
    assert [p.name for p in written] == ["r.md", "messages_sent.png"]
    assert written[1].read_bytes().startswith(b"\x89PNG")
    md = written[0].read_text()
    assert "![messages_sent](r_files/messages_sent.png)" in md
    assert "| gradient.source | medium.loss_prob | runs | mean | std | ci_low | ci_high |" in md
    with pytest.raises(ReportError, match=r"a report is .html or .md"):
        write_report(tmp_path / "d", tmp_path / "r.pdf")
    with pytest.raises(ReportError, match=r"x = 'seed' is not a swept parameter"):
        write_report(tmp_path / "d", tmp_path / "r.md", x="seed")


# ---------------------------------------------------------------------------- command line


def test_register_adds_sweep_and_report_sub_commands():
    parser = argparse.ArgumentParser()
    subparsers = parser.add_subparsers(dest="command")
    experiments_cli.register_sweep(subparsers)
    experiments_cli.register_report(subparsers)
    args = parser.parse_args(["sweep", "s.toml", "--out", "d", "--workers", "3", "--resume"])
    assert (args.sweep_file, args.out, args.workers, args.resume) == ("s.toml", "d", 3, True)
    assert args.func is experiments_cli._cmd_sweep
    args = parser.parse_args(["report", "d", "--out", "r.md", "--metric", "a", "--metric", "b"])
    assert (args.directory, args.out, args.metric) == ("d", "r.md", ["a", "b"])
    assert args.func is experiments_cli._cmd_report


@pytest.fixture
def kilonet_main():
    return kilonet.app.cli.main


def test_cli_sweep_then_report(tmp_path, kilonet_main, capsys):
    sweep_file = tmp_path / "small.toml"
    sweep_file.write_text(SMALL)
    out = tmp_path / "out"
    assert kilonet_main(["sweep", str(sweep_file), "--out", str(out), "--no-progress"]) == 0
    assert "sweep small: 4 runs; 4 run now (0 failed)" in capsys.readouterr().err
    assert kilonet_main(["sweep", "--resume", "--out", str(out), "--no-progress"]) == 0
    assert "0 run now (0 failed), 4 already stored" in capsys.readouterr().err
    report = tmp_path / "report.html"
    assert kilonet_main(["report", str(out), "--out", str(report)]) == 0
    assert report.read_text().startswith("<!DOCTYPE html>")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["sweep", "{bad}", "--out", "{out}"], "[grid] medium.loss_prob = 2.0 is out of range"),
        (["sweep", "{good}", "--out", "{out}", "--workers", "0"], "--workers must be at least 1"),
        (["sweep", "--resume", "--out", "{out}"], "holds no sweep to resume"),
        (["sweep", "--out", "{out}"], "give a sweep file, or --resume"),
        (["sweep", "{missing}", "--out", "{out}"], "no such sweep file"),
        (["report", "{out}", "--out", "{tmp}/r.html"], "no sweep results here"),
    ],
)
def test_cli_user_errors_are_one_line_exit_2_and_leave_nothing(
    tmp_path, kilonet_main, capsys, argv, message
):
    (tmp_path / "bad.toml").write_text(SMALL.replace("[0.0, 0.3]", "[0.0, 2.0]"))
    (tmp_path / "good.toml").write_text(SMALL)
    names = {
        "bad": tmp_path / "bad.toml",
        "good": tmp_path / "good.toml",
        "missing": tmp_path / "missing.toml",
        "out": tmp_path / "out",
        "tmp": tmp_path,
    }
    assert kilonet_main([a.format(**names) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("kilonet: error: ") and message in err
    assert err.count("\n") == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "r.html").exists()


def test_runs_are_json_records():
    # what a worker returns must survive the trip through the store unchanged
    rec = execute_run(parse_sweep(SMALL, name="small").runs()[1])
    assert json.loads(json.dumps(rec.summary)) == rec.summary
    assert rec.cell == {"medium.loss_prob": 0.3}
