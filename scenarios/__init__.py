"""Named scenarios, by name. ``kilonet run NAME`` and sweeps look them up here."""

from __future__ import annotations

from scenarios import follower, gcs, gradient, localize, maze
from scenarios.base import RunResult, Scenario, ScenarioError, run, write_outputs

__all__ = [
    "DEFAULT",
    "SCENARIOS",
    "RunResult",
    "Scenario",
    "ScenarioError",
    "get",
    "run",
    "write_outputs",
]

SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        follower.SCENARIO,
        gcs.SCENARIO,
        gradient.SCENARIO,
        localize.SCENARIO,
        maze.SCENARIO,
    )
}

#: What ``kilonet run`` runs when no scenario is named.
DEFAULT = "gcs"


def get(name: str) -> Scenario:
    """The scenario called ``name``.

    Raises
    ------
    ScenarioError
        If there is none; the message lists the known names.
    """
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ScenarioError(
            f"unknown scenario {name!r}; known scenarios: {', '.join(sorted(SCENARIOS))}"
        ) from None
