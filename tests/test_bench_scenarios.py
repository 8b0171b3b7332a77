"""benchmarks/bench_scenarios.py: a smoke run prints one row per asked row and size, each with
its CPU time and that time's ratio to its target."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


@pytest.fixture
def bench(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import bench_scenarios

    return bench_scenarios


def test_smoke_rows_have_cpu_and_ratio(bench, capsys: pytest.CaptureFixture[str]) -> None:
    bench.main(["--rows", "gcs", "kilombo", "--sizes", "8", "--duration", "2"])
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [(r["row"], r["robots"]) for r in rows] == [("gcs", 8), ("kilombo", 8)]
    gcs, kilombo = rows
    assert gcs["command"] == "kilonet run gcs --robots 8 --quiet --duration 2.0"
    assert gcs["cpu_s"] > 0 and gcs["target_cpu_s"] == 60.0
    assert gcs["ratio"] == round(gcs["cpu_s"] / 60.0, 3)
    assert kilombo["reference"] == "kilonet_channel_off"
    assert kilombo["ratio_to_reference"] == round(kilombo["cpu_s"] / kilombo["reference_cpu_s"], 2)
    assert kilombo["ratio"] is None  # only Kilombo itself judges the 4x target


def test_default_row_is_the_readme_run(bench) -> None:
    assert bench.cli_argv("default", 100, None) == ["run", "--quiet"]
    assert bench.cli_argv("localize", 1000, None) == [
        "run",
        "localize",
        "--robots",
        "1000",
        "--seed",
        "1",
        "--quiet",
    ]


def test_failed_run_is_one_line_error(bench) -> None:
    with pytest.raises(RuntimeError, match=r"^kilonet run nosuch: exit 2: .*nosuch"):
        bench.run_cli(["run", "nosuch"])


def test_tests_row_is_the_readme_test_command_less_its_install(bench, monkeypatch) -> None:
    readme = (BENCHMARKS.parent / "README.md").read_text()
    assert "python -m pytest -n auto" in readme
    seen = []
    monkeypatch.setattr(
        bench,
        "run_cli",
        lambda argv, module: seen.append((module, argv)) or {"cpu_s": 300.0, "wall_s": 90.0},
    )
    row = bench.tests_row()
    assert seen == [("pytest", ["-n", "auto", "-q", "-p", "no:cacheprovider"])]
    assert row["command"].startswith("python -m pytest -n auto")
    assert row["ratio"] == 0.5 and row["target_wall_s"] == 180.0


def test_a_failing_child_names_its_module(bench) -> None:
    with pytest.raises(RuntimeError, match=r"^pytest --no-such-option: exit 4"):
        bench.run_cli(["--no-such-option"], module="pytest")
