"""The in-memory mesh contracts: one home (``carlaocc.schemas.meshes``), frozen, fields as the layers use
them; catalog source adapters return them and standardization accepts them as they are."""

import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from carlaocc.schemas import meshes
from carlaocc.schemas.meshes import AssetGeometry, MeshPart, SceneMesh, SourceAsset, SourcePart

ROOT = Path(__file__).resolve().parents[2]
CONTRACTS = ("MeshPart", "SceneMesh", "AssetGeometry", "SourcePart", "SourceAsset", "Axis", "Units")
# names of the duplicates and bridges the contracts replaced: they must not come back
RETIRED = ("RawAsset", "RawPart", "MeshPartLike", "_raw_asset")


def _fields(cls) -> list[tuple[str, object]]:
    return [(f.name, f.default) for f in dataclasses.fields(cls)]


def test_fields_order_and_defaults():
    M = dataclasses.MISSING
    assert _fields(SourcePart) == [("name", M), ("vertices", M), ("faces", M), ("material", "default"),
                                   ("transparent", False), ("texture", ""), ("semantic_id", None), ("color", None),
                                   ("corner_uv", None), ("image", None)]
    assert _fields(SourceAsset) == [
        ("source", M), ("source_path", M), ("licence", M), ("category", M), ("subclass", M), ("parts", M),
        ("up", "+z"), ("forward", "+x"), ("units", "unknown"), ("normalized", False), ("target_length", None),
        ("licence_required", False), ("notes", ()),
    ]  # fmt: skip
    assert _fields(MeshPart) == [("name", M), ("vertices", M), ("faces", M), ("semantic_id", M),
                                 ("material", "default"), ("transparent", False), ("color", (200, 200, 200, 255)),
                                 ("corner_uv", None), ("image", None)]
    assert _fields(AssetGeometry) == [("asset_id", M), ("parts", M), ("part_closed", M)]
    assert [f for f, _ in _fields(SceneMesh)] == ["vertices", "faces", "semantic_id", "instance_id", "is_stuff",
                                                  "closed", "name", "transparent", "asset_id", "part", "color",
                                                  "corner_uv", "image"]


def test_frozen_and_arrays_coerced():
    p = MeshPart("p", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]], 14)
    assert p.vertices.dtype == np.float64 and p.faces.dtype == np.int64 and p.vertices.flags.c_contiguous
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.name = "q"  # type: ignore[misc]
    s = SceneMesh(np.zeros((3, 3), np.float32), np.array([[0, 1, 2]], np.int32), 1, 0, True, False)
    assert s.vertices.dtype == np.float64 and s.faces.dtype == np.int64


def _code_files():
    for top in ("schemas", "stages", "catalog", "pipeline", "carlaocc", "tests", "benchmarks", "tools"):
        yield from sorted((ROOT / top).rglob("*.py"))


def test_one_home_and_no_retired_bridges():
    """Only ``schemas/meshes.py`` defines the contracts (class or alias); the retired duplicates
    and converters are defined and imported nowhere."""
    home = Path(meshes.__file__).resolve()
    offenders = []
    for path in _code_files():
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            names = []
            if isinstance(node, (ast.ClassDef, ast.FunctionDef)):
                names = [node.name]
            elif isinstance(node, ast.Assign):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
            elif isinstance(node, ast.ImportFrom):
                names = [a.name for a in node.names if a.name in RETIRED]
            for name in names:
                if name in RETIRED or (name in CONTRACTS and path.resolve() != home and node.col_offset == 0
                                       and not isinstance(node, ast.ImportFrom)):
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} {name}")
    assert not offenders, offenders
