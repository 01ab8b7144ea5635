"""Temporal Consistency Score (paper, section 4.2), with the conventions the paper leaves loose.

Inputs: two consecutive semantic grids ``O_t`` and ``O_{t+1}`` (uint8, ``[x, y, z]``, 0 = free),
the grids' geometry (``origin`` = minimum corner of voxel (0, 0, 0) and ``voxel_size``, metres, in
the frame the grid is expressed in: the LiDAR frame for CarlaOcc) and the two **sensor-to-world**
4x4 poses ``P_t``, ``P_{t+1}`` of that frame.

Convention (exact):

1. **Pose order.** ``T = inv(P_{t+1}) @ P_t`` (``P`` sensor-to-world, column vectors,
   ``p = T x``) maps frame-t sensor coordinates into frame t+1. The paper writes
   ``T_t T_{t+1}^{-1}``: the same map under a row-vector convention (``p = x T_t T_{t+1}^{-1}``,
   applied left to right) with sensor-to-world ``T``. (With world-to-sensor ``T`` and column
   vectors it would be ``inv(P_t) @ P_{t+1}``, the inverse map.)
2. **Warp.** Every voxel ``v = (i, j, k)`` of grid t has the centre
   ``x(v) = origin_t + (v + 0.5) * voxel_t``; its image is ``p = T x(v)``.
3. **Nearest sampling** ``Pi``: the frame-(t+1) voxel containing ``p``,
   ``u = floor((p - origin_{t+1}) / voxel_{t+1})``; the warped label is ``W(v) = O_{t+1}(u)``
   (so ``Ṽ_t^(c) = {v | W(v) = c}``, a set of frame-t voxels, like ``V_t^(c) = {v | O_t(v) = c}``).
   A centre exactly on a voxel face (measure zero) goes wherever float rounding puts it.
4. **Valid mask** ``M_t``: voxels ``v`` with ``u`` inside grid t+1 (centres leaving the region are
   excluded), with a static class in both frames (``static[O_t(v)]`` and ``static[W(v)]``; free,
   class 0, counts as static, dynamic classes are the taxonomy's road users) and, when visibility
   masks are given, observed in both frames (``mask_t(v)`` and ``mask_{t+1}(u)`` nonzero).
5. **Counts** per class ``c >= 1`` (free is not a class: free/free agreement adds nothing, free
   against an occupied class adds to that class's union):
   ``I_c = |{v in M_t | O_t(v) = c and W(v) = c}|``,
   ``U_c = |{v in M_t | O_t(v) = c or W(v) = c}|``.
6. **Aggregation.** The paper's equation pools the sums:
   ``s_tc = sum_t sum_c I_c / sum_t sum_c U_c`` over pairs ``(t, t+1)`` and classes ``c >= 1``
   (:attr:`TemporalCounts.score`); NaN when the union is empty. The per-class counts are kept, so
   the class-averaged variant (mean over classes of ``sum_t I_c / sum_t U_c``,
   :meth:`TemporalCounts.mean_class_iou`) is available too; it is not the paper's score.

A static scene seen from a sensor moved by whole voxels (or rotated by multiples of 90 degrees
about a voxel-lattice axis) scores exactly 1.

Speed: the per-voxel loop is compiled (numba) and visits, per (i, j) column of grid t, only the z
range that can contribute (voxels where both ``O_t(v)`` and ``W(v)`` are free add nothing): the hull
of the column's occupied range and of the back-warped occupied ranges of the frame-(t+1) columns
the warped column passes through.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numba
import numpy as np

from carlaocc.schemas.taxonomy import dynamic_ids
from carlaocc.stages.quality.blocks import (BitGrid, BlockedGrid, first_bit, first_nonzero, last_bit,
                                             last_nonzero, uint8_grid)

N_CLASSES = 256  # counts are kept per uint8 value, as for spatial continuity


@dataclass(frozen=True)
class TemporalCounts:
    """Per-class intersection and union voxel counts (index = class id; class 0, free, stays 0)."""

    intersection: np.ndarray  # (256,) int64
    union: np.ndarray  # (256,) int64

    @property
    def total_intersection(self) -> int:
        return int(self.intersection[1:].sum())

    @property
    def total_union(self) -> int:
        return int(self.union[1:].sum())

    @property
    def score(self) -> float:
        """The paper's ``s_tc``: pooled ``sum I / sum U`` over classes >= 1; NaN when ``U`` is 0."""
        return pooled_temporal(self.total_intersection, self.total_union)

    def class_iou(self) -> np.ndarray:
        """(256,) float64 IoU per class (NaN where the class's union is empty, and for class 0)."""
        iou = np.full(N_CLASSES, np.nan)
        has = self.union > 0
        has[0] = False
        iou[has] = self.intersection[has] / self.union[has]
        return iou

    def mean_class_iou(self) -> float:
        """Alternative aggregation (not the paper's): mean IoU over classes with a nonempty union."""
        iou = self.class_iou()
        return float("nan") if np.isnan(iou).all() else float(np.nanmean(iou))

    def __add__(self, other: TemporalCounts) -> TemporalCounts:
        return TemporalCounts(self.intersection + other.intersection, self.union + other.union)


