"""Generator of catalog/towns/crossroads.xodr, the builtin OpenDRIVE town (original work of carlaocc).

Usage: ``python tools/make_crossroads.py catalog/towns/crossroads.xodr``.
"""
import math, sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from carlaocc.schemas.opendrive import Geometry
from carlaocc.stages.scenes.opendrive.geometry import evaluate_geometry

W, SW = 3.5, 3.0  # lane, sidewalk width
PI = math.pi


def G(kind, length, **kw):
    base = dict(curvature=0.0, curv_start=0.0, curv_end=0.0, a=0.0, b=0.0, c=0.0, d=0.0, au=0.0, bu=0.0, cu=0.0,
                du=0.0, av=0.0, bv=0.0, cv=0.0, dv=0.0, p_range="normalized")
    base.update(kw)
    return dict(kind=kind, length=length, **base)


def chain(x, y, hdg, parts):
    """Give each geometry its start pose; return (geoms, end pose)."""
    out, s = [], 0.0
    for p in parts:
        g = dict(p, s=s, x=x, y=y, hdg=hdg)
        ex, ey, eh = evaluate_geometry(Geometry(**g), [p["length"]])
        x, y, hdg = float(ex[0]), float(ey[0]), float(eh[0])
        s += p["length"]
        out.append(g)
    return out, (x, y, hdg)


def turn(sign, R, Ls):
    """90-degree turn: spiral, arc, spiral (sign +1 left, -1 right)."""
    k = sign / R
    arc = (PI / 2 - Ls / R) * R
    return [G("spiral", Ls, curv_start=0.0, curv_end=k), G("arc", arc, curvature=k), G("spiral", Ls, curv_start=k, curv_end=0.0)]


def bezier_quarter(sign, r):
    """Left (sign +1) / right quarter circle of radius r as a normalized paramPoly3 (cubic Bezier)."""
    kk = 0.5522847498 * r
    P0, P1, P2, P3 = np.array([0, 0]), np.array([kk, 0]), np.array([r, sign * (r - kk)]), np.array([r, sign * r])
    a, b, c, d = P0, 3 * (P1 - P0), 3 * (P0 - 2 * P1 + P2), P3 - 3 * P2 + 3 * P1 - P0
    p = np.linspace(0, 1, 200001)
    du = b[0] + 2 * c[0] * p + 3 * d[0] * p * p
    dv = b[1] + 2 * c[1] * p + 3 * d[1] * p * p
    sp = np.hypot(du, dv)
    L = float(np.sum((sp[1:] + sp[:-1]) / 2 * np.diff(p)))
    return G("paramPoly3", L, au=a[0], bu=b[0], cu=c[0], du=d[0], av=a[1], bv=b[1], cv=c[1], dv=d[1], p_range="normalized")


def solve(x, y, hdg, build, target):
    """build(L2, L3) -> parts; L2, L3 enter linearly: solve so the end lands on target (x, y)."""
    _, e00 = chain(x, y, hdg, build(0.0, 0.0))
    _, e10 = chain(x, y, hdg, build(1.0, 0.0))
    _, e01 = chain(x, y, hdg, build(0.0, 1.0))
    A = np.array([[e10[0] - e00[0], e01[0] - e00[0]], [e10[1] - e00[1], e01[1] - e00[1]]])
    L = np.linalg.solve(A, np.array(target) - np.array(e00[:2]))
    geoms, end = chain(x, y, hdg, build(*L))
    assert math.hypot(end[0] - target[0], end[1] - target[1]) < 1e-6, end
    return geoms, end


# ------------------------------------------------------------------ arm roads
MAIN = 2
SIDE = 1
roads = {}  # id -> dict(geoms, n, elev, shoulder, sections, signals, pred, succ, name)

