"""3D object detection, nuScenes style: mAP over BEV centre distances, mATE, mASE, mAOE, mAVE,
mAAE and the nuScenes detection score (NDS).

The semantics are nuscenes-devkit's ``nuscenes.eval.detection.algo.accumulate`` / ``calc_ap`` /
``calc_tp`` (devkit 1.2), restated:

* Per class and distance threshold ``d``: predictions of that class from every sample are sorted
  by descending score (ties: the later prediction first, as the devkit's
  ``sorted((score, i))[::-1]``). Each takes the not-yet-taken ground-truth box of its class in its
  sample with the smallest BEV (x, y) centre distance (the first such box on ties) and is a TP
  when that distance is ``< d``, else an FP.
* ``precision`` and ``recall`` along the ranking are resampled at 101 recalls ``0, 0.01 .. 1``
  with ``np.interp(..., right=0)``; so is the score. ``AP = mean(max(0, precision[11:] - 0.1))
  / 0.9`` (min_recall 0.1 and min_precision 0.1: the recall-0.1 bin itself excluded).
* TP errors at ``d = 2 m``, for every match: ``trans_err`` = BEV centre distance (m),
  ``scale_err = 1 - IoU`` of the two boxes aligned (same centre and yaw: ``prod min(size) /
  (prod a + prod b - prod min(size))``), ``orient_err`` = smallest yaw difference in ``[0, pi]``
  (period 2 pi). Their running means along the ranking are resampled on the 101-point score axis;
  the class error is their mean from recall bin 11 to the highest recall reached, or 1 when that
  is below 0.11.
* A class without ground truth, or without any match, scores AP 0 and errors 1 (the devkit's
  ``no_predictions``). ``mAP`` = mean over classes of the mean AP over the thresholds; ``mATE``,
  ``mASE``, ``mAOE`` = means over classes.

* ``vel_err`` = L2 distance of the 2-D velocities (m/s; NaN where a box has none) and
  ``attr_err`` = 1 - (attributes equal; NaN where the ground truth has none), NaN left out of
  the running means. Per the
  devkit's class rules, ``traffic_cone`` has no orientation, velocity or attribute error (NaN),
  ``barrier`` no velocity or attribute error and an orientation period of pi. ``mAVE`` / ``mAAE``
  are the class means (NaN classes left out) and
  ``NDS = (5 mAP + sum over the five TP errors of max(0, 1 - error)) / 10``.
* Filters (``nuscenes_filters``, the devkit's ``filter_eval_boxes``): ground-truth boxes with
  ``num_pts == 0`` are dropped (predictions carry -1 and are kept), and boxes of a class in
  :data:`CLASS_RANGES` farther than its range from the ego -- ``ego_dist`` when the box carries
  it, else the BEV distance of its centre from the origin (boxes in the ego or LiDAR frame).

Not reproduced: the bike-rack filter (no racks here).
Frames: boxes in any common frame (LiDAR or world), metres and radians, yaw about +z.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CLASS_RANGES", "DIST_THS", "Box3D", "DetectionAccumulator", "DetectionResult", "MetricCurve", "accumulate",
           "calc_ap", "calc_tp", "nd_score"]

DIST_THS: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0)
DIST_TH_TP: float = 2.0
MIN_RECALL: float = 0.1
MIN_PRECISION: float = 0.1
NELEM: int = 101
TP_METRICS: tuple[str, ...] = ("trans_err", "scale_err", "orient_err", "vel_err", "attr_err")
MEAN_AP_WEIGHT = 5.0
CLASS_RANGES: dict[str, float] = {
    "car": 50.0, "truck": 50.0, "bus": 50.0, "trailer": 50.0, "construction_vehicle": 50.0,
    "pedestrian": 40.0, "motorcycle": 40.0, "bicycle": 40.0, "traffic_cone": 30.0, "barrier": 30.0,
}  # fmt: skip
"""The nuScenes detection classes and their evaluation ranges (m; devkit ``cvpr_2019``)."""


@dataclass(frozen=True)
class Box3D:
    """One box: ``center`` (x, y, z) and ``size`` (length, width, height) in metres, ``yaw`` in
    radians about +z, ``label`` a class name, ``score`` the confidence (ground truth: unused)."""

    center: tuple[float, float, float]
    size: tuple[float, float, float]
    yaw: float
    label: str
    score: float = 1.0
    velocity: tuple[float, float] | None = None  # vx, vy m/s (the boxes' frame); None: unknown
    attribute: str = ""  # nuScenes attribute name ("" : none)
    num_pts: int = -1  # LiDAR (+ radar) points in a ground-truth box; -1: unknown (predictions)
    ego_dist: float | None = None  # BEV distance from the ego (m), when the frame is not the ego's
    ego_xy: tuple[float, float] | None = None  # the ego's position in the boxes' frame, when known

    def __post_init__(self) -> None:
        if len(self.center) != 3 or not all(math.isfinite(v) for v in self.center):
            raise ValueError(f"box centre must be 3 finite numbers, got {self.center!r}")
        if len(self.size) != 3 or not all(math.isfinite(v) and v > 0 for v in self.size):
            raise ValueError(f"box size must be 3 positive numbers (l, w, h), got {self.size!r}")
        if not math.isfinite(self.yaw):
            raise ValueError(f"box yaw must be finite, got {self.yaw!r}")
        if not math.isfinite(self.score):
            raise ValueError(f"box score must be finite, got {self.score!r}")


@dataclass(frozen=True)
class _Set:
    """Boxes of one class in one sample, as arrays (rows in input order)."""

    xy: np.ndarray  # (k, 2)
    size: np.ndarray  # (k, 3)
    yaw: np.ndarray  # (k,)
    score: np.ndarray  # (k,)
    vel: np.ndarray  # (k, 2), NaN where unknown
    attr: tuple[str, ...]


def _as_set(boxes: Sequence[Box3D]) -> _Set:
    return _Set(
        np.array([b.center[:2] for b in boxes], dtype=np.float64).reshape(-1, 2),
        np.array([b.size for b in boxes], dtype=np.float64).reshape(-1, 3),
        np.array([b.yaw for b in boxes], dtype=np.float64),
        np.array([b.score for b in boxes], dtype=np.float64),
        np.array([b.velocity if b.velocity is not None else (np.nan, np.nan) for b in boxes], dtype=np.float64).reshape(-1, 2),
        tuple(b.attribute for b in boxes),
    )


def _in_range(b: Box3D) -> bool:
    """Whether a box of a nuScenes class lies within its class range of the ego."""
    rng = CLASS_RANGES.get(b.label)
    if rng is None:
        return True
    d = b.ego_dist if b.ego_dist is not None else math.hypot(b.center[0], b.center[1])
    return d < rng  # the devkit's strict test


@dataclass(frozen=True)
class MetricCurve:
    """The devkit's ``DetectionMetricData``: 101-point recall, precision, score and TP errors."""

    recall: np.ndarray
    precision: np.ndarray
    confidence: np.ndarray
    errors: dict[str, np.ndarray]

    @classmethod
    def no_predictions(cls) -> MetricCurve:
        return cls(np.linspace(0, 1, NELEM), np.zeros(NELEM), np.zeros(NELEM), {k: np.ones(NELEM) for k in TP_METRICS})

    @property
    def max_recall_ind(self) -> int:
        """Index of the highest recall reached (last nonzero score), 0 if none."""
        nz = np.nonzero(self.confidence)[0]
        return int(nz[-1]) if len(nz) else 0


