"""The summary's truth-measured fold figure (``fold_outliers``, kilonet.scenarios.gcs) on the
double ring of issue 46 (tests/data/gcs_fold_double_ring.csv, 94 robots), with the robots'
fold rule off and on (``gcs.fold``, kilonet.protocols.gcs.split_detection).

Off, seed 1 ends with one robot, a bad fix about 117 mm off, whose estimated distances disagree
with the true ones to a majority of its neighbours: robot 74, which never settles (it missed the
done mark of one transform, from a seed at the edge of its range). On, the swarm finds its folds
itself, and repairs or splits them: no final frame holds an outlier.
"""

from __future__ import annotations

import json
from pathlib import Path

from kilonet.app.cli import main

RING = Path(__file__).parent / "data" / "gcs_fold_double_ring.csv"


def _summary(capsys, fold: bool) -> dict:
    args = ["run", "gcs", "--placement", str(RING), "--seed", "1", "--json"]
    assert main([*args, "--set", f"gcs.fold={str(fold).lower()}"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["robots"] == 94
    return summary


def test_the_double_ring_reports_its_fold_with_the_rule_off(capsys):
    summary = _summary(capsys, fold=False)
    assert summary["fold_outliers"] == [74]
    assert summary["fold_repaired"] == summary["fold_split"] == 0


def test_the_swarm_repairs_or_splits_the_double_rings_folds(capsys):
    summary = _summary(capsys, fold=True)
    assert summary["fold_outliers"] == []
    assert summary["fold_repaired"] + summary["fold_split"] > 0
    assert summary["localized_fraction"] == 1.0
