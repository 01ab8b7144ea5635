"""The report stage on a tiny synthetic store: statistics (the quality stage's per-frame counts
summed by the aggregate stage) against hand counts, the plots, a self-contained report page, its
partition's needs, and the lineage and size sections."""

from __future__ import annotations

import base64
import json
import re
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.occupancy import OccupancyStore
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.catalog.usage import store_usage
from carlaocc.pipeline.engine.spec import Context, Partition
from carlaocc.pipeline.tasks.report import PLOTS_DIR, REPORT_HTML, report_task
from carlaocc.pipeline.tasks.report_page import SECTIONS, stage_lineage
from carlaocc.pipeline.engine.registry import STAGES
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import DatasetConfig, QualityConfig
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, ClassStatisticsRecord, FrameRecord, QualityRecord,
                                      RunRecord, SequenceRecord)

CAR, BUILDING, ROAD = (taxonomy.by_name(n).id for n in ("Car", "Building", "Road"))
GRID = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(6.4, 6.4, 1.6), voxel_size=0.4)  # 16 x 16 x 4
SEQS = ("town00_low_seq000", "town00_high_seq000")
FRAMES = 3
POSE = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
T0 = datetime(2025, 1, 2, 3, 4, 5, tzinfo=timezone.utc)


def _frame(t: int, seq_index: int) -> tuple[np.ndarray, np.ndarray]:
    """Road slab (256 voxels), building id 1 (2x2x3 = 12 voxels), parked car id 2 (2 voxels) and
    a moving car id 10 (2 voxels) one voxel further each frame; sequence 1 has no parked car."""
    sem = np.zeros(GRID.shape, np.uint8)
    inst = np.zeros(GRID.shape, np.uint32)
    sem[:, :, 0] = ROAD
    sem[0:2, 0:2, 1:4], inst[0:2, 0:2, 1:4] = BUILDING, 1
    if seq_index == 0:
        sem[5, 5:7, 1], inst[5, 5:7, 1] = CAR, 2
    sem[8 + t, 10:12, 1], inst[8 + t, 10:12, 1] = CAR, 10
    return sem, inst


def _run(stage: str, partition: str, outputs: dict, inputs: dict | None = None, run_id: str = "20250102T030405Z-abc",
         status: str = "completed") -> RunRecord:
    return RunRecord(run_id=run_id, stage=stage, partition=partition, code_version="c0de", config_hash="cf6",
                     cache_key="k", input_fingerprints=json.dumps(inputs or {}),
                     output_fingerprints=json.dumps(outputs),
                     status=status, started_at=T0, ended_at=T0 + timedelta(seconds=2), host="h")


@pytest.fixture
def small(store: Store, make_asset) -> Store:
    occ = OccupancyStore(store)
    for i, s in enumerate(SEQS):
        ParquetTable(store, SequenceRecord).save(s, [SequenceRecord(
            sequence_id=s, town="town00", seed=1, frame_count=FRAMES, rate_hz=10.0,
            traffic_level="low" if i == 0 else "high", ego_asset_id="ego")])
    actors = ParquetTable(store, ActorStateRecord)
    for i, seq in enumerate(SEQS):
        occ.create(seq, GRID, FRAMES, 6)  # 16 = 6 + 6 + 4: padded edge chunks
        for t in range(FRAMES):
            sem, inst = _frame(t, i)
            occ.write_frame(seq, GRID, t, {"semantic": sem, "instance": inst})
        ParquetTable(store, FrameRecord).save(seq, [FrameRecord(sequence_id=seq, frame_index=t, timestamp=0.1 * t,
                                                                ego_pose=POSE, lidar_pose=POSE) for t in range(FRAMES)])
        actors.save(seq, [ActorStateRecord(sequence_id=seq, frame_index=t, instance_id=10, asset_id="car",
                                           semantic_id=CAR, pose=POSE, box_center=[0.0, 0.0, 0.0],
                                           box_size=[4.0, 2.0, 1.5], yaw=0.0, velocity=[1.0, 0.0, 0.0],
                                           angular_velocity=[0.0, 0.0, 0.0]) for t in range(FRAMES)])
    ParquetTable(store, AssetRecord).save("source=procedural/procedural", [
        make_asset("a", "procedural", "Car"), make_asset("b", "procedural", "Car"),
        make_asset("c", "procedural", "Building")])
    ParquetTable(store, AssetRecord).save("source=folder/f", [make_asset("d", "folder", "Car")])
    # the statistics: the quality stage's per-frame counts in two tasks a sequence (frames 0-1, 2),
    # summed by the aggregate stage
    from carlaocc.pipeline.tasks.aggregate import aggregate_task
    from carlaocc.pipeline.tasks.quality import quality_task

    for seq in SEQS:
        keys = []
        for first, stop in ((0, 2), (2, 3)):
            keys.append(f"{seq}/{GRID.key}/{first:04d}")
            quality_task(store, QualityConfig(), Partition(keys[-1], {
                "sequence_id": seq, "voxel_size": 0.4, "grid": GRID.model_dump(mode="json"), "first": first,
                "stop": stop}))
        aggregate_task(store, QualityConfig(), Partition(f"{seq}/{GRID.key}", {
            "sequence_id": seq, "voxel_size": 0.4, "voxel_size_key": GRID.key, "quality_keys": keys}))
    LineageLog(store).append("voxelize", "r1", [
        _run("voxelize", f"{s}/0.4/{t:04d}", {f"occupancy.zarr/{s}/0.4/semantic[{t}]": "sha256:aa",
                                               f"occupancy.zarr/{s}/0.4/instance[{t}]": "sha256:bb"},
             {"ingest/procedural": "x1", "scenes/town00": "x2"}) for s in SEQS for t in range(FRAMES)])
    LineageLog(store).append("quality", "r1", [
        _run("metrics", f"{s}/0.4", {f"metrics/quality/{s}/0.4.parquet": "sha256:cc"}) for s in SEQS])
    return store


