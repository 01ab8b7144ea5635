"""OpenDRIVE (.xodr) reader: parse a road network into the records of
:mod:`carlaocc.schemas.opendrive` (an :class:`~carlaocc.schemas.opendrive.OpenDriveNetwork`).

Only the parts the scene stage needs are read (see the schema module); everything else
(controllers, userData, vendor extensions, surface CRG, ...) is ignored. Geometry evaluation
lives in :mod:`carlaocc.stages.scenes.opendrive.geometry`, which takes these records.

Why no third-party reader: the only candidates in the package index are ``pyxodr`` (0.1.3,
2023, read-only wrapper pulling ``lxml``/``shapely``, its own object model and no line numbers
in errors) and a fork of it. The OpenDRIVE geometry is a few hundred lines of well-specified
maths, so writing it keeps the dependency surface at the standard library (``xml.parsers.expat``
to keep element line numbers for error messages) and lets the evaluator live in ``stages``.

Units are those of the file (metres, radians). Coordinates are OpenDRIVE's inertial frame:
right-handed, x east, y north, z up, which is also this project's world frame. CARLA's own
``.xodr`` files are already written in this right-handed frame (the CARLA server flips y when it
loads them), so no conversion is applied here.

Errors: every malformed or unsupported input raises :class:`OpenDriveError` whose message names
the element path and source line, e.g. ``"road 12: geometry 3: unknown type 'clothoid2' (line
57)"``; a file that is not XML or whose root is not ``<OpenDRIVE>`` is an error too.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from pathlib import Path
from xml.parsers import expat

from carlaocc.schemas.opendrive import (
    Connection,
    Geometry,
    Header,
    Junction,
    LaneRecord,
    LaneLink,
    LaneSection,
    OpenDriveNetwork,
    Poly3Record,
    Road,
    RoadLink,
    RoadMark,
    RoadMarkLine,
    RoadObject,
    RoadTypeRecord,
    Signal,
)

__all__ = ["OpenDriveError", "read_opendrive", "parse_opendrive"]


class OpenDriveError(ValueError):
    """A malformed or unsupported OpenDRIVE input; the message names the element and line."""


# ---------------------------------------------------------------------------------------------
# XML with line numbers


def _parse_xml(data: bytes, source: str) -> tuple[ET.Element, dict[int, int]]:
    """Build an ElementTree with expat, remembering each element's start line (by ``id``)."""
    lines: dict[int, int] = {}
    builder = ET.TreeBuilder()
    parser = expat.ParserCreate()
    parser.buffer_text = True

    def start(tag, attrs):
        elem = builder.start(tag, attrs)
        lines[id(elem)] = parser.CurrentLineNumber

    parser.StartElementHandler = start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(data, True)
        root = builder.close()
    except expat.ExpatError as exc:
        raise OpenDriveError(
            f"{source}: not well-formed XML: {expat.ErrorString(exc.code)} "
            f"(line {exc.lineno}, column {exc.offset})"
        ) from None
    except AssertionError:  # TreeBuilder.close() on an empty/unfinished document
        raise OpenDriveError(f"{source}: not an XML document") from None
    return root, lines


class _Ctx:
    """Element path + line lookup for error messages and typed attribute access."""

    def __init__(self, lines: dict[int, int], source: str):
        self.lines = lines
        self.source = source

    def err(self, where: str, elem: ET.Element | None, msg: str) -> OpenDriveError:
        line = self.lines.get(id(elem)) if elem is not None else None
        suffix = f" (line {line})" if line is not None else ""
        prefix = f"{where}: " if where else ""
        return OpenDriveError(f"{prefix}{msg}{suffix}")

    def str_(self, where, elem, name, default=None, required=False) -> str | None:
        value = elem.get(name)
        if value is None:
            if required:
                raise self.err(where, elem, f"<{elem.tag}> missing attribute '{name}'")
            return default
        return value

    def float_(self, where, elem, name, default=None, required=False) -> float | None:
        value = elem.get(name)
        if value is None or (value.strip() == "" and not required):
            if required:
                raise self.err(where, elem, f"<{elem.tag}> missing attribute '{name}'")
            return default
        try:
            out = float(value)
        except ValueError:
            raise self.err(where, elem, f"<{elem.tag}> attribute '{name}'={value!r} is not a number") from None
        if not math.isfinite(out):
            raise self.err(where, elem, f"<{elem.tag}> attribute '{name}'={value!r} is not finite")
        return out

    def int_(self, where, elem, name, default=None, required=False) -> int | None:
        value = elem.get(name)
        if value is None:
            if required:
                raise self.err(where, elem, f"<{elem.tag}> missing attribute '{name}'")
            return default
        try:
            return int(value)
        except ValueError:
            try:
                f = float(value)
            except ValueError:
                f = math.nan
            if f.is_integer():
                return int(f)
            raise self.err(where, elem, f"<{elem.tag}> attribute '{name}'={value!r} is not an integer") from None


