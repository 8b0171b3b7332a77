"""The stages of ``localize`` on one robot, in order
(:class:`kilonet.protocols.common.phases.Stage`).

``election`` (phase 1, :mod:`kilonet.protocols.localize.phase1_election`), ``localize`` (the spread
and termination, phases 2 and 3), ``island`` (after DONE, for a robot of an island the spread left
out: phase 4, :mod:`kilonet.protocols.localize.phase4_island`) and ``done``. Members compare equal
to their names, which the trace's ``stage`` events carry.

>>> LocalizeStage.names()
('election', 'localize', 'island', 'done')
"""

from __future__ import annotations

from kilonet.protocols.common.phases import Stage

__all__ = ["LocalizeStage"]


class LocalizeStage(Stage):
    """Where a ``localize`` robot is: electing, localizing, placing its island, or done."""

    ELECTION = "election"
    LOCALIZE = "localize"
    ISLAND = "island"
    DONE = "done"
