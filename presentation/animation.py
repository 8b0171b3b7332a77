"""Animations of a finished run: GIF, MP4 and a self-contained HTML replay.

A run directory (``scenarios.write_outputs``) records what happened as events: LED changes,
poses of moving robots, stops, protocol events and (with ``trace.messages``) transmissions.
Frames are sampled from those tables at render time, so the trace stays small however long the
video. Robots are drawn as 33 mm discs at their true positions (moving robots interpolated
between their recorded poses), filled with their LED colour (kilolib level 0–3 per channel is
drawn as 0, 85, 170, 255); simulated time, and the protocol phase when the run logged ``phase``
events, appear in the top-left corner.

Overlays (:data:`OVERLAYS`):

``edges``
    the communication graph (:class:`kilonet.visibility.LinkModel`) with the run's
    ``medium.range_mm`` and ``medium.occlusion*``, recomputed when robots move or leave;
``messages``
    a blue ring around each robot that delivered a message in the last ``window_s`` seconds
    (needs a run with ``--set trace.messages=true``);
``paths``
    the path each moving robot has travelled so far;
``estimates``
    each robot's estimated position (robots table ``est_x_mm``, ``est_y_mm``, in table
    coordinates) with its error segment from the true position;
``frames``
    frame membership (robots table ``frame``; empty or negative: none) as a coloured halo.

Stopped robots (crash, battery) get a red ring; removed robots vanish at their removal time.

GIFs are written with matplotlib's Pillow writer (no external binaries), every frame mapped to
one fixed palette that holds all 64 LED colours exactly; MP4 needs ``ffmpeg`` on the ``PATH``.
The HTML replay is one file with the data embedded as JSON and a JavaScript player
(play/pause, scrub, playback speed, overlay toggles) that needs no network access.

``animate_run(run_dir)`` is the entry point for ``kilonet run --animate`` and
``kilonet animate``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import resources
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.animation import FFMpegWriter, PillowWriter
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.figure import Figure
from PIL import Image

from kilonet.alignment import procrustes_rmse
from kilonet.placement import ROBOT_DIAMETER_MM
from kilonet.visibility import LinkModel

__all__ = [
    "FORMATS",
    "MAX_FRAMES",
    "OVERLAYS",
    "AnimationError",
    "FrameRenderer",
    "Replay",
    "RunData",
    "aligned_estimates",
    "animate_run",
    "frame_times",
    "level_to_rgb",
    "load_run",
    "render_html",
    "render_video",
    "replay_data",
]

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
_TABLE = (240, 240, 240)
_RIM = (51, 51, 51)
_CRASHED = (214, 39, 40)
_SENDER = (0, 120, 255)
_EDGE = (150, 150, 150)
_PATH = (31, 119, 180)
_ESTIMATE = (148, 103, 189)
_TEXT = (0, 0, 0)
_BOX = (255, 255, 255)
# Frame halos: matplotlib's tab10 without its red and purple, which mark stopped robots and
# estimates.
_FRAME_COLOURS = (
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (140, 86, 75), (227, 119, 194),
    (127, 127, 127), (188, 189, 34), (23, 190, 207),
)  # fmt: skip


_FRAME_RGBA = np.array([(r / 255, g / 255, b / 255, 1.0) for r, g, b in _FRAME_COLOURS])

_SCALE_BARS_MM = (10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0, 2000.0, 5000.0)


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
    step = speed / fps
    n = math.floor((end_s - start_s) / step + 1e-9) + 1
    return start_s + np.arange(n) * step


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
    """Read a run directory written by ``scenarios.write_outputs`` (CSV or Parquet tables).

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
        (rotation, shift, reflection; :func:`kilonet.alignment.procrustes_rmse`), as the
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


# --------------------------------------------------------------------------- rendering


def _rgb(colour: tuple[int, int, int], alpha: float = 1.0) -> tuple[float, float, float, float]:
    return (colour[0] / 255, colour[1] / 255, colour[2] / 255, alpha)


#: The LED key's disc radius and line height, pixels; the width of a character of its text
#: (8 pt sans-serif at 100 dpi), for laying entries out before they are drawn.
_KEY_DISC_PX = 5
_KEY_LINE_PX = 16
_KEY_CHAR_PX = 6.0


