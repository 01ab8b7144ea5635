"""Multi-resolution pooling and resampling of occupancy volumes to other datasets' grids.

Frames and units
----------------
Our volumes live on a :class:`~carlaocc.schemas.grid.GridSpec`: the LiDAR frame (x forward, y left, z up,
metres, origin at the LiDAR, 1.73 m above the ground); voxel ``(i, j, k)`` covers
``[origin + (i, j, k) * vs, origin + (i + 1, j + 1, k + 1) * vs]``, arrays are indexed
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
* :func:`pooling_disagreement`: compare a directly voxelized coarse grid with a pooled one.
* :class:`TargetGrid`, :data:`OCC3D_NUSCENES`, :data:`SSCBENCH_KITTI360` and :func:`resample`:
  sim-to-real export onto another dataset's grid and label set.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import CLASSES, TARGETS, LabelTable, by_name, mapping

__all__ = [
    "DEFAULT_POOLING_PRIORITY",
    "rank_table",
    "pool_to_grid",
    "pool_instances",
    "pool_window",
    "pooling_disagreement",
    "TargetGrid",
    "OCC3D_NUSCENES",
    "SSCBENCH_KITTI360",
    "resample",
]

_FACTOR_TOLERANCE = 1e-6
_SLAB_BYTES = 1 << 25  # ~32 MB of working buffers per x-slab (pooling and the translation path)
_POINT_CHUNK = 1 << 22  # occupied voxels transformed at once by resample's general path


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


def _check_volume(name: str, a: np.ndarray, shape: tuple[int, ...], dtype: type | None = None) -> None:
    if a.shape != tuple(shape):
        raise ValueError(f"{name} has shape {a.shape}, expected {tuple(shape)}")
    if dtype is not None and a.dtype != dtype:
        raise ValueError(f"{name} must be {np.dtype(dtype).name}, got {a.dtype}")


def _slabs(fine: GridSpec, coarse: GridSpec, f: int, itemsize: int):
    """Yield ``(cx0, cx1, fx0, fx1)``: coarse x-slab ``[cx0, cx1)`` and its fine rows ``[fx0, fx1)``
    (clipped to the fine grid; the rest of the slab is padding)."""
    _, cy, cz = coarse.shape
    per_coarse_x = f * (cy * f) * (cz * f) * itemsize
    step = max(1, _SLAB_BYTES // per_coarse_x)
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
    _check_volume("semantic", semantic, fine.shape, np.uint8)
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
    _check_volume("instance", instance, fine.shape, np.uint32)
    _check_volume("semantic_fine", semantic_fine, fine.shape, np.uint8)
    _check_volume("pooled_semantic", pooled_semantic, coarse.shape, np.uint8)
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
    _check_volume("semantic", semantic, fine.shape, np.uint8)
    _check_volume("instance", instance, fine.shape, np.uint32)
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


# ------------------------------------------------------------------------------------------------
# resampling onto another dataset's grid and label set
# ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TargetGrid:
    """Another dataset's voxel grid and label set.

    ``shape`` (X, Y, Z) voxels of edge ``voxel_size`` metres; voxel ``(i, j, k)`` covers
    ``range_min + [i, i+1) x [j, j+1) x [k, k+1) * voxel_size`` in the target ``frame`` (arrays
    indexed ``[x, y, z]``, x forward, y left, z up). ``taxonomy`` is a key of
    :data:`carlaocc.schemas.taxonomy.TARGETS`; ``free_label`` marks empty voxels.
    """

    name: str
    shape: tuple[int, int, int]
    voxel_size: float
    range_min: tuple[float, float, float]
    frame: Literal["ego", "lidar"]
    taxonomy: str
    free_label: int

    def __post_init__(self) -> None:
        shape = tuple(int(n) for n in self.shape)
        rmin = tuple(float(v) for v in self.range_min)
        if len(shape) != 3 or any(n < 1 for n in shape):
            raise ValueError(f"{self.name}: shape must be 3 positive ints, got {self.shape!r}")
        if len(rmin) != 3 or not all(math.isfinite(v) for v in rmin):
            raise ValueError(f"{self.name}: range_min must be 3 finite floats, got {self.range_min!r}")
        if not (math.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise ValueError(f"{self.name}: voxel_size must be positive, got {self.voxel_size!r}")
        if self.frame not in ("ego", "lidar"):
            raise ValueError(f"{self.name}: frame must be 'ego' or 'lidar', got {self.frame!r}")
        if self.taxonomy not in TARGETS:
            raise ValueError(f"{self.name}: unknown taxonomy {self.taxonomy!r}; valid: {', '.join(TARGETS)}")
        if not 0 <= int(self.free_label) <= 255:
            raise ValueError(f"{self.name}: free_label must fit uint8, got {self.free_label!r}")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "range_min", rmin)
        object.__setattr__(self, "voxel_size", float(self.voxel_size))
        object.__setattr__(self, "free_label", int(self.free_label))

    @property
    def range_max(self) -> tuple[float, float, float]:
        """Maximum corner of the grid, ``range_min + shape * voxel_size`` (target frame, metres)."""
        return tuple(round(lo + n * self.voxel_size, 9) for lo, n in zip(self.range_min, self.shape))  # type: ignore[return-value]


OCC3D_NUSCENES = TargetGrid("occ3d-nuscenes", (200, 200, 16), 0.4, (-40.0, -40.0, -1.0), "ego", "occ3d_nuscenes", 17)
"""Occ3D-nuScenes. Source: Tsinghua-MARS-Lab/Occ3D README (voxel size 0.4 m, range
[-40, -40, -1, 40, 40, 5.4] m, volume [200, 200, 16], classes 0-17 with 17 = free). Frame: the
nuScenes **ego** (vehicle) frame, x forward, y left, z up -- stated by the challenge organisers
(CVPR2023-3D-Occupancy-Prediction issues #8 "It is in ego coordinate" and #36 "the Occ ground truth
in Vehicle coors"); index order ``[x, y, z]`` per that repository's ``utils/vis.py``
(``voxel2points``: index 0 * vs + range[0] is x, 1 is y, 2 is z). So pass the LiDAR-to-ego pose
(``LidarSpec.sensor_to_ego()``: up by 1.73 m, forward by the LiDAR's x offset) as ``grid_to_target``.
"""

SSCBENCH_KITTI360 = TargetGrid(
    "sscbench-kitti360", (256, 256, 32), 0.2, (0.0, -25.6, -2.0), "lidar", "sscbench_kitti360", 0
)
"""SSCBench-KITTI-360 (SemanticKITTI SSC layout). Source: ai4ce/SSCBench
``method/MonoScene/monoscene/data/kitti_360/kitti_360_dataset.py`` (``voxel_size = 0.2``,
``vox_origin = [0, -25.6, -2]``, ``scene_size = (51.2, 51.2, 6.4)``) and
``dataset/KITTI-360/README.md`` (256 x 256 x 32 voxels of 0.2 m); the MonoScene ``vox2pix`` helper
documents ``vox_origin`` as the LiDAR (velodyne) coordinates of voxel (0, 0, 0) and enumerates
voxels with ``meshgrid(x, y, z, indexing='ij')``, i.e. ``[x, y, z]`` order. Forward only:
x in [0, 51.2], y in [-25.6, 25.6], z in [-2, 4.4] m of the LiDAR frame; 0 = empty/unlabeled.
``grid_to_target`` is the identity for our LiDAR frame (x forward, y left, z up, like the
velodyne's); the real rig's mounting height is not modelled (ours is 1.73 m above the ground).
"""


def _check_affine(m: np.ndarray) -> np.ndarray:
    m = np.asarray(m, dtype=np.float64)
    if m.shape != (4, 4) or not np.all(np.isfinite(m)):
        raise ValueError(f"grid_to_target must be a finite 4x4 matrix, got shape {m.shape}")
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0), atol=0.0, rtol=0.0):
        raise ValueError(f"grid_to_target must be affine (last row 0 0 0 1), got {m[3].tolist()}")
    return m


def _label_lut(target: TargetGrid, table: str | LabelTable | None = None) -> np.ndarray:
    """uint8 table of length 256: CarlaOcc class id -> target id under label table ``table``
    (None: the default; ids beyond the taxonomy -> free)."""
    lut = np.full(256, target.free_label, dtype=np.uint8)
    table = mapping(target.taxonomy, table)
    lut[: len(table)] = np.asarray(table, dtype=np.uint8)
    return lut


def _axis_groups(origin: float, vs: float, n: int, shift: float, tmin: float, tvs: float, tn: int):
    """Translation-only fast path, one axis: our voxels ``0..n-1`` -> target voxels by centre.

    Returns ``(starts, targets, stop)``: ``reduceat`` group starts into our axis, the target index
    of each group (centres binned exactly as the general path does) and the end of the last group,
    or ``None`` when nothing lands.
    """
    centre = origin + (np.arange(n) + 0.5) * vs  # 1. our voxel centres along this axis (m)
    t = np.floor((centre + shift - tmin) / tvs).astype(np.int64)  # 2. target index of each
    inside = np.flatnonzero((t >= 0) & (t < tn))  # 3. a contiguous run (t is monotone)
    if inside.size == 0:
        return None
    ti = t[inside]
    first = np.concatenate(([0], np.flatnonzero(np.diff(ti)) + 1))  # 4. where the target changes
    return inside[first], ti[first], int(inside[-1]) + 1


def _reduce_translation(
    vol: np.ndarray, values, grid: GridSpec, shift: np.ndarray, target: TargetGrid, ufunc, dtype
) -> np.ndarray:
    """Grouped ``ufunc.reduceat`` along x, y, z of ``values(vol[x0:x1])``: the exact result of
    binning voxel centres when the transform is a pure translation (each target index then depends
    on one source index only). Works in x-slabs of whole target rows (~32 MB of source voxels)."""
    out = np.zeros(target.shape, dtype=dtype)
    groups = []
    for ax in range(3):
        g = _axis_groups(
            grid.origin[ax], grid.voxel_size, grid.shape[ax], float(shift[ax]),
            target.range_min[ax], target.voxel_size, target.shape[ax],
        )  # fmt: skip
        if g is None:
            return out  # the grids do not overlap along this axis
        groups.append(g)
    (sx, tx, stop_x), (sy, ty, stop_y), (sz, tz, stop_z) = groups
    _, ny, nz = grid.shape
    ends = np.append(sx[1:], stop_x)  # end of each x group (exclusive)
    rows_per_slab = max(1, _SLAB_BYTES // max(1, ny * nz))
    g0 = 0
    while g0 < sx.size:
        # 1. a run of whole x groups of about rows_per_slab source rows
        g1 = g0 + 1
        while g1 < sx.size and ends[g1] - sx[g0] <= rows_per_slab:
            g1 += 1
        x0, x1 = int(sx[g0]), int(ends[g1 - 1])
        # 2. values of the slab (ranks or observed flags), reduced along x, then y, then z
        red = ufunc.reduceat(values(vol[x0:x1, sy[0] : stop_y, sz[0] : stop_z]), sx[g0:g1] - x0, axis=0)
        red = ufunc.reduceat(red, sy - sy[0], axis=1)
        red = ufunc.reduceat(red, sz - sz[0], axis=2)
        # 3. scatter the group results to their target voxels
        out[np.ix_(tx[g0:g1], ty, tz)] = red
        g0 = g1
    return out


def _bin_points(
    idx: np.ndarray, grid: GridSpec, m: np.ndarray, target: TargetGrid
) -> tuple[np.ndarray, np.ndarray]:
    """General path: linear source indices -> (kept positions, target linear indices)."""
    # 1. voxel centres of the source grid (LiDAR frame, metres), one 1-D array per axis
    ijk = np.unravel_index(idx, grid.shape)
    c = [grid.origin[a] + (ijk[a] + 0.5) * grid.voxel_size for a in range(3)]
    del ijk
    ok = np.ones(idx.size, dtype=bool)
    lin = np.zeros(idx.size, dtype=np.int64)
    for a in range(3):
        # 2. into the target frame: row a of the affine map
        p = m[a, 0] * c[0] + m[a, 1] * c[1] + m[a, 2] * c[2] + m[a, 3]
        # 3. bin: floor((p - range_min) / voxel_size); outside the target grid -> dropped
        t = np.floor((p - target.range_min[a]) / target.voxel_size)
        ok &= (t >= 0) & (t < target.shape[a])
        lin *= target.shape[a]
        lin += np.where(ok, t, 0).astype(np.int64)
    keep = np.flatnonzero(ok)
    return keep, lin[keep]


def _bin_reduce(
    vol: np.ndarray, values, grid: GridSpec, m: np.ndarray, target: TargetGrid, ufunc, dtype, points: bool
) -> np.ndarray:
    """Reduce ``values(vol)`` of the non-zero voxels of ``vol`` per target voxel with ``ufunc``
    (``np.maximum`` on ranks, ``np.logical_or`` on observed flags); 0 where nothing lands.

    ``points=False`` requires ``m`` to be a pure translation (separable ``reduceat`` path); the
    general path (``points=True``) bins the voxel centres in chunks with ``ufunc.at``. Both bin
    the same centres with the same arithmetic, so they agree exactly on translations.
    """
    if not points:
        return _reduce_translation(vol, values, grid, m[:3, 3], target, ufunc, dtype)
    out = np.zeros(int(np.prod(target.shape)), dtype=dtype)
    flat = vol.reshape(-1)
    occupied = np.flatnonzero(flat)
    for s in range(0, occupied.size, _POINT_CHUNK):
        idx = occupied[s : s + _POINT_CHUNK]
        keep, lin = _bin_points(idx, grid, m, target)
        ufunc.at(out, lin, values(flat[idx[keep]]).astype(dtype, copy=False))
    return out.reshape(target.shape)


def resample(
    semantic: np.ndarray,
    grid: GridSpec,
    target: TargetGrid,
    grid_to_target: np.ndarray,
    masks: Mapping[str, np.ndarray] | None = None,
    priority: np.ndarray | Sequence[int] | None = None,
    label_table: str | LabelTable | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Resample a CarlaOcc semantic volume onto another dataset's grid and label set.

    ``semantic``: uint8 ``grid.shape`` (our class ids, 0 = free), LiDAR frame. ``grid_to_target``:
    4x4 affine mapping our LiDAR frame to the target frame (metres) -- for Occ3D the LiDAR-to-ego
    pose, for SSCBench-KITTI-360 the identity. ``masks``: optional visibility volumes of
    ``grid.shape`` (non-zero = observed).

    Method: the centre of each occupied voxel is mapped into the target frame and binned into
    target voxel ``floor((p - range_min) / voxel_size)``; centres outside the target grid are
    dropped. Each target voxel takes the **highest-priority** class among the centres it received
    (priority on our class ids, as in :func:`pool_to_grid`), then that class is mapped through
    ``taxonomy.mapping(target.taxonomy, label_table)`` (the label table the volume was built under;
    None: the default); classes the target maps to its empty label rank below
    all others (they only win a voxel nothing else reaches). Target voxels that receive nothing get
    ``target.free_label``. A class that maps to the target's ignore/unlabelled id keeps that id
    (e.g. Wall -> 0 in SemanticKITTI, which coincides with empty there, as in the real labels).
    A mask voxel of the target is observed when any observed voxel centre of ours falls in it.

    Pure translations (the usual LiDAR -> ego case) take an exact separable fast path (grouped
    ``reduceat`` per axis, the same binning of the same centres); other transforms bin the points
    in chunks with ``np.maximum.at`` on ranks.

    Returns ``(labels, masks)``: uint8 ``target.shape`` and a dict of bool ``target.shape`` arrays
    (empty when ``masks`` is None).
    """
    _check_volume("semantic", semantic, grid.shape, np.uint8)
    m = _check_affine(grid_to_target)
    mask_items = dict(masks or {})
    for name, mk in mask_items.items():
        _check_volume(f"mask {name!r}", np.asarray(mk), grid.shape)
    lut = _label_lut(target, label_table)
    # classes the target maps to its empty label rank below every class it keeps, so a wall or
    # prop voxel in a target voxel of road does not turn the road empty (SemanticKITTI: 0)
    prio = [int(c) for c in (DEFAULT_POOLING_PRIORITY if priority is None else priority)]
    prio = [c for c in prio if lut[c] != target.free_label] + [c for c in prio if lut[c] == target.free_label]
    rank, label = rank_table(prio)
    points = not np.array_equal(m[:3, :3], np.eye(3))  # a pure translation takes the fast path

    # 1. per target voxel, the max rank of the classes whose centres land in it (0 = nothing)
    best = _bin_reduce(semantic, lambda a: rank[a], grid, m, target, np.maximum, np.uint8, points)
    # 2. rank -> our class -> target id; nothing received -> free
    labels = lut[label[best]]
    labels[best == 0] = target.free_label
    # 3. masks: a target voxel is observed when any observed voxel centre of ours falls in it
    out_masks = {
        name: _bin_reduce(np.asarray(mk), lambda a: a != 0, grid, m, target, np.logical_or, bool, points)
        for name, mk in mask_items.items()
    }
    return labels, out_masks


def resample_panoptic(
    semantic: np.ndarray,
    instance: np.ndarray,
    flow: np.ndarray | None,
    grid: GridSpec,
    target: TargetGrid,
    grid_to_target: np.ndarray,
    priority: np.ndarray | Sequence[int] | None = None,
    label_table: str | LabelTable | None = None,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The instance ids and flow of a CarlaOcc frame on another dataset's grid, binned like
    :func:`resample` bins the classes (the same voxel centres, the same class priority).

    ``instance``: uint32 ``grid.shape`` (0 = stuff or free); ``flow``: ``grid.shape + (3,)`` (m/s,
    our LiDAR frame's axes) or None. Returns ``(instances, flow)``: uint32 ``target.shape``, each
    target voxel the largest instance id among the centres of its winning class (0 when that
    class is stuff), and float32 ``target.shape + (3,)``: the mean flow of the centres with a
    non-zero flow in the voxel (their moving material: the road users, which outrank what they
    stand on), rotated into the target frame's axes (m/s); None without ``flow``.
    """
    _check_volume("semantic", semantic, grid.shape, np.uint8)
    _check_volume("instance", np.asarray(instance), grid.shape)
    m = _check_affine(grid_to_target)
    lut = _label_lut(target, label_table)
    prio = [int(c) for c in (DEFAULT_POOLING_PRIORITY if priority is None else priority)]
    prio = [c for c in prio if lut[c] != target.free_label] + [c for c in prio if lut[c] == target.free_label]
    rank, _ = rank_table(prio)
    points = not np.array_equal(m[:3, :3], np.eye(3))
    # 1. per target voxel, max of (class rank << 32 | instance): the winning class's largest id
    key = (rank[semantic].astype(np.uint64) << np.uint64(32)) | np.asarray(instance, dtype=np.uint64)
    best = _bin_reduce(key, lambda a: a, grid, m, target, np.maximum, np.uint64, points)
    instances = (best & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    if flow is None:
        return instances, None
    flow = np.asarray(flow)
    if flow.shape != (*grid.shape, 3):
        raise ValueError(f"flow has shape {flow.shape}, expected {(*grid.shape, 3)}")
    # 2. the mean of the non-zero flows per target voxel, component by component
    moving = np.any(flow != 0, axis=-1)
    count = _bin_reduce(moving.astype(np.uint32), lambda a: a, grid, m, target, np.add, np.uint32, points)
    out = np.zeros((*target.shape, 3), np.float32)
    for c in range(3):
        comp = np.where(moving, flow[..., c].astype(np.float32), np.float32(0))
        out[..., c] = _bin_reduce(comp, lambda a: a, grid, m, target, np.add, np.float64, points)
    with np.errstate(invalid="ignore", divide="ignore"):
        out /= np.maximum(count, 1)[..., None]
    # 3. velocities are directions: the frame change rotates them, it does not move them
    return instances, (out @ m[:3, :3].T.astype(np.float32)).astype(np.float32)


def downsample_ssc(labels: np.ndarray, factor: int, empty: int = 0, invalid: int = 255,
                   empty_fraction: float = 0.95) -> np.ndarray:
    """The coarse SSC target MonoScene-style loaders read beside the full one (SSCBench's
    ``_1_8.npy``): each ``factor``-cube block of ``labels`` (X, Y, Z, each divisible by
    ``factor``) becomes ``empty`` or ``invalid`` -- whichever of the two is more frequent -- when
    those two together fill more than ``empty_fraction`` of it, else its most frequent other
    label (ties: the smallest id)."""
    X, Y, Z = labels.shape
    if X % factor or Y % factor or Z % factor:
        raise ValueError(f"a {labels.shape} grid does not divide into blocks of {factor}")
    # 1. one row of factor**3 labels per block, blocks in C order
    blocks = labels.reshape(X // factor, factor, Y // factor, factor, Z // factor, factor)
    blocks = blocks.transpose(0, 2, 4, 1, 3, 5).reshape(-1, factor ** 3)
    n_empty = np.count_nonzero(blocks == empty, axis=1)
    n_invalid = np.count_nonzero(blocks == invalid, axis=1)
    # 2. the most frequent label among the others (counts per label id, argmax picks the smallest on ties)
    other = np.where((blocks == empty) | (blocks == invalid), 0, blocks.astype(np.int64) + 1)
    counts = np.zeros((len(blocks), int(other.max()) + 1), np.int64)
    np.add.at(counts, (np.repeat(np.arange(len(blocks)), blocks.shape[1]), other.reshape(-1)), 1)
    counts[:, 0] = 0
    majority = (counts.argmax(axis=1) - 1).astype(labels.dtype)
    # 3. mostly empty or unobserved blocks take the more frequent of the two
    mostly_empty = (n_empty + n_invalid) > empty_fraction * factor ** 3
    out = np.where(mostly_empty, np.where(n_empty > n_invalid, empty, invalid), majority)
    return out.astype(labels.dtype).reshape(X // factor, Y // factor, Z // factor)


SEMANTICKITTI_GRID = TargetGrid("semantickitti", SSCBENCH_KITTI360.shape, SSCBENCH_KITTI360.voxel_size,
                                SSCBENCH_KITTI360.range_min, "lidar", "semantickitti", 0)
"""SemanticKITTI SSC: the forward KITTI grid of SSCBench, raw SemanticKITTI ids (free 0)."""
SURROUNDOCC_GRID = TargetGrid("surroundocc", (200, 200, 16), 0.5, (-50.0, -50.0, -5.0), "lidar", "occ3d_nuscenes", 17)
"""SurroundOcc: 200 x 200 x 16 at 0.5 m over [-50, -50, -5, 50, 50, 3] m, LiDAR frame."""
OPENOCC_V2 = TargetGrid("openocc-v2", (200, 200, 16), 0.4, (-40.0, -40.0, -1.0), "ego", "openocc_v2", 16)
"""OpenOcc v2: the Occ3D grid and frame (OccNet ray_metrics / nuscenes_occ), its own class order."""
UNIOCC = TargetGrid("uniocc", (200, 200, 16), 0.4, (-40.0, -40.0, -1.0), "ego", "uniocc", 10)
"""UniOcc: 0.4 m over [-40, -40, -1, 40, 40, 5.4] m (uniocc_viz.py); we place it in the ego frame."""