# R1: J1 east arm (10, 0) -> J2 west arm (100, 0); two lane sections
g, _ = chain(10.0, 0.0, 0.0, [G("line", 90.0)])
roads["1"] = dict(name="Main East", geoms=g, n=MAIN, sections=[0.0, 40.0])
# R2: J1 west arm (-10, 0) heading west -> J3 east arm (-100, 0)
g, _ = chain(-10.0, 0.0, PI, [G("line", 90.0)])
roads["2"] = dict(name="Main West", geoms=g, n=MAIN)
# R3: J1 north arm (0, 13) north, two right turns (spiral-arc-spiral), south into J2 north arm (110, 13)
g, end = solve(0.0, 13.0, PI / 2, lambda a, b: [G("line", 50.0), *turn(-1, 30.0, 15.0), G("line", a),
                                                 *turn(-1, 30.0, 15.0), G("line", b)], (110.0, 13.0))
roads["3"] = dict(name="North Loop", geoms=g, n=SIDE, shoulder=True)
# R4: J1 south arm (0, -13) south, two left turns (arcs), north into J2 south arm (110, -13); a 2 m hill
g, end = solve(0.0, -13.0, -PI / 2, lambda a, b: [G("line", 50.0), G("arc", 30.0 * PI / 2, curvature=1 / 30.0), G("line", a),
                                                  G("arc", 30.0 * PI / 2, curvature=1 / 30.0), G("line", b)], (110.0, -13.0))
roads["4"] = dict(name="South Hill", geoms=g, n=SIDE, hill=2.0)
# R5: J3 north arm (-110, 13) north, four left quarter turns (one a paramPoly3), back north into J3 south arm
R5 = 22.0
build5 = lambda b: [G("line", 20.0), bezier_quarter(+1, R5), G("line", 12.0),
                    G("arc", R5 * PI / 2, curvature=1 / R5), G("line", 70.0),
                    G("arc", R5 * PI / 2, curvature=1 / R5), G("line", 12.0),
                    G("arc", R5 * PI / 2, curvature=1 / R5), G("line", b)]
_, e0 = chain(-110.0, 13.0, PI / 2, build5(0.0))
g, end = chain(-110.0, 13.0, PI / 2, build5(-13.0 - e0[1]))
assert math.hypot(end[0] + 110.0, end[1] + 13.0) < 1e-3, end
assert abs(math.remainder(end[2] - PI / 2, 2 * PI)) < 1e-6, end
roads["5"] = dict(name="West Loop", geoms=g, n=SIDE)
for r in roads.values():
    r["length"] = sum(x["length"] for x in r["geoms"])

# ------------------------------------------------------------------ junctions and arms
# arm: (road, contact, junction)
arms = {
    "100": [("1", "start"), ("2", "start"), ("3", "start"), ("4", "start")],
    "200": [("1", "end"), ("3", "end"), ("4", "end")],
    "300": [("2", "end"), ("5", "start"), ("5", "end")],
}
names = {"100": "Crossroads", "200": "East T", "300": "West T"}
for jid, lst in arms.items():
    for rid, cp in lst:
        roads[rid]["pred" if cp == "start" else "succ"] = ("junction", jid, None)


def arm_pose(rid, cp):
    r = roads[rid]
    gs = r["geoms"]
    if cp == "start":
        g0 = gs[0]
        return np.array([g0["x"], g0["y"]]), g0["hdg"]
    gl = gs[-1]
    x, y, h = evaluate_geometry(Geometry(**gl), [gl["length"]])
    return np.array([x[0], y[0]]), float(h[0]) + PI


def left(h):
    return np.array([-math.sin(h), math.cos(h)])


