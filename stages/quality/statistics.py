"""Per-frame class statistics (voxels per class, distinct instances per class) and their sums
over frames: what the quality stage counts in each frame and the aggregate stage sums per
sequence (the paper's statistics figure draws them; :mod:`carlaocc.stages.report.statistics`).

Inputs are occupancy grids (semantic uint8 class ids 0-29, 0 = free; instance uint32 ids, 0 =
stuff or free, unique within a sequence); outputs are plain count arrays indexed by class id
(length :data:`N_CLASSES`) and pair keys. Nothing here reads a file.

Instance counting works on voxels, which is what the dataset holds: an instance is a distinct
``(class, instance id)`` pair among the occupied voxels with a nonzero instance id, so an object
that is never inside the grid is not counted, and an id that (against the contract) carries two
classes counts once in each. Sequences are summed frame by frame through
:class:`SequenceStatistics` (memory: the pairs seen so far).
"""

from __future__ import annotations

from collections.abc import Iterable

import numba
import numpy as np

from carlaocc.schemas import taxonomy

N_CLASSES = len(taxonomy.CLASSES)  # 30: ids 0..29


@numba.njit(cache=True, nogil=True)
def _count_kernel(sem, counts):  # pragma: no cover - numba
    """Occupied voxels per class into ``counts`` (free voxels, most of a grid, are skipped: the
    caller derives them; repeated increments of one counter would serialize the loop)."""
    for v in range(sem.size):
        c = sem[v]
        if c != 0:
            counts[c] += 1


@numba.njit(cache=True, nogil=True)
def _pairs_kernel(sem, inst, start, counts, keys):  # pragma: no cover - numba
    """From voxel ``start`` on: count occupied voxels per class into ``counts`` (free ones are
    skipped, as in :func:`_count_kernel`) and append the key ``id << 8 | class`` of each occupied
    voxel with a nonzero instance to ``keys`` when it differs from the previous such voxel's (objects
    are runs of voxels along z, so this drops most repeats). Stops when ``keys`` is full; returns
    (keys written, next voxel)."""
    n, prev, cap = 0, np.int64(-1), keys.size
    for v in range(start, sem.size):
        c = sem[v]
        if c != 0:
            counts[c] += 1
        i = inst[v]
        if i != 0 and c != 0:  # instances of occupied voxels only
            k = (np.int64(i) << 8) | np.int64(c)
            if k != prev:
                if n == cap:
                    if c != 0:
                        counts[c] -= 1  # voxel v is counted again by the next call
                    return n, v
                keys[n] = k
                n += 1
                prev = k
    return n, sem.size


@numba.njit(cache=True, nogil=True)
def _column_pairs_kernel(sem, inst, lo, hi, col, keys):  # pragma: no cover - numba
    """From column ``col`` on of a block (``sem``, ``inst``: ``(bx, by, Z)``; ``lo``, ``hi``:
    ``(bx, by)`` occupied z ranges): append the key ``id << 8 | class`` of each occupied voxel in
    the column's range with a nonzero instance id when it differs from the previous such voxel's.
    Stops before a column that might not fit in ``keys``; returns (keys written, next column)."""
    bx, by, Z = sem.shape
    n, prev, cap = 0, np.int64(-1), keys.size
    for q in range(col, bx * by):
        a, b = q // by, q % by
        if n + Z > cap:
            return n, q
        for k in range(lo[a, b], hi[a, b] + 1):
            i = inst[a, b, k]
            c = sem[a, b, k]
            if i != 0 and c != 0:  # instances of occupied voxels only (as frame_statistics)
                key = (np.int64(i) << 8) | np.int64(c)
                if key != prev:
                    keys[n] = key
                    n += 1
                    prev = key
    return n, bx * by


