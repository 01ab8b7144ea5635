"""nuScenes-style detection metrics.

nuscenes-devkit 1.2.0 (the only release on PyPI) pins ``numpy<2`` while this project needs
``numpy>=2``, so it cannot be a test dependency. The reference here is an independent, loop-based
transcription of its ``accumulate`` / ``calc_ap`` / ``calc_tp`` (lists, ``sorted`` on
``(score, index)``, a nested nearest-ground-truth scan), plus hand-worked cases. (The kit itself
was run once, outside the test suite, on 300 random fixtures: agreement to 2e-15.)
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from carlaocc.stages.evaluation.detection import Box3D, DetectionAccumulator

THS = (0.5, 1.0, 2.0, 4.0)


def reference(samples, classes):
    """AP per (class, threshold) and (ATE, ASE, AOE) per class, the devkit's way, in loops."""
    ap, tp_err = {}, {}
    for c in classes:
        for th in THS:
            npos = sum(b.label == c for _, g in samples for b in g)
            preds = [(s, b) for s, (p, _) in enumerate(samples) for b in p if b.label == c]
            confs = [b.score for _, b in preds]
            sortind = [i for (v, i) in sorted((v, i) for (i, v) in enumerate(confs))][::-1]
            taken, tps, fps, conf, errs, mconf = set(), [], [], [], [[], [], []], []
            for ind in sortind:
                s, pb = preds[ind]
                min_dist, match = math.inf, None
                for gi, gb in enumerate(samples[s][1]):
                    if gb.label == c and (s, gi) not in taken:
                        d = math.sqrt((pb.center[0] - gb.center[0]) ** 2 + (pb.center[1] - gb.center[1]) ** 2)
                        if d < min_dist:
                            min_dist, match = d, gi
                conf.append(pb.score)
                if min_dist < th:
                    taken.add((s, match))
                    tps.append(1)
                    fps.append(0)
                    gb = samples[s][1][match]
                    inter = math.prod(min(a, b) for a, b in zip(gb.size, pb.size))
                    d = abs(gb.yaw - pb.yaw) % (2 * math.pi)
                    errs[0].append(min_dist)
                    errs[1].append(1 - inter / (math.prod(gb.size) + math.prod(pb.size) - inter))
                    errs[2].append(min(d, 2 * math.pi - d))
                    mconf.append(pb.score)
                else:
                    tps.append(0)
                    fps.append(1)
            if npos == 0 or not mconf:
                prec, rconf, curves = np.zeros(101), np.zeros(101), [np.ones(101)] * 3
            else:
                tpc, fpc = np.cumsum(tps), np.cumsum(fps)
                rec = tpc / npos
                x = np.linspace(0, 1, 101)
                prec = np.interp(x, rec, tpc / (tpc + fpc), right=0)
                rconf = np.interp(x, rec, np.array(conf), right=0)
                curves = []
                for e in errs:
                    run = [sum(e[: k + 1]) / (k + 1) for k in range(len(e))]
                    curves.append(np.interp(rconf[::-1], mconf[::-1], run[::-1])[::-1])
            ap[c, th] = float(np.mean(np.maximum(prec[11:] - 0.1, 0))) / 0.9
            if th == 2.0:
                nz = np.nonzero(rconf)[0]
                last = nz[-1] if len(nz) else 0
                tp_err[c] = tuple(1.0 if last < 11 else float(np.mean(cv[11 : last + 1])) for cv in curves)
    return ap, tp_err


def _random_samples(rng, classes):
    samples = []
    for _ in range(rng.integers(1, 6)):
        g, p = [], []
        for _ in range(rng.integers(0, 7)):
            c = str(rng.choice(classes))
            xyz, lwh, yaw = rng.uniform(-10, 10, 3), rng.uniform(0.5, 5, 3), rng.uniform(-4, 4)
            g.append(Box3D(tuple(xyz), tuple(lwh), float(yaw), c))
            for _ in range(rng.integers(0, 3)):
                cc = c if rng.random() < 0.8 else str(rng.choice(classes))
                p.append(Box3D(tuple(xyz + rng.normal(0, 1.5, 3)), tuple(lwh * rng.uniform(0.7, 1.3, 3)),
                               float(yaw + rng.normal(0, 1)), cc, float(np.round(rng.random(), 1))))  # ties
        for _ in range(rng.integers(0, 3)):
            p.append(Box3D(tuple(rng.uniform(-10, 10, 3)), (4.0, 2.0, 1.5), 0.3, str(rng.choice(classes)), float(rng.random())))
        samples.append((p, g))
    return samples


