"""Traffic sequences: an ego car driving through a procedural town among vehicles and walkers.

World frame of the town (metres, Z up, road at z = 0); time in seconds. Each sequence:

* **Ego** -- a Car asset on a lane chosen by farthest-point sampling over the town's lane starts
  (sequence k of a town starts as far as possible from sequences 0..k-1, as in the paper), with
  target speed ``config.ego_speed``. The ego is *not* an actor record: its pose is the frame's
  ``ego_pose`` (origin on the ground at the vehicle's bottom centre, +X forward) and
  ``lidar_pose = ego_pose @ translation(0, 0, 1.73)``.
* **Vehicles** (Car 80 %, Truck 10 %, Bus 10 % of the available assets) spawn on lanes at the
  traffic level's density per km of road centreline (DESIGN table: none/low/medium/high = 0/4/8/16
  per km, at most 128). Up to four of them are *escort* cars spawned around the ego -- two ahead on
  its lane, two on the opposite lane beside and ahead of it -- so the default occupancy region
  holds moving cars from the first frame. Target speeds are the urban limit times
  ``1 + spread * u``, u uniform in [-1, 1] (spread 30/35/40 %). Vehicles follow random routes over
  the lane graph (straight on or turning at each intersection, never U-turning) with the
  Intelligent Driver Model; the level's "gap to leader" is the IDM standstill gap. An
  intersection holds one vehicle at a time (first come, first served; a vehicle waits before the
  box until it is granted), so crossing traffic never interpenetrates.
* **Walkers** (Pedestrian assets; 0/2/4/8 per km, at most 64) walk the block sidewalk loops, one
  loop per direction, never overtaking; ``gait_phase`` advances by walked distance over the gait
  cycle length (two steps of 0.415 x body height) and wraps to [0, 1).

Actors are recorded in every frame, ordered by instance id; instance ids start above the town's
largest placement instance id and are stable across the sequence. Poses are asset-to-world,
``box_center`` is the world box centre at half height, ``box_size`` the asset extent (l, w, h),
``velocity`` the analytic world velocity (speed along the heading), m/s.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from schemas.configs import ScenesConfig
from schemas.records import ActorStateRecord, AssetRecord, FrameRecord, SequenceRecord
from stages.geometry import pose_matrix, pose_to_list
from stages.scenes.town import LaneSegment, Town

__all__ = ["SequenceResult", "TrafficLevel", "TRAFFIC_LEVELS", "simulate_sequences", "LIDAR_HEIGHT"]

LIDAR_HEIGHT = 1.73  # m above the ground, on the ego's vertical axis
URBAN_SPEED_LIMIT = 30.0 / 3.6  # m/s, reference speed of background vehicles
MAX_VEHICLES, MAX_WALKERS = 128, 64
VEHICLE_MIX = (("Car", 0.8), ("Truck", 0.1), ("Bus", 0.1))
MAX_SUBSTEP = 0.05  # s, longest integration step
# Intelligent Driver Model parameters (vehicles)
IDM_ACCEL, IDM_DECEL, IDM_HEADWAY, IDM_MAX_BRAKE = 1.5, 3.0, 1.2, 9.0  # m/s2, m/s2, s, m/s2
EGO_GAP = 3.0  # m, standstill gap of the ego
WALKER_GAP = 0.8  # m, walkers keep this much space to the walker ahead
STOP_BACK = 2.0  # m, vehicles wait this far (plus their standstill gap) before a closed intersection,
# clear of the front corners of long vehicles swinging out of a turn
GAIT_STEP = 0.415  # step length / body height


@dataclass(frozen=True)
class TrafficLevel:
    """Densities per km of road centreline, IDM standstill gap (m) and speed spread (fraction)."""

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
    """One simulated sequence: its record, one frame record per frame, actor states (frame-major,
    then instance id)."""

    sequence: SequenceRecord
    frames: list[FrameRecord]
    actors: list[ActorStateRecord]


# --------------------------------------------------------------------------------------------
# paths: polylines with cumulative arc length
# --------------------------------------------------------------------------------------------


@dataclass
class _Path:
    """A polyline path in the world xy plane (m) with its cumulative arc length, the arc-length
    intervals it spends inside intersections, and whether it is a closed loop."""

    xy: np.ndarray  # (K, 2)
    s: np.ndarray  # (K,)
    boxes: list[tuple[float, float, tuple[int, int]]] = field(default_factory=list)  # (s_in, s_out, node)
    closed: bool = False

    @classmethod
    def from_points(cls, points, boxes=(), closed: bool = False) -> _Path:
        """Path through ``points`` (repeated points dropped); a closed path returns to its start."""
        xy = np.asarray(points, dtype=np.float64)
        if closed:
            xy = np.vstack([xy, xy[:1]])
        keep = np.concatenate([[True], np.hypot(*np.diff(xy, axis=0).T) > 1e-9])
        xy = xy[keep]
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
        return cls(xy=xy, s=s, boxes=list(boxes), closed=closed)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def at(self, s: float) -> tuple[float, float, float]:
        """(x, y, yaw) at arc length ``s`` (wrapped on closed paths, clamped on open ones)."""
        s = s % self.length if self.closed else min(max(s, 0.0), self.length)
        i = min(max(int(np.searchsorted(self.s, s, side="right")) - 1, 0), len(self.s) - 2)
        (x0, y0), (x1, y1) = self.xy[i], self.xy[i + 1]
        t = (s - self.s[i]) / (self.s[i + 1] - self.s[i])
        return float(x0 + t * (x1 - x0)), float(y0 + t * (y1 - y0)), math.atan2(y1 - y0, x1 - x0)


def _successors(lanes: Sequence[LaneSegment]) -> dict[int, list[int]]:
    """Lane graph: the lanes a vehicle may take at the end of each lane (same lane index, any
    direction but back where it came from)."""
    starts: dict[tuple[tuple[int, int], int], list[LaneSegment]] = {}
    for lane in lanes:
        starts.setdefault((lane.start_node, lane.lane_index), []).append(lane)
    out = {}
    for lane in lanes:
        nxt = starts.get((lane.end_node, lane.lane_index), [])
        out[lane.lane_id] = [m.lane_id for m in nxt if m.end_node != lane.start_node]
    return out


def _connector(a: LaneSegment, b: LaneSegment, samples: int = 16) -> np.ndarray:
    """Interior points of the path through the intersection from the end of ``a`` to the start of
    ``b``: none when going straight, a quadratic Bezier around the corner point when turning."""
    da, db = np.asarray(a.direction), np.asarray(b.direction)
    if float(da @ db) > 0.99:
        return np.zeros((0, 2))
    p0, p1 = np.asarray(a.end), np.asarray(b.start)
    corner = p0 + da * float((p1 - p0) @ da)  # where the two lane lines cross
    t = np.linspace(0.0, 1.0, samples + 2)[1:-1, None]
    return (1 - t) ** 2 * p0 + 2 * t * (1 - t) * corner + t**2 * p1


def _rounded_loop(corners, radius: float = 0.8, samples: int = 12) -> np.ndarray:
    """Points of a closed polygon with every corner replaced by a circular arc of ``radius`` m
    (shrunk on short edges), so walkers turn smoothly."""
    c = np.asarray(corners, dtype=np.float64)
    out = []
    for k in range(len(c)):
        prev, here, nxt = c[k - 1], c[k], c[(k + 1) % len(c)]
        u_in, u_out = here - prev, nxt - here
        l_in, l_out = float(np.linalg.norm(u_in)), float(np.linalg.norm(u_out))
        u_in, u_out = u_in / l_in, u_out / l_out
        r = min(radius, 0.4 * l_in, 0.4 * l_out)
        # quadratic Bezier between the tangent points: for a right angle close to a circular arc
        p0, p1 = here - u_in * r, here + u_out * r
        t = np.linspace(0.0, 1.0, samples)[:, None]
        out.extend((1 - t) ** 2 * p0 + 2 * t * (1 - t) * here + t**2 * p1)
    return np.asarray(out)


def _route(
    lanes: Sequence[LaneSegment], succ: dict[int, list[int]], first: int, length: float, rng: np.random.Generator
) -> _Path:
    """A random route starting at the start of lane ``first``, at least ``length`` m long, with the
    arc-length intervals inside intersections recorded."""
    lane = lanes[first]
    points = [np.asarray(lane.start), np.asarray(lane.end)]
    s = lane.length
    boxes = []
    while s < length:
        options = succ[lane.lane_id]
        if not options:
            raise ValueError(f"lane {lane.lane_id} is a dead end; the road grid must be connected")
        nxt = lanes[options[int(rng.integers(len(options)))]]
        inner = _connector(lane, nxt)
        # arc length through the intersection: along the connector polyline to the next start
        chain = np.vstack([points[-1][None], inner, np.asarray(nxt.start)[None]])
        through = float(np.sum(np.hypot(*np.diff(chain, axis=0).T)))
        boxes.append((s, s + through, lane.end_node))
        points.extend(list(inner) + [np.asarray(nxt.start), np.asarray(nxt.end)])
        s += through + nxt.length
        lane = nxt
    return _Path.from_points(points, boxes)


# --------------------------------------------------------------------------------------------
# agents and the simulation step
# --------------------------------------------------------------------------------------------


@dataclass
class _Agent:
    """A simulated road user: its asset, path, arc length ``s`` (centre), speed, target speed."""

    asset: AssetRecord
    path: _Path
    s: float
    v: float
    v0: float
    z: float
    loop: int = -1  # walkers: index of their walk loop
    gait0: float = 0.0
    walked: float = 0.0
    box: int = 0  # vehicles: index of the next intersection interval not yet left

    @property
    def length(self) -> float:
        return float(self.asset.extent[0])

    @property
    def width(self) -> float:
        return float(self.asset.extent[1])


def _leader_gaps(vehicles: list[_Agent]) -> tuple[np.ndarray, np.ndarray]:
    """Bumper gap (m) to, and speed along our heading (m/s) of, the nearest vehicle ahead in our
    corridor (lateral overlap, heading within ~72 deg); inf / 0 when there is none."""
    n = len(vehicles)
    gaps, lead_v = np.full(n, np.inf), np.zeros(n)
    if n < 2:
        return gaps, lead_v
    state = np.array([v.path.at(v.s) for v in vehicles])
    pos, h = state[:, :2], np.column_stack([np.cos(state[:, 2]), np.sin(state[:, 2])])
    L = np.array([v.length for v in vehicles])
    W = np.array([v.width for v in vehicles])
    speed = np.array([v.v for v in vehicles])
    rel = pos[None, :, :] - pos[:, None, :]  # [i, j] = pos_j - pos_i
    along = np.einsum("ijk,ik->ij", rel, h)
    lateral = np.abs(rel[:, :, 0] * h[:, None, 1] - rel[:, :, 1] * h[:, None, 0])
    aligned = h @ h.T
    ahead = (along > 0) & (lateral < (W[:, None] + W[None, :]) / 2 + 0.3) & (aligned > 0.3)
    np.fill_diagonal(ahead, False)
    gap = np.where(ahead, along - (L[:, None] + L[None, :]) / 2, np.inf)
    j = np.argmin(gap, axis=1)
    gaps = gap[np.arange(n), j]
    lead_v = np.where(np.isfinite(gaps), speed[j] * aligned[np.arange(n), j], 0.0)
    return gaps, lead_v


def _idm(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, v_lead: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """Intelligent Driver Model acceleration (m/s2), clipped to [-IDM_MAX_BRAKE, IDM_ACCEL]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        free = 1.0 - np.where(v0 > 0, (v / np.where(v0 > 0, v0, 1.0)) ** 4, 1.0)
        s_star = s0 + np.maximum(0.0, v * IDM_HEADWAY + v * (v - v_lead) / (2 * math.sqrt(IDM_ACCEL * IDM_DECEL)))
        interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    acc = IDM_ACCEL * (free - interaction)
    return np.clip(acc, -IDM_MAX_BRAKE, IDM_ACCEL)


