"""OpenDRIVE geometry: reference lines, elevation, lane boundaries, road-surface and road-mark
meshes of the roads of a parsed network (:mod:`carlaocc.schemas.opendrive` records, as
:func:`carlaocc.catalog.opendrive.read_opendrive` returns them). Pure compute (numpy); never opens
a file. World frame = the file's inertial frame (metres, radians, right-handed, Z up).

Geometry conventions (ASAM OpenDRIVE 1.4-1.8): s along the reference line, t to its left;
left lanes (positive ids) extend to +t, right lanes to -t, both starting at the lane offset.
Superelevation is the roll of the cross section about the reference line (positive: the road
falls to the right), so a point at lateral offset t lies at ``t cos(phi)`` horizontally and
``t sin(phi)`` above the reference-line elevation.

Spirals and poly3/paramPoly3 arc-length tables are integrated with 8-point Gauss-Legendre on
sub-intervals of at most 1 m (error far below 1 mm for any curvature found on roads). poly3 and
paramPoly3 are re-parameterised by arc length, so ``s`` is distance along the curve for every
kind (the p range only fixes the curve's end parameter: ``1`` for normalized, ``length`` for
arcLength).

Not supported (ignored): lane ``<border>`` records (lanes defined by borders only get zero
width), lane ``<height>``, road ``<shape>`` (OpenDRIVE 1.6 lateral shape), crossfall, and
``singleSide`` sections are treated as ordinary ones.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from carlaocc.schemas.opendrive import Geometry, LaneRecord, LaneSection, Poly3Record, Road, RoadMark

__all__ = [
    "SURFACE_KINDS",
    "surface_kind",
    "evaluate_geometry",
    "reference_pose",
    "reference_line",
    "elevation",
    "superelevation",
    "lane_offset",
    "LaneStrip",
    "lane_boundaries",
    "st_to_world",
    "road_surface_meshes",
    "section_strips",
    "strip_mesh",
    "road_marks",
    "mesh_area",
]

# lane type (lower-cased) -> surface kind; types not listed map to "other", "none" is skipped.
# parking, bus/taxi/HOV lanes and ramps are drivable asphalt (CARLA labels them Road).
SURFACE_KINDS: dict[str, str] = {
    **{t: "driving" for t in (
        "driving", "entry", "exit", "onramp", "offramp", "connectingramp", "bidirectional", "parking",
        "bus", "taxi", "hov", "sliplane", "mwyentry", "mwyexit", "special1", "special2", "special3",
        "roadworks",
    )},
    "sidewalk": "sidewalk", "walking": "sidewalk",
    "shoulder": "shoulder",
    "border": "border",
    "curb": "curb",
    "median": "median", "restricted": "median",
    "biking": "biking",
    "rail": "rail", "tram": "rail",
}  # fmt: skip

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)
_MAX_SUB = 1.0  # m (or parameter units): largest Gauss-Legendre sub-interval


def surface_kind(lane_type: str) -> str | None:
    """Surface kind of a lane type, ``None`` for lanes without a surface (type ``none``)."""
    t = (lane_type or "none").strip().lower()
    if t == "none":
        return None
    return SURFACE_KINDS.get(t, "other")


# ---------------------------------------------------------------------------------------------
# planView geometry


def _cumulative_integral(f, x: np.ndarray) -> np.ndarray:
    """``F(x_i) = integral_0^{x_i} f`` for sorted ``x >= 0`` (vectorised ``f``; may return a
    tuple of arrays), by Gauss-Legendre on sub-intervals of at most :data:`_MAX_SUB`."""
    x = np.asarray(x, dtype=float)
    knots = np.unique(np.concatenate([[0.0], x]))
    # refine: split each interval into ceil(len / _MAX_SUB) pieces
    lens = np.diff(knots)
    pieces = np.maximum(1, np.ceil(lens / _MAX_SUB).astype(int))
    starts = np.repeat(knots[:-1], pieces) + (np.concatenate([np.arange(p) for p in pieces]) if len(pieces) else np.zeros(0)) * np.repeat(lens / pieces, pieces)
    h = np.repeat(lens / pieces, pieces)
    mid = starts + h / 2
    nodes = mid[:, None] + (h / 2)[:, None] * _GL_X[None, :]
    vals = f(nodes)
    single = not isinstance(vals, tuple)
    vals = (vals,) if single else vals
    outs = []
    for v in vals:
        seg = (v * _GL_W[None, :]).sum(axis=1) * h / 2
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        ends = np.concatenate([[0], np.cumsum(pieces)])  # cum index at each knot
        at_knots = cum[ends]
        outs.append(at_knots[np.searchsorted(knots, x)])
    return outs[0] if single else tuple(outs)


def _arclength_inverse(speed, p_end: float, ds: np.ndarray, length: float, fit: bool) -> np.ndarray:
    """Parameter p(ds) on ``[0, p_end]`` whose arc length from 0 equals ``ds``. With ``fit``
    (paramPoly3, whose end parameter is known) the arc length is scaled so the whole curve maps
    onto ``[0, length]`` even if the file's length is slightly off; without it (poly3, where
    ``p_end`` is only an upper bound) ``ds`` is the true arc length."""
    n = max(64, int(math.ceil(abs(p_end) / 0.05)) + 1)
    n = min(n, 20001)
    p = np.linspace(0.0, p_end, n)
    arc = _cumulative_integral(speed, p)
    total = arc[-1]
    if total <= 0 or length <= 0:
        return np.zeros_like(ds)
    target = np.clip(ds, 0.0, length) * (total / length if fit else 1.0)
    target = np.minimum(target, total)
    # linear interpolation refined by two Newton steps on the exact arc-length
    q = np.interp(target, arc, p)
    for _ in range(2):
        idx = np.clip(np.searchsorted(p, q) - 1, 0, n - 2)
        a0 = arc[idx] + _cumulative_integral_between(speed, p[idx], q)
        q = q - (a0 - target) / np.maximum(speed(q), 1e-12)
    return q


def _cumulative_integral_between(f, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``integral_a^b f`` elementwise (short intervals) with 8-point Gauss-Legendre."""
    mid, half = (a + b) / 2, (b - a) / 2
    nodes = mid[:, None] + half[:, None] * _GL_X[None, :]
    return (f(nodes) * _GL_W[None, :]).sum(axis=1) * half


