import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from carlaocc.stages.quality import isolated_mask_reference, sequence_continuity, spatial_continuity_counts


def test_single_voxel_is_isolated_and_pair_is_not():
    sem = np.zeros((4, 4, 4), np.uint8)
    sem[1, 1, 1] = 3
    c = spatial_continuity_counts(sem)
    assert c.occupied[3] == 1 and c.isolated[3] == 1 and c.score == 0.0
    sem[1, 1, 2] = 3
    c = spatial_continuity_counts(sem)
    assert c.occupied[3] == 2 and c.isolated[3] == 0 and c.score == 1.0


def test_neighbour_of_another_class_does_not_connect():
    sem = np.zeros((3, 3, 3), np.uint8)
    sem[1, 1, 1], sem[1, 1, 2] = 3, 14
    c = spatial_continuity_counts(sem)
    assert c.isolated[3] == 1 and c.isolated[14] == 1 and c.score == 0.0


def test_diagonal_is_not_a_face_neighbour():
    sem = np.zeros((3, 3, 3), np.uint8)
    sem[0, 0, 0] = sem[1, 1, 1] = 5
    assert spatial_continuity_counts(sem).isolated[5] == 2


def test_empty_grid_has_no_score():
    assert np.isnan(spatial_continuity_counts(np.zeros((2, 2, 2), np.uint8)).score)


@settings(max_examples=60, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9)),
              elements=st.integers(0, 4)))
def test_agrees_with_brute_force_reference(sem):
    c = spatial_continuity_counts(sem)
    ref = isolated_mask_reference(sem)
    for cls in range(1, 5):
        assert c.occupied[cls] == int((sem == cls).sum())
        assert c.isolated[cls] == int((ref & (sem == cls)).sum())
    assert c.occupied[0] == 0 and c.isolated[0] == 0


def test_sequence_sums_frames():
    a = np.zeros((3, 3, 3), np.uint8)
    a[1, 1, 1] = 1
    b = np.zeros((3, 3, 3), np.uint8)
    b[0, 0, :] = 1
    total = sequence_continuity([spatial_continuity_counts(a), spatial_continuity_counts(b)])
    assert total.occupied[1] == 4 and total.isolated[1] == 1 and total.score == 0.75


# -- the metrics stage's task: s_sc and s_tc per frame, pair and sequence from the store --------
def _write_sequence(store, frames, poses, masks=None, seq="seq0", bits=False):
    """A sequence's occupancy frames and LiDAR poses in ``store`` (grid 1 m over 6 x 5 x 3 m);
    ``bits``: the masks' union also as voxelize keeps it, ``observed_bits``."""
    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.grid import GridSpec
    from carlaocc.schemas.records import FrameRecord

    grid = GridSpec(region_min=(0, 0, 0), region_max=(6, 5, 3), voxel_size=1.0)
    occ = OccupancyStore(store)
    names = ("semantic", "mask_camera", "mask_lidar") if masks is not None else ("semantic",)
    names += ("observed_bits",) if bits else ()
    occ.create(seq, grid, len(frames), 4, names=names)
    for t, sem in enumerate(frames):
        arrays = {"semantic": sem}
        if masks is not None:
            arrays |= {"mask_camera": masks[t][0], "mask_lidar": masks[t][1]}
        if bits:
            arrays["observed_bits"] = np.packbits((masks[t][0] != 0) | (masks[t][1] != 0), axis=-1,
                                                  bitorder="little")
        occ.write_frame(seq, grid, t, arrays)
    rows = [FrameRecord(sequence_id=seq, frame_index=t, timestamp=0.1 * t, ego_pose=np.eye(4).ravel().tolist(),
                        lidar_pose=np.asarray(p, float).ravel().tolist()) for t, p in enumerate(poses)]
    ParquetTable(store, FrameRecord).save(seq, rows)
    return grid


def _run_metrics(store, grid, seq="seq0"):
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.pipeline.engine.spec import Partition
    from carlaocc.pipeline.tasks.quality import quality_task
    from carlaocc.schemas.configs import QualityConfig
    from carlaocc.schemas.records import QualityRecord

    from carlaocc.catalog.occupancy import OccupancyStore
    from carlaocc.pipeline.tasks.aggregate import aggregate_task

    # the map with one frame a task (every pair crosses a border: frame t + 1 is the next task's),
    # then the reduce (the sequence rows)
    n = OccupancyStore(store).open(seq, grid, "semantic").shape[0]
    keys = []
    for first in range(n):
        part = Partition(f"{seq}/{grid.key}/{first:04d}", {"sequence_id": seq, "voxel_size": grid.voxel_size,
                                                            "grid": grid.model_dump(mode="json"), "first": first,
                                                            "stop": first + 1})
        quality_task(store, QualityConfig(frames_per_task=1), part)
        keys.append(part.key)
    aggregate_task(store, QualityConfig(), Partition(f"{seq}/{grid.key}", {
        "sequence_id": seq, "voxel_size": grid.voxel_size, "voxel_size_key": grid.key, "quality_keys": keys}))
    rows = ParquetTable(store, QualityRecord).load()
    return {(r.metric, r.frame_index): r for r in rows}


