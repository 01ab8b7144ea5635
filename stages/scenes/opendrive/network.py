"""OpenDRIVE town network: the lane graph and the walk graph of a parsed network
(:mod:`carlaocc.schemas.opendrive`) on the town contract (:mod:`carlaocc.stages.scenes.network`);
part of :mod:`carlaocc.stages.scenes.opendrive.town`.

World frame = the file's inertial frame (metres, right-handed, Z up).

* **Lanes** (contract :class:`~carlaocc.stages.scenes.network.Lane`): one per (road, lane section,
  driving lane) whose width reaches 1 m: the centre line sampled every <= 1 m at the road surface,
  in the travel direction (right-hand traffic: negative ids along +s, positive ids against s),
  with the road surface's upward normal at each point (elevation and superelevation).
  Successors follow lane links inside a road, road links (``elementType="road"`` with the lane's
  successor / predecessor id) and junction connections (``incomingRoad`` + ``laneLink from``); a
  link is kept only when the lane's end meets the successor's start within :data:`JOIN_TOL` m
  horizontally and :data:`JOIN_STEP` m vertically (the rest are counted as mismatches). The
  vertical allowance matters on hilly maps: a lane's height is its road's reference-line
  elevation (plus superelevation), and a junction connector whose reference line starts beside
  the incoming lane's (CARLA's towns have no superelevation) meets it a few decimetres higher or
  lower on a slope; such links are kept and counted as ``link_steps``. Left / right neighbours: adjacent driving lanes of the
  same section and side. Connector lanes carry ``junction`` = the junction's id as an int (the
  file's id when every junction id is an integer, else the position in sorted id order). Only the
  lanes on a cycle are kept (every strongly connected component of at least two lanes: no route
  dead-ends), renumbered to positions.
  ``road_length`` = the summed length of the non-junction roads that keep at least one lane.
* **Walkways**: one per (road, section, sidewalk lane): its centre line on the raised surface.
  Ends closer than :data:`WALK_JOIN` m share a walk-graph node (sidewalks continue across
  sections, roads and junction corners). **Crosswalks**: at every end of a non-junction road
  that links to a junction and has sidewalks on both sides, a straight walkway across the road's
  cross-section at that end (the junction entry) joining the innermost sidewalk of each side;
  it carries the junction's id.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from carlaocc.schemas.opendrive import OpenDriveNetwork, Road
from carlaocc.stages.scenes.opendrive import geometry as od
from carlaocc.stages.scenes.network import URBAN_SPEED_LIMIT, Lane, RoadNetwork, Walkway
from carlaocc.stages.scenes.opendrive.surfaces import SECTION_MIN

__all__ = ["build_opendrive_network", "LANE_STEP", "JOIN_TOL", "JOIN_STEP", "WALK_JOIN", "MIN_LANE_WIDTH"]

LANE_STEP = 1.0  # m: lane / walkway centre-line sampling along s
JOIN_TOL = 0.1  # m: a lane's end and its successor's start must meet within this horizontally
JOIN_STEP = 0.5  # m: ... and within this vertically (a step on a slope, see the module docstring)
WALK_JOIN = 1.0  # m: sidewalk ends closer than this share a walk-graph node
MIN_LANE_WIDTH = 1.0  # m: driving lanes never reaching this width are not lanes
MPH, KMH = 0.44704, 1 / 3.6


def _junction_ids(odr: OpenDriveNetwork) -> dict[str, int]:
    """Junction id (file string) -> int: the file's ids when all are integers >= 0, else the
    position in sorted order."""
    ids = sorted({str(j.id) for j in odr.junctions} | {str(r.junction) for r in odr.roads if str(r.junction) != "-1"})
    try:
        as_int = {j: int(j) for j in ids}
        if len(set(as_int.values())) == len(ids) and min(as_int.values(), default=0) >= 0:
            return as_int
    except ValueError:
        pass
    return {j: k for k, j in enumerate(ids)}


def _speed(road: Road, s: float) -> float:
    """Speed limit (m/s) of the road type record in force at ``s``; the urban default without one."""
    limit = URBAN_SPEED_LIMIT
    for t in road.types:
        if t.s <= s + 1e-9 and t.speed_max:
            unit = (t.speed_unit or "m/s").lower()
            limit = t.speed_max * (MPH if unit == "mph" else KMH if unit in ("km/h", "kmh") else 1.0)
    return float(limit)


# ---------------------------------------------------------------------------------------------
# the lane graph


def build_opendrive_network(odr: OpenDriveNetwork, curb_height: float, source: str = "") -> tuple[RoadNetwork, dict]:
    """The lane and walk graphs of a parsed OpenDRIVE network (see the module docstring) and
    statistics: ``lanes_raw``, ``links``, ``link_mismatches`` (links whose ends do not meet
    within :data:`JOIN_TOL` horizontally and :data:`JOIN_STEP` vertically; ``mismatch_max`` the
    largest 3D gap among them), ``link_steps`` (links kept with a vertical step over
    :data:`JOIN_TOL`; ``step_max`` the largest), ``link_missing`` (links naming an absent lane), ``scc_dropped``,
    ``walkways``, ``crosswalks``. Raises ``ValueError`` naming ``source`` when no driving lane
    exists or the lane graph has no cycle."""
    label = source or "OpenDRIVE network"
    jids = _junction_ids(odr)
    roads = {str(r.id): r for r in odr.roads}
    # 1. driving-lane centre lines, keyed (road, section, lane id)
    raw: dict[tuple[str, int, int], dict] = {}
    nsec: dict[str, int] = {}
    for road in odr.roads:
        rid = str(road.id)
        nsec[rid] = len(road.lane_sections)
        for i, s, ref, strips in od.section_strips(road, LANE_STEP, SECTION_MIN):
            for st in strips:
                if od.surface_kind(st.lane_type) != "driving":
                    continue
                w = np.abs(st.t_outer - st.t_inner)
                if float(w.max()) < MIN_LANE_WIDTH:
                    continue
                t_mid = (st.t_inner + st.t_outer) / 2
                pts = od.st_to_world(road, s, t_mid, ref)
                normals = od.surface_normal(road, s, t_mid, ref)
                if st.lane_id > 0:
                    pts, normals = pts[::-1], normals[::-1]
                keep = np.concatenate([[True], np.hypot(*np.diff(pts[:, :2], axis=0).T) > 1e-6])
                pts, normals = pts[keep], normals[keep]
                if len(pts) < 2:
                    continue
                raw[(rid, i, st.lane_id)] = dict(
                    points=pts, normals=normals, width=float(w.mean()), lane=st.lane, road=rid,
                    junction=jids.get(str(road.junction), -1) if str(road.junction) != "-1" else -1,
                    speed=_speed(road, float(s[0])),
                )  # fmt: skip
    if not raw:
        raise ValueError(f"{label}: no driving lanes (no lane of a driving type with a width of {MIN_LANE_WIDTH} m)")

    # 2. successors
    junction_by_id = {str(j.id): j for j in odr.junctions}
    stats = {"lanes_raw": len(raw), "links": 0, "link_mismatches": 0, "link_missing": 0, "mismatch_max": 0.0,
             "link_steps": 0, "step_max": 0.0}  # fmt: skip

    def targets(key):
        rid, i, lid = key
        road, lane = roads[rid], raw[key]["lane"]
        forward = lid < 0
        nxt_id = lane.successor if forward else lane.predecessor
        inner_next = i + 1 if forward else i - 1
        if 0 <= inner_next < nsec[rid]:
            return [(rid, inner_next, nxt_id if nxt_id is not None else lid)]
        link = road.successor if forward else road.predecessor
        if link is None:
            return []
        if link.element_type == "road":
            if nxt_id is None or str(link.element_id) not in roads:
                return []
            r2 = str(link.element_id)
            return [(r2, 0 if link.contact_point != "end" else nsec[r2] - 1, nxt_id)]
        junction = junction_by_id.get(str(link.element_id))
        out = []
        for conn in junction.connections if junction is not None else ():
            if str(conn.incoming_road) != rid or str(conn.connecting_road) not in roads:
                continue
            r2 = str(conn.connecting_road)
            for ll in conn.lane_links:
                if ll.from_lane == lid:
                    out.append((r2, 0 if conn.contact_point != "end" else nsec[r2] - 1, ll.to_lane))
        return out

    keys = list(raw)
    index = {k: n for n, k in enumerate(keys)}
    succ: list[list[int]] = [[] for _ in keys]
    for n, key in enumerate(keys):
        end = raw[key]["points"][-1]
        for t in dict.fromkeys(targets(key)):
            if t not in raw:
                stats["link_missing"] += 1
                continue
            d = raw[t]["points"][0] - end
            gap_xy, step = float(np.hypot(d[0], d[1])), abs(float(d[2]))
            stats["links"] += 1
            if gap_xy > JOIN_TOL or step > JOIN_STEP:
                stats["link_mismatches"] += 1
                stats["mismatch_max"] = max(stats["mismatch_max"], float(np.linalg.norm(d)))
                continue
            if step > JOIN_TOL:
                stats["link_steps"] += 1
                stats["step_max"] = max(stats["step_max"], step)
            if index[t] != n:
                succ[n].append(index[t])

    # 3. the lanes on a cycle: every strongly connected component of two lanes or more (from any
    #    of them a route goes on forever; the one-way circuits of a loop road without junctions,
    #    one per lane and direction, are separate components)
    rows = [n for n, ss in enumerate(succ) for _ in ss]
    cols = [m for ss in succ for m in ss]
    graph = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(keys), len(keys)))
    _, comp = connected_components(graph, directed=True, connection="strong")
    sizes = np.bincount(comp)
    if sizes.max() < 2:
        raise ValueError(f"{label}: the lane graph has no cycle (every route dead-ends), nothing to drive on")
    kept = [n for n in range(len(keys)) if sizes[comp[n]] >= 2]
    new = {old: k for k, old in enumerate(kept)}
    stats["scc_dropped"] = len(keys) - len(kept)

    lanes = []
    for old in kept:
        rid, i, lid = keys[old]
        info = raw[keys[old]]

        def neighbour(step: int) -> int:
            nid = lid + step if lid > 0 else lid - step
            if nid == 0 or (nid > 0) != (lid > 0):
                return -1
            m = index.get((rid, i, nid))
            return new.get(m, -1) if m is not None else -1

        lanes.append(Lane(
            lane_id=new[old], points=info["points"], normals=info["normals"], width=info["width"],
            successors=tuple(sorted({new[m] for m in succ[old] if m in new})),
            left=neighbour(-1), right=neighbour(+1), junction=info["junction"], speed_limit=info["speed"], road=rid,
        ))  # fmt: skip
    kept_roads = {ln.road for ln in lanes}
    road_length = float(sum(r.length for r in odr.roads if str(r.junction) == "-1" and str(r.id) in kept_roads))
    if road_length <= 0:  # a network made of junction roads only
        road_length = float(sum(r.length for r in odr.roads if str(r.id) in kept_roads))

    walkways, wstats = _walkways(odr, curb_height, jids)
    stats.update(wstats)
    return RoadNetwork(lanes=tuple(lanes), walkways=tuple(walkways), road_length=road_length), stats


def _walkways(odr: OpenDriveNetwork, curb: float, jids: dict[str, int]) -> tuple[list[Walkway], dict]:
    """Sidewalk centre lines joined at shared ends, and crosswalks at junction entries."""
    lines = []  # (points, width, key)
    ends: dict[tuple[str, int, int], tuple[int, int]] = {}
    side_info: dict[tuple[str, str], list] = {}  # (road, "start"/"end") -> [(lane id, t_centre, sidewalk t ranges)]
    for road in odr.roads:
        rid = str(road.id)
        last = max(len(road.lane_sections) - 1, 0)
        for i, s, ref, strips in od.section_strips(road, LANE_STEP, SECTION_MIN):
            for st in strips:
                if od.surface_kind(st.lane_type) != "sidewalk":
                    continue
                w = np.abs(st.t_outer - st.t_inner)
                if float(w.max()) < 0.5:
                    continue
                tc = (st.t_inner + st.t_outer) / 2
                pts = od.st_to_world(road, s, tc, ref) + [0.0, 0.0, curb]
                keep = np.concatenate([[True], np.hypot(*np.diff(pts[:, :2], axis=0).T) > 1e-6])
                pts = pts[keep]
                if len(pts) < 2 or float(np.sum(np.hypot(*np.diff(pts[:, :2], axis=0).T))) < 0.2:
                    continue
                lines.append((pts, float(w.mean()), (rid, i, st.lane_id)))
                if i == 0:
                    side_info.setdefault((rid, "start"), []).append((st.lane_id, float(tc[0]), float(st.t_inner[0]), float(st.t_outer[0])))
                if i == last:
                    side_info.setdefault((rid, "end"), []).append((st.lane_id, float(tc[-1]), float(st.t_inner[-1]), float(st.t_outer[-1])))
    # walk-graph nodes: cluster all line ends within WALK_JOIN
    P = np.array([p for pts, _, _ in lines for p in (pts[0, :2], pts[-1, :2])]).reshape(-1, 2)
    parent = list(range(len(P)))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    if len(P):
        for a, b in sorted(cKDTree(P).query_pairs(WALK_JOIN)):
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    node_of: dict[int, int] = {}

    def node(k: int) -> int:
        return node_of.setdefault(find(k), len(node_of))

    walkways: list[Walkway] = []
    end_node: dict[tuple[str, int, int, str], int] = {}
    for n, (pts, w, key) in enumerate(lines):
        a, b = node(2 * n), node(2 * n + 1)
        end_node[(*key, "first")], end_node[(*key, "last")] = a, b
        walkways.append(Walkway(walkway_id=len(walkways), points=pts, start_node=a, end_node=b, width=w))
    # crosswalks across each junction entry of a non-junction road with sidewalks on both sides
    crosswalks = 0
    for road in odr.roads:
        if str(road.junction) != "-1":
            continue
        rid = str(road.id)
        for where, link in (("start", road.predecessor), ("end", road.successor)):
            if link is None or link.element_type != "junction" or str(link.element_id) not in jids:
                continue
            info = side_info.get((rid, where), [])
            left = [x for x in info if x[0] > 0]
            right = [x for x in info if x[0] < 0]
            if not left or not right:
                continue
            la, ra = min(left, key=lambda x: x[0]), max(right, key=lambda x: x[0])
            s_end = 0.0 if where == "start" else road.length
            sec = 0 if where == "start" else len(road.lane_sections) - 1
            pos = "first" if where == "start" else "last"
            # the sidewalk lines' ends at this road end: "first" point of the section's line is at
            # the section start (s order, before any reversal: sidewalk lines are never reversed)
            na, nb = end_node.get((rid, sec, ra[0], pos)), end_node.get((rid, sec, la[0], pos))
            if na is None or nb is None:
                continue
            n_pts = max(2, int(math.ceil(abs(la[1] - ra[1]) / LANE_STEP)) + 1)
            t = np.linspace(ra[1], la[1], n_pts)
            pts = od.st_to_world(road, np.full(n_pts, s_end), t)
            raised = np.zeros(n_pts, bool)
            for _lid, _tc, ti, to in info:
                raised |= (t >= min(ti, to) - 1e-6) & (t <= max(ti, to) + 1e-6)
            pts[:, 2] += np.where(raised, curb, 0.0)
            walkways.append(Walkway(walkway_id=len(walkways), points=pts, start_node=na, end_node=nb, width=2.5,
                                    crosswalk=True, junction=jids[str(link.element_id)]))  # fmt: skip
            crosswalks += 1
    return walkways, {"walkways": len(walkways) - crosswalks, "crosswalks": crosswalks}