def evaluate_geometry(geom: Geometry, ds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World ``(x, y, heading)`` at distances ``ds`` (array, from the geometry start) along one
    planView geometry."""
    ds = np.atleast_1d(np.asarray(ds, dtype=float))
    x0, y0, h0 = geom.x, geom.y, geom.hdg
    kind = geom.kind
    if kind == "arc" and abs(geom.curvature) < 1e-15:
        kind = "line"
    if kind == "spiral" and abs(geom.curv_end - geom.curv_start) < 1e-15:
        if abs(geom.curv_start) < 1e-15:
            kind = "line"
        else:
            kind, k = "arc", geom.curv_start
    else:
        k = geom.curvature
    if kind == "line":
        return x0 + ds * math.cos(h0), y0 + ds * math.sin(h0), np.full_like(ds, h0)
    if kind == "arc":
        h = h0 + k * ds
        return x0 + (np.sin(h) - math.sin(h0)) / k, y0 - (np.cos(h) - math.cos(h0)) / k, h
    if kind == "spiral":
        k0 = geom.curv_start
        rate = (geom.curv_end - geom.curv_start) / geom.length if geom.length > 0 else 0.0

        def theta(u):
            return h0 + k0 * u + 0.5 * rate * u * u

        order = np.argsort(ds)
        cx, cy = _cumulative_integral(lambda u: (np.cos(theta(u)), np.sin(theta(u))), ds[order])
        x, y = np.empty_like(ds), np.empty_like(ds)
        x[order], y[order] = x0 + cx, y0 + cy
        return x, y, theta(ds)
    if kind == "poly3":
        a, b, c, d = geom.a, geom.b, geom.c, geom.d

        def dv(u):
            return b + 2 * c * u + 3 * d * u * u

        u = _arclength_inverse(lambda u: np.sqrt(1 + dv(u) ** 2), geom.length, ds, geom.length, fit=False)
        v = a + u * (b + u * (c + u * d))
        ch, sh = math.cos(h0), math.sin(h0)
        return x0 + u * ch - v * sh, y0 + u * sh + v * ch, h0 + np.arctan(dv(u))
    if kind == "paramPoly3":
        p_end = 1.0 if geom.p_range == "normalized" else geom.length

        def du(p):
            return geom.bu + 2 * geom.cu * p + 3 * geom.du * p * p

        def dvp(p):
            return geom.bv + 2 * geom.cv * p + 3 * geom.dv * p * p

        p = _arclength_inverse(lambda p: np.hypot(du(p), dvp(p)), p_end, ds, geom.length, fit=True)
        u = geom.au + p * (geom.bu + p * (geom.cu + p * geom.du))
        v = geom.av + p * (geom.bv + p * (geom.cv + p * geom.dv))
        ch, sh = math.cos(h0), math.sin(h0)
        return x0 + u * ch - v * sh, y0 + u * sh + v * ch, h0 + np.arctan2(dvp(p), du(p))
    raise ValueError(f"unknown geometry kind {geom.kind!r}")


def _geometry_ranges(road: Road) -> list[tuple[Geometry, float, float]]:
    """(geometry, s_start, s_end) clipped to ``[0, road.length]``; the last geometry extends to
    the road end if the planView is shorter than the declared length."""
    geoms = list(road.geometries)
    out = []
    for i, g in enumerate(geoms):
        s0 = g.s
        s1 = geoms[i + 1].s if i + 1 < len(geoms) else max(g.s + g.length, road.length)
        s1 = min(s1, road.length) if road.length > 0 else s1
        if s1 > s0 or (i == 0 and len(geoms) == 1):
            out.append((g, s0, max(s1, s0)))
    return out or [(geoms[0], geoms[0].s, geoms[0].s)]


def reference_pose(road: Road, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reference-line ``(x, y, heading)`` at arbitrary road-absolute ``s`` (array)."""
    s = np.atleast_1d(np.asarray(s, dtype=float))
    ranges = _geometry_ranges(road)
    starts = np.array([r[1] for r in ranges])
    idx = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(ranges) - 1)
    x, y, h = np.empty_like(s), np.empty_like(s), np.empty_like(s)
    for i in np.unique(idx):
        m = idx == i
        g = ranges[i][0]
        x[m], y[m], h[m] = evaluate_geometry(g, s[m] - g.s)
    return x, y, h


