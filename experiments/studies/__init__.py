"""One-off studies and the measured figures of the docs, built on the sweep machinery above.

- :mod:`experiments.studies.localization_study`: the localization study's tables and figures
  from the two ``localization_*.toml`` sweeps.
- :mod:`experiments.studies.topology_study`: the report on the ``topology.toml`` sweep.
- :mod:`experiments.studies.compare_reference_rules`: phase 3's two reference-selection rules
  compared by phase 4's accuracy.
- :mod:`experiments.studies.gcs_measured`, :mod:`experiments.studies.follower_measured`,
  :mod:`experiments.studies.labs_measured`: the generated blocks of ``docs/gcs.md``,
  ``docs/follower.md`` and ``examples/labs/README.md``.
- :mod:`experiments.studies.validation`: kilonet against real-Kilobot data
  (``docs/validation.md``).

:mod:`experiments.publish` runs them; the sweep files stay in ``experiments/``.
"""
