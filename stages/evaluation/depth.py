"""Monocular depth metrics (Eigen et al. 2014, as in Monodepth2 / the KITTI depth benchmark).

Per image, a pixel is **valid** when its ground truth is finite and ``min_depth < gt < max_depth``
(so ``gt > 0`` always) and the optional ``mask`` keeps it. Predictions are clipped to
``[min_depth, max_depth]`` first (Monodepth2), optionally after per-image median scaling
(``scale="median"``: ``pred *= median(gt) / median(pred)`` over the valid pixels, for
relative-depth models). Over the valid pixels, with ``p`` prediction and ``g`` ground truth:

* ``abs_rel = mean |p - g| / g``, ``sq_rel = mean (p - g)^2 / g``,
* ``rmse = sqrt(mean (p - g)^2)``, ``rmse_log = sqrt(mean (ln p - ln g)^2)``,
* ``a1, a2, a3 = mean [max(p / g, g / p) < 1.25^k]`` for ``k = 1, 2, 3``.

Two dataset averages are reported: ``pixel`` (the sums run over every valid pixel of every image,
so large images weigh more; RMSE is the root of the pooled mean) and ``image`` (each metric per
image, then the mean over images with at least one valid pixel; the KITTI/Monodepth2 table
convention). Units: metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

__all__ = ["DEPTH_METRICS", "DepthAccumulator", "DepthResult", "depth_sums"]

DEPTH_METRICS: tuple[str, ...] = ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1", "a2", "a3")
# sums kept per image: n, |d|/g, d^2/g, d^2, dlog^2, [r<1.25], [r<1.25^2], [r<1.25^3]
_N_SUMS = 8


def depth_sums(
    pred: np.ndarray,
    gt: np.ndarray,
    min_depth: float,
    max_depth: float,
    mask: np.ndarray | None = None,
    scale: Literal["none", "median"] = "none",
) -> np.ndarray:
    """The 8 sums of one image: ``(n, sum |p-g|/g, sum (p-g)^2/g, sum (p-g)^2, sum dlog^2,
    count r < 1.25, r < 1.25^2, r < 1.25^3)`` over its valid pixels (see module doc)."""
    p = np.asarray(pred, dtype=np.float64)
    g = np.asarray(gt, dtype=np.float64)
    if p.shape != g.shape:
        raise ValueError(f"prediction shape {p.shape} differs from ground truth shape {g.shape}")
    # 1. valid pixels: finite ground truth inside the cap, kept by the mask
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(g) & (g > min_depth) & (g < max_depth)
    if mask is not None:
        if np.shape(mask) != g.shape:
            raise ValueError(f"mask shape {np.shape(mask)} differs from ground truth shape {g.shape}")
        valid &= np.asarray(mask, dtype=bool)
    g = g[valid]
    p = p[valid]
    if not np.isfinite(p).all():
        raise ValueError(f"prediction has {int((~np.isfinite(p)).sum())} non-finite values on valid pixels")
    out = np.zeros(_N_SUMS, dtype=np.float64)
    if g.size == 0:
        return out
    # 2. optional median scaling, then clip predictions to the cap
    if scale == "median":
        mp = np.median(p)
        if mp <= 0:
            raise ValueError("median scaling needs a positive median prediction")
        p = p * (np.median(g) / mp)
    elif scale != "none":
        raise ValueError(f"scale must be 'none' or 'median', got {scale!r}")
    p = np.clip(p, min_depth, max_depth)
    # 3. the sums
    d = p - g
    ratio = np.maximum(p / g, g / p)
    out[0] = g.size
    out[1] = np.sum(np.abs(d) / g)
    out[2] = np.sum(d * d / g)
    out[3] = np.sum(d * d)
    out[4] = np.sum((np.log(p) - np.log(g)) ** 2)
    out[5] = np.count_nonzero(ratio < 1.25)
    out[6] = np.count_nonzero(ratio < 1.25**2)
    out[7] = np.count_nonzero(ratio < 1.25**3)
    return out


def _metrics(s: np.ndarray) -> np.ndarray:
    """The 7 metrics from sums ``s`` (``(..., 8)``); NaN where ``n = 0``."""
    n = s[..., 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.stack([s[..., 1] / n, s[..., 2] / n, np.sqrt(s[..., 3] / n), np.sqrt(s[..., 4] / n),
                      s[..., 5] / n, s[..., 6] / n, s[..., 7] / n], axis=-1)  # fmt: skip
    return np.where((n > 0)[..., None], m, np.nan)


@dataclass(frozen=True)
class DepthResult:
    """Pixel-pooled and per-image-mean metrics (dicts keyed by :data:`DEPTH_METRICS`)."""

    pixel: dict[str, float]
    image: dict[str, float]
    images: int  # images added
    valid_images: int  # images with at least one valid pixel
    pixels: int  # valid pixels
    min_depth: float
    max_depth: float
    scale: str

    def to_dict(self) -> dict:
        f = lambda v: None if np.isnan(v) else float(v)  # noqa: E731
        return {
            "metric": "depth", "images": self.images, "valid_images": self.valid_images,
            "pixels": self.pixels, "min_depth": self.min_depth, "max_depth": self.max_depth,
            "scale": self.scale,
            "pixel": {k: f(v) for k, v in self.pixel.items()},
            "image": {k: f(v) for k, v in self.image.items()},
        }  # fmt: skip


@dataclass
class DepthAccumulator:
    """Sums over images: ``update(pred, gt, mask=None)`` per image, ``result()`` at the end.

    Defaults ``min_depth = 1e-3`` m and ``max_depth = 80`` m (the KITTI Eigen cap).
    """

    min_depth: float = 1e-3
    max_depth: float = 80.0
    scale: Literal["none", "median"] = "none"
    totals: np.ndarray = field(init=False)
    per_image: list[np.ndarray] = field(init=False)

    def __post_init__(self) -> None:
        if not (0 < self.min_depth < self.max_depth and np.isfinite(self.max_depth)):
            raise ValueError(f"need 0 < min_depth < max_depth (finite), got {self.min_depth}, {self.max_depth}")
        if self.scale not in ("none", "median"):
            raise ValueError(f"scale must be 'none' or 'median', got {self.scale!r}")
        self.totals = np.zeros(_N_SUMS, dtype=np.float64)
        self.per_image = []

    def update(self, pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Add one image (``pred``, ``gt`` in metres, one shape; ``mask`` bool, optional)."""
        s = depth_sums(pred, gt, self.min_depth, self.max_depth, mask, self.scale)
        self.totals += s
        self.per_image.append(s)

    def result(self) -> DepthResult:
        per = np.array(self.per_image, dtype=np.float64).reshape(-1, _N_SUMS)
        per = per[per[:, 0] > 0]
        pixel = _metrics(self.totals)
        image = _metrics(per).mean(axis=0) if len(per) else np.full(len(DEPTH_METRICS), np.nan)
        return DepthResult(
            pixel=dict(zip(DEPTH_METRICS, map(float, pixel))), image=dict(zip(DEPTH_METRICS, map(float, image))),
            images=len(self.per_image), valid_images=len(per), pixels=int(self.totals[0]),
            min_depth=self.min_depth, max_depth=self.max_depth, scale=self.scale,
        )  # fmt: skip