connectors = []  # dicts
next_id = [500]
for jid, lst in arms.items():
    poses = {a: arm_pose(*a) for a in lst}
    for a in lst:
        Pa, ha = poses[a]
        na = roads[a[0]]["n"]
        for b in lst:
            if a == b:
                continue
            Pb, hb = poses[b]
            nb = roads[b[0]]["n"]
            h0 = ha + PI
            turn_ang = math.remainder(hb - h0, 2 * PI)
            kind = "straight" if abs(turn_ang) < 0.3 else ("left" if turn_ang > 0 else "right")
            # is the connector on the junction boundary (no arm on its right)?
            ang = lambda h: h % (2 * PI)
            span = (ang(hb) - ang(ha)) % (2 * PI)  # ccw from a's outward heading to b's
            others = [(ang(poses[c][1]) - ang(ha)) % (2 * PI) for c in lst if c not in (a, b)]
            boundary = not any(0 < o < span for o in others)
            if kind == "straight":
                pairs = [(k, min(k, nb)) for k in range(1, na + 1)]
            elif kind == "left":
                pairs = [(1, 1)]
            else:
                pairs = [(na, nb)]
            for ka, kb in pairs:
                A = Pa + left(ha) * (ka - 0.5) * W
                B = Pb - left(hb) * (kb - 0.5) * W
                d0, d1 = np.array([math.cos(h0), math.sin(h0)]), np.array([math.cos(hb), math.sin(hb)])
                if kind == "straight":
                    parts = [G("line", float(np.linalg.norm(B - A)))]
                else:
                    M = np.column_stack([d0, d1])
                    u, v = np.linalg.solve(M, B - A)  # A + u d0 + v d1 = B
                    r = min(u, v)
                    k = (1 if kind == "left" else -1) / r
                    parts = [G("line", u - r), G("arc", r * PI / 2, curvature=k), G("line", v - r)]
                    parts = [p for p in parts if p["length"] > 1e-9]
                geoms, end = chain(float(A[0]), float(A[1]), h0, parts)
                assert math.hypot(end[0] - B[0], end[1] - B[1]) < 1e-6, (jid, a, b, end, B)
                in_lane = ka if a[1] == "start" else -ka
                out_lane = -kb if b[1] == "start" else kb
                side_walk = boundary and ka == na and kb == nb
                cid = str(next_id[0]); next_id[0] += 1
                connectors.append(dict(id=cid, jid=jid, geoms=geoms, length=sum(p["length"] for p in parts),
                                       a=a, b=b, in_lane=in_lane, out_lane=out_lane, sidewalk=side_walk,
                                       sw_in=(na + 1) * (1 if a[1] == "start" else -1),
                                       sw_out=(nb + 1) * (-1 if b[1] == "start" else 1)))

# ------------------------------------------------------------------ signals
def arm_signals():
    sig = {}
    def add(rid, cp, type_, name, subtype="-1", value=-1, dynamic=True):
        r = roads[rid]
        t_abs = r["n"] * W + 1.2
        if cp == "start":
            s, t, o = 1.5, t_abs, "-"
        else:
            s, t, o = r["length"] - 1.5, -t_abs, "+"
        sig.setdefault(rid, []).append(dict(s=s, t=t, orientation=o, type=type_, subtype=subtype, value=value,
                                            dynamic="yes" if dynamic else "no", name=name))
    for rid, cp in arms["100"]:
        add(rid, cp, "1000001", "Signal_3Light")
    add("3", "end", "206", "Sign_Stop", dynamic=False)
    add("4", "end", "205", "Sign_Yield", dynamic=False)
    add("5", "start", "206", "Sign_Stop", dynamic=False)
    add("5", "end", "206", "Sign_Stop", dynamic=False)
    # speed limits mid-road, right-hand side of +s traffic
    for rid, v in (("1", 50), ("4", 30)):
        r = roads[rid]
        sig.setdefault(rid, []).append(dict(s=r["length"] / 2, t=-(r["n"] * W + 1.2), orientation="+", type="274",
                                            subtype="-1", value=v, dynamic="no", name="Sign_SpeedLimit"))
    return sig

signals = arm_signals()

# ------------------------------------------------------------------ XML
def f(v):
    return repr(float(v)) if not isinstance(v, str) else v

def geom_xml(g):
    head = f'<geometry s="{f(g["s"])}" x="{f(g["x"])}" y="{f(g["y"])}" hdg="{f(g["hdg"])}" length="{f(g["length"])}">'
    k = g["kind"]
    if k == "line":
        body = "<line/>"
    elif k == "arc":
        body = f'<arc curvature="{f(g["curvature"])}"/>'
    elif k == "spiral":
        body = f'<spiral curvStart="{f(g["curv_start"])}" curvEnd="{f(g["curv_end"])}"/>'
    else:
        body = ('<paramPoly3 aU="{au}" bU="{bu}" cU="{cu}" dU="{du}" aV="{av}" bV="{bv}" cV="{cv}" dV="{dv}" pRange="normalized"/>'
                .format(**{k2: f(g[k2]) for k2 in ("au", "bu", "cu", "du", "av", "bv", "cv", "dv")}))
    return f"        {head}{body}</geometry>"