@dataclass(frozen=True)
class _KeyLayout:
    """Where the LED key's entries go: ``(levels, meaning, (column of the disc's centre,
    row of entries))``, and the height of the strip along the image's bottom edge (pixels)."""

    entries: list[tuple[tuple[int, int, int], str, tuple[float, int]]]
    height_px: int

    def row_px(self, row: int, image_height_px: int) -> float:
        """The pixel row (from the top) of the centre of entry row ``row``."""
        return image_height_px - self.height_px + 5 + _KEY_LINE_PX * (row + 0.5)


def _key_layout(key: list[tuple[tuple[int, int, int], str]], width_px: int) -> _KeyLayout:
    """Entries left to right after an ``LED:`` title, wrapping onto new rows.

    Examples
    --------
    >>> layout = _key_layout([((3, 0, 0), "seed"), ((0, 3, 0), "located")], 640)
    >>> layout.height_px, [xy for _, _, xy in layout.entries]
    (26, [(45.0, 0), (95.0, 0)])
    >>> _key_layout([((3, 3, 3), "x" * 60)] * 3, 640).height_px  # one entry a row
    58
    >>> _key_layout([], 640).height_px
    0
    """
    if not key:
        return _KeyLayout([], 0)
    left = 8 + 4 * _KEY_CHAR_PX + 8  # after "LED:"
    x, row = left, 0
    entries = []
    for levels, meaning in key:
        width = 2 * _KEY_DISC_PX + 4 + len(meaning) * _KEY_CHAR_PX + 12
        if x + width > width_px - 8 and x > left:
            x, row = left, row + 1
        entries.append((levels, meaning, (x + _KEY_DISC_PX, row)))
        x += width
    return _KeyLayout(entries, (row + 1) * _KEY_LINE_PX + 10)


