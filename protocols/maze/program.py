"""Maze localization (the lab seed): landmark trilateration, coverage, wall-based Bayes filter.

One robot stands in a grid maze whose map it was flashed with (the seed's program holds the wall
configuration as an array). Four landmarks stand at the maze corners. Each *step* the robot,
standing still at a cell centre:

1. **Ranges the landmarks** — with its camera (``landmarks = "camera"``, the seed), or by
   listening for ``listen_s`` to landmark beacons on the infrared medium (``"infrared"``): each
   beacon is a Kilobot broadcasting its index and coordinates, and the robot uses the median
   distance estimate of each beacon it heard within ``neighbour_max_mm`` (beyond, kilolib's
   estimates saturate: :mod:`kilonet.protocols.ranging_limit`). It says so (event ``few_landmarks``)
   when it has fewer than three ranges.
2. **Trilaterates** — with the seed's linear formula (A…F, :func:`kilonet.protocols.common.geometry.
   trilaterate_linear`) over the first three landmarks it has (the fourth ignored, as the seed
   ignores its yellow cylinder), or with least squares over all it has when it has four
   (:func:`kilonet.protocols.common.geometry.multilaterate`; ``fit = "lsq"``, the default).
3. **Maps (x, y) to a cell** and marks it visited; the event ``step`` carries the grid with
   ``X`` for visited cells, as the seed prints it. Without a fix it keeps the cell it
   dead-reckons from the last cell and command.
4. **Senses the walls** on its four sides and updates its belief over cells with the Bayes
   filter (:func:`bayes_step`): motion model move ``p_move`` (0.8) / stay ``1 − p_move`` (0.2),
   sensor model per side ``p(z=0 | s=0) = p_open`` (0.7 in the seed) and
   ``p(z=1 | s=1) = p_wall`` (0.95 by default: the seed's text gives only the first entry) —
   the table it assumes (:attr:`MazeParams.filter_table`), by default the sensor's true one.
   It logs the probabilities that the last move happened or not (the seed's *move* and *stay*
   probabilities) every step, and the seed's unnormalised products for its likeliest cell.
5. **Plans the next move** — the seed's random walk (``planner = "random"``: a random open
   direction of its cell) or the nearest unvisited cell, breadth-first over the maze graph
   (``planner = "bfs"``) — and drives one cell. It navigates by the trilaterated cell
   (``navigate_by = "landmarks"``) or by its belief's most likely cell (``"belief"``). When its
   own map marks every reachable cell visited it stops (event ``covered``; LED green), or at
   ``max_steps`` (event ``step_limit``; LED red).

Message (kilolib v2, type 40), broadcast by a landmark beacon in infrared mode::

    data[0]     landmark  uint8, index 0–3 (SW, SE, NE, NW corner)
    data[1..2]  x_mm      int16, the beacon's position
    data[3..4]  y_mm      int16

LEDs of the landmarks are the seed's cylinder colours: red, green, blue, yellow (NW, the one the
linear formula ignores when all four are there).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from kilonet.message import Layout, Message
from kilonet.params import ParamError, param
from kilonet.protocols.common.geometry import GeometryError, multilaterate, trilaterate_linear
from kilonet.protocols.common.phases import Stage
from kilonet.protocols.common.ranging_limit import trusted_range
from kilonet.protocols.maze.hardware import (
    DIRECTIONS,
    Maze,
    MazeError,
    MazeKilobot,
    parse_size,
)
from kilonet.robot import Kilobot

if TYPE_CHECKING:  # networkx is imported where used, so that listing scenarios stays fast
    import networkx as nx

__all__ = [
    "LANDMARK",
    "LANDMARK_COLORS",
    "BayesStep",
    "Fix",
    "LandmarkBeacon",
    "MazeParams",
    "MazeRobot",
    "MazeStage",
    "bayes_step",
    "locate",
    "nearest_unvisited",
    "predict",
    "random_walk_direction",
    "wall_likelihood",
]

LANDMARK = Layout("landmark", type=40, fields=[("landmark", "B"), ("x_mm", "h"), ("y_mm", "h")])

#: LED colours of the landmarks SW, SE, NE, NW (the seed's cylinders).
LANDMARK_COLORS = ((3, 0, 0), (0, 3, 0), (0, 0, 3), (3, 3, 0))


# -- trilateration ----------------------------------------------------------------------------
@dataclass(frozen=True)
class Fix:
    """A position estimate: where, how (``"linear"`` or ``"lsq"``) and from how many landmarks."""

    x_mm: float
    y_mm: float
    method: str
    landmarks: int


def locate(
    anchors_mm: np.ndarray, ranges_mm: np.ndarray, fit: Literal["lsq", "linear"] = "lsq"
) -> Fix | None:
    """Position from the landmarks that have a range (``nan``: not found).

    With fewer than three ranges there is no fix (``None``). With exactly three, or with
    ``fit = "linear"``, the seed's linear formula over the first three found
    (:func:`kilonet.protocols.common.geometry.trilaterate_linear`); with four or more and ``fit =
    "lsq"``, the
    least-squares fit over all (:func:`kilonet.protocols.common.geometry.multilaterate`'s estimate,
    taken whatever its verdict: the robot trusts its landmarks).

    Raises
    ------
    GeometryError
        If the landmarks used are collinear (least squares: within multilaterate's default
        1 mm of one line).

    Examples
    --------
    >>> anchors = np.array([[0.0, 0.0], [400.0, 0.0], [400.0, 400.0], [0.0, 400.0]])
    >>> locate(anchors, [141.4213562373095, 316.22776601683796, np.nan, 316.22776601683796])
    Fix(x_mm=100.0, y_mm=100.0, method='linear', landmarks=3)
    >>> fix = locate(anchors, np.hypot(*(anchors - [100.0, 250.0]).T))
    >>> round(fix.x_mm, 6), round(fix.y_mm, 6), fix.method, fix.landmarks
    (100.0, 250.0, 'lsq', 4)
    >>> locate(anchors, [150.0, np.nan, np.nan, 300.0]) is None
    True
    """
    anchors = np.asarray(anchors_mm, dtype=float).reshape(-1, 2)
    ranges = np.asarray(ranges_mm, dtype=float)
    found = np.flatnonzero(~np.isnan(ranges))
    if len(found) < 3:
        return None
    if fit == "linear" or len(found) == 3:
        x, y = trilaterate_linear(anchors[found[:3]], ranges[found[:3]])
        return Fix(round(x, 9), round(y, 9), "linear", 3)
    fit_all = multilaterate(anchors[found], ranges[found])
    if fit_all.reason == "collinear_anchors":
        raise GeometryError("the anchors are collinear: no unique position")
    return Fix(fit_all.x_mm, fit_all.y_mm, "lsq", len(found))


# -- the Bayes filter over cells --------------------------------------------------------------
def wall_likelihood(
    walls: np.ndarray, reading: tuple[bool, ...], p_open: float, p_wall: float
) -> np.ndarray:
    """``p(z | s)`` of one four-side reading for every cell: the product over W, N, E, S of
    ``p_wall`` / ``1 − p_wall`` (a wall there) or ``p_open`` / ``1 − p_open`` (none).

    Parameters
    ----------
    walls : (N, 4) bool array
        The map's walls per cell (W, N, E, S).
    reading : 4 bools
        The sensor's reading, True = "wall".
    p_open, p_wall : float
        ``p(z=0 | s=0)`` and ``p(z=1 | s=1)``.

    Examples
    --------
    >>> walls = np.array([[True, True, False, True]])
    >>> float(wall_likelihood(walls, (True, True, True, True), 0.7, 0.9)[0])  # 0.9·0.9·0.3·0.9
    0.2187
    """
    z = np.asarray(reading, dtype=bool)
    p = np.where(walls, np.where(z, p_wall, 1 - p_wall), np.where(z, 1 - p_open, p_open))
    return np.round(p.prod(axis=1), 15)


def _branches(
    belief: np.ndarray, neighbours: np.ndarray, direction: str, p_move: float
) -> tuple[np.ndarray, np.ndarray]:
    """The motion model's two branches: mass that moved one cell ``direction``, mass that stayed."""
    k = DIRECTIONS.index(direction)
    target = neighbours[:, k]
    can = target != np.arange(len(belief))
    moved = np.zeros_like(belief)
    np.add.at(moved, target[can], p_move * belief[can])
    return moved, belief * np.where(can, 1 - p_move, 1.0)


