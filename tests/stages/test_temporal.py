import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.quality import (relative_pose, sequence_temporal, static_table, temporal_consistency_counts)
from carlaocc.schemas.taxonomy import by_name
from carlaocc.stages.quality.blocks import BlockedGrid

CAR = by_name("Car").id
ROAD, BUILDING, VEG = by_name("Road").id, by_name("Building").id, by_name("Vegetation").id


def reference_counts(sem0, sem1, pose0, pose1, voxel_size, origin, mask0=None, mask1=None, static=None,
                     vs1=None, origin1=None):
    """Brute force, straight from the documented convention: python loops over every voxel."""
    static = static_table() if static is None else static
    vs1 = voxel_size if vs1 is None else vs1
    origin1 = origin if origin1 is None else origin1
    T = np.linalg.inv(np.asarray(pose1, float)) @ np.asarray(pose0, float)
    inter, union = np.zeros(256, np.int64), np.zeros(256, np.int64)
    for v in itertools.product(*(range(n) for n in sem0.shape)):
        centre = np.asarray(origin, float) + (np.asarray(v) + 0.5) * voxel_size
        p = T[:3, :3] @ centre + T[:3, 3]
        u = tuple(int(math.floor(x)) for x in (p - np.asarray(origin1, float)) / vs1)
        if any(x < 0 or x >= n for x, n in zip(u, sem1.shape)):
            continue
        a, b = int(sem0[v]), int(sem1[u])
        if not (static[a] and static[b]):
            continue
        if mask0 is not None and not (mask0[v] and mask1[u]):
            continue
        for c in range(1, 256):
            in_a, in_b = a == c, b == c
            inter[c] += in_a and in_b
            union[c] += in_a or in_b
    return inter, union


def pose(rot=np.eye(3), t=(0, 0, 0)):
    p = np.eye(4)
    p[:3, :3], p[:3, 3] = rot, t
    return p


