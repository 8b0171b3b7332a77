"""Rubenstein's global coordinate system (thesis: Kaiser 2014), one module per phase.

* :mod:`~protocols.gcs.program` — the Kilobot program :class:`GcsRobot` that runs the phases.
* :mod:`~protocols.gcs.base` — its parameters, message layouts and the :class:`Phase` base.
* The thesis's phases, in order: :mod:`~protocols.gcs.phase1_unique_ids`,
  :mod:`~protocols.gcs.phase2_seed_election`, :mod:`~protocols.gcs.phase3_local_frames`,
  :mod:`~protocols.gcs.phase4_localization`, :mod:`~protocols.gcs.phase5_merging_groups`,
  :mod:`~protocols.gcs.phase6_merging`, and kilonet's phase 7,
  :mod:`~protocols.gcs.phase7_refinement`. A phase imports from earlier phases only.
* What the phases share: :mod:`~protocols.gcs.frame_keys` (frame names and ranks),
  :mod:`~protocols.gcs.merging_rules` (phase 6's decisions as pure functions),
  :mod:`~protocols.gcs.global_estimate` (a robot's global position),
  :mod:`~protocols.gcs.split_detection` and :mod:`~protocols.gcs.recovery` (the thesis's §7
  detection and remedy of split frames).
"""
