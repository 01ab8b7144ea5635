"""Built-in OpenDRIVE towns: the resolver and the shipped crossroads file."""

from __future__ import annotations

import collections

import pytest

from carlaocc.catalog.opendrive import read_opendrive
from carlaocc.catalog.towns import builtin_names, resolve_opendrive


def test_builtin_names_lists_crossroads():
    names = builtin_names()
    assert {"crossroads.xodr", "hills.xodr"} <= set(names) and names == sorted(names)


def test_resolve_builtin_and_path(tmp_path):
    p = resolve_opendrive("builtin:crossroads.xodr")
    assert p.is_file() and p.name == "crossroads.xodr"
    f = tmp_path / "x.xodr"
    f.write_text("<OpenDRIVE/>")
    assert resolve_opendrive(str(f)) == f


@pytest.mark.parametrize("ref, exc", [
    ("builtin:nope.xodr", FileNotFoundError), ("builtin:../catalog/__init__.py", ValueError), ("builtin:", ValueError),
    ("", ValueError), ("/definitely/not/here.xodr", FileNotFoundError),
])  # fmt: skip
def test_resolve_errors_name_the_reference(ref, exc):
    with pytest.raises(exc) as info:
        resolve_opendrive(ref)
    assert repr(ref) in str(info.value)


def test_resolve_directory_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="directory"):
        resolve_opendrive(str(tmp_path))


def test_crossroads_content():
    net = read_opendrive(resolve_opendrive("builtin:crossroads.xodr"))
    assert (net.header.rev_major, net.header.rev_minor) == (1, 4)
    kinds = {g.kind for r in net.roads for g in r.geometries}
    assert {"line", "arc", "spiral", "paramPoly3"} <= kinds
    # one 4-way junction (4 incoming roads) and T junctions (3 incoming roads), all with lane links
    # arms = distinct (incoming road, contact point) pairs: road 5 loops into one T at both ends
    arms = {j.id: {(net.road(c.connecting_road).predecessor.element_id, net.road(c.connecting_road).predecessor.contact_point)
                   for c in j.connections} for j in net.junctions}  # fmt: skip
    assert sorted(len(v) for v in arms.values()) == [3, 3, 4]
    assert all(c.lane_links for j in net.junctions for c in j.connections)
    main = [r for r in net.roads if r.junction == "-1" and sum(ln.type == "driving" for ln in r.lane_sections[0].right) == 2]
    assert main and all(ln.widths[0].a == 3.5 for r in main for ln in r.lane_sections[0].right if ln.type == "driving")
    types = collections.Counter(ln.type for r in net.roads for sec in r.lane_sections for ln in sec.left + sec.right)
    assert types["sidewalk"] > 0 and types["shoulder"] > 0
    assert any(abs(e.c) > 0 for r in net.roads for e in r.elevations)
    sig = collections.Counter(s.type for s in net.signals)
    assert sig["1000001"] == 4 and sig["206"] >= 1 and sig["205"] >= 1
    assert any(m.type != "none" for r in net.roads for sec in r.lane_sections for ln in sec.center + sec.right
               for m in ln.road_marks)  # fmt: skip
    # bounding box about 250-300 m
    xs = [g.x for r in net.roads for g in r.geometries]
    ys = [g.y for r in net.roads for g in r.geometries]
    assert 200 < max(xs) - min(xs) < 320 and 150 < max(ys) - min(ys) < 320


def test_hills_content_and_generator(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    path = resolve_opendrive("builtin:hills.xodr")
    net = read_opendrive(path)
    assert [r.id for r in net.roads] == ["1", "2", "3", "4"] and not net.junctions
    # a crest and a sag, two banked half circles
    assert [len(r.elevations) for r in net.roads] == [2, 1, 2, 1]
    assert all(min(p.a for p in r.superelevations) == pytest.approx(-0.12) for r in (net.roads[1], net.roads[3]))
    # the shipped file is the generator's output
    root = Path(__file__).resolve().parents[2]
    out = tmp_path / "hills.xodr"
    subprocess.run([sys.executable, str(root / "tools" / "make_hills.py"), str(out)], check=True, capture_output=True)
    assert out.read_text() == path.read_text()
