"""The summary's truth-measured fold figure (``fold_outliers``, kilonet.scenarios.gcs) on the
double ring of issue 46 (tests/data/gcs_fold_double_ring.csv, 94 robots): seed 1 ends with
one robot, a bad fix about 117 mm off, whose estimated distances disagree with the true ones
to all six of its neighbours; the swarm does not repair it yet (the rule,
kilonet.protocols.gcs.fold_rule, is not wired in)."""

from __future__ import annotations

import json
from pathlib import Path

from kilonet.app.cli import main

RING = Path(__file__).parent / "data" / "gcs_fold_double_ring.csv"


def test_the_double_ring_reports_its_fold(capsys):
    assert main(["run", "gcs", "--placement", str(RING), "--seed", "1", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["robots"] == 94
    assert summary["fold_outliers"] == [74]
