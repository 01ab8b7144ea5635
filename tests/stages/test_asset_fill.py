"""Per-asset fill figures of the ADMesh library (issue 18): how each asset is filled under
``auto`` (``fill_method``) and how much of its volume came from hole handling
(``hole_fill_voxels``, ``hole_fill_fraction``) at the reference voxel size, recorded at ingest
(standardized and procedural assets) and queryable in SQL; tables written before these columns
existed still load."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest
import trimesh
from carlaocc.catalog.parquet import ParquetTable, table_bytes, to_table
from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from carlaocc.schemas.configs import IngestConfig
from carlaocc.schemas.meshes import AssetGeometry, SourceAsset, SourcePart
from carlaocc.schemas.records import AssetRecord
from carlaocc.stages.ingest.procedural import ingest_procedural
from carlaocc.stages.ingest.standardize import StandardizedAsset, standardize
from carlaocc.stages.voxelize.breakdown import (
    asset_fill,
    asset_meshes,
    fill_breakdown,
    reference_grid,
    reference_voxel_size,
)
from carlaocc.stages.voxelize.fill import fills
from shared_data import require, shared_path
from typer.testing import CliRunner

cli = CliRunner()
VS = 0.05  # the reference voxel of the single assets below (none is longer than 12.8 m)


@pytest.fixture
def fine_reference(monkeypatch):
    """The single-asset figures at 0.05 m, up to 256 voxels a side (the library's default
    reference is coarser, for ingest speed), so the hand-counted interiors below apply."""
    import carlaocc.stages.voxelize.breakdown as B

    monkeypatch.setattr(B, "FILL_REFERENCE_VOXEL", VS)
    monkeypatch.setattr(B, "FILL_REFERENCE_MAX_EDGE", 256)
FILL_COLUMNS = ("fill_method", "fill_voxel_size", "fill_voxels", "hole_fill_voxels", "hole_fill_fraction")


# -- meshes (asset frame: metres, Z up) -----------------------------------------------------------
def _box(size, centre=(0.0, 0.0, 0.0), floor: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A box, faces outward; ``floor=False`` drops its two bottom triangles (an open floor)."""
    m = trimesh.creation.box(size)
    V = np.asarray(m.vertices) + np.asarray(centre)
    F = np.asarray(m.faces)
    if not floor:
        F = F[np.asarray(m.face_normals)[:, 2] > -0.5]
    return V, F


def _source(category: str, subclass: str, parts: dict[str, tuple[np.ndarray, np.ndarray]]) -> SourceAsset:
    return SourceAsset(source="folder", source_path=f"test://{category}/{subclass}", licence="CC0-1.0",
                       category=category, subclass=subclass, units="m",
                       parts=tuple(SourcePart(name, V, F) for name, (V, F) in parts.items()))


def _ingest(category: str, subclass: str, parts) -> StandardizedAsset:
    s = standardize(_source(category, subclass, parts))
    assert isinstance(s, StandardizedAsset), s
    return s


def _consistent(a: AssetRecord) -> None:
    """The recorded fraction is hole voxels over occupied voxels, at the reference voxel size."""
    assert a.fill_voxel_size == pytest.approx(reference_voxel_size(np.array(a.extent)))
    assert a.fill_voxels > 0
    assert a.hole_fill_fraction == pytest.approx(a.hole_fill_voxels / a.fill_voxels)


# -- the figures of single assets -----------------------------------------------------------------
# a house 6.025 x 5.025 x 5.0125 m: after standardization (origin at the bottom centre) its walls
# and roof lie a quarter voxel off the 0.05 m lattice, so no voxel centre is on a face and the
# interior is 120 x 100 x 100 voxel centres (x: -60.25 < i + 0.5 < 60.25, z: 0 < k + 0.5 < 100.25)
HOUSE = (6.025, 5.025, 5.0125)
HOUSE_INTERIOR = 120 * 100 * 100


