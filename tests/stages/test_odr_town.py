"""OpenDRIVE towns on the town contract: hand-computable lanes, the builtin crossroads town, the
CARLA towns of the shared test data, signals, non-overlapping placements, determinism, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from carlaocc.catalog.opendrive import parse_opendrive, read_opendrive
from carlaocc.catalog.towns import resolve_opendrive
from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import IngestConfig, ScenesConfig, TownSpec
from carlaocc.stages.geometry import pose_from_list
from carlaocc.stages.ingest import ingest_procedural
from carlaocc.stages.scenes.network import check_network
from carlaocc.stages.scenes.opendrive.network import build_opendrive_network
from carlaocc.stages.scenes.opendrive.town import build_opendrive_town, build_opendrive_town_with_stats
from shared_data import needs, shared_path

DATA = shared_path("opendrive")
SEM = {n: taxonomy.by_name(n).id for n in ("Building", "Vegetation", "TrafficLight", "TrafficSign", "Terrain")}


@pytest.fixture(scope="module")
def lib():
    return ingest_procedural(IngestConfig())


@pytest.fixture(scope="module")
def extents(lib):
    return {a.asset_id: a for a in lib.assets}


def build(odr, lib, index=1, seed=11, source="test.xodr", assets=None):
    spec = TownSpec(style="opendrive", opendrive=source)
    return build_opendrive_town_with_stats(odr, spec, ScenesConfig(seed=seed), index,
                                           lib.assets if assets is None else assets, source)  # fmt: skip


@pytest.fixture(scope="module")
def crossroads(lib):
    path = resolve_opendrive("builtin:crossroads.xodr")
    odr = read_opendrive(path)
    town, stats = build(odr, lib, source=str(path))
    return odr, town, stats


# ---------------------------------------------------------------------------- a hand-made stadium

R = 30.0
STADIUM = f"""<OpenDRIVE><header revMajor="1" revMinor="4"/>
<road id="7" length="{200 + 2 * math.pi * R!r}" junction="-1">
 <link><predecessor elementType="road" elementId="7" contactPoint="end"/>
       <successor elementType="road" elementId="7" contactPoint="start"/></link>
 <planView>
  <geometry s="0" x="0" y="0" hdg="0" length="100"><line/></geometry>
  <geometry s="100" x="100" y="0" hdg="0" length="{math.pi * R!r}"><arc curvature="{1 / R!r}"/></geometry>
  <geometry s="{100 + math.pi * R!r}" x="100" y="{2 * R!r}" hdg="{math.pi!r}" length="100"><line/></geometry>
  <geometry s="{200 + math.pi * R!r}" x="0" y="{2 * R!r}" hdg="{math.pi!r}" length="{math.pi * R!r}"><arc curvature="{1 / R!r}"/></geometry>
 </planView>
 <lanes>
  {"".join(f'''<laneSection s="{s0}">
   <left><lane id="1" type="sidewalk"><link><predecessor id="1"/><successor id="1"/></link><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></left>
   <center><lane id="0" type="none"/></center>
   <right><lane id="-1" type="driving"><link><predecessor id="-1"/><successor id="-1"/></link><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
          <lane id="-2" type="sidewalk"><width sOffset="0" a="2" b="0" c="0" d="0"/></lane></right>
  </laneSection>''' for s0 in (0, 100))}
 </lanes>
