"""``kilonet run`` and ``kilonet params`` on the inputs of a user's second hour: odd ``--out``
values, a run file given as the program, parameters of ``--program`` and of one section."""

from __future__ import annotations

from pathlib import Path

import pytest

from kilonet.app.cli import main


def one_error(capsys) -> str:
    out, err = capsys.readouterr()
    line = err.split("\r")[-1]
    assert out == "" and line.count("\n") == 1, err
    return line


@pytest.mark.parametrize(
    ("out", "message"),
    [
        ("", "--out needs a directory name, got an empty one"),
        (".", ". is the current directory or holds it"),
        ("..", ".. is the current directory or holds it"),
    ],
)
def test_an_out_that_cannot_be_a_run_is_refused_before_the_run(
    tmp_path, capsys, monkeypatch, out, message
):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    argv = ["run", "gradient", "--robots", "5", "--duration", "1", "--out", out, "--replace"]
    assert main(argv) == 2
    assert message in one_error(capsys)
    assert list(tmp_path.rglob("*")) == [work]


def test_a_run_file_given_as_the_program_says_where_it_goes(tmp_path, capsys):
    run_file = tmp_path / "x.toml"
    run_file.write_text("seed = 1\n")
    assert main(["run", "--program", str(run_file), "--robots", "3"]) == 2
    assert "x.toml: a program is a Python file" in one_error(capsys)


def test_params_program_lists_the_kernel_defaults(capsys):
    from kilonet.params import Params

    assert main(["params", "program"]) == 0
    rows = {line.split()[0]: line.split()[1] for line in capsys.readouterr().out.splitlines()}
    p = Params()  # the kernel's defaults, not a scenario's (gcs: a 0.2 s period)
    assert rows["duration_s"] == str(p.duration_s) == "60.0"
    assert rows["robot.tx_period_s"] == str(p.robot.tx_period_s)
    assert rows["placement.spacing_mm"] == str(p.placement.spacing_mm)
    assert not any(key.startswith("gcs.") for key in rows)


def test_params_of_one_section(capsys):
    assert main(["params", "ranging"]) == 0
    keys = [line.split()[0] for line in capsys.readouterr().out.splitlines()[1:]]
    assert keys and all(key.startswith("ranging.") for key in keys)
    assert "ranging.sigma_mm" in keys


def test_params_of_nothing_known_lists_the_scenarios(capsys):
    assert main(["params", "nosuch"]) == 2
    assert "unknown scenario 'nosuch'; known scenarios:" in one_error(capsys)


# -- progress ---------------------------------------------------------------------------------
GRADIENT = ["run", "gradient", "--robots", "5", "--duration", "10"]


def test_progress_is_silent_when_stderr_is_not_a_terminal(capsys):
    assert main(GRADIENT) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    assert err == "kilonet: no --out DIR given, so nothing was written\n"


