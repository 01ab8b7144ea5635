"""Procedural towns: a Manhattan road grid with kerbs, sidewalks, grass, road markings and placed
assets (buildings, trees, street lights, traffic lights and signs, benches, bins, bicycles).

World frame: metres, right-handed, Z up, the road surface at z = 0, road-grid node (0, 0) at the
origin. With ``n = blocks``, ``B = block_size``, ``R = road_width``, ``S = sidewalk_width``:

* road centrelines run along x and along y at ``c_k = k (B + R)``, k = 0..n; each carriageway is
  ``c_k +- R/2`` wide and carries ``lanes_per_direction`` lanes each way, right-hand traffic;
* block (i, j) is the square ``[c_i + R/2, c_(i+1) - R/2] x [c_j + R/2, c_(j+1) - R/2]`` (B by B,
  kerb to kerb); its outer ring of width S is sidewalk, raised to ``curb_height``, its interior
  grass (Terrain) at the same height; buildings stand in the interior, set back from the sidewalk;
* around the outer roads a sidewalk ring of width S and a terrain margin of :data:`TOWN_MARGIN` m.

Stuff meshes (world frame, pose = identity) are **thin closed slabs** standing for surfaces:
several disjoint or face-touching boxes per mesh, each closed on its own, :data:`SURFACE` (1 cm)
thick so that a surface voxelizer sees one layer, not a hollow top-and-bottom pair. The road is
``[-SURFACE, 0]``; sidewalk and terrain tops are ``[curb_height - SURFACE, curb_height]``; the
sidewalk mesh also holds the kerb faces, thin walls ``[-SURFACE, curb_height - SURFACE]`` along
every kerb line (under the sidewalk's edge, touching its top slab); road markings are
``[-SURFACE / 2, MARKING_TOP]`` (1 cm proud of the road). Slab tops and bottoms are tessellated
into tiles of at most :data:`STUFF_TILE` m so a frame can cull the triangles outside its region.

Things are placed on their support: buildings and sidewalk furniture at ``z = curb_height``.
Pole-like assets are positioned by their pole axis using the asset-frame conventions documented
in :mod:`stages.ingest.procedural` (derived from the asset extent; the pole radius is taken as
:data:`POLE_RADIUS`, within 5 cm of every procedural pole).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from schemas import taxonomy
from schemas.configs import ScenesConfig
from schemas.records import AssetRecord, PlacementRecord
from stages.geometry import AssetGeometry, MeshPart, concatenate, is_watertight, pose_matrix, pose_to_list

__all__ = ["Town", "LaneSegment", "WalkLoop", "build_town", "town_name", "lanes_per_direction"]

SURFACE = 0.01  # m: thickness of the thin closed slabs that stand for ground surfaces
STUFF_TILE = 8.0  # m: largest tile edge of a stuff slab's top and bottom faces
TOWN_MARGIN = 30.0  # m: terrain beyond the outer sidewalk ring
MARKING_TOP = 0.01  # m: top of the road-marking slabs (1 cm above the road)
LANE_WIDTH_MIN = 3.0  # m: a carriageway half gets floor(half / this) lanes (at least one)
POLE_RADIUS = 0.09  # m: pole radius assumed when placing pole-like assets by their pole axis

_SEM = {name: taxonomy.by_name(name).id for name in (
    "Road", "Sidewalk", "Terrain", "RoadLine", "Building", "Vegetation", "Pole", "TrafficLight",
    "TrafficSign", "Static", "Bicycle",
)}  # fmt: skip
_THINGS = frozenset(taxonomy.thing_ids())
_STUFF_NAMES = ("road", "sidewalk", "terrain", "roadline")


@dataclass(frozen=True)
class LaneSegment:
    """One lane between two intersections, world frame (m). Vehicles drive from ``start`` to
    ``end`` along ``direction`` (unit xy); ``start``/``end`` lie on the edges of the start/end
    intersection boxes. ``lane_index`` 0 is next to the centre line."""

    lane_id: int
    start_node: tuple[int, int]
    end_node: tuple[int, int]
    lane_index: int
    direction: tuple[float, float]
    start: tuple[float, float]
    end: tuple[float, float]
    width: float

    @property
    def length(self) -> float:
        """Length of the lane segment (m)."""
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])


@dataclass(frozen=True)
class WalkLoop:
    """A closed walking line on a block's sidewalk, world frame (m): the corners in walking
    order (the last corner connects back to the first), at height ``z`` (the sidewalk top)."""

    block: tuple[int, int]
    corners: tuple[tuple[float, float], ...]
    z: float

    @property
    def length(self) -> float:
        """Perimeter of the loop (m)."""
        c = np.asarray(self.corners + self.corners[:1])
        return float(np.sum(np.hypot(*np.diff(c, axis=0).T)))


@dataclass(frozen=True)
class Town:
    """A procedural town: static placements (stuff first), its world-frame stuff meshes keyed by
    ``"<town>/<name>"``, and the road description the traffic simulator uses."""

    name: str
    index: int
    placements: list[PlacementRecord]
    stuff: dict[str, AssetGeometry]
    lanes: tuple[LaneSegment, ...]
    intersections: dict[tuple[int, int], tuple[float, float, float, float]]  # node -> xmin, ymin, xmax, ymax
    walk_loops: tuple[WalkLoop, ...]
    road_length: float  # m of road centreline (each road once)
    road_width: float
    curb_height: float
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax of the ground (m)
    max_instance_id: int


def town_name(town_index: int) -> str:
    """``0 -> "town00"``."""
    return f"town{town_index:02d}"


def lanes_per_direction(road_width: float) -> int:
    """Lanes each way on a carriageway of ``road_width`` m (at least one)."""
    return max(1, int((road_width / 2) // LANE_WIDTH_MIN))


# --------------------------------------------------------------------------------------------
# stuff geometry
# --------------------------------------------------------------------------------------------


def _slab(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float, tile: float = STUFF_TILE):
    """Closed axis-aligned slab ``[x0, x1] x [y0, y1] x [z0, z1]`` (m) whose top and bottom are
    grids of tiles of at most ``tile`` m and whose sides match the grid edges (watertight,
    outward normals). Returns (vertices (N, 3), faces (M, 3))."""
    nx, ny = max(1, math.ceil((x1 - x0) / tile - 1e-9)), max(1, math.ceil((y1 - y0) / tile - 1e-9))
    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")  # grid vertex (i, j) -> index i * (ny + 1) + j
    n = (nx + 1) * (ny + 1)
    top = np.column_stack([gx.ravel(), gy.ravel(), np.full(n, z1)])
    bottom = top.copy()
    bottom[:, 2] = z0
    idx = np.arange(n).reshape(nx + 1, ny + 1)
    # cell corners counter-clockwise seen from above: a (i, j), b (i+1, j), c (i+1, j+1), d (i, j+1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = [np.column_stack([a, b, c]), np.column_stack([a, c, d])]  # top, normal +z
    faces += [np.column_stack([a, c, b]) + n, np.column_stack([a, d, c]) + n]  # bottom, normal -z
    # boundary ring, counter-clockwise seen from above; each edge p -> q gets an outward quad
    ring = np.concatenate([idx[:-1, 0], idx[-1, :-1], idx[:0:-1, -1], idx[0, :0:-1]])
    p, q = ring, np.roll(ring, -1)
    faces += [np.column_stack([p + n, q + n, q]), np.column_stack([p + n, q, p])]
    return np.vstack([top, bottom]), np.concatenate(faces).astype(np.int64)


def _ring(x0: float, x1: float, y0: float, y1: float, width: float) -> list[tuple[float, float, float, float]]:
    """Four non-overlapping rectangles (xmin, xmax, ymin, ymax) forming the ring of ``width``
    just inside the rectangle ``[x0, x1] x [y0, y1]``."""
    return [
        (x0, x1, y0, y0 + width),
        (x0, x1, y1 - width, y1),
        (x0, x0 + width, y0 + width, y1 - width),
        (x1 - width, x1, y0 + width, y1 - width),
    ]


def _slabs(rects, z0: float, z1: float):
    """Tiled slabs ``[z0, z1]`` over ``rects`` (xmin, xmax, ymin, ymax) as one (vertices, faces)."""
    return concatenate([_slab(r[0], r[1], r[2], r[3], z0, z1) for r in rects])


def _stuff_geometry(key: str, mesh, semantic: str, material: str) -> AssetGeometry:
    """One stuff mesh (a single part) from (vertices, faces)."""
    V, F = mesh
    part = MeshPart(name=key.split("/")[-1], vertices=V, faces=F, semantic_id=_SEM[semantic], material=material)
    return AssetGeometry(asset_id=key, parts=(part,), part_closed=(is_watertight(F),))


def _marking_rects(lane: LaneSegment, road_width: float, n_lanes: int) -> list[tuple[float, float, float, float]]:
    """Road markings owned by one lane segment, as axis-aligned rectangles (m): the stop line
    across its lanes before the end intersection, and -- for the lane next to the centre line --
    the centre line (drawn once per road, by the +x / +y direction), its edge line and, between
    lanes, dashed lane lines. Pieces never overlap: lines stop 2 m short of the intersections,
    the stop line is 1.2-1.6 m short."""
    d = np.asarray(lane.direction)
    right = np.array([d[1], -d[0]])
    # the road centre line point at the lane's start, and the along-road length
    base = np.asarray(lane.start) - right * (lane.lane_index + 0.5) * lane.width
    length = lane.length
    out: list[tuple[float, float, float, float]] = []

    def strip(s0: float, s1: float, off0: float, off1: float) -> None:
        # rectangle between along-distances s0..s1 and right-offsets off0..off1 from the centre line
        pts = np.array([base + d * s + right * o for s in (s0, s1) for o in (off0, off1)])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        out.append((float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])))

    if lane.lane_index == 0:
        strip(length - 1.6, length - 1.2, 0.15, road_width / 2 - 0.15)  # stop line
        if d[0] + d[1] > 0:
            strip(2.0, length - 2.0, -0.075, 0.075)  # centre line, once per road
        strip(2.0, length - 2.0, road_width / 2 - 0.31, road_width / 2 - 0.19)  # edge line
        for k in range(1, n_lanes):  # dashed lane lines: 3 m dashes, 6 m gaps
            s = 2.0
            while s + 3.0 <= length - 2.0:
                strip(s, s + 3.0, k * lane.width - 0.06, k * lane.width + 0.06)
                s += 9.0
    return out


# --------------------------------------------------------------------------------------------
# placement helpers
# --------------------------------------------------------------------------------------------


def _rot(yaw: float, v) -> np.ndarray:
    """Rotate the xy vector ``v`` by ``yaw`` rad about +Z."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _yaw_of(v) -> float:
    """Heading (rad) of the xy vector ``v``."""
    return math.atan2(float(v[1]), float(v[0]))


