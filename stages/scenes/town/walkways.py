"""Walkways of a procedural town (:mod:`carlaocc.stages.scenes.town.build`): the sidewalks along the roads
with their kerbs, the sidewalk corners of the junction zones, the ground of each block (grass at
kerb height, the lot outline the buildings fill, the walk loop around it), the outer sidewalk ring
with its terrain margin, and the walk graph (a walkway along each loop between crosswalk ends, and a
crosswalk on every junction arm).

World frame: metres, Z up; sidewalk and grass tops are ``[curb - SURFACE, curb]``, kerb faces
thin walls ``[-SURFACE, curb - SURFACE]`` under every kerb edge; walk loops run ``S / 2`` from the
kerbs, counter-clockwise; sidewalk walkways lie at kerb height, crosswalks at
:data:`CROSSWALK_Z` on the zebra.
"""

from __future__ import annotations

import numpy as np

from carlaocc.stages.scenes.network import Walkway, polyline_lengths
from carlaocc.stages.scenes.placing import STUFF_TILE, SURFACE, slab, slabs
from carlaocc.stages.scenes.town.geometry import (
    densify,
    offset_line,
    project_on_loop,
    ribbon,
    ring_rects,
    strip,
    sub_line,
)
from carlaocc.stages.scenes.town.layout import TOWN_MARGIN, ZEBRA, Segment, TownDraft

__all__ = ["CROSSWALK_Z", "block_ground", "junction_corners", "outer_ground", "sidewalks_along", "walk_graph"]

CROSSWALK_Z = 0.01  # m: crosswalk walkways lie on the zebra


def sidewalks_along(draft: TownDraft, seg: Segment) -> None:
    """Sidewalk (and kerb face) on each side of road segment ``seg`` that borders a block; the
    outer ring holds the sidewalk of the outermost roads' outer sides."""
    curb, S = draft.curb, draft.lay.S
    P, H = seg.P, seg.sec.half
    top = curb - SURFACE
    for sgn, region in ((1, seg.left), (-1, seg.right)):
        if region[0] == "outer":
            continue  # the outer ring holds that sidewalk
        lo, hi = sorted((sgn * H, sgn * (H + S)))
        draft.pieces["sidewalk"].append(ribbon(P, lo, hi, top, curb))
        if top > 0:
            klo, khi = sorted((sgn * H, sgn * (H + SURFACE)))
            draft.pieces["sidewalk"].append(ribbon(P, klo, khi, -SURFACE, top))


def junction_corners(draft: TownDraft, i: int, j: int) -> None:
    """Sidewalk squares (``Z`` by ``Z``, with their kerb faces) in the corners of junction zone
    (i, j) that bound a block."""
    lay, curb, Z = draft.lay, draft.curb, draft.lay.Z
    c = lay.centre(i, j)
    Hc, Hr = lay.cols[i].half, lay.rows[j].half
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
        draft.pieces["sidewalk"].append(slabs(side, top, curb))
        if top > 0:
            draft.pieces["sidewalk"].append(slabs(kerb, -SURFACE, top))


