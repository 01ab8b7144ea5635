"""Dataset statistics against hand counts and a brute-force reference; plots are valid PNGs."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import AssetRecord, AssetStatisticsRecord, QualityRecord
from carlaocc.stages.report import plots
from carlaocc.stages.quality.statistics import (N_CLASSES, SequenceStatistics, class_voxel_counts, frame_statistics,
                                                instance_class_pairs, instances_per_class, split_pairs)
from carlaocc.stages.report.statistics import asset_distribution, motion_share

CAR, PED, BUILDING, ROAD = (taxonomy.by_name(n).id for n in ("Car", "Pedestrian", "Building", "Road"))


def _scene():
    """6x5x4 grid: road slab, a building (id 3), two cars (ids 7, 8), a pedestrian (id 9)."""
    sem = np.zeros((6, 5, 4), np.uint8)
    inst = np.zeros((6, 5, 4), np.uint32)
    sem[:, :, 0] = ROAD  # 30 road voxels
    sem[0:2, 0:2, 1:4] = BUILDING  # 12
    inst[0:2, 0:2, 1:4] = 3
    sem[3, 0:2, 1] = CAR  # 2
    inst[3, 0:2, 1] = 7
    sem[5, 4, 1:3] = CAR  # 2
    inst[5, 4, 1:3] = 8
    sem[4, 3, 1] = PED  # 1
    inst[4, 3, 1] = 9
    return sem, inst


def test_class_voxel_counts_by_hand():
    sem, _ = _scene()
    counts = class_voxel_counts(sem)
    assert counts.shape == (N_CLASSES,) and counts.dtype == np.int64
    expected = np.zeros(N_CLASSES, np.int64)
    expected[[ROAD, BUILDING, CAR, PED]] = [30, 12, 4, 1]
    expected[0] = sem.size - 47
    np.testing.assert_array_equal(counts, expected)
    # other integer dtypes and stacked frames count the same
    np.testing.assert_array_equal(class_voxel_counts(sem.astype(np.int32)), counts)
    np.testing.assert_array_equal(class_voxel_counts(np.stack([sem, sem])), 2 * counts)
    assert class_voxel_counts(np.zeros((0, 3), np.uint8)).sum() == 0


@pytest.mark.parametrize("bad, match", [
    (np.full((2, 2), 30, np.uint8), "class id 30"),
    (np.full((2, 2), -1, np.int16), "class id -1"),
    (np.zeros((2, 2), np.float32), "dtype float32"),
])  # fmt: skip
def test_class_voxel_counts_refuses_bad_grids(bad, match):
    with pytest.raises(ValueError, match=match):
        class_voxel_counts(bad)


def test_instance_pairs_and_sequence_statistics_by_hand():
    sem, inst = _scene()
    ids, cls = split_pairs(instance_class_pairs(sem, inst))
    assert ids.tolist() == [3, 7, 8, 9] and cls.tolist() == [BUILDING, CAR, CAR, PED]
    # frame 2: car 7 moved, car 8 left the grid, a new car 11 came in
    sem2, inst2 = sem.copy(), inst.copy()
    sem2[3, 0:2, 1], inst2[3, 0:2, 1] = 0, 0
    sem2[2, 3, 1], inst2[2, 3, 1] = CAR, 7
    sem2[5, 4, 1:3], inst2[5, 4, 1:3] = 0, 0
    sem2[1, 4, 1], inst2[1, 4, 1] = CAR, 11
    stats = SequenceStatistics()
    stats.add(sem, inst)
    stats.add(sem2, inst2)
    assert stats.frames == 2
    assert stats.voxels[CAR] == 4 + 2 and stats.voxels[ROAD] == 60
    n = stats.instances()
    assert (n[CAR], n[BUILDING], n[PED], n[ROAD]) == (3, 1, 1, 0)  # cars 7, 8, 11 once each
    moving = stats.instances(only_ids=[7, 11, 9, 999])
    assert (moving[CAR], moving[PED], moving[BUILDING]) == (2, 1, 0)
    # voxels only (no instance grid)
    only = SequenceStatistics()
    only.add(sem)
    assert only.instances().sum() == 0 and only.voxels[BUILDING] == 12


def test_an_id_with_two_classes_counts_in_each():
    sem = np.array([[[CAR, PED]]], np.uint8)
    inst = np.array([[[5, 5]]], np.uint32)
    n = instances_per_class(instance_class_pairs(sem, inst))
    assert n[CAR] == 1 and n[PED] == 1


def _reference(sem, inst):
    # instances of occupied voxels (an id on a free voxel breaks the contract and is not counted)
    m = (inst.reshape(-1) > 0) & (sem.reshape(-1) > 0)
    keys = (inst.reshape(-1)[m].astype(np.uint64) << np.uint64(8)) | sem.reshape(-1)[m].astype(np.uint64)
    return np.bincount(sem.reshape(-1), minlength=N_CLASSES), np.unique(keys)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 40), st.sampled_from([3, 300, 2**31]))
def test_frame_statistics_matches_brute_force(seed, n, top):
    rng = np.random.default_rng(seed)
    shape = (n, 7, 5)
    sem = rng.integers(0, N_CLASSES, shape).astype(np.uint8)
    inst = np.where(rng.random(shape) < 0.4, rng.integers(1, top + 1, shape), 0).astype(np.uint32)
    counts, pairs = frame_statistics(sem, inst)
    ref_counts, ref_pairs = _reference(sem, inst)
    np.testing.assert_array_equal(counts, ref_counts)
    np.testing.assert_array_equal(pairs, ref_pairs)


def test_frame_statistics_beyond_one_key_buffer():
    """More runs of distinct ids than the kernel's key buffer holds (65 536): several buffers."""
    n = 300_000
    sem = np.full((n, 1, 1), CAR, np.uint8)
    inst = (np.arange(n, dtype=np.uint32) % 100_000 + 1).reshape(n, 1, 1)
    sem[::7] = PED
    counts, pairs = frame_statistics(sem, inst)
    ref_counts, ref_pairs = _reference(sem, inst)
    np.testing.assert_array_equal(counts, ref_counts)
    np.testing.assert_array_equal(pairs, ref_pairs)


