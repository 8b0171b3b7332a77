"""Rubenstein's global coordinate system (thesis: Kaiser 2014), one module per phase.

* :mod:`~kilonet.protocols.gcs.program` — the Kilobot program :class:`GcsRobot` that runs the
  phases.
* :mod:`~kilonet.protocols.gcs.base` — its parameters, message layouts and the :class:`Phase` base.
* The thesis's phases, in order: :mod:`~kilonet.protocols.gcs.phase1_unique_ids`,
  :mod:`~kilonet.protocols.gcs.phase2_seed_election`,
  :mod:`~kilonet.protocols.gcs.phase3_local_frames`,
  :mod:`~kilonet.protocols.gcs.phase4_localization`,
  :mod:`~kilonet.protocols.gcs.phase5_merging_groups`, :mod:`~kilonet.protocols.gcs.phase6_merging`,
  and kilonet's phase 7, :mod:`~kilonet.protocols.gcs.phase7_refinement`. A phase imports from
  earlier phases only.
* What the phases share: :mod:`~kilonet.protocols.gcs.frame_keys` (frame names and ranks),
  :mod:`~kilonet.protocols.gcs.merging_rules` (phase 6's decisions as pure functions),
  :mod:`~kilonet.protocols.gcs.global_estimate` (a robot's global position),
  :mod:`~kilonet.protocols.gcs.split_detection` and :mod:`~kilonet.protocols.gcs.recovery` (the
  thesis's §7 detection and remedy of split frames).
"""
