"""A researcher's own program file is a scenario like any other (issue 43, item 1): its declared
settings are parameters (``params.json``, the summary, ``kilonet params --program``, sweeps),
its source is kept and hashed, and what ``report()`` returns goes to ``robots.csv`` and the
summary; a sweep file may name it, and runs it serially, in the process pool and on Dask."""

from __future__ import annotations

import hashlib
import json

import pandas as pd
import pytest

from kilonet import scenarios
from kilonet.app.cli import main
from kilonet.experiments.runner import execute_run, run_sweep
from kilonet.experiments.store import ResultStore
from kilonet.experiments.sweep import SweepError, load_sweep
from kilonet.scenarios.program import (
    ProgramError,
    declared_settings,
    load_program,
    program_scenario,
)

LEADER = """\
from kilonet.message import Message
from kilonet.robot import Kilobot


class Leader(Kilobot):
    patience_ticks = 62
    colour = "red"
    eager = False

    def setup(self):
        self.best = self.kilo_uid
        self.heard_at = 0

    def loop(self):
        if self.kilo_ticks - self.heard_at > self.patience_ticks:
            if self.best == self.kilo_uid:
                self.set_color(3, 0, 0)
            else:
                self.set_color(0, 0, 0)

    def message_tx(self):
        return Message(bytes([self.best]))

    def message_rx(self, message, distance):
        if message.data[0] > self.best:
            self.best = message.data[0]
            self.heard_at = self.kilo_ticks

    def report(self):
        return {"leader": self.best == self.kilo_uid, "best": self.best,
                "patience": self.patience_ticks, "name": self.colour}
"""

SWEEP = """\
program = "bots/leader.py:Leader"
seeds = 1
[fixed]
duration_s = 4.0
"placement.robots" = 4
[grid]
"program.patience_ticks" = [31, 93]
"medium.loss_prob" = [0.0, 0.5]
"""


def one_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture
def leader(tmp_path):
    path = tmp_path / "bots" / "leader.py"
    path.parent.mkdir()
    path.write_text(LEADER)
    return path


@pytest.fixture
def sweep_file(tmp_path, leader):
    path = tmp_path / "election.toml"
    path.write_text(SWEEP)
    return path


# -- a run's directory --------------------------------------------------------------------------
def test_a_run_keeps_the_source_its_hash_settings_and_reported_state(tmp_path, leader, capsys):
    run_file = tmp_path / "run.toml"
    run_file.write_text("duration_s = 6\n[program]\ncolour = 'blue'\n")
    out = tmp_path / "out"
    argv = ["run", str(run_file), "--program", f"{leader}:Leader", "--robots", "5"]
    assert main([*argv, "--set", "program.patience_ticks=31", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)

    digest = hashlib.sha256(leader.read_bytes()).hexdigest()
    assert (out / "program.py").read_bytes() == leader.read_bytes()
    assert json.loads((out / "summary.json").read_text()) == summary
    assert summary["program"] == "leader.py:Leader" and summary["program_sha256"] == digest
    assert summary["program_settings"] == {"patience_ticks": 31, "colour": "blue", "eager": False}
    params = json.loads((out / "params.json").read_text())
    assert (params["program.patience_ticks"], params["program.colour"]) == (31, "blue")
    assert params["program.eager"] is False

    robots = pd.read_csv(out / "robots.csv")
    assert list(robots.columns[-4:]) == ["leader", "best", "patience", "name"]
    assert robots["leader"].tolist() == [False, False, False, False, True]  # uid 4 wins
    assert robots["best"].tolist() == [4] * 5 and robots["patience"].tolist() == [31] * 5
    assert summary["report"] == {
        "leader": {"true": 1, "false": 4, "none": 0},
        "best": {"min": 4, "mean": 4.0, "max": 4, "none": 0},
        "patience": {"min": 31, "mean": 31.0, "max": 31, "none": 0},
        "name": {"distinct": 1, "most": "blue", "none": 0},
    }


def test_the_settings_section_leaves_the_simulation_as_it_was(leader):
    # Same seed, same run, whether a setting equal to the default is given or not; a setting
    # that differs reaches every robot.
    plain = scenarios.run(program_scenario(str(leader)), {"placement.robots": 4, "duration_s": 3})
    same = scenarios.run(
        program_scenario(str(leader), {"patience_ticks": 62}),
        {"placement.robots": 4, "duration_s": 3},
    )
    assert plain.sim.trace.frames()["led"].equals(same.sim.trace.frames()["led"])
    assert {k: v for k, v in plain.summary.items() if k != "wall_time_s"} == {
        k: v for k, v in same.summary.items() if k != "wall_time_s"
    }
    other = scenarios.run(
        program_scenario(str(leader)),
        {"placement.robots": 4, "duration_s": 3, "program.patience_ticks": 5},
    )
    assert [r.patience_ticks for r in other.sim.robots] == [5] * 4
    assert other.summary["report"]["patience"]["min"] == 5


def test_declared_settings_are_public_scalars_bases_first(tmp_path):
    path = tmp_path / "kinds.py"
    path.write_text(
        "import math\nfrom kilonet.robot import Kilobot\n\n\n"
        "class Base(Kilobot):\n    gain = 0.5\n    limit = 3\n\n\n"
        "class Bot(Base):\n    limit = 'none'\n    forever = math.inf\n    _private = 1\n"
        "    table = (1, 2)\n    gain = (0.1, 0.2)\n"
    )
    _, cls = load_program(f"{path}:Bot")
    assert declared_settings(cls) == {"limit": "none"}


# -- report() mistakes --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("return [1]", "report.py:6: report() returned list; it returns a dict"),
        ("return {'x_mm': 1}", "report.py:6: report() returns 'x_mm', a column kilonet writes"),
        ("return {'pos': (1, 2)}", "report.py:6: report() returned 'pos': (1, 2); its keys"),
        ("return 1 / 0", "report.py:7: in report: ZeroDivisionError: division by zero"),
    ],
)
def test_a_report_that_cannot_be_recorded_is_one_line_and_nothing_is_written(
    tmp_path, capsys, body, message
):
    path = tmp_path / "report.py"
    path.write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Bad(Kilobot):\n\n"
        f"    def report(self):\n        {body}\n"
    )
    out = tmp_path / "out"
    argv = ["run", "--program", str(path), "--robots", "2", "--duration", "1", "--quiet"]
    assert main([*argv, "--out", str(out)]) == 2
    assert one_error(capsys).startswith(f"kilonet: error: {tmp_path}/{message}")
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["report.py"]