class _Intersections:
    """First-come-first-served intersection reservations: node -> vehicle index. A request's
    rank is the step at which the vehicle first asked for that box (then its distance, then its
    index), so a waiting vehicle is never starved by later arrivals."""

    def __init__(self) -> None:
        self.holder: dict[tuple[int, int], int] = {}
        self.since: dict[tuple[int, int], int] = {}  # (vehicle, box index) -> first request step
        self.step = 0

    def gaps(self, vehicles: list[_Agent], leader_gap: np.ndarray) -> np.ndarray:
        """Update reservations and return each vehicle's gap (m) to the edge of an intersection
        it may not enter yet (inf when free to go)."""
        n = len(vehicles)
        # 1. advance each vehicle past the boxes its rear has left, releasing what it held
        for i, a in enumerate(vehicles):
            while a.box < len(a.path.boxes) and a.s - a.length / 2 > a.path.boxes[a.box][1]:
                node = a.path.boxes[a.box][2]
                if self.holder.get(node) == i:
                    del self.holder[node]
                self.since.pop((i, a.box), None)
                a.box += 1
        # 2. requests from vehicles approaching their next box with no vehicle in between
        stop = np.full(n, np.inf)
        requests = []
        for i, a in enumerate(vehicles):
            if a.box >= len(a.path.boxes):
                continue
            s_in, _, node = a.path.boxes[a.box]
            d = s_in - (a.s + a.length / 2)
            if self.holder.get(node) == i:
                continue  # granted already
            if d <= 0:
                # inside without a grant (it could not stop in time): it claims a free box
                self.holder.setdefault(node, i)
                continue
            lookahead = a.v * a.v / (2 * IDM_DECEL) + 15.0
            if d < lookahead and leader_gap[i] > d:
                since = self.since.setdefault((i, a.box), self.step)
                requests.append((since, d, i, node))
            stop[i] = d - STOP_BACK
        # 3. grant free boxes to the earliest requester (distance, then index, break ties)
        for since, d, i, node in sorted(requests):
            if node not in self.holder:
                self.holder[node] = i
                stop[i] = np.inf
        self.step += 1
        return stop


