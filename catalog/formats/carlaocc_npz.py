"""The published CarlaOcc occupancy ``.npz`` (the layout of the released dataset).

Written with ``np.savez_compressed``; keys:

* ``occupancy``: ``(N, 4)`` **uint16** rows ``(x, y, z, sem << 11 | inst)``, one per occupied
  voxel (semantic id != 0, class 0 ``None`` being free), in C order of ``(x, y, z)``. The packed
  id gives the semantic class 5 bits (0-31) and the instance id 11 bits (0-2047); indices are
  16 bits (0-65535).
* ``voxel_size``: 0-d float64, metres.
* ``voxel_origin``: ``(3,)`` float64, minimum corner of voxel (0, 0, 0), metres, LiDAR frame.
* ``volume_size``: ``(3,)`` int64, the grid shape ``(X, Y, Z)``.

(The scalar dtypes of ``voxel_size`` / ``voxel_origin`` / ``volume_size`` are this module's
choice; :func:`load_carlaocc_npz` accepts any real/integer dtype for them.)

Internally instances are uint32 and never wrap (DESIGN.md); the 11-bit cap is an export concern:
:func:`save_carlaocc_npz` **refuses** ids that do not fit rather than wrapping them, and
:func:`published_instance_ids` gives a sequence's instances the published ids (static things
1..999, actors 1000 + id mod 1000), stable across its frames, applied with
:func:`remap_instances`.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carlaocc.catalog.formats import FormatError, PathLike, atomic_write, read_npz
from carlaocc.catalog.formats.layout import DatasetFormat, LabelGrid
from carlaocc.schemas import taxonomy

__all__ = [
    "CARLAOCC_KEYS",
    "CARLAOCC_NPZ_FORMAT",
    "INSTANCE_BITS",
    "MAX_INDEX",
    "MAX_INSTANCE",
    "MAX_SEMANTIC",
    "CarlaOccFrame",
    "load_carlaocc_grid",
    "load_carlaocc_npz",
    "pack_ids",
    "published_instance_ids",
    "remap_instances",
    "save_carlaocc_npz",
    "unpack_ids",
]

INSTANCE_BITS: int = 11
MAX_SEMANTIC: int = (1 << (16 - INSTANCE_BITS)) - 1  # 31
MAX_INSTANCE: int = (1 << INSTANCE_BITS) - 1  # 2047
MAX_INDEX: int = 0xFFFF
CARLAOCC_KEYS: tuple[str, ...] = ("occupancy", "voxel_size", "voxel_origin", "volume_size")


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


def pack_ids(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """``sem << 11 | inst`` as uint16; caller guarantees ``sem <= 31`` and ``inst <= 2047``."""
    return (semantic.astype(np.uint16) << INSTANCE_BITS) | instance.astype(np.uint16)


def unpack_ids(packed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`pack_ids`: ``(semantic uint8, instance uint32)``."""
    packed = packed.astype(np.uint16, copy=False)
    return (packed >> INSTANCE_BITS).astype(np.uint8), (packed & MAX_INSTANCE).astype(np.uint32)


def _refuse(where: str, what: str, largest: int, limit: int, why: str) -> FormatError:
    return FormatError(f"{where}: {what} {largest} exceeds {limit} ({why}); refusing to wrap")


def save_carlaocc_npz(
    path: PathLike,
    semantic: np.ndarray,
    instance: np.ndarray,
    voxel_size: float,
    voxel_origin: Sequence[float],
) -> None:
    """Write a frame as a CarlaOcc ``.npz`` (``np.savez_compressed``, atomic).

    ``semantic``: integer ``(X, Y, Z)`` class ids (0 = free, not stored); ``instance``: integer
    ``(X, Y, Z)`` ids of the same shape (0 for stuff). Refuses (``FormatError`` naming the largest
    offending value and the limit) a semantic id > 31, an instance id > 2047, a grid whose indices
    exceed 65535, and instance ids on free voxels (they would be lost).
    """
    where = f"{os.fspath(path)} (writing)"
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
    if sem.size and sem.max() > MAX_SEMANTIC:
        raise _refuse(where, "semantic id", int(sem.max()), MAX_SEMANTIC, "5 bits")
    if inst.size and inst.max() > MAX_INSTANCE:
        raise _refuse(where, "instance id", int(inst.max()), MAX_INSTANCE, "11 bits; see published_instance_ids")
    stray = instance.reshape(-1)[semantic.reshape(-1) == 0]
    if stray.size and stray.max() > 0:
        raise FormatError(f"{where}: instance id {int(stray.max())} on a free voxel (semantic 0) would be lost")

    xyz = np.stack(np.unravel_index(idx, semantic.shape), axis=1).astype(np.uint16)
    occupancy = np.concatenate([xyz, pack_ids(sem, inst)[:, None]], axis=1)
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        occupancy=occupancy,
        voxel_size=np.float64(voxel_size),
        voxel_origin=np.asarray(origin, dtype=np.float64),
        volume_size=np.asarray(semantic.shape, dtype=np.int64),
    )
    atomic_write(path, lambda fh: fh.write(buf.getbuffer()))


