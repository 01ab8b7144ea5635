"""Our OpenDRIVE road surfaces against CARLA's own OpenDRIVE parser (the ``carla`` wheel, test extra).

CARLA parses a ``.xodr`` without a simulator (``carla.Map(name, text)``); its locations are in
Unreal's left-handed frame: (x, -y, z) of OpenDRIVE's. Figures, per map (issue 38's "Done when"):

* ``waypoints``: CARLA's driving-lane waypoints every 2 m and both their lane edges, the share
  within 0.1 m (3D) of our Road/RoadLine surface. CARLA ignores ``<superelevation>`` (its
  waypoints and roll stay level, see :func:`test_carla_ignores_superelevation`), so a point's
  height is compared after adding the bank CARLA leaves out, ``t sin(phi)`` with ``t`` CARLA's own
  lateral offset of the point from the road's reference line; ``waypoints_raw`` without it.
* ``inside``: 20,000 points sampled uniformly (by area) on our Road and RoadLine meshes that lie in
  some CARLA lane: CARLA's ``get_waypoint(project_to_road=False, lane_type=Any)`` finds one, or the
  point lies in one of CARLA's lane cross-section cells (:func:`lane_cells`: every lane of the
  cross sections of CARLA's driving waypoints every 0.25 m, its centre, direction and width from
  CARLA's API) (``inside_raw``: ``get_waypoint`` alone; it only tests
  the lane whose centre line is nearest, so a point in a wide lane nearer the centre of a narrow
  shoulder beside it is reported outside every lane, :func:`test_get_waypoint_nearest_centre_only`).
* ``widths``: CARLA's lane width against ours at each waypoint's (road, lane, s): the share within 0.05 m.
* ``solid_marks_drawn``: of the waypoint lane edges CARLA reports a solid (or double) line on,
  the share within 0.1 m of our RoadLine meshes.

The shared CARLA towns are slow (tens of seconds: ``-m slow``); the fast twins run the same
check on the small shared maps and on ``tools/make_rural.py``'s map (15 % climb, banked arc,
laneOffset, width records with sOffset and cubic terms, shoulder, border and none lanes).
Run ``pytest -s tests/stages/test_opendrive_carla.py`` to print the figures.
"""

from __future__ import annotations

import importlib.util
import math
import os
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from carlaocc.catalog.opendrive import parse_opendrive
from carlaocc.stages.scenes.opendrive import geometry as od
from carlaocc.stages.scenes.opendrive import surfaces as su
from shared_data import needs, shared_path

carla = pytest.importorskip("carla") if not os.environ.get("CI") else __import__("carla")

DATA = shared_path("opendrive")
REPO = Path(__file__).resolve().parents[2]
ROAD_MESHES = {name for name, (_mesh, cls, _mat) in su.SURFACE_MESHES.items() for name in [_mesh] if cls == "Road"}