class _Placer:
    """Accumulates placement records in order: sequential placement ids, per-kind names, and
    instance ids 1.. for thing classes (taxonomy thing ids), 0 for stuff."""

    def __init__(self, town: str) -> None:
        self.town = town
        self.records: list[PlacementRecord] = []
        self.counts: dict[str, int] = {}
        self.next_instance = 1

    def add(self, kind: str, asset_id: str, semantic_id: int, pose: np.ndarray, named: str | None = None) -> None:
        """Record one placement; ``named`` overrides the ``<kind>_<nnn>`` name (stuff)."""
        k = self.counts.get(kind, 0)
        self.counts[kind] = k + 1
        instance = 0
        if semantic_id in _THINGS:
            instance, self.next_instance = self.next_instance, self.next_instance + 1
        self.records.append(PlacementRecord(
            town=self.town, placement_id=len(self.records), name=named or f"{kind}_{k:03d}",
            asset_id=asset_id, mesh_path="", semantic_id=semantic_id, instance_id=instance,
            pose=pose_to_list(pose),
        ))  # fmt: skip

    def add_asset(self, kind: str, asset: AssetRecord, xy, z: float, yaw: float, anchor=(0.0, 0.0)) -> None:
        """Place ``asset`` so its asset-frame point ``anchor`` (xy, m) lands on world ``xy``."""
        origin = np.asarray(xy, dtype=np.float64) - _rot(yaw, anchor)
        self.add(kind, asset.asset_id, asset.category_id, pose_matrix(origin[0], origin[1], z, yaw))