def _walker_gaps(walkers: list[_Agent]) -> tuple[np.ndarray, np.ndarray]:
    """Gap (m) to, and speed of, the next walker ahead on the same loop (inf / 0 if alone)."""
    n = len(walkers)
    gaps, lead_v = np.full(n, np.inf), np.zeros(n)
    for i, a in enumerate(walkers):
        for j, b in enumerate(walkers):
            if i == j or a.loop != b.loop:
                continue
            ahead = (b.s - a.s) % a.path.length - (a.length + b.length) / 2
            if ahead < gaps[i]:
                gaps[i], lead_v[i] = ahead, b.v
    return gaps, lead_v


# --------------------------------------------------------------------------------------------
# spawning
# --------------------------------------------------------------------------------------------


def _assets_of(assets: Sequence[AssetRecord], category: str) -> list[AssetRecord]:
    """Assets of a category, in a stable order (sub-class, id)."""
    return sorted((a for a in assets if a.category == category), key=lambda a: (a.subclass, a.asset_id))


def _ego_starts(town: Town, count: int, seed: int) -> list[int]:
    """Farthest-point sampling over the starts of the centre-side lanes: the first at random, each
    next one farthest from those chosen (lowest lane id on ties)."""
    cands = [lane for lane in town.lanes if lane.lane_index == 0]
    pts = np.array([lane.start for lane in cands])
    rng = np.random.default_rng(np.random.SeedSequence([seed, town.index, 0x65676F]))
    chosen = [int(rng.integers(len(cands)))]
    dist = np.hypot(*(pts - pts[chosen[0]]).T)
    while len(chosen) < count:
        k = int(np.argmax(dist))
        chosen.append(k)
        dist = np.minimum(dist, np.hypot(*(pts - pts[k]).T))
    return [cands[k].lane_id for k in chosen]


