"""SemanticKITTI semantic scene completion voxels: four files per scan, ``<stem>.<ext>``.

Layout (confirmed against ``PRBonn/semantic-kitti-api`` ``auxiliary/SSCDataset.py``: ``unpack``
reads bit 7 of each byte first, ``.label`` is read with ``np.fromfile(dtype=np.uint16)`` and
everything is reshaped C-order to ``VOXEL_DIMS = (256, 256, 32)``):

* ``<stem>.bin`` (occupancy), ``<stem>.invalid``, ``<stem>.occluded``: a bool grid of shape
  ``(256, 256, 32)`` flattened in C order and bit-packed **MSB first** (``np.packbits`` default
  ``bitorder="big"``): 256*256*32/8 = 262 144 bytes each, no header;
* ``<stem>.label``: ``uint16`` little-endian raw SemanticKITTI label ids (0 = empty/unlabeled,
  10 = car, ... 259), C order: 2 bytes per voxel = 4 194 304 bytes, no header.

Axes ``[x, y, z]``; frame: the KITTI LiDAR (velodyne) frame, metres; voxel size 0.2 m over
x [0, 51.2], y [-25.6, 25.6], z [-2, 4.4] (:data:`SEMANTICKITTI_RANGE`).

``learning_map`` / ``learning_map_inv`` (raw id <-> the 20 training ids) are embedded below; the
tests check them against ``semantic-kitti.yaml``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import FormatError, PathLike, atomic_write
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid, grid_origin
from carlaocc.schemas import taxonomy

__all__ = [
    "LEARNING_MAP",
    "LEARNING_MAP_INV",
    "SEMANTICKITTI_FORMAT",
    "SEMANTICKITTI_RANGE",
    "SEMANTICKITTI_SHAPE",
    "SEMANTICKITTI_VOXEL_SIZE",
    "SemanticKittiVoxels",
    "load_semantickitti",
    "load_semantickitti_grid",
    "save_semantickitti",
    "scan_paths",
    "to_learning",
    "to_raw",
]

SEMANTICKITTI_SHAPE: tuple[int, int, int] = (256, 256, 32)
SEMANTICKITTI_VOXEL_SIZE: float = 0.2
SEMANTICKITTI_RANGE: tuple[float, float, float, float, float, float] = (0.0, -25.6, -2.0, 51.2, 25.6, 4.4)
"""(x_min, y_min, z_min, x_max, y_max, z_max), metres, LiDAR frame."""

_N = SEMANTICKITTI_SHAPE[0] * SEMANTICKITTI_SHAPE[1] * SEMANTICKITTI_SHAPE[2]
BITS_BYTES: int = _N // 8
LABEL_BYTES: int = _N * 2
_BIT_EXTS: tuple[str, str, str] = ("invalid", "occluded", "bin")
_LABEL_DTYPE = np.dtype("<u2")

# Source: SemanticKITTI semantic-kitti.yaml (semantic-kitti-api config), ``learning_map``.
LEARNING_MAP: dict[int, int] = {
    0: 0, 1: 0, 10: 1, 11: 2, 13: 5, 15: 3, 16: 5, 18: 4, 20: 5, 30: 6, 31: 7, 32: 8, 40: 9,
    44: 10, 48: 11, 49: 12, 50: 13, 51: 14, 52: 0, 60: 9, 70: 15, 71: 16, 72: 17, 80: 18, 81: 19,
    99: 0, 252: 1, 253: 7, 254: 6, 255: 8, 256: 5, 257: 5, 258: 4, 259: 5,
}  # fmt: skip
# Source: the same file, ``learning_map_inv``.
LEARNING_MAP_INV: dict[int, int] = {
    0: 0, 1: 10, 2: 11, 3: 15, 4: 18, 5: 20, 6: 30, 7: 31, 8: 32, 9: 40, 10: 44, 11: 48, 12: 49,
    13: 50, 14: 51, 15: 70, 16: 71, 17: 72, 18: 80, 19: 81,
}  # fmt: skip

_UNMAPPED = -1
_TO_LEARNING = np.full(max(LEARNING_MAP) + 1, _UNMAPPED, dtype=np.int16)
_TO_LEARNING[list(LEARNING_MAP)] = list(LEARNING_MAP.values())
_TO_RAW = np.array([LEARNING_MAP_INV[i] for i in range(len(LEARNING_MAP_INV))], dtype=np.uint16)


def to_learning(labels: np.ndarray) -> np.ndarray:
    """Raw SemanticKITTI ids (any integer array) -> learning ids 0..19, uint8, same shape.

    ``ValueError`` naming the offending ids if some id is not a key of :data:`LEARNING_MAP`.
    """
    labels = np.asarray(labels)
    flat = labels.ravel()
    bad = (flat < 0) | (flat >= len(_TO_LEARNING))
    out = np.full(flat.shape, _UNMAPPED, dtype=np.int16)
    out[~bad] = _TO_LEARNING[flat[~bad]]
    if (out == _UNMAPPED).any():
        ids = np.unique(flat[out == _UNMAPPED])
        raise ValueError(f"raw SemanticKITTI ids without a learning id: {ids[:10].tolist()}")
    return out.astype(np.uint8).reshape(labels.shape)


def to_raw(learning: np.ndarray) -> np.ndarray:
    """Learning ids 0..19 (any integer array) -> raw SemanticKITTI ids, uint16, same shape.

    ``ValueError`` naming the offending ids if some id is outside 0..19.
    """
    learning = np.asarray(learning)
    bad = (learning < 0) | (learning >= len(_TO_RAW))
    if bad.any():
        raise ValueError(f"learning ids outside 0..{len(_TO_RAW) - 1}: {np.unique(learning[bad])[:10].tolist()}")
    return _TO_RAW[learning]


@dataclass(frozen=True)
class SemanticKittiVoxels:
    """One scan's voxels, each ``(256, 256, 32)`` indexed ``[x, y, z]`` (LiDAR frame, 0.2 m).

    ``occupied``, ``invalid``, ``occluded``: bool. ``labels``: uint16 raw SemanticKITTI ids.
    """

    occupied: np.ndarray
    invalid: np.ndarray
    occluded: np.ndarray
    labels: np.ndarray


def scan_paths(directory: PathLike, stem: str) -> dict[str, Path]:
    """Paths of a scan's four files, keyed by extension (``bin``, ``invalid``, ``occluded``, ``label``)."""
    d = Path(os.fspath(directory))
    return {ext: d / f"{stem}.{ext}" for ext in ("bin", "invalid", "occluded", "label")}


