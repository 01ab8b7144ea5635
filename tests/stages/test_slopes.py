"""Cars on slopes and banks (the builtin hills town: an 8 m crest, a 3 m sag, two half circles
banked by 0.12 rad): every vehicle stands on the road surface with pitch and roll, so its wheels
touch the road within one voxel and none of its voxels lies under the road; yaw-only poses fail
both (the checks can fail)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carlaocc.catalog.opendrive import read_opendrive
from carlaocc.catalog.towns import resolve_opendrive
from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.records import FrameRecord
from carlaocc.schemas.taxonomy import by_name
from carlaocc.stages.geometry import (pose_from_list, pose_matrix, pose_to_list, rotation_matrix, transform_points,
                                      yaw_pitch_roll)
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes import build_town, simulate_sequence
from carlaocc.stages.scenes.assembly import PlacementIndex, assemble_frame
from carlaocc.stages.scenes.traffic.simulation import TRAFFIC_LEVELS, TrafficLevel, ego_starts
from carlaocc.stages.voxelize import voxelize_scene

VOXEL = 0.1  # m
ROAD = by_name("Road").id
TILT = math.radians(3.0)  # a car counts as pitched / rolled beyond this


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


@pytest.fixture(scope="module")
def hills(lib):
    """The hills town and a dense three-frame sequence on it (every actor recorded)."""
    saved = TRAFFIC_LEVELS["high"]
    TRAFFIC_LEVELS["high"] = TrafficLevel(30.0, 0.0, 2.0, 0.3)
    try:
        path = resolve_opendrive("builtin:hills.xodr")
        cfg = ScenesConfig(frame_count=3, actor_range=1000.0)
        town = build_town(TownSpec(style="opendrive", opendrive=str(path)), cfg, 0, lib.assets,
                          read_opendrive(path), str(path))  # fmt: skip
        res = simulate_sequence(cfg, town, lib.assets, "high", 0, ego_starts(town, 1, cfg.seed)[0])
    finally:
        TRAFFIC_LEVELS["high"] = saved
    geometry = {**lib.geometry, **town.stuff}
    return town, res, geometry


def _road_height(V: np.ndarray, F: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Height (m) of the topmost triangle of the mesh (V, F) above each world point ``xy`` (Q, 2)
    (NaN where none lies above or below it): barycentric interpolation in the xy projection."""
    # only the triangles whose xy box meets the queries' box
    tri = V[F]  # (M, 3, 3)
    near = np.all((tri[:, :, :2].min(axis=1) <= xy.max(axis=0)) & (tri[:, :, :2].max(axis=1) >= xy.min(axis=0)), axis=1)
    a, b, c = tri[near, 0], tri[near, 1], tri[near, 2]
    out = np.full(len(xy), np.nan)
    for q, p in enumerate(xy):
        # barycentric coordinates of p in every triangle's xy projection
        v0, v1, v2 = b[:, :2] - a[:, :2], c[:, :2] - a[:, :2], p - a[:, :2]
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        ok = np.abs(den) > 1e-12
        u = np.where(ok, (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / np.where(ok, den, 1), -1)
        v = np.where(ok, (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / np.where(ok, den, 1), -1)
        inside = ok & (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9)
        if inside.any():
            z = a[inside, 2] + u[inside] * (b[inside, 2] - a[inside, 2]) + v[inside] * (c[inside, 2] - a[inside, 2])
            out[q] = z.max()
    return out


def _road_mesh(town) -> tuple[np.ndarray, np.ndarray]:
    parts = [(p.vertices, p.faces) for g in town.stuff.values() for p in g.parts if p.semantic_id == ROAD]
    offsets = np.cumsum([0] + [len(v) for v, _ in parts])
    return np.concatenate([v for v, _ in parts]), np.concatenate([f + o for (_, f), o in zip(parts, offsets)])


def _wheel_bottoms(geom) -> np.ndarray:
    """(4, 3) asset-frame points: the lowest vertex of each quarter (front/rear x left/right)."""
    V = np.concatenate([p.vertices for p in geom.parts])
    out = []
    for sx in (1, -1):
        for sy in (1, -1):
            q = V[(np.sign(V[:, 0]) == sx) & (np.sign(V[:, 1]) == sy)]
            out.append(q[np.argmin(q[:, 2])])
    return np.array(out)


def _tilted_cars(res, lib, n: int = 6):
    """Up to ``n`` pitched and ``n`` rolled cars of frame 0 (distinct instances)."""
    cars = {a.asset_id for a in lib.assets if a.category == "Car"}
    actors = [a for a in res.actors if a.frame_index == 0 and a.asset_id in cars]
    pitched = [a for a in actors if abs(a.pitch) > TILT][:n]
    rolled = [a for a in actors if abs(a.roll) > TILT][:n]
    return pitched, rolled


def test_cars_pitch_and_roll_with_the_road(hills, lib):
    town, res, _ = hills
    pitched, rolled = _tilted_cars(res, lib)
    assert len(pitched) >= 3 and len(rolled) >= 3
    for a in pitched + rolled:
        T = pose_from_list(a.pose)
        # the pose's rotation is the recorded angles; the box centre sits half the height up the body's z
        assert np.allclose(T[:3, :3], rotation_matrix(a.yaw, a.pitch, a.roll), atol=1e-12)
        assert np.allclose(a.box_center, T[:3, 3] + T[:3, 2] * a.box_size[2] / 2)
    # the crest is at most 15 % steep, the banks 0.12 rad: the angles stay in that range
    assert max(abs(a.pitch) for a in pitched) < math.atan(0.16)
    assert max(abs(a.roll) for a in rolled) < 0.13
    # the ego tilts too (it starts on a banked curve), and its LiDAR with it
    ego = [pose_from_list(f.ego_pose) for f in res.frames]
    assert abs(yaw_pitch_roll(ego[0])[2]) > TILT
    assert all(np.allclose(pose_from_list(f.lidar_pose)[:3, :3], T[:3, :3]) for f, T in zip(res.frames, ego))


def test_wheels_touch_the_road(hills, lib):
    town, res, geometry = hills
    V, F = _road_mesh(town)
    pitched, rolled = _tilted_cars(res, lib)
    worst, worst_level = 0.0, 0.0
    for a in pitched + rolled:
        wheels = _wheel_bottoms(geometry[a.asset_id])
        T = pose_from_list(a.pose)
        level = pose_matrix(*T[:3, 3], a.yaw)  # the same car without pitch and roll
        for pose, acc in ((T, "tilted"), (level, "level")):
            w = transform_points(pose, wheels)
            gap = np.abs(w[:, 2] - _road_height(V, F, w[:, :2]))
            assert np.isfinite(gap).all()
            if acc == "tilted":
                worst = max(worst, float(gap.max()))
            else:
                worst_level = max(worst_level, float(gap.max()))
    assert worst <= VOXEL, f"a wheel is {worst:.3f} m off the road"
    assert worst_level > VOXEL  # yaw-only poses would float or sink: the check can fail


def _voxels_under_the_road(town, res, geometry, a, pose) -> tuple[int, int]:
    """(voxels of the car ``a`` posed at ``pose`` whose centre is more than a voxel under the road
    surface, voxels of the car) in a world-aligned 0.1 m grid around it, the frame's whole scene
    composed (elevation order along world z)."""
    frame = res.frames[a.frame_index]
    actor = a.model_copy(update={"pose": pose_to_list(pose)})
    centre = pose[:3, 3]
    lo, hi = centre - [4.0, 4.0, 2.0], centre + [4.0, 4.0, 3.0]
    world = FrameRecord(sequence_id=frame.sequence_id, frame_index=frame.frame_index, timestamp=frame.timestamp,
                        ego_pose=frame.ego_pose, lidar_pose=pose_to_list(np.eye(4)))  # fmt: skip
    scene = assemble_frame(world, [actor], PlacementIndex(town.placements), geometry, (lo, hi))
    grid = GridSpec(region_min=tuple(lo), region_max=tuple(hi), voxel_size=VOXEL)
    _, instance = voxelize_scene(scene, grid)
    ijk = np.argwhere(instance == a.instance_id)
    centres = np.asarray(grid.origin) + (ijk + 0.5) * VOXEL
    V, F = _road_mesh(town)
    road = _road_height(V, F, centres[:, :2])
    return int(np.sum(centres[:, 2] < road - VOXEL)), len(ijk)


def test_car_voxels_are_not_cut_by_the_road(hills, lib):
    town, res, geometry = hills
    pitched, rolled = _tilted_cars(res, lib, n=2)
    cut_level = 0
    for a in pitched + rolled:
        T = pose_from_list(a.pose)
        under, total = _voxels_under_the_road(town, res, geometry, a, T)
        assert total > 1000 and under == 0, f"{under} of {total} voxels of car {a.instance_id} are under the road"
        cut_level += _voxels_under_the_road(town, res, geometry, a, pose_matrix(*T[:3, 3], a.yaw))[0]
    assert cut_level > 0  # yaw-only cars sink into the crest and the banks


def test_lane_normals_follow_the_hills_profile(hills):
    from carlaocc.stages.scenes.network import Lane, RoadNetwork, check_network

    town, _, _ = hills
    by_road: dict[str, float] = {}
    for ln in town.network.lanes:
        tilt = np.arccos(np.clip(ln.up_at(np.linspace(0.0, ln.length, 200))[:, 2], -1, 1))
        by_road[ln.road] = max(by_road.get(ln.road, 0.0), float(tilt.max()))
    # the crest's steepest grade is 1.5 * 8 / 80 = 15 %, the banks 0.12 rad, the sag 1.5 * 3 / 80
    assert by_road["1"] == pytest.approx(math.atan(0.15), abs=2e-3)
    assert by_road["2"] == pytest.approx(0.12, abs=2e-3) and by_road["4"] == pytest.approx(0.12, abs=2e-3)
    assert by_road["3"] == pytest.approx(math.atan(1.5 * 3 / 80), abs=2e-3)
    # the banks lean into their curves: the normal's horizontal part points to the curve's centre
    # (the east one at (160, 45), the west one at (0, 45)); the crest's leans back uphill
    for ln in town.network.lanes:
        s = np.linspace(0.3, 0.7, 5) * ln.length
        p, n = ln.at(s)[0], ln.up_at(s)
        if ln.road in ("2", "4"):
            centre = np.array([160.0, 45.0]) if ln.road == "2" else np.array([0.0, 45.0])
            assert (np.einsum("ij,ij->i", n[:, :2], centre - p[:, :2]) > 0).all()
    up_hill = [ln for ln in town.network.lanes if ln.road == "1" and ln.points[-1, 0] > ln.points[0, 0]]
    s = np.array([0.25]) * up_hill[0].length  # climbing the crest: the normal leans against the travel (-x)
    assert up_hill[0].up_at(s)[0, 0] < -0.05
    # both directions of both lanes of the loop are kept (four one-way circuits)
    assert len(town.network.lanes) == 16
    # a lane without normals is level; upside-down normals are refused
    level = Lane(lane_id=0, points=np.array([[0.0, 0, 0], [10.0, 0, 0]]), width=3.0, successors=(0,))
    assert np.array_equal(level.up_at([0.0, 5.0]), [[0.0, 0.0, 1.0]] * 2)
    bad = Lane(lane_id=0, points=level.points, width=3.0, successors=(0,), normals=[[0.0, 0, -1], [0.0, 0, 1]])
    with pytest.raises(ValueError, match="normals"):
        check_network(RoadNetwork(lanes=(bad,), walkways=(), road_length=10.0))