def predict(
    belief: np.ndarray, neighbours: np.ndarray, direction: str, p_move: float
) -> np.ndarray:
    """Belief after commanding one move ``direction``: from each cell the robot reaches the next
    cell with ``p_move`` and stays with ``1 − p_move``; a wall that way keeps it in place.

    Parameters
    ----------
    belief : (N,) array
        Probability of each cell before the move.
    neighbours : (N, 4) int array
        Where a move W, N, E, S from each cell ends
        (:attr:`kilonet.protocols.maze.hardware.Maze.neighbours`).
    direction : str
        The commanded move.
    p_move : float
        Probability that a move with no wall in the way happens.

    Examples
    --------
    Three cells in a row, walls only at the ends; move east from certainly cell 0:

    >>> neighbours = np.array([[0, 0, 1, 0], [0, 1, 2, 1], [1, 2, 2, 2]])
    >>> predict(np.array([1.0, 0.0, 0.0]), neighbours, "E", 0.8).round(3).tolist()
    [0.2, 0.8, 0.0]
    """
    moved, stayed = _branches(belief, neighbours, direction, p_move)
    return moved + stayed


@dataclass(frozen=True)
class BayesStep:
    """One filter step: the posterior over cells, the posterior probabilities that the
    commanded move happened (``p_moved``) or the robot stayed (``p_stayed``), and the reading's
    likelihood ``p(z | s)`` per cell."""

    belief: np.ndarray
    p_moved: float
    p_stayed: float
    likelihood: np.ndarray


