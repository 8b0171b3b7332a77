"""``localize``: one global frame for a whole swarm, grown from one elected root.

* :mod:`~protocols.localize.program` — the Kilobot program :class:`LocalizeRobot`.
* :mod:`~protocols.localize.base` — its parameters, neighbour table and message layouts.
* Its phases, in order: :mod:`~protocols.localize.phase1_election` (root and tree),
  :mod:`~protocols.localize.phase2_spread` (the frame spreads outward),
  :mod:`~protocols.localize.phase3_termination` (the swarm decides it is done),
  :mod:`~protocols.localize.phase4_island` (left-out islands place themselves).
* :mod:`~protocols.localize.island_solve` — the island's math (pure, no robot API).
"""
