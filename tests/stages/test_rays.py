"""RayIoU / RayPQ (stages/evaluation/rays.py): the known answers of training-formats.md section 10,
the first-hit traversal against every voxel's exact slab interval (a march in small steps misses
the slivers a ray clips, as seed 46 found), and RayPQ's matching rules."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from carlaocc.schemas import taxonomy
from carlaocc.stages.evaluation.rays import RayAccumulator, first_hits, query_directions, select_origins

OCC3D = list(taxonomy.OCC3D_NUSCENES_NAMES)  # 18 classes, free 17
FREE = 17
ORIGIN = np.array([-40.0, -40.0, -1.0])
VS = 0.4


def test_query_directions_and_origins():
    d = query_directions()
    assert d.shape == (14040, 3) and np.allclose(np.linalg.norm(d, axis=1), 1.0)
    pitch = np.degrees(np.arcsin(d[:, 2]))
    assert pitch.min() == pytest.approx(-45.0) and 12.0 < pitch.max() < 13.0
    assert len(np.unique(np.round(pitch, 6))) == 39
    pos = np.column_stack([np.linspace(-60, 60, 25), np.zeros(25), np.zeros(25)])
    o = select_origins(pos)
    assert len(o) == 8 and np.all(np.abs(o[:, 0]) < 39)
    kept = pos[np.abs(pos[:, 0]) < 39]
    np.testing.assert_array_equal(o, kept[np.round(np.linspace(0, len(kept) - 1, 8)).astype(int)])


def test_index_to_metre_and_exit_face_depth():
    # index (0,0,0) -> centre (-39.8, -39.8, -0.8); the point (0, 0, 0) is in voxel (100, 100, 2)
    assert np.allclose(ORIGIN + 0.5 * VS, [-39.8, -39.8, -0.8])
    assert np.array_equal(np.floor((np.zeros(3) - ORIGIN) / VS).astype(int), [100, 100, 2])
    occ = np.zeros((200, 200, 16), bool)
    i0, j, k = 50, 60, 5
    for i1 in (i0 + 1, i0 + 5, i0 + 20):
        occ[:] = False
        occ[i1, j, k] = True
        o = ORIGIN + (np.array([i0, j, k]) + 0.5) * VS
        depth, lin = first_hits(occ, o[None], np.array([[1.0, 0.0, 0.0]]), ORIGIN, VS)
        assert depth[0] == pytest.approx((i1 + 1 - (i0 + 0.5)) * VS)
        assert lin[0] == (i1 * 200 + j) * 16 + k
    # i1 = i0 + 5: 2.2 m, the exit face
    occ[:] = False
    occ[i0 + 5, j, k] = True
    assert first_hits(occ, (ORIGIN + (np.array([i0, j, k]) + 0.5) * VS)[None], np.array([[1.0, 0, 0]]), ORIGIN, VS
                      )[0][0] == pytest.approx(2.2)


def _brute(occ, o, d, voxel_size, origin):
    """Every voxel's exact slab interval along the ray (voxel units), independent of the
    traversal: the voxels the ray passes through (a positive length inside, however short), in
    entry order; the first occupied one and where the ray leaves it, else the last voxel."""
    p = (o - origin) / voxel_size
    idx = np.indices(occ.shape).reshape(3, -1).T
    with np.errstate(divide="ignore", invalid="ignore"):
        a, b = (idx - p) / d, (idx + 1 - p) / d
    t0 = np.nanmax(np.minimum(a, b), axis=1)
    t1 = np.nanmin(np.maximum(a, b), axis=1)
    crossed = t1 > np.maximum(t0, 0.0)
    order = np.flatnonzero(crossed)[np.argsort(t0[crossed], kind="stable")]
    for v in order:
        if occ[tuple(idx[v])]:
            return t1[v] * voxel_size, tuple(idx[v]), True
    last = order[-1]
    return t1[last] * voxel_size, tuple(idx[last]), False


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**31 - 1))
@example(46)  # a ray that clips a 0.2 mm sliver of an occupied voxel as it leaves the grid
def test_first_hits_agree_with_a_brute_force_march(seed):
    rng = np.random.default_rng(seed)
    occ = rng.random((12, 10, 6)) < 0.08
    origin = np.array([-1.0, 2.0, 0.5])
    voxel_size = 0.5
    o = origin + rng.uniform([0.5, 0.5, 0.5], [5.5, 4.5, 2.5])
    dirs = rng.normal(size=(12, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    depth, lin = first_hits(occ, o[None], dirs, origin, voxel_size)
    for r, d in enumerate(dirs):
        bd, bv, hit = _brute(occ, o, d, voxel_size, origin)
        assert bv is not None
        ours = np.unravel_index(lin[r], occ.shape)
        assert bool(occ[ours]) == hit, r  # a hit in both or in neither
        if hit:  # the same voxel (a miss's last voxel may differ where the ray leaves through an edge)
            assert lin[r] == np.ravel_multi_index(bv, occ.shape), (r, bv)
        # SparseOcc's float32 rays: origin, end point and depth rounded to float32 (~1e-7 relative)
        assert depth[r] == pytest.approx(bd, abs=5e-6)


def _grid_with_wall(x_index=150, label=15):
    sem = np.full((200, 200, 16), FREE, np.uint8)
    sem[:, :, 0:2] = 11  # driveable surface
    sem[x_index:x_index + 2, :, 2:12] = label  # a wall across x
    sem[90:96, 120:124, 2:6] = 4  # a car
    return sem


def _acc(**kw):
    return RayAccumulator(OCC3D, thing_classes=(2, 3, 4, 5, 6, 7, 9, 10), **kw)


LIDAR = np.array([[0.9, 0.0, 1.8]])


def test_identity_is_one_absent_is_nan_and_empty_is_zero():
    gt = _grid_with_wall()
    inst = np.zeros(gt.shape, np.uint32)
    inst[gt == 4] = 7
    acc = _acc()
    acc.update(gt, gt, LIDAR, ORIGIN, VS, inst, inst)
    r = acc.ray_iou()
    present = {c for c, n in zip(r.classes, r.gt_rays) if n > 0}
    assert present == {"driveable_surface", "manmade", "car"}
    for k in range(3):
        for i, c in enumerate(r.classes):
            assert (r.iou[k, i] == 1.0) if c in present else math.isnan(r.iou[k, i])
    assert r.ray_iou == 1.0 and acc.ray_pq().ray_pq == 1.0
    empty = _acc()
    empty.update(gt, np.full_like(gt, FREE), LIDAR, ORIGIN, VS, inst, np.zeros_like(inst))
    r0 = empty.ray_iou()
    assert all(r0.iou[k, r0.classes.index(c)] == 0.0 for k in range(3) for c in present)
    pq0 = empty.ray_pq()
    assert all(pq0.pq[k, pq0.classes.index(c)] == 0.0 for k in range(3) for c in present)


def test_label_swap_closed_form():
    gt = _grid_with_wall()
    pred = gt.copy()
    pred[gt == 4] = 10  # car predicted as truck, same geometry
    acc = _acc()
    acc.update(gt, pred, LIDAR, ORIGIN, VS)
    r = acc.ray_iou()
    G = dict(zip(r.classes, r.gt_rays))
    for k in range(3):
        assert r.iou[k, r.classes.index("car")] == 0.0
        assert r.iou[k, r.classes.index("truck")] == pytest.approx(0 / (0 + G["car"]))  # no truck in the GT
        assert r.iou[k, r.classes.index("manmade")] == 1.0
    # a swap between two present classes: IoU_B = G_B / (G_A + G_B)
    gt2 = gt.copy()
    gt2[60:64, 60:64, 2:6] = 10  # a truck in the ground truth too
    pred2 = gt2.copy()
    pred2[gt2 == 4] = 10
    acc2 = _acc()
    acc2.update(gt2, pred2, LIDAR, ORIGIN, VS)
    r2 = acc2.ray_iou()
    G2 = dict(zip(r2.classes, r2.gt_rays))
    assert G2["truck"] > 0 and G2["car"] > 0
    for k in range(3):
        assert r2.iou[k, r2.classes.index("truck")] == pytest.approx(G2["truck"] / (G2["car"] + G2["truck"]))


@pytest.mark.parametrize("k, passes", [(1, (True, True, True)), (3, (False, True, True)),
                                       (5, (False, False, True)), (10, (False, False, False))])
def test_head_on_shift(k, passes):
    gt = np.full((200, 200, 16), FREE, np.uint8)
    gt[150, :, :] = 15
    pred = np.full_like(gt, FREE)
    pred[150 + k, :, :] = 15
    o = ORIGIN + (np.array([100, 100, 8]) + 0.5) * VS
    acc = RayAccumulator(OCC3D, directions=np.array([[1.0, 0.0, 0.0]]))
    acc.update(gt, pred, o[None], ORIGIN, VS)
    r = acc.ray_iou()
    got = tuple(bool(r.iou[t, r.classes.index("manmade")] == 1.0) for t in range(3))
    assert got == passes


def test_whole_grid_shift_is_monotone_in_the_threshold():
    gt = _grid_with_wall()
    pred = np.full_like(gt, FREE)
    pred[1:] = gt[:-1]
    acc = _acc()
    acc.update(gt, pred, LIDAR, ORIGIN, VS)
    by = acc.ray_iou().by_threshold
    assert by[1.0] <= by[2.0] <= by[4.0] < 1.0


def test_relative_variant_accepts_a_far_ray_within_ten_percent():
    for relative, want in ((False, 0.0), (True, 1.0)):
        acc = RayAccumulator(OCC3D, relative=relative)
        acc.add_rays(np.array([30.0]), np.array([4]), np.array([32.5]), np.array([4]))
        assert acc.ray_iou().iou[0, OCC3D.index("car")] == want


def test_raypq_matching_boundary_and_small_segments():
    car = OCC3D.index("car")
    things = (car,)

    def score(g_ids, p_ids):
        acc = RayAccumulator(OCC3D, thing_classes=things)
        n = len(g_ids)
        d = np.full(n, 10.0)
        acc.add_rays(d, np.full(n, car), d, np.full(n, car), np.asarray(g_ids), np.asarray(p_ids))
        r = acc.ray_pq()
        c = r.classes.index("car")
        return r.pq[0, c], r.sq[0, c], r.rq[0, c]

    # GT segment 1 of 20 rays; prediction 2 overlaps 10 of them and has 10 more: IoU 10/30 < .5
    # exactly 0.5: 20 GT rays, prediction covers 15 of them plus 5 others -> IoU 15/25 = .6 (match)
    g = [1] * 20 + [0] * 10
    p_half = [2] * 10 + [3] * 10 + [2] * 10  # pred 2: 10 shared + 10 outside = 20; GT 1: 20 -> IoU 10/30
    pq, sq, rq = score(g, p_half)
    assert pq == 0.0 and rq == 0.0  # no match: FP (pred 2, 20 rays) and FN (GT 1); pred 3 (10 rays) FP too
    # IoU exactly 0.5: GT 20 rays, pred covers 10 of them + 0 others -> 10 / (10 + 20 - 10) = 0.5: no match
    g2 = [1] * 20
    p2 = [2] * 10 + [4] * 10
    assert score(g2, p2)[2] == 0.0
    # just above 0.5: pred covers 11 of 20 -> 11/20 = 0.55: a TP with SQ 0.55
    p3 = [2] * 11 + [4] * 9
    pq3, sq3, rq3 = score(g2, p3)
    assert sq3 == pytest.approx(0.55) and rq3 > 0
    # segments under 10 rays are neither FP nor FN: a 9-ray GT segment alone, unmatched
    g4 = [5] * 9
    p4 = [6] * 3 + [7] * 3 + [8] * 3  # no prediction covers half of it
    assert np.isnan(score(g4, p4)[0])
    # ... while a 10-ray one unmatched is an FN (PQ 0)
    assert score([5] * 10, [6] * 3 + [7] * 3 + [8] * 4)[0] == 0.0


def test_mave_and_the_occupancy_score():
    names = list(taxonomy.OPENOCC_V2_NAMES)  # free 16
    car = names.index("car")
    gt = np.full((200, 200, 16), 16, np.uint8)
    gt[:, :, 0:2] = names.index("driveable_surface")
    gt[120:130, 95:105, 2:6] = car
    flow = np.zeros((*gt.shape, 2), np.float32)
    flow[gt == car] = (3.0, 0.0)
    o = np.array([[0.0, 0.0, 1.8]])
    # the same flow: mAVE 0, score 0.9 * 1 + 0.1
    acc = RayAccumulator(names, flow_classes=(car,))
    acc.update(gt, gt, o, ORIGIN, VS, gt_flow=flow, pred_flow=flow)
    assert acc.mave()[0] == 0.0 and acc.occupancy_score() == pytest.approx(1.0)
    # a car predicted still: every TP car ray is 3 m/s off; mAVE 3 > 1 adds nothing
    acc2 = RayAccumulator(names, flow_classes=(car,))
    acc2.update(gt, gt, o, ORIGIN, VS, gt_flow=flow, pred_flow=np.zeros_like(flow))
    m, per = acc2.mave()
    assert m == pytest.approx(3.0) and per["car"] == pytest.approx(3.0)
    assert acc2.occupancy_score() == pytest.approx(0.9)
    # half the speed: mAVE 1.5 -> still 0.9; 0.5 m/s off -> 0.9 + 0.05
    acc3 = RayAccumulator(names, flow_classes=(car,))
    acc3.update(gt, gt, o, ORIGIN, VS, gt_flow=flow, pred_flow=flow * (2.5 / 3.0))
    assert acc3.mave()[0] == pytest.approx(0.5, abs=1e-6) and acc3.occupancy_score() == pytest.approx(0.95)


def test_raypq_instance_over_two_classes_keeps_its_rays_in_their_classes():
    """As SparseOcc: a ground-truth instance whose rays carry two classes loses its id, not its
    rays -- 30 car + 5 truck rays of one instance, all predicted car of one instance: a car TP."""
    car, truck = OCC3D.index("car"), OCC3D.index("truck")
    acc = RayAccumulator(OCC3D, thing_classes=(car, truck))
    d = np.full(35, 10.0)
    gl = np.array([car] * 30 + [truck] * 5)
    acc.add_rays(d, gl, d, np.full(35, car), np.ones(35, np.int64), np.ones(35, np.int64))
    r = acc.ray_pq()
    assert r.rq[0, r.classes.index("car")] == 1.0
