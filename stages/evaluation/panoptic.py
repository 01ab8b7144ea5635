"""Panoptic occupancy: PQ, SQ, RQ over voxels (Kirillov et al. 2019), things and stuff separately.

The exact convention (panopticapi's ``pq_compute`` for void, KITTI/semantic-kitti-api
``PanopticEval`` for the minimum segment size), per frame:

1. Voxels outside the optional ``mask`` are dropped from everything.
2. **Segments.** A stuff class's segment is all its voxels in the frame (instance ids ignored);
   a thing segment is one ``(class, instance)`` pair (instance 0 on a thing class is one segment
   too). The free label and ignore ids form no segment, in ground truth or prediction.
3. **Void** = voxels whose ground truth is an ignore id. They belong to no ground-truth segment;
   a predicted segment keeps them in its area.
4. **IoU** of ground-truth segment ``g`` and predicted segment ``p`` of the same class:
   ``|g & p| / (|g| + |p| - |g & p| - |p & void|)`` (the void part of ``p`` leaves the union).
5. **Match** when IoU > 0.5; such a match is unique (two segments of one side are disjoint, so
   each segment has at most one partner above 0.5). Every match is a TP whatever its size.
6. **FN**: an unmatched ground-truth segment with at least ``min_size`` voxels (smaller unmatched
   ground truth is ignored, KITTI's ``min_points``).
7. **FP**: an unmatched predicted segment, unless more than half of it is void (panopticapi) or
   its non-void part has fewer than ``min_size`` voxels (KITTI).

Per class over all frames: ``PQ = sum IoU(TP) / (TP + FP/2 + FN/2)``, ``SQ = sum IoU(TP) / TP``
(0 when TP = 0), ``RQ = TP / (TP + FP/2 + FN/2)``, so ``PQ = SQ * RQ``. A class with no segment
at all (TP + FP + FN = 0) is NaN and left out of the means (panopticapi); ``PQ``, ``SQ``, ``RQ``
are the means over the remaining classes, ``*_things`` / ``*_stuff`` over thing / stuff classes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from carlaocc.stages.evaluation.ssc import DEFAULT_IGNORE, LabelMap

__all__ = ["PanopticAccumulator", "PanopticResult", "frame_counts"]


def _check_labels(sem: np.ndarray, n: int, ignore: tuple[int, ...], what: str) -> None:
    if not np.issubdtype(sem.dtype, np.integer):
        raise ValueError(f"{what} must be integers, got {sem.dtype}")
    if sem.size == 0:
        return
    bad = (sem < 0) | (sem >= n)
    if ignore:
        bad &= ~np.isin(sem, np.asarray(ignore))
    if bad.any():
        raise ValueError(f"{what} has label {int(sem[bad][0])} outside 0..{n - 1} that is not ignored {list(ignore)}")


def frame_counts(
    pred_sem: np.ndarray,
    pred_inst: np.ndarray,
    gt_sem: np.ndarray,
    gt_inst: np.ndarray,
    label_map: LabelMap,
    things: tuple[int, ...],
    ignore: tuple[int, ...] = DEFAULT_IGNORE,
    min_size: int = 0,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-label ``(tp, fp, fn, iou_sum)`` of one frame, each ``(label_map.n,)`` (see module doc).

    Arrays of one shape (any dimensionality): semantic labels in ``label_map``'s space, integer
    instance ids >= 0 (uint32 in our data), optional bool ``mask`` of kept voxels.
    """
    shape = np.shape(gt_sem)
    for name, a in (("predicted semantics", pred_sem), ("predicted instances", pred_inst),
                    ("ground-truth instances", gt_inst)) + ((("mask", mask),) if mask is not None else ()):
        if np.shape(a) != shape:
            raise ValueError(f"{name} shape {np.shape(a)} differs from ground-truth semantics shape {shape}")
    n, free = label_map.n, label_map.free
    ps, gs = np.asarray(pred_sem).reshape(-1), np.asarray(gt_sem).reshape(-1)
    pi, gi = np.asarray(pred_inst).reshape(-1), np.asarray(gt_inst).reshape(-1)
    _check_labels(gs, n, ignore, "ground-truth semantics")
    _check_labels(ps, n, ignore, "predicted semantics")
    for what, a in (("predicted instances", pi), ("ground-truth instances", gi)):
        if not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{what} must be integers, got {a.dtype}")
        if a.size and a.min() < 0:
            raise ValueError(f"{what} has a negative id {int(a.min())}")

    # 1. per-voxel roles: void (gt ignored), gt segment, predicted segment; then keep only the
    #    voxels that matter (most of a grid is free in both)
    ign = np.asarray(ignore, dtype=np.int64)
    void = np.isin(gs, ign)
    gt_ok = ~void & (gs != free)
    pr_ok = ~np.isin(ps, ign) & (ps != free)
    rel = gt_ok | pr_ok
    if mask is not None:
        rel &= np.asarray(mask, dtype=bool).reshape(-1)
    idx = np.flatnonzero(rel)
    gs, ps = gs[idx].astype(np.int64), ps[idx].astype(np.int64)
    # instance ids renumbered densely per side (only equality matters), so any id range (uint64
    # included) fits the 32 low bits of the segment key below
    gi = np.unique(gi[idx], return_inverse=True)[1].reshape(-1).astype(np.int64)
    pi = np.unique(pi[idx], return_inverse=True)[1].reshape(-1).astype(np.int64)
    void, gt_ok, pr_ok = void[idx], gt_ok[idx], pr_ok[idx]

    # 2. segment keys: class << 32 | instance, instance forced to 0 on stuff classes
    is_thing = np.zeros(max(n, 256), dtype=bool)
    is_thing[list(things)] = True
    g_key = (gs << 32) | np.where(is_thing[np.clip(gs, 0, is_thing.size - 1)], gi, 0)
    p_key = (ps << 32) | np.where(is_thing[np.clip(ps, 0, is_thing.size - 1)], pi, 0)
    g_keys, g_inv, g_area = np.unique(g_key[gt_ok], return_inverse=True, return_counts=True)
    p_keys, p_inv, p_area = np.unique(p_key[pr_ok], return_inverse=True, return_counts=True)
    # void part of each predicted segment
    p_void = np.bincount(p_inv[void[pr_ok]], minlength=len(p_keys))

    # 3. intersections of same-class segment pairs
    g_of = np.full(len(gs), -1, dtype=np.int64)
    g_of[gt_ok] = g_inv
    p_of = np.full(len(ps), -1, dtype=np.int64)
    p_of[pr_ok] = p_inv
    both = gt_ok & pr_ok & (gs == ps)
    pairs, inter = np.unique(g_of[both] * max(len(p_keys), 1) + p_of[both], return_counts=True)
    pg, pp = pairs // max(len(p_keys), 1), pairs % max(len(p_keys), 1)
    union = g_area[pg] + p_area[pp] - inter - p_void[pp]
    iou = inter / union
    hit = iou > 0.5

    # 4. TP / FN / FP per class
    g_cls, p_cls = (g_keys >> 32).astype(np.intp), (p_keys >> 32).astype(np.intp)
    g_matched = np.zeros(len(g_keys), dtype=bool)
    g_matched[pg[hit]] = True
    p_matched = np.zeros(len(p_keys), dtype=bool)
    p_matched[pp[hit]] = True
    tp = np.bincount(g_cls[pg[hit]], minlength=n)[:n]
    iou_sum = np.bincount(g_cls[pg[hit]], weights=iou[hit], minlength=n)[:n]
    fn_seg = ~g_matched & (g_area >= min_size)
    fn = np.bincount(g_cls[fn_seg], minlength=n)[:n]
    fp_seg = ~p_matched & (2 * p_void <= p_area) & (p_area - p_void >= min_size)
    fp = np.bincount(p_cls[fp_seg], minlength=n)[:n]
    return tp.astype(np.int64), fp.astype(np.int64), fn.astype(np.int64), iou_sum.astype(np.float64)