def test_open_box_building_records_winding_and_its_interior_from_holes(fine_reference):
    """A building without its floor: winding numbers fill it, and every filled voxel is reachable
    from outside through the open floor -- all of the interior came from hole handling."""
    open_house = _ingest("Building", "house", {"walls": _box(HOUSE, (0, 0, HOUSE[2] / 2), floor=False)})
    a = open_house.asset
    assert not a.watertight and a.fill_method == "winding"
    assert a.fill_voxel_size == VS
    assert a.hole_fill_voxels == pytest.approx(HOUSE_INTERIOR, rel=0.03)
    _consistent(a)
    # the same box with its floor: parity, the same volume, nothing from holes
    closed_house = _ingest("Building", "house", {"walls": _box(HOUSE, (0, 0, HOUSE[2] / 2))}).asset
    assert closed_house.watertight and closed_house.fill_method == "parity"
    assert closed_house.hole_fill_voxels == 0 and closed_house.hole_fill_fraction == 0.0
    assert a.fill_voxels == pytest.approx(closed_house.fill_voxels, rel=0.03)
    # what is recorded is what asset_fill measures on the standardized geometry
    f = asset_fill(open_house.geometry)
    assert (f.method, f.voxels, f.from_holes) == (a.fill_method, a.fill_voxels, a.hole_fill_voxels)
    assert f.filled == pytest.approx(HOUSE_INTERIOR, rel=0.03) and f.from_holes <= f.filled


def test_watertight_procedural_asset_records_parity_and_no_holes(fine_reference):
    lib = ingest_procedural(IngestConfig(variants_per_subclass=1))
    by_sub = {(a.category, a.subclass): a for a in lib.assets}
    for key in [("Car", "sedan"), ("Building", "house"), ("Pole", "street_light")]:
        a = by_sub[key]
        assert a.watertight and a.fill_method == "parity", key
        assert a.hole_fill_voxels == 0 and a.hole_fill_fraction == 0.0
        _consistent(a)
    # parity skips the flood fill; measuring it anyway finds no filled voxel reachable from outside
    for key in [("Car", "sedan"), ("Building", "house")]:
        geom = lib.geometry[by_sub[key].asset_id]
        meshes, method = asset_meshes(geom)
        b = fill_breakdown(meshes, reference_grid(meshes), "auto")
        f = asset_fill(geom)
        assert method == "parity" and b.filled > 0 and b.from_holes == 0
        assert (f.voxels, f.filled) == (b.total, b.filled) and f.voxels == by_sub[key].fill_voxels


def test_vegetation_fills_the_trunk_only(fine_reference):
    """A tree's crown is foliage, not a solid: only the part named trunk is filled, so the crown's
    interior is not counted in the asset's voxels."""
    # a quarter voxel off the lattice, but for the ground: no face but the trunk's ends on a lattice plane
    trunk = _box((0.425, 0.425, 2.2), (0, 0, 1.1))
    crown = _box((3.025, 3.025, 3.025), (0, 0, 3.5))
    tree = _ingest("Vegetation", "tree", {"trunk": trunk, "crown": crown})
    a = tree.asset
    assert a.fill_method == "parity" and a.hole_fill_voxels == 0
    _consistent(a)
    crown_only = asset_fill(AssetGeometry("c", (tree.geometry.parts[1],), (True,)))
    assert crown_only.method == "surface" and crown_only.filled == 0
    f = asset_fill(tree.geometry)
    # the fill added the trunk's inside (8 x 8 columns of 44 voxel centres, less the layers its
    # ends and the crown's bottom paint) and no more: the trunk is at most 10 x 10 x 46 voxels
    assert 8 * 8 * 41 <= f.filled <= 8 * 8 * 44
    assert crown_only.voxels < a.fill_voxels <= crown_only.voxels + 10 * 10 * 46
    assert a.fill_voxels < (3.0 / VS) ** 3 / 4  # far below a solid crown
    # an open trunk (no bottom) is filled by winding numbers; the crown still stays a surface
    open_tree = _ingest("Vegetation", "tree", {"trunk": _box((0.425, 0.425, 2.2), (0, 0, 1.1), floor=False),
                                               "crown": crown}).asset
    assert open_tree.fill_method == "winding"
    assert open_tree.fill_voxels == pytest.approx(a.fill_voxels, rel=0.02)
    # the crown alone, named like one: a surface asset
    assert _ingest("Vegetation", "bush", {"crown": _box((1.0, 1.0, 0.8), (0, 0, 0.4))}).asset.fill_method == "surface"