def _samples(s0: float, s1: float, step: float) -> np.ndarray:
    n = max(1, int(math.ceil((s1 - s0) / step - 1e-9)))
    return np.linspace(s0, s1, n + 1)


def reference_line(road: Road, step: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sample the reference line every ``<= step`` metres, each geometry's start and end
    included exactly (a geometry's end is replaced by the next one's start). Returns
    ``(s, x, y, heading)``."""
    if step <= 0:
        raise ValueError("step must be positive")
    parts = []
    ranges = _geometry_ranges(road)
    for i, (g, s0, s1) in enumerate(ranges):
        s = _samples(s0, s1, step)
        if i + 1 < len(ranges):
            s = s[:-1]
        if len(s):
            x, y, h = evaluate_geometry(g, s - g.s)
            parts.append((s, x, y, h))
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(4))  # type: ignore[return-value]


# ---------------------------------------------------------------------------------------------
# profiles


def _piecewise_poly(records: Sequence[Poly3Record], s, offset: float = 0.0) -> np.ndarray:
    """Evaluate piecewise cubic records at ``s``; 0 where no record
    applies; the first record also covers ``s`` before its start."""
    s = np.atleast_1d(np.asarray(s, dtype=float))
    out = np.zeros_like(s)
    if not records:
        return out
    starts = np.array([r.s for r in records]) + offset
    idx = np.clip(np.searchsorted(starts, s + 1e-12, side="right") - 1, 0, len(records) - 1)
    for i in np.unique(idx):
        r = records[i]
        m = idx == i
        u = s[m] - starts[i]
        out[m] = r.a + u * (r.b + u * (r.c + u * r.d))
    return out


def elevation(road: Road, s) -> np.ndarray:
    """Reference-line elevation z(s)."""
    return _piecewise_poly(road.elevations, s)


def superelevation(road: Road, s) -> np.ndarray:
    """Superelevation (roll, radians) of the cross section at s."""
    return _piecewise_poly(road.superelevations, s)


def lane_offset(road: Road, s) -> np.ndarray:
    """Lateral shift of the lane reference (centre lane) from the road reference line."""
    return _piecewise_poly(road.lane_offsets, s)


# ---------------------------------------------------------------------------------------------
# lanes


@dataclass(frozen=True)
class LaneStrip:
    """One lane over one lane section: lateral offsets at the samples ``s``. ``t_inner`` is the
    border nearer the centre lane; left lanes have ``t_outer >= t_inner``, right lanes
    ``t_outer <= t_inner``."""

    section: int
    lane_id: int
    lane_type: str
    s: np.ndarray
    t_inner: np.ndarray
    t_outer: np.ndarray
    lane: LaneRecord | None = None


def _section_ranges(road: Road) -> list[tuple[int, LaneSection, float, float]]:
    secs = list(road.lane_sections)
    out = []
    for i, sec in enumerate(secs):
        s1 = secs[i + 1].s if i + 1 < len(secs) else road.length
        out.append((i, sec, sec.s, max(s1, sec.s)))
    return out


def _section_strips(road: Road, index: int, sec: LaneSection, s: np.ndarray) -> list[LaneStrip]:
    base = lane_offset(road, s)
    strips = []
    for lanes, sign in ((sec.left, 1.0), (sec.right, -1.0)):
        t = base.copy()
        for lane in lanes:  # sorted inner to outer
            w = np.maximum(_piecewise_poly(lane.widths, s, offset=sec.s), 0.0) if lane.widths else np.zeros_like(s)
            outer = t + sign * w
            strips.append(LaneStrip(index, lane.id, lane.type, s, t, outer, lane))
            t = outer
    return strips


def lane_boundaries(road: Road, s_samples) -> list[LaneStrip]:
    """Per lane and lane section, the inner/outer lateral offsets t(s) at those of
    ``s_samples`` that fall in the section (``sec.s <= s < next.s``; the last section also
    takes ``s == road.length``). Offsets = laneOffset + cumulative widths (negative widths
    clamp to 0)."""
    s_samples = np.sort(np.atleast_1d(np.asarray(s_samples, dtype=float)))
    out = []
    ranges = _section_ranges(road)
    for i, sec, s0, s1 in ranges:
        last = i == len(ranges) - 1
        m = (s_samples >= s0) & ((s_samples <= s1) if last else (s_samples < s1))
        if i == 0:
            m |= s_samples < s0
        if m.any():
            out.extend(_section_strips(road, i, sec, s_samples[m]))
    return out


def st_to_world(road: Road, s, t, ref=None) -> np.ndarray:
    """World points ``(..., 3)`` of road coordinates (s, t) on the road surface, with
    elevation and superelevation. ``ref`` may pass precomputed ``(x, y, heading)`` at ``s``."""
    s = np.asarray(s, dtype=float)
    t = np.asarray(t, dtype=float)
    x, y, h = reference_pose(road, s) if ref is None else ref
    phi = superelevation(road, s)
    th, tz = t * np.cos(phi), t * np.sin(phi)
    return np.stack([x - th * np.sin(h), y + th * np.cos(h), elevation(road, s) + tz], axis=-1)


def surface_normal(road: Road, s, t, ref=None, ds: float = 1e-3) -> np.ndarray:
    """Upward unit normals ``(..., 3)`` of the road surface at road coordinates (s, t): the cross
    product of the surface's tangents along s (central difference of :func:`st_to_world` over
    ``ds`` m, one-sided at the road's ends) and along t (the superelevated cross section,
    ``(-cos(phi) sin(h), cos(phi) cos(h), sin(phi))``). A level road gives (0, 0, 1)."""
    s = np.asarray(s, dtype=float)
    t = np.asarray(t, dtype=float)
    # 1. tangent along s at constant t (the lane's own t(s) does not tilt the surface)
    s0 = np.clip(s - ds, 0.0, road.length)
    s1 = np.clip(s + ds, 0.0, road.length)
    d_s = st_to_world(road, s1, t) - st_to_world(road, s0, t)
    # 2. tangent along t: the cross section rolled by the superelevation
    _, _, h = reference_pose(road, s) if ref is None else ref
    phi = superelevation(road, s)
    d_t = np.stack([-np.cos(phi) * np.sin(h), np.cos(phi) * np.cos(h), np.sin(phi)], axis=-1)
    # 3. s x t points up (s forward, t to the left)
    n = np.cross(d_s, d_t)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def _section_samples(road: Road, s0: float, s1: float, step: float) -> np.ndarray:
    s = _samples(s0, s1, step)
    knots = [g.s for g in road.geometries if s0 < g.s < s1]
    if knots:
        s = np.unique(np.concatenate([s, knots]))
    return s


def section_strips(
    road: Road, step: float, min_length: float = 1e-9
) -> Iterator[tuple[int, np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray], list[LaneStrip]]]:
    """Per lane section at least ``min_length`` m long: ``(section index, s samples (<= step
    apart plus every geometry start inside it), reference pose at s, lane strips)``."""
    for i, sec, s0, s1 in _section_ranges(road):
        if s1 - s0 < min_length:
            continue
        s = _section_samples(road, s0, s1, step)
        yield i, s, reference_pose(road, s), _section_strips(road, i, sec, s)


def strip_mesh(p_inner: np.ndarray, p_outer: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Triangle strip between two polylines of n points; degenerate triangles dropped and every
    triangle wound counter-clockwise seen from above (normal z >= 0)."""
    n = len(p_inner)
    verts = np.empty((2 * n, 3))
    verts[0::2], verts[1::2] = p_inner, p_outer
    i = np.arange(n - 1)
    a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    e1, e2 = verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]]
    nrm = np.cross(e1, e2)
    area2 = np.linalg.norm(nrm, axis=1)
    faces = faces[area2 > 1e-10]
    flip = nrm[area2 > 1e-10, 2] < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return verts, faces


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    verts, faces, off = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + off)
        off += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def road_surface_meshes(road: Road, step: float = 0.5) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Road surface as triangle strips between lane borders, in world coordinates, grouped by
    surface kind (see :data:`SURFACE_KINDS`; lanes of type ``none`` are skipped). Values are
    ``(vertices (N, 3) float64, faces (M, 3) int64)`` with upward (+z) face normals. Each lane
    section is sampled every ``<= step`` metres plus every geometry start inside it."""
    if step <= 0:
        raise ValueError("step must be positive")
    parts: dict[str, list] = {}
    for _i, s, ref, strips in section_strips(road, step):
        for strip in strips:
            kind = surface_kind(strip.lane_type)
            if kind is None or not np.any(np.abs(strip.t_outer - strip.t_inner) > 1e-9):
                continue
            mesh = strip_mesh(st_to_world(road, s, strip.t_inner, ref), st_to_world(road, s, strip.t_outer, ref))
            if len(mesh[1]):
                parts.setdefault(kind, []).append(mesh)
    return {k: _merge(v) for k, v in parts.items()}


def mesh_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total triangle area."""
    if len(faces) == 0:
        return 0.0
    v = vertices[faces]
    return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())


