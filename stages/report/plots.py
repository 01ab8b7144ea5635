"""Plots of the dataset statistics and quality scores, as PNG bytes (matplotlib, headless).

Every function takes counts or records (see :mod:`carlaocc.stages.report.statistics`) and returns the
PNG of one figure. Figures are made with :class:`matplotlib.figure.Figure` and the Agg canvas,
never through ``pyplot``: no global state, no display, safe in worker threads. The PNGs carry no
software/version metadata, so the same counts give the same bytes with the same matplotlib.
Classes are drawn in their taxonomy colours (CARLA/Cityscapes palette).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter

from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import QualityRecord
from carlaocc.schemas.records import AssetStatisticsRecord
from carlaocc.stages.report.statistics import N_CLASSES, MotionShare

DPI = 100
_SOURCE_COLOURS = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#76b7b2", "#edc948", "#b07aa1", "#ff9da7",
                   "#9c755f", "#bab0ac")
_STATIC_COLOUR, _MOVING_COLOUR = "#8c9bb0", "#e8702a"
_METRIC_NAMES = {"spatial_continuity": "spatial continuity s_sc", "temporal_consistency": "temporal consistency s_tc"}


def class_colour(class_id: int) -> tuple[float, float, float]:
    """Matplotlib RGB (0-1) of a taxonomy class."""
    return tuple(v / 255.0 for v in taxonomy.by_id(class_id).color)


def _figure(width_in: float, height_in: float, margins: tuple[float, float, float, float] = (0.9, 0.25, 1.1, 0.45),
            wspace: float = 0.2, hspace: float = 0.2) -> Figure:
    """A figure with fixed margins (left, right, bottom, top) in inches: an automatic layout
    (constrained/tight) measures every text twice and costs more than drawing the figure."""
    fig = Figure(figsize=(width_in, height_in), dpi=DPI)
    FigureCanvasAgg(fig)
    left, right, bottom, top = margins
    fig.subplots_adjust(left=left / width_in, right=1 - right / width_in, bottom=bottom / height_in,
                        top=1 - top / height_in, wspace=wspace, hspace=hspace)
    return fig


def to_png(fig: Figure) -> bytes:
    """PNG bytes of a figure (no metadata: deterministic)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def _counts(values, name: str) -> np.ndarray:
    a = np.asarray(values, dtype=np.int64)
    if a.shape != (N_CLASSES,):
        raise ValueError(f"{name} must be one count per class, shape ({N_CLASSES},), got {a.shape}")
    if (a < 0).any():
        raise ValueError(f"{name} holds negative counts")
    return a


def _si(v: float) -> str:
    """12 -> '12', 12500 -> '12.5k', 3.2e6 -> '3.2M'."""
    for div, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(v) >= div:
            return f"{v / div:.3g}{suffix}"
    return f"{v:.0f}"


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="#666666")
    ax.set_xticks([])
    ax.set_yticks([])


def class_voxel_plot(voxels, title: str = "Voxels per class") -> bytes:
    """Occupied voxels per class (free space left out), log-scale bars in the class colours,
    largest first, each labelled with its count and share of the occupied voxels."""
    v = _counts(voxels, "voxels")
    ids = [c for c in np.argsort(-v, kind="stable") if c != 0 and v[c] > 0]
    fig = _figure(max(6.0, 0.42 * len(ids) + 2.0), 4.2)
    ax = fig.add_subplot()
    ax.set_title(title)
    if not ids:
        _empty(ax, "no occupied voxel")
        return to_png(fig)
    total = v[1:].sum()
    heights = v[ids]
    ax.bar(range(len(ids)), heights, color=[class_colour(c) for c in ids], edgecolor="#333333", linewidth=0.4)
    ax.set_yscale("log")
    ax.set_ylim(max(0.5, heights.min() / 3), heights.max() * 8)
    ax.set_xticks(range(len(ids)), [taxonomy.by_id(c).name for c in ids], rotation=60, ha="right")
    ax.set_ylabel("voxels (log scale)")
    for x, h in enumerate(heights):
        ax.text(x, h * 1.15, f"{_si(h)}\n{100 * h / total:.2g}%", ha="center", va="bottom", fontsize=7)
    ax.grid(axis="y", which="major", alpha=0.3)
    return to_png(fig)