def _moving_street(shift):
    """The same static street seen from a LiDAR ``shift`` voxels further along x."""
    world = np.zeros((12, 5, 3), np.uint8)
    world[:, :, 0] = 1  # road
    world[3:5, 0:2, 1:3] = 3  # a building
    world[8, 4, 1] = 9  # a lone bush
    return world[shift:shift + 6].copy()


def test_metrics_task_writes_temporal_consistency(store):
    frames = [_moving_street(s) for s in (0, 1, 3)]
    poses = [np.eye(4) for _ in frames]
    for p, s in zip(poses, (0, 1, 3)):
        p[0, 3] = float(s)
    car = 14
    frames[1][0, 2, 1] = car  # a car appears: dynamic, excluded from s_tc
    grid = _write_sequence(store, frames, poses)
    rows = _run_metrics(store, grid)
    # a static world seen with the right poses is perfectly consistent, per pair and overall
    for key in (("temporal_consistency", 0), ("temporal_consistency", 1), ("temporal_consistency", None)):
        assert rows[key].value == 1.0 and rows[key].numerator == rows[key].denominator > 0
    assert ("temporal_consistency", 2) not in rows
    pair = [rows[("temporal_consistency", t)].denominator for t in (0, 1)]
    assert rows[("temporal_consistency", None)].denominator == sum(pair)
    # spatial continuity rows carry their ratio terms too
    sc = rows[("spatial_continuity", 1)]
    assert sc.numerator == sc.occupied - sc.isolated and sc.denominator == sc.occupied and sc.isolated == 1  # the car


@pytest.mark.parametrize("bits", [False, True], ids=["masks", "observed_bits"])
def test_metrics_task_uses_poses_and_the_mask_union(store, bits):
    frames = [_moving_street(0), _moving_street(1)]
    frames[1][4, 4, 1] = 5  # a fence voxel frame t never saw ...
    ones = np.ones(frames[0].shape, np.uint8)
    hidden = ones.copy()
    hidden[4, 4, 1] = 0
    # ... frame t+1 did not see it either: observed in neither camera nor LiDAR mask
    masks = [(ones, ones), (hidden, hidden)]
    moved = np.eye(4)
    moved[0, 3] = 1.0
    grid = _write_sequence(store, frames, [np.eye(4), moved], masks=masks, bits=bits)
    assert _run_metrics(store, grid)[("temporal_consistency", 0)].value == 1.0
    # seen by the LiDAR only: the union of the masks counts it, and the pair disagrees there
    masks = [(ones, ones), (hidden, ones)]
    grid = _write_sequence(store, frames, [np.eye(4), moved], masks=masks, bits=bits)
    row = _run_metrics(store, grid)[("temporal_consistency", 0)]
    assert row.denominator - row.numerator == 1
    # with wrong poses (no motion) the same frames disagree along every moved boundary
    grid = _write_sequence(store, frames, [np.eye(4), np.eye(4)], masks=masks, bits=bits)
    assert _run_metrics(store, grid)[("temporal_consistency", 0)].value < 0.9


@pytest.mark.parametrize("store", ["local"], indirect=True)  # the reading is the store's own: one kind is enough
def test_quality_tables_from_observed_bits_equal_those_from_the_masks(store):
    """The quality stage reads observed_bits (the masks' union as bits) when voxelize wrote it;
    every table is the same as from the two uint8 masks (an older root's path)."""
    from carlaocc.catalog.parquet import ParquetTable
    from carlaocc.schemas.records import ClassQualityRecord, FrameStatisticsRecord

    rng = np.random.default_rng(7)
    frames = [_moving_street(s) for s in (0, 1, 2)]
    for f in frames:  # scattered labels and holes
        hit = rng.random(f.shape) < 0.15
        f[hit] = rng.integers(0, 30, int(hit.sum()), dtype=np.uint8)
    masks = [tuple((rng.random(frames[0].shape) < 0.6).astype(np.uint8) for _ in range(2)) for _ in frames]
    poses = [np.eye(4) for _ in frames]
    for p, s in zip(poses, (0, 1, 2)):
        p[0, 3] = float(s)

    def tables(bits):
        grid = _write_sequence(store, frames, poses, masks=masks, bits=bits)
        q = _run_metrics(store, grid)
        rest = [sorted(r.model_dump_json() for r in ParquetTable(store, m).load())
                for m in (ClassQualityRecord, FrameStatisticsRecord)]
        return {k: r.model_dump() for k, r in q.items()}, rest

    with_masks, with_bits = tables(False), tables(True)
    assert with_bits == with_masks
    assert with_masks[0][("temporal_consistency", None)]["denominator"] > 0
    # the bits are what is read: nothing observed there, no pair counts (the masks still say 60 %)
    from carlaocc.catalog.occupancy import OccupancyStore

    grid = _write_sequence(store, frames, poses, masks=masks, bits=True)
    occ = OccupancyStore(store)
    for t in range(len(frames)):
        occ.write_frame("seq0", grid, t, {"observed_bits": np.zeros((6, 5, 1), np.uint8)})
    assert _run_metrics(store, grid)[("temporal_consistency", None)].denominator == 0


def test_metrics_task_names_a_missing_pose(store):
    from carlaocc.catalog.store import StoreError

    grid = _write_sequence(store, [_moving_street(0), _moving_street(1)], [np.eye(4)])
    with pytest.raises(StoreError, match=r"no LiDAR pose for frame\(s\) \[1\]"):
        _run_metrics(store, grid)