def pooled_temporal(intersection: int, union: int) -> float:
    """``sum I / sum U`` from counts summed over any classes and frame pairs (the one definition of
    the score: a pair's, a sequence's and a dataset's); NaN when ``union`` is 0."""
    return float("nan") if union == 0 else intersection / union


def empty_temporal_counts() -> TemporalCounts:
    return TemporalCounts(np.zeros(N_CLASSES, np.int64), np.zeros(N_CLASSES, np.int64))


def sequence_temporal(per_pair: Iterable[TemporalCounts]) -> TemporalCounts:
    """Counts summed over frame pairs (the paper's sums over t)."""
    total = empty_temporal_counts()
    for c in per_pair:
        total = total + c
    return total


def static_table(dynamic: Iterable[int] | None = None) -> np.ndarray:
    """(256,) bool lookup: True for static class ids. ``dynamic`` defaults to the CarlaOcc
    taxonomy's dynamic classes (the road users); every other id, free included, is static."""
    table = np.ones(N_CLASSES, dtype=np.bool_)
    ids = np.asarray(list(dynamic_ids() if dynamic is None else dynamic), dtype=np.int64)
    if ids.size and (ids.min() < 0 or ids.max() >= N_CLASSES):
        raise ValueError(f"dynamic class ids must be 0..255, got {ids.tolist()}")
    table[ids] = False
    return table


def relative_pose(pose_t: np.ndarray, pose_t1: np.ndarray) -> np.ndarray:
    """``inv(P_{t+1}) @ P_t``: frame-t sensor coordinates -> frame-(t+1) sensor coordinates."""
    p0, p1 = _pose(pose_t, "pose_t"), _pose(pose_t1, "pose_t1")
    return np.linalg.inv(p1) @ p0


def _pose(pose, name: str) -> np.ndarray:
    p = np.asarray(pose, dtype=np.float64)
    if p.shape == (16,):
        p = p.reshape(4, 4)
    if p.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 matrix (or 16 row-major floats), got shape {p.shape}")
    if not np.isfinite(p).all():
        raise ValueError(f"{name} must be finite")
    if not np.allclose(p[3], (0.0, 0.0, 0.0, 1.0)):
        raise ValueError(f"{name}: last row must be (0, 0, 0, 1), got {p[3].tolist()}")
    if abs(np.linalg.det(p[:3, :3]) - 1.0) > 1e-3:
        raise ValueError(f"{name}: rotation part is not a rotation (det {np.linalg.det(p[:3, :3]):.4g})")
    return p


def _semantic(a, name: str) -> BlockedGrid:
    """A semantic grid (dense or :class:`~.blocks.BlockedGrid`) as uint8 blocks."""
    return uint8_grid(a, name)


