"""BuildingNetAdapter over a small OBJ + component label JSON written by the test."""

from __future__ import annotations

import json

import pytest

from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.buildingnet import BuildingNetAdapter, label_class, subclass_from_name
from carlaocc.schemas.taxonomy import by_name

# a unit cube per component, shifted along x: "o <index>" components as BuildingNet writes
# them, plus "g" groups (named groups are tried first)
CUBE_V = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]
CUBE_F = [(1, 2, 3, 4), (5, 8, 7, 6), (1, 5, 6, 2), (2, 6, 7, 3), (3, 7, 8, 4), (4, 8, 5, 1)]


def _obj(components):
    lines = ["mtllib house.mtl"]
    for k, (tag, name, mat) in enumerate(components):
        lines += [f"v {x + 2 * k} {y} {z}" for x, y, z in CUBE_V]
        lines.append(f"{tag} {name}")
        if mat:
            lines.append(f"usemtl {mat}")
        base = 8 * k
        lines += ["f " + " ".join(str(base + i) for i in face) for face in CUBE_F]
    return "\n".join(lines) + "\n"


COMPONENTS = [("g", "wall_01", "plaster"), ("g", "window_01", "frame"), ("g", "mystery", "tinted"),
              ("g", "Fence_A", ""), ("o", "2", ""), ("o", "5", "")]  # fmt: skip
LABELS = {"wall_01": "wall", "WINDOW_01": "window", "2": 5, "fence_a": "fence", "5": "ground"}


@pytest.fixture
def root(tmp_path):
    (tmp_path / "RESIDENTIALvilla_mesh0001.obj").write_text(_obj(COMPONENTS))
    (tmp_path / "RESIDENTIALvilla_mesh0001_label.json").write_text(json.dumps(LABELS))
    (tmp_path / "house.mtl").write_text("newmtl plaster\nKd 1 1 1\nmap_Kd plaster.jpg\n"
                                        "newmtl frame\nKd 0 0 0\nnewmtl tinted\nd 0.5\n")  # fmt: skip
    return str(tmp_path)


def test_parts_labels_and_declarations(root):
    a = BuildingNetAdapter()
    [item] = a.list_items(root)
    assert item.key == "RESIDENTIALvilla_mesh0001"
    assert item.files[-1].endswith("_label.json") and any(f.endswith(".mtl") for f in item.files)
    asset = a.read(root, item)
    assert (asset.category, asset.subclass) == ("Building", "house")
    assert (asset.up, asset.forward, asset.units) == ("+y", "+z", "unknown")
    assert asset.licence == "BuildingNet terms of use" and not asset.licence_required
    parts = {p.name: p for p in asset.parts}
    assert list(parts) == ["wall_01", "window_01", "mystery", "Fence_A", "2", "5"]
    sid = {n: p.semantic_id for n, p in parts.items()}
    assert sid == {"wall_01": by_name("Building").id, "window_01": by_name("Building").id,
                   "2": by_name("Vegetation").id, "Fence_A": by_name("Fence").id,
                   "mystery": None, "5": by_name("Ground").id}  # fmt: skip
    assert parts["window_01"].transparent and parts["window_01"].material == "glass"
    assert parts["mystery"].transparent  # MTL d 0.5, unlabeled
    assert not parts["wall_01"].transparent and parts["wall_01"].texture == "plaster.jpg"
    for p in asset.parts:  # each part keeps only its own cube
        assert p.vertices.shape == (8, 3) and p.faces.shape == (12, 3)
    assert parts["5"].vertices[:, 0].min() == 10


def test_groups_inherit_their_objects_label(tmp_path):
    (tmp_path / "m.obj").write_text(_obj([("o", "7", ""), ("g", "trim", ""), ("g", "sill", "")]))
    (tmp_path / "m_label.json").write_text(json.dumps({"7": "window", "sill": "wall"}))
    a = BuildingNetAdapter()
    [item] = a.list_items(str(tmp_path))
    parts = {p.name: p for p in a.read(str(tmp_path), item).parts}
    assert parts["trim"].transparent and not parts["sill"].transparent


def test_meta_subclass_and_labels_dir(tmp_path):
    (tmp_path / "OBJ_MODELS").mkdir()
    (tmp_path / "labels").mkdir()
    (tmp_path / "OBJ_MODELS" / "COMMERCIALcastle_mesh0002.obj").write_text(_obj(COMPONENTS[:2]))
    (tmp_path / "labels" / "COMMERCIALcastle_mesh0002_label.json").write_text(
        json.dumps({"labels": {"wall_01": 1, "window_01": 2}, "subclass": "tower", "licence": "x"}))
    a = BuildingNetAdapter(labels_dir="labels")
    [item] = a.list_items(str(tmp_path))
    asset = a.read(str(tmp_path), item)
    assert (asset.subclass, asset.licence) == ("tower", "x")
    assert [p.transparent for p in asset.parts] == [False, True]


def test_problems(tmp_path):
    (tmp_path / "a.obj").write_text(_obj(COMPONENTS[:1]))  # no label file
    (tmp_path / "b.obj").write_text(_obj(COMPONENTS[:1]))
    (tmp_path / "b_label.json").write_text(json.dumps({"0": 1, "1": 1}))  # per-point labels
    (tmp_path / "c.obj").write_text(_obj(COMPONENTS[:1]))
    (tmp_path / "c_label.json").write_text(json.dumps({"wall_01": "spaceship"}))
    (tmp_path / "d.obj").write_text("v 0 0 0\nf 1 2 3\n")  # index out of range
    (tmp_path / "d_label.json").write_text("{}")
    (tmp_path / "e.obj").write_text(_obj(COMPONENTS[:1]))
    (tmp_path / "e_label.json").write_text("{broken")
    a = BuildingNetAdapter()
    got = {}
    for it in a.list_items(str(tmp_path)):
        with pytest.raises(SourceError) as e:
            a.read(str(tmp_path), it)
        got[it.key] = e.value.reason
    assert got == {"a": "bad metadata", "b": "bad metadata", "c": "bad metadata",
                   "d": "unreadable file", "e": "bad metadata"}  # fmt: skip


def test_label_table():
    assert label_class("window") == ("Building", True)
    assert label_class("door-glass") == ("Building", True)
    assert label_class(17) == ("Fence", False)
    assert label_class("0") == (None, False)
    assert label_class("tree") == ("Vegetation", False)
    assert label_class("Sidewalk") == ("Sidewalk", False)  # a taxonomy class name
    with pytest.raises(KeyError):
        label_class(99)
    assert subclass_from_name("RELIGIOUSchurch_mesh2095") == "religious"
    assert subclass_from_name("RESIDENTIALapartment_mesh1") == "apartment"
    assert subclass_from_name("my_building") is None