def bayes_step(
    belief: np.ndarray,
    maze: Maze,
    direction: str | None,
    reading: tuple[bool, ...],
    *,
    p_move: float = 0.8,
    p_open: float = 0.7,
    p_wall: float = 0.95,
) -> BayesStep:
    """Prediction for the commanded ``direction`` (``None``: no move yet), then correction by
    the wall ``reading``.

    The posterior splits into the two branches of the motion model, as the seed computes them:
    *move* — ``p_move · p(z | walls of the next cell)`` — and *stay* —
    ``(1 − p_move) · p(z | walls of the current cell)`` (a wall in the way: stay with 1).

    Raises
    ------
    ValueError
        If the reading has probability zero under the model from every cell (possible only
        with a sensor table containing 0 or 1).

    Examples
    --------
    >>> maze = Maze.from_text('''
    ... +---+---+
    ... |       |
    ... +---+---+
    ... ''')
    >>> step = bayes_step(np.array([0.5, 0.5]), maze, "E", (False, True, True, True), p_wall=0.9)
    >>> step.belief.round(4).tolist(), round(step.p_moved, 4)
    ([0.0053, 0.9947], 0.4421)
    """
    likelihood = wall_likelihood(maze.walls, reading, p_open, p_wall)
    if direction is None:
        moved, stayed = np.zeros_like(belief), belief
    else:
        moved, stayed = _branches(belief, maze.neighbours, direction, p_move)
    moved, stayed = moved * likelihood, stayed * likelihood
    total = float(moved.sum() + stayed.sum())
    if total <= 0:
        raise ValueError(f"wall reading {reading} is impossible from every cell under the model")
    return BayesStep(
        (moved + stayed) / total,
        float(moved.sum() / total),
        float(stayed.sum() / total),
        likelihood,
    )


# -- exploration --------------------------------------------------------------------------------
def nearest_unvisited(graph: nx.Graph, start: int, visited: set[int]) -> list[int] | None:
    """Shortest path (breadth-first) from ``start`` to the nearest cell not in ``visited``;
    ties go to the lowest cell index. ``None`` when every reachable cell is visited.

    Examples
    --------
    >>> import networkx as nx
    >>> nearest_unvisited(nx.path_graph(4), 1, {0, 1})
    [1, 2]
    >>> nearest_unvisited(nx.path_graph(3), 0, {0, 1, 2}) is None
    True
    """
    import networkx as nx

    paths = nx.single_source_shortest_path(graph, start)
    todo = [(len(path), cell) for cell, path in paths.items() if cell not in visited]
    if not todo:
        return None
    return paths[min(todo)[1]]


def random_walk_direction(maze: Maze, cell: int, rng: np.random.Generator) -> str | None:
    """The seed's random walk: a uniformly random open direction out of ``cell`` (``None`` in
    a closed cell)."""
    options = maze.open_directions(cell)
    return options[int(rng.integers(len(options)))] if options else None


