"""Presentation: pictures of finished runs, a layer above ``scenarios/``.

It reads the run directory that :func:`kilonet.scenarios.base.write_run_files` writes, so it sits
above the scenarios (and below ``experiments/``, whose ``publish`` draws the README's animation).

* :mod:`~kilonet.viz.animation` — :func:`animate_run`: a run as GIF, MP4 or HTML replay.
* :mod:`~kilonet.viz.cli` — the ``kilonet animate`` command and ``kilonet run --animate``.
"""