class FrameRenderer:
    """A matplotlib figure of the swarm whose artists are updated in place for each frame.

    Parameters
    ----------
    replay : Replay
        The run's state over time.
    overlays : iterable of str
        Names from :data:`OVERLAYS`.
    width_px : int
        Image width in pixels; the height follows the swarm's aspect ratio (both even).
    title : str
        First line of the corner text (e.g. the scenario name).
    """

    DPI = 100

    def __init__(
        self, replay: Replay, overlays: Iterable[str] = (), *, width_px: int = 640, title: str = ""
    ) -> None:
        self.replay = replay
        self.overlays = frozenset(overlays)
        self.title = title
        xmin, xmax, ymin, ymax = replay.extent_mm()
        # A strip above the swarm for the corner text, one line per thing it may show.
        steps = replay.steps
        self._frames_shown = "frames" in self.overlays and steps is not None
        self._estimates_shown = "estimates" in self.overlays and steps is not None
        lines = 1 + sum(
            (
                "messages" in self.overlays,
                self._frames_shown,
                self._estimates_shown,
                len(replay._phase_t) > 0,
            )
        )
        strip_px = 15 * lines + 10
        width_px = 2 * round(width_px / 2)
        key = _key_layout(replay.led_key, width_px)
        swarm_px = min(max(width_px * (ymax - ymin) / (xmax - xmin), 160), 2 * width_px)
        height_px = 2 * round((swarm_px + strip_px + key.height_px) / 2)
        # Widen the shorter side so one mm is the same number of pixels both ways.
        scale = min(width_px / (xmax - xmin), swarm_px / (ymax - ymin))
        cx, cy = (xmin + xmax) / 2, (ymin + ymax) / 2
        half_w = width_px / scale / 2
        bottom = cy - (swarm_px / 2 + key.height_px) / scale
        self.size_px = (width_px, height_px)
        self.fig = Figure(figsize=(width_px / self.DPI, height_px / self.DPI), dpi=self.DPI)
        FigureCanvasAgg(self.fig)
        self.fig.patch.set_facecolor(_rgb(_TABLE))
        ax = self.fig.add_axes((0, 0, 1, 1))
        ax.set_axis_off()
        ax.set_xlim(cx - half_w, cx + half_w)
        ax.set_ylim(bottom, bottom + height_px / scale)
        self.ax = ax
        self._scale_bar(ax, cx + half_w, bottom + key.height_px / scale, 1 / scale)
        self._draw_key(key, height_px)

        n = replay.n
        start = replay.start_mm
        d = 2 * replay.radius_mm
        self._edges = self._paths = self._halos = self._errors = self._marks = None
        self._edge_key: tuple[bytes, bytes] | None = None
        if "edges" in self.overlays:
            self._edges = LineCollection([], colors=[_rgb(_EDGE)], linewidths=0.8, zorder=1)
            ax.add_collection(self._edges)
        if "paths" in self.overlays and len(replay.moving):
            self._paths = LineCollection([], colors=[_rgb(_PATH)], linewidths=1.5, zorder=1.2)
            ax.add_collection(self._paths)
        if self._frames_shown:
            self._halos = self._discs(d + 6, start, np.zeros((n, 4)), 1.4)
            self._halos.set_linewidths(0)
        if self._estimates_shown:
            self._errors = LineCollection([], colors=[_rgb(_ESTIMATE)], linewidths=1.2, zorder=1.6)
            ax.add_collection(self._errors)
            self._marks = ax.scatter(
                [], [], marker="x", s=30, c=[_rgb(_ESTIMATE)], linewidths=1.5, zorder=3
            )
        self._bodies = self._discs(d, start, np.zeros((n, 4)), zorder=2)
        self._bodies.set_linewidths(0.8)
        # Marks go around a body, not on it: a rim in any one colour vanishes on some LED.
        self._crashed = self._rings(d + 7, _CRASHED)
        self._senders = self._rings(d + 7, _SENDER) if "messages" in self.overlays else None
        self._text = ax.text(
            0.01,
            0.99,
            "",
            transform=ax.transAxes,
            va="top",
            ha="left",
            family="monospace",
            fontsize=9,
            color=_rgb(_TEXT),
            zorder=5,
            bbox={"facecolor": _rgb(_BOX), "edgecolor": _rgb(_RIM), "boxstyle": "square,pad=0.3"},
        )

    def _draw_key(self, key: _KeyLayout, height_px: int) -> None:
        """The LED key along the bottom edge: a disc in each LED colour and what it means."""
        from matplotlib.patches import Ellipse

        width_px = self.size_px[0]
        #: (colour levels, meaning, (column, row from the top) of the disc's centre), pixels.
        self.key_entries: list[tuple[tuple[int, int, int], str, tuple[float, float]]] = []
        if not key.entries:
            return

        def text(x: float, y: float, words: str) -> None:
            self.fig.text(
                x / width_px, 1 - y / height_px, words, ha="left", va="center", fontsize=8,
                color=_rgb(_TEXT),
            )  # fmt: skip

        text(8, key.row_px(0, height_px), "LED:")
        for levels, meaning, (x, row) in key.entries:
            y = key.row_px(row, height_px)
            colour = tuple(int(v) for v in level_to_rgb(np.array([levels]))[0])
            disc = Ellipse(
                (x / width_px, 1 - y / height_px),
                2 * _KEY_DISC_PX / width_px,
                2 * _KEY_DISC_PX / height_px,
                transform=self.fig.transFigure,
                facecolor=_rgb(colour),
                edgecolor=_rgb(_RIM),
                linewidth=0.8,
            )
            self.fig.patches.append(disc)
            text(x + _KEY_DISC_PX + 4, y, meaning)
            self.key_entries.append((levels, meaning, (x, y)))

    def _discs(
        self, diameter_mm: float, offsets: np.ndarray, colours: np.ndarray, zorder: float
    ) -> EllipseCollection:
        n = len(offsets)
        discs = EllipseCollection(
            np.full(n, diameter_mm),
            np.full(n, diameter_mm),
            np.zeros(n),
            units="xy",
            offsets=offsets,
            offset_transform=self.ax.transData,
            facecolors=colours,
            zorder=zorder,
        )
        self.ax.add_collection(discs)
        return discs

    def _rings(self, diameter_mm: float, colour: tuple[int, int, int]) -> EllipseCollection:
        """Rings drawn around the robots at the offsets set per frame (one shape for all, so
        the cost follows the number of rings shown, not the swarm size)."""
        rings = EllipseCollection(
            [diameter_mm],
            [diameter_mm],
            [0.0],
            units="xy",
            offsets=np.zeros((1, 2)),
            offset_transform=self.ax.transData,
            facecolors="none",
            edgecolors=[_rgb(colour)],
            linewidths=2.0,
            zorder=2.5,
        )
        rings.set_visible(False)
        self.ax.add_collection(rings)
        return rings

    @staticmethod
    def _show_rings(rings: EllipseCollection, offsets_mm: np.ndarray) -> None:
        # An empty offsets array would still draw the one shape at the origin.
        rings.set_visible(len(offsets_mm) > 0)
        if len(offsets_mm):
            rings.set_offsets(offsets_mm)

    @staticmethod
    def _scale_bar(ax: Any, right: float, bottom: float, mm_per_px: float) -> None:
        # The longest round length that fits in 150 pixels.
        fits = [v for v in _SCALE_BARS_MM if v <= 150 * mm_per_px]
        length = fits[-1] if fits else _SCALE_BARS_MM[0]
        x1, y = right - 12 * mm_per_px, bottom + 12 * mm_per_px
        ax.plot([x1 - length, x1], [y, y], color=_rgb(_TEXT), linewidth=2, zorder=4)
        ax.text(
            x1 - length / 2,
            y + 4 * mm_per_px,
            f"{length:g} mm",
            ha="center",
            va="bottom",
            fontsize=8,
            color=_rgb(_TEXT),
            zorder=4,
        )

    def draw(self, t_s: float) -> None:
        """Update every artist to the state at ``t_s`` (the next save or grab shows it)."""
        r = self.replay
        pos = r.positions(t_s) if len(r.moving) else r.start_mm
        present = r.present(t_s)
        stopped = r.stopped(t_s)
        face = np.ones((r.n, 4))
        face[:, :3] = level_to_rgb(r.leds(t_s)) / 255
        face[~present, 3] = 0.0
        edge = np.tile(_rgb(_RIM), (r.n, 1))
        edge[~present, 3] = 0.0
        if len(r.moving):
            self._bodies.set_offsets(pos)
        self._bodies.set_facecolors(face)
        self._bodies.set_edgecolors(edge)
        self._show_rings(self._crashed, pos[stopped & present])
        lines = [f"{self.title}  t = {_format_time(t_s)}".strip()]
        if self._senders is not None:
            senders = r.senders(t_s)
            senders = senders[present[senders]]
            self._show_rings(self._senders, pos[senders])
            lines.append(f"senders in last {r.window_s:g} s: {len(senders)}")
        if self._edges is not None:
            key = (pos.tobytes(), present.tobytes())
            if key != self._edge_key:
                self._edge_key = key
                pairs = r.edges(pos, present)
                self._edges.set_segments(pos[pairs])
        if self._paths is not None:
            self._paths.set_segments([r.path(k, t_s) for k in r.moving if present[k]])
        steps = r.steps
        k = steps.index(t_s) if steps is not None else -1
        if self._halos is not None:
            frame = steps.frame[k] if k >= 0 else np.full(r.n, -1)
            member = (frame >= 0) & present
            colours = np.zeros((r.n, 4))
            colours[member] = _FRAME_RGBA[frame[member] % len(_FRAME_COLOURS)]
            self._halos.set_offsets(pos)
            self._halos.set_facecolors(colours)
            count = len(np.unique(frame[member]))
            lines.append(f"{'frames' if steps.held else 'final frames'}: {count}")
        if self._errors is not None:
            est = steps.xy_mm[k] if k >= 0 else np.full((r.n, 2), np.nan)
            shown = np.flatnonzero(np.isfinite(est).all(axis=1) & present)
            self._errors.set_segments(np.stack([pos[shown], est[shown]], axis=1))
            self._marks.set_offsets(est[shown] if len(shown) else np.empty((0, 2)))
            lines.append(steps.note(k))
        phase = r.phase(t_s)
        if phase is not None:
            lines.append(f"phase: {phase}")
        self._text.set_text("\n".join(lines))

    def pixel_xy(self, points_mm: np.ndarray) -> np.ndarray:
        """(K, 2) pixel coordinates (column, row from the top) of table points in a frame."""
        xy = self.ax.transData.transform(np.asarray(points_mm, dtype=float))
        return np.column_stack([xy[:, 0], self.size_px[1] - xy[:, 1]])

    def image(self, t_s: float) -> Image.Image:
        """The frame at ``t_s`` as an RGB image."""
        self.draw(t_s)
        canvas = self.fig.canvas
        canvas.draw()
        return Image.frombuffer(
            "RGBA", self.size_px, canvas.buffer_rgba(), "raw", "RGBA", 0, 1
        ).convert("RGB")


