"""Rendering a replay into frames with matplotlib, and writing them as GIF or MP4
(:func:`render_video`)."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.animation import FFMpegWriter, PillowWriter
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import EllipseCollection, LineCollection
from matplotlib.figure import Figure
from PIL import Image

from kilonet.viz.run_data import (
    BOX_RGB,
    CRASHED_RGB,
    EDGE_RGB,
    ESTIMATE_RGB,
    FRAME_COLOURS,
    FRAME_RGBA,
    PATH_RGB,
    RIM_RGB,
    SCALE_BARS_MM,
    SENDER_RGB,
    TABLE_RGB,
    TEXT_RGB,
    AnimationError,
    Replay,
    atomic_output,
    level_to_rgb,
)

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
        self.fig.patch.set_facecolor(_rgb(TABLE_RGB))
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
            self._edges = LineCollection([], colors=[_rgb(EDGE_RGB)], linewidths=0.8, zorder=1)
            ax.add_collection(self._edges)
        if "paths" in self.overlays and len(replay.moving):
            self._paths = LineCollection([], colors=[_rgb(PATH_RGB)], linewidths=1.5, zorder=1.2)
            ax.add_collection(self._paths)
        if self._frames_shown:
            self._halos = self._discs(d + 6, start, np.zeros((n, 4)), 1.4)
            self._halos.set_linewidths(0)
        if self._estimates_shown:
            self._errors = LineCollection(
                [], colors=[_rgb(ESTIMATE_RGB)], linewidths=1.2, zorder=1.6
            )
            ax.add_collection(self._errors)
            self._marks = ax.scatter(
                [], [], marker="x", s=30, c=[_rgb(ESTIMATE_RGB)], linewidths=1.5, zorder=3
            )
        self._bodies = self._discs(d, start, np.zeros((n, 4)), zorder=2)
        self._bodies.set_linewidths(0.8)
        # Marks go around a body, not on it: a rim in any one colour vanishes on some LED.
        self._crashed = self._rings(d + 7, CRASHED_RGB)
        self._senders = self._rings(d + 7, SENDER_RGB) if "messages" in self.overlays else None
        self._text = ax.text(
            0.01,
            0.99,
            "",
            transform=ax.transAxes,
            va="top",
            ha="left",
            family="monospace",
            fontsize=9,
            color=_rgb(TEXT_RGB),
            zorder=5,
            bbox={
                "facecolor": _rgb(BOX_RGB),
                "edgecolor": _rgb(RIM_RGB),
                "boxstyle": "square,pad=0.3",
            },
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
                color=_rgb(TEXT_RGB),
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
                edgecolor=_rgb(RIM_RGB),
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
        fits = [v for v in SCALE_BARS_MM if v <= 150 * mm_per_px]
        length = fits[-1] if fits else SCALE_BARS_MM[0]
        x1, y = right - 12 * mm_per_px, bottom + 12 * mm_per_px
        ax.plot([x1 - length, x1], [y, y], color=_rgb(TEXT_RGB), linewidth=2, zorder=4)
        ax.text(
            x1 - length / 2,
            y + 4 * mm_per_px,
            f"{length:g} mm",
            ha="center",
            va="bottom",
            fontsize=8,
            color=_rgb(TEXT_RGB),
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
        edge = np.tile(_rgb(RIM_RGB), (r.n, 1))
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
            colours[member] = FRAME_RGBA[frame[member] % len(FRAME_COLOURS)]
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
    fixed = [
        TABLE_RGB,
        RIM_RGB,
        CRASHED_RGB,
        SENDER_RGB,
        EDGE_RGB,
        PATH_RGB,
        ESTIMATE_RGB,
        TEXT_RGB,
        BOX_RGB,
    ]
    fixed += list(FRAME_COLOURS)
    greys = [(v, v, v) for v in range(0, 256, 12)]
    blend = [tuple((np.array(c) + np.array(RIM_RGB)) // 2) for c in led]
    soft = [tuple((np.array(c) + np.array(TABLE_RGB)) // 2) for c in fixed[1:]]
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
    with atomic_output(out_file) as tmp, writer.saving(renderer.fig, str(tmp), FrameRenderer.DPI):
        for t in times_s:
            renderer.draw(float(t))
            writer.grab_frame()
    return renderer
