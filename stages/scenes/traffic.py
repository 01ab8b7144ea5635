"""Traffic sequences: an ego car driving a route through a town among vehicles and walkers.

Works on any :class:`~stages.scenes.network.Town` (procedural or OpenDRIVE). World frame of the
town (metres, Z up); time in seconds; ``rate_hz`` frames per second (20 by default), integrated
in sub-steps of at most :data:`MAX_SUBSTEP`.

* **Ego** -- a Car asset starting on a lane chosen by farthest-point sampling over the lane
  starts of the town: the town's sequences start as far from each other as possible (the first
  at random). The ego is not an actor record; its pose is the frame's ``ego_pose`` (origin on the
  ground at the vehicle's bottom centre, +X forward) and the sensor poses follow from the rig.
* **Vehicles** (Car 80 %, Truck 10 %, Bus 10 % of the assets narrow enough for the lanes) spawn
  on road lanes at the traffic level's density per km of road (DESIGN table, at most 128). A few
  *escorts* spawn along the ego's route ahead of and behind it, beside it on a parallel lane and
  ahead of it on a nearby lane running the other way, so the occupancy
  region holds traffic from the first frame. Each vehicle's target speed is its lane's speed limit
  times ``1 + spread u`` (u uniform in [-1, 1]). Vehicles drive random routes over the lane graph
  with the Intelligent Driver Model (the level's "gap to leader" is the IDM standstill gap);
  leaders are found along the lanes (the vehicle's lane, the lanes it has planned next, and the
  lane a vehicle's rear still overhangs), not by straight-line distance, so curves do not confuse
  them.
* **Lane changes** (a MOBIL-style rule): on road lanes with a parallel neighbour, a vehicle held
  up by a slower leader moves over when the neighbour lane gives it a clear acceleration gain and
  the gaps to the new leader and the new follower are safe. The move takes :data:`LANE_CHANGE_TIME`
  s; meanwhile the vehicle occupies both lanes.
* **Junctions** are reserved: a vehicle enters a junction's connector lanes only when it holds
  the junction alone; walkers on its crosswalks hold it together. Requests are served first come,
  first served, so crossing traffic and pedestrians on crosswalks never interpenetrate.
* **Walkers** (Pedestrian assets; 0/2/4/8 per km, at most 64) walk the walk graph (sidewalks,
  and crosswalks when the junction is theirs), keep right, and yield to the walker ahead of them
  (the higher instance id yields when two block each other). ``gait_phase`` advances by walked
  distance over the gait cycle (two steps of 0.415 x body height) and is missing while standing;
  the Skeletal Motion Analyzer matches the canonical ``phase_index`` of every walker frame.

Recorded per frame: the frame (ego and LiDAR poses), every rig sensor's pose, and every actor
within ``actor_range`` m of the ego: stable instance id (numbered above the town's placements),
asset, class, pose (asset-to-world), 3D box (centre at half height, extent l, w, h), yaw,
linear and angular velocity (central differences of the simulated poses over the frames).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import ActorStateRecord, AssetRecord, FrameRecord, SensorPoseRecord, SequenceRecord
from carlaocc.stages.geometry import pose_matrix, pose_to_list
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town, Walkway

__all__ = [
    "SequenceResult", "TrafficLevel", "TRAFFIC_LEVELS", "simulate_sequence", "simulate_town", "sequence_name",
    "ego_starts",
]  # fmt: skip

MAX_VEHICLES, MAX_WALKERS = 128, 64
MAX_ESCORTS = 6  # cars spawned around the ego (counted in the level's vehicles)
VEHICLE_MIX = (("Car", 0.8), ("Truck", 0.1), ("Bus", 0.1))
MAX_SUBSTEP = 0.05  # s, longest integration step
# Intelligent Driver Model parameters (vehicles)
IDM_ACCEL, IDM_DECEL, IDM_HEADWAY, IDM_MAX_BRAKE = 1.5, 3.0, 1.2, 9.0  # m/s2, m/s2, s, m/s2
EGO_GAP = 3.0  # m, standstill gap of the ego
STOP_BACK = 0.5  # m, vehicles wait this far before the end of their lane when the junction is not theirs
LANE_CHANGE_TIME = 3.0  # s, duration of a lane change
LANE_CHANGE_GAIN = 0.3  # m/s2, acceleration advantage that makes a lane change worth it
LANE_CHANGE_SAFE = 2.0  # m/s2, the most a lane change may make the new follower brake
LANE_CHANGE_EVERY = 1.0  # s, how often a vehicle considers a lane change
LOOKAHEAD = 80.0  # m, how far along its route a vehicle looks for a leader
WALKER_CLEAR = 0.15  # m, walkers keep this much space between their boxes
WALKER_STEER = 1.5  # walkers move towards their path point at most this many times their speed
ASIDE_RATE = 0.4  # m/s: how fast a yielding walker steps aside (and back)
GAIT_STEP = 0.415  # step length / body height
STAND_SPEED = 0.1  # m/s: slower walkers stand (no gait phase)


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


# --------------------------------------------------------------------------------------------
# agents
# --------------------------------------------------------------------------------------------


@dataclass
class _Vehicle:
    """A vehicle on the lane graph: centre at arc length ``s`` on ``lane``; ``route`` holds the
    lanes planned after it; during a lane change ``lc_from`` is the lane it leaves and ``lc_t`` the
    elapsed time."""

    asset: AssetRecord
    lane: int
    s: float
    v: float
    v_factor: float  # target speed = lane speed limit x this (the ego: fixed speed, see v_fixed)
    route: list[int] = field(default_factory=list)
    prev: int = -1  # the lane before ``lane`` (its rear may still overhang it)
    lc_from: int = -1
    lc_t: float = 0.0
    next_lc_check: float = 0.0
    v_fixed: float | None = None
    lane_changes: int = 0

    @property
    def length(self) -> float:
        return float(self.asset.extent[0])

    @property
    def width(self) -> float:
        return float(self.asset.extent[1])


@dataclass
class _Walker:
    """A walker on the walk graph: on walkway ``way`` at arc length ``s``, walking towards its end
    (``sign`` +1) or its start (-1); ``pos`` its actual position (steered towards the path)."""

    asset: AssetRecord
    way: int
    s: float
    sign: int
    v0: float
    pos: np.ndarray
    yaw: float
    v: float = 0.0
    phase: float = 0.0
    plan: tuple[int, int] | None = None  # the walkway (and direction) taken at the next node
    walked: float = 0.0
    aside: float = 0.0  # m stepped aside (to the right) to let an oncoming walker pass

    @property
    def radius(self) -> float:
        return 0.5 * math.hypot(float(self.asset.extent[0]), float(self.asset.extent[1]))


def _smoothstep(t: float) -> float:
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def _s_on_old_lane(lanes: Sequence[Lane], a: _Vehicle) -> float:
    """Arc length on the lane a lane-changing vehicle leaves, at the same fraction of the lane."""
    return a.s * lanes[a.lc_from].length / lanes[a.lane].length


def _vehicle_pose(lanes: Sequence[Lane], a: _Vehicle) -> tuple[np.ndarray, float]:
    """World position (3,) and yaw of a vehicle: on its lane, or blended from the lane it leaves
    (at the same fraction of the lane) during a lane change."""
    lane = lanes[a.lane]
    p, yaw = lane.at(a.s)
    if a.lc_from < 0:
        return p, float(yaw)
    q, _ = lanes[a.lc_from].at(_s_on_old_lane(lanes, a))
    w = _smoothstep(a.lc_t / LANE_CHANGE_TIME)
    pos = q + w * (p - q)
    # heading: the lane's plus the drift angle of the lateral motion
    dw = 6.0 * (a.lc_t / LANE_CHANGE_TIME) * (1 - a.lc_t / LANE_CHANGE_TIME) / LANE_CHANGE_TIME
    lateral = float(np.hypot(*(p - q)[:2])) * dw
    normal = np.array([-math.sin(yaw), math.cos(yaw)])
    side = float(np.sign((p - q)[:2] @ normal))
    return pos, float(yaw) + math.atan2(side * lateral, max(a.v, 0.5))


def _idm(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, v_lead: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """Intelligent Driver Model acceleration (m/s2), clipped to [-IDM_MAX_BRAKE, IDM_ACCEL]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        free = 1.0 - np.where(v0 > 0, (v / np.where(v0 > 0, v0, 1.0)) ** 4, 1.0)
        s_star = s0 + np.maximum(0.0, v * IDM_HEADWAY + v * (v - v_lead) / (2 * math.sqrt(IDM_ACCEL * IDM_DECEL)))
        interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    return np.clip(IDM_ACCEL * (free - interaction), -IDM_MAX_BRAKE, IDM_ACCEL)


