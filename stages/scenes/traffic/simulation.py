"""Traffic sequences: an ego car driving a route through a town among vehicles and walkers.

Works on any :class:`~carlaocc.stages.scenes.network.Town` (procedural or OpenDRIVE). World frame of
the town (metres, Z up); time in seconds; ``rate_hz`` frames per second (20 by default), integrated
in sub-steps of at most :data:`MAX_SUBSTEP`.

* **Ego** -- a Car asset starting on a lane chosen by farthest-point sampling over the lane
  starts of the town: the town's sequences start as far from each other as possible (the first
  at random). The ego is not an actor record; its pose is the frame's ``ego_pose`` (origin on the
  ground at the vehicle's bottom centre, +X forward) and the sensor poses follow from the rig.
* **Vehicles** (Car 80 %, Truck 10 %, Bus 10 % of the assets narrow enough for the lanes) spawn
  on road lanes at the traffic level's density per km of road (docs/architecture.md "Traffic
  levels", at most 128). A few *escorts* spawn along the ego's route ahead of and behind it,
  beside it on a parallel lane and ahead of it on a nearby lane running the other way, so the
  occupancy region holds traffic from the first frame. Each vehicle's target speed is its lane's speed limit
  times ``1 + spread u`` (u uniform in [-1, 1]). Vehicles drive random routes over the lane graph
  with the Intelligent Driver Model (the level's "gap to leader" is the IDM standstill gap);
  leaders are found along the lanes (the vehicle's lane, the lanes it has planned next, and the
  lane a vehicle's rear still overhangs), not by straight-line distance, so curves do not confuse
  them.
* **Lane changes** (a MOBIL-style rule): on road lanes with a parallel neighbour, a vehicle held
  up by a slower leader moves over when the neighbour lane gives it a clear acceleration gain and
  the gaps to the new leader and the new follower are safe. The move takes ``LANE_CHANGE_TIME``
  (3 s); meanwhile the vehicle occupies both lanes.
* **Junctions** are reserved: a vehicle enters a junction's connector lanes only when it holds
  the junction alone; walkers on its crosswalks hold it together. Requests are served first come,
  first served, so crossing traffic and pedestrians on crosswalks never interpenetrate.
* **Walkers** (Pedestrian assets; 0/2/4/8 per km, at most 64) walk the walk graph (sidewalks,
  and crosswalks when the junction is theirs), keep right, and yield to the walker ahead of them
  (the higher instance id yields when two block each other). ``gait_phase`` advances by walked
  distance over the gait cycle (two steps of 0.415 x body height) and is missing while standing;
  the Skeletal Motion Analyzer matches the canonical ``phase_index`` of every walker frame.

The vehicles live in :mod:`~carlaocc.stages.scenes.traffic.vehicles`, the walkers in
:mod:`~carlaocc.stages.scenes.traffic.walkers`, the junction reservations they share in
:mod:`~carlaocc.stages.scenes.traffic.junctions`; this module spawns them, integrates and records.

Recorded per frame: the frame (ego and LiDAR poses), every rig sensor's pose, and every actor
within ``actor_range`` m of the ego: stable instance id (numbered above the town's placements),
asset, class, pose (asset-to-world), 3D box (centre half its height above the pose origin along the
body's up axis, extent l, w, h), yaw, pitch and roll, linear and angular velocity (central
differences of the simulated poses over the frames). Vehicles and the ego stand on the road
surface: their up axis is the lane's surface normal (elevation and superelevation pitch and roll
them; the frame's LiDAR and cameras turn with the ego); walkers stay upright.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import ActorStateRecord, AssetRecord, FrameRecord, SensorPoseRecord, SequenceRecord
from carlaocc.stages.geometry import angular_velocity, box_center, pose_matrix, pose_to_list, tilt_to_normal
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town
from carlaocc.stages.scenes.traffic.junctions import JunctionReservations
from carlaocc.stages.scenes.traffic.vehicles import EGO_GAP, IDM_DECEL, Vehicle, VehicleTraffic, vehicle_pose
from carlaocc.stages.scenes.traffic.walkers import STAND_SPEED, Walker, WalkerTraffic

__all__ = [
    "SequenceResult", "Simulation", "TrafficLevel", "TRAFFIC_LEVELS", "simulate_sequence", "simulate_town",
    "sequence_name", "ego_starts",
]  # fmt: skip

MAX_VEHICLES, MAX_WALKERS = 128, 64
MAX_ESCORTS = 6  # cars spawned around the ego (counted in the level's vehicles)
VEHICLE_MIX = (("Car", 0.8), ("Truck", 0.1), ("Bus", 0.1))
MAX_SUBSTEP = 0.05  # s, longest integration step


@dataclass(frozen=True)
class TrafficLevel:
    """Densities per km of road, IDM standstill gap (m) and speed spread (fraction)."""

    vehicles_per_km: float
    walkers_per_km: float
    gap: float
    speed_spread: float


TRAFFIC_LEVELS: dict[str, TrafficLevel] = {
    "none": TrafficLevel(0.0, 0.0, 3.0, 0.0),
    "low": TrafficLevel(4.0, 2.0, 3.0, 0.30),
    "medium": TrafficLevel(8.0, 4.0, 2.5, 0.35),
    "high": TrafficLevel(16.0, 8.0, 2.0, 0.40),
}


@dataclass(frozen=True)
class SequenceResult:
    """One simulated sequence: its record, frames, sensor poses (frame-major, rig order) and
    actor states (frame-major, then instance id), plus counters of what happened."""

    sequence: SequenceRecord
    frames: list[FrameRecord]
    sensor_poses: list[SensorPoseRecord]
    actors: list[ActorStateRecord]
    lane_changes: int = 0
    vehicles: int = 0
    walkers: int = 0


def sequence_name(town: str, level: str, k: int) -> str:
    """``("town00", "high", 0) -> "town00_high_seq000"``."""
    return f"{town}_{level}_seq{k:03d}"


class Simulation:
    """State and stepping of one sequence: the vehicles (the ego first) and the walkers, sharing
    the junction reservations and the random stream ``rng``; ``time`` (s) and ``step_no`` count
    the integration steps."""

    def __init__(self, network: RoadNetwork, rng: np.random.Generator, level: TrafficLevel, ego_gap: float):
        self.junctions = JunctionReservations()
        self.driving = VehicleTraffic(network.lanes, rng, level.gap, ego_gap, self.junctions)
        self.walking = WalkerTraffic(network.walkways, rng, self.junctions)
        self.step_no = 0
        self.time = 0.0

    def step(self, dt: float) -> None:
        """Advance the vehicles, then the walkers, by ``dt`` s."""
        self.driving.step(dt, self.step_no, self.time)
        self.walking.step(dt, self.step_no)
        self.step_no += 1
        self.time += dt


# --------------------------------------------------------------------------------------------
# spawning
# --------------------------------------------------------------------------------------------


def _assets_of(assets: Sequence[AssetRecord], category: str) -> list[AssetRecord]:
    """Assets of a category, in a stable order (sub-class, id)."""
    return sorted((a for a in assets if a.category == category), key=lambda a: (a.subclass, a.asset_id))


def _road_lanes(net: RoadNetwork) -> list[Lane]:
    """Lanes outside junctions, where vehicles spawn and egos start."""
    return [ln for ln in net.lanes if ln.junction < 0]


def ego_starts(town: Town, count: int, seed: int, spacing: float = 10.0) -> list[tuple[int, float]]:
    """Farthest-point sampling of ego start points (lane id, arc length): candidates every
    ``spacing`` m along the road lanes, at least 8 m from either lane end (lane middles for
    shorter lanes); the first at random from ``seed``, each next the candidate farthest (in xy)
    from those chosen."""
    cands: list[tuple[int, float]] = []
    for ln in _road_lanes(town.network):
        s = np.arange(8.0, ln.length - 8.0 + 1e-9, spacing) if ln.length >= 16.0 else np.array([ln.length / 2])
        cands += [(ln.lane_id, float(v)) for v in s]
    if not cands:
        raise ValueError(f"town {town.name} has no road lanes outside junctions to start on")
    lanes = town.network.lanes
    pts = np.array([lanes[k].at(s)[0][:2] for k, s in cands])
    rng = np.random.default_rng(np.random.SeedSequence([seed, town.index, 0x65676F]))
    chosen = [int(rng.integers(len(cands)))]
    dist = np.hypot(*(pts - pts[chosen[0]]).T)
    while len(chosen) < count:
        k = int(np.argmax(dist))
        chosen.append(k)
        dist = np.minimum(dist, np.hypot(*(pts - pts[k]).T))
    return [cands[k] for k in chosen]


def _vehicle_pools(assets: Sequence[AssetRecord], net: RoadNetwork, town: str) -> dict[str, list[AssetRecord]]:
    """Vehicle assets by category that fit the road lanes (width + 0.1 m <= the 10th-percentile
    road lane width)."""
    widths = np.array([ln.width for ln in _road_lanes(net)])
    lane_w = float(np.percentile(widths, 10)) if len(widths) else 3.5
    pools = {c: [a for a in _assets_of(assets, c) if a.extent[1] <= lane_w - 0.1] for c in ("Car", "Truck", "Bus")}
    if not pools["Car"]:
        raise ValueError(f"no Car asset is narrower than the {lane_w:.2f} m lanes of {town} minus 0.1 m")
    return pools


def _pick_vehicle(rng: np.random.Generator, pools: dict[str, list[AssetRecord]]) -> AssetRecord:
    """A vehicle asset drawn by :data:`VEHICLE_MIX` over the categories that have assets."""
    cats = [(c, w) for c, w in VEHICLE_MIX if pools.get(c)]
    weights = np.array([w for _, w in cats])
    cat = cats[int(rng.choice(len(cats), p=weights / weights.sum()))][0]
    return pools[cat][int(rng.integers(len(pools[cat])))]


def _opposite_lane(net: RoadNetwork, lane: Lane, s: float) -> int:
    """A road lane passing within 10 m of ``lane`` at ``s`` running the other way, or -1."""
    mid, yaw = lane.at(s)
    best, best_d = -1, 10.0
    for ln in _road_lanes(net):
        if ln.length < 10.0:
            continue
        k = int(np.argmin(np.hypot(*(ln.points[:, :2] - mid[:2]).T)))
        p, y = ln.at(float(ln.cum[k]))
        d = float(np.hypot(*(p - mid)[:2]))
        if d < best_d and math.cos(float(y) - float(yaw)) < -0.8:
            best, best_d = ln.lane_id, d
    return best


# --------------------------------------------------------------------------------------------
# one sequence
# --------------------------------------------------------------------------------------------


def simulate_sequence(
    scenes: ScenesConfig, town: Town, assets: Sequence[AssetRecord], level_name: str, k: int,
    ego_start: tuple[int, float], match_phases=None,
) -> SequenceResult:  # fmt: skip
    """Spawn and simulate sequence ``k`` of ``level_name`` traffic through ``town`` with the ego
    starting at ``ego_start`` = (lane id, arc length). ``match_phases`` (the Skeletal Motion Analyzer's
    ``match_walker_phases``) fills ``phase_index`` of walkers; None leaves it empty."""
    if level_name not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {level_name!r}; valid: {', '.join(TRAFFIC_LEVELS)}")
    level = TRAFFIC_LEVELS[level_name]
    net = town.network
    level_no = list(TRAFFIC_LEVELS).index(level_name)
    seq_seed = int(np.random.SeedSequence([scenes.seed, town.index, level_no, k]).generate_state(1)[0])
    rng = np.random.default_rng(seq_seed)
    pools = _vehicle_pools(assets, net, town.name)
    pedestrians = _assets_of(assets, "Pedestrian")
    sim = Simulation(net, rng, level, EGO_GAP)
    vehicles, walkers = sim.driving.vehicles, sim.walking.walkers
    lanes = net.lanes

    # 1. the ego: a Car in the middle of its farthest-point lane
    ego_asset = pools["Car"][int(rng.integers(len(pools["Car"])))]
    ego_lane = ego_start[0]
    ego = Vehicle(ego_asset, ego_lane, ego_start[1], scenes.ego_speed, 1.0, v_fixed=scenes.ego_speed)
    vehicles.append(ego)
    placed: dict[int, list[tuple[float, float]]] = {ego_lane: [(ego.s, ego.length)]}

    def try_spawn(lane_id: int, s: float, asset: AssetRecord) -> bool:
        # a vehicle fits when it lies on a road lane and keeps its gap to the others there
        lane, L = lanes[lane_id], float(asset.extent[0])
        if lane.junction >= 0 or lane.width < asset.extent[1] + 0.1 or not (L / 2 + 1.0 <= s <= lane.length - L / 2 - 3.0):
            return False
        if any(abs(s - s2) < (L + L2) / 2 + level.gap + 3.0 for s2, L2 in placed.get(lane_id, [])):
            return False
        factor = 1.0 + level.speed_spread * float(rng.uniform(-1.0, 1.0))
        # start no faster than what stops before the lane end (a junction may follow)
        v_start = min(lane.speed_limit * factor, math.sqrt(2 * IDM_DECEL * max(0.0, lane.length - s - L / 2 - 3.0)))
        a = Vehicle(asset, lane_id, s, v_start, factor)
        vehicles.append(a)
        placed.setdefault(lane_id, []).append((s, L))
        return True

    km = net.road_length / 1000.0
    n_vehicles = min(MAX_VEHICLES, int(round(level.vehicles_per_km * km)))
    n_walkers = min(MAX_WALKERS, int(round(level.walkers_per_km * km)))
    if n_walkers and not pedestrians:
        raise ValueError(f"traffic level {level_name!r} needs Pedestrian assets for walkers; none given")

    # 2. escorts: cars ahead of and behind the ego along its route, beside it on a parallel lane,
    #    and ahead of it on a nearby lane running the other way
    sim.driving.plan(ego)
    route = [ego_lane, *ego.route]

    def along(d: float) -> tuple[int, float] | None:
        # the point d m along the ego's route from its centre (behind: on its own lane only)
        s = ego.s + d
        if s < 0:
            return None
        for ln in route:
            if s <= lanes[ln].length:
                return ln, s
            s -= lanes[ln].length
        return None

    # candidate spots in order of preference; the first MAX_ESCORTS that fit are taken
    escorts = [along(d) for d in (18.0, 36.0, -15.0, 26.0, 46.0, 12.0, -22.0)]
    side = lanes[ego_lane].left if lanes[ego_lane].left >= 0 else lanes[ego_lane].right
    if side >= 0:
        f = lanes[side].length / lanes[ego_lane].length
        escorts += [(side, (ego.s + d) * f) for d in (8.0, -10.0, 16.0)]
    opposite = _opposite_lane(net, lanes[ego_lane], ego.s)
    if opposite >= 0:
        # the point of the opposite lane beside the ego, then ahead of it (seen from the ego)
        op = lanes[opposite]
        beside = float(op.cum[np.argmin(np.hypot(*(op.points[:, :2] - lanes[ego_lane].at(ego.s)[0][:2]).T))])
        escorts += [(opposite, beside - d) for d in (8.0, 30.0, 0.0, 18.0, -10.0)]
    taken = 0
    for spot in escorts:
        if spot is None or taken >= min(MAX_ESCORTS, n_vehicles):
            continue
        taken += try_spawn(spot[0], spot[1], pools["Car"][int(rng.integers(len(pools["Car"])))])

    # 3. the other vehicles on random road lanes (weighted by length), a bounded number of tries
    road = _road_lanes(net)
    p_lane = np.array([ln.length for ln in road])
    p_lane /= p_lane.sum()
    tries = 0
    while len(vehicles) - 1 < n_vehicles and tries < 50 * max(n_vehicles, 1):
        tries += 1
        lane = road[int(rng.choice(len(road), p=p_lane))]
        try_spawn(lane.lane_id, float(rng.uniform(0.0, lane.length)), _pick_vehicle(rng, pools))
    safe_start_speeds(vehicles)

    # 4. walkers on sidewalks (not on crosswalks), spaced along their walkway
    sidewalks = [w for w in net.walkways if not w.crosswalk and w.length >= 1.0]
    tries = 0
    while sidewalks and len(walkers) < n_walkers and tries < 50 * n_walkers:
        tries += 1
        way = sidewalks[int(rng.integers(len(sidewalks)))]
        s = float(rng.uniform(0.0, way.length))
        p, _ = way.at(s)
        if any(float(np.hypot(*(w.pos - p)[:2])) < 2.0 for w in walkers):
            continue
        asset = pedestrians[int(rng.integers(len(pedestrians)))]
        speed = float(rng.uniform(0.8, 1.2) if asset.subclass == "child" else rng.uniform(1.1, 1.6))
        w = Walker(asset, way.walkway_id, s, 1 if rng.uniform() < 0.5 else -1, speed, p.copy(), 0.0,
                    phase=float(rng.uniform()))  # fmt: skip
        target, w.yaw = sim.walking.path_point(w)
        w.pos = target
        walkers.append(w)

    # 5. integrate, recording every agent's pose at every frame
    sequence_id = sequence_name(town.name, level_name, k)
    n_sub = max(1, math.ceil((1.0 / scenes.rate_hz) / MAX_SUBSTEP - 1e-9))
    dt = 1.0 / scenes.rate_hz / n_sub
    F, nv, nw = scenes.frame_count, len(vehicles), len(walkers)
    pos = np.zeros((F, nv + nw, 3))
    yaw = np.zeros((F, nv + nw))
    up = np.zeros((F, nv + nw, 3))
    up[..., 2] = 1.0  # walkers stay upright; vehicles stand on the road surface
    phase = np.full((F, nw), np.nan)
    for f in range(F):
        for i, a in enumerate(vehicles):
            pos[f, i], yaw[f, i], up[f, i] = vehicle_pose(lanes, a)
        for i, w in enumerate(walkers):
            pos[f, nv + i], yaw[f, nv + i] = w.pos, w.yaw
            phase[f, i] = w.phase if w.v >= STAND_SPEED else np.nan
        if f < F - 1:
            for _ in range(n_sub):
                sim.step(dt)
    times = np.arange(F) / scenes.rate_hz
    frames, sensors, actors = _records(scenes, sequence_id, times, pos, yaw, up, phase, vehicles, walkers,
                                       match_phases, town, seq_seed)  # fmt: skip
    sequence = SequenceRecord(
        sequence_id=sequence_id, town=town.name, seed=seq_seed, frame_count=F, rate_hz=scenes.rate_hz,
        traffic_level=level_name, ego_asset_id=ego_asset.asset_id,
    )  # fmt: skip
    return SequenceResult(
        sequence=sequence, frames=frames, sensor_poses=sensors, actors=actors,
        lane_changes=sum(a.lane_changes for a in vehicles), vehicles=nv - 1, walkers=nw,
    )  # fmt: skip


def safe_start_speeds(vehicles: list[Vehicle], decel: float = IDM_DECEL) -> None:
    """Slow down, in place, every spawned vehicle that could not stop behind the vehicle ahead of
    it on its lane: front to back per lane, a follower starts no faster than ``sqrt(v_lead**2 +
    2 * decel * gap)`` m/s (both braking at ``decel`` m/s2 to a stop end ``gap`` m apart, gap
    bumper to bumper). Vehicles with a fixed speed (the ego) keep it."""
    by_lane: dict[int, list[Vehicle]] = {}
    for a in vehicles:
        by_lane.setdefault(a.lane, []).append(a)
    for queue in by_lane.values():
        queue.sort(key=lambda a: -a.s)
        for lead, a in zip(queue, queue[1:]):
            gap = max(0.0, lead.s - a.s - (lead.length + a.length) / 2)
            if a.v_fixed is None:
                a.v = min(a.v, math.sqrt(lead.v**2 + 2 * decel * gap))


def _records(scenes, sequence_id, times, pos, yaw, up, phase, vehicles: list[Vehicle], walkers: list[Walker],
             match_phases, town: Town, seed: int):  # fmt: skip
    """Frame, sensor-pose and actor records from the simulated poses: positions ``pos`` (F, A, 3),
    headings ``yaw`` (F, A) and the upward normals ``up`` (F, A, 3) of the surface each agent
    stands on (pitch and roll follow from them); agent 0 is the ego. Velocities and angle rates
    are central differences over the frames (one-sided at the ends), angles unwrapped first."""
    F = len(times)
    pitch, roll = tilt_to_normal(yaw, up)
    yaw_u, roll_u = np.unwrap(yaw, axis=0), np.unwrap(roll, axis=0)
    if F >= 2:
        vel = np.gradient(pos, times, axis=0)
        rates = [np.gradient(a, times, axis=0) for a in (yaw_u, pitch, roll_u)]
    else:
        vel, rates = np.zeros_like(pos), [np.zeros_like(yaw)] * 3
    omega = angular_velocity(yaw, pitch, roll, *rates)  # (F, A, 3) world frame
    nv = len(vehicles)
    agents: list[AssetRecord] = [a.asset for a in vehicles] + [w.asset for w in walkers]
    phase_index: dict[int, list[int]] = {}
    if match_phases is not None:
        for i, w in enumerate(walkers):
            phase_index[i] = match_phases(times, pos[:, nv + i], yaw_u[:, nv + i], phase[:, i],
                                          float(w.asset.extent[2]), seed + i)  # fmt: skip
    rig = scenes.rig
    lidar_to_ego = np.asarray(rig.lidar.sensor_to_ego())
    cams = [(c.name, np.asarray(c.camera_to_ego())) for c in rig.cameras]
    first_instance = town.max_instance_id + 1
    frames, sensors, actors = [], [], []
    for f in range(F):
        ego_pose = pose_matrix(*pos[f, 0], yaw[f, 0], pitch[f, 0], roll[f, 0])
        lidar = ego_pose @ lidar_to_ego
        frames.append(FrameRecord(sequence_id=sequence_id, frame_index=f, timestamp=float(times[f]),
                                  ego_pose=pose_to_list(ego_pose), lidar_pose=pose_to_list(lidar)))  # fmt: skip
        for name, T in cams:
            sensors.append(SensorPoseRecord(sequence_id=sequence_id, frame_index=f, sensor=name,
                                            pose=pose_to_list(ego_pose @ T)))  # fmt: skip
        sensors.append(SensorPoseRecord(sequence_id=sequence_id, frame_index=f, sensor=rig.lidar.name,
                                        pose=pose_to_list(lidar)))  # fmt: skip
        for i in range(1, len(agents)):
            asset = agents[i]
            l, w, h = (float(e) for e in asset.extent)
            x, y, z = (float(c) for c in pos[f, i])
            if math.hypot(x - pos[f, 0, 0], y - pos[f, 0, 1]) > scenes.actor_range:
                continue
            walker = i - nv if i >= nv else -1
            gait = None if walker < 0 or not np.isfinite(phase[f, walker]) else float(phase[f, walker])
            pidx = phase_index[walker][f] if walker >= 0 and walker in phase_index else None
            pose = pose_matrix(x, y, z, yaw[f, i], pitch[f, i], roll[f, i])
            actors.append(ActorStateRecord(
                sequence_id=sequence_id, frame_index=f, instance_id=first_instance + i - 1, asset_id=asset.asset_id,
                semantic_id=asset.category_id, pose=pose_to_list(pose), box_center=box_center(pose, h),
                box_size=[l, w, h], yaw=float(math.remainder(yaw[f, i], 2 * math.pi)), pitch=float(pitch[f, i]),
                roll=float(roll[f, i]), velocity=[float(c) for c in vel[f, i]],
                angular_velocity=[float(c) for c in omega[f, i]], gait_phase=gait,
                phase_index=None if pidx is None else int(pidx),
            ))  # fmt: skip
    return frames, sensors, actors


def simulate_town(
    scenes: ScenesConfig, spec: TownSpec, town: Town, assets: Sequence[AssetRecord], match_phases=None
) -> list[SequenceResult]:
    """Every sequence of a town: ``spec.sequences_of(level)`` per traffic level, the egos' start
    lanes spread over the town by farthest-point sampling (in level order). Needs a Car asset
    (the ego) and, when a level has walkers, a Pedestrian asset."""
    if not _assets_of(assets, "Car"):
        cats = sorted({a.category for a in assets})
        raise ValueError(f"traffic needs at least one asset of category Car for the ego; got categories {cats}")
    jobs = [(level, k) for level in spec.traffic_levels for k in range(spec.sequences_of(level))]
    starts = ego_starts(town, len(jobs), scenes.seed)
    return [simulate_sequence(scenes, town, assets, level, k, lane, match_phases)
            for (level, k), lane in zip(jobs, starts)]  # fmt: skip
