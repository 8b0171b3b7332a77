"""A design page (``docs/*.md``, not ``docs/results/``) says what and why and holds no
measurement history: no commit ids in prose, no "Measured" section, no "used to" or "before
issue N", no table of measured quantities (issue 42, item 7). Those belong to the generated
results pages, which ``python -m kilonet.experiments.publish`` rewrites and stamps. And every
test a design page cites as a check exists."""

from __future__ import annotations

import ast
import re
import subprocess
from itertools import pairwise
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DESIGN = sorted((ROOT / "docs").glob("*.md"))

#: Prose that is measurement history, each with what it is.
HISTORY = {
    "a commit id": re.compile(r"\bcommits? +[0-9a-f]{7,40}\b", re.I),
    "a 'Measured' heading": re.compile(r"^#{1,6} +Measured\b", re.I | re.M),
    "'used to' (what the code did once)": re.compile(
        r"(?<!\bis )(?<!\bare )(?<!\bbe )(?<!\bbeen )(?<!\bbeing )\bused to\b", re.I
    ),
    "'before issue N'": re.compile(r"\bbefore issue\b", re.I),
}
#: A header cell of a Markdown table that names a quantity a run measures.
MEASURED_COLUMN = re.compile(r"\bRMSE\b|\bCPU s\b|\bwall s\b", re.I)
#: A table's separator row: ``|---|:--:|``.
SEPARATOR = re.compile(r"^\|(?: *:?-+:? *\|)+ *$")


def history(text: str) -> list[str]:
    """What in ``text`` is measurement history: ``"<what>: <the words>"`` for each phrase of
    :data:`HISTORY` (searched with the lines joined, so a phrase broken over two lines counts;
    a heading, line by line) and for each table header (the row above a separator row) with a
    measured column."""
    prose = re.sub(r"[ \t]*\n[ \t]*(?!#)", " ", text)
    found = [
        f"{what}: {match.group(0)!r}"
        for what, pattern in HISTORY.items()
        for match in pattern.finditer(prose)
    ]
    lines = text.splitlines()
    for header, separator in pairwise(lines):
        if SEPARATOR.match(separator.strip()):
            cells = [c.strip() for c in header.strip().strip("|").split("|")]
            found += [f"a table of measured {c!r}" for c in cells if MEASURED_COLUMN.search(c)]
    return found


def ids(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@pytest.mark.parametrize("page", DESIGN, ids=ids)
def test_a_design_page_holds_no_measurement_history(page):
    assert history(page.read_text()) == [], f"{ids(page)} holds measurement history"


def test_the_old_localize_page_is_caught():
    """The page before issue 42's rewrite is history through and through: every kind of
    pattern fires on it."""
    old = subprocess.run(
        ["git", "show", "f0cef03:docs/localize.md"], cwd=ROOT, capture_output=True, text=True
    )
    if old.returncode != 0:
        pytest.skip("no git history here")
    found = history(old.stdout)
    kinds = {f.split(":")[0] for f in found}
    assert kinds >= {"a commit id", "a 'Measured' heading", "'used to' (what the code did once)",
                     "'before issue N'"}  # fmt: skip
    assert any(f.startswith("a table of measured 'RMSE mm (solver)'") for f in found)


@pytest.mark.parametrize(
    ("text", "kind"),
    [
        ("as at commit 5b7a32e the run", "a commit id"),
        ("## Measured\n\nthe runs", "a 'Measured' heading"),
        ("the rule used to place them", "'used to' (what the code did once)"),
        ("Before issue 33's rules four runs", "'before issue N'"),
        ("| case | RMSE mm |\n|---|---:|\n| a | 1 |", "a table of measured 'RMSE mm'"),
        ("| run | CPU s | wall s |\n| --- | --- | --- |", "a table of measured 'CPU s'"),
    ],
)
def test_each_kind_of_history_is_caught(text, kind):
    assert any(f.startswith(kind) for f in history(text)), history(text)


@pytest.mark.parametrize(
    "text",
    [
        "the key is used to sign; they are used to it",
        "a commit message says what and why",
        "| key | meaning |\n|---|---|\n| `rmse_mm` | RMSE of the estimates |",
        "measured noise (`sigma_mm`) scales each tolerance",
    ],
)
def test_design_prose_is_not_taken_for_history(text):
    assert history(text) == []


def _tests_defined() -> dict[str, set[str]]:
    out = {}
    for path in (ROOT / "tests").glob("test_*.py"):
        tree = ast.parse(path.read_text())
        out[f"tests/{path.name}"] = {
            node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef)
        }
    return out


@pytest.mark.parametrize("page", DESIGN, ids=ids)
def test_every_test_a_design_page_cites_exists(page):
    """``tests/test_x.py::name`` and, after it, ``::other`` (the same file) name tests."""
    defined = _tests_defined()
    current = None
    missing = []
    for match in re.finditer(r"`(tests/test_\w+\.py)?(?:::(\w+))?`", page.read_text()):
        file, name = match.groups()
        if file:
            if file not in defined:
                missing.append(file)
                continue
            current = file
        if name and (current is None or name not in defined[current]):
            missing.append(f"{current}::{name}")
    assert missing == [], f"{ids(page)} cites tests that do not exist"
