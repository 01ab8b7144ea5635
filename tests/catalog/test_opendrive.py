"""OpenDRIVE reader: real CARLA/Scenic files and malformed inputs."""

from __future__ import annotations

import pytest

from carlaocc.catalog.opendrive import OpenDriveError, parse_opendrive, read_opendrive
from carlaocc.schemas.opendrive import OpenDriveNetwork
from shared_data import needs, shared_path

DATA = shared_path("opendrive")
NAMES = ["Town01", "Town02", "Town10HD", "Issue274", "shoulders", "zero_width"]
needs_data = needs(DATA)

# counts from testdata/MANIFEST.tsv
COUNTS = {
    "Town01": (122, 12, 36, 22),
    "Town02": (84, 8, 24, 21),
    "Town10HD": (108, 9, 21, 60),
    "Issue274": (1, 0, 0, 0),
    "shoulders": (4, 0, 0, 0),
    "zero_width": (3, 0, 0, 0),
}


@needs_data
@pytest.mark.parametrize("name", NAMES)
def test_real_files_parse_with_manifest_counts(name):
    net = read_opendrive(DATA / f"{name}.xodr")
    assert isinstance(net, OpenDriveNetwork)
    roads, junctions, signals, objects = COUNTS[name]
    assert (len(net.roads), len(net.junctions), len(net.signals), len(net.objects)) == (roads, junctions, signals, objects)
    for road in net.roads:
        assert road.geometries and road.lane_sections
        assert [g.s for g in road.geometries] == sorted(g.s for g in road.geometries)
        for sec in road.lane_sections:
            assert all(lane.id > 0 for lane in sec.left) and all(lane.id < 0 for lane in sec.right)
            assert [abs(lane.id) for lane in sec.left] == sorted(abs(lane.id) for lane in sec.left)


@needs_data
def test_town01_details():
    net = read_opendrive(DATA / "Town01.xodr")
    assert net.header.rev_major == 1 and net.header.rev_minor == 4 and net.header.vendor == "VectorZero"
    assert "+proj=tmerc" in net.header.geo_reference
    kinds = {g.kind for r in net.roads for g in r.geometries}
    assert kinds == {"line", "arc"}
    road = net.road(1)
    assert (road.predecessor.element_type, road.predecessor.element_id) == ("junction", "26")
    assert (road.successor.element_type, road.successor.element_id) == ("junction", "54")
    assert road.length == pytest.approx(157.55) and road.junction == "-1"
    assert net.road(0).types[0].type == "town" and net.road(0).types[0].speed_max == 25
    j = next(j for j in net.junctions if j.id == "26")
    c = j.connections[1]
    assert (c.incoming_road, c.connecting_road, c.contact_point) == ("1", "28", "start")
    assert [(ll.from_lane, ll.to_lane) for ll in c.lane_links] == [(2, 2), (3, 1)]
    sig = next(s for s in net.signals if s.id == "362")
    assert sig.type == "1000001" and sig.subtype == "-1" and sig.orientation == "-"
    assert sig.s == pytest.approx(35.840466582261428) and sig.t == pytest.approx(-4.4797897637266599)
    assert sig.z_offset == pytest.approx(-0.69904327392578125) and sig.height == pytest.approx(1.1595988571643829)
    assert sig.name == "Signal_3Light_Post01" and sig.dynamic
    obj = next(o for o in net.objects if o.id == "435")
    assert obj.name == "Speed_30" and obj.s == pytest.approx(17.472293596265814)


@needs_data
def test_issue274_lanes_and_marks():
    net = read_opendrive(DATA / "Issue274.xodr")
    road = net.roads[0]
    assert road.lane_offsets[0].a == pytest.approx(7.2)
    sec = road.lane_sections[0]
    assert [lane.id for lane in sec.right] == [-1, -2, -3, -4] and sec.center[0].id == 0
    lane = sec.right[0]
    assert lane.type == "driving" and lane.widths[0].a == pytest.approx(3.6)
    mark = lane.road_marks[0]
    assert mark.type == "broken" and mark.width == pytest.approx(0.15)
    assert mark.lines[0].length == pytest.approx(3.0) and mark.lines[0].space == pytest.approx(9.0)
    assert sec.center[0].road_marks[0].color == "yellow"


def test_zero_width_widths_sorted_by_soffset():
    xml = """<OpenDRIVE><road id="1" length="10"><planView>
      <geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry></planView>
      <lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right>
        <lane id="-1" type="driving">
          <width sOffset="5" a="2" b="0" c="0" d="0"/><width sOffset="0" a="1" b="0" c="0" d="0"/>
        </lane></right></laneSection></lanes></road></OpenDRIVE>"""
    lane = parse_opendrive(xml).roads[0].lane_sections[0].right[0]
    assert [w.s for w in lane.widths] == [0.0, 5.0]


