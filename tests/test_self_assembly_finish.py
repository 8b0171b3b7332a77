"""A self-assembly run ends when the assembly is done or has stalled, not at its time cap."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from kilonet.protocols.self_assembly.program import AssemblyStage
from kilonet.scenarios.self_assembly import STALLED_S, _stop_when


def _robot(stage: AssemblyStage, since_joined_s: float | None = None) -> SimpleNamespace:
    return SimpleNamespace(stage=stage, since_joined_s=lambda: since_joined_s)


S, W, M, J, L = (
    AssemblyStage.SEED,
    AssemblyStage.WAIT,
    AssemblyStage.MOVE_OUTSIDE,
    AssemblyStage.JOINED,
    AssemblyStage.LOST,
)


@pytest.mark.parametrize(
    ("robots", "stops"),
    [
        ([_robot(S), _robot(J, 5.0), _robot(L)], True),  # done
        ([_robot(S), _robot(J, STALLED_S + 1), _robot(M)], True),  # stalled: no room left
        ([_robot(S), _robot(J, STALLED_S + 1), _robot(J, 10.0), _robot(M)], False),
        ([_robot(S), _robot(J, STALLED_S + 1), _robot(M), _robot(W)], True),  # blocked start
        ([_robot(S), _robot(J, STALLED_S - 1), _robot(W)], False),
        ([_robot(S), _robot(M)], False),  # none joined yet
    ],
)
def test_the_run_ends_when_every_robot_is_done_or_none_joined_for_the_stall_window(robots, stops):
    assert _stop_when(SimpleNamespace(robots=robots)) is stops
