"""Resampling of occupancy volumes onto other datasets' grids and label sets (the Occ3D-nuScenes
and SSCBench-KITTI-360 exports, the flow export, ``carlaocc eval rayiou/raypq``), and the coarse SSC
targets of the SSCBench layout.

Frames and units
----------------
Our volumes live on a :class:`~carlaocc.schemas.grid.GridSpec`: the LiDAR frame (x forward, y left, z up,
metres, origin at the LiDAR, 1.73 m above the ground); voxel ``(i, j, k)`` covers
``[origin + (i, j, k) * voxel_size, origin + (i + 1, j + 1, k + 1) * voxel_size]``, arrays are indexed
``[x, y, z]`` and class 0 (``None``) is free. A target voxel takes the present class of highest
priority, the rule of our own pooling (:mod:`carlaocc.stages.voxelize.pooling`, "Class priority").

Public API
----------
* :class:`TargetGrid`, :data:`OCC3D_NUSCENES`, :data:`SSCBENCH_KITTI360` and :func:`resample`:
  sim-to-real export onto another dataset's grid and label set; :func:`resample_panoptic` the
  instance ids and flow on it.
* :func:`downsample_ssc`: the coarse SSC target beside the full one (SSCBench's ``_1_8.npy``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.taxonomy import TARGETS, LabelTable, mapping
from carlaocc.stages.voxelize.pooling import DEFAULT_POOLING_PRIORITY, SLAB_BYTES, check_volume, rank_table

__all__ = [
    "TargetGrid",
    "OCC3D_NUSCENES",
    "SSCBENCH_KITTI360",
    "resample",
    "resample_panoptic",
    "downsample_ssc",
]

_POINT_CHUNK = 1 << 22  # occupied voxels transformed at once by resample's general path


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
(``voxel2points``: index 0 * voxel_size + range[0] is x, 1 is y, 2 is z). So pass the LiDAR-to-ego pose
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


def _axis_groups(origin: float, voxel_size: float, n: int, shift: float, tmin: float, target_voxel_size: float, tn: int):
    """Translation-only fast path, one axis: our voxels ``0..n-1`` -> target voxels by centre.

    Returns ``(starts, targets, stop)``: ``reduceat`` group starts into our axis, the target index
    of each group (centres binned exactly as the general path does) and the end of the last group,
    or ``None`` when nothing lands.
    """
    centre = origin + (np.arange(n) + 0.5) * voxel_size  # 1. our voxel centres along this axis (m)
    t = np.floor((centre + shift - tmin) / target_voxel_size).astype(np.int64)  # 2. target index of each
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
    rows_per_slab = max(1, SLAB_BYTES // max(1, ny * nz))
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


def bin_reduce(
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
    check_volume("semantic", semantic, grid.shape, np.uint8)
    m = _check_affine(grid_to_target)
    mask_items = dict(masks or {})
    for name, mk in mask_items.items():
        check_volume(f"mask {name!r}", np.asarray(mk), grid.shape)
    lut = _label_lut(target, label_table)
    # classes the target maps to its empty label rank below every class it keeps, so a wall or
    # prop voxel in a target voxel of road does not turn the road empty (SemanticKITTI: 0)
    prio = [int(c) for c in (DEFAULT_POOLING_PRIORITY if priority is None else priority)]
    prio = [c for c in prio if lut[c] != target.free_label] + [c for c in prio if lut[c] == target.free_label]
    rank, label = rank_table(prio)
    points = not np.array_equal(m[:3, :3], np.eye(3))  # a pure translation takes the fast path

    # 1. per target voxel, the max rank of the classes whose centres land in it (0 = nothing)
    best = bin_reduce(semantic, lambda a: rank[a], grid, m, target, np.maximum, np.uint8, points)
    # 2. rank -> our class -> target id; nothing received -> free
    labels = lut[label[best]]
    labels[best == 0] = target.free_label
    # 3. masks: a target voxel is observed when any observed voxel centre of ours falls in it
    out_masks = {
        name: bin_reduce(np.asarray(mk), lambda a: a != 0, grid, m, target, np.logical_or, bool, points)
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
    check_volume("semantic", semantic, grid.shape, np.uint8)
    check_volume("instance", np.asarray(instance), grid.shape)
    m = _check_affine(grid_to_target)
    lut = _label_lut(target, label_table)
    prio = [int(c) for c in (DEFAULT_POOLING_PRIORITY if priority is None else priority)]
    prio = [c for c in prio if lut[c] != target.free_label] + [c for c in prio if lut[c] == target.free_label]
    rank, _ = rank_table(prio)
    points = not np.array_equal(m[:3, :3], np.eye(3))
    # 1. per target voxel, max of (class rank << 32 | instance): the winning class's largest id
    key = (rank[semantic].astype(np.uint64) << np.uint64(32)) | np.asarray(instance, dtype=np.uint64)
    best = bin_reduce(key, lambda a: a, grid, m, target, np.maximum, np.uint64, points)
    instances = (best & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    if flow is None:
        return instances, None
    flow = np.asarray(flow)
    if flow.shape != (*grid.shape, 3):
        raise ValueError(f"flow has shape {flow.shape}, expected {(*grid.shape, 3)}")
    # 2. the mean of the non-zero flows per target voxel, component by component
    moving = np.any(flow != 0, axis=-1)
    count = bin_reduce(moving.astype(np.uint32), lambda a: a, grid, m, target, np.add, np.uint32, points)
    out = np.zeros((*target.shape, 3), np.float32)
    for c in range(3):
        comp = np.where(moving, flow[..., c].astype(np.float32), np.float32(0))
        out[..., c] = bin_reduce(comp, lambda a: a, grid, m, target, np.add, np.float64, points)
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