def _pick_vehicle_asset(rng: np.random.Generator, pools: dict[str, list[AssetRecord]]) -> AssetRecord:
    """A vehicle asset drawn by :data:`VEHICLE_MIX` over the categories that have assets."""
    cats = [(c, w) for c, w in VEHICLE_MIX if pools.get(c)]
    weights = np.array([w for _, w in cats])
    cat = cats[int(rng.choice(len(cats), p=weights / weights.sum()))][0]
    return pools[cat][int(rng.integers(len(pools[cat])))]


def _simulate_one(
    config: ScenesConfig, town: Town, assets: Sequence[AssetRecord], k: int, ego_lane: int
) -> SequenceResult:
    """Spawn and simulate sequence ``k`` of ``town`` with the ego starting on ``ego_lane``."""
    level = TRAFFIC_LEVELS[config.traffic_level]
    seq_seed = int(np.random.SeedSequence([config.seed, town.index, k]).generate_state(1)[0])
    rng = np.random.default_rng(seq_seed)
    lanes, succ = town.lanes, _successors(town.lanes)
    # vehicles must fit their lane with 10 cm to spare (narrow roads take narrow vehicles only)
    lane_width = min(lane.width for lane in lanes)
    pools = {c: [a for a in _assets_of(assets, c) if a.extent[1] <= lane_width - 0.1] for c in ("Car", "Truck", "Bus")}
    pools["Pedestrian"] = _assets_of(assets, "Pedestrian")
    if not pools["Car"]:
        raise ValueError(
            f"no Car asset is narrower than the {lane_width:g} m lanes of {town.name} minus 0.1 m "
            f"(road_width {town.road_width:g} m); widen the road"
        )
    duration = (config.frame_count - 1) / config.rate_hz

    def route_length(s: float, v0: float) -> float:
        # enough path for the whole sequence at the target speed, plus a margin
        return s + 1.2 * v0 * duration + 60.0

    # 1. the ego: a Car on its farthest-point lane, a few metres past the intersection
    ego_asset = pools["Car"][int(rng.integers(len(pools["Car"])))]
    s_ego = ego_asset.extent[0] / 2 + 3.0
    ego = _Agent(ego_asset, _route(lanes, succ, ego_lane, route_length(s_ego, config.ego_speed), rng),
                 s_ego, config.ego_speed, config.ego_speed, 0.0)  # fmt: skip
    vehicles = [ego]
    on_lane: dict[int, list[tuple[float, float]]] = {ego_lane: [(s_ego, ego_asset.extent[0])]}

    def try_spawn(lane_id: int, s: float, asset: AssetRecord) -> bool:
        # a vehicle fits when it lies between the intersections and keeps its gap on the lane
        L, lane = asset.extent[0], lanes[lane_id]
        if not (L / 2 + 1.0 <= s <= lane.length - L / 2 - 3.0):
            return False
        if any(abs(s - s2) < (L + L2) / 2 + level.gap + 3.0 for s2, L2 in on_lane.get(lane_id, [])):
            return False
        v0 = URBAN_SPEED_LIMIT * (1.0 + level.speed_spread * float(rng.uniform(-1.0, 1.0)))
        vehicles.append(_Agent(asset, _route(lanes, succ, lane_id, route_length(s, v0), rng), s, v0, v0, 0.0))
        on_lane.setdefault(lane_id, []).append((s, L))
        return True

    km = town.road_length / 1000.0
    n_vehicles = min(MAX_VEHICLES, int(round(level.vehicles_per_km * km)))
    n_walkers = min(MAX_WALKERS, int(round(level.walkers_per_km * km)))
    if n_walkers and not pools["Pedestrian"]:
        raise ValueError(f"traffic level {config.traffic_level!r} needs Pedestrian assets for walkers; none given")

    # 2. escorts: cars ahead of the ego on its lane and on the opposite lane beside/ahead of it
    ego_l = lanes[ego_lane]
    opposite = [
        m.lane_id for m in lanes
        if (m.start_node, m.end_node, m.lane_index) == (ego_l.end_node, ego_l.start_node, 0)
    ]  # fmt: skip
    escorts = [(ego_lane, s_ego + 20.0), (ego_lane, s_ego + 38.0)]
    if opposite:
        escorts += [(opposite[0], ego_l.length - s_ego - 8.0), (opposite[0], ego_l.length - s_ego - 30.0)]
    for lane_id, s in escorts[: min(4, n_vehicles)]:
        try_spawn(lane_id, s, pools["Car"][int(rng.integers(len(pools["Car"])))])

    # 3. the remaining vehicles on random lanes (weighted by length), a bounded number of tries
    lane_p = np.array([lane.length for lane in lanes])
    lane_p /= lane_p.sum()
    tries = 0
    while len(vehicles) - 1 < n_vehicles and tries < 50 * max(n_vehicles, 1):
        tries += 1
        asset = _pick_vehicle_asset(rng, pools)
        lane_id = int(rng.choice(len(lanes), p=lane_p))
        try_spawn(lane_id, float(rng.uniform(0.0, lanes[lane_id].length)), asset)

    # 4. walkers on the sidewalk loops, spaced along each loop
    walkers: list[_Agent] = []
    loop_paths = [_Path.from_points(_rounded_loop(loop.corners), closed=True) for loop in town.walk_loops]
    tries = 0
    while len(walkers) < n_walkers and tries < 50 * n_walkers:
        tries += 1
        li = int(rng.integers(len(loop_paths)))
        path, s = loop_paths[li], float(rng.uniform(0.0, loop_paths[li].length))
        if any(w.loop == li and min((w.s - s) % path.length, (s - w.s) % path.length) < 2.0 for w in walkers):
            continue
        asset = pools["Pedestrian"][int(rng.integers(len(pools["Pedestrian"])))]
        speed = float(rng.uniform(0.8, 1.2) if asset.subclass == "child" else rng.uniform(1.1, 1.6))
        walkers.append(_Agent(asset, path, s, speed, speed, town.walk_loops[li].z, loop=li, gait0=float(rng.uniform())))

    # 5. integrate, recording every frame before stepping to the next
    sequence_id = f"{town.name}_seq{k:03d}"
    first_instance = town.max_instance_id + 1
    s0 = np.array([EGO_GAP] + [level.gap] * (len(vehicles) - 1))
    n_sub = max(1, math.ceil((1.0 / config.rate_hz) / MAX_SUBSTEP - 1e-9))
    dt = 1.0 / config.rate_hz / n_sub
    boxes = _Intersections()
    frames: list[FrameRecord] = []
    actors: list[ActorStateRecord] = []
    for f in range(config.frame_count):
        frames.append(_frame_record(sequence_id, f, f / config.rate_hz, ego))
        for idx, a in enumerate(vehicles[1:] + walkers):
            actors.append(_actor_record(sequence_id, f, first_instance + idx, a))
        if f == config.frame_count - 1:
            break
        for _ in range(n_sub):
            _step_vehicles(vehicles, boxes, s0, dt)
            _step_walkers(walkers, dt)

    sequence = SequenceRecord(
        sequence_id=sequence_id, town=town.name, seed=seq_seed, frame_count=config.frame_count,
        rate_hz=config.rate_hz, traffic_level=config.traffic_level, ego_asset_id=ego_asset.asset_id,
    )  # fmt: skip
    return SequenceResult(sequence=sequence, frames=frames, actors=actors)


