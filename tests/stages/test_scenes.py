"""Procedural towns, traffic sequences and per-frame scene composition."""

from __future__ import annotations

import collections

import numpy as np
import pytest

from schemas import taxonomy
from schemas.configs import IngestConfig, ScenesConfig, VoxelizeConfig
from schemas.records import ActorStateRecord
from stages.geometry import invert_pose, is_watertight, pose_from_list, transform_points
from stages.ingest import ingest_procedural
from stages.scenes import build_town, compose_frame_scene, simulate_sequences
from stages.scenes.traffic import LIDAR_HEIGHT

THINGS = set(taxonomy.thing_ids())
STUFF = set(taxonomy.stuff_ids())
CAR = taxonomy.by_name("Car").id
REGION_LO, REGION_HI = np.array([-25.6, -25.6, -3.0]), np.array([51.2, 25.6, 10.0])


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


@pytest.fixture(scope="module")
def town(lib):
    return build_town(ScenesConfig(), 0, lib.assets)


@pytest.fixture(scope="module")
def sequences(lib, town):
    return simulate_sequences(ScenesConfig(), town, lib.assets)


@pytest.fixture(scope="module")
def geometry(lib, town):
    return {**lib.geometry, **town.stuff}


def _footprint(p, extent) -> tuple[float, float, float, float]:
    """World AABB (xmin, xmax, ymin, ymax) of a placed asset's footprint."""
    T = pose_from_list(p.pose)
    l, w = extent[0] / 2, extent[1] / 2
    c = transform_points(T, np.array([[sx * l, sy * w, 0.0] for sx in (-1, 1) for sy in (-1, 1)]))
    return c[:, 0].min(), c[:, 0].max(), c[:, 1].min(), c[:, 1].max()


# ------------------------------------------------------------------------------------- town


def test_town_is_deterministic_and_seeded(lib, town):
    again = build_town(ScenesConfig(), 0, list(reversed(lib.assets)))  # asset order does not matter
    assert again.placements == town.placements
    for key, geom in town.stuff.items():
        assert geom.parts[0].vertices.tobytes() == again.stuff[key].parts[0].vertices.tobytes()
    assert build_town(ScenesConfig(seed=12), 0, lib.assets).placements != town.placements
    assert build_town(ScenesConfig(), 1, lib.assets).placements != town.placements


def test_placement_ids_and_instances(town):
    assert [p.placement_id for p in town.placements] == list(range(len(town.placements)))
    assert len({p.name for p in town.placements}) == len(town.placements)
    things = [p.instance_id for p in town.placements if p.semantic_id in THINGS]
    assert things and len(set(things)) == len(things) and min(things) >= 1
    assert max(things) == town.max_instance_id
    assert all(p.instance_id == 0 for p in town.placements if p.semantic_id in STUFF)
    assert all(p.mesh_path == "" and p.town == "town00" for p in town.placements)


def test_stuff_meshes(town):
    names = {"road", "sidewalk", "terrain", "roadline"}
    assert set(town.stuff) == {f"town00/{n}" for n in names}
    by_name = {p.name: p for p in town.placements}
    for n in names:
        p = by_name[n]
        assert p.asset_id == f"town00/{n}" and p.instance_id == 0
        assert np.allclose(pose_from_list(p.pose), np.eye(4))
        part = town.stuff[p.asset_id].parts[0]
        assert part.semantic_id == p.semantic_id == taxonomy.by_name(n).id
        assert is_watertight(part.faces) and town.stuff[p.asset_id].part_closed == (True,)
    top = {n: town.stuff[f"town00/{n}"].parts[0].vertices[:, 2].max() for n in names}
    assert top["road"] == pytest.approx(0.0) and top["sidewalk"] == pytest.approx(ScenesConfig().curb_height)
    assert 0.0 < top["roadline"] < 0.05


