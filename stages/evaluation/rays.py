"""Ray-based occupancy metrics: RayIoU and RayPQ (SparseOcc), with OccNet's relative-depth variant.

The protocol (``../shared/reference/training-formats.md`` sections 7, 8 and 10 give it with its
public sources), per evaluated sample:

1. **Origins**: up to 8 positions in the sample's grid frame (metres): the LiDAR positions of the
   frames of its scene, past and future, mapped into the sample's frame, kept when ``|x| < 39``
   and ``|y| < 39`` m, then 8 of them at indices ``round(linspace(0, n - 1, 8))``
   (:func:`select_origins`).
2. **Directions**: one fixed LiDAR-like set of 39 pitches x 360 azimuths = 14,040 unit vectors
   (:func:`query_directions`): pitches ``-(pi/2 - atan(k + 1))`` for k = 0..9, then steps of the
   last gap until the pitch reaches 0.21 rad; azimuths every degree.
3. **First hit** of each ray in a grid, by the exact voxel traversal of
   :mod:`carlaocc.stages.voxelize.visibility` (Amanatides-Woo, the same slab clipping and setup,
   :mod:`carlaocc.stages.voxelize.dda`) with SparseOcc's rounding and tie rule (its CUDA caster
   ``lib/dvr/dvr.cu``): float32 origins and end points (origin + direction, voxel units), the
   direction re-normalised from them in float64, ties stepping z, then y, then x, and a float32
   depth (:func:`first_hits`); the visibility masks keep their own rule:
   the first occupied voxel it enters; its **depth is where the ray leaves that voxel** (the exit
   face), in metres; a ray that leaves the grid without a hit takes the last voxel it crossed and
   that voxel's exit (normally free). The same origins and directions run through the ground
   truth and the prediction.
4. **Rays kept**: those whose ground-truth label is not free.
5. **RayIoU**, over all rays of the dataset, per class ``c`` and threshold ``t`` (1, 2, 4 m):
   ``TP`` = rays with both labels ``c`` and ``|d_pred - d_gt| < t`` (strict; OccNet's variant also
   accepts ``|d_pred - d_gt| / d_gt < 0.1``), ``IoU = TP / (GT + P - TP)``; classes with no ray
   on either side are NaN and left out of the means; ``RayIoU@t`` = mean over classes,
   ``RayIoU`` = mean over thresholds and classes.
6. **RayPQ**: each ray also carries the instance id of the voxel it hits. Ground-truth things
   (``thing_classes``) form one segment per instance (an instance whose rays carry more than one
   class loses its id: its rays join their class's segment of rays without an instance); every
   other class is one segment per class and sample. Per sample, class
   and threshold: segments are matched at IoU > 0.5, the intersection counting only rays within
   the depth threshold, the areas all the segment's rays; ``FP`` / ``FN`` are unmatched segments of
   at least 10 rays. ``PQ = sum IoU / (TP + FP/2 + FN/2)`` per class over the dataset.
7. **Flow** (OccNet's occupancy-and-flow track), when both sides carry a 2-D flow per voxel:
   ``mAVE`` = the mean over the moving classes of the mean L2 error (m/s) between the flows at
   the hit voxels of the true-positive rays at 2 m; the occupancy score is
   ``0.9 * RayIoU + 0.1 * max(1 - mAVE, 0)``.

Frames and units: grids are ``(X, Y, Z)`` class ids indexed ``[x, y, z]``; a voxel ``(i, j, k)``
spans ``origin + [i, i + 1) * voxel_size`` on each axis; ray origins are metres in the grid's
frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from carlaocc.stages.voxelize.dda import axis_setup, clamp_floor, slab

__all__ = ["RayAccumulator", "RayIoUResult", "RayPQResult", "first_hits", "query_directions", "ray_inputs", "select_origins",
           "THRESHOLDS", "MIN_SEGMENT_RAYS", "MAX_ORIGINS", "ORIGIN_LIMIT"]

THRESHOLDS = (1.0, 2.0, 4.0)
MIN_SEGMENT_RAYS = 10
MAX_ORIGINS = 8
ORIGIN_LIMIT = 39.0  # m: origins with |x| or |y| beyond are dropped
RELATIVE = 0.1  # OccNet's relative depth error
FLOW_THRESHOLD = 2.0  # m: the true-positive rays mAVE is measured on (OccNet)


def query_directions() -> np.ndarray:
    """(14040, 3) float64 unit ray directions: 39 pitches from -45 deg up to about 12.6 deg (the
    first ten ``-(pi/2 - atan(k + 1))``, then steps of the last gap until 0.21 rad is reached),
    each at the 360 whole-degree azimuths."""
    pitches = [-(math.pi / 2 - math.atan(k + 1)) for k in range(10)]
    while pitches[-1] < 0.21:  # the gap taken afresh from the last two each time (as SparseOcc)
        pitches.append(pitches[-1] + (pitches[-1] - pitches[-2]))
    p = np.asarray(pitches)[:, None]
    az = np.radians(np.arange(360.0))[None, :]
    d = np.stack([np.cos(p) * np.cos(az), np.cos(p) * np.sin(az), np.sin(p) * np.ones_like(az)], axis=-1)
    return d.reshape(-1, 3)


def select_origins(positions: np.ndarray) -> np.ndarray:
    """Origins of one sample from the LiDAR positions (T, 3) of its scene's frames in the sample's
    grid frame (m, in time order): those with ``|x|, |y| < 39`` m, at most 8 evenly spread."""
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    p = p[(np.abs(p[:, 0]) < ORIGIN_LIMIT) & (np.abs(p[:, 1]) < ORIGIN_LIMIT)]
    if len(p) > MAX_ORIGINS:
        p = p[np.round(np.linspace(0, len(p) - 1, MAX_ORIGINS)).astype(np.int64)]
    return p


@njit(cache=True, nogil=True)
def _first_hit(occ, nx, ny, nz, ox, oy, oz, ex, ey, ez):
    """(exit t in voxels, linear voxel index) of the first occupied voxel along the ray from
    ``o`` through the end point ``e`` (voxel units, float32 values computed in float64 as
    SparseOcc's caster does), or of the last voxel it crosses in the grid; (-1, -1) when it misses
    the grid. Ties step z, then y, then x (x only when strictly nearest, y when strictly nearer
    than z), SparseOcc's ``lib/dvr/dvr.cu`` rule."""
    rx, ry, rz = ex - ox, ey - oy, ez - oz
    norm = math.sqrt(rx * rx + ry * ry + rz * rz)
    if not (norm > 0.0):
        return -1.0, -1
    dx, dy, dz = rx / norm, ry / norm, rz / norm
    t0, t1 = slab(ox, dx, nx, 0.0, math.inf)
    t0, t1 = slab(oy, dy, ny, t0, t1)
    t0, t1 = slab(oz, dz, nz, t0, t1)
    if not (t0 <= t1):
        return -1.0, -1
    i = clamp_floor(ox + t0 * dx, nx)
    j = clamp_floor(oy + t0 * dy, ny)
    k = clamp_floor(oz + t0 * dz, nz)
    tmx, tdx, sx, lx = axis_setup(ox, dx, i, nx)
    tmy, tdy, sy, ly = axis_setup(oy, dy, j, ny)
    tmz, tdz, sz, lz = axis_setup(oz, dz, k, nz)
    while True:
        t_exit = min(tmx, tmy, tmz)  # where the ray leaves the current voxel
        lin = (i * ny + j) * nz + k
        if occ[lin]:
            return t_exit, lin
        if tmx < tmy and tmx < tmz:
            if lx == 0:
                return t_exit, lin
            lx -= 1
            tmx += tdx
            i += sx
        elif tmy < tmz:
            if ly == 0:
                return t_exit, lin
            ly -= 1
            tmy += tdy
            j += sy
        else:
            if lz == 0:
                return t_exit, lin
            lz -= 1
            tmz += tdz
            k += sz


@njit(parallel=True, cache=True, nogil=True)
def _first_hits(occ, nx, ny, nz, O, E, t_out, lin_out):
    n = E.shape[0] // O.shape[0]
    for r in prange(E.shape[0]):
        q = r // n
        t, lin = _first_hit(occ, nx, ny, nz, np.float64(O[q, 0]), np.float64(O[q, 1]), np.float64(O[q, 2]),
                            np.float64(E[r, 0]), np.float64(E[r, 1]), np.float64(E[r, 2]))
        t_out[r] = t
        lin_out[r] = lin


def ray_inputs(origins: np.ndarray, directions: np.ndarray, grid_origin, voxel_size: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """The caster's inputs as SparseOcc's ``process_one_sample`` forms them: float32 origins and
    end points in voxel units, ``float32((o - grid_origin) / voxel_size)`` and
    ``float32((float32(d) + o - grid_origin) / voxel_size)`` (the end point one metre along the
    float32 direction), computed in float64 from the float32 grid origin and voxel size.
    Returns ((Q, 3), (Q * N, 3)) float32, origin-major."""
    o = np.asarray(origins, np.float64).reshape(-1, 3)
    off = np.asarray(grid_origin, np.float32).astype(np.float64)
    voxel_size32 = np.float64(np.float32(voxel_size))  # the voxel size as the official float32 grid holds it
    d = np.asarray(directions, np.float32).reshape(-1, 3).astype(np.float64)
    O = ((o - off) / voxel_size32).astype(np.float32)
    E = (((d[None, :, :] + o[:, None, :]) - off) / voxel_size32).astype(np.float32).reshape(-1, 3)
    return np.ascontiguousarray(O), np.ascontiguousarray(E)


def first_hits(occupied: np.ndarray, origins: np.ndarray, directions: np.ndarray, grid_origin, voxel_size: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Depth (m, to the exit face of the hit voxel) and linear index of the hit voxel (C order;
    -1: the ray misses the grid) of every (origin, direction) pair, origin-major: ray
    ``q * len(directions) + d``. ``occupied``: (X, Y, Z) bool; origins (Q, 3) m in the grid's
    frame; directions (N, 3) unit.

    SparseOcc's rounding: float32 origins and end points (:func:`ray_inputs`), the direction
    re-normalised from them, and the depth ``float32(float32(t) * float32(voxel_size))`` as
    its float32 ``pred_dist * voxel_size`` (returned as float64)."""
    occ = np.ascontiguousarray(occupied, dtype=np.bool_).reshape(-1)
    nx, ny, nz = occupied.shape
    O, E = ray_inputs(origins, directions, grid_origin, voxel_size)
    t = np.empty(len(E), np.float64)
    lin = np.empty(len(E), np.int64)
    if len(E):
        _first_hits(occ, nx, ny, nz, O, E, t, lin)
    depth = (t.astype(np.float32) * np.float32(voxel_size)).astype(np.float64)
    return np.where(lin < 0, t, depth), lin


@dataclass
class RayIoUResult:
    classes: list[str]
    thresholds: tuple[float, ...]
    iou: np.ndarray  # (T, C) per threshold and class (NaN: no ray either side)
    gt_rays: np.ndarray  # (C,)
    variant: str

    @property
    def by_threshold(self) -> dict[float, float]:
        return {t: float(np.nanmean(self.iou[k])) if np.isfinite(self.iou[k]).any() else float("nan")
                for k, t in enumerate(self.thresholds)}

    @property
    def ray_iou(self) -> float:
        return float(np.nanmean(self.iou)) if np.isfinite(self.iou).any() else float("nan")

    def to_dict(self) -> dict:
        out = {"variant": self.variant, "RayIoU": self.ray_iou}
        out.update({f"RayIoU@{t:g}": v for t, v in self.by_threshold.items()})
        out["per_class"] = {c: {f"@{t:g}": (None if not np.isfinite(self.iou[k, i]) else float(self.iou[k, i]))
                                for k, t in enumerate(self.thresholds)} | {"gt_rays": int(self.gt_rays[i])}
                            for i, c in enumerate(self.classes)}
        return out


@dataclass
class RayPQResult:
    classes: list[str]
    thresholds: tuple[float, ...]
    pq: np.ndarray  # (T, C)
    sq: np.ndarray
    rq: np.ndarray

    @property
    def by_threshold(self) -> dict[float, float]:
        return {t: float(np.nanmean(self.pq[k])) if np.isfinite(self.pq[k]).any() else float("nan")
                for k, t in enumerate(self.thresholds)}

    @property
    def ray_pq(self) -> float:
        return float(np.nanmean(self.pq)) if np.isfinite(self.pq).any() else float("nan")

    def to_dict(self) -> dict:
        out = {"RayPQ": self.ray_pq}
        out.update({f"RayPQ@{t:g}": v for t, v in self.by_threshold.items()})
        out["per_class_pq"] = {c: {f"@{t:g}": (None if not np.isfinite(self.pq[k, i]) else float(self.pq[k, i]))
                                for k, t in enumerate(self.thresholds)} for i, c in enumerate(self.classes)}
        return out


@dataclass
class RayAccumulator:
    """RayIoU and RayPQ over a dataset, one sample at a time (:meth:`update`).

    ``classes``: the label names in id order, the free class last (Occ3D: 18 names, free 17;
    OpenOcc v2: 17, free 16). ``thing_classes``: the ids RayPQ keeps one segment per instance for.
    ``relative``: OccNet's variant (a ray within 10 % of the ground-truth depth is also a TP)."""

    classes: list[str]
    thing_classes: tuple[int, ...] = ()
    thresholds: tuple[float, ...] = THRESHOLDS
    relative: bool = False
    directions: np.ndarray = field(default_factory=query_directions)
    _tp: np.ndarray = field(init=False)
    _gt: np.ndarray = field(init=False)
    _pr: np.ndarray = field(init=False)
    _pq: np.ndarray = field(init=False)  # (T, C, 4): TP, FP, FN, sum IoU
    _ave: np.ndarray = field(init=False)  # (C, 2): flow error sum, TP rays (at FLOW_THRESHOLD)
    rays: int = field(init=False, default=0)
    has_flow: bool = field(init=False, default=False)
    flow_classes: tuple[int, ...] = ()  # the moving classes mAVE is over (OccNet: the 8 road users)

    def __post_init__(self) -> None:
        n, t = len(self.classes), len(self.thresholds)
        self.free = n - 1
        self._tp = np.zeros((t, n), np.int64)
        self._gt = np.zeros(n, np.int64)
        self._pr = np.zeros(n, np.int64)
        self._pq = np.zeros((t, n, 4), np.float64)
        self._ave = np.zeros((n, 2), np.float64)

    def cast(self, sem: np.ndarray, origins: np.ndarray, grid_origin, voxel_size: float,
             inst: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """(depth, label, instance) of every ray through one grid (labels ``free`` where the ray's
        last voxel is free; misses are free at depth 0)."""
        depth, lin = first_hits(sem != self.free, origins, self.directions, grid_origin, voxel_size)
        miss = lin < 0
        lin = np.where(miss, 0, lin)
        flat = sem.reshape(-1)
        label = np.where(miss, self.free, flat[lin]).astype(np.int64)
        ids = None if inst is None else np.where(miss, 0, inst.reshape(-1)[lin]).astype(np.int64)
        return np.where(miss, 0.0, depth), label, ids

    def update(self, gt_sem: np.ndarray, pred_sem: np.ndarray, origins: np.ndarray, grid_origin, voxel_size: float,
               gt_inst: np.ndarray | None = None, pred_inst: np.ndarray | None = None,
               gt_flow: np.ndarray | None = None, pred_flow: np.ndarray | None = None) -> None:
        """Score one sample: its ground truth and prediction (same grid), ray origins (m), and
        optionally instance ids (RayPQ) and 2-D flows ``(X, Y, Z, 2)`` m/s (mAVE)."""
        if gt_sem.shape != pred_sem.shape:
            raise ValueError(f"prediction {pred_sem.shape} and ground truth {gt_sem.shape} differ in shape")
        n = len(self.classes)
        for what, a in (("ground truth", gt_sem), ("prediction", pred_sem)):
            bad = (a < 0) | (a >= n)
            if a.size and bad.any():
                raise ValueError(f"{what} has label {a[bad].flat[0]} outside 0..{n - 1} ({n} classes, free {n - 1})")
        for what, a, trailing in (("ground-truth instances", gt_inst, ()), ("predicted instances", pred_inst, ()),
                                  ("ground-truth flow", gt_flow, (2,)), ("predicted flow", pred_flow, (2,))):
            if a is not None and np.shape(a)[:3] != gt_sem.shape or a is not None and np.shape(a)[3:] not in ((), trailing,
                                                                                                             (3,)):
                raise ValueError(f"{what} has shape {np.shape(a)}, expected {gt_sem.shape + trailing}")
            if a is not None and not trailing and not np.issubdtype(np.asarray(a).dtype, np.integer):
                raise ValueError(f"{what} must be integers, got {np.asarray(a).dtype}")
        origins = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(origins)):
            raise ValueError("ray origins are not finite (check the poses: translations and unit quaternions)")
        if len(origins) == 0:
            return
        gd, gl, gi = self.cast(gt_sem, origins, grid_origin, voxel_size, gt_inst)
        pd, pl, pi = self.cast(pred_sem, origins, grid_origin, voxel_size, pred_inst)
        gv = pv = None
        if gt_flow is not None and pred_flow is not None:
            # the flow at each ray's hit voxel (2-D, m/s)
            gv = self._flow_at(gt_sem, gt_flow, origins, grid_origin, voxel_size)
            pv = self._flow_at(pred_sem, pred_flow, origins, grid_origin, voxel_size)
        self.add_rays(gd, gl, pd, pl, gi, pi, gv, pv)

    def _flow_at(self, sem, flow, origins, grid_origin, voxel_size) -> np.ndarray:
        _, lin = first_hits(sem != self.free, origins, self.directions, grid_origin, voxel_size)
        f = np.asarray(flow, np.float64).reshape(-1, np.asarray(flow).shape[-1])[:, :2]
        return np.where((lin >= 0)[:, None], f[np.maximum(lin, 0)], 0.0)

    def add_rays(self, gd: np.ndarray, gl: np.ndarray, pd: np.ndarray, pl: np.ndarray,
                 gi: np.ndarray | None = None, pi: np.ndarray | None = None,
                 gv: np.ndarray | None = None, pv: np.ndarray | None = None) -> None:
        """Score one sample's rays: ground-truth and predicted depth (m), label and (for RayPQ)
        instance id of every ray, in the same order."""
        n = len(self.classes)
        gd, gl, pd, pl = (np.asarray(a) for a in (gd, gl, pd, pl))
        gl, pl = gl.astype(np.int64), pl.astype(np.int64)
        # keep the rays whose ground truth sees something
        keep = gl != self.free
        gd, gl, pd, pl = gd[keep], gl[keep], pd[keep], pl[keep]
        self.rays += int(keep.sum())
        self._gt += np.bincount(gl, minlength=n)
        self._pr += np.bincount(pl, minlength=n)
        err = np.abs(pd - gd)
        same = gl == pl
        for k, t in enumerate(self.thresholds):
            ok = err < t
            if self.relative:
                ok |= err / np.maximum(gd, 1e-12) < RELATIVE
            self._tp[k] += np.bincount(gl[same & ok], minlength=n)
        if gv is not None and pv is not None:
            # OccNet's mAVE: the 2-D flow error on the true-positive rays at 2 m of the moving classes
            tp = same & (err < FLOW_THRESHOLD)
            if self.relative:
                tp |= same & (err / np.maximum(gd, 1e-12) < RELATIVE)
            e = np.linalg.norm(np.asarray(gv)[keep] - np.asarray(pv)[keep], axis=1)
            np.add.at(self._ave, (gl[tp], 0), e[tp])
            np.add.at(self._ave, (gl[tp], 1), 1.0)
            self.has_flow = True
        if gi is not None and pi is not None:
            self._update_pq(gl, gd, np.asarray(gi, np.int64)[keep], pl, pd, np.asarray(pi, np.int64)[keep])

    def mave(self) -> tuple[float, dict[str, float | None]]:
        """(mAVE, per moving class mean flow error in m/s) over the true-positive rays at 2 m;
        classes without such rays are left out (NaN when none has any)."""
        per = {}
        for c in self.flow_classes:
            s, n = self._ave[c]
            per[self.classes[c]] = float(s / n) if n else None
        vals = [v for v in per.values() if v is not None]
        return (float(np.mean(vals)) if vals else float("nan")), per

    def occupancy_score(self) -> float:
        """OccNet's occupancy-and-flow score ``0.9 * RayIoU + 0.1 * max(1 - mAVE, 0)``."""
        m, _ = self.mave()
        return 0.9 * self.ray_iou().ray_iou + 0.1 * max(1.0 - m, 0.0) if math.isfinite(m) else float("nan")

    def _update_pq(self, gl, gd, gi, pl, pd, pi) -> None:
        n = len(self.classes)
        things = np.isin(np.arange(n), np.asarray(self.thing_classes, dtype=np.int64))
        # 1. ground-truth segments: things per instance (an instance over several classes: free),
        #    everything else one segment per class; the same for the prediction
        gi = gi.copy()
        tg = things[gl] & (gi > 0)
        if tg.any():
            key = gi[tg]
            for iid in np.unique(key):
                rows = np.flatnonzero(tg)[key == iid]
                if len(np.unique(gl[rows])) > 1:
                    gi[rows] = 0  # as SparseOcc: its rays keep their classes, in no instance's segment
        gseg = np.where(things[gl] & (gi > 0), gi + 1, 0)
        pseg = np.where(things[pl] & (pi > 0), pi + 1, 0)
        for c in range(n - 1):
            gmask, pmask = gl == c, pl == c
            if not (gmask.any() or pmask.any()):
                continue
            g_ids, g_area = np.unique(gseg[gmask], return_counts=True)
            p_ids, p_area = np.unique(pseg[pmask], return_counts=True)
            ga, pa = dict(zip(g_ids.tolist(), g_area.tolist())), dict(zip(p_ids.tolist(), p_area.tolist()))
            both = gmask & pmask
            err = np.abs(pd - gd)
            for k, t in enumerate(self.thresholds):
                ok = both & (err < t)
                pairs, inter = np.unique(pseg[ok] + (gseg[ok] << 32), return_counts=True)
                matched_g, matched_p, tp, siou = set(), set(), 0, 0.0
                for key, i_n in zip(pairs.tolist(), inter.tolist()):
                    p_id, g_id = key & 0xFFFFFFFF, key >> 32
                    iou = i_n / (pa[p_id] + ga[g_id] - i_n)
                    if iou > 0.5:
                        matched_g.add(g_id)
                        matched_p.add(p_id)
                        tp += 1
                        siou += iou
                fn = sum(1 for g, a in ga.items() if g not in matched_g and a >= MIN_SEGMENT_RAYS)
                fp = sum(1 for p, a in pa.items() if p not in matched_p and a >= MIN_SEGMENT_RAYS)
                self._pq[k, c] += (tp, fp, fn, siou)

    def ray_iou(self) -> RayIoUResult:
        union = self._gt[None, :] + self._pr[None, :] - self._tp
        with np.errstate(invalid="ignore", divide="ignore"):
            iou = np.where(union > 0, self._tp / np.maximum(union, 1), np.nan)
        keep = [c for c in range(len(self.classes)) if c != self.free]
        return RayIoUResult([self.classes[c] for c in keep], self.thresholds, iou[:, keep], self._gt[keep],
                            "occnet-relative" if self.relative else "sparseocc")

    def ray_pq(self) -> RayPQResult:
        tp, fp, fn, s = (self._pq[..., i] for i in range(4))
        denom = tp + 0.5 * fp + 0.5 * fn
        with np.errstate(invalid="ignore", divide="ignore"):
            pq = np.where(denom > 0, s / np.maximum(denom, 1e-12), np.nan)
            sq = np.where(tp > 0, s / np.maximum(tp, 1), np.where(denom > 0, 0.0, np.nan))
            rq = np.where(denom > 0, tp / np.maximum(denom, 1e-12), np.nan)
        keep = [c for c in range(len(self.classes)) if c != self.free]
        return RayPQResult([self.classes[c] for c in keep], self.thresholds, pq[:, keep], sq[:, keep], rq[:, keep])