def rz90(n):
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][n % 4]
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def cube_rotations():
    """The 24 rotations of the cube (signed permutation matrices, det +1), exact integers."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            m = np.zeros((3, 3))
            for r, (col, s) in enumerate(zip(perm, signs)):
                m[r, col] = s
            if round(np.linalg.det(m)) == 1:
                out.append(m)
    return out


ROTATIONS = cube_rotations()


def world_scene(lo, hi):
    """A static world on the integer voxel lattice: label of world voxel (x, y, z)."""
    def label(x, y, z):
        if z == 0:
            return ROAD
        if 2 <= x <= 4 and -1 <= y <= 1 and 1 <= z <= 3:
            return BUILDING
        if (x + 2 * y + 3 * z) % 7 == 0 and z > 0:
            return VEG
        return 0
    return label


def render(label, sensor_pose, shape, origin, voxel_size):
    """Grid of a sensor at ``sensor_pose`` (sensor-to-world): sample the world at voxel centres."""
    sem = np.zeros(shape, np.uint8)
    for v in itertools.product(*(range(n) for n in shape)):
        centre = np.asarray(origin) + (np.asarray(v) + 0.5) * voxel_size
        w = sensor_pose[:3, :3] @ centre + sensor_pose[:3, 3]
        sem[v] = label(*(int(math.floor(x / voxel_size)) for x in w))
    return sem


@pytest.mark.parametrize("rot, shift", [(np.eye(3), (2, -1, 0)), (rz90(1), (1, 3, 0)), (rz90(2), (0, 0, 1))])
def test_static_scene_moved_by_whole_voxels_scores_one(rot, shift):
    voxel_size, shape = 0.5, (10, 9, 6)
    origin = (-2.5, -2.0, -1.0)  # a whole number of voxels: centres stay on the half-voxel lattice
    label = world_scene(None, None)
    p0 = pose(rz90(0), (0.5, 0.0, 0.5))
    p1 = pose(rot, np.asarray(shift) * voxel_size + p0[:3, 3])
    s0, s1 = render(label, p0, shape, origin, voxel_size), render(label, p1, shape, origin, voxel_size)
    c = temporal_consistency_counts(s0, s1, p0, p1, voxel_size, origin)
    assert c.total_union > 20 and c.score == 1.0
    assert (c.intersection == c.union).all()


def test_one_class_relabelled_matches_hand_count():
    s0 = np.zeros((4, 4, 4), np.uint8)
    s0[0, :, 0] = 1  # 4 voxels of class 1 ...
    s0[1, :, 0] = 1  # ... 8 in all
    s0[3, :2, 0] = 2  # 2 voxels of class 2
    s1 = s0.copy()
    s1[1, :3, 0] = 2  # 3 class-1 voxels relabelled 2 in the next frame
    s1[3, 3, 3] = 9  # one new vegetation voxel where frame t is free
    c = temporal_consistency_counts(s0, s1, np.eye(4), np.eye(4), 0.2, (0, 0, 0))
    assert (c.intersection[1], c.union[1]) == (5, 8)
    assert (c.intersection[2], c.union[2]) == (2, 5)
    assert (c.intersection[9], c.union[9]) == (0, 1)
    assert c.score == pytest.approx(7 / 14)
    assert c.mean_class_iou() == pytest.approx((5 / 8 + 2 / 5 + 0) / 3)


def test_voxels_leaving_the_region_are_excluded():
    s = np.full((5, 3, 2), ROAD, np.uint8)
    # the sensor moves 2 voxels forward: frame-t voxels x = 0, 1 map behind grid t+1
    c = temporal_consistency_counts(s, s, np.eye(4), pose(t=(0.4, 0, 0)), 0.2, (0, 0, 0))
    assert c.union[ROAD] == 3 * 3 * 2 and c.score == 1.0
    # moving out entirely leaves nothing to compare
    far = temporal_consistency_counts(s, s, np.eye(4), pose(t=(5.0, 0, 0)), 0.2, (0, 0, 0))
    assert far.total_union == 0 and math.isnan(far.score)


def test_dynamic_classes_are_excluded():
    s0 = np.zeros((6, 4, 3), np.uint8)
    s0[:, :, 0] = ROAD
    s1 = s0.copy()
    s0[1, 1, 1] = CAR
    s1[4, 2, 1] = CAR  # the car drove on; the road stays
    c = temporal_consistency_counts(s0, s1, np.eye(4), np.eye(4), 0.5, (0, 0, 0))
    assert c.union[CAR] == 0 and c.score == 1.0
    # the same frames counting cars as static disagree at both car positions
    every = temporal_consistency_counts(s0, s1, np.eye(4), np.eye(4), 0.5, (0, 0, 0),
                                        static=static_table(dynamic=()))
    assert every.union[CAR] == 2 and every.intersection[CAR] == 0 and every.score < 1
    # a car in one frame over road in the other excludes that road voxel too
    s1[1, 1, 0] = CAR
    c = temporal_consistency_counts(s0, s1, np.eye(4), np.eye(4), 0.5, (0, 0, 0))
    assert c.union[ROAD] == 6 * 4 - 1


def test_masks_are_respected_in_both_frames():
    s0 = np.zeros((4, 4, 2), np.uint8)
    s0[:, :, 0] = ROAD
    s1 = s0.copy()
    s1[3, :, 0] = 0  # frame t+1 lost the road's last row ...
    m0, m1 = np.ones(s0.shape, bool), np.ones(s1.shape, bool)
    eye = np.eye(4)
    assert temporal_consistency_counts(s0, s1, eye, eye, 1.0, (0, 0, 0)).score == 12 / 16
    m1[3, :, 0] = False  # ... where it did not observe it
    c = temporal_consistency_counts(s0, s1, eye, eye, 1.0, (0, 0, 0), mask_t=m0, mask_t1=m1)
    assert c.score == 1.0 and c.union[ROAD] == 12
    # frame t's mask is looked up at v, frame t+1's at the warped voxel u = v - (1, 0, 0)
    shifted = pose(t=(1.0, 0, 0))
    m0[:] = True
    m1[:] = True
    m1[0, :, :] = False  # hides the frame-t voxels x = 1
    c = temporal_consistency_counts(s0, s0, eye, shifted, 1.0, (0, 0, 0), mask_t=m0, mask_t1=m1)
    assert c.union[ROAD] == 2 * 4


def test_sequence_sums_pairs_and_pools():
    a = np.zeros((3, 3, 3), np.uint8)
    a[0, 0, 0] = 1
    b = a.copy()
    b[1, 1, 1] = 2
    eye = np.eye(4)
    p1 = temporal_consistency_counts(a, a, eye, eye, 1.0, (0, 0, 0))  # 1 / 1
    p2 = temporal_consistency_counts(a, b, eye, eye, 1.0, (0, 0, 0))  # 1 / 2
    total = sequence_temporal([p1, p2])
    assert total.total_intersection == 2 and total.total_union == 3 and total.score == pytest.approx(2 / 3)


def test_relative_pose_maps_frame_t_into_frame_t1():
    p0, p1 = pose(rz90(1), (3, 0, 0)), pose(np.eye(3), (1, 1, 0))
    x_t = np.array([1.0, 0, 0, 1])
    world = p0 @ x_t
    assert np.allclose(relative_pose(p0, p1) @ x_t, np.linalg.inv(p1) @ world)


def test_bad_inputs_are_named():
    s = np.zeros((2, 2, 2), np.uint8)
    eye = np.eye(4)
    with pytest.raises(ValueError, match="pose_t1 must be a 4x4"):
        temporal_consistency_counts(s, s, eye, np.eye(3), 1.0, (0, 0, 0))
    with pytest.raises(ValueError, match="both visibility masks"):
        temporal_consistency_counts(s, s, eye, eye, 1.0, (0, 0, 0), mask_t=s)
    with pytest.raises(ValueError, match="mask_t1 has shape"):
        temporal_consistency_counts(s, s, eye, eye, 1.0, (0, 0, 0), mask_t=s, mask_t1=np.zeros((3, 2, 2)))
    with pytest.raises(ValueError, match="semantic_t must be 3D"):
        temporal_consistency_counts(s[0], s, eye, eye, 1.0, (0, 0, 0))
    with pytest.raises(ValueError, match="voxel_size"):
        temporal_consistency_counts(s, s, eye, eye, 0.0, (0, 0, 0))


@st.composite
def lattice_pairs(draw):
    shape0 = tuple(draw(st.integers(1, 6)) for _ in range(3))
    shape1 = tuple(draw(st.integers(1, 6)) for _ in range(3))
    voxel_size = draw(st.sampled_from([1.0, 0.5, 0.4, 0.2]))
    origin = tuple(voxel_size * draw(st.integers(-4, 1)) for _ in range(3))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    labels = np.array([0, 0, ROAD, BUILDING, VEG, CAR], np.uint8)
    s0 = labels[rng.integers(0, len(labels), shape0)]
    s1 = labels[rng.integers(0, len(labels), shape1)]
    poses = []
    for _ in range(2):
        rot = ROTATIONS[draw(st.integers(0, len(ROTATIONS) - 1))]
        t = np.asarray([draw(st.integers(-3, 3)) for _ in range(3)]) * voxel_size
        poses.append(pose(rot, t))
    masks = (rng.random(shape0) < 0.8, rng.random(shape1) < 0.8) if draw(st.booleans()) else (None, None)
    return s0, s1, poses, voxel_size, origin, masks


@settings(max_examples=80, deadline=None)
@given(lattice_pairs())
def test_agrees_with_brute_force_on_lattice_motions(case):
    s0, s1, (p0, p1), voxel_size, origin, (m0, m1) = case
    c = temporal_consistency_counts(s0, s1, p0, p1, voxel_size, origin, mask_t=m0, mask_t1=m1)
    inter, union = reference_counts(s0, s1, p0, p1, voxel_size, origin, m0, m1)
    assert (c.intersection == inter).all() and (c.union == union).all()


def _rotation(rng, max_angle):
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    a = rng.uniform(-max_angle, max_angle)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([0.05, 0.6, 3.0]))
def test_agrees_with_brute_force_on_generic_motions(seed, max_angle):
    # generic poses (no centre lands on a voxel face) and different grids for the two frames
    rng = np.random.default_rng(seed)
    s0 = rng.choice(np.array([0, 0, 0, ROAD, VEG, CAR], np.uint8), size=tuple(rng.integers(2, 7, 3)))
    s1 = rng.choice(np.array([0, 0, ROAD, VEG], np.uint8), size=tuple(rng.integers(2, 7, 3)))
    p0 = pose(_rotation(rng, max_angle), rng.uniform(-1, 1, 3))
    p1 = pose(_rotation(rng, max_angle), rng.uniform(-1, 1, 3))
    o0, o1 = rng.uniform(-2, 0, 3), rng.uniform(-2, 0, 3)
    v1 = float(rng.choice([0.4, 0.5]))
    c = temporal_consistency_counts(s0, s1, p0, p1, 0.4, o0, voxel_size_t1=v1, origin_t1=o1)
    inter, union = reference_counts(s0, s1, p0, p1, 0.4, o0, vs1=v1, origin1=o1)
    assert (c.intersection == inter).all() and (c.union == union).all()


def test_tall_sparse_columns_skip_nothing_that_counts():
    # occupied voxels high in frame t+1's columns but free in frame t: the visited z range must
    # reach them through the back-warped ranges (pitched sensor)
    rng = np.random.default_rng(3)
    s0 = np.zeros((8, 8, 30), np.uint8)
    s1 = np.zeros((8, 8, 30), np.uint8)
    s0[:, :, 2] = ROAD
    s1[rng.integers(0, 8, 20), rng.integers(0, 8, 20), rng.integers(0, 30, 20)] = VEG
    p1 = pose(_rotation(np.random.default_rng(7), 0.3), (0.3, -0.2, 0.4))
    c = temporal_consistency_counts(s0, s1, np.eye(4), p1, 0.2, (-0.8, -0.8, -1.0))
    inter, union = reference_counts(s0, s1, np.eye(4), p1, 0.2, (-0.8, -0.8, -1.0))
    assert (c.union == union).all() and (c.intersection == inter).all() and union[VEG] > 0


# -- block-major grids (as the store decodes them) ------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.integers(1, 4), st.booleans())
def test_temporal_counts_on_blocks_with_two_masks_agree_with_brute_force(seed, bx, by, two_masks):
    rng = np.random.default_rng(seed)
    # columns up to 40 voxels: the observed-range narrowing skips whole 8-byte words
    shape0 = (*rng.integers(2, 5, 2), int(rng.integers(2, 41)))
    shape1 = (*rng.integers(2, 5, 2), int(rng.integers(2, 41)))
    s0 = rng.choice(np.array([0, 0, 0, ROAD, VEG, CAR], np.uint8), size=shape0)
    s1 = rng.choice(np.array([0, 0, ROAD, VEG], np.uint8), size=shape1)
    p0, p1 = pose(_rotation(rng, 0.6), rng.uniform(-1, 1, 3)), pose(_rotation(rng, 0.6), rng.uniform(-1, 1, 3))
    o0, o1 = rng.uniform(-2, 0, 3), rng.uniform(-2, 0, 3)
    masks0 = [rng.random(shape0) < 0.5 for _ in range(1 + two_masks)]
    masks1 = [rng.random(shape1) < 0.5 for _ in range(1 + two_masks)]
    # frame t block-major with its masks in its blocks, frame t+1 in other blocks and its masks dense
    c = temporal_consistency_counts(BlockedGrid.from_dense(s0, (bx, by)), BlockedGrid.from_dense(s1, (by, bx)), p0, p1, 0.4, o0,
                                    voxel_size_t1=0.5, origin_t1=o1,
                                    mask_t=tuple(BlockedGrid.from_dense(m.astype(np.uint8), (bx, by)) for m in masks0),
                                    mask_t1=tuple(masks1))
    inter, union = reference_counts(s0, s1, p0, p1, 0.4, o0, np.logical_or.reduce(masks0),
                                    np.logical_or.reduce(masks1), vs1=0.5, origin1=o1)
    assert (c.intersection == inter).all() and (c.union == union).all()


def test_temporal_counts_need_the_same_masks_in_both_frames():
    s = np.zeros((2, 2, 2), np.uint8)
    m = np.ones((2, 2, 2), bool)
    with pytest.raises(ValueError, match="same ones"):
        temporal_consistency_counts(s, s, np.eye(4), np.eye(4), 1.0, (0, 0, 0), mask_t=(m, m), mask_t1=m)
    with pytest.raises(ValueError, match="one or two"):
        temporal_consistency_counts(s, s, np.eye(4), np.eye(4), 1.0, (0, 0, 0), mask_t=(m, m, m), mask_t1=(m, m, m))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 4), st.integers(1, 4), st.integers(1, 21), st.booleans())
def test_temporal_counts_with_bit_masks_agree_with_brute_force(seed, bx, by, Z, other_blocks):
    """Visibility given as bits packed along z (the stored observed_bits, a BitGrid), in the
    semantic grid's blocks or in others, counts as the uint8 masks do (any height, not only
    whole bytes)."""
    from carlaocc.stages.quality.blocks import BitGrid

    rng = np.random.default_rng(seed)
    shape = (rng.integers(2, 9), rng.integers(2, 9), Z)
    s0 = rng.choice(np.array([0, 0, 1, 3, 14], np.uint8), size=shape)
    s1 = rng.choice(np.array([0, 0, 1, 3, 14], np.uint8), size=shape)
    p0, p1 = np.eye(4), np.eye(4)
    p1[:3, 3] = rng.integers(-2, 3, 3) * 0.4
    m0, m1 = rng.random(shape) < 0.5, rng.random(shape) < 0.5
    g0, g1 = BlockedGrid.from_dense(s0, (bx, by)), BlockedGrid.from_dense(s1, (by, bx))
    eb = (by, bx) if other_blocks else (bx, by)
    b0 = BitGrid.pack(BlockedGrid.from_dense(m0.astype(np.uint8), eb))
    b1 = BitGrid.pack(BlockedGrid.from_dense(m1.astype(np.uint8), (by, bx)))
    c = temporal_consistency_counts(g0, g1, p0, p1, 0.4, (0.0, 0.0, 0.0), mask_t=b0, mask_t1=b1)
    inter, union = reference_counts(s0, s1, p0, p1, 0.4, (0.0, 0.0, 0.0), m0, m1)
    np.testing.assert_array_equal(c.intersection, inter)
    np.testing.assert_array_equal(c.union, union)
