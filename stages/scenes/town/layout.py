"""The plan of a procedural town (:mod:`carlaocc.stages.scenes.town.build`): the style rules, road
cross-sections, the grid of junctions and road segments, and the draft the concern modules
(:mod:`~carlaocc.stages.scenes.town.roads`, :mod:`~carlaocc.stages.scenes.town.walkways`,
:mod:`~carlaocc.stages.scenes.town.buildings`, :mod:`~carlaocc.stages.scenes.town.furniture`) build
the town into.

World frame: metres, right-handed, Z up, the road surface at z = 0; junction ``(i, j)`` is where
column ``i`` (x = ``cx[i]``) meets row ``j`` (y = ``ry[j]`` plus the row's lateral shift there);
arm directions are the unit axes E, N, W, S as integer pairs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from carlaocc.schemas.configs import TownSpec
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.scenes.network import polyline_lengths
from carlaocc.stages.scenes.placing import POLE_RADIUS, AssetPools, rot2
from carlaocc.stages.scenes.town.geometry import SAMPLE, Footprints

__all__ = [
    "STYLES", "STYLE_RULES", "LANE_WIDTH", "TOWN_MARGIN", "ZEBRA", "STUFF_KINDS", "CrossSection", "Style", "Segment",
    "Layout", "TownDraft", "cross_section",
]  # fmt: skip

STYLES = ("downtown", "suburb", "arterial")
LANE_WIDTH = 3.5  # m
TOWN_MARGIN = 20.0  # m of terrain beyond the outer sidewalk ring
ZEBRA = 3.0  # m: crosswalk band width along the road
FLAT = 6.0  # m: straight road kept beyond each junction zone on a curved row
MEDIAN = 2.0  # m: arterial median width
URBAN = 30.0 / 3.6  # m/s
ARTERIAL = 50.0 / 3.6
_AXES = ((1, 0), (0, 1), (-1, 0), (0, -1))  # arm directions E, N, W, S
# the stuff meshes of a town, in the order they are placed
STUFF_KINDS = ("road", "sidewalk", "terrain", "roadline", "guardrail", "fence", "wall")


@dataclass(frozen=True)
class CrossSection:
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
class Style:
    """The rules of a town style: grid and cross-section defaults, building and lot sizes,
    spacing of lights and trees, traffic control, furniture and lot frontages."""

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


STYLE_RULES = {
    "downtown": Style(3, 70.0, None, 4.0, 2, 0.0, 0.0,
                      ("office", "tower", "commercial", "residential", "apartment", "public"),
                      (20.0, 34.0), (0.5, 1.5), 30.0, (22.0, 28.0), (9.0, 14.0), (0, 1), 1.0, 0.7, ""),
    "suburb": Style(2, 110.0, None, 2.5, 1, 2.5, 0.0, ("house", "garage", "residential"),
                    (17.0, 24.0), (4.0, 7.0), 16.0, (34.0, 42.0), (8.0, 12.0), (2, 5), 0.3, 0.3, "fence"),
    "arterial": Style(3, 90.0, None, 3.0, 1, 0.0, 0.0,
                      ("commercial", "industrial", "warehouse", "gas_station", "office", "apartment", "public",
                       "religious"), (30.0, 48.0), (3.0, 6.0), 40.0, (26.0, 32.0), (14.0, 20.0), (1, 3),
                      1.0, 0.3, "wall"),
}  # fmt: skip


@dataclass
class Segment:
    """A road between two junction zones: centreline ``P`` (K, 2) from zone edge to zone edge, the
    junctions at either end with the arm directions (outward from each junction), and the regions
    (``("block", i, j)`` or ``("outer",)``) on its left and right."""

    name: str
    P: np.ndarray
    sec: CrossSection
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


class Layout:
    """Grid positions, cross-sections, junctions and road segments of one town."""

    def __init__(self, style: str, rules: Style, spec: TownSpec, rng: np.random.Generator) -> None:
        B = spec.block_size if spec.block_size is not None else rules.block_size
        S = spec.sidewalk_width if spec.sidewalk_width is not None else rules.sidewalk_width
        n = spec.blocks if spec.blocks is not None else rules.blocks
        self.B, self.S = B, S
        self.nx, self.ny = n, (2 if style == "arterial" else n)
        self.zc = max(2.0, S / 2 + 0.6)  # crosswalk centre beyond the cross road's kerb
        self.Z = max(S, self.zc + ZEBRA / 2 + 1.0)  # junction zone depth beyond the cross road's kerb
        if B - 2 * self.Z < 6.0:
            raise ValueError(
                f"block_size {B:g} m is too small for sidewalks of {S:g} m: the junction corners take "
                f"{self.Z:g} m at each end and at least 6 m of block interior must remain"
            )
        main = cross_section(spec.road_width, rules.lanes, rules.parking, rules.median, URBAN)
        if style == "arterial":
            lanes = int(rng.integers(2, 4))
            art = cross_section(spec.road_width, lanes, 0.0, MEDIAN, ARTERIAL, shoulder=0.5)
            local = cross_section(None, 1, 0.0, 0.0, URBAN, shoulder=1.0)  # room for turns off the arterial
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
        self._by_name = {s.name: s for s in self.segments}

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

    def arm_section(self, i: int, j: int, u) -> CrossSection:
        return self.rows[j] if u[0] else self.cols[i]

    def block(self, i: int, j: int) -> tuple:
        return ("block", i, j) if 0 <= i < self.nx and 0 <= j < self.ny else ("outer",)

    def segment(self, name: str) -> Segment:
        """The segment named ``name`` (``row<j>_<i>`` or ``col<i>_<j>``)."""
        return self._by_name[name]

    def sides(self):
        """(segment, sgn, region) of every road side bordering a block or the outer ring."""
        for seg in self.segments:
            for sgn, region in ((1, seg.left), (-1, seg.right)):
                yield seg, sgn, region

    def _segments(self) -> list[Segment]:
        segs: list[Segment] = []
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
                segs.append(Segment(f"row{j}_{i}", P, sec, (i, j), (i + 1, j), (1, 0), (-1, 0),
                                    self.block(i, j), self.block(i, j - 1)))  # fmt: skip
        for i in range(self.nx + 1):
            sec = self.cols[i]
            for j in range(self.ny):
                a, b = self.centre(i, j), self.centre(i, j + 1)
                P = np.array([[a[0], a[1] + self.rows[j].half + Z], [b[0], b[1] - self.rows[j + 1].half - Z]])
                segs.append(Segment(f"col{i}_{j}", P, sec, (i, j), (i, j + 1), (0, 1), (0, -1),
                                    self.block(i - 1, j), self.block(i, j)))  # fmt: skip
        return segs


def cross_section(road_width: float | None, lanes: int, parking: float, median: float, speed: float,
                  shoulder: float = 0.0) -> CrossSection:  # fmt: skip
    """Cross-section from a lane count, or from an overriding carriageway width."""
    if road_width is None:
        return CrossSection(lanes, median / 2 + lanes * LANE_WIDTH + shoulder + parking, median, parking, speed)
    half = road_width / 2
    n = int((half - median / 2 - parking) // LANE_WIDTH)
    if n < 1:
        raise ValueError(
            f"road_width {road_width:g} m leaves no {LANE_WIDTH:g} m lane each way "
            f"(median {median:g} m, parking strips {parking:g} m)"
        )
    return CrossSection(n, half, median, parking, speed)


class TownDraft:
    """A procedural town under construction: its style, layout, asset pools, kerb height and random
    stream, the stuff pieces by kind (closed (vertices, faces) slabs, concatenated into the stuff
    meshes at the end), the lot polygons (closed, counter-clockwise) and walk loops (closed, (K, 2))
    by region, which junctions are signalised, the footprints of what stands on the ground and
    the deferred asset placements ``(kind, asset, xy, yaw, anchor)`` in placement order."""

    def __init__(self, style: str, rules: Style, lay: Layout, pools: AssetPools, curb: float,
                 rng: np.random.Generator) -> None:  # fmt: skip
        self.style, self.rules, self.lay = style, rules, lay
        self.pools, self.curb, self.rng = pools, curb, rng
        self.pieces: dict[str, list] = {k: [] for k in STUFF_KINDS}
        self.feet = Footprints()
        self.lots: dict[tuple, np.ndarray] = {}  # block -> lot polygon (closed, CCW)
        self.loops: dict[tuple, np.ndarray] = {}  # region -> closed walk loop (K, 2)
        self.signal: dict[tuple[int, int], bool] = {}
        self.placements: list = []  # deferred asset placements (kind, asset, xy, yaw, anchor)

    def put(self, kind: str, asset: AssetRecord, xy, yaw: float, anchor=(0.0, 0.0), half=None, at=None,
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

    def pole(self, kind: str, asset: AssetRecord, xy, yaw: float) -> bool:
        """Place a pole-like asset by its pole axis (asset-frame conventions of the procedural source)."""
        ext = asset.extent
        pole_y = ext[1] / 2 - POLE_RADIUS if asset.subclass == "overhead_signal" else 0.0
        anchor = (-ext[0] / 2 + POLE_RADIUS, pole_y)
        return self.put(kind, asset, xy, yaw, anchor, half=(0.25, 0.25), at=np.asarray(xy, float))