@pytest.mark.parametrize("category, subclass, size", [("Fence", "metal_fence", (3.0, 0.3, 1.2)),
                                                      ("Road", "lane", (10.0, 4.0, 0.3))])
def test_thin_and_open_classes_record_surface_and_nothing_filled(category, subclass, size, fine_reference):
    """Fence and Road stay surfaces under ``auto`` even as closed boxes with room inside."""
    s = _ingest(category, subclass, {category.lower(): _box(size)})
    a = s.asset
    assert a.watertight and a.fill_method == "surface"
    assert a.hole_fill_voxels == 0 and a.hole_fill_fraction == 0.0
    _consistent(a)
    meshes, _ = asset_meshes(s.geometry)
    grid = reference_grid(meshes)
    auto = fill_breakdown(meshes, grid, "auto")
    assert auto.filled == 0 and a.fill_voxels == auto.surface == asset_fill(s.geometry).voxels
    assert fill_breakdown(meshes, grid, "solid").filled > 0  # the rule, not the geometry, leaves it hollow


def test_breakdown_of_an_unfilled_voxelization_reuses_it(monkeypatch):
    """Nothing filled under the mode (``surface``, or only classes ``auto`` leaves hollow): the
    voxelization passed as ``solid`` is the surface one, so the counts come without a second
    voxelization or a flood fill -- the same counts as computed from scratch."""
    import carlaocc.stages.voxelize.breakdown as breakdown
    from carlaocc.schemas.grid import GridSpec
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.schemas.taxonomy import by_name
    from carlaocc.stages.voxelize import voxelize_scene

    V, F = _box((2.0, 1.0, 1.0))
    grid = GridSpec(region_min=(-1.5, -1.0, -1.0), region_max=(1.5, 1.0, 1.0), voxel_size=0.1)
    cases = [([SceneMesh(V, F, by_name("Building").id, 0, True, closed=True)], "surface"),
             ([SceneMesh(V, F, by_name("Fence").id, 0, True, closed=True)], "auto")]
    for meshes, fill in cases:
        solid, _ = voxelize_scene(meshes, grid, fill=fill)
        want = fill_breakdown(meshes, grid, fill)
        assert want.surface == int((solid > 0).sum()) > 0 and want.filled == 0 and want.from_holes == 0
        with monkeypatch.context() as m:
            m.setattr(breakdown, "voxelize_scene", lambda *a, **k: pytest.fail("voxelized again"))
            m.setattr(breakdown, "outside", lambda *a, **k: pytest.fail("flood-filled"))
            assert fill_breakdown(meshes, grid, fill, solid=solid) == want
    # a filled mesh still gets both voxelizations (its surface is not the solid)
    meshes = [SceneMesh(V, F, by_name("Building").id, 0, True, closed=True)]
    solid, _ = voxelize_scene(meshes, grid, fill="auto")
    assert fill_breakdown(meshes, grid, "auto", solid=solid).filled > 0


