"""The CarlaOcc occupancy ``.npz`` of one frame: the one place that writes and reads it.

Keys (the official release's, fengyi233/carlaocc ``docs/source/occ_generation.rst``):

* ``occupancy``: ``(N, 4)`` **uint16** rows ``(x, y, z, label)``, one per occupied voxel
  (semantic id != 0, class 0 ``None`` being free), in C order of ``(x, y, z)``; indices 0-65535.
* ``voxel_size``: 0-d float64, metres.
* ``voxel_origin``: ``(3,)``, minimum corner of voxel (0, 0, 0), metres, LiDAR frame.
* ``volume_size``: ``(3,)`` integers, the grid shape ``(X, Y, Z)``.

Two label encodings (:data:`LABEL_ENCODINGS`):

* ``bits`` (the default): ``semantic << 11 | instance`` -- semantic 0-31 in the high 5 bits,
  instance 0-2047 in the low 11. This is what the release's code writes and reads
  (``utils/data_converter.py`` ``encode_combined_id`` / ``decode_combined_id``, used by
  ``occupancy_generation/generators/gen_pano_occ.py`` and by ``utils/load_utils.py``
  ``load_pano_occ``, the reader of ``tutorials/dataset.py``), with moving objects at
  ``1000 + id % 1000`` (``get_fg_instance_id``).
* ``decimal``: ``semantic * 1000 + instance`` -- semantic 0-64, instance 0-999: the formula of
  the release's documentation (``occ_generation.rst``), which its code does not follow. A file
  written so carries a fifth key, ``label_encoding`` = ``"decimal"``, so it is never misread;
  files without the key are ``bits``.

(The scalar dtypes of ``voxel_size`` / ``voxel_origin`` / ``volume_size`` are the writer's
choice; :func:`load_carlaocc_npz` accepts any real/integer dtype for them.)

Internally instances are uint32 and never wrap (docs/architecture.md "Instance ids"); the ranges
above are an export concern: :func:`save_carlaocc_npz` **refuses** ids that do not fit rather than
wrapping them, and
:func:`carlaocc.catalog.formats.carlaocc_release.release_instance_ids` gives a sequence's
instances ids that fit, stable across its frames.
"""

from __future__ import annotations

import io
import math
import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import FormatError, PathLike, atomic_write, read_npz
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid
from carlaocc.schemas import taxonomy

__all__ = [
    "CARLAOCC_KEYS",
    "CARLAOCC_NPZ_FORMAT",
    "LABEL_ENCODINGS",
    "LABEL_LIMITS",
    "MAX_INDEX",
    "CarlaOccFrame",
    "load_carlaocc_grid",
    "load_carlaocc_npz",
    "npz_bytes",
    "pack_ids",
    "CarlaOccRows",
    "load_carlaocc_rows",
    "save_carlaocc_npz",
    "unpack_ids",
]

LABEL_ENCODINGS: tuple[str, ...] = ("bits", "decimal")
LABEL_LIMITS: dict[str, tuple[int, int]] = {"bits": (31, 2047), "decimal": (64, 999)}
"""Largest semantic and instance id of each encoding."""
INSTANCE_BITS: int = 11
MAX_INDEX: int = 0xFFFF
CARLAOCC_KEYS: tuple[str, ...] = ("occupancy", "voxel_size", "voxel_origin", "volume_size")
ENCODING_KEY = "label_encoding"


def check_encoding(encoding: str) -> str:
    """``encoding`` when it is one of :data:`LABEL_ENCODINGS`; ``ValueError`` naming them otherwise."""
    if encoding not in LABEL_ENCODINGS:
        raise ValueError(f"label encoding must be one of {', '.join(LABEL_ENCODINGS)}, got {encoding!r}")
    return encoding


@dataclass(frozen=True)
class CarlaOccFrame:
    """One frame, dense: ``semantic`` uint8 and ``instance`` uint32, both ``(X, Y, Z)`` ``[x, y, z]``.

    ``voxel_size`` in metres, ``voxel_origin`` the minimum corner of voxel (0, 0, 0) (metres,
    LiDAR frame).
    """

    semantic: np.ndarray
    instance: np.ndarray
    voxel_size: float
    voxel_origin: tuple[float, float, float]


def pack_ids(semantic: np.ndarray, instance: np.ndarray, encoding: str = "bits") -> np.ndarray:
    """The uint16 labels of ``encoding``: ``semantic << 11 | instance`` (bits) or
    ``semantic * 1000 + instance`` (decimal); the caller guarantees the ids fit
    (:data:`LABEL_LIMITS`)."""
    s, i = np.asarray(semantic).astype(np.uint16), np.asarray(instance).astype(np.uint16)
    if check_encoding(encoding) == "bits":
        return (s << np.uint16(INSTANCE_BITS)) | i
    return (s * np.uint16(1000) + i).astype(np.uint16)


