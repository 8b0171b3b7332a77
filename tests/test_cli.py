"""The ``kilonet`` command line as a newcomer meets it: every bad or edge input either runs or
is refused in one line (exit status 2) with nothing written; outputs are checked before the
simulation starts; an existing ``--out`` is never merged; progress and help tell the truth."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from importlib.metadata import entry_points, version
from pathlib import Path

import pytest

from kilonet import scenarios
from kilonet.app.cli import COMMANDS, main
from kilonet.placement import save_csv
from kilonet.protocols.gcs.base import PHASES
from kilonet.simulation import Simulation

ROOT = Path(__file__).resolve().parents[1]

BLINK = """\
from kilonet.robot import Kilobot


class Blink(Kilobot):
    def setup(self):
        self.set_color(0, 0, 3)

    def loop(self):
        if self.kilo_ticks >= 32:
            self.set_color(3, 0, 0)
            self.set_motors(255, 255)
"""


def tree(root: Path) -> list[str]:
    """Every path under ``root`` (hidden ones too), relative, sorted."""
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def error_line(err: str) -> str:
    """The error message a run printed on stderr: the text after an erased progress bar."""
    assert err.count("\n") == 1, err
    return err.split("\r")[-1].rstrip("\n")


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """Inputs of every kind, in ``tmp_path / "in"``."""
    d = tmp_path / "in"
    d.mkdir()
    (d / "binary.toml").write_bytes(b"\x00\x01\x02\xff\xfe")
    (d / "folder.toml").mkdir()
    (d / "bad_key.toml").write_text('scenario = "gradient"\n[medium]\nloss_prob = 0.1\nlos = 1\n')
    (d / "bad_value.toml").write_text('scenario = "gradient"\nmedium.range_mm = 5\n')
    (d / "bad_syntax.toml").write_text('scenario = "gradient"\n[medium\n')
    (d / "three_fields.csv").write_text("x_mm,y_mm\n0,0\n50,0,7\n")
    (d / "huge.csv").write_text("x_mm,y_mm\n0,0\n1e308,0\n")
    save_csv([[0.0, 0.0], [50.0, 0.0], [100.0, 0.0]], d / "line.csv")
    save_csv([[0.0, 0.0], [500.0, 0.0]], d / "far_apart.csv")
    (d / "a_file").write_text("not a directory\n")
    (d / "old.png").write_bytes(b"an earlier figure")
    (d / "blink.py").write_text(BLINK)
    (d / "no_robot.py").write_text("def helper():\n    return 1\n")
    (d / "not_a_robot.py").write_text(BLINK + "\n\nclass Helper:\n    pass\n")
    (d / "syntax.py").write_text("from kilonet.robot import Kilobot\n\nclass Bad(Kilobot)\n")
    (d / "raises_in_setup.py").write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Bad(Kilobot):\n"
        "    def setup(self):\n        self.speed = 1 / 0\n"
    )
    (d / "raises_on_load.py").write_text("import math\n\nLIMIT = math.sqrt(-1)\n")
    (d / "raises_in_loop.py").write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Bad(Kilobot):\n"
        "    def loop(self):\n        if self.kilo_ticks > 40:\n"
        "            raise RuntimeError('lost my way')\n"
    )
    (d / "needs_args.py").write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Bad(Kilobot):\n"
        "    def __init__(self, speed):\n        self.speed = speed\n"
    )
    (d / "two_robots.py").write_text(BLINK + "\n\nclass Other(Blink):\n    pass\n")
    full = d / "full"
    full.mkdir()
    (full / "stale.png").write_text("an earlier run's figure\n")
    return {p.name: p for p in d.iterdir()}


# (argv with {name} for files and {tmp} for the temporary directory, message part)
REFUSED = [
    (["run", "{binary.toml}"], "binary.toml: not a UTF-8 text file"),
    (["run", "{folder.toml}"], "folder.toml: is a directory, not a run file"),
    (["run", "{tmp}/in/missing.toml"], "missing.toml: no such run file"),
    (["run", "{bad_key.toml}"], "bad_key.toml:4: unknown parameter 'medium.los'"),
    (["run", "{bad_value.toml}"], "bad_value.toml:2: medium.range_mm = 5.0 is out of range"),
    (["run", "{bad_syntax.toml}"], "bad_syntax.toml: not valid TOML (Expected ']'"),
    (["run", "gradient", "--placement", "{three_fields.csv}"], "line 3: 3 fields, but the header"),
    (["run", "gradient", "--placement", "{huge.csv}"], "line 3: position (1e+308, 0) is more"),
    (["run", "gradient", "--placement", "{tmp}/in/nowhere.csv"], "no such placement file"),
    (
        ["run", "gradient", "--robots", "10", "--placement", "{line.csv}"],
        "--robots 10 and --placement",
    ),
    (
        ["run", "gradient", "--set", "placement.robots=10", "--placement", "{line.csv}"],
        "line.csv has 3 robots; give one or the other",
    ),
    (["run", "gradient", "--robots", "0"], "--robots 0: give the number of robots"),
    (["run", "gradient", "--until", "ids"], "--until is an option of the gcs scenario, not of"),
    (["run", "nosuch"], "unknown scenario 'nosuch'; known scenarios: follower, gcs"),
    (["run", "gradient", "--set", "medium.los=1"], "unknown parameter 'medium.los'"),
    (["run", "gradient", "--set", "medium.reach=argos-x"], "medium.reach = 'argos-x' is not one"),
    (
        ["run", "gradient", "--set", "ranging.calibration_file={tmp}/in/cal.csv"],
        "cal.csv: no such calibration file",
    ),
    (
        ["run", "gradient", "--set", "ranging.calibration_file={line.csv}"],
        "line.csv: no column irhigh_0",
    ),
    (["run", "gradient", "--set", "ranging.model=nowhere:Model"], "cannot import nowhere"),
    (["run", "gradient", "--set", "medium.range_mm"], "--set expects KEY=VALUE"),
    (["run", "gradient", "--duration", "nan"], "duration_s = nan is not a finite number"),
    (["run", "gradient", "--animate"], "--animate needs --out DIR"),
    (["run", "gradient", "--replace"], "--replace needs --out DIR"),
    (["run", "gradient", "--out", "{a_file}"], "a_file exists and is not a directory"),
    (["run", "gradient", "--out", "{a_file}/run"], "a_file: it is not a directory"),
    (["run", "gradient", "--out", "{full}"], "full already exists; choose another --out or pass"),
    (["run", "--program", "{tmp}/in/missing.py", "--robots", "3"], "no such program file"),
    (["run", "--program", "{folder.toml}", "--robots", "3"], "is a directory, not a program"),
    (["run", "--program", "{no_robot.py}", "--robots", "3"], "no_robot.py: defines no Kilobot"),
    (
        ["run", "--program", "{not_a_robot.py}:Helper", "--robots", "3"],
        "not_a_robot.py:14: Helper is not a Kilobot subclass",
    ),
    (["run", "--program", "{blink.py}:Nobody", "--robots", "3"], "blink.py: has no 'Nobody'"),
    (["run", "--program", "{syntax.py}", "--robots", "3"], "syntax.py:3: syntax error: expected"),
    (
        ["run", "--program", "{raises_on_load.py}", "--robots", "3"],
        "raises_on_load.py:3: while loading: ValueError: math domain error",
    ),
    (
        ["run", "--program", "{raises_in_setup.py}", "--robots", "3"],
        "raises_in_setup.py:6: in setup: ZeroDivisionError: division by zero",
    ),
    (
        ["run", "--program", "{raises_in_loop.py}", "--robots", "3", "--duration", "5"],
        "raises_in_loop.py:7: in loop: RuntimeError: lost my way",
    ),
    (["run", "--program", "{needs_args.py}", "--robots", "3"], "needs_args.py:4: Bad() needs"),
    (["run", "--program", "{two_robots.py}", "--robots", "3"], "several Kilobot subclasses"),
    (["run", "--program", "{blink.py}"], "--program needs --placement F.csv or --robots N"),
    (["run", "gcs", "--program", "{blink.py}", "--robots", "3"], "not the scenario 'gcs'"),
    (
        ["run", "{bad_key.toml}", "--program", "{blink.py}", "--robots", "3"],
        "bad_key.toml: names scenario 'gradient', but --program runs your own program",
    ),
    (["analyze", "{line.csv}", "--out", "{tmp}/in/figure.svg"], "the figure is a PNG"),
    (["analyze", "{line.csv}", "--out", "{old.png}"], "old.png already exists"),
    (["analyze", "{tmp}/in/nowhere.csv"], "no such placement file or named placement"),
    (["params", "nosuch"], "unknown scenario 'nosuch'"),
]


@pytest.mark.parametrize(("argv", "message"), REFUSED, ids=[m[:40] for _, m in REFUSED])
def test_bad_input_is_refused_in_one_line_with_nothing_written(
    files, tmp_path, capsys, monkeypatch, argv, message
):
    names = {name: str(path) for name, path in files.items()} | {"tmp": str(tmp_path)}
    argv = [_fill(a, names) for a in argv]
    monkeypatch.chdir(tmp_path)
    before = tree(tmp_path)
    assert main([*argv, "--out", str(tmp_path / "out")] if _takes_out(argv) else argv) == 2
    out, err = capsys.readouterr()
    line = error_line(err)
    assert line.startswith("kilonet: error: ") and message in line, line
    assert out == ""
    assert tree(tmp_path) == before  # nothing written, not even an empty parent directory


def test_an_error_during_the_run_is_one_line_with_and_without_json(files, tmp_path, capsys):
    argv = ["run", "--program", str(files["raises_in_loop.py"]), "--robots", "3"]
    for extra in ([], ["--json"]):
        assert main([*argv, "--out", str(tmp_path / "out"), *extra]) == 2
        out, err = capsys.readouterr()
        assert "raises_in_loop.py:7: in loop: RuntimeError" in error_line(err) and out == ""
        assert not (tmp_path / "out").exists()


def test_an_interrupted_run_leaves_nothing(files, tmp_path, capsys):
    program = tmp_path / "in" / "interrupts.py"
    program.write_text(
        "from kilonet.robot import Kilobot\n\n\nclass Stop(Kilobot):\n"
        "    def loop(self):\n        raise KeyboardInterrupt\n"
    )
    out = tmp_path / "runs" / "one"
    assert main(["run", "--program", str(program), "--robots", "3", "--out", str(out)]) == 130
    line = error_line(capsys.readouterr().err)
    assert re.fullmatch(
        r"kilonet: interrupted in robot \d's loop \(interrupts.py:6\) at .* s", line
    )
    assert not (tmp_path / "runs").exists()


def _fill(arg: str, names: dict[str, str]) -> str:
    for name, value in names.items():
        arg = arg.replace(f"{{{name}}}", value)
    return arg


def _takes_out(argv: list[str]) -> bool:
    """Add an --out DIR to the run cases that have none, so that 'nothing written' means
    something for them too."""
    return argv[0] == "run" and not {"--out", "--replace", "--animate"} & set(argv)


def test_an_unusable_out_is_refused_before_the_simulation_starts(files, monkeypatch, capsys):
    started = []
    monkeypatch.setattr(Simulation, "start", lambda self: started.append(self))
    for out in (files["a_file"] / "run", files["full"]):
        assert main(["run", "gradient", "--out", str(out)]) == 2
    assert started == []
    assert capsys.readouterr().err.count("kilonet: error:") == 2


@pytest.mark.skipif(not Path("/proc/self").exists(), reason="needs /proc (Linux)")
def test_out_under_proc_is_refused(capsys):
    assert main(["run", "gradient", "--out", "/proc/kilonet-run"]) == 2
    assert "cannot write in /proc" in error_line(capsys.readouterr().err)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root writes anywhere")
def test_out_in_a_read_only_folder_is_refused(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        assert main(["run", "gradient", "--out", str(locked / "run")]) == 2
    finally:
        locked.chmod(0o700)
    assert "cannot write in" in error_line(capsys.readouterr().err)
    assert list(locked.iterdir()) == []


# -- runs that must work ---------------------------------------------------------------------
@pytest.mark.parametrize("name", ["gcs", "gradient", "follower", "maze"])
def test_a_zero_second_run_runs_every_setup(name, capsys):
    assert main(["run", name, "--duration", "0", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scenario"] == name and summary["sim_time_s"] == 0.0


def test_gcs_without_any_pair_in_range_runs_and_reports_no_bound(files, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["run", "gcs", "--placement", str(files["far_apart.csv"]), "--out", str(out)]) == 0
    text = (out / "summary.json").read_text()
    summary = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in summary.json"))
    assert summary["crlb_rmse_mm"] is None
    assert summary["localized_fraction"] == 0.0
    assert summary["rmse_mm"] is None  # no frame to align: NaN, written as null


def test_replace_swaps_the_whole_directory(files, tmp_path, capsys):
    full = files["full"]
    assert main(["run", "gradient", "--duration", "1", "--out", str(full), "--replace"]) == 0
    assert not (full / "stale.png").exists()
    assert {"summary.json", "params.json", "robots.csv", "gradient.png"} <= set(tree(full))
    assert [p.name for p in full.parent.iterdir() if p.name.startswith(".")] == []


def test_replace_without_atomic_exchange_moves_aside_then_in(files, monkeypatch, capsys):
    import kilonet.scenarios.output_dir as output_dir

    monkeypatch.setattr(output_dir, "_exchange", lambda a, b: False)
    full = files["full"]
    assert main(["run", "gradient", "--duration", "1", "--out", str(full), "--replace"]) == 0
    assert not (full / "stale.png").exists() and (full / "summary.json").exists()
    assert [p.name for p in full.parent.iterdir() if p.name.startswith(".")] == []


def test_an_existing_empty_directory_is_used(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["run", "gradient", "--duration", "1", "--out", str(empty)]) == 0
    assert (empty / "summary.json").exists()
    assert f"to {empty}" in capsys.readouterr().err


def test_out_creates_missing_parents(tmp_path, capsys):
    out = tmp_path / "runs" / "today" / "g"
    assert main(["run", "gradient", "--duration", "1", "--out", str(out), "--json"]) == 0
    assert (out / "summary.json").exists()


def test_a_run_without_out_says_so_in_one_line(capsys):
    assert main(["run", "gradient", "--duration", "1", "--json"]) == 0
    out, err = capsys.readouterr()
    assert err == "kilonet: no --out DIR given, so nothing was written\n"
    assert json.loads(out)["sim_time_s"] == 1.0


def test_analyze_writes_nothing_unless_asked(files, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(files["line.csv"].parent)
    before = tree(tmp_path)
    assert main(["analyze", str(files["line.csv"]), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["robots"] == 3
    assert tree(tmp_path) == before
    figure = tmp_path / "prediction.png"
    assert main(["analyze", str(files["line.csv"]), "--out", str(figure)]) == 0
    assert tree(tmp_path) == sorted([*before, "prediction.png"])
    assert figure.stat().st_size > 1000
    assert main(["analyze", str(files["line.csv"]), "--out", str(figure)]) == 2
    assert main(["analyze", str(files["line.csv"]), "--out", str(figure), "--replace"]) == 0


# -- your own program --------------------------------------------------------------------------
def test_a_program_file_runs_with_every_output(files, tmp_path, capsys):
    out = tmp_path / "blink"
    argv = ["run", "--program", str(files["blink.py"]), "--robots", "5", "--duration", "3"]
    assert main([*argv, "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scenario"] == "program" and summary["program"] == "blink.py:Blink"
    assert summary["robots"] == 5 and summary["sim_time_s"] == 3.0
    names = set(tree(out))
    assert {"robots.csv", "led.csv", "events.csv", "poses.csv", "summary.json"} <= names
    assert {"params.json", "program.png"} <= names
    led = (out / "led.csv").read_text().splitlines()
    assert led[0] == "t_s,robot,r,g,b" and any(line.endswith(",3,0,0") for line in led[1:])
    robots = (out / "robots.csv").read_text().splitlines()
    assert len(robots) == 6  # header and five robots
    assert len((out / "poses.csv").read_text().splitlines()) > 1  # they drove


def test_a_program_runs_on_a_placement_and_by_class_name(files, tmp_path, capsys):
    argv = ["run", "--program", f"{files['two_robots.py']}:Other"]
    assert main([*argv, "--placement", str(files["line.csv"]), "--duration", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["program"] == "two_robots.py:Other" and summary["robots"] == 3


# -- help, version, listings -----------------------------------------------------------------
def _declared_commands() -> list[str]:
    """The sub-commands pyproject.toml declares (``kilonet.commands`` entry points)."""
    import tomllib

    config = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    return list(config["project"]["entry-points"][COMMANDS])


def test_help_lists_every_registered_command(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    registered = sorted(ep.name for ep in entry_points(group=COMMANDS))
    assert registered == sorted(_declared_commands())  # pyproject.toml's table, installed
    assert all(f"    {name} " in text or f"    {name}\n" in text for name in registered)


@pytest.mark.parametrize("name", sorted(ep.name for ep in entry_points(group=COMMANDS)))
def test_each_command_entry_point_registers_its_own_name(name):
    import argparse

    from kilonet.app.cli import CommandParser

    (ep,) = [ep for ep in entry_points(group=COMMANDS) if ep.name == name]
    sub = argparse.ArgumentParser().add_subparsers(parser_class=CommandParser)
    ep.load()(sub)
    assert list(sub.choices) == [name]


def test_version_comes_from_the_installed_metadata(capsys):
    with pytest.raises(SystemExit):
        main(["--version"])
    assert capsys.readouterr().out == f"kilonet {version('kilonet')}\n"


def test_run_help_says_defaults_repeats_and_where_parameters_are(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert "default: gcs" in text and "(default: 1)" in text  # scenario and seed
    assert "repeat for more" in text and "kilonet params" in text
    assert "examples:" in text and "kilonet run --program" in text
    assert f"--until {{{','.join(PHASES)}}}" in text
    assert "gcs: stop after this phase (gcs.until, default merge)" in text


def test_params_shows_types_and_allowed_values(capsys):
    assert main(["params", "gcs"]) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()}
    assert f"one of: {', '.join(PHASES)}" in rows["gcs.until"]
    assert "float, 33 to 1000" in rows["medium.range_mm"]
    assert " bool " in rows["medium.csma"]
    assert "int >= 0" in rows["seed"]
    assert rows["key"].split()[:2] == ["key", "default"]


def test_output_into_a_closed_pipe_ends_quietly():
    child = subprocess.Popen(
        [sys.executable, "-m", "kilonet.app.cli", "params", "gcs"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    child.stdout.close()  # the reader is gone before the first line (``| head -0``)
    err = child.stderr.read().decode()
    assert child.wait(timeout=60) == 141
    assert err == ""


def test_scenarios_lists_the_registered_ones(capsys):
    assert main(["scenarios"]) == 0
    names = [line.split()[0] for line in capsys.readouterr().out.splitlines()]
    assert names == scenarios.names()
    assert names == ["follower", "gcs", "gradient", "localize", "maze", "self-assembly"]


# -- progress -----------------------------------------------------------------------------------
def test_progress_shows_the_set_up_then_a_bar_to_a_known_end(capsys):
    scenarios.run(scenarios.get("gradient"), {"duration_s": 2.0}, progress=True)
    err = capsys.readouterr().err
    assert "gradient: placing robots" in err and "gradient: building 100 robots" in err
    assert "100% |" in err and "2.0/2.0 sim s" in err


def test_progress_without_a_known_end_is_an_honest_count(capsys):
    scenarios.run(scenarios.get("follower"), progress=True)
    err = capsys.readouterr().err
    assert "until the follower arrives or gives up (at most 600 s)" in err
    assert "%" not in err


def test_gcs_progress_names_the_phase_and_ends_at_its_window(capsys):
    scenarios.run(scenarios.get("gcs"), {"placement.robots": 12, "gcs.until": "ids"}, progress=True)
    err = capsys.readouterr().err
    assert "phase 1/6 ids (to 8 s)" in err and "9.0/9.0 sim s" in err and "100% |" in err


def test_expected_ends():
    from kilonet.scenarios.base import _expected_end_s, build_params
    from kilonet.scenarios.gcs import _expected_end_s as gcs_end

    def end(name, **overrides):
        scenario = scenarios.get(name)
        return _expected_end_s(scenario, build_params(scenario, overrides))

    assert end("gradient") == 30.0  # no stop condition: its duration
    assert end("follower") is None and end("maze") is None  # a stop condition only
    assert end("gcs") is None  # merging ends when the seeds agree
    assert end("gcs", **{"gcs.until": "ids"}) == 9.0  # the window, and the second it waits
    assert end("gcs", **{"gcs.until": "ids", "duration_s": 5.0}) == 5.0  # capped
    assert gcs_end(build_params(scenarios.get("gcs"), {"gcs.until": "seeds"})) == 8.0 + 33.0 + 1


# -- start-up -------------------------------------------------------------------------------------
HEAVY = ("pandas", "matplotlib", "scipy", "networkx", "tqdm")


def _heavy_modules_after(code: str) -> list[str]:
    probe = f"import sys\n{code}\nprint(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, check=True
    )
    return json.loads(done.stdout.splitlines()[-1].replace("'", '"'))


@pytest.mark.parametrize("argv", [["--help"], ["scenarios"], ["params"], ["run", "--help"]])
def test_listing_commands_import_no_heavy_library(argv):
    code = (
        f"from kilonet.app.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass"
    )
    assert _heavy_modules_after(code) == []


def test_the_top_level_help_loads_no_protocol_and_run_help_lists_the_scenario_options(capsys):
    code = (
        "import sys\nfrom kilonet.app.cli import main\ntry:\n    main(['--help'])\n"
        "except SystemExit:\n    pass\n"
        "print(sorted(m for m in sys.modules if m.startswith('kilonet.protocols')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True
    )
    assert done.stdout.splitlines()[-1] == "[]"
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "--until {ids,seeds,frames,localization,groups,merge,refine}" in capsys.readouterr().out


def test_a_run_reaches_its_first_event_without_pandas_or_matplotlib():
    code = (
        "from kilonet import scenarios\n"
        "from kilonet.scenarios.base import build_params, place\n"
        "from kilonet.simulation import Simulation\n"
        "s = scenarios.get('gradient'); p = build_params(s); x = place(s, p)\n"
        "sim = Simulation(x, s.setup.program(p, x), p); sim.start(); sim.env.step()"
    )
    assert _heavy_modules_after(code) == ["scipy"]  # the medium's k-d tree