# -- the library in SQL ---------------------------------------------------------------------------
def test_an_ingested_library_answers_fill_queries_and_old_tables_still_load(tmp_path):
    root = tmp_path / "data"
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("ingest:\n  variants_per_subclass: 1\n")
    r = cli.invoke(app, ["run", "--stages", "ingest", "--root", str(root), "--config", str(cfg),
                         "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    store = Store(str(root))
    cols, rows = query(store, "SELECT fill_method, count(*), sum(hole_fill_voxels), min(fill_voxels), "
                              "min(fill_voxel_size) FROM assets GROUP BY 1 ORDER BY 1")
    assert cols[0] == "fill_method"
    by_method = {m: rest for m, *rest in rows}
    # the procedural builders make closed parts: filled ones by parity, nothing from holes
    assert set(by_method) == {"parity", "surface"}
    assert by_method["parity"][0] > by_method["surface"][0] > 0
    assert all(holes == 0 and vox > 0 and size >= VS for _, holes, vox, size in by_method.values())
    # a surface asset is exactly one none of whose parts the rule fills
    _, parts = query(store, "SELECT a.fill_method, p.semantic_id, p.name FROM parts p JOIN assets a USING (asset_id)")
    for method, sid, name in parts:
        assert method == "parity" or not fills(sid, name), (method, sid, name)
    _, rows = query(store, "SELECT " + ", ".join(FILL_COLUMNS) + " FROM assets WHERE category = 'Vegetation' "
                           "AND subclass = 'tree'")
    assert [r[0] for r in rows] == ["parity"]  # its trunk

    # a table file written before the fill columns existed loads with their defaults
    old = to_table(AssetRecord, ParquetTable(store, AssetRecord).load()[:1]).drop_columns(list(FILL_COLUMNS))
    old = old.set_column(0, "asset_id", pa.array(["0ld0ld0ld0ld0ld0"]))
    store.write_bytes(ParquetTable(store, AssetRecord).path("source=folder/old"), table_bytes(old))
    _, rows = query(store, "SELECT " + ", ".join(FILL_COLUMNS) + " FROM assets WHERE asset_id = '0ld0ld0ld0ld0ld0'")
    assert rows == [("", 0.0, 0, 0, 0.0)]


# -- real meshes through the folder source --------------------------------------------------------
KENNEY = {  # file -> (category, sub-class, how auto fills it)
    "kenney-roads/road-straight.glb": ("Road", "lane", "surface"),
    "kenney-retro-urban/detail-light-single.glb": ("Pole", "street_light", "parity"),  # watertight
    "kenney-roads/construction-cone.glb": ("Static", "traffic_cone", "winding"),  # open
    "kenney-suburban/tree-large.glb": ("Vegetation", "tree", "surface"),  # one part, no trunk
    "kenney-suburban/building-type-a.glb": ("Building", "house", "winding"),  # not watertight
}


def test_kenney_meshes_ingested_from_a_folder_record_their_fill(tmp_path):
    meshes = require(shared_path("meshes"))
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\n" + "".join(f"{k},{c},{s}\n" for k, (c, s, _) in KENNEY.items()))
    store = Store(str(tmp_path / "data"))
    r = cli.invoke(app, ["ingest", "folder", str(meshes), "--category-map", str(cmap), "--root", store.url,
                         "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    _, rows = query(store, "SELECT source_path, watertight, " + ", ".join(FILL_COLUMNS) + " FROM assets")
    got = {p.split("testdata/meshes/")[-1]: rest for p, *rest in rows}
    assert set(got) == set(KENNEY)
    for key, (watertight, method, size, voxels, holes, fraction) in got.items():
        assert method == KENNEY[key][2], key
        if method != "surface":  # a filled asset: parity exactly when watertight
            assert watertight == (method == "parity"), key
        assert voxels > 0 and 0 <= holes <= voxels
        assert fraction == pytest.approx(holes / voxels)
        # the library's reference voxel: 0.1 m, coarser for assets longer than 6.4 m
        assert size >= 0.1 - 1e-12


def test_outside_is_the_complement_of_binary_fill_holes():
    """The flood fill from the boundary (one labelling pass) finds what scipy's hole filling
    leaves out, on random grids with enclosed pockets and on a shell with one opening."""
    from carlaocc.stages.voxelize.breakdown import outside
    from scipy import ndimage

    rng = np.random.default_rng(3)
    for density in (0.3, 0.5, 0.65):
        surf = rng.random((23, 17, 29)) < density
        assert np.array_equal(outside(surf), ~ndimage.binary_fill_holes(surf))
    shell = np.zeros((12, 12, 12), dtype=bool)
    shell[2:10, 2:10, 2:10] = True
    shell[3:9, 3:9, 3:9] = False
    assert not outside(shell)[5, 5, 5]
    shell[5, 5, 2] = False  # a one-voxel hole in the bottom
    assert outside(shell)[5, 5, 5] and np.array_equal(outside(shell), ~ndimage.binary_fill_holes(shell))
