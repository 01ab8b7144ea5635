"""Pooling our own grids into coarser grids of ours: class-priority pooling of semantic and
instance volumes (``carlaocc compare-voxel-sizes``, the release export's coarse views) and the
disagreement between a pooled and a directly voxelized volume. The class priority and its rank
tables are shared with the resampling onto other datasets' grids (:mod:`carlaocc.stages.export.resample`).

Frames and units
----------------
Our volumes live on a :class:`~carlaocc.schemas.grid.GridSpec`: the LiDAR frame (x forward, y left, z up,
metres, origin at the LiDAR, 1.73 m above the ground); voxel ``(i, j, k)`` covers
``[origin + (i, j, k) * voxel_size, origin + (i + 1, j + 1, k + 1) * voxel_size]``, arrays are indexed
``[x, y, z]`` and class 0 (``None``) is free.

Class priority
--------------
Whenever several classes meet in one bigger voxel, the label is the present class of **highest
priority** (not the majority: a majority vote erases thin structures and small road users, which
are exactly what a coarse grid must keep). :data:`DEFAULT_POOLING_PRIORITY` lists the CarlaOcc
classes, highest first, in five tiers; inside a tier, lower class id first:

1. dynamic things (the road users): Pedestrian, Rider, Car, Truck, Bus, Train, Motorcycle, Bicycle;
2. thin static structures, which vanish under averaging: Fence, Pole, TrafficLight, TrafficSign,
   GuardRail;
3. small static props: Static, Dynamic (movable props), Other;
4. other (volumetric) static classes: Building, Wall, Vegetation, Bridge, Rock;
5. ground-like surfaces, which everything above rests on: Road, Sidewalk, Terrain, Water,
   RoadLine, Ground, RailTrack;

and last Sky (never inside the region). A priority is turned into a *rank* lookup table over all
256 uint8 labels: free (0) has rank 0, the listed classes get the highest ranks in list order, any
unlisted non-zero label ranks below every listed one (lower id higher). Ranks are a permutation of
0..255, so "max rank, then map back" is the priority rule, fully vectorized.

Public API
----------
* :func:`pool_to_grid` / :func:`pool_instances`: fine grid -> coarser grid of the same origin
  (integer voxel-size factor), in x-slabs of coarse voxels.
* :func:`pool_window`: the same onto a coarse grid covering another window of the region.
* :func:`pooling_disagreement`: compare a directly voxelized coarse grid with a pooled one.
* :data:`DEFAULT_POOLING_PRIORITY`, :func:`rank_table`, :func:`check_volume`, :data:`SLAB_BYTES`:
  shared with :mod:`carlaocc.stages.export.resample`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import CLASSES, by_name

__all__ = [
    "DEFAULT_POOLING_PRIORITY",
    "SLAB_BYTES",
    "check_volume",
    "rank_table",
    "pool_to_grid",
    "pool_instances",
    "pool_window",
    "pooling_disagreement",
]

_FACTOR_TOLERANCE = 1e-6
SLAB_BYTES = 1 << 25  # ~32 MB of working buffers per x-slab (pooling and the resampling's translation path)


# ------------------------------------------------------------------------------------------------
# class priority
# ------------------------------------------------------------------------------------------------


def _default_priority() -> tuple[int, ...]:
    """The documented tiers (module docstring), resolved to class ids from the taxonomy table."""
    thin = {by_name(n).id for n in ("Fence", "Pole", "TrafficLight", "TrafficSign", "GuardRail")}
    props = {by_name(n).id for n in ("Static", "Dynamic", "Other")}
    ground = {by_name(n).id for n in ("Road", "Sidewalk", "Terrain", "Water", "RoadLine", "Ground", "RailTrack")}
    never = {by_name("None").id, by_name("Sky").id}

    def tier(c) -> int:
        if c.id in never:
            return 5
        if c.motion == "dynamic":
            return 0
        if c.id in thin:
            return 1
        if c.id in props:
            return 2
        if c.id in ground:
            return 4
        return 3

    ranked = sorted((c for c in CLASSES if c.id != 0), key=lambda c: (tier(c), c.id))
    return tuple(c.id for c in ranked)


DEFAULT_POOLING_PRIORITY: tuple[int, ...] = _default_priority()
"""CarlaOcc class ids (1-29), highest pooling priority first; the rule is in the module docstring:
dynamic things > thin static structures > small props > other static > ground-like > Sky."""


def rank_table(priority: Sequence[int] | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(rank, label)``: uint8 lookup tables of length 256, inverse permutations of each other.

    ``priority`` lists labels (1-255, distinct), highest priority first; ``None`` means
    :data:`DEFAULT_POOLING_PRIORITY`. Free (0) has rank 0; listed labels take ranks 255, 254, ...
    in order; unlisted non-zero labels follow, lower id ranking higher.
    """
    prio = np.asarray(DEFAULT_POOLING_PRIORITY if priority is None else priority)
    if prio.ndim != 1 or (prio.size and not np.issubdtype(prio.dtype, np.integer)):
        raise ValueError(f"priority must be a 1-D sequence of integer labels, got {prio!r}")
    prio = prio.astype(np.int64)
    if np.any((prio < 1) | (prio > 255)):
        raise ValueError("priority labels must be in 1..255 (0 is free and always ranks lowest)")
    if np.unique(prio).size != prio.size:
        raise ValueError("priority labels must be distinct")
    listed = set(prio.tolist())
    order = list(prio.tolist()) + [c for c in range(1, 256) if c not in listed]  # highest first
    label = np.zeros(256, dtype=np.uint8)  # rank -> label
    label[255 - np.arange(255)] = np.asarray(order, dtype=np.uint8)
    rank = np.zeros(256, dtype=np.uint8)  # label -> rank
    rank[label] = np.arange(256, dtype=np.uint8)
    return rank, label


