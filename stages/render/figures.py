"""Figures of occupancy frames, composed of the views of :mod:`carlaocc.stages.render.occupancy`.

:func:`occupancy_figure`: one frame at a glance, a title strip over the BEV, the 3D view and a
legend of the classes present. :func:`multi_voxel_size_figure`: one column per voxel size, the
3D view and the BEV of the same metric window around the ego, the BEV nearest-neighbour sampled
to a common pixel size so coarse voxels show as bigger blocks. Inputs as in
:mod:`carlaocc.stages.render.occupancy` (``[x, y, z]`` grids, LiDAR frame, metres); outputs ``(H, W, 3)``
uint8 RGB, deterministic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import CLASSES, palette
from carlaocc.stages.render.colours import check_mode
from carlaocc.stages.render.occupancy import (DEFAULT_MAX_VOXELS, FREE_RGB, bev_colours, bev_image, block_top,
                                             classes_present, crop_indices, draw_ego, grid_arrays, top_surface,
                                             voxel_view)  # fmt: skip
from carlaocc.stages.render.sheets import FONT_HEIGHT, FONT_WIDTH, draw_text, text_width

__all__ = ["multi_voxel_size_figure", "occupancy_figure"]

_FIG_BG = (255, 255, 255)
_STRIP_BG = (236, 236, 236)
_TEXT = (20, 20, 20)


def _top_range(ktop_list, grids) -> tuple[float, float] | None:
    """Metric (lowest, highest) top-voxel centre over several top maps (``None`` when all free)."""
    lo, hi = math.inf, -math.inf
    for ktop, grid in zip(ktop_list, grids, strict=True):
        occ = ktop >= 0
        if occ.any():
            ks = ktop[occ]
            lo = min(lo, grid.origin[2] + (int(ks.min()) + 0.5) * grid.voxel_size)
            hi = max(hi, grid.origin[2] + (int(ks.max()) + 0.5) * grid.voxel_size)
    return None if lo > hi else (lo, hi)


def _bev_window(ktop, stop, itop, grid: GridSpec, i0: int, j0: int, window, shape, mode, z_range, relief, free_color):
    """BEV of the metric ``window`` ((xmin, xmax), (ymin, ymax)) sampled nearest-neighbour to
    ``shape`` (rows, cols) pixels from top maps of a crop starting at voxel (i0, j0)."""
    (xmin, xmax), (ymin, ymax) = window
    rows, cols = shape
    colours = bev_colours(ktop, stop, itop, grid.origin[2], grid.voxel_size, mode, z_range, relief, free_color)
    x = xmax - (np.arange(rows) + 0.5) * (xmax - xmin) / rows
    y = ymax - (np.arange(cols) + 0.5) * (ymax - ymin) / cols
    i = np.floor((x - grid.origin[0]) / grid.voxel_size).astype(np.int64) - i0
    j = np.floor((y - grid.origin[1]) / grid.voxel_size).astype(np.int64) - j0
    vi = (i >= 0) & (i < ktop.shape[0])
    vj = (j >= 0) & (j < ktop.shape[1])
    out = np.empty((rows, cols, 3), np.float32)
    out[:] = np.asarray(free_color, np.float32)
    sub = colours[np.clip(i, 0, max(ktop.shape[0] - 1, 0))][:, np.clip(j, 0, max(ktop.shape[1] - 1, 0))]
    keep = vi[:, None] & vj[None, :]
    out[keep] = sub[keep]
    return np.ascontiguousarray(np.clip(np.round(out), 0, 255).astype(np.uint8))


def _resize_nearest(img: np.ndarray, rows: int, cols: int) -> np.ndarray:
    r = (np.arange(rows) * img.shape[0]) // rows
    c = (np.arange(cols) * img.shape[1]) // cols
    return np.ascontiguousarray(img[r][:, c])


def _place(canvas: np.ndarray, img: np.ndarray, y: int, x: int) -> None:
    canvas[y : y + img.shape[0], x : x + img.shape[1]] = img


def _fit_text(text: str, width: int, scale: int) -> str:
    max_chars = max(1, (width + scale) // ((FONT_WIDTH + 1) * scale))
    return text if len(text) <= max_chars else text[: max(0, max_chars - 2)] + ".."[:max_chars]


def _strip(width: int, text: str, scale: int, centre: bool = True) -> np.ndarray:
    h = (FONT_HEIGHT + 4) * scale
    strip = np.empty((h, width, 3), np.uint8)
    strip[:] = _STRIP_BG
    text = _fit_text(text, width - 4 * scale, scale)
    x = (width - text_width(text, scale)) // 2 if centre else 2 * scale
    draw_text(strip, text, x, 2 * scale, _TEXT, scale)
    return strip


def _legend(class_ids: Sequence[int], mode: str, height: int, scale: int, things: set[int]) -> np.ndarray:
    """Legend panel: a colour swatch and the name of every class, in columns of at most
    ``height`` pixels; ``things`` (the classes with instance ids in the frame, whichever label
    table built it) are starred in instance mode (one colour per instance)."""
    row_h = (FONT_HEIGHT + 4) * scale
    names = [CLASSES[c].name + (" *" if mode == "instance" and c in things else "") for c in class_ids]
    notes = ["* colour per instance"] if mode == "instance" and any(c in things for c in class_ids) else []
    if mode == "height":
        names, notes = ["(colour = height)"], []
    lines = len(names) + len(notes)
    per_col = max(1, (height - 2 * scale) // row_h)
    ncols = max(1, -(-lines // per_col))
    sw = FONT_HEIGHT * scale
    col_w = sw + 3 * scale + max([text_width(n, scale) for n in names + notes] + [1]) + 4 * scale
    panel = np.empty((max(height, row_h), ncols * col_w, 3), np.uint8)
    panel[:] = _FIG_BG
    for n, name in enumerate(names + notes):
        c, r = divmod(n, per_col)
        x, y = c * col_w + scale, scale + r * row_h
        if n < len(names) and mode != "height":
            panel[y : y + sw, x : x + sw] = np.asarray(palette()[class_ids[n]], np.uint8)
            panel[y : y + sw, x : x + sw][[0, -1]] = _TEXT
            panel[y : y + sw, x : x + sw][:, [0, -1]] = _TEXT
            draw_text(panel, name, x + sw + 3 * scale, y, _TEXT, scale)
        else:
            draw_text(panel, name, x, y, _TEXT, scale)
    return panel


def occupancy_figure(
    semantic,
    instance,
    grid: GridSpec,
    title: str,
    *,
    height: int = 540,
    mode: str = "instance",
    elevation_deg: float = 35.0,
    azimuth_deg: float = 180.0,
    max_voxels: int = DEFAULT_MAX_VOXELS,
) -> np.ndarray:
    """One frame at a glance: a title strip over [BEV | 3D view | legend of the classes present],
    the panels ``height`` pixels high with a caption strip under the BEV and the 3D view (the 3D
    caption names the pooling, if any). The BEV (:func:`bev_height_map`, ego marked) is block-
    downsampled to at least ``height`` rows and nearest-resized to exactly ``height``; the 3D view
    (:func:`perspective_view`) is ``height`` x ``16/9 height``."""
    check_mode(mode)
    H = int(height)
    if H < 32:
        raise ValueError(f"height must be >= 32 pixels, got {height}")
    sem, inst, has = grid_arrays(semantic, instance, grid)
    inst_arg = inst if has else None
    scale = 1 if H < 400 else 2
    X = sem.shape[0]
    # BEV: block top-most downsample to >= H rows, then nearest-resize to H rows
    f = max(1, X // H)
    ktop, stop, itop = top_surface(sem, inst_arg)
    if f > 1:
        ktop, stop, itop = block_top(ktop, stop, itop, f)
    cell = grid.voxel_size * f
    bev = bev_image(bev_colours(ktop, stop, itop, grid.origin[2], grid.voxel_size, mode, None, True, FREE_RGB))
    draw_ego(bev, grid.origin[0] + ktop.shape[0] * cell, grid.origin[1] + ktop.shape[1] * cell, cell)
    bw = max(1, int(round(bev.shape[1] * H / bev.shape[0])))
    bev = _resize_nearest(bev, H, bw)
    view, pool = voxel_view(sem, inst, has, grid.origin, grid.voxel_size, (H, int(round(H * 16 / 9))),
                            elevation_deg, azimuth_deg, mode, 40.0, None, max_voxels, _FIG_BG, 2, 0.03,
                            True)  # fmt: skip
    present = [int(c) for c in classes_present(sem) if c < len(CLASSES)]
    # the classes carrying instance ids in this frame (the dataset's label table decided which)
    things = {int(c) for c in np.unique(sem[inst > 0])} if has else set()
    legend = _legend(present, mode, H, scale, things)
    gap = 6 * scale
    voxel_size_label = f"{grid.voxel_size:g} m"
    cap_bev = _strip(bev.shape[1], f"BEV {voxel_size_label}, up = forward", scale)
    pooled = f", pooled x{pool} ({grid.voxel_size * pool:g} m)" if pool > 1 else ""
    cap_3d = _strip(view.shape[1], f"3D {voxel_size_label}{pooled}", scale)
    width = bev.shape[1] + view.shape[1] + legend.shape[1] + 2 * gap
    title_strip = _strip(width, str(title), scale + 1, centre=False)
    cap_h = cap_bev.shape[0]
    fig = np.empty((title_strip.shape[0] + gap + max(H, legend.shape[0]) + cap_h, width, 3), np.uint8)
    fig[:] = _FIG_BG
    _place(fig, title_strip, 0, 0)
    y = title_strip.shape[0] + gap
    _place(fig, bev, y, 0)
    _place(fig, cap_bev, y + H, 0)
    _place(fig, view, y, bev.shape[1] + gap)
    _place(fig, cap_3d, y + H, bev.shape[1] + gap)
    _place(fig, legend, y, bev.shape[1] + view.shape[1] + 2 * gap)
    return fig


def multi_voxel_size_figure(
    frames: Sequence[tuple[str, np.ndarray, np.ndarray | None, GridSpec]],
    *,
    window=((-5.0, 15.0), (-10.0, 10.0)),
    cell_size: int = 360,
    mode: str = "instance",
    elevation_deg: float = 35.0,
    azimuth_deg: float = 180.0,
    max_voxels: int = DEFAULT_MAX_VOXELS,
    title: str | None = None,
) -> np.ndarray:
    """The multi-voxel-size figure: one column per ``(label, semantic, instance, grid)`` frame
    (typically the same scene at 0.05 / 0.1 / 0.2 / 0.4 m), the label on top, then the 3D view of
    the metric ``window`` ((xmin, xmax), (ymin, ymax), all heights) and the BEV of the same window
    with the ego marked, ``cell_size`` pixels per window x extent, nearest-neighbour sampled so
    coarser voxels show as bigger blocks. Every column uses the same camera (framing the window
    over the common occupied height range) and the same BEV height normalisation; an optional
    ``title`` strip goes on top."""
    check_mode(mode)
    if not frames:
        raise ValueError("multi_voxel_size_figure needs at least one frame")
    (xmin, xmax), (ymin, ymax) = window
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"empty window {window!r}")
    rows = int(cell_size)
    cols = max(1, int(round(rows * (ymax - ymin) / (xmax - xmin))))
    view_h = max(1, int(round(cols * 0.75)))
    scale = 1 if cols < 300 else 2
    crops = []
    for label, semantic, instance, grid in frames:
        sem, inst, has = grid_arrays(semantic, instance, grid)
        sx, sy, _ = crop_indices(grid.origin, grid.voxel_size, grid.shape, window, centres=False)
        csem = np.ascontiguousarray(sem[sx, sy, :])
        cinst = np.ascontiguousarray(inst[sx, sy, :]) if has else None
        tops = top_surface(csem, cinst)
        occ_z = np.flatnonzero(csem.any(axis=(0, 1))) if csem.size else np.empty(0, np.int64)
        zr = None
        if occ_z.size:
            zr = (grid.origin[2] + occ_z[0] * grid.voxel_size, grid.origin[2] + (occ_z[-1] + 1) * grid.voxel_size)
        crops.append((str(label), csem, cinst, grid, sx.start, sy.start, tops, zr))
    z_range = _top_range([c[6][0] for c in crops], [c[3] for c in crops])
    zs = [c[7] for c in crops if c[7] is not None]
    zbox = (min(z[0] for z in zs), max(z[1] for z in zs)) if zs else None
    gap = 8
    label_h = (FONT_HEIGHT + 4) * (scale + 1)
    col_h = label_h + view_h + gap + rows
    fig_w = len(crops) * cols + (len(crops) - 1) * gap
    title_strip = _strip(fig_w, title, scale + 1, centre=False) if title else np.empty((0, fig_w, 3), np.uint8)
    top = title_strip.shape[0] + (gap if title else 0)
    fig = np.empty((top + col_h, fig_w, 3), np.uint8)
    fig[:] = _FIG_BG
    _place(fig, title_strip, 0, 0)
    for n, (label, csem, cinst, grid, i0, j0, (ktop, stop, itop), _) in enumerate(crops):
        x0 = n * (cols + gap)
        _place(fig, _strip(cols, label, scale + 1), top, x0)
        if zbox is not None and csem.size:
            corner = (grid.origin[0] + i0 * grid.voxel_size, grid.origin[1] + j0 * grid.voxel_size, grid.origin[2])
            view, _ = voxel_view(csem, cinst if cinst is not None else np.zeros((1, 1, 1), np.uint32),
                                 cinst is not None, corner, grid.voxel_size, (view_h, cols), elevation_deg,
                                 azimuth_deg, mode, 40.0, (window[0], window[1], zbox), max_voxels, _FIG_BG, 2,
                                 0.03, True)  # fmt: skip
            _place(fig, view, top + label_h, x0)
        bev = _bev_window(ktop, stop, itop, grid, i0, j0, window, (rows, cols), mode, z_range, True, FREE_RGB)
        draw_ego(bev, xmax, ymax, (xmax - xmin) / rows)
        _place(fig, bev, top + label_h + view_h + gap, x0)
    return fig