@dataclass(frozen=True)
class PanopticResult:
    """PQ, SQ, RQ per class and averaged (all, things, stuff); fractions, NaN where undefined."""

    label_map: str
    class_ids: tuple[int, ...]
    class_names: tuple[str, ...]
    is_thing: tuple[bool, ...]
    tp: np.ndarray
    fp: np.ndarray
    fn: np.ndarray
    iou_sum: np.ndarray
    pq_class: np.ndarray
    sq_class: np.ndarray
    rq_class: np.ndarray
    means: dict[str, float]  # pq, sq, rq, pq_things, ..., rq_stuff
    frames: int
    min_size: int

    def to_dict(self) -> dict:
        """Plain JSON-able dict (NaN -> None)."""
        f = lambda v: None if np.isnan(v) else float(v)  # noqa: E731
        return {
            "metric": "panoptic",
            "label_map": self.label_map,
            "frames": self.frames,
            "min_size": self.min_size,
            **{k: f(v) for k, v in self.means.items()},
            "classes": [
                {"id": i, "name": nm, "thing": th, "pq": f(pq), "sq": f(sq), "rq": f(rq),
                 "tp": int(tp), "fp": int(fp), "fn": int(fn)}
                for i, nm, th, pq, sq, rq, tp, fp, fn in zip(
                    self.class_ids, self.class_names, self.is_thing, self.pq_class, self.sq_class,
                    self.rq_class, self.tp, self.fp, self.fn)
            ],
        }  # fmt: skip