def _partition() -> Partition:
    return Partition("dataset", {"grids": [GRID.model_dump(mode="json")], "sequences": list(SEQS)})


def test_report_task_writes_statistics_plots_and_page(small):
    stale = f"{PLOTS_DIR}/class_voxels_9.9.png"
    small.write_bytes(stale, b"old")
    outputs = report_task(small, QualityConfig(), _partition())
    # outputs are fingerprinted files that exist; the stale plot of another voxel size is gone
    assert REPORT_HTML in outputs and not small.exists(stale)
    for rel, fp in outputs.items():
        assert small.fingerprint(rel) == fp, rel
    plots = {rel for rel in outputs if rel.startswith(PLOTS_DIR)}
    assert plots == {f"{PLOTS_DIR}/{n}.png" for n in ("class_voxels_0.4", "instances_0.4", "motion_0.4", "assets",
                                                      "quality", "frame")}  # no cameras: no sensors sheet
    for rel in plots:
        assert small.read_bytes(rel)[:8] == b"\x89PNG\r\n\x1a\n"
    # class statistics against hand counts
    rows = {(r.sequence_id, r.semantic_id): r for r in ParquetTable(small, ClassStatisticsRecord).load()}
    a, b = SEQS
    assert rows[(a, ROAD)].voxels == FRAMES * 256 and rows[(a, ROAD)].instances == 0
    assert rows[(a, BUILDING)].voxels == FRAMES * 12 and rows[(a, BUILDING)].instances == 1
    assert (rows[(a, CAR)].voxels, rows[(a, CAR)].instances, rows[(a, CAR)].moving_instances) == (12, 2, 1)
    assert (rows[(b, CAR)].voxels, rows[(b, CAR)].instances, rows[(b, CAR)].moving_instances) == (6, 1, 1)
    assert rows[(a, 0)].voxels == FRAMES * (16 * 16 * 4) - FRAMES * (256 + 12 + 4)
    assert all(r.frames == FRAMES and r.voxel_size == 0.4 for r in rows.values())
    # queryable through the catalog views
    cols, got = query(small, "SELECT category, sum(assets) FROM statistics_assets GROUP BY 1 ORDER BY 1")
    assert got == [("Building", 1), ("Car", 3)]
    _, got = query(small, "SELECT sum(instances) FROM statistics_classes s JOIN classes c ON s.semantic_id = c.id "
                          "WHERE c.name = 'Car'")
    assert got[0][0] == 3


def test_report_page_is_self_contained(small):
    report_task(small, QualityConfig(), _partition())
    page = small.read_bytes(REPORT_HTML).decode()
    # nothing loaded from outside the file: no remote or relative src/href/url(), no scripts
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:|//|file:)""", page, re.I)
    assert not re.search(r"""src\s*=\s*["'](?!data:)""", page, re.I)
    assert not re.search(r"""href\s*=\s*["'](?!#)""", page, re.I)
    assert "<script" not in page.lower() and "@import" not in page and "url(" not in page
    for section in SECTIONS:
        assert f'id="{section}"' in page, section
    # every plot inlined as a PNG data URI
    images = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(images) == 6
    assert all(base64.b64decode(i)[:8] == b"\x89PNG\r\n\x1a\n" for i in images)
    # the scores are the aggregate stage's sequence rows, with their worst frame
    rows = ParquetTable(small, QualityRecord).load([f"{s}/{GRID.key}" for s in SEQS])
    assert {(r.metric, r.frame_index) for r in rows} == {("spatial_continuity", None), ("temporal_consistency", None)}
    # (the arrays' visibility masks were never written: nothing observed, no temporal score)
    sc = [r for r in rows if r.metric == "spatial_continuity"]
    assert len(sc) == 2 and all(r.worst_value == 1.0 and r.worst_frame == 0 for r in sc), sc
    # the content: sizes, sequences, scores, lineage
    for text in ("occupancy.zarr", "town00_high_seq000", f"{sc[0].value:.5f}", "temporal consistency", "voxelize",
                 "c0de", "cf6", "20250102T030405Z-abc", "occupancy.zarr/semantic ×6"):
        assert text in page, text


