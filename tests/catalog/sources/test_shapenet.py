"""ShapeNetAdapter over a ShapeNetCore v2 layout built in tmp_path around a real OBJ."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.shapenet import ShapeNetAdapter, classify
from shared_data import needs, shared_path

HULL = str(shared_path("meshes/scenic/bmwx5_hull.obj"))
pytestmark = needs(HULL)

TAXONOMY = [
    {"synsetId": "02958343", "name": "car,auto,automobile,machine,motorcar",
     "children": ["04285965", "03100240"], "numInstances": 3514},
    {"synsetId": "04285965", "name": "sport utility,sport utility vehicle,S.U.V.,SUV",
     "children": [], "numInstances": 100},
    {"synsetId": "03100240", "name": "convertible", "children": [], "numInstances": 10},
    {"synsetId": "02691156", "name": "airplane,aeroplane,plane", "children": [], "numInstances": 4045},
    {"synsetId": "02924116", "name": "bus,autobus,coach", "children": [], "numInstances": 939},
]  # fmt: skip


def _model(root, synset, model):
    d = root / synset / model / "models"
    d.mkdir(parents=True)
    shutil.copy(HULL, d / "model_normalized.obj")


@pytest.fixture
def root(tmp_path):
    r = tmp_path / "ShapeNetCore.v2"
    r.mkdir()
    (r / "taxonomy.json").write_text(json.dumps(TAXONOMY))
    _model(r, "02958343", "suv0001")
    _model(r, "02958343", "car0002")
    _model(r, "02691156", "plane0001")
    _model(r, "02924116", "bus0001")
    (r / "all.csv").write_text("id,synsetId,subSynsetId,modelId,split\n"
                               "1,02958343,04285965,suv0001,train\n"
                               "2,02958343,02958343,car0002,test\n")  # fmt: skip
    (r / "02958343" / "README.txt").write_text("not a model")
    return str(r)


def test_lists_models(root):
    items = ShapeNetAdapter().list_items(root)
    assert [it.key for it in items] == ["02691156/plane0001", "02924116/bus0001",
                                        "02958343/car0002", "02958343/suv0001"]  # fmt: skip
    assert items[-1].files[0].endswith(os.path.join("models", "model_normalized.obj"))


def test_car_declarations(root):
    a = ShapeNetAdapter()
    items = {it.key: it for it in a.list_items(root)}
    asset = a.read(root, items["02958343/suv0001"])
    assert (asset.category, asset.subclass) == ("Car", "suv")  # sub-synset from all.csv
    assert (asset.up, asset.forward, asset.units) == ("+y", "-z", "unknown")
    assert asset.normalized and not asset.licence_required
    assert asset.licence == "ShapeNet terms of use"
    assert sum(len(p.faces) for p in asset.parts) == 1168
    plain = a.read(root, items["02958343/car0002"])
    assert (plain.category, plain.subclass) == ("Car", "sedan")
    bus = a.read(root, items["02924116/bus0001"])
    assert (bus.category, bus.subclass) == ("Bus", "city_bus")


def test_airplane_has_no_category(root):
    a = ShapeNetAdapter()
    item = next(it for it in a.list_items(root) if it.key.startswith("02691156"))
    with pytest.raises(SourceError) as e:
        a.read(root, item)
    assert e.value.reason == "no category"
    assert "airplane" in e.value.hint


def test_missing_model_file(root):
    a = ShapeNetAdapter()
    item = next(it for it in a.list_items(root) if it.key == "02924116/bus0001")
    os.remove(item.files[0])
    with pytest.raises(SourceError) as e:
        a.read(root, item)
    assert e.value.reason == "missing mesh"


def test_root_without_taxonomy(tmp_path):
    with pytest.raises(SourceError) as e:
        ShapeNetAdapter().list_items(str(tmp_path))
    assert e.value.reason == "bad metadata"


def test_classify_by_name_and_hypernyms():
    tax = {
        "02958343": {"name": "car", "children": ["99999999"]},
        "99999999": {"name": "hatchback,hatch", "children": ["88888888"]},
        "88888888": {"name": "weird custom", "children": []},
    }
    assert classify("02958343", "99999999", tax) == ("Car", "hatchback")  # a word of its name
    assert classify("02958343", "88888888", tax) == ("Car", "hatchback")  # via its parent
    assert classify("02958343", "03100240", {}) == ("Car", "convertible")  # known sub-synset
    assert classify("03792782", None, {}) == ("Bicycle", "mountain_bike")
    assert classify("04379243", None, {}) is None  # table