class _Occupancy:
    """Which vehicles are on which lane, at which arc length: a vehicle counts on its lane, on the
    lane it is leaving during a lane change, and on its previous lane while its rear overhangs it."""

    def __init__(self, lanes: Sequence[Lane], vehicles: Sequence[_Vehicle]) -> None:
        self.by_lane: dict[int, list[tuple[float, int]]] = {}
        for j, a in enumerate(vehicles):
            self.by_lane.setdefault(a.lane, []).append((a.s, j))
            if a.lc_from >= 0:
                self.by_lane.setdefault(a.lc_from, []).append((_s_on_old_lane(lanes, a), j))
            if a.prev >= 0 and a.s - a.length / 2 < 0:
                self.by_lane.setdefault(a.prev, []).append((lanes[a.prev].length + a.s, j))

    def leader(self, lanes, vehicles, i: int, lane: int, s: float, ahead: Sequence[int]) -> tuple[float, int]:
        """Bumper gap (m) to and index of the nearest vehicle ahead of vehicle ``i`` standing at
        ``s`` on ``lane`` and driving on over the lanes ``ahead``; (inf, -1) when none within
        :data:`LOOKAHEAD`."""
        me = vehicles[i]
        offset = -s
        for ln in [lane, *ahead]:
            best = None
            for s_j, j in self.by_lane.get(ln, ()):
                if j == i:
                    continue
                d = offset + s_j
                if d > 0 or (ln == lane and d == 0 and j > i):
                    if best is None or d < best[0]:
                        best = (d, j)
            if best is not None:
                d, j = best
                return d - (me.length + vehicles[j].length) / 2, j
            offset += lanes[ln].length
            if offset > LOOKAHEAD:
                break
        return math.inf, -1


