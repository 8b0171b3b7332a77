"""Every benchmark the docs name runs on this code: each at a small size, so a script that a
published figure cites cannot rot unnoticed (issue 43: two of them had stopped running)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: script -> small arguments, and a pattern its last line of output must match.
SMOKE = {
    "bench_animation.py": (
        ["--robots", "20", "--sim-s", "10", "--video-s", "1", "--fps", "5"],
        r"ms/frame",
    ),
    "bench_delivery.py": (["--collided", "0.4", "--repeat", "1"], r"us per transmission"),
    "bench_gcs.py": (["--sizes", "20", "--seed", "1", "--floor"], r'"floor": "table"'),
    "bench_kilombo.py": (["--sizes", "50", "--repeat", "1"], r'"robots": 50'),
    "bench_large.py": (
        ["--runs", "gradient", "--robots", "20", "--timeout", "60"],
        r'"finished": true',
    ),
    "bench_locality.py": (
        ["--sizes", "50", "--transmissions", "1000", "--repeat", "1"],
        r"ns / event",
    ),
    "bench_localize.py": (["--sizes", "30", "--seeds", "1"], r'"localized_fraction": 1\.0'),
    "bench_math.py": (["--repeat", "1", "--crlb-robots", "30"], r"crlb_rmse_mm, 30 robots"),
    "bench_medium.py": (["--sizes", "30", "--sim-s", "5", "--repeat", "1"], r"^\s+30\s"),
    "bench_scenarios.py": (
        ["--rows", "gcs", "localize", "--sizes", "20", "--duration", "5"],
        r'"ratio"',
    ),
    "bench_startup.py": (["--robots", "20", "--repeat", "1"], r"first event after"),
    "bench_sweep.py": (
        ["--workers", "1", "--seeds", "1", "--robots", "10", "--sim-s", "2"],
        r"load average",
    ),
    "bench_testkit.py": (["--tests", "5", "--repeat", "1"], r"ms$"),
    "gcs_windows.py": (["--sizes", "20", "--seeds", "1"], r'"robots": 20'),
}


def test_every_benchmark_script_has_a_smoke_run():
    scripts = {p.name for p in (ROOT / "benchmarks").glob("*.py")}
    assert scripts - set(SMOKE) == set(), "add a small run of each new benchmark here"


def test_every_benchmark_the_docs_name_exists():
    named = set()
    for page in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]:
        named.update(re.findall(r"benchmarks/(\w+\.py)", page.read_text()))
    assert named <= set(SMOKE), named - set(SMOKE)


@pytest.mark.parametrize("script", sorted(SMOKE))
def test_the_benchmark_runs_at_a_small_size(script: str, tmp_path: Path):
    argv, last_line = SMOKE[script]
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / script), *argv],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.strip().splitlines()
    assert lines and re.search(last_line, lines[-1]), done.stdout[-2000:]
