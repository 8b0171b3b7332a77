"""Report tables as a reader meets them: no exponents on counts, no fraction's interval past 1."""

from __future__ import annotations

import pandas as pd

from kilonet.experiments.report import _markdown_table, aggregate


def test_a_fractions_interval_stays_within_0_and_1():
    runs = pd.DataFrame(
        {
            "p": [0.1, 0.1, 0.1],
            "status": ["ok"] * 3,
            "gradient_correct_fraction": [1.0, 1.0, 0.9],
            "lost_random": [1.0, 1.0, 0.9],
        }
    )
    table = aggregate(runs, ["p"], ["gradient_correct_fraction", "lost_random"]).set_index("metric")
    assert table.loc["gradient_correct_fraction", "ci_high"] == 1.0
    assert table.loc["gradient_correct_fraction", "ci_low"] > 0.7
    assert table.loc["lost_random", "ci_high"] > 1.0  # not a fraction: the interval as it is


def test_counts_print_without_an_exponent():
    row = _markdown_table(pd.DataFrame({"mean": [76510.4], "std": [1234.56]}))[2]
    assert row == "| 76,510 | 1235 |"
