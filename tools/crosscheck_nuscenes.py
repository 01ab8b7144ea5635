"""Cross-check stages.evaluation.detection against nuscenes-devkit 1.2.0 (algo.accumulate / calc_ap / calc_tp).

Not a test: nuscenes-devkit 1.2.0 pins numpy<2, which this project cannot install beside its own
dependencies. To run it, install the devkit and pyquaternion without their dependencies into a
separate directory and put it on the path (the script stubs the
devkit's unused sklearn, tqdm and cachetools imports):

    pip install --no-deps --target .venv/nuscenes-devkit nuscenes-devkit==1.2.0 pyquaternion==0.9.9
    PYTHONPATH=.venv/nuscenes-devkit python tools/crosscheck_nuscenes.py 300

(`make venv` installs it there; tests/stages/test_nuscenes_crosscheck.py runs this script.)

Compares mAP at 0.5/1/2/4 m, mATE/mASE/mAOE/mAVE/mAAE at 2 m (with the devkit's cone and
barrier rules) and NDS (the devkit's DetectionMetrics over its ten classes) on random fixtures
with velocities and attributes (tied scores included).
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

from nuscenes.eval.detection.constants import DETECTION_NAMES
from nuscenes.eval.detection.data_classes import DetectionConfig, DetectionMetrics

CLASSES = ("car", "pedestrian", "truck", "barrier", "traffic_cone")
ATTRS = {"car": ("vehicle.moving", "vehicle.stopped"), "truck": ("vehicle.moving", "vehicle.parked"),
         "pedestrian": ("pedestrian.moving", "pedestrian.standing"), "barrier": ("",), "traffic_cone": ("",)}
CFG = DetectionConfig({n: 50 for n in DETECTION_NAMES}, "center_distance", [0.5, 1.0, 2.0, 4.0], 2.0, 0.1, 0.1, 500, 5)
worst = 0.0
for seed in range(int(sys.argv[1]) if len(sys.argv) > 1 else 200):
    rng = np.random.default_rng(seed)
    acc = DetectionAccumulator(classes=tuple(DETECTION_NAMES))
    gtb, prb = EvalBoxes(), EvalBoxes()
    for s in range(rng.integers(1, 6)):
        tok = f"s{s}"
        g, p = [], []
        for _ in range(rng.integers(0, 8)):
            c = str(rng.choice(CLASSES)); xyz = rng.uniform(-10, 10, 3); lwh = rng.uniform(0.5, 5, 3); yaw = rng.uniform(-4, 4)
            v = tuple(rng.normal(0, 3, 2)); at = str(rng.choice(ATTRS[c]))
            g.append(Box3D(tuple(xyz), tuple(lwh), float(yaw), c, 1.0, v, at))
            for _ in range(rng.integers(0, 3)):
                cc = c if rng.random() < 0.8 else str(rng.choice(CLASSES))
                pxyz = xyz + rng.normal(0, 1.5, 3); plwh = lwh * rng.uniform(0.7, 1.3, 3); pyaw = yaw + rng.normal(0, 1)
                sc = float(np.round(rng.random(), 1))
                pv = tuple(np.asarray(v) + rng.normal(0, 1, 2)); pat = str(rng.choice(ATTRS[cc]))
                p.append(Box3D(tuple(pxyz), tuple(plwh), float(pyaw), cc, sc, pv, pat))
        for _ in range(rng.integers(0, 3)):
            cc = str(rng.choice(CLASSES))
            p.append(Box3D(tuple(rng.uniform(-10, 10, 3)), (1.0, 2.0, 1.5), 0.3, cc, float(rng.random()), (0.0, 0.0),
                           ATTRS[cc][0]))
        acc.update(tok, p, g)
        mk = lambda b, score: DetectionBox(sample_token=tok, translation=tuple(map(float, b.center)), size=(b.size[1], b.size[0], b.size[2]),
                                           rotation=tuple(Quaternion(axis=[0, 0, 1], angle=b.yaw).elements), detection_name=b.label, detection_score=score,
                                           velocity=tuple(b.velocity), attribute_name=b.attribute)
        gtb.add_boxes(tok, [mk(b, -1.0) for b in g])
        prb.add_boxes(tok, [mk(b, b.score) for b in p])
    res = acc.result()
    metrics = DetectionMetrics(CFG)
    for c in DETECTION_NAMES:  # the devkit's evaluate(): its class rules, then its metrics
        for d in (0.5, 1.0, 2.0, 4.0):
            md = accumulate(gtb, prb, c, center_distance, d)
            a = calc_ap(md, 0.1, 0.1)
            metrics.add_label_ap(c, d, a)
            worst = max(worst, abs(a - res.ap[c][d]))
            assert abs(a - res.ap[c][d]) < 1e-9, (seed, c, d, a, res.ap[c][d])
            if d == 2.0:
                for m in ("trans_err", "scale_err", "orient_err", "vel_err", "attr_err"):
                    if c == "traffic_cone" and m in ("attr_err", "vel_err", "orient_err"):
                        t = np.nan
                    elif c == "barrier" and m in ("attr_err", "vel_err"):
                        t = np.nan
                    else:
                        t = calc_tp(md, 0.1, m)
                    metrics.add_label_tp(c, m, t)
                    ours = res.tp_errors[c][m]
                    assert (np.isnan(t) and np.isnan(ours)) or abs(t - ours) < 1e-9, (seed, c, m, t, ours)
                    if not np.isnan(t):
                        worst = max(worst, abs(t - ours))
    nds = metrics.nd_score
    worst = max(worst, abs(nds - res.nds))
    assert abs(nds - res.nds) < 1e-9, (seed, nds, res.nds)
print("all agree (AP, the five TP errors, NDS); worst abs difference", worst)
