"""Animations of a finished run: GIF, MP4 and a self-contained HTML replay.

A run directory (``kilonet.scenarios.write_outputs``) records what happened as events: LED changes,
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

import math
from collections.abc import Iterable
from pathlib import Path

from matplotlib.animation import FFMpegWriter

from kilonet.viz.replay import render_html, replay_data
from kilonet.viz.run_data import (
    FORMATS,
    MAX_FRAMES,
    OVERLAYS,
    AnimationError,
    Replay,
    RunData,
    aligned_estimates,
    frame_count,
    frame_times,
    level_to_rgb,
    load_run,
)
from kilonet.viz.video import FrameRenderer, render_video

__all__ = [
    "FORMATS",
    "GIF_FPS",
    "MAX_FRAMES",
    "OVERLAYS",
    "AnimationError",
    "FrameRenderer",
    "Replay",
    "RunData",
    "aligned_estimates",
    "animate_run",
    "frame_count",
    "frame_times",
    "level_to_rgb",
    "load_run",
    "render_html",
    "render_video",
    "replay_data",
]


#: The frame rates a GIF can hold (frames per second): a frame's delay is a whole number of
#: hundredths of a second in 16 bits, 0.01 s to 655.35 s.
GIF_FPS = (1 / 655.35, 100.0)

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
        A run directory written by ``kilonet.scenarios.write_outputs`` (``kilonet run --out DIR``).
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
        run lacks, a bad number, a frame rate a GIF cannot hold (:data:`GIF_FPS`), more than
        :data:`MAX_FRAMES` frames, or MP4 without ffmpeg.
    OSError
        If the file cannot be written (a read-only or full disk); nothing is left behind.
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
    if suffix == ".gif" and not GIF_FPS[0] <= fps <= GIF_FPS[1]:
        raise AnimationError(
            f"--fps {fps:g}: a GIF plays {GIF_FPS[0]:.4f} to {GIF_FPS[1]:g} frames per second "
            "(a frame lasts 0.01 s to 655.35 s); write a .mp4 or .html for another rate"
        )
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
    frames = frame_count(start_s, end, fps, speed)  # before anything is drawn or allocated
    if frames > MAX_FRAMES:
        raise AnimationError(
            f"{frames:,} frames ({end - start_s:g} s at speed {speed:g}, {fps:g} fps) is more "
            f"than {MAX_FRAMES:,}; raise --speed or lower --fps"
        )
    frame_s = speed / fps
    tx_period = float(run.params.get("robot.tx_period_s", 0.2))
    window = window_s if window_s is not None else min(frame_s, tx_period)
    replay = Replay(run, window_s=window, align_estimates=align_estimates)
    chosen = _choose_overlays(run, replay, overlays)
    times = frame_times(start_s, end, fps, speed)
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
