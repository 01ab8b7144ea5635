"""Every persisted model round-trips through Parquet (local and memory stores)."""

from datetime import datetime, timezone

import pytest
from pydantic import ValidationError

from carlaocc.catalog.parquet import ParquetTable, arrow_schema, from_table, to_table
from carlaocc.schemas import records as R

POSE = [1.0, 0, 0, 2.5, 0, 1.0, 0, -3.25, 0, 0, 1.0, 0.0, 0, 0, 0, 1.0]
T0 = datetime(2026, 1, 2, 3, 4, 5, 678000, tzinfo=timezone.utc)

SAMPLES: dict[type[R.Record], list[R.Record]] = {
    R.AssetRecord: [R.AssetRecord(asset_id="a1b2", source="procedural", source_path="procedural://car/sedan/0",
                                  licence="CC0-1.0", category_id=14, category="Car", subclass="sedan",
                                  extent=[4.6, 1.9, 1.45], vertex_count=410, face_count=812, part_count=2,
                                  transparent_part_count=1, surface_area=31.5, volume=9.25, watertight=True,
                                  scale_applied=0.01, scale_rule="declared units: cm",
                                  geometry_hash="abc123", aliases=["x/dup.obj", "y/dup2.obj"],
                                  mesh_path="admesh/meshes/a1b2.glb"),
                    R.AssetRecord(asset_id="open1", source="folder", source_path="/m/sign.glb", licence="CC0-1.0",
                                  category_id=8, category="TrafficSign", subclass="stop", extent=[0.1, 0.8, 2.5],
                                  vertex_count=30, face_count=40, part_count=1, transparent_part_count=0,
                                  surface_area=2.0, volume=None, watertight=False, geometry_hash="def",
                                  mesh_path="admesh/meshes/open1.glb")],
    R.PartRecord: [R.PartRecord(asset_id="a1b2", part_index=i, name=n, material=m, transparent=t,
                                semantic_id=14, face_count=12, watertight=True, texture="Textures/metal.png")
                   for i, (n, m, t) in enumerate([("body", "paint", False), ("windows", "glass", True)])],
    R.QuarantineRecord: [R.QuarantineRecord(stage="ingest", source="folder", source_path="/x/broken.obj",
                                            reason="NaN vertices", hint="re-export the mesh")],
    R.PlacementRecord: [R.PlacementRecord(town="town00", placement_id=3, name="building_003", asset_id="b1",
                                          mesh_path="admesh/meshes/b1.glb", semantic_id=3, instance_id=7,
                                          pose=POSE, is_thing=True, aabb_min=[1.0, -6.0, 0.15],
                                          aabb_max=[13.0, 2.5, 21.0])],
    R.TownRecord: [R.TownRecord(town="town01", style="opendrive", source="builtin:crossroads.xodr", seed=11,
                                road_length=812.5, lane_count=40, junction_count=2, walkway_length=900.0,
                                crosswalk_count=8, placement_count=120, bounds=[-100.0, -80.0, 100.0, 90.5])],
    R.SequenceRecord: [R.SequenceRecord(sequence_id="town00_seq000", town="town00", seed=1, frame_count=20,
                                        rate_hz=20.0, traffic_level="medium", ego_asset_id="a1b2"),
                       R.SequenceRecord(sequence_id="town00_seq000~swap-car-s3", town="town00", seed=1,
                                        frame_count=20, rate_hz=20.0, traffic_level="medium",
                                        ego_asset_id="a1b2", parent_sequence_id="town00_seq000",
                                        edit="swap Car seed=3")],
    R.SensorPoseRecord: [R.SensorPoseRecord(sequence_id="s", frame_index=1, sensor=n, pose=POSE)
                         for n in ("camera_00", "lidar")],
    R.FrameRecord: [R.FrameRecord(sequence_id="s", frame_index=i, timestamp=i / 20, ego_pose=POSE,
                                  lidar_pose=POSE) for i in range(3)],
    R.ActorStateRecord: [
        R.ActorStateRecord(sequence_id="s", frame_index=0, instance_id=101, asset_id="a1b2", semantic_id=14,
                           pose=POSE, box_center=[1, 2, 0.7], box_size=[4.6, 1.9, 1.45], yaw=0.3,
                           velocity=[5.0, 0.1, 0.0], angular_velocity=[0.0, 0.0, 0.2], gait_phase=None),
        R.ActorStateRecord(sequence_id="s", frame_index=0, instance_id=102, asset_id="p1", semantic_id=12,
                           pose=POSE, box_center=[1, 2, 0.9], box_size=[0.5, 0.5, 1.8], yaw=-1.0,
                           velocity=[1.2, 0.0, 0.0], angular_velocity=[0.0, 0.0, 0.0], gait_phase=0.25,
                           phase_index=8, scale=0.8889),
    ],
    R.SkeletonRecord: [
        R.SkeletonRecord(sequence_id="s", frame_index=0, instance_id=102, asset_id="p1", joint_index=0, joint="pelvis",
                         world=[10.0, 2.0, 0.95], lidar=[3.5, -1.25, -0.8]),
        R.SkeletonRecord(sequence_id="s", frame_index=0, instance_id=102, asset_id="p1", joint_index=10,
                         joint="r_hand", world=[10.2, 1.7, 0.8], lidar=[3.7, -1.55, -0.95]),
    ],
    R.EgoStateRecord: [
        R.EgoStateRecord(sequence_id="s", frame_index=0, velocity=[5.0, 0.05, 0.0], acceleration=[0.1, 0.0, -0.02]),
        R.EgoStateRecord(sequence_id="s", frame_index=1, velocity=[5.1, 0.05, 0.0], acceleration=[0.0, 0.0, 0.0]),
    ],
    R.QualityRecord: [
        R.QualityRecord(sequence_id="s", voxel_size=0.2, frame_index=0, metric="spatial_continuity",
                        value=0.99, occupied=100, isolated=1),
        R.QualityRecord(sequence_id="s", voxel_size=0.2, frame_index=None, metric="spatial_continuity",
                        value=float("nan"), occupied=0, isolated=0),
        R.QualityRecord(sequence_id="s", voxel_size=0.2, frame_index=3, metric="temporal_consistency",
                        value=0.75, numerator=3, denominator=4),
        R.QualityRecord(sequence_id="s", voxel_size=0.2, frame_index=None, metric="temporal_consistency",
                        value=0.8, numerator=8, denominator=10, worst_value=0.75, worst_frame=3),
    ],
    R.ClassQualityRecord: [R.ClassQualityRecord(sequence_id="s", voxel_size=0.05, frame_index=2,
                                                semantic_id=14, occupied=55, isolated=0)],
    R.RectificationRecord: [
        R.RectificationRecord(sequence_id="s", frame_index=3, camera="camera_00", source="raycast", pixels=529408,
                              transparency=120, omission=7, relabelled=100, depth_changed=121,
                              raw_semantic_wrong=110, semantic_mismatch=0, instance_mismatch=0, depth_mismatch=0),
        R.RectificationRecord(sequence_id="s", frame_index=4, camera="camera_01", source="recorded", pixels=10,
                              transparency=0, omission=0, relabelled=0, depth_changed=0, raw_semantic_wrong=-1,
                              semantic_mismatch=-1, instance_mismatch=-1, depth_mismatch=-1),
    ],
    R.LidarAgreementRecord: [
        R.LidarAgreementRecord(sequence_id="s", frame_index=3, points=5760, static_points=5000, missed=2,
                               median_m=0.0001, p95_m=0.02, within=0.998, tolerance_m=0.1),
        R.LidarAgreementRecord(sequence_id="s", frame_index=4, points=0, static_points=0, missed=0, median_m=-1.0,
                               p95_m=-1.0, within=0.0, tolerance_m=0.1),
    ],
    R.FrameStatisticsRecord: [R.FrameStatisticsRecord(sequence_id="s", voxel_size=0.05, frame_index=3, semantic_id=14,
                                                      voxels=2345, instance_ids=[7, 12, 4294967295]),
                              R.FrameStatisticsRecord(sequence_id="s", voxel_size=0.05, frame_index=3, semantic_id=0,
                                                      voxels=10**9, instance_ids=[])],
    R.ClassStatisticsRecord: [R.ClassStatisticsRecord(sequence_id="s", voxel_size=0.2, semantic_id=14, frames=20,
                                                      voxels=12345, instances=9, moving_instances=4)],
    R.AssetStatisticsRecord: [R.AssetStatisticsRecord(source="procedural", category_id=14, category="Car", assets=33)],
    R.RunRecord: [R.RunRecord(run_id="r1", stage="voxelize", partition="s/0.2/0001", code_version="c",
                              config_hash="h", cache_key="k", input_fingerprints="{}",
                              output_fingerprints='{"x": "sha256:1"}', status="failed", started_at=T0,
                              ended_at=T0, host="h", error="ValueError: boom")],
}


