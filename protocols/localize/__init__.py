"""``localize``: one global frame for a whole swarm, grown from one elected root.

* :mod:`~kilonet.protocols.localize.program` — the Kilobot program :class:`LocalizeRobot`.
* :mod:`~kilonet.protocols.localize.base` — its parameters, neighbour table and message layouts.
* Its phases, in order: :mod:`~kilonet.protocols.localize.phase1_election` (root and tree),
  :mod:`~kilonet.protocols.localize.phase2_spread` (the frame spreads outward),
  :mod:`~kilonet.protocols.localize.phase3_termination` (the swarm decides it is done),
  :mod:`~kilonet.protocols.localize.phase4_island` (left-out islands place themselves).
* :mod:`~kilonet.protocols.localize.island_solve` — the island's math (pure, no robot API).
"""
