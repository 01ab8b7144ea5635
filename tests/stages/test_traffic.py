"""Traffic simulation on a hand-built ring town: lanes, lane changes, a reserved junction with a
crosswalk, walkers, farthest-point starts, the rig and the recorded actor states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.stages.geometry import pose_from_list
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes.traffic import simulation as traffic
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town, Walkway, check_network
from carlaocc.stages.scenes.traffic.simulation import (
    TRAFFIC_LEVELS, TrafficLevel, ego_starts, simulate_sequence, simulate_town,
)
from carlaocc.stages.scenes.traffic.vehicles import EGO_GAP, Vehicle

R_CENTRE = 30.0  # m, road centre line radius
HALF = 0.22  # rad: the junction spans angles -HALF .. HALF


def _arc(r: float, a0: float, a1: float, z: float = 0.0) -> np.ndarray:
    n = max(2, int(abs(a1 - a0) * r / 0.8) + 1)
    a = np.linspace(a0, a1, n)
    return np.column_stack([r * np.cos(a), r * np.sin(a), np.full(n, z)])


def ring_network() -> RoadNetwork:
    """A ring road (centre radius 30 m), two 3.5 m lanes each way. Counter-clockwise traffic
    keeps right, i.e. outside (radii 31.75 and 35.25); clockwise inside (28.25, 24.75). Every lane
    is a road piece plus a connector through junction 0 (angles -HALF..HALF). Walkways: an outer and
    an inner sidewalk circle joined by a crosswalk along +x through the junction."""
    specs = [(31.75, 1), (35.25, 1), (28.25, -1), (24.75, -1)]  # (radius, +1 ccw / -1 cw)
    lanes: list[Lane] = []
    for k, (r, d) in enumerate(specs):
        road_id, conn_id = 2 * k, 2 * k + 1
        if d > 0:
            road, conn = _arc(r, HALF, 2 * math.pi - HALF), _arc(r, -HALF, HALF)
        else:
            road, conn = _arc(r, 2 * math.pi - HALF, HALF), _arc(r, HALF, -HALF)
        # neighbours: the lane next to the centre line has its neighbour on the right
        left = right = -1
        if k in (0, 2):
            right = 2 * (k + 1)
        else:
            left = 2 * (k - 1)
        lanes.append(Lane(road_id, road, 3.5, successors=(conn_id,), left=left, right=right, road=f"ring{k}"))
        lanes.append(Lane(conn_id, conn, 3.5, successors=(road_id,), junction=0, road=f"ring{k}"))
    walk = [
        Walkway(0, _arc(39.0, 0.0, math.pi, 0.15), 0, 1, width=3.0),
        Walkway(1, _arc(39.0, math.pi, 2 * math.pi, 0.15), 1, 0, width=3.0),
        Walkway(2, _arc(21.0, 0.0, math.pi, 0.15), 2, 3, width=3.0),
        Walkway(3, _arc(21.0, math.pi, 2 * math.pi, 0.15), 3, 2, width=3.0),
        Walkway(4, np.array([[21.0, 0.0, 0.0], [39.0, 0.0, 0.0]]), 2, 0, width=3.0, crosswalk=True, junction=0),
    ]
    return RoadNetwork(lanes=tuple(lanes), walkways=tuple(walk), road_length=2 * math.pi * R_CENTRE)


def ring_town() -> Town:
    return Town(name="town00", index=0, style="downtown", source="", placements=[], stuff={},
                network=ring_network(), bounds=(-45.0, -45.0, 45.0, 45.0), max_instance_id=10)


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


@pytest.fixture
def dense(monkeypatch):
    """A denser "high" level so the ring's 188 m of road holds real traffic."""
    monkeypatch.setitem(TRAFFIC_LEVELS, "high", TrafficLevel(60.0, 60.0, 2.0, 0.4))


