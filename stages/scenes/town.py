"""Procedural towns in three styles (``downtown``, ``suburb``, ``arterial``) on the town contract of
:mod:`stages.scenes.network`.

World frame: metres, right-handed, Z up, the road surface at z = 0. Every style is a road grid:
``nx + 1`` straight north-south *columns* at ``x = cx[i]`` and ``ny + 1`` east-west *rows* at
``y = ry[j]``; in the arterial style the middle row is the arterial, shifted sideways between
junctions by smooth S-curves (sampled at <= :data:`SAMPLE` m, straight for :data:`FLAT` m beyond
each junction zone), so every junction is axis-aligned. Each road has a cross-section
(:class:`_Section`): ``lanes`` lanes of :data:`LANE_WIDTH` m each way (right-hand traffic), an
optional raised median (grass, kerbed, with a guard rail) and an optional parking strip along each
kerb. ``block_size`` is the kerb-to-kerb distance between neighbouring roads.

Junction zones: the square ``|x - cx| <= Hc + Z``, ``|y - cy| <= Hr + Z`` around a junction centre
(``Hc``/``Hr`` the column/row half-widths, ``Z`` the zone depth). It holds the crosswalk (zebra) of
every approach and the stop line at its edge; road lanes end at the zone edge and connector lanes
(straight, left and right turns, cubic curves sampled <= 1 m, carrying the junction id) cross it.
The zone's corner squares (``Z`` by ``Z``) are sidewalk. Blocks are bounded by sidewalks of width
``S`` along every road; their interior is grass (Terrain) at kerb height holding the lots. Around
the outermost roads runs a sidewalk ring of width ``max(S, Z)`` and a terrain margin of
:data:`TOWN_MARGIN` m.

Stuff meshes (world frame, identity pose, keys ``"<town>/<name>"``) are **thin closed slabs**
(:data:`SURFACE` thick) standing for surfaces, tessellated into pieces of at most
:data:`STUFF_TILE` m: straight pieces are axis-aligned tiled slabs, curved pieces are extruded
ribbons (grids along a polyline and across offsets from it). The road is ``[-SURFACE, 0]``;
sidewalk, terrain and median tops are ``[curb - SURFACE, curb]``; the sidewalk mesh also holds the
kerb faces (thin walls ``[-SURFACE, curb - SURFACE]`` under every kerb edge); road markings are
``[0, MARKING_TOP]`` on the road; fences, walls and guard rails stand on the grass. Pieces touch at
faces or edges only, every piece is closed on its own, so every stuff mesh is watertight.

Things and props are placed on their support (kerb height) and never overlap one another: every
placement registers an oriented footprint (pole-like assets a small square at the pole axis, found
through the asset-frame conventions of :mod:`stages.ingest.procedural` with :data:`POLE_RADIUS`;
trees their crown in lots and their trunk on sidewalks). Buildings fill lots along every block
side, street-facing, choosing the asset whose footprint fits the lot best. Nothing but connector
and road lanes lies on the carriageway except parked cars, which stay inside the parking strips.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.geometry import concatenate
from carlaocc.stages.scenes.network import Lane, RoadNetwork, Town, Walkway, polyline_lengths
from carlaocc.stages.scenes.placing import (
    POLE_RADIUS,
    STUFF_TILE,
    SURFACE,
    AssetPools,
    Placer,
    grid_slab,
    rot2,
    slab,
    slabs,
    stuff_geometry,  # fmt: skip
    yaw_of,
)

__all__ = ["STYLES", "build_procedural_town", "town_name"]

STYLES = ("downtown", "suburb", "arterial")
LANE_WIDTH = 3.5  # m
TOWN_MARGIN = 20.0  # m of terrain beyond the outer sidewalk ring
MARKING_TOP = 0.01  # m: road markings stand 1 cm proud of the road
CROSSWALK_Z = 0.01  # m: crosswalk walkways lie on the zebra
ZEBRA = 3.0  # m: crosswalk band width along the road
SAMPLE = 1.0  # m: largest spacing of curve samples (lanes, curved roads)
FLAT = 6.0  # m: straight road kept beyond each junction zone on a curved row
MEDIAN = 2.0  # m: arterial median width
URBAN = 30.0 / 3.6  # m/s
ARTERIAL = 50.0 / 3.6
TURN = 25.0 / 3.6
_AXES = ((1, 0), (0, 1), (-1, 0), (0, -1))  # arm directions E, N, W, S


@dataclass(frozen=True)
class _Section:
    """Road cross-section: ``lanes`` each way next to a median (0 = painted centre line), a
    parking strip at each kerb, ``half`` = centre line to kerb (m)."""

    lanes: int
    half: float
    median: float = 0.0
    parking: float = 0.0
    speed: float = URBAN

    def lane_offset(self, k: int) -> float:
        """Distance of lane ``k`` (0 next to the centre) from the centre line."""
        return self.median / 2 + (k + 0.5) * LANE_WIDTH


@dataclass(frozen=True)
class _Style:
    blocks: int
    block_size: float
    road_width: float | None  # None: derived from the lanes
    sidewalk_width: float
    lanes: int
    parking: float
    median: float
    buildings: tuple[str, ...]
    lot: tuple[float, float]  # lot frontage range, m
    setback: tuple[float, float]  # building setback behind the sidewalk, m
    max_depth: float  # largest building depth, m
    light_spacing: tuple[float, float]
    tree_spacing: tuple[float, float] | None  # street trees on sidewalks
    lot_trees: tuple[int, int]  # trees per lot
    signal_share: float  # share of junctions with traffic lights (others get stop signs)
    furniture: float  # chance of each bench / bin / bicycle / hydrant per sidewalk side
    frontage: str  # "", "fence" (with hedges) or "wall" (walls on the main road, fences elsewhere)


_STYLES = {
    "downtown": _Style(3, 70.0, None, 4.0, 2, 0.0, 0.0,
                       ("office", "tower", "commercial", "residential", "apartment", "public"),
                       (20.0, 34.0), (0.5, 1.5), 30.0, (22.0, 28.0), (9.0, 14.0), (0, 1), 1.0, 0.7, ""),
    "suburb": _Style(2, 110.0, None, 2.5, 1, 2.5, 0.0, ("house", "garage", "residential"),
                     (17.0, 24.0), (4.0, 7.0), 16.0, (34.0, 42.0), (8.0, 12.0), (2, 5), 0.3, 0.3, "fence"),
    "arterial": _Style(3, 90.0, None, 3.0, 1, 0.0, 0.0,
                       ("commercial", "industrial", "warehouse", "gas_station", "office", "apartment", "public",
                        "religious"), (30.0, 48.0), (3.0, 6.0), 40.0, (26.0, 32.0), (14.0, 20.0), (1, 3),
                       1.0, 0.3, "wall"),
}  # fmt: skip


def town_name(index: int) -> str:
    """``0 -> "town00"``."""
    return f"town{index:02d}"


# --------------------------------------------------------------------------------------------
# polylines and extruded slabs
# --------------------------------------------------------------------------------------------


def _tangents(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vertex tangents of an (K, 2) polyline and the left normals scaled for a constant offset
    distance (mitred)."""
    D = np.diff(P, axis=0)
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    T = np.vstack([D[:1], D[:-1] + D[1:], D[-1:]])
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    seg = np.vstack([D[:1], D])  # a segment meeting each vertex
    scale = 1.0 / np.maximum(np.einsum("ij,ij->i", T, seg), 0.5)
    return T, np.column_stack([-T[:, 1], T[:, 0]]) * scale[:, None]