def test_report_partition_needs_every_upstream_output(small):
    """The report reads the sequences' aggregates, not their frames: its needs are the aggregate
    partitions, the scenes and ingest partitions, and the one frame it renders (with its cameras
    once the sensors stage ran)."""
    ctx = Context(small, DatasetConfig(), (0.4,))
    assert list(STAGES)[-1] == "report" and STAGES["report"].upstream[-1] == "aggregate"
    (part,) = STAGES["report"].partitions(ctx)
    needs = set(part.needs)
    for seq in SEQS:
        assert ("aggregate", f"{seq}/0.4") in needs
    first = sorted(SEQS)[0]
    assert {n for n in needs if n[0] == "voxelize"} == {("voxelize", f"{first}/0.4/{FRAMES // 2:04d}")}
    assert not any(s == "quality" for s, _ in needs)
    assert ("scenes", "town00") in needs and ("ingest", "procedural") in needs
    assert not any(s == "sensors" for s, _ in needs)
    assert part.params["sequences"] == sorted(SEQS)
    # once the sensors stage has run, the report reads the rendered frame's cameras too
    LineageLog(small).append("sensors", "r2", [_run("sensors", f"{SEQS[0]}/0000", {})])
    (part,) = STAGES["report"].partitions(ctx)
    assert {n for n in part.needs if n[0] == "sensors"} == {("sensors", f"{first}/{FRAMES // 2:04d}")}


def test_read_tile_agrees_with_zarr(small):
    """The report's fast chunk reader returns what zarr-python reads, edge chunks and missing
    (all-zero) chunks included."""
    occ = OccupancyStore(small)
    for name in ("semantic", "instance"):
        arr = occ.open(SEQS[0], GRID, name)
        for t in range(FRAMES):
            for x0, nx in ((0, 16), (0, 6), (6, 10), (12, 4)):
                tile = occ.read_tile(SEQS[0], GRID, t, name, x0, nx)
                assert tile.dtype == arr.dtype
                np.testing.assert_array_equal(tile, arr[t, x0:x0 + nx])
    with pytest.raises(ValueError, match="whole chunks"):
        occ.read_tile(SEQS[0], GRID, 0, "semantic", 3, 6)


def test_stage_lineage_collapses_partitions():
    recs = [_run("voxelize", "s/0.4/0000", {"occupancy.zarr/s/0.4/semantic[0]": "a", "metrics/x/y.parquet": "b"},
                 {"scenes/town00": "1", "file:/x.xodr": "2"}, run_id="r1"),
            _run("voxelize", "s/0.4/0000", {"occupancy.zarr/s/0.4/semantic[0]": "c"}, {"scenes/town00": "1"},
                 run_id="r2"),
            _run("voxelize", "s/0.4/0001", {}, {}, run_id="r1", status="failed")]
    (L,) = stage_lineage(recs)
    assert (L.stage, L.partitions, L.completed, L.run_ids) == ("voxelize", 2, 1, ["r1", "r2"])
    assert L.inputs == {"scenes": 1} and L.outputs == {"occupancy.zarr/semantic": 1}
    assert L.task_seconds == pytest.approx(4.0)
    # a recorded frame's outputs: both LiDAR folders collapse to one kind each, whatever the sequence
    recs = [_run("sensors", f"{seq}/0000", {f"lidar_recorded/{seq}/000000.parquet": "a", f"lidar/{seq}/000000.parquet": "b",
                                           f"metrics/lidar_agreement/{seq}/0000.parquet": "c"}, {}, run_id="r1")
            for seq in ("s1", "s2")]  # fmt: skip
    (L,) = stage_lineage(recs)
    assert L.outputs == {"lidar_recorded": 2, "lidar": 2, "metrics/lidar_agreement": 2}


