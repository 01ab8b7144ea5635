"""The adapter registry and the protocol every adapter follows."""

from __future__ import annotations

import pytest

from carlaocc.catalog.sources.base import SourceAdapter
from carlaocc.catalog.sources.registry import ADAPTERS, adapter


def test_kinds():
    assert set(ADAPTERS) == {"folder", "shapenet", "buildingnet", "meshfleet", "carla", "carla-recording"}
    for kind, cls in ADAPTERS.items():
        assert cls.kind == kind
        a = adapter(kind)
        assert isinstance(a, cls)
        assert callable(a.list_items) and callable(a.read)
        _: SourceAdapter = a  # structural typing


def test_options():
    assert adapter("folder", category_map="m.csv").category_map == "m.csv"
    assert adapter("meshfleet", csv="x.csv", meshes="m").meshes == "m"
    assert adapter("buildingnet", labels_dir="labels").labels_dir == "labels"


def test_unknown_kind_names_valid_kinds():
    with pytest.raises(ValueError, match="valid kinds: buildingnet, carla, carla-recording, folder, meshfleet, shapenet"):
        adapter("objaverse")


def test_unknown_option():
    with pytest.raises(ValueError, match="accepted: category_map"):
        adapter("folder", categories="m.csv")
