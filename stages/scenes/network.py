"""The town contract: what every town builder (procedural styles, OpenDRIVE) hands to traffic
simulation and to per-frame assembly.

World frame of the town: metres, right-handed, Z up. Everything here is plain numpy and frozen
dataclasses, independent of how the town was made:

* :class:`Lane` -- a directed driving lane as a polyline along its centre, in the travel
  direction, at the road surface. Lanes chain through ``successors``. Lanes crossing a junction
  (connector lanes) carry the junction's id; a vehicle reserves the junction before it enters
  one. ``left`` / ``right`` name the adjacent same-direction lanes that run parallel to this one
  over its whole length (lane changes move between them).
* :class:`Walkway` -- an undirected walking line (sidewalk or crosswalk) between two walk-graph
  nodes. Crosswalks cross a carriageway; the ones inside a junction's reservation zone carry its
  id so walkers and vehicles never share the zone unsafely.
* :class:`RoadNetwork` -- lanes, walkways and the road length the traffic densities refer to.
* :class:`Town` -- the network plus the placements (stuff first, at identity poses) and the
  world-frame stuff meshes keyed ``"<town>/<name>"``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.meshes import AssetGeometry
from carlaocc.schemas.records import PlacementRecord

__all__ = ["Lane", "Walkway", "RoadNetwork", "Town", "polyline_lengths", "polyline_at", "check_network"]

URBAN_SPEED_LIMIT = 30.0 / 3.6  # m/s, default lane speed limit


def polyline_lengths(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (m) at each vertex of a (K, 2|3) polyline, measured in xy."""
    p = np.asarray(points, dtype=np.float64)
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p[:, :2], axis=0).T))])


def polyline_at(points: np.ndarray, cum: np.ndarray, s) -> tuple[np.ndarray, np.ndarray]:
    """Position (…, 3) and heading yaw (…,) rad at arc length(s) ``s`` (clamped to the line).

    ``points`` is (K, 3), ``cum`` its :func:`polyline_lengths`. Positions are linear between
    vertices; the heading turns linearly from one vertex tangent to the next (a vertex's tangent
    bisects its two segments), so it is continuous and its rate follows the curvature."""
    s = np.clip(np.asarray(s, dtype=np.float64), 0.0, cum[-1])
    # 1. the segment holding each s (zero-length segments are never chosen)
    i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2)
    seg = np.maximum(cum[i + 1] - cum[i], 1e-12)
    # 2. linear interpolation of the position inside it
    t = (s - cum[i]) / seg
    p0, p1 = points[i], points[i + 1]
    pos = p0 + t[..., None] * (p1 - p0)
    # 3. heading: segment headings, vertex tangents bisecting them, blended along the segment
    d = np.diff(points[:, :2], axis=0)
    seg_yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    vertex_yaw = np.concatenate([seg_yaw[:1], (seg_yaw[:-1] + seg_yaw[1:]) / 2, seg_yaw[-1:]])
    yaw = vertex_yaw[i] + t * (vertex_yaw[i + 1] - vertex_yaw[i])
    return pos, np.remainder(yaw + np.pi, 2 * np.pi) - np.pi