def test_all_geometry_kinds_parse():
    xml = """<OpenDRIVE><header revMajor="1" revMinor="6"/><road id="7" length="50"><planView>
      <geometry s="0" x="0" y="0" hdg="0" length="10"><line/></geometry>
      <geometry s="10" x="10" y="0" hdg="0" length="10"><arc curvature="0.1"/></geometry>
      <geometry s="20" x="0" y="0" hdg="0" length="10"><spiral curvStart="0" curvEnd="0.02"/></geometry>
      <geometry s="30" x="0" y="0" hdg="0" length="10"><poly3 a="0" b="0" c="0.01" d="0"/></geometry>
      <geometry s="40" x="0" y="0" hdg="0" length="10">
        <paramPoly3 aU="0" bU="10" cU="0" dU="0" aV="0" bV="0" cV="0" dV="0" pRange="arcLength"/></geometry>
      </planView>
      <elevationProfile><elevation s="0" a="1" b="0.1" c="0" d="0"/></elevationProfile>
      <lateralProfile><superelevation s="0" a="0.05" b="0" c="0" d="0"/></lateralProfile>
      <lanes><laneSection s="0"><center><lane id="0" type="none"/></center></laneSection></lanes>
    </road></OpenDRIVE>"""
    net = parse_opendrive(xml)
    g = net.roads[0].geometries
    assert [x.kind for x in g] == ["line", "arc", "spiral", "poly3", "paramPoly3"]
    assert g[1].curvature == 0.1 and g[2].curv_end == 0.02 and g[3].c == 0.01
    assert g[4].bu == 10 and g[4].p_range == "arcLength"
    assert net.roads[0].elevations[0].b == 0.1 and net.roads[0].superelevations[0].a == 0.05
    assert net.header.rev_minor == 6


GOOD_ROAD = """<road id="12" length="10"><planView>
  <geometry s="0" x="0" y="0" hdg="0" length="10">{shape}</geometry></planView>
  <lanes><laneSection s="0"><center><lane id="0" type="none"/></center></laneSection></lanes></road>"""


def _doc(shape="<line/>"):
    return "<?xml version='1.0'?>\n<OpenDRIVE>\n" + GOOD_ROAD.format(shape=shape) + "\n</OpenDRIVE>"


def test_good_doc_helper_parses():
    assert parse_opendrive(_doc()).roads[0].id == "12"


@pytest.mark.parametrize(
    "text, fragments",
    [
        ("", ["empty"]),
        ("this is not xml", ["not well-formed XML", "line 1"]),
        (_doc()[:120], ["not well-formed XML", "line"]),  # truncated
        ("<?xml version='1.0'?>\n<kml><road/></kml>", ["<kml>", "expected <OpenDRIVE>"]),
        (_doc("<clothoid2/>"), ["road 12: geometry 0: unknown type 'clothoid2'", "line 4"]),
        (_doc('<arc/>'), ["road 12: geometry 0", "<arc> missing attribute 'curvature'"]),
        (_doc('<spiral curvStart="0"/>'), ["road 12: geometry 0", "'curvEnd'"]),
        (_doc('<paramPoly3 aU="0" bU="1" cU="0" dU="0" aV="0" bV="0" cV="0" dV="0" pRange="p"/>'), ["pRange"]),
        (_doc().replace('hdg="0" ', ""), ["road 12: geometry 0", "<geometry> missing attribute 'hdg'", "line 4"]),
        (_doc().replace('x="0"', 'x="abc"'), ["road 12: geometry 0", "'x'='abc' is not a number"]),
        (_doc().replace('<lane id="0"', '<lane'), ["road 12: laneSection 0", "<lane> missing attribute 'id'"]),
        (_doc().replace('<lane id="0"', '<lane id="2"'), ["lane id 2 not allowed in <center>"]),
        (_doc().replace('<road id="12" length="10">', '<road id="12">'), ["road 12", "'length'"]),
        (_doc().replace("<line/>", ""), ["road 12: geometry 0", "expected exactly one shape element"]),
        (_doc().replace("<planView>", "<planViewX>").replace("</planView>", "</planViewX>"), ["road 12", "missing <planView>"]),
    ],
)
def test_malformed_inputs_raise_opendrive_error(text, fragments):
    with pytest.raises(OpenDriveError) as info:
        parse_opendrive(text)
    for frag in fragments:
        assert frag in str(info.value)


def test_read_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.xodr"
    bad.write_text(_doc("<clothoid2/>"))
    with pytest.raises(OpenDriveError, match=r"bad\.xodr: road 12: geometry 0: unknown type 'clothoid2'"):
        read_opendrive(bad)
    with pytest.raises(OpenDriveError, match="cannot read"):
        read_opendrive(tmp_path / "missing.xodr")
    binary = tmp_path / "bin.xodr"
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(OpenDriveError, match="not well-formed XML"):
        read_opendrive(binary)
