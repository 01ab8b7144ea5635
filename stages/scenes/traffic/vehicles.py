"""Vehicles of a traffic sequence (:mod:`carlaocc.stages.scenes.traffic.simulation`): vehicles on the lane
graph driven by the Intelligent Driver Model, leaders found along the lanes, MOBIL-style lane
changes and junction reservations (:mod:`~carlaocc.stages.scenes.traffic.junctions`).

World frame of the town: metres, Z up; time in seconds, speeds in m/s, accelerations in m/s2.
A vehicle's position is its centre's arc length ``s`` (m) along its lane; gaps are bumper to
bumper along the lanes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.scenes.network import Lane
from carlaocc.stages.scenes.traffic.junctions import JunctionReservations

__all__ = [
    "EGO_GAP", "IDM_DECEL", "LANE_CHANGE_TIME", "LOOKAHEAD", "LaneOccupancy", "Vehicle", "VehicleTraffic", "idm",
    "vehicle_pose",
]  # fmt: skip

# Intelligent Driver Model parameters (vehicles)
IDM_ACCEL, IDM_DECEL, IDM_HEADWAY, IDM_MAX_BRAKE = 1.5, 3.0, 1.2, 9.0  # m/s2, m/s2, s, m/s2
EGO_GAP = 3.0  # m, standstill gap of the ego
STOP_BACK = 0.5  # m, vehicles wait this far before the end of their lane when the junction is not theirs
LANE_CHANGE_TIME = 3.0  # s, duration of a lane change
LANE_CHANGE_GAIN = 0.3  # m/s2, acceleration advantage that makes a lane change worth it
LANE_CHANGE_SAFE = 2.0  # m/s2, the most a lane change may make the new follower brake
LANE_CHANGE_EVERY = 1.0  # s, how often a vehicle considers a lane change
LOOKAHEAD = 80.0  # m, how far along its route a vehicle looks for a leader
@dataclass
class Vehicle:
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


def smoothstep(t: float) -> float:
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def s_on_old_lane(lanes: Sequence[Lane], a: Vehicle) -> float:
    """Arc length on the lane a lane-changing vehicle leaves, at the same fraction of the lane."""
    return a.s * lanes[a.lc_from].length / lanes[a.lane].length


def vehicle_pose(lanes: Sequence[Lane], a: Vehicle) -> tuple[np.ndarray, float, np.ndarray]:
    """World position (3,), yaw (rad) and the road surface's upward unit normal (3,) under a
    vehicle: on its lane, or blended from the lane it leaves (at the same fraction of the lane)
    during a lane change. The vehicle stands on the surface: its up axis is the normal
    (:func:`carlaocc.stages.geometry.tilt_to_normal` turns it into pitch and roll)."""
    lane = lanes[a.lane]
    p, yaw = lane.at(a.s)
    up = lane.up_at(a.s)
    if a.lc_from < 0:
        return p, float(yaw), up
    s_old = s_on_old_lane(lanes, a)
    q, _ = lanes[a.lc_from].at(s_old)
    w = smoothstep(a.lc_t / LANE_CHANGE_TIME)
    # between two points of one cross section the blend stays on a planar (banked) surface
    pos = q + w * (p - q)
    n = lanes[a.lc_from].up_at(s_old)
    n = n + w * (up - n)
    # heading: the lane's plus the drift angle of the lateral motion
    dw = 6.0 * (a.lc_t / LANE_CHANGE_TIME) * (1 - a.lc_t / LANE_CHANGE_TIME) / LANE_CHANGE_TIME
    lateral = float(np.hypot(*(p - q)[:2])) * dw
    normal = np.array([-math.sin(yaw), math.cos(yaw)])
    side = float(np.sign((p - q)[:2] @ normal))
    return pos, float(yaw) + math.atan2(side * lateral, max(a.v, 0.5)), n / np.linalg.norm(n)


def idm(v: np.ndarray, v0: np.ndarray, gap: np.ndarray, v_lead: np.ndarray, s0: np.ndarray) -> np.ndarray:
    """Intelligent Driver Model acceleration (m/s2), clipped to [-IDM_MAX_BRAKE, IDM_ACCEL]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        free = 1.0 - np.where(v0 > 0, (v / np.where(v0 > 0, v0, 1.0)) ** 4, 1.0)
        s_star = s0 + np.maximum(0.0, v * IDM_HEADWAY + v * (v - v_lead) / (2 * math.sqrt(IDM_ACCEL * IDM_DECEL)))
        interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
    return np.clip(IDM_ACCEL * (free - interaction), -IDM_MAX_BRAKE, IDM_ACCEL)


