"""``self-assembly``: robots move one after another from a packed start into a shape
(Rubenstein, Cornejo and Nagpal, Science 345:795, 2014; ``docs/self_assembly.md``).

Four seed robots mark the origin of the shape's frame: rows 0-3 of the placement, the first at
(0, 0) with gradient 0, the others with gradient 1; the seeds know their positions, every other
robot learns its own through the medium. The shape is a bitmap that every robot holds
(``self_assembly.shape``: a shipped shape's name, see :func:`shipped_shapes`, or a ``.txt``
bitmap or a ``.png`` image), each cell ``self_assembly.cell_mm`` wide, placed so that its
bottom-left corner lies :data:`SEED_MARGIN_MM` left of and below the seed at the origin; it
must contain all four seeds.
The generated placement packs the other robots on a hex lattice to the left of and below the
seeds.

Summary figures against ground truth: ``joined_fraction`` (robots that joined the shape, of
those that could move), ``iou`` (intersection over union of the seeds' and joined robots'
bodies with the target), the joined robots' localization error (median and largest, their
estimate against their true position), ``assembled_s`` (the last join), the most and the mean
number of robots moving at once, ``jammed_robots`` (moving robots whose body advanced less than
:data:`JAM_MM` in some :data:`JAM_S` of their motion), ``contacts`` (integration steps in which
a moving body touched another) and ``lost`` robots. Files: ``self_assembly.png`` and the
robots table's ``stage``, ``est_x_mm``, ``est_y_mm`` and ``localization_error_mm`` columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from kilonet.errors import read_text
from kilonet.params import ParamError, param
from kilonet.protocols.self_assembly.program import AssemblyStage, SelfAssembly
from kilonet.protocols.self_assembly.rules import Shape
from kilonet.scenarios.base import Drawing, Reporting, RunResult, Scenario, Setup

if TYPE_CHECKING:
    import pandas as pd

    from kilonet.params import Params
    from kilonet.simulation import Simulation

__all__ = [
    "SCENARIO",
    "SEEDS",
    "SelfAssemblyParams",
    "ShapeError",
    "frame_rotation_deg",
    "iou",
    "load_shape",
    "read_bitmap",
    "shipped_shapes",
]

#: The shipped shapes' folder (package data).
SHAPES_DIR = Path(__file__).with_name("shapes")
#: Seed robots, their positions in the shape's frame (a packed diamond, 36 mm apart), mm.
SEEDS = np.array([[0.0, 0.0], [36.0, 0.0], [18.0, 31.18], [54.0, 31.18]])
#: Spacing of the packed start, mm (bodies 1 mm apart).
PACKED_MM = 34.0
#: Largest jitter of a packed robot along each axis, mm.
JITTER_MM = 0.4
#: The body diameter, mm: no two packed robots start closer.
BODY_MM = 33.0
#: A moving robot whose body advances less than this in ``JAM_S`` seconds is jammed, mm.
JAM_MM = 10.0
#: The shape's bitmap starts this far left of and below the origin seed, mm: a seed's body
#: radius and a little, so that the packed start just below the seeds lies outside it.
SEED_MARGIN_MM = 18.0
JAM_S = 30.0
#: The run ends when no robot joined for this long, seconds: the assembly has stalled (the last
#: robots jam round the start, where the robots still waiting hear them and never start).
STALLED_S = 600.0
#: Characters of a text bitmap: inside, and outside.
INSIDE, OUTSIDE = "#1", ".0 "


class ShapeError(ParamError):
    """A shape file that cannot be read as a bitmap; the message names the file and line."""


@dataclass(frozen=True)
class SelfAssemblyParams:
    """Parameters of the self-assembly scenario."""

    section_name = "self_assembly"
    shape: str = param(
        "square", doc="the target: a shipped shape's name, or a .txt bitmap or .png image"
    )
    cell_mm: float = param(40.0, lo=5.0, hi=1000.0, doc="side of one bitmap cell, mm")


def shipped_shapes() -> list[str]:
    """The names of the shapes shipped with kilonet (``self_assembly.shape = NAME``)."""
    return sorted(p.stem for p in SHAPES_DIR.glob("*.txt"))


def read_bitmap(text: str, source: str) -> np.ndarray:
    """A text bitmap's cells: ``#`` or ``1`` inside, ``.``, ``0`` or a space outside, row 0
    the top line; lines starting with ``;`` are comments, and short lines are outside to
    their end.

    Raises
    ------
    ShapeError
        If a line holds another character (``source:line:column`` says where), or no cell is
        inside.

    >>> read_bitmap("; a corner\\n#.\\n##\\n", "x.txt").astype(int).tolist()
    [[1, 0], [1, 1]]
    """
    rows: list[list[bool]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if line.startswith(";"):
            continue
        line = line.rstrip()
        for col, char in enumerate(line, start=1):
            if char not in INSIDE + OUTSIDE:
                raise ShapeError(
                    f"{source}:{number}:{col}: {char!r} is not a bitmap cell "
                    f"('#' or '1' inside, '.' or '0' outside)"
                )
        rows.append([c in INSIDE for c in line])
    while rows and not any(rows[-1]):
        rows.pop()
    while rows and not any(rows[0]):
        rows.pop(0)
    if not rows:
        raise ShapeError(f"{source}: no cell of the shape is inside ('#' or '1')")
    width = max(len(r) for r in rows)
    return np.array([r + [False] * (width - len(r)) for r in rows], dtype=bool)


def _read_png(path: Path) -> np.ndarray:
    import matplotlib.image as mpimg

    try:
        image = mpimg.imread(path)
    except (OSError, ValueError, SyntaxError) as exc:
        raise ShapeError(f"{path}: not a readable PNG image ({exc})") from None
    image = np.asarray(image, dtype=float)
    if image.ndim == 2:
        dark, opaque = image < 0.5, np.ones(image.shape, dtype=bool)
    else:
        dark = image[..., :3].mean(axis=2) < 0.5
        opaque = image[..., 3] >= 0.5 if image.shape[2] == 4 else np.ones(dark.shape, bool)
    mask = dark & opaque
    if not mask.any():
        raise ShapeError(f"{path}: no pixel of the shape is dark (the shape is its dark pixels)")
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return mask[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]


def load_shape(name: str, cell_mm: float) -> Shape:
    """The shape ``name`` (a shipped shape, or a ``.txt``/``.png`` file) at ``cell_mm`` per
    cell, its bottom-left corner :data:`SEED_MARGIN_MM` left of and below the origin seed.

    Raises
    ------
    ShapeError
        If the file is missing or unreadable, not a bitmap, or the shape does not contain all
        four seeds.
    """
    path = Path(name)
    if path.suffix.lower() not in (".txt", ".png"):
        if name not in shipped_shapes():
            raise ShapeError(
                f"self_assembly.shape = {name!r}: not a shipped shape "
                f"({', '.join(shipped_shapes())}) nor a .txt or .png file"
            )
        path = SHAPES_DIR / f"{name}.txt"
    if path.suffix.lower() == ".png":
        if not path.is_file():
            raise ShapeError(f"{path}: no such shape file")
        mask = _read_png(path)
    else:
        mask = read_bitmap(read_text(path, ShapeError, "shape file"), str(path))
    shape = Shape(mask, float(cell_mm), (-SEED_MARGIN_MM, -SEED_MARGIN_MM))
    outside = [i for i, (x, y) in enumerate(SEEDS) if not shape.contains(x, y)]
    if outside:
        raise ShapeError(
            f"{path}: at {cell_mm:g} mm a cell, seed robot(s) {outside} at "
            f"{SEEDS[outside].round(1).tolist()} mm lie outside the shape; its bottom-left "
            "cells hold the seeds (fill them, or make the cells larger)"
        )
    return shape


def _generate(params: Params, n: int, rng: np.random.Generator) -> np.ndarray:
    """The four seeds, then ``n - 4`` robots packed on a hex lattice :data:`PACKED_MM` apart to
    the left of and below them, its top-right robot beside the origin seed, each jittered by
    up to :data:`JITTER_MM` along each axis. Two neighbours jittered towards each other can
    close in by ``2 * sqrt(2) * JITTER_MM``, to less than a body: both then stay on their
    lattice spots (a robot on its spot and a jittered one stay ``sqrt(2) * JITTER_MM`` short of
    the spacing at most, bodies apart), and every start without such a pair is as drawn. The
    start touches the shape only at the seeds: robots edge-follow clockwise along its top into
    the shape."""
    if n < 5:
        raise ValueError(f"self-assembly needs the 4 seeds and at least one robot to move, not {n}")
    movers = n - len(SEEDS)
    cols = max(2, math.ceil(math.sqrt(movers)))
    row_mm = PACKED_MM * math.sqrt(3) / 2
    spots = []
    for k in range(movers):
        row, col = divmod(k, cols)
        spots.append((-PACKED_MM * (col + 1) - (row % 2) * PACKED_MM / 2, -row * row_mm))
    from scipy.spatial import cKDTree

    lattice = np.array(spots)
    packed = lattice + rng.uniform(-JITTER_MM, JITTER_MM, (movers, 2))
    close = cKDTree(packed).query_pairs(BODY_MM, output_type="ndarray")
    if len(close):
        unjittered = np.unique(close)
        packed[unjittered] = lattice[unjittered]
    return np.vstack([SEEDS, packed])


def _program(params: Params, positions: np.ndarray):
    s = params.scenario
    shape = load_shape(s.shape, s.cell_mm)
    if len(positions) < 5:
        raise ParamError(
            f"self-assembly needs the 4 seeds and a robot to move, not {len(positions)}"
        )
    origin = positions[0]

    def make(i: int) -> SelfAssembly:
        if i < len(SEEDS):
            at = positions[i] - origin
            return SelfAssembly(
                shape, seed_at_mm=(float(at[0]), float(at[1])), seed_gradient=int(i > 0)
            )
        return SelfAssembly(shape)

    return make


def iou(
    shape: Shape, centres_mm: np.ndarray, diameter_mm: float, resolution_mm: float = 1.0
) -> float:
    """Intersection over union of the bodies (discs at ``centres_mm``) with the shape's
    cells, on a raster of ``resolution_mm``.

    >>> s = Shape(np.ones((1, 1), dtype=bool), 33.0)
    >>> round(iou(s, np.array([[16.5, 16.5]]), 33.0, 0.25), 2)  # a disc in its square: π/4
    0.79
    """
    x0, y0, x1, y1 = shape.extent_mm
    if len(centres_mm):
        r = diameter_mm / 2
        x0, y0 = min(x0, centres_mm[:, 0].min() - r), min(y0, centres_mm[:, 1].min() - r)
        x1, y1 = max(x1, centres_mm[:, 0].max() + r), max(y1, centres_mm[:, 1].max() + r)
    xs = np.arange(x0, x1, resolution_mm) + resolution_mm / 2
    ys = np.arange(y0, y1, resolution_mm) + resolution_mm / 2
    gx, gy = np.meshgrid(xs, ys)
    rows, cols = shape.mask.shape
    col = np.floor((gx - shape.origin_mm[0]) / shape.cell_mm).astype(int)
    row = np.floor((gy - shape.origin_mm[1]) / shape.cell_mm).astype(int)
    valid = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    target = np.zeros(gx.shape, dtype=bool)
    target[valid] = shape.mask[rows - 1 - row[valid], col[valid]]
    bodies = np.zeros(gx.shape, dtype=bool)
    for cx, cy in centres_mm:
        bodies |= (gx - cx) ** 2 + (gy - cy) ** 2 <= (diameter_mm / 2) ** 2
    union = (target | bodies).sum()
    return float((target & bodies).sum() / union) if union else 0.0


def frame_rotation_deg(true_mm: np.ndarray, estimates_mm: np.ndarray) -> float | None:
    """How far the robots' shared frame is turned about the origin seed, degrees
    (counter-clockwise positive): the angle of the least-squares similarity through the origin
    that carries the robots' true positions onto their estimates (both ``(n, 2)``, mm, in the
    seeds' frame). A shape whose estimates are each a few mm off but turned together by this
    angle comes out warped, every robot's error growing with its distance from the seeds.
    ``None`` without robots.

    >>> true = np.array([[100.0, 0.0], [0.0, 200.0]])
    >>> turn = np.deg2rad(10.0)
    >>> est = true @ np.array([[np.cos(turn), np.sin(turn)], [-np.sin(turn), np.cos(turn)]])
    >>> round(frame_rotation_deg(true, est), 6), frame_rotation_deg(true[:0], est[:0])
    (10.0, None)
    """
    t = true_mm[:, 0] + 1j * true_mm[:, 1]
    e = estimates_mm[:, 0] + 1j * estimates_mm[:, 1]
    if not len(t) or not np.any(t):
        return None
    return float(np.degrees(np.angle(np.vdot(t, e))))


def _stages(sim: Simulation) -> list[AssemblyStage]:
    return [r.stage for r in sim.robots]


def _stop_when(sim: Simulation) -> bool:
    """Every robot joined or is lost; or the assembly stalled: none joined for
    :data:`STALLED_S` (the robots still moving find no room in the shape, or circle round
    the start where the robots still waiting hear them, and the waiting never start)."""
    stages = _stages(sim)
    done = (AssemblyStage.SEED, AssemblyStage.JOINED, AssemblyStage.LOST)
    if all(s in done for s in stages):
        return True
    since = [t for r in sim.robots if (t := r.since_joined_s()) is not None]
    return bool(since) and min(since) > STALLED_S


def _progress(sim: Simulation) -> str:
    stages = _stages(sim)
    moving = sum(s in (AssemblyStage.MOVE_OUTSIDE, AssemblyStage.MOVE_INSIDE) for s in stages)
    return f"{stages.count(AssemblyStage.JOINED)} joined, {moving} moving"


def _moving_at_once(events: pd.DataFrame) -> tuple[int, float]:
    """The most robots moving at once, and the mean over the time from the first start to
    the last stop (0 for a run in which none moved)."""
    changes = events[events["event"].isin(["start", "stopped", "lost"])]
    if changes.empty:
        return 0, 0.0
    steps = np.where(changes["event"] == "start", 1, -1)
    times = changes["t_s"].to_numpy()
    count = np.cumsum(steps)
    span = times[-1] - times[0]
    mean = float(np.sum(count[:-1] * np.diff(times)) / span) if span > 0 else 0.0
    return int(count.max()), mean


def _jammed(sim: Simulation, events: pd.DataFrame) -> int:
    """Robots whose body advanced less than :data:`JAM_MM` in some :data:`JAM_S` between
    their start and their stop (or the run's end), sampled every second."""
    poses = sim.trace.poses_frame()
    starts = events[events["event"] == "start"].set_index("robot")["t_s"]
    ends = events[events["event"].isin(["stopped", "lost"])].groupby("robot")["t_s"].first()
    jammed = 0
    for robot, t0 in starts.items():
        t1 = float(ends.get(robot, sim.env.now))
        if t1 - t0 < JAM_S:
            continue
        mine = poses[poses["robot"] == robot]
        grid = np.arange(t0, t1, 1.0)
        at = np.searchsorted(mine["t_s"].to_numpy(), grid, side="right") - 1
        xy = np.where(
            (at >= 0)[:, None],
            mine[["x_mm", "y_mm"]].to_numpy()[np.maximum(at, 0)],
            sim.initial_positions_mm[robot],
        )
        lag = int(JAM_S)
        moved = np.hypot(*(xy[lag:] - xy[:-lag]).T)
        jammed += bool((moved < JAM_MM).any())
    return jammed


def _robot_columns(sim: Simulation) -> pd.DataFrame:
    import pandas as pd

    origin = sim.initial_positions_mm[0]
    rows = []
    for i, robot in enumerate(sim.robots):
        est = robot.estimate
        true = sim.world.positions_mm[i] - origin
        err = math.nan if est is None else math.hypot(est[0] - true[0], est[1] - true[1])
        rows.append(
            {
                "robot": i,
                "stage": robot.stage.value,
                "est_x_mm": math.nan if est is None else est[0],
                "est_y_mm": math.nan if est is None else est[1],
                "localization_error_mm": err,
            }
        )
    return pd.DataFrame(rows)


def _metrics(sim: Simulation) -> dict[str, Any]:
    s = sim.params.scenario
    shape = load_shape(s.shape, s.cell_mm)
    stages = _stages(sim)
    joined = [i for i, st in enumerate(stages) if st is AssemblyStage.JOINED]
    standing = (AssemblyStage.SEED, AssemblyStage.SETTLE, AssemblyStage.JOINED)
    placed = [i for i, st in enumerate(stages) if st in standing]
    columns = _robot_columns(sim)
    errors = columns.loc[joined, "localization_error_mm"].to_numpy()
    true = sim.world.positions_mm[joined] - sim.initial_positions_mm[0]
    estimates = columns.loc[joined, ["est_x_mm", "est_y_mm"]].to_numpy(dtype=float)
    events = sim.trace.events_frame()
    joins = events[events["event"] == "joined"]
    most, mean = _moving_at_once(events)
    movers = len(stages) - stages.count(AssemblyStage.SEED)
    centres = sim.world.positions_mm[placed] - sim.initial_positions_mm[0]
    return {
        "joined": len(joined),
        "joined_fraction": len(joined) / movers if movers else 0.0,
        "iou": iou(shape, centres, sim.world.diameter_mm),
        "localization_error_median_mm": float(np.median(errors)) if len(errors) else None,
        "localization_error_max_mm": float(np.max(errors)) if len(errors) else None,
        "frame_rotation_deg": frame_rotation_deg(true, estimates),
        "assembled_s": float(joins["t_s"].max()) if len(joins) else None,
        "moving_at_once_max": most,
        "moving_at_once_mean": mean,
        "jammed_robots": _jammed(sim, events),
        "contacts": int(sum(sim.motion.blocked_count)),
        "lost": stages.count(AssemblyStage.LOST),
        "shape_cells": int(shape.mask.sum()),
    }


def _figure(result: RunResult, out_dir: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle, Rectangle

    sim = result.sim
    s = result.params.scenario
    shape = load_shape(s.shape, s.cell_mm)
    pos = sim.world.positions_mm - sim.initial_positions_mm[0]
    fig, ax = plt.subplots(figsize=(7, 7))
    rows, _ = shape.mask.shape
    for r, c in zip(*np.nonzero(shape.mask), strict=True):
        x = shape.origin_mm[0] + c * shape.cell_mm
        y = shape.origin_mm[1] + (rows - 1 - r) * shape.cell_mm
        ax.add_patch(Rectangle((x, y), shape.cell_mm, shape.cell_mm, color="0.88", lw=0))
    for (x, y), robot in zip(pos, sim.robots, strict=True):
        color = [c / 3 for c in robot.color]
        ax.add_patch(Circle((x, y), sim.world.diameter_mm / 2, fc=color, ec="k", lw=0.5))
    lo = np.minimum(pos.min(axis=0), shape.extent_mm[:2]) - 40
    hi = np.maximum(pos.max(axis=0), shape.extent_mm[2:]) + 40
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    m = result.summary
    ax.set_title(
        f"self-assembly: {m['joined_fraction']:.0%} joined, IoU {m['iou']:.2f} "
        f"(t = {m['sim_time_s']:.0f} s)"
    )
    fig.tight_layout()
    fig.savefig(out_dir / "self_assembly.png", dpi=100)
    plt.close(fig)


SCENARIO = Scenario(
    name="self-assembly",
    summary="programmable self-assembly: robots edge-follow from a packed start into a shape",
    setup=Setup(
        program=_program,
        section=SelfAssemblyParams,
        robots=100,
        defaults={"duration_s": 7200.0, "robot.loop_ticks": 4, "motion.step_s": 0.2},
        supports={"medium.message_format": ("kilolib",), "robot.rx_distance": ("estimate",)},
        placement=_generate,
        stop_when=_stop_when,
    ),
    reporting=Reporting(
        metrics=_metrics,
        robot_columns=_robot_columns,
        ends_when=f"every robot joined the shape or is lost, or none joined for {STALLED_S:g} s",
        progress_note=_progress,
    ),
    drawing=Drawing(
        figures=_figure,
    ),
)
