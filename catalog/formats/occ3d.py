"""Occ3D-nuScenes ground truth: one ``labels.npz`` per sample.

Layout (checked against the real sample ``occupancy/occ3d-nuscenes/labels.npz`` of testdata, from
the CVPR2023-3D-Occupancy-Prediction repository):

* a **compressed** npz (zip members deflated, as written by ``np.savez_compressed``) holding,
  in this order, ``semantics``, ``mask_lidar``, ``mask_camera``;
* each array ``uint8``, shape ``(200, 200, 16)``, C order, indexed ``[x, y, z]``;
* ``semantics``: Occ3D class ids 0-17 (:data:`carlaocc.schemas.taxonomy.OCC3D_NUSCENES_NAMES`), 17 = free;
* ``mask_lidar`` / ``mask_camera``: 1 where the voxel is observed by the LiDAR / the cameras,
  else 0.

Frame and units: the **ego** frame, metres; voxel ``(i, j, k)`` covers
``OCC3D_RANGE[:3] + (i, j, k) * 0.4`` to ``+ 0.4`` (range -40..40 in x and y, -1..5.4 in z).

:func:`load_occ3d` accepts any common 3-D shape (other Occ3D variants, e.g. Waymo, differ) but
requires the three keys, uint8 arrays of one shape and 0/1 masks. Semantic ids are not
range-checked (the free id differs between Occ3D variants: 17 for nuScenes, 23 for Waymo).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import FormatError, PathLike, atomic_write, read_npz
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid, grid_origin
from carlaocc.schemas import taxonomy

__all__ = [
    "NUSCENES_DYNAMIC",
    "OCC3D_FORMAT",
    "OCC3D_FREE",
    "OCC3D_KEYS",
    "OCC3D_RANGE",
    "OCC3D_SHAPE",
    "OCC3D_VOXEL_SIZE",
    "Occ3DFrame",
    "load_occ3d",
    "load_occ3d_grid",
    "save_occ3d",
]

OCC3D_SHAPE: tuple[int, int, int] = (200, 200, 16)
OCC3D_FREE: int = 17
OCC3D_VOXEL_SIZE: float = 0.4
OCC3D_RANGE: tuple[float, float, float, float, float, float] = (-40.0, -40.0, -1.0, 40.0, 40.0, 5.4)
"""(x_min, y_min, z_min, x_max, y_max, z_max), metres, ego frame."""
OCC3D_KEYS: tuple[str, str, str] = ("semantics", "mask_lidar", "mask_camera")
NUSCENES_DYNAMIC: tuple[str, ...] = ("bicycle", "bus", "car", "construction_vehicle", "motorcycle", "pedestrian",
                                     "trailer", "truck")
"""The nuScenes classes of road users (Occ3D and SurroundOcc names), left out of temporal scores."""


@dataclass(frozen=True)
class Occ3DFrame:
    """One Occ3D sample: three uint8 ``(X, Y, Z)`` arrays indexed ``[x, y, z]``, ego frame.

    ``semantics`` holds Occ3D ids (17 = free); the masks hold 0/1.
    """

    semantics: np.ndarray
    mask_lidar: np.ndarray
    mask_camera: np.ndarray


def _validate(arrays: dict[str, np.ndarray], where: str) -> None:
    shape = arrays["semantics"].shape
    for key in OCC3D_KEYS:
        a = arrays[key]
        if a.dtype != np.uint8:
            raise FormatError(f"{where}: {key} must be uint8, got {a.dtype}")
        if a.ndim != 3:
            raise FormatError(f"{where}: {key} must be 3-D (X, Y, Z), got shape {a.shape}")
        if a.shape != shape:
            raise FormatError(f"{where}: {key} has shape {a.shape}, semantics has {shape}")
    for key in OCC3D_KEYS[1:]:
        if arrays[key].size and arrays[key].max() > 1:
            raise FormatError(f"{where}: {key} must hold 0/1, found {int(arrays[key].max())}")


def save_occ3d(path: PathLike, frame: Occ3DFrame) -> None:
    """Write ``frame`` as an Occ3D ``labels.npz`` (``np.savez_compressed``, atomic).

    Refuses (``FormatError``) arrays that are not uint8 or not of one 3-D shape.
    """
    arrays = {k: np.asarray(getattr(frame, k)) for k in OCC3D_KEYS}
    _validate(arrays, f"{os.fspath(path)} (writing)")
    # Serialise in memory first: np.savez_* appends ".npz" to string names, and the temp file
    # must receive the exact bytes.
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.ascontiguousarray(arrays[k]) for k in OCC3D_KEYS})
    atomic_write(path, lambda fh: fh.write(buf.getbuffer()))


def load_occ3d(path: PathLike) -> Occ3DFrame:
    """Read an Occ3D ``labels.npz``; validates keys, dtype uint8 and one common 3-D shape."""
    arrays = read_npz(path, OCC3D_KEYS)
    _validate(arrays, os.fspath(path))
    return Occ3DFrame(**arrays)


def load_occ3d_grid(path: Path) -> LabelGrid:
    """An Occ3D-nuScenes ``labels.npz`` as a :class:`LabelGrid`: ids shifted by one so that 0 is
    free (free 17 -> 0, class k -> k + 1), ``mask_camera`` as the visibility mask, the nuScenes
    geometry (0.4 m from :data:`OCC3D_RANGE`, ego frame). ``FormatError`` naming the file for
    another shape or an id above 17."""
    f = load_occ3d(path)
    sem = f.semantics
    # the reader takes any Occ3D variant; the audit's geometry and names are Occ3D-nuScenes'
    if sem.shape != OCC3D_SHAPE:
        raise FormatError(f"{path}: Occ3D-nuScenes grids are {OCC3D_SHAPE} (0.4 m from {OCC3D_RANGE[:3]}), "
                          f"got {sem.shape}")
    if sem.size and int(sem.max()) > OCC3D_FREE:
        raise FormatError(f"{path}: Occ3D-nuScenes ids are 0..{OCC3D_FREE} ({OCC3D_FREE} = free), "
                          f"found {int(sem.max())}")
    # free (17) -> 0, class k -> k + 1
    lut = (np.arange(256) + 1).astype(np.uint8)
    lut[OCC3D_FREE] = 0
    return LabelGrid(str(path), lut[sem], f.mask_camera.astype(bool), OCC3D_VOXEL_SIZE, grid_origin(OCC3D_RANGE))


_NAMES = taxonomy.OCC3D_NUSCENES_NAMES
OCC3D_FORMAT = DatasetFormat(
    "occ3d", "Occ3D-nuScenes", "labels.npz", load_occ3d_grid, _NAMES, lambda i: i - 1,
    tuple(_NAMES.index(n) + 1 for n in NUSCENES_DYNAMIC), "mask_camera",
    # gts/<scene>/<sample_token>/labels.npz: the scene is the sequence, the token names the frame
    sequence=lambda p: p.parent.parent, numbered=False, token=lambda p: p.parent.name)
"""The Occ3D-nuScenes layout (:mod:`carlaocc.catalog.formats.layout`)."""