def block_pairs(semantic: np.ndarray, instance: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The distinct ``(instance id, class)`` pair keys (sorted uint64, see :func:`split_pairs`) of
    a block of a frame, ``semantic`` uint8 and ``instance`` uint32 ``(bx, by, Z)``, visiting in
    each ``(a, b)`` column only ``[lo[a, b], hi[a, b]]``: the semantic grid's occupied range
    (an instance id marks an occupied voxel, so the free rest of a column, most of a frame, is
    never read). What :func:`frame_statistics` finds."""
    if semantic.shape != instance.shape or lo.shape != semantic.shape[:2] or hi.shape != lo.shape:
        raise ValueError(f"block shapes differ: semantic {semantic.shape}, instance {instance.shape}, "
                         f"ranges {lo.shape} and {hi.shape}")
    keys = np.empty(max(1 << 16, 2 * semantic.shape[2]), np.int64)
    found, col = [], 0
    # the kernel fills a fixed buffer of run keys; each full buffer is reduced to its distinct keys
    while True:
        n, col = _column_pairs_kernel(semantic, instance, lo, hi, col, keys)
        found.append(np.unique(keys[:n]))
        if col >= semantic.shape[0] * semantic.shape[1]:
            break
    return (np.unique(np.concatenate(found)) if len(found) > 1 else found[0]).astype(np.uint64)


def _flat_u8(semantic: np.ndarray) -> np.ndarray:
    """A semantic grid as a flat uint8 array (ValueError naming a bad dtype or id)."""
    sem = np.asarray(semantic)
    if sem.dtype != np.uint8:
        if sem.dtype.kind not in "ui":
            raise ValueError(f"semantic grid must hold integer class ids, got dtype {sem.dtype}")
        if sem.size and (sem.min() < 0 or sem.max() >= N_CLASSES):
            bad = int(sem.min()) if sem.min() < 0 else int(sem.max())
            raise ValueError(f"semantic grid holds class id {bad}, outside the taxonomy's 0..{N_CLASSES - 1}")
        sem = sem.astype(np.uint8)
    return np.ascontiguousarray(sem).reshape(-1)


def _check_counts(counts: np.ndarray, size: int) -> np.ndarray:
    """The kernels' 256 occupied counts -> ``(N_CLASSES,)`` with the free voxels at 0."""
    counts[0] = size - counts[1:].sum()
    if counts[N_CLASSES:].any():
        bad = N_CLASSES + int(np.flatnonzero(counts[N_CLASSES:])[0])
        raise ValueError(f"semantic grid holds class id {bad}, outside the taxonomy's 0..{N_CLASSES - 1}")
    return counts[:N_CLASSES].copy()


def class_voxel_counts(semantic: np.ndarray) -> np.ndarray:
    """Voxels per class id of a semantic grid of any shape (a frame, or frames stacked):
    ``(N_CLASSES,)`` int64, index 0 = free voxels. ValueError naming the first id outside 0..29."""
    counts = np.zeros(256, np.int64)
    sem = _flat_u8(semantic)
    # one linear pass (np.bincount would first widen the uint8 grid to int64)
    _count_kernel(sem, counts)
    return _check_counts(counts, sem.size)


def frame_statistics(semantic: np.ndarray, instance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One pass over a frame: (voxels per class ``(N_CLASSES,)`` int64, the distinct
    ``(instance id, class)`` pairs of its voxels with a nonzero instance id as sorted uint64 keys
    ``id << 8 | class``, see :func:`split_pairs`)."""
    sem = _flat_u8(semantic)
    inst = np.asarray(instance)
    if inst.shape != np.shape(semantic):
        raise ValueError(f"instance grid shape {inst.shape} differs from the semantic grid's {np.shape(semantic)}")
    if inst.dtype.kind not in "ui":
        raise ValueError(f"instance grid must hold integer ids, got dtype {inst.dtype}")
    if inst.dtype.kind == "i" and inst.size and inst.min() < 0:
        raise ValueError(f"instance grid holds a negative id {int(inst.min())}")
    if inst.dtype.itemsize > 4:
        if inst.size and inst.max() >= 1 << 32:
            raise ValueError(f"instance id {int(inst.max())} does not fit in 32 bits")
        inst = inst.astype(np.uint32)
    inst = np.ascontiguousarray(inst).reshape(-1)
    counts = np.zeros(256, np.int64)
    keys = np.empty(1 << 16, np.int64)
    found, start = [], 0
    # the kernel fills a fixed buffer of run keys; each full buffer is reduced to its distinct keys
    while True:
        n, start = _pairs_kernel(sem, inst, start, counts, keys)
        found.append(np.unique(keys[:n]))
        if start >= sem.size:
            break
    pairs = np.unique(np.concatenate(found)).astype(np.uint64) if len(found) > 1 else found[0].astype(np.uint64)
    return _check_counts(counts, sem.size), pairs


def instance_class_pairs(semantic: np.ndarray, instance: np.ndarray) -> np.ndarray:
    """The distinct ``(instance id, class id)`` pairs of a frame's voxels with a nonzero instance
    id, as sorted uint64 keys ``id << 8 | class`` (see :func:`split_pairs`)."""
    return frame_statistics(semantic, instance)[1]


def pair_keys(instance_ids: np.ndarray, classes: np.ndarray) -> np.ndarray:
    """(instance ids, class ids) -> sorted distinct pair keys ``id << 8 | class`` (the inverse of
    :func:`split_pairs`)."""
    ids = np.asarray(instance_ids, dtype=np.uint64)
    return np.unique((ids << np.uint64(8)) | np.asarray(classes, dtype=np.uint64))


def split_pairs(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pair keys ``id << 8 | class`` -> (instance ids uint64, class ids int64)."""
    keys = np.asarray(keys, dtype=np.uint64)
    return keys >> np.uint64(8), (keys & np.uint64(0xFF)).astype(np.int64)


def instances_per_class(keys: np.ndarray, only_ids: Iterable[int] | None = None) -> np.ndarray:
    """``(N_CLASSES,)`` int64 number of distinct instances per class of pair keys; with
    ``only_ids``, only the instances whose id is among them (e.g. the moving actors)."""
    ids, cls = split_pairs(keys)
    if only_ids is not None:
        sel = np.isin(ids, np.fromiter((int(i) for i in only_ids), dtype=np.uint64))
        cls = cls[sel]
    if cls.size and cls.max() >= N_CLASSES:
        raise ValueError(f"instance pairs hold class id {int(cls.max())}, outside 0..{N_CLASSES - 1}")
    return np.bincount(cls, minlength=N_CLASSES).astype(np.int64)


class SequenceStatistics:
    """Voxel and instance statistics of one sequence, accumulated frame by frame (or tile by tile
    of each frame: any partition of a frame's voxels gives the same counts).

    ``add(semantic, instance)`` per frame or tile; then ``voxels`` (voxels per class summed over
    the frames), ``frames``, ``pairs`` (distinct instance/class pair keys of the sequence) and
    :meth:`instances`.
    """

    def __init__(self) -> None:
        self.voxels = np.zeros(N_CLASSES, np.int64)
        self.frames = 0
        self.pairs = np.zeros(0, np.uint64)

    def add(self, semantic: np.ndarray, instance: np.ndarray | None = None, *, last_tile: bool = True) -> None:
        """Count one frame, or one tile of a frame (``instance`` None: voxels only); the frame
        counts once its ``last_tile`` is added."""
        if instance is None:
            self.add_counts(class_voxel_counts(semantic), None, last_tile=last_tile)
        else:
            self.add_counts(*frame_statistics(semantic, instance), last_tile=last_tile)

    def add_counts(self, voxels: np.ndarray, pairs: np.ndarray | None, *, last_tile: bool = True) -> None:
        """Add what :func:`frame_statistics` found in a frame or tile (voxels per class, pair keys):
        the same as :meth:`add` on its grids, for counts computed elsewhere (per-frame tables)."""
        self.voxels += np.asarray(voxels, np.int64)
        if pairs is not None:
            # union of small sorted arrays: the pairs of a frame are a few thousand at most
            self.pairs = np.union1d(self.pairs, np.asarray(pairs, np.uint64))
        self.frames += int(last_tile)

    def instances(self, only_ids: Iterable[int] | None = None) -> np.ndarray:
        """Distinct instances per class over the frames added (see :func:`instances_per_class`)."""
        return instances_per_class(self.pairs, only_ids)
