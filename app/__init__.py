"""The application: the ``kilonet`` command line (:mod:`kilonet.app.cli`) and the sub-commands
of the scenarios (``run``, ``scenarios``, ``params``, ``analyze``).

The top layer: it may use the experiments, the pictures, the scenarios and the kernel, and
nothing imports it. ``python -m kilonet`` and the ``kilonet`` console script start it.
"""
