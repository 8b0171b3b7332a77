"""What a replay shows, read from a run directory: the run's tables (:func:`load_run`), the
state of the swarm at any moment (:class:`Replay`), estimates aligned per frame onto the truth.

Shared by the video renderer (:mod:`kilonet.viz.video`) and the HTML replay
(:mod:`kilonet.viz.replay`); :func:`kilonet.viz.animation.animate_run` chooses between them.
"""

from __future__ import annotations

import json
import math
import os
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.protocols.common.alignment import procrustes_rmse
from kilonet.visibility import LinkModel

#: Overlay names accepted by the renderers and ``kilonet animate --overlay``.
OVERLAYS = ("edges", "messages", "paths", "estimates", "frames")

#: Output suffixes: ``.gif`` (Pillow), ``.mp4`` (ffmpeg), ``.html`` (self-contained replay).
FORMATS = (".gif", ".mp4", ".html")

#: At most this many frames per video; more means a too low ``speed`` for the run's length.
MAX_FRAMES = 20_000

_TABLES: dict[str, tuple[str, ...]] = {
    "led": ("t_s", "robot", "r", "g", "b"),
    "poses": ("t_s", "robot", "x_mm", "y_mm"),
    "stops": ("t_s", "robot", "cause"),
    "events": ("t_s", "robot", "event", "data"),
    "messages": ("t_s", "sender", "delivered"),
    "estimates": ("t_s", "robot", "x_mm", "y_mm", "frame"),
}