def _offset(P: np.ndarray, d: float) -> np.ndarray:
    """The polyline ``P`` moved ``d`` m to its left (negative: right)."""
    return P + _tangents(P)[1] * d


def _densify(P: np.ndarray, step: float) -> np.ndarray:
    """``P`` with points inserted so that no segment is longer than ``step`` m."""
    seg = np.diff(P, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / step - 1e-9).astype(np.int64))
    if np.all(n == 1):
        return P
    k = np.repeat(np.arange(len(seg)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n, n)
    return np.vstack([P[:1], P[k] + t[:, None] * seg[k]])


def _sub(P: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of polyline ``P`` between arc lengths ``s0 < s1``."""
    cum = polyline_lengths(P)
    s0, s1 = max(0.0, s0), min(float(cum[-1]), s1)
    inner = P[(cum > s0 + 1e-9) & (cum < s1 - 1e-9)]
    ends = [np.array([np.interp(s, cum, P[:, k]) for k in range(2)]) for s in (s0, s1)]
    return np.vstack([ends[0], inner, ends[1]])


def _at(P: np.ndarray, cum: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Point and unit tangent of polyline ``P`` at arc length ``s``."""
    s = min(max(s, 0.0), float(cum[-1]))
    i = min(max(int(np.searchsorted(cum, s, side="right")) - 1, 0), len(P) - 2)
    d = P[i + 1] - P[i]
    L = float(np.linalg.norm(d))
    return P[i] + d * ((s - cum[i]) / L), d / L


def _ribbon(P: np.ndarray, o0: float, o1: float, z0: float, z1: float):
    """Closed slab over the band between left offsets ``o0 < o1`` of polyline ``P``."""
    P = _densify(P, STUFF_TILE)
    N = _tangents(P)[1]
    offs = np.linspace(o0, o1, max(1, math.ceil((o1 - o0) / STUFF_TILE - 1e-9)) + 1)
    return grid_slab(P[:, None, :] + N[:, None, :] * offs[None, :, None], z0, z1)


def _strip(x: np.ndarray, yb: np.ndarray, yt: np.ndarray, z0: float, z1: float):
    """Closed slab over the x-monotone region ``yb(x) <= y <= yt(x)`` sampled at ``x``."""
    m = max(1, math.ceil(float(np.max(yt - yb)) / STUFF_TILE - 1e-9))
    t = np.linspace(0.0, 1.0, m + 1)[None, :]
    G = np.stack([np.repeat(x[:, None], m + 1, axis=1), yb[:, None] + (yt - yb)[:, None] * t], axis=-1)
    return grid_slab(G, z0, z1)


def _rect(cx: float, cy: float, u, a0: float, a1: float, b0: float, b1: float):
    """Axis-aligned rect (xmin, xmax, ymin, ymax) of ``a0..a1`` along the axis ``u`` and
    ``b0..b1`` along its left normal, from (cx, cy)."""
    v = (-u[1], u[0])
    xs = [cx + u[0] * a + v[0] * b for a in (a0, a1) for b in (b0, b1)]
    ys = [cy + u[1] * a + v[1] * b for a in (a0, a1) for b in (b0, b1)]
    return (min(xs), max(xs), min(ys), max(ys))


def _ring(x0: float, x1: float, y0: float, y1: float, w: float):
    """Four non-overlapping rects forming the ring of width ``w`` just inside the rect."""
    return [(x0, x1, y0, y0 + w), (x0, x1, y1 - w, y1), (x0, x0 + w, y0 + w, y1 - w), (x1 - w, x1, y0 + w, y1 - w)]


def _bezier(p0, h0, p1, h1) -> np.ndarray:
    """Cubic curve from ``p0`` heading ``h0`` to ``p1`` heading ``h1`` (unit), sampled <= 1 m."""
    chord = float(np.linalg.norm(p1 - p0))
    if abs(h0[0] * h1[0] + h0[1] * h1[1] - 1.0) < 1e-9 and abs(h0[0] * (p1 - p0)[1] - h0[1] * (p1 - p0)[0]) < 1e-6:
        n = max(1, math.ceil(chord / (0.9 * SAMPLE)))
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        return p0 + t * (p1 - p0)
    turn = h0[0] * h1[1] - h0[1] * h1[0]  # > 0: left turn
    k = (0.45 if turn > 0.5 else 0.85) * chord  # right turns: long handles swing wide of the kerb corner
    c0, c1 = p0 + h0 * k, p1 - h1 * k
    t = np.linspace(0.0, 1.0, 257)[:, None]
    dense = (1 - t) ** 3 * p0 + 3 * (1 - t) ** 2 * t * c0 + 3 * (1 - t) * t**2 * c1 + t**3 * p1
    cum = polyline_lengths(dense)
    s = np.linspace(0.0, cum[-1], max(2, math.ceil(cum[-1] / (0.9 * SAMPLE))) + 1)  # even arc-length steps
    out = np.column_stack([np.interp(s, cum, dense[:, 0]), np.interp(s, cum, dense[:, 1])])
    out[0], out[-1] = p0, p1
    return out


def _inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test of (M, 2) ``pts`` against the closed (K, 2) ``poly``."""
    a, b = poly, np.roll(poly, -1, axis=0)
    x, y = pts[:, 0:1], pts[:, 1:2]
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    xint = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / np.where(b[:, 1] == a[:, 1], 1e-12, b[:, 1] - a[:, 1])
    return (np.sum(cond & (x < xint), axis=1) % 2) == 1


def _ray(poly: np.ndarray, p, d) -> float:
    """Distance from ``p`` along unit ``d`` to the nearest edge of the closed ``poly``."""
    a, b = poly, np.roll(poly, -1, axis=0)
    e = b - a
    den = d[0] * e[:, 1] - d[1] * e[:, 0]
    ok = np.abs(den) > 1e-12
    w = a - p
    t = np.where(ok, (w[:, 0] * e[:, 1] - w[:, 1] * e[:, 0]) / np.where(ok, den, 1.0), np.inf)
    u = np.where(ok, (w[:, 0] * d[1] - w[:, 1] * d[0]) / np.where(ok, den, 1.0), -1.0)
    hit = ok & (t > 1e-6) & (u >= 0) & (u <= 1)
    return float(t[hit].min()) if hit.any() else 0.0


# --------------------------------------------------------------------------------------------
# footprints
# --------------------------------------------------------------------------------------------


class _Footprints:
    """Oriented footprint rectangles (centre, half sizes, yaw) in a spatial hash; separating-axis
    overlap tests keep placements apart."""

    CELL = 16.0

    def __init__(self) -> None:
        self.items: list[tuple[np.ndarray, np.ndarray]] = []  # corners (4, 2), axes (2, 2)
        self.grid: dict[tuple[int, int], list[int]] = {}

    @staticmethod
    def corners(c, half, yaw: float) -> tuple[np.ndarray, np.ndarray]:
        u = np.array([math.cos(yaw), math.sin(yaw)])
        v = np.array([-u[1], u[0]])
        k = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=np.float64)
        pts = np.asarray(c, dtype=np.float64)[:2] + (k[:, :1] * half[0]) * u + (k[:, 1:] * half[1]) * v
        return pts, np.stack([u, v])

    def _cells(self, pts: np.ndarray):
        lo, hi = np.floor(pts.min(axis=0) / self.CELL).astype(int), np.floor(pts.max(axis=0) / self.CELL).astype(int)
        return [(i, j) for i in range(lo[0], hi[0] + 1) for j in range(lo[1], hi[1] + 1)]

    def free(self, c, half, yaw: float, gap: float = 0.3) -> bool:
        pts, ax = self.corners(c, (half[0] + gap / 2, half[1] + gap / 2), yaw)
        seen: set[int] = set()
        for cell in self._cells(pts):
            for k in self.grid.get(cell, ()):
                if k in seen:
                    continue
                seen.add(k)
                q, bx = self.items[k]
                if not any(self._apart(pts, q, a) for a in (*ax, *bx)):
                    return False
        return True

    @staticmethod
    def _apart(p: np.ndarray, q: np.ndarray, a: np.ndarray) -> bool:
        pa, qa = p @ a, q @ a
        return pa.max() <= qa.min() or qa.max() <= pa.min()

    def add(self, c, half, yaw: float, gap: float = 0.3) -> None:
        pts, ax = self.corners(c, (half[0] + gap / 2, half[1] + gap / 2), yaw)
        self.items.append((pts, ax))
        for cell in self._cells(pts):
            self.grid.setdefault(cell, []).append(len(self.items) - 1)


# --------------------------------------------------------------------------------------------
# layout
# --------------------------------------------------------------------------------------------


@dataclass
class _Segment:
    """A road between two junction zones: centreline ``P`` (K, 2) from zone edge to zone edge, the
    junctions at either end with the arm directions (outward from each junction), and the regions
    (``("block", i, j)`` or ``("outer",)``) on its left and right."""

    name: str
    P: np.ndarray
    sec: _Section
    ja: tuple[int, int]
    jb: tuple[int, int]
    ua: tuple[int, int]
    ub: tuple[int, int]
    left: tuple
    right: tuple
    cum: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.cum = polyline_lengths(self.P)

    @property
    def length(self) -> float:
        return float(self.cum[-1])


class _Layout:
    """Grid positions, cross-sections, junctions and road segments of one town."""

    def __init__(self, style: str, st: _Style, spec: TownSpec, rng: np.random.Generator) -> None:
        B = spec.block_size if spec.block_size is not None else st.block_size
        S = spec.sidewalk_width if spec.sidewalk_width is not None else st.sidewalk_width
        n = spec.blocks if spec.blocks is not None else st.blocks
        self.B, self.S = B, S
        self.nx, self.ny = n, (2 if style == "arterial" else n)
        self.zc = max(2.0, S / 2 + 0.6)  # crosswalk centre beyond the cross road's kerb
        self.Z = max(S, self.zc + ZEBRA / 2 + 1.0)  # junction zone depth beyond the cross road's kerb
        if B - 2 * self.Z < 6.0:
            raise ValueError(
                f"block_size {B:g} m is too small for sidewalks of {S:g} m: the junction corners take "
                f"{self.Z:g} m at each end and at least 6 m of block interior must remain"
            )
        main = _section(spec.road_width, st.lanes, st.parking, st.median, URBAN)
        if style == "arterial":
            lanes = int(rng.integers(2, 4))
            art = _section(spec.road_width, lanes, 0.0, MEDIAN, ARTERIAL, shoulder=0.5)
            local = _section(None, 1, 0.0, 0.0, URBAN, shoulder=1.0)  # room for turns off the arterial
            self.cols = [local] * (self.nx + 1)
            self.rows = [local, art, local]
        else:
            self.cols = [main] * (self.nx + 1)
            self.rows = [main] * (self.ny + 1)
        Hc = [s.half for s in self.cols]
        Hr = [s.half for s in self.rows]
        self.cx = [0.0]
        for i in range(self.nx):
            self.cx.append(self.cx[-1] + Hc[i] + B + Hc[i + 1])
        self.ry = [0.0]
        for j in range(self.ny):
            self.ry.append(self.ry[-1] + Hr[j] + B + Hr[j + 1])
        # lateral shifts of each row at each column (the arterial's S-curves)
        self.shift = [[0.0] * (self.nx + 1) for _ in range(self.ny + 1)]
        self.curved = [False] * (self.ny + 1)
        if style == "arterial":
            amp = min(12.0, 0.15 * B, (B - 2 * self.Z - 30.0) / 2)
            runs = [self.cx[i + 1] - self.cx[i] - Hc[i] - Hc[i + 1] - 2 * (self.Z + FLAT) for i in range(self.nx)]
            if amp > 1.0 and min(runs) >= 30.0:
                amp = min(amp, 0.2 * min(runs))
                self.shift[1] = [float(rng.uniform(-amp, amp)) for _ in range(self.nx + 1)]
                self.curved[1] = True
        self.X0, self.X1 = self.cx[0] - Hc[0], self.cx[-1] + Hc[-1]
        self.Y0, self.Y1 = self.ry[0] - Hr[0], self.ry[-1] + Hr[-1]
        self.ring = max(S, self.Z)
        self.segments = self._segments()

    def centre(self, i: int, j: int) -> np.ndarray:
        return np.array([self.cx[i], self.ry[j] + self.shift[j][i]])

    def jid(self, i: int, j: int) -> int:
        return j * (self.nx + 1) + i

    def arms(self, i: int, j: int) -> list[tuple[int, int]]:
        ok = {(1, 0): i < self.nx, (0, 1): j < self.ny, (-1, 0): i > 0, (0, -1): j > 0}
        return [u for u in _AXES if ok[u]]

    def cross_half(self, i: int, j: int, u) -> float:
        """Half-width of the road crossing arm ``u`` at junction (i, j)."""
        return self.cols[i].half if u[0] else self.rows[j].half

    def arm_section(self, i: int, j: int, u) -> _Section:
        return self.rows[j] if u[0] else self.cols[i]

    def block(self, i: int, j: int) -> tuple:
        return ("block", i, j) if 0 <= i < self.nx and 0 <= j < self.ny else ("outer",)

    def _segments(self) -> list[_Segment]:
        segs: list[_Segment] = []
        Z = self.Z
        for j in range(self.ny + 1):
            sec = self.rows[j]
            for i in range(self.nx):
                x0 = self.cx[i] + self.cols[i].half + Z
                x1 = self.cx[i + 1] - self.cols[i + 1].half - Z
                y0, y1 = self.ry[j] + self.shift[j][i], self.ry[j] + self.shift[j][i + 1]
                if self.curved[j] and y0 != y1:
                    xa, xb = x0 + FLAT, x1 - FLAT
                    xs = np.concatenate([[x0], np.linspace(xa, xb, math.ceil((xb - xa) / (0.9 * SAMPLE)) + 1), [x1]])
                    t = np.clip((xs - xa) / (xb - xa), 0.0, 1.0)
                    P = np.column_stack([xs, y0 + (y1 - y0) * (1 - np.cos(math.pi * t)) / 2])
                else:
                    P = np.array([[x0, y0], [x1, y1]])
                segs.append(_Segment(f"row{j}_{i}", P, sec, (i, j), (i + 1, j), (1, 0), (-1, 0),
                                     self.block(i, j), self.block(i, j - 1)))  # fmt: skip
        for i in range(self.nx + 1):
            sec = self.cols[i]
            for j in range(self.ny):
                a, b = self.centre(i, j), self.centre(i, j + 1)
                P = np.array([[a[0], a[1] + self.rows[j].half + Z], [b[0], b[1] - self.rows[j + 1].half - Z]])
                segs.append(_Segment(f"col{i}_{j}", P, sec, (i, j), (i, j + 1), (0, 1), (0, -1),
                                     self.block(i - 1, j), self.block(i, j)))  # fmt: skip
        return segs


def _section(road_width: float | None, lanes: int, parking: float, median: float, speed: float,
             shoulder: float = 0.0) -> _Section:  # fmt: skip
    """Cross-section from a lane count, or from an overriding carriageway width."""
    if road_width is None:
        return _Section(lanes, median / 2 + lanes * LANE_WIDTH + shoulder + parking, median, parking, speed)
    half = road_width / 2
    n = int((half - median / 2 - parking) // LANE_WIDTH)
    if n < 1:
        raise ValueError(
            f"road_width {road_width:g} m leaves no {LANE_WIDTH:g} m lane each way "
            f"(median {median:g} m, parking strips {parking:g} m)"
        )
    return _Section(n, half, median, parking, speed)


# --------------------------------------------------------------------------------------------
# the town
# --------------------------------------------------------------------------------------------


def build_procedural_town(spec: TownSpec, scenes: ScenesConfig, index: int, assets: Sequence[AssetRecord]) -> Town:
    """Build procedural town ``index`` in ``spec.style`` from the ADMesh ``assets``.

    Deterministic from ``(scenes.seed, index, spec.style)`` and the set of assets (whatever their
    order). ``spec.blocks / block_size / road_width / sidewalk_width`` override the style's
    defaults. Needs at least one Building asset; other categories are placed when present (Car
    only as parked cars in the suburb). Raises ``ValueError`` for other styles or layouts without
    room for sidewalks and lanes.
    """
    if spec.style not in _STYLES:
        raise ValueError(f"build_procedural_town builds the styles {list(STYLES)}, not {spec.style!r}")
    pools = AssetPools(assets)
    if not pools.get("Building"):
        raise ValueError(f"a procedural town needs at least one asset of category Building; got {sorted(pools.by_cat)}")
    st = _STYLES[spec.style]
    code = STYLES.index(spec.style)
    rng = np.random.default_rng(np.random.SeedSequence([scenes.seed, index, code, 0x70776E]))
    lay = _Layout(spec.style, st, spec, rng)
    name = town_name(index)
    return _Builder(name, index, spec.style, st, lay, pools, scenes.curb_height, rng).build()


class _Builder:
    def __init__(self, name, index, style, st: _Style, lay: _Layout, pools: AssetPools, curb: float, rng) -> None:
        self.name, self.index, self.style, self.st, self.lay = name, index, style, st, lay
        self.pools, self.curb, self.rng = pools, curb, rng
        self.pieces: dict[str, list] = {k: [] for k in ("road", "sidewalk", "terrain", "roadline", "guardrail",
                                                         "fence", "wall")}  # fmt: skip
        self.feet = _Footprints()
        self.lots: dict[tuple, np.ndarray] = {}  # block -> lot polygon (closed, CCW)
        self.loops: dict[tuple, np.ndarray] = {}  # region -> closed walk loop (K, 2)
        self.signal: dict[tuple[int, int], bool] = {}
        self.placements: list = []  # deferred asset placements (kind, asset, xy, yaw, anchor)

    # ---------------------------------------------------------------- stuff
    def build(self) -> Town:
        lay = self.lay
        for i in range(lay.nx + 1):
            for j in range(lay.ny + 1):
                self.signal[(i, j)] = self._signalised(i, j)
        for seg in lay.segments:
            self._segment_stuff(seg)
        for j in range(lay.ny + 1):
            for i in range(lay.nx + 1):
                self._junction_stuff(i, j)
        for bj in range(lay.ny):
            for bi in range(lay.nx):
                self._block(bi, bj)
        self._outer()
        network = self._network()
        self._things()  # before the stuff meshes: lot frontages add fences and walls
        stuff = {}
        semantic = {"road": ("Road", "asphalt"), "sidewalk": ("Sidewalk", "paving"), "terrain": ("Terrain", "grass"),
                    "roadline": ("RoadLine", "paint"), "guardrail": ("GuardRail", "metal"),
                    "fence": ("Fence", "wood"), "wall": ("Wall", "concrete")}  # fmt: skip
        placer = Placer(self.name)
        for key, parts in self.pieces.items():
            if not parts:
                continue
            k = f"{self.name}/{key}"
            stuff[k] = stuff_geometry(k, concatenate(parts), *semantic[key])
            placer.add_stuff(stuff[k])
        for kind, asset, xy, yaw, anchor in self.placements:
            placer.add_asset(kind, asset, xy, self.curb, yaw, anchor)
        g = TOWN_MARGIN + lay.ring
        bounds = (lay.X0 - g, lay.Y0 - g, lay.X1 + g, lay.Y1 + g)
        return Town(
            name=self.name, index=self.index, style=self.style, source="", placements=placer.records, stuff=stuff,
            network=network, bounds=tuple(float(b) for b in bounds), max_instance_id=placer.next_instance - 1,
            curb_height=self.curb,
        )  # fmt: skip

    def _signalised(self, i: int, j: int) -> bool:
        lay = self.lay
        if self.style == "arterial":
            return j == 1
        if len(lay.arms(i, j)) < 3:
            return self.style != "suburb"
        return bool(self.rng.uniform() < self.st.signal_share)

    def _segment_stuff(self, seg: _Segment) -> None:
        sec, curb, S = seg.sec, self.curb, self.lay.S
        P, H, m = seg.P, sec.half, sec.median
        top = curb - SURFACE
        if m > 0:
            self.pieces["road"] += [_ribbon(P, -H, -m / 2, -SURFACE, 0.0), _ribbon(P, m / 2, H, -SURFACE, 0.0)]
            self.pieces["terrain"].append(_ribbon(P, -m / 2 + SURFACE, m / 2 - SURFACE, top, curb))
            kerbs = [_ribbon(P, -m / 2, -m / 2 + SURFACE, -SURFACE, curb), _ribbon(P, m / 2 - SURFACE, m / 2, -SURFACE, curb)]
            L = seg.length
            for s0, s1 in ((0.0, SURFACE), (L - SURFACE, L)):  # noses
                kerbs.append(_ribbon(_sub(P, s0, s1), -m / 2 + SURFACE, m / 2 - SURFACE, -SURFACE, top))
            if top > 0:
                self.pieces["sidewalk"] += kerbs
            else:
                self.pieces["terrain"] += kerbs
            rail = _sub(P, 1.0, L - 1.0)
            self.pieces["guardrail"].append(_ribbon(rail, -0.15, 0.15, curb, curb + 0.8))
        else:
            self.pieces["road"].append(_ribbon(P, -H, H, -SURFACE, 0.0))
        for sgn, region in ((1, seg.left), (-1, seg.right)):
            if region[0] == "outer":
                continue  # the outer ring holds that sidewalk
            lo, hi = sorted((sgn * H, sgn * (H + S)))
            self.pieces["sidewalk"].append(_ribbon(P, lo, hi, top, curb))
            if top > 0:
                klo, khi = sorted((sgn * H, sgn * (H + SURFACE)))
                self.pieces["sidewalk"].append(_ribbon(P, klo, khi, -SURFACE, top))
        # markings: centre line, lane lines (dashed), edge / parking lines
        L = seg.length
        lines = []
        if m == 0:
            lines += [(-0.2, -0.08), (0.08, 0.2)]  # double centre line
        edge = m / 2 + sec.lanes * LANE_WIDTH
        for sgn in (1, -1):
            o = sorted((sgn * (edge - 0.15), sgn * edge)) if sec.parking or edge < H else sorted(
                (sgn * (H - 0.3), sgn * (H - 0.15)))
            lines.append(tuple(o))
        for a, b in lines:
            self.pieces["roadline"].append(_ribbon(_sub(P, 0.5, L - 0.5), a, b, 0.0, MARKING_TOP))
        for k in range(1, sec.lanes):
            o = m / 2 + k * LANE_WIDTH
            s = 2.0
            while s + 3.0 <= L - 1.0:
                for sgn in (1, -1):
                    a, b = sorted((sgn * (o - 0.06), sgn * (o + 0.06)))
                    self.pieces["roadline"].append(_ribbon(_sub(P, s, s + 3.0), a, b, 0.0, MARKING_TOP))
                s += 9.0

    def _junction_stuff(self, i: int, j: int) -> None:
        lay, curb, Z = self.lay, self.curb, self.lay.Z
        c = lay.centre(i, j)
        Hc, Hr = lay.cols[i].half, lay.rows[j].half
        arms = lay.arms(i, j)
        road = [(c[0] - Hc, c[0] + Hc, c[1] - Hr, c[1] + Hr)]
        marks = []
        for u in arms:
            Hx, sec = lay.cross_half(i, j, u), lay.arm_section(i, j, u)
            H = sec.half
            road.append(_rect(c[0], c[1], u, Hx, Hx + Z, -H, H))
            # zebra: stripes 0.5 m wide every 1 m across the carriageway, along the road
            n = int((2 * H - 0.6) // 1.0)
            b0 = -n / 2.0 + 0.25
            for k in range(n):
                marks.append(_rect(c[0], c[1], u, Hx + self.lay.zc - ZEBRA / 2, Hx + self.lay.zc + ZEBRA / 2,
                                   b0 + k, b0 + k + 0.5))  # fmt: skip
            # stop line at the zone edge, across the incoming lanes (on the arm's left = +v side)
            marks.append(_rect(c[0], c[1], u, Hx + Z - 0.5, Hx + Z - 0.1, sec.median / 2 + 0.1,
                               sec.median / 2 + sec.lanes * LANE_WIDTH - 0.1))  # fmt: skip
        self.pieces["road"].append(slabs(road, -SURFACE, 0.0))
        self.pieces["roadline"].append(slabs(marks, 0.0, MARKING_TOP))
        # corner squares where two arms bound a block
        top = curb - SURFACE
        side, kerb = [], []
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            if lay.block(i if sx > 0 else i - 1, j if sy > 0 else j - 1)[0] != "block":
                continue
            x0, x1 = sorted((c[0] + sx * Hc, c[0] + sx * (Hc + Z)))
            y0, y1 = sorted((c[1] + sy * Hr, c[1] + sy * (Hr + Z)))
            side.append((x0, x1, y0, y1))
            kx0, kx1 = sorted((c[0] + sx * Hc, c[0] + sx * (Hc + SURFACE)))
            ky0, ky1 = sorted((c[1] + sy * Hr, c[1] + sy * (Hr + SURFACE)))
            kerb.append((x0, x1, ky0, ky1))
            ky0b, ky1b = sorted((c[1] + sy * (Hr + SURFACE), c[1] + sy * (Hr + Z)))
            kerb.append((kx0, kx1, ky0b, ky1b))
        if side:
            self.pieces["sidewalk"].append(slabs(side, top, curb))
            if top > 0:
                self.pieces["sidewalk"].append(slabs(kerb, -SURFACE, top))

    def _seg(self, name: str) -> _Segment:
        return self._by_name[name]

    def _block(self, bi: int, bj: int) -> None:
        """Terrain of block (bi, bj), its lot polygon and walk loop."""
        lay, S, Z, curb = self.lay, self.lay.S, self.lay.Z, self.curb
        if not hasattr(self, "_by_name"):
            self._by_name = {s.name: s for s in lay.segments}
        bot, top_ = self._seg(f"row{bj}_{bi}"), self._seg(f"row{bj + 1}_{bi}")
        Hb, Ht = lay.rows[bj].half, lay.rows[bj + 1].half
        Hl, Hr_ = lay.cols[bi].half, lay.cols[bi + 1].half
        cl, cr = lay.cx[bi], lay.cx[bi + 1]
        yLb = lay.centre(bi, bj)[1] + Hb + Z
        yLt = lay.centre(bi, bj + 1)[1] - Ht - Z
        yRb = lay.centre(bi + 1, bj)[1] + Hb + Z
        yRt = lay.centre(bi + 1, bj + 1)[1] - Ht - Z
        xL, xR = cl + Hl + S, cr - Hr_ - S
        xm0, xm1 = cl + Hl + Z, cr - Hr_ - Z
        b = _offset(bot.P, Hb + S)
        t = _offset(top_.P, -(Ht + S))
        xs = np.unique(np.concatenate([b[:, 0], t[:, 0]]))
        xs = _densify(np.column_stack([xs, np.zeros_like(xs)]), STUFF_TILE)[:, 0]
        xs = xs[np.concatenate([[True], np.diff(xs) > 1e-6])]
        yb, yt = np.interp(xs, b[:, 0], b[:, 1]), np.interp(xs, t[:, 0], t[:, 1])
        low, high = curb - SURFACE, curb
        ter = [_strip(xs, yb, yt, low, high)]
        if xm0 - xL > 1e-6:
            ter.append(slab(xL, xm0, yLb, yLt, low, high))
            ter.append(slab(xm1, xR, yRb, yRt, low, high))
        self.pieces["terrain"] += ter
        poly = [(xL, yLb), (xm0, yLb), *zip(xs, yb), (xm1, yRb), (xR, yRb), (xR, yRt), (xm1, yRt),
                *zip(xs[::-1], yt[::-1]), (xm0, yLt), (xL, yLt)]  # fmt: skip
        poly = np.array(poly, dtype=np.float64)
        keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-6])
        self.lots[("block", bi, bj)] = poly[keep]
        # walk loop: S/2 from the kerbs, counter-clockwise
        wb = _offset(bot.P, Hb + S / 2)
        wt = _offset(top_.P, -(Ht + S / 2))
        loop = np.vstack([
            [[cl + Hl + S / 2, wb[0, 1]]], wb, [[cr - Hr_ - S / 2, wb[-1, 1]]],
            [[cr - Hr_ - S / 2, wt[-1, 1]]], wt[::-1], [[cl + Hl + S / 2, wt[0, 1]]],
        ])  # fmt: skip
        keep = np.concatenate([[True], np.linalg.norm(np.diff(loop, axis=0), axis=1) > 1e-6])
        self.loops[("block", bi, bj)] = loop[keep]

    def _outer(self) -> None:
        lay, curb = self.lay, self.curb
        w = lay.ring
        X0, X1, Y0, Y1 = lay.X0, lay.X1, lay.Y0, lay.Y1
        top = curb - SURFACE
        self.pieces["sidewalk"].append(slabs(_ring(X0 - w, X1 + w, Y0 - w, Y1 + w, w), top, curb))
        if top > 0:
            self.pieces["sidewalk"].append(
                slabs(_ring(X0 - SURFACE, X1 + SURFACE, Y0 - SURFACE, Y1 + SURFACE, SURFACE), -SURFACE, top))
        g = TOWN_MARGIN
        self.pieces["terrain"].append(slabs(_ring(X0 - w - g, X1 + w + g, Y0 - w - g, Y1 + w + g, g), top, curb))
        o = lay.S / 2
        self.loops[("outer",)] = np.array([[X0 - o, Y0 - o], [X1 + o, Y0 - o], [X1 + o, Y1 + o], [X0 - o, Y1 + o]])

    # ---------------------------------------------------------------- network
    def _network(self) -> RoadNetwork:
        lay = self.lay
        lanes: list[dict] = []
        ins: dict[tuple, list[int]] = {}  # (i, j, arm) -> in-lane ids by index
        outs: dict[tuple, list[int]] = {}
        for seg in lay.segments:
            sec = seg.sec
            for forward in (True, False):
                ids = []
                for k in range(sec.lanes):
                    off = sec.lane_offset(k)
                    pts = _offset(seg.P, -off) if forward else _offset(seg.P, off)[::-1]
                    pts = _densify(pts, SAMPLE)
                    ids.append(len(lanes))
                    lanes.append({"points": pts, "road": seg.name, "speed": sec.speed, "junction": -1, "succ": []})
                for k, lid in enumerate(ids):
                    lanes[lid]["left"] = ids[k - 1] if k > 0 else -1
                    lanes[lid]["right"] = ids[k + 1] if k + 1 < len(ids) else -1
                ja, ua, jb, ub = (seg.ja, seg.ua, seg.jb, seg.ub) if forward else (seg.jb, seg.ub, seg.ja, seg.ua)
                outs[(*ja, ua)] = ids
                ins[(*jb, ub)] = ids
        for j in range(lay.ny + 1):
            for i in range(lay.nx + 1):
                jid = lay.jid(i, j)
                arms = lay.arms(i, j)
                for u in arms:
                    d = (-u[0], -u[1])
                    left, right = (-d[1], d[0]), (d[1], -d[0])
                    in_ids = ins[(i, j, u)]
                    n = len(in_ids)
                    moves: dict[int, list[tuple]] = {k: [] for k in range(n)}
                    for w in arms:
                        if w == u:
                            continue  # no U-turns: the grid has no dead ends
                        out_ids = outs[(i, j, w)]
                        if w == d:
                            for k in range(n):  # on into the same lane or a neighbour (a lane change)
                                near = {min(k + dk, len(out_ids) - 1) for dk in (-1, 0, 1) if k + dk >= 0}
                                moves[k].append((w, [out_ids[x] for x in sorted(near)]))
                        elif w == right:  # kerb lane to kerb lane: keeps clear of the kerb corner
                            moves[n - 1].append((w, out_ids[-1:]))
                        elif w == left:  # innermost lane into any lane (the wide arc)
                            moves[0].append((w, out_ids))
                    for k in range(n):
                        if not moves[k]:  # a middle lane with no way straight on: turn
                            if right in arms:  # into the lane of the same rank: a wide arc
                                o = outs[(i, j, right)]
                                moves[k].append((right, [o[min(k, len(o) - 1)]]))
                            elif left in arms:
                                moves[k].append((left, outs[(i, j, left)]))
                        src = lanes[in_ids[k]]
                        p0 = src["points"][-1]
                        for w, targets in moves[k]:
                            for t in targets:
                                dst = lanes[t]
                                p1 = dst["points"][0]
                                pts = _bezier(p0, np.array(d, float), p1, np.array(w, float))
                                speed = min(src["speed"], dst["speed"]) if w == d else min(TURN, src["speed"])
                                src["succ"].append(len(lanes))
                                lanes.append({"points": pts, "road": f"junction{jid}", "speed": speed, "junction": jid,
                                              "succ": [t], "left": -1, "right": -1})  # fmt: skip
        out = tuple(
            Lane(lane_id=k, points=np.column_stack([ln["points"], np.zeros(len(ln["points"]))]), width=LANE_WIDTH,
                 successors=tuple(ln["succ"]), left=ln["left"], right=ln["right"], junction=ln["junction"],
                 speed_limit=float(ln["speed"]), road=ln["road"])
            for k, ln in enumerate(lanes)
        )  # fmt: skip
        road_length = sum(s.length for s in lay.segments)
        for j in range(lay.ny + 1):
            for i in range(lay.nx + 1):
                road_length += sum(lay.cross_half(i, j, u) + lay.Z for u in lay.arms(i, j))
        return RoadNetwork(lanes=out, walkways=self._walkways(), road_length=float(road_length))

    def _walkways(self) -> tuple[Walkway, ...]:
        lay, S, curb = self.lay, self.lay.S, self.curb
        nodes: dict[tuple, int] = {}
        on_loop: dict[tuple, list[tuple[np.ndarray, int]]] = {r: [] for r in self.loops}
        walks: list[Walkway] = []
        crossings = []
        for j in range(lay.ny + 1):
            for i in range(lay.nx + 1):
                c = lay.centre(i, j)
                for u in lay.arms(i, j):
                    Hx, H = lay.cross_half(i, j, u), lay.arm_section(i, j, u).half
                    v = np.array([-u[1], u[0]], dtype=float)
                    base = c + np.array(u, float) * (Hx + lay.zc)
                    ends = []
                    for sgn in (1, -1):
                        key = (i, j, u, sgn)
                        nodes[key] = len(nodes)
                        p = base + v * sgn * (H + S / 2)
                        # the quadrant between u and its left (sgn 1) or right (sgn -1) neighbour arm
                        q = (u[0] - sgn * u[1], u[1] + sgn * u[0])
                        region = lay.block(i if q[0] > 0 else i - 1, j if q[1] > 0 else j - 1)
                        on_loop[region].append((p, nodes[key]))
                        ends.append((p, nodes[key]))
                    crossings.append((ends, lay.jid(i, j)))
        width = max(1.0, S - min(1.2, 0.45 * S))
        for region, loop in self.loops.items():
            closed = np.vstack([loop, loop[:1]])
            cum = polyline_lengths(closed)
            total = float(cum[-1])
            marks = sorted((_project(closed, cum, p), n) for p, n in on_loop[region])
            for k, (s0, n0) in enumerate(marks):
                s1, n1 = marks[(k + 1) % len(marks)]
                if k + 1 == len(marks):
                    s1 += total
                twice = np.vstack([closed, closed[1:]])
                pts = _sub(twice, s0, s1)
                walks.append(Walkway(walkway_id=len(walks), points=np.column_stack([pts, np.full(len(pts), curb)]),
                                     start_node=n0, end_node=n1, width=width))  # fmt: skip
        for ends, jid in crossings:
            (p0, n0), (p1, n1) = ends[1], ends[0]
            pts = np.array([[p0[0], p0[1], CROSSWALK_Z], [p1[0], p1[1], CROSSWALK_Z]])
            walks.append(Walkway(walkway_id=len(walks), points=pts, start_node=n0, end_node=n1, width=ZEBRA,
                                 crosswalk=True, junction=jid))  # fmt: skip
        return tuple(walks)

    # ---------------------------------------------------------------- things
    def _put(self, kind: str, asset: AssetRecord, xy, yaw: float, anchor=(0.0, 0.0), half=None, at=None,
             gap: float = 0.3) -> bool:  # fmt: skip
        """Place ``asset`` (deferred) when its footprint is free; ``half``/``at`` override the
        footprint (default: the asset box)."""
        xy = np.asarray(xy, dtype=np.float64)
        centre = xy - rot2(yaw, anchor)
        if half is None:
            half, at = (asset.extent[0] / 2, asset.extent[1] / 2), centre
        at = centre if at is None else at
        if not self.feet.free(at, half, yaw, gap):
            return False
        self.feet.add(at, half, yaw, gap)
        self.placements.append((kind, asset, xy, yaw, anchor))
        return True

    def _pole(self, kind: str, asset: AssetRecord, xy, yaw: float) -> bool:
        """Place a pole-like asset by its pole axis (asset-frame conventions of the procedural source)."""
        ext = asset.extent
        pole_y = ext[1] / 2 - POLE_RADIUS if asset.subclass == "overhead_signal" else 0.0
        anchor = (-ext[0] / 2 + POLE_RADIUS, pole_y)
        return self._put(kind, asset, xy, yaw, anchor, half=(0.25, 0.25), at=np.asarray(xy, float))

    def _things(self) -> None:
        self._buildings()
        self._junction_furniture()
        self._sidewalk_furniture()
        if self.style == "suburb":
            self._parked_cars()
        self._lot_trees()
        self._margin_trees()

    def _sides(self):
        """(segment, sgn, region) of every road side bordering a block or the outer ring."""
        for seg in self.lay.segments:
            for sgn, region in ((1, seg.left), (-1, seg.right)):
                yield seg, sgn, region

    def _buildings(self) -> None:
        st, rng, lay, S = self.st, self.rng, self.lay, self.lay.S
        pool = self.pools.get("Building", list(st.buildings)) or self.pools.get("Building")
        ext = np.array([a.extent[:2] for a in pool])
        main = lay.rows[1] if self.style == "arterial" else None
        for seg, sgn, region in self._sides():
            if region[0] != "block":
                continue
            poly, H = self.lots[region], seg.sec.half
            L = seg.length
            a = float(rng.uniform(0.0, 2.0))
            while a < L - 8.0:
                w = min(float(rng.uniform(*st.lot)), L - a)
                s = a + w / 2
                p, tng = _at(seg.P, seg.cum, s)
                nrm = np.array([-tng[1], tng[0]]) * sgn  # into the block
                front = p + nrm * (H + S)
                setback = float(rng.uniform(*st.setback)) + (0.8 if st.frontage else 0.0)
                room = _ray(poly, front + nrm * 0.05, nrm) / 2 - setback - 0.5
                depth_max = min(room, st.max_depth)
                fits = np.flatnonzero((ext[:, 1] <= w - 1.5) & (ext[:, 0] <= depth_max))
                placed = None
                if fits.size:
                    order = fits[np.argsort(-(ext[fits, 0] * ext[fits, 1]), kind="stable")]
                    first = int(rng.integers(min(3, order.size)))  # one of the three best fits
                    for k in [*order[first:], *order[:first]][:6]:
                        asset = pool[int(k)]
                        d0, d1 = asset.extent[0], asset.extent[1]
                        c = front + nrm * (setback + d0 / 2)
                        yaw = yaw_of(-nrm)
                        pts, _ = _Footprints.corners(c, (d0 / 2 + 0.3, d1 / 2 + 0.3), yaw)
                        if not _inside(poly, pts).all() or _inside(pts, poly).any():
                            continue
                        if self._put("building", asset, c, yaw, gap=1.0):
                            placed = (asset, c, d1)
                            break
                if placed is not None:
                    self._frontage(seg, sgn, a, w, s, seg.sec is main)
                a += w

    def _frontage(self, seg: _Segment, sgn: int, a: float, w: float, s_gate: float, on_main: bool) -> None:
        """Front fence / hedge / wall of a lot (``a .. a + w`` along ``seg``) with a 3 m gate."""
        st, rng = self.st, self.rng
        if not st.frontage:
            return
        H, S, curb = seg.sec.half, self.lay.S, self.curb
        off = H + S + 0.4
        hedges = self.pools.get("Vegetation", ["hedge"])
        if st.frontage == "fence" and hedges and rng.uniform() < 0.4:
            s = a + 0.8
            while s < a + w - 0.8:
                hedge = hedges[int(rng.integers(len(hedges)))]
                ln = hedge.extent[0]
                if s + ln > a + w - 0.8:
                    break
                if abs(s + ln / 2 - s_gate) > ln / 2 + 1.5:
                    p, tng = _at(seg.P, seg.cum, s + ln / 2)
                    nrm = np.array([-tng[1], tng[0]]) * sgn
                    self._put("hedge", hedge, p + nrm * (off + hedge.extent[1] / 2), yaw_of(tng), gap=0.1)
                s += ln + 0.2
            return
        kind, half_t, height = ("wall", 0.12, 1.8) if (st.frontage == "wall" and on_main) else ("fence", 0.03, 1.1)
        for s0, s1 in ((a + 0.5, s_gate - 1.5), (s_gate + 1.5, a + w - 0.5)):
            if s1 - s0 < 1.0:
                continue
            P = _sub(seg.P, s0, s1)
            lo, hi = sorted((sgn * (off - half_t), sgn * (off + half_t)))
            self.pieces[kind].append(_ribbon(P, lo, hi, curb, curb + height))
            # register the line so trees and hedges keep off it
            for q0, q1 in zip(_offset(P, sgn * off)[:-1], _offset(P, sgn * off)[1:]):
                self.feet.add((q0 + q1) / 2, (float(np.linalg.norm(q1 - q0)) / 2, half_t), yaw_of(q1 - q0), 0.1)

    def _junction_furniture(self) -> None:
        lay, rng = self.lay, self.rng
        pd = min(0.5, 0.4 * lay.S)
        for j in range(lay.ny + 1):
            for i in range(lay.nx + 1):
                c = lay.centre(i, j)
                signal = self.signal[(i, j)]
                for u in lay.arms(i, j):
                    Hx, sec = lay.cross_half(i, j, u), lay.arm_section(i, j, u)
                    uu = np.array(u, float)
                    v = np.array([-u[1], u[0]], float)
                    # beside the stop line, on the right of the incoming traffic (+v of the arm)
                    pole = c + uu * (Hx + lay.Z + 0.6) + v * (sec.half + pd)
                    if signal:
                        wide = sec.half - sec.parking >= 6.0
                        asset = self.pools.pick(rng, "TrafficLight", ["overhead_signal"] if wide else ["vehicle_signal"])
                        if asset is not None and asset.subclass == "pedestrian_signal":
                            asset = None
                        if asset is not None:
                            self._pole("traffic_light", asset, pole, yaw_of(uu))
                    else:
                        sign = self.pools.get("TrafficSign", ["stop"]) or self.pools.get("TrafficSign", ["yield"])
                        if sign:
                            self._pole("traffic_sign", sign[int(rng.integers(len(sign)))], pole, yaw_of(uu))

    def _sidewalk_furniture(self) -> None:
        st, rng, lay = self.st, self.rng, self.lay
        S = lay.S
        pd = min(0.5, 0.4 * S)
        fz = min(1.2, 0.45 * S)
        street_trees = self.pools.get("Vegetation", ["tree"]) if st.tree_spacing else []
        light = self.pools.pick(rng, "Pole", ["street_light"])
        if light is not None and light.subclass != "street_light":
            light = None
        for seg, sgn, region in self._sides():
            H, L = seg.sec.half, seg.length

            def at(s: float, depth: float, seg=seg, sgn=sgn, H=H):
                p, tng = _at(seg.P, seg.cum, s)
                nrm = np.array([-tng[1], tng[0]]) * sgn  # away from the road
                return p + nrm * (H + depth), tng, nrm

            if light is not None:
                s = float(rng.uniform(2.0, 8.0))
                while s < L - 2.0:
                    xy, _, nrm = at(s, pd)
                    self._pole("street_light", light, xy, yaw_of(-nrm))
                    s += float(rng.uniform(*st.light_spacing))
            if street_trees and S >= 2.0:
                s = float(rng.uniform(4.0, 10.0))
                while s < L - 3.0:
                    tree = street_trees[int(rng.integers(len(street_trees)))]
                    xy, _, _ = at(s, max(fz / 2, pd))
                    self._put("tree", tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(0.45, 0.45), at=xy,
                              gap=1.0)  # fmt: skip
                    s += float(rng.uniform(*st.tree_spacing))
            sign = self.pools.pick(rng, "TrafficSign", ["speed_limit", "parking", "no_entry", "one_way", "direction",
                                                        "warning", "pedestrian_crossing"])  # fmt: skip
            if sign is not None and rng.uniform() < 0.6 and L > 8.0:
                xy, tng, _ = at(float(rng.uniform(3.0, L - 3.0)), pd)
                # the kerb-side lane on this side travels -sgn * tangent: face it
                self._pole("traffic_sign", sign, xy, yaw_of(tng * sgn))
            if fz < 0.6 or L < 8.0:
                continue
            for category, sub, kind in (("Static", "bench", "bench"), ("Static", "bin", "bin"),
                                        ("Static", "hydrant", "hydrant"), ("Bicycle", None, "bicycle")):  # fmt: skip
                asset = self.pools.pick(rng, category, [sub] if sub else None)
                if asset is None or rng.uniform() >= st.furniture:
                    continue
                if sub and asset.subclass != sub:
                    continue
                depth = fz / 2 if kind != "bicycle" else min(fz, S) / 2
                xy, tng, nrm = at(float(rng.uniform(3.0, L - 3.0)), depth)
                e = asset.extent
                if kind == "bicycle":
                    yaw = yaw_of(tng)
                    if e[1] / 2 > depth - 0.05:
                        continue
                else:
                    yaw = yaw_of(nrm)  # seat / opening away from the road
                    if e[0] / 2 > depth - 0.05:
                        continue
                self._put(kind, asset, xy, yaw)

    def _parked_cars(self) -> None:
        rng = self.rng
        for seg, sgn, region in self._sides():
            sec = seg.sec
            if sec.parking <= 0:
                continue
            cars = [a for a in self.pools.get("Car") if a.extent[1] <= sec.parking - 0.3]
            if not cars:
                return
            L = seg.length
            s = float(rng.uniform(1.0, 6.0))
            while s < L - 3.0:
                car = cars[int(rng.integers(len(cars)))]
                ln = car.extent[0]
                if s + ln > L - 1.0:
                    break
                if rng.uniform() < 0.6:
                    p, tng = _at(seg.P, seg.cum, s + ln / 2)
                    nrm = np.array([-tng[1], tng[0]]) * sgn
                    xy = p + nrm * (sec.half - sec.parking / 2)
                    self._put("parked_car", car, xy, yaw_of(-sgn * tng), gap=0.5)
                s += ln + float(rng.uniform(1.0, 4.0))

    def _lot_trees(self) -> None:
        rng, st = self.rng, self.st
        trees = self.pools.get("Vegetation", ["tree", "conifer", "bush", "palm"])
        if not trees:
            return
        for poly in self.lots.values():
            lo, hi = poly.min(axis=0), poly.max(axis=0)
            area = float((hi - lo).prod())
            tries = int(area / 600.0 * rng.integers(st.lot_trees[0], st.lot_trees[1] + 1)) + 1
            for _ in range(tries):
                tree = trees[int(rng.integers(len(trees)))]
                r = max(tree.extent[0], tree.extent[1]) / 2
                xy = lo + rng.uniform(size=2) * (hi - lo)
                pts, _ = _Footprints.corners(xy, (r + 0.3, r + 0.3), 0.0)
                if not _inside(poly, pts).all() or _inside(pts, poly).any():
                    continue
                self._put(tree.subclass, tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(r, r), at=xy)

    def _margin_trees(self) -> None:
        rng, lay = self.rng, self.lay
        trees = self.pools.get("Vegetation", ["tree", "conifer"])
        if not trees:
            return
        w = lay.ring
        x0, x1, y0, y1 = lay.X0 - w, lay.X1 + w, lay.Y0 - w, lay.Y1 + w
        perimeter = 2 * ((x1 - x0) + (y1 - y0))
        for _ in range(int(perimeter / 10.0)):
            tree = trees[int(rng.integers(len(trees)))]
            r = max(tree.extent[0], tree.extent[1]) / 2
            depth = float(rng.uniform(r + 0.5, TOWN_MARGIN - r - 0.5))
            side = int(rng.integers(4))
            t = float(rng.uniform(0.0, 1.0))
            xy = [(x0 + t * (x1 - x0), y0 - depth), (x1 + depth, y0 + t * (y1 - y0)),
                  (x0 + t * (x1 - x0), y1 + depth), (x0 - depth, y0 + t * (y1 - y0))][side]  # fmt: skip
            self._put(tree.subclass, tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(r, r), at=np.array(xy))


def _project(closed: np.ndarray, cum: np.ndarray, p) -> float:
    """Arc length along the closed polyline of the point nearest to ``p``."""
    a, b = closed[:-1], closed[1:]
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-12), 0.0, 1.0)
    d = np.linalg.norm(a + e * t[:, None] - p, axis=1)
    k = int(np.argmin(d))
    return float(cum[k] + t[k] * np.linalg.norm(e[k]))