def test_buildings_stay_off_roads_and_sidewalks(lib, town):
    cfg = ScenesConfig()
    extent = {a.asset_id: a.extent for a in lib.assets}
    pitch = cfg.block_size + cfg.road_width
    half = cfg.road_width / 2 + cfg.sidewalk_width  # road plus the sidewalks either side
    buildings = [p for p in town.placements if p.name.startswith("building_")]
    assert len(buildings) >= 2 * cfg.blocks**2
    for p in buildings:
        x0, x1, y0, y1 = _footprint(p, extent[p.asset_id])
        for k in range(cfg.blocks + 1):
            c = k * pitch
            assert x1 <= c - half or x0 >= c + half, p.name
            assert y1 <= c - half or y0 >= c + half, p.name


def test_lanes_are_right_hand(town):
    for lane in town.lanes:
        d = np.asarray(lane.direction)
        right = np.array([d[1], -d[0]])
        mid = (np.asarray(lane.start) + np.asarray(lane.end)) / 2
        # the road centre line is the lane's nearest multiple of the road pitch on the other axis
        axis = 1 if abs(d[0]) > 0.5 else 0
        pitch = ScenesConfig().block_size + ScenesConfig().road_width
        centre = round(mid[axis] / pitch) * pitch
        assert (mid[axis] - centre) * right[axis] > 0
    assert town.road_length == pytest.approx(2 * 4 * (3 * 70 + 10))


def test_town_needs_buildings(lib):
    with pytest.raises(ValueError, match="Building"):
        build_town(ScenesConfig(), 0, [a for a in lib.assets if a.category != "Building"])
    with pytest.raises(ValueError, match="block interior"):
        build_town(ScenesConfig(block_size=12.0, sidewalk_width=5.0), 0, lib.assets)


# ------------------------------------------------------------------------------------ traffic


def test_sequence_frames_and_poses(sequences):
    assert len(sequences) == 1
    sr = sequences[0]
    assert sr.sequence.sequence_id == "town00_seq000"
    assert sr.sequence.frame_count == len(sr.frames) >= 20 and sr.sequence.rate_hz == 20.0
    for k, f in enumerate(sr.frames):
        assert f.frame_index == k and f.timestamp == pytest.approx(k / 20.0)
        E, L = pose_from_list(f.ego_pose), pose_from_list(f.lidar_pose)
        assert E[2, 3] == 0.0
        assert np.allclose(L[:3, :3], E[:3, :3]) and np.allclose(L[:3, 3], E[:3, 3] + [0, 0, LIDAR_HEIGHT])
    start, end = pose_from_list(sr.frames[0].ego_pose), pose_from_list(sr.frames[-1].ego_pose)
    assert np.linalg.norm(end[:3, 3] - start[:3, 3]) > 5.0  # 0.95 s at about 8 m/s


def test_instance_ids_stable_and_unique(sequences, town):
    sr = sequences[0]
    per_frame = collections.defaultdict(list)
    asset_of: dict[int, str] = {}
    for a in sr.actors:
        per_frame[a.frame_index].append(a.instance_id)
        assert asset_of.setdefault(a.instance_id, a.asset_id) == a.asset_id
    ids = per_frame[0]
    assert ids and len(set(ids)) == len(ids) and min(ids) > town.max_instance_id
    assert all(sorted(v) == sorted(ids) for v in per_frame.values())
    assert sorted(per_frame) == list(range(len(sr.frames)))
    assert all(a.semantic_id in THINGS for a in sr.actors)


def _check_velocities(actors, rate_hz):
    tracks = collections.defaultdict(list)
    for a in actors:
        tracks[a.instance_id].append(a)
    for track in tracks.values():
        P = np.array([pose_from_list(a.pose)[:3, 3] for a in track])
        V = np.array([a.velocity for a in track])
        moved = np.diff(P, axis=0) * rate_hz
        mean = (V[1:] + V[:-1]) / 2
        # polyline paths: the heading turns at vertices, a few degrees per frame at most
        tol = 0.1 * np.linalg.norm(mean, axis=1) + 0.05
        assert np.all(np.linalg.norm(moved - mean, axis=1) <= tol)
        for a in track:
            assert a.box_size == pytest.approx(a.box_size) and a.box_center[2] == pytest.approx(
                pose_from_list(a.pose)[2, 3] + a.box_size[2] / 2
            )
            assert a.yaw == pytest.approx(np.arctan2(a.pose[4], a.pose[0]))


