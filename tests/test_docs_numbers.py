"""Numbers in docs prose that the code decides, re-derived from the code (the measured ones sit
in ``python -m kilonet.experiments.publish`` blocks)."""

from __future__ import annotations

import math
import re
from pathlib import Path

from kilonet import scenarios
from kilonet.protocols.gcs.program import phase_windows_s
from kilonet.scenarios.base import build_params

ROOT = Path(__file__).resolve().parents[1]


def prose(page: str) -> str:
    return " ".join((ROOT / page).read_text().split())


def test_gcs_md_names_when_phase_5_starts_and_how_far_clocks_drift_by_then():
    text = prose("docs/gcs.md")
    match = re.search(r"`robot.clock_sd` = (\d+) % by default: by phase 5, (\d+) s in, two "
                      r"robots' windows are typically about a second apart", text)  # fmt: skip
    assert match, "the sentence on phase windows and clock drift changed"
    params = build_params(scenarios.get("gcs"))
    assert int(match[1]) == round(100 * params.robot.clock_sd)
    starts = {name: start for name, start, _ in phase_windows_s(params.scenario)}
    assert int(match[2]) == starts["groups"]
    # two robots' clocks differ by N(0, sqrt(2) * clock_sd) of the elapsed time
    apart_s = math.sqrt(2) * params.robot.clock_sd * starts["groups"]
    assert 0.7 <= apart_s <= 1.5
