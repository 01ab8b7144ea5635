"""Pooling across voxel sizes and resampling to other datasets' grids (stages/voxelize/pooling.py, stages/export/resample.py).

Orientation tests place objects at known LiDAR-frame positions (x forward, y left, z up) and check
the exact target voxel index, so a swapped or mirrored axis fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.rig import LidarSpec
from carlaocc.schemas.taxonomy import (
    CLASSES,
    OCC3D_NUSCENES_NAMES,
    SSCBENCH_KITTI360_NAMES,
    by_name,
    dynamic_ids,
    mapping,
    thing_ids,
)
from carlaocc.stages.export.resample import OCC3D_NUSCENES, SSCBENCH_KITTI360, TargetGrid, bin_reduce, resample
from carlaocc.stages.voxelize.pooling import (
    DEFAULT_POOLING_PRIORITY,
    pool_instances,
    pool_to_grid,
    pooling_disagreement,
    rank_table,
)

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

ROAD, SIDEWALK, BUILDING, FENCE, POLE = (by_name(n).id for n in ("Road", "Sidewalk", "Building", "Fence", "Pole"))
VEGETATION, CAR, RIDER, BICYCLE, WALL = (by_name(n).id for n in ("Vegetation", "Car", "Rider", "Bicycle", "Wall"))
THINGS = np.zeros(256, dtype=bool)
THINGS[list(thing_ids())] = True


def _grids(shape, coarse_vs: float, f: int, origin=(0.0, 0.0, 0.0)) -> tuple[GridSpec, GridSpec]:
    """A coarse grid of ``shape`` voxels and the fine grid ``f`` times finer on the same region."""
    rmax = tuple(o + n * coarse_vs for o, n in zip(origin, shape))
    coarse = GridSpec(region_min=origin, region_max=rmax, voxel_size=coarse_vs)
    fine = GridSpec(region_min=origin, region_max=rmax, voxel_size=coarse_vs / f)
    return fine, coarse


def _repeat(a: np.ndarray, f: int) -> np.ndarray:
    return a.repeat(f, axis=0).repeat(f, axis=1).repeat(f, axis=2)


def _lidar_to_ego(lidar: LidarSpec) -> np.ndarray:
    return np.asarray(lidar.sensor_to_ego(), dtype=np.float64)


# ------------------------------------------------------------------------------------------------
# priority
# ------------------------------------------------------------------------------------------------


def test_default_priority_rule():
    prio = list(DEFAULT_POOLING_PRIORITY)
    assert sorted(prio) == list(range(1, 30))  # every class but free, once
    pos = {c: prio.index(c) for c in prio}
    assert set(prio[: len(dynamic_ids())]) == set(dynamic_ids())  # road users first
    thin = [by_name(n).id for n in ("Fence", "Pole", "TrafficLight", "TrafficSign", "GuardRail")]
    ground = [by_name(n).id for n in ("Road", "Sidewalk", "Terrain", "Water", "RoadLine", "Ground", "RailTrack")]
    assert max(pos[c] for c in dynamic_ids()) < min(pos[c] for c in thin)
    assert max(pos[c] for c in thin) < pos[BUILDING] < min(pos[c] for c in ground)
    assert prio[-1] == by_name("Sky").id


def test_rank_table_is_a_permutation_and_validates():
    rank, label = rank_table()
    assert rank[0] == 0 and label[0] == 0
    assert np.array_equal(label[rank], np.arange(256))
    assert rank[DEFAULT_POOLING_PRIORITY[0]] == 255
    assert rank[30] > rank[31] > 0  # unlisted labels: below the listed ones, lower id higher
    assert rank[30] < rank[DEFAULT_POOLING_PRIORITY[-1]]
    for bad in ([0, 1], [1, 1], [256], [[1, 2]], [1.5]):
        with pytest.raises(ValueError):
            rank_table(bad)


# ------------------------------------------------------------------------------------------------
# pooling
# ------------------------------------------------------------------------------------------------


@SETTINGS
@given(
    coarse=hnp.arrays(np.uint8, hnp.array_shapes(min_dims=3, max_dims=3, min_side=1, max_side=5), elements=st.integers(0, 29)),
    f=st.sampled_from([2, 3, 4]),
    voxel_size=st.sampled_from([0.2, 0.25, 0.5, 1.0]),
)
def test_pooling_a_repeated_grid_returns_it(coarse, f, voxel_size):
    fine_g, coarse_g = _grids(coarse.shape, voxel_size, f, origin=(-1.0, 0.6, -3.0))
    assert fine_g.shape == tuple(n * f for n in coarse.shape)
    fine = _repeat(coarse, f)
    assert np.array_equal(pool_to_grid(fine, fine_g, coarse_g), coarse)
    # instances: thing voxels carry an id, stuff 0; pooling the repeated ids returns them
    ids = np.where(THINGS[coarse], np.arange(coarse.size, dtype=np.uint32).reshape(coarse.shape) + 1, 0).astype(np.uint32)
    assert np.array_equal(pool_instances(_repeat(ids, f), fine, fine_g, coarse_g, coarse), ids)


@SETTINGS
@given(
    fine=hnp.arrays(np.uint8, (6, 4, 6), elements=st.sampled_from([0, ROAD, POLE, CAR, VEGETATION, 40])),
    f=st.sampled_from([2, 3]),
)
def test_pooling_matches_a_per_block_reference(fine, f):
    shape = tuple(math.ceil(n / f) for n in fine.shape)
    fine_g = GridSpec(region_min=(0, 0, 0), region_max=tuple(n * 0.1 for n in fine.shape), voxel_size=0.1)
    coarse_g = GridSpec(region_min=(0, 0, 0), region_max=tuple(n * 0.1 for n in fine.shape), voxel_size=0.1 * f)
    assert coarse_g.shape == shape
    got = pool_to_grid(fine, fine_g, coarse_g)
    rank, _ = rank_table()
    for idx in np.ndindex(*shape):
        block = fine[tuple(slice(i * f, i * f + f) for i in idx)]
        present = [c for c in np.unique(block) if c]
        want = max(present, key=lambda c: rank[c]) if present else 0
        assert got[idx] == want


def test_a_pole_voxel_wins_over_a_block_of_road():
    fine_g, coarse_g = _grids((2, 1, 1), 0.5, 5)
    fine = np.full(fine_g.shape, ROAD, dtype=np.uint8)
    fine[7, 2, 4] = POLE  # one voxel of the second block
    assert pool_to_grid(fine, fine_g, coarse_g).ravel().tolist() == [ROAD, POLE]
    fine[8, 0, 0] = CAR  # a road user beats the pole
    assert pool_to_grid(fine, fine_g, coarse_g).ravel().tolist() == [ROAD, CAR]
    custom = [ROAD, POLE, CAR]  # a caller's priority: road first
    assert pool_to_grid(fine, fine_g, coarse_g, np.array(custom)).ravel().tolist() == [ROAD, ROAD]


def test_pooling_pads_a_grown_grid_with_free():
    # fine 0.05 m over 1.55 m = 31 voxels; coarse 0.5 m grows to 4 voxels = 40 fine (9 padded)
    fine_g = GridSpec(region_min=(0, 0, 0), region_max=(1.55, 0.5, 0.5), voxel_size=0.05)
    coarse_g = GridSpec(region_min=(0, 0, 0), region_max=(1.55, 0.5, 0.5), voxel_size=0.5)
    assert fine_g.shape == (31, 10, 10) and coarse_g.shape == (4, 1, 1) and coarse_g.grown
    fine = np.zeros(fine_g.shape, dtype=np.uint8)
    fine[30, 9, 9] = FENCE  # the last fine voxel, inside the grown coarse voxel 3
    fine[:10] = ROAD
    assert pool_to_grid(fine, fine_g, coarse_g).ravel().tolist() == [ROAD, 0, 0, FENCE]


def test_default_grid_005_to_05_shape_and_growth():
    fine_g, coarse_g = GridSpec(voxel_size=0.05), GridSpec(voxel_size=0.5)
    assert fine_g.shape == (1536, 1024, 260) and coarse_g.shape == (154, 103, 26)
    fine = np.zeros(fine_g.shape, dtype=np.uint8)
    fine[0, 0, 0] = ROAD
    fine[1530:1536, 1020:1024, 250:260] = ROAD
    fine[1535, 1023, 259] = CAR  # last fine voxel: in the last (grown) coarse voxel along x and y
    inst = np.zeros(fine_g.shape, dtype=np.uint32)
    inst[1535, 1023, 259] = 9
    pooled = pool_to_grid(fine, fine_g, coarse_g)
    assert pooled.shape == (154, 103, 26)
    assert pooled[153, 102, 25] == CAR and pooled[0, 0, 0] == ROAD
    assert np.count_nonzero(pooled) == 2
    ids = pool_instances(inst, fine, fine_g, coarse_g, pooled)
    assert ids[153, 102, 25] == 9 and np.count_nonzero(ids) == 1


def test_pooled_instances_smallest_id_of_the_winning_class():
    fine_g, coarse_g = _grids((3, 1, 1), 0.4, 2)
    sem = np.zeros(fine_g.shape, dtype=np.uint8)
    inst = np.zeros(fine_g.shape, dtype=np.uint32)
    # block 0: two cars (ids 7, 5) and a building (id 2, loses to the cars) -> 5
    sem[0, 0, 0], inst[0, 0, 0] = CAR, 7
    sem[1, 1, 1], inst[1, 1, 1] = CAR, 5
    sem[0, 1, 0], inst[0, 1, 0] = BUILDING, 2
    # block 1: a pole (stuff) beats a building -> 0
    sem[2, 0, 0] = POLE
    sem[3, 0, 0], inst[3, 0, 0] = BUILDING, 4
    # block 2: a building alone (a static thing) keeps its id
    sem[5, 1, 1], inst[5, 1, 1] = BUILDING, 11
    pooled = pool_to_grid(sem, fine_g, coarse_g)
    assert pooled.ravel().tolist() == [CAR, POLE, BUILDING]
    assert pool_instances(inst, sem, fine_g, coarse_g, pooled).ravel().tolist() == [5, 0, 11]


def test_pooling_rejects_mismatched_grids():
    fine = GridSpec(voxel_size=0.2)
    with pytest.raises(ValueError, match="integer multiple"):
        pool_to_grid(np.zeros(fine.shape, np.uint8), fine, GridSpec(voxel_size=0.5))
    with pytest.raises(ValueError, match="integer multiple"):
        pool_to_grid(np.zeros(fine.shape, np.uint8), fine, GridSpec(voxel_size=0.1))
    shifted = GridSpec(region_min=(-25.4, -25.6, -3.0), voxel_size=0.4)
    with pytest.raises(ValueError, match="region_min"):
        pool_to_grid(np.zeros(fine.shape, np.uint8), fine, shifted)
    with pytest.raises(ValueError, match="shape"):
        pool_to_grid(np.zeros((3, 3, 3), np.uint8), fine, GridSpec(voxel_size=0.4))
    with pytest.raises(ValueError, match="uint8"):
        pool_to_grid(np.zeros(fine.shape, np.int32), fine, GridSpec(voxel_size=0.4))


# ------------------------------------------------------------------------------------------------
# disagreement
# ------------------------------------------------------------------------------------------------


def test_disagreement_hand_example():
    direct = np.array([0, ROAD, ROAD, CAR, POLE, 0], dtype=np.uint8).reshape(1, 2, 3)
    pooled = np.array([0, ROAD, POLE, 0, POLE, CAR], dtype=np.uint8).reshape(1, 2, 3)
    d = pooling_disagreement(direct, pooled)
    # occupied direct {1,2,3,4}, pooled {1,2,4,5}: both {1,2,4}, union 5; voxel 2 differs
    assert d == {
        "voxels": 6,
        "occupied_direct": 4,
        "occupied_pooled": 4,
        "occupancy_mismatch": 2,
        "label_mismatch": 1,
        "occupancy_iou": pytest.approx(3 / 5),
        "mismatch_rate": pytest.approx(3 / 5),
    }


def test_disagreement_of_identical_grids_is_zero():
    rng = np.random.default_rng(3)
    a = rng.integers(0, 30, (8, 7, 6)).astype(np.uint8)
    d = pooling_disagreement(a, a.copy())
    assert d["occupancy_mismatch"] == d["label_mismatch"] == 0
    assert d["mismatch_rate"] == 0.0 and d["occupancy_iou"] == 1.0
    empty = pooling_disagreement(np.zeros((2, 2, 2), np.uint8), np.zeros((2, 2, 2), np.uint8))
    assert empty["occupancy_iou"] == 1.0 and empty["mismatch_rate"] == 0.0
    with pytest.raises(ValueError, match="same shape"):
        pooling_disagreement(a, a[:-1])


# ------------------------------------------------------------------------------------------------
# resampling: target grids and orientation
# ------------------------------------------------------------------------------------------------

G02 = GridSpec(voxel_size=0.2)  # default region, 384 x 256 x 65


def _index(grid: GridSpec, x: float, y: float, z: float) -> tuple[int, int, int]:
    """Index of our voxel containing a LiDAR-frame point."""
    return tuple(math.floor((p - o) / grid.voxel_size) for p, o in zip((x, y, z), grid.origin))  # type: ignore[return-value]


def _centre(grid: GridSpec, idx) -> np.ndarray:
    return np.asarray(grid.origin) + (np.asarray(idx) + 0.5) * grid.voxel_size


def _car_block(x: float, y: float, z: float, n: int = 2) -> np.ndarray:
    """A Car block of n^3 voxels of G02 whose first voxel contains (x, y, z) (LiDAR frame)."""
    sem = np.zeros(G02.shape, dtype=np.uint8)
    i, j, k = _index(G02, x, y, z)
    sem[i : i + n, j : j + n, k : k + n] = CAR
    return sem


def test_target_grid_constants_match_their_datasets():
    assert OCC3D_NUSCENES.range_max == (40.0, 40.0, 5.4)
    assert SSCBENCH_KITTI360.range_max == (51.2, 25.6, 4.4)
    assert OCC3D_NUSCENES_NAMES[OCC3D_NUSCENES.free_label] == "free"
    assert SSCBENCH_KITTI360_NAMES[SSCBENCH_KITTI360.free_label] == "unlabeled"
    with pytest.raises(ValueError):
        TargetGrid("x", (1, 1), 0.4, (0, 0, 0), "ego", "occ3d_nuscenes", 17)
    with pytest.raises(ValueError):
        TargetGrid("x", (1, 1, 1), 0.4, (0, 0, 0), "world", "occ3d_nuscenes", 17)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        TargetGrid("x", (1, 1, 1), 0.4, (0, 0, 0), "ego", "nope", 17)


@pytest.mark.parametrize("lidar", [LidarSpec(), LidarSpec(x=0.9)], ids=["rig", "lidar-x-0.9"])
def test_orientation_occ3d(lidar):
    sem = _car_block(10.05, 5.05, -0.95)  # 10 m ahead, 5 m to the left, 0.95 m below the LiDAR
    labels, _ = resample(sem, G02, OCC3D_NUSCENES, _lidar_to_ego(lidar))
    car = OCC3D_NUSCENES_NAMES.index("car")
    assert car == 4
    # expected: every occupied voxel centre by the brief's formula, in the ego frame
    want = set()
    for idx in zip(*np.nonzero(sem)):
        x, y, z = _centre(G02, idx)
        want.add((
            math.floor((x + lidar.x + 40) / 0.4),
            math.floor((y + 40) / 0.4),
            math.floor((z + lidar.z - (-1)) / 0.4),
        ))  # fmt: skip
    got = set(zip(*(a.tolist() for a in np.nonzero(labels != OCC3D_NUSCENES.free_label))))
    assert got == want
    assert all(labels[v] == car for v in got)
    # the first voxel by hand: centre (10.1, 5.1, -0.9) -> i = (10.1 + x_off + 40) / 0.4, ...
    i = math.floor((10.1 + lidar.x + 40) / 0.4)
    assert labels[i, 112, 4] == car  # j = floor(45.1 / 0.4), k = floor((-0.9 + 1.73 + 1) / 0.4)
    assert labels[i, 87, 4] == OCC3D_NUSCENES.free_label  # the mirror (y = -5.1) stays free
    assert (labels != 17).sum() == len(want)


def test_orientation_sscbench_kitti360():
    sem = _car_block(10.05, 5.05, -0.95)
    labels, _ = resample(sem, G02, SSCBENCH_KITTI360, np.eye(4))
    car = SSCBENCH_KITTI360_NAMES.index("car")
    assert mapping("sscbench_kitti360")[CAR] == car == 1
    # both grids are 0.2 m in the LiDAR frame: the 2x2x2 block lands on 2x2x2 target voxels
    i, j, k = math.floor(10.1 / 0.2), math.floor((5.1 + 25.6) / 0.2), math.floor((-0.9 + 2) / 0.2)
    assert (i, j, k) == (50, 153, 5)
    block = [[a, b, c] for a in (i, i + 1) for b in (j, j + 1) for c in (k, k + 1)]
    assert np.argwhere(labels).tolist() == block
    assert np.all(labels[labels != 0] == car)
    assert labels[i, math.floor((-5.1 + 25.6) / 0.2), k] == 0  # not mirrored to the right


def test_object_behind_is_in_occ3d_but_not_in_sscbench():
    sem = _car_block(-5.05, 2.05, -0.95)
    occ, _ = resample(sem, G02, OCC3D_NUSCENES, _lidar_to_ego(LidarSpec()))
    ssc, _ = resample(sem, G02, SSCBENCH_KITTI360, np.eye(4))
    assert not ssc.any()  # SSCBench is forward only (x >= 0)
    # centres x = -5.1, -4.9 m -> i = floor(34.9 / 0.4) = 87; y = 2.1, 2.3 -> j = 105;
    # z = -0.9, -0.7 m -> ego 0.83, 1.03 m -> k = 4, 5
    assert np.argwhere(occ == 4).tolist() == [[87, 105, 4], [87, 105, 5]]
    assert np.count_nonzero(occ != 17) == 2


def test_rotated_transform_uses_the_general_path():
    # target frame turned 180 degrees about z: ahead-left becomes behind-right
    m = np.diag([-1.0, -1.0, 1.0, 1.0])
    m[2, 3] = 1.73
    sem = _car_block(10.05, 5.05, -0.95, n=1)
    labels, _ = resample(sem, G02, OCC3D_NUSCENES, m)
    assert np.argwhere(labels == 4).tolist() == [[math.floor((-10.1 + 40) / 0.4), math.floor((-5.1 + 40) / 0.4), 4]]


def test_priority_applies_to_our_classes_before_mapping():
    # one Occ3D voxel (0.4 m) receives 2x2x2 of our 0.2 m voxels
    ego = _lidar_to_ego(LidarSpec())
    i, j, k = _index(G02, 10.05, 5.05, -0.95)
    i, j = i - i % 2, j - j % 2  # align to an Occ3D voxel along x, y (both grids start on 0.4 m)
    sem = np.zeros(G02.shape, np.uint8)
    sem[i : i + 2, j : j + 2, k] = VEGETATION
    sem[i, j, k] = FENCE  # thin structure beats vegetation -> barrier (release), not vegetation
    labels, _ = resample(sem, G02, OCC3D_NUSCENES, ego)
    (hit,) = map(tuple, np.argwhere(labels != 17))
    assert labels[hit] == OCC3D_NUSCENES_NAMES.index("barrier")
    # under carlaocc-v1's table a fence is manmade
    labels, _ = resample(sem, G02, OCC3D_NUSCENES, ego, label_table="carlaocc-v1")
    assert labels[hit] == OCC3D_NUSCENES_NAMES.index("manmade")
    sem[i + 1, j + 1, k] = RIDER
    sem[i + 1, j, k] = BICYCLE  # rider ranks above bicycle -> pedestrian
    labels, _ = resample(sem, G02, OCC3D_NUSCENES, ego)
    assert labels[hit] == OCC3D_NUSCENES_NAMES.index("pedestrian")


def test_class_mapped_to_unlabelled_keeps_that_id():
    kitti = TargetGrid("semantickitti", (256, 256, 32), 0.2, (0.0, -25.6, -2.0), "lidar", "semantickitti", 0)
    sem = np.zeros(G02.shape, np.uint8)
    i, j, k = _index(G02, 10.05, 5.05, -0.95)
    sem[i, j, k] = WALL  # SemanticKITTI learning map: other-structure -> 0 (unlabeled = empty)
    sem[i + 3, j, k] = ROAD
    labels, _ = resample(sem, G02, kitti, np.eye(4))
    assert mapping("semantickitti")[WALL] == 0
    assert np.argwhere(labels).tolist() == [[50 + 3, 153, 5]] and labels[53, 153, 5] == 9
    # every class maps through the taxonomy table (a one-voxel grid at (10.1, 5.1, -0.9))
    tiny = GridSpec(region_min=(10.0, 5.0, -1.0), region_max=(10.2, 5.2, -0.8), voxel_size=0.2)
    for c in CLASSES[1:]:
        got, _ = resample(np.full((1, 1, 1), c.id, np.uint8), tiny, OCC3D_NUSCENES, np.eye(4))
        assert got[125, 112, 0] == c.occ3d_nuscenes
        assert np.count_nonzero(got != 17) == (c.occ3d_nuscenes != 17)


def test_masks_are_resampled_by_any_observed_centre():
    sem = np.zeros(G02.shape, np.uint8)
    cam = np.zeros(G02.shape, bool)
    i, j, k = _index(G02, 10.05, 5.05, -0.95)
    cam[i, j, k] = True  # a single observed voxel of ours
    cam[0, 0, 0] = True  # behind/outside SSCBench
    labels, masks = resample(sem, G02, SSCBENCH_KITTI360, np.eye(4), masks={"camera": cam, "lidar": ~cam})
    assert not labels.any()
    assert np.argwhere(masks["camera"]).tolist() == [[50, 153, 5]]
    assert masks["lidar"].sum() == masks["lidar"].size - 1  # everything else observed
    assert masks["camera"].dtype == bool and masks["camera"].shape == SSCBENCH_KITTI360.shape
    assert resample(sem, G02, SSCBENCH_KITTI360, np.eye(4))[1] == {}
    with pytest.raises(ValueError, match="mask"):
        resample(sem, G02, SSCBENCH_KITTI360, np.eye(4), masks={"camera": cam[:-1]})
    with pytest.raises(ValueError, match="4x4"):
        resample(sem, G02, SSCBENCH_KITTI360, np.eye(3))


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31),
    shift=st.tuples(*(st.floats(-3.0, 3.0, allow_nan=False) for _ in range(3))),
    target=st.sampled_from([OCC3D_NUSCENES, SSCBENCH_KITTI360]),
    voxel_size=st.sampled_from([0.15, 0.3, 0.4, 0.5]),
)
def test_translation_fast_path_equals_binning_the_centres(seed, shift, target, voxel_size):
    rng = np.random.default_rng(seed)
    grid = GridSpec(region_min=(-6.0, -4.0, -2.5), region_max=(9.0, 5.0, 3.0), voxel_size=voxel_size)
    vol = np.where(rng.random(grid.shape) < 0.3, rng.integers(1, 30, grid.shape), 0).astype(np.uint8)
    m = np.eye(4)
    m[:3, 3] = shift
    rank, _ = rank_table()
    for values, ufunc, dtype in ((lambda a: rank[a], np.maximum, np.uint8), (lambda a: a != 0, np.logical_or, bool)):
        fast = bin_reduce(vol, values, grid, m, target, ufunc, dtype, points=False)
        slow = bin_reduce(vol, values, grid, m, target, ufunc, dtype, points=True)
        assert np.array_equal(fast, slow)


def test_classes_mapped_to_target_empty_do_not_erase_road():
    """A prop or wall voxel inside a target voxel of road keeps it road (review finding): classes
    the target maps to its empty label rank below every class it keeps."""
    from carlaocc.schemas import taxonomy

    skitti = TargetGrid("sk", (256, 256, 32), 0.2, (0.0, -25.6, -2.0), "lidar", "semantickitti", 0)
    grid = GridSpec(region_min=(0.0, -25.6, -2.0), region_max=(51.2, 25.6, 4.4), voxel_size=0.1)
    sem = np.zeros(grid.shape, np.uint8)
    road, static = taxonomy.by_name("Road").id, taxonomy.by_name("Static").id
    assert taxonomy.mapping("semantickitti")[static] == 0
    sem[10:12, 20:22, 4:6] = road  # one 0.2 m target voxel of road...
    sem[10, 20, 4] = static  # ...with one prop voxel in it
    labels, _ = resample(sem, grid, skitti, np.eye(4))
    assert labels[5, 10, 2] == taxonomy.mapping("semantickitti")[road]
    # alone, the prop still maps to the target's empty label
    sem[:] = 0
    sem[10, 20, 4] = static
    labels, _ = resample(sem, grid, skitti, np.eye(4))
    assert labels[5, 10, 2] == 0


# -- pooling onto another window of the region (the release's grids) ------------------------------


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), f=st.sampled_from([1, 2, 4]), shift=st.tuples(st.integers(-6, 6), st.integers(-6, 6),
                                                                                  st.integers(-6, 6)))
def test_pool_window_agrees_with_brute_force(seed, f, shift):
    from carlaocc.stages.voxelize.pooling import pool_window, rank_table

    rng = np.random.default_rng(seed)
    fine = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(1.2, 1.0, 0.8), voxel_size=0.1)
    sem = np.where(rng.random(fine.shape) < 0.3, rng.choice([ROAD, BUILDING, CAR, POLE, VEGETATION], fine.shape), 0)
    sem = sem.astype(np.uint8)
    inst = np.where(np.isin(sem, [CAR, POLE]), rng.integers(1, 5, fine.shape), 0).astype(np.uint32)
    voxel_size = 0.1 * f
    lo = tuple(round(0.1 * s, 6) for s in shift)
    coarse = GridSpec(region_min=lo, region_max=tuple(round(a + n * voxel_size, 6) for a, n in zip(lo, (3, 2, 2))), voxel_size=voxel_size)
    got_s, got_i = pool_window(sem, inst, fine, coarse)
    rank, _ = rank_table()
    # brute force: every coarse voxel's fine voxels by index arithmetic
    for I, J, K in np.ndindex(coarse.shape):
        cells = [(shift[0] + I * f + a, shift[1] + J * f + b, shift[2] + K * f + c)
                 for a in range(f) for b in range(f) for c in range(f)]
        inside = [x for x in cells if all(0 <= x[d] < fine.shape[d] for d in range(3))]
        labels = [int(sem[x]) for x in inside if sem[x]]
        want = max(labels, key=lambda c: rank[c]) if labels else 0
        assert got_s[I, J, K] == want
        ids = [int(inst[x]) for x in inside if sem[x] == want and inst[x]]
        assert got_i[I, J, K] == (min(ids) if ids else 0)


def test_pool_window_of_the_release_grids_on_the_default_region():
    from carlaocc.stages.voxelize.pooling import pool_window

    fine = GridSpec(voxel_size=0.1)  # 768 x 512 x 130 from (-25.6, -25.6, -3)
    sem = np.zeros(fine.shape, np.uint8)
    inst = np.zeros(fine.shape, np.uint32)
    sem[256, 0, 6], inst[256, 0, 6] = CAR, 7  # x 0.0, y -25.6, z -2.4: the forward view's first voxel
    fwd = GridSpec(region_min=(0.0, -25.6, -2.4), region_max=(51.2, 25.6, 4.0), voxel_size=0.2)
    s, i = pool_window(sem, inst, fine, fwd)
    assert s.shape == (256, 256, 32) and s[0, 0, 0] == CAR and i[0, 0, 0] == 7 and np.count_nonzero(s) == 1
    same = GridSpec(voxel_size=0.1)
    s1, i1 = pool_window(sem, inst, fine, same)
    assert np.array_equal(s1, sem) and np.array_equal(i1, inst)
    with pytest.raises(ValueError, match="whole number"):
        pool_window(sem, inst, fine, GridSpec(region_min=(0.05, -25.6, -3.0), region_max=(51.25, 25.6, 10.0), voxel_size=0.2))