def _yaw_diff(a: np.ndarray | float, b: np.ndarray | float, period: float = 2 * np.pi) -> np.ndarray:
    """``|angle from b to a|`` in ``[0, pi]`` (devkit ``angle_diff`` with its ``> pi`` shift)."""
    d = (np.asarray(a) - np.asarray(b) + period / 2) % period - period / 2
    d = np.where(d > np.pi, d - 2 * np.pi, d)
    return np.abs(d)


def _scale_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boxes of sizes ``a`` and ``b`` with the same centre and yaw."""
    inter = float(np.prod(np.minimum(a, b)))
    return inter / (float(np.prod(a)) + float(np.prod(b)) - inter)


def _cummean(x: np.ndarray) -> np.ndarray:
    """Running mean ignoring NaN; all NaN -> ones (devkit ``cummean``)."""
    if np.isnan(x).sum() == len(x):
        return np.ones(len(x))
    s = np.nancumsum(x.astype(float))
    c = np.cumsum(~np.isnan(x))
    return np.divide(s, c, out=np.zeros_like(s), where=c != 0)


def accumulate(gt: list[_Set], pred: list[_Set], dist_th: float, label: str = "") -> MetricCurve:
    """Match one class's predictions to its ground truth over all samples at ``dist_th`` metres.

    ``gt[s]`` / ``pred[s]``: that class's boxes of sample ``s`` (samples in input order);
    ``label`` decides the devkit's class rules (cone, barrier).
    """
    period = np.pi if label == "barrier" else 2 * np.pi
    npos = sum(len(g.yaw) for g in gt)
    if npos == 0:
        return MetricCurve.no_predictions()
    # 1. all predictions in sample-then-box order, sorted by descending (score, position)
    sample = np.concatenate([np.full(len(p.yaw), s, dtype=np.intp) for s, p in enumerate(pred)] + [np.zeros(0, np.intp)])
    row = np.concatenate([np.arange(len(p.yaw)) for p in pred] + [np.zeros(0, np.intp)]).astype(np.intp)
    score = np.concatenate([p.score for p in pred] + [np.zeros(0)])
    order = np.lexsort((np.arange(len(score)), score))[::-1]
    # 2. greedy matching to the nearest free ground truth of the same sample
    taken = [np.zeros(len(g.yaw), dtype=bool) for g in gt]
    is_tp = np.zeros(len(order), dtype=bool)
    m_conf: list[float] = []
    errs: dict[str, list[float]] = {k: [] for k in TP_METRICS}
    for rank, j in enumerate(order):
        s, r = sample[j], row[j]
        g, p = gt[s], pred[s]
        if len(g.yaw) == 0:
            continue
        diff = g.xy - p.xy[r]
        dist = np.sqrt(diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1])
        dist[taken[s]] = np.inf
        k = int(np.argmin(dist))  # first minimum, as the devkit's strict "<" scan
        if dist[k] < dist_th:
            taken[s][k] = True
            is_tp[rank] = True
            m_conf.append(float(p.score[r]))
            errs["trans_err"].append(float(dist[k]))
            errs["scale_err"].append(1.0 - _scale_iou(g.size[k], p.size[r]))
            errs["orient_err"].append(np.nan if label == "traffic_cone" else float(_yaw_diff(g.yaw[k], p.yaw[r], period)))
            no_motion = label in ("traffic_cone", "barrier")
            errs["vel_err"].append(np.nan if no_motion else float(np.linalg.norm(g.vel[k] - p.vel[r])))
            errs["attr_err"].append(np.nan if no_motion or not g.attr[k] else float(g.attr[k] != p.attr[r]))
    if not m_conf:
        return MetricCurve.no_predictions()
    # 3. precision / recall along the ranking, resampled at 101 recalls
    tp = np.cumsum(is_tp).astype(float)
    fp = np.cumsum(~is_tp).astype(float)
    conf = score[order]
    prec = tp / (fp + tp)
    rec = tp / float(npos)
    rec_interp = np.linspace(0, 1, NELEM)
    prec = np.interp(rec_interp, rec, prec, right=0)
    conf = np.interp(rec_interp, rec, conf, right=0)
    # 4. running means of the TP errors, resampled on the score axis (np.interp needs increasing x)
    mc = np.array(m_conf)
    out = {k: np.interp(conf[::-1], mc[::-1], _cummean(np.array(v))[::-1])[::-1] for k, v in errs.items()}
    return MetricCurve(rec_interp, prec, conf, out)


def calc_ap(md: MetricCurve, min_recall: float = MIN_RECALL, min_precision: float = MIN_PRECISION) -> float:
    """Average precision above ``min_recall`` with precision offset by ``min_precision``."""
    prec = np.copy(md.precision)[round(100 * min_recall) + 1 :]
    prec -= min_precision
    prec[prec < 0] = 0
    return float(np.mean(prec)) / (1.0 - min_precision)


def calc_tp(md: MetricCurve, metric: str, min_recall: float = MIN_RECALL) -> float:
    """Mean TP error from just above ``min_recall`` to the highest recall reached (1 if none)."""
    first = round(100 * min_recall) + 1
    last = md.max_recall_ind
    if last < first:
        return 1.0
    return float(np.mean(md.errors[metric][first : last + 1]))


def _class_tp(md: MetricCurve, metric: str, label: str) -> float:
    """The class's TP error, NaN where the devkit ignores the metric for the class."""
    if label == "traffic_cone" and metric in ("orient_err", "vel_err", "attr_err"):
        return float("nan")
    if label == "barrier" and metric in ("vel_err", "attr_err"):
        return float("nan")
    return calc_tp(md, metric)


