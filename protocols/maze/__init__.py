"""Maze localization (the lab seed): landmark trilateration, coverage, wall-based Bayes filter.

* :mod:`~kilonet.protocols.maze.program` — the maze robot's program.
* :mod:`~kilonet.protocols.maze.hardware` — the maze world and the hardware a maze robot carries
  (landmark camera, wall sensor, cell drive), which the maze scenario builds.
"""
