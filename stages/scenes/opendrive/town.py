"""OpenDRIVE towns on the town contract (:mod:`carlaocc.stages.scenes.network`): surfaces, road
marks, signals, procedural buildings / vegetation / terrain beside the network, and the lane and
walk graphs, all from a parsed ``.xodr`` network (:mod:`carlaocc.schemas.opendrive`, as
:func:`carlaocc.catalog.opendrive.read_opendrive` returns it).
World frame = the file's inertial frame (metres, right-handed, Z up).

How the town is made (all deterministic from ``(scenes.seed, index)`` and the asset set):

* **Surfaces, road marks, footprint raster, terrain**: :mod:`carlaocc.stages.scenes.opendrive.surfaces`.
* **Lanes, walkways, crosswalks** (the lane and walk graphs):
  :mod:`carlaocc.stages.scenes.opendrive.network`.
* **Signals** (here). Type ``1000001`` (CARLA) or any dynamic ``1000xxx`` signal becomes a
  TrafficLight/vehicle_signal, other types a TrafficSign of the mapped sub-class
  (:data:`SIGN_SUBCLASSES`, e.g. 206 stop, 205 yield, 274 speed_limit; unmapped types any sign).
  The pole stands at the signal's (s, t) on the surface, the lenses / plate (+X) face the
  traffic the ``orientation`` names (``+``: traffic along +s, so facing -s; ``-``: facing +s;
  ``none``: the traffic of the side the signal stands on), turned by ``hOffset`` taken modulo pi
  (a signal never faces away from its traffic; CARLA exports carry +-pi offsets). Signals whose
  footprint touches a driving-lane cell, or whose pole is within 1 m of one already placed, are
  skipped and counted.
* **Buildings** (here) walk the outer border of every non-junction road side, facing the road
  (+X towards it), set back :data:`CLEARANCE` + 0.5-3 m; **vegetation** (trees, bushes, ...) is
  scattered over free cells within :data:`NEAR` m of a surface. A footprint (the asset's
  oriented xy box) is accepted only when every raster cell it touches is free: not within
  :data:`CLEARANCE` m of a surface, not under a signal, a building or a plant (plus a gap).

Not done: lane ``<height>`` (sidewalks use ``curb_height``), road ``<objects>`` (crosswalk
polygons, parking spaces), signal ``zOffset`` (assets stand on the ground at their own height),
left-hand-traffic roads, zebra paint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import ScenesConfig, TownSpec
from carlaocc.schemas.opendrive import OpenDriveNetwork, Signal
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.geometry import concatenate
from carlaocc.stages.scenes.opendrive import geometry as od
from carlaocc.stages.scenes.network import Town
from carlaocc.stages.scenes.opendrive.network import build_opendrive_network
from carlaocc.stages.scenes.opendrive.surfaces import (
    CELL,
    MARGIN,
    MESH_ORDER,
    SURFACE_MESHES,
    TERRAIN_DZ,
    FootprintRaster,
    junction_fill,
    lane_surfaces,
    nearest_surface,
    road_mark_meshes,
    terrain_quads,
)
from carlaocc.stages.scenes.placing import POLE_RADIUS, AssetPools, Placer, rot2, stuff_geometry

__all__ = ["build_opendrive_town", "build_opendrive_town_with_stats", "SIGN_SUBCLASSES"]

CLEARANCE = 1.5  # m: buildings and plants keep this far from every surface
OBJECT_GAP = 1.0  # m: between placed buildings / plants
NEAR = 40.0  # m: vegetation within this distance of a surface

# OpenDRIVE / German StVO sign types -> procedural TrafficSign sub-classes
SIGN_SUBCLASSES: dict[str, str] = {
    "206": "stop", "205": "yield", "274": "speed_limit", "278": "speed_limit", "267": "no_entry",
    "220": "one_way", "350": "pedestrian_crossing", "314": "parking", "101": "warning", "102": "warning",
    "103": "warning", "105": "warning", "120": "warning", "123": "warning", "138": "warning",
    "306": "direction", "301": "direction", "437": "direction",
}  # fmt: skip
TRAFFIC_LIGHT_TYPE = "1000001"


# ---------------------------------------------------------------------------------------------
# placements


def _signal_asset(sig: Signal, pools: AssetPools, rng) -> AssetRecord | None:
    light = str(sig.type) == TRAFFIC_LIGHT_TYPE or (sig.dynamic and str(sig.type).startswith("1000"))
    if light:
        return pools.pick(rng, "TrafficLight", ["vehicle_signal"])
    return pools.pick(rng, "TrafficSign", [SIGN_SUBCLASSES.get(str(sig.type), "__any__")])


def _place_signals(odr: OpenDriveNetwork, placer: Placer, pools: AssetPools, raster: FootprintRaster,
                   blocked: np.ndarray, rng, stats) -> None:  # fmt: skip
    poles: list[np.ndarray] = []
    for road in odr.roads:
        for sig in road.signals:
            asset = _signal_asset(sig, pools, rng)
            if asset is None:
                stats["signals_no_asset"] += 1
                continue
            s = float(np.clip(sig.s, 0.0, road.length))
            x, y, h = (float(v[0]) for v in od.reference_pose(road, [s]))
            p = od.st_to_world(road, np.array([s]), np.array([sig.t]))[0]
            orient = (sig.orientation or "none").strip()
            along = orient == "-" or (orient not in ("+", "-") and sig.t > 0)
            face = h if along else h + math.pi
            off = (float(sig.h_offset or 0.0) + math.pi / 2) % math.pi - math.pi / 2
            yaw = face + off
            ext = asset.extent
            anchor = np.array([-ext[0] / 2 + POLE_RADIUS, 0.0])
            centre = p[:2] - rot2(yaw, anchor)
            cells = raster.rect_cells(centre, yaw, ext[0], ext[1])
            if cells is None or raster.drive[cells].any():
                stats["signals_on_driving"] += 1
                continue
            if any(np.hypot(*(q - p[:2])) < 1.0 for q in poles):
                stats["signals_duplicate"] += 1
                continue
            i, j = raster.cells(p[None, :2])
            z = float(raster.top[i[0], j[0]]) if raster.surf[i[0], j[0]] else float(p[2])
            kind = "traffic_light" if asset.category == "TrafficLight" else "traffic_sign"
            placer.add_asset(kind, asset, p[:2], z, yaw, anchor=tuple(anchor))
            blocked[cells] = True
            poles.append(p[:2].copy())
            stats["signals_placed"] += 1


def _ground_z(terrain_z: np.ndarray, cells) -> float:
    return float(terrain_z[cells].min())


def _place_buildings(odr: OpenDriveNetwork, placer, pools, raster, blocked, terrain_z, rng, stats) -> None:
    gap = int(math.ceil(OBJECT_GAP / CELL))
    for road in odr.roads:
        if str(road.junction) != "-1" or road.length < 8.0:
            continue
        weights = (("office", "commercial", "apartment"), ("house", "residential", "garage"))[int(rng.uniform() < 0.5)]
        for side in (-1, 1):
            s_all = np.arange(0.0, road.length, 1.0)
            if len(s_all) < 2:
                continue
            strips = od.lane_boundaries(road, s_all)
            t_out = np.zeros_like(s_all)
            for st in strips:
                if st.lane_id * side > 0 and od.surface_kind(st.lane_type) is not None:
                    m = np.isin(s_all, st.s)
                    cur = t_out[m]
                    t_out[m] = np.where(side * st.t_outer > side * cur, st.t_outer, cur)
            ref = od.reference_pose(road, s_all)
            border = od.st_to_world(road, s_all, t_out, ref)
            beyond = od.st_to_world(road, s_all, t_out + side, ref)
            normal = beyond[:, :2] - border[:, :2]
            normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
            k = int(rng.integers(0, 6))
            while k < len(s_all) - 4:
                placed = False
                for _ in range(3):
                    asset = pools.pick(rng, "Building", [weights[int(rng.integers(len(weights)))]])
                    if asset is None:
                        return
                    depth, front = float(asset.extent[0]), float(asset.extent[1])
                    mid = min(k + int(front / 2), len(s_all) - 1)
                    n = normal[mid]
                    setback = CLEARANCE + float(rng.uniform(0.5, 3.0))
                    centre = border[mid, :2] + n * (setback + depth / 2)
                    yaw = math.atan2(-n[1], -n[0])
                    cells = raster.rect_cells(centre, yaw, depth, front)
                    if cells is None or blocked[cells].any():
                        continue
                    placer.add_asset("building", asset, centre, _ground_z(terrain_z, cells), yaw)
                    grown = raster.rect_cells(centre, yaw, depth + 2 * gap * CELL, front + 2 * gap * CELL)
                    blocked[grown if grown is not None else cells] = True
                    stats["buildings"] += 1
                    k += int(front) + int(rng.integers(2, 6))
                    placed = True
                    break
                if not placed:
                    k += 3


def _place_vegetation(placer, pools, raster, blocked, terrain_z, dist, rng, stats) -> None:
    if not pools.get("Vegetation"):
        return
    near = (~blocked) & (dist <= NEAR)
    ii, jj = np.nonzero(near)
    if not len(ii):
        return
    attempts = min(1500, int(len(ii) * CELL * CELL / 60.0))
    order = rng.permutation(len(ii))[:attempts]
    gap = OBJECT_GAP
    for k in order:
        if blocked[ii[k], jj[k]]:
            continue
        asset = pools.pick(rng, "Vegetation", [("tree", "tree", "bush", "conifer", "hedge", "palm")[int(rng.integers(6))]])
        centre = np.array([raster.x0 + (ii[k] + 0.5) * CELL, raster.y0 + (jj[k] + 0.5) * CELL])
        yaw = float(rng.uniform(-math.pi, math.pi))
        cells = raster.rect_cells(centre, yaw, float(asset.extent[0]), float(asset.extent[1]))
        if cells is None or blocked[cells].any():
            continue
        placer.add_asset(asset.subclass, asset, centre, _ground_z(terrain_z, cells), yaw)
        grown = raster.rect_cells(centre, yaw, float(asset.extent[0]) + 2 * gap, float(asset.extent[1]) + 2 * gap)
        blocked[grown if grown is not None else cells] = True
        stats["vegetation"] += 1


# ---------------------------------------------------------------------------------------------
# the town


def build_opendrive_town_with_stats(odr: OpenDriveNetwork, spec: TownSpec, scenes: ScenesConfig, index: int,
                                    assets: Sequence[AssetRecord], source: str) -> tuple[Town, dict]:  # fmt: skip
    """:func:`build_opendrive_town` plus build statistics (lanes, link checks, signals placed and
    skipped, buildings, vegetation, terrain quads)."""
    name = f"town{index:02d}"
    label = source or odr.source or "OpenDRIVE network"
    if not odr.roads:
        raise ValueError(f"{label}: no roads")
    curb = scenes.curb_height
    pools = AssetPools(assets)
    rng = np.random.default_rng(np.random.SeedSequence([scenes.seed, index, 0x6F6472]))
    network, stats = build_opendrive_network(odr, curb, label)
    stats.update(signals_placed=0, signals_on_driving=0, signals_duplicate=0, signals_no_asset=0, buildings=0,
                 vegetation=0)  # fmt: skip

    # 1. surfaces, raster, terrain
    meshes, samples = lane_surfaces(odr, curb)
    allp = np.vstack([p for p, _ in samples])
    lo, hi = allp[:, :2].min(axis=0) - MARGIN, allp[:, :2].max(axis=0) + MARGIN
    raster = FootprintRaster(lo, hi)
    for pts, driving in samples:
        raster.mark(pts, driving)
    fill = junction_fill(odr, lo, hi)
    if fill:
        meshes.setdefault("junction", []).extend(fill)
        for V, _F in fill:
            centres = V.reshape(-1, 4, 3).mean(axis=1)
            raster.mark(centres, True)
    dist, terrain_q = nearest_surface(raster)
    terrain = terrain_quads(raster, terrain_q)
    stats["terrain_quads"] = len(terrain[1]) // 2
    sem_of = {v[0]: (v[1], v[2]) for v in SURFACE_MESHES.values()}
    stuff = {}
    for mesh_name in MESH_ORDER:
        if mesh_name in meshes:
            key = f"{name}/{mesh_name}"
            stuff[key] = stuff_geometry(key, concatenate(meshes[mesh_name]), *sem_of[mesh_name])
    marks = road_mark_meshes(odr)
    if marks:
        stuff[f"{name}/roadline"] = stuff_geometry(f"{name}/roadline", concatenate(marks), "RoadLine", "paint")
    if len(terrain[1]):
        stuff[f"{name}/terrain"] = stuff_geometry(f"{name}/terrain", terrain, "Terrain", "grass")
    placer = Placer(name, frozenset(taxonomy.thing_ids(scenes.taxonomy)))
    for geom in stuff.values():
        placer.add_stuff(geom)

    # 2. things beside the network
    terrain_z = terrain_q * TERRAIN_DZ
    blocked = dist <= CLEARANCE
    _place_signals(odr, placer, pools, raster, blocked, rng, stats)
    _place_buildings(odr, placer, pools, raster, blocked, terrain_z, rng, stats)
    _place_vegetation(placer, pools, raster, blocked, terrain_z, dist, rng, stats)

    town = Town(
        name=name, index=index, style="opendrive", source=source, placements=placer.records, stuff=stuff,
        network=network, bounds=raster.bounds, max_instance_id=placer.next_instance - 1, curb_height=curb,
    )  # fmt: skip
    return town, stats


def build_opendrive_town(odr: OpenDriveNetwork, spec: TownSpec, scenes: ScenesConfig, index: int,
                         assets: Sequence[AssetRecord], source: str) -> Town:  # fmt: skip
    """Town ``index`` (``"town%02d"``) from the parsed OpenDRIVE network ``odr`` with ``assets``
    placed beside it; ``source`` names the file (recorded on the town and in error messages).
    Raises ``ValueError`` naming the file when the network cannot form a town (no roads, no
    driving lane, no cycle in the lane graph)."""
    return build_opendrive_town_with_stats(odr, spec, scenes, index, assets, source)[0]
