"""Procedural towns in three styles on the town contract (the stages.scenes.town package)."""

from __future__ import annotations

import collections
import math

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.stages.geometry import is_watertight, pose_from_list, transform_points
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes.network import check_network
from carlaocc.stages.scenes.town.build import build_procedural_town, town_name
from carlaocc.stages.scenes.town.layout import LANE_WIDTH, STYLES

THINGS = set(taxonomy.thing_ids())
CURB = ScenesConfig().curb_height


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


@pytest.fixture(scope="module")
def towns(lib):
    return {s: build_procedural_town(TownSpec(style=s), ScenesConfig(), 3, lib.assets) for s in STYLES}


@pytest.fixture(scope="module")
def assets(lib):
    return {a.asset_id: a for a in lib.assets}


def _box(p, a):
    """Footprint corners (4, 2) of a placed asset and its world pose."""
    T = pose_from_list(p.pose)
    l, w = a.extent[0] / 2, a.extent[1] / 2
    return transform_points(T, np.array([[l, w, 0], [-l, w, 0], [-l, -w, 0], [l, -w, 0]], float))[:, :2], T


def _overlap(p: np.ndarray, q: np.ndarray, tol: float = 1e-6) -> bool:
    """Separating-axis overlap of two convex quads (corners in order)."""
    for poly in (p, q):
        for k in range(4):
            e = poly[(k + 1) % 4] - poly[k]
            ax = np.array([-e[1], e[0]])
            if (p @ ax).max() <= (q @ ax).min() + tol or (q @ ax).max() <= (p @ ax).min() + tol:
                return False
    return True


def _lane_points(net, step: float = 0.25, connectors: bool = True):
    pts, half = [], []
    for ln in net.lanes:
        if ln.junction >= 0 and not connectors:
            continue
        s = np.arange(0.0, ln.length, step)
        xyz, _ = ln.at(np.append(s, ln.length))
        pts.append(xyz[:, :2])
        half.append(np.full(len(xyz), ln.width / 2))
    return np.vstack(pts), np.concatenate(half)


# ------------------------------------------------------------------------------ structure


@pytest.mark.parametrize("style", STYLES)
def test_each_style_builds_a_valid_town(towns, style):
    town = towns[style]
    check_network(town.network)
    assert town.name == town_name(3) == "town03" and town.index == 3 and town.style == style and town.source == ""
    assert town.curb_height == CURB
    x0, y0, x1, y1 = town.bounds
    assert x1 - x0 > 150 and y1 - y0 > 150
    for ln in town.network.lanes:
        assert np.all((ln.points[:, 0] > x0) & (ln.points[:, 0] < x1) & (ln.points[:, 1] > y0) & (ln.points[:, 1] < y1))
    assert town.network.road_length > 500
    # stuff first, then things; ids sequential and names unique
    placements = town.placements
    assert [p.placement_id for p in placements] == list(range(len(placements)))
    assert len({p.name for p in placements}) == len(placements)
    n_stuff = len(town.stuff)
    assert [p.asset_id for p in placements[:n_stuff]] == list(town.stuff)
    assert all(p.asset_id not in town.stuff for p in placements[n_stuff:])


def test_deterministic_and_independent_of_asset_order(lib, towns):
    town = towns["arterial"]
    again = build_procedural_town(TownSpec(style="arterial"), ScenesConfig(), 3, list(reversed(lib.assets)))
    assert again.placements == town.placements
    for key, geom in town.stuff.items():
        assert geom.parts[0].vertices.tobytes() == again.stuff[key].parts[0].vertices.tobytes()
    assert [ln.points.tobytes() for ln in again.network.lanes] == [ln.points.tobytes() for ln in town.network.lanes]
    other_seed = build_procedural_town(TownSpec(style="arterial"), ScenesConfig(seed=12), 3, lib.assets)
    other_index = build_procedural_town(TownSpec(style="arterial"), ScenesConfig(), 4, lib.assets)
    assert other_seed.placements != town.placements and other_index.placements != town.placements
    assert other_index.name == "town04"


def test_layout_overrides(lib):
    spec = TownSpec(style="downtown", blocks=2, block_size=50.0, road_width=21.0, sidewalk_width=3.0)
    town = build_procedural_town(spec, ScenesConfig(), 0, lib.assets)
    check_network(town.network)
    assert len(town.network.junction_ids) == 9  # a 3 x 3 grid of junctions
    road = [ln for ln in town.network.lanes if ln.junction < 0]
    per_direction = collections.Counter((ln.road, round(float(ln.at(0.0)[1]), 3)) for ln in road)
    assert set(per_direction.values()) == {3}  # 21 m carriageway: three 3.5 m lanes each way


