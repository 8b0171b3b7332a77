"""kilonet's pytest plugin: the test kit's fixtures, registered through the ``pytest11`` entry
point (``kilonet = "kilonet.testing.plugin"``), so any project with kilonet installed has them.

Fixtures
--------
``scripted_world``
    A factory: ``scripted_world(program, **options)`` is a :class:`kilonet.testing.ScriptedWorld`
    (same arguments). When the test fails, its report gets a section per world made, with
    what each robot under test heard, sent, logged and how its state ended.
``swarm``
    :func:`kilonet.testing.run_swarm`.

Importing this module imports neither kilonet's kernel nor NumPy: a session that uses no
fixture pays nothing for the plugin.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

__all__ = ["scripted_world", "swarm"]

_WORLDS = pytest.StashKey[list]()


@pytest.fixture
def scripted_world(request: pytest.FixtureRequest) -> Iterator[Callable[..., Any]]:
    """Build :class:`kilonet.testing.ScriptedWorld` s; a failing test's report shows each
    one's timeline."""
    from kilonet.testing import ScriptedWorld

    worlds: list = []
    request.node.stash[_WORLDS] = worlds

    def make(program: Any, **options: Any) -> ScriptedWorld:
        world = ScriptedWorld(program, **options)
        worlds.append(world)
        return world

    yield make


@pytest.fixture
def swarm() -> Callable[..., Any]:
    """:func:`kilonet.testing.run_swarm`."""
    from kilonet.testing import run_swarm

    return run_swarm


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo) -> Iterator[Any]:
    report = yield
    if report.when == "call" and report.failed:
        failure = str(call.excinfo.value) if call.excinfo is not None else ""
        for k, world in enumerate(item.stash.get(_WORLDS, [])):
            try:
                text = world.explain()
            except Exception as exc:  # a report must not hide the test's own failure
                text = f"(cannot describe the world: {exc!r})"
            if text not in failure:  # the kit's own assertions say it already
                report.sections.append((f"kilonet scripted world {k}", text))
    return report
