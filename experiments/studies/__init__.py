"""One-off studies and the measured figures of the docs, built on the sweep machinery above.

- :mod:`kilonet.experiments.studies.localization_study`: the localization study's tables and figures
  from the two ``localization_*.toml`` sweeps.
- :mod:`kilonet.experiments.studies.topology_study`: the report on the ``topology.toml`` sweep.
- :mod:`kilonet.experiments.studies.compare_reference_rules`: phase 3's two reference-selection
  rules compared by phase 4's accuracy.
- :mod:`kilonet.experiments.studies.gcs_measured`,
  :mod:`kilonet.experiments.studies.follower_measured`,
  :mod:`kilonet.experiments.studies.labs_measured`: the generated blocks of
  ``docs/results/gcs.md``, ``docs/results/follower.md`` and ``examples/labs/README.md``.
- :mod:`kilonet.experiments.studies.validation`: kilonet against real-Kilobot data
  (``docs/results/validation.md``).
- :mod:`kilonet.experiments.studies.self_assembly_study`: self-assembly against the ranging
  model, message loss and swarm size (issue 47), its sweep and its report.

:mod:`kilonet.experiments.publish` runs them; the sweep files stay in ``experiments/``.
"""