# ----------------------------------------------------------------------------------- lanes


@pytest.mark.parametrize("style", STYLES)
def test_lane_graph(towns, style):
    net = towns[style].network
    lanes = net.lanes
    assert all(ln.width == LANE_WIDTH for ln in lanes)
    connectors = [ln for ln in lanes if ln.junction >= 0]
    road = [ln for ln in lanes if ln.junction < 0]
    assert connectors and road
    for ln in lanes:
        # polylines sampled at <= 1 m, at the road surface
        assert np.all(np.diff(ln.cum) <= 1.0 + 1e-9) and np.all(ln.points[:, 2] == 0.0)
        assert ln.successors, f"lane {ln.lane_id} has no way on"
        for s in ln.successors:
            assert np.linalg.norm(lanes[s].points[0] - ln.points[-1]) < 0.01
            # connectors lead road to road through one junction
            assert (lanes[s].junction >= 0) != (ln.junction >= 0)
    for ln in connectors:
        assert ln.left == ln.right == -1 and ln.road == f"junction{ln.junction}"
    turns = collections.Counter()
    for ln in connectors:
        _, y = ln.at(np.array([0.0, ln.length]))
        turn = math.remainder(float(y[1] - y[0]), 2 * math.pi)
        turns[round(turn / (math.pi / 2))] += 1
    assert turns[0] and turns[1] and turns[-1]  # straight, left and right turns
    for ln in road:
        for side in ("left", "right"):
            m = getattr(ln, side)
            if m >= 0:
                other = lanes[m]
                assert other.road == ln.road and abs(other.length - ln.length) < 0.05 * ln.length + 0.5
                # parallel: 3.5 m apart at both ends, on the named side
                d0 = other.points[0, :2] - ln.points[0, :2]
                _, yaw = ln.at(0.0)
                lateral = -math.sin(yaw) * d0[0] + math.cos(yaw) * d0[1]
                assert lateral == pytest.approx(LANE_WIDTH if side == "left" else -LANE_WIDTH, abs=0.02)
    # strongly connected through successors
    rows = [k for k, ln in enumerate(lanes) for _ in ln.successors]
    cols = [s for ln in lanes for s in ln.successors]
    graph = csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(lanes), len(lanes)))
    assert connected_components(graph, directed=True, connection="strong")[0] == 1


def test_right_hand_traffic_and_speeds(towns):
    for town in towns.values():
        road = [ln for ln in town.network.lanes if ln.junction < 0]
        by_road = collections.defaultdict(list)
        for ln in road:
            by_road[ln.road].append(ln)
        for lanes in by_road.values():
            # two directions; each lane's mid point lies right of the other direction's lanes
            mids = [(ln, *ln.at(ln.length / 2)) for ln in lanes]
            for ln, p, yaw in mids:
                for other, q, _ in mids:
                    if other is ln:
                        continue
                    d = q[:2] - p[:2]
                    if abs(math.remainder(float(other.at(other.length / 2)[1] - yaw), 2 * math.pi)) > 2:
                        assert -math.sin(yaw) * d[0] + math.cos(yaw) * d[1] > 0  # the other way is to the left
    arterial = [ln.speed_limit for ln in towns["arterial"].network.lanes if ln.junction < 0]
    assert max(arterial) == pytest.approx(50 / 3.6) and min(arterial) == pytest.approx(30 / 3.6)


# -------------------------------------------------------------------------------- walkways