def test_store_usage_counts_parts(tmp_path):
    store = Store(str(tmp_path / "root"))
    assert store_usage(store) == []
    store.write_bytes("admesh/assets/x.parquet", b"12345")
    store.write_bytes("admesh/meshes/a.glb", b"1")
    store.write_bytes("metrics/report.html", b"123")
    store.write_bytes("notes.txt", b"12")
    (tmp_path / "root" / "admesh" / ".tmp-x").write_bytes(b"999")
    usage = {u.part: (u.files, u.bytes) for u in store_usage(store, exclude=("metrics/report.html",))}
    assert usage == {"admesh": (2, 6), "other": (1, 2)}


def test_lineage_is_a_readable_table_with_hashes_folded(small):
    from carlaocc.pipeline.tasks.report_page import render_html

    recs = [_run("voxelize", f"s/0.4/{t:04d}", {f"occupancy.zarr/s/0.4/semantic[{t}]": "x"}, {"scenes/s": "y"})
            for t in range(3)]
    recs = [r.model_copy(update={"code_version": "0123456789abcdef" * 4}) for r in recs]
    recs[2] = recs[2].model_copy(update={"status": "failed", "run_id": "20250103T000000Z-def"})
    page = render_html(root="r", sequences=[], grids=[], totals={}, asset_rows=[], quality=[], usage=[],
                       lineage=stage_lineage(recs), images={})
    section = page[page.index('id="lineage"'):]
    readable, folded = section.split("<details><summary>hashes", 1)
    # stage, completed partitions, when, task time, the short code version, what it read and wrote
    for text in ("<th>stage</th>", "<th>completed</th>", "<th>finished (UTC)</th>", "<th>code</th>",
                 "<b>voxelize</b>", "2 of 3", "2025-01-02 03:04:07", "6.0 s", "<code>01234567</code>",
                 "scenes ×3", "occupancy.zarr/semantic ×3"):
        assert text in readable, text
    # the hashes and run ids only inside the folded element
    assert "0123456789abcdef" not in readable and "20250102T030405Z-abc" not in readable and "cf6" not in readable
    assert "0123456789abcdef" * 4 in folded and "20250103T000000Z-def" in folded and "cf6" in folded
    assert folded.index("</details>") > folded.index("cf6")


def test_report_cameras_are_named_from_the_recorded_poses(small):
    from carlaocc.catalog.sensors import SensorStore
    from carlaocc.pipeline.tasks.report import recorded_camera_roles
    from carlaocc.schemas.records import SensorPoseRecord
    from carlaocc.schemas.rig import RigConfig, camera_roles
    from carlaocc.stages.geometry import invert_pose

    rig = RigConfig()
    seq = min(SEQS)  # the sequence the report renders
    # the ego moved and turned: the world poses differ from the rig's, the roles must not
    world = np.array([[0.0, -1.0, 0.0, 5.0], [1.0, 0.0, 0.0, -3.0], [0.0, 0.0, 1.0, 0.2], [0, 0, 0, 1.0]])
    lidar_world = world @ np.array(rig.lidar.sensor_to_ego())
    frames = [FrameRecord(sequence_id=seq, frame_index=t, timestamp=0.1 * t, ego_pose=world.ravel().tolist(),
                          lidar_pose=lidar_world.ravel().tolist()) for t in range(FRAMES)]
    ParquetTable(small, FrameRecord).save(seq, frames)
    ParquetTable(small, SensorPoseRecord).save(seq, [
        SensorPoseRecord(sequence_id=seq, frame_index=t, sensor=c.name,
                         pose=(world @ np.array(c.camera_to_ego())).ravel().tolist())
        for t in range(FRAMES) for c in rig.cameras])
    sensors = SensorStore(small)
    for c in rig.cameras[:2]:
        sensors.create(seq, c.name, 8, 4, FRAMES, ("depth", "semantic", "instance", "normal", "rgb"))
        for t in range(FRAMES):
            sensors.write_image(seq, c.name, t, "depth", np.full((4, 8), 5.0, np.float32))
            sensors.write_image(seq, c.name, t, "semantic", np.full((4, 8), 7, np.uint8))
            sensors.write_image(seq, c.name, t, "instance", np.zeros((4, 8), np.uint32))
            sensors.write_image(seq, c.name, t, "normal", np.zeros((4, 8, 3), np.float32))
            sensors.write_image(seq, c.name, t, "rgb", np.full((4, 8, 3), 99, np.uint8))
    roles = recorded_camera_roles(small, seq, 1)
    assert roles == {n: r for n, r in camera_roles(rig.cameras[:2]).items()}
    assert roles["camera_00"] == "front, stereo left (with camera_01)"
    # (the sheet itself, RGB row first: tests/stages/test_render.py; the page: tests/test_end_to_end.py)
