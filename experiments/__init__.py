"""Parameter sweeps over the named scenarios, a crash-safe results store, and reports.

- :mod:`kilonet.experiments.sweep`: sweep files (TOML) → validated
  :class:`~kilonet.experiments.sweep.Sweep` → runs (cells × seeds).
- :mod:`kilonet.experiments.runner`: runs the missing runs on a local process pool or a Dask
  cluster.
- :mod:`kilonet.experiments.store`: one SQLite row per finished run, appended durably.
- :mod:`kilonet.experiments.report`: DataFrames and Figures aggregated over seeds; HTML/Markdown
  files.
- :mod:`kilonet.experiments.cli`: the ``kilonet sweep`` and ``kilonet report`` sub-commands.
- :mod:`kilonet.experiments.publish`: regenerates the docs' measured blocks and the sweeps' reports.
- :mod:`kilonet.experiments.studies`: one-off studies and the docs' measured figures.

The shipped sweeps are the ``*.toml`` files beside this module; their reports are in
``experiments/reports/``.
"""
