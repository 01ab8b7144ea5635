"""Plan geometry of the procedural towns (:mod:`carlaocc.stages.scenes.town.build`): polylines in the xy
plane, closed slabs extruded along them, rectangles around junctions, polygon tests and the oriented
footprints that keep placed things apart.

World frame: metres, Z up; polylines are (K, 2) arrays of xy points, headings in radians from
+X. Slabs are returned as (vertices (N, 3), faces (M, 3)) closed meshes (see
:func:`carlaocc.stages.scenes.placing.grid_slab`).
"""

from __future__ import annotations

import math

import numpy as np

from carlaocc.stages.scenes.network import polyline_lengths
from carlaocc.stages.scenes.placing import STUFF_TILE, grid_slab

__all__ = [
    "SAMPLE", "Footprints", "arm_rect", "bezier", "densify", "inside", "offset_line", "point_at", "project_on_loop",
    "ray_to_edge", "ribbon", "ring_rects", "strip", "sub_line", "tangents",
]  # fmt: skip

SAMPLE = 1.0  # m: largest spacing of curve samples (lanes, curved roads)


# --------------------------------------------------------------------------------------------
# polylines and extruded slabs
# --------------------------------------------------------------------------------------------


def tangents(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vertex tangents of an (K, 2) polyline and the left normals scaled for a constant offset
    distance (mitred)."""
    D = np.diff(P, axis=0)
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    T = np.vstack([D[:1], D[:-1] + D[1:], D[-1:]])
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    seg = np.vstack([D[:1], D])  # a segment meeting each vertex
    scale = 1.0 / np.maximum(np.einsum("ij,ij->i", T, seg), 0.5)
    return T, np.column_stack([-T[:, 1], T[:, 0]]) * scale[:, None]


def offset_line(P: np.ndarray, d: float) -> np.ndarray:
    """The polyline ``P`` moved ``d`` m to its left (negative: right)."""
    return P + tangents(P)[1] * d


def densify(P: np.ndarray, step: float) -> np.ndarray:
    """``P`` with points inserted so that no segment is longer than ``step`` m."""
    seg = np.diff(P, axis=0)
    n = np.maximum(1, np.ceil(np.linalg.norm(seg, axis=1) / step - 1e-9).astype(np.int64))
    if np.all(n == 1):
        return P
    k = np.repeat(np.arange(len(seg)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 1) / np.repeat(n, n)
    return np.vstack([P[:1], P[k] + t[:, None] * seg[k]])


def sub_line(P: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of polyline ``P`` between arc lengths ``s0 < s1``."""
    cum = polyline_lengths(P)
    s0, s1 = max(0.0, s0), min(float(cum[-1]), s1)
    inner = P[(cum > s0 + 1e-9) & (cum < s1 - 1e-9)]
    ends = [np.array([np.interp(s, cum, P[:, k]) for k in range(2)]) for s in (s0, s1)]
    return np.vstack([ends[0], inner, ends[1]])


def point_at(P: np.ndarray, cum: np.ndarray, s: float) -> tuple[np.ndarray, np.ndarray]:
    """Point and unit tangent of polyline ``P`` at arc length ``s``."""
    s = min(max(s, 0.0), float(cum[-1]))
    i = min(max(int(np.searchsorted(cum, s, side="right")) - 1, 0), len(P) - 2)
    d = P[i + 1] - P[i]
    L = float(np.linalg.norm(d))
    return P[i] + d * ((s - cum[i]) / L), d / L


def ribbon(P: np.ndarray, o0: float, o1: float, z0: float, z1: float):
    """Closed slab over the band between left offsets ``o0 < o1`` of polyline ``P``."""
    P = densify(P, STUFF_TILE)
    N = tangents(P)[1]
    offs = np.linspace(o0, o1, max(1, math.ceil((o1 - o0) / STUFF_TILE - 1e-9)) + 1)
    return grid_slab(P[:, None, :] + N[:, None, :] * offs[None, :, None], z0, z1)


def strip(x: np.ndarray, yb: np.ndarray, yt: np.ndarray, z0: float, z1: float):
    """Closed slab over the x-monotone region ``yb(x) <= y <= yt(x)`` sampled at ``x``."""
    m = max(1, math.ceil(float(np.max(yt - yb)) / STUFF_TILE - 1e-9))
    t = np.linspace(0.0, 1.0, m + 1)[None, :]
    G = np.stack([np.repeat(x[:, None], m + 1, axis=1), yb[:, None] + (yt - yb)[:, None] * t], axis=-1)
    return grid_slab(G, z0, z1)


def arm_rect(cx: float, cy: float, u, a0: float, a1: float, b0: float, b1: float):
    """Axis-aligned rect (xmin, xmax, ymin, ymax) of ``a0..a1`` along the axis ``u`` and
    ``b0..b1`` along its left normal, from (cx, cy)."""
    v = (-u[1], u[0])
    xs = [cx + u[0] * a + v[0] * b for a in (a0, a1) for b in (b0, b1)]
    ys = [cy + u[1] * a + v[1] * b for a in (a0, a1) for b in (b0, b1)]
    return (min(xs), max(xs), min(ys), max(ys))


def ring_rects(x0: float, x1: float, y0: float, y1: float, w: float):
    """Four non-overlapping rects forming the ring of width ``w`` just inside the rect."""
    return [(x0, x1, y0, y0 + w), (x0, x1, y1 - w, y1), (x0, x0 + w, y0 + w, y1 - w), (x1 - w, x1, y0 + w, y1 - w)]


def bezier(p0, h0, p1, h1) -> np.ndarray:
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


def inside(poly: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Even-odd point-in-polygon test of (M, 2) ``pts`` against the closed (K, 2) ``poly``."""
    a, b = poly, np.roll(poly, -1, axis=0)
    x, y = pts[:, 0:1], pts[:, 1:2]
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    xint = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / np.where(b[:, 1] == a[:, 1], 1e-12, b[:, 1] - a[:, 1])
    return (np.sum(cond & (x < xint), axis=1) % 2) == 1


def ray_to_edge(poly: np.ndarray, p, d) -> float:
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



def project_on_loop(closed: np.ndarray, cum: np.ndarray, p) -> float:
    """Arc length along the closed polyline of the point nearest to ``p``."""
    a, b = closed[:-1], closed[1:]
    e = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-12), 0.0, 1.0)
    d = np.linalg.norm(a + e * t[:, None] - p, axis=1)
    k = int(np.argmin(d))
    return float(cum[k] + t[k] * np.linalg.norm(e[k]))


# --------------------------------------------------------------------------------------------
# footprints
# --------------------------------------------------------------------------------------------


class Footprints:
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