def _step_vehicles(vehicles: list[_Agent], boxes: _Intersections, s0: np.ndarray, dt: float) -> None:
    """Advance every vehicle by ``dt`` s: leader and intersection gaps, IDM acceleration,
    trapezoidal position update along the path."""
    gaps, lead_v = _leader_gaps(vehicles)
    stop = boxes.gaps(vehicles, gaps)
    # the nearer of the leader and a closed intersection (a standing obstacle) governs
    use_stop = stop < gaps
    gap = np.where(use_stop, stop, gaps)
    v_lead = np.where(use_stop, 0.0, lead_v)
    v = np.array([a.v for a in vehicles])
    v0 = np.array([a.v0 for a in vehicles])
    v_new = np.maximum(0.0, v + _idm(v, v0, gap, v_lead, s0) * dt)
    v_new[v0 <= 0] = 0.0  # a parked ego stays parked
    for a, vn in zip(vehicles, v_new):
        a.s += 0.5 * (a.v + float(vn)) * dt
        a.v = float(vn)


def _step_walkers(walkers: list[_Agent], dt: float) -> None:
    """Advance every walker by ``dt`` s at its own pace, slowing to the walker ahead's pace when
    closer than :data:`WALKER_GAP` and stopping when closer than half of it (trapezoidal update,
    like the vehicles)."""
    gaps, lead_v = _walker_gaps(walkers)
    for a, g, lv in zip(walkers, gaps, lead_v):
        v = a.v0 if g > WALKER_GAP else (min(a.v0, lv) if g > WALKER_GAP / 2 else 0.0)
        step = 0.5 * (a.v + v) * dt
        a.s += step
        a.walked += step
        a.v = v


