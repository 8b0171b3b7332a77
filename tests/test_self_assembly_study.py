"""The self-assembly study (experiments/studies/self_assembly_study.py), run on a tiny grid:
its sweep is valid, its runs go through the sweep machinery, and its report holds their
figures."""

from __future__ import annotations

import pandas as pd
import pytest

from kilonet.experiments.report import load
from kilonet.experiments.studies.self_assembly_study import (
    AXES,
    FIGURES,
    SWEEP,
    cell_table,
    run_study,
    write_report,
)
from kilonet.experiments.sweep import parse_sweep


def test_the_study_sweeps_ranging_loss_and_size_over_three_seeds_in_24_runs():
    sweep = parse_sweep(SWEEP, name="study")
    assert sweep.grid == {"ranging.model": ["tables", "gaussian"], "medium.loss_prob": [0.0, 0.2]}
    assert [case["placement.robots"] for case in sweep.cases] == [24, 48]
    assert sweep.seeds == (1, 2, 3) and len(sweep.runs()) == 24


#: Six robots (two move) into a 3 x 3 square of 40 mm cells, both ranging models, one seed.
TINY = """
scenario = "self-assembly"
seeds = 1
[fixed]
"placement.robots" = 6
"self_assembly.shape" = "square"
"self_assembly.cell_mm" = 40.0
duration_s = 600.0
"medium.loss_prob" = 0.0
[grid]
"ranging.model" = ["tables", "gaussian"]
"""


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    directory = tmp_path_factory.mktemp("study") / "runs"
    run_study(directory, TINY, workers=1)
    return directory


def test_the_tiny_study_runs_and_reports_each_cell(tiny, tmp_path):
    _, results = load(tiny)
    assert len(results) == 2 and set(results["status"]) == {"ok"}
    table = cell_table(results)
    assert list(table.columns) == ["ranging.model", "runs", *FIGURES]  # the axis it swept
    assert sorted(table["ranging.model"]) == ["gaussian", "tables"]
    for _, row in results.iterrows():
        mine = table[table["ranging.model"] == row["ranging.model"]].iloc[0]
        # one seed: the mean, the smallest and the largest are the run's own figure
        value = row["joined_fraction"]
        assert mine["joined_fraction"] == f"{value:.3f} ({value:.3f} to {value:.3f})"
    report = write_report(tiny, tmp_path / "report.md").read_text()
    assert report.startswith("# Self-assembly: ranging model, message loss and swarm size\n")
    assert "2 runs stored (0 failed)" in report and "| tables |" in report
    assert "## Beside the paper" in report


def test_a_study_with_no_finished_run_has_nothing_to_report():
    results = pd.DataFrame({"status": ["failed"], **{axis: [1] for axis in AXES}})
    with pytest.raises(ValueError, match="no run of the study finished"):
        cell_table(results)