# -- the programs ---------------------------------------------------------------------------
@dataclass(frozen=True)
class MazeParams:
    """Parameters of the maze scenario (section ``maze``): the world the scenario builds (maze,
    landmarks, the robot's true sensors and drive) and the program's own settings, which
    :class:`MazeRobot` takes directly.

    The wall sensor's true error table (``wall_p_open``, ``wall_p_wall``) and the table the
    Bayes filter assumes (``filter_p_open``, ``filter_p_wall``) are separate, so a mismatch
    between model and sensor can be studied; the filter's default (``none``) is the true table.
    """

    section_name = "maze"
    size: str = param("4x4", doc="maze size WIDTHxHEIGHT in cells")
    cell_mm: float = param(100.0, lo=1.0, hi=10_000.0, doc="side of a square cell")
    loops: float = param(0.0, lo=0.0, hi=1.0, doc="share of inner walls removed (0: perfect)")
    planner: Literal["bfs", "random"] = param(
        "bfs", doc="nearest unvisited cell (breadth-first), or the seed's random walk"
    )
    navigate_by: Literal["landmarks", "belief"] = param(
        "landmarks", doc="plan with the trilaterated cell, or the belief's most likely cell"
    )
    landmarks: Literal["camera", "infrared"] = param(
        "camera", doc="range landmarks by camera model, or by hearing Kilobot beacons"
    )
    neighbour_max_mm: float = param(
        90.0,
        lo=33.0,
        hi=255.0,
        doc="infrared: a beacon heard at a larger estimate is not ranged (kilolib's tables "
        "end at 98 mm; near their end a strong emitter reads up to 10 mm near)",
    )
    fit: Literal["lsq", "linear"] = param(
        "lsq", doc="least squares over four landmarks, or always the seed's linear formula"
    )
    landmark_offset_mm: float = param(
        0.0, lo=0.0, hi=1000.0, doc="landmarks stand this far outside the corners (each axis)"
    )
    sigma_mm: float = param(5.0, lo=0.0, hi=1000.0, doc="camera range noise (sd)")
    camera_range_mm: float = param(10_000.0, lo=1.0, hi=1e6, doc="farthest landmark found")
    dropout_prob: float = param(0.05, lo=0.0, hi=1.0, doc="camera misses a landmark")
    wall_p_open: float = param(0.7, lo=0.0, hi=1.0, doc="true wall sensor: p(z=0 | s=0)")
    wall_p_wall: float = param(0.95, lo=0.0, hi=1.0, doc="true wall sensor: p(z=1 | s=1)")
    filter_p_open: float | None = param(
        None, lo=0.0, hi=1.0, doc="p(z=0 | s=0) the filter assumes (none: wall_p_open)"
    )
    filter_p_wall: float | None = param(
        None, lo=0.0, hi=1.0, doc="p(z=1 | s=1) the filter assumes (none: wall_p_wall)"
    )
    p_move: float = param(0.8, lo=0.0, hi=1.0, doc="filter's motion model: p(move)")
    mark_belief: float = param(
        0.5, lo=0.0, hi=1.0, doc="navigating by belief: least belief to mark a cell visited"
    )
    slip_prob: float = param(0.0, lo=0.0, hi=1.0, doc="drive: share of moves that stay put")
    listen_s: float = param(1.0, lo=0.0, hi=600.0, doc="standing time in a cell before sensing")
    max_steps: int = param(1000, lo=1, hi=1_000_000, doc="the robot gives up after this many")
    burn_in_steps: int = param(5, lo=0, hi=1_000_000, doc="steps left out of belief accuracy")

    def __post_init__(self) -> None:
        try:
            cols, rows = parse_size(self.size)
        except MazeError as exc:
            raise ParamError(f"maze.size: {exc}") from None
        if cols * rows > 10_000:
            raise ParamError(f"maze.size = {self.size!r}: at most 10000 cells")

    @property
    def filter_table(self) -> tuple[float, float]:
        """``(p(z=0 | s=0), p(z=1 | s=1))`` the filter assumes: its own, else the true one.

        Examples
        --------
        >>> MazeParams(wall_p_open=0.6).filter_table
        (0.6, 0.95)
        >>> MazeParams(wall_p_open=0.6, filter_p_open=0.7).filter_table
        (0.7, 0.95)
        """
        p_open = self.wall_p_open if self.filter_p_open is None else self.filter_p_open
        p_wall = self.wall_p_wall if self.filter_p_wall is None else self.filter_p_wall
        return p_open, p_wall