class _Junctions:
    """Junction reservations, first come first served: one vehicle alone, or any number of
    walkers together. ``queue[j]`` holds pending requests ``(step, kind, index)``."""

    def __init__(self) -> None:
        self.vehicle: dict[int, int] = {}
        self.walkers: dict[int, set[int]] = {}
        self.queue: dict[int, dict[tuple[str, int], int]] = {}

    def free_for(self, junction: int, kind: str) -> bool:
        if junction in self.vehicle:
            return False
        return kind == "walker" or not self.walkers.get(junction)

    def request(self, junction: int, kind: str, index: int, step: int) -> None:
        self.queue.setdefault(junction, {}).setdefault((kind, index), step)

    def grant(self) -> None:
        """Serve each junction's queue in request order until a request must wait."""
        for junction, pending in self.queue.items():
            for (kind, index), _step in sorted(pending.items(), key=lambda kv: (kv[1], kv[0])):
                if not self.free_for(junction, kind):
                    break
                if kind == "vehicle":
                    self.vehicle[junction] = index
                else:
                    self.walkers.setdefault(junction, set()).add(index)
                del pending[(kind, index)]

    def holds(self, junction: int, kind: str, index: int) -> bool:
        if kind == "vehicle":
            return self.vehicle.get(junction) == index
        return index in self.walkers.get(junction, ())

    def release_all_but(self, keep: set[int], kind: str, index: int) -> None:
        """Release every junction held or requested by ``(kind, index)`` except those in ``keep``."""
        held = [j for j, h in self.vehicle.items() if h == index] if kind == "vehicle" else [
            j for j, ws in self.walkers.items() if index in ws]
        queued = [j for j, pending in self.queue.items() if (kind, index) in pending]
        for j in set(held + queued) - keep:
            self.release(j, kind, index)

    def release(self, junction: int, kind: str, index: int) -> None:
        if kind == "vehicle":
            if self.vehicle.get(junction) == index:
                del self.vehicle[junction]
        else:
            self.walkers.get(junction, set()).discard(index)
        self.queue.get(junction, {}).pop((kind, index), None)


# --------------------------------------------------------------------------------------------
# the simulation
# --------------------------------------------------------------------------------------------