def nd_score(mean_ap: float, tp_errors: dict[str, float]) -> float:
    """``(5 mAP + sum over the five TP errors of max(0, 1 - error)) / 10``; an error no class
    measured (NaN) counts as 1."""
    scores = [max(0.0, 1.0 - (1.0 if not math.isfinite(e) else e)) for e in (tp_errors[m] for m in TP_METRICS)]
    return (MEAN_AP_WEIGHT * mean_ap + sum(scores)) / (MEAN_AP_WEIGHT + len(TP_METRICS))


@dataclass(frozen=True)
class DetectionResult:
    """Per-class AP per threshold and TP errors, and their means."""

    classes: tuple[str, ...]
    ap: dict[str, dict[float, float]]  # class -> threshold -> AP
    tp_errors: dict[str, dict[str, float]]  # class -> metric -> error
    mean_ap: float
    mate: float
    mase: float
    maoe: float
    mave: float
    maae: float
    nds: float
    gt_counts: dict[str, int]
    pred_counts: dict[str, int]
    samples: int
    dist_ths: tuple[float, ...]

    def to_dict(self) -> dict:
        return {
            "metric": "det", "samples": self.samples, "dist_ths": list(self.dist_ths),
            "mAP": self.mean_ap, "mATE": self.mate, "mASE": self.mase, "mAOE": self.maoe,
            "mAVE": self.mave, "mAAE": self.maae, "NDS": self.nds,
            "classes": [
                {"name": c, "ap": float(np.mean(list(self.ap[c].values()))),
                 "ap_by_distance": {str(d): v for d, v in self.ap[c].items()},
                 "ate": self.tp_errors[c]["trans_err"], "ase": self.tp_errors[c]["scale_err"],
                 "aoe": self.tp_errors[c]["orient_err"], "ave": self.tp_errors[c]["vel_err"],
                 "aae": self.tp_errors[c]["attr_err"], "gt": self.gt_counts[c], "pred": self.pred_counts[c]}
                for c in self.classes
            ],
        }  # fmt: skip