# -- kilonet params --program -------------------------------------------------------------------
def test_params_program_lists_the_programs_settings(leader, capsys):
    assert main(["params", "program", "--program", f"{leader}:Leader"]) == 0
    rows = [line.split()[:3] for line in capsys.readouterr().out.splitlines()[1:]]
    assert rows == [
        ["program.patience_ticks", "62", "int"],
        ["program.colour", "red", "str"],
        ["program.eager", "False", "bool"],
    ]
    assert main(["params", "--program", str(leader)]) == 0
    keys = [line.split()[0] for line in capsys.readouterr().out.splitlines()[1:]]
    assert "medium.loss_prob" in keys and keys[-3:] == [row[0] for row in rows]
    assert main(["params", "gcs", "--program", str(leader)]) == 2
    assert "--program lists your program's parameters, not the scenario 'gcs'" in one_error(capsys)
    assert main(["params", "--program", str(leader.parent / "none.py")]) == 2
    assert one_error(capsys).endswith("none.py: no such program file")


# -- sweeps -------------------------------------------------------------------------------------
def _results(records) -> dict[str, tuple]:
    """What a run computed, by run id (not where, when or how fast)."""
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


def test_a_2x2_program_sweep_run_serially_stores_each_cells_settings(sweep_file, leader):
    sweep = load_sweep(sweep_file)
    digest = hashlib.sha256(leader.read_bytes()).hexdigest()
    assert sweep.scenario == f"program:{leader.resolve()}:Leader@{digest}"
    assert sweep.swept == ["program.patience_ticks", "medium.loss_prob"]
    records = [execute_run(run) for run in sweep.runs()]  # one after the other, in this process
    assert [r.status for r in records] == ["ok"] * 4, [r.error for r in records]
    for run, record in zip(sweep.runs(), records, strict=True):
        s = record.summary
        assert s["scenario"] == "program" and s["program_sha256"] == digest
        assert s["program_settings"] == {
            "patience_ticks": run.cell["program.patience_ticks"],
            "colour": "red",
            "eager": False,
        }
        assert s["report"]["patience"]["max"] == run.cell["program.patience_ticks"]
        assert s["report"]["best"] == {"min": 3, "mean": 3.0, "max": 3, "none": 0}
        assert s["robots"] == 4
    lossy = [
        r for run, r in zip(sweep.runs(), records, strict=True) if run.cell["medium.loss_prob"]
    ]
    assert all(r.summary["lost_random"] > 0 for r in lossy)


def test_the_process_pool_stores_what_the_serial_runs_give(sweep_file, tmp_path):
    sweep = load_sweep(sweep_file)
    serial = _results(execute_run(run) for run in sweep.runs())
    outcome = run_sweep(sweep, tmp_path / "pool", workers=2, progress=False)
    assert (outcome.ok, outcome.failed) == (4, 0)
    with ResultStore.open(tmp_path / "pool") as store:
        stored = store.records()
        frame = store.frame()
    assert _results(stored) == serial
    assert sorted(frame["program_settings.patience_ticks"]) == [31, 31, 93, 93]
    assert set(frame["report.leader.true"]) == {1}