@dataclass
class PanopticAccumulator:
    """Per-class TP/FP/FN/IoU sums over frames (see the module doc for the convention).

    ``things``: thing label ids (default: the label map's); ``min_size``: voxels.
    """

    label_map: LabelMap
    ignore: tuple[int, ...] = DEFAULT_IGNORE
    min_size: int = 0
    things: tuple[int, ...] | None = None
    tp: np.ndarray = field(init=False)
    fp: np.ndarray = field(init=False)
    fn: np.ndarray = field(init=False)
    iou_sum: np.ndarray = field(init=False)
    frames: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        n = self.label_map.n
        self.ignore = tuple(int(v) for v in self.ignore)
        if self.min_size < 0:
            raise ValueError(f"min_size must be >= 0 voxels, got {self.min_size}")
        if self.things is None:
            self.things = self.label_map.things
        self.things = tuple(int(t) for t in self.things)
        bad = [t for t in self.things if not 0 <= t < n or t == self.label_map.free]
        if bad:
            raise ValueError(f"thing ids {bad} are not classes of label map {self.label_map.name!r} (0..{n - 1}, not free)")
        self.tp = np.zeros(n, dtype=np.int64)
        self.fp = np.zeros(n, dtype=np.int64)
        self.fn = np.zeros(n, dtype=np.int64)
        self.iou_sum = np.zeros(n, dtype=np.float64)

    def update(self, pred_sem, pred_inst, gt_sem, gt_inst, mask=None) -> None:
        """Add one frame (see :func:`frame_counts`)."""
        tp, fp, fn, s = frame_counts(pred_sem, pred_inst, gt_sem, gt_inst, self.label_map,
                                     self.things, self.ignore, self.min_size, mask)  # fmt: skip
        self.tp += tp
        self.fp += fp
        self.fn += fn
        self.iou_sum += s
        self.frames += 1

    def result(self) -> PanopticResult:
        """PQ/SQ/RQ per class and their means over the classes that have a segment."""
        lm = self.label_map
        cls = np.array([c for c in lm.classes if c not in self.ignore], dtype=np.intp)
        tp, fp, fn, s = self.tp[cls], self.fp[cls], self.fn[cls], self.iou_sum[cls]
        present = (tp + fp + fn) > 0
        den = tp + 0.5 * fp + 0.5 * fn
        nan = np.full(len(cls), np.nan)
        pq = np.divide(s, den, out=nan.copy(), where=present)
        rq = np.divide(tp, den, out=nan.copy(), where=present)
        sq = np.where(present, np.divide(s, tp, out=np.zeros(len(cls)), where=tp > 0), np.nan)
        thing = np.isin(cls, np.asarray(self.things, dtype=np.intp))
        means: dict[str, float] = {}
        for suffix, sel in (("", np.ones(len(cls), bool)), ("_things", thing), ("_stuff", ~thing)):
            use = sel & present
            for name, v in (("pq", pq), ("sq", sq), ("rq", rq)):
                means[name + suffix] = float(v[use].mean()) if use.any() else float("nan")
        return PanopticResult(
            label_map=lm.name, class_ids=tuple(int(c) for c in cls), class_names=tuple(lm.names[c] for c in cls),
            is_thing=tuple(bool(t) for t in thing), tp=tp, fp=fp, fn=fn, iou_sum=s,
            pq_class=pq, sq_class=sq, rq_class=rq, means=means, frames=self.frames, min_size=self.min_size,
        )  # fmt: skip
