"""The README a newcomer reads: its two set-up commands come first, its Python runs, its
commands name commands and scenarios that exist, and every file it or a docs page links to is
shipped."""

from __future__ import annotations

import re
import shlex
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from kilonet import scenarios
from kilonet.app.cli import COMMANDS

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text()
PAGES = [ROOT / "README.md", *sorted(ROOT.glob("docs/*.md")), *ROOT.glob("examples/**/*.md")]


def _blocks(text: str, language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", text, re.S)


def test_the_first_lines_give_the_two_set_up_commands():
    first = _blocks(README, "bash")[0].splitlines()
    assert [line.split("#")[0].strip() for line in first] == [
        "pip install . && kilonet run",
        "pip install -e '.[test]' && python -m pytest -n auto",
    ]
    assert README.index("```bash") < README.index("\n## ")


def test_ci_runs_the_readmes_test_command():
    test_command = _blocks(README, "bash")[0].splitlines()[1].split("#")[0].strip()
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert ci[-1] == test_command


def test_the_python_in_the_readme_runs(capsys):
    for block in _blocks(README, "python"):
        exec(compile(block, "README.md", "exec"), {})
    assert "[0, 1, 2]" in capsys.readouterr().out  # the gradient example's hop counts


def _commands() -> list[list[str]]:
    lines = [
        line.split("  #")[0] for block in _blocks(README, "bash") for line in block.splitlines()
    ]
    return [shlex.split(line) for line in lines if line.startswith("kilonet ")]


def test_every_kilonet_command_in_the_readme_exists_and_names_real_scenarios_and_files():
    known = {ep.name for ep in entry_points(group=COMMANDS)}
    for argv in _commands():
        assert argv[1].startswith("-") or argv[1] in known, argv
        if argv[1] == "run" and len(argv) > 2 and not argv[2].startswith("-"):
            target = argv[2]
            if not target.endswith(".toml"):
                assert target in scenarios.names(), argv
        for word in argv[2:]:
            if word.startswith(("experiments/", "examples/", "docs/")):
                assert (ROOT / word.split(":")[0]).exists(), word


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_every_relative_link_of_a_page_points_to_a_shipped_file(page):
    for target in re.findall(r"\]\(([^)#\s]+)\)", page.read_text()):
        if "://" in target:
            continue
        assert (page.parent / target).exists(), f"{page.name} links to a missing {target}"


def test_every_input_file_a_quick_start_command_names_exists():
    for argv in _commands():
        inputs = [w for k, w in enumerate(argv) if k == 0 or argv[k - 1] != "--out"]
        for word in inputs:
            path = word.split(":")[0]
            if path.endswith((".py", ".toml", ".csv")):
                assert (ROOT / path).exists(), f"the README's `{shlex.join(argv)}` names {path}"
