"""SurroundOcc ground truth: one sparse ``.npy`` per LiDAR key frame.

Layout (confirmed against ``weiyithu/SurroundOcc``):

* ``tools/generate_occupancy_nuscenes/generate_occupancy_nuscenes.py`` ends with
  ``np.save(path, np.floor(pcd_np).astype(np.int))``: a plain ``.npy`` holding an ``(N, 4)``
  **int64** array (``np.int`` is the platform C long, int64 on Linux) of rows
  ``(x, y, z, label)`` -- voxel indices and the semantic label -- one row per occupied voxel;
* its ``config.yaml``: ``voxel_size 0.5``, ``pc_range [-50, -50, -5, 50, 50, 3]``,
  ``occ_size [200, 200, 16]``;
* ``docs/data.md``: the indices are in the **LiDAR** frame (not ego); empty voxels have no row;
* ``projects/mmdet3d_plugin/datasets/pipelines/loading.py`` reads it with ``np.load`` and treats
  label 0 (nuScenes "noise") as ignore (255). Labels are the nuScenes-lidarseg learning ids 0-16.

Voxel ``(i, j, k)`` covers ``SURROUNDOCC_RANGE[:3] + (i, j, k) * 0.5`` to ``+ 0.5``, metres.
Rows come out of :func:`dense_to_surroundocc` in C order of ``(x, y, z)`` (as the generator's
``vv[gt_ > 0]`` does).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import FormatError, PathLike, atomic_write
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid, grid_origin
from carlaocc.catalog.formats.occ3d import NUSCENES_DYNAMIC
from carlaocc.schemas import taxonomy

__all__ = [
    "SURROUNDOCC_DTYPE",
    "SURROUNDOCC_FORMAT",
    "SURROUNDOCC_NAMES",
    "SURROUNDOCC_RANGE",
    "SURROUNDOCC_SHAPE",
    "SURROUNDOCC_VOXEL_SIZE",
    "dense_to_surroundocc",
    "load_surroundocc",
    "load_surroundocc_grid",
    "save_surroundocc",
    "surroundocc_to_dense",
]

SURROUNDOCC_SHAPE: tuple[int, int, int] = (200, 200, 16)
SURROUNDOCC_VOXEL_SIZE: float = 0.5
SURROUNDOCC_RANGE: tuple[float, float, float, float, float, float] = (-50.0, -50.0, -5.0, 50.0, 50.0, 3.0)
"""(x_min, y_min, z_min, x_max, y_max, z_max), metres, LiDAR frame."""
SURROUNDOCC_DTYPE = np.dtype(np.int64)


def _check_rows(rows: np.ndarray, shape: tuple[int, int, int], where: str) -> None:
    if rows.ndim != 2 or rows.shape[1] != 4:
        raise FormatError(f"{where}: expected an (N, 4) array of (x, y, z, label) rows, got shape {rows.shape}")
    if not np.issubdtype(rows.dtype, np.integer):
        raise FormatError(f"{where}: rows must be integers, got dtype {rows.dtype}")
    if len(rows) == 0:
        return
    lo = rows.min(axis=0)
    hi = rows.max(axis=0)
    for axis, name in enumerate("xyz"):
        if lo[axis] < 0 or hi[axis] >= shape[axis]:
            raise FormatError(
                f"{where}: {name} index out of range [0, {shape[axis] - 1}]: min {int(lo[axis])}, max {int(hi[axis])}"
            )
    if lo[3] < 0:
        raise FormatError(f"{where}: negative label {int(lo[3])}")
    if int(hi[3]) > np.iinfo(SURROUNDOCC_DTYPE).max:  # unsigned rows beyond int64 would wrap negative
        raise FormatError(f"{where}: label {int(hi[3])} does not fit the format's int64")


def dense_to_surroundocc(semantic: np.ndarray, free: int) -> np.ndarray:
    """Dense ``(X, Y, Z)`` integer labels -> ``(N, 4)`` int64 rows for voxels ``!= free``.

    Rows are ``(x, y, z, label)`` in C order of the voxel index.
    """
    semantic = np.asarray(semantic)
    if semantic.ndim != 3:
        raise ValueError(f"semantic must be 3-D (X, Y, Z), got shape {semantic.shape}")
    idx = np.argwhere(semantic != free)
    labels = semantic[tuple(idx.T)]
    return np.concatenate([idx, labels[:, None]], axis=1).astype(SURROUNDOCC_DTYPE)


def surroundocc_to_dense(
    rows: np.ndarray, shape: tuple[int, int, int] = SURROUNDOCC_SHAPE, free: int = 0
) -> np.ndarray:
    """``(N, 4)`` rows -> dense uint8 ``(X, Y, Z)`` grid filled with ``free`` elsewhere.

    ``free`` defaults to 0, SurroundOcc's empty label. ``ValueError`` if a row's label equals
    ``free`` (it would vanish: SurroundOcc's own label 0 means *noise*; pass another ``free``),
    if a label or ``free`` does not fit uint8, if a voxel appears twice, or if an index falls
    outside ``shape``.
    """
    rows = np.asarray(rows)
    _check_rows(rows, tuple(shape), "SurroundOcc rows")
    if not 0 <= free <= 255:
        raise ValueError(f"free label {free} does not fit uint8")
    labels = rows[:, 3]
    if len(rows) and labels.max() > 255:
        raise ValueError(f"label {int(labels.max())} does not fit uint8")
    if (labels == free).any():
        raise ValueError(f"{int((labels == free).sum())} rows carry the free label {free}; choose another free label")
    flat = np.ravel_multi_index(tuple(rows[:, :3].T), shape)
    if len(np.unique(flat)) != len(flat):
        raise ValueError("SurroundOcc rows list some voxel more than once")
    dense = np.full(shape, free, dtype=np.uint8)
    dense.reshape(-1)[flat] = labels
    return dense


def save_surroundocc(path: PathLike, rows: np.ndarray, shape: tuple[int, int, int] = SURROUNDOCC_SHAPE) -> None:
    """Write ``rows`` as SurroundOcc's ``(N, 4)`` int64 ``.npy`` (atomic); validates indices in ``shape``."""
    rows = np.asarray(rows)
    _check_rows(rows, tuple(shape), f"{os.fspath(path)} (writing)")
    buf = io.BytesIO()
    np.save(buf, np.ascontiguousarray(rows, dtype=SURROUNDOCC_DTYPE), allow_pickle=False)
    atomic_write(path, lambda fh: fh.write(buf.getbuffer()))


def load_surroundocc(path: PathLike, shape: tuple[int, int, int] = SURROUNDOCC_SHAPE) -> np.ndarray:
    """Read a SurroundOcc ``.npy``: ``(N, 4)`` int64 rows ``(x, y, z, label)``.

    Any integer dtype on disk is accepted and returned as int64. ``FormatError`` naming the file
    if it is not a readable npy, not ``(N, 4)`` integers, or has an index outside ``shape``.
    """
    p = os.fspath(path)
    try:
        rows = np.load(p, allow_pickle=False)
    except FileNotFoundError:
        raise
    except (OSError, ValueError, EOFError) as e:
        raise FormatError(f"{p}: unreadable or truncated .npy ({type(e).__name__}: {e})") from e
    if not isinstance(rows, np.ndarray):
        rows.close()
        raise FormatError(f"{p}: an npz archive, expected a single (N, 4) .npy array")
    _check_rows(rows, tuple(shape), p)
    return rows.astype(SURROUNDOCC_DTYPE, copy=False)


def load_surroundocc_grid(path: Path) -> LabelGrid:
    """A SurroundOcc ``.npy`` as a :class:`LabelGrid`: label k -> k + 1 so that 0 can be free (a
    voxel without a row; SurroundOcc's label 0 "noise" becomes class 1), no visibility mask, 0.5 m
    from :data:`SURROUNDOCC_RANGE` (LiDAR frame). ``FormatError`` naming the file for a label that
    does not fit the uint8 ids (0..254) or rows that do not make a grid."""
    rows = load_surroundocc(path)
    if len(rows) and int(rows[:, 3].max()) >= 255:
        raise FormatError(f"{path}: label {int(rows[:, 3].max())} does not fit the audit's uint8 ids (0..254)")
    shifted = rows.copy()
    shifted[:, 3] += 1  # label k -> k + 1 so that 0 can be free (SurroundOcc's label 0 is "noise")
    try:
        sem = surroundocc_to_dense(shifted, SURROUNDOCC_SHAPE, free=0)
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return LabelGrid(str(path), sem, None, SURROUNDOCC_VOXEL_SIZE, grid_origin(SURROUNDOCC_RANGE))


SURROUNDOCC_NAMES: tuple[str, ...] = ("noise",) + taxonomy.OCC3D_NUSCENES_NAMES[1:17]
"""SurroundOcc's label names: the nuScenes-lidarseg learning ids 0-16."""

SURROUNDOCC_FORMAT = DatasetFormat(
    "surroundocc", "SurroundOcc", ".npy", load_surroundocc_grid, SURROUNDOCC_NAMES, lambda i: i - 1,
    tuple(SURROUNDOCC_NAMES.index(n) + 1 for n in NUSCENES_DYNAMIC), "none")
"""The SurroundOcc layout (:mod:`carlaocc.catalog.formats.layout`)."""
