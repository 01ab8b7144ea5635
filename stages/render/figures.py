"""Figures of occupancy frames, composed of the views of :mod:`carlaocc.stages.render.occupancy`
and laid out by :func:`carlaocc.stages.render.layout.compose` (matplotlib's text, a key per row).

:func:`occupancy_figure`: one frame at a glance, a title over the top view (axes in metres), the
3D view and the key. :func:`multi_voxel_size_figure`: one column per voxel size, the 3D view over
the top view of the same metric window around the ego, the top view nearest-neighbour sampled to a
common pixel size so coarse voxels show as bigger blocks. Inputs as in
:mod:`carlaocc.stages.render.occupancy` (``[x, y, z]`` grids, LiDAR frame, metres); outputs a
:class:`~carlaocc.stages.render.layout.Sheet` (the ``(H, W, 3)`` uint8 RGB image, the panel titles
and boxes, the keys), deterministic.

Every key states the colouring: in ``instance`` mode a class whose voxels carry instance ids is
listed with the colours of its instances, never with a class colour it is not drawn in
(:func:`class_entries`); the ego marker and free columns have entries; ``height`` mode has a
scale in metres instead of classes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import CLASSES, palette
from carlaocc.schemas.rig import facing
from carlaocc.stages.render.colours import check_mode, height_ramp, instance_colors
from carlaocc.stages.render.layout import ColourScale, Key, LegendEntry, Panel, Sheet, compose
from carlaocc.stages.render.occupancy import (DEFAULT_MAX_VOXELS, FREE_RGB, bev_colours, bev_image, block_top,
                                             classes_present, crop_indices, draw_ego, grid_arrays, top_surface,
                                             voxel_view)  # fmt: skip

__all__ = ["EGO_ENTRY", "FREE_ENTRY", "class_entries", "height_scale", "multi_voxel_size_figure", "occupancy_figure"]

_FIG_BG = (255, 255, 255)


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


_MODE_HEADINGS = {
    "instance": "colour: class; things one colour per instance",
    "semantic": "colour: class (taxonomy palette)",
    "height": "colour: height of the voxel",
}
EGO_ENTRY = LegendEntry("ego (LiDAR origin), tip forward", ((255, 255, 255),), "marker")
FREE_ENTRY = LegendEntry("free column (nothing occupied)", (FREE_RGB,))


def class_entries(semantic: np.ndarray, instance: np.ndarray | None, mode: str) -> list[LegendEntry]:
    """Legend entries of the classes present in a grid (or a map), in class order: a class swatch
    in its palette colour, except, in instance mode, for a class whose voxels carry instance ids
    (things in the dataset's label table): it is drawn one colour per instance, so its entry shows
    the colours of up to four of its instances and says so, claiming no class colour."""
    sem = np.asarray(semantic)
    inst = None if instance is None else np.asarray(instance)
    out = []
    # the (class, id) pairs of the voxels with an instance id, gathered once
    if mode == "instance" and inst is not None:
        things = inst > 0
        t_sem, t_inst = sem[things], inst[things]
    else:
        t_sem, t_inst = np.empty(0, sem.dtype), np.empty(0, np.uint32)
    for c in (int(c) for c in classes_present(sem) if c < len(CLASSES)):
        name = CLASSES[c].name
        ids = np.unique(t_inst[t_sem == c])
        if len(ids):
            cols = tuple(tuple(int(v) for v in col) for col in instance_colors(ids[:4]))
            n = len(ids)
            out.append(LegendEntry(f"{name}: one colour per instance ({n} here)", cols, "instances"))
        else:
            out.append(LegendEntry(name, (tuple(palette()[c]),)))
    return out


def height_scale(z_range, label: str) -> ColourScale:
    """The height ramp over ``z_range`` (lowest, highest) metres as a colour scale, ticks at the
    two ends and at round heights between them."""
    lo, hi = float(z_range[0]), float(z_range[1])
    ramp = np.round(height_ramp(np.linspace(0.0, 1.0, 64))).astype(np.uint8)
    if hi <= lo:
        return ColourScale(label, ramp, ((0.0, f"{lo:.1f}"),))
    # round steps of 1, 2 or 5 x 10^k giving 2 to 6 ticks inside the range
    span = hi - lo
    step = next(m * 10.0**k for k in range(-2, 4) for m in (1, 2, 5) if span / (m * 10.0**k) <= 5)
    first = math.ceil(lo / step) * step
    inner = [first + n * step for n in range(int((hi - first) / step) + 1)]
    ticks = [(0.0, f"{lo:.1f}"), (1.0, f"{hi:.1f}")]
    ticks += [((v - lo) / span, f"{v:g}") for v in inner if 0.08 < (v - lo) / span < 0.92]
    return ColourScale(label, ramp, tuple(sorted(ticks)))


def _occupied_z(sem: np.ndarray, z0: float, voxel_size: float) -> tuple[float, float] | None:
    """(lowest, highest) voxel centre height of the occupied voxels, metres (``None``: empty)."""
    occ = np.flatnonzero(sem.any(axis=(0, 1)))
    if occ.size == 0:
        return None
    return z0 + (occ[0] + 0.5) * voxel_size, z0 + (occ[-1] + 0.5) * voxel_size


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
) -> Sheet:
    """One frame at a glance: under ``title``, [top view | 3D view | key], the views ``height``
    pixels high. The top view (bird's-eye, the top-most voxel of each column, ego marked) has
    axes in metres in the LiDAR frame (x forward up the page, y left to the left), block-
    downsampled to at least ``height`` rows and nearest-resized to exactly ``height``; the 3D
    view (:func:`perspective_view`) is ``height`` x ``16/9 height`` and says where it looks from
    and its pooling. The key states the colouring: class swatches (things in instance mode by
    the colours of their instances, see :func:`class_entries`), the ego marker and free columns,
    or in height mode the height scale in metres shared by both views."""
    check_mode(mode)
    H = int(height)
    if H < 32:
        raise ValueError(f"height must be >= 32 pixels, got {height}")
    sem, inst, has = grid_arrays(semantic, instance, grid)
    inst_arg = inst if has else None
    X = sem.shape[0]
    # one height range for both views in height mode: the occupied voxel centres
    z_range = _occupied_z(sem, grid.origin[2], grid.voxel_size) if mode == "height" else None
    # top view: block top-most downsample to >= H rows, then nearest-resize to H rows
    f = max(1, X // H)
    ktop, stop, itop = top_surface(sem, inst_arg)
    if f > 1:
        ktop, stop, itop = block_top(ktop, stop, itop, f)
    cell = grid.voxel_size * f
    x_top, y_left = grid.origin[0] + ktop.shape[0] * cell, grid.origin[1] + ktop.shape[1] * cell
    bev = bev_image(bev_colours(ktop, stop, itop, grid.origin[2], grid.voxel_size, mode, z_range, True, FREE_RGB))
    draw_ego(bev, x_top, y_left, cell)
    bw = max(1, int(round(bev.shape[1] * H / bev.shape[0])))
    bev = _resize_nearest(bev, H, bw)
    view, pool = voxel_view(sem, inst, has, grid.origin, grid.voxel_size, (H, int(round(H * 16 / 9))),
                            elevation_deg, azimuth_deg, mode, 40.0, None, max_voxels, _FIG_BG, 2, 0.03,
                            True, z_range)  # fmt: skip
    size = f"{grid.voxel_size:g} m"
    pooled = f", pooled x{pool} ({grid.voxel_size * pool:g} m)" if pool > 1 else ""
    panels = [
        Panel(f"top view, {size} voxels", bev, (y_left, grid.origin[1], grid.origin[0], x_top),
              "y, m (left +)", "x, m (forward +)"),
        Panel(f"3D, {size}{pooled}: from {_view_words(azimuth_deg)}, {elevation_deg:g} deg up", view),
    ]
    entries = [] if mode == "height" else class_entries(sem, inst if has else None, mode)
    entries += [EGO_ENTRY, FREE_ENTRY]
    if mode != "height":
        entries.append(LegendEntry("top view: darker = lower top", kind="text"))
    scale = height_scale(z_range, "voxel centre z, m (LiDAR frame)") if z_range is not None else None
    return compose([(panels, Key(_MODE_HEADINGS[mode], tuple(entries), scale))], title=str(title))


def _view_words(azimuth_deg: float) -> str:
    """Where a 3D view's camera stands, in words: azimuth 180 is behind the ego."""
    return {"front": "ahead", "rear": "behind"}.get(facing(azimuth_deg), facing(azimuth_deg))


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
) -> Sheet:
    """The multi-voxel-size figure: one column per ``(label, semantic, instance, grid)`` frame
    (typically the same scene at 0.05 / 0.1 / 0.2 / 0.4 m): the 3D view of the metric ``window``
    ((xmin, xmax), (ymin, ymax), all heights) over the top view of the same window with axes in
    metres and the ego marked, ``cell_size`` pixels per window x extent, nearest-neighbour
    sampled so coarser voxels show as bigger blocks. Every column uses the same camera (framing
    the window over the common occupied height range) and the same height normalisation; each
    row's key states the colouring (the classes of every column; in height mode the scale)."""
    check_mode(mode)
    if not frames:
        raise ValueError("multi_voxel_size_figure needs at least one frame")
    (xmin, xmax), (ymin, ymax) = window
    if not (xmax > xmin and ymax > ymin):
        raise ValueError(f"empty window {window!r}")
    rows = int(cell_size)
    cols = max(1, int(round(rows * (ymax - ymin) / (xmax - xmin))))
    view_h = max(1, int(round(cols * 0.75)))
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
    views, bevs, entries = [], [], {}
    for label, csem, cinst, grid, i0, j0, (ktop, stop, itop), _ in crops:
        view = np.full((view_h, cols, 3), _FIG_BG, np.uint8)
        if zbox is not None and csem.size:
            corner = (grid.origin[0] + i0 * grid.voxel_size, grid.origin[1] + j0 * grid.voxel_size, grid.origin[2])
            view, _ = voxel_view(csem, cinst if cinst is not None else np.zeros((1, 1, 1), np.uint32),
                                 cinst is not None, corner, grid.voxel_size, (view_h, cols), elevation_deg,
                                 azimuth_deg, mode, 40.0, (window[0], window[1], zbox), max_voxels, _FIG_BG, 2,
                                 0.03, True)  # fmt: skip
        views.append(Panel(f"{label}: 3D from {_view_words(azimuth_deg)}", view))
        bev = _bev_window(ktop, stop, itop, grid, i0, j0, window, (rows, cols), mode, z_range, True, FREE_RGB)
        draw_ego(bev, xmax, ymax, (xmax - xmin) / rows)
        bevs.append(Panel(f"{label}: top view", bev, (ymax, ymin, xmin, xmax), "y, m (left +)", "x, m (forward +)"))
        if mode != "height" and csem.size:
            for e in class_entries(csem, cinst, mode):
                entries.setdefault(e.label.split(":")[0], e)
    heading = _MODE_HEADINGS[mode]
    scale_3d = height_scale(zbox, "height, m (LiDAR frame)") if mode == "height" and zbox is not None else None
    scale_bev = height_scale(z_range, "top voxel z, m") if mode == "height" and z_range is not None else None
    top_notes = [] if mode == "height" else [LegendEntry("top view: darker = lower top", kind="text")]
    return compose([(views, Key(heading, tuple(entries.values()), scale_3d)),
                    (bevs, Key("top view", (EGO_ENTRY, FREE_ENTRY, *top_notes), scale_bev))], title=title)
