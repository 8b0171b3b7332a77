"""Issue 42 item 5: a Scenario is what builds a run, what reports it and what draws it."""

from __future__ import annotations

import dataclasses

import pytest

from kilonet import scenarios
from kilonet.scenarios.base import Drawing, Reporting, Setup


@pytest.mark.parametrize("name", scenarios.names())
def test_every_registered_scenario_is_made_of_the_three_parts(name):
    scenario = scenarios.get(name)  # through its kilonet.scenarios entry point
    assert [f.name for f in dataclasses.fields(scenario)] == [
        "name",
        "summary",
        "setup",
        "reporting",
        "drawing",
    ]
    assert isinstance(scenario.setup, Setup) and callable(scenario.setup.program)
    assert isinstance(scenario.reporting, Reporting) and callable(scenario.reporting.metrics)
    assert isinstance(scenario.drawing, Drawing) and callable(scenario.drawing.figures)


def test_a_program_file_is_a_scenario_of_the_same_parts(tmp_path):
    from kilonet.scenarios.program import program_scenario

    (tmp_path / "bot.py").write_text(
        "from kilonet import Kilobot\n\nclass Bot(Kilobot):\n    gain = 0.5\n"
        "    def loop(self):\n        pass\n"
    )
    scenario = program_scenario(str(tmp_path / "bot.py"), {"gain": 0.7})
    assert scenario.setup.robots == 0 and scenario.setup.defaults == {"program.gain": 0.7}
    assert scenario.setup.section.section_name == "program"
    assert scenario.reporting.robot_columns is None  # no report() method
    assert callable(scenario.drawing.figures)


def test_the_parts_have_their_defaults():
    scenario = scenarios.Scenario("bare", "a scenario of a program only", Setup(lambda p, x: None))
    assert scenario.reporting == Reporting() and scenario.drawing == Drawing()
    assert scenario.setup.robots == 100 and scenario.setup.options == ()