def _frame_record(sequence_id: str, index: int, t: float, ego: _Agent) -> FrameRecord:
    """Frame record of the ego's current state: ego-to-world and LiDAR-to-world poses."""
    x, y, yaw = ego.path.at(ego.s)
    ego_pose = pose_matrix(x, y, 0.0, yaw)
    lidar = ego_pose @ pose_matrix(0.0, 0.0, LIDAR_HEIGHT, 0.0)
    return FrameRecord(sequence_id=sequence_id, frame_index=index, timestamp=t,
                       ego_pose=pose_to_list(ego_pose), lidar_pose=pose_to_list(lidar))  # fmt: skip


def _actor_record(sequence_id: str, index: int, instance: int, a: _Agent) -> ActorStateRecord:
    """Actor state record of agent ``a`` now (walkers carry their gait phase)."""
    x, y, yaw = a.path.at(a.s)
    l, w, h = (float(e) for e in a.asset.extent)
    gait = None
    if a.loop >= 0:
        cycle = 2.0 * GAIT_STEP * h
        gait = float((a.gait0 + a.walked / cycle) % 1.0)
        gait = 0.0 if gait >= 1.0 else gait  # float wrap-around guard
    return ActorStateRecord(
        sequence_id=sequence_id, frame_index=index, instance_id=instance, asset_id=a.asset.asset_id,
        semantic_id=a.asset.category_id, pose=pose_to_list(pose_matrix(x, y, a.z, yaw)),
        box_center=[x, y, a.z + h / 2], box_size=[l, w, h], yaw=yaw,
        velocity=[a.v * math.cos(yaw), a.v * math.sin(yaw), 0.0], gait_phase=gait,
    )  # fmt: skip


def simulate_sequences(config: ScenesConfig, town: Town, assets: Sequence[AssetRecord]) -> list[SequenceResult]:
    """Simulate ``config.sequences_per_town`` sequences (ids ``"<town>_seq000"``...) of
    ``config.frame_count`` frames at ``config.rate_hz`` through ``town``. Deterministic from
    ``config.seed``, the town and the asset set. Needs a Car asset (the ego) and, when the traffic
    level has walkers, a Pedestrian asset."""
    if config.traffic_level not in TRAFFIC_LEVELS:
        raise ValueError(f"unknown traffic level {config.traffic_level!r}; valid: {', '.join(TRAFFIC_LEVELS)}")
    if not _assets_of(assets, "Car"):
        cats = sorted({a.category for a in assets})
        raise ValueError(
            f"simulate_sequences needs at least one asset of category Car for the ego; got categories {cats}"
        )
    if not town.lanes:
        raise ValueError(f"town {town.name} has no lanes to drive on")
    starts = _ego_starts(town, config.sequences_per_town, config.seed)
    return [_simulate_one(config, town, assets, k, lane) for k, lane in enumerate(starts)]