@dataclass
class DetectionAccumulator:
    """Boxes per sample: ``update(sample, pred, gt)`` per frame, ``result()`` at the end.

    ``classes``: the evaluated class names (default: every class in the ground truth; a listed
    class without ground truth scores AP 0, predictions of unlisted classes are ignored).
    """

    classes: tuple[str, ...] | None = None
    dist_ths: tuple[float, ...] = DIST_THS
    dist_th_tp: float = DIST_TH_TP
    nuscenes_filters: bool = False  # class ranges and GT boxes without points (see the module doc)
    samples: dict[str, tuple[list[Box3D], list[Box3D]]] = field(init=False, default_factory=dict)

    def __post_init__(self) -> None:
        if self.dist_th_tp not in self.dist_ths:
            raise ValueError(f"dist_th_tp {self.dist_th_tp} must be one of dist_ths {self.dist_ths}")

    def update(self, sample: str, pred: Sequence[Box3D], gt: Sequence[Box3D]) -> None:
        """Add one sample's predicted and ground-truth boxes (sample ids must be unique)."""
        if sample in self.samples:
            raise ValueError(f"sample {sample!r} added twice")
        self.samples[sample] = (list(pred), list(gt))

    def result(self) -> DetectionResult:
        samples = list(self.samples.values())
        if self.nuscenes_filters:
            samples = [([b for b in p if _in_range(b)], [b for b in g if _in_range(b) and b.num_pts != 0])
                       for p, g in samples]
        classes = self.classes or tuple(sorted({b.label for _, g in samples for b in g}))
        ap: dict[str, dict[float, float]] = {}
        tp_err: dict[str, dict[str, float]] = {}
        for c in classes:
            gt = [_as_set([b for b in g if b.label == c]) for _, g in samples]
            pr = [_as_set([b for b in p if b.label == c]) for p, _ in samples]
            curves = {d: accumulate(gt, pr, d, c) for d in self.dist_ths}
            ap[c] = {d: calc_ap(curves[d]) for d in self.dist_ths}
            tp_err[c] = {m: _class_tp(curves[self.dist_th_tp], m, c) for m in TP_METRICS}

        def mean(xs) -> float:
            xs = [x for x in xs if math.isfinite(x)]
            return float(np.mean(xs)) if xs else float("nan")

        m_ap = mean([np.mean(list(ap[c].values())) for c in classes])
        means = {m: mean([tp_err[c][m] for c in classes]) for m in TP_METRICS}
        return DetectionResult(
            classes=tuple(classes), ap=ap, tp_errors=tp_err, mean_ap=m_ap,
            mate=means["trans_err"], mase=means["scale_err"], maoe=means["orient_err"],
            mave=means["vel_err"], maae=means["attr_err"], nds=nd_score(m_ap, means),
            gt_counts={c: sum(b.label == c for _, g in samples for b in g) for c in classes},
            pred_counts={c: sum(b.label == c for p, _ in samples for b in p) for c in classes},
            samples=len(samples), dist_ths=tuple(self.dist_ths),
        )  # fmt: skip
