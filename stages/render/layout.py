"""Sheets of labelled pictures: panels placed pixel for pixel, titled and explained with
matplotlib's text (its bundled DejaVu Sans, not a bitmap font), each row ending in a legend or a
colour scale.

A :class:`Panel` is an RGB image with a title and, optionally, metric axes (``extent`` in metres,
tick labels and axis names drawn around it). A row of panels shares a :class:`Key`: the legend
entries (:class:`LegendEntry`: a swatch of one colour, a swatch of several colours for things
drawn one colour per instance, a marker, or a line of text) and/or a :class:`ColourScale` (a ramp
with labelled ticks: depth in metres, height in metres). :func:`compose` draws a sheet and returns
a :class:`Sheet`: the ``(H, W, 3)`` uint8 image, each panel's title and the pixel box its image
landed in, and each row's key, so a caller (or a test) can see what the picture says.

Images are drawn at their own size (one image pixel = one sheet pixel: pasted into the drawn
sheet inside their axes, no resampling), so the colours inside a panel are the input's. Figures use :class:`matplotlib.figure.Figure` and the
Agg canvas (no ``pyplot``, no global state, no display); the same inputs give the same pixels with
the same matplotlib.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.textpath import TextToPath
from matplotlib.patches import Polygon, Rectangle

__all__ = ["ColourScale", "Key", "LegendEntry", "Panel", "Sheet", "compose"]

DPI = 100
FONT_PT = 9.0  # legend and tick text
TITLE_PT = 10.0  # panel titles
SHEET_TITLE_PT = 13.0
_ROW_PX = 17  # a legend line, pixels
_TITLE_PX = 22  # the strip above a panel holding its title
_AXES_LEFT_PX, _AXES_BOTTOM_PX = 58, 40  # room for tick labels and axis names of a metric panel
_GAP_PX = 10
_TEXT = "#141414"
_FRAME_RGB = (20, 20, 20)
_SCALE_PX = 120  # a colour scale: its bar, tick labels and name
_TEXT_TO_PATH = TextToPath()


@dataclass(frozen=True)
class LegendEntry:
    """One line of a key: ``kind`` ``"swatch"`` (``colours[0]``), ``"instances"`` (a swatch split
    into ``colours``: one colour per instance), ``"marker"`` (the ego's arrow-head, in
    ``colours[0]`` with a dark edge) or ``"text"`` (no swatch). Colours are RGB 0..255."""

    label: str
    colours: tuple[tuple[int, int, int], ...] = ()
    kind: str = "swatch"

    def __post_init__(self):
        if self.kind not in ("swatch", "instances", "marker", "text"):
            raise ValueError(f"unknown legend entry kind {self.kind!r}")
        if self.kind != "text" and not self.colours:
            raise ValueError(f"legend entry {self.label!r} ({self.kind}) needs a colour")


@dataclass(frozen=True)
class ColourScale:
    """A colour ramp and what it measures: ``colours`` (N, 3) RGB 0..255 sampled evenly along
    the ramp's position 0..1 (bottom to top), ``ticks`` ``(position, label)`` pairs, ``label`` the
    quantity and unit (e.g. ``"depth, m"``)."""

    label: str
    colours: np.ndarray
    ticks: tuple[tuple[float, str], ...]


@dataclass(frozen=True)
class Key:
    """What a row's colours mean: a heading, legend entries and an optional colour scale."""

    heading: str = ""
    entries: tuple[LegendEntry, ...] = ()
    scale: ColourScale | None = None

    @property
    def labels(self) -> list[str]:
        """The entries' labels, in order."""
        return [e.label for e in self.entries]


@dataclass(frozen=True)
class Panel:
    """An image to place: ``title`` above it; with ``extent`` = (left, right, bottom, top) in
    metres, ticks and the axis names ``xlabel`` / ``ylabel`` around it (the image spans the
    extent, so a right edge smaller than the left edge is an axis growing to the left)."""

    title: str
    image: np.ndarray
    extent: tuple[float, float, float, float] | None = None
    xlabel: str = ""
    ylabel: str = ""


@dataclass(frozen=True)
class Sheet:
    """A composed sheet: the RGB image, the panels' titles, the pixel box ``(row0, row1, col0,
    col1)`` (half-open) of each panel's image in the sheet, and each row's key."""

    image: np.ndarray
    titles: list[str]
    boxes: list[tuple[int, int, int, int]]
    keys: list[Key] = field(default_factory=list)


def _rgb01(c) -> tuple[float, float, float]:
    return tuple(float(v) / 255.0 for v in c)


def _text_px(text: str, points: float, bold: bool = False) -> float:
    """Width in pixels of ``text`` in matplotlib's default font at ``points`` (at :data:`DPI`)."""
    prop = FontProperties(size=points, weight="bold" if bold else "normal")
    width, _, _ = _TEXT_TO_PATH.get_text_width_height_descent(text, prop, ismath=False)
    return width * DPI / 72.0