# ------------------------------------------------------------------------------------------------
# pooling to a coarser grid of the same origin
# ------------------------------------------------------------------------------------------------


def _pool_factor(fine: GridSpec, coarse: GridSpec) -> int:
    """The integer voxel-size ratio ``coarse / fine``; ValueError unless the grids nest."""
    ratio = coarse.voxel_size / fine.voxel_size
    f = round(ratio)
    if f < 1 or abs(ratio - f) > _FACTOR_TOLERANCE:
        raise ValueError(
            f"coarse voxel size {coarse.voxel_size:g} m is not an integer multiple of the fine voxel "
            f"size {fine.voxel_size:g} m (ratio {ratio:.9g})"
        )
    tol = _FACTOR_TOLERANCE * fine.voxel_size
    if any(abs(a - b) > tol for a, b in zip(fine.region_min, coarse.region_min)):
        raise ValueError(
            f"fine and coarse grids must share region_min (the origin): {fine.region_min} vs {coarse.region_min}"
        )
    if any(nf > nc * f for nf, nc in zip(fine.shape, coarse.shape)):
        raise ValueError(f"fine grid {fine.shape} extends beyond coarse grid {coarse.shape} x {f}")
    return int(f)


def check_volume(name: str, a: np.ndarray, shape: tuple[int, ...], dtype: type | None = None) -> None:
    """ValueError unless ``a`` has ``shape`` (and ``dtype``, when given); ``name`` names it in the message."""
    if a.shape != tuple(shape):
        raise ValueError(f"{name} has shape {a.shape}, expected {tuple(shape)}")
    if dtype is not None and a.dtype != dtype:
        raise ValueError(f"{name} must be {np.dtype(dtype).name}, got {a.dtype}")


