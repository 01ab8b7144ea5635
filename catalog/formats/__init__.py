"""Readers and writers of the external occupancy formats that models train on.

One module per format, each with ``save_*`` / ``load_*`` (one place per format), a
``load_*_grid`` reading a frame as a :class:`~carlaocc.catalog.formats.layout.LabelGrid` for the quality
scores, and its ``*_FORMAT`` layout (file ending, sequences, class names; :data:`FORMATS` by name):

* :mod:`carlaocc.catalog.formats.occ3d` -- Occ3D-nuScenes ``labels.npz`` (dense uint8, ego frame).
* :mod:`carlaocc.catalog.formats.semantickitti` -- SemanticKITTI SSC voxels (``.bin/.invalid/.occluded``
  bit-packed grids, ``.label`` uint16), LiDAR frame.
* :mod:`carlaocc.catalog.formats.surroundocc` -- SurroundOcc sparse ``(N, 4)`` voxel rows, LiDAR frame.
* :mod:`carlaocc.catalog.formats.carlaocc_npz` -- a CarlaOcc ``.npz`` per frame on our grid (``semantic * 1000 + instance``).
* :mod:`carlaocc.catalog.formats.carlaocc_release` -- the official release's folder layout (grids, calib, poses, splits, images).

Shared by the audit of these datasets:

* :mod:`carlaocc.catalog.formats.layout` -- :class:`DatasetFormat` (how a format lies on disk),
  :class:`LabelGrid`, collecting a dataset's files, grouping them into sequences, reading a frame.
* :mod:`carlaocc.catalog.formats.poses` -- pose files (``.npy``, ``.json`` keyed by frame, KITTI
  ``poses.txt`` and ``calib.txt``) and the sequences their frames form with them.

Conventions shared by every module:

* Paths are ``str | os.PathLike``. A missing file raises the ordinary :class:`FileNotFoundError`;
  a file that exists but is not a valid instance of its format raises :class:`FormatError`, whose
  message names the file and says what is wrong (missing key, wrong shape/dtype, truncated file,
  ids out of range).
* Writers are atomic: the bytes go to a temporary file in the destination directory, are flushed
  to disk, and ``os.replace`` puts them in place, so a crash never leaves a half-written file.
  Writers refuse (``FormatError``) to write data the format cannot represent, instead of wrapping.
* Functions are small and numpy-only; arrays are indexed ``[x, y, z]`` unless a module says
  otherwise.
"""

from __future__ import annotations

import os
import uuid
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import IO, Union

import numpy as np

PathLike = Union[str, "os.PathLike[str]"]


class FormatError(ValueError):
    """A file (or an array about to be written) is not a valid instance of its format."""


class DatasetInputError(ValueError):
    """Bad input naming a dataset's files: an unknown format, a path without files, an unreadable
    file (the reader's message, naming it), poses that do not fit the frames."""


def atomic_write(path: PathLike, write: Callable[[IO[bytes]], None]) -> Path:
    """Call ``write(fh)`` on a temporary file next to ``path``, fsync it, then ``os.replace``.

    Parent directories are created. On any exception the temporary file is removed and ``path``
    is left as it was. Returns ``path`` as a :class:`~pathlib.Path`.
    """
    final = Path(os.fspath(path))
    final.parent.mkdir(parents=True, exist_ok=True)
    # os.open with 0o666 (not tempfile.mkstemp, whose 0o600 would stick to the final file), so
    # the result gets the usual umask-derived permissions.
    tmp = final.parent / f".{final.name}.{uuid.uuid4().hex}.partial"
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return final


def read_npz(path: PathLike, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Read arrays ``keys`` from the ``.npz`` at ``path`` (no pickles), fully into memory.

    Raises :class:`FileNotFoundError` if ``path`` does not exist and :class:`FormatError` (naming
    the file) if it is not a readable npz (truncated, corrupt member) or lacks one of ``keys``.
    """
    p = os.fspath(path)
    try:
        loaded = np.load(p, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise FormatError(f"{p}: not an npz archive (it holds a single .npy array)")
        with loaded as z:
            missing = [k for k in keys if k not in z.files]
            if missing:
                raise FormatError(f"{p}: missing key(s) {missing}; present: {sorted(z.files)}")
            return {k: z[k] for k in keys}
    except (FormatError, FileNotFoundError):
        raise
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as e:
        raise FormatError(f"{p}: unreadable or truncated npz ({type(e).__name__}: {e})") from e


# Public API, re-exported (defined after FormatError, which the modules import from here).
from carlaocc.catalog.formats.carlaocc_npz import (
    CARLAOCC_NPZ_FORMAT,
    CarlaOccFrame,
    load_carlaocc_npz,
    save_carlaocc_npz,
)
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid
from carlaocc.catalog.formats.occ3d import OCC3D_FORMAT, Occ3DFrame, load_occ3d, save_occ3d
from carlaocc.catalog.formats.semantickitti import (
    SEMANTICKITTI_FORMAT,
    SemanticKittiVoxels,
    load_semantickitti,
    save_semantickitti,
    to_learning,
    to_raw,
)
from carlaocc.catalog.formats.surroundocc import (
    SURROUNDOCC_FORMAT,
    dense_to_surroundocc,
    load_surroundocc,
    save_surroundocc,
    surroundocc_to_dense,
)

FORMATS: dict[str, DatasetFormat] = {
    f.name: f for f in (OCC3D_FORMAT, SEMANTICKITTI_FORMAT, SURROUNDOCC_FORMAT, CARLAOCC_NPZ_FORMAT)
}
"""The dataset layouts by their command-line name: occ3d, semantickitti, surroundocc, carlaocc-npz."""


def dataset_format(name: str) -> DatasetFormat:
    """The layout named ``name``; :class:`DatasetInputError` naming the known ones otherwise."""
    try:
        return FORMATS[name]
    except KeyError:
        raise DatasetInputError(f"unknown format {name!r}; choose one of {', '.join(FORMATS)}") from None


__all__ = [
    "FORMATS",
    "CarlaOccFrame",
    "DatasetFormat",
    "DatasetInputError",
    "FormatError",
    "LabelGrid",
    "Occ3DFrame",
    "PathLike",
    "SemanticKittiVoxels",
    "atomic_write",
    "dataset_format",
    "dense_to_surroundocc",
    "load_carlaocc_npz",
    "load_occ3d",
    "load_semantickitti",
    "load_surroundocc",
    "read_npz",
    "save_carlaocc_npz",
    "save_occ3d",
    "save_semantickitti",
    "save_surroundocc",
    "surroundocc_to_dense",
    "to_learning",
    "to_raw",
]
