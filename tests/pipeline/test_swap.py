"""Parametric editing: ``scenes swap`` writes a new sequence whose actors of one class use other
assets of a compatible footprint, everything else unchanged, with lineage to the original."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from carlaocc.catalog.lineage import LineageLog
from carlaocc.catalog.parquet import ParquetTable
from carlaocc.catalog.store import Store, StoreError
from carlaocc.pipeline.cli import app
from carlaocc.pipeline.commands.scene_editing import SWAP_STAGE, compatible, swap_class
from carlaocc.schemas.records import (ActorStateRecord, AssetRecord, EgoStateRecord, FrameRecord, SensorPoseRecord,
                                      SequenceRecord)
from carlaocc.stages.geometry import pose_matrix, pose_to_list

POSE = [1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
cli = CliRunner()


def _asset(aid: str, category: str, cid: int, extent) -> AssetRecord:
    return AssetRecord(asset_id=aid, source="procedural", source_path=f"procedural://{aid}", licence="CC0-1.0",
                       category_id=cid, category=category, subclass="x", extent=list(extent), vertex_count=8,
                       face_count=12, part_count=1, transparent_part_count=0, surface_area=1.0, volume=1.0,
                       watertight=True, geometry_hash=aid, mesh_path=f"admesh/meshes/{aid}.glb")


ASSETS = [
    _asset("car_a", "Car", 14, (4.5, 1.8, 1.5)),
    _asset("car_b", "Car", 14, (4.7, 1.85, 1.45)),
    _asset("car_c", "Car", 14, (4.3, 1.75, 1.6)),
    _asset("car_long", "Car", 14, (6.5, 2.0, 1.9)),  # a limousine: not compatible with car_a
    _asset("ped", "Pedestrian", 12, (0.5, 0.6, 1.75)),
]


def _actor(f: int, inst: int, asset: AssetRecord, x: float) -> ActorStateRecord:
    l, w, h = asset.extent
    pose = pose_to_list(pose_matrix(x, 0.0, 0.0, 0.0))
    return ActorStateRecord(sequence_id="town00_low_seq000", frame_index=f, instance_id=inst, asset_id=asset.asset_id,
                            semantic_id=asset.category_id, pose=pose, box_center=[x, 0.0, h / 2], box_size=[l, w, h],
                            yaw=0.0, velocity=[5.0, 0, 0], angular_velocity=[0, 0, 0.1])


@pytest.fixture
def store(tmp_path):
    store = Store(str(tmp_path / "data"))
    ParquetTable(store, AssetRecord).save("source=procedural/procedural", ASSETS)
    sid = "town00_low_seq000"
    ParquetTable(store, SequenceRecord).save(sid, [SequenceRecord(
        sequence_id=sid, town="town00", seed=5, frame_count=2, rate_hz=20.0, traffic_level="low",
        ego_asset_id="car_a")])
    ParquetTable(store, FrameRecord).save(sid, [FrameRecord(sequence_id=sid, frame_index=f, timestamp=f / 20,
                                                            ego_pose=POSE, lidar_pose=POSE) for f in range(2)])
    ParquetTable(store, SensorPoseRecord).save(sid, [SensorPoseRecord(sequence_id=sid, frame_index=f, sensor="lidar",
                                                                      pose=POSE) for f in range(2)])
    ParquetTable(store, ActorStateRecord).save(sid, [
        _actor(f, inst, a, 10.0 * inst + f) for f in range(2)
        for inst, a in ((101, ASSETS[0]), (102, ASSETS[1]), (103, ASSETS[3]), (104, ASSETS[4]))])
    return store


def test_compatible_keeps_the_footprint():
    names = [a.asset_id for a in compatible(ASSETS[0], ASSETS)]
    assert names == ["car_b", "car_c"]  # not itself, not the limousine, not the pedestrian
    assert compatible(ASSETS[3], ASSETS) == []


def test_swap_writes_a_child_sequence_with_lineage(store):
    (res,) = swap_class(store, "Car", seed=3)
    new = "town00_low_seq000~swap-car-s3"
    assert res.sequence_id == new and res.parent == "town00_low_seq000"
    assert (res.swapped, res.kept) == (2, 1)  # the limousine has no compatible asset
    (seq,) = ParquetTable(store, SequenceRecord).load([new])
    assert seq.parent_sequence_id == "town00_low_seq000" and seq.edit == "swap Car seed=3"
    old = {(a.frame_index, a.instance_id): a for a in ParquetTable(store, ActorStateRecord).load(["town00_low_seq000"])}
    got = {(a.frame_index, a.instance_id): a for a in ParquetTable(store, ActorStateRecord).load([new])}
    assert got.keys() == old.keys()
    for key, a in got.items():
        o = old[key]
        # trajectories and timing unchanged; cars 101/102 got another compatible car
        assert a.pose == o.pose and a.velocity == o.velocity and a.box_center[:2] == o.box_center[:2]
        if key[1] in (101, 102):
            assert a.asset_id != o.asset_id and a.asset_id in {"car_a", "car_b", "car_c"}
            ext = next(x.extent for x in ASSETS if x.asset_id == a.asset_id)
            assert a.box_size == ext and a.box_center[2] == pytest.approx(ext[2] / 2)
        else:
            assert a.asset_id == o.asset_id
    # the same instance keeps its replacement in every frame
    assert got[(0, 101)].asset_id == got[(1, 101)].asset_id
    assert len(ParquetTable(store, FrameRecord).load([new])) == 2
    assert len(ParquetTable(store, SensorPoseRecord).load([new])) == 2
    (run,) = LineageLog(store).load(SWAP_STAGE)
    assert run.partition == new and "scenes/actors/town00_low_seq000.parquet" in json.loads(run.input_fingerprints)
    # deterministic: the same seed gives the same assets; swapping again edits only originals
    again = swap_class(store, "Car", seed=3)
    assert [r.sequence_id for r in again] == [new]
    assert {(a.frame_index, a.instance_id): a.asset_id for a in ParquetTable(store, ActorStateRecord).load([new])} == {
        k: a.asset_id for k, a in got.items()}


def test_swap_copies_a_recorded_ego_motion(store):
    """A recorded sequence's ego velocities (``ego_states``) go with the swapped copy, named in its
    lineage; a sequence without them gets none."""
    sid, t_ego = "town00_low_seq000", ParquetTable(store, EgoStateRecord)
    rows = [EgoStateRecord(sequence_id=sid, frame_index=f, velocity=[5.0, 0.05 * f, 0.0], acceleration=[0.1, 0, 0])
            for f in range(2)]
    t_ego.save(sid, rows)
    (res,) = swap_class(store, "Car", seed=3)
    got = sorted(t_ego.load([res.sequence_id]), key=lambda r: r.frame_index)
    assert [r.model_copy(update={"sequence_id": sid}) for r in got] == rows
    assert all(r.sequence_id == res.sequence_id for r in got)
    (run,) = LineageLog(store).load(SWAP_STAGE)
    assert t_ego.path(sid) in json.loads(run.input_fingerprints)
    assert t_ego.path(res.sequence_id) in json.loads(run.output_fingerprints)


def test_swap_without_ego_states_writes_none(store):
    (res,) = swap_class(store, "Car", seed=3)
    assert not ParquetTable(store, EgoStateRecord).exists(res.sequence_id)


def test_swap_errors(store):
    with pytest.raises(StoreError, match="unknown class"):
        swap_class(store, "Spaceship", 1)
    # nothing of the class to swap: a clear error, and no file written
    with pytest.raises(StoreError, match="nothing to swap.*Road.*nothing written"):
        swap_class(store, "Road", 1)
    with pytest.raises(StoreError, match="nothing to swap"):
        swap_class(store, "Bus", 1)
    assert [s.sequence_id for s in ParquetTable(store, SequenceRecord).load()] == ["town00_low_seq000"]
    with pytest.raises(StoreError, match="not in"):
        swap_class(store, "Car", 1, ["nope"])


def test_swap_cli(store):
    r = cli.invoke(app, ["scenes", "swap", "--class", "Car", "--seed", "4", "--root", store.url])
    assert r.exit_code == 0, r.output
    assert "~swap-car-s4: 2 Car actor(s) and 0 static placement(s) swapped, 1 kept" in r.output
    r = cli.invoke(app, ["scenes", "swap", "--class", "Tree", "--seed", "4", "--root", store.url])
    assert r.exit_code == 2 and "unknown class" in r.output


def test_static_swap_writes_its_own_placements(store):
    """Static objects (buildings) are placements, not actors: a swap writes the edited sequence's
    own copy of the town's placements with the swapped assets on the same lots (same pose, AABB of
    the new box); the town's placements are untouched."""
    from carlaocc.schemas.records import PlacementRecord

    houses = [_asset("house_a", "Building", 3, (10.0, 8.0, 6.0)), _asset("house_b", "Building", 3, (10.5, 8.4, 6.5)),
              _asset("tower", "Building", 3, (12.0, 12.0, 40.0))]
    ParquetTable(store, AssetRecord).save("source=procedural/procedural", ASSETS + houses)
    pose = [1.0, 0, 0, 20.0, 0, 1.0, 0, 5.0, 0, 0, 1.0, 0, 0, 0, 0, 1.0]
    town = [PlacementRecord(town="town00", placement_id=i, name=n, asset_id=a, mesh_path="", semantic_id=3,
                            instance_id=i + 1, pose=pose, is_thing=True, aabb_min=[0, 0, 0], aabb_max=[1, 1, 1])
            for i, (n, a) in enumerate((("building_000", "house_a"), ("building_001", "tower")))]
    t_place = ParquetTable(store, PlacementRecord)
    t_place.save("town=town00", town)
    (r,) = swap_class(store, "Building", 2)
    assert (r.swapped, r.swapped_static, r.kept_static) == (0, 1, 1)  # the tower has no compatible asset
    (new,) = ParquetTable(store, SequenceRecord).load([r.sequence_id])
    assert new.placements == f"sequence={r.sequence_id}" and new.placements_key() == new.placements
    got = {p.placement_id: p for p in t_place.load([new.placements])}
    assert got[0].asset_id == "house_b" and got[0].pose == pose
    assert got[0].aabb_min == pytest.approx([20 - 5.25, 5 - 4.2, 0]) and got[0].aabb_max == pytest.approx([25.25, 9.2, 6.5])
    assert got[1] == town[1]
    assert t_place.load(["town=town00"]) == town  # the town itself is untouched
    # actors unchanged: no car swapped in a building swap
    assert ParquetTable(store, ActorStateRecord).load([r.sequence_id]) == [
        a.model_copy(update={"sequence_id": r.sequence_id}) for a in ParquetTable(store, ActorStateRecord).load(["town00_low_seq000"])]