def _slabs(fine: GridSpec, coarse: GridSpec, f: int, itemsize: int):
    """Yield ``(cx0, cx1, fx0, fx1)``: coarse x-slab ``[cx0, cx1)`` and its fine rows ``[fx0, fx1)``
    (clipped to the fine grid; the rest of the slab is padding)."""
    _, cy, cz = coarse.shape
    per_coarse_x = f * (cy * f) * (cz * f) * itemsize
    step = max(1, SLAB_BYTES // per_coarse_x)
    nfx = fine.shape[0]
    for cx0 in range(0, coarse.shape[0], step):
        cx1 = min(coarse.shape[0], cx0 + step)
        yield cx0, cx1, min(nfx, cx0 * f), min(nfx, cx1 * f)


def pool_to_grid(
    semantic: np.ndarray, fine: GridSpec, coarse: GridSpec, priority: np.ndarray | Sequence[int] | None = None
) -> np.ndarray:
    """Class-priority pooling of a fine semantic volume onto a coarser grid of the same origin.

    ``semantic``: uint8 ``fine.shape`` (0 = free). ``coarse.voxel_size`` must be an integer
    multiple ``f`` of ``fine.voxel_size`` (within 1e-6) and both grids must share ``region_min``.
    Coarse voxel ``(I, J, K)`` covers fine voxels ``[f*I, f*I+f) x [f*J, f*J+f) x [f*K, f*K+f)``;
    where the coarse grid grew past the fine one (0.5 m on 76.8 m: 154 x 10 = 1540 > 1536 fine
    voxels) the missing fine voxels count as free. A coarse voxel is occupied when any of its fine
    voxels is, and takes the present class of highest ``priority`` (see :func:`rank_table`).

    Blocks holding a single class (most of them: free space, building interiors, road) are
    recognised by their largest and smallest non-zero label being equal and take it directly; only
    mixed blocks go through the rank table (a 256-entry gather is several times slower per voxel
    than the elementwise block reductions). Returns uint8 ``coarse.shape``. Peak extra memory: two
    x-slab buffers (~16 MB of fine voxels each) plus the gathered mixed blocks.
    """
    f = _pool_factor(fine, coarse)
    check_volume("semantic", semantic, fine.shape, np.uint8)
    rank, label = rank_table(priority)
    _, cy, cz = coarse.shape
    out = np.empty(coarse.shape, dtype=np.uint8)
    _, ny, nz = fine.shape
    buf = low = None
    for cx0, cx1, fx0, fx1 in _slabs(fine, coarse, f, 2):
        n = cx1 - cx0
        # 1. the slab's fine labels, zero-padded (free) to whole coarse blocks
        if buf is None or buf.shape[0] != n * f:
            buf = np.zeros((n * f, cy * f, cz * f), dtype=np.uint8)
            low = np.empty_like(buf)
        else:
            buf[fx1 - fx0 :] = 0  # rows past the fine grid (last slab only) stay free
        buf[: fx1 - fx0, :ny, :nz] = semantic[fx0:fx1]
        blocks = buf.reshape(n, f, cy, f, cz, f)
        # 2. per f^3 block, the largest label and the smallest non-zero one (label - 1 wraps free
        #    to 255). Reduce x first (elementwise over planes), then y, then the short z runs.
        hi = blocks.max(axis=1).max(axis=2).max(axis=3)
        np.subtract(buf, 1, out=low)
        lo = low.reshape(blocks.shape).min(axis=1).min(axis=2).min(axis=3) + np.uint8(1)
        # 3. a block holding one class (or none) is that class: no priority needed
        res = out[cx0:cx1]
        res[...] = hi
        # 4. mixed blocks: gather their fine voxels, max rank (the priority rule), rank -> label
        a, b, c = np.nonzero(hi != lo)
        if a.size:
            r = np.arange(f)
            cells = blocks[
                a[:, None, None, None], r[None, :, None, None],
                b[:, None, None, None], r[None, None, :, None],
                c[:, None, None, None], r[None, None, None, :],
            ]  # fmt: skip
            res[a, b, c] = label[rank[cells].reshape(a.size, -1).max(axis=1)]
    return out


def pool_instances(
    instance: np.ndarray,
    semantic_fine: np.ndarray,
    fine: GridSpec,
    coarse: GridSpec,
    pooled_semantic: np.ndarray,
) -> np.ndarray:
    """Instance ids of a pooled volume (uint32 ``coarse.shape``; 0 for stuff and free).

    ``instance`` (uint32) and ``semantic_fine`` (uint8) are on ``fine``; ``pooled_semantic`` is the
    result of :func:`pool_to_grid` on them. A coarse voxel takes the **smallest non-zero**
    instance id among its fine voxels of the winning class (deterministic; 0 when none carries
    one): stuff and free voxels carry 0 whatever the label table, so they stay 0. Same grid rules and slab memory as
    :func:`pool_to_grid` (about 10 bytes per fine voxel of a slab).
    """
    f = _pool_factor(fine, coarse)
    check_volume("instance", instance, fine.shape, np.uint32)
    check_volume("semantic_fine", semantic_fine, fine.shape, np.uint8)
    check_volume("pooled_semantic", pooled_semantic, coarse.shape, np.uint8)
    none = np.iinfo(np.uint32).max
    _, cy, cz = coarse.shape
    _, ny, nz = fine.shape
    out = np.zeros(coarse.shape, dtype=np.uint32)
    for cx0, cx1, fx0, fx1 in _slabs(fine, coarse, f, 10):
        n = cx1 - cx0
        win = pooled_semantic[cx0:cx1]
        if not instance[fx0:fx1].any():
            continue  # no instance in this slab: all zero
        # 1. fine labels / ids of the slab, padded (label 0 never equals a thing winner)
        sem = np.zeros((n * f, cy * f, cz * f), dtype=np.uint8)
        sem[: fx1 - fx0, :ny, :nz] = semantic_fine[fx0:fx1]
        ids = np.zeros(sem.shape, dtype=np.uint32)
        ids[: fx1 - fx0, :ny, :nz] = instance[fx0:fx1]
        # 2. keep the ids of the fine voxels of the block's winning class; others (and 0) -> none
        sem6 = sem.reshape(n, f, cy, f, cz, f)
        ids6 = ids.reshape(sem6.shape)
        keep = (sem6 == win[:, None, :, None, :, None]) & (ids6 != 0)
        cand = np.where(keep, ids6, none)
        # 3. smallest id per block (x, y, z as in pool_to_grid); none -> 0; stuff winners -> 0
        best = cand.min(axis=1).min(axis=2).min(axis=3)
        best[best == none] = 0
        out[cx0:cx1] = best
    return out


def pool_window(
    semantic: np.ndarray,
    instance: np.ndarray,
    fine: GridSpec,
    coarse: GridSpec,
    priority: np.ndarray | Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Class-priority pooling onto a coarse grid that may cover another window of the region.

    ``coarse.voxel_size`` must be an integer multiple ``f`` of ``fine.voxel_size`` and the coarse
    origin must sit a whole number of fine voxels from the fine one (the release's 0.2 m forward
    view starts 256 fine voxels of 0.1 m ahead of our origin and 6 above it). Steps:

    1. the fine voxels under the coarse grid are cut out of ``semantic`` / ``instance``; where
       the coarse grid reaches beyond the fine region they are free (0);
    2. that window is pooled with :func:`pool_to_grid` and :func:`pool_instances`.

    Returns ``(semantic uint8, instance uint32)`` of ``coarse.shape``. Both grids in one frame
    (the LiDAR frame), metres.
    """
    ratio = coarse.voxel_size / fine.voxel_size
    f = round(ratio)
    if f < 1 or abs(ratio - f) > _FACTOR_TOLERANCE:
        raise ValueError(f"coarse voxel size {coarse.voxel_size:g} m is not an integer multiple of {fine.voxel_size:g} m")
    shift = (np.asarray(coarse.origin) - np.asarray(fine.origin)) / fine.voxel_size
    offset = np.round(shift).astype(np.int64)
    if np.abs(shift - offset).max() > 1e-6:
        raise ValueError(f"coarse origin {coarse.origin} is not a whole number of {fine.voxel_size:g} m voxels from "
                         f"{fine.origin}")
    check_volume("semantic", semantic, fine.shape, np.uint8)
    check_volume("instance", instance, fine.shape, np.uint32)
    # 1. the window under the coarse grid: a view when it lies inside the fine grid, else a copy
    #    that is zero where it leaves the fine region
    want = np.asarray(coarse.shape) * f
    src = [slice(max(0, o), min(n, o + w)) for o, n, w in zip(offset, fine.shape, want)]
    if all(o >= 0 and o + w <= n for o, n, w in zip(offset, fine.shape, want)):
        sem_w, inst_w = semantic[tuple(src)], instance[tuple(src)]
    else:
        sem_w = np.zeros(tuple(want), np.uint8)
        inst_w = np.zeros(tuple(want), np.uint32)
        dst = [slice(s.start - o, s.stop - o) for s, o in zip(src, offset)]
        if all(s.stop > s.start for s in src):
            sem_w[tuple(dst)] = semantic[tuple(src)]
            inst_w[tuple(dst)] = instance[tuple(src)]
    window = GridSpec(region_min=coarse.region_min, region_max=tuple(
        float(np.float64(o) + n * fine.voxel_size) for o, n in zip(coarse.origin, want)), voxel_size=fine.voxel_size)
    if window.shape != tuple(want):
        raise ValueError(f"window grid {window.shape} is not {tuple(want)} voxels")  # rounding of the region
    if f == 1:
        return sem_w, inst_w  # the same voxels: the window is the result
    # 2. pool the window
    sem_c = pool_to_grid(sem_w, window, coarse, priority)
    return sem_c, pool_instances(inst_w, sem_w, window, coarse, sem_c)


# ------------------------------------------------------------------------------------------------
# disagreement between a direct and a pooled coarse volume
# ------------------------------------------------------------------------------------------------


def pooling_disagreement(direct: np.ndarray, pooled: np.ndarray) -> dict:
    """Compare two label volumes of one grid (0 = free), e.g. voxelized at 0.5 m vs pooled from 0.05 m.

    Keys: ``voxels`` (total), ``occupied_direct``, ``occupied_pooled``, ``occupancy_mismatch``
    (exactly one occupied), ``label_mismatch`` (both occupied, labels differ), ``occupancy_iou``
    (intersection / union of the occupied sets; 1.0 when both are empty) and ``mismatch_rate``
    ``(occupancy_mismatch + label_mismatch) / max(1, union)``. Counts are ints, ratios floats.
    """
    direct = np.asarray(direct)
    pooled = np.asarray(pooled)
    if direct.shape != pooled.shape:
        raise ValueError(f"direct {direct.shape} and pooled {pooled.shape} volumes must have the same shape")
    od = direct != 0
    op = pooled != 0
    n_d = int(np.count_nonzero(od))
    n_p = int(np.count_nonzero(op))
    both = od & op
    inter = int(np.count_nonzero(both))
    union = n_d + n_p - inter
    occ_mis = union - inter
    lab_mis = int(np.count_nonzero(both & (direct != pooled)))
    return {
        "voxels": int(direct.size),
        "occupied_direct": n_d,
        "occupied_pooled": n_p,
        "occupancy_mismatch": occ_mis,
        "label_mismatch": lab_mis,
        "occupancy_iou": inter / union if union else 1.0,
        "mismatch_rate": (occ_mis + lab_mis) / max(1, union),
    }