# Colours (RGB 0-255). The table is light so that dark (unset) LEDs and white ones both show.
TABLE_RGB = (240, 240, 240)
RIM_RGB = (51, 51, 51)
CRASHED_RGB = (214, 39, 40)
SENDER_RGB = (0, 120, 255)
EDGE_RGB = (150, 150, 150)
PATH_RGB = (31, 119, 180)
ESTIMATE_RGB = (148, 103, 189)
TEXT_RGB = (0, 0, 0)
BOX_RGB = (255, 255, 255)
# Frame halos: matplotlib's tab10 without its red and purple, which mark stopped robots and
# estimates.
FRAME_COLOURS = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (140, 86, 75), (227, 119, 194),
    (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip


FRAME_RGBA = np.array([(r / 255, g / 255, b / 255, 1.0) for r, g, b in FRAME_COLOURS])

SCALE_BARS_MM = (10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0)


class AnimationError(ValueError):
    """A run directory or an animation option is unusable; the message says which and why."""


def level_to_rgb(levels: np.ndarray) -> np.ndarray:
    """kilolib LED levels (0–3 per channel) as 8-bit RGB values (0, 85, 170, 255).

    Examples
    --------
    >>> level_to_rgb(np.array([[0, 1, 3]])).tolist()
    [[0, 85, 255]]
    """
    return np.asarray(levels, dtype=np.int64) * 85


def frame_times(start_s: float, end_s: float, fps: float, speed: float) -> np.ndarray:
    """Simulated times (s) of the frames of a video from ``start_s`` to ``end_s``.

    One frame every ``speed / fps`` simulated seconds, starting at ``start_s``; the last frame is
    the last one not after ``end_s``.

    Examples
    --------
    >>> frame_times(0.0, 1.0, fps=4, speed=1.0).tolist()
    [0.0, 0.25, 0.5, 0.75, 1.0]
    >>> len(frame_times(0.0, 600.0, fps=10, speed=30.0))
    201
    """
    return start_s + np.arange(frame_count(start_s, end_s, fps, speed)) * (speed / fps)


def frame_count(start_s: float, end_s: float, fps: float, speed: float) -> int:
    """How many frames :func:`frame_times` gives, counted without making them, so that a
    video too long to draw is refused before memory for its frames is asked for
    (``--fps 1e9`` would be tens of GiB). ``sys.maxsize`` when the count does not fit.

    Examples
    --------
    >>> frame_count(0.0, 600.0, fps=10, speed=30.0), frame_count(0.0, 30.0, fps=1e9, speed=1.0)
    (201, 30000000001)
    """
    step = speed / fps
    span = (end_s - start_s) / step if step > 0 else math.inf
    return math.floor(span + 1e-9) + 1 if span < sys.maxsize else sys.maxsize


# ------------------------------------------------------------------------------ run data


@dataclass
class RunData:
    """The tables of a run directory (missing optional tables are empty), its parameters and
    summary. ``robots`` is sorted by robot index."""

    path: Path
    robots: pd.DataFrame
    led: pd.DataFrame
    poses: pd.DataFrame
    stops: pd.DataFrame
    events: pd.DataFrame
    messages: pd.DataFrame
    estimates: pd.DataFrame
    led_key: list[tuple[tuple[int, int, int], str]] = field(default_factory=list)
    params: dict[str, Any] = field(default_factory=dict)
    summary: dict[str, Any] = field(default_factory=dict)

    @property
    def n_robots(self) -> int:
        """Number of robots."""
        return len(self.robots)

    @property
    def duration_s(self) -> float:
        """Simulated seconds the run lasted (summary, else parameters, else the last event)."""
        for value in (self.summary.get("sim_time_s"), self.params.get("duration_s")):
            if isinstance(value, int | float) and value >= 0:
                return float(value)
        ends = [float(t["t_s"].max()) for t in (self.led, self.poses, self.stops) if len(t)]
        return max(ends, default=0.0)

    @property
    def messages_traced(self) -> bool:
        """Whether the run recorded its transmissions (``trace.messages``)."""
        return bool(self.params.get("trace.messages", len(self.messages) > 0))


def _read_table(run_dir: Path, name: str) -> pd.DataFrame | None:
    for suffix, reader in ((".csv", pd.read_csv), (".parquet", pd.read_parquet)):
        path = run_dir / f"{name}{suffix}"
        if path.exists():
            try:
                return reader(path)
            except Exception as exc:  # any reader failure means an unusable file for the user
                raise AnimationError(f"{path}: cannot read the table ({exc})") from None
    return None


def _read_json(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {}
    try:
        value = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise AnimationError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(value, dict):
        raise AnimationError(f"{path}: expected a JSON object")
    return value


def load_run(run_dir: str | Path) -> RunData:
    """Read a run directory written by ``kilonet.scenarios.write_outputs`` (CSV or Parquet tables).

    Raises
    ------
    AnimationError
        If the directory or its robots table is missing or empty, a table cannot be read,
        lacks a column, or names a robot that is not in the robots table.
    """
    path = Path(run_dir)
    if not path.is_dir():
        raise AnimationError(f"{path}: no such run directory")
    robots = _read_table(path, "robots")
    if robots is None:
        raise AnimationError(f"{path}: no robots.csv or robots.parquet (not a run directory?)")
    _require(robots, ("x0_mm", "y0_mm"), path / "robots")
    if robots.empty:
        raise AnimationError(f"{path / 'robots'}: no robots to draw")
    if "robot" in robots:
        robots = robots.sort_values("robot", kind="stable").reset_index(drop=True)
        if not np.array_equal(robots["robot"].to_numpy(), np.arange(len(robots))):
            raise AnimationError(f"{path / 'robots'}: robot indexes must be 0..{len(robots) - 1}")
    tables: dict[str, pd.DataFrame] = {}
    for name, columns in _TABLES.items():
        table = _read_table(path, name)
        if table is None:
            table = pd.DataFrame({c: [] for c in columns})
        _require(table, columns, path / name)
        who = "sender" if name == "messages" else "robot"
        ids = table[who].to_numpy()
        if len(ids) and (ids.min() < 0 or ids.max() >= len(robots)):
            raise AnimationError(
                f"{path / name}: {who} {int(ids.max() if ids.max() >= len(robots) else ids.min())}"
                f" is not one of the {len(robots)} robots"
            )
        tables[name] = table
    return RunData(
        path=path,
        robots=robots,
        led_key=_led_key(_read_table(path, "led_key"), path / "led_key"),
        params=_read_json(path / "params.json"),
        summary=_read_json(path / "summary.json"),
        **tables,
    )


def _led_key(table: pd.DataFrame | None, where: Path) -> list[tuple[tuple[int, int, int], str]]:
    """The ``led_key`` table's entries: ``((r, g, b) levels 0-3, meaning)``; none without it."""
    if table is None:
        return []
    _require(table, ("r", "g", "b", "meaning"), where)
    levels = table[["r", "g", "b"]].to_numpy()
    if len(levels) and not np.isin(levels, (0, 1, 2, 3)).all():
        raise AnimationError(f"{where}: LED levels must be 0, 1, 2 or 3")
    return [
        ((int(r), int(g), int(b)), str(meaning))
        for (r, g, b), meaning in zip(levels, table["meaning"], strict=True)
    ]


def _require(table: pd.DataFrame, columns: Iterable[str], where: Path) -> None:
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise AnimationError(f"{where}: missing column(s) {', '.join(missing)}")


# ------------------------------------------------------------------------ state over time


class Replay:
    """The state of a run at any simulated time, sampled from its event tables.

    Queries at increasing times are incremental (the renderers ask frame after frame); an
    earlier time restarts from the beginning.

    Parameters
    ----------
    run : RunData
        The run.
    window_s : float
        Length of the window (s) for :meth:`senders`.
    align_estimates : bool
        Draw the estimates after the best rigid alignment of each frame onto the truth
        (rotation, shift, reflection; :func:`kilonet.protocols.common.alignment.procrustes_rmse`),
        as the
        position metrics do; groups of fewer than three estimates are then left out. ``False``
        draws them as recorded, for estimates already in table coordinates. The estimates are
        those the robots held at each moment (the run's ``estimates`` table) where the run
        recorded them, else the robots table's end-of-run ``est_x_mm``, ``est_y_mm`` and
        ``frame``, drawn throughout and labelled final.
    """

    def __init__(
        self, run: RunData, *, window_s: float = 0.2, align_estimates: bool = True
    ) -> None:
        self.run = run
        self.n = run.n_robots
        self.window_s = window_s
        self.start_mm = run.robots[["x0_mm", "y0_mm"]].to_numpy(dtype=float)
        self.radius_mm = ROBOT_DIAMETER_MM / 2
        params = run.params
        self.links = LinkModel(
            float(params.get("medium.range_mm", 85.0)),
            params.get("medium.occlusion", "none"),
            float(params.get("medium.occlusion_range_factor", 1.0)),
            float(params.get("medium.occlusion_loss", 0.0)),
            self.radius_mm,
        )
        step_s = float(run.params.get("motion.step_s", 0.05))

        led = run.led.sort_values("t_s", kind="stable")
        self._led_t = led["t_s"].to_numpy(dtype=float)
        self._led_robot = led["robot"].to_numpy(dtype=np.intp)
        self._led_level = led[["r", "g", "b"]].to_numpy(dtype=np.int64)
        self._led_state = np.zeros((self.n, 3), dtype=np.int64)
        self._led_next = 0
        self._led_clock = -math.inf

        self.tracks = _tracks(run.poses, self.start_mm, step_s)
        self.moving = np.array(sorted(self.tracks), dtype=np.intp)

        stops = run.stops
        self.stop_s = np.full(self.n, math.inf)
        self.removed_s = np.full(self.n, math.inf)
        if len(stops):
            first = stops.groupby("robot")["t_s"].min()
            self.stop_s[first.index.to_numpy(dtype=np.intp)] = first.to_numpy()
            removed = stops[stops["cause"] == "removed"].groupby("robot")["t_s"].min()
            self.removed_s[removed.index.to_numpy(dtype=np.intp)] = removed.to_numpy()

        phases = run.events[run.events["event"] == "phase"].sort_values("t_s", kind="stable")
        self._phase_t = phases["t_s"].to_numpy(dtype=float)
        self._phase_label = [_phase_label(d) for d in phases["data"]]

        sent = run.messages[run.messages["delivered"] > 0].sort_values("t_s", kind="stable")
        self._msg_t = sent["t_s"].to_numpy(dtype=float)
        self._msg_sender = sent["sender"].to_numpy(dtype=np.intp)

        robots = run.robots
        #: (N,) rank of each robot's final frame among the frame labels, -1 for none.
        self.frame_rank = _frame_ranks(robots["frame"]) if "frame" in robots.columns else None
        self.frame_count = 0 if self.frame_rank is None else int(self.frame_rank.max() + 1)
        self.estimates_mm = None
        self.estimate_rmse_mm = math.nan
        self.align_estimates = align_estimates
        if {"est_x_mm", "est_y_mm"} <= set(robots.columns):
            est = robots[["est_x_mm", "est_y_mm"]].to_numpy(dtype=float)
            if align_estimates:
                final = ["x_mm", "y_mm"] if {"x_mm", "y_mm"} <= set(robots.columns) else None
                truth = robots[final].to_numpy(dtype=float) if final else self.start_mm
                groups = self.frame_rank if self.frame_rank is not None else np.zeros(self.n)
                est = aligned_estimates(est, truth, groups)
                errors = np.hypot(*(est - truth).T)
                errors = errors[np.isfinite(errors)]
                self.estimate_rmse_mm = (
                    float(np.sqrt(np.mean(errors**2))) if len(errors) else math.nan
                )
            self.estimates_mm = est
        self.led_key = run.led_key
        #: What the ``estimates`` and ``frames`` overlays draw at each moment.
        self.steps: EstimateSteps | None = None
        if len(run.estimates):
            self.steps = held_estimates(run.estimates, self.n, self.positions, align_estimates)
        elif self.estimates_mm is not None or self.frame_rank is not None:
            self.steps = EstimateSteps.final(
                self.n, self.estimates_mm, self.frame_rank, self.estimate_rmse_mm
            )

    @property
    def has_estimates(self) -> bool:
        """Whether the run has estimates to draw (held over time, or final)."""
        return self.estimates_mm is not None or (self.steps is not None and self.steps.held)

    @property
    def has_frames(self) -> bool:
        """Whether the run has frame memberships to draw (held over time, or final)."""
        return self.frame_rank is not None or (self.steps is not None and self.steps.held)

    def leds(self, t_s: float) -> np.ndarray:
        """(N, 3) kilolib LED levels at ``t_s``: the last change at or before it (0 before)."""
        if t_s < self._led_clock:
            self._led_state[:] = 0
            self._led_next = 0
        self._led_clock = t_s
        end = int(np.searchsorted(self._led_t, t_s, side="right"))
        if end > self._led_next:
            # Latest change per robot wins; numpy leaves repeated-index assignment unordered.
            robots = self._led_robot[self._led_next : end][::-1]
            levels = self._led_level[self._led_next : end][::-1]
            _, latest = np.unique(robots, return_index=True)
            self._led_state[robots[latest]] = levels[latest]
            self._led_next = end
        return self._led_state.copy()

    def positions(self, t_s: float) -> np.ndarray:
        """(N, 2) true positions (mm) at ``t_s``; moving robots interpolated between poses."""
        pos = self.start_mm.copy()
        for robot, (t, x, y) in self.tracks.items():
            pos[robot] = np.interp(t_s, t, x), np.interp(t_s, t, y)
        return pos

    def path(self, robot: int, t_s: float) -> np.ndarray:
        """(K, 2) path (mm) of a moving ``robot`` from the start to its position at ``t_s``."""
        t, x, y = self.tracks[robot]
        k = int(np.searchsorted(t, t_s, side="left"))
        now = np.array([[np.interp(t_s, t, x), np.interp(t_s, t, y)]])
        return np.vstack([np.column_stack([x[:k], y[:k]]), now])

    def present(self, t_s: float) -> np.ndarray:
        """(N,) whether each robot is on the table at ``t_s`` (removed robots are not)."""
        return self.removed_s > t_s

    def stopped(self, t_s: float) -> np.ndarray:
        """(N,) whether each robot has stopped (crash, battery, removal) by ``t_s``."""
        return self.stop_s <= t_s

    def phase(self, t_s: float) -> str | None:
        """The label of the latest ``phase`` event at or before ``t_s``, if any."""
        k = int(np.searchsorted(self._phase_t, t_s, side="right"))
        return self._phase_label[k - 1] if k else None

    def senders(self, t_s: float) -> np.ndarray:
        """Robots that delivered a message in ``(t_s - window_s, t_s]``, sorted."""
        lo = int(np.searchsorted(self._msg_t, t_s - self.window_s, side="right"))
        hi = int(np.searchsorted(self._msg_t, t_s, side="right"))
        return np.unique(self._msg_sender[lo:hi])

    def edges(self, positions_mm: np.ndarray, present: np.ndarray) -> np.ndarray:
        """(E, 2) robot pairs that can hear each other at these positions."""
        links = self.links.links(positions_mm, present)
        return np.column_stack([links.i, links.j])

    def extent_mm(self, margin_mm: float = 30.0) -> tuple[float, float, float, float]:
        """``(xmin, xmax, ymin, ymax)`` covering every position a robot held, plus a margin."""
        points = [self.start_mm] + [np.column_stack([x, y]) for _, x, y in self.tracks.values()]
        allpos = np.vstack(points) if self.n else np.zeros((1, 2))
        lo = allpos.min(axis=0) - self.radius_mm - margin_mm
        hi = allpos.max(axis=0) + self.radius_mm + margin_mm
        return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _phase_label(data: Any) -> str:
    """What a ``phase`` event's data says: its ``phase`` or ``name`` field, else the data."""
    try:
        value = json.loads(data) if isinstance(data, str) else data
    except ValueError:
        return str(data)
    if isinstance(value, dict):
        for key in ("phase", "name"):
            if key in value:
                return str(value[key])
        if len(value) == 1:
            return str(next(iter(value.values())))
        return ", ".join(f"{k}={v}" for k, v in value.items())
    return str(value)


def _frame_ranks(labels: pd.Series) -> np.ndarray:
    """Rank of each robot's frame label among the distinct labels (sorted), -1 for none.

    A label is none when missing, empty or a negative number.

    Examples
    --------
    >>> _frame_ranks(pd.Series(["root9", "", "root12", None, "root9"])).tolist()
    [1, -1, 0, -1, 1]
    >>> _frame_ranks(pd.Series([3, -1, 7, 3])).tolist()
    [0, -1, 1, 0]
    """
    text = labels.astype("string").str.strip()
    numeric = pd.to_numeric(labels, errors="coerce")
    member = (text.notna() & (text != "") & ~(numeric < 0)).to_numpy(dtype=bool)
    ranks = np.full(len(labels), -1)
    if member.any():
        values = numeric if numeric[member].notna().all() else text
        _, ranks[member] = np.unique(values[member].to_numpy(), return_inverse=True)
    return ranks


def aligned_estimates(
    estimated_mm: np.ndarray, true_mm: np.ndarray, groups: np.ndarray
) -> np.ndarray:
    """Estimates after the best rigid alignment (with reflection) of each group onto the truth.

    Robots are grouped by ``groups`` (e.g. the rank of their frame); a group with fewer than
    three finite estimates cannot be aligned and comes back as NaN, as do missing estimates.

    Examples
    --------
    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [90.0, 90.0]])
    >>> local = truth[:3] @ [[0.0, 1.0], [-1.0, 0.0]] + 500.0  # rotated, shifted frame
    >>> est = np.vstack([local, [[1.0, 2.0]]])
    >>> (aligned_estimates(est, truth, np.array([0, 0, 0, 1])).round(6) + 0.0).tolist()
    [[0.0, 0.0], [40.0, 0.0], [0.0, 30.0], [nan, nan]]
    """
    est = np.asarray(estimated_mm, dtype=float)
    out = np.full_like(est, np.nan)
    known = np.isfinite(est).all(axis=1)
    for group in np.unique(groups[known]):
        members = np.flatnonzero(known & (groups == group))
        if len(members) >= 3:
            _, _, out[members] = procrustes_rmse(est[members], true_mm[members])
    return out


@dataclass(frozen=True)
class EstimateSteps:
    """The robots' position estimates and frames as step functions of time: step ``k`` holds
    from ``t_s[k]`` until the next step (nothing before the first).

    Attributes
    ----------
    t_s : (K,) array
        Step times, s, increasing (``-inf`` for end-of-run values shown throughout).
    xy_mm : (K, N, 2) array
        Each robot's estimate (aligned per frame when asked), mm; NaN for none.
    frame : (K, N) array of int
        Each robot's frame, numbered by first appearance; -1 for none.
    rmse_mm : (K,) array
        RMS error of the aligned estimates at each step, mm (NaN when nothing is aligned).
    held : bool
        Whether these are what the robots held at each moment (else end-of-run values).
    aligned : bool
        Whether each frame was aligned onto the truth.
    """

    t_s: np.ndarray
    xy_mm: np.ndarray
    frame: np.ndarray
    rmse_mm: np.ndarray
    held: bool
    aligned: bool

    @classmethod
    def final(
        cls, n: int, xy_mm: np.ndarray | None, frame: np.ndarray | None, rmse_mm: float
    ) -> EstimateSteps:
        """End-of-run estimates and frames (either may be missing), shown throughout."""
        xy = np.full((1, n, 2), np.nan) if xy_mm is None else xy_mm[None].astype(float)
        ranks = np.full((1, n), -1) if frame is None else frame[None]
        return cls(np.array([-math.inf]), xy, ranks, np.array([rmse_mm]), False, True)

    def index(self, t_s: float) -> int:
        """The step in force at ``t_s``, or -1 before the first."""
        return int(np.searchsorted(self.t_s, t_s, side="right")) - 1

    def note(self, k: int) -> str:
        """The corner line that says what the estimates drawn at step ``k`` are."""
        if not self.held:
            what = "final estimates"
        elif k < 0 or not np.isfinite(self.xy_mm[k]).any():
            return "estimates held: none yet"
        else:
            what = "estimates held"
        if not self.aligned:
            return f"{what}, as recorded"
        if math.isnan(self.rmse_mm[max(k, 0)]):
            return f"{what}: no frame of 3 to align"
        return f"{what}, aligned per frame: RMSE {self.rmse_mm[max(k, 0)]:.1f} mm"


def held_estimates(table: pd.DataFrame, n: int, truth_at: Any, align: bool = True) -> EstimateSteps:
    """The estimates robots held over a run, from its ``estimates`` table (one row per change:
    ``t_s, robot, x_mm, y_mm, frame``; NaN position or empty frame: none from then on).

    ``truth_at(t_s)`` gives the (N, 2) true positions (mm) each step is aligned onto.

    Examples
    --------
    >>> rows = pd.DataFrame({"t_s": [1.0, 1.0, 1.0, 2.0], "robot": [0, 1, 2, 1],
    ...                      "x_mm": [10.0, 50.0, 10.0, 54.0], "y_mm": [5.0, 5.0, 45.0, 5.0],
    ...                      "frame": ["a", "a", "a", "a"]})
    >>> truth = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 40.0], [90.0, 0.0]])
    >>> steps = held_estimates(rows, 4, lambda t: truth)
    >>> steps.t_s.tolist(), steps.index(0.5), steps.index(1.5)
    ([1.0, 2.0], -1, 0)
    >>> (steps.xy_mm[0, :3].round(9) + 0.0).tolist()  # shifted frame, aligned back exactly
    [[0.0, 0.0], [40.0, 0.0], [0.0, 40.0]]
    >>> steps.frame[1].tolist(), bool(np.isnan(steps.xy_mm[1, 3]).all())
    ([0, 0, 0, -1], True)
    """
    rows = table.sort_values("t_s", kind="stable")
    labels = rows["frame"].astype("string").fillna("").str.strip()
    xy_rows = rows[["x_mm", "y_mm"]].to_numpy(dtype=float)
    none = (labels == "").to_numpy() | ~np.isfinite(xy_rows).all(axis=1)
    codes, _ = pd.factorize(labels.where(~none))  # by first appearance; -1: none
    robot = rows["robot"].to_numpy(dtype=np.intp)
    times, starts = np.unique(rows["t_s"].to_numpy(dtype=float), return_index=True)
    bounds = [*starts.tolist(), len(rows)]
    held = np.full((n, 2), np.nan)
    frame = np.full(n, -1)
    xy, frames, rmse = [], [], []
    for k, t in enumerate(times):
        block = slice(bounds[k], bounds[k + 1])
        held[robot[block]] = np.where(none[block, None], np.nan, xy_rows[block])
        frame[robot[block]] = codes[block]
        shown, error = held.copy(), math.nan
        if align:
            truth = truth_at(float(t))
            shown = aligned_estimates(held, truth, frame)
            errors = np.hypot(*(shown - truth).T)
            errors = errors[np.isfinite(errors)]
            error = float(np.sqrt(np.mean(errors**2))) if len(errors) else math.nan
        xy.append(shown)
        frames.append(frame.copy())
        rmse.append(error)
    shape = (len(times), n)
    return EstimateSteps(
        times,
        np.array(xy).reshape(*shape, 2),
        np.array(frames, dtype=int).reshape(shape),
        np.array(rmse),
        True,
        align,
    )


def _tracks(
    poses: pd.DataFrame, start_mm: np.ndarray, step_s: float
) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per moving robot: times (s) and positions (mm) to interpolate between.

    The motion model records a pose every ``step_s`` while a robot moves and when its motors
    switch, but not when they switch on (nothing moved yet). A gap longer than one step is
    therefore a rest: the robot stood still until one step before the next pose, so a point is
    inserted there instead of letting interpolation creep across the rest.
    """
    tracks = {}
    for robot, group in poses.sort_values(["robot", "t_s"], kind="stable").groupby("robot"):
        r = int(robot)
        t = np.concatenate([[0.0], group["t_s"].to_numpy(dtype=float)])
        x = np.concatenate([[start_mm[r, 0]], group["x_mm"].to_numpy(dtype=float)])
        y = np.concatenate([[start_mm[r, 1]], group["y_mm"].to_numpy(dtype=float)])
        gap = np.flatnonzero(np.diff(t) > 1.5 * step_s)
        if len(gap):
            t = np.insert(t, gap + 1, t[gap + 1] - step_s)
            x = np.insert(x, gap + 1, x[gap])
            y = np.insert(y, gap + 1, y[gap])
        tracks[r] = (t, x, y)
    return tracks


@contextmanager
def atomic_output(out_file: Path) -> Iterator[Path]:
    """A temporary path beside ``out_file`` that replaces it only when the block succeeds.

    The temporary name keeps the suffix, which tells the writers the format.
    """
    out_file.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_file.with_name(f".{out_file.stem}.{os.getpid()}.partial{out_file.suffix}")
    try:
        yield tmp
        os.replace(tmp, out_file)
    finally:
        tmp.unlink(missing_ok=True)
