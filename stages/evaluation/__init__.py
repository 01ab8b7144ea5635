"""Evaluation kit for models trained on the data: pure metric computation, accumulable over frames.

* :mod:`carlaocc.stages.evaluation.ssc` -- semantic occupancy: confusion matrix, geometry IoU, per-class
  IoU and mIoU with ignore ids and an optional visibility mask, in any :class:`LabelMap`.
* :mod:`carlaocc.stages.evaluation.panoptic` -- panoptic occupancy: PQ, SQ, RQ (IoU > 0.5 matching),
  things and stuff separately, minimum segment size, void handling.
* :mod:`carlaocc.stages.evaluation.depth` -- monocular depth: AbsRel, SqRel, RMSE, RMSElog, delta < 1.25^k.
* :mod:`carlaocc.stages.evaluation.detection` -- 3D detection, nuScenes style: mAP over centre distances,
  mATE, mASE, mAOE (nuscenes-devkit ``accumulate`` / ``calc_ap`` / ``calc_tp`` semantics).

Every metric has an accumulator with ``update(...)`` per frame and ``result()`` at the end, so a
dataset is scored one frame at a time in bounded memory. Nothing here opens a path: the CLI
(``carlaocc eval``, :mod:`carlaocc.pipeline.cli.evaluate`) reads the files and feeds the arrays in.
"""

from carlaocc.stages.evaluation.depth import DepthAccumulator, DepthResult
from carlaocc.stages.evaluation.detection import Box3D, DetectionAccumulator, DetectionResult
from carlaocc.stages.evaluation.panoptic import PanopticAccumulator, PanopticResult
from carlaocc.stages.evaluation.ssc import LABEL_MAPS, LabelMap, SSCAccumulator, SSCResult, confusion_matrix, label_map

__all__ = [
    "LABEL_MAPS",
    "Box3D",
    "DepthAccumulator",
    "DepthResult",
    "DetectionAccumulator",
    "DetectionResult",
    "LabelMap",
    "PanopticAccumulator",
    "PanopticResult",
    "SSCAccumulator",
    "SSCResult",
    "confusion_matrix",
    "label_map",
]
