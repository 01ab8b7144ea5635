"""Shared fixtures: a store per test (local temporary directory or memory://), record factories."""

from __future__ import annotations

import uuid

import pytest

from carlaocc.catalog.store import Store


@pytest.fixture(params=["local", "memory"])
def store(request, tmp_path) -> Store:
    """A fresh empty store, local and in memory (every catalog test runs on both)."""
    if request.param == "local":
        yield Store(str(tmp_path / "root"))
        return
    url = f"memory://carlaocc-test-{uuid.uuid4().hex}"
    yield Store(url)
    import fsspec

    fs = fsspec.filesystem("memory")
    root = Store(url).root
    if fs.exists(root):
        fs.rm(root, recursive=True)


@pytest.fixture
def make_asset():
    """``make_asset(asset_id, source, category)``: a minimal valid :class:`AssetRecord` (a 1 m cube)."""
    from carlaocc.schemas import taxonomy
    from carlaocc.schemas.records import AssetRecord

    def make(aid: str, source: str, category: str) -> AssetRecord:
        c = taxonomy.by_name(category)
        return AssetRecord(asset_id=aid, source=source, source_path=f"{source}://{aid}", licence="CC0-1.0",
                           category_id=c.id, category=c.name, subclass="x", extent=[1.0, 1.0, 1.0],
                           vertex_count=8, face_count=12, part_count=1, transparent_part_count=0,
                           surface_area=6.0, volume=1.0, watertight=True, geometry_hash=aid,
                           mesh_path=f"admesh/meshes/{aid}.glb")

    return make