def _bool(value: str | None) -> bool:
    return str(value).strip().lower() in ("true", "yes", "1")


# ---------------------------------------------------------------------------------------------
# element parsers


def _poly(ctx: _Ctx, where: str, elem: ET.Element, s_name: str = "s") -> Poly3Record:
    return Poly3Record(
        s=ctx.float_(where, elem, s_name, required=True),
        a=ctx.float_(where, elem, "a", required=True),
        b=ctx.float_(where, elem, "b", required=True),
        c=ctx.float_(where, elem, "c", required=True),
        d=ctx.float_(where, elem, "d", required=True),
    )


def _sorted_polys(records: list[Poly3Record]) -> tuple[Poly3Record, ...]:
    return tuple(sorted(records, key=lambda r: r.s))  # stable: equal s keeps file order


def _geometry(ctx: _Ctx, where: str, elem: ET.Element) -> Geometry:
    f = ctx.float_
    base = dict(
        s=f(where, elem, "s", required=True),
        x=f(where, elem, "x", required=True),
        y=f(where, elem, "y", required=True),
        hdg=f(where, elem, "hdg", required=True),
        length=f(where, elem, "length", required=True),
        line=ctx.lines.get(id(elem)),
    )
    if base["length"] < 0:
        raise ctx.err(where, elem, f"negative length {base['length']}")
    kids = [k for k in elem if k.tag != "userData"]
    if len(kids) != 1:
        raise ctx.err(where, elem, f"expected exactly one shape element, found {len(kids)}")
    shape = kids[0]
    kind = shape.tag
    if kind == "line":
        return Geometry(kind="line", **base)
    if kind == "arc":
        return Geometry(kind="arc", curvature=f(where, shape, "curvature", required=True), **base)
    if kind == "spiral":
        return Geometry(
            kind="spiral",
            curv_start=f(where, shape, "curvStart", required=True),
            curv_end=f(where, shape, "curvEnd", required=True),
            **base,
        )
    if kind == "poly3":
        return Geometry(kind="poly3", **{k: f(where, shape, k, required=True) for k in "abcd"}, **base)
    if kind == "paramPoly3":
        names = {"au": "aU", "bu": "bU", "cu": "cU", "du": "dU", "av": "aV", "bv": "bV", "cv": "cV", "dv": "dV"}
        coeffs = {k: f(where, shape, v, required=True) for k, v in names.items()}
        p_range = shape.get("pRange", "normalized")
        if p_range not in ("normalized", "arcLength"):
            raise ctx.err(where, shape, f"unknown paramPoly3 pRange {p_range!r}")
        return Geometry(kind="paramPoly3", p_range=p_range, **coeffs, **base)
    raise ctx.err(where, shape, f"unknown type {kind!r}")


def _road_mark(ctx: _Ctx, where: str, elem: ET.Element) -> RoadMark:
    lines = []
    for t in elem.findall("type"):
        for i, ln in enumerate(t.findall("line")):
            w = f"{where}: line {i}"
            lines.append(RoadMarkLine(
                length=ctx.float_(w, ln, "length", required=True),
                space=ctx.float_(w, ln, "space", required=True),
                t_offset=ctx.float_(w, ln, "tOffset", 0.0),
                s_offset=ctx.float_(w, ln, "sOffset", 0.0),
                width=ctx.float_(w, ln, "width", ctx.float_(w, t, "width")),
                rule=ln.get("rule", "none"),
            ))  # fmt: skip
    return RoadMark(
        s_offset=ctx.float_(where, elem, "sOffset", required=True),
        type=ctx.str_(where, elem, "type", required=True),
        weight=elem.get("weight", "standard"),
        color=elem.get("color", "standard"),
        material=elem.get("material", "standard"),
        width=ctx.float_(where, elem, "width"),
        lane_change=elem.get("laneChange", "both"),
        height=ctx.float_(where, elem, "height", 0.0),
        lines=tuple(lines),
    )


def _lane(ctx: _Ctx, where: str, elem: ET.Element) -> LaneRecord:
    lane_id = ctx.int_(where, elem, "id", required=True)
    w = f"{where}: lane {lane_id}"
    link = elem.find("link")
    pred = succ = None
    if link is not None:
        p, s_ = link.find("predecessor"), link.find("successor")
        pred = ctx.int_(w, p, "id", required=True) if p is not None else None
        succ = ctx.int_(w, s_, "id", required=True) if s_ is not None else None
    return LaneRecord(
        id=lane_id,
        type=elem.get("type", "none"),
        level=_bool(elem.get("level")),
        widths=_sorted_polys([_poly(ctx, f"{w}: width {i}", e, "sOffset") for i, e in enumerate(elem.findall("width"))]),
        borders=_sorted_polys([_poly(ctx, f"{w}: border {i}", e, "sOffset") for i, e in enumerate(elem.findall("border"))]),
        road_marks=tuple(sorted(
            (_road_mark(ctx, f"{w}: roadMark {i}", e) for i, e in enumerate(elem.findall("roadMark"))),
            key=lambda m: m.s_offset,
        )),
        predecessor=pred,
        successor=succ,
    )  # fmt: skip