# ---------------------------------------------------------------------------------------------
# road marks

_DEFAULT_MARK_WIDTH = 0.15  # m
_BROKEN = (3.0, 9.0)  # m: default dash length / gap of a broken line
_SINGLE = {"solid", "broken"}


def _mark_lines(mark: RoadMark) -> list[tuple[float, float | None, float | None, float]]:
    """(t offset, dash length or None for solid, gap, width) of each line of a road mark."""
    w = mark.width if mark.width else _DEFAULT_MARK_WIDTH
    if mark.lines:
        return [(ln.t_offset, ln.length if ln.space > 0 else None, ln.space, ln.width or w) for ln in mark.lines]
    words = mark.type.strip().lower().split()
    if not words or any(x not in _SINGLE for x in words):
        return []  # none, curb, grass, botts dots, custom: no painted strip
    if len(words) == 1:
        offs = [0.0]
    else:  # double lines: centred on the border, one line width apart
        offs = [w, -w]
    return [(o, *(_BROKEN if word == "broken" else (None, None)), w) for o, word in zip(offs, words)]


def road_marks(road: Road, step: float = 0.5) -> list[dict]:
    """Painted road marks as thin flat strips lying on the road surface (no lift), one entry per
    road-mark record and line: ``{"lane_id", "section", "type", "color", "vertices", "faces"}``.
    Solid lines are continuous; broken lines use the file's ``<type><line>`` pattern or
    3 m dash / 9 m gap. Marks sit on the lane's outer border (centre lane: the lane offset).
    ``none``/``curb``/``grass``/``botts dots`` produce nothing."""
    out = []
    for i, sec, s0, s1 in _section_ranges(road):
        if s1 - s0 < 1e-9:
            continue
        s_all = _section_samples(road, s0, s1, step)
        strips = _section_strips(road, i, sec, s_all)
        borders = [(lane, lane_offset(road, s_all)) for lane in sec.center]
        borders += [(st.lane, st.t_outer) for st in strips]
        for lane, t_border in borders:
            marks = list(lane.road_marks)
            for j, mark in enumerate(marks):
                m0 = s0 + mark.s_offset
                m1 = s0 + marks[j + 1].s_offset if j + 1 < len(marks) else s1
                m1 = min(m1, s1)
                if m1 - m0 < 1e-6:
                    continue
                for t_off, dash, gap, width in _mark_lines(mark):
                    if dash is None:
                        intervals = [(m0, m1)]
                    else:
                        period = dash + gap
                        starts = np.arange(m0, m1, period)
                        intervals = [(a, min(a + dash, m1)) for a in starts if min(a + dash, m1) - a > 1e-3]
                    for a, b in intervals:
                        s = _samples(a, b, step)
                        tb = np.interp(s, s_all, t_border) + t_off
                        ref = reference_pose(road, s)
                        v, f = strip_mesh(st_to_world(road, s, tb - width / 2, ref), st_to_world(road, s, tb + width / 2, ref))
                        if len(f):
                            out.append({"lane_id": lane.id, "section": i, "type": mark.type, "color": mark.color,
                                        "vertices": v, "faces": f})  # fmt: skip
    return out
