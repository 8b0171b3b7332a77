"""Every slow test has a default-tier twin, so every claim it makes can fail in CI.

CI runs the default tier only (``-m 'not slow'``, pyproject.toml). A slow test is twinned when
its own file holds a default-tier test that makes its assertions on a smaller run: either
another parametrization of the same function (the full size carries ``marks=pytest.mark.slow``)
or a test marked ``@pytest.mark.twin_of("<slow test's function>")``. A strict xfail's twin must
be a strict xfail too. The convention is in docs/testing.md ("Slow tests and their twins").
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: A pytest plugin for the collecting subprocess: every collected test, slow or not, its marks.
PLUGIN = textwrap.dedent(
    """
    import json, os

    def pytest_collection_finish(session):
        rows = []
        for item in session.items:
            xfail = item.get_closest_marker("xfail")
            rows.append({
                "nodeid": item.nodeid,
                "file": item.nodeid.split("::")[0],
                "function": getattr(item, "originalname", item.name),
                "slow": item.get_closest_marker("slow") is not None,
                "twin_of": [m.args[0] for m in item.iter_markers("twin_of")],
                "strict_xfail": xfail is not None and xfail.kwargs.get("strict", False),
            })
        with open(os.environ["SLOW_TWINS_OUT"], "w") as out:
            json.dump(rows, out)
    """
)


#: pytest's options for the collecting subprocess: the plugin, and slow tests not deselected.
COLLECT = ["-p", "slow_twins_plugin", "-p", "no:cacheprovider", "-m", "slow or not slow"]


@dataclass(frozen=True)
class Collected:
    """One collected test: its node id, file, function, and the marks the rule looks at."""

    nodeid: str
    file: str
    function: str
    slow: bool
    twin_of: list[str]
    strict_xfail: bool


def missing_twins(tests: list[Collected]) -> list[str]:
    """What breaks the convention, one line each (empty when every slow test is twinned).

    There is no exemption: a claim no smaller run can make runs at full size in the default
    tier instead of being marked slow.
    """
    problems = []
    slow = [t for t in tests if t.slow]
    slow_functions = {(t.file, t.function) for t in slow}
    default = [t for t in tests if not t.slow]
    for s in slow:
        twins = [
            t
            for t in default
            if t.file == s.file and (t.function == s.function or s.function in t.twin_of)
        ]
        if not twins:
            problems.append(f"{s.nodeid}: slow, and no default-tier twin in {s.file}")
        elif s.strict_xfail and not any(t.strict_xfail for t in twins):
            problems.append(f"{s.nodeid}: a strict xfail whose twins are not strict xfails")
    for t in default:
        for name in t.twin_of:
            if (t.file, name) not in slow_functions:
                problems.append(f"{t.nodeid}: twin_of({name!r}) names no slow test in {t.file}")
    return problems


def collect_all(tmp_path: Path) -> list[Collected]:
    """Every test of the suite, slow or not, as pytest itself collects it (a subprocess)."""
    (tmp_path / "slow_twins_plugin.py").write_text(PLUGIN)
    out = tmp_path / "collected.json"
    env = {
        **os.environ,
        "PYTHONPATH": str(tmp_path),
        "SLOW_TWINS_OUT": str(out),
    }
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "--collect-only", "-q", *COLLECT],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return [Collected(**row) for row in json.loads(out.read_text())]


def test_every_slow_test_has_a_default_tier_twin(tmp_path):
    tests = collect_all(tmp_path)
    assert sum(t.slow for t in tests) > 0 and sum(not t.slow for t in tests) > 1000
    assert missing_twins(tests) == []


def _test(function: str, *, slow: bool, twin_of=(), strict_xfail=False, param="") -> Collected:
    file = "tests/test_x.py"
    return Collected(
        f"{file}::{function}{param}", file, function, slow, list(twin_of), strict_xfail
    )


def test_the_rule_reports_a_slow_test_without_a_twin():
    tests = [_test("test_big", slow=True), _test("test_other", slow=False)]
    assert missing_twins(tests) == [
        "tests/test_x.py::test_big: slow, and no default-tier twin in tests/test_x.py"
    ]


def test_the_rule_takes_a_marked_twin_or_a_smaller_parametrization():
    marked = [_test("test_big", slow=True), _test("test_small", slow=False, twin_of=["test_big"])]
    sized = [
        _test("test_big", slow=True, param="[300]"),
        _test("test_big", slow=False, param="[40]"),
    ]
    assert missing_twins(marked) == missing_twins(sized) == []


def test_the_rule_wants_a_strict_xfail_twinned_by_a_strict_xfail():
    tests = [
        _test("test_big", slow=True, strict_xfail=True),
        _test("test_small", slow=False, twin_of=["test_big"]),
    ]
    assert missing_twins(tests) == [
        "tests/test_x.py::test_big: a strict xfail whose twins are not strict xfails"
    ]


def test_the_rule_reports_a_dangling_twin():
    tests = [_test("test_small", slow=False, twin_of=["test_gone"])]
    assert missing_twins(tests) == [
        "tests/test_x.py::test_small: twin_of('test_gone') names no slow test in tests/test_x.py"
    ]
