"""OpenDRIVE towns on the town contract (:mod:`stages.scenes.network`): surfaces, road marks,
signals, procedural buildings / vegetation / terrain beside the network, and the lane and walk
graphs, all from a parsed ``.xodr`` network.

The parsed network is read by attribute only (``roads``, ``junctions``; see
:mod:`stages.scenes.opendrive` for the road attributes) -- stages never import :mod:`catalog`.
World frame = the file's inertial frame (metres, right-handed, Z up).

How the town is made (all deterministic from ``(scenes.seed, index)`` and the asset set):

* **Surfaces.** Every lane of every road and lane section becomes a triangle strip between its
  borders (sampled every <= 0.5 m plus every geometry start; line, arc, spiral, poly3 and
  paramPoly3 reference lines, lane offsets and widths, elevation and superelevation). Strips are
  grouped by surface kind (:func:`stages.scenes.opendrive.surface_kind`) into stuff meshes, see
  :data:`SURFACE_MESHES`. The drivable lanes of junction connecting roads go to the ``junction``
  mesh (class Road), with the holes the connectors leave inside the junction filled by 0.5 m
  cells at the mean junction height. Sidewalk and curb lanes are raised by ``curb_height``; a
  vertical kerb face runs along every raised strip's inner border where its inner neighbour is
  not raised. Road marks (:func:`stages.scenes.opendrive.road_marks`) on driving / shoulder /
  centre lanes are lifted :data:`MARK_LIFT` above the road (class RoadLine).
* **Footprint raster.** All surfaces are sampled every <= 0.25 m into a 0.5 m raster: a
  surface mask, a driving mask and the top height per cell.
* **Terrain** (class Terrain) covers every raster cell no surface sample falls in, out to
  :data:`MARGIN` m around the network, at the height of the nearest surface cell (quantised to
  5 cm), as flat quads of at most 8 m merged from equal-height runs. It never lies under a road.
* **Signals.** Type ``1000001`` (CARLA) or any dynamic ``1000xxx`` signal becomes a
  TrafficLight/vehicle_signal, other types a TrafficSign of the mapped sub-class
  (:data:`SIGN_SUBCLASSES`, e.g. 206 stop, 205 yield, 274 speed_limit; unmapped types any sign).
  The pole stands at the signal's (s, t) on the surface, the lenses / plate (+X) face the
  traffic the ``orientation`` names (``+``: traffic along +s, so facing -s; ``-``: facing +s;
  ``none``: the traffic of the side the signal stands on), turned by ``hOffset`` taken modulo pi
  (a signal never faces away from its traffic; CARLA exports carry +-pi offsets). Signals whose
  footprint touches a driving-lane cell, or whose pole is within 1 m of one already placed, are
  skipped and counted.
* **Buildings** walk the outer border of every non-junction road side, facing the road (+X
  towards it), set back :data:`CLEARANCE` + 0.5-3 m; **vegetation** (trees, bushes, ...) is
  scattered over free cells within :data:`NEAR` m of a surface. A footprint (the asset's
  oriented xy box) is accepted only when every raster cell it touches is free: not within
  :data:`CLEARANCE` m of a surface, not under a signal, a building or a plant (plus a gap).
* **Lanes** (contract :class:`Lane`): one per (road, lane section, driving lane) whose width
  reaches 1 m: the centre line sampled every <= 1 m at the road surface, in the travel direction
  (right-hand traffic: negative ids along +s, positive ids against s). Successors follow lane
  links inside a road, road links (``elementType="road"`` with the lane's successor /
  predecessor id) and junction connections (``incomingRoad`` + ``laneLink from``); a link is
  kept only when the lane's end meets the successor's start within :data:`JOIN_TOL` m (the rest
  are counted as mismatches). Left / right neighbours: adjacent driving lanes of the same section
  and side. Connector lanes carry ``junction`` = the junction's id as an int (the file's id when
  every junction id is an integer, else the position in sorted id order). Only the largest
  strongly connected component of the lane graph is kept, lanes renumbered to positions.
  ``road_length`` = the summed length of the non-junction roads that keep at least one lane.
* **Walkways**: one per (road, section, sidewalk lane): its centre line on the raised surface.
  Ends closer than :data:`WALK_JOIN` m share a walk-graph node (sidewalks continue across
  sections, roads and junction corners). **Crosswalks**: at every end of a non-junction road
  that links to a junction and has sidewalks on both sides, a straight walkway across the road's
  cross-section at that end (the junction entry) joining the innermost sidewalk of each side;
  it carries the junction's id.

Not done: lane ``<height>`` (sidewalks use ``curb_height``), road ``<objects>`` (crosswalk
polygons, parking spaces), signal ``zOffset`` (assets stand on the ground at their own height),
left-hand-traffic roads, zebra paint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.geometry import concatenate
from carlaocc.stages.scenes import opendrive as od
from carlaocc.stages.scenes.network import URBAN_SPEED_LIMIT, Lane, RoadNetwork, Town, Walkway
from carlaocc.stages.scenes.placing import POLE_RADIUS, AssetPools, Placer, rot2, stuff_geometry

__all__ = ["build_opendrive_town", "build_opendrive_town_with_stats", "build_opendrive_network",
           "SURFACE_MESHES", "SIGN_SUBCLASSES"]  # fmt: skip

CELL = 0.5  # m: footprint raster cell
SURF_STEP = 0.5  # m: surface sampling along s
LANE_STEP = 1.0  # m: lane / walkway centre-line sampling along s
SECTION_MIN = 1e-6  # m: shorter lane sections are skipped
CLEARANCE = 1.5  # m: buildings and plants keep this far from every surface
OBJECT_GAP = 1.0  # m: between placed buildings / plants
NEAR = 40.0  # m: vegetation within this distance of a surface
MARGIN = 45.0  # m: terrain beyond the surfaces' bounding box
MARK_LIFT = 0.01  # m: road marks above the road surface
JOIN_TOL = 0.1  # m: a lane's end and its successor's start must meet within this
WALK_JOIN = 1.0  # m: sidewalk ends closer than this share a walk-graph node
MIN_LANE_WIDTH = 1.0  # m: driving lanes never reaching this width are not lanes
TERRAIN_DZ = 0.05  # m: terrain height quantum
TERRAIN_RUN = 16  # cells: largest terrain quad edge (16 * 0.5 = 8 m, the stuff tile)
MPH, KMH = 0.44704, 1 / 3.6

# surface kind -> (stuff mesh name, semantic class, material); junction driving lanes -> "junction"
SURFACE_MESHES: dict[str, tuple[str, str, str]] = {
    "driving": ("road", "Road", "asphalt"),
    "junction": ("junction", "Road", "asphalt"),
    "shoulder": ("shoulder", "Road", "asphalt"),
    "biking": ("bike_lane", "Road", "asphalt"),
    "sidewalk": ("sidewalk", "Sidewalk", "paving"),
    "curb": ("sidewalk", "Sidewalk", "concrete"),
    "border": ("border", "Ground", "gravel"),
    "median": ("median", "Terrain", "grass"),
    "rail": ("rail", "RailTrack", "steel"),
    "other": ("other_surface", "Ground", "gravel"),
}
_MESH_ORDER = ("road", "junction", "shoulder", "bike_lane", "sidewalk", "border", "median", "rail", "other_surface")
_RAISED = frozenset({"sidewalk", "curb"})
_MARKED = frozenset({"driving", "shoulder", "biking"})

# OpenDRIVE / German StVO sign types -> procedural TrafficSign sub-classes
SIGN_SUBCLASSES: dict[str, str] = {
    "206": "stop", "205": "yield", "274": "speed_limit", "278": "speed_limit", "267": "no_entry",
    "220": "one_way", "350": "pedestrian_crossing", "314": "parking", "101": "warning", "102": "warning",
    "103": "warning", "105": "warning", "120": "warning", "123": "warning", "138": "warning",
    "306": "direction", "301": "direction", "437": "direction",
}  # fmt: skip
TRAFFIC_LIGHT_TYPE = "1000001"


# ---------------------------------------------------------------------------------------------
# per-lane strips


def _junction_ids(odr) -> dict[str, int]:
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


def _speed(road, s: float) -> float:
    """Speed limit (m/s) of the road type record in force at ``s``; the urban default without one."""
    limit = URBAN_SPEED_LIMIT
    for t in getattr(road, "types", ()):
        if t.s <= s + 1e-9 and t.speed_max:
            unit = (t.speed_unit or "m/s").lower()
            limit = t.speed_max * (MPH if unit == "mph" else KMH if unit in ("km/h", "kmh") else 1.0)
    return float(limit)


# ---------------------------------------------------------------------------------------------
# surfaces and the footprint raster


class _Raster:
    """A 0.5 m grid over the town: surface mask, driving mask, top height, blocked cells."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        self.x0, self.y0 = float(lo[0]), float(lo[1])
        self.nx = int(math.ceil((hi[0] - lo[0]) / CELL))
        self.ny = int(math.ceil((hi[1] - lo[1]) / CELL))
        self.surf = np.zeros((self.nx, self.ny), bool)
        self.drive = np.zeros((self.nx, self.ny), bool)
        self.top = np.full((self.nx, self.ny), -np.inf)

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return self.x0, self.y0, self.x0 + self.nx * CELL, self.y0 + self.ny * CELL

    def cells(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        i = np.clip(np.floor((xy[..., 0] - self.x0) / CELL).astype(np.int64), 0, self.nx - 1)
        j = np.clip(np.floor((xy[..., 1] - self.y0) / CELL).astype(np.int64), 0, self.ny - 1)
        return i, j

    def mark(self, pts: np.ndarray, driving: bool) -> None:
        i, j = self.cells(pts)
        self.surf[i, j] = True
        if driving:
            self.drive[i, j] = True
        np.maximum.at(self.top, (i, j), pts[:, 2])

    def rect_cells(self, centre, yaw: float, length: float, width: float) -> tuple[np.ndarray, np.ndarray] | None:
        """Cells an oriented rectangle touches (cell centres within the rectangle grown by half a
        cell diagonal); None when it leaves the grid."""
        c, s = math.cos(yaw), math.sin(yaw)
        hx, hy = length / 2, width / 2
        ex, ey = abs(c) * hx + abs(s) * hy, abs(s) * hx + abs(c) * hy
        i0, i1 = math.floor((centre[0] - ex - self.x0) / CELL) - 1, math.floor((centre[0] + ex - self.x0) / CELL) + 1
        j0, j1 = math.floor((centre[1] - ey - self.y0) / CELL) - 1, math.floor((centre[1] + ey - self.y0) / CELL) + 1
        if i0 < 0 or j0 < 0 or i1 >= self.nx or j1 >= self.ny:
            return None
        ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
        px, py = self.x0 + (ii + 0.5) * CELL - centre[0], self.y0 + (jj + 0.5) * CELL - centre[1]
        u, v = c * px + s * py, -s * px + c * py
        grow = CELL * math.sqrt(0.5)
        m = (np.abs(u) <= hx + grow) & (np.abs(v) <= hy + grow)
        return ii[m], jj[m]


def _strip_points(p_in: np.ndarray, p_out: np.ndarray) -> np.ndarray:
    """Points every <= 0.25 m over a strip between two sampled borders (for the raster)."""
    sub = 3  # along s: samples are <= 0.5 m apart -> <= 0.17 m
    f = np.linspace(0.0, 1.0, sub, endpoint=False)
    a_in = (p_in[:-1, None, :] * (1 - f[None, :, None]) + p_in[1:, None, :] * f[None, :, None]).reshape(-1, 3)
    a_out = (p_out[:-1, None, :] * (1 - f[None, :, None]) + p_out[1:, None, :] * f[None, :, None]).reshape(-1, 3)
    a_in, a_out = np.vstack([a_in, p_in[-1:]]), np.vstack([a_out, p_out[-1:]])
    width = float(np.max(np.linalg.norm(a_out[:, :2] - a_in[:, :2], axis=1)))
    nt = max(2, int(math.ceil(width / 0.25)) + 1)
    g = np.linspace(0.0, 1.0, nt)
    return (a_in[:, None, :] * (1 - g[None, :, None]) + a_out[:, None, :] * g[None, :, None]).reshape(-1, 3)


def _kerb_wall(p: np.ndarray, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertical strip from the polyline ``p`` up ``height`` m (both windings, seen either side)."""
    n = len(p)
    top = p + np.array([0.0, 0.0, height])
    V = np.empty((2 * n, 3))
    V[0::2], V[1::2] = p, top
    i = np.arange(n - 1)
    a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
    return V, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int64)


def _surfaces(odr, curb: float):
    """Per mesh name the strips (vertices, faces), and the raster sample points (points,
    driving) of every strip."""
    meshes: dict[str, list] = {}
    samples: list[tuple[np.ndarray, bool]] = []
    for road in odr.roads:
        in_junction = str(road.junction) != "-1"
        for _i, s, ref, strips in od.section_strips(road, SURF_STEP, SECTION_MIN):
            raised_ids = set()
            for st in strips:
                if od.surface_kind(st.lane_type) in _RAISED:
                    raised_ids.add(st.lane_id)
            for st in strips:
                kind = od.surface_kind(st.lane_type)
                if kind is None or not np.any(np.abs(st.t_outer - st.t_inner) > 1e-6):
                    continue
                p_in, p_out = od.st_to_world(road, s, st.t_inner, ref), od.st_to_world(road, s, st.t_outer, ref)
                raised = kind in _RAISED
                if raised:
                    p_in, p_out = p_in + [0, 0, curb], p_out + [0, 0, curb]
                mesh = od.strip_mesh(p_in, p_out)
                if len(mesh[1]):
                    name = SURFACE_MESHES["junction" if kind == "driving" and in_junction else kind][0]
                    meshes.setdefault(name, []).append(mesh)
                    samples.append((_strip_points(p_in, p_out), kind == "driving"))
                inner_id = st.lane_id - (1 if st.lane_id > 0 else -1)
                if raised and curb > 0 and inner_id not in raised_ids:
                    meshes.setdefault("sidewalk", []).append(_kerb_wall(p_in - [0, 0, curb], curb))
    return meshes, samples


def _junction_fill(odr, raster_lo, raster_hi) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per junction, 0.5 m quads filling the holes its connectors' surfaces enclose (at the
    junction's mean surface height)."""
    out = []
    by_junction: dict[str, list] = {}
    for road in odr.roads:
        if str(road.junction) != "-1":
            by_junction.setdefault(str(road.junction), []).append(road)
    for _jid, roads in sorted(by_junction.items()):
        pts = []
        for road in roads:
            for _i, s, ref, strips in od.section_strips(road, SURF_STEP, SECTION_MIN):
                for st in strips:
                    if od.surface_kind(st.lane_type) is None or not np.any(np.abs(st.t_outer - st.t_inner) > 1e-6):
                        continue
                    pts.append(_strip_points(od.st_to_world(road, s, st.t_inner, ref),
                                             od.st_to_world(road, s, st.t_outer, ref)))  # fmt: skip
        if not pts:
            continue
        P = np.vstack(pts)
        lo, hi = P[:, :2].min(axis=0) - CELL, P[:, :2].max(axis=0) + CELL
        r = _Raster(lo, hi + CELL)
        r.mark(P, False)
        holes = ndimage.binary_fill_holes(r.surf) & ~r.surf
        ii, jj = np.nonzero(holes)
        if not len(ii):
            continue
        x0, y0 = r.x0 + ii * CELL, r.y0 + jj * CELL
        out.append(_flat_quads(x0, x0 + CELL, y0, y0 + CELL, float(np.mean(P[:, 2]))))
    return out


def _road_marks(odr) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for road in odr.roads:
        types = {}
        for sec in road.lane_sections:
            for lane in (*sec.left, *sec.center, *sec.right):
                types[lane.id] = lane.type
        for m in od.road_marks(road, step=SURF_STEP):
            kind = od.surface_kind(types.get(m["lane_id"], "none"))
            if m["lane_id"] == 0 or kind in _MARKED:
                out.append((m["vertices"] + [0.0, 0.0, MARK_LIFT], m["faces"]))
    return out


def _nearest_surface(raster: _Raster) -> tuple[np.ndarray, np.ndarray]:
    """Per raster cell: the distance (m) to the nearest surface cell and that cell's top height
    in whole steps of :data:`TERRAIN_DZ` (0 when there is no surface)."""
    dist, (ni, nj) = ndimage.distance_transform_edt(~raster.surf, sampling=CELL, return_indices=True)
    if not raster.surf.any():
        return dist, np.zeros(dist.shape, np.int64)
    return dist, np.round(raster.top[ni, nj] / TERRAIN_DZ).astype(np.int64)


def _flat_quads(x0: np.ndarray, x1: np.ndarray, y0: np.ndarray, y1: np.ndarray, z) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal rectangles ``[x0, x1] x [y0, y1]`` at heights ``z`` (m), two triangles each,
    facing up. Returns (vertices (4n, 3), faces (2n, 3))."""
    n = len(x0)
    z = np.broadcast_to(np.asarray(z, dtype=np.float64), (n,))
    V = np.empty((4 * n, 3))
    V[0::4] = np.column_stack([x0, y0, z])
    V[1::4] = np.column_stack([x1, y0, z])
    V[2::4] = np.column_stack([x1, y1, z])
    V[3::4] = np.column_stack([x0, y1, z])
    b = 4 * np.arange(n)
    F = np.concatenate([np.stack([b, b + 1, b + 2], 1), np.stack([b, b + 2, b + 3], 1)]).astype(np.int64)
    return V, F


def _terrain(raster: _Raster, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat quads over the cells no surface covers, at the nearest surface's height ``q`` (in
    steps of :data:`TERRAIN_DZ`, from :func:`_nearest_surface`)."""
    free = ~raster.surf
    rects = []  # (i0, i1, j0, j1, q)
    open_runs: dict[tuple[int, int, int], list] = {}
    for j in range(raster.ny):
        col_free, col_q = free[:, j], q[:, j]
        runs = []
        i = 0
        while i < raster.nx:
            if not col_free[i]:
                i += 1
                continue
            k = i
            while k + 1 < raster.nx and col_free[k + 1] and col_q[k + 1] == col_q[i] and k + 1 - i < TERRAIN_RUN:
                k += 1
            runs.append((i, k + 1, int(col_q[i])))
            i = k + 1
        nxt: dict[tuple[int, int, int], list] = {}
        for run in runs:
            rect = open_runs.pop(run, None)
            if rect is not None and rect[3] - rect[2] < TERRAIN_RUN:
                rect[3] = j + 1
            else:
                if rect is not None:
                    rects.append(rect)
                rect = [run[0], run[1], j, j + 1, run[2]]
            nxt[run] = rect
        rects.extend(open_runs.values())
        open_runs = nxt
    rects.extend(open_runs.values())
    if not rects:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    R = np.array(rects, dtype=np.float64)
    x0, x1 = raster.x0 + R[:, 0] * CELL, raster.x0 + R[:, 1] * CELL
    y0, y1 = raster.y0 + R[:, 2] * CELL, raster.y0 + R[:, 3] * CELL
    return _flat_quads(x0, x1, y0, y1, R[:, 4] * TERRAIN_DZ)


# ---------------------------------------------------------------------------------------------
# the lane graph


def build_opendrive_network(odr, curb_height: float, source: str = "") -> tuple[RoadNetwork, dict]:
    """The lane and walk graphs of a parsed OpenDRIVE network (see the module docstring) and
    statistics: ``lanes_raw``, ``links``, ``link_mismatches`` (links whose ends do not meet
    within :data:`JOIN_TOL`), ``link_missing`` (links naming an absent lane), ``scc_dropped``,
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
                pts = od.st_to_world(road, s, (st.t_inner + st.t_outer) / 2, ref)
                if st.lane_id > 0:
                    pts = pts[::-1]
                keep = np.concatenate([[True], np.hypot(*np.diff(pts[:, :2], axis=0).T) > 1e-6])
                pts = pts[keep]
                if len(pts) < 2:
                    continue
                raw[(rid, i, st.lane_id)] = dict(
                    points=pts, width=float(w.mean()), lane=st.lane, road=rid,
                    junction=jids.get(str(road.junction), -1) if str(road.junction) != "-1" else -1,
                    speed=_speed(road, float(s[0])),
                )  # fmt: skip
    if not raw:
        raise ValueError(f"{label}: no driving lanes (no lane of a driving type with a width of {MIN_LANE_WIDTH} m)")

    # 2. successors
    junction_by_id = {str(j.id): j for j in odr.junctions}
    stats = {"lanes_raw": len(raw), "links": 0, "link_mismatches": 0, "link_missing": 0, "mismatch_max": 0.0}

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
            gap = float(np.linalg.norm(raw[t]["points"][0] - end))
            stats["links"] += 1
            if gap > JOIN_TOL:
                stats["link_mismatches"] += 1
                stats["mismatch_max"] = max(stats["mismatch_max"], gap)
                continue
            if index[t] != n:
                succ[n].append(index[t])

    # 3. largest strongly connected component
    rows = [n for n, ss in enumerate(succ) for _ in ss]
    cols = [m for ss in succ for m in ss]
    graph = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(keys), len(keys)))
    _, comp = connected_components(graph, directed=True, connection="strong")
    sizes = np.bincount(comp)
    best = int(np.argmax(sizes))
    if sizes[best] < 2 and not any(n in succ[n] for n in range(len(keys))):
        raise ValueError(f"{label}: the lane graph has no cycle (every route dead-ends), nothing to drive on")
    kept = [n for n in range(len(keys)) if comp[n] == best]
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
            lane_id=new[old], points=info["points"], width=info["width"],
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


def _walkways(odr, curb: float, jids: dict[str, int]) -> tuple[list[Walkway], dict]:
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


# ---------------------------------------------------------------------------------------------
# placements


def _signal_asset(sig, pools: AssetPools, rng) -> AssetRecord | None:
    light = str(sig.type) == TRAFFIC_LIGHT_TYPE or (sig.dynamic and str(sig.type).startswith("1000"))
    if light:
        return pools.pick(rng, "TrafficLight", ["vehicle_signal"])
    return pools.pick(rng, "TrafficSign", [SIGN_SUBCLASSES.get(str(sig.type), "__any__")])


def _place_signals(odr, placer: Placer, pools: AssetPools, raster: _Raster, blocked: np.ndarray, rng, stats) -> None:
    poles: list[np.ndarray] = []
    for road in odr.roads:
        for sig in road.signals:
            asset = _signal_asset(sig, pools, rng)
            if asset is None:
                stats["signals_no_asset"] += 1
                continue
            s = float(np.clip(sig.s, 0.0, road.length))
            x, y, h = (float(v[0]) for v in od.reference_pose(road, [s]))
            p = od.st_to_world(road, np.array([s]), np.array([sig.t]))[0]
            orient = (sig.orientation or "none").strip()
            along = orient == "-" or (orient not in ("+", "-") and sig.t > 0)
            face = h if along else h + math.pi
            off = (float(sig.h_offset or 0.0) + math.pi / 2) % math.pi - math.pi / 2
            yaw = face + off
            ext = asset.extent
            anchor = np.array([-ext[0] / 2 + POLE_RADIUS, 0.0])
            centre = p[:2] - rot2(yaw, anchor)
            cells = raster.rect_cells(centre, yaw, ext[0], ext[1])
            if cells is None or raster.drive[cells].any():
                stats["signals_on_driving"] += 1
                continue
            if any(np.hypot(*(q - p[:2])) < 1.0 for q in poles):
                stats["signals_duplicate"] += 1
                continue
            i, j = raster.cells(p[None, :2])
            z = float(raster.top[i[0], j[0]]) if raster.surf[i[0], j[0]] else float(p[2])
            kind = "traffic_light" if asset.category == "TrafficLight" else "traffic_sign"
            placer.add_asset(kind, asset, p[:2], z, yaw, anchor=tuple(anchor))
            blocked[cells] = True
            poles.append(p[:2].copy())
            stats["signals_placed"] += 1


def _ground_z(terrain_z: np.ndarray, cells) -> float:
    return float(terrain_z[cells].min())


def _place_buildings(odr, placer, pools, raster, blocked, terrain_z, rng, stats) -> None:
    gap = int(math.ceil(OBJECT_GAP / CELL))
    for road in odr.roads:
        if str(road.junction) != "-1" or road.length < 8.0:
            continue
        weights = (("office", "commercial", "apartment"), ("house", "residential", "garage"))[int(rng.uniform() < 0.5)]
        for side in (-1, 1):
            s_all = np.arange(0.0, road.length, 1.0)
            if len(s_all) < 2:
                continue
            strips = od.lane_boundaries(road, s_all)
            t_out = np.zeros_like(s_all)
            for st in strips:
                if st.lane_id * side > 0 and od.surface_kind(st.lane_type) is not None:
                    m = np.isin(s_all, st.s)
                    cur = t_out[m]
                    t_out[m] = np.where(side * st.t_outer > side * cur, st.t_outer, cur)
            ref = od.reference_pose(road, s_all)
            border = od.st_to_world(road, s_all, t_out, ref)
            beyond = od.st_to_world(road, s_all, t_out + side, ref)
            normal = beyond[:, :2] - border[:, :2]
            normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
            k = int(rng.integers(0, 6))
            while k < len(s_all) - 4:
                placed = False
                for _ in range(3):
                    asset = pools.pick(rng, "Building", [weights[int(rng.integers(len(weights)))]])
                    if asset is None:
                        return
                    depth, front = float(asset.extent[0]), float(asset.extent[1])
                    mid = min(k + int(front / 2), len(s_all) - 1)
                    n = normal[mid]
                    setback = CLEARANCE + float(rng.uniform(0.5, 3.0))
                    centre = border[mid, :2] + n * (setback + depth / 2)
                    yaw = math.atan2(-n[1], -n[0])
                    cells = raster.rect_cells(centre, yaw, depth, front)
                    if cells is None or blocked[cells].any():
                        continue
                    placer.add_asset("building", asset, centre, _ground_z(terrain_z, cells), yaw)
                    grown = raster.rect_cells(centre, yaw, depth + 2 * gap * CELL, front + 2 * gap * CELL)
                    blocked[grown if grown is not None else cells] = True
                    stats["buildings"] += 1
                    k += int(front) + int(rng.integers(2, 6))
                    placed = True
                    break
                if not placed:
                    k += 3


def _place_vegetation(placer, pools, raster, blocked, terrain_z, dist, rng, stats) -> None:
    if not pools.get("Vegetation"):
        return
    near = (~blocked) & (dist <= NEAR)
    ii, jj = np.nonzero(near)
    if not len(ii):
        return
    attempts = min(1500, int(len(ii) * CELL * CELL / 60.0))
    order = rng.permutation(len(ii))[:attempts]
    gap = OBJECT_GAP
    for k in order:
        if blocked[ii[k], jj[k]]:
            continue
        asset = pools.pick(rng, "Vegetation", [("tree", "tree", "bush", "conifer", "hedge", "palm")[int(rng.integers(6))]])
        centre = np.array([raster.x0 + (ii[k] + 0.5) * CELL, raster.y0 + (jj[k] + 0.5) * CELL])
        yaw = float(rng.uniform(-math.pi, math.pi))
        cells = raster.rect_cells(centre, yaw, float(asset.extent[0]), float(asset.extent[1]))
        if cells is None or blocked[cells].any():
            continue
        placer.add_asset(asset.subclass, asset, centre, _ground_z(terrain_z, cells), yaw)
        grown = raster.rect_cells(centre, yaw, float(asset.extent[0]) + 2 * gap, float(asset.extent[1]) + 2 * gap)
        blocked[grown if grown is not None else cells] = True
        stats["vegetation"] += 1


# ---------------------------------------------------------------------------------------------
# the town


def build_opendrive_town_with_stats(odr, spec: TownSpec, scenes: ScenesConfig, index: int,
                                    assets: Sequence[AssetRecord], source: str) -> tuple[Town, dict]:  # fmt: skip
    """:func:`build_opendrive_town` plus build statistics (lanes, link checks, signals placed and
    skipped, buildings, vegetation, terrain quads)."""
    name = f"town{index:02d}"
    label = source or getattr(odr, "source", "") or "OpenDRIVE network"
    if not getattr(odr, "roads", ()):
        raise ValueError(f"{label}: no roads")
    curb = scenes.curb_height
    pools = AssetPools(assets)
    rng = np.random.default_rng(np.random.SeedSequence([scenes.seed, index, 0x6F6472]))
    network, stats = build_opendrive_network(odr, curb, label)
    stats.update(signals_placed=0, signals_on_driving=0, signals_duplicate=0, signals_no_asset=0, buildings=0,
                 vegetation=0)  # fmt: skip

    # 1. surfaces, raster, terrain
    meshes, samples = _surfaces(odr, curb)
    allp = np.vstack([p for p, _ in samples])
    lo, hi = allp[:, :2].min(axis=0) - MARGIN, allp[:, :2].max(axis=0) + MARGIN
    raster = _Raster(lo, hi)
    for pts, driving in samples:
        raster.mark(pts, driving)
    fill = _junction_fill(odr, lo, hi)
    if fill:
        meshes.setdefault("junction", []).extend(fill)
        for V, _F in fill:
            centres = V.reshape(-1, 4, 3).mean(axis=1)
            raster.mark(centres, True)
    dist, terrain_q = _nearest_surface(raster)
    terrain = _terrain(raster, terrain_q)
    stats["terrain_quads"] = len(terrain[1]) // 2
    sem_of = {v[0]: (v[1], v[2]) for v in SURFACE_MESHES.values()}
    stuff = {}
    for mesh_name in _MESH_ORDER:
        if mesh_name in meshes:
            key = f"{name}/{mesh_name}"
            stuff[key] = stuff_geometry(key, concatenate(meshes[mesh_name]), *sem_of[mesh_name])
    marks = _road_marks(odr)
    if marks:
        stuff[f"{name}/roadline"] = stuff_geometry(f"{name}/roadline", concatenate(marks), "RoadLine", "paint")
    if len(terrain[1]):
        stuff[f"{name}/terrain"] = stuff_geometry(f"{name}/terrain", terrain, "Terrain", "grass")
    placer = Placer(name)
    for geom in stuff.values():
        placer.add_stuff(geom)

    # 2. things beside the network
    terrain_z = terrain_q * TERRAIN_DZ
    blocked = dist <= CLEARANCE
    _place_signals(odr, placer, pools, raster, blocked, rng, stats)
    _place_buildings(odr, placer, pools, raster, blocked, terrain_z, rng, stats)
    _place_vegetation(placer, pools, raster, blocked, terrain_z, dist, rng, stats)

    town = Town(
        name=name, index=index, style="opendrive", source=source, placements=placer.records, stuff=stuff,
        network=network, bounds=raster.bounds, max_instance_id=placer.next_instance - 1, curb_height=curb,
    )  # fmt: skip
    return town, stats


def build_opendrive_town(odr, spec: TownSpec, scenes: ScenesConfig, index: int, assets: Sequence[AssetRecord],
                         source: str) -> Town:  # fmt: skip
    """Town ``index`` (``"town%02d"``) from the parsed OpenDRIVE network ``odr`` (read by
    attribute) with ``assets`` placed beside it; ``source`` names the file (recorded on the town
    and in error messages). Raises ``ValueError`` naming the file when the network cannot form a
    town (no roads, no driving lane, no cycle in the lane graph)."""
    return build_opendrive_town_with_stats(odr, spec, scenes, index, assets, source)[0]