def _key_layout(key: Key | None, height: int) -> tuple[int, int, int]:
    """(width, height, lines per column) in pixels of a key's area beside a row ``height`` pixels
    high: as many lines a column as the row holds, at least 8 (the row grows to fit)."""
    if key is None or (not key.entries and key.scale is None and not key.heading):
        return 0, 0, 1
    lines = len(key.entries) + (1 if key.heading else 0)
    per_col = max(1, min(lines, 8), (height - 6) // _ROW_PX)
    cols = max(1, -(-lines // per_col))
    widest = max([_text_px(e.label, FONT_PT) + (0 if e.kind == "text" else 26) for e in key.entries]
                 + [_text_px(key.heading, FONT_PT, bold=True), 40.0])
    col_w = int(math.ceil(widest * 1.06)) + 14  # Agg draws a little wider than the path metrics
    width = cols * col_w + (_SCALE_PX if key.scale is not None else 0)
    tall = max(min(per_col, lines) * _ROW_PX + 6, 100 if key.scale is not None else 0)
    return width, tall, per_col


def _draw_key(fig: Figure, key: Key, x: int, y: int, w: int, h: int, per_col: int, W: int, H: int) -> None:
    """Draw ``key`` into the sheet area with top-left pixel (x, y), w x h pixels, ``per_col``
    lines a column."""
    ax = fig.add_axes((x / W, 1 - (y + h) / H, w / W, h / H))
    ax.set_xlim(0, w)
    ax.set_ylim(h, 0)  # pixel coordinates, y down
    ax.axis("off")
    lines: list[LegendEntry | str] = ([key.heading] if key.heading else []) + list(key.entries)
    scale_w = _SCALE_PX if key.scale is not None else 0
    col_w = (w - scale_w) / max(1, -(-len(lines) // per_col)) if lines else 0
    for n, line in enumerate(lines):
        c, r = divmod(n, per_col)
        x0, y0 = c * col_w + 2, 3 + r * _ROW_PX
        if isinstance(line, str):  # the heading
            ax.text(x0, y0 + 7, line, fontsize=FONT_PT, fontweight="bold", va="center", color=_TEXT)
            continue
        sw = 20  # swatch width, pixels
        if line.kind == "swatch":
            ax.add_patch(Rectangle((x0, y0 + 1), sw, 12, facecolor=_rgb01(line.colours[0]), edgecolor=_TEXT, lw=0.6))
        elif line.kind == "instances":
            # one stripe per instance colour: the class has no single colour here
            k = len(line.colours)
            for i, col in enumerate(line.colours):
                ax.add_patch(Rectangle((x0 + i * sw / k, y0 + 1), sw / k, 12, facecolor=_rgb01(col), lw=0))
            ax.add_patch(Rectangle((x0, y0 + 1), sw, 12, fill=False, edgecolor=_TEXT, lw=0.6))
        elif line.kind == "marker":
            # the ego's arrow-head, tip up (forward), as drawn on the top views
            ax.add_patch(Polygon([(x0 + sw / 2, y0), (x0 + sw / 2 - 6, y0 + 14), (x0 + sw / 2 + 6, y0 + 14)],
                                 closed=True, facecolor=_rgb01(line.colours[0]), edgecolor=_TEXT, lw=0.8))
        tx = x0 + (sw + 6 if line.kind != "text" else 0)
        ax.text(tx, y0 + 7, line.label, fontsize=FONT_PT, va="center", color=_TEXT)
    if key.scale is not None:
        s = key.scale
        bar_h = max(40, h - 30)
        sx = w - scale_w + 10
        cax = fig.add_axes(((x + sx) / W, 1 - (y + 8 + bar_h) / H, 16 / W, bar_h / H))
        ramp = np.asarray(s.colours, dtype=np.float64) / 255.0
        cax.imshow(ramp[::-1, None, :], aspect="auto", extent=(0, 1, 0, 1), interpolation="nearest")
        cax.set_xticks([])
        cax.yaxis.tick_right()
        cax.set_yticks([p for p, _ in s.ticks], [t for _, t in s.ticks], fontsize=FONT_PT)
        cax.set_ylabel(s.label, fontsize=FONT_PT)
        cax.yaxis.set_label_position("right")


def compose(rows: Sequence[tuple[Sequence[Panel], Key | None]], title: str | None = None,
            background=(255, 255, 255)) -> Sheet:
    """Draw rows of panels, each row followed by its key, into one sheet.

    Columns are as wide as their widest image, rows as high as their tallest; a column holding
    a metric panel gets room for its tick labels on the left, a row holding one room for the
    x-axis under it. Every image is drawn at one sheet pixel per image pixel, centred in its
    cell. Returns the :class:`Sheet` (its ``titles`` and ``boxes`` in row-major panel order)."""
    if not rows or not any(len(p) for p, _ in rows):
        raise ValueError("compose needs at least one panel")
    ncols = max(len(p) for p, _ in rows)
    images = [[np.ascontiguousarray(np.asarray(p.image)[:, :, :3]) for p in panels] for panels, _ in rows]
    for r in images:
        for im in r:
            if im.ndim != 3 or im.dtype != np.uint8:
                raise ValueError(f"panel images must be (H, W, 3) uint8, got {im.shape} {im.dtype}")
    col_w = [max([im.shape[1] for r in images for c, im in enumerate(r) if c == k] + [0]) for k in range(ncols)]
    col_axes = [any(p.extent is not None for panels, _ in rows for c, p in enumerate(panels) if c == k) for k in range(ncols)]
    row_h = [max(im.shape[0] for im in r) if r else 0 for r in images]
    row_axes = [any(p.extent is not None for p in panels) for panels, _ in rows]
    key_sizes = [_key_layout(key, row_h[n]) for n, (_, key) in enumerate(rows)]
    # a column is at least as wide as its panels' titles
    col_w = [max([w] + [int(_text_px(p.title, TITLE_PT)) + 8 for panels, _ in rows for c, p in enumerate(panels) if c == k])
             for k, w in enumerate(col_w)]
    # horizontal layout: [axes margin] cell gap [axes margin] cell ... key
    col_x, x = [], _GAP_PX
    for k in range(ncols):
        x += _AXES_LEFT_PX if col_axes[k] else 0
        col_x.append(x)
        x += col_w[k] + _GAP_PX
    key_x = x
    W = key_x + max([kw for kw, _, _ in key_sizes] + [0]) + _GAP_PX
    # vertical layout: [sheet title] per row: title strip, cell, [axes margin]
    y = _GAP_PX + (int(SHEET_TITLE_PT * 2.2) if title else 0)
    row_y = []
    for n in range(len(rows)):
        row_y.append(y + _TITLE_PX)
        y += _TITLE_PX + max(row_h[n], key_sizes[n][1]) + (_AXES_BOTTOM_PX if row_axes[n] else 0) + _GAP_PX
    H = y
    fig = Figure(figsize=(W / DPI, H / DPI), dpi=DPI, facecolor=_rgb01(background))
    canvas = FigureCanvasAgg(fig)
    if title:
        fig.text(_GAP_PX / W, 1 - (_GAP_PX + 4) / H, title, fontsize=SHEET_TITLE_PT, fontweight="bold", va="top",
                 color=_TEXT)
    titles, boxes, keys = [], [], []
    for n, (panels, key) in enumerate(rows):
        for k, (panel, im) in enumerate(zip(panels, images[n])):
            h, w = im.shape[:2]
            # the image's pixel box, centred in its cell
            c0 = col_x[k] + (col_w[k] - w) // 2
            r0 = row_y[n] + (row_h[n] - h) // 2
            # the axes carry the title, ticks and names; the image itself is pasted into the
            # drawn sheet afterwards, pixel for pixel (faster and exact, no resampling)
            ax = fig.add_axes((c0 / W, 1 - (r0 + h) / H, w / W, h / H))
            ax.set_facecolor("none")
            for spine in ax.spines.values():
                spine.set_visible(False)
            ax.set_title(panel.title, fontsize=TITLE_PT, color=_TEXT, pad=4)
            if panel.extent is None:
                ax.set_xticks([])
                ax.set_yticks([])
            else:
                left, right, bottom, top = panel.extent
                ax.set_xlim(left, right)
                ax.set_ylim(bottom, top)
                ax.tick_params(labelsize=FONT_PT)
                ax.set_xlabel(panel.xlabel, fontsize=FONT_PT)
                ax.set_ylabel(panel.ylabel, fontsize=FONT_PT)
            titles.append(panel.title)
            boxes.append((r0, r0 + h, c0, c0 + w))
        if key is not None:
            kw, kh, per_col = key_sizes[n]
            if kw:
                _draw_key(fig, key, key_x, row_y[n], kw, max(kh, row_h[n]), per_col, W, H)
            keys.append(key)
    canvas.draw()
    image = np.asarray(canvas.buffer_rgba())[:, :, :3].copy()
    panels = [p for ps, _ in rows for p in ps]
    ims = [im for r in images for im in r]
    for panel, im, (r0, r1, c0, c1) in zip(panels, ims, boxes):
        image[r0:r1, c0:c1] = im
        if panel.extent is not None:  # a one-pixel frame just outside a metric panel
            frame = np.array(_FRAME_RGB, np.uint8)
            image[max(r0 - 1, 0), max(c0 - 1, 0) : c1 + 1] = frame
            image[min(r1, H - 1), max(c0 - 1, 0) : c1 + 1] = frame
            image[max(r0 - 1, 0) : r1 + 1, max(c0 - 1, 0)] = frame
            image[max(r0 - 1, 0) : r1 + 1, min(c1, W - 1)] = frame
    return Sheet(image, titles, boxes, keys)
