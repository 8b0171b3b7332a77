"""``kilonet --help`` and the listing of commands import nothing heavy (issue 44: the help
took 0.8 s when registering the commands imported numpy, the scenarios and a protocol)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

HEAVY = ("numpy", "scipy", "simpy", "pandas", "matplotlib", "networkx")

_CHILD = """
import contextlib, io, json, sys
from kilonet.app.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        status = main(ARGV)
    except SystemExit as exc:
        status = exc.code
print(json.dumps({"status": status, "help": out.getvalue(),
                  "heavy": sorted(m for m in HEAVY if m in sys.modules)}))
"""


def _imported(argv: list[str]) -> dict:
    """Run ``kilonet ARGV`` in a fresh interpreter; its exit status, output and the heavy
    modules it imported."""
    code = _CHILD.replace("ARGV", repr(argv)).replace("HEAVY", repr(HEAVY))
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    return json.loads(done.stdout.splitlines()[-1])


@pytest.mark.parametrize("argv", [["--help"], ["sweep", "--help"], ["analyze", "--help"]])
def test_help_imports_no_heavy_library(argv: list[str]) -> None:
    got = _imported(argv)
    assert got["status"] == 0
    assert got["heavy"] == []
    assert "usage: kilonet" in got["help"]


def test_help_lists_every_command() -> None:
    got = _imported(["--help"])
    for command in ("run", "scenarios", "params", "analyze", "animate", "sweep", "report"):
        assert any(line.split()[:1] == [command] for line in got["help"].splitlines())


def test_run_help_still_loads_the_scenario_options() -> None:
    """``kilonet run --help`` shows every scenario's own options, so it loads the scenarios
    (and numpy with them): the deferral must not lose them."""
    got = _imported(["run", "--help"])
    assert got["status"] == 0
    assert "--until {ids,seeds,frames,localization,groups,merge,refine}" in got["help"]
    assert "numpy" in got["heavy"]


def test_scenarios_package_exports_stay_reachable() -> None:
    """The names :mod:`kilonet.scenarios` exported eagerly before are still there, now
    imported on first use."""
    import kilonet.scenarios as scenarios
    from kilonet.scenarios.base import Scenario, ScenarioError

    assert scenarios.Scenario is Scenario
    assert isinstance(scenarios.get("gcs"), Scenario)
    with pytest.raises(ScenarioError, match="unknown scenario 'nope'; known scenarios: "):
        scenarios.get("nope")
