"""OpenDRIVE town ground: lane surfaces, road marks, the footprint raster and terrain, from a
parsed network (:mod:`carlaocc.schemas.opendrive`); part of :mod:`carlaocc.stages.scenes.opendrive.town`.

World frame = the file's inertial frame (metres, right-handed, Z up).

* **Surfaces** (:func:`lane_surfaces`). Every lane of every road and lane section becomes a
  triangle strip between its borders (sampled every <= 0.5 m plus every geometry start; line,
  arc, spiral, poly3 and paramPoly3 reference lines, lane offsets and widths, elevation and
  superelevation). Strips are grouped by surface kind
  (:func:`carlaocc.stages.scenes.opendrive.geometry.surface_kind`) into stuff meshes, see
  :data:`SURFACE_MESHES`. The drivable lanes of junction connecting roads go to the ``junction``
  mesh (class Road), with the holes the connectors leave inside the junction filled by 0.5 m
  cells at the mean junction height (:func:`junction_fill`). Sidewalk and curb lanes are raised
  by ``curb_height``; a vertical kerb face runs along every raised strip's inner border where its
  inner neighbour is not raised. Road marks (:func:`carlaocc.stages.scenes.opendrive.geometry.road_marks`)
  on driving / shoulder / centre lanes are lifted :data:`MARK_LIFT` above the road (class
  RoadLine; :func:`road_mark_meshes`).
* **Footprint raster** (:class:`FootprintRaster`). All surfaces are sampled every <= 0.25 m into a
  0.5 m raster: a surface mask, a driving mask and the top height per cell.
* **Terrain** (:func:`terrain_quads`, class Terrain) covers every raster cell no surface sample
  falls in, out to :data:`MARGIN` m around the network, at the height of the nearest surface cell
  (quantised to 5 cm, :func:`nearest_surface`), as flat quads of at most 8 m merged from
  equal-height runs. It never lies under a road.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from carlaocc.schemas.opendrive import OpenDriveNetwork
from carlaocc.stages.scenes.opendrive import geometry as od

__all__ = ["CELL", "SURF_STEP", "SECTION_MIN", "MARGIN", "MARK_LIFT", "TERRAIN_DZ", "SURFACE_MESHES", "MESH_ORDER",
           "FootprintRaster", "lane_surfaces", "junction_fill", "road_mark_meshes", "nearest_surface",
           "terrain_quads"]  # fmt: skip

CELL = 0.5  # m: footprint raster cell
SURF_STEP = 0.5  # m: surface sampling along s
SECTION_MIN = 1e-6  # m: shorter lane sections are skipped
MARGIN = 45.0  # m: terrain beyond the surfaces' bounding box
MARK_LIFT = 0.01  # m: road marks above the road surface
TERRAIN_DZ = 0.05  # m: terrain height quantum
TERRAIN_RUN = 16  # cells: largest terrain quad edge (16 * 0.5 = 8 m, the stuff tile)

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
MESH_ORDER = ("road", "junction", "shoulder", "bike_lane", "sidewalk", "border", "median", "rail", "other_surface")
_RAISED = frozenset({"sidewalk", "curb"})
_MARKED = frozenset({"driving", "shoulder", "biking"})


class FootprintRaster:
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


def lane_surfaces(
    odr: OpenDriveNetwork, curb: float
) -> tuple[dict[str, list[tuple[np.ndarray, np.ndarray]]], list[tuple[np.ndarray, bool]]]:
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


def junction_fill(odr: OpenDriveNetwork, raster_lo, raster_hi) -> list[tuple[np.ndarray, np.ndarray]]:
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
        r = FootprintRaster(lo, hi + CELL)
        r.mark(P, False)
        holes = ndimage.binary_fill_holes(r.surf) & ~r.surf
        ii, jj = np.nonzero(holes)
        if not len(ii):
            continue
        x0, y0 = r.x0 + ii * CELL, r.y0 + jj * CELL
        out.append(_flat_quads(x0, x0 + CELL, y0, y0 + CELL, float(np.mean(P[:, 2]))))
    return out


def road_mark_meshes(odr: OpenDriveNetwork) -> list[tuple[np.ndarray, np.ndarray]]:
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


def nearest_surface(raster: FootprintRaster) -> tuple[np.ndarray, np.ndarray]:
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


def terrain_quads(raster: FootprintRaster, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat quads over the cells no surface covers, at the nearest surface's height ``q`` (in
    steps of :data:`TERRAIN_DZ`, from :func:`nearest_surface`)."""
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