def _corners(center, size, yaw) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    l, w = size[0] / 2, size[1] / 2
    local = np.array([[l, w], [-l, w], [-l, -w], [l, -w]])
    return local @ np.array([[c, s], [-s, c]]) + np.asarray(center[:2])


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two convex quadrilaterals (4, 2)."""
    for poly in (a, b):
        for k in range(4):
            e = poly[(k + 1) % 4] - poly[k]
            n = np.array([-e[1], e[0]])
            pa, pb = a @ n, b @ n
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def _boxes(result, lib) -> dict[int, list[tuple[int, np.ndarray]]]:
    """Per frame: (instance id, footprint corners) of every actor and of the ego (id -1)."""
    ego_ext = next(a.extent for a in lib.assets if a.asset_id == result.sequence.ego_asset_id)
    out: dict[int, list[tuple[int, np.ndarray]]] = {}
    for f in result.frames:
        T = pose_from_list(f.ego_pose)
        out.setdefault(f.frame_index, []).append(
            (-1, _corners(T[:2, 3], ego_ext, math.atan2(T[1, 0], T[0, 0]))))
    for a in result.actors:
        out.setdefault(a.frame_index, []).append((a.instance_id, _corners(a.box_center, a.box_size, a.yaw)))
    return out


def test_ring_network_is_valid():
    check_network(ring_network())


def test_no_two_actors_interpenetrate_and_traffic_moves(lib, dense):
    cfg = ScenesConfig(frame_count=400, actor_range=1000.0)
    res = simulate_sequence(cfg, ring_town(), lib.assets, "high", 0, (0, 60.0))
    assert res.vehicles >= 10 and res.walkers >= 10
    for f, boxes in _boxes(res, lib).items():
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                assert not _overlap(boxes[i][1], boxes[j][1]), f"frame {f}: {boxes[i][0]} overlaps {boxes[j][0]}"
    # traffic flows: the median vehicle covered real distance, and lane changes happened
    by_id: dict[int, list] = {}
    for a in res.actors:
        by_id.setdefault(a.instance_id, []).append(a)
    moved = [np.hypot(*(np.array(v[-1].box_center) - np.array(v[0].box_center))[:2]) for v in by_id.values()
             if v[0].semantic_id != 12]
    assert np.median(moved) > 5.0


def test_a_held_up_vehicle_changes_lanes_and_the_follower_waits(lib):
    """A fast car behind a slow one on the kerb lane moves to the free neighbour lane and passes;
    with a car alongside in that lane it stays behind instead."""
    net = ring_network()
    cars = sorted((a for a in lib.assets if a.category == "Car"), key=lambda a: a.asset_id)

    def run(blocker: bool):
        sim = traffic.Simulation(net, np.random.default_rng(0), TrafficLevel(0, 0, 2.0, 0.0), EGO_GAP)
        slow = Vehicle(cars[0], 2, 60.0, 3.0, 1.0, v_fixed=3.0)
        fast = Vehicle(cars[1], 2, 40.0, 10.0, 1.0, v_fixed=12.0)
        sim.driving.vehicles += [slow, fast]
        if blocker:  # a car beside the fast one on the neighbour lane, at the same speed
            sim.driving.vehicles.append(Vehicle(cars[2], 0, 40.0 * net.lanes[0].length / net.lanes[2].length,
                                                10.0, 1.0, v_fixed=10.0))
        for v in sim.driving.vehicles:
            sim.driving.plan(v)
        changed_at = None
        for k in range(140):
            sim.step(0.05)
            if fast.lane_changes and changed_at is None:
                changed_at = k
            # the changing car never touches the slow one, nor the one beside it
            for other in sim.driving.vehicles:
                if other is not fast and (other.lane == fast.lane or other.lane == fast.lc_from):
                    assert abs(fast.s - other.s) > (fast.length + other.length) / 2 or fast.lane != other.lane \
                        and other.lane != fast.lc_from
        return fast, changed_at

    fast, at = run(blocker=False)
    assert fast.lane_changes == 1 and fast.lane == 0 and fast.s > 60.0 and at < 5
    fast, at = run(blocker=True)
    assert at is None or at > 20  # not while the neighbour lane is taken beside it


def test_walkers_cross_only_when_the_junction_is_theirs(lib, monkeypatch):
    monkeypatch.setitem(TRAFFIC_LEVELS, "high", TrafficLevel(60.0, 250.0, 2.0, 0.4))
    cfg = ScenesConfig(frame_count=400, actor_range=1000.0)
    res = simulate_sequence(cfg, ring_town(), lib.assets, "high", 1, (2, 50.0))
    on_crosswalk = [a for a in res.actors if a.semantic_id == 12 and abs(a.box_center[1]) < 1.0
                    and 24.0 < a.box_center[0] < 36.0]
    assert on_crosswalk, "some walker should use the crosswalk in 20 s"
    # while a walker is on the crosswalk, no vehicle is inside the junction's arc
    frames = {a.frame_index for a in on_crosswalk}
    for a in res.actors:
        if a.frame_index in frames and a.semantic_id != 12:
            ang = math.atan2(a.box_center[1], a.box_center[0])
            assert abs(ang) > 0.05 or not (22.0 < math.hypot(*a.box_center[:2]) < 38.0)


def test_records_are_consistent(lib):
    cfg = ScenesConfig(frame_count=30)
    res = simulate_sequence(cfg, ring_town(), lib.assets, "high", 0, (0, 60.0))
    assert [f.frame_index for f in res.frames] == list(range(30))
    assert res.sequence.sequence_id == "town00_high_seq000"
    # sensor poses: the rig's six cameras and the LiDAR every frame, LiDAR at 1.73 m above the ego
    assert len(res.sensor_poses) == 30 * 7
    for f in res.frames:
        E, L = pose_from_list(f.ego_pose), pose_from_list(f.lidar_pose)
        assert np.allclose(np.linalg.inv(E) @ L, np.array(cfg.rig.lidar.sensor_to_ego()), atol=1e-9)
    cam = [p for p in res.sensor_poses if p.sensor == "camera_00" and p.frame_index == 0][0]
    E = pose_from_list(res.frames[0].ego_pose)
    assert np.allclose(np.linalg.inv(E) @ pose_from_list(cam.pose), np.array(cfg.rig.cameras[0].camera_to_ego()))
    # instance ids stable and above the town's placements; velocities match the motion
    ids = {a.instance_id for a in res.actors}
    assert min(ids) > 10
    by_id: dict[int, dict[int, object]] = {}
    for a in res.actors:
        by_id.setdefault(a.instance_id, {})[a.frame_index] = a
    for track in by_id.values():
        for f in range(1, 29):
            if f - 1 in track and f + 1 in track and f in track:
                d = (np.array(track[f + 1].box_center) - np.array(track[f - 1].box_center)) * cfg.rate_hz / 2
                assert np.allclose(d, track[f].velocity, atol=1e-6)
    # vehicles turning around the ring: angular velocity ~ v / r
    cars = [a for a in res.actors if a.semantic_id != 12 and a.frame_index == 15]
    for a in cars:
        v, r = math.hypot(*a.velocity[:2]), math.hypot(*a.box_center[:2])
        if v > 2.0 and min(abs(r - lr) for lr in (24.75, 28.25, 31.75, 35.25)) < 0.1:  # not changing lanes
            assert abs(abs(a.angular_velocity[2]) - v / r) < 0.25 * v / r + 0.02
    walkers = [a for a in res.actors if a.semantic_id == 12]
    assert walkers and all(a.gait_phase is None or 0.0 <= a.gait_phase < 1.0 for a in walkers)


def test_actor_range_filters_far_actors(lib, dense):
    near = simulate_sequence(ScenesConfig(frame_count=3, actor_range=15.0), ring_town(), lib.assets, "high", 0, (0, 60.0))
    far = simulate_sequence(ScenesConfig(frame_count=3, actor_range=1000.0), ring_town(), lib.assets, "high", 0, (0, 60.0))
    assert 0 < len(near.actors) < len(far.actors)
    for a in near.actors:
        E = pose_from_list(near.frames[a.frame_index].ego_pose)
        assert math.hypot(a.box_center[0] - E[0, 3], a.box_center[1] - E[1, 3]) <= 15.0


def test_deterministic_and_levels(lib):
    cfg = ScenesConfig(frame_count=10)
    a = simulate_sequence(cfg, ring_town(), lib.assets, "medium", 0, (0, 60.0))
    b = simulate_sequence(cfg, ring_town(), lib.assets, "medium", 0, (0, 60.0))
    assert a == b
    none = simulate_sequence(cfg, ring_town(), lib.assets, "none", 0, (0, 60.0))
    assert none.actors == [] and none.vehicles == 0
    with pytest.raises(ValueError, match="unknown traffic level"):
        simulate_sequence(cfg, ring_town(), lib.assets, "rush", 0, (0, 60.0))


def test_farthest_point_starts_spread_out():
    town = ring_town()
    starts = ego_starts(town, 2, seed=3)
    assert len(set(starts)) == 2
    pts = [town.network.lanes[k].at(s)[0] for k, s in starts]
    assert np.hypot(*(pts[0] - pts[1])[:2]) > 50.0  # across the ring (diameter ~60 m)


def test_simulate_town_names_sequences_per_level(lib):
    spec = TownSpec(style="downtown", traffic_levels=("low", "high"), sequences_per_level=2)
    seqs = simulate_town(ScenesConfig(frame_count=2), spec, ring_town(), lib.assets)
    assert [s.sequence.sequence_id for s in seqs] == [
        "town00_low_seq000", "town00_low_seq001", "town00_high_seq000", "town00_high_seq001"]
    assert len({s.frames[0].ego_pose[3] for s in seqs}) == 4  # four different starts
    with pytest.raises(ValueError, match="category Car"):
        simulate_town(ScenesConfig(frame_count=2), spec, ring_town(), [a for a in lib.assets if a.category != "Car"])


def test_phase_matcher_is_called_per_walker(lib):
    calls = []

    def fake(times, positions, yaws, phase, height, seed):
        calls.append((len(times), height))
        return [7] * len(times)

    res = simulate_sequence(ScenesConfig(frame_count=5, actor_range=1000.0), ring_town(), lib.assets, "high", 0, (0, 60.0),
                            match_phases=fake)
    assert calls and all(n == 5 for n, _ in calls)
    assert {a.phase_index for a in res.actors if a.semantic_id == 12} == {7}
    assert all(a.phase_index is None for a in res.actors if a.semantic_id != 12)


def test_traffic_module_constants_match_design():
    assert (traffic.MAX_VEHICLES, traffic.MAX_WALKERS) == (128, 64)
    assert [TRAFFIC_LEVELS[k].vehicles_per_km for k in ("none", "low", "medium", "high")] == [0, 4, 8, 16]


def test_spawned_followers_start_slow_enough_to_stop_behind_their_leader(lib):
    from carlaocc.stages.scenes.traffic.simulation import safe_start_speeds
    from carlaocc.stages.scenes.traffic.vehicles import IDM_DECEL, Vehicle

    car = next(a for a in lib.assets if a.category == "Car")
    L = float(car.extent[0])
    lead = Vehicle(car, 0, 50.0, 12.0, 1.0)
    fast = Vehicle(car, 0, 50.0 - L - 6.0, 24.0, 1.0)  # 6 m bumper to bumper behind it
    slow = Vehicle(car, 0, 10.0, 5.0, 1.0)  # far behind and slow: untouched
    ego = Vehicle(car, 1, 50.0, 8.0, 1.0, v_fixed=8.0)
    other = Vehicle(car, 1, 50.0 - L - 1.0, 20.0, 1.0)
    safe_start_speeds([slow, fast, lead, ego, other])
    assert fast.v == pytest.approx(math.sqrt(12.0**2 + 2 * IDM_DECEL * 6.0))
    assert (lead.v, slow.v, ego.v) == (12.0, 5.0, 8.0)
    assert other.v == pytest.approx(math.sqrt(8.0**2 + 2 * IDM_DECEL * 1.0))
