"""MeshFleetAdapter over the real MeshFleet CSV (read-only) and a tmp mesh folder."""

from __future__ import annotations

import csv

import pytest
import trimesh

from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.meshfleet import MeshFleetAdapter
from shared_data import needs, shared_path

CSV = str(shared_path("meshfleet/meshfleet_with_vehicle_categories_df.csv"))
pytestmark = needs(CSV)


@pytest.fixture(scope="module")
def rows():
    csv.field_size_limit(1 << 30)
    with open(CSV, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.fixture
def setup(tmp_path, rows):
    meshes = tmp_path / "meshes"
    meshes.mkdir()
    suv = next(r for r in rows if r["category"] == "SUV" and r["license"])
    bus = next(r for r in rows if r["category"] == "bus" and not r["license"])
    trimesh.creation.box(extents=(4.6, 1.9, 1.7)).export(str(meshes / f"{suv['sha256']}.glb"))
    trimesh.creation.box(extents=(12, 2.5, 3)).export(str(meshes / f"{bus['sha256']}.OBJ"))
    adapter = MeshFleetAdapter(csv=CSV, meshes=str(meshes))
    return adapter, str(tmp_path), suv, bus


def test_every_row_listed(setup, rows):
    adapter, root, suv, bus = setup
    items = adapter.list_items(root)
    assert len(items) == len(rows) == 1620
    assert [it.key for it in items] == sorted(r["sha256"] for r in rows)
    by = {it.key: it for it in items}
    assert by[suv["sha256"]].files and by[bus["sha256"]].files
    assert sum(1 for it in items if it.files) == 2


def test_present_meshes_read(setup):
    adapter, root, suv, bus = setup
    by = {it.key: it for it in adapter.list_items(root)}
    a = adapter.read(root, by[suv["sha256"]])
    assert (a.category, a.subclass, a.source) == ("Car", "suv", "meshfleet")
    assert (a.up, a.forward, a.units) == ("+y", "+z", "unknown")  # GLB: glTF frame
    assert a.normalized and a.licence_required
    assert a.licence == suv["license"] != ""
    assert a.target_length is None  # the normalized_* columns are ratios, not metres
    assert by[suv["sha256"]].meta["length_to_height"] == pytest.approx(float(suv["normalized_depth_of_object"]))
    b = adapter.read(root, by[bus["sha256"]])
    assert (b.category, b.subclass, b.licence) == ("Bus", "city_bus", "")
    assert (b.up, b.forward) == ("+z", "+x")  # OBJ, case-insensitive extension


def test_absent_meshes_are_missing_not_fatal(setup):
    adapter, root, suv, bus = setup
    items = adapter.list_items(root)
    reasons = {}
    for it in items:
        if it.key in (suv["sha256"], bus["sha256"]):
            continue
        with pytest.raises(SourceError) as e:
            adapter.read(root, it)
        reasons[e.value.reason] = reasons.get(e.value.reason, 0) + 1
        if len(reasons) == 1 and reasons["missing mesh"] == 1:
            assert it.key in e.value.hint  # names the expected file
    assert reasons == {"missing mesh": 1618}


def test_unsupported_format_and_unmapped_category(tmp_path):
    sha = "ab" * 32
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / f"{sha}.fbx").write_bytes(b"Kaydara FBX Binary")
    (tmp_path / "fleet.csv").write_text(
        "sha256,category,license,fileType\n"
        f"{sha},Sedan,MIT License,fbx\n"
        f"{'cd' * 32},boat,MIT License,glb\n"
        f"nothex,Sedan,,glb\n"
    )
    a = MeshFleetAdapter()  # defaults: the only CSV in root, root/meshes
    got = {}
    for it in a.list_items(str(tmp_path)):
        with pytest.raises(SourceError) as e:
            a.read(str(tmp_path), it)
        got[it.meta["line"]] = e.value.reason
    assert got == {2: "unreadable file", 3: "no category", 4: "bad metadata"}


def test_axes_option(setup):
    adapter, root, suv, bus = setup
    turned = MeshFleetAdapter(csv=adapter.csv, meshes=adapter.meshes, up="+y", forward="+x")
    item = next(it for it in turned.list_items(root) if it.key == suv["sha256"])
    a = turned.read(root, item)
    assert (a.up, a.forward) == ("+y", "+x")
    with pytest.raises(ValueError):
        MeshFleetAdapter(up="+y", forward="-y")
    with pytest.raises(ValueError):
        MeshFleetAdapter(up="+y")


def test_csv_without_required_column(tmp_path):
    (tmp_path / "fleet.csv").write_text("sha256,category\n" + "ab" * 32 + ",Sedan\n")
    with pytest.raises(SourceError) as e:
        MeshFleetAdapter().list_items(str(tmp_path))
    assert e.value.reason == "bad metadata" and "license" in e.value.hint