def _lane_section(ctx: _Ctx, where: str, elem: ET.Element) -> LaneSection:
    def side(name: str, sign: int) -> tuple[LaneRecord, ...]:
        node = elem.find(name)
        if node is None:
            return ()
        lanes = [_lane(ctx, f"{where}: {name}", e) for e in node.findall("lane")]
        for lane in lanes:
            if (sign == 0 and lane.id != 0) or (sign != 0 and lane.id * sign <= 0):
                raise ctx.err(where, node, f"lane id {lane.id} not allowed in <{name}>")
        ids = [lane.id for lane in lanes]
        if len(set(ids)) != len(ids):
            raise ctx.err(where, node, f"duplicate lane ids in <{name}>: {sorted(ids)}")
        return tuple(sorted(lanes, key=lambda lane: abs(lane.id)))

    return LaneSection(
        s=ctx.float_(where, elem, "s", required=True),
        single_side=_bool(elem.get("singleSide")),
        left=side("left", 1),
        center=side("center", 0),
        right=side("right", -1),
    )


def _link(ctx: _Ctx, where: str, elem: ET.Element | None) -> RoadLink | None:
    if elem is None:
        return None
    return RoadLink(
        element_type=ctx.str_(where, elem, "elementType", required=True),
        element_id=ctx.str_(where, elem, "elementId", required=True),
        contact_point=elem.get("contactPoint"),
    )


def _signal(ctx: _Ctx, where: str, e: ET.Element) -> Signal:
    f = ctx.float_
    sid = ctx.str_(where, e, "id", required=True)
    w = f"{where}: signal {sid}"
    return Signal(
        id=sid, name=e.get("name", ""), s=f(w, e, "s", required=True), t=f(w, e, "t", required=True),
        z_offset=f(w, e, "zOffset", 0.0), h_offset=f(w, e, "hOffset", 0.0),
        orientation=e.get("orientation", "none"), dynamic=_bool(e.get("dynamic")),
        country=e.get("country", ""), type=e.get("type", ""), subtype=e.get("subtype", ""),
        value=f(w, e, "value"), text=e.get("text", ""), height=f(w, e, "height"), width=f(w, e, "width"),
        pitch=f(w, e, "pitch", 0.0), roll=f(w, e, "roll", 0.0),
    )  # fmt: skip


def _object(ctx: _Ctx, where: str, e: ET.Element) -> RoadObject:
    f = ctx.float_
    oid = ctx.str_(where, e, "id", required=True)
    w = f"{where}: object {oid}"
    return RoadObject(
        id=oid, name=e.get("name", ""), type=e.get("type", ""),
        s=f(w, e, "s", required=True), t=f(w, e, "t", required=True), z_offset=f(w, e, "zOffset", 0.0),
        hdg=f(w, e, "hdg", 0.0), pitch=f(w, e, "pitch", 0.0), roll=f(w, e, "roll", 0.0),
        orientation=e.get("orientation", "none"), length=f(w, e, "length"), width=f(w, e, "width"),
        height=f(w, e, "height"), radius=f(w, e, "radius"),
    )  # fmt: skip


