"""Semantic occupancy metrics against an independent semantic-kitti-api ``iouEval`` reference,
hand-worked numbers, the real Occ3D sample, and hypothesis properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from carlaocc.schemas import taxonomy
from carlaocc.stages.evaluation.ssc import LABEL_MAPS, LabelMap, SSCAccumulator, confusion_matrix, label_map
from shared_data import needs, shared_path

OCC3D_SAMPLE = shared_path("occupancy/occ3d-nuscenes/labels.npz")

# a tiny label space: 0 free, 1..4 classes
SMALL = LabelMap("small", ("free", "a", "b", "c", "d"), 0, (3, 4), (0,) * 30)


def kitti_api_ioueval(pred, gt, n, ignore):
    """semantic-kitti-api ``iouEval`` written out: conf[pred, gt] (np.add.at), ignore rows and
    columns zeroed, tp = diag, fp = row sum - tp, fn = column sum - tp, iou = tp / (tp+fp+fn+eps).
    Ignore ids outside 0..n-1 get one extra row/column (index n), zeroed the same way."""
    size = n + 1
    remap = lambda a: np.where(np.isin(a, [i for i in ignore if i >= n]), n, a)  # noqa: E731
    p, g = remap(np.asarray(pred).ravel()), remap(np.asarray(gt).ravel())
    conf = np.zeros((size, size), dtype=np.int64)
    np.add.at(conf, (p, g), 1)
    drop = [n] + [i for i in ignore if i < n]
    conf[drop, :] = 0
    conf[:, drop] = 0
    tp = np.diag(conf).astype(float)
    fp = conf.sum(axis=1) - tp
    fn = conf.sum(axis=0) - tp
    union = tp + fp + fn
    return tp[:n], fp[:n], fn[:n], tp[:n] / (union[:n] + 1e-15), union[:n]


labels = st.integers(0, 4) | st.just(255)


@settings(max_examples=150, deadline=None)
@given(data=st.data(), shape=hnp.array_shapes(min_dims=1, max_dims=3, max_side=7))
def test_matches_semantic_kitti_api_formula(data, shape):
    gt = data.draw(hnp.arrays(np.uint8, shape, elements=labels))
    pred = data.draw(hnp.arrays(np.uint8, shape, elements=st.integers(0, 4)))
    ignore = (255,) + ((2,) if data.draw(st.booleans()) else ())
    acc = SSCAccumulator(SMALL, ignore)
    acc.update(pred, gt)
    res = acc.result()
    tp, fp, fn, iou, union = kitti_api_ioueval(pred, gt, SMALL.n, ignore)
    ids = np.array(res.class_ids)
    assert 2 not in ids or 2 not in ignore
    np.testing.assert_array_equal(res.tp, tp[ids])
    np.testing.assert_array_equal(res.fp, fp[ids])
    np.testing.assert_array_equal(res.fn, fn[ids])
    present = union[ids] > 0
    np.testing.assert_allclose(res.iou[present], iou[ids][present], rtol=1e-12)
    assert np.isnan(res.iou[~present]).all()
    if present.any():
        assert res.miou == pytest.approx(iou[ids][present].mean(), rel=1e-12)
    else:
        assert np.isnan(res.miou)


def test_ignored_prediction_is_the_ignore_row():
    # gt 2, pred 2 (ignored id inside the range): dropped like semantic-kitti-api's ignore row
    gt = np.array([1, 2, 2, 3], np.uint8)
    pred = np.array([1, 2, 1, 2], np.uint8)
    acc = SSCAccumulator(SMALL, ignore=(2,))
    acc.update(pred, gt)
    r = acc.result()
    assert 2 not in r.class_ids
    # voxel 3 (gt 3, pred 2) is skipped: class 3 has no FN
    row = dict(zip(r.class_ids, zip(r.tp, r.fp, r.fn)))
    assert row[3] == (0, 0, 0) and row[1] == (1, 0, 0)
    assert r.pred_ignored == 1


def test_hand_worked_geometry_and_classes():
    # 10 voxels; free = 0
    gt = np.array([0, 0, 0, 1, 1, 1, 2, 2, 255, 0], np.uint8)
    pred = np.array([0, 1, 0, 1, 1, 2, 2, 0, 1, 2], np.uint8)
    acc = SSCAccumulator(SMALL)
    acc.update(pred, gt)
    r = acc.result()
    # class 1: tp 2 (idx 3,4), fp 1 (idx 1), fn 1 (idx 5) -> 2/4; class 2: tp 1 (idx 6),
    # fp 2 (idx 5, 9), fn 1 (idx 7) -> 1/4; classes 3, 4 absent -> NaN; voxel 8 void
    iou = dict(zip(r.class_ids, r.iou))
    assert iou[1] == 0.5 and iou[2] == 0.25 and np.isnan(iou[3]) and np.isnan(iou[4])
    assert r.miou == pytest.approx(0.375)
    # geometry: occupied gt {3,4,5,6,7}, occupied pred {1,3,4,5,6,9} (voxel 8 skipped):
    # tp 4 (3,4,5,6), fp 2 (1, 9), fn 1 (7) -> 4/7, precision 4/6, recall 4/5
    assert r.geometry_iou == pytest.approx(4 / 7)
    assert r.geometry_precision == pytest.approx(4 / 6)
    assert r.geometry_recall == pytest.approx(4 / 5)
    assert r.voxels == 9


def test_mask_skips_voxels():
    gt = np.array([1, 1, 2, 2], np.uint8)
    pred = np.array([1, 2, 2, 1], np.uint8)
    mask = np.array([True, False, True, False])
    acc = SSCAccumulator(SMALL)
    acc.update(pred, gt, mask)
    r = acc.result()
    assert r.miou == 1.0 and r.voxels == 2


@settings(max_examples=60, deadline=None)
@given(gt=hnp.arrays(np.uint8, hnp.array_shapes(min_dims=3, max_dims=3, max_side=6), elements=st.integers(0, 4)))
def test_perfect_prediction_scores_one(gt):
    acc = SSCAccumulator(SMALL)
    acc.update(gt.copy(), gt)
    r = acc.result()
    if (gt != 0).any():
        assert r.miou == 1.0 and r.geometry_iou == 1.0
        assert np.all((r.iou == 1.0) | np.isnan(r.iou))
    else:
        assert np.isnan(r.miou)


@settings(max_examples=80, deadline=None)
@given(data=st.data(), shape=hnp.array_shapes(min_dims=1, max_dims=3, max_side=6), perm=st.permutations([1, 2, 3, 4]))
def test_class_permutation_permutes_ious(data, shape, perm):
    gt = data.draw(hnp.arrays(np.uint8, shape, elements=st.integers(0, 4)))
    pred = data.draw(hnp.arrays(np.uint8, shape, elements=st.integers(0, 4)))
    lut = np.array([0] + list(perm), np.uint8)  # free stays free
    a, b = SSCAccumulator(SMALL), SSCAccumulator(SMALL)
    a.update(pred, gt)
    b.update(lut[pred], lut[gt])
    ra, rb = a.result(), b.result()
    np.testing.assert_array_equal(rb.iou[lut[1:] - 1], ra.iou)  # class c's IoU moved to perm(c)
    assert ra.geometry_iou == rb.geometry_iou or (np.isnan(ra.geometry_iou) and np.isnan(rb.geometry_iou))
    assert ra.miou == pytest.approx(rb.miou, nan_ok=True)


@settings(max_examples=40, deadline=None)
@given(frames=st.lists(st.tuples(hnp.arrays(np.uint8, 12, elements=labels), hnp.arrays(np.uint8, 12, elements=st.integers(0, 4))), min_size=1, max_size=4))
def test_accumulating_frames_equals_one_concatenated_frame(frames):
    acc, one = SSCAccumulator(SMALL), SSCAccumulator(SMALL)
    for gt, pred in frames:
        acc.update(pred, gt)
    one.update(np.concatenate([p for _, p in frames]), np.concatenate([g for g, _ in frames]))
    np.testing.assert_array_equal(acc.confusion, one.confusion)
    assert acc.result().frames == len(frames)


def test_wide_dtypes_and_confusion_layout():
    gt = np.array([0, 1, 4, 4], np.int32)
    pred = np.array([1, 1, 4, 0], np.uint16)
    cm, skipped = confusion_matrix(pred, gt, 5)
    assert skipped == 0
    assert cm[0, 1] == 1 and cm[1, 1] == 1 and cm[4, 4] == 1 and cm[4, 0] == 1 and cm.sum() == 4  # [gt, pred]


@pytest.mark.parametrize("pred, gt, message", [
    (np.zeros(3, np.uint8), np.zeros(4, np.uint8), "shape"),
    (np.zeros(3, np.uint8), np.array([0, 9, 0], np.uint8), "ground truth has 1 voxels with label 9"),
    (np.array([0, 7, 300], np.int32), np.zeros(3, np.uint8), "prediction has 2 voxels with label 7"),
    (np.array([0, -1, 0], np.int64), np.zeros(3, np.uint8), "label -1"),
    (np.zeros(3, np.float32), np.zeros(3, np.uint8), "integers"),
])
def test_bad_labels_are_named(pred, gt, message):
    with pytest.raises(ValueError, match=message):
        SSCAccumulator(SMALL).update(pred, gt)


def test_label_maps_come_from_the_taxonomy():
    occ3d = label_map("occ3d")
    assert occ3d.n == 18 and occ3d.free == 17 and occ3d.names == taxonomy.OCC3D_NUSCENES_NAMES
    assert occ3d.from_carlaocc == taxonomy.mapping("occ3d_nuscenes")
    assert occ3d.names[occ3d.things[0]] == "bicycle" and "manmade" not in [occ3d.names[t] for t in occ3d.things]
    bench = label_map("benchmark")
    assert bench.n == 16 and bench.free == 15 and bench.names[:15] == taxonomy.BENCHMARK15_NAMES
    # None and Sky (IGNORE in benchmark15) are free here; Building and road users are things
    assert bench.from_carlaocc[0] == 15 and bench.from_carlaocc[11] == 15
    assert {bench.names[t] for t in bench.things} == {"Pole", "TrafficLight", "TrafficSign", "Person", "Car",
                                                      "Truck", "OtherVehicle"}
    v1 = label_map("benchmark", "carlaocc-v1")
    assert {v1.names[t] for t in v1.things} == {"Building", "Person", "Car", "Truck", "OtherVehicle"}
    assert label_map("sscbench").n == 19 and label_map("sscbench").free == 0
    assert label_map("carlaocc").n == 30 and label_map("carlaocc").things == taxonomy.thing_ids()
    with pytest.raises(ValueError, match="unknown label map 'kitti'"):
        label_map("kitti")
    # conversion: CarlaOcc Car (14) -> Occ3D car (4), None -> free, 255 passes, 30 is an error
    np.testing.assert_array_equal(occ3d.convert_carlaocc(np.array([14, 0, 255], np.uint8)), [4, 17, 255])
    with pytest.raises(ValueError, match="id 30"):
        occ3d.convert_carlaocc(np.array([30], np.uint8))
    assert set(LABEL_MAPS) == {"carlaocc", "benchmark", "occ3d", "sscbench", "semantickitti"}


@needs(OCC3D_SAMPLE)
def test_real_occ3d_sample_with_camera_mask():
    z = np.load(OCC3D_SAMPLE)
    gt, cam = z["semantics"], z["mask_camera"].astype(bool)
    rng = np.random.default_rng(0)
    pred = gt.copy()
    flip = rng.random(gt.shape) < 0.2
    pred[flip] = rng.integers(0, 18, int(flip.sum()))
    acc = SSCAccumulator(label_map("occ3d"))
    acc.update(pred, gt, cam)
    r = acc.result()
    tp, fp, fn, iou, union = kitti_api_ioueval(pred[cam], gt[cam], 18, (255,))
    ok = union[:17] > 0
    np.testing.assert_allclose(r.iou[ok], iou[:17][ok], rtol=1e-12)
    assert r.voxels == int(cam.sum())
    perfect = SSCAccumulator(label_map("occ3d"))
    perfect.update(gt, gt, cam)
    assert perfect.result().miou == 1.0 and perfect.result().geometry_iou == 1.0
