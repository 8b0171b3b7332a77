"""A maze world and the hardware a maze robot carries: landmark camera, wall sensor, cell drive.

The world is a grid of square cells, ``cols`` wide and ``rows`` high, each ``cell_mm`` on a side,
with walls on some cell sides (the outer boundary is always walled). The maze lies on the table
with its south-west corner at the origin; cells are numbered in reading order from the
north-west corner, as the seed's grid printout shows them::

    +---+---+---+
    | 0   1 | 2 |        cell = row * cols + col, row 0 the northmost
    +   +---+   +        cell centre = ((col + ½) cell_mm, (rows − row − ½) cell_mm)
    | 3   4   5 |
    +---+---+---+

Wall directions are always listed in the seed's order **W, N, E, S** (:data:`DIRECTIONS`).

Hardware models (pure functions of the true state they are given, returning noisy readings):

* :class:`RangeSensor` — the seed's camera, ranging to coloured landmark cylinders: true
  distance + ``N(0, sigma_mm)``, nothing beyond ``range_mm``, and each reading independently
  lost with ``dropout_prob`` (a cylinder the camera failed to find).
* :class:`WallSensor` — the seed's lidar, one reading per side: a wall is reported with
  ``p(z=1 | s=1) = p_wall`` when there is one, and no wall with ``p(z=0 | s=0) = p_open``
  (0.7 in the seed) when there is none; the four sides err independently.
* :class:`MazeKilobot` — a :class:`~kilonet.robot.Kilobot` with that hardware and a drive that
  moves it from one cell centre to the neighbouring one. It is the robot side only: its
  ``"maze"`` part, which holds the world's ground truth, the run's streams and the motion
  service, is :class:`kilonet.scenarios.maze_hardware.MazeBody`, fitted by whoever builds the run.

Why moves are discrete, cell centre to cell centre: the seed's robot moves cell to cell under
its own wall-following controller, and the filter it runs reasons over cells. The kernel's
motion model (:mod:`kilonet.motion`) knows nothing of walls, so an open-loop Kilobot driven by
timed motor pulses, with its per-robot speed and turn-rate error, would drift through walls
that the simulator cannot stop it at. A drive that turns to the commanded compass heading and
then covers one cell keeps the world exact in the state space the robot reasons about, while
its simulated duration is the Kilobot's: the turn takes ``angle / turn rate`` and the straight
``cell_mm / speed`` at *this robot's* ``motion.speed_mm_s`` and ``motion.turn_deg_s`` (with
their per-robot errors and the battery's slow-down), and the motors drain the battery as they
would. A wall in the commanded direction stops the robot in its cell (it bumps and stays), as
does another robot's body on the way (robots never overlap), and a commanded move fails with
``slip_prob`` (the motors stall). Poses go into the trace at the
start of every move, after the turn and at its end.

Randomness: range and wall readings draw from the run's ``ranging`` stream, slips from its
``motion`` stream (see :mod:`kilonet.simulation`); maze generators take a Generator.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from kilonet.robot import Kilobot

if TYPE_CHECKING:
    import networkx as nx

__all__ = [
    "DIRECTIONS",
    "HEADING_RAD",
    "Maze",
    "MazeError",
    "MazeKilobot",
    "RangeSensor",
    "WallSensor",
    "corner_landmarks",
    "generate_maze",
    "parse_size",
]

#: Wall and move directions in the seed's order.
DIRECTIONS = ("W", "N", "E", "S")
#: (row, col) step of a move in each direction (rows count southward).
_STEP = {"W": (0, -1), "N": (-1, 0), "E": (0, 1), "S": (1, 0)}
#: Compass heading on the table (0 = +x, east; counter-clockwise), per direction.
HEADING_RAD = {"W": math.pi, "N": math.pi / 2, "E": 0.0, "S": 3 * math.pi / 2}
_OPPOSITE = {0: 2, 1: 3, 2: 0, 3: 1}


class MazeError(ValueError):
    """A maze description is inconsistent or a cell/direction does not exist."""


def parse_size(text: str) -> tuple[int, int]:
    """``"WIDTHxHEIGHT"`` in cells → ``(cols, rows)``.

    Raises
    ------
    MazeError
        If the text is not two positive integers joined by ``x``.

    Examples
    --------
    >>> parse_size("4x3")
    (4, 3)
    >>> parse_size(" 5X5 ")
    (5, 5)
    """
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", str(text))
    if not match or int(match[1]) < 1 or int(match[2]) < 1:
        raise MazeError(f"maze size {text!r} is not WIDTHxHEIGHT in cells (e.g. 4x4)")
    return int(match[1]), int(match[2])


@dataclass(frozen=True, eq=False)
class Maze:
    """A grid maze: which sides of which cells are walled.

    Parameters
    ----------
    cols, rows : int
        Width and height in cells.
    walls : (rows * cols, 4) bool array
        ``walls[cell, k]`` is True when side ``DIRECTIONS[k]`` (W, N, E, S) of ``cell`` is
        walled. Neighbouring cells must agree on their shared side; the boundary is walled.
    cell_mm : float
        Side of one square cell, mm.

    Raises
    ------
    MazeError
        If the shape is wrong, the boundary is open, or two cells disagree on a shared wall.

    Examples
    --------
    >>> maze = Maze.from_text('''
    ... +---+---+
    ... |       |
    ... +---+   +
    ... |       |
    ... +---+---+
    ... ''')
    >>> maze.n_cells, maze.walls_of(0), maze.neighbour(1, "S")
    (4, (True, True, False, True), 3)
    >>> maze.cell_at(150.0, 50.0), maze.centre_mm(3).tolist()
    (3, [150.0, 50.0])
    """

    cols: int
    rows: int
    walls: np.ndarray
    cell_mm: float = 100.0
    _neighbours: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        walls = np.array(self.walls, dtype=bool)
        if self.cols < 1 or self.rows < 1:
            raise MazeError(f"a maze needs at least one cell, got {self.cols}x{self.rows}")
        if walls.shape != (self.cols * self.rows, 4):
            raise MazeError(
                f"walls must have shape ({self.cols * self.rows}, 4) for a "
                f"{self.cols}x{self.rows} maze, got {walls.shape}"
            )
        if not self.cell_mm > 0:
            raise MazeError(f"cell_mm must be positive, got {self.cell_mm}")
        neighbours = np.empty((self.n_cells, 4), dtype=np.intp)
        for cell in range(self.n_cells):
            row, col = divmod(cell, self.cols)
            for k, d in enumerate(DIRECTIONS):
                r, c = row + _STEP[d][0], col + _STEP[d][1]
                inside = 0 <= r < self.rows and 0 <= c < self.cols
                if not inside:
                    if not walls[cell, k]:
                        raise MazeError(f"cell {cell} is open to the {d} at the maze boundary")
                    neighbours[cell, k] = cell
                    continue
                other = r * self.cols + c
                if walls[cell, k] != walls[other, _OPPOSITE[k]]:
                    raise MazeError(f"cells {cell} and {other} disagree on their shared wall")
                neighbours[cell, k] = cell if walls[cell, k] else other
        walls.setflags(write=False)
        neighbours.setflags(write=False)
        object.__setattr__(self, "walls", walls)
        object.__setattr__(self, "_neighbours", neighbours)

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_text(cls, text: str, *, cell_mm: float = 100.0) -> Maze:
        """A maze from its drawing (the format of :meth:`render`).

        Corners are ``+``, horizontal walls ``---`` and vertical walls ``|``; a gap of spaces is
        an opening. Cell contents are ignored.

        Raises
        ------
        MazeError
            If the drawing is not a grid of ``+``-cornered cells four characters wide.
        """
        lines = [line.rstrip() for line in text.strip("\n").splitlines()]
        if len(lines) < 3 or len(lines) % 2 == 0 or (len(lines[0]) - 1) % 4:
            raise MazeError("a maze drawing needs 2·rows+1 lines of 4·cols+1 characters")
        rows, cols = (len(lines) - 1) // 2, (len(lines[0]) - 1) // 4
        lines = [line.ljust(4 * cols + 1) for line in lines]
        walls = np.zeros((rows * cols, 4), dtype=bool)
        for row in range(rows):
            top, mid, bottom = lines[2 * row], lines[2 * row + 1], lines[2 * row + 2]
            for col in range(cols):
                x = 4 * col
                walls[row * cols + col] = (
                    mid[x] == "|",
                    top[x + 1 : x + 4].strip() != "",
                    mid[x + 4] == "|",
                    bottom[x + 1 : x + 4].strip() != "",
                )
        return cls(cols, rows, walls, cell_mm)

    # -- geometry -----------------------------------------------------------------------------
    @property
    def n_cells(self) -> int:
        """Number of cells."""
        return self.cols * self.rows

    @property
    def size_mm(self) -> tuple[float, float]:
        """Width and height of the maze, mm."""
        return self.cols * self.cell_mm, self.rows * self.cell_mm

    def centre_mm(self, cell: int) -> np.ndarray:
        """Centre of ``cell`` on the table, mm."""
        row, col = divmod(self._check(cell), self.cols)
        return np.array([(col + 0.5) * self.cell_mm, (self.rows - row - 0.5) * self.cell_mm])

    def cell_at(self, x_mm: float, y_mm: float) -> int | None:
        """The cell containing the point, or ``None`` outside the maze (edges: the cell to the
        north-east of a corner point, except on the maze's own east and north edges)."""
        col = math.floor(x_mm / self.cell_mm)
        row = self.rows - 1 - math.floor(y_mm / self.cell_mm)
        width, height = self.size_mm
        if x_mm == width:
            col = self.cols - 1
        if y_mm == height:
            row = 0
        if not (0 <= col < self.cols and 0 <= row < self.rows):
            return None
        return row * self.cols + col

    def nearest_cell(self, x_mm: float, y_mm: float) -> int:
        """The cell containing the point, or the one nearest to it if it lies outside."""
        width, height = self.size_mm
        cell = self.cell_at(min(max(x_mm, 0.0), width), min(max(y_mm, 0.0), height))
        assert cell is not None
        return cell

    # -- walls and moves ----------------------------------------------------------------------
    def walls_of(self, cell: int) -> tuple[bool, bool, bool, bool]:
        """Walls of ``cell`` as (W, N, E, S), True = wall."""
        return tuple(bool(w) for w in self.walls[self._check(cell)])

    def is_open(self, cell: int, direction: str) -> bool:
        """Whether a robot in ``cell`` can move ``direction`` (W, N, E or S)."""
        return not self.walls[self._check(cell), _index(direction)]

    def open_directions(self, cell: int) -> list[str]:
        """Directions out of ``cell`` without a wall, in W, N, E, S order."""
        return [d for d in DIRECTIONS if self.is_open(cell, d)]

    def neighbour(self, cell: int, direction: str) -> int:
        """Where a move ``direction`` from ``cell`` ends: the next cell, or ``cell`` at a wall."""
        return int(self._neighbours[self._check(cell), _index(direction)])

    @property
    def neighbours(self) -> np.ndarray:
        """``(n_cells, 4)`` table of :meth:`neighbour` for every cell and direction (W, N, E, S),
        read-only."""
        return self._neighbours

    def direction_to(self, cell: int, other: int) -> str:
        """The direction of the open move from ``cell`` to the adjacent ``other``.

        Raises
        ------
        MazeError
            If ``other`` is not reachable from ``cell`` in one move.
        """
        for k, d in enumerate(DIRECTIONS):
            if self._neighbours[cell, k] == other != cell:
                return d
        raise MazeError(f"cell {other} is not one open move from cell {cell}")

    def graph(self) -> nx.Graph:
        """The maze as a graph: one node per cell (attribute ``pos``: centre in mm), one edge per
        opening between neighbouring cells."""
        import networkx as nx

        g = nx.Graph()
        for cell in range(self.n_cells):
            g.add_node(cell, pos=tuple(self.centre_mm(cell).tolist()))
        for cell in range(self.n_cells):
            for k in (2, 3):  # E and S: each opening once
                other = int(self._neighbours[cell, k])
                if other != cell:
                    g.add_edge(cell, other)
        return g

    # -- drawing ------------------------------------------------------------------------------
    def render(self, marks: dict[int, str] | set[int] | None = None, mark: str = "X") -> str:
        """Text drawing of the maze; ``marks`` puts a character in cells (a set: ``mark``).

        Examples
        --------
        >>> print(Maze.from_text('''
        ... +---+---+
        ... |       |
        ... +---+---+
        ... ''').render({1}))
        +---+---+
        |     X |
        +---+---+
        """
        if marks is None:
            marks = {}
        elif not isinstance(marks, dict):
            marks = dict.fromkeys(marks, mark)
        out = []
        for row in range(self.rows):
            top, mid = "+", "|"
            for col in range(self.cols):
                cell = row * self.cols + col
                _w, n, e, _s = self.walls[cell]
                top += ("---" if n else "   ") + "+"
                mid += f" {str(marks.get(cell, ' '))[:1]} " + ("|" if e else " ")
            out += [top, mid]
        bottom = "+"
        for col in range(self.cols):
            bottom += ("---" if self.walls[(self.rows - 1) * self.cols + col, 3] else "   ") + "+"
        out.append(bottom)
        return "\n".join(out)

    def _check(self, cell: int) -> int:
        if not 0 <= cell < self.n_cells:
            raise MazeError(f"cell {cell} is not in the {self.cols}x{self.rows} maze")
        return int(cell)


def _index(direction: str) -> int:
    try:
        return DIRECTIONS.index(direction)
    except ValueError:
        raise MazeError(f"direction {direction!r} is not one of W, N, E, S") from None


def generate_maze(
    cols: int,
    rows: int,
    rng: np.random.Generator,
    *,
    cell_mm: float = 100.0,
    loops: float = 0.0,
) -> Maze:
    """A random maze: a perfect maze (randomised depth-first search), then a share of the
    remaining inner walls removed to make loops.

    Parameters
    ----------
    cols, rows : int
        Size in cells.
    rng : numpy.random.Generator
        The run's generator (its placement stream in the ``maze`` scenario).
    cell_mm : float
        Cell side, mm.
    loops : float
        Share (0–1) of the inner walls left by the perfect maze that are removed; 0 gives a
        perfect maze (exactly one path between any two cells), 1 an open grid.

    Returns
    -------
    Maze
        Every cell is reachable from every other.

    Raises
    ------
    MazeError
        If the size is not positive or ``loops`` is outside [0, 1].

    Notes
    -----
    O(cells). The recursive backtracker makes long corridors and few junctions — the hard case
    for a robot that localizes from walls.

    Examples
    --------
    >>> import networkx as nx
    >>> maze = generate_maze(4, 4, np.random.default_rng(0))
    >>> g = maze.graph()
    >>> g.number_of_edges(), nx.is_connected(g)
    (15, True)
    >>> generate_maze(4, 4, np.random.default_rng(0), loops=1.0).graph().number_of_edges()
    24
    """
    if cols < 1 or rows < 1:
        raise MazeError(f"a maze needs at least one cell, got {cols}x{rows}")
    if not 0.0 <= loops <= 1.0:
        raise MazeError(f"loops must be in [0, 1], got {loops}")
    n = cols * rows
    walls = np.ones((n, 4), dtype=bool)

    def cells_beside(cell: int) -> list[tuple[int, int]]:
        row, col = divmod(cell, cols)
        out = []
        for k, d in enumerate(DIRECTIONS):
            r, c = row + _STEP[d][0], col + _STEP[d][1]
            if 0 <= r < rows and 0 <= c < cols:
                out.append((k, r * cols + c))
        return out

    start = int(rng.integers(n))
    seen = np.zeros(n, dtype=bool)
    seen[start] = True
    stack = [start]
    while stack:
        cell = stack[-1]
        fresh = [(k, other) for k, other in cells_beside(cell) if not seen[other]]
        if not fresh:
            stack.pop()
            continue
        k, other = fresh[int(rng.integers(len(fresh)))]
        walls[cell, k] = walls[other, _OPPOSITE[k]] = False
        seen[other] = True
        stack.append(other)
    if loops > 0:
        inner = [
            (cell, k, other)
            for cell in range(n)
            for k, other in cells_beside(cell)
            if k in (2, 3) and walls[cell, k]
        ]
        remove = rng.random(len(inner)) < loops
        for (cell, k, other), gone in zip(inner, remove, strict=True):
            if gone:
                walls[cell, k] = walls[other, _OPPOSITE[k]] = False
    return Maze(cols, rows, walls, cell_mm)


def corner_landmarks(maze: Maze, offset_mm: float = 0.0) -> np.ndarray:
    """The four landmark positions at the maze corners, mm: SW, SE, NE, NW, each moved
    ``offset_mm`` outward along both axes.

    Examples
    --------
    >>> corner_landmarks(generate_maze(2, 1, np.random.default_rng(0))).tolist()
    [[0.0, 0.0], [200.0, 0.0], [200.0, 100.0], [0.0, 100.0]]
    """
    width, height = maze.size_mm
    o = offset_mm
    return np.array(
        [[0.0 - o, 0.0 - o], [width + o, 0.0 - o], [width + o, height + o], [0.0 - o, height + o]]
    )


@dataclass(frozen=True)
class RangeSensor:
    """The camera that measures the distance to each landmark (the seed's coloured cylinders).

    Parameters
    ----------
    sigma_mm : float
        Standard deviation of the Gaussian range noise, mm.
    range_mm : float
        Farthest landmark the camera finds, mm (centre to centre).
    dropout_prob : float
        Probability that a landmark in range is not found in one scan.
    """

    sigma_mm: float = 5.0
    range_mm: float = 10_000.0
    dropout_prob: float = 0.0

    def read(
        self, position_mm: np.ndarray, landmarks_mm: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        """One scan: the measured range to each landmark, mm, ``nan`` where none was found.

        Ranges are true distance + ``N(0, sigma_mm)``, never negative.

        Examples
        --------
        >>> RangeSensor(sigma_mm=0.0, range_mm=60.0).read(
        ...     np.zeros(2), np.array([[30.0, 40.0], [100.0, 0.0]]), np.random.default_rng(1))
        array([50., nan])
        """
        landmarks = np.asarray(landmarks_mm, dtype=float).reshape(-1, 2)
        true = np.hypot(*(landmarks - np.asarray(position_mm, dtype=float)).T)
        noise = rng.normal(0.0, self.sigma_mm, len(true)) if self.sigma_mm > 0 else 0.0
        lost = rng.random(len(true)) < self.dropout_prob
        ranges = np.maximum(true + noise, 0.0)
        ranges[lost | ~(true <= self.range_mm)] = np.nan
        return ranges


@dataclass(frozen=True)
class WallSensor:
    """The wall sensor on four sides (the seed's lidar), with a per-direction error table.

    Parameters
    ----------
    p_open : float
        ``p(z=0 | s=0)``: a side without a wall reads "no wall" (the seed: 0.7).
    p_wall : float
        ``p(z=1 | s=1)``: a side with a wall reads "wall".
    """

    p_open: float = 0.7
    p_wall: float = 0.95

    def read(self, walls: tuple[bool, ...], rng: np.random.Generator) -> tuple[bool, ...]:
        """One reading per side of a cell whose true walls are ``walls`` (W, N, E, S).

        Examples
        --------
        >>> WallSensor(p_open=1.0, p_wall=1.0).read((True, False, False, True),
        ...                                         np.random.default_rng(0))
        (True, False, False, True)
        """
        truth = np.asarray(walls, dtype=bool)
        u = rng.random(len(truth))
        reading = np.where(truth, u < self.p_wall, u >= self.p_open)
        return tuple(bool(z) for z in reading)


class MazeKilobot(Kilobot):
    """A Kilobot carrying maze hardware: a landmark camera, a wall sensor and a cell drive.

    Programs subclass it and call :meth:`sense_landmark_ranges`, :meth:`sense_walls` and
    :meth:`drive`; like every :class:`Kilobot` they never see the world itself. The hardware is
    the robot's ``"maze"`` part (:meth:`~kilonet.robot.Kilobot.hardware`), which the run that
    builds the maze fits to it (:func:`kilonet.scenarios.maze_hardware.fit_maze_hardware`).
    """

    def __init__(self) -> None:
        self._driving = False

    @property
    def driving(self) -> bool:
        """Whether a move started by :meth:`drive` is still under way."""
        return self._driving

    def sense_landmark_ranges(self) -> np.ndarray:
        """One camera scan: range to each landmark robot in mm, ``nan`` where none was found.

        Landmarks lifted off the table are never found.
        """
        return self.hardware("maze").landmark_ranges()

    def sense_walls(self) -> tuple[bool, bool, bool, bool]:
        """One wall reading of the robot's cell, (W, N, E, S), True = "wall".

        Raises
        ------
        MazeError
            If the robot is not standing in the maze.
        """
        return self.hardware("maze").walls()

    def drive(self, direction: str) -> None:
        """Turn to compass ``direction`` (W, N, E, S) and drive one cell that way.

        The move runs in simulated time (see the module notes); :attr:`driving` is True until it
        ends. A wall in the way, or a slip, leaves the robot in its cell. A stopped robot does
        not move.

        Raises
        ------
        RuntimeError
            If a move is already under way.
        MazeError
            If ``direction`` is not W, N, E or S.
        """
        heading = HEADING_RAD[DIRECTIONS[_index(direction)]]
        if self._driving:
            raise RuntimeError("drive() called while the previous move is still under way")
        if self.hardware("maze").drive(direction, heading, self._arrived):
            self._driving = True

    def _arrived(self, _moved: bool) -> None:
        self._driving = False
