"""docs/testing.md stays true, and the pytest plugin works as an installed plugin.

The page's ``python`` blocks are one test module: pytest runs it (through ``pytester``, so
the fixtures come from the ``pytest11`` entry point as in a user's project) and every test in
it passes, except the one in the ``python fails`` block, whose failure message must be the
``text`` block that follows it.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import numpy.fft  # noqa: F401 - loaded before pytester's in-process runs, which would load it twice
import pytest

from kilonet.testing import ScriptedWorld

PAGE = Path(__file__).resolve().parents[1] / "docs" / "testing.md"
BLOCK = re.compile(r"^```(\w+)( fails)?\n(.*?)^```$", re.S | re.M)


def blocks() -> list[tuple[str, bool, str]]:
    return [(m[1], bool(m[2]), m[3]) for m in BLOCK.finditer(PAGE.read_text())]


def module_source() -> str:
    return "\n\n".join(code for lang, _, code in blocks() if lang == "python")


def test_the_pages_examples_pass_and_its_failing_example_fails(pytester: pytest.Pytester):
    pytester.makepyfile(test_page=module_source())
    result = pytester.runpytest("-p", "no:cacheprovider")
    failing = sum(1 for lang, fails, _ in blocks() if lang == "python" and fails)
    tests = module_source().count("\ndef test_")
    assert failing == 1 and tests == 6
    result.assert_outcomes(passed=tests - failing, failed=failing)


def test_the_failure_message_on_the_page_is_what_the_kit_says(tmp_path):
    pieces = blocks()
    (k,) = [i for i, (lang, fails, _) in enumerate(pieces) if fails]
    assert pieces[k + 1][0] == "text"
    path = tmp_path / "page_examples.py"  # a file, so the kit can quote a condition's source
    path.write_text(module_source())
    spec = importlib.util.spec_from_file_location("page_examples", path)
    page = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(page)
    with pytest.raises(AssertionError) as failure:
        page.test_a_wrong_expectation(ScriptedWorld)
    assert str(failure.value) == pieces[k + 1][2].rstrip("\n")


def test_a_failing_plain_assert_gets_the_worlds_timeline_in_its_report(pytester):
    pytester.makepyfile(
        """
        from kilonet import Kilobot, Layout

        PING = Layout("ping", type=2, fields=[("n", "B")])

        class Quiet(Kilobot):
            def message_rx(self, message, distance_mm):
                self.log("heard", n=PING.unpack(message).n)

        def test_plain_assert(scripted_world):
            world = scripted_world(Quiet(), layouts=[PING])
            world.hear(PING.pack(n=7), at_s=0.1, sender="s")
            world.advance(1.0)
            assert world.sent()

        def test_swarm_fixture(swarm):
            assert swarm(Quiet, "line", robots=2, until_s=0.5).t_s == 0.5
        """
    )
    result = pytester.runpytest("-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, failed=1)
    result.stdout.fnmatch_lines(
        [
            "*- kilonet scripted world 0 -*",
            "robot 0 (Quiet) at 1.000 s: kilo_ticks *, LED (0, 0, 0), motors (0, 0), running",
            "*0.104 s  from 's' at 50  Ping(n=7)",
            "*0.104 s  heard n=7",
        ]
    )


def test_the_defaults_table_is_what_the_code_does():
    import ast
    import importlib
    import inspect

    import kilonet.testing as kit
    from kilonet.params import Params

    text = PAGE.read_text()
    table = text[text.index("## The kit's defaults") :]
    cells = re.findall(r"^\| `([^`]+)` \|", table, re.M)
    assert len(cells) >= 14
    for cell in cells:
        constant = re.fullmatch(r"([\w.]+)\.(\w+) = (.+)", cell)
        if constant:
            module = importlib.import_module(constant[1])
            assert getattr(module, constant[2]) == ast.literal_eval(constant[3]), cell
            continue
        call = re.fullmatch(r"(\w+)(?:\.(\w+))?\((\w+)=(.+)\)", cell)
        assert call, cell
        owner = getattr(kit, call[1])
        function = getattr(owner, call[2]) if call[2] else owner
        default = inspect.signature(function).parameters[call[3]].default
        assert default == ast.literal_eval(call[4]), cell
    p = Params()
    assert p.seed == 1 and p.duration_s == 60
    assert "1 with the kernel's defaults" in table and "60 s runs" in table
    assert "to `duration_s`, 60 s" in table
