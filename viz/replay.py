"""The self-contained HTML replay: the run's data as JSON (:func:`replay_data`) inside the
player page ``viz/replay.html`` (package data), written by :func:`render_html`."""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from kilonet.viz.run_data import (
    CRASHED_RGB,
    EDGE_RGB,
    ESTIMATE_RGB,
    FRAME_COLOURS,
    PATH_RGB,
    RIM_RGB,
    SCALE_BARS_MM,
    SENDER_RGB,
    TABLE_RGB,
    Replay,
    atomic_output,
    level_to_rgb,
)

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
    data: dict[str, Any] = {
        "title": title,
        "start_s": 0.0,
        "duration_s": float(r.run.duration_s),
        "speed": speed,
        "radius_mm": r.radius_mm,
        "extent_mm": list(r.extent_mm()),
        "x0": _rounded(r.start_mm[:, 0], 2),
        "y0": _rounded(r.start_mm[:, 1], 2),
        "led": _led_changes(r),
        "tracks": _track_rows(r),
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
        data["edges"] = _edge_changes(r, edge_times_s)
    if r.steps is not None:
        data.update(_estimate_steps(r.steps, overlays))
    data["led_key"] = [
        [_css(tuple(int(v) for v in level_to_rgb(np.array([levels]))[0])), meaning]
        for levels, meaning in r.led_key
    ]
    data["scale_bars_mm"] = list(SCALE_BARS_MM)  # the player picks the longest that fits
    return data


def _led_changes(r: Replay) -> dict[str, list]:
    """Every robot's LED changes, robot by robot (``start``: each robot's first row), colour
    codes ``16 r + 4 g + b`` of kilolib levels."""
    order = np.lexsort((r._led_t, r._led_robot))
    level = r._led_level[order]
    codes = level[:, 0] * 16 + level[:, 1] * 4 + level[:, 2]
    return {
        "start": _offsets(r._led_robot[order], r.n),
        "t": _rounded(r._led_t[order], 5),
        "c": codes.tolist(),
    }


def _track_rows(r: Replay) -> dict[str, list]:
    """The tracks of the robots that move, one after another (``start``: each one's first
    row)."""
    robots = [int(k) for k in r.moving]

    def joined(column: int) -> np.ndarray:
        return np.concatenate([r.tracks[k][column] for k in robots]) if robots else np.empty(0)

    lengths = [len(r.tracks[k][0]) for k in robots]
    return {
        "robot": robots,
        "start": np.concatenate([[0], np.cumsum(lengths)]).astype(int).tolist(),
        "t": _rounded(joined(0), 4),
        "x": _rounded(joined(1), 2),
        "y": _rounded(joined(2), 2),
    }


def _edge_changes(r: Replay, edge_times_s: Iterable[float]) -> dict[str, list]:
    """The communication graph at each of ``edge_times_s`` where it changed."""
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
    return {"t": keys, "pairs": lists}


def _estimate_steps(steps: Any, overlays: frozenset[str]) -> dict[str, Any]:
    """The ``estimates`` and ``frames`` entries the overlays ask for, from the held estimates
    (:class:`~kilonet.viz.run_data.EstimateSteps`)."""
    # Step k holds from t[k] on; end-of-run values hold from the start.
    times = [round(float(t), 5) if np.isfinite(t) else -1.0 for t in steps.t_s]
    found: dict[str, Any] = {}
    if "estimates" in overlays:
        found["estimates"] = {
            "t": times,
            "x": [_nullable(xy[:, 0]) for xy in steps.xy_mm],
            "y": [_nullable(xy[:, 1]) for xy in steps.xy_mm],
            "note": [steps.note(k) for k in range(len(times))],
            "before": steps.note(-1),
        }
    if "frames" in overlays:
        found["frames"] = {
            "t": times,
            "rank": steps.frame.tolist(),
            "label": "frames" if steps.held else "final frames",
            "colours": [_css(c) for c in FRAME_COLOURS],
        }
    return found


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
        "table": _css(TABLE_RGB),
        "rim": _css(RIM_RGB),
        "crashed": _css(CRASHED_RGB),
        "sender": _css(SENDER_RGB),
        "edge": _css(EDGE_RGB),
        "path": _css(PATH_RGB),
        "estimate": _css(ESTIMATE_RGB),
    }
    template = resources.files("kilonet.viz").joinpath("replay.html").read_text("utf-8")
    page = template.replace("__TITLE__", _escape(data.get("title") or "kilonet run"))
    page = page.replace("__COLOURS__", json.dumps(palette)).replace("__DATA__", payload)
    with atomic_output(out_file) as tmp:
        tmp.write_text(page, encoding="utf-8")


def _css(colour: tuple[int, int, int]) -> str:
    return "#{:02x}{:02x}{:02x}".format(*colour)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