def rural_xodr() -> str:
    spec = importlib.util.spec_from_file_location("make_rural", REPO / "tools" / "make_rural.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.rural_xodr()


def merged(parts):
    V = np.concatenate([p[0] for p in parts])
    off = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    return V, np.concatenate([p[1] + o for p, o in zip(parts, off)])


def road_and_roadline(odr):
    """Our Road-class meshes (driving, junction, shoulder, bike lanes, junction fill) and the road marks."""
    meshes, _ = su.lane_surfaces(odr, 0.15)
    parts = [m for name, lst in meshes.items() if name in ROAD_MESHES for m in lst]
    parts += su.junction_fill(odr, None, None) + su.road_mark_meshes(odr)
    return merged(parts)


def surface_distance(V, F, P, k=24):
    """Distance (m) of each point to the nearest of the ``k`` triangles with the nearest centroids
    (triangles are <= 0.5 m long: the nearest one is always among them for points near the surface)."""
    tri = V[F]
    _, idx = cKDTree(tri.mean(axis=1)).query(P, k=k)
    Q = np.repeat(P, k, axis=0)
    c = trimesh.triangles.closest_point(tri[idx.ravel()], Q)
    return np.linalg.norm(c - Q, axis=1).reshape(len(P), k).min(axis=1)


def sample_surface(V, F, n, rng):
    """``n`` points uniform by area on the triangles."""
    tri = V[F]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    i = rng.choice(len(F), n, p=area / area.sum())
    r = rng.random((n, 2))
    flip = r.sum(axis=1) > 1
    r[flip] = 1 - r[flip]
    t = tri[i]
    return t[:, 0] + r[:, :1] * (t[:, 1] - t[:, 0]) + r[:, 1:] * (t[:, 2] - t[:, 0])


def loc(p):
    return carla.Location(float(p[0]), float(-p[1]), float(p[2]))


def crosscheck(text: str, n_inside: int = 20_000, seed: int = 0) -> dict:
    """The figures of the module docstring for one map."""
    odr = parse_opendrive(text)
    cmap = carla.Map("crosscheck", text)
    V, F = road_and_roadline(odr)
    wps = [w for w in cmap.generate_waypoints(2.0) if w.lane_type == carla.LaneType.Driving]
    pts, bank, marks = [], [], []
    widths = []
    for w in wps:
        road = odr.road(w.road_id)
        phi = poly_at(road.superelevations, w.s)
        c, r, hw = w.transform.location, w.transform.get_right_vector(), w.lane_width / 2
        t_centre = carla_t(w, road)
        for side, p in ((0.0, (c.x, -c.y, c.z)),
                        (+1.0, (c.x + r.x * hw, -(c.y + r.y * hw), c.z)),
                        (-1.0, (c.x - r.x * hw, -(c.y - r.y * hw), c.z))):  # fmt: skip
            # right vector (Unreal) points to the driving direction's right: for right lanes
            # (driving along +s) that is -t, for left lanes +t
            dt = side * hw * (-1.0 if w.lane_id < 0 else 1.0)
            pts.append(p)
            bank.append((t_centre + dt) * math.sin(phi))
            mark = w.right_lane_marking if side > 0 else w.left_lane_marking if side < 0 else None
            marks.append("" if mark is None else str(mark.type))
        ours = [st for st in od.lane_boundaries(road, [w.s]) if st.lane_id == w.lane_id]
        widths.append(abs(ours[0].t_outer[0] - ours[0].t_inner[0]) - w.lane_width if ours else np.inf)
    P, dz = np.array(pts), np.array(bank)
    raw = surface_distance(V, F, P)
    banked = surface_distance(V, F, P + np.column_stack([np.zeros((len(P), 2)), dz]))
    # 4. road marks: CARLA's solid lines at the lane edges it reports them on, on our RoadLine
    solid = np.isin(np.array(marks), ["Solid", "SolidSolid", "SolidBroken", "BrokenSolid"])
    near_mark = np.zeros(0)
    if solid.any():
        VM, FM = merged(su.road_mark_meshes(odr))
        near_mark = surface_distance(VM, FM, P[solid] + np.column_stack([np.zeros((solid.sum(), 2)), dz[solid]]), k=8)
    rng = np.random.default_rng(seed)
    S = sample_surface(V, F, n_inside, rng)
    found_raw = np.array([cmap.get_waypoint(loc(p), project_to_road=False, lane_type=carla.LaneType.Any) is not None
                          for p in S])  # fmt: skip
    found = found_raw | inside_lanes(lane_cells(cmap), S)
    widths = np.abs(np.array(widths))
    return {
        "waypoints": len(wps),
        "waypoints_raw": float(np.mean(raw <= 0.1)),
        "waypoints_on_road": float(np.mean(banked <= 0.1)),
        "max_waypoint_distance": float(banked.max()),
        "inside_raw": float(found_raw.mean()),
        "inside": float(found.mean()),
        "widths": float(np.mean(widths <= 0.05)),
        "solid_marks": int(solid.sum()),
        "solid_marks_drawn": float(np.mean(near_mark <= 0.1)) if solid.any() else 1.0,
        "max_width_error": float(widths.max()),
    }


def poly_at(records, s: float) -> float:
    """Independent evaluation of OpenDRIVE cubic records (laneOffset, superelevation) at road-absolute s."""
    val = 0.0
    for r in records:
        if r.s <= s + 1e-9:
            ds = s - r.s
            val = r.a + r.b * ds + r.c * ds * ds + r.d * ds**3
    return val


def carla_t(w, road) -> float:
    """Lateral offset (m, +left of the road's +s) of a waypoint's lane centre from the road's
    reference line: the laneOffset plus, from CARLA's lane chain at the same s, the widths of the
    lanes between it and the centre lane and half its own."""
    t, cur = w.lane_width / 2, w
    while True:
        inner = [n for n in (cur.get_left_lane(), cur.get_right_lane())
                 if n is not None and n.lane_id * w.lane_id > 0 and abs(n.lane_id) < abs(cur.lane_id)]  # fmt: skip
        if not inner:
            break
        cur = inner[0]
        t += cur.lane_width
    return poly_at(road.lane_offsets, w.s) + math.copysign(t, w.lane_id)


def lane_cells(cmap, step: float = 0.25):
    """CARLA's lanes as cross-section cells: for every driving waypoint every ``step`` m and all
    its lateral neighbours (any lane type, both ways), the lane centre (x, y) in OpenDRIVE's
    frame, the unit forward direction (x, y) and half the lane width, from CARLA's own API."""
    centre, forward, half, seen = [], [], [], set()
    for w in cmap.generate_waypoints(step):
        todo = [w]
        while todo:  # the whole cross section at this s: neighbours of neighbours, any type
            c = todo.pop()
            key = (c.road_id, c.section_id, c.lane_id, round(c.s, 3))
            if key in seen:
                continue
            seen.add(key)
            if c.lane_width > 0:
                q, f = c.transform.location, c.transform.get_forward_vector()
                n = max(math.hypot(f.x, f.y), 1e-12)
                centre.append((q.x, -q.y))
                forward.append((f.x / n, -f.y / n))
                half.append(c.lane_width / 2)
            todo += [x for x in (c.get_left_lane(), c.get_right_lane()) if x is not None]
    return np.array(centre), np.array(forward), np.array(half)


def inside_lanes(cells, P, step: float = 0.25) -> np.ndarray:
    """Per point (x, y[, z]): inside some cell of :func:`lane_cells` -- within half a step along
    the lane (plus 5 cm) and within half the lane width across it."""
    centre, forward, half = cells
    reach = math.hypot(step / 2 + 0.05, float(half.max()))
    tree = cKDTree(centre)
    out = np.zeros(len(P), bool)
    for i, cand in enumerate(tree.query_ball_point(np.asarray(P)[:, :2], reach)):
        if not cand:
            continue
        d = np.asarray(P[i][:2]) - centre[cand]
        along = np.abs(np.sum(d * forward[cand], axis=1))
        across = np.abs(d[:, 0] * forward[cand][:, 1] - d[:, 1] * forward[cand][:, 0])
        out[i] = bool(np.any((along <= step / 2 + 0.05) & (across <= half[cand])))
    return out


def report(name: str, fig: dict) -> None:
    print(f"\n{name}: " + ", ".join(f"{k} {v:.4f}" if isinstance(v, float) else f"{k} {v}" for k, v in fig.items()))


def check(fig: dict) -> None:
    assert fig["waypoints_on_road"] >= 0.995, fig
    assert fig["inside"] >= 0.97, fig
    assert fig["widths"] >= 0.99, fig
    assert fig["solid_marks_drawn"] >= 0.99, fig


def test_rural_map_against_carla():
    fig = crosscheck(rural_xodr(), n_inside=5_000)
    report("rural", fig)
    check(fig)
    assert fig["waypoints"] > 300


@needs(DATA)
@pytest.mark.parametrize("name", ["shoulders.xodr", "Issue274.xodr", "zero_width.xodr"])
def test_small_shared_maps_against_carla(name):
    fig = crosscheck((DATA / name).read_text(), n_inside=2_000)
    report(name, fig)
    check(fig)


@pytest.mark.slow
@needs(DATA)
@pytest.mark.parametrize("name", ["Town01.xodr", "Town02.xodr", "Town10HD.xodr"])
def test_carla_towns_against_carla(name):
    fig = crosscheck((DATA / name).read_text())
    report(name, fig)
    check(fig)


def test_carla_ignores_superelevation():
    """Why the height comparison adds the bank back: on the rural map's banked arc (phi = -0.08 rad
    at s = 150 m) CARLA's lane centres on both sides sit at the reference line's elevation with
    zero roll, where OpenDRIVE's cross section (and ours) is tilted by ``t sin(phi)``."""
    text = rural_xodr()
    odr, cmap = parse_opendrive(text), carla.Map("bank", text)
    road = odr.road("1")
    assert poly_at(road.superelevations, 150.0) == pytest.approx(-0.08)
    z_ref = poly_at(road.elevations, 150.0)
    seen = 0
    for w in cmap.generate_waypoints(1.0):
        if abs(w.s - 150.0) < 0.5 and w.lane_type == carla.LaneType.Driving:
            assert w.transform.location.z == pytest.approx(z_ref, abs=1e-3)  # the crest is level from 120 to 160 m
            assert w.transform.rotation.roll == pytest.approx(0.0, abs=1e-6)
            t = carla_t(w, road)
            ours = od.st_to_world(road, np.array([w.s]), np.array([t]))[0]
            assert ours[2] - w.transform.location.z == pytest.approx(t * math.sin(-0.08), abs=2e-3)
            seen += 1
    assert seen >= 2


def test_get_waypoint_nearest_centre_only():
    """Why ``inside`` also uses CARLA's lane cells: a point inside a 4 m driving lane, 0.5 m from its outer
    edge, is nearer the centre of the 0.3 m shoulder beside it (0.65 m) than its own lane's (1.5 m);
    CARLA's ``get_waypoint(project_to_road=False)`` tests only that nearest lane and finds none."""
    text = ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="4" name="w"/>'
            '<road name="r" length="40" id="1" junction="-1"><planView><geometry s="0" x="0" y="0" hdg="0" '
            'length="40"><line/></geometry></planView><lanes><laneSection s="0"><center><lane id="0" type="none"/>'
            '</center><right><lane id="-1" type="driving" level="false"><width sOffset="0" a="4" b="0" c="0" d="0"/>'
            '</lane><lane id="-2" type="shoulder" level="false"><width sOffset="0" a="0.3" b="0" c="0" d="0"/>'
            "</lane></right></laneSection></lanes></road></OpenDRIVE>")  # fmt: skip
    cmap = carla.Map("narrow", text)
    p = (20.0, -3.5, 0.0)  # OpenDRIVE frame: t = -3.5, inside lane -1 (t in [-4, 0])
    assert cmap.get_waypoint(loc(p), project_to_road=False, lane_type=carla.LaneType.Any) is None
    assert cmap.get_waypoint(loc(p), project_to_road=True, lane_type=carla.LaneType.Any).lane_id == -2
    cells = lane_cells(cmap)
    assert inside_lanes(cells, [p, (20.0, -4.2, 0.0)]).all()
    assert not inside_lanes(cells, [(20.0, -4.4, 0.0), (20.0, 0.2, 0.0), (41.0, -1.0, 0.0)]).any()
    assert cmap.get_waypoint(loc((20.0, -1.0, 0.0)), project_to_road=False, lane_type=carla.LaneType.Any).lane_id == -1