class MazeStage(Stage):
    """Where the maze robot is in its cycle (:class:`kilonet.protocols.common.phases.Stage`):
    listening in a cell (it senses and plans once ``listen_s`` has passed), moving to the next one,
    or done (maze covered or step limit reached)."""

    LISTEN = "listen"
    MOVING = "moving"
    DONE = "done"


class MazeRobot(MazeKilobot):
    """The maze robot: each step ranges, trilaterates, marks, filters, plans and drives.

    After the run, ``belief_history`` holds the belief over cells after every step (row ``k``:
    step ``k``; step 0 is the first sensing, before any move), and ``visited`` its own marks.

    Parameters
    ----------
    params : MazeParams
        Its settings (the scenario's section).
    maze : Maze
        Its map of the maze.
    landmarks_mm : (4, 2) array
        Landmark coordinates it knows (camera mode); in infrared mode it learns them from the
        beacons' messages instead.
    """

    LED_KEY = (
        ((0, 0, 1), "listening"),
        ((0, 1, 1), "moving"),
        ((0, 3, 0), "maze covered"),
        ((3, 0, 0), "step limit reached"),
    )

    def __init__(self, params: MazeParams, maze: Maze, landmarks_mm: np.ndarray) -> None:
        super().__init__()
        self.params = params
        self.map = maze
        self.landmarks_mm = np.asarray(landmarks_mm, dtype=float)

    def setup(self) -> None:
        self.graph = self.map.graph()
        self.belief = np.full(self.map.n_cells, 1.0 / self.map.n_cells)
        self.belief_history: list[np.ndarray] = []
        self.visited: set[int] = set()
        self.step = 0
        self.state = MazeStage.LISTEN
        self.cell: int | None = None
        self._command: str | None = None
        self._arrived_tick = self.kilo_ticks
        self._heard: dict[int, tuple[float, float, list[int]]] = {}
        self.set_color(0, 0, 1)

    def loop(self) -> None:
        if self.state is MazeStage.MOVING and not self.driving:
            self.state = MazeStage.LISTEN
            self._arrived_tick = self.kilo_ticks
            self._heard = {}  # estimates taken while moving do not describe this cell
            self.set_color(0, 0, 1)
        elif self.state is MazeStage.LISTEN and (
            self.kilo_ticks - self._arrived_tick >= self.params.listen_s * self.ticks_per_s
        ):
            self._sense_and_move()

    def message_rx(self, message: Message, distance_mm: int) -> None:
        if self.params.landmarks != "infrared" or self.state is not MazeStage.LISTEN:
            return
        if LANDMARK.matches(message) and trusted_range(distance_mm, self.params.neighbour_max_mm):
            beacon = LANDMARK.unpack(message)
            self._heard.setdefault(beacon.landmark, (beacon.x_mm, beacon.y_mm, []))[2].append(
                distance_mm
            )

    # -- one step ---------------------------------------------------------------------------
    def _ranges(self) -> tuple[np.ndarray, np.ndarray]:
        if self.params.landmarks == "camera":
            return self.landmarks_mm, self.sense_landmark_ranges()
        ids = sorted(self._heard)
        anchors = np.array([self._heard[i][:2] for i in ids], dtype=float).reshape(-1, 2)
        ranges = np.array([float(np.median(self._heard[i][2])) for i in ids])
        return anchors, ranges

    def _sense_and_move(self) -> None:
        prog = self.params
        p_open, p_wall = prog.filter_table
        anchors, ranges = self._ranges()
        heard = int((~np.isnan(ranges)).sum())
        fix = None
        if heard < 3:
            self.log("few_landmarks", step=self.step, heard=heard)
        else:
            try:
                fix = locate(anchors, ranges, prog.fit)
            except GeometryError as exc:
                self.log("no_fix", step=self.step, reason=str(exc))
        reading = self.sense_walls()
        try:
            update = bayes_step(
                self.belief,
                self.map,
                self._command,
                reading,
                p_move=prog.p_move,
                p_open=p_open,
                p_wall=p_wall,
            )
        except ValueError:
            # The model rules out every cell: start over from a uniform prior (kidnapped robot).
            self.log("belief_reset", step=self.step)
            uniform = np.full(self.map.n_cells, 1.0 / self.map.n_cells)
            update = bayes_step(uniform, self.map, None, reading, p_open=p_open, p_wall=p_wall)
        seed_move, seed_stay = self._seed_products(update.likelihood)
        self.belief = update.belief
        self.belief_history.append(self.belief)
        best = int(np.argmax(self.belief))
        self.cell = self._where(fix, best)
        if prog.navigate_by == "landmarks" or self.belief[best] >= prog.mark_belief:
            self.visited.add(self.cell)
        self.log(
            "step",
            step=self.step,
            command=self._command,
            heard=heard,
            x_mm=None if fix is None else round(fix.x_mm, 2),
            y_mm=None if fix is None else round(fix.y_mm, 2),
            method=None if fix is None else fix.method,
            cell=self.cell,
            visited=len(self.visited),
            walls="".join(d for d, z in zip(DIRECTIONS, reading, strict=True) if z),
            belief_cell=best,
            belief_max=round(float(self.belief[best]), 6),
            p_moved=round(update.p_moved, 6),
            p_stayed=round(update.p_stayed, 6),
            seed_move=seed_move,
            seed_stay=seed_stay,
            grid=self.map.render(self.visited),
        )
        self._plan_and_drive()

    def _seed_products(self, likelihood: np.ndarray) -> tuple[float | None, float | None]:
        """The seed's printed numbers for the cell the robot believed it was in before the move:
        move = p_move · p(z | walls of the next cell), stay = (1 − p_move) · p(z | walls of
        that cell)."""
        if self._command is None:
            return None, None
        here = int(np.argmax(self.belief))
        there = self.map.neighbour(here, self._command)
        p_move = self.params.p_move if there != here else 0.0
        return round(p_move * float(likelihood[there]), 6), round(
            (1 - p_move) * float(likelihood[here]), 6
        )

    def _where(self, fix: Fix | None, best: int) -> int:
        """The cell the robot navigates by."""
        if self.params.navigate_by == "belief":
            return best
        if fix is not None:
            return self.map.nearest_cell(fix.x_mm, fix.y_mm)
        if self.cell is not None and self._command is not None:
            return self.map.neighbour(self.cell, self._command)  # dead reckoning
        return best

    def _plan_and_drive(self) -> None:
        prog = self.params
        import networkx as nx

        reachable = nx.node_connected_component(self.graph, self.cell)
        if reachable <= self.visited:
            self.log("covered", step=self.step, visited=len(self.visited))
            self.state = MazeStage.DONE
            self.set_color(0, 3, 0)
            return
        if self.step >= prog.max_steps:
            self.log("step_limit", step=self.step, visited=len(self.visited))
            self.state = MazeStage.DONE
            self.set_color(3, 0, 0)
            return
        # The current cell counts as visited for planning: if it is not marked yet (an unsure
        # belief), staying put would teach the robot nothing new.
        path = nearest_unvisited(self.graph, self.cell, self.visited | {self.cell})
        if prog.planner == "bfs" and path is not None:
            direction = self.map.direction_to(path[0], path[1])
        else:
            direction = random_walk_direction(self.map, self.cell, self.rand)
        self.drive(direction)
        self._command = direction
        self.step += 1
        self.state = MazeStage.MOVING
        self.set_color(0, 1, 1)


class LandmarkBeacon(Kilobot):
    """A landmark at a maze corner: a coloured cylinder for the camera, and in infrared mode a
    Kilobot broadcasting its index and coordinates.

    Parameters
    ----------
    landmark : int
        Its index 0–3 (SW, SE, NE, NW); sets its colour.
    position_mm : (x, y)
        The coordinates it was flashed with, mm.
    broadcast : bool
        Whether it transmits (infrared mode).
    """

    LED_KEY = tuple(
        (c, f"landmark {name}")
        for c, name in zip(LANDMARK_COLORS, ("SW", "SE", "NE", "NW"), strict=True)
    )

    def __init__(self, landmark: int, position_mm: tuple[float, float], broadcast: bool) -> None:
        self.landmark = landmark
        self.position_mm = position_mm
        self.broadcast = broadcast

    def setup(self) -> None:
        self.set_color(*LANDMARK_COLORS[self.landmark % len(LANDMARK_COLORS)])
        x, y = self.position_mm
        self._message = LANDMARK.pack(landmark=self.landmark, x_mm=round(x), y_mm=round(y))

    def message_tx(self) -> Message | None:
        return self._message if self.broadcast else None