def mark(type_, color="standard", width=0.15):
    if type_ == "none":
        return '<roadMark sOffset="0.0" type="none" weight="standard" color="standard" width="0.0"/>'
    return f'<roadMark sOffset="0.0" type="{type_}" weight="standard" color="{color}" material="standard" width="{width}" laneChange="{"both" if type_ == "broken" else "none"}"/>'

def lane_xml(lid, type_, widths, rm, link=None):
    ln = f'            <lane id="{lid}" type="{type_}" level="false">'
    if link:
        p, s_ = link
        ln += "<link>" + (f'<predecessor id="{p}"/>' if p is not None else "") + (f'<successor id="{s_}"/>' if s_ is not None else "") + "</link>"
    for so, a, b in widths:
        ln += f'<width sOffset="{f(so)}" a="{f(a)}" b="{f(b)}" c="0.0" d="0.0"/>'
    ln += rm + "</lane>"
    return ln

def arm_section(r, s0, s1, links=False):
    n = r["n"]
    out = []
    L = s1 - s0
    for side, sign in (("left", 1), ("right", -1)):
        lanes = []
        for k in range(1, n + 1):
            rm = mark("broken") if k < n else mark("solid")
            lanes.append(lane_xml(sign * k, "driving", [(0.0, W, 0.0)], rm, (sign * k, sign * k) if links else None))
        k = n + 1
        if r.get("shoulder") and side == "right":
            ramp = 20.0
            lanes.append(lane_xml(sign * k, "shoulder", [(0.0, 0.0, 1.5 / ramp), (ramp, 1.5, 0.0), (L - ramp, 1.5, -1.5 / ramp)], mark("none")))
            k += 1
        lanes.append(lane_xml(sign * k, "sidewalk", [(0.0, SW, 0.0)], mark("none"), (sign * k, sign * k) if links else None))
        if side == "right":
            lanes.sort(key=lambda x: 0)  # inner to outer already
        out.append(f"          <{side}>\n" + "\n".join(lanes) + f"\n          </{side}>")
    centre = "solid solid" if n == MAIN else "broken"
    color = "yellow" if n == MAIN else "standard"
    c = f'          <center>\n            <lane id="0" type="none" level="false">{mark(centre, color)}</lane>\n          </center>'
    return f'        <laneSection s="{f(s0)}">\n{out[0]}\n{c}\n{out[1]}\n        </laneSection>'

def link_xml(pred, succ):
    def one(tag, v):
        if v is None:
            return ""
        et, eid, cp = v
        return f'<{tag} elementType="{et}" elementId="{eid}"' + (f' contactPoint="{cp}"' if cp else "") + "/>"
    return f"      <link>{one('predecessor', pred)}{one('successor', succ)}</link>"

def elev_xml(r):
    if not r.get("hill"):
        return '      <elevationProfile><elevation s="0.0" a="0.0" b="0.0" c="0.0" d="0.0"/></elevationProfile>'
    h, L = r["hill"], r["length"]
    m = L / 2
    return ("      <elevationProfile>"
            f'<elevation s="0.0" a="0.0" b="0.0" c="{f(3 * h / m**2)}" d="{f(-2 * h / m**3)}"/>'
            f'<elevation s="{f(m)}" a="{f(h)}" b="0.0" c="{f(-3 * h / m**2)}" d="{f(2 * h / m**3)}"/>'
            "</elevationProfile>")

lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<OpenDRIVE>",
         '  <header revMajor="1" revMinor="4" name="crossroads" version="1.0" date="2025-01-01" '
         'north="130.0" south="-130.0" east="130.0" west="-180.0" vendor="carlaocc"/>']
