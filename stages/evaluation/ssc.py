"""Semantic occupancy (semantic scene completion) metrics: confusion matrix, geometry IoU, mIoU.

Conventions (exactly those of the semantic-kitti-api ``iouEval``, with NaN for absent classes as
in the Occ3D challenge's ``Metric_mIoU``):

* The confusion matrix ``C[g, p]`` counts voxels with ground-truth label ``g`` and predicted label
  ``p`` (rows = ground truth, columns = prediction; semantic-kitti-api stores the transpose).
* A voxel is **skipped** when it is outside the optional ``mask`` (e.g. Occ3D ``mask_camera``),
  when its ground truth is an ignore id (the ignore *column* of semantic-kitti-api), or when its
  prediction is an ignore id (the ignore *row*: predicting an ignored id is neither a hit nor a
  miss; :attr:`SSCResult.pred_ignored` counts such voxels so it is never silent).
* Per class ``c``: ``TP = C[c, c]``, ``FP = sum_g C[g, c] - TP``, ``FN = sum_p C[c, p] - TP`` and
  ``IoU = TP / (TP + FP + FN)``. Classes are every label of the map except the free label. A
  class that never occurs in ground truth or prediction (union 0 over everything accumulated) has
  IoU NaN and is left out of ``mIoU`` (the mean over the other classes); semantic-kitti-api would
  add 1e-15 to the union and average a 0 in instead.
* Geometry (completion) IoU: occupied = any label but free, over the same voxels:
  ``TP = sum_{g, p != free} C[g, p]``, ``FP = sum_{p != free} C[free, p]``,
  ``FN = sum_{g != free} C[g, free]`` (SSCBench / MonoScene ``get_score_completion``).

Label ids outside the map (and not ignored) are an error naming the value, not a silent skip.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numba
import numpy as np

from carlaocc.schemas import taxonomy

__all__ = [
    "DEFAULT_IGNORE",
    "LABEL_MAPS",
    "LabelMap",
    "SSCAccumulator",
    "SSCResult",
    "confusion_matrix",
    "label_map",
]

DEFAULT_IGNORE: tuple[int, ...] = (taxonomy.IGNORE,)


@dataclass(frozen=True)
class LabelMap:
    """A label space to score in.

    ``names[i]`` names label id ``i`` (``0 .. n - 1``); ``free`` is the id of empty space (``None``
    when the space has none, and then there is no geometry IoU); ``things`` are the ids that carry
    instances (panoptic); ``from_carlaocc[k]`` is the id of CarlaOcc class ``k`` (0-29) here.
    """

    name: str
    names: tuple[str, ...]
    free: int | None
    things: tuple[int, ...]
    from_carlaocc: tuple[int, ...]

    @property
    def n(self) -> int:
        """Number of label ids (the confusion matrix is ``n x n``)."""
        return len(self.names)

    @property
    def classes(self) -> tuple[int, ...]:
        """The evaluated class ids: every id but the free one."""
        return tuple(i for i in range(self.n) if i != self.free)

    @cached_property
    def _carlaocc_table(self) -> tuple[np.ndarray, np.ndarray]:
        # uint8 lookup CarlaOcc id -> this space's id (255 = ignore passes through), and which
        # uint8 values are CarlaOcc ids at all; built once per map
        lut = np.zeros(256, dtype=np.uint8)
        valid = np.zeros(256, dtype=bool)
        lut[: len(self.from_carlaocc)] = self.from_carlaocc
        valid[: len(self.from_carlaocc)] = True
        lut[taxonomy.IGNORE], valid[taxonomy.IGNORE] = taxonomy.IGNORE, True
        return lut, valid

    def convert_carlaocc(self, semantic: np.ndarray) -> np.ndarray:
        """Map a CarlaOcc-id array (0-29; 255 = ignore passes through) into this space (uint8)."""
        sem = np.asarray(semantic)
        if sem.dtype != np.uint8:
            if sem.size and (sem.min() < 0 or sem.max() > 255):
                raise ValueError(f"CarlaOcc semantic ids must be 0..29 (or 255), found {int(sem.min())}..{int(sem.max())}")
            sem = sem.astype(np.uint8)
        lut, valid = self._carlaocc_table
        # the ids present (one counting pass, no per-voxel temporaries), then one uint8 lookup
        present = np.flatnonzero(np.bincount(sem.reshape(-1), minlength=256))
        bad = present[~valid[present]]
        if bad.size:
            raise ValueError(f"CarlaOcc semantic id {int(bad[0])} is not a class (0..29, or 255 = ignore)")
        return lut[sem]


def _things_of(target: str, table: taxonomy.LabelTable) -> tuple[int, ...]:
    """Target ids whose CarlaOcc sources are all thing classes of ``table`` (ids with no source
    are stuff)."""
    lut = table.mapping(target)
    sources: dict[int, set[str]] = {}
    for c in table.classes:
        sources.setdefault(lut[c.id], set()).add(c.kind)
    return tuple(sorted(t for t, kinds in sources.items() if kinds == {"thing"} and t != taxonomy.IGNORE))


def _carlaocc(table: taxonomy.LabelTable) -> LabelMap:
    names = tuple(c.name for c in table.classes)
    return LabelMap("carlaocc", names, 0, table.thing_ids(), tuple(range(len(names))))


def _benchmark(table: taxonomy.LabelTable) -> LabelMap:
    # benchmark15 has no free id: the classes it ignores (None, Sky) never occupy a voxel, so
    # here they become an explicit free id 15 and geometry IoU / FP on empty space work.
    names = taxonomy.BENCHMARK15_NAMES + ("free",)
    free = len(taxonomy.BENCHMARK15_NAMES)
    lut = tuple(free if t == taxonomy.IGNORE else t for t in table.mapping("benchmark15"))
    return LabelMap("benchmark", names, free, _things_of("benchmark15", table), lut)


def _target(name: str, target: str, free: int, table: taxonomy.LabelTable) -> LabelMap:
    return LabelMap(name, taxonomy.TARGETS[target], free, _things_of(target, table), table.mapping(target))


def _label_maps(table: taxonomy.LabelTable) -> dict[str, LabelMap]:
    return {
        "carlaocc": _carlaocc(table),
        "benchmark": _benchmark(table),
        "occ3d": _target("occ3d", "occ3d_nuscenes", 17, table),
        "sscbench": _target("sscbench", "sscbench_kitti360", 0, table),
        "semantickitti": _target("semantickitti", "semantickitti", 0, table),
    }


LABEL_MAPS: dict[str, LabelMap] = _label_maps(taxonomy.label_table())
"""Under the default label table: CarlaOcc 30 (0 = free), the paper's 15-class benchmark
(+ 15 = free), Occ3D-nuScenes 18 (17 = free), SSCBench-KITTI-360 19 and SemanticKITTI 20
(0 = empty)."""
_BY_TABLE: dict[str, dict[str, LabelMap]] = {taxonomy.DEFAULT_LABEL_TABLE: LABEL_MAPS}


def label_map(name: str, table: str | None = None) -> LabelMap:
    """The :class:`LabelMap` called ``name`` (see :data:`LABEL_MAPS`) under label table ``table``
    (None: the default; it decides the things and the Occ3D / KITTI-360 ids); ``ValueError``
    otherwise."""
    lt = taxonomy.label_table(table)
    maps = _BY_TABLE.get(lt.name)
    if maps is None:
        maps = _BY_TABLE[lt.name] = _label_maps(lt)
    try:
        return maps[name]
    except KeyError:
        raise ValueError(f"unknown label map {name!r}; valid: {', '.join(maps)}") from None


@numba.njit(cache=True, nogil=True)
def _confusion_kernel(gt, pred, mask, use_mask, lut, n):  # pragma: no cover - jitted
    cm = np.zeros((n, n), dtype=np.int64)
    # bad[0] = bad gt count, bad[1] = first bad gt value, bad[2..3] the same for pred, bad[4] =
    # voxels skipped for an ignored prediction
    bad = np.zeros(5, dtype=np.int64)
    size = lut.size
    for i in range(gt.size):
        if use_mask and not mask[i]:
            continue
        g = np.int64(gt[i])
        r = lut[g] if 0 <= g < size else -2
        if r == -1:  # ignored ground truth: the ignore column
            continue
        if r == -2:
            if bad[0] == 0:
                bad[1] = g
            bad[0] += 1
            continue
        p = np.int64(pred[i])
        c = lut[p] if 0 <= p < size else -2
        if c == -1:  # ignored prediction: the ignore row
            bad[4] += 1
            continue
        if c == -2:
            if bad[2] == 0:
                bad[3] = p
            bad[2] += 1
            continue
        cm[r, c] += 1
    return cm, bad


def _flat_int(a: np.ndarray, what: str) -> np.ndarray:
    arr = np.asarray(a)
    if not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"{what} labels must be integers, got {arr.dtype}")
    return np.ascontiguousarray(arr).reshape(-1)


def confusion_matrix(
    pred: np.ndarray,
    gt: np.ndarray,
    n: int,
    ignore: tuple[int, ...] = DEFAULT_IGNORE,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, int]:
    """``(C, pred_ignored)``: the ``n x n`` int64 confusion matrix ``C[gt, pred]`` of one frame.

    ``pred``, ``gt``: integer label arrays of one shape (any dimensionality); ``mask``: optional
    bool array of that shape, ``False`` voxels are skipped. Voxels whose ground truth or prediction
    is in ``ignore`` are skipped (``pred_ignored`` counts those skipped for the prediction).
    ``ValueError`` naming the value for a label outside ``0 .. n - 1`` that is not ignored, and
    for shape mismatches. One compiled pass, no temporaries (a 0.05 m grid is 409 M voxels).
    """
    if np.shape(pred) != np.shape(gt):
        raise ValueError(f"prediction shape {np.shape(pred)} differs from ground truth shape {np.shape(gt)}")
    g = _flat_int(gt, "ground-truth")
    p = _flat_int(pred, "predicted")
    if mask is not None:
        if np.shape(mask) != np.shape(gt):
            raise ValueError(f"mask shape {np.shape(mask)} differs from ground truth shape {np.shape(gt)}")
        m = np.ascontiguousarray(mask, dtype=bool).reshape(-1)
    else:
        m = np.ones(1, dtype=bool)
    # label -> row/column lookup: -1 ignored, -2 invalid (outside the map)
    size = max(256, n, max(ignore, default=0) + 1)
    lut = np.full(size, -2, dtype=np.int64)
    lut[:n] = np.arange(n)
    for v in ignore:
        if v >= 0:
            lut[v] = -1
    cm, bad = _confusion_kernel(g, p, m, mask is not None, lut, np.int64(n))
    if bad[0]:
        raise ValueError(f"ground truth has {int(bad[0])} voxels with label {int(bad[1])} (or others) "
                         f"outside 0..{n - 1} that is not ignored {list(ignore)}")
    if bad[2]:
        raise ValueError(f"prediction has {int(bad[2])} voxels with label {int(bad[3])} (or others) "
                         f"outside 0..{n - 1} that is not ignored {list(ignore)}")
    return cm, int(bad[4])


def _nan_div(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    num = np.asarray(num, dtype=np.float64)
    den = np.asarray(den, dtype=np.float64)
    return np.divide(num, den, out=np.full(np.shape(num), np.nan), where=den > 0)


def _nanmean(x: np.ndarray) -> float:
    x = np.asarray(x, dtype=np.float64)
    ok = ~np.isnan(x)
    return float(x[ok].mean()) if ok.any() else float("nan")


@dataclass(frozen=True)
class SSCResult:
    """Scores of everything accumulated; fractions in ``[0, 1]``, NaN where undefined."""

    label_map: str
    class_ids: tuple[int, ...]
    class_names: tuple[str, ...]
    tp: np.ndarray  # (K,) int64 per evaluated class
    fp: np.ndarray
    fn: np.ndarray
    iou: np.ndarray  # (K,) float64, NaN for a class absent from gt and prediction
    miou: float
    geometry_iou: float  # NaN without a free label
    geometry_precision: float
    geometry_recall: float
    confusion: np.ndarray  # (n, n) int64, C[gt, pred]
    frames: int
    voxels: int  # voxels counted (not skipped)
    pred_ignored: int  # voxels skipped because the prediction was an ignore id

    def to_dict(self) -> dict:
        """Plain JSON-able dict (NaN -> None), per-class rows plus the means."""
        f = lambda v: None if np.isnan(v) else float(v)  # noqa: E731
        return {
            "metric": "ssc",
            "label_map": self.label_map,
            "frames": self.frames,
            "voxels": self.voxels,
            "pred_ignored": self.pred_ignored,
            "miou": f(self.miou),
            "geometry": {"iou": f(self.geometry_iou), "precision": f(self.geometry_precision),
                         "recall": f(self.geometry_recall)},
            "classes": [
                {"id": i, "name": n, "iou": f(v), "tp": int(t), "fp": int(a), "fn": int(b)}
                for i, n, v, t, a, b in zip(self.class_ids, self.class_names, self.iou, self.tp, self.fp, self.fn)
            ],
            "confusion": self.confusion.tolist(),
        }


@dataclass
class SSCAccumulator:
    """Sum of confusion matrices over frames: ``update`` per frame, ``result`` at the end.

    Labels must already be in ``label_map``'s space (see :meth:`LabelMap.convert_carlaocc`).
    """

    label_map: LabelMap
    ignore: tuple[int, ...] = DEFAULT_IGNORE
    confusion: np.ndarray = field(init=False)
    frames: int = field(init=False, default=0)
    pred_ignored: int = field(init=False, default=0)

    def __post_init__(self) -> None:
        self.ignore = tuple(int(v) for v in self.ignore)
        self.confusion = np.zeros((self.label_map.n, self.label_map.n), dtype=np.int64)

    def update(self, pred: np.ndarray, gt: np.ndarray, mask: np.ndarray | None = None) -> None:
        """Add one frame (``pred``, ``gt`` of one shape, optional bool ``mask`` of kept voxels)."""
        cm, skipped = confusion_matrix(pred, gt, self.label_map.n, self.ignore, mask)
        self.confusion += cm
        self.pred_ignored += skipped
        self.frames += 1

    def result(self) -> SSCResult:
        """Per-class IoU, mIoU and geometry IoU of everything added so far. Ignored ids inside the
        label range have empty rows and columns (semantic-kitti-api): the kernel never counts them."""
        cm = self.confusion
        lm = self.label_map
        classes = np.array([c for c in lm.classes if c not in self.ignore], dtype=np.intp)
        tp_all = np.diag(cm)
        fp_all = cm.sum(axis=0) - tp_all
        fn_all = cm.sum(axis=1) - tp_all
        tp, fp, fn = tp_all[classes], fp_all[classes], fn_all[classes]
        iou = _nan_div(tp, tp + fp + fn)
        # geometry: occupied (not free) vs free over the same voxels
        if lm.free is None:
            g_iou = g_prec = g_rec = float("nan")
        else:
            occ = np.ones(lm.n, dtype=bool)
            occ[lm.free] = False
            g_tp = cm[np.ix_(occ, occ)].sum()
            g_fp = cm[lm.free, occ].sum()
            g_fn = cm[occ, lm.free].sum()
            g_iou = float(_nan_div(g_tp, g_tp + g_fp + g_fn))
            g_prec = float(_nan_div(g_tp, g_tp + g_fp))
            g_rec = float(_nan_div(g_tp, g_tp + g_fn))
        return SSCResult(
            label_map=lm.name,
            class_ids=tuple(int(c) for c in classes),
            class_names=tuple(lm.names[c] for c in classes),
            tp=tp, fp=fp, fn=fn, iou=iou, miou=_nanmean(iou),
            geometry_iou=g_iou, geometry_precision=g_prec, geometry_recall=g_rec,
            confusion=self.confusion.copy(), frames=self.frames, voxels=int(cm.sum()),
            pred_ignored=self.pred_ignored,
        )  # fmt: skip