class LaneOccupancy:
    """Which vehicles are on which lane, at which arc length: a vehicle counts on its lane, on the
    lane it is leaving during a lane change, and on its previous lane while its rear overhangs it."""

    def __init__(self, lanes: Sequence[Lane], vehicles: Sequence[Vehicle]) -> None:
        self.by_lane: dict[int, list[tuple[float, int]]] = {}
        for j, a in enumerate(vehicles):
            self.by_lane.setdefault(a.lane, []).append((a.s, j))
            if a.lc_from >= 0:
                self.by_lane.setdefault(a.lc_from, []).append((s_on_old_lane(lanes, a), j))
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

class VehicleTraffic:
    """The vehicles of one sequence (the ego first) on the lane graph: route planning, junction
    reservations, leaders, lane changes and the IDM update. ``gap`` is the traffic level's IDM
    standstill gap (m), ``ego_gap`` the ego's; random draws (routes) come from ``rng``."""

    def __init__(self, lanes: Sequence[Lane], rng: np.random.Generator, gap: float, ego_gap: float,
                 junctions: JunctionReservations) -> None:  # fmt: skip
        self.lanes = lanes
        self.rng = rng
        self.gap = gap
        self.ego_gap = ego_gap
        self.junctions = junctions
        self.vehicles: list[Vehicle] = []
        self.preds: dict[int, list[int]] = {}
        for ln in self.lanes:
            for nxt in ln.successors:
                self.preds.setdefault(nxt, []).append(ln.lane_id)

    def plan(self, a: Vehicle, metres: float = LOOKAHEAD + 20.0) -> None:
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

    def target_speed(self, a: Vehicle) -> float:
        return a.v_fixed if a.v_fixed is not None else self.lanes[a.lane].speed_limit * a.v_factor

    def junctions_wanted(self, a: Vehicle) -> tuple[set[int], int, float]:
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

    def step(self, dt: float, step_no: int, time: float) -> None:
        """Advance every vehicle by ``dt`` s from ``time`` (s), integration step ``step_no``:
        junction reservations, lane-based leaders, lane changes, IDM acceleration and a
        trapezoidal update along the lanes."""
        V, lanes, J = self.vehicles, self.lanes, self.junctions
        if not V:
            return
        n = len(V)
        occ = LaneOccupancy(lanes, V)
        gaps, lead_v = np.full(n, np.inf), np.zeros(n)
        for i, a in enumerate(V):
            g, j = occ.leader(lanes, V, i, a.lane, a.s, a.route)
            if a.lc_from >= 0:
                # changing lanes: still partly in the old lane, so its leader there counts too
                g2, j2 = occ.leader(lanes, V, i, a.lc_from, s_on_old_lane(lanes, a), ())
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
                J.request(int(approach[i]), "vehicle", i, step_no)
        J.grant()
        # blocked: a junction lies ahead that is not ours; stop before it
        blocked = np.array([approach[i] >= 0 and not J.holds(int(approach[i]), "vehicle", i) for i in range(n)])
        stop = np.where(blocked, to_junction - STOP_BACK, np.inf)
        use_stop = stop < gaps
        gap = np.where(use_stop, stop, gaps)
        v_lead = np.where(use_stop, 0.0, lead_v)
        v = np.array([a.v for a in V])
        v0 = np.array([self.target_speed(a) for a in V])
        s0 = np.array([self.ego_gap] + [self.gap] * (n - 1))
        acc = idm(v, v0, gap, v_lead, s0)
        # 2. lane changes (never while a junction ahead is requested or held)
        for i, a in enumerate(V):
            if a.lc_from < 0 and time >= a.next_lc_check and approach[i] < 0:
                a.next_lc_check = time + LANE_CHANGE_EVERY
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

    def consider_lane_change(self, i: int, acc_now: float, gap_now: float, occ: LaneOccupancy, s0: float) -> None:
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
            if g_lead < s0 + 0.8 * a.v or g_back < self.gap + 0.8 * v_back:
                continue
            v_lead = V[j_lead].v if j_lead >= 0 else 0.0
            one = np.ones(1)
            acc_new = float(idm(a.v * one, self.target_speed(a) * one, g_lead * one, v_lead * one, s0 * one)[0])
            if j_back >= 0:
                b = V[j_back]
                acc_back = idm(b.v * one, self.target_speed(b) * one, g_back * one, a.v * one, self.gap * one)
                if float(acc_back[0]) < -LANE_CHANGE_SAFE:
                    continue
            if acc_new - acc_now > LANE_CHANGE_GAIN:
                a.lc_from, a.lc_t = a.lane, 0.0
                a.lane, a.s, a.route, a.prev = target, s_t, route_t, -1
                a.lane_changes += 1
                self.plan(a)
                return