def block_ground(draft: TownDraft, bi: int, bj: int) -> None:
    """Terrain of block (bi, bj), its lot polygon and walk loop."""
    lay, S, Z, curb = draft.lay, draft.lay.S, draft.lay.Z, draft.curb
    bot, top_ = lay.segment(f"row{bj}_{bi}"), lay.segment(f"row{bj + 1}_{bi}")
    Hb, Ht = lay.rows[bj].half, lay.rows[bj + 1].half
    Hl, Hr_ = lay.cols[bi].half, lay.cols[bi + 1].half
    cl, cr = lay.cx[bi], lay.cx[bi + 1]
    yLb = lay.centre(bi, bj)[1] + Hb + Z
    yLt = lay.centre(bi, bj + 1)[1] - Ht - Z
    yRb = lay.centre(bi + 1, bj)[1] + Hb + Z
    yRt = lay.centre(bi + 1, bj + 1)[1] - Ht - Z
    xL, xR = cl + Hl + S, cr - Hr_ - S
    xm0, xm1 = cl + Hl + Z, cr - Hr_ - Z
    b = offset_line(bot.P, Hb + S)
    t = offset_line(top_.P, -(Ht + S))
    xs = np.unique(np.concatenate([b[:, 0], t[:, 0]]))
    xs = densify(np.column_stack([xs, np.zeros_like(xs)]), STUFF_TILE)[:, 0]
    xs = xs[np.concatenate([[True], np.diff(xs) > 1e-6])]
    yb, yt = np.interp(xs, b[:, 0], b[:, 1]), np.interp(xs, t[:, 0], t[:, 1])
    low, high = curb - SURFACE, curb
    ter = [strip(xs, yb, yt, low, high)]
    if xm0 - xL > 1e-6:
        ter.append(slab(xL, xm0, yLb, yLt, low, high))
        ter.append(slab(xm1, xR, yRb, yRt, low, high))
    draft.pieces["terrain"] += ter
    poly = [(xL, yLb), (xm0, yLb), *zip(xs, yb), (xm1, yRb), (xR, yRb), (xR, yRt), (xm1, yRt),
            *zip(xs[::-1], yt[::-1]), (xm0, yLt), (xL, yLt)]  # fmt: skip
    poly = np.array(poly, dtype=np.float64)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(poly, axis=0), axis=1) > 1e-6])
    draft.lots[("block", bi, bj)] = poly[keep]
    # walk loop: S/2 from the kerbs, counter-clockwise
    wb = offset_line(bot.P, Hb + S / 2)
    wt = offset_line(top_.P, -(Ht + S / 2))
    loop = np.vstack([
        [[cl + Hl + S / 2, wb[0, 1]]], wb, [[cr - Hr_ - S / 2, wb[-1, 1]]],
        [[cr - Hr_ - S / 2, wt[-1, 1]]], wt[::-1], [[cl + Hl + S / 2, wt[0, 1]]],
    ])  # fmt: skip
    keep = np.concatenate([[True], np.linalg.norm(np.diff(loop, axis=0), axis=1) > 1e-6])
    draft.loops[("block", bi, bj)] = loop[keep]


def outer_ground(draft: TownDraft) -> None:
    """The sidewalk ring (width ``ring``) around the outermost roads, its kerb faces, the terrain
    margin of :data:`TOWN_MARGIN` m beyond it and the walk loop of the ring."""
    lay, curb = draft.lay, draft.curb
    w = lay.ring
    X0, X1, Y0, Y1 = lay.X0, lay.X1, lay.Y0, lay.Y1
    top = curb - SURFACE
    draft.pieces["sidewalk"].append(slabs(ring_rects(X0 - w, X1 + w, Y0 - w, Y1 + w, w), top, curb))
    if top > 0:
        draft.pieces["sidewalk"].append(
            slabs(ring_rects(X0 - SURFACE, X1 + SURFACE, Y0 - SURFACE, Y1 + SURFACE, SURFACE), -SURFACE, top))
    g = TOWN_MARGIN
    draft.pieces["terrain"].append(slabs(ring_rects(X0 - w - g, X1 + w + g, Y0 - w - g, Y1 + w + g, g), top, curb))
    o = lay.S / 2
    draft.loops[("outer",)] = np.array([[X0 - o, Y0 - o], [X1 + o, Y0 - o], [X1 + o, Y1 + o], [X0 - o, Y1 + o]])


def walk_graph(draft: TownDraft) -> tuple[Walkway, ...]:
    """The walk graph: nodes at both ends of every junction arm's crosswalk; the walkways along
    each walk loop between the nodes on it, in loop order, then the crosswalks."""
    lay, S, curb = draft.lay, draft.lay.S, draft.curb
    nodes: dict[tuple, int] = {}
    on_loop: dict[tuple, list[tuple[np.ndarray, int]]] = {r: [] for r in draft.loops}
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
    for region, loop in draft.loops.items():
        closed = np.vstack([loop, loop[:1]])
        cum = polyline_lengths(closed)
        total = float(cum[-1])
        marks = sorted((project_on_loop(closed, cum, p), n) for p, n in on_loop[region])
        for k, (s0, n0) in enumerate(marks):
            s1, n1 = marks[(k + 1) % len(marks)]
            if k + 1 == len(marks):
                s1 += total
            twice = np.vstack([closed, closed[1:]])
            pts = sub_line(twice, s0, s1)
            walks.append(Walkway(walkway_id=len(walks), points=np.column_stack([pts, np.full(len(pts), curb)]),
                                 start_node=n0, end_node=n1, width=width))  # fmt: skip
    for ends, jid in crossings:
        (p0, n0), (p1, n1) = ends[1], ends[0]
        pts = np.array([[p0[0], p0[1], CROSSWALK_Z], [p1[0], p1[1], CROSSWALK_Z]])
        walks.append(Walkway(walkway_id=len(walks), points=pts, start_node=n0, end_node=n1, width=ZEBRA,
                             crosswalk=True, junction=jid))  # fmt: skip
    return tuple(walks)