@pytest.mark.parametrize("seed", range(40))
def test_matches_loop_reference_on_random_fixtures(seed):
    rng = np.random.default_rng(seed)
    classes = ("Car", "Pedestrian", "Truck")
    samples = _random_samples(rng, classes)
    acc = DetectionAccumulator(classes=classes)
    for i, (p, g) in enumerate(samples):
        acc.update(f"s{i}", p, g)
    r = acc.result()
    ap, tp_err = reference(samples, classes)
    for c in classes:
        for th in THS:
            assert r.ap[c][th] == pytest.approx(ap[c, th], abs=1e-12)
        got = (r.tp_errors[c]["trans_err"], r.tp_errors[c]["scale_err"], r.tp_errors[c]["orient_err"])
        np.testing.assert_allclose(got, tp_err[c], atol=1e-12)
    assert r.mean_ap == pytest.approx(np.mean([np.mean([ap[c, t] for t in THS]) for c in classes]), abs=1e-12)
    assert r.mate == pytest.approx(np.mean([tp_err[c][0] for c in classes]), abs=1e-12)


def test_hand_worked_single_match():
    # one car, predicted 0.7 m away (BEV), 0.2 m higher (ignored), 10 % longer, yaw off by 0.3
    gt = Box3D((0, 0, 0), (4.0, 2.0, 1.5), 3.0, "Car")
    pr = Box3D((0.7, 0, 0.2), (4.4, 2.0, 1.5), 3.3 - 2 * math.pi, "Car", 0.9)
    acc = DetectionAccumulator()
    acc.update("a", [pr], [gt])
    r = acc.result()
    # a miss at 0.5 m (AP 0), a hit at 1, 2, 4 m: precision 1 at every recall -> AP 1
    assert r.ap["Car"] == pytest.approx({0.5: 0.0, 1.0: 1.0, 2.0: 1.0, 4.0: 1.0})  # (1 - 0.1) / 0.9
    assert r.mean_ap == pytest.approx(0.75)
    assert r.mate == pytest.approx(0.7)
    assert r.mase == pytest.approx(1 - 4.0 / 4.4)  # aligned IoU = 4*2*1.5 / 4.4*2*1.5
    assert r.maoe == pytest.approx(0.3)  # across the +-pi wrap


def test_half_recall_and_false_positive_ranking():
    # 2 cars; the best-scored prediction is a false positive, then one hit:
    # ranking: FP (0.9), TP (0.5) -> precision 0, 1/2 at recalls 0, 1/2; interpolated at recalls
    # 0.11..0.50 (40 of the 90 bins above 0.1) between (0, 0) and (0.5, 0.5): p(r) = r
    # AP = sum_{k=11}^{50} (k/100 - 0.1) / 90 / 0.9
    g = [Box3D((0, 0, 0), (4, 2, 1.5), 0, "Car"), Box3D((20, 0, 0), (4, 2, 1.5), 0, "Car")]
    p = [Box3D((50, 50, 0), (4, 2, 1.5), 0, "Car", 0.9), Box3D((0.1, 0, 0), (4, 2, 1.5), 0, "Car", 0.5)]
    acc = DetectionAccumulator()
    acc.update("a", p, g)
    r = acc.result()
    expected = sum(k / 100 - 0.1 for k in range(11, 51)) / 90 / 0.9
    assert r.ap["Car"][2.0] == pytest.approx(expected)
    assert r.tp_errors["Car"]["trans_err"] == pytest.approx(0.1)


def test_perfect_detections_and_missing_classes():
    rng = np.random.default_rng(3)
    acc = DetectionAccumulator(classes=("Car", "Bus"))
    for s in range(4):
        g = [Box3D(tuple(rng.uniform(-30, 30, 3)), (4, 2, 1.5), float(rng.uniform(-3, 3)), "Car") for _ in range(5)]
        acc.update(f"s{s}", [Box3D(b.center, b.size, b.yaw, b.label, 0.8) for b in g], g)
    r = acc.result()
    assert r.ap["Car"] == pytest.approx({t: 1.0 for t in THS})
    # no velocities or attributes given: those errors are the devkit's 1 (nothing measured)
    assert r.tp_errors["Car"] == {"trans_err": 0.0, "scale_err": 0.0, "orient_err": 0.0, "vel_err": 1.0, "attr_err": 1.0}
    # a listed class without ground truth: AP 0 and errors 1 (the devkit's no_predictions)
    assert r.ap["Bus"] == {t: 0.0 for t in THS} and r.tp_errors["Bus"]["trans_err"] == 1.0
    assert r.mean_ap == pytest.approx(0.5)