def unpack_ids(packed: np.ndarray, encoding: str = "bits") -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_ids`: ``(semantic uint8, instance uint32)``."""
    packed = np.asarray(packed).astype(np.uint16, copy=False)
    if check_encoding(encoding) == "bits":
        return (packed >> INSTANCE_BITS).astype(np.uint8), (packed & 0x7FF).astype(np.uint32)
    return (packed // 1000).astype(np.uint8), (packed % 1000).astype(np.uint32)


def _refuse(where: str, what: str, largest: int, limit: int, why: str) -> FormatError:
    return FormatError(f"{where}: {what} {largest} exceeds {limit} ({why}); refusing to wrap")


def save_carlaocc_npz(
    path: PathLike,
    semantic: np.ndarray,
    instance: np.ndarray,
    voxel_size: float,
    voxel_origin: Sequence[float],
    encoding: str = "bits",
) -> int:
    """Write a frame as a CarlaOcc ``.npz`` (deflated, atomic); returns the rows written.

    ``semantic``: integer ``(X, Y, Z)`` class ids (0 = free, not stored); ``instance``: integer
    ``(X, Y, Z)`` ids of the same shape (0 for stuff); ``encoding`` one of
    :data:`LABEL_ENCODINGS`. Refuses (``FormatError`` naming the largest offending value and the
    limit) ids beyond the encoding's :data:`LABEL_LIMITS`, a grid whose indices exceed 65535, and
    instance ids on free voxels (they would be lost).
    """
    where = f"{os.fspath(path)} (writing)"
    max_sem, max_inst = LABEL_LIMITS[check_encoding(encoding)]
    semantic = np.asarray(semantic)
    instance = np.asarray(instance)
    if semantic.ndim != 3 or instance.shape != semantic.shape:
        raise FormatError(f"{where}: semantic {semantic.shape} and instance {instance.shape} must be one 3-D shape")
    for name, a in (("semantic", semantic), ("instance", instance)):
        if not np.issubdtype(a.dtype, np.integer):
            raise FormatError(f"{where}: {name} must be integers, got {a.dtype}")
    if max(semantic.shape) - 1 > MAX_INDEX:
        raise _refuse(where, "voxel index", max(semantic.shape) - 1, MAX_INDEX, "16-bit indices")
    origin = tuple(float(v) for v in voxel_origin)
    if len(origin) != 3 or not all(math.isfinite(v) for v in origin):
        raise FormatError(f"{where}: voxel_origin must be 3 finite numbers, got {voxel_origin!r}")
    if not (math.isfinite(voxel_size) and voxel_size > 0):
        raise FormatError(f"{where}: voxel_size must be positive and finite, got {voxel_size!r}")

    idx = np.flatnonzero(semantic)
    sem = semantic.reshape(-1)[idx]
    inst = instance.reshape(-1)[idx]
    if semantic.size and semantic.min() < 0:
        raise FormatError(f"{where}: negative semantic id {int(semantic.min())}")
    if instance.size and instance.min() < 0:
        raise FormatError(f"{where}: negative instance id {int(instance.min())}")
    if sem.size and sem.max() > max_sem:
        raise _refuse(where, "semantic id", int(sem.max()), max_sem, f"the {encoding} encoding")
    if inst.size and inst.max() > max_inst:
        raise _refuse(where, "instance id", int(inst.max()), max_inst, f"the {encoding} encoding; see "
                      "carlaocc_release.release_instance_ids")
    stray = instance.reshape(-1)[semantic.reshape(-1) == 0]
    if stray.size and stray.max() > 0:
        raise FormatError(f"{where}: instance id {int(stray.max())} on a free voxel (semantic 0) would be lost")

    xyz = np.stack(np.unravel_index(idx, semantic.shape), axis=1).astype(np.uint16)
    arrays = {"occupancy": np.concatenate([xyz, pack_ids(sem, inst, encoding)[:, None]], axis=1),
              "voxel_size": np.float64(voxel_size), "voxel_origin": np.asarray(origin, dtype=np.float64),
              "volume_size": np.asarray(semantic.shape, dtype=np.int64)}  # fmt: skip
    if encoding != "bits":
        arrays[ENCODING_KEY] = np.asarray(encoding)
    data = npz_bytes(arrays)
    atomic_write(path, lambda fh: fh.write(data))
    return len(idx)


def npz_bytes(arrays: Mapping[str, np.ndarray], level: int = 1) -> bytes:
    """An ``.npz`` (deflated zip of ``.npy`` members, as ``np.savez_compressed`` writes and
    ``np.load`` reads) at zlib ``level``: level 1 writes a dense 0.1 m frame about five times
    faster than ``savez_compressed``'s default, for files a few percent larger."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=level) as zf:
        for name, a in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(a), allow_pickle=False)
    return buf.getvalue()


@dataclass(frozen=True)
class CarlaOccRows:
    """One frame, sparse, as a CarlaOcc ``.npz`` holds it: ``index`` (N, 3) int64 voxel indices
    ``i, j, k`` (C order over ``volume_size``), ``semantic`` (N,) uint8 (never 0) and ``instance``
    (N,) uint32; ``voxel_size`` m, ``voxel_origin`` the minimum corner of voxel (0, 0, 0) (m, LiDAR
    frame), ``volume_size`` voxels (x, y, z)."""

    index: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    voxel_size: float
    voxel_origin: tuple[float, float, float]
    volume_size: tuple[int, int, int]


def load_carlaocc_rows(path: PathLike) -> CarlaOccRows:
    """Read a CarlaOcc ``.npz`` without densifying it: its occupied voxels in C order, labels
    decoded as its ``label_encoding`` key says (``bits`` without one).

    ``FormatError`` naming the file for a missing key, a wrong shape/dtype, an index outside
    ``volume_size``, a row with semantic 0, a voxel listed twice, an unknown encoding, or a
    truncated archive.
    """
    p = os.fspath(path)
    a = read_npz(path, CARLAOCC_KEYS)
    encoding = "bits"
    with np.load(p, allow_pickle=False) as z:
        if ENCODING_KEY in z.files:
            encoding = str(z[ENCODING_KEY])
    if encoding not in LABEL_ENCODINGS:
        raise FormatError(f"{p}: unknown label_encoding {encoding!r} (known: {', '.join(LABEL_ENCODINGS)})")
    occ, voxel_size, vo, shape = a["occupancy"], a["voxel_size"], a["voxel_origin"], a["volume_size"]
    if occ.dtype != np.uint16 or occ.ndim != 2 or occ.shape[1] != 4:
        raise FormatError(f"{p}: occupancy must be (N, 4) uint16, got {occ.shape} {occ.dtype}")
    if shape.shape != (3,) or not np.issubdtype(shape.dtype, np.integer) or (shape <= 0).any():
        raise FormatError(f"{p}: volume_size must be 3 positive integers, got {shape!r}")
    if voxel_size.size != 1 or not np.issubdtype(voxel_size.dtype, np.number) or not (np.isfinite(voxel_size) & (voxel_size > 0)).all():
        raise FormatError(f"{p}: voxel_size must be one positive finite number, got {voxel_size!r}")
    if vo.shape != (3,) or not np.issubdtype(vo.dtype, np.number) or not np.isfinite(vo).all():
        raise FormatError(f"{p}: voxel_origin must be 3 finite numbers, got {vo!r}")
    dims = tuple(int(n) for n in shape)
    if len(occ):
        hi = occ[:, :3].max(axis=0)
        for axis, name in enumerate("xyz"):
            if hi[axis] >= dims[axis]:
                raise FormatError(f"{p}: {name} index {int(hi[axis])} outside volume_size {dims}")
    sem, inst = unpack_ids(occ[:, 3], encoding)
    if (sem == 0).any():
        raise FormatError(f"{p}: {int((sem == 0).sum())} occupancy rows have semantic 0 (free)")
    flat = np.ravel_multi_index(tuple(occ[:, :3].T.astype(np.intp)), dims)
    # C order over the volume (the file may list its rows in any order); a repeat is adjacent then
    order = np.argsort(flat, kind="stable")
    flat = flat[order]
    if len(flat) > 1 and (np.diff(flat) == 0).any():
        raise FormatError(f"{p}: occupancy lists some voxel more than once")
    origin = tuple(float(v) for v in vo)
    return CarlaOccRows(occ[order, :3].astype(np.int64), sem[order], inst[order], float(voxel_size.reshape(())),
                        origin, dims)  # type: ignore[arg-type]


def load_carlaocc_npz(path: PathLike) -> CarlaOccFrame:
    """Read a CarlaOcc ``.npz`` and rebuild the dense ``semantic`` (uint8) / ``instance`` (uint32)
    (:func:`load_carlaocc_rows`, whose ``FormatError`` it raises)."""
    rows = load_carlaocc_rows(path)
    semantic = np.zeros(rows.volume_size, dtype=np.uint8)
    instance = np.zeros(rows.volume_size, dtype=np.uint32)
    flat = np.ravel_multi_index(tuple(rows.index.T), rows.volume_size)
    semantic.reshape(-1)[flat] = rows.semantic
    instance.reshape(-1)[flat] = rows.instance
    return CarlaOccFrame(semantic, instance, rows.voxel_size, rows.voxel_origin)


def load_carlaocc_grid(path: Path) -> LabelGrid:
    """A CarlaOcc ``.npz`` as a :class:`LabelGrid`: its semantic ids (0 = free), no visibility
    mask, the file's own voxel size and origin (LiDAR frame)."""
    f = load_carlaocc_npz(path)
    return LabelGrid(str(path), f.semantic, None, f.voxel_size, f.voxel_origin)


CARLAOCC_NPZ_FORMAT = DatasetFormat(
    "carlaocc-npz", "CarlaOcc", ".npz", load_carlaocc_grid, tuple(c.name for c in taxonomy.CLASSES),
    lambda i: i, taxonomy.dynamic_ids(), "none")
"""The CarlaOcc ``.npz`` layout (:mod:`carlaocc.catalog.formats.layout`)."""