def _check_grid(name: str, a: np.ndarray, dtype: type) -> None:
    if a.shape != SEMANTICKITTI_SHAPE:
        raise FormatError(f"SemanticKITTI {name}: shape {a.shape}, expected {SEMANTICKITTI_SHAPE}")
    if a.dtype != dtype:
        raise FormatError(f"SemanticKITTI {name}: dtype {a.dtype}, expected {np.dtype(dtype)}")


def save_semantickitti(directory: PathLike, stem: str, voxels: SemanticKittiVoxels) -> dict[str, Path]:
    """Write ``<stem>.bin/.invalid/.occluded/.label`` into ``directory`` (created if missing).

    Each file is written atomically; ``.bin`` is written last, so a scan whose ``.bin`` is present
    (the file SemanticKITTI tools enumerate scans by) has all its companions. Returns the paths.
    """
    grids = {"bin": voxels.occupied, "invalid": voxels.invalid, "occluded": voxels.occluded}
    for ext, a in grids.items():
        _check_grid(f"{stem}.{ext}", np.asarray(a), np.bool_)
    _check_grid(f"{stem}.label", np.asarray(voxels.labels), np.uint16)
    paths = scan_paths(directory, stem)
    label_bytes = np.ascontiguousarray(voxels.labels, dtype=_LABEL_DTYPE).tobytes()
    atomic_write(paths["label"], lambda fh: fh.write(label_bytes))
    for ext in _BIT_EXTS:
        packed = np.packbits(np.ascontiguousarray(grids[ext]).ravel(), bitorder="big").tobytes()
        atomic_write(paths[ext], lambda fh, b=packed: fh.write(b))
    return paths


def _read_exact(path: Path, size: int, what: str) -> bytes:
    data = path.read_bytes()
    if len(data) != size:
        state = "truncated" if len(data) < size else "too long"
        raise FormatError(f"{path}: {state} {what}: {len(data)} bytes, expected {size} for {SEMANTICKITTI_SHAPE}")
    return data


def load_semantickitti(directory: PathLike, stem: str) -> SemanticKittiVoxels:
    """Read the four files of scan ``stem``; checks each file's exact byte size.

    ``FileNotFoundError`` if a file is missing, ``FormatError`` naming the file if its size is
    wrong.
    """
    paths = scan_paths(directory, stem)
    grids = {}
    for ext in _BIT_EXTS:
        raw = np.frombuffer(_read_exact(paths[ext], BITS_BYTES, "bit-packed grid"), dtype=np.uint8)
        grids[ext] = np.unpackbits(raw, bitorder="big").view(np.bool_).reshape(SEMANTICKITTI_SHAPE)
    raw = _read_exact(paths["label"], LABEL_BYTES, "uint16 label grid")
    labels = np.frombuffer(raw, dtype=_LABEL_DTYPE).astype(np.uint16).reshape(SEMANTICKITTI_SHAPE)
    return SemanticKittiVoxels(
        occupied=grids["bin"], invalid=grids["invalid"], occluded=grids["occluded"], labels=labels
    )


def load_semantickitti_grid(path: Path) -> LabelGrid:
    """The scan of a SemanticKITTI ``<stem>.label`` as a :class:`LabelGrid`: the learning ids
    (0 = empty), not ``.invalid`` as the visibility mask, 0.2 m from :data:`SEMANTICKITTI_RANGE`
    (LiDAR frame). ``FormatError`` naming the file for a raw id without a learning id."""
    v = load_semantickitti(path.parent, path.name[: -len(".label")])
    try:
        sem = to_learning(v.labels)
    except ValueError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return LabelGrid(str(path), sem, ~v.invalid, SEMANTICKITTI_VOXEL_SIZE, grid_origin(SEMANTICKITTI_RANGE))


SEMANTICKITTI_FORMAT = DatasetFormat(
    "semantickitti", "SemanticKITTI", ".label", load_semantickitti_grid, taxonomy.SEMANTICKITTI_NAMES,
    lambda i: i, tuple(range(1, 9)), "not .invalid",
    # voxel scans only: the point-cloud labels/*.label of a sequence have no .invalid beside them
    accept=lambda p: p.with_suffix(".invalid").is_file())
"""The SemanticKITTI voxel layout (:mod:`carlaocc.catalog.formats.layout`)."""
