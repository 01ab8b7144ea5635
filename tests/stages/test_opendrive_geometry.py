"""OpenDRIVE geometry evaluator: hand-computable cases and the real CARLA towns."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.special import fresnel

from carlaocc.schemas.opendrive import Geometry, LaneRecord, LaneSection, Poly3Record, Road, RoadMark
from carlaocc.stages.scenes.opendrive import geometry as od
from shared_data import needs, shared_path

DATA = shared_path("opendrive")
needs_data = needs(DATA)


def geom(kind="line", s=0.0, x=0.0, y=0.0, hdg=0.0, length=10.0, **kw):
    return Geometry(kind=kind, s=s, x=x, y=y, hdg=hdg, length=length, **kw)


def poly(s=0.0, a=0.0, b=0.0, c=0.0, d=0.0):
    return Poly3Record(s=s, a=a, b=b, c=c, d=d)


def lane(lane_id, widths, lane_type="driving", marks=()):
    return LaneRecord(id=lane_id, type=lane_type, widths=tuple(widths), road_marks=tuple(marks))


def mark(mark_type, color, width):
    return RoadMark(s_offset=0.0, type=mark_type, color=color, width=width)


def road(geoms, length, left=(), right=(), offsets=(), elev=(), sup=(), center=None, sections=None):
    if sections is None:
        sections = (LaneSection(s=0.0, left=tuple(left), right=tuple(right), center=(center or lane(0, (), "none"),)),)
    return Road(id="1", name="", length=length, junction="-1", geometries=tuple(geoms), elevations=tuple(elev),
                superelevations=tuple(sup), lane_offsets=tuple(offsets), lane_sections=tuple(sections))  # fmt: skip


def fine_integral(theta, x0, y0, L, n=2_000_001):
    """Reference: cumulative trapezoid of (cos, sin)(theta) on a very fine grid."""
    u = np.linspace(0.0, L, n)
    th = theta(u)
    du = u[1] - u[0]
    return x0 + np.trapezoid(np.cos(th), dx=du), y0 + np.trapezoid(np.sin(th), dx=du)


# ----------------------------------------------------------------------------- planView


def test_line_heading_30_degrees():
    h = math.radians(30)
    x, y, hd = od.evaluate_geometry(geom("line", x=1, y=2, hdg=h, length=10), [0, 10])
    assert x == pytest.approx([1, 1 + 10 * math.cos(h)]) and y == pytest.approx([2, 2 + 5])
    assert hd == pytest.approx([h, h])


def test_arc_quarter_and_half_circle():
    # curvature 0.1 = radius 10: s = 5 pi is a quarter circle, s = 10 pi a half circle
    g = geom("arc", x=3, y=4, hdg=0, length=math.pi * 10, curvature=0.1)
    x, y, h = od.evaluate_geometry(g, [0, math.pi * 5, math.pi * 10])
    assert x == pytest.approx([3, 13, 3], abs=1e-9)
    assert y == pytest.approx([4, 14, 24], abs=1e-9)
    assert h == pytest.approx([0, math.pi / 2, math.pi])
    # negative curvature turns right
    x, y, _ = od.evaluate_geometry(geom("arc", length=math.pi * 10, curvature=-0.1), [math.pi * 10])
    assert (x[0], y[0]) == pytest.approx((0, -20), abs=1e-9)


def test_spiral_matches_fresnel_and_fine_integration():
    L, k1, h0 = 50.0, 0.02, 0.3
    g = geom("spiral", x=1, y=2, hdg=h0, length=L, curv_start=0.0, curv_end=k1)
    ds = np.array([0.0, 7.3, 25.0, 50.0])
    x, y, h = od.evaluate_geometry(g, ds)
    rate = k1 / L
    scale = math.sqrt(math.pi / rate)
    S, C = fresnel(ds / scale)
    xl, yl = scale * C, scale * S
    assert np.abs(x - (1 + xl * math.cos(h0) - yl * math.sin(h0))).max() < 1e-6
    assert np.abs(y - (2 + xl * math.sin(h0) + yl * math.cos(h0))).max() < 1e-6
    xr, yr = fine_integral(lambda u: h0 + 0.5 * rate * u * u, 1, 2, L)
    assert math.hypot(x[-1] - xr, y[-1] - yr) < 1e-3
    assert h[-1] == pytest.approx(h0 + 0.5 * k1 * L)


def test_spiral_with_nonzero_start_curvature():
    L, k0, k1 = 40.0, -0.05, 0.03
    g = geom("spiral", hdg=-1.0, length=L, curv_start=k0, curv_end=k1)
    x, y, h = od.evaluate_geometry(g, [L])
    rate = (k1 - k0) / L
    xr, yr = fine_integral(lambda u: -1.0 + k0 * u + 0.5 * rate * u * u, 0, 0, L)
    assert math.hypot(x[0] - xr, y[0] - yr) < 1e-3
    assert h[0] == pytest.approx(-1.0 + (k0 + k1) / 2 * L)


def test_poly3_endpoint_by_arc_length():
    c, L, h0 = 0.01, 10.0, math.radians(45)
    g = geom("poly3", x=5, y=-5, hdg=h0, length=L, a=0.5, b=0.0, c=c, d=0.0)
    u_end = brentq(lambda u: quad(lambda t: math.sqrt(1 + (2 * c * t) ** 2), 0, u)[0] - L, 0, L)
    v_end = 0.5 + c * u_end**2
    x, y, h = od.evaluate_geometry(g, [0, L])
    ex = 5 + u_end * math.cos(h0) - v_end * math.sin(h0)
    ey = -5 + u_end * math.sin(h0) + v_end * math.cos(h0)
    assert (x[-1], y[-1]) == pytest.approx((ex, ey), abs=1e-4)
    assert (x[0], y[0]) == pytest.approx((5 - 0.5 * math.sin(h0), -5 + 0.5 * math.cos(h0)))
    assert h[-1] == pytest.approx(h0 + math.atan(2 * c * u_end))


@pytest.mark.parametrize("p_range", ["normalized", "arcLength"])
def test_param_poly3_endpoints(p_range):
    # u(p) = 20 q, v(p) = 5 q^2 - 2 q^3 with q = p / p_end: the same curve for both ranges
    length = quad(lambda q: math.hypot(20, 10 * q - 6 * q * q), 0, 1)[0]
    p_end = 1.0 if p_range == "normalized" else length
    k = 1 / p_end
    g = geom("paramPoly3", x=100, y=50, hdg=math.pi / 2, length=length, p_range=p_range,
             bu=20 * k, cv=5 * k**2, dv=-2 * k**3)  # fmt: skip
    x, y, h = od.evaluate_geometry(g, [0, length / 2, length])
    # heading pi/2: local u -> world +y, local v -> world -x
    assert (x[-1], y[-1]) == pytest.approx((100 - 3, 50 + 20), abs=1e-6)
    assert (x[0], y[0]) == pytest.approx((100, 50))
    assert h[-1] == pytest.approx(math.pi / 2 + math.atan2(4, 20))
    # the midpoint is at half the arc length along the curve
    q = brentq(lambda q: quad(lambda t: math.hypot(20, 10 * t - 6 * t * t), 0, q)[0] - length / 2, 0, 1)
    assert (x[1], y[1]) == pytest.approx((100 - (5 * q**2 - 2 * q**3), 50 + 20 * q), abs=1e-5)


def test_reference_line_samples_each_geometry_exactly():
    g1 = geom("line", length=10)
    g2 = geom("arc", s=10, x=10, length=math.pi * 5, curvature=0.1)
    r = road([g1, g2], 10 + math.pi * 5)
    s, x, y, h = od.reference_line(r, step=0.5)
    assert s[0] == 0 and s[-1] == pytest.approx(r.length) and 10.0 in s
    assert np.all(np.diff(s) <= 0.5 + 1e-9) and np.all(np.diff(s) > 0)
    assert (x[-1], y[-1]) == pytest.approx((20, 10), abs=1e-9)  # quarter circle of radius 10
    assert h[-1] == pytest.approx(math.pi / 2)
    assert np.all(np.hypot(np.diff(x), np.diff(y)) <= 0.5 + 1e-9)


def test_elevation_and_superelevation_profiles():
    r = road([geom(length=100)], 100, elev=[poly(0, 1, 0.1), poly(50, 6, 0, 0.01)], sup=[poly(0, 0.02)])
    assert od.elevation(r, [0, 10, 50, 60]) == pytest.approx([1, 2, 6, 7])
    assert od.superelevation(r, [0, 99]) == pytest.approx([0.02, 0.02])
    p = od.st_to_world(r, np.array([10.0]), np.array([-3.0]))[0]
    assert p == pytest.approx([10, -3 * math.cos(0.02), 2 - 3 * math.sin(0.02)])


# ----------------------------------------------------------------------------- lanes


def _by_id(strips):
    return {st.lane_id: st for st in strips}


def test_lane_boundaries_polynomial_widths():
    r = road([geom(length=20)], 20,
             left=[lane(1, [poly(0, 3.0)]), lane(2, [poly(0, 1.0, 0.1)])],
             right=[lane(-1, [poly(0, 3.5, 0.0, 0.01)]), lane(-2, [poly(0, 2.0), poly(10, 2.0, -0.1)], "sidewalk")])  # fmt: skip
    s = np.array([0.0, 5.0, 10.0, 20.0])
    b = _by_id(od.lane_boundaries(r, s))
    assert b[1].t_inner == pytest.approx([0, 0, 0, 0]) and b[1].t_outer == pytest.approx([3, 3, 3, 3])
    assert b[2].t_inner == pytest.approx([3, 3, 3, 3]) and b[2].t_outer == pytest.approx(3 + 1 + 0.1 * s)
    w1 = 3.5 + 0.01 * s**2
    assert b[-1].t_inner == pytest.approx(0 * s) and b[-1].t_outer == pytest.approx(-w1)
    w2 = np.array([2.0, 2.0, 2.0, 1.0])
    assert b[-2].t_inner == pytest.approx(-w1) and b[-2].t_outer == pytest.approx(-w1 - w2)


def test_lane_offset_shifts_everything_and_sections_split():
    sec0 = LaneSection(s=0.0, left=(lane(1, [poly(0, 3.0)]),), right=(lane(-1, [poly(0, 3.0)]),), center=(lane(0, (), "none"),))
    sec1 = LaneSection(s=10.0, left=(), right=(lane(-1, [poly(0, 2.0, 0.1)]),), center=(lane(0, (), "none"),))
    r = road([geom(length=20)], 20, offsets=[poly(0, 1.5), poly(10, 1.5, 0.05)], sections=[sec0, sec1])
    strips = od.lane_boundaries(r, np.array([0.0, 5.0, 10.0, 20.0]))
    first = {st.lane_id: st for st in strips if st.section == 0}
    second = {st.lane_id: st for st in strips if st.section == 1}
    assert first[1].t_inner == pytest.approx([1.5, 1.5]) and first[1].t_outer == pytest.approx([4.5, 4.5])
    assert first[-1].t_outer == pytest.approx([-1.5, -1.5])
    assert list(second) == [-1] and second[-1].s == pytest.approx([10, 20])
    assert second[-1].t_inner == pytest.approx([1.5, 2.0]) and second[-1].t_outer == pytest.approx([-0.5, -1.0])


def test_straight_road_surface_area_and_normals():
    r = road([geom(hdg=0.7, x=3, y=4, length=40)], 40,
             left=[lane(1, [poly(0, 3.0)]), lane(2, [poly(0, 2.0)], "sidewalk")],
             right=[lane(-1, [poly(0, 3.5)]), lane(-2, [poly(0, 0.5)], "shoulder"), lane(-3, [poly(0, 1.0)], "none")],
             elev=[poly(0, 2.0)])  # fmt: skip
    meshes = od.road_surface_meshes(r, step=1.0)
    assert set(meshes) == {"driving", "sidewalk", "shoulder"}
    assert od.mesh_area(*meshes["driving"]) == pytest.approx(40 * 6.5)
    assert od.mesh_area(*meshes["sidewalk"]) == pytest.approx(40 * 2.0)
    assert od.mesh_area(*meshes["shoulder"]) == pytest.approx(40 * 0.5)
    for v, f in meshes.values():
        assert v.shape[1] == 3 and f.shape[1] == 3 and f.max() < len(v)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        assert np.all(n[:, 2] > 0)
        assert v[:, 2] == pytest.approx(np.full(len(v), 2.0))


def test_curved_superelevated_surface_normals_up_and_zero_width_dropped():
    g = geom("arc", length=30, curvature=-0.05)
    r = road([g], 30, left=[lane(1, [poly(0, 3.0)])],
             right=[lane(-1, [poly(0, 3.0)]), lane(-2, [poly(0, 0.0)], "sidewalk")], sup=[poly(0, 0.05)])  # fmt: skip
    meshes = od.road_surface_meshes(r, step=0.5)
    assert "sidewalk" not in meshes
    v, f = meshes["driving"]
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(n[:, 2] > 0)
    assert od.mesh_area(v, f) == pytest.approx(30 * 6, rel=2e-3)  # sloped cross-section keeps its width
    assert v[:, 2].min() < -0.1 and v[:, 2].max() > 0.1  # superelevation tilts the cross section


def test_road_marks_solid_and_broken():
    center = lane(0, (), "none", marks=[mark("solid", "yellow", 0.2)])
    right = [lane(-1, [poly(0, 3.0)], marks=[mark("broken", "white", 0.1)]),
             lane(-2, [poly(0, 3.0)], marks=[mark("none", "white", None)])]  # fmt: skip
    r = road([geom(length=30)], 30, right=right, center=center)
    marks = od.road_marks(r, step=1.0)
    solid = [m for m in marks if m["lane_id"] == 0]
    broken = [m for m in marks if m["lane_id"] == -1]
    assert not [m for m in marks if m["lane_id"] == -2]
    assert len(solid) == 1 and od.mesh_area(solid[0]["vertices"], solid[0]["faces"]) == pytest.approx(30 * 0.2)
    assert len(broken) == 3  # dashes at 0-3, 12-15, 24-27
    assert sum(od.mesh_area(m["vertices"], m["faces"]) for m in broken) == pytest.approx(9 * 0.1)
    ys = np.concatenate([m["vertices"][:, 1] for m in broken])
    assert ys.min() == pytest.approx(-3.05) and ys.max() == pytest.approx(-2.95)


def test_surface_kinds():
    assert od.surface_kind("driving") == od.surface_kind("onRamp") == od.surface_kind("parking") == "driving"
    assert od.surface_kind("sidewalk") == "sidewalk" and od.surface_kind("none") is None
    assert od.surface_kind("shoulder") == "shoulder" and od.surface_kind("weird") == "other"


# ----------------------------------------------------------------------------- real towns


@needs_data
@pytest.mark.parametrize("name", ["Town01", "Town02", "Town10HD", "Issue274", "shoulders", "zero_width"])
def test_real_reference_lines_are_continuous(name):
    from carlaocc.catalog.opendrive import read_opendrive

    net = read_opendrive(DATA / f"{name}.xodr")
    for r in net.roads:
        gs = r.geometries
        for a, b in zip(gs[:-1], gs[1:]):
            x, y, h = od.evaluate_geometry(a, [a.length])
            assert math.hypot(x[0] - b.x, y[0] - b.y) < 0.01, (name, r.id, b.s)
        s, x, y, h = od.reference_line(r, step=1.0)
        assert np.all(np.diff(s) > 0) and np.all(np.hypot(np.diff(x), np.diff(y)) < 1.0 + 0.01)


@needs_data
def test_town01_surface_has_plausible_extent():
    # its build time is measured by benchmarks/bench_scenes.py
    from carlaocc.catalog.opendrive import read_opendrive

    net = read_opendrive(DATA / "Town01.xodr")
    parts = [od.road_surface_meshes(r, step=0.5) for r in net.roads]
    driving = [m["driving"] for m in parts if "driving" in m]
    assert len(driving) == 122 - sum("driving" not in m for m in parts)
    v = np.concatenate([d[0] for d in driving])
    f = np.concatenate([d[1] for d in driving])
    extent = v.max(0) - v.min(0)
    assert 200 < extent[0] < 1000 and 200 < extent[1] < 1000 and extent[2] < 5
    assert np.all(v[:, 0] > net.header.west - 20) and np.all(v[:, 0] < net.header.east + 20)
    assert np.all(v[:, 1] > net.header.south - 20) and np.all(v[:, 1] < net.header.north + 20)
    area = sum(od.mesh_area(*d) for d in driving)
    assert 10_000 < area < 60_000 and len(f) > 10_000
    for vv, ff in driving:
        n = np.cross(vv[ff[:, 1]] - vv[ff[:, 0]], vv[ff[:, 2]] - vv[ff[:, 0]])
        assert np.all(n[:, 2] > 0)


def test_surface_normals_tilt_with_grade_and_superelevation():
    # a straight road heading 30 degrees, rising 10 % and banked by 0.1 rad (falling to the right)
    h = math.radians(30.0)
    r = road([geom(hdg=h, length=100.0)], 100.0, right=[lane(-1, [poly(a=3.5)])], elev=[poly(b=0.1)],
             sup=[poly(a=0.1)])  # fmt: skip
    s = np.array([0.0, 20.0, 50.0, 100.0])
    n = od.surface_normal(r, s, np.full(4, -1.75))
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    # perpendicular to both surface directions: along the road (up the grade) and across it
    along = np.array([np.cos(h), np.sin(h), 0.1])
    across = np.array([-np.cos(0.1) * np.sin(h), np.cos(0.1) * np.cos(h), np.sin(0.1)])
    np.testing.assert_allclose(n @ along, 0.0, atol=1e-9)
    np.testing.assert_allclose(n @ across, 0.0, atol=1e-9)
    assert (n[:, 2] > 0).all()
    # a level road is exactly up
    flat = road([geom(hdg=h, length=10.0)], 10.0, right=[lane(-1, [poly(a=3.5)])])
    assert np.array_equal(od.surface_normal(flat, np.array([0.0, 5.0]), np.array([-1.0, -2.0]))[:, 2], [1.0, 1.0])
