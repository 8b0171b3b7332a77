"""The maze robot's hardware against the true world: what its camera, wall sensor and drive read
and move.

:class:`kilonet.protocols.maze.hardware.MazeKilobot` is the robot side: its program calls
``sense_landmark_ranges()``, ``sense_walls()`` and ``drive()``, which reach the robot's ``"maze"``
part (:meth:`kilonet.robot.Kilobot.hardware`). This module is the other side, a sensor and
actuator model like :mod:`kilonet.sensors`: a :class:`MazeBody` is handed the ground truth it
reads (the world's positions and present and running flags, the true maze), the run's random
streams and the motion service, and nothing else. :func:`fit_maze_hardware` gives the run's
``Simulation(hardware=...)`` the fit that builds one per robot.

Randomness, as on the robot: range and wall readings draw from the run's ``ranging`` stream,
slips from its ``motion`` stream, each at the moment the program asks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from kilonet.protocols.maze.hardware import Maze, MazeError, RangeSensor, WallSensor

if TYPE_CHECKING:
    from kilonet.motion import Motion
    from kilonet.simulation import Simulation
    from kilonet.world import World

__all__ = ["MazeBody", "MazeHardware", "fit_maze_hardware"]


@dataclass(frozen=True)
class MazeHardware:
    """What a maze robot is built with and where it runs.

    Parameters
    ----------
    maze : Maze
        The true maze it stands in.
    range_sensor : RangeSensor
        Its landmark camera.
    wall_sensor : WallSensor
        Its wall sensor.
    landmark_robots : tuple of int
        Indices of the robots that are the landmarks, in the order the camera reports them (it
        tells landmarks apart by colour).
    slip_prob : float
        Probability that a commanded move leaves the robot in its cell (motor stall).
    """

    maze: Maze
    range_sensor: RangeSensor = field(default_factory=RangeSensor)
    wall_sensor: WallSensor = field(default_factory=WallSensor)
    landmark_robots: tuple[int, ...] = ()
    slip_prob: float = 0.0


class MazeBody:
    """One robot's maze hardware in the world: camera, wall sensor and cell drive.

    Parameters
    ----------
    spec : MazeHardware
        The hardware and the true maze.
    robot : int
        The robot that carries it.
    world : World
        Where the robots stand (read at each reading and move).
    ranging, motion_rng : numpy.random.Generator
        The run's ``ranging`` stream (range and wall readings) and ``motion`` stream (slips).
    motion : Motion
        The run's motion service (the cell-to-cell move).
    """

    def __init__(
        self,
        spec: MazeHardware,
        robot: int,
        world: World,
        ranging: np.random.Generator,
        motion_rng: np.random.Generator,
        motion: Motion,
    ) -> None:
        self.spec = spec
        self._robot = robot
        self._world = world
        self._ranging = ranging
        self._motion_rng = motion_rng
        self._motion = motion
        self._marks = list(spec.landmark_robots)

    def landmark_ranges(self) -> np.ndarray:
        """One camera scan: range to each landmark robot in mm, ``nan`` where none was found
        (a landmark lifted off the table is never found)."""
        world, marks = self._world, self._marks
        ranges = self.spec.range_sensor.read(
            world.positions_mm[self._robot], world.positions_mm[marks], self._ranging
        )
        ranges[~world.present[marks]] = np.nan
        return ranges

    def walls(self) -> tuple[bool, bool, bool, bool]:
        """One wall reading of the robot's true cell, (W, N, E, S), True = "wall".

        Raises
        ------
        MazeError
            If the robot is not standing in the maze.
        """
        walls = self.spec.maze.walls_of(self.cell())
        return self.spec.wall_sensor.read(walls, self._ranging)

    def drive(self, direction: str, heading_rad: float, done: Callable[[bool], None]) -> bool:
        """Start a move from the robot's cell one cell towards ``direction`` at compass
        ``heading_rad``; ``done(moved)`` is called when it ends. A wall in the way, or a slip
        (``slip_prob``), keeps the robot in its cell.

        Returns
        -------
        bool
            Whether a move started (a stopped robot does not move).

        Raises
        ------
        MazeError
            If the robot is not standing in the maze.
        """
        if not self._world.running[self._robot]:
            return False
        maze = self.spec.maze
        cell = self.cell()
        slipped = bool(self._motion_rng.random() < self.spec.slip_prob)
        # A wall in the way or a slip: the robot turns, bumps and stays in its cell.
        target = cell if slipped else maze.neighbour(cell, direction)
        self._motion.move_to(
            self._robot, heading_rad, maze.centre_mm(target), done, drive_mm=maze.cell_mm
        )
        return True

    def cell(self) -> int:
        """The cell the robot truly stands in: the one whose walls the sensor faces.

        Raises
        ------
        MazeError
            If the robot is not standing in the maze.
        """
        x, y = self._world.positions_mm[self._robot]
        cell = self.spec.maze.cell_at(x, y)
        if cell is None:
            raise MazeError(f"robot {self._robot} at ({x:.1f}, {y:.1f}) mm is outside the maze")
        return cell


def fit_maze_hardware(
    spec: MazeHardware, robots: Sequence[int] | None = None
) -> dict[str, Callable[[Simulation, int], MazeBody | None]]:
    """The ``hardware`` argument of a :class:`~kilonet.simulation.Simulation` whose robots
    ``robots`` (default: all) carry ``spec``: each gets its own :class:`MazeBody`."""
    carriers = None if robots is None else set(robots)

    def fit(sim: Simulation, robot: int) -> MazeBody | None:
        if carriers is not None and robot not in carriers:
            return None
        return MazeBody(
            spec, robot, sim.world, sim.stream("ranging"), sim.stream("motion"), sim.motion
        )

    return {"maze": fit}
