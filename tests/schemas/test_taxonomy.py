"""Tests of the CarlaOcc taxonomy table (schemas/taxonomy.py)."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pydantic
import pytest

from carlaocc.schemas import taxonomy as tx
from shared_data import require, shared_path

SEMANTIC_KITTI_YAML = shared_path("occupancy/semantic-kitti/semantic-kitti.yaml")

ROAD_USERS = ("Pedestrian", "Rider", "Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle")

CARLA_NAMES = (
    "None", "Road", "Sidewalk", "Building", "Wall", "Fence", "Pole", "TrafficLight",
    "TrafficSign", "Vegetation", "Terrain", "Sky", "Pedestrian", "Rider", "Car", "Truck", "Bus",
    "Train", "Motorcycle", "Bicycle", "Static", "Dynamic", "Other", "Water", "RoadLine",
    "Ground", "Bridge", "RailTrack", "GuardRail", "Rock",
)  # fmt: skip

# CarlaOcc class -> SemanticKITTI raw label name, where the counterpart is unambiguous.
SEMANTICKITTI_COUNTERPARTS = {
    "Car": "car",
    "Bicycle": "bicycle",
    "Motorcycle": "motorcycle",
    "Truck": "truck",
    "Bus": "bus",
    "Train": "on-rails",
    "Pedestrian": "person",
    "Road": "road",
    "RoadLine": "lane-marking",
    "Sidewalk": "sidewalk",
    "Building": "building",
    "Fence": "fence",
    "Vegetation": "vegetation",
    "Terrain": "terrain",
    "Pole": "pole",
    "TrafficSign": "traffic-sign",
}


def _target_name(target: str, class_name: str) -> str:
    """Name (lower case) of the target class that ``class_name`` maps to."""
    tid = tx.mapping(target)[tx.by_name(class_name).id]
    return tx.TARGETS[target][tid].lower()


# --- the table -------------------------------------------------------------------------------


def test_thirty_rows_in_id_order_with_carla_names() -> None:
    assert len(tx.CLASSES) == 30
    assert [c.id for c in tx.CLASSES] == list(range(30))
    assert tuple(c.name for c in tx.CLASSES) == CARLA_NAMES


def test_names_and_colors_unique() -> None:
    assert len({c.name.lower() for c in tx.CLASSES}) == 30
    assert len({c.color for c in tx.CLASSES}) == 30
    for c in tx.CLASSES:
        assert len(c.color) == 3 and all(0 <= v <= 255 for v in c.color), c.name


def test_carla_palette_spot_checks() -> None:
    assert tx.by_name("Road").color == (128, 64, 128)
    assert tx.by_name("Car").color == (0, 0, 142)
    assert tx.by_name("Pedestrian").color == (220, 20, 60)
    assert tx.by_name("Vegetation").color == (107, 142, 35)
    assert tx.by_name("None").color == (0, 0, 0)
    assert tx.palette() == tuple(c.color for c in tx.CLASSES)


def test_subclasses_are_unique_snake_case() -> None:
    for c in tx.CLASSES:
        assert len(set(c.subclasses)) == len(c.subclasses), c.name
        for s in c.subclasses:
            assert s == s.lower() and " " not in s and s, (c.name, s)
    assert {"sedan", "suv", "van", "pickup"} <= set(tx.by_name("Car").subclasses)
    assert {"residential", "office"} <= set(tx.by_name("Building").subclasses)
    assert {"adult", "child"} <= set(tx.by_name("Pedestrian").subclasses)


def test_version_is_a_nonempty_string() -> None:
    assert isinstance(tx.TAXONOMY_VERSION, str) and tx.TAXONOMY_VERSION


# --- kinds and motion --------------------------------------------------------------------------


def test_road_users_are_things_and_dynamic() -> None:
    ids = {tx.by_name(n).id for n in ROAD_USERS}
    assert ids <= set(tx.thing_ids())
    assert ids <= set(tx.dynamic_ids())
    for n in ROAD_USERS:
        c = tx.by_name(n)
        assert c.kind == "thing" and c.motion == "dynamic", n


def test_things_and_stuff_partition_the_table() -> None:
    things, stuff = set(tx.thing_ids()), set(tx.stuff_ids())
    assert things.isdisjoint(stuff)
    assert things | stuff == set(range(30))
    assert tx.thing_ids() == tuple(sorted(things))
    for name in ("None", "Sky", "Road", "Vegetation", "Terrain"):
        assert tx.by_name(name).id in stuff, name
        assert tx.by_name(name).motion == "static", name
    # the release: poles, lights and signs are instances, buildings are not; none of them moves
    for name in ("Pole", "TrafficLight", "TrafficSign"):
        assert tx.by_name(name).kind == "thing" and tx.by_name(name).motion == "static", name
    assert tx.by_name("Building").kind == "stuff"
    # carlaocc-v1: the other way round
    v1 = tx.label_table("carlaocc-v1")
    assert v1.by_id(tx.by_name("Building").id).kind == "thing"
    assert not {tx.by_name(n).id for n in ("Pole", "TrafficLight", "TrafficSign")} & set(v1.thing_ids())
    for table in tx.LABEL_TABLES.values():
        assert set(table.thing_ids()) | set(table.stuff_ids()) == set(range(30))
        assert {tx.by_name(n).id for n in ROAD_USERS} <= set(table.thing_ids())


# --- the release's label table ------------------------------------------------------------------

# fengyi233/carlaocc utils/labels.py (commit de6a21c), transcribed independently of the module
# under test: (name, is_instance, colour, nuscenes_id, kitti360_id) per id 0..29.
RELEASE_LABELS_PY = [
    ("None", False, (0, 0, 0), 17, 0), ("Road", False, (128, 64, 128), 11, 7),
    ("Sidewalk", False, (244, 35, 232), 13, 9), ("Building", False, (70, 70, 70), 15, 11),
    ("Wall", False, (102, 102, 156), 15, 17), ("Fence", False, (190, 153, 153), 1, 12),
    ("Pole", True, (153, 153, 153), 15, 15), ("TrafficLight", True, (250, 170, 30), 0, 16),
    ("TrafficSign", True, (220, 220, 0), 0, 16), ("Vegetation", False, (107, 142, 35), 16, 13),
    ("Terrain", False, (152, 251, 152), 14, 14), ("Sky", False, (70, 130, 180), 17, 0),
    ("Pedestrian", True, (220, 20, 60), 7, 6), ("Rider", True, (255, 0, 0), 7, 6),
    ("Car", True, (0, 0, 142), 4, 1), ("Truck", True, (0, 0, 70), 10, 4),
    ("Bus", True, (0, 60, 100), 3, 5), ("Train", True, (0, 80, 100), 9, 5),
    ("Motorcycle", True, (0, 0, 230), 6, 3), ("Bicycle", True, (119, 11, 32), 2, 2),
    ("Static", False, (110, 190, 160), 0, 18), ("Dynamic", False, (170, 120, 50), 0, 18),
    ("Other", False, (55, 90, 80), 0, 18), ("Water", False, (45, 60, 150), 12, 10),
    ("RoadLine", False, (157, 234, 50), 11, 7), ("Ground", False, (81, 0, 81), 14, 10),
    ("Bridge", False, (150, 100, 100), 15, 17), ("RailTrack", False, (230, 150, 140), 12, 10),
    ("GuardRail", False, (180, 165, 180), 1, 12), ("Rock", False, (180, 130, 70), 14, 14),
]


def test_the_default_table_is_the_release_row_by_row() -> None:
    assert tx.DEFAULT_LABEL_TABLE == "release" and tx.label_table().name == "release"
    table = tx.label_table("release")
    assert len(RELEASE_LABELS_PY) == 30
    for i, (name, is_instance, color, nus, k360) in enumerate(RELEASE_LABELS_PY):
        c = table.by_id(i)
        assert (c.name, c.kind == "thing", c.color, c.occ3d_nuscenes, c.sscbench_kitti360) == \
            (name, is_instance, color, nus, k360), i
        assert tx.by_id(i) == c  # module-level lookups are the default table's


def test_carlaocc_v1_differs_from_the_release_in_nine_rows() -> None:
    v1, rel = tx.label_table("carlaocc-v1"), tx.label_table("release")
    differ = [a.name for a, b in zip(v1.classes, rel.classes) if a != b]
    assert differ == ["Building", "Fence", "Pole", "TrafficLight", "TrafficSign", "Train", "Static", "Ground",
                      "GuardRail"]
    # the release's Occ3D ids: barrier, others, terrain, trailer
    occ = tx.OCC3D_NUSCENES_NAMES
    for name, want in (("Fence", "barrier"), ("GuardRail", "barrier"), ("TrafficLight", "others"),
                       ("TrafficSign", "others"), ("Static", "others"), ("Ground", "terrain"), ("Train", "trailer")):
        assert occ[tx.mapping("occ3d_nuscenes", "release")[tx.by_name(name).id]] == want, name
        assert occ[tx.mapping("occ3d_nuscenes", "carlaocc-v1")[tx.by_name(name).id]] != want, name
    # KITTI-360, SemanticKITTI and the 15 classes agree
    for target in ("sscbench_kitti360", "semantickitti", "benchmark15"):
        assert v1.mapping(target) == rel.mapping(target), target


def test_unknown_label_table_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="valid: release, carlaocc-v1"):
        tx.label_table("cityscapes")


# --- mappings ----------------------------------------------------------------------------------


@pytest.mark.parametrize("target", list(tx.TARGETS))
def test_every_mapping_in_range(target: str) -> None:
    table = tx.mapping(target)
    names = tx.TARGETS[target]
    assert len(table) == 30
    for cid, tid in enumerate(table):
        if target == "benchmark15" and tid == tx.IGNORE:
            continue
        assert 0 <= tid < len(names), (target, tx.by_id(cid).name, tid)
    if target in tx.DERIVED_TARGETS:  # derived from each class's row, not a column of it
        assert table == tuple(tx.DERIVED_TARGETS[target](c) for c in tx.CLASSES)
    else:
        assert table == tuple(getattr(c, target) for c in tx.CLASSES)


@pytest.mark.parametrize("table", ["release", "carlaocc-v1"])
def test_openocc_v2_and_uniocc_maps(table: str) -> None:
    o = dict(zip((c.name for c in tx.label_table(table).classes), tx.mapping("openocc_v2", table)))
    u = dict(zip((c.name for c in tx.label_table(table).classes), tx.mapping("uniocc", table)))
    on, un = tx.OPENOCC_V2_NAMES, tx.UNIOCC_NAMES
    # the same nuScenes class as Occ3D, by name, in OpenOcc's order; free is 16 there
    for name in ("Road", "Sidewalk", "Car", "Truck", "Bus", "Pedestrian", "Bicycle", "Motorcycle", "Vegetation", "Terrain"):
        occ3d = tx.OCC3D_NUSCENES_NAMES[tx.mapping("occ3d_nuscenes", table)[tx.by_name(name).id]]
        assert on[o[name]] == occ3d, name
    assert on[o["None"]] == "free" and o["None"] == 16 and on[o["Building"]] == "manmade"
    assert "others" not in on and on[o["Other"]] == "manmade"  # Occ3D's others has no OpenOcc class
    assert [un[u[n]] for n in ("None", "Road", "Sidewalk", "Building", "Pole", "Car", "Rider", "Terrain")] == \
        ["free", "road", "road", "building", "other", "car", "pedestrian", "terrain"]
    assert u["None"] == 10 and len(un) == 11


def test_target_name_tables_have_the_right_sizes() -> None:
    assert len(tx.OCC3D_NUSCENES_NAMES) == 18 and tx.OCC3D_NUSCENES_NAMES[17] == "free"
    assert len(tx.SSCBENCH_KITTI360_NAMES) == 19
    assert len(tx.SEMANTICKITTI_NAMES) == 20
    assert len(tx.BENCHMARK15_NAMES) == 15
    expected = {"occ3d_nuscenes", "sscbench_kitti360", "semantickitti", "benchmark15", "openocc_v2", "uniocc"}
    assert len(tx.OPENOCC_V2_NAMES) == 17 and len(tx.UNIOCC_NAMES) == 11
    assert set(tx.TARGETS) == expected
    for names in tx.TARGETS.values():
        assert len(set(names)) == len(names)


@pytest.mark.parametrize("target", list(tx.TARGETS))
def test_car_maps_to_car(target: str) -> None:
    assert _target_name(target, "Car") == "car"


@pytest.mark.parametrize("target", list(tx.TARGETS))
def test_pedestrian_maps_to_person(target: str) -> None:
    assert _target_name(target, "Pedestrian") in {"person", "pedestrian"}


@pytest.mark.parametrize("target", list(tx.TARGETS))
def test_road_maps_to_road(target: str) -> None:
    assert _target_name(target, "Road") in {"road", "driveable_surface"}
    assert _target_name(target, "RoadLine") == _target_name(target, "Road")


@pytest.mark.parametrize("name", ["None", "Sky"])
def test_empty_classes_map_to_free(name: str) -> None:
    assert _target_name("occ3d_nuscenes", name) == "free"
    assert _target_name("sscbench_kitti360", name) == "unlabeled"
    assert _target_name("semantickitti", name) == "unlabeled"
    assert tx.mapping("benchmark15")[tx.by_name(name).id] == tx.IGNORE


def test_occupied_classes_never_map_to_free_in_occ3d() -> None:
    free = tx.OCC3D_NUSCENES_NAMES.index("free")
    for c in tx.CLASSES:
        if c.name not in ("None", "Sky"):
            assert c.occ3d_nuscenes != free, c.name
            assert c.benchmark15 != tx.IGNORE, c.name


def test_benchmark15_uses_every_group() -> None:
    used = set(tx.mapping("benchmark15")) - {tx.IGNORE}
    assert used == set(range(15))


def test_unknown_target_raises_value_error_naming_targets() -> None:
    with pytest.raises(ValueError) as err:
        tx.mapping("cityscapes")
    for t in tx.TARGETS:
        assert t in str(err.value)


def test_semantickitti_agrees_with_yaml_learning_map() -> None:
    import yaml

    cfg = yaml.safe_load(require(SEMANTIC_KITTI_YAML).read_text())
    raw_by_name = {v: int(k) for k, v in cfg["labels"].items()}
    learning_map = {int(k): int(v) for k, v in cfg["learning_map"].items()}
    # our names table is the yaml's learning classes, in learning-id order
    inv = {int(k): int(v) for k, v in cfg["learning_map_inv"].items()}
    assert tx.SEMANTICKITTI_NAMES == tuple(cfg["labels"][inv[i]] for i in range(len(inv)))
    table = tx.mapping("semantickitti")
    for ours, theirs in SEMANTICKITTI_COUNTERPARTS.items():
        expected = learning_map[raw_by_name[theirs]]
        assert table[tx.by_name(ours).id] == expected, (ours, theirs)


# --- lookups -----------------------------------------------------------------------------------


def test_by_id_and_by_name_round_trip() -> None:
    for c in tx.CLASSES:
        assert tx.by_id(c.id) is c
        assert tx.by_name(c.name) is c
    with pytest.raises(KeyError):
        tx.by_id(30)
    with pytest.raises(KeyError):
        tx.by_id(-1)


def test_by_name_case_insensitive() -> None:
    assert tx.by_name("car").id == 14
    assert tx.by_name("CAR").id == 14
    assert tx.by_name("trafficlight").id == 7
    assert tx.by_name("TRAFFICSIGN").id == 8


def test_by_name_unknown_raises_key_error_listing_names() -> None:
    with pytest.raises(KeyError) as err:
        tx.by_name("Spaceship")
    msg = str(err.value)
    assert "Spaceship" in msg
    for name in ("Car", "Pedestrian", "Rock"):
        assert name in msg


# --- model behaviour ---------------------------------------------------------------------------


def test_models_are_frozen() -> None:
    car = tx.by_name("Car")
    with pytest.raises(pydantic.ValidationError):
        car.name = "Lorry"  # type: ignore[misc]
    with pytest.raises(pydantic.ValidationError):
        car.occ3d_nuscenes = 0  # type: ignore[misc]
    assert tx.by_name("Car").name == "Car"
    assert tx.by_name("Car").occ3d_nuscenes == tx.OCC3D_NUSCENES_NAMES.index("car")


def test_models_reject_unknown_fields() -> None:
    row = tx.table_rows()[14]
    with pytest.raises(pydantic.ValidationError):
        tx.SemanticClass(**row, instance_capable=True)


def test_table_rows_are_plain_and_round_trip() -> None:
    rows = tx.table_rows()
    assert len(rows) == 30
    for row, c in zip(rows, tx.CLASSES, strict=True):
        assert isinstance(row, dict)
        assert isinstance(row["color"], list) and isinstance(row["subclasses"], list)
        assert tx.SemanticClass(**row) == c


# --- purity ------------------------------------------------------------------------------------


def test_module_imports_only_stdlib_and_pydantic() -> None:
    source = Path(tx.__file__).read_text()
    allowed = set(sys.stdlib_module_names) | {"pydantic", "__future__"}
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                assert alias.name.split(".")[0] in allowed, alias.name
        elif isinstance(node, ast.ImportFrom):
            assert node.level == 0, "no relative imports"
            assert node.module is not None and node.module.split(".")[0] in allowed, node.module
