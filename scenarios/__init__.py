"""Named scenarios, by name. ``kilonet run NAME`` and sweeps look them up here.

A scenario registers itself as an entry point of the group ``kilonet.scenarios``
(``[project.entry-points."kilonet.scenarios"]`` in ``pyproject.toml``; a package of your own
can add scenarios the same way): the entry's name is the scenario's name, its value the
:class:`Scenario` object (``"kilonet.scenarios.gcs:SCENARIO"``). A scenario's module is imported
only when the scenario is asked for.
"""

from __future__ import annotations

from importlib.metadata import entry_points

from kilonet.scenarios.base import RunResult, Scenario, ScenarioError, run, write_outputs

__all__ = [
    "DEFAULT",
    "GROUP",
    "RunResult",
    "Scenario",
    "ScenarioError",
    "get",
    "names",
    "run",
    "write_outputs",
]

#: Entry-point group of the scenarios.
GROUP = "kilonet.scenarios"

#: What ``kilonet run`` runs when no scenario is named.
DEFAULT = "gcs"


def names() -> list[str]:
    """The registered scenarios' names, sorted (nothing is imported)."""
    return sorted({ep.name for ep in entry_points(group=GROUP)})


def get(name: str) -> Scenario:
    """The scenario called ``name``.

    Raises
    ------
    ScenarioError
        If there is none; the message lists the known names.
    TypeError
        If the entry point names something that is not a :class:`Scenario` (a packaging bug).
    """
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        known = ", ".join(names()) or f"none ({GROUP} entry points: is kilonet installed?)"
        raise ScenarioError(f"unknown scenario {name!r}; known scenarios: {known}")
    scenario = found[0].load()
    if not isinstance(scenario, Scenario) or scenario.name != name:
        raise TypeError(f"entry point {found[0].value} of {GROUP} is not the Scenario {name!r}")
    return scenario
