"""Panoptic quality: a hand-worked example, a brute-force set-based reference, and hypothesis
properties (perfect prediction scores 1, instance ids are arbitrary labels)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from carlaocc.stages.evaluation.panoptic import PanopticAccumulator
from carlaocc.stages.evaluation.ssc import LabelMap

# 0 free, 1 road (stuff), 2 car (thing), 3 wall (stuff), 4 person (thing)
SMALL = LabelMap("small", ("free", "road", "car", "wall", "person"), 0, (2, 4), (0,) * 30)
V = 255  # void


def _hand_frame():
    #        idx: 0  1  2  3  4  5 | 6  7  8  9 |10 11 12 |13 |14 15 |16 17 18 19
    gt_s = [1, 1, 1, 1, 1, 1, 2, 2, 2, 2, 2, 2, 2, 2, V, V, 0, 0, 0, 0]
    gt_i = [0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 3, 0, 0, 0, 0, 0, 0]
    pr_s = [1, 1, 1, 1, 1, 0, 2, 2, 2, 2, 2, 2, 2, 0, 2, 2, 2, 2, 2, 2]
    pr_i = [9, 9, 0, 0, 0, 0, 7, 7, 7, 7, 8, 9, 9, 0, 7, 5, 7, 6, 6, 6]
    return [np.array(a, np.uint32) for a in (pr_s, pr_i, gt_s, gt_i)]


def test_hand_worked_example():
    # Ground truth: road = voxels 0-5 (6); car 1 = 6-9 (4); car 2 = 10-12 (3); car 3 = 13 (1);
    # void = 14, 15; free = 16-19.
    # Prediction: road = 0-4 (5; its instance ids are ignored, road is stuff); car 7 = 6-9, 14,
    # 16 (6, one void); car 8 = 10 (1); car 9 = 11, 12 (2); car 5 = 15 (1, all void);
    # car 6 = 17-19 (3, on free).
    # road:  road/road  inter 5, union 6 + 5 - 5 = 6           -> IoU 5/6, TP
    # car 1: car 7      inter 4, union 4 + 6 - 4 - 1 (void) = 5 -> IoU 0.8, TP
    #        (without taking void out of the union it would be 4/6)
    # car 2: car 9      inter 2, union 3 + 2 - 2 = 3           -> IoU 2/3, TP
    #        car 8      inter 1, union 3 + 1 - 1 = 3           -> 1/3, no match
    # car 3: nothing predicted                                  -> FN (size 1)
    # car 8 unmatched (size 1) -> FP; car 6 unmatched (3) -> FP; car 5 is all void -> not FP.
    # PQ_road = (5/6) / 1 = 0.8333, SQ 5/6, RQ 1
    # PQ_car = (0.8 + 2/3) / (2 + 2/2 + 1/2) = 1.4667 / 3.5 = 0.41905, SQ 0.7333, RQ 2/3.5
    # PQ = (0.8333 + 0.41905) / 2 = 0.62619 (wall, person have no segment: left out)
    acc = PanopticAccumulator(SMALL)
    acc.update(*_hand_frame())
    r = acc.result()
    row = {n: (pq, sq, rq, tp, fp, fn) for n, pq, sq, rq, tp, fp, fn in
           zip(r.class_names, r.pq_class, r.sq_class, r.rq_class, r.tp, r.fp, r.fn)}
    assert row["road"][3:] == (1, 0, 0) and row["car"][3:] == (2, 2, 1)
    assert row["road"][0] == pytest.approx(5 / 6) and row["road"][2] == 1.0
    assert row["car"][0] == pytest.approx((0.8 + 2 / 3) / 3.5)
    assert row["car"][1] == pytest.approx((0.8 + 2 / 3) / 2)
    assert row["car"][2] == pytest.approx(2 / 3.5)
    assert np.isnan(row["wall"][0]) and np.isnan(row["person"][0])
    assert r.means["pq"] == pytest.approx((5 / 6 + (0.8 + 2 / 3) / 3.5) / 2)
    assert r.means["pq_things"] == pytest.approx((0.8 + 2 / 3) / 3.5)
    assert r.means["pq_stuff"] == pytest.approx(5 / 6)
    # min_size 2: car 3 (1 voxel) is no FN, car 8 (1 voxel) no FP: PQ_car = 1.4667 / 2.5 = 0.58667
    acc2 = PanopticAccumulator(SMALL, min_size=2)
    acc2.update(*_hand_frame())
    r2 = acc2.result()
    car = r2.class_names.index("car")
    assert (r2.tp[car], r2.fp[car], r2.fn[car]) == (2, 1, 0)
    assert r2.pq_class[car] == pytest.approx((0.8 + 2 / 3) / 2.5)


def reference_counts(ps, pi, gs, gi, lm, things, ignore, min_size):
    """Brute force over sets of voxel indices (module doc of stages.evaluation.panoptic)."""
    ps, pi, gs, gi = (np.asarray(a).ravel().tolist() for a in (ps, pi, gs, gi))
    void = {v for v, g in enumerate(gs) if g in ignore}
    gseg, pseg = {}, {}
    for v in range(len(gs)):
        if gs[v] not in ignore and gs[v] != lm.free:
            gseg.setdefault((gs[v], gi[v] if gs[v] in things else 0), set()).add(v)
        if ps[v] not in ignore and ps[v] != lm.free:
            pseg.setdefault((ps[v], pi[v] if ps[v] in things else 0), set()).add(v)
    tp, fp, fn, s = (np.zeros(lm.n) for _ in range(4))
    gm, pm = set(), set()
    for gk, g in gseg.items():
        for pk, p in pseg.items():
            if gk[0] != pk[0]:
                continue
            inter = len(g & p)
            iou = inter / (len(g) + len(p) - inter - len(p & void))
            if iou > 0.5:
                assert gk not in gm and pk not in pm  # matching is unique
                gm.add(gk)
                pm.add(pk)
                tp[gk[0]] += 1
                s[gk[0]] += iou
    for gk, g in gseg.items():
        if gk not in gm and len(g) >= min_size:
            fn[gk[0]] += 1
    for pk, p in pseg.items():
        nv = len(p & void)
        if pk not in pm and nv / len(p) <= 0.5 and len(p) - nv >= min_size:
            fp[pk[0]] += 1
    return tp, fp, fn, s


sem_el = st.integers(0, 4)


@settings(max_examples=150, deadline=None)
@given(data=st.data(), shape=hnp.array_shapes(min_dims=1, max_dims=3, max_side=6), min_size=st.integers(0, 3))
def test_matches_brute_force_reference(data, shape, min_size):
    gs = data.draw(hnp.arrays(np.uint8, shape, elements=sem_el | st.just(V)))
    ps = data.draw(hnp.arrays(np.uint8, shape, elements=sem_el))
    gi = data.draw(hnp.arrays(np.uint32, shape, elements=st.integers(0, 3)))
    pi = data.draw(hnp.arrays(np.uint32, shape, elements=st.integers(0, 3)))
    acc = PanopticAccumulator(SMALL, min_size=min_size)
    acc.update(ps, pi, gs, gi)
    tp, fp, fn, s = reference_counts(ps, pi, gs, gi, SMALL, {2, 4}, {V}, min_size)
    np.testing.assert_array_equal(acc.tp, tp)
    np.testing.assert_array_equal(acc.fp, fp)
    np.testing.assert_array_equal(acc.fn, fn)
    np.testing.assert_allclose(acc.iou_sum, s, rtol=1e-12)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), shape=hnp.array_shapes(min_dims=3, max_dims=3, max_side=6))
def test_perfect_prediction_scores_one(data, shape):
    gs = data.draw(hnp.arrays(np.uint8, shape, elements=sem_el))
    gi = data.draw(hnp.arrays(np.uint32, shape, elements=st.integers(0, 5)))
    acc = PanopticAccumulator(SMALL)
    acc.update(gs.copy(), gi.copy(), gs, gi)
    r = acc.result()
    if (gs != 0).any():
        assert r.means["pq"] == r.means["sq"] == r.means["rq"] == 1.0
    else:
        assert np.isnan(r.means["pq"])


@settings(max_examples=80, deadline=None)
@given(data=st.data(), shape=hnp.array_shapes(min_dims=1, max_dims=3, max_side=6),
       perm_p=st.permutations(range(6)), perm_g=st.permutations(range(6)))
def test_permuting_instance_ids_keeps_pq(data, shape, perm_p, perm_g):
    gs = data.draw(hnp.arrays(np.uint8, shape, elements=sem_el | st.just(V)))
    ps = data.draw(hnp.arrays(np.uint8, shape, elements=sem_el))
    gi = data.draw(hnp.arrays(np.uint32, shape, elements=st.integers(0, 5)))
    pi = data.draw(hnp.arrays(np.uint32, shape, elements=st.integers(0, 5)))
    # any relabelling of instances (a bijection, here also to large uint32 ids)
    lut_p = np.array(perm_p, np.uint32) * 1_000_003 + 7
    lut_g = np.array(perm_g, np.uint32) * 999_983
    a, b = PanopticAccumulator(SMALL), PanopticAccumulator(SMALL)
    a.update(ps, pi, gs, gi)
    b.update(ps, lut_p[pi], gs, lut_g[gi])
    ra, rb = a.result(), b.result()
    for k in ra.means:
        assert ra.means[k] == pytest.approx(rb.means[k], nan_ok=True)
    np.testing.assert_array_equal(ra.tp, rb.tp)


def test_instance_ids_beyond_32_bits_stay_distinct():
    # two perfect cars; the prediction names them 7 and 7 + 2^33 (ids that share their low 32
    # bits, and whose high bits would spill into the class of a class << 32 | id key)
    gs = np.array([2, 2, 2, 2, 0], np.uint8)
    gi = np.array([1, 1, 2, 2, 0], np.uint64)
    pi = np.array([7, 7, 7 + (2 << 32), 7 + (2 << 32), 0], np.uint64)
    acc = PanopticAccumulator(SMALL)
    acc.update(gs, pi, gs, gi)
    r = acc.result()
    car = r.class_names.index("car")
    assert (r.tp[car], r.fp[car], r.fn[car]) == (2, 0, 0) and r.means["pq"] == 1.0


def test_frames_accumulate_and_mask_drops_voxels():
    frame = _hand_frame()
    acc = PanopticAccumulator(SMALL)
    acc.update(*frame)
    acc.update(*frame)
    r = acc.result()
    car = r.class_names.index("car")
    assert (r.tp[car], r.fp[car], r.fn[car]) == (4, 4, 2) and r.frames == 2
    # a mask hiding voxels 13-19 removes car 3 (FN), car 6 (FP) and the void: FP = car 8 only
    mask = np.arange(20) < 13
    m = PanopticAccumulator(SMALL)
    m.update(*frame, mask=mask)
    rm = m.result()
    assert (rm.tp[car], rm.fp[car], rm.fn[car]) == (2, 1, 0)
    # car 7 lost its void and free voxels: IoU 4/4
    assert rm.iou_sum[car] == pytest.approx(1 + 2 / 3)


def test_bad_input_is_named():
    ps, pi, gs, gi = _hand_frame()
    with pytest.raises(ValueError, match="predicted instances shape"):
        PanopticAccumulator(SMALL).update(ps, pi[:3], gs, gi)
    with pytest.raises(ValueError, match="label 9"):
        PanopticAccumulator(SMALL).update(np.where(ps == 1, 9, ps), pi, gs, gi)
    with pytest.raises(ValueError, match="negative"):
        PanopticAccumulator(SMALL).update(ps, pi.astype(np.int64) - 1, gs, gi)
    with pytest.raises(ValueError, match="thing ids \\[0\\]"):
        PanopticAccumulator(SMALL, things=(0,))
