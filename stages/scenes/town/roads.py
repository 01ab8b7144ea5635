"""Roads of a procedural town (:mod:`carlaocc.stages.scenes.town.build`): the carriageway surfaces of road
segments and junction boxes (with the arterial's kerbed grass median and guard rail), the road
markings (centre, lane, edge and parking lines, zebras, stop lines) and the lane graph (road
lanes and the connector lanes crossing each junction).

World frame: metres, Z up, the road surface at z = 0; surfaces are thin closed slabs
``[-SURFACE, 0]``, markings ``[0, MARKING_TOP]``, the median's grass and kerbs stand at the
kerb height. Right-hand traffic: a segment's forward lanes run on the right of its centreline.
"""

from __future__ import annotations

import numpy as np

from carlaocc.stages.scenes.network import Lane
from carlaocc.stages.scenes.placing import SURFACE, slabs
from carlaocc.stages.scenes.town.geometry import SAMPLE, arm_rect, bezier, densify, offset_line, ribbon, sub_line
from carlaocc.stages.scenes.town.layout import LANE_WIDTH, ZEBRA, Layout, Segment, TownDraft

__all__ = ["MARKING_TOP", "junction_surfaces", "lane_graph", "road_length", "road_surfaces"]

MARKING_TOP = 0.01  # m: road markings stand 1 cm proud of the road
TURN = 25.0 / 3.6  # m/s, speed limit of turning connector lanes


def road_surfaces(draft: TownDraft, seg: Segment) -> None:
    """Carriageway, median (grass, kerbs, noses, guard rail) and markings of road segment ``seg``."""
    sec, curb = seg.sec, draft.curb
    P, H, m = seg.P, sec.half, sec.median
    top = curb - SURFACE
    if m > 0:
        draft.pieces["road"] += [ribbon(P, -H, -m / 2, -SURFACE, 0.0), ribbon(P, m / 2, H, -SURFACE, 0.0)]
        draft.pieces["terrain"].append(ribbon(P, -m / 2 + SURFACE, m / 2 - SURFACE, top, curb))
        kerbs = [ribbon(P, -m / 2, -m / 2 + SURFACE, -SURFACE, curb), ribbon(P, m / 2 - SURFACE, m / 2, -SURFACE, curb)]
        L = seg.length
        for s0, s1 in ((0.0, SURFACE), (L - SURFACE, L)):  # noses
            kerbs.append(ribbon(sub_line(P, s0, s1), -m / 2 + SURFACE, m / 2 - SURFACE, -SURFACE, top))
        if top > 0:
            draft.pieces["sidewalk"] += kerbs
        else:
            draft.pieces["terrain"] += kerbs
        rail = sub_line(P, 1.0, L - 1.0)
        draft.pieces["guardrail"].append(ribbon(rail, -0.15, 0.15, curb, curb + 0.8))
    else:
        draft.pieces["road"].append(ribbon(P, -H, H, -SURFACE, 0.0))
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
        draft.pieces["roadline"].append(ribbon(sub_line(P, 0.5, L - 0.5), a, b, 0.0, MARKING_TOP))
    for k in range(1, sec.lanes):
        o = m / 2 + k * LANE_WIDTH
        s = 2.0
        while s + 3.0 <= L - 1.0:
            for sgn in (1, -1):
                a, b = sorted((sgn * (o - 0.06), sgn * (o + 0.06)))
                draft.pieces["roadline"].append(ribbon(sub_line(P, s, s + 3.0), a, b, 0.0, MARKING_TOP))
            s += 9.0


def junction_surfaces(draft: TownDraft, i: int, j: int) -> None:
    """Carriageway of the junction zone (i, j) and its markings: a zebra and a stop line on every arm."""
    lay, Z = draft.lay, draft.lay.Z
    c = lay.centre(i, j)
    Hc, Hr = lay.cols[i].half, lay.rows[j].half
    arms = lay.arms(i, j)
    road = [(c[0] - Hc, c[0] + Hc, c[1] - Hr, c[1] + Hr)]
    marks = []
    for u in arms:
        Hx, sec = lay.cross_half(i, j, u), lay.arm_section(i, j, u)
        H = sec.half
        road.append(arm_rect(c[0], c[1], u, Hx, Hx + Z, -H, H))
        # zebra: stripes 0.5 m wide every 1 m across the carriageway, along the road
        n = int((2 * H - 0.6) // 1.0)
        b0 = -n / 2.0 + 0.25
        for k in range(n):
            marks.append(arm_rect(c[0], c[1], u, Hx + lay.zc - ZEBRA / 2, Hx + lay.zc + ZEBRA / 2,
                                  b0 + k, b0 + k + 0.5))  # fmt: skip
        # stop line at the zone edge, across the incoming lanes (on the arm's left = +v side)
        marks.append(arm_rect(c[0], c[1], u, Hx + Z - 0.5, Hx + Z - 0.1, sec.median / 2 + 0.1,
                              sec.median / 2 + sec.lanes * LANE_WIDTH - 0.1))  # fmt: skip
    draft.pieces["road"].append(slabs(road, -SURFACE, 0.0))
    draft.pieces["roadline"].append(slabs(marks, 0.0, MARKING_TOP))


def lane_graph(lay: Layout) -> tuple[Lane, ...]:
    """The lanes of the town: ``lanes`` each way along every segment (densified to <= SAMPLE m),
    then per junction the connector lanes of every allowed move (no U-turns), as cubic curves."""
    lanes: list[dict] = []
    ins: dict[tuple, list[int]] = {}  # (i, j, arm) -> in-lane ids by index
    outs: dict[tuple, list[int]] = {}
    for seg in lay.segments:
        sec = seg.sec
        for forward in (True, False):
            ids = []
            for k in range(sec.lanes):
                off = sec.lane_offset(k)
                pts = offset_line(seg.P, -off) if forward else offset_line(seg.P, off)[::-1]
                pts = densify(pts, SAMPLE)
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
                            pts = bezier(p0, np.array(d, float), p1, np.array(w, float))
                            speed = min(src["speed"], dst["speed"]) if w == d else min(TURN, src["speed"])
                            src["succ"].append(len(lanes))
                            lanes.append({"points": pts, "road": f"junction{jid}", "speed": speed, "junction": jid,
                                          "succ": [t], "left": -1, "right": -1})  # fmt: skip
    return tuple(
        Lane(lane_id=k, points=np.column_stack([ln["points"], np.zeros(len(ln["points"]))]), width=LANE_WIDTH,
             successors=tuple(ln["succ"]), left=ln["left"], right=ln["right"], junction=ln["junction"],
             speed_limit=float(ln["speed"]), road=ln["road"])
        for k, ln in enumerate(lanes)
    )  # fmt: skip


def road_length(lay: Layout) -> float:
    """Length (m) the traffic densities refer to: every segment plus every junction arm up to the
    zone edge."""
    length = sum(s.length for s in lay.segments)
    for j in range(lay.ny + 1):
        for i in range(lay.nx + 1):
            length += sum(lay.cross_half(i, j, u) + lay.Z for u in lay.arms(i, j))
    return float(length)