def test_velocities_match_pose_differences(sequences):
    _check_velocities(sequences[0].actors, 20.0)


def test_busy_long_sequence_velocities(lib, town):
    cfg = ScenesConfig(frame_count=120, traffic_level="high")
    sr = simulate_sequences(cfg, town, lib.assets)[0]
    _check_velocities(sr.actors, cfg.rate_hz)
    counts = collections.Counter(a.semantic_id for a in sr.actors if a.frame_index == 0)
    assert counts[CAR] > 10 and counts[taxonomy.by_name("Pedestrian").id] > 5


def test_moving_cars_in_the_grid_region(sequences):
    sr = sequences[0]
    best = 0
    for f in sr.frames:
        W2L = invert_pose(pose_from_list(f.lidar_pose))
        n = 0
        for a in sr.actors:
            if a.frame_index != f.frame_index or a.semantic_id != CAR or np.hypot(*a.velocity[:2]) < 0.5:
                continue
            p = transform_points(W2L, np.array([a.box_center]))[0]
            n += bool(np.all(p >= REGION_LO) and np.all(p <= REGION_HI))
        best = max(best, n)
    assert best >= 3


def test_walkers_and_gait(sequences):
    walkers = [a for a in sequences[0].actors if a.semantic_id == taxonomy.by_name("Pedestrian").id]
    assert walkers
    assert all(a.gait_phase is not None and 0.0 <= a.gait_phase < 1.0 for a in walkers)
    assert all(a.gait_phase is None for a in sequences[0].actors if a.semantic_id != taxonomy.by_name("Pedestrian").id)
    assert all(a.pose[11] == pytest.approx(ScenesConfig().curb_height) for a in walkers)
    first = {a.instance_id: a.gait_phase for a in walkers if a.frame_index == 0}
    last = {a.instance_id: a.gait_phase for a in walkers if a.frame_index == 19}
    assert any(first[i] != last[i] for i in first)


def test_traffic_is_deterministic_and_scales_with_level(lib, town, sequences):
    again = simulate_sequences(ScenesConfig(), town, lib.assets)
    assert again[0].sequence == sequences[0].sequence
    assert again[0].frames == sequences[0].frames and again[0].actors == sequences[0].actors
    counts = {}
    for level in ("none", "low", "high"):
        sr = simulate_sequences(ScenesConfig(traffic_level=level, frame_count=2), town, lib.assets)[0]
        counts[level] = sum(a.frame_index == 0 for a in sr.actors)
    assert counts["none"] == 0 < counts["low"] < counts["high"]


def test_several_sequences_start_apart(lib, town):
    seqs = simulate_sequences(ScenesConfig(sequences_per_town=3, frame_count=2), town, lib.assets)
    assert [s.sequence.sequence_id for s in seqs] == ["town00_seq000", "town00_seq001", "town00_seq002"]
    starts = np.array([pose_from_list(s.frames[0].ego_pose)[:2, 3] for s in seqs])
    assert min(np.linalg.norm(starts[i] - starts[j]) for i in range(3) for j in range(i)) > 50.0


def test_traffic_needs_a_car(lib, town):
    with pytest.raises(ValueError, match="Car"):
        simulate_sequences(ScenesConfig(), town, [a for a in lib.assets if a.category != "Car"])


# ------------------------------------------------------------------------------------ compose


@pytest.fixture(scope="module")
def scene(sequences, town, geometry):
    sr = sequences[0]
    grid = VoxelizeConfig().grid(0.2)
    return compose_frame_scene(sr.frames[0], sr.actors, town.placements, geometry, grid, sr.sequence.ego_asset_id)