class _Polyline:
    """Shared by lanes and walkways: ``points`` (K, 3) and their cumulative length ``cum``."""

    points: np.ndarray
    cum: np.ndarray

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points, dtype=np.float64)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cum", polyline_lengths(pts))

    @property
    def length(self) -> float:
        """Length along the line (m)."""
        return float(self.cum[-1])

    def at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Position(s) and yaw(s) (in the line's direction) at arc length ``s`` m from its start."""
        return polyline_at(self.points, self.cum, s)


@dataclass(frozen=True)
class Lane(_Polyline):
    """A directed driving lane (world frame, m). ``points`` (K >= 2, 3) follow the lane centre in
    the travel direction at the road surface; consecutive points are distinct in xy."""

    lane_id: int
    points: np.ndarray
    width: float
    successors: tuple[int, ...] = ()
    left: int = -1  # adjacent same-direction lane on the left, parallel over the whole lane, or -1
    right: int = -1
    junction: int = -1  # id of the junction a connector lane crosses, -1 on ordinary road
    speed_limit: float = URBAN_SPEED_LIMIT  # m/s
    road: str = ""  # the road it belongs to (OpenDRIVE road id, or the builder's road name)
    # (K, 3) upward unit normals of the road surface at ``points`` (elevation and superelevation
    # tilt it), or None for a level road (0, 0, 1)
    normals: np.ndarray | None = field(default=None, repr=False, compare=False)
    cum: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.normals is not None:
            n = np.asarray(self.normals, dtype=np.float64).reshape(-1, 3)
            object.__setattr__(self, "normals", n / np.linalg.norm(n, axis=1, keepdims=True))

    def up_at(self, s) -> np.ndarray:
        """Upward unit normal(s) (…, 3) of the road surface at arc length(s) ``s`` (clamped):
        linear between the points' normals, renormalized; (0, 0, 1) on a level lane."""
        s = np.asarray(s, dtype=np.float64)
        if self.normals is None:
            return np.broadcast_to(np.array([0.0, 0.0, 1.0]), s.shape + (3,)).copy()
        s = np.clip(s, 0.0, self.cum[-1])
        i = np.clip(np.searchsorted(self.cum, s, side="right") - 1, 0, len(self.cum) - 2)
        t = (s - self.cum[i]) / np.maximum(self.cum[i + 1] - self.cum[i], 1e-12)
        n = self.normals[i] + t[..., None] * (self.normals[i + 1] - self.normals[i])
        return n / np.linalg.norm(n, axis=-1, keepdims=True)



@dataclass(frozen=True)
class Walkway(_Polyline):
    """An undirected walking line between walk-graph nodes ``start_node`` and ``end_node``
    (world frame, m): ``points`` (K >= 2, 3) on the walking surface, from start to end."""

    walkway_id: int
    points: np.ndarray
    start_node: int
    end_node: int
    width: float = 2.0  # m of walkable width (walkers keep right of the centre)
    crosswalk: bool = False
    junction: int = -1  # crosswalks inside a junction's reservation zone: that junction's id
    cum: np.ndarray = field(init=False, repr=False, compare=False)



@dataclass(frozen=True)
class RoadNetwork:
    """Lanes (ids = index), walkways (ids = index) and the road length (m of road centreline,
    each road counted once) that traffic densities per km refer to."""

    lanes: tuple[Lane, ...]
    walkways: tuple[Walkway, ...]
    road_length: float

    @property
    def junction_ids(self) -> tuple[int, ...]:
        return tuple(sorted({ln.junction for ln in self.lanes if ln.junction >= 0}))


@dataclass(frozen=True)
class Town:
    """A town: placements (stuff first with identity poses, then things), world-frame stuff
    meshes keyed ``"<town>/<name>"`` (the asset ids of the stuff placements), the road network,
    the ground bounds and the largest instance id handed out (actors are numbered above it)."""

    name: str
    index: int
    style: str
    source: str  # OpenDRIVE file of opendrive towns, "" for procedural ones
    placements: list[PlacementRecord]
    stuff: dict[str, AssetGeometry]
    network: RoadNetwork
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax of the ground (m)
    max_instance_id: int
    curb_height: float = 0.15


def check_network(net: RoadNetwork) -> None:
    """Raise ``ValueError`` naming the first broken invariant of ``net``: at least one lane, ids
    equal to positions, successor and neighbour references valid, lanes at least 0.5 m long with
    finite points and a positive width, normals (when given) finite, one per point and upward, neighbours running the same way, walkways with finite
    points and non-negative node ids, and a positive road length. (Dead ends are the builders'
    business: they keep the strongly connected part of their lane graph.)"""
    if not net.lanes:
        raise ValueError("the road network has no lanes")
    n = len(net.lanes)
    for k, ln in enumerate(net.lanes):
        where = f"lane {ln.lane_id} (road {ln.road!r})"
        if ln.lane_id != k:
            raise ValueError(f"{where}: lane ids must equal their position, found at {k}")
        if ln.points.ndim != 2 or ln.points.shape[1] != 3 or len(ln.points) < 2:
            raise ValueError(f"{where}: points must be (K >= 2, 3), got {ln.points.shape}")
        if not np.all(np.isfinite(ln.points)):
            raise ValueError(f"{where}: non-finite points")
        if ln.normals is not None and (ln.normals.shape != ln.points.shape or not np.all(np.isfinite(ln.normals))
                                       or np.any(ln.normals[:, 2] <= 0.0)):  # fmt: skip
            raise ValueError(f"{where}: normals must be finite, one per point, and point upwards")
        if ln.length < 0.5:
            raise ValueError(f"{where}: {ln.length:.3f} m long, shorter than 0.5 m")
        if not (math.isfinite(ln.width) and ln.width > 0):
            raise ValueError(f"{where}: width {ln.width} is not positive")
        for s in ln.successors:
            if not 0 <= s < n:
                raise ValueError(f"{where}: successor {s} does not exist")
        for side in ("left", "right"):
            m = getattr(ln, side)
            if m == -1:
                continue
            if not 0 <= m < n or m == k:
                raise ValueError(f"{where}: {side} neighbour {m} does not exist")
            other = net.lanes[m]
            # neighbours run the same way: headings at the middle agree within 45 degrees
            _, y0 = ln.at(ln.length / 2)
            _, y1 = other.at(other.length / 2)
            if math.cos(float(y0) - float(y1)) < math.cos(math.pi / 4):
                raise ValueError(f"{where}: {side} neighbour {m} runs the other way")
    nodes = {w.start_node for w in net.walkways} | {w.end_node for w in net.walkways}
    for k, w in enumerate(net.walkways):
        if w.walkway_id != k:
            raise ValueError(f"walkway {w.walkway_id}: ids must equal their position, found at {k}")
        if len(w.points) < 2 or w.length < 0.2 or not np.all(np.isfinite(w.points)):
            raise ValueError(f"walkway {w.walkway_id}: needs >= 2 finite points and 0.2 m of length")
    if nodes and min(nodes) < 0:
        raise ValueError("walk-graph node ids must be >= 0")
    if not (math.isfinite(net.road_length) and net.road_length > 0):
        raise ValueError(f"road_length {net.road_length} must be positive")
