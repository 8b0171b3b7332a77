"""docs/outputs.md documents every key of every scenario's summary.json and every file a run
writes, and nothing else."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from kilonet import scenarios
from kilonet.scenarios.base import RunResult, write_run_files
from kilonet.scenarios.program import program_scenario

OUTPUTS = Path(__file__).resolve().parents[1] / "docs" / "outputs.md"


def documented_keys(text: str) -> set[str]:
    """The dotted keys in the first column of the summary tables; ``.seeds`` after
    ``phase_times_s.ids`` in one cell is ``phase_times_s.seeds``."""
    keys = set()
    summary = text[text.index("## Summary keys") :]
    for line in summary.splitlines():
        if not line.startswith("| `"):
            continue
        names = re.findall(r"`([^`]+)`", line.split("|")[1])
        prefix = names[0].rpartition(".")[0]
        keys.update(f"{prefix}{n}" if n.startswith(".") else n for n in names)
    return keys


def flat_keys(summary: dict, prefix: str = "") -> set[str]:
    out = set()
    for key, value in summary.items():
        if isinstance(value, dict):
            out |= flat_keys(value, f"{prefix}{key}.")
        else:
            out.add(f"{prefix}{key}")
    return out


@pytest.fixture(scope="module")
def results(tmp_path_factory) -> dict[str, RunResult]:
    program = tmp_path_factory.mktemp("program") / "idle.py"
    program.write_text("from kilonet.robot import Kilobot\n\n\nclass Idle(Kilobot):\n    pass\n")
    runs = {
        "gcs": (scenarios.get("gcs"), {"placement.robots": 12}),
        "gcs_refine": (scenarios.get("gcs"), {"placement.robots": 12, "gcs.refine": True}),
        "gradient": (scenarios.get("gradient"), {"duration_s": 5.0}),
        "follower": (scenarios.get("follower"), {}),
        "localize": (scenarios.get("localize"), {"placement.robots": 20}),
        "maze": (scenarios.get("maze"), {"maze.size": "2x2"}),
        "program": (program_scenario(str(program)), {"placement.robots": 3, "duration_s": 1.0}),
    }
    return {name: scenarios.run(s, o) for name, (s, o) in runs.items()}


@pytest.fixture(scope="module")
def summaries(results) -> dict[str, set[str]]:
    return {name: flat_keys(result.summary) for name, result in results.items()}


def test_every_file_a_run_writes_is_documented(results, tmp_path):
    named = set(re.findall(r"`([\w.-]+\.(?:png|csv|txt|json|py))`", OUTPUTS.read_text()))
    missing = {}
    for name, result in results.items():
        out = tmp_path / name
        out.mkdir()
        written = {p.name for p in write_run_files(result, out)}
        missing[name] = sorted(written - named)
    assert all(not files for files in missing.values()), f"unlisted in {OUTPUTS}: {missing}"


def test_every_summary_key_is_documented(summaries):
    documented = documented_keys(OUTPUTS.read_text())
    missing = {name: sorted(keys - documented) for name, keys in summaries.items()}
    assert all(not keys for keys in missing.values()), f"undocumented in {OUTPUTS}: {missing}"


def test_every_documented_key_exists(summaries):
    produced = set().union(*summaries.values())
    stale = sorted(documented_keys(OUTPUTS.read_text()) - produced)
    assert not stale, f"{OUTPUTS} documents keys no run writes: {stale}"