def test_bad_boxes_and_duplicate_samples():
    with pytest.raises(ValueError, match="size"):
        Box3D((0, 0, 0), (4, 0, 1), 0, "Car")
    with pytest.raises(ValueError, match="centre"):
        Box3D((0, math.nan, 0), (4, 2, 1), 0, "Car")
    with pytest.raises(ValueError, match="score"):
        Box3D((0, 0, 0), (4, 2, 1), 0, "Car", math.inf)
    acc = DetectionAccumulator()
    acc.update("a", [], [])
    with pytest.raises(ValueError, match="sample 'a' added twice"):
        acc.update("a", [], [])


def _nd_boxes(rng, n=6, speed=5.0):
    out = []
    for _ in range(n):
        v = tuple(rng.normal(0, speed, 2))
        out.append(Box3D(tuple(rng.uniform(-30, 30, 3)), (4.0, 2.0, 1.5), float(rng.uniform(-3, 3)), "car", 1.0, v,
                         "vehicle.moving", 10))
    return out


def test_nds_known_answers():
    from carlaocc.stages.evaluation.detection import nd_score

    # perfect boxes with velocities and attributes: every error 0, NDS 1
    rng = np.random.default_rng(5)
    acc = DetectionAccumulator(classes=("car",), nuscenes_filters=True)
    for s in range(3):
        g = _nd_boxes(rng)
        acc.update(f"s{s}", [Box3D(b.center, b.size, b.yaw, b.label, 0.9, b.velocity, b.attribute) for b in g], g)
    r = acc.result()
    assert r.mean_ap == pytest.approx(1.0) and r.mave == 0.0 and r.maae == 0.0 and r.nds == pytest.approx(1.0)
    # an empty submission: mAP 0, every TP error 1, NDS 0
    acc0 = DetectionAccumulator(classes=("car",))
    acc0.update("s0", [], _nd_boxes(rng))
    r0 = acc0.result()
    assert r0.mean_ap == 0.0 and r0.nds == 0.0 and r0.mave == 1.0
    # the arithmetic: mAP 0.5 and every error 0.5 -> 0.5; an error above 1 adds 0, never less
    half = dict.fromkeys(("trans_err", "scale_err", "orient_err", "vel_err", "attr_err"), 0.5)
    assert nd_score(0.5, half) == pytest.approx(0.5)
    assert nd_score(0.5, half | {"vel_err": 1.7}) == pytest.approx((2.5 + 0.5 * 4) / 10)
    # velocities off by 1 m/s everywhere: mAVE 1; wrong attributes: mAAE 1
    acc2 = DetectionAccumulator(classes=("car",))
    g = _nd_boxes(rng)
    acc2.update("s0", [Box3D(b.center, b.size, b.yaw, b.label, 0.9, (b.velocity[0] + 1.0, b.velocity[1]),
                             "vehicle.stopped") for b in g], g)
    r2 = acc2.result()
    assert r2.mave == pytest.approx(1.0) and r2.maae == 1.0


def test_class_rules_and_filters():
    cone = Box3D((5, 0, 0), (0.4, 0.4, 0.8), 0.0, "traffic_cone", 1.0, (0.0, 0.0), "", 3)
    barrier = Box3D((0, 6, 0), (2.0, 0.5, 1.0), 0.0, "barrier", 1.0, None, "", 4)
    acc = DetectionAccumulator(classes=("traffic_cone", "barrier"), nuscenes_filters=True)
    # the barrier predicted turned by pi: no orientation error (period pi); the cone turned: ignored
    acc.update("s0", [Box3D(cone.center, cone.size, 2.0, "traffic_cone", 0.9),
                      Box3D(barrier.center, barrier.size, math.pi, "barrier", 0.9)], [cone, barrier])
    r = acc.result()
    assert math.isnan(r.tp_errors["traffic_cone"]["orient_err"]) and math.isnan(r.tp_errors["traffic_cone"]["vel_err"])
    assert r.tp_errors["barrier"]["orient_err"] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(r.tp_errors["barrier"]["attr_err"])
    # filters: a car beyond 50 m and a ground-truth box without points are dropped
    far = Box3D((60, 0, 0), (4, 2, 1.5), 0.0, "car", 1.0, (0, 0), "vehicle.parked", 5)
    empty = Box3D((10, 0, 0), (4, 2, 1.5), 0.0, "car", 1.0, (0, 0), "vehicle.parked", 0)
    near = Box3D((20, 0, 0), (4, 2, 1.5), 0.0, "car", 1.0, (0, 0), "vehicle.parked", 5)
    f = DetectionAccumulator(classes=("car",), nuscenes_filters=True)
    f.update("s0", [Box3D(near.center, near.size, 0.0, "car", 0.9, (0, 0), "vehicle.parked")], [far, empty, near])
    assert f.result().gt_counts["car"] == 1 and f.result().mean_ap == pytest.approx(1.0)
