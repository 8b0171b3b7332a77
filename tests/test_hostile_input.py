"""Hostile and generated input to the command line: every outcome is a run (exit 0) or one line
on stderr with exit 2, never a traceback, a hang or a half-written output.

The regression tests pin the cases found by hand and by the fuzz campaign; the Hypothesis tests
draw placements, ``--set`` values and sweep files and run the real ``kilonet`` entry point
(:func:`kilonet.cli.main`) in-process on tiny swarms. ``test_cli_fuzz_campaign`` is the long
campaign (``-m slow``).
"""

from __future__ import annotations

import json

import pytest

import kilonet.cli

SCENARIOS = ("gradient", "localize", "follower", "gcs", "maze")


def _kilonet(argv: list[str], capsys) -> tuple[int, str]:
    status = kilonet.cli.main(argv)
    return status, capsys.readouterr().err


def _one_line(err: str) -> str:
    assert err.startswith("kilonet: error: "), err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


# ---------------------------------------------------------------------------- regressions


@pytest.mark.parametrize("scenario", ["gradient", "localize", "follower", "gcs"])
def test_the_thesis_message_format_is_refused_in_one_line_by_scenarios_it_cannot_carry(
    tmp_path, capsys, scenario
):
    argv = ["run", scenario, "--duration", "2", "--set", "medium.message_format=thesis"]
    status, err = _kilonet([*argv, "--out", str(tmp_path / "out")], capsys)
    assert status == 2
    assert _one_line(err) == (
        f"kilonet: error: medium.message_format = 'thesis': the {scenario} scenario's messages "
        "need the 'kilolib' format (its type byte and payload do not fit the thesis's 23 "
        "bits)\n"
    )
    assert not (tmp_path / "out").exists()


def test_a_sweep_over_the_message_format_is_refused_naming_the_cell(tmp_path, capsys):
    sweep = tmp_path / "formats.toml"
    sweep.write_text(
        'scenario = "gradient"\n[fixed]\nduration_s = 2.0\n'
        '[grid]\n"medium.message_format" = ["kilolib", "thesis"]\n'
    )
    status, err = _kilonet(["sweep", str(sweep), "--out", str(tmp_path / "out")], capsys)
    assert status == 2
    assert _one_line(err).startswith(
        f"kilonet: error: {sweep}: [grid] medium.message_format = 'thesis': the gradient "
    )
    assert not (tmp_path / "out").exists()


def test_the_maze_runs_with_the_thesis_message_format(capsys):
    argv = ["run", "maze", "--duration", "5", "--json", "--set", "medium.message_format=thesis"]
    status, err = _kilonet(argv, capsys)
    assert status == 0, err


def test_localize_with_every_robot_crashed_writes_its_figure(tmp_path, capsys):
    out = tmp_path / "out"
    argv = ["run", "localize", "--robots", "12", "--duration", "3", "--out", str(out)]
    status, err = _kilonet([*argv, "--set", "faults.crash_fraction=1"], capsys)
    assert status == 0, err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["localized_fraction"] == 0 and summary["rmse_mm"] is None
    assert (out / "localize.png").stat().st_size > 0


@pytest.mark.parametrize("y", ["1e-30", "0", "-1e-300"])
def test_the_gradient_figure_of_a_swarm_without_height(tmp_path, capsys, y):
    placement = tmp_path / "line.csv"
    placement.write_text(f"x_mm,y_mm\n0,0\n40,{y}\n80,0\n")
    out = tmp_path / "out"
    argv = ["run", "gradient", "--placement", str(placement), "--duration", "1"]
    status, err = _kilonet([*argv, "--out", str(out)], capsys)
    assert status == 0, err
    assert (out / "gradient.png").stat().st_size > 0


def test_a_uid_that_only_python_calls_a_digit_is_one_line(tmp_path, capsys):
    placement = tmp_path / "uids.csv"
    placement.write_text("x_mm,y_mm,uid\n0,0,1\n40,0,²\n", encoding="utf-8")
    status, err = _kilonet(["run", "gradient", "--placement", str(placement)], capsys)
    assert status == 2
    assert _one_line(err) == (
        f"kilonet: error: {placement} line 3: uid is not an integer 0-65535 ('²')\n"
    )