class _Sim:
    """State and stepping of one sequence."""

    def __init__(self, network: RoadNetwork, rng: np.random.Generator, level: TrafficLevel, ego_gap: float):
        self.lanes = network.lanes
        self.ways = network.walkways
        self.rng = rng
        self.level = level
        self.vehicles: list[_Vehicle] = []
        self.walkers: list[_Walker] = []
        self.junctions = _Junctions()
        self.step_no = 0
        self.time = 0.0
        self.ego_gap = ego_gap
        self.preds: dict[int, list[int]] = {}
        for ln in self.lanes:
            for nxt in ln.successors:
                self.preds.setdefault(nxt, []).append(ln.lane_id)
        # walk graph: node -> [(walkway, sign of travel when leaving the node along it)]
        self.node_ways: dict[int, list[tuple[int, int]]] = {}
        for w in self.ways:
            self.node_ways.setdefault(w.start_node, []).append((w.walkway_id, 1))
            self.node_ways.setdefault(w.end_node, []).append((w.walkway_id, -1))

    # -- vehicles ---------------------------------------------------------------------------
    def plan(self, a: _Vehicle, metres: float = LOOKAHEAD + 20.0) -> None:
        """Extend ``a.route`` with random successors until it reaches ``metres`` past ``a.s``."""
        last = a.route[-1] if a.route else a.lane
        ahead = self.lanes[a.lane].length - a.s + sum(self.lanes[ln].length for ln in a.route)
        while ahead < metres:
            options = self.lanes[last].successors
            if not options:
                break
            last = options[int(self.rng.integers(len(options)))]
            a.route.append(last)
            ahead += self.lanes[last].length

    def target_speed(self, a: _Vehicle) -> float:
        return a.v_fixed if a.v_fixed is not None else self.lanes[a.lane].speed_limit * a.v_factor


    def junctions_wanted(self, a: _Vehicle) -> tuple[set[int], int, float]:
        """Junctions vehicle ``a`` is in (its lane, or the lane its rear overhangs), and the next
        junction on its route with the distance (m) from its front bumper to that junction's first
        connector (-1, inf when none within :data:`LOOKAHEAD`)."""
        lanes = self.lanes
        inside = {lanes[a.lane].junction} - {-1}
        if a.prev >= 0 and a.s - a.length / 2 < 0 and lanes[a.prev].junction >= 0:
            inside.add(lanes[a.prev].junction)
        dist = lanes[a.lane].length - a.s - a.length / 2
        for ln in a.route:
            j = lanes[ln].junction
            if j >= 0 and j not in inside:
                return inside, j, dist
            dist += lanes[ln].length
            if dist > LOOKAHEAD:
                break
        return inside, -1, math.inf

    def step_vehicles(self, dt: float) -> None:
        """Advance every vehicle by ``dt`` s: junction reservations, lane-based leaders, lane
        changes, IDM acceleration and a trapezoidal update along the lanes."""
        V, lanes, J = self.vehicles, self.lanes, self.junctions
        if not V:
            return
        n = len(V)
        occ = _Occupancy(lanes, V)
        gaps, lead_v = np.full(n, np.inf), np.zeros(n)
        for i, a in enumerate(V):
            g, j = occ.leader(lanes, V, i, a.lane, a.s, a.route)
            if a.lc_from >= 0:
                # changing lanes: still partly in the old lane, so its leader there counts too
                g2, j2 = occ.leader(lanes, V, i, a.lc_from, _s_on_old_lane(lanes, a), ())
                if g2 < g:
                    g, j = g2, j2
            gaps[i], lead_v[i] = g, (V[j].v if j >= 0 else 0.0)
        # 1. junctions: claim the one we are in, request the next one when close and first in line
        approach = np.full(n, -1)
        to_junction = np.full(n, np.inf)  # front bumper to the next junction's first connector
        for i, a in enumerate(V):
            inside, approach[i], to_junction[i] = self.junctions_wanted(a)
            for j in inside:
                if not J.holds(j, "vehicle", i) and J.free_for(j, "vehicle"):
                    J.vehicle[j] = i  # inside without a grant (spawned there): claim the free box
            near = a.v * a.v / (2 * IDM_DECEL) + 15.0
            if approach[i] >= 0 and to_junction[i] < near and gaps[i] > to_junction[i] - 1.0:
                J.request(int(approach[i]), "vehicle", i, self.step_no)
        J.grant()
        # blocked: a junction lies ahead that is not ours; stop before it
        blocked = np.array([approach[i] >= 0 and not J.holds(int(approach[i]), "vehicle", i) for i in range(n)])
        stop = np.where(blocked, to_junction - STOP_BACK, np.inf)
        use_stop = stop < gaps
        gap = np.where(use_stop, stop, gaps)
        v_lead = np.where(use_stop, 0.0, lead_v)
        v = np.array([a.v for a in V])
        v0 = np.array([self.target_speed(a) for a in V])
        s0 = np.array([self.ego_gap] + [self.level.gap] * (n - 1))
        acc = _idm(v, v0, gap, v_lead, s0)
        # 2. lane changes (never while a junction ahead is requested or held)
        for i, a in enumerate(V):
            if a.lc_from < 0 and self.time >= a.next_lc_check and approach[i] < 0:
                a.next_lc_check = self.time + LANE_CHANGE_EVERY
                self.consider_lane_change(i, float(acc[i]), float(gaps[i]), occ, float(s0[i]))
        # 3. move along the lanes, onto the planned ones
        v_new = np.maximum(0.0, v + acc * dt)
        v_new[v0 <= 0] = 0.0
        for i, (a, vn) in enumerate(zip(V, v_new)):
            step = 0.5 * (a.v + float(vn)) * dt
            if blocked[i] and step > to_junction[i]:
                step, vn = max(0.0, float(to_junction[i])), 0.0  # never enter a junction that is not ours
            a.s += step
            a.v = float(vn)
            if a.lc_from >= 0:
                a.lc_t += dt
                if a.lc_t >= LANE_CHANGE_TIME:
                    a.lc_from, a.lc_t = -1, 0.0
            while a.s > lanes[a.lane].length and a.route:
                a.lc_from, a.lc_t = -1, 0.0  # a lane change ends at the lane end at the latest
                a.s -= lanes[a.lane].length
                a.prev, a.lane = a.lane, a.route.pop(0)
            self.plan(a)
        # 4. release what each vehicle no longer needs (held or queued)
        for i, a in enumerate(V):
            inside, ahead, _ = self.junctions_wanted(a)
            keep = inside | ({ahead} - {-1})
            J.release_all_but(keep, "vehicle", i)

    def consider_lane_change(self, i: int, acc_now: float, gap_now: float, occ: _Occupancy, s0: float) -> None:
        """MOBIL-style: move to a parallel neighbour lane when it gives ``LANE_CHANGE_GAIN`` more
        acceleration than staying and both new gaps are safe for us and the new follower (the
        leader in the old lane still governs until the change is done)."""
        a, lanes, V = self.vehicles[i], self.lanes, self.vehicles
        lane = lanes[a.lane]
        if lane.junction >= 0 or a.v < 1.0 or a.prev >= 0 and a.s - a.length / 2 < 0:
            return
        if gap_now < s0 + 0.5 * a.v:
            return  # too close to the leader to pull out safely
        if lane.length - a.s < a.v * LANE_CHANGE_TIME + a.length + 5.0:
            return  # not enough lane left to finish the manoeuvre
        for target in (lane.left, lane.right):
            if target < 0 or lanes[target].width < a.width + 0.1:
                continue
            t_lane = lanes[target]
            s_t = a.s * t_lane.length / lane.length
            route_t: list[int] = []
            if t_lane.successors:
                route_t = [t_lane.successors[int(self.rng.integers(len(t_lane.successors)))]]
            g_lead, j_lead = occ.leader(lanes, V, i, target, s_t, route_t)
            # the new follower: the nearest vehicle behind us on the target lane
            g_back, j_back = math.inf, -1
            for s_j, j in occ.by_lane.get(target, ()):
                if j != i and s_j <= s_t:
                    g = s_t - s_j - (a.length + V[j].length) / 2
                    if g < g_back:
                        g_back, j_back = g, j
            for p in self.preds.get(target, ()):  # a follower still on the lane before the target
                for s_j, j in occ.by_lane.get(p, ()):
                    if j != i:
                        g = s_t + lanes[p].length - s_j - (a.length + V[j].length) / 2
                        if g < g_back:
                            g_back, j_back = g, j
            v_back = V[j_back].v if j_back >= 0 else 0.0
            if g_lead < s0 + 0.8 * a.v or g_back < self.level.gap + 0.8 * v_back:
                continue
            v_lead = V[j_lead].v if j_lead >= 0 else 0.0
            one = np.ones(1)
            acc_new = float(_idm(a.v * one, self.target_speed(a) * one, g_lead * one, v_lead * one, s0 * one)[0])
            if j_back >= 0:
                b = V[j_back]
                acc_back = _idm(b.v * one, self.target_speed(b) * one, g_back * one, a.v * one, self.level.gap * one)
                if float(acc_back[0]) < -LANE_CHANGE_SAFE:
                    continue
            if acc_new - acc_now > LANE_CHANGE_GAIN:
                a.lc_from, a.lc_t = a.lane, 0.0
                a.lane, a.s, a.route, a.prev = target, s_t, route_t, -1
                a.lane_changes += 1
                self.plan(a)
                return

    # -- walkers ----------------------------------------------------------------------------
    def walker_target(self, w: _Walker) -> tuple[np.ndarray, float]:
        """Path point (3,) and heading of a walker: its walkway point, kept right of the centre."""
        way = self.ways[w.way]
        p, yaw = way.at(w.s)
        yaw = float(yaw) if w.sign > 0 else float(yaw) + math.pi
        offset = min(0.45, way.width / 4) + w.aside
        return p + np.array([math.sin(yaw), -math.cos(yaw), 0.0]) * offset, yaw

    def remaining(self, w: _Walker) -> float:
        """Metres left on the walker's walkway in its walking direction."""
        return self.ways[w.way].length - w.s if w.sign > 0 else w.s

    def ensure_plan(self, w: _Walker) -> tuple[int, int]:
        """The walkway (and direction) a walker takes at its next node, drawn once: any other
        walkway at the node, or back along its own at a dead end."""
        if w.plan is None:
            way = self.ways[w.way]
            node = way.end_node if w.sign > 0 else way.start_node
            options = [(k, sg) for k, sg in self.node_ways.get(node, []) if k != w.way] or [(w.way, -w.sign)]
            w.plan = options[int(self.rng.integers(len(options)))]
        return w.plan

    def crossing_ahead(self, w: _Walker, index: int) -> tuple[int, float] | None:
        """(junction, metres to it) of a crosswalk the walker is about to step on without holding
        its junction, when within 3 m of it; else None."""
        r = self.remaining(w)
        if r > 3.0:
            return None
        nxt = self.ways[self.ensure_plan(w)[0]]
        if nxt.crosswalk and nxt.junction >= 0 and not self.junctions.holds(nxt.junction, "walker", index):
            return nxt.junction, r
        return None

    def step_walkers(self, dt: float) -> None:
        """Advance every walker by ``dt`` s: yield to walkers ahead, wait for the junction of a
        crosswalk, walk along the graph, steer towards the path point."""
        W, J = self.walkers, self.junctions
        if not W:
            return
        pos = np.array([w.pos[:2] for w in W])
        heading = np.array([[math.cos(w.yaw), math.sin(w.yaw)] for w in W])
        radius = np.array([w.radius for w in W])
        rel = pos[None, :, :] - pos[:, None, :]  # [i, j] = pos_j - pos_i
        along = np.einsum("ijk,ik->ij", rel, heading)
        lateral = np.abs(rel[:, :, 0] * heading[:, None, 1] - rel[:, :, 1] * heading[:, None, 0])
        reach = radius[:, None] + radius[None, :] + WALKER_CLEAR
        ahead = (along > -0.5 * reach) & (lateral < reach)
        np.fill_diagonal(ahead, False)
        # two walkers blocking each other: the higher index steps aside (to its right) until the
        # other can pass; both keep their distance meanwhile
        idx = np.arange(len(W))
        yields = (ahead & ahead.T & (idx[:, None] > idx[None, :])).any(axis=1)
        gap = np.where(ahead, np.hypot(along, lateral) - reach, np.inf).min(axis=1)
        for i, w in enumerate(W):
            room = max(0.0, self.ways[w.way].width / 2 - min(0.45, self.ways[w.way].width / 4) - 0.3)
            w.aside = min(room, w.aside + ASIDE_RATE * dt) if yields[i] else max(0.0, w.aside - ASIDE_RATE * dt)
        crossing = [self.crossing_ahead(w, i) for i, w in enumerate(W)]
        for i, c in enumerate(crossing):
            if c is not None and c[1] < 2.0:
                J.request(c[0], "walker", i, self.step_no)
        J.grant()
        where = np.array([w.pos[:2] for w in W])  # current positions, updated as walkers move
        for i, w in enumerate(W):
            w.v = w.v0 if gap[i] > 0.6 else (0.5 * w.v0 if gap[i] > 0.2 else 0.0)
            before = (w.way, w.s, w.sign, w.plan, w.pos, w.walked)
            step = w.v * dt
            c = crossing[i]
            if c is not None and not J.holds(c[0], "walker", i):
                step = min(step, max(0.0, c[1] - 0.4))  # wait at the kerb
                w.v = step / dt
            w.walked += step
            while step > 0:
                r = self.remaining(w)
                if step <= r:
                    w.s += w.sign * step
                    break
                step -= r
                w.way, w.sign = self.ensure_plan(w)
                w.plan = None
                w.s = 0.0 if w.sign > 0 else self.ways[w.way].length
            target, yaw = self.walker_target(w)
            # steer: move towards the path point at a bounded speed (no jumps at corners)
            d = target - w.pos
            dist = float(np.linalg.norm(d[:2]))
            cap = max(w.v, 0.3) * WALKER_STEER * dt
            if dist > cap:
                d = d * (cap / dist)
            w.pos = w.pos + d
            # hard rule: a move that would bring the walker's disc into another's is not made
            near = np.hypot(*(where - w.pos[:2]).T) < radius + radius[i]
            near[i] = False
            if near.any():
                w.way, w.s, w.sign, w.plan, w.pos, w.walked = before
                w.v = 0.0
                continue
            where[i] = w.pos[:2]
            if w.v > 0:
                w.yaw = math.atan2(d[1], d[0]) if dist > 0.05 * dt else yaw
            w.phase = (w.phase + w.v * dt / (2.0 * GAIT_STEP * float(w.asset.extent[2]))) % 1.0
            # hold a junction only while on one of its crosswalks
            way = self.ways[w.way]
            keep = {way.junction} if way.crosswalk and way.junction >= 0 else set()
            J.release_all_but(keep | ({c[0]} if c is not None else set()), "walker", i)

    def step(self, dt: float) -> None:
        self.step_vehicles(dt)
        self.step_walkers(dt)
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
    sim = _Sim(net, rng, level, EGO_GAP)
    lanes = net.lanes

    # 1. the ego: a Car in the middle of its farthest-point lane
    ego_asset = pools["Car"][int(rng.integers(len(pools["Car"])))]
    ego_lane = ego_start[0]
    ego = _Vehicle(ego_asset, ego_lane, ego_start[1], scenes.ego_speed, 1.0, v_fixed=scenes.ego_speed)
    sim.vehicles.append(ego)
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
        a = _Vehicle(asset, lane_id, s, v_start, factor)
        sim.vehicles.append(a)
        placed.setdefault(lane_id, []).append((s, L))
        return True

    km = net.road_length / 1000.0
    n_vehicles = min(MAX_VEHICLES, int(round(level.vehicles_per_km * km)))
    n_walkers = min(MAX_WALKERS, int(round(level.walkers_per_km * km)))
    if n_walkers and not pedestrians:
        raise ValueError(f"traffic level {level_name!r} needs Pedestrian assets for walkers; none given")

    # 2. escorts: cars ahead of and behind the ego along its route, beside it on a parallel lane,
    #    and ahead of it on a nearby lane running the other way
    sim.plan(ego)
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
    while len(sim.vehicles) - 1 < n_vehicles and tries < 50 * max(n_vehicles, 1):
        tries += 1
        lane = road[int(rng.choice(len(road), p=p_lane))]
        try_spawn(lane.lane_id, float(rng.uniform(0.0, lane.length)), _pick_vehicle(rng, pools))

    # 4. walkers on sidewalks (not on crosswalks), spaced along their walkway
    sidewalks = [w for w in net.walkways if not w.crosswalk and w.length >= 1.0]
    tries = 0
    while sidewalks and len(sim.walkers) < n_walkers and tries < 50 * n_walkers:
        tries += 1
        way = sidewalks[int(rng.integers(len(sidewalks)))]
        s = float(rng.uniform(0.0, way.length))
        p, _ = way.at(s)
        if any(float(np.hypot(*(w.pos - p)[:2])) < 2.0 for w in sim.walkers):
            continue
        asset = pedestrians[int(rng.integers(len(pedestrians)))]
        speed = float(rng.uniform(0.8, 1.2) if asset.subclass == "child" else rng.uniform(1.1, 1.6))
        w = _Walker(asset, way.walkway_id, s, 1 if rng.uniform() < 0.5 else -1, speed, p.copy(), 0.0,
                    phase=float(rng.uniform()))  # fmt: skip
        target, w.yaw = sim.walker_target(w)
        w.pos = target
        sim.walkers.append(w)

    # 5. integrate, recording every agent's pose at every frame
    sequence_id = sequence_name(town.name, level_name, k)
    n_sub = max(1, math.ceil((1.0 / scenes.rate_hz) / MAX_SUBSTEP - 1e-9))
    dt = 1.0 / scenes.rate_hz / n_sub
    F, nv, nw = scenes.frame_count, len(sim.vehicles), len(sim.walkers)
    pos = np.zeros((F, nv + nw, 3))
    yaw = np.zeros((F, nv + nw))
    phase = np.full((F, nw), np.nan)
    for f in range(F):
        for i, a in enumerate(sim.vehicles):
            pos[f, i], yaw[f, i] = _vehicle_pose(lanes, a)
        for i, w in enumerate(sim.walkers):
            pos[f, nv + i], yaw[f, nv + i] = w.pos, w.yaw
            phase[f, i] = w.phase if w.v >= STAND_SPEED else np.nan
        if f < F - 1:
            for _ in range(n_sub):
                sim.step(dt)
    times = np.arange(F) / scenes.rate_hz
    frames, sensors, actors = _records(scenes, sequence_id, times, pos, yaw, phase, sim, match_phases, town,
                                       seq_seed)  # fmt: skip
    sequence = SequenceRecord(
        sequence_id=sequence_id, town=town.name, seed=seq_seed, frame_count=F, rate_hz=scenes.rate_hz,
        traffic_level=level_name, ego_asset_id=ego_asset.asset_id,
    )  # fmt: skip
    return SequenceResult(
        sequence=sequence, frames=frames, sensor_poses=sensors, actors=actors,
        lane_changes=sum(a.lane_changes for a in sim.vehicles), vehicles=nv - 1, walkers=nw,
    )  # fmt: skip