def test_frame_statistics_refuses_mismatched_grids():
    with pytest.raises(ValueError, match="instance grid shape"):
        frame_statistics(np.zeros((2, 2, 2), np.uint8), np.zeros((2, 2, 3), np.uint32))
    with pytest.raises(ValueError, match="negative id"):
        frame_statistics(np.zeros((1, 1, 2), np.uint8), np.array([[[0, -3]]], np.int32))
    with pytest.raises(ValueError, match="class id 40"):
        frame_statistics(np.array([[[40]]], np.uint8), np.array([[[1]]], np.uint32))


def _count(source: str, category_id: int, category: str, assets: int) -> AssetStatisticsRecord:
    return AssetStatisticsRecord(source=source, category_id=category_id, category=category, assets=assets)


def test_asset_distribution(make_asset):
    assets = [make_asset("a", "procedural", "Car"), make_asset("b", "procedural", "Car"), make_asset("c", "folder", "Car"),
              make_asset("d", "procedural", "Building"), make_asset("e", "objaverse", "Pedestrian")]
    rows = asset_distribution(assets)
    # by class id, then source
    assert rows == [_count("procedural", BUILDING, "Building", 1), _count("objaverse", PED, "Pedestrian", 1),
                    _count("folder", CAR, "Car", 1), _count("procedural", CAR, "Car", 2)]
    assert asset_distribution([]) == []


def test_motion_share():
    voxels = np.zeros(N_CLASSES, np.int64)
    voxels[[0, ROAD, BUILDING, CAR, PED]] = [1000, 50, 30, 15, 5]
    inst = np.zeros(N_CLASSES, np.int64)
    inst[[BUILDING, CAR, PED]] = [4, 6, 2]
    moving = np.zeros(N_CLASSES, np.int64)
    moving[[CAR, PED]] = [5, 2]
    share = motion_share(voxels, inst, moving)
    assert share.dynamic_voxels == 20 and share.static_voxels == 80  # free space is no class
    assert share.static_instances[BUILDING] == 4 and share.static_instances[CAR] == 1
    assert share.moving_fraction == pytest.approx(7 / 12)
    moving[BUILDING] = 5
    with pytest.raises(ValueError, match="Building: 5 moving instances > 4"):
        motion_share(voxels, inst, moving)
    with pytest.raises(ValueError, match="shape"):
        motion_share(voxels[:5], inst, moving)


