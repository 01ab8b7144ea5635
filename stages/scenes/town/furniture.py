"""Street furniture and vegetation of a procedural town (:mod:`carlaocc.stages.scenes.town.build`): which
junctions are signalised, traffic lights and stop signs at the junctions, street lights, street
trees, traffic signs, benches, bins, hydrants and bicycles along the sidewalks, parked cars in
the suburb's parking strips, trees in the lots and in the terrain margin.

World frame: metres, Z up, yaw in radians. Pole-like assets are placed by their pole axis (see
:meth:`~carlaocc.stages.scenes.town.layout.TownDraft.pole`); every placement keeps its footprint
free of the others'. Sidewalk depths are measured from the kerb: poles ``min(0.5, 0.4 S)``, the
furniture zone ``min(1.2, 0.45 S)`` wide."""

from __future__ import annotations

import math

import numpy as np

from carlaocc.stages.scenes.placing import yaw_of
from carlaocc.stages.scenes.town.geometry import Footprints, inside, point_at
from carlaocc.stages.scenes.town.layout import TOWN_MARGIN, TownDraft

__all__ = ["place_furniture", "signalised"]


def signalised(draft: TownDraft, i: int, j: int) -> bool:
    """Whether junction (i, j) gets traffic lights (else stop or yield signs): in the arterial
    style those of the arterial row; two-armed corners unless in the suburb; the others by the
    style's signal share (one random draw each)."""
    lay = draft.lay
    if draft.style == "arterial":
        return j == 1
    if len(lay.arms(i, j)) < 3:
        return draft.style != "suburb"
    return bool(draft.rng.uniform() < draft.rules.signal_share)


def _junction_furniture(draft: TownDraft) -> None:
    """A traffic light or a stop / yield sign beside the stop line of every junction arm."""
    lay, rng = draft.lay, draft.rng
    pd = min(0.5, 0.4 * lay.S)
    for j in range(lay.ny + 1):
        for i in range(lay.nx + 1):
            c = lay.centre(i, j)
            signal = draft.signal[(i, j)]
            for u in lay.arms(i, j):
                Hx, sec = lay.cross_half(i, j, u), lay.arm_section(i, j, u)
                uu = np.array(u, float)
                v = np.array([-u[1], u[0]], float)
                # beside the stop line, on the right of the incoming traffic (+v of the arm)
                pole = c + uu * (Hx + lay.Z + 0.6) + v * (sec.half + pd)
                if signal:
                    wide = sec.half - sec.parking >= 6.0
                    asset = draft.pools.pick(rng, "TrafficLight", ["overhead_signal"] if wide else ["vehicle_signal"])
                    if asset is not None and asset.subclass == "pedestrian_signal":
                        asset = None
                    if asset is not None:
                        draft.pole("traffic_light", asset, pole, yaw_of(uu))
                else:
                    sign = draft.pools.get("TrafficSign", ["stop"]) or draft.pools.get("TrafficSign", ["yield"])
                    if sign:
                        draft.pole("traffic_sign", sign[int(rng.integers(len(sign)))], pole, yaw_of(uu))


