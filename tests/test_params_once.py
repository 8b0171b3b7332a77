"""Issue 42 item 5: ``kilonet run`` builds a run's parameters once and the run uses them."""

from __future__ import annotations

import json

import pytest

import kilonet.scenarios.base as base
from kilonet.app.cli import main
from kilonet.scenarios.thesis_placements import PREMISE


@pytest.fixture
def builds(monkeypatch):
    """Every call of the parameter builder, wherever it is called from."""
    calls = []
    real = base.build_params

    def counted(*args, **kwargs):
        calls.append((args, kwargs))
        return real(*args, **kwargs)

    # kilonet.app.commands imports it from base where it is called: patching base counts all
    monkeypatch.setattr(base, "build_params", counted)
    return calls


def test_kilonet_run_builds_the_parameters_once(builds, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["run", "gradient", "--robots", "10", "--duration", "2", "--out", str(out), "-q"]
    assert main(argv) == 0
    assert len(builds) == 1
    written = json.loads((out / "params.json").read_text())
    assert written["placement.robots"] == 10 and written["duration_s"] == 2.0
    assert json.loads((out / "summary.json").read_text())["robots"] == 10


def test_a_run_file_is_built_once_too_and_still_named_with_its_line(builds, tmp_path, capsys):
    good = tmp_path / "good.toml"
    good.write_text('scenario = "gradient"\nduration_s = 2.0\n[placement]\nrobots = 10\n')
    assert main(["run", str(good), "-q"]) == 0
    assert len(builds) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text('scenario = "gradient"\n[medium]\nloss_prob = 0.2\nlos = 1\n')
    assert main(["run", str(bad), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"kilonet: error: {bad}:4: ") and "medium.los" in err
    assert err.count("\n") == 1


def test_a_named_placement_brings_its_premise_into_the_one_build(builds, tmp_path):
    out = tmp_path / "run"
    argv = ["run", "gcs", "--placement", "thesis-7.1a", "--until", "ids", "--out", str(out), "-q"]
    assert main(argv) == 0
    assert len(builds) == 1
    written = json.loads((out / "params.json").read_text())
    assert {key: written[key] for key in PREMISE} == PREMISE
