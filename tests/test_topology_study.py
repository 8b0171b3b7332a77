"""The topology study (experiments/studies/topology_study.py) on hand-made sweep results."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from kilonet.experiments.studies.topology_study import (
    RANGE,
    RECOVERY,
    detection_scores,
    one_frame_shares,
    prediction_confusion,
)


def _run(range_mm, density, recoveries, frames, predicted, neighbours, flagged, boundary):
    return {
        "status": "ok",
        RANGE: range_mm,
        "placement.density_per_m2": density,
        RECOVERY: recoveries,
        "frames": frames,
        "predicted.final_frames": predicted,
        "mean_neighbours": neighbours,
        "detected.split_boundary": json.dumps(flagged),
        "failures.boundary": json.dumps(boundary),
    }


@pytest.fixture
def results() -> pd.DataFrame:
    rows = [
        _run(75, 350, 0, 2, 2, 4.0, [1, 2], [1, 3]),
        _run(75, 350, 2, 1, 2, 4.0, [], []),
        _run(85, 350, 0, 1, 1, 6.0, [], []),
        _run(85, 350, 2, 1, 1, 6.0, [], []),
        _run(85, 500, 0, 3, 2, 8.0, [4], [4, 5]),
        _run(85, 500, 2, 2, 2, 8.0, [], []),
    ]
    failed = dict(rows[0], status="failed", frames=9)
    return pd.DataFrame([*rows, failed])


def test_confusion_counts_runs_without_recovery_and_the_share_predicted(results):
    table, equal = prediction_confusion(results)
    assert equal == pytest.approx(2 / 3)
    assert table.loc[2, 2] == 1 and table.loc[1, 1] == 1 and table.loc[2, 3] == 1
    assert int(table.to_numpy().sum()) == 3  # the failed run and the recovery runs are left out


def test_one_frame_shares_by_neighbour_range_and_density(results):
    shares = one_frame_shares(results)
    assert shares.loc[(75, 350), "without recovery"] == 0.0
    assert shares.loc[(75, 350), "with recovery"] == 1.0
    assert shares.loc[(85, 500), "with recovery"] == 0.0
    assert shares.loc[("all", "all"), "without recovery"] == pytest.approx(1 / 3)
    assert shares.loc[("all", "all"), "with recovery"] == pytest.approx(2 / 3)
    assert shares.loc[(85, 500), "mean_neighbours"] == 8.0


def test_detection_pools_precision_and_recall(results):
    scores = detection_scores(results)
    assert scores["flagged"] == 3 and scores["boundary_robots"] == 4
    assert scores["precision"] == pytest.approx(2 / 3)
    assert scores["recall"] == pytest.approx(2 / 4)