def _sidewalk_furniture(draft: TownDraft) -> None:
    """Along every road side: street lights, street trees, a traffic sign, and benches, bins,
    hydrants and bicycles on the furniture zone of the sidewalk."""
    rules, rng, lay = draft.rules, draft.rng, draft.lay
    S = lay.S
    pd = min(0.5, 0.4 * S)
    fz = min(1.2, 0.45 * S)
    street_trees = draft.pools.get("Vegetation", ["tree"]) if rules.tree_spacing else []
    light = draft.pools.pick(rng, "Pole", ["street_light"])
    if light is not None and light.subclass != "street_light":
        light = None
    for seg, sgn, region in draft.lay.sides():
        H, L = seg.sec.half, seg.length

        def at(s: float, depth: float, seg=seg, sgn=sgn, H=H):
            p, tng = point_at(seg.P, seg.cum, s)
            nrm = np.array([-tng[1], tng[0]]) * sgn  # away from the road
            return p + nrm * (H + depth), tng, nrm

        if light is not None:
            s = float(rng.uniform(2.0, 8.0))
            while s < L - 2.0:
                xy, _, nrm = at(s, pd)
                draft.pole("street_light", light, xy, yaw_of(-nrm))
                s += float(rng.uniform(*rules.light_spacing))
        if street_trees and S >= 2.0:
            s = float(rng.uniform(4.0, 10.0))
            while s < L - 3.0:
                tree = street_trees[int(rng.integers(len(street_trees)))]
                xy, _, _ = at(s, max(fz / 2, pd))
                draft.put("tree", tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(0.45, 0.45), at=xy,
                          gap=1.0)  # fmt: skip
                s += float(rng.uniform(*rules.tree_spacing))
        sign = draft.pools.pick(rng, "TrafficSign", ["speed_limit", "parking", "no_entry", "one_way", "direction",
                                                    "warning", "pedestrian_crossing"])  # fmt: skip
        if sign is not None and rng.uniform() < 0.6 and L > 8.0:
            xy, tng, _ = at(float(rng.uniform(3.0, L - 3.0)), pd)
            # the kerb-side lane on this side travels -sgn * tangent: face it
            draft.pole("traffic_sign", sign, xy, yaw_of(tng * sgn))
        if fz < 0.6 or L < 8.0:
            continue
        for category, sub, kind in (("Static", "bench", "bench"), ("Static", "bin", "bin"),
                                    ("Static", "hydrant", "hydrant"), ("Bicycle", None, "bicycle")):  # fmt: skip
            asset = draft.pools.pick(rng, category, [sub] if sub else None)
            if asset is None or rng.uniform() >= rules.furniture:
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
            draft.put(kind, asset, xy, yaw)


def _parked_cars(draft: TownDraft) -> None:
    """Cars parked along the parking strips, facing the traffic of their side."""
    rng = draft.rng
    for seg, sgn, region in draft.lay.sides():
        sec = seg.sec
        if sec.parking <= 0:
            continue
        cars = [a for a in draft.pools.get("Car") if a.extent[1] <= sec.parking - 0.3]
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
                p, tng = point_at(seg.P, seg.cum, s + ln / 2)
                nrm = np.array([-tng[1], tng[0]]) * sgn
                xy = p + nrm * (sec.half - sec.parking / 2)
                draft.put("parked_car", car, xy, yaw_of(-sgn * tng), gap=0.5)
            s += ln + float(rng.uniform(1.0, 4.0))


def _lot_trees(draft: TownDraft) -> None:
    """Trees, conifers, bushes and palms at random free spots inside the lots."""
    rng, rules = draft.rng, draft.rules
    trees = draft.pools.get("Vegetation", ["tree", "conifer", "bush", "palm"])
    if not trees:
        return
    for poly in draft.lots.values():
        lo, hi = poly.min(axis=0), poly.max(axis=0)
        area = float((hi - lo).prod())
        tries = int(area / 600.0 * rng.integers(rules.lot_trees[0], rules.lot_trees[1] + 1)) + 1
        for _ in range(tries):
            tree = trees[int(rng.integers(len(trees)))]
            r = max(tree.extent[0], tree.extent[1]) / 2
            xy = lo + rng.uniform(size=2) * (hi - lo)
            pts, _ = Footprints.corners(xy, (r + 0.3, r + 0.3), 0.0)
            if not inside(poly, pts).all() or inside(pts, poly).any():
                continue
            draft.put(tree.subclass, tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(r, r), at=xy)


def _margin_trees(draft: TownDraft) -> None:
    """Trees and conifers in the terrain margin around the town."""
    rng, lay = draft.rng, draft.lay
    trees = draft.pools.get("Vegetation", ["tree", "conifer"])
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
        draft.put(tree.subclass, tree, xy, float(rng.uniform(-math.pi, math.pi)), half=(r, r), at=np.array(xy))


def place_furniture(draft: TownDraft) -> None:
    """Everything but the buildings, in placement order: junction furniture, sidewalk furniture,
    parked cars (suburb only), lot trees, margin trees."""
    _junction_furniture(draft)
    _sidewalk_furniture(draft)
    if draft.style == "suburb":
        _parked_cars(draft)
    _lot_trees(draft)
    _margin_trees(draft)
