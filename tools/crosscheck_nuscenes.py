"""Cross-check stages.evaluation.detection against nuscenes-devkit 1.2.0 (algo.accumulate / calc_ap / calc_tp).

Not a test: nuscenes-devkit 1.2.0 pins numpy<2, which this project cannot install beside its own
dependencies. To run it, install the devkit and pyquaternion without their dependencies into a
separate directory and put it on the path (the script stubs the
devkit's unused sklearn, tqdm and cachetools imports):

    pip install --no-deps --target /tmp/nusc nuscenes-devkit==1.2.0 pyquaternion
    PYTHONPATH=/tmp/nusc python tools/crosscheck_nuscenes.py 300

Compares mAP at 0.5/1/2/4 m and mATE/mASE/mAOE at 2 m on random fixtures (tied scores included);
last run: all agree, worst absolute difference 1.8e-15.
"""
import sys
import types

import numpy as np

# stand-ins for devkit imports the detection algorithms never use
for _name, _attrs in {"sklearn": {}, "sklearn.metrics": {}, "tqdm": {"tqdm": lambda it=None, **kw: it},
                      "cachetools": {"cached": lambda *a, **kw: (lambda f: f), "LRUCache": dict}}.items():
    try:
        __import__(_name)
    except ImportError:
        sys.modules[_name] = types.ModuleType(_name)
        sys.modules[_name].__dict__.update(_attrs)
        if "." in _name:
            setattr(sys.modules[_name.rsplit(".", 1)[0]], _name.rsplit(".", 1)[1], sys.modules[_name])
from pyquaternion import Quaternion
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.detection.data_classes import DetectionBox
from nuscenes.eval.common.utils import center_distance
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[1]))
from carlaocc.stages.evaluation.detection import Box3D, DetectionAccumulator

CLASSES = ("car", "pedestrian", "truck")
worst = 0.0
for seed in range(int(sys.argv[1]) if len(sys.argv) > 1 else 200):
    rng = np.random.default_rng(seed)
    acc = DetectionAccumulator(classes=CLASSES)
    gtb, prb = EvalBoxes(), EvalBoxes()
    for s in range(rng.integers(1, 6)):
        tok = f"s{s}"
        g, p = [], []
        for _ in range(rng.integers(0, 8)):
            c = str(rng.choice(CLASSES)); xyz = rng.uniform(-10, 10, 3); lwh = rng.uniform(0.5, 5, 3); yaw = rng.uniform(-4, 4)
            g.append(Box3D(tuple(xyz), tuple(lwh), float(yaw), c))
            for _ in range(rng.integers(0, 3)):
                cc = c if rng.random() < 0.8 else str(rng.choice(CLASSES))
                pxyz = xyz + rng.normal(0, 1.5, 3); plwh = lwh * rng.uniform(0.7, 1.3, 3); pyaw = yaw + rng.normal(0, 1)
                sc = float(np.round(rng.random(), 1))
                p.append(Box3D(tuple(pxyz), tuple(plwh), float(pyaw), cc, sc))
        for _ in range(rng.integers(0, 3)):
            p.append(Box3D(tuple(rng.uniform(-10, 10, 3)), (1.0, 2.0, 1.5), 0.3, str(rng.choice(CLASSES)), float(rng.random())))
        acc.update(tok, p, g)
        mk = lambda b, score: DetectionBox(sample_token=tok, translation=tuple(map(float, b.center)), size=(b.size[1], b.size[0], b.size[2]),
                                           rotation=tuple(Quaternion(axis=[0, 0, 1], angle=b.yaw).elements), detection_name=b.label, detection_score=score)
        gtb.add_boxes(tok, [mk(b, -1.0) for b in g])
        prb.add_boxes(tok, [mk(b, b.score) for b in p])
    res = acc.result()
    for c in CLASSES:
        for d in (0.5, 1.0, 2.0, 4.0):
            md = accumulate(gtb, prb, c, center_distance, d)
            a = calc_ap(md, 0.1, 0.1)
            worst = max(worst, abs(a - res.ap[c][d]))
            assert abs(a - res.ap[c][d]) < 1e-9, (seed, c, d, a, res.ap[c][d])
            if d == 2.0:
                for m in ("trans_err", "scale_err", "orient_err"):
                    t = calc_tp(md, 0.1, m)
                    worst = max(worst, abs(t - res.tp_errors[c][m]))
                    assert abs(t - res.tp_errors[c][m]) < 1e-9, (seed, c, m, t, res.tp_errors[c][m])
print("all agree; worst abs difference", worst)