# -- plots ----------------------------------------------------------------------------------------
def _png_size(data: bytes) -> tuple[int, int]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _counts():
    voxels = np.zeros(N_CLASSES, np.int64)
    voxels[[0, ROAD, BUILDING, CAR, PED, 9]] = [10**7, 2 * 10**5, 5 * 10**5, 4000, 120, 30000]
    inst = np.zeros(N_CLASSES, np.int64)
    inst[[BUILDING, CAR, PED]] = [40, 25, 6]
    moving = np.zeros(N_CLASSES, np.int64)
    moving[[CAR, PED]] = [12, 6]
    return voxels, inst, moving


def test_plots_are_pngs_of_sensible_size():
    voxels, inst, moving = _counts()
    quality = [QualityRecord(sequence_id=f"town00_seq{i}", voxel_size=r, frame_index=None, metric=m, value=v,
                             occupied=10, isolated=0)
               for i in range(3) for r in (0.2, 0.4)
               for m, v in (("spatial_continuity", 0.995 - 0.001 * i), ("temporal_consistency", 0.97 + 0.01 * i))]
    quality.append(QualityRecord(sequence_id="x", voxel_size=0.2, frame_index=3, metric="spatial_continuity",
                                 value=0.5, occupied=1, isolated=0))  # frame rows are not drawn
    figures = {
        "voxels": plots.class_voxel_plot(voxels),
        "instances": plots.instances_plot(inst, moving),
        "assets": plots.asset_plot([_count("procedural", CAR, "Car", 30), _count("folder", CAR, "Car", 3),
                                    _count("procedural", BUILDING, "Building", 12)]),
        "motion": plots.motion_plot(motion_share(voxels, inst, moving)),
        "quality": plots.quality_plot(quality),
    }
    for name, data in figures.items():
        w, h = _png_size(data)
        assert 400 <= w <= 3000 and 250 <= h <= 3000, (name, w, h)
    # two metrics: two panels, taller than one
    one = plots.quality_plot([q for q in quality if q.metric == "spatial_continuity"])
    assert _png_size(figures["quality"])[1] > _png_size(one)[1]
    # deterministic bytes
    assert plots.class_voxel_plot(voxels) == figures["voxels"]


def test_plots_of_nothing_still_draw():
    zero = np.zeros(N_CLASSES, np.int64)
    for data in (plots.class_voxel_plot(zero), plots.instances_plot(zero), plots.asset_plot([]),
                 plots.quality_plot([]), plots.motion_plot(motion_share(zero, zero, zero))):
        _png_size(data)


def test_plots_refuse_bad_counts():
    with pytest.raises(ValueError, match="one count per class"):
        plots.class_voxel_plot(np.ones(5))
    with pytest.raises(ValueError, match="negative"):
        plots.instances_plot(-np.ones(N_CLASSES))


def test_score_axes_say_where_they_start():
    from matplotlib.collections import LineCollection

    # scores close to 1: the axis is zoomed and its label says so
    bottom, top, label = plots.score_axis([0.995, 0.997, 0.999])
    assert 0.9 < bottom < 0.995 and top > 0.999 and label == f"score (axis from {bottom:.3f}, not 0)"
    # spread scores: the axis starts at 0
    assert plots.score_axis([0.2, 0.9]) == (0.0, pytest.approx(1.075), "score")
    rows = [QualityRecord(sequence_id=f"s{i}", voxel_size=0.2, frame_index=None, metric="spatial_continuity",
                          value=v, occupied=10, isolated=0) for i, v in enumerate((0.995, 0.998))]
    (ax,) = plots.quality_figure(rows).axes
    assert ax.get_ylim()[0] == pytest.approx(bottom := plots.score_axis([0.995, 0.998])[0])
    assert ax.get_ylabel() == f"score (axis from {bottom:.3f}, not 0)"
    # a zoomed axis draws dots on stems, not bars whose length would not be the score
    assert not ax.patches and any(isinstance(c, LineCollection) for c in ax.collections)
    low = [r.model_copy(update={"value": v}) for r, v in zip(rows, (0.3, 0.9))]
    (ax,) = plots.quality_figure(low).axes
    assert ax.get_ylim()[0] == 0.0 and ax.get_ylabel() == "score" and len(ax.patches) == 2