def instances_plot(instances, moving=None, title: str = "Instances per class") -> bytes:
    """Distinct instances per thing class, bars in the class colours, largest first; with
    ``moving`` (per class, instances that are dynamic actors) the actor part is hatched."""
    n = _counts(instances, "instances")
    m = None if moving is None else _counts(moving, "moving")
    ids = [c for c in np.argsort(-n, kind="stable") if n[c] > 0]
    fig = _figure(max(5.0, 0.6 * len(ids) + 2.0), 3.8, (0.8, 0.2, 0.9, 0.45))
    ax = fig.add_subplot()
    ax.set_title(title)
    if not ids:
        _empty(ax, "no instance")
        return to_png(fig)
    colours = [class_colour(c) for c in ids]
    ax.bar(range(len(ids)), n[ids], color=colours, edgecolor="#333333", linewidth=0.4)
    if m is not None and m[ids].any():
        ax.bar(range(len(ids)), m[ids], color="none", edgecolor="white", hatch="///", linewidth=0)
        handle = Patch(facecolor="#777777", edgecolor="white", hatch="///", label="dynamic actors (hatched)")
        ax.legend(handles=[handle], loc="upper right", fontsize=8)
    for x, c in enumerate(ids):
        ax.text(x, n[c], f"{n[c]:,}", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(ids)), [taxonomy.by_id(c).name for c in ids], rotation=30, ha="right")
    ax.set_ylabel("instances")
    ax.set_ylim(0, n[ids].max() * 1.15)
    ax.grid(axis="y", alpha=0.3)
    return to_png(fig)