@pytest.mark.parametrize("style", STYLES)
def test_walk_graph(towns, style):
    town = towns[style]
    net = town.network
    nodes = sorted({w.start_node for w in net.walkways} | {w.end_node for w in net.walkways})
    assert nodes == list(range(len(nodes)))
    graph = csr_matrix((np.ones(len(net.walkways)), ([w.start_node for w in net.walkways],
                                                     [w.end_node for w in net.walkways])), shape=(len(nodes),) * 2)  # fmt: skip
    assert connected_components(graph, directed=False)[0] == 1
    crossings = [w for w in net.walkways if w.crosswalk]
    assert crossings and all(w.junction >= 0 and np.all(w.points[:, 2] == pytest.approx(0.01)) for w in crossings)
    assert {w.junction for w in crossings} == set(net.junction_ids)
    sidewalks = [w for w in net.walkways if not w.crosswalk]
    assert all(w.junction == -1 and np.all(w.points[:, 2] == CURB) for w in sidewalks)
    # sidewalk nodes meet: the end of a walkway is where the next one at that node starts
    where = collections.defaultdict(list)
    for w in sidewalks:
        where[w.start_node].append(w.points[0, :2])
        where[w.end_node].append(w.points[-1, :2])
    for pts in where.values():
        assert np.ptp(np.array(pts), axis=0).max() < 1e-6
    # crosswalks span a carriageway: they cross road lanes, sidewalks never do
    lane_pts, half = _lane_points(net, 0.5, connectors=False)
    tree = cKDTree(lane_pts)
    for w in sidewalks[:: max(1, len(sidewalks) // 40)]:
        xyz, _ = w.at(np.linspace(0.0, w.length, 20))
        d, k = tree.query(xyz[:, :2])
        assert np.all(d > half[k]), "a sidewalk walkway runs on a driving lane"
    turn_pts, turn_half = _lane_points(net, 0.5)
    tree = cKDTree(turn_pts)
    for w in crossings:
        d, k = tree.query(w.at(np.linspace(0.0, w.length, 20))[0][:, :2])
        assert np.any(d < turn_half[k])


# ------------------------------------------------------------------------------ placements


@pytest.mark.parametrize("style", STYLES)
def test_placement_records(towns, assets, style):
    town = towns[style]
    things = [p for p in town.placements if p.is_thing]
    ids = [p.instance_id for p in things]
    assert ids and len(set(ids)) == len(ids) and min(ids) >= 1 and max(ids) == town.max_instance_id
    assert all(p.semantic_id in THINGS for p in things)
    for p in town.placements:
        assert p.town == town.name and p.mesh_path == ""
        if p.asset_id in town.stuff:
            assert p.instance_id == 0 and not p.is_thing and np.allclose(pose_from_list(p.pose), np.eye(4))
            V = town.stuff[p.asset_id].parts[0].vertices
            assert np.allclose(p.aabb_min, V.min(axis=0)) and np.allclose(p.aabb_max, V.max(axis=0))
            continue
        a = assets[p.asset_id]
        assert p.semantic_id == a.category_id and p.is_thing == (a.category_id in THINGS)
        if not p.is_thing:
            assert p.instance_id == 0
        T = pose_from_list(p.pose)
        assert T[2, 3] == pytest.approx(CURB)  # everything stands on kerb-high ground or sidewalk
        l, w, h = a.extent
        box = np.array([[x, y, z] for x in (-l / 2, l / 2) for y in (-w / 2, w / 2) for z in (0.0, h)])
        world = transform_points(T, box)
        assert np.all(world.min(axis=0) >= np.array(p.aabb_min) - 1e-6)
        assert np.all(world.max(axis=0) <= np.array(p.aabb_max) + 1e-6)


@pytest.mark.parametrize("style", STYLES)
def test_things_apart_and_off_the_lanes(towns, assets, style):
    # the solid objects (buildings, parked vehicles, bicycles): poles, lights and signs, instances
    # under the release's table, stand on the kerb and may overhang a lane
    town = towns[style]
    solid = set(taxonomy.thing_ids("carlaocc-v1"))
    things = [p for p in town.placements if p.semantic_id in solid]
    boxes = [_box(p, assets[p.asset_id])[0] for p in things]
    centres = np.array([b.mean(axis=0) for b in boxes])
    radius = np.array([np.linalg.norm(b - b.mean(axis=0), axis=1).max() for b in boxes])
    tree = cKDTree(centres)
    for a, b in tree.query_pairs(2 * radius.max()):
        if np.linalg.norm(centres[a] - centres[b]) < radius[a] + radius[b]:
            assert not _overlap(boxes[a], boxes[b]), (things[a].name, things[b].name)
    lane_pts, half = _lane_points(town.network)
    lanes_tree = cKDTree(lane_pts)
    for p, box, c, r in zip(things, boxes, centres, radius):
        near = lanes_tree.query_ball_point(c, r + LANE_WIDTH / 2)
        if not near:
            continue
        # distance of the lane points from the box, in the box frame
        u = (box[0] - box[1]) / np.linalg.norm(box[0] - box[1])
        v = np.array([-u[1], u[0]])
        q = lane_pts[near] - c
        local = np.abs(np.column_stack([q @ u, q @ v]))
        hx, hy = np.linalg.norm(box[0] - box[1]) / 2, np.linalg.norm(box[1] - box[2]) / 2
        dist = np.linalg.norm(np.maximum(local - [hx, hy], 0.0), axis=1)
        assert np.all(dist >= half[near] - 1e-6), f"{p.name} stands on a driving lane"


@pytest.mark.parametrize("style", STYLES)
def test_street_furniture_poles_on_sidewalks(towns, assets, style):
    """Pole-like props stand on kerb-high ground, their pole axis off every lane corridor."""
    town = towns[style]
    lane_pts, half = _lane_points(town.network)
    lanes_tree = cKDTree(lane_pts)
    poles = [p for p in town.placements if p.name.split("_")[0] in ("street", "traffic")]
    assert poles
    for p in poles:
        a = assets[p.asset_id]
        T = pose_from_list(p.pose)
        pole_y = a.extent[1] / 2 - 0.09 if a.subclass == "overhead_signal" else 0.0
        axis = transform_points(T, np.array([[-a.extent[0] / 2 + 0.09, pole_y, 0.0]]))[0, :2]
        d, k = lanes_tree.query(axis)
        assert d > half[k] + 0.2, p.name


# ------------------------------------------------------------------------------------ stuff


@pytest.mark.parametrize("style", STYLES)
def test_stuff_meshes(towns, style):
    town = towns[style]
    names = {k.split("/")[1] for k in town.stuff}
    assert {"road", "sidewalk", "terrain", "roadline"} <= names
    semantic = {"road": "Road", "sidewalk": "Sidewalk", "terrain": "Terrain", "roadline": "RoadLine",
                "guardrail": "GuardRail", "fence": "Fence", "wall": "Wall"}  # fmt: skip
    for key, geom in town.stuff.items():
        part = geom.parts[0]
        assert key.startswith(f"{town.name}/") and geom.asset_id == key
        assert part.semantic_id == taxonomy.by_name(semantic[key.split("/")[1]]).id
        # every stuff mesh is a union of closed thin slabs
        assert is_watertight(part.faces) and geom.part_closed == (True,)
        V, F = part.vertices, part.faces
        edges = np.linalg.norm(V[F] - V[np.roll(F, 1, axis=1)], axis=2)
        assert edges.max() < 8.0 * math.sqrt(2) + 1e-6  # tiles small enough to cull
    top = {n: town.stuff[f"{town.name}/{n}"].parts[0].vertices[:, 2] for n in names}
    assert top["road"].max() == pytest.approx(0.0) and top["road"].min() == pytest.approx(-0.01)
    assert top["sidewalk"].max() == pytest.approx(CURB) and top["terrain"].max() == pytest.approx(CURB)
    assert top["roadline"].min() == pytest.approx(0.0) and top["roadline"].max() == pytest.approx(0.01)
    # sidewalks keep off the lanes: no sidewalk-top vertex inside a lane corridor (turning
    # connectors included: right turns swing wide of the sharp kerb corners)
    V = town.stuff[f"{town.name}/sidewalk"].parts[0].vertices
    tops = V[np.isclose(V[:, 2], CURB)][:, :2]
    lane_pts, half = _lane_points(town.network, 0.25)
    d, k = cKDTree(lane_pts).query(tops)
    assert np.all(d >= half[k] - 1e-3)


def test_style_features(towns, assets):
    # downtown: traffic lights at every junction, a zebra on every crosswalk
    for style in ("downtown", "arterial"):
        town = towns[style]
        lines = cKDTree(town.stuff[f"{town.name}/roadline"].parts[0].vertices[:, :2])
        for w in (w for w in town.network.walkways if w.crosswalk):
            mid = w.at(w.length / 2)[0][:2]
            assert lines.query_ball_point(mid, 2.0), f"{style}: crosswalk {w.walkway_id} has no zebra"
    downtown = towns["downtown"]
    lights = np.array([pose_from_list(p.pose)[:2, 3] for p in downtown.placements if p.name.startswith("traffic_light")])
    for jid in downtown.network.junction_ids:
        ends = np.array([ln.points[0, :2] for ln in downtown.network.lanes if ln.junction == jid])
        centre = ends.mean(axis=0)
        assert (np.linalg.norm(lights - centre, axis=1) < 25.0).sum() >= 2
    # suburb: parked cars along the kerb, parallel to the lanes, and stop signs
    suburb = towns["suburb"]
    cars = [p for p in suburb.placements if p.name.startswith("parked_car")]
    assert len(cars) >= 10 and all(p.semantic_id == taxonomy.by_name("Car").id and p.is_thing for p in cars)
    lane_pts, _ = _lane_points(suburb.network)
    d, _ = cKDTree(lane_pts).query(np.array([pose_from_list(p.pose)[:2, 3] for p in cars]))
    assert np.all((d > LANE_WIDTH / 2 + 0.5) & (d < LANE_WIDTH + 1.5))  # in the strip next to the lane
    assert any(assets[p.asset_id].subclass == "stop" for p in suburb.placements if p.name.startswith("traffic_sign"))
    assert f"{suburb.name}/fence" in suburb.stuff
    houses = [p for p in suburb.placements if p.name.startswith("building_") and assets[p.asset_id].subclass == "house"]
    assert len(houses) >= 10
    # arterial: a curved multi-lane road with a median guard rail and walls along the lots
    art = towns["arterial"]
    assert {f"{art.name}/guardrail", f"{art.name}/wall"} <= set(art.stuff)
    fast = [ln for ln in art.network.lanes if ln.junction < 0 and ln.speed_limit > 10]
    assert sum(ln.left >= 0 for ln in fast) >= len(fast) // 3
    yaws = np.concatenate([np.diff(np.unwrap(ln.at(ln.cum)[1])) for ln in fast])
    assert np.abs(yaws).max() > 0.005  # really curved
    headings = np.concatenate([ln.at(ln.cum[:-1])[1] for ln in fast])
    assert np.any(np.abs(np.sin(2 * headings)) > 0.05)  # not axis-aligned everywhere


@pytest.mark.parametrize("style", STYLES)
def test_buildings_fit_their_lots(towns, assets, style):
    town = towns[style]
    buildings = [p for p in town.placements if p.name.startswith("building_")]
    assert len(buildings) >= 12
    wanted = {"downtown": {"office", "tower", "commercial", "residential", "apartment", "public"},
              "suburb": {"house", "garage", "residential"}}.get(style)  # fmt: skip
    if wanted:
        assert {assets[p.asset_id].subclass for p in buildings} <= wanted
    # every building faces a street: its +X axis points at the nearest road lane
    lane_pts, _ = _lane_points(town.network, 1.0)
    tree = cKDTree(lane_pts)
    for p in buildings:
        T = pose_from_list(p.pose)
        a = assets[p.asset_id]
        front = T[:2, 3] + T[:2, 0] * a.extent[0] / 2
        back = T[:2, 3] - T[:2, 0] * a.extent[0] / 2
        assert tree.query(front)[0] < tree.query(back)[0]


# --------------------------------------------------------------------------------- refusals


def test_bad_configs(lib):
    with pytest.raises(ValueError, match="Building"):
        build_procedural_town(TownSpec(), ScenesConfig(), 0, [a for a in lib.assets if a.category != "Building"])
    with pytest.raises(ValueError, match="sidewalk"):
        build_procedural_town(TownSpec(block_size=12.0, sidewalk_width=5.0), ScenesConfig(), 0, lib.assets)
    with pytest.raises(ValueError, match="lane"):
        build_procedural_town(TownSpec(style="suburb", road_width=8.0), ScenesConfig(), 0, lib.assets)
    with pytest.raises(ValueError, match="opendrive"):
        spec = TownSpec(style="opendrive", opendrive="builtin:crossroads.xodr")
        build_procedural_town(spec, ScenesConfig(), 0, lib.assets)
    with pytest.raises(ValueError, match="village"):
        build_procedural_town(TownSpec.model_construct(style="village"), ScenesConfig(), 0, lib.assets)


def test_only_buildings_is_enough(lib):
    only = [a for a in lib.assets if a.category == "Building"]
    town = build_procedural_town(TownSpec(style="suburb"), ScenesConfig(), 0, only)
    check_network(town.network)
    cats = {p.semantic_id for p in town.placements if p.asset_id not in town.stuff}
    assert cats == {taxonomy.by_name("Building").id}