def test_a_changed_program_does_not_resume_into_its_old_sweep(sweep_file, leader, tmp_path, capsys):
    argv = ["sweep", str(sweep_file), "--out", str(tmp_path / "out"), "--no-progress"]
    assert main([*argv, "--workers", "1"]) == 0
    capsys.readouterr()
    leader.write_text(LEADER.replace("patience_ticks = 62", "patience_ticks = 63"))
    assert main(argv) == 2
    assert one_error(capsys).startswith(f"kilonet: error: {tmp_path / 'out'} holds sweep ")
    with ResultStore.open(tmp_path / "out") as store:
        assert store.counts()["ok"] == 4


def test_a_program_sweep_on_a_local_dask_cluster(sweep_file, tmp_path, capsys):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None
    ) as cluster:
        argv = ["sweep", str(sweep_file), "--out", str(tmp_path / "dask"), "--no-progress"]
        assert main([*argv, "--scheduler", cluster.scheduler_address]) == 0
    assert "sweep election: 4 runs; 4 run now (0 failed)" in capsys.readouterr().err
    with ResultStore.open(tmp_path / "dask") as store:
        stored = store.records()
    serial = _results(execute_run(run) for run in load_sweep(sweep_file).runs())
    assert _results(stored) == serial


def test_a_program_changed_after_the_sweep_was_defined_is_refused(sweep_file, leader, tmp_path):
    sweep = load_sweep(sweep_file)
    leader.write_text(LEADER.replace("patience_ticks = 62", "patience_ticks = 63"))
    record = execute_run(sweep.runs()[0])
    assert record.status == "failed"
    assert "leader.py: changed since the sweep was defined (sha256 " in record.error
    with pytest.raises(ProgramError, match="changed since the sweep was defined"):
        scenarios.get(sweep.scenario)
    # A new definition of the changed program is another sweep: other run ids.
    assert {r.run_id for r in load_sweep(sweep_file).runs()}.isdisjoint(
        r.run_id for r in sweep.runs()
    )


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            SWEEP.replace('program = "bots/leader.py:Leader"', 'scenario = "program"'),
            'scenario = "program" needs program = "FILE.py:ClassName"',
        ),
        (
            SWEEP.replace("bots/leader.py", "bots/missing.py"),
            "program: {tmp}/bots/missing.py: no such program file",
        ),
        (
            SWEEP.replace(":Leader", ":Nobody"),
            "program: {tmp}/bots/leader.py: has no 'Nobody'",
        ),
        (
            'scenario = "gcs"\n' + SWEEP,
            "scenario = 'gcs' and program = 'bots/leader.py:Leader': a sweep runs one",
        ),
        (
            SWEEP.replace('"program.patience_ticks"', '"program.speed"'),
            "[grid] unknown parameter 'program.speed'; program has: colour, eager, patience_ticks",
        ),
        (
            SWEEP.replace("[31, 93]", '[31, "fast"]'),
            "[grid] program.patience_ticks = 'fast' is not an integer",
        ),
        (
            SWEEP.replace('"placement.robots" = 4\n', ""),
            'cell {"program.patience_ticks": 31, "medium.loss_prob": 0.0}: placement.robots '
            "is not set and your program leader.py:Leader on every robot has no swarm",
        ),
    ],
)
def test_a_program_sweep_file_with_a_mistake_is_one_line(tmp_path, leader, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SweepError) as caught:
        load_sweep(path)
    assert str(caught.value).startswith(f"{path}: {message.replace('{tmp}', str(tmp_path))}")
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--no-progress"]) == 2
    assert one_error(capsys).startswith("kilonet: error: ")
    assert not out.exists()


def test_params_program_of_a_program_without_settings_and_a_reserved_name(tmp_path, capsys):
    idle = tmp_path / "idle.py"
    idle.write_text("from kilonet.robot import Kilobot\n\n\nclass Idle(Kilobot):\n    pass\n")
    assert main(["params", "program", "--program", str(idle)]) == 0
    assert capsys.readouterr().out.split() == [
        "key",
        "default",
        "type",
        "and",
        "allowed",
        "values",
        "description",
    ]
    idle.write_text(idle.read_text().replace("pass", "section_name = 'mine'"))
    assert main(["params", "--program", str(idle)]) == 2
    assert one_error(capsys) == (
        f"kilonet: error: {idle}: Idle.section_name: kilonet names a parameter section with "
        "this attribute, so a program's setting cannot have this name; rename it"
    )
