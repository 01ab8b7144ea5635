"""A scene's panoptic occupancy as its occupied voxels only (:class:`SparseVoxels`), built tile by
tile: memory proportional to the occupied voxels plus one tile, never the whole dense grid.

The same voxels and labels as :func:`carlaocc.stages.voxelize.voxelize_scene` (it is the same
tile iterator, :func:`carlaocc.stages.voxelize.voxelize_tiles`: fusion, elevation order, fills);
each tile's occupied voxels are extracted and the tile's buffers are reused for the next one.
Fills (parity, winding numbers) work inside a tile as in the pipeline.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.voxels import SparseVoxels
from carlaocc.stages.voxelize.compose import voxelize_tiles
from carlaocc.stages.voxelize.fill import FillMode

__all__ = ["occupied_voxels", "nonzero_bytes"]


@njit(cache=True, nogil=True)
def _nonzero_bytes(values, words, base, out_index, out_values):
    """Write the positions (plus ``base``) and values of the non-zero bytes of ``values`` (uint8)
    into ``out_index`` / ``out_values``, ascending; ``words`` views its first ``8 * len(words)``
    bytes as uint64, so a zero word skips 8 bytes at once. Returns how many were written."""
    o = 0
    # 1. whole words: look at the bytes of non-zero words only
    for w in range(words.shape[0]):
        if words[w] != 0:
            for b in range(8 * w, 8 * w + 8):
                v = values[b]
                if v != 0:
                    out_index[o] = base + b
                    out_values[o] = v
                    o += 1
    # 2. the bytes after the last whole word
    for b in range(8 * words.shape[0], values.shape[0]):
        v = values[b]
        if v != 0:
            out_index[o] = base + b
            out_values[o] = v
            o += 1
    return o


def nonzero_bytes(values: np.ndarray, base: int = 0, index_dtype=np.int64) -> tuple[np.ndarray, np.ndarray]:
    """``(base + np.flatnonzero(values), values[that])`` of a contiguous 1-D uint8 array, at
    memory speed on sparse data (8 bytes at a time where they are all zero); the indices as
    ``index_dtype`` (the caller makes sure they fit)."""
    n = int(np.count_nonzero(values))  # a SIMD count sizes the output
    index = np.empty(n, dtype=index_dtype)
    out = np.empty(n, dtype=np.uint8)
    if n == 0:
        return index, out
    whole = len(values) // 8 if values.ctypes.data % 8 == 0 else 0  # unaligned: byte by byte
    _nonzero_bytes(values, values[:8 * whole].view(np.uint64), index.dtype.type(base), index, out)
    return index, out


def occupied_voxels(meshes: Sequence[SceneMesh], grid: GridSpec, fill: FillMode = "auto", up=None,
                    tile_x: int = 64) -> SparseVoxels:
    """The occupied voxels of ``meshes`` (grid frame, metres) on ``grid`` under ``fill``, with
    their semantic and instance labels; ``tile_x`` (x-slab width, voxels) only changes how the
    work is cut, never the result."""
    X, Y, Z = (int(s) for s in grid.shape)
    # linear indices as uint32 where they fit (every grid the standalone voxelizer accepts): half
    # the memory, and what its file stores
    index_dtype = np.uint32 if X * Y * Z <= 2**32 else np.int64
    plane = Y * Z  # voxels in one x-layer: a tile starting at x0 begins at linear index x0 * plane
    index, semantic, things = [], [], []
    count = 0
    for tile in voxelize_tiles(meshes, grid, tile_x, fill, up):
        # 1. the tile's occupied voxels as grid linear indices (a tile holds whole x-layers;
        #    ascending within the tile, and tiles come in ascending x)
        base = tile.x0 * plane
        found, sem = nonzero_bytes(tile.semantic.reshape(-1), base, index_dtype)
        if len(found) == 0:
            continue
        index.append(found)
        semantic.append(sem)
        # 2. instance ids: only things write nonzero ones; a tile no thing reached has none
        if len(tile.things):
            things.append((count, tile.instance.reshape(-1)[found - base]))
        count += len(found)
    instance = np.zeros(count, dtype=np.uint32)
    for start, ids in things:
        instance[start:start + len(ids)] = ids
    if not index:
        return SparseVoxels(grid, np.zeros(0, index_dtype), np.zeros(0, np.uint8), instance)
    return SparseVoxels(grid, np.concatenate(index), np.concatenate(semantic), instance)