_KIND = {"Building": "building", "Pole": "street_light", "TrafficLight": "traffic_light",
         "TrafficSign": "traffic_sign", "Bicycle": "bicycle"}  # fmt: skip


def _kind(asset: AssetRecord) -> str:
    """Placement-name stem of an asset: its category, or its sub-class for vegetation/props."""
    return _KIND.get(asset.category, asset.subclass)


class _Pools:
    """Assets by category (and sub-class), sorted by (sub-class, asset id) so the town does not
    depend on the order the assets arrive in."""

    def __init__(self, assets: Sequence[AssetRecord]) -> None:
        self.by_cat: dict[str, list[AssetRecord]] = {}
        for a in sorted(assets, key=lambda a: (a.category_id, a.subclass, a.asset_id)):
            self.by_cat.setdefault(a.category, []).append(a)

    def get(self, category: str, subclasses: Sequence[str] | None = None) -> list[AssetRecord]:
        """Assets of ``category`` (restricted to ``subclasses`` when given)."""
        pool = self.by_cat.get(category, [])
        return [a for a in pool if subclasses is None or a.subclass in subclasses]

    def pick(
        self, rng: np.random.Generator, category: str, subclasses: Sequence[str] | None = None
    ) -> AssetRecord | None:
        """A uniformly drawn asset of ``category`` (and ``subclasses``), falling back to any asset
        of the category when no sub-class matches; None when the category is empty."""
        pool = self.get(category, subclasses) or self.get(category)
        return pool[int(rng.integers(len(pool)))] if pool else None