def _road(ctx: _Ctx, elem: ET.Element, index: int) -> Road:
    rid = elem.get("id")
    if rid is None:
        raise ctx.err(f"road #{index}", elem, "<road> missing attribute 'id'")
    where = f"road {rid}"
    plan = elem.find("planView")
    if plan is None:
        raise ctx.err(where, elem, "missing <planView>")
    geoms = [_geometry(ctx, f"{where}: geometry {i}", g) for i, g in enumerate(plan.findall("geometry"))]
    if not geoms:
        raise ctx.err(where, plan, "<planView> has no <geometry>")
    geoms.sort(key=lambda g: g.s)

    ep, lp, lanes = elem.find("elevationProfile"), elem.find("lateralProfile"), elem.find("lanes")
    elev = [] if ep is None else [_poly(ctx, f"{where}: elevation {i}", e) for i, e in enumerate(ep.findall("elevation"))]
    sup = [] if lp is None else [_poly(ctx, f"{where}: superelevation {i}", e) for i, e in enumerate(lp.findall("superelevation"))]
    if lanes is None:
        raise ctx.err(where, elem, "missing <lanes>")
    offsets = [_poly(ctx, f"{where}: laneOffset {i}", e) for i, e in enumerate(lanes.findall("laneOffset"))]
    sections = [_lane_section(ctx, f"{where}: laneSection {i}", e) for i, e in enumerate(lanes.findall("laneSection"))]
    if not sections:
        raise ctx.err(where, lanes, "<lanes> has no <laneSection>")
    sections.sort(key=lambda sec: sec.s)

    link = elem.find("link")
    types = []
    for i, t in enumerate(elem.findall("type")):
        sp = t.find("speed")
        types.append(RoadTypeRecord(
            s=ctx.float_(f"{where}: type {i}", t, "s", required=True),
            type=t.get("type", ""),
            speed_max=None if sp is None else _speed(sp.get("max")),
            speed_unit=None if sp is None else sp.get("unit"),
        ))  # fmt: skip
    sig_node, obj_node = elem.find("signals"), elem.find("objects")
    return Road(
        id=rid,
        name=elem.get("name", ""),
        length=ctx.float_(where, elem, "length", required=True),
        junction=elem.get("junction", "-1"),
        geometries=tuple(geoms),
        elevations=_sorted_polys(elev),
        superelevations=_sorted_polys(sup),
        lane_offsets=_sorted_polys(offsets),
        lane_sections=tuple(sections),
        predecessor=None if link is None else _link(ctx, f"{where}: link", link.find("predecessor")),
        successor=None if link is None else _link(ctx, f"{where}: link", link.find("successor")),
        types=tuple(types),
        signals=() if sig_node is None else tuple(_signal(ctx, where, e) for e in sig_node.findall("signal")),
        objects=() if obj_node is None else tuple(_object(ctx, where, e) for e in obj_node.findall("object")),
        line=ctx.lines.get(id(elem)),
    )


def _speed(value: str | None) -> float | None:
    try:
        return float(value) if value is not None else None
    except ValueError:  # "no limit" / "undefined"
        return None


def _junction(ctx: _Ctx, elem: ET.Element) -> Junction:
    jid = ctx.str_("junction", elem, "id", required=True)
    where = f"junction {jid}"
    conns = []
    for c in elem.findall("connection"):
        cid = ctx.str_(where, c, "id", required=True)
        w = f"{where}: connection {cid}"
        conns.append(Connection(
            id=cid,
            incoming_road=ctx.str_(w, c, "incomingRoad", required=True),
            connecting_road=ctx.str_(w, c, "connectingRoad", required=True),
            contact_point=c.get("contactPoint"),
            lane_links=tuple(
                LaneLink(ctx.int_(w, ll, "from", required=True), ctx.int_(w, ll, "to", required=True))
                for ll in c.findall("laneLink")
            ),
        ))  # fmt: skip
    return Junction(id=jid, name=elem.get("name", ""), connections=tuple(conns))


def _header(ctx: _Ctx, elem: ET.Element | None) -> Header:
    if elem is None:
        return Header()
    f, w = ctx.float_, "header"
    geo = elem.find("geoReference")
    return Header(
        rev_major=ctx.int_(w, elem, "revMajor"), rev_minor=ctx.int_(w, elem, "revMinor"),
        name=elem.get("name", ""), version=elem.get("version", ""), date=elem.get("date", ""),
        north=f(w, elem, "north"), south=f(w, elem, "south"), east=f(w, elem, "east"), west=f(w, elem, "west"),
        vendor=elem.get("vendor", ""), geo_reference=(geo.text or "").strip() if geo is not None else "",
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# entry points


def parse_opendrive(data: bytes | str, source: str = "<string>") -> OpenDriveNetwork:
    """Parse OpenDRIVE XML given as bytes or text. ``source`` only labels error messages."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    if not data.strip():
        raise OpenDriveError(f"{source}: empty file, not an OpenDRIVE document")
    root, lines = _parse_xml(data, source)
    ctx = _Ctx(lines, source)
    if root.tag != "OpenDRIVE":
        raise OpenDriveError(f"{source}: root element is <{root.tag}>, expected <OpenDRIVE> (line {lines.get(id(root))})")
    roads = tuple(_road(ctx, e, i) for i, e in enumerate(root.findall("road")))
    ids = [r.id for r in roads]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise OpenDriveError(f"{source}: duplicate road ids {dup[:10]}")
    return OpenDriveNetwork(
        header=_header(ctx, root.find("header")),
        roads=roads,
        junctions=tuple(_junction(ctx, e) for e in root.findall("junction")),
        source=source,
    )


def read_opendrive(path: str | os.PathLike) -> OpenDriveNetwork:
    """Read and parse an ``.xodr`` file (read in place; never copied)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise OpenDriveError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        return parse_opendrive(data, source=str(path))
    except OpenDriveError as exc:
        msg = str(exc)
        raise OpenDriveError(msg if msg.startswith(str(path)) else f"{path}: {msg}") from None