</road></OpenDRIVE>"""


def test_stadium_lanes_are_exact():
    net, stats = build_opendrive_network(parse_opendrive(STADIUM, "stadium.xodr"), 0.15, "stadium.xodr")
    check_network(net)
    assert len(net.lanes) == 2 and stats["link_mismatches"] == 0
    straight, curved = net.lanes
    # the straight section: centre of lane -1 at t = -1.75, running +x, every <= 1 m
    assert np.allclose(straight.points[:, 1], -1.75) and np.allclose(straight.points[:, 2], 0.0)
    assert straight.points[0, 0] == pytest.approx(0.0) and straight.points[-1, 0] == pytest.approx(100.0)
    assert np.all(np.diff(straight.points[:, 0]) > 0) and np.max(np.diff(straight.points[:, 0])) <= 1.0 + 1e-9
    assert straight.width == pytest.approx(3.5) and straight.length == pytest.approx(100.0)
    assert straight.junction == -1 and straight.road == "7" and straight.left == straight.right == -1
    # the arcs: lane centre on a circle of radius R + 1.75 about (100, R) (and (0, R))
    p = curved.points
    first_arc = p[p[:, 0] > 100 + 1e-6]
    assert len(first_arc) > 50
    assert np.allclose(np.hypot(first_arc[:, 0] - 100, first_arc[:, 1] - R), R + 1.75, atol=1e-6)
    assert curved.length == pytest.approx(100 + 2 * math.pi * (R + 1.75), rel=2e-3)  # chords of <= 1 m
    # the loop closes: each lane's successor is the other, ends meet starts
    assert straight.successors == (1,) and curved.successors == (0,)
    assert np.linalg.norm(straight.points[-1] - curved.points[0]) < 1e-9
    assert np.linalg.norm(curved.points[-1] - straight.points[0]) < 1e-9
    assert net.road_length == pytest.approx(200 + 2 * math.pi * R)
    # sidewalks: centre lines on the raised surface at t = +1 and t = -4.5, joined into loops
    side = [w for w in net.walkways if not w.crosswalk]
    assert len(side) == 4 and not any(w.crosswalk for w in net.walkways)
    left0 = next(w for w in side if w.points[0, 1] > 0 and w.points[0, 0] < 1 and abs(w.points[-1, 1] - 1) < 1e-6)
    assert np.allclose(left0.points[:, 1], 1.0) and np.allclose(left0.points[:, 2], 0.15) and left0.width == 2.0
    # two loops of two walkways: 4 nodes, each shared by two walkway ends
    nodes = [n for w in side for n in (w.start_node, w.end_node)]
    assert len(set(nodes)) == 4 and all(nodes.count(n) == 2 for n in nodes)


def test_stadium_town_surfaces(lib):
    town, stats = build(parse_opendrive(STADIUM, "stadium.xodr"), lib, source="stadium.xodr")
    road = town.stuff["town01/road"].parts[0]
    assert road.semantic_id == taxonomy.by_name("Road").id
    V = road.vertices
    on_straight = V[(V[:, 0] > 1) & (V[:, 0] < 99) & (V[:, 1] < 1e-9) & (V[:, 1] > -10)]
    assert np.allclose(np.unique(np.round(on_straight[:, 1], 9)), [-3.5, 0.0])
    side = town.stuff["town01/sidewalk"].parts[0]
    assert side.vertices[:, 2].max() == pytest.approx(0.15)  # raised by the curb height
    assert town.style == "opendrive" and town.source == "stadium.xodr" and town.name == "town01"


def test_network_errors_name_the_file():
    no_driving = STADIUM.replace('type="driving"', 'type="sidewalk"')
    with pytest.raises(ValueError, match=r"nodrive\.xodr: no driving lanes"):
        build_opendrive_network(parse_opendrive(no_driving, "nodrive.xodr"), 0.15, "nodrive.xodr")
    dead_end = STADIUM.replace('<successor elementType="road" elementId="7" contactPoint="start"/>', "")
    with pytest.raises(ValueError, match=r"deadend\.xodr: the lane graph has no cycle"):
        build_opendrive_network(parse_opendrive(dead_end, "deadend.xodr"), 0.15, "deadend.xodr")


# ---------------------------------------------------------------------------- crossroads


def test_crossroads_network(crossroads):
    odr, town, stats = crossroads
    net = town.network
    check_network(net)
    assert stats["link_mismatches"] == 0 and stats["link_missing"] == 0 and stats["scc_dropped"] == 0
    # 5 roads: 2 main (2 lanes each way, 2 sections on road 1) + 3 side (1 each way) + 26 connectors
    assert len(net.lanes) == 2 * 4 + 4 + 2 * 3 + 26
    # strongly connected: every lane reaches and is reached from lane 0
    succ = [ln.successors for ln in net.lanes]
    pred = [[] for _ in succ]
    for i, ss in enumerate(succ):
        for j in ss:
            pred[j].append(i)
    for graph in (succ, pred):
        seen, todo = {0}, [0]
        while todo:
            for j in graph[todo.pop()]:
                if j not in seen:
                    seen.add(j)
                    todo.append(j)
        assert len(seen) == len(net.lanes)
    for ln in net.lanes:
        for j in ln.successors:
            assert np.linalg.norm(ln.points[-1] - net.lanes[j].points[0]) < 0.1
    # connector lanes carry their junction's id, road lanes none
    conn = {ln.junction for ln in net.lanes if int(ln.road) >= 500}
    assert conn == {100, 200, 300} and net.junction_ids == (100, 200, 300)
    assert all(ln.junction == -1 for ln in net.lanes if int(ln.road) < 500)
    # neighbours on the main road: lanes -1 and -2 of each section are each other's left/right
    main = [ln for ln in net.lanes if ln.road == "1"]
    assert len(main) == 8 and sum(ln.left >= 0 for ln in main) == 4 and sum(ln.right >= 0 for ln in main) == 4
    for ln in main:
        if ln.right >= 0:
            other = net.lanes[ln.right]
            assert other.left == ln.lane_id and abs(abs(ln.points[0, 1]) - abs(other.points[0, 1])) == pytest.approx(3.5)
    # road length: the five non-junction roads
    assert net.road_length == pytest.approx(sum(r.length for r in odr.roads if r.junction == "-1"))
    # the hill: road 4 rises 2 m
    assert max(ln.points[:, 2].max() for ln in net.lanes if ln.road == "4") == pytest.approx(2.0, abs=0.01)
    assert max(ln.points[:, 2].max() for ln in net.lanes if ln.road == "1") == pytest.approx(0.0)


def test_crossroads_walkways(crossroads):
    _, town, stats = crossroads
    walk = town.network.walkways
    cross = [w for w in walk if w.crosswalk]
    # every junction entry of a road with sidewalks on both sides: 4 + 3 + 3 arms
    assert len(cross) == 10 and {w.junction for w in cross} == {100, 200, 300}
    assert all(w.junction == -1 for w in walk if not w.crosswalk)
    # the crosswalk ends are sidewalk nodes, and the walk graph is one component
    side_nodes = {n for w in walk if not w.crosswalk for n in (w.start_node, w.end_node)}
    assert all(w.start_node in side_nodes and w.end_node in side_nodes for w in cross)
    parent = {}

    def find(a):
        while parent.setdefault(a, a) != a:
            a = parent[a]
        return a

    for w in walk:
        parent[find(w.start_node)] = find(w.end_node)
    assert len({find(n) for n in parent}) == 1
    # sidewalk centre lines are on the raised surface (roads at 0 except the hill road)
    flat = [w for w in walk if not w.crosswalk and w.points[:, 2].max() < 1.0]
    assert flat and all(np.allclose(w.points[:, 2], 0.15) for w in flat)


def _rects(town, extents, sems):
    """(placement, centre xy, yaw, half length, half width) of asset placements of classes ``sems``."""
    out = []
    for rec in town.placements:
        if rec.semantic_id not in sems or rec.asset_id not in extents:
            continue
        T = pose_from_list(rec.pose)
        a = extents[rec.asset_id]
        out.append((rec, T[:2, 3].copy(), math.atan2(T[1, 0], T[0, 0]), a.extent[0] / 2, a.extent[1] / 2))
    return out


def _inside(points, rect, grow=0.0):
    _, c, yaw, hl, hw = rect
    d = points[:, :2] - c
    u = d[:, 0] * math.cos(yaw) + d[:, 1] * math.sin(yaw)
    v = -d[:, 0] * math.sin(yaw) + d[:, 1] * math.cos(yaw)
    return (np.abs(u) <= hl + grow) & (np.abs(v) <= hw + grow)


def _corners(rect):
    _, c, yaw, hl, hw = rect
    R2 = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    return np.array([[-hl, -hw], [hl, -hw], [hl, hw], [-hl, hw]]) @ R2.T + c


def _overlap(a, b) -> bool:
    """Separating-axis test of two oriented rectangles (touching counts as apart)."""
    ca, cb = _corners(a), _corners(b)
    for rect in (a, b):
        for ang in (rect[2], rect[2] + math.pi / 2):
            ax = np.array([math.cos(ang), math.sin(ang)])
            pa, pb = ca @ ax, cb @ ax
            if pa.max() <= pb.min() + 1e-9 or pb.max() <= pa.min() + 1e-9:
                return False
    return True


def _surface_points(town, names):
    pts = []
    for n in names:
        g = town.stuff.get(f"{town.name}/{n}")
        if g is not None:
            p = g.parts[0]
            tri = p.vertices[p.faces]
            pts += [p.vertices, tri.mean(axis=1), (tri[:, 0] + tri[:, 1]) / 2, (tri[:, 1] + tri[:, 2]) / 2,
                    (tri[:, 0] + tri[:, 2]) / 2]  # fmt: skip
    return np.vstack(pts)


def _corridor_points(town):
    pts = []
    for ln in town.network.lanes:
        p = ln.points
        d = np.diff(p[:, :2], axis=0)
        d = np.vstack([d, d[-1:]]) / np.maximum(np.linalg.norm(np.vstack([d, d[-1:]]), axis=1, keepdims=True), 1e-9)
        n = np.column_stack([-d[:, 1], d[:, 0]])
        for f in np.linspace(-0.5, 0.5, 7):
            pts.append(p[:, :2] + n * f * ln.width)
    return np.vstack(pts)


def check_placements(town, extents):
    """The placement invariants every OpenDRIVE town keeps."""
    recs = town.placements
    # stuff first at identity, then things; placement ids and AABBs valid; instance ids unique
    n_stuff = len(town.stuff)
    assert [r.asset_id for r in recs[:n_stuff]] == list(town.stuff)
    assert all(r.pose == list(np.eye(4).ravel()) and r.instance_id == 0 for r in recs[:n_stuff])
    assert [r.placement_id for r in recs] == list(range(len(recs)))
    for r in recs:
        assert all(math.isfinite(v) for v in r.aabb_min + r.aabb_max)
        assert all(lo <= hi for lo, hi in zip(r.aabb_min, r.aabb_max))
    for r in recs[:n_stuff]:
        V = np.concatenate([p.vertices for p in town.stuff[r.asset_id].parts])
        assert np.allclose(r.aabb_min, V.min(axis=0)) and np.allclose(r.aabb_max, V.max(axis=0))
    inst = [r.instance_id for r in recs if r.is_thing]
    assert inst == list(range(1, len(inst) + 1)) and town.max_instance_id == len(inst)
    # buildings and plants never touch a road/sidewalk/shoulder/junction surface
    surf = _surface_points(town, ("road", "junction", "shoulder", "sidewalk", "bike_lane", "median", "border"))
    tree = cKDTree(surf[:, :2])
    objects = _rects(town, extents, {SEM["Building"], SEM["Vegetation"]})
    for rect in objects:
        near = tree.query_ball_point(rect[1], math.hypot(rect[3], rect[4]) + 0.1)
        assert not _inside(surf[near], rect).any(), f"{rect[0].name} overlaps a surface"
    # no asset footprint (signals included) overlaps a driving-lane corridor
    signals = _rects(town, extents, {SEM["TrafficLight"], SEM["TrafficSign"]})
    corr = _corridor_points(town)
    ctree = cKDTree(corr)
    for rect in objects + signals:
        near = ctree.query_ball_point(rect[1], math.hypot(rect[3], rect[4]) + 0.1)
        assert not _inside(corr[near], rect).any(), f"{rect[0].name} overlaps a lane corridor"
    # no two asset footprints overlap
    allr = objects + signals
    centres = cKDTree(np.array([r[1] for r in allr]))
    radius = max(math.hypot(r[3], r[4]) for r in allr)
    for i, j in centres.query_pairs(2 * radius):
        a, b = allr[i], allr[j]
        if np.hypot(*(a[1] - b[1])) < math.hypot(a[3], a[4]) + math.hypot(b[3], b[4]):
            assert not _overlap(a, b), f"{a[0].name} overlaps {b[0].name}"
    # terrain never lies under a driving lane
    ter = town.stuff.get(f"{town.name}/terrain")
    if ter is not None:
        p = ter.parts[0]
        tc = p.vertices[p.faces].mean(axis=1)
        lane_pts = np.vstack([ln.points[:, :2] for ln in town.network.lanes])
        d, _ = cKDTree(lane_pts).query(tc[:, :2])
        assert d.min() > 1.0


def test_crossroads_placements(crossroads, extents):
    _, town, stats = crossroads
    check_placements(town, extents)
    cats = {}
    for r in town.placements[len(town.stuff):]:
        a = extents[r.asset_id]
        cats.setdefault((a.category, a.subclass if a.category in ("TrafficSign", "TrafficLight") else ""), []).append(r)
    assert len(cats[("Building", "")]) >= 30 and len(cats[("Vegetation", "")]) >= 100
    assert {k for k in town.stuff} >= {f"town01/{n}" for n in ("road", "junction", "sidewalk", "shoulder", "roadline",
                                                              "terrain")}  # fmt: skip


def test_crossroads_signals(crossroads, extents):
    odr, town, stats = crossroads
    assert stats["signals_placed"] == len(odr.signals) == 10 and stats["signals_on_driving"] == 0
    by = {}
    for rec, c, yaw, hl, hw in _rects(town, extents, {SEM["TrafficLight"], SEM["TrafficSign"]}):
        a = extents[rec.asset_id]
        T = pose_from_list(rec.pose)
        pole = T[:2, 3] + T[:2, 0] * (-a.extent[0] / 2 + 0.09)
        by.setdefault(a.subclass, []).append((pole, yaw, T[2, 3]))
    assert len(by["vehicle_signal"]) == 4 and len(by["stop"]) == 3 and len(by["yield"]) == 1
    assert len(by["speed_limit"]) == 2
    from carlaocc.stages.scenes.opendrive import geometry as od

    for road in odr.roads:
        for sig in road.signals:
            p = od.st_to_world(road, np.array([sig.s]), np.array([sig.t]))[0]
            _, _, h = od.reference_pose(road, [sig.s])
            face = float(h[0]) + (0.0 if sig.orientation == "-" else math.pi)
            sub = {"1000001": "vehicle_signal", "206": "stop", "205": "yield", "274": "speed_limit"}[sig.type]
            match = [q for q in by[sub] if np.hypot(*(q[0] - p[:2])) < 1e-6]
            assert len(match) == 1, (road.id, sig.id)
            assert math.cos(match[0][1] - face) > 0.999  # +X faces the traffic it controls
            assert match[0][2] == pytest.approx(p[2] + 0.15, abs=0.02)  # on the raised sidewalk


def test_crossroads_deterministic(crossroads, lib):
    odr, town, _ = crossroads
    again, _ = build(odr, lib, source=town.source, assets=list(reversed(lib.assets)))
    assert again.placements == town.placements and again.bounds == town.bounds
    other, _ = build(odr, lib, seed=12, source=town.source)
    assert other.placements != town.placements
    assert [r.asset_id for r in other.placements[: len(other.stuff)]] == [r.asset_id for r in town.placements[: len(town.stuff)]]


# ---------------------------------------------------------------------------- CARLA towns


@needs(DATA)
# Town10HD: 149 lanes in its main circuit plus a separate 783 m circuit of 16 (every lane on a
# cycle is kept, not only the largest strongly connected component)
@pytest.mark.parametrize("name, lanes, min_signals", [("Town01", 124, 30), ("Town10HD", 149 + 16, 15)])
def test_carla_towns_build(lib, extents, name, lanes, min_signals):
    odr = read_opendrive(DATA / f"{name}.xodr")
    town, stats = build(odr, lib, index=3, source=str(DATA / f"{name}.xodr"))
    check_network(town.network)
    assert town.name == "town03" and len(town.network.lanes) == lanes
    assert stats["link_mismatches"] == 0 and stats["link_missing"] == 0
    assert stats["signals_placed"] >= min_signals and stats["buildings"] > 20 and stats["vegetation"] > 100
    total = sum(r.length for r in odr.roads if r.junction == "-1")
    assert town.network.road_length == pytest.approx(total, rel=0.05)
    assert len([w for w in town.network.walkways if w.crosswalk]) > 10
    check_placements(town, extents)