def _rects_overlap(a, b, gap: float = 0.0) -> bool:
    """Whether rectangles (xmin, xmax, ymin, ymax) overlap once ``a`` is grown by ``gap``."""
    return a[0] - gap < b[1] and b[0] < a[1] + gap and a[2] - gap < b[3] and b[2] < a[3] + gap


@dataclass(frozen=True)
class _Side:
    """One kerb line of a sidewalk: from ``start`` along unit ``along`` for ``length`` m; ``out``
    is the unit normal pointing at the road, the sidewalk lies on the ``-out`` side."""

    start: np.ndarray
    along: np.ndarray
    out: np.ndarray
    length: float

    def point(self, a: float, depth: float) -> np.ndarray:
        """World xy at ``a`` m along the kerb and ``depth`` m into the sidewalk (or beyond)."""
        return self.start + self.along * a - self.out * depth


def _block_sides(x0: float, x1: float, y0: float, y1: float) -> list[_Side]:
    """The four kerb lines of a block, counter-clockwise: south, east, north, west."""
    return [
        _Side(np.array([x0, y0]), np.array([1.0, 0.0]), np.array([0.0, -1.0]), x1 - x0),
        _Side(np.array([x1, y0]), np.array([0.0, 1.0]), np.array([1.0, 0.0]), y1 - y0),
        _Side(np.array([x1, y1]), np.array([-1.0, 0.0]), np.array([0.0, 1.0]), x1 - x0),
        _Side(np.array([x0, y1]), np.array([0.0, -1.0]), np.array([-1.0, 0.0]), y1 - y0),
    ]


def _outer_sides(X0: float, X1: float) -> list[_Side]:
    """The kerb lines of the outer sidewalk ring, facing the outer roads (the square ``X0..X1``)."""
    return [
        _Side(np.array([X1, X0]), np.array([-1.0, 0.0]), np.array([0.0, 1.0]), X1 - X0),
        _Side(np.array([X1, X1]), np.array([0.0, -1.0]), np.array([-1.0, 0.0]), X1 - X0),
        _Side(np.array([X0, X1]), np.array([1.0, 0.0]), np.array([0.0, -1.0]), X1 - X0),
        _Side(np.array([X0, X0]), np.array([0.0, 1.0]), np.array([1.0, 0.0]), X1 - X0),
    ]


