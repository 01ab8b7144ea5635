"""Buildings of a procedural town (:mod:`carlaocc.stages.scenes.town.build`): street-facing buildings
filling the lots along every block side, and the lot frontages of the suburb (fences with hedges)
and the arterial style (walls on the main road, fences elsewhere), each with a 3 m gate.

World frame: metres, Z up, yaw in radians; buildings stand at kerb height with their asset +X
towards the street; a lot spans ``a .. a + w`` m along its road segment; fences and walls are
thin closed ribbons standing on the grass ``0.4`` m behind the sidewalk.
"""

from __future__ import annotations

import numpy as np

from carlaocc.stages.scenes.placing import yaw_of
from carlaocc.stages.scenes.town.geometry import (
    Footprints,
    inside,
    offset_line,
    point_at,
    ray_to_edge,
    ribbon,
    sub_line,
)
from carlaocc.stages.scenes.town.layout import Segment, TownDraft

__all__ = ["frontage", "place_buildings"]


def place_buildings(draft: TownDraft) -> None:
    """Buildings in lots along every block side, street-facing behind the sidewalk and a setback:
    lots of random frontage one after the other, each taking one of the three best-fitting assets
    (largest footprint that fits the lot) whose footprint lies inside the lot outline; a lot with
    a building gets its frontage."""
    rules, rng, lay, S = draft.rules, draft.rng, draft.lay, draft.lay.S
    pool = draft.pools.get("Building", list(rules.buildings)) or draft.pools.get("Building")
    ext = np.array([a.extent[:2] for a in pool])
    main = lay.rows[1] if draft.style == "arterial" else None
    for seg, sgn, region in draft.lay.sides():
        if region[0] != "block":
            continue
        poly, H = draft.lots[region], seg.sec.half
        L = seg.length
        a = float(rng.uniform(0.0, 2.0))
        while a < L - 8.0:
            w = min(float(rng.uniform(*rules.lot)), L - a)
            s = a + w / 2
            p, tng = point_at(seg.P, seg.cum, s)
            nrm = np.array([-tng[1], tng[0]]) * sgn  # into the block
            front = p + nrm * (H + S)
            setback = float(rng.uniform(*rules.setback)) + (0.8 if rules.frontage else 0.0)
            room = ray_to_edge(poly, front + nrm * 0.05, nrm) / 2 - setback - 0.5
            depth_max = min(room, rules.max_depth)
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
                    pts, _ = Footprints.corners(c, (d0 / 2 + 0.3, d1 / 2 + 0.3), yaw)
                    if not inside(poly, pts).all() or inside(pts, poly).any():
                        continue
                    if draft.put("building", asset, c, yaw, gap=1.0):
                        placed = (asset, c, d1)
                        break
            if placed is not None:
                frontage(draft, seg, sgn, a, w, s, seg.sec is main)
            a += w


def frontage(draft: TownDraft, seg: Segment, sgn: int, a: float, w: float, s_gate: float, on_main: bool) -> None:
    """Front fence / hedge / wall of a lot (``a .. a + w`` along ``seg``) with a 3 m gate."""
    rules, rng = draft.rules, draft.rng
    if not rules.frontage:
        return
    H, S, curb = seg.sec.half, draft.lay.S, draft.curb
    off = H + S + 0.4
    hedges = draft.pools.get("Vegetation", ["hedge"])
    if rules.frontage == "fence" and hedges and rng.uniform() < 0.4:
        s = a + 0.8
        while s < a + w - 0.8:
            hedge = hedges[int(rng.integers(len(hedges)))]
            ln = hedge.extent[0]
            if s + ln > a + w - 0.8:
                break
            if abs(s + ln / 2 - s_gate) > ln / 2 + 1.5:
                p, tng = point_at(seg.P, seg.cum, s + ln / 2)
                nrm = np.array([-tng[1], tng[0]]) * sgn
                draft.put("hedge", hedge, p + nrm * (off + hedge.extent[1] / 2), yaw_of(tng), gap=0.1)
            s += ln + 0.2
        return
    kind, half_t, height = ("wall", 0.12, 1.8) if (rules.frontage == "wall" and on_main) else ("fence", 0.03, 1.1)
    for s0, s1 in ((a + 0.5, s_gate - 1.5), (s_gate + 1.5, a + w - 0.5)):
        if s1 - s0 < 1.0:
            continue
        P = sub_line(seg.P, s0, s1)
        lo, hi = sorted((sgn * (off - half_t), sgn * (off + half_t)))
        draft.pieces[kind].append(ribbon(P, lo, hi, curb, curb + height))
        # register the line so trees and hedges keep off it
        for q0, q1 in zip(offset_line(P, sgn * off)[:-1], offset_line(P, sgn * off)[1:]):
            draft.feet.add((q0 + q1) / 2, (float(np.linalg.norm(q1 - q0)) / 2, half_t), yaw_of(q1 - q0), 0.1)
