"""The observed bits of a frame: ``mask_camera | mask_lidar`` (observed by any sensor of the rig)
kept as bits packed along z, as the quality stage reads them (``observed_bits``).

The masks are traced as column bits (:mod:`carlaocc.stages.voxelize.visibility`, "Working layout"):
column ``(i, j)`` of an ``(X, Y, Z)`` grid is ``W = ceil(Z / 64)`` uint64 words, voxel ``k`` bit
``k % 64`` of word ``k // 64``. On a little-endian machine that is byte ``k // 8``, bit ``k % 8``
of the column's bytes: the first ``ceil(Z / 8)`` bytes of a column are
``np.packbits(column, bitorder="little")`` as they are, so a block of the packed grid is a strided
copy of the words' bytes, with no unpacking to one byte per voxel.
"""

from __future__ import annotations

import sys

import numpy as np

from carlaocc.stages.scratch import scratch

__all__ = ["observed_columns", "packed_block", "unpack_z"]

if sys.byteorder != "little":  # pragma: no cover - every platform numba supports here is little-endian
    raise ImportError("the observed bits assume a little-endian machine (column words read as bytes)")


def observed_columns(*masks: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """The OR of column-bit masks of one grid (flat uint64, the same length): observed by any."""
    if not masks:
        raise ValueError("give at least one column-bit mask")
    n = masks[0].size
    if any(m.size != n or m.dtype != np.uint64 for m in masks):
        raise ValueError("column-bit masks must be uint64 arrays of one length")
    out = scratch("observed_columns", n, np.uint64) if out is None else out
    np.copyto(out, masks[0])
    for m in masks[1:]:
        np.bitwise_or(out, m, out=out)
    return out


def packed_block(words: np.ndarray, shape: tuple[int, int, int], i0: int, j0: int, bx: int, by: int,
                 name: str = "observed_block") -> np.ndarray | None:
    """Columns ``[i0, i0 + bx) x [j0, j0 + by)`` of a column-bit mask of a grid of ``shape``
    ``(X, Y, Z)`` as uint8 ``(bx, by, ceil(Z / 8))``, z packed little bit order (voxel ``k`` is bit
    ``k % 8`` of byte ``k // 8``; bits past ``Z`` zero), in the per-thread buffer ``name`` (the
    next call overwrites it); None when no voxel of the block is set."""
    X, Y, Z = (int(s) for s in shape)
    W = -(-Z // 64)
    if words.size != X * Y * W:
        raise ValueError(f"column words of {words.size} do not fit a grid of {shape}")
    if not (0 <= i0 and 0 <= j0 and i0 + bx <= X and j0 + by <= Y):
        raise ValueError(f"block [{i0}, {i0 + bx}) x [{j0}, {j0 + by}) outside the grid's {X} x {Y} columns")
    zb = -(-Z // 8)
    # 1. the block's columns as bytes: the first ceil(Z / 8) bytes of each column's words
    view = words.view(np.uint8).reshape(X, Y, 8 * W)[i0:i0 + bx, j0:j0 + by, :zb]
    out = scratch(name, bx * by * zb, np.uint8).reshape(bx, by, zb)
    np.copyto(out, view)
    # 2. bits past Z in the last byte cleared (a trace never sets them; kept exact regardless)
    if Z % 8:
        out[..., -1] &= np.uint8((1 << (Z % 8)) - 1)
    # 3. an empty block is not stored
    flat = out.reshape(-1)
    body = flat[: flat.size // 8 * 8].view(np.uint64)
    if not body.any() and not flat[body.size * 8:].any():
        return None
    return out


def unpack_z(bits: np.ndarray, z: int) -> np.ndarray:
    """The uint8 0/1 volume of bits packed along the last axis (``(..., ceil(z / 8))`` ->
    ``(..., z)``): ``np.unpackbits(bits, axis=-1, count=z, bitorder="little")``."""
    return np.unpackbits(np.asarray(bits, dtype=np.uint8), axis=-1, count=int(z), bitorder="little")
