"""Colours of occupancy pictures, shared by every view, and of instance ids.

Colouring ``mode`` (:data:`MODES`):

* ``"instance"`` (the default, panoptic): stuff by its class colour, every voxel with a nonzero
  instance id (things) by a colour hashed from the id (:func:`instance_colors`: saturated,
  deterministic, independent of the frame, so one object keeps its colour over a sequence);
* ``"semantic"``: every voxel by its class colour (:func:`carlaocc.schemas.taxonomy.palette`);
* ``"height"``: a blue-to-red ramp over the height of the voxel centre.
"""

from __future__ import annotations

import numpy as np

from carlaocc.schemas.taxonomy import palette

__all__ = ["MODES", "check_mode", "height_ramp", "instance_colors", "voxel_colours"]

MODES = ("instance", "semantic", "height")
_PALETTE = np.asarray(palette() + ((0, 0, 0),) * (256 - len(palette())), dtype=np.float32)  # any uint8 id
# height ramp anchors (t, RGB): dark blue, blue, cyan, green, yellow, orange, red
_RAMP_T = np.array([0.0, 0.15, 0.35, 0.55, 0.72, 0.87, 1.0])
_RAMP_RGB = np.array(
    [(48, 18, 120), (60, 100, 230), (30, 190, 230), (60, 225, 110), (200, 235, 50), (250, 160, 40), (215, 45, 20)],
    dtype=np.float64,
)


def check_mode(mode: str) -> None:
    """``ValueError`` naming the valid modes unless ``mode`` is one of :data:`MODES`."""
    if mode not in MODES:
        raise ValueError(f"unknown mode {mode!r}; valid modes: {', '.join(MODES)}")


def instance_colors(ids) -> np.ndarray:
    """Deterministic saturated RGB colour (uint8, shape ``ids.shape + (3,)``) of instance ids: the
    32-bit id is mixed (golden-ratio multiply, murmur3 finaliser) into a hue (any), a saturation
    (0.65-0.95) and a value (0.80-1.0)."""
    m32 = np.uint64(0xFFFFFFFF)
    x = np.asarray(ids).astype(np.uint64) & m32
    x = (x * np.uint64(0x9E3779B1)) & m32
    x ^= x >> np.uint64(16)
    x = (x * np.uint64(0x85EBCA6B)) & m32
    x ^= x >> np.uint64(13)
    x = (x * np.uint64(0xC2B2AE35)) & m32
    x ^= x >> np.uint64(16)
    h = (x & np.uint64(0xFFFF)).astype(np.float64) / 65536.0
    s = 0.65 + 0.30 * ((x >> np.uint64(16)) & np.uint64(0xFF)).astype(np.float64) / 255.0
    v = 0.80 + 0.20 * ((x >> np.uint64(24)) & np.uint64(0xFF)).astype(np.float64) / 255.0
    h6 = h * 6.0
    sector = np.floor(h6).astype(np.int64) % 6
    frac = h6 - np.floor(h6)
    p, q, t = v * (1 - s), v * (1 - s * frac), v * (1 - s * (1 - frac))
    r = np.choose(sector, [v, q, p, p, t, v])
    g = np.choose(sector, [t, v, v, q, p, p])
    b = np.choose(sector, [p, p, t, v, v, q])
    return np.round(np.stack([r, g, b], axis=-1) * 255.0).astype(np.uint8)


def height_ramp(t: np.ndarray) -> np.ndarray:
    """Float32 RGB (0..255) of the height ramp at positions ``t`` (0 = lowest, 1 = highest;
    clipped), dark blue through cyan, green and yellow to red."""
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, 1.0)
    return np.stack([np.interp(t, _RAMP_T, _RAMP_RGB[:, c]) for c in range(3)], axis=-1).astype(np.float32)


def voxel_colours(sem, inst, z, mode: str, z_range) -> np.ndarray:
    """Float32 RGB (0..255) in ``mode`` of voxels with classes ``sem``, instances ``inst`` and heights ``z``."""
    if mode == "height":
        lo, hi = z_range
        return height_ramp((z - lo) / max(hi - lo, 1e-9))
    out = _PALETTE[sem]
    if mode == "instance":
        things = inst != 0
        if things.any():
            ids, inverse = np.unique(inst[things], return_inverse=True)
            out[things] = instance_colors(ids).astype(np.float32)[inverse]
    return out