def test_progress_lines_are_whole_lines(capsys):
    assert main([*GRADIENT, "--progress", "lines"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert lines[:4] == [
        "gradient: placing robots",
        "gradient: building 5 robots",
        "gradient: starting",
        "gradient: running to 10 sim s",
    ]
    shares = [line.split()[1] for line in lines[4:-3]]
    assert shares == [f"{p}%" for p in range(10, 101, 10)]
    assert lines[-3] == "gradient: scoring"
    assert lines[-2].startswith("gradient: done at 10 sim s in ")
    assert max(len(line) for line in lines) < 80


def test_quiet_leaves_only_the_summary(capsys):
    assert main([*GRADIENT, "--quiet", "--progress", "lines"]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out.startswith("scenario")


def test_the_phase_shows_before_what_the_run_waits_for(capsys):
    from kilonet import scenarios

    scenarios.run(scenarios.get("gcs"), {"placement.robots": 12, "duration_s": 3}, progress="bar")
    last = capsys.readouterr().err.split("\r")[-1]
    assert last.index("phase 1/6 ids") < last.index("until merging")
    assert last.index("phase 1/6 ids") < 80


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_a_run_ended_by_a_signal_leaves_nothing(tmp_path, signame):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "runs" / "one"
    child = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "kilonet",
            "run",
            "gradient",
            "--robots",
            "30",
            "--duration",
            "100000",
            "--out",
            str(out),
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    waited = 0.0
    while not list((tmp_path / "runs").glob(".one.*")) and waited < 120:  # staging is made
        time.sleep(0.1)
        waited += 0.1
    time.sleep(0.5)  # into the run
    child.send_signal(getattr(signal, signame))
    _, err = child.communicate()
    assert child.returncode == 128 + getattr(signal, signame)
    assert err.strip().splitlines()[-1] == f"kilonet: stopped by {signame}"
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "robots",
    [
        pytest.param([], marks=pytest.mark.slow, id="default"),
        # The default tier's twin: 40 robots also end in one frame beside isolated seeds.
        pytest.param(["--robots", "40"], id="40"),
    ],
)
def test_the_default_run_reports_no_split_beside_one_frame(robots, capsys):
    assert main(["run", *robots, "--json"]) == 0
    summary = __import__("json").loads(capsys.readouterr().out)
    assert summary["frames"] == 1 and summary["failures"]["isolated_seeds"]
    assert summary["failures"]["split_frames"] == 0


# -- run directories ----------------------------------------------------------------------------
def test_robots_csv_has_the_uids_and_messages_csv_needs_trace_messages(tmp_path):
    import pandas as pd

    placement = tmp_path / "three.csv"
    placement.write_text("x_mm,y_mm,uid\n0,0,42\n50,0,7\n100,0,9\n")
    base = ["run", "gradient", "--placement", str(placement), "--duration", "2", "--quiet"]
    assert main([*base, "--out", str(tmp_path / "plain")]) == 0
    robots = pd.read_csv(tmp_path / "plain" / "robots.csv")
    assert list(robots.columns[:2]) == ["robot", "uid"]
    assert robots.uid.tolist() == [42, 7, 9]
    assert not (tmp_path / "plain" / "messages.csv").exists()
    assert main([*base, "--set", "trace.messages=true", "--out", str(tmp_path / "traced")]) == 0
    messages = pd.read_csv(tmp_path / "traced" / "messages.csv")
    assert len(messages) > 0 and list(messages.columns[:2]) == ["t_s", "sender"]


def test_a_uid_given_twice_is_refused(tmp_path, capsys):
    placement = tmp_path / "twice.csv"
    placement.write_text("x_mm,y_mm,uid\n0,0,42\n50,0,7\n100,0,42\n")
    argv = ["run", "gradient", "--placement", str(placement), "--out", str(tmp_path / "out")]
    assert main(argv) == 2
    assert "twice.csv: uid 42 is given to data rows 1 and 3" in one_error(capsys)
    assert not (tmp_path / "out").exists()


def test_the_readme_quotes_the_defaults_it_names():
    from kilonet.params import Params
    from kilonet.robot import ADC_CONVERSION_S
    from kilonet.watchdog import BUSY_CALL_S

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    readme = " ".join(readme.split())
    p = Params()
    assert f"({p.duration_s:g} s, kilolib's transmit period, a " in readme
    assert f"{p.placement.spacing_mm:g} mm hex lattice)" in readme
    assert f"stops a call that runs {BUSY_CALL_S:g} s of wall time" in readme
    assert f"reading takes the ADC's {ADC_CONVERSION_S * 1e6:.0f} µs" in readme


# -- a program's own settings -------------------------------------------------------------------
SETTABLE = """\
from kilonet.robot import Kilobot


class Settable(Kilobot):
    period_ticks = 31
    gain = 0.5
    label = "a"

    def setup(self):
        self.log("settings", period_ticks=self.period_ticks, gain=self.gain, label=self.label)
"""


def test_a_run_files_program_section_and_set_give_the_programs_settings(tmp_path, capsys):
    import json

    program = tmp_path / "settable.py"
    program.write_text(SETTABLE)
    run_file = tmp_path / "run.toml"
    run_file.write_text("duration_s = 1\n\n[program]\nperiod_ticks = 62\ngain = 2\n")
    out = tmp_path / "out"
    argv = ["run", str(run_file), "--program", str(program), "--robots", "2", "--quiet"]
    assert main([*argv, "--set", "program.label=b", "--out", str(out)]) == 0
    events = (out / "events.csv").read_text().splitlines()
    assert json.loads(events[1].split(",", 3)[3].strip('"').replace('""', '"')) == {
        "period_ticks": 62,
        "gain": 2.0,
        "label": "b",
    }
    capsys.readouterr()
    run_file.write_text("[program]\nperiod_ticks = 62\nspeed = 3\n")
    assert main(argv) == 2
    assert "run.toml:3: program.speed: Settable has no class attribute 'speed'" in one_error(capsys)
    assert main([*argv, "--set", "program.period_ticks=fast"]) == 2
    line = one_error(capsys)
    assert "--set program.period_ticks: program.period_ticks = 'fast' is not an int" in line