lines.insert(1, "<!-- crossroads.xodr: a small original town of the carlaocc project (CC0-1.0). A 4-way junction "
                "(100) with traffic lights, two T junctions (200, 300) with stop and yield signs, main roads with two "
                "3.5 m lanes each way, side roads with one, 3 m sidewalks, a shoulder on road 3, a 2 m hill on road "
                "4; geometry: line, arc, spiral (road 3), paramPoly3 (road 5). Generated by carlaocc's author script. -->")
for rid, r in roads.items():
    lines.append(f'  <road name="{r["name"]}" length="{f(r["length"])}" id="{rid}" junction="-1">')
    lines.append(link_xml(r.get("pred"), r.get("succ")))
    lines.append(f'      <type s="0.0" type="town"><speed max="{50 if r["n"] == MAIN else 30}" unit="km/h"/></type>')
    lines.append("      <planView>")
    lines += [geom_xml(g) for g in r["geoms"]]
    lines.append("      </planView>")
    lines.append(elev_xml(r))
    lines.append('      <lateralProfile/>')
    lines.append("      <lanes>")
    secs = r.get("sections", [0.0]) + [r["length"]]
    for i in range(len(secs) - 1):
        lines.append(arm_section(r, secs[i], secs[i + 1], links=len(secs) > 2))
    lines.append("      </lanes>")
    if rid in signals:
        lines.append("      <signals>")
        for k, sg in enumerate(signals[rid]):
            lines.append(f'        <signal s="{f(sg["s"])}" t="{f(sg["t"])}" id="{rid}{k:02d}" name="{sg["name"]}" dynamic="{sg["dynamic"]}" '
                         f'orientation="{sg["orientation"]}" zOffset="0.0" country="OpenDRIVE" type="{sg["type"]}" '
                         f'subtype="{sg["subtype"]}" value="{sg["value"]}" height="1.0" width="0.8" hOffset="0.0" pitch="0.0" roll="0.0"/>')
        lines.append("      </signals>")
    lines.append("  </road>")
for c in connectors:
    a, b = c["a"], c["b"]
    lines.append(f'  <road name="Connector {c["id"]}" length="{f(c["length"])}" id="{c["id"]}" junction="{c["jid"]}">')
    lines.append(link_xml(("road", a[0], a[1]), ("road", b[0], b[1])))
    lines.append('      <type s="0.0" type="town"><speed max="30" unit="km/h"/></type>')
    lines.append("      <planView>")
    lines += [geom_xml(g) for g in c["geoms"]]
    lines.append("      </planView>")
    # elevation: connectors touching the hill road's ends stay at 0 (the hill starts and ends flat)
    lines.append('      <elevationProfile><elevation s="0.0" a="0.0" b="0.0" c="0.0" d="0.0"/></elevationProfile>')
    lines.append("      <lanes>")
    lines.append(f'        <laneOffset s="0.0" a="{f(W / 2)}" b="0.0" c="0.0" d="0.0"/>')
    right = [lane_xml(-1, "driving", [(0.0, W, 0.0)], mark("none"), (c["in_lane"], c["out_lane"]))]
    if c["sidewalk"]:
        right.append(lane_xml(-2, "sidewalk", [(0.0, SW, 0.0)], mark("none"), (c["sw_in"], c["sw_out"])))
    lines.append('        <laneSection s="0.0">')
    lines.append(f'          <center>\n            <lane id="0" type="none" level="false">{mark("none")}</lane>\n          </center>')
    lines.append("          <right>\n" + "\n".join(right) + "\n          </right>")
    lines.append("        </laneSection>")
    lines.append("      </lanes>")
    lines.append("  </road>")
for jid, lst in arms.items():
    lines.append(f'  <junction id="{jid}" name="{names[jid]}">')
    k = 0
    for c in connectors:
        if c["jid"] != jid:
            continue
        lines.append(f'    <connection id="{k}" incomingRoad="{c["a"][0]}" connectingRoad="{c["id"]}" contactPoint="start">'
                     f'<laneLink from="{c["in_lane"]}" to="-1"/></connection>')
        k += 1
    lines.append("  </junction>")
lines.append("</OpenDRIVE>")
open(sys.argv[1], "w").write("\n".join(lines) + "\n")
print("roads", len(roads), "connectors", len(connectors), {k: round(r["length"], 1) for k, r in roads.items()})