def _records(scenes, sequence_id, times, pos, yaw, phase, sim: _Sim, match_phases, town: Town, seed: int):
    """Frame, sensor-pose and actor records from the simulated poses ``pos`` (F, A, 3) and
    ``yaw`` (F, A); agent 0 is the ego. Velocities are central differences over the frames
    (one-sided at the ends); yaw is unwrapped first."""
    F = len(times)
    yaw_u = np.unwrap(yaw, axis=0)
    if F >= 2:
        vel = np.gradient(pos, times, axis=0)
        yaw_rate = np.gradient(yaw_u, times, axis=0)
    else:
        vel, yaw_rate = np.zeros_like(pos), np.zeros_like(yaw)
    nv = len(sim.vehicles)
    agents: list[AssetRecord] = [a.asset for a in sim.vehicles] + [w.asset for w in sim.walkers]
    phase_index: dict[int, list[int]] = {}
    if match_phases is not None:
        for i, w in enumerate(sim.walkers):
            phase_index[i] = match_phases(times, pos[:, nv + i], yaw_u[:, nv + i], phase[:, i],
                                          float(w.asset.extent[2]), seed + i)  # fmt: skip
    rig = scenes.rig
    lidar_to_ego = np.asarray(rig.lidar.sensor_to_ego())
    cams = [(c.name, np.asarray(c.camera_to_ego())) for c in rig.cameras]
    first_instance = town.max_instance_id + 1
    frames, sensors, actors = [], [], []
    for f in range(F):
        ego_pose = pose_matrix(pos[f, 0, 0], pos[f, 0, 1], pos[f, 0, 2], yaw[f, 0])
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
            actors.append(ActorStateRecord(
                sequence_id=sequence_id, frame_index=f, instance_id=first_instance + i - 1, asset_id=asset.asset_id,
                semantic_id=asset.category_id, pose=pose_to_list(pose_matrix(x, y, z, yaw[f, i])),
                box_center=[x, y, z + h / 2], box_size=[l, w, h], yaw=float(math.remainder(yaw[f, i], 2 * math.pi)),
                velocity=[float(c) for c in vel[f, i]], angular_velocity=[0.0, 0.0, float(yaw_rate[f, i])],
                gait_phase=gait, phase_index=None if pidx is None else int(pidx),
            ))  # fmt: skip
    return frames, sensors, actors


def simulate_town(
    scenes: ScenesConfig, spec: TownSpec, town: Town, assets: Sequence[AssetRecord], match_phases=None
) -> list[SequenceResult]:
    """Every sequence of a town: ``spec.sequences_per_level`` per traffic level, the egos' start
    lanes spread over the town by farthest-point sampling (in level order). Needs a Car asset
    (the ego) and, when a level has walkers, a Pedestrian asset."""
    if not _assets_of(assets, "Car"):
        cats = sorted({a.category for a in assets})
        raise ValueError(f"traffic needs at least one asset of category Car for the ego; got categories {cats}")
    jobs = [(level, k) for level in spec.traffic_levels for k in range(spec.sequences_per_level)]
    starts = ego_starts(town, len(jobs), scenes.seed)
    return [simulate_sequence(scenes, town, assets, level, k, lane, match_phases)
            for (level, k), lane in zip(jobs, starts)]  # fmt: skip