class _Obstacles:
    """Sidewalk furniture footprints as discs (centre xy, radius), for spacing checks."""

    def __init__(self) -> None:
        self.items: list[tuple[float, float, float]] = []

    def free(self, xy, radius: float, clearance: float = 0.8) -> bool:
        """True when a disc at ``xy`` keeps ``clearance`` m from every disc placed so far."""
        return all(math.hypot(xy[0] - x, xy[1] - y) >= radius + r + clearance for x, y, r in self.items)

    def add(self, xy, radius: float) -> None:
        self.items.append((float(xy[0]), float(xy[1]), radius))


# --------------------------------------------------------------------------------------------
# the town
# --------------------------------------------------------------------------------------------


def _check_config(config: ScenesConfig) -> None:
    """Refuse layouts with no room for a block interior or a walking line."""
    interior = config.block_size - 2 * config.sidewalk_width
    if interior < 4.0:
        raise ValueError(
            f"block_size {config.block_size:g} m minus two sidewalks of {config.sidewalk_width:g} m leaves "
            f"{interior:g} m of block interior; at least 4 m is needed (raise block_size or lower sidewalk_width)"
        )


def build_town(config: ScenesConfig, town_index: int, assets: Sequence[AssetRecord]) -> Town:
    """Build town ``town_index`` (named ``"town%02d"``) from the ADMesh ``assets``.

    Deterministic from ``config.seed`` and ``town_index`` (and the set of assets, whatever their
    order). Needs at least one Building asset; other categories are placed when present
    (Vegetation, Pole, TrafficLight, TrafficSign, Static, Bicycle). Returns the placements (stuff
    first, then buildings, vegetation, traffic lights, street furniture), the world-frame stuff
    meshes and the lane/intersection/walk-loop description of the road network.
    """
    _check_config(config)
    pools = _Pools(assets)
    if not pools.get("Building"):
        cats = sorted(pools.by_cat)
        raise ValueError(f"build_town needs at least one asset of category Building; got categories {cats}")
    name = town_name(town_index)
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, town_index, 0x70776E]))
    n, B, R, S = config.blocks, config.block_size, config.road_width, config.sidewalk_width
    curb = config.curb_height
    P = B + R
    c = [k * P for k in range(n + 1)]
    X0, X1 = c[0] - R / 2, c[-1] + R / 2  # the square covered by the road grid
    n_lanes = lanes_per_direction(R)
    lane_w = (R / 2) / n_lanes

    # 1. lanes: every edge of the node grid, both directions, n_lanes each (right-hand traffic)
    lanes: list[LaneSegment] = []
    edges = [((i, j), (i + 1, j)) for j in range(n + 1) for i in range(n)]
    edges += [((i, j), (i, j + 1)) for i in range(n + 1) for j in range(n)]
    for u, v in edges:
        for a, b in ((u, v), (v, u)):
            ca, cb = np.array([c[a[0]], c[a[1]]]), np.array([c[b[0]], c[b[1]]])
            d = (cb - ca) / np.linalg.norm(cb - ca)
            right = np.array([d[1], -d[0]])
            for k in range(n_lanes):
                off = right * (k + 0.5) * lane_w
                start, end = ca + d * R / 2 + off, cb - d * R / 2 + off
                lanes.append(LaneSegment(
                    lane_id=len(lanes), start_node=a, end_node=b, lane_index=k,
                    direction=(float(d[0]), float(d[1])), start=(float(start[0]), float(start[1])),
                    end=(float(end[0]), float(end[1])), width=lane_w,
                ))  # fmt: skip
    intersections = {
        (i, j): (c[i] - R / 2, c[j] - R / 2, c[i] + R / 2, c[j] + R / 2) for i in range(n + 1) for j in range(n + 1)
    }

    # 2. stuff: road strips (x roads whole, y roads between the x roads), sidewalk rings, terrain
    road_rects = [(X0, X1, cj - R / 2, cj + R / 2) for cj in c]
    road_rects += [(ci - R / 2, ci + R / 2, c[j] + R / 2, c[j + 1] - R / 2) for ci in c for j in range(n)]
    blocks = [(i, j) for j in range(n) for i in range(n)]
    block_rect = {(i, j): (c[i] + R / 2, c[i + 1] - R / 2, c[j] + R / 2, c[j + 1] - R / 2) for i, j in blocks}
    sidewalk_rects = [r for bij in blocks for r in _ring(*block_rect[bij], S)]
    sidewalk_rects += _ring(X0 - S, X1 + S, X0 - S, X1 + S, S)
    # kerb faces: a thin wall under the edge of every sidewalk that borders a road
    kerb_rects = [r for bij in blocks for r in _ring(*block_rect[bij], SURFACE)]
    kerb_rects += _ring(X0 - SURFACE, X1 + SURFACE, X0 - SURFACE, X1 + SURFACE, SURFACE)
    interiors = {bij: (r[0] + S, r[1] - S, r[2] + S, r[3] - S) for bij, r in block_rect.items()}
    g_lo, g_hi = X0 - S - TOWN_MARGIN, X1 + S + TOWN_MARGIN  # the whole ground square
    terrain_rects = list(interiors.values()) + _ring(g_lo, g_hi, g_lo, g_hi, TOWN_MARGIN)
    marking_rects = [r for lane in lanes for r in _marking_rects(lane, R, n_lanes)]
    top = curb - SURFACE
    sidewalk = _slabs(sidewalk_rects, top, curb)
    if top > 0.0:  # no kerb faces on a flush sidewalk
        sidewalk = concatenate([sidewalk, _slabs(kerb_rects, -SURFACE, top)])
    stuff = {
        f"{name}/road": _stuff_geometry(f"{name}/road", _slabs(road_rects, -SURFACE, 0.0), "Road", "asphalt"),
        f"{name}/sidewalk": _stuff_geometry(f"{name}/sidewalk", sidewalk, "Sidewalk", "paving"),
        f"{name}/terrain": _stuff_geometry(f"{name}/terrain", _slabs(terrain_rects, top, curb), "Terrain", "grass"),
        f"{name}/roadline": _stuff_geometry(
            f"{name}/roadline", _slabs(marking_rects, -SURFACE / 2, MARKING_TOP), "RoadLine", "paint"
        ),
    }
    placer = _Placer(name)
    for key in _STUFF_NAMES:
        geom = stuff[f"{name}/{key}"]
        placer.add(key, geom.asset_id, geom.parts[0].semantic_id, np.eye(4), named=key)

    # 3. buildings: walk every block side, street-facing (+X towards the road), set back
    footprints: dict[tuple[int, int], list[tuple[float, float, float, float]]] = {b: [] for b in blocks}
    for bij in blocks:
        downtown = rng.uniform() < 0.35
        weights = (("office", 0.55), ("residential", 0.45)) if downtown else (("house", 0.65), ("residential", 0.35))
        inner = interiors[bij]
        for side in _block_sides(*block_rect[bij]):
            a = S + float(rng.uniform(0.5, 2.0))
            while a < side.length - S - 4.0:
                placed = False
                for _ in range(4):  # a few draws; a smaller building may fit where a large did not
                    sub = weights[0][0] if rng.uniform() < weights[0][1] else weights[1][0]
                    asset = pools.pick(rng, "Building", [sub])
                    depth, front = asset.extent[0], asset.extent[1]
                    setback = float(rng.uniform(1.0, 3.0))
                    centre = side.point(a + front / 2, S + setback + depth / 2)
                    half = np.abs(side.out) * depth / 2 + np.abs(side.along) * front / 2
                    rect = (centre[0] - half[0], centre[0] + half[0], centre[1] - half[1], centre[1] + half[1])
                    inside = (rect[0] >= inner[0] + 0.5 and rect[1] <= inner[1] - 0.5
                              and rect[2] >= inner[2] + 0.5 and rect[3] <= inner[3] - 0.5)  # fmt: skip
                    if inside and not any(_rects_overlap(rect, f, 1.5) for f in footprints[bij]):
                        footprints[bij].append(rect)
                        placer.add_asset("building", asset, centre, curb, _yaw_of(side.out))
                        a += front + float(rng.uniform(1.5, 4.0))
                        placed = True
                        break
                if not placed:
                    a += 2.0

    # 4. vegetation inside blocks and in the outer margin, clear of buildings and of each other
    plants: list[tuple[float, float, float]] = []

    def plant_at(xy, asset: AssetRecord, rects) -> bool:
        radius = max(asset.extent[0], asset.extent[1]) / 2
        box = (xy[0] - radius, xy[0] + radius, xy[1] - radius, xy[1] + radius)
        if any(_rects_overlap(box, f, 0.5) for f in rects):
            return False
        if any(math.hypot(xy[0] - x, xy[1] - y) < radius + r for x, y, r in plants):
            return False
        plants.append((float(xy[0]), float(xy[1]), radius))
        placer.add_asset(_kind(asset), asset, xy, curb, float(rng.uniform(-math.pi, math.pi)))
        return True

    if pools.get("Vegetation"):
        for bij in blocks:
            inner = interiors[bij]
            for _ in range(int(rng.integers(3, 8))):
                asset = pools.pick(rng, "Vegetation")
                r = max(asset.extent[0], asset.extent[1]) / 2
                if inner[1] - inner[0] <= 2 * r + 1 or inner[3] - inner[2] <= 2 * r + 1:
                    continue
                for _attempt in range(10):
                    xy = (rng.uniform(inner[0] + r + 0.5, inner[1] - r - 0.5),
                          rng.uniform(inner[2] + r + 0.5, inner[3] - r - 0.5))  # fmt: skip
                    if plant_at(xy, asset, footprints[bij]):
                        break
        # margin: a loose band of trees, one try per ~12 m of perimeter
        lo, hi = X0 - S, X1 + S
        for _ in range(int(4 * (hi - lo) / 12)):
            asset = pools.pick(rng, "Vegetation")
            t, depth = float(rng.uniform(lo, hi)), float(rng.uniform(2.0, TOWN_MARGIN - 3.0))
            side = int(rng.integers(4))
            xy = [(t, lo - depth), (hi + depth, t), (t, hi + depth), (lo - depth, t)][side]
            plant_at(xy, asset, [])

    # 5. traffic lights: one per intersection approach, on the kerb corner at the approach's right
    furniture = _Obstacles()
    pole_depth = min(0.5, 0.4 * S)
    overhead = R / 2 >= 3.0
    if pools.get("TrafficLight"):
        for (i, j) in sorted(intersections):
            centre = np.array([c[i], c[j]])
            for d in ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)):
                prev = (i - int(d[0]), j - int(d[1]))
                if prev not in intersections:
                    continue  # no road arrives from that side
                d_ = np.array(d)
                right = np.array([d_[1], -d_[0]])
                pole = centre - d_ * (R / 2 + pole_depth) + right * (R / 2 + pole_depth)
                asset = pools.pick(rng, "TrafficLight", ["overhead_signal"] if overhead else ["vehicle_signal"])
                ext = asset.extent
                # the pole axis in the asset frame (mast-arm signals have it at the +Y end)
                pole_y = ext[1] / 2 - POLE_RADIUS if asset.subclass == "overhead_signal" else 0.0
                anchor = (-ext[0] / 2 + POLE_RADIUS, pole_y)
                placer.add_asset("traffic_light", asset, pole, curb, _yaw_of(-d_), anchor)
                furniture.add(pole, 0.3)

    # 6. sidewalk furniture along every kerb: street lights, street trees, a sign, bench, bin, bike
    street_trees = pools.get("Vegetation", ["tree"])
    fz = min(1.2, 0.45 * S)  # furniture zone next to the kerb; walkers use the rest
    sides = [s for bij in blocks for s in _block_sides(*block_rect[bij])] + _outer_sides(X0, X1)
    for side in sides:
        a_lo, a_hi = S + 1.0, side.length - S - 1.0
        if a_hi <= a_lo:
            continue
        # street lights every 24-30 m, arm over the road
        light = pools.pick(rng, "Pole", ["street_light"])
        a = a_lo + float(rng.uniform(2.0, 8.0))
        while light is not None and a < a_hi:
            xy = side.point(a, pole_depth)
            if furniture.free(xy, 0.3):
                anchor = (-light.extent[0] / 2 + POLE_RADIUS, 0.0)
                placer.add_asset("street_light", light, xy, curb, _yaw_of(side.out), anchor)
                furniture.add(xy, 0.3)
            a += float(rng.uniform(24.0, 30.0))
        # street trees every 10-16 m (high crowns only), trunk in the furniture zone
        a = a_lo + float(rng.uniform(4.0, 10.0))
        while street_trees and a < a_hi:
            xy = side.point(a, max(fz / 2, pole_depth))
            tree = street_trees[int(rng.integers(len(street_trees)))]
            if furniture.free(xy, 0.5, 1.5):
                placer.add_asset(_kind(tree), tree, xy, curb, float(rng.uniform(-math.pi, math.pi)))
                furniture.add(xy, 0.5)
            a += float(rng.uniform(10.0, 16.0))
        # one traffic sign, facing the traffic that drives along this kerb
        sign = pools.pick(rng, "TrafficSign")
        if sign is not None and rng.uniform() < 0.8:
            xy = side.point(float(rng.uniform(a_lo, a_hi)), pole_depth)
            if furniture.free(xy, 0.4):
                facing = np.array([-side.out[1], side.out[0]])  # against the kerb-side lane's travel
                anchor = (-sign.extent[0] / 2 + POLE_RADIUS, 0.0)
                placer.add_asset("traffic_sign", sign, xy, curb, _yaw_of(facing), anchor)
                furniture.add(xy, 0.4)
        # a bench (facing the buildings), a bin and a parked bicycle, when the zone is wide enough
        if fz < 0.6:
            continue
        for category, subclass, p_place, yaw_dir in (
            ("Static", "bench", 0.5, -side.out), ("Static", "bin", 0.5, -side.out), ("Bicycle", None, 0.3, side.along),
        ):  # fmt: skip
            asset = pools.pick(rng, category, [subclass] if subclass else None)
            if asset is None or rng.uniform() >= p_place:
                continue
            radius = max(asset.extent[0], asset.extent[1]) / 2
            xy = side.point(float(rng.uniform(a_lo, a_hi)), fz / 2)
            if furniture.free(xy, radius):
                placer.add_asset(_kind(asset), asset, xy, curb, _yaw_of(yaw_dir))
                furniture.add(xy, radius)

    # 7. walking lines: per block, one loop each way on the walker part of the sidewalk
    loops: list[WalkLoop] = []
    for bij in blocks:
        x0, x1, y0, y1 = block_rect[bij]
        for frac, ccw in ((0.3, True), (0.75, False)):
            o = fz + frac * (S - fz)
            corners = [(x0 + o, y0 + o), (x1 - o, y0 + o), (x1 - o, y1 - o), (x0 + o, y1 - o)]
            loops.append(WalkLoop(block=bij, corners=tuple(corners if ccw else corners[::-1]), z=curb))

    road_length = 2 * (n + 1) * (X1 - X0)
    return Town(
        name=name, index=town_index, placements=placer.records, stuff=stuff, lanes=tuple(lanes),
        intersections=intersections, walk_loops=tuple(loops), road_length=float(road_length),
        road_width=R, curb_height=curb, bounds=(g_lo, g_lo, g_hi, g_hi),
        max_instance_id=placer.next_instance - 1,
    )  # fmt: skip