def _format_time(t_s: float) -> str:
    """Simulated time for the corner, e.g. ``'12.30 s'`` or ``'1:05.0'`` past a minute."""
    if t_s < 60:
        return f"{t_s:6.2f} s"
    minutes, seconds = divmod(t_s, 60)
    return f"{int(minutes)}:{seconds:04.1f}"


# ------------------------------------------------------------------------------ writers


def _gif_palette() -> Image.Image:
    """One palette for every frame: the 64 LED colours exactly, the drawing's other colours,
    a grey ramp and LED/rim blends for anti-aliased edges and text."""
    levels = [0, 85, 170, 255]
    led = [(r, g, b) for r in levels for g in levels for b in levels]
    fixed = [_TABLE, _RIM, _CRASHED, _SENDER, _EDGE, _PATH, _ESTIMATE, _TEXT, _BOX]
    fixed += list(_FRAME_COLOURS)
    greys = [(v, v, v) for v in range(0, 256, 12)]
    blend = [tuple((np.array(c) + np.array(_RIM)) // 2) for c in led]
    soft = [tuple((np.array(c) + np.array(_TABLE)) // 2) for c in fixed[1:]]
    colours: list[tuple[int, ...]] = []
    for c in led + fixed + greys + blend + soft:
        c = tuple(int(v) for v in c)
        if c not in colours:
            colours.append(c)
    colours = colours[:255]  # one index stays free: Pillow marks unchanged pixels with it
    flat = [v for c in colours for v in c]
    palette = Image.new("P", (1, 1))
    palette.putpalette(flat)
    return palette


class _PaletteGifWriter(PillowWriter):
    """matplotlib's Pillow writer, mapping each frame to one fixed palette as it is grabbed.

    Exact LED colours (adaptive per-frame palettes shift them and flicker), and a quarter of
    the memory of keeping RGBA frames until the end.
    """

    def setup(self, fig: Figure, outfile: Any, dpi: float | None = None) -> None:
        super().setup(fig, outfile, dpi=dpi)
        self._palette = _gif_palette()
        # Palette index of every exact palette colour, keyed by the RGB bytes of a pixel read
        # as a little-endian integer (255: not a palette colour; the palette has <= 255).
        rgb = np.array(self._palette.getpalette(), dtype=np.uint32).reshape(-1, 3)
        keys = rgb[:, 0] | (rgb[:, 1] << 8) | (rgb[:, 2] << 16)
        self._exact = np.full(1 << 24, 255, dtype=np.uint8)
        self._exact[keys] = np.arange(len(keys), dtype=np.uint8)

    def grab_frame(self, **savefig_kwargs: Any) -> None:
        buf = BytesIO()
        self.fig.savefig(buf, **{**savefig_kwargs, "format": "rgba", "dpi": self.dpi})
        width, height = self.frame_size
        rgba = Image.frombuffer("RGBA", (width, height), buf.getbuffer(), "raw", "RGBA", 0, 1)
        # Pillow maps to the nearest entry of a coarse colour grid, which can pick a grey next
        # to an LED colour; pixels that are exactly a palette colour keep that colour.
        nearest = rgba.convert("RGB").quantize(palette=self._palette, dither=Image.Dither.NONE)
        indexes = np.array(nearest).reshape(-1)
        pixels = np.frombuffer(buf.getbuffer(), dtype="<u4") & 0xFFFFFF
        exact = self._exact[pixels]
        hit = exact != 255
        indexes[hit] = exact[hit]
        frame = Image.frombytes("P", (width, height), indexes.tobytes())
        frame.putpalette(self._palette.getpalette())
        self._frames.append(frame)

    def finish(self) -> None:
        self._frames[0].save(
            self.outfile,
            save_all=True,
            append_images=self._frames[1:],
            duration=round(1000 / self.fps),
            loop=0,
            optimize=True,
        )


@contextmanager
def _atomic(out_file: Path) -> Iterator[Path]:
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


def render_video(
    replay: Replay,
    out_file: Path,
    times_s: np.ndarray,
    *,
    fps: float,
    overlays: Iterable[str] = (),
    width_px: int = 640,
    title: str = "",
) -> FrameRenderer:
    """Write one frame per time in ``times_s`` to a GIF or MP4 (by suffix); returns the renderer
    (its :meth:`FrameRenderer.pixel_xy` locates robots in the frames).

    Raises
    ------
    AnimationError
        For an MP4 when ``ffmpeg`` is not on the ``PATH``.
    """
    suffix = out_file.suffix.lower()
    if suffix == ".mp4":
        if not FFMpegWriter.isAvailable():
            raise AnimationError(
                f"{out_file}: writing MP4 needs ffmpeg on the PATH, which was not found; "
                "write a .gif or .html instead"
            )
        writer: Any = FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"])
    else:
        writer = _PaletteGifWriter(fps=fps)
    renderer = FrameRenderer(replay, overlays, width_px=width_px, title=title)
    with _atomic(out_file) as tmp, writer.saving(renderer.fig, str(tmp), FrameRenderer.DPI):
        for t in times_s:
            renderer.draw(float(t))
            writer.grab_frame()
    return renderer


# ---------------------------------------------------------------------------- HTML replay


def replay_data(
    replay: Replay,
    overlays: Iterable[str] = (),
    *,
    title: str = "",
    edge_times_s: Iterable[float] = (),
    speed: float = 1.0,
) -> dict[str, Any]:
    """The JSON-ready data of the HTML replay: start positions, LED changes and tracks per robot
    (compressed sparse rows), stops, phases, senders and, for ``edges``, the communication
    graph at each of ``edge_times_s`` where it changed. Times in s, lengths in mm."""
    overlays = frozenset(overlays)
    r = replay
    n = r.n
    led_order = np.lexsort((r._led_t, r._led_robot))
    led_robot = r._led_robot[led_order]
    level = r._led_level[led_order]
    codes = level[:, 0] * 16 + level[:, 1] * 4 + level[:, 2]
    track_robots = [int(k) for k in r.moving]
    track_t = [r.tracks[k][0] for k in track_robots]
    data: dict[str, Any] = {
        "title": title,
        "start_s": 0.0,
        "duration_s": float(r.run.duration_s),
        "speed": speed,
        "radius_mm": r.radius_mm,
        "extent_mm": list(r.extent_mm()),
        "x0": _rounded(r.start_mm[:, 0], 2),
        "y0": _rounded(r.start_mm[:, 1], 2),
        "led": {
            "start": _offsets(led_robot, n),
            "t": _rounded(r._led_t[led_order], 5),
            "c": codes.tolist(),
        },
        "tracks": {
            "robot": track_robots,
            "start": np.concatenate([[0], np.cumsum([len(t) for t in track_t])])
            .astype(int)
            .tolist(),
            "t": _rounded(np.concatenate(track_t) if track_t else np.empty(0), 4),
            "x": _rounded(
                np.concatenate([r.tracks[k][1] for k in track_robots])
                if track_robots
                else np.empty(0),
                2,
            ),
            "y": _rounded(
                np.concatenate([r.tracks[k][2] for k in track_robots])
                if track_robots
                else np.empty(0),
                2,
            ),
        },
        "stop_s": [None if math.isinf(v) else round(float(v), 5) for v in r.stop_s],
        "removed_s": [None if math.isinf(v) else round(float(v), 5) for v in r.removed_s],
        "phase": {"t": _rounded(r._phase_t, 5), "label": r._phase_label},
        "overlays": sorted(overlays),
    }
    if "messages" in overlays:
        data["messages"] = {
            "window_s": r.window_s,
            "t": _rounded(r._msg_t, 5),
            "sender": r._msg_sender.tolist(),
        }
    if "edges" in overlays:
        keys, lists, last = [], [], None
        for t in edge_times_s:
            pos, present = r.positions(t), r.present(t)
            state = (pos.tobytes(), present.tobytes())
            if state == last:
                continue
            last = state
            pairs = r.edges(pos, present).ravel().tolist()
            if lists and pairs == lists[-1]:
                continue
            keys.append(round(float(t), 5))
            lists.append(pairs)
        data["edges"] = {"t": keys, "pairs": lists}
    steps = r.steps
    if steps is not None and ({"estimates", "frames"} & overlays):
        # Step k holds from t[k] on; end-of-run values hold from the start.
        times = [round(float(t), 5) if np.isfinite(t) else -1.0 for t in steps.t_s]
        if "estimates" in overlays:
            data["estimates"] = {
                "t": times,
                "x": [_nullable(xy[:, 0]) for xy in steps.xy_mm],
                "y": [_nullable(xy[:, 1]) for xy in steps.xy_mm],
                "note": [steps.note(k) for k in range(len(times))],
                "before": steps.note(-1),
            }
        if "frames" in overlays:
            data["frames"] = {
                "t": times,
                "rank": steps.frame.tolist(),
                "label": "frames" if steps.held else "final frames",
                "colours": [_css(c) for c in _FRAME_COLOURS],
            }
    data["led_key"] = [
        [_css(tuple(int(v) for v in level_to_rgb(np.array([levels]))[0])), meaning]
        for levels, meaning in r.led_key
    ]
    return data


def _nullable(values: np.ndarray) -> list[float | None]:
    """Values rounded to 0.01 (mm), ``None`` for NaN (JSON has no NaN)."""
    return [round(float(v), 2) if np.isfinite(v) else None for v in values]


def _rounded(values: np.ndarray, decimals: int) -> list[float]:
    return np.round(np.asarray(values, dtype=float), decimals).tolist()


def _offsets(sorted_robots: np.ndarray, n: int) -> list[int]:
    """CSR row offsets: events of robot k are ``[start[k], start[k + 1])``."""
    return np.searchsorted(sorted_robots, np.arange(n + 1), side="left").tolist()


def render_html(data: dict[str, Any], out_file: Path) -> None:
    """Write the self-contained HTML replay of :func:`replay_data`'s ``data``."""
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False)
    payload = payload.replace("</", "<\\/")  # keep "</script>" inside the data from closing it
    palette = {
        "table": _css(_TABLE),
        "rim": _css(_RIM),
        "crashed": _css(_CRASHED),
        "sender": _css(_SENDER),
        "edge": _css(_EDGE),
        "path": _css(_PATH),
        "estimate": _css(_ESTIMATE),
    }
    template = resources.files("presentation").joinpath("replay.html").read_text("utf-8")
    page = template.replace("__TITLE__", _escape(data.get("title") or "kilonet run"))
    page = page.replace("__COLOURS__", json.dumps(palette)).replace("__DATA__", payload)
    with _atomic(out_file) as tmp:
        tmp.write_text(page, encoding="utf-8")


def _css(colour: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*colour)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


# ---------------------------------------------------------------------------- entry point


def _choose_overlays(run: RunData, replay: Replay, overlays: Iterable[str] | None) -> set[str]:
    """The overlays to draw: those asked for (each checked against the run's data), or by
    default every one whose data the run has except ``edges``."""
    if overlays is None:
        chosen = {"paths"} if len(replay.moving) else set()
        if run.messages_traced and len(run.messages):
            chosen.add("messages")
        if replay.has_estimates:
            chosen.add("estimates")
        if replay.has_frames:
            chosen.add("frames")
        return chosen
    chosen = set(overlays) - {"none"}
    unknown = sorted(chosen - set(OVERLAYS))
    if unknown:
        raise AnimationError(
            f"unknown overlay {unknown[0]!r}; choose from {', '.join(OVERLAYS)} (or none)"
        )
    where = run.path
    if "messages" in chosen and not run.messages_traced:
        raise AnimationError(
            f"{where}: overlay 'messages' needs a run recorded with --set trace.messages=true"
        )
    if "estimates" in chosen and not replay.has_estimates:
        raise AnimationError(
            f"{where}: overlay 'estimates' needs an estimates table, or est_x_mm and est_y_mm "
            "in the robots table"
        )
    if "frames" in chosen and not replay.has_frames:
        raise AnimationError(
            f"{where}: overlay 'frames' needs an estimates table, or a frame column in the "
            "robots table"
        )
    return chosen


def animate_run(
    out_dir: str | Path,
    out_file: str | Path | None = None,
    *,
    fps: float = 10.0,
    speed: float | None = None,
    start_s: float = 0.0,
    end_s: float | None = None,
    overlays: Iterable[str] | None = None,
    window_s: float | None = None,
    width_px: int = 640,
    align_estimates: bool = True,
) -> Path:
    """Animate the run directory ``out_dir``; returns the file written.

    Parameters
    ----------
    out_dir : path
        A run directory written by ``scenarios.write_outputs`` (``kilonet run --out DIR``).
    out_file : path, optional
        ``.gif``, ``.mp4`` or ``.html``; default ``out_dir/animation.gif``. Written atomically
        (a failure leaves nothing behind); missing parent directories are created.
    fps : float
        Video frames per second (GIF delays are whole hundredths of a second, so 10, 20, 25 or
        50 play exactly).
    speed : float, optional
        Simulated seconds per video second; default: the whole run in at most 20 s
        (``max(1, duration / 20)``). The HTML player starts at this speed.
    start_s, end_s : float
        Simulated interval to show (s); default the whole run.
    overlays : iterable of str, optional
        Names from :data:`OVERLAYS` (``"none"`` for none); default: every overlay whose data
        the run has, except ``edges``.
    window_s : float, optional
        The ``messages`` overlay highlights senders of the last ``window_s`` seconds; default
        one frame interval, at most one transmit period (``robot.tx_period_s``).
    width_px : int
        Frame width in pixels (the height follows the swarm's shape).
    align_estimates : bool
        Align each frame's estimates onto the truth before drawing them (see :class:`Replay`);
        ``False`` draws them as recorded.

    Raises
    ------
    AnimationError
        For an unusable run directory, an unknown suffix or overlay, an overlay whose data the
        run lacks, a bad number, more than :data:`MAX_FRAMES` frames, or MP4 without ffmpeg.
    """
    out_dir = Path(out_dir)
    target = Path(out_file) if out_file is not None else out_dir / "animation.gif"
    suffix = target.suffix.lower()
    if suffix not in FORMATS:
        raise AnimationError(f"{target}: unknown animation format; use {', '.join(FORMATS)}")
    if suffix == ".mp4" and not FFMpegWriter.isAvailable():
        raise AnimationError(
            f"{target}: writing MP4 needs ffmpeg on the PATH, which was not found; "
            "write a .gif or .html instead"
        )
    _check_positive("--fps", fps)
    if speed is not None:
        _check_positive("--speed", speed)
    if window_s is not None:
        _check_positive("--window", window_s)
    if not 64 <= width_px <= 4096:
        raise AnimationError(f"--size must be between 64 and 4096 pixels, not {width_px}")
    run = load_run(out_dir)
    duration = run.duration_s
    end = duration if end_s is None else end_s
    if not (math.isfinite(start_s) and math.isfinite(end)) or not 0 <= start_s <= end:
        raise AnimationError(
            f"--start/--end must satisfy 0 <= start <= end, got start {start_s:g} s, "
            f"end {end:g} s (the run lasted {duration:g} s)"
        )
    speed = speed if speed is not None else max(1.0, (end - start_s) / 20.0)
    frame_s = speed / fps
    tx_period = float(run.params.get("robot.tx_period_s", 0.2))
    window = window_s if window_s is not None else min(frame_s, tx_period)
    replay = Replay(run, window_s=window, align_estimates=align_estimates)
    chosen = _choose_overlays(run, replay, overlays)
    times = frame_times(start_s, end, fps, speed)
    if len(times) > MAX_FRAMES:
        raise AnimationError(
            f"{len(times)} frames ({end - start_s:g} s at speed {speed:g}, {fps:g} fps) is more "
            f"than {MAX_FRAMES}; raise --speed or lower --fps"
        )
    title = str(run.summary.get("scenario", ""))
    if suffix == ".html":
        data = replay_data(replay, chosen, title=title, edge_times_s=times, speed=speed)
        data["start_s"], data["duration_s"] = float(start_s), float(end)
        render_html(data, target)
    else:
        render_video(
            replay, target, times, fps=fps, overlays=chosen, width_px=width_px, title=title
        )
    return target


def _check_positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise AnimationError(f"{name} must be a positive number, not {value!r}")
