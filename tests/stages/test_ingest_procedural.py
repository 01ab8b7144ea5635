"""The procedural ADMesh source: determinism, closed parts, metric sizes, taxonomy coverage,
transparent parts and content-derived ids."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from schemas import taxonomy
from schemas.configs import IngestConfig
from stages.geometry import is_watertight
from stages.ingest import IngestResult, asset_id_for, ingest_procedural

ID = {name: taxonomy.by_name(name).id for name in (
    "Car", "Truck", "Bus", "Building", "Vegetation", "Pole", "TrafficLight", "TrafficSign", "Pedestrian", "Static",
)}  # fmt: skip


@pytest.fixture(scope="module")
def lib() -> IngestResult:
    return ingest_procedural(IngestConfig())


def _of(lib: IngestResult, category: str, subclass: str | None = None):
    return [a for a in lib.assets if a.category == category and (subclass is None or a.subclass == subclass)]


def _signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Divergence theorem: positive for a closed mesh with outward normals."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def test_same_seed_gives_identical_records_and_arrays(lib):
    again = ingest_procedural(IngestConfig())
    assert again.assets == lib.assets
    assert again.parts == lib.parts
    assert list(again.geometry) == list(lib.geometry)
    for aid, geom in lib.geometry.items():
        for p, q in zip(geom.parts, again.geometry[aid].parts):
            assert p.vertices.tobytes() == q.vertices.tobytes()
            assert p.faces.tobytes() == q.faces.tobytes()


def test_different_seed_gives_different_assets(lib):
    other = ingest_procedural(IngestConfig(seed=IngestConfig().seed + 1))
    assert {a.asset_id for a in other.assets}.isdisjoint({a.asset_id for a in lib.assets})
    sedans = [a.extent for a in _of(lib, "Car", "sedan")]
    assert sedans != [a.extent for a in other.assets if a.subclass == "sedan"]


def test_every_part_is_closed_and_outward(lib):
    for asset in lib.assets:
        geom = lib.geometry[asset.asset_id]
        assert asset.watertight and all(geom.part_closed), asset.source_path
        for part in geom.parts:
            assert is_watertight(part.faces), (asset.source_path, part.name)
            assert _signed_volume(part.vertices, part.faces) > 0, (asset.source_path, part.name)
    assert all(p.watertight for p in lib.parts)


def test_categories_and_subclasses(lib):
    categories = {a.category for a in lib.assets}
    assert len(categories) >= 9
    assert set(ID) <= categories
    for category, subs in {
        "Car": {"sedan", "suv", "hatchback", "van"},
        "Building": {"house", "residential", "office"},
        "Vegetation": {"tree", "bush"},
        "Pedestrian": {"adult", "child"},
        "Static": {"bench", "bin"},
        "Pole": {"street_light"},
    }.items():
        assert subs <= {a.subclass for a in _of(lib, category)}
    for a in lib.assets:
        # categories and sub-classes come from the taxonomy vocabulary
        assert taxonomy.by_name(a.category).id == a.category_id
        assert a.subclass in taxonomy.by_id(a.category_id).subclasses


@pytest.mark.parametrize(
    "category, axis, lo, hi",
    [
        ("Car", 0, 3.5, 5.5),
        ("Car", 1, 1.6, 2.1),
        ("Truck", 0, 6.0, 10.5),
        ("Bus", 0, 6.0, 13.0),
        ("Building", 2, 4.0, 60.0),
        ("Pedestrian", 2, 1.0, 2.1),
        ("Vegetation", 2, 0.5, 14.0),
        ("Pole", 2, 6.0, 10.0),
        ("TrafficLight", 2, 2.8, 7.0),
        ("TrafficSign", 2, 2.0, 3.5),
        ("Static", 2, 0.5, 1.2),
    ],
)
def test_metric_sizes(lib, category, axis, lo, hi):
    for a in _of(lib, category):
        assert lo <= a.extent[axis] <= hi, (a.source_path, a.extent)


def test_sedan_length_range_and_variants_vary():
    lib3 = ingest_procedural(IngestConfig(variants_per_subclass=3))
    lengths = [a.extent[0] for a in _of(lib3, "Car", "sedan")]
    assert len(lengths) == 3 and len(set(lengths)) == 3
    assert all(4.3 <= x <= 4.9 for x in lengths)


def test_asset_frame_origin_at_bottom_centre(lib):
    for a in lib.assets:
        V = np.concatenate([p.vertices for p in lib.geometry[a.asset_id].parts])
        lo, hi = V.min(axis=0), V.max(axis=0)
        assert lo[2] == pytest.approx(0.0, abs=1e-6)
        assert (lo[:2] + hi[:2]) / 2 == pytest.approx([0.0, 0.0], abs=1e-6)
        assert list(hi - lo) == pytest.approx(a.extent, abs=1e-6)


def test_transparent_window_parts(lib):
    for category in ("Car", "Truck", "Bus", "Building"):
        for a in _of(lib, category):
            glass = [p for p in lib.geometry[a.asset_id].parts if p.transparent]
            assert glass, a.source_path
            assert all(p.material == "glass" and p.semantic_id == a.category_id for p in glass)
    opaque_classes = {p.semantic_id for p in lib.parts if not p.transparent}
    assert ID["Car"] in opaque_classes


def test_infrastructure_parts_carry_their_own_classes(lib):
    for a in _of(lib, "TrafficLight"):
        sems = {p.name: p.semantic_id for p in lib.geometry[a.asset_id].parts}
        assert sems["pole"] == ID["Pole"] and sems["head"] == ID["TrafficLight"]
    for a in _of(lib, "TrafficSign"):
        sems = {p.name: p.semantic_id for p in lib.geometry[a.asset_id].parts}
        assert sems["pole"] == ID["Pole"] and sems["plate"] == ID["TrafficSign"]
    for a in _of(lib, "Vegetation", "tree"):
        assert {p.name for p in lib.geometry[a.asset_id].parts} == {"trunk", "crown"}


def test_records_describe_the_geometry(lib):
    parts_by_asset: dict[str, list] = {}
    for p in lib.parts:
        parts_by_asset.setdefault(p.asset_id, []).append(p)
    for a in lib.assets:
        geom = lib.geometry[a.asset_id]
        recs = parts_by_asset[a.asset_id]
        assert [r.part_index for r in recs] == list(range(len(geom.parts)))
        assert a.face_count == sum(len(p.faces) for p in geom.parts) == sum(r.face_count for r in recs)
        for r, p in zip(recs, geom.parts):
            assert (r.name, r.material, r.transparent) == (p.name, p.material, p.transparent)
            assert r.semantic_id == p.semantic_id
        assert a.source == "procedural" and a.licence == "CC0-1.0 (generated)" and a.mesh_path == ""
        assert a.source_path.startswith(f"procedural://{a.category}/{a.subclass}/")


def test_triangle_budget(lib):
    for a in lib.assets:
        limit = 2000 if a.category in ("Car", "Truck", "Bus", "Rider", "Pedestrian") else 1000
        assert a.face_count <= limit, (a.source_path, a.face_count)
    assert all(a.face_count <= 800 for a in _of(lib, "Building"))


def test_asset_ids_unique_and_content_derived(lib):
    ids = [a.asset_id for a in lib.assets]
    assert len(set(ids)) == len(ids)
    for a in lib.assets:
        geom = lib.geometry[a.asset_id]
        assert len(a.asset_id) == 16 and int(a.asset_id, 16) >= 0
        assert asset_id_for(a.category, a.subclass, list(geom.parts)) == a.asset_id
    a = _of(lib, "Car", "sedan")[0]
    parts = list(lib.geometry[a.asset_id].parts)
    moved = parts[0].vertices.copy()
    moved[0, 0] += 0.001  # one vertex, one millimetre
    changed = [replace(parts[0], vertices=moved)] + parts[1:]
    assert asset_id_for(a.category, a.subclass, changed) != a.asset_id
    assert asset_id_for(a.category, "suv", parts) != a.asset_id