def test_scene_is_in_the_lidar_frame(scene):
    # the highest road triangle under the LiDAR lies 1.73 m below it
    road = [m for m in scene if m.semantic_id == taxonomy.by_name("Road").id]
    assert len(road) == 1
    V, F = road[0].vertices, road[0].faces
    a, b, c = V[F[:, 0], :2], V[F[:, 1], :2], V[F[:, 2], :2]

    def cross(u, v):
        return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

    o = np.zeros_like(a)
    s1, s2, s3 = cross(b - a, o - a), cross(c - b, o - b), cross(a - c, o - c)
    under = ((s1 >= 0) & (s2 >= 0) & (s3 >= 0)) | ((s1 <= 0) & (s2 <= 0) & (s3 <= 0))
    assert under.any()
    assert V[F[under]][:, :, 2].max() == pytest.approx(-LIDAR_HEIGHT, abs=1e-9)


def test_scene_labels_and_geometry(scene):
    assert scene
    for m in scene:
        assert np.isfinite(m.vertices).all() and len(m.faces) > 0
        assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
        assert m.is_stuff == (m.semantic_id in STUFF)
        if m.is_stuff:
            assert m.instance_id == 0 and not m.closed
            # culled: every stuff triangle touches the region grown by the margin
            tri = m.vertices[m.faces]
            assert np.all(tri.min(axis=1) <= REGION_HI + 0.5) and np.all(tri.max(axis=1) >= REGION_LO - 0.5)
        else:
            assert m.instance_id > 0 and m.closed
            assert np.all(m.vertices.max(axis=0) >= REGION_LO - 0.5)
            assert np.all(m.vertices.min(axis=0) <= REGION_HI + 0.5)
    classes = {m.semantic_id for m in scene}
    assert {taxonomy.by_name(n).id for n in ("Road", "Sidewalk", "RoadLine", "Car", "Building")} <= classes


def test_ego_is_not_in_the_scene(scene, sequences, town, geometry):
    # nothing of class Car occupies the ego's own body around the LiDAR's foot
    for m in scene:
        if m.semantic_id == CAR:
            lo, hi = m.vertices.min(axis=0), m.vertices.max(axis=0)
            assert not (np.all(lo[:2] <= 0.0) and np.all(hi[:2] >= 0.0)), m.name
    # an actor record standing at the ego pose is dropped as the ego
    sr = sequences[0]
    f = sr.frames[0]
    ego = ActorStateRecord(
        sequence_id=f.sequence_id, frame_index=0, instance_id=10**6, asset_id=sr.sequence.ego_asset_id,
        semantic_id=CAR, pose=f.ego_pose, box_center=[0.0, 0.0, 0.7], box_size=[4.5, 1.8, 1.4], yaw=0.0,
        velocity=[0.0, 0.0, 0.0],
    )  # fmt: skip
    grid = VoxelizeConfig().grid(0.2)
    out = compose_frame_scene(f, [*sr.actors, ego], town.placements, geometry, grid, sr.sequence.ego_asset_id)
    assert all(m.instance_id != 10**6 for m in out)


def test_compose_is_deterministic_and_checks_geometry(scene, sequences, town, geometry):
    sr = sequences[0]
    grid = VoxelizeConfig().grid(0.2)
    again = compose_frame_scene(sr.frames[0], sr.actors, town.placements, geometry, grid, sr.sequence.ego_asset_id)
    assert [m.name for m in again] == [m.name for m in scene]
    assert all(np.array_equal(a.vertices, b.vertices) for a, b in zip(again, scene))
    # only this frame's actors are used
    actor_ids = {m.instance_id for m in scene if m.instance_id > town.max_instance_id}
    assert actor_ids <= {a.instance_id for a in sr.actors if a.frame_index == 0}
    with pytest.raises(ValueError, match="no geometry"):
        compose_frame_scene(sr.frames[0], sr.actors, town.placements, dict(town.stuff), grid)
