"""The procedural ADMesh source: determinism, closed parts, metric sizes, taxonomy coverage,
transparent parts and content-derived ids."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import IngestConfig
from carlaocc.stages.geometry import is_watertight
from carlaocc.stages.ingest import IngestResult, asset_id_for, ingest_procedural

ID = {name: taxonomy.by_name(name).id for name in (
    "Car", "Truck", "Bus", "Train", "Building", "Vegetation", "Pole", "TrafficLight", "TrafficSign", "Pedestrian",
    "Static",
)}  # fmt: skip
POLE_RADIUS_ASSUMED = 0.09  # stages.scenes.placing.POLE_RADIUS: every procedural pole is within 5 cm of it


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
    # every thing class of the taxonomy (the road users and Building) has assets, Train included
    assert {taxonomy.by_id(i).name for i in taxonomy.thing_ids()} <= categories
    assert set(ID) <= categories
    for category, subs in {
        "Car": {"sedan", "suv", "hatchback", "van", "coupe", "wagon", "minivan", "pickup", "taxi", "police"},
        "Truck": {"box_truck", "tanker", "fire_truck", "semi_truck", "garbage_truck", "cement_mixer", "dump_truck"},
        "Bus": {"city_bus", "minibus", "coach", "school_bus", "double_decker"},
        "Train": {"tram", "metro", "train"},
        "Motorcycle": {"sport", "cruiser", "scooter", "moped"},
        "Bicycle": {"city_bike", "road_bike", "mountain_bike", "cargo_bike"},
        "Rider": {"cyclist", "motorcyclist"},
        "Pedestrian": {"adult", "child"},
        "Building": {"house", "residential", "apartment", "office", "tower", "commercial", "industrial",
                     "warehouse", "garage", "gas_station", "religious", "public"},
        "Vegetation": {"tree", "conifer", "bush", "palm", "hedge"},
        "Pole": {"street_light", "utility_pole"},
        "TrafficLight": {"vehicle_signal", "pedestrian_signal", "overhead_signal"},
        "TrafficSign": {"stop", "yield", "speed_limit", "no_entry", "one_way", "pedestrian_crossing", "parking"},
        "Static": {"bench", "bin", "hydrant", "bus_stop", "bollard", "traffic_cone", "phone_booth"},
    }.items():  # fmt: skip
        assert subs <= {a.subclass for a in _of(lib, category)}, category
    for a in lib.assets:
        # categories and sub-classes come from the taxonomy vocabulary
        assert taxonomy.by_name(a.category).id == a.category_id
        assert a.subclass in taxonomy.by_id(a.category_id).subclasses


def test_default_library_has_200_distinct_assets(lib):
    assert len(lib.assets) >= 200
    assert len({a.geometry_hash for a in lib.assets}) == len(lib.assets) >= 200
    # every sub-class has the configured number of variants
    per_sub = {}
    for a in lib.assets:
        per_sub[(a.category, a.subclass)] = per_sub.get((a.category, a.subclass), 0) + 1
    assert set(per_sub.values()) == {IngestConfig().variants_per_subclass}


def test_variants_do_not_depend_on_the_variant_count(lib):
    # variant k of a sub-class is drawn from its own generator: asking for fewer variants gives a prefix
    one = ingest_procedural(IngestConfig(variants_per_subclass=1))
    firsts = [a for a in lib.assets if a.source_path.endswith("/0")]
    assert [a.asset_id for a in one.assets] == [a.asset_id for a in firsts]


@pytest.mark.parametrize(
    "category, axis, lo, hi",
    [
        ("Car", 0, 3.5, 5.5),
        ("Car", 1, 1.6, 2.1),
        ("Truck", 0, 6.0, 17.0),
        ("Truck", 1, 2.2, 2.6),
        ("Truck", 2, 2.5, 4.1),
        ("Bus", 0, 6.0, 14.0),
        ("Bus", 2, 2.5, 4.45),
        ("Train", 0, 16.0, 33.0),
        ("Train", 1, 2.2, 3.2),
        ("Motorcycle", 0, 1.5, 2.4),
        ("Bicycle", 0, 1.5, 2.8),
        ("Rider", 2, 1.5, 2.0),
        ("Building", 2, 2.5, 140.0),
        ("Pedestrian", 2, 1.0, 2.1),
        ("Vegetation", 2, 0.5, 14.0),
        ("Pole", 2, 6.0, 12.5),
        ("TrafficLight", 2, 2.3, 7.0),
        ("TrafficSign", 2, 2.0, 3.5),
        ("Static", 2, 0.3, 7.5),
        ("Dynamic", 2, 0.2, 1.8),
    ],
)
def test_metric_sizes(lib, category, axis, lo, hi):
    assert _of(lib, category)
    for a in _of(lib, category):
        assert lo <= a.extent[axis] <= hi, (a.source_path, a.extent)


@pytest.mark.parametrize(
    "category, subclass, axis, lo, hi",
    [
        ("Truck", "semi_truck", 0, 14.5, 17.0),
        ("Bus", "double_decker", 2, 4.1, 4.45),
        ("Building", "tower", 2, 70.0, 140.0),
        ("Building", "house", 2, 4.0, 10.0),
        ("Building", "garage", 2, 2.5, 3.5),
        ("Car", "pickup", 0, 5.0, 5.5),
        ("Train", "tram", 0, 20.0, 32.5),
        ("Pedestrian", "child", 2, 1.0, 1.45),
        ("Static", "bench", 2, 0.7, 1.0),
        ("Static", "traffic_cone", 2, 0.45, 0.8),
    ],
)
def test_subclass_sizes(lib, category, subclass, axis, lo, hi):
    assert _of(lib, category, subclass)
    for a in _of(lib, category, subclass):
        assert lo <= a.extent[axis] <= hi, (a.source_path, a.extent)


def test_sedan_length_range_and_variants_vary(lib):
    lengths = [a.extent[0] for a in _of(lib, "Car", "sedan")]
    assert len(lengths) == IngestConfig().variants_per_subclass == len(set(lengths))
    assert all(4.3 <= x <= 4.9 for x in lengths)


def test_asset_frame_origin_at_bottom_centre(lib):
    for a in lib.assets:
        V = np.concatenate([p.vertices for p in lib.geometry[a.asset_id].parts])
        lo, hi = V.min(axis=0), V.max(axis=0)
        assert lo[2] == pytest.approx(0.0, abs=1e-6)
        assert (lo[:2] + hi[:2]) / 2 == pytest.approx([0.0, 0.0], abs=1e-6)
        assert list(hi - lo) == pytest.approx(a.extent, abs=1e-6)


def test_transparent_window_parts(lib):
    for category in ("Car", "Truck", "Bus", "Train", "Building"):
        for a in _of(lib, category):
            glass = [p for p in lib.geometry[a.asset_id].parts if p.transparent]
            assert glass, a.source_path
            assert a.transparent_part_count == len(glass)
            assert all(p.material == "glass" and p.semantic_id == a.category_id for p in glass)
    for subclass in ("bus_stop", "phone_booth"):
        for a in _of(lib, "Static", subclass):
            assert any(p.transparent for p in lib.geometry[a.asset_id].parts), a.source_path
    opaque_classes = {p.semantic_id for p in lib.parts if not p.transparent}
    assert ID["Car"] in opaque_classes
    # glass is never the whole of an asset
    for a in lib.assets:
        assert a.transparent_part_count < a.part_count


def test_road_vehicles_stand_on_their_wheels(lib):
    for category in ("Car", "Truck", "Bus", "Motorcycle", "Bicycle", "Rider"):
        for a in _of(lib, category):
            parts = lib.geometry[a.asset_id].parts
            wheels = [p for p in parts if p.name.startswith("wheel")]
            assert len(wheels) >= 2, a.source_path
            assert min(p.vertices[:, 2].min() for p in wheels) == pytest.approx(0.0, abs=1e-6)
            # the other parts ride above the ground
            others = [p for p in parts if not p.name.startswith("wheel")]
            assert min(p.vertices[:, 2].min() for p in others) > 0.01, a.source_path


def test_pole_axis_conventions(lib):
    """The pole of pole-like assets is where the module docstring says (the town anchors them by it)."""
    for a in lib.assets:
        if a.category not in ("Pole", "TrafficLight", "TrafficSign"):
            continue
        pole = next(p for p in lib.geometry[a.asset_id].parts if p.name == "pole")
        V = pole.vertices
        r = (V[:, 0].max() - V[:, 0].min()) / 2
        assert abs(r - POLE_RADIUS_ASSUMED) <= 0.05, (a.source_path, r)
        axis_x, axis_y = (V[:, 0].max() + V[:, 0].min()) / 2, (V[:, 1].max() + V[:, 1].min()) / 2
        assert axis_x == pytest.approx(-a.extent[0] / 2 + r, abs=1e-6), a.source_path
        want_y = a.extent[1] / 2 - r if a.subclass == "overhead_signal" else 0.0
        assert axis_y == pytest.approx(want_y, abs=1e-6), a.source_path
        assert V[:, 2].min() == pytest.approx(0.0, abs=1e-6)


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
        limit = 2000 if a.category in ("Car", "Truck", "Bus", "Train", "Rider", "Pedestrian") else 1000
        assert a.face_count <= limit, (a.source_path, a.face_count)
    assert all(a.face_count <= 800 for a in _of(lib, "Building"))
    # the whole default library stays light (the town voxelizes whole frames at 0.05 m)
    assert sum(a.face_count for a in lib.assets) <= 120_000


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
