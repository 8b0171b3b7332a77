"""Named scenarios, by name. ``kilonet run NAME`` and sweeps look them up here.

A scenario registers itself as an entry point of the group ``kilonet.scenarios``
(``[project.entry-points."kilonet.scenarios"]`` in ``pyproject.toml``; a package of your own
can add scenarios the same way): the entry's name is the scenario's name, its value the
:class:`Scenario` object (``"kilonet.scenarios.gcs:SCENARIO"``), made of its :class:`Setup`
(what builds a run), :class:`Reporting` (what reports it) and :class:`Drawing` (what draws it).
A scenario's module is imported only when the scenario is asked for.

A researcher's own program file is a scenario too, under the name a sweep stores for it
(``program:/path/to/FILE.py:ClassName@SHA256``, :func:`kilonet.scenarios.program.program_key`):
:func:`get` loads the file by its path, so any process that sees the file can run it.
"""

from __future__ import annotations

from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from kilonet.lazy import lazy_exports

if TYPE_CHECKING:
    from kilonet.scenarios.base import Scenario

#: What :mod:`kilonet.scenarios.base` lends this package, imported on first use.
_FROM_BASE = (
    "Drawing",
    "Reporting",
    "RunResult",
    "Scenario",
    "ScenarioError",
    "Setup",
    "run",
    "run_with_params",
    "write_outputs",
)

__all__ = ["DEFAULT", "GROUP", *_FROM_BASE, "get", "names"]

#: Entry-point group of the scenarios.
GROUP = "kilonet.scenarios"

#: What ``kilonet run`` runs when no scenario is named.
DEFAULT = "gcs"

# The scenarios' machinery (numpy, the kernel) is imported on first use: the command line
# lists the scenarios' names for its help without it (kilonet.lazy).
__getattr__, __dir__ = lazy_exports(
    __name__,
    {name: "kilonet.scenarios.base" for name in _FROM_BASE},
    globals(),
)


def names() -> list[str]:
    """The registered scenarios' names, sorted (nothing is imported)."""
    return sorted({ep.name for ep in entry_points(group=GROUP)})


def get(name: str) -> Scenario:
    """The scenario called ``name``: a registered one, or a program file's
    (``program:FILE.py:ClassName@SHA256``, see :func:`kilonet.scenarios.program.program_key`).

    Raises
    ------
    ScenarioError
        If there is none; the message lists the known names. For a program file, a
        :class:`~kilonet.scenarios.program.ProgramError` if it cannot be loaded or changed since
        its name was made.
    TypeError
        If the entry point names something that is not a :class:`Scenario` (a packaging bug).
    """
    from kilonet.scenarios.base import Scenario, ScenarioError
    from kilonet.scenarios.program import PROGRAM_PREFIX, scenario_of_key

    if name.startswith(PROGRAM_PREFIX):
        return scenario_of_key(name)
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        known = ", ".join(names()) or f"none ({GROUP} entry points: is kilonet installed?)"
        raise ScenarioError(f"unknown scenario {name!r}; known scenarios: {known}")
    scenario = found[0].load()
    if not isinstance(scenario, Scenario) or scenario.name != name:
        raise TypeError(f"entry point {found[0].value} of {GROUP} is not the Scenario {name!r}")
    return scenario