def _masks(m, sem: BlockedGrid, name: str) -> tuple[BitGrid, int]:
    """A frame's visibility: one mask or a tuple of masks (observed by any), each dense, a
    :class:`~.blocks.BlockedGrid` (nonzero = observed) or a :class:`~.blocks.BitGrid` (the stored
    ``observed_bits``, used as it is when in ``sem``'s blocks), as one bit grid in ``sem``'s
    blocks; and how many masks were given."""
    masks = list(m) if isinstance(m, tuple) else [m]
    if not 1 <= len(masks) <= 2:
        raise ValueError(f"{name}: give one or two visibility masks, got {len(masks)}")
    out = None
    for mask in masks:
        if isinstance(mask, BitGrid):
            if mask.shape != sem.shape:
                raise ValueError(f"{name} has shape {mask.shape}, its semantic grid has {sem.shape}")
            bits = mask if mask.blocks.shape[:4] == sem.blocks.shape[:4] else BitGrid.pack(
                sem.like(mask.unpacked(), name))
        else:
            bits = BitGrid.pack(sem.like(mask, name))
        # observed by any: the OR of the masks' bits
        out = bits if out is None else BitGrid(out.blocks | bits.blocks, sem.shape)
    return out, len(masks)


def column_ranges(semantic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per ``(i, j)`` column of a semantic grid (dense or :class:`~.blocks.BlockedGrid`): the
    lowest and highest ``k`` with a nonzero label (``lo > hi`` when none), int32 ``(X, Y)`` each.
    Compute it once per frame and pass it to :func:`temporal_consistency_counts` for both pairs
    the frame belongs to (:func:`~carlaocc.stages.quality.continuity.continuity_and_ranges` gives
    it with the continuity counts in the same pass)."""
    grid = _semantic(semantic, "semantic")
    ox, oy = grid.offsets()
    return _column_ranges(grid.flat, grid.words(), ox, oy, grid.shape[2])


@numba.njit(cache=True, nogil=True)
def _column_ranges(flat, words, ox, oy, Z):  # pragma: no cover - numba
    """Per (i, j) column: the lowest and highest k with a nonzero label (lo > hi when none)."""
    X, Y = ox.size, oy.size
    lo = np.full((X, Y), Z, dtype=np.int32)
    hi = np.full((X, Y), -1, dtype=np.int32)
    for i in range(X):
        for j in range(Y):
            s = ox[i] + oy[j]
            first = first_nonzero(flat, words, s, s + Z) - s
            if first < Z:
                lo[i, j] = first
                hi[i, j] = last_nonzero(flat, words, s + first, s + Z) - s
    return lo, hi


@numba.njit(cache=True, nogil=True)
def _tc_kernel(sem0, ox0, oy0, Z0, sem1, ox1, oy1, Z1, mb0, mx0, my0, mb1, mx1, my1, has_mask, static, A, c,
               lo0, hi0, lo1, hi1):  # pragma: no cover - numba
    """Count per-class intersections and unions. ``q = A @ (i, j, k) + c`` is voxel (i, j, k)'s
    centre warped into frame t+1's continuous voxel coordinates (voxel u spans [u, u + 1)). Each
    grid is read flat through its offset tables (voxel (i, j, k) of frame t is
    ``sem0[ox0[i] + oy0[j] + k]``, :class:`~.blocks.BlockedGrid`); each frame's visibility (when
    ``has_mask``) is bits packed along z, voxel (i, j, k) of frame t being bit ``k % 8`` of
    ``mb0[mx0[i] + my0[j] + k // 8]`` (:class:`~.blocks.BitGrid`)."""
    X0, Y0 = ox0.size, oy0.size
    X1, Y1 = ox1.size, oy1.size
    inter = np.zeros(256, dtype=np.int64)
    union = np.zeros(256, dtype=np.int64)
    a02, a12, a22 = A[0, 2], A[1, 2], A[2, 2]
    for i in range(X0):
        for j in range(Y0):
            # warped centre of (i, j, 0); the column is the line bx + k * a02 ...
            bx = A[0, 0] * i + A[0, 1] * j + c[0]
            by = A[1, 0] * i + A[1, 1] * j + c[1]
            bz = A[2, 0] * i + A[2, 1] * j + c[2]
            # k range to visit: start with the column's own occupied range
            k_lo = lo0[i, j]
            k_hi = hi0[i, j]
            # frame-(t+1) columns the warped line crosses: bounding box of its end points
            ex, ey = bx + a02 * (Z0 - 1), by + a12 * (Z0 - 1)
            ix0 = int(math.floor(min(bx, ex)))
            ix1 = int(math.floor(max(bx, ex)))
            iy0 = int(math.floor(min(by, ey)))
            iy1 = int(math.floor(max(by, ey)))
            ix0, iy0 = max(ix0, 0), max(iy0, 0)
            ix1, iy1 = min(ix1, X1 - 1), min(iy1, Y1 - 1)
            if ix0 <= ix1 and iy0 <= iy1:
                zlo, zhi = Z1, -1
                for ii in range(ix0, ix1 + 1):
                    for jj in range(iy0, iy1 + 1):
                        if lo1[ii, jj] < zlo:
                            zlo = lo1[ii, jj]
                        if hi1[ii, jj] > zhi:
                            zhi = hi1[ii, jj]
                if zlo <= zhi:
                    if abs(a22) > 0.25:
                        # q_z(k) in [zlo, zhi + 1)  <=>  k between these two bounds (one voxel margin)
                        ka = (zlo - bz) / a22
                        kb = (zhi + 1 - bz) / a22
                        klo = int(math.floor(min(ka, kb))) - 1
                        khi = int(math.ceil(max(ka, kb))) + 1
                    else:  # the column lies across frame t+1's z axis: visit all of it
                        klo, khi = 0, Z0 - 1
                    if klo < k_lo:
                        k_lo = klo
                    if khi > k_hi:
                        k_hi = khi
            k_lo = max(k_lo, 0)
            k_hi = min(k_hi, Z0 - 1)
            s0 = ox0[i] + oy0[j]
            m0 = mx0[i] + my0[j]
            if has_mask and k_lo <= k_hi:
                # every voxel that counts is observed in frame t: narrow the range to the
                # column's first and last observed voxels in it (unobserved runs, the insides of
                # the ground and of buildings, skipped eight voxels at a time)
                a0 = first_bit(mb0, m0, k_lo, k_hi)
                k_hi = last_bit(mb0, m0, k_lo, k_hi)
                k_lo = a0
            for k in range(k_lo, k_hi + 1):
                a = sem0[s0 + k]
                if not static[a]:
                    continue
                # nearest voxel of frame t+1: floor of the continuous coordinates, inside the grid
                qx = bx + a02 * k
                qy = by + a12 * k
                qz = bz + a22 * k
                if qx < 0.0 or qy < 0.0 or qz < 0.0:
                    continue
                u = int(qx)
                w = int(qy)
                s = int(qz)
                if u >= X1 or w >= Y1 or s >= Z1:
                    continue
                s1 = ox1[u] + oy1[w] + s
                b = sem1[s1]
                # free against free adds nothing (most of the range): the masks are read only
                # where a count may change
                if (a == 0 and b == 0) or not static[b]:
                    continue
                if has_mask and ((mb0[m0 + (k >> 3)] >> (k & 7)) & 1) == 0:
                    continue
                if has_mask and ((mb1[mx1[u] + my1[w] + (s >> 3)] >> (s & 7)) & 1) == 0:
                    continue
                # per-class intersection and union over classes >= 1
                if a == b:
                    if a != 0:
                        inter[a] += 1
                        union[a] += 1
                else:
                    if a != 0:
                        union[a] += 1
                    if b != 0:
                        union[b] += 1
    return inter, union


def warp_to_voxels(relative: np.ndarray, origin_t: Sequence[float], voxel_t: float,
                   origin_t1: Sequence[float], voxel_t1: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, c)`` with ``q = A @ v + c``: the centre of grid-t voxel ``v`` (integer index vector)
    mapped by ``relative`` (frame t -> frame t+1) into grid t+1's continuous voxel coordinates,
    ``q = (R (origin_t + (v + 0.5) voxel_t) + t - origin_t1) / voxel_t1``."""
    R, t = relative[:3, :3], relative[:3, 3]
    o0, o1 = np.asarray(origin_t, np.float64), np.asarray(origin_t1, np.float64)
    A = R * (voxel_t / voxel_t1)
    c = (R @ (o0 + 0.5 * voxel_t) + t - o1) / voxel_t1
    return np.ascontiguousarray(A), np.ascontiguousarray(c)


def temporal_consistency_counts(
    semantic_t: np.ndarray | BlockedGrid,
    semantic_t1: np.ndarray | BlockedGrid,
    pose_t: np.ndarray,
    pose_t1: np.ndarray,
    voxel_size: float,
    origin: Sequence[float],
    *,
    mask_t: np.ndarray | BlockedGrid | tuple | None = None,
    mask_t1: np.ndarray | BlockedGrid | tuple | None = None,
    static: np.ndarray | None = None,
    voxel_size_t1: float | None = None,
    origin_t1: Sequence[float] | None = None,
    ranges_t: tuple[np.ndarray, np.ndarray] | None = None,
    ranges_t1: tuple[np.ndarray, np.ndarray] | None = None,
) -> TemporalCounts:
    """Per-class ``|I_c|`` and ``|U_c|`` within ``M_t`` of the pair (t, t+1) (module docstring).

    ``semantic_*``: uint8 (or integer 0..255) ``(X, Y, Z)`` grids, 0 = free, dense or
    :class:`~carlaocc.stages.quality.blocks.BlockedGrid` (as the store decodes them). ``pose_*``: 4x4
    sensor-to-world poses of the grids' frame. ``voxel_size`` (m) and ``origin`` (m, minimum corner
    of voxel (0, 0, 0)) describe grid t and, unless ``voxel_size_t1`` / ``origin_t1`` are given,
    grid t+1 too. ``mask_*``: visibility (nonzero = observed), both or neither; a tuple of
    two masks per frame means observed by either (camera or LiDAR); a
    :class:`~carlaocc.stages.quality.blocks.BitGrid` is a mask already packed to bits (the stored
    ``observed_bits``), read as it is. ``static``: (256,)
    bool table (:func:`static_table`; default: the CarlaOcc taxonomy). ``ranges_*``: each grid's
    :func:`column_ranges`, when the caller already has them (computed here otherwise).
    """
    sem0, sem1 = _semantic(semantic_t, "semantic_t"), _semantic(semantic_t1, "semantic_t1")
    if (mask_t is None) != (mask_t1 is None):
        raise ValueError("give both visibility masks (mask_t and mask_t1) or neither")
    if mask_t is None:
        m0 = m1 = BitGrid.pack(BlockedGrid.dense(np.zeros((1, 1, 1), np.uint8)))  # never read
        (mx0, my0), (mx1, my1) = m0.offsets(), m1.offsets()
    else:
        (m0, n0), (m1, n1) = _masks(mask_t, sem0, "mask_t"), _masks(mask_t1, sem1, "mask_t1")
        if n0 != n1:
            raise ValueError(f"mask_t has {n0} masks and mask_t1 {n1}: give each frame the same ones")
        (mx0, my0), (mx1, my1) = m0.offsets(), m1.offsets()
    table = static_table() if static is None else np.asarray(static, dtype=np.bool_)
    if table.shape != (N_CLASSES,):
        raise ValueError(f"static must be a (256,) bool table, got shape {table.shape}")
    voxel_size_t1 = voxel_size if voxel_size_t1 is None else voxel_size_t1
    o1 = origin if origin_t1 is None else origin_t1
    for name, v in (("voxel_size", voxel_size), ("voxel_size_t1", voxel_size_t1)):
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive finite number of metres, got {v!r}")
    for name, o in (("origin", origin), ("origin_t1", o1)):
        if len(o) != 3 or not all(math.isfinite(float(x)) for x in o):
            raise ValueError(f"{name} must be 3 finite numbers, got {o!r}")
    A, c = warp_to_voxels(relative_pose(pose_t, pose_t1), origin, float(voxel_size), o1, float(voxel_size_t1))
    # per-column occupied z ranges bound the work to voxels where O_t or W is occupied
    lo0, hi0 = column_ranges(sem0) if ranges_t is None else ranges_t
    lo1, hi1 = column_ranges(sem1) if ranges_t1 is None else ranges_t1
    if lo0.shape != sem0.shape[:2] or lo1.shape != sem1.shape[:2]:
        raise ValueError("ranges_t / ranges_t1 must be the column_ranges of semantic_t / semantic_t1")
    (ox0, oy0), (ox1, oy1) = sem0.offsets(), sem1.offsets()
    inter, union = _tc_kernel(sem0.flat, ox0, oy0, sem0.shape[2], sem1.flat, ox1, oy1, sem1.shape[2],
                              m0.flat, mx0, my0, m1.flat, mx1, my1, mask_t is not None, table, A, c,
                              lo0, hi0, lo1, hi1)
    return TemporalCounts(inter, union)