def load_carlaocc_npz(path: PathLike) -> CarlaOccFrame:
    """Read a CarlaOcc ``.npz`` and rebuild the dense ``semantic`` (uint8) / ``instance`` (uint32).

    ``FormatError`` naming the file for a missing key, a wrong shape/dtype, an index outside
    ``volume_size``, a row with semantic 0, a voxel listed twice, or a truncated archive.
    """
    p = os.fspath(path)
    a = read_npz(path, CARLAOCC_KEYS)
    occ, vs, vo, shape = a["occupancy"], a["voxel_size"], a["voxel_origin"], a["volume_size"]
    if occ.dtype != np.uint16 or occ.ndim != 2 or occ.shape[1] != 4:
        raise FormatError(f"{p}: occupancy must be (N, 4) uint16, got {occ.shape} {occ.dtype}")
    if shape.shape != (3,) or not np.issubdtype(shape.dtype, np.integer) or (shape <= 0).any():
        raise FormatError(f"{p}: volume_size must be 3 positive integers, got {shape!r}")
    if vs.size != 1 or not np.issubdtype(vs.dtype, np.number) or not (np.isfinite(vs) & (vs > 0)).all():
        raise FormatError(f"{p}: voxel_size must be one positive finite number, got {vs!r}")
    if vo.shape != (3,) or not np.issubdtype(vo.dtype, np.number) or not np.isfinite(vo).all():
        raise FormatError(f"{p}: voxel_origin must be 3 finite numbers, got {vo!r}")
    dims = tuple(int(n) for n in shape)
    if len(occ):
        hi = occ[:, :3].max(axis=0)
        for axis, name in enumerate("xyz"):
            if hi[axis] >= dims[axis]:
                raise FormatError(f"{p}: {name} index {int(hi[axis])} outside volume_size {dims}")
    sem, inst = unpack_ids(occ[:, 3])
    if (sem == 0).any():
        raise FormatError(f"{p}: {int((sem == 0).sum())} occupancy rows have semantic 0 (free)")
    flat = np.ravel_multi_index(tuple(occ[:, :3].T.astype(np.intp)), dims)
    if len(np.unique(flat)) != len(flat):
        raise FormatError(f"{p}: occupancy lists some voxel more than once")
    semantic = np.zeros(dims, dtype=np.uint8)
    instance = np.zeros(dims, dtype=np.uint32)
    semantic.reshape(-1)[flat] = sem
    instance.reshape(-1)[flat] = inst
    origin = tuple(float(v) for v in vo)
    return CarlaOccFrame(semantic, instance, float(vs.reshape(())), origin)  # type: ignore[arg-type]


def published_instance_ids(ids: np.ndarray, actor_ids: np.ndarray, where: str = "sequence") -> np.ndarray:
    """The published CarlaOcc id of each of a sequence's instances (DESIGN.md): static things
    numbered 1..999 in id order, simulated actors at 1000 + (id mod 1000).

    ``ids``: the sorted unique nonzero instance ids appearing in the sequence; ``actor_ids``: the
    ids of its simulated actors. Returns int64 new ids aligned with ``ids``. Refuses
    (:class:`FormatError` naming ``where``) more than 999 static things or two actors equal
    modulo 1000 instead of wrapping.
    """
    ids = np.asarray(ids).astype(np.int64, copy=False)
    is_actor = np.isin(ids, np.asarray(actor_ids).astype(np.int64, copy=False))
    n_static = int((~is_actor).sum())
    if n_static > 999:
        raise FormatError(f"{where}: {n_static} static instances, more than CarlaOcc npz's ids 1-999 hold")
    new = np.zeros(len(ids), dtype=np.int64)
    new[~is_actor] = np.arange(1, n_static + 1)
    new[is_actor] = 1000 + ids[is_actor] % 1000
    if len(np.unique(new[is_actor])) != int(is_actor.sum()):
        raise FormatError(f"{where}: two actors share an id modulo 1000 (CarlaOcc npz's 1000-1999 range)")
    return new


def remap_instances(instance: np.ndarray, ids: np.ndarray, new: np.ndarray) -> np.ndarray:
    """uint32 copy of ``instance`` with each id of the sorted ``ids`` replaced by ``new`` (0 stays
    0; every nonzero value must be in ``ids``)."""
    f = np.asarray(instance)
    if len(ids) == 0:
        return np.zeros(f.shape, dtype=np.uint32)
    pos = np.minimum(np.searchsorted(ids, f), len(ids) - 1)  # the clip only guards zeros
    return np.where(f == 0, 0, np.asarray(new)[pos]).astype(np.uint32)


def load_carlaocc_grid(path: Path) -> LabelGrid:
    """A CarlaOcc ``.npz`` as a :class:`LabelGrid`: its semantic ids (0 = free), no visibility
    mask, the file's own voxel size and origin (LiDAR frame)."""
    f = load_carlaocc_npz(path)
    return LabelGrid(str(path), f.semantic, None, f.voxel_size, f.voxel_origin)


CARLAOCC_NPZ_FORMAT = DatasetFormat(
    "carlaocc-npz", "CarlaOcc", ".npz", load_carlaocc_grid, tuple(c.name for c in taxonomy.CLASSES),
    lambda i: i, taxonomy.dynamic_ids(), "none")
"""The published CarlaOcc ``.npz`` layout (:mod:`carlaocc.catalog.formats.layout`)."""