def asset_plot(rows: Sequence[AssetStatisticsRecord], title: str = "ADMesh assets per class and source") -> bytes:
    """Assets per category, stacked by source (one colour per source, legend), categories in
    taxonomy order; the bar's total above it."""
    fig = _figure(max(6.0, 0.5 * len({r.category_id for r in rows}) + 2.5), 4.0, (0.7, 0.2, 1.1, 0.45))
    ax = fig.add_subplot()
    ax.set_title(title)
    if not rows:
        _empty(ax, "no asset")
        return to_png(fig)
    cats = sorted({(r.category_id, r.category) for r in rows})
    sources = sorted({r.source for r in rows})
    table = np.zeros((len(sources), len(cats)), np.int64)
    for r in rows:
        table[sources.index(r.source), cats.index((r.category_id, r.category))] += r.assets
    bottom = np.zeros(len(cats), np.int64)
    for i, s in enumerate(sources):
        ax.bar(range(len(cats)), table[i], bottom=bottom, label=s, color=_SOURCE_COLOURS[i % len(_SOURCE_COLOURS)],
               edgecolor="#333333", linewidth=0.4)
        bottom += table[i]
    for x, total in enumerate(bottom):
        ax.text(x, total, str(int(total)), ha="center", va="bottom", fontsize=8)
    ax.set_xticks(range(len(cats)), [c for _, c in cats], rotation=40, ha="right")
    # the class colour as a swatch under each tick label
    for label, (cid, _) in zip(ax.get_xticklabels(), cats):
        if 0 <= cid < N_CLASSES:
            label.set_bbox({"facecolor": class_colour(cid), "alpha": 0.35, "edgecolor": "none", "pad": 1.5})
    ax.set_ylabel("assets")
    ax.set_ylim(0, bottom.max() * 1.15)
    ax.legend(title="source", fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return to_png(fig)


def motion_plot(share: MotionShare, title: str = "Static vs dynamic") -> bytes:
    """Two panels: instances per thing class split into placed (static) objects and dynamic
    actors (horizontal stacked bars, overall share in the caption), and occupied voxels of static
    vs dynamic taxonomy classes."""
    fig = _figure(9.5, 3.8, (1.1, 0.2, 0.65, 0.75), wspace=0.35)
    fig.suptitle(title)
    ax, ax2 = fig.subplots(1, 2, width_ratios=[2.2, 1])
    st, mv = _counts(share.static_instances, "static_instances"), _counts(share.moving_instances, "moving_instances")
    ids = [c for c in np.argsort(-(st + mv), kind="stable") if st[c] + mv[c] > 0][::-1]
    if ids:
        y = np.arange(len(ids))
        ax.barh(y, st[ids], color=_STATIC_COLOUR, label="placed (static)")
        ax.barh(y, mv[ids], left=st[ids], color=_MOVING_COLOUR, label="actors (dynamic)")
        ax.set_yticks(y, [taxonomy.by_id(c).name for c in ids])
        for tick, c in zip(ax.get_yticklabels(), ids):
            tick.set_bbox({"facecolor": class_colour(c), "alpha": 0.35, "edgecolor": "none", "pad": 1.5})
        for yy, c in zip(y, ids):
            ax.text(st[c] + mv[c], yy, f" {st[c]:,} + {mv[c]:,}", va="center", fontsize=8)
        ax.set_xlim(0, (st[ids] + mv[ids]).max() * 1.3)
        frac = share.moving_fraction
        ax.set_title(f"instances: {100 * frac:.1f}% dynamic actors" if not math.isnan(frac) else "instances")
        ax.set_xlabel("instances")
        ax.legend(loc="lower right", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    else:
        _empty(ax, "no instance")
    total = share.static_voxels + share.dynamic_voxels
    if total:
        vals = [share.static_voxels, share.dynamic_voxels]
        ax2.bar([0, 1], vals, color=[_STATIC_COLOUR, _MOVING_COLOUR], edgecolor="#333333", linewidth=0.4)
        ax2.set_yscale("log")
        ax2.set_ylim(max(0.5, min(v for v in vals if v > 0) / 3) if any(vals) else 1, max(vals) * 6)
        ax2.set_xticks([0, 1], ["static classes", "dynamic classes"])
        for x, v in enumerate(vals):
            ax2.text(x, max(v, 1) * 1.15, f"{_si(v)}\n{100 * v / total:.3g}%", ha="center", va="bottom", fontsize=8)
        ax2.set_title("occupied voxels")
        ax2.set_ylabel("voxels (log scale)")
        ax2.grid(axis="y", alpha=0.3)
    else:
        _empty(ax2, "no occupied voxel")
    return to_png(fig)


def metric_label(metric: str) -> str:
    """Display name of a quality metric."""
    return _METRIC_NAMES.get(metric, metric.replace("_", " "))


def score_axis(values: Sequence[float]) -> tuple[float, float, str]:
    """(bottom, top, y-axis label) of a score panel. Scores of 0..1 sit close to 1, so the axis
    is zoomed to their range when that range is narrow (under a third of the way from 0), and
    then says so in its label: ``"score (axis from 0.992, not 0)"``; otherwise it starts at 0."""
    lo, hi = min(values), max(values)
    pad = max((hi - lo) * 0.25, 0.002)
    top = min(1.0, hi) + pad if hi <= 1.0 else hi + pad
    bottom = max(0.0, lo - 4 * pad)
    if bottom < top / 3:
        return 0.0, top, "score"
    return bottom, top, f"score (axis from {bottom:.3f}, not 0)"


def quality_figure(rows: Sequence[QualityRecord], title: str = "Quality scores per sequence") -> Figure:
    """The figure of :func:`quality_plot` (its axes can be inspected)."""
    seq_rows = [r for r in rows if r.frame_index is None and math.isfinite(r.value)]
    metrics = sorted({r.metric for r in seq_rows})
    n_panels = max(1, len(metrics))
    fig = _figure(max(6.0, 3.0 + 0.9 * len({r.sequence_id for r in seq_rows})), 0.6 + 3.0 * n_panels,
                  (0.9, 0.2, 0.8, 0.6), hspace=0.9 / (2.2 if n_panels > 1 else 1))
    fig.suptitle(title)
    if not metrics:
        _empty(fig.add_subplot(), "no quality score")
        return fig
    axes = fig.subplots(len(metrics), 1, squeeze=False)[:, 0]
    for ax, metric in zip(axes, metrics):
        mine = [r for r in seq_rows if r.metric == metric]
        seqs = sorted({r.sequence_id for r in mine})
        voxel_sizes = sorted({r.voxel_size for r in mine})
        width = 0.8 / len(voxel_sizes)
        bottom, top, label = score_axis([r.value for r in mine])
        # bars from 0 when the axis starts at 0; on a zoomed axis a bar's length would not be its
        # value, so each score is a dot on a stem from the axis' bottom
        for k, voxel_size in enumerate(voxel_sizes):
            xs, ys = [], []
            for r in mine:
                if r.voxel_size == voxel_size:
                    xs.append(seqs.index(r.sequence_id) - 0.4 + width * (k + 0.5))
                    ys.append(r.value)
            colour = _SOURCE_COLOURS[k % len(_SOURCE_COLOURS)]
            if bottom == 0.0:
                ax.bar(xs, ys, width=width * 0.9, label=f"{voxel_size:g} m", color=colour)
            else:
                ax.vlines(xs, bottom, ys, colors=colour, linewidth=1.0, alpha=0.6)
                ax.plot(xs, ys, "o", color=colour, label=f"{voxel_size:g} m")
            for x, v in zip(xs, ys):
                ax.text(x, v, f"{v:.4f}", ha="center", va="bottom", fontsize=7)
        ax.set_ylim(bottom, top)
        ax.set_ylabel(label, fontsize=8)
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.3f}"))
        ax.set_xticks(range(len(seqs)), seqs, rotation=15, ha="right", fontsize=8)
        ax.set_title(metric_label(metric), fontsize=10)
        ax.legend(title="voxel", fontsize=7, title_fontsize=7, loc="lower right")
        ax.grid(axis="y", alpha=0.3)
    return fig


def quality_plot(rows: Sequence[QualityRecord], title: str = "Quality scores per sequence") -> bytes:
    """One panel per metric of the sequence-level rows (``frame_index`` None; frame rows are
    ignored): a score per sequence, one colour per voxel size, the value over each. The y axis
    is zoomed to the scores' range when they sit close to 1, and its label then says where it
    starts (:func:`score_axis`); the scores are dots on stems then, bars only on an axis from 0."""
    return to_png(quality_figure(rows, title))