def test_every_persisted_model_has_samples():
    subclasses = {c for c in vars(R).values() if isinstance(c, type) and issubclass(c, R.Record) and c is not R.Record}
    assert subclasses == set(R.PERSISTED) == set(SAMPLES)
    assert len({m.TABLE for m in R.PERSISTED}) == len(R.PERSISTED)


def _same(a: R.Record, b: R.Record) -> bool:
    # NaN != NaN: compare through JSON dumps, where NaN is spelled the same
    return a.model_dump_json() == b.model_dump_json()


@pytest.mark.parametrize("model", list(SAMPLES), ids=lambda m: m.__name__)
def test_round_trip_through_parquet(store, model):
    table = ParquetTable(store, model)
    fp = table.save("part/k1", SAMPLES[model])
    assert fp.startswith("sha256:")
    assert table.exists("part/k1")
    back = table.load()
    assert len(back) == len(SAMPLES[model])
    assert all(_same(a, b) for a, b in zip(SAMPLES[model], back))
    assert table.load_arrow().schema.equals(arrow_schema(model), check_metadata=False)


@pytest.mark.parametrize("model", list(SAMPLES), ids=lambda m: m.__name__)
def test_empty_table_keeps_schema(store, model):
    t = ParquetTable(store, model).load_arrow()
    assert t.num_rows == 0 and t.schema.names == list(model.model_fields)


def test_arrow_round_trip_in_memory():
    rows = SAMPLES[R.ActorStateRecord]
    assert from_table(R.ActorStateRecord, to_table(R.ActorStateRecord, rows)) == rows


def test_records_validate_poses_and_vectors():
    with pytest.raises(ValidationError, match="16 floats"):
        R.PlacementRecord(town="t", placement_id=0, name="x", asset_id="a", mesh_path="m", semantic_id=1,
                          instance_id=0, pose=[1.0] * 12)
    with pytest.raises(ValidationError, match="finite"):
        R.FrameRecord(sequence_id="s", frame_index=0, timestamp=0.0, ego_pose=[float("nan")] * 16, lidar_pose=POSE)
    with pytest.raises(ValidationError, match="3 components"):
        R.AssetRecord(**{**SAMPLES[R.AssetRecord][0].model_dump(), "extent": [1.0, 2.0]})
