"""The CarlaOcc taxonomy: 30 semantic classes (CARLA UE5 0.10 ``CityObjectLabel``) as one table.

Every class row carries its CARLA/Cityscapes colour, stuff/thing kind, static/dynamic motion, a
fine sub-class vocabulary and its id in four target label sets:

* ``occ3d_nuscenes`` (18 ids, 17 = free),
* ``sscbench_kitti360`` (19 ids, 0 = unlabeled, which is the *empty* label of SSC ground truth),
* ``semantickitti`` (20 learning ids, 0 = unlabeled/empty),
* ``benchmark15``, the 15-class grouping of the CarlaOcc paper's per-class table, numbered 0-14 in
  the paper's column order (Road = 0 ... Other = 14). It has no free/empty class: classes that
  never occupy a voxel map to :data:`IGNORE` (255), which evaluation skips.

Label tables: which classes carry instance ids (things) and the Occ3D-nuScenes and KITTI-360 ids
depend on the *label table*, a named option recorded with every dataset:

* ``release`` (the default): the official CarlaOcc release's table, ``utils/labels.py`` of
  fengyi233/carlaocc (:data:`RELEASE_LABELS` transcribes its ``is_instance``, ``nuscenes_id`` and
  ``kitti360_id`` columns). Things are Pole, TrafficLight, TrafficSign and the eight road users;
  Building is stuff. Fence and GuardRail -> Occ3D barrier; TrafficLight, TrafficSign and Static
  -> others; Ground -> terrain; Train -> trailer.
* ``carlaocc-v1``: this project's first table (the rows below as written): Building is a thing,
  Pole/TrafficLight/TrafficSign stuff, and the Occ3D ids of the notes below.

The release has no SemanticKITTI or 15-class columns: those are this project's in both tables,
and so are colours (equal to the release's), motion and sub-classes.

Empty space: class 0 (``None``) is the empty label of the grid, so a voxel of class 0 is free; it
maps to free/unlabeled in every target (``IGNORE`` in benchmark15). ``Sky`` never occupies a voxel
(CARLA has no sky mesh inside the region) and maps the same way.

Mapping decisions of ``carlaocc-v1`` worth knowing (KITTI means both SSCBench-KITTI-360 and SemanticKITTI):

* ``RoadLine`` -> driveable_surface / road (KITTI lane-marking is folded into road).
* ``Ground`` (shared spaces, flat islands), ``Water`` and ``RailTrack`` -> other_flat /
  other-ground (nuScenes ``flat.other`` explicitly holds water and rail tracks); benchmark15 Ground.
* ``Terrain`` and ``Rock`` -> terrain; benchmark15 Ground.
* ``Wall``, ``Fence``, ``GuardRail``, ``Pole``, ``TrafficLight``, ``TrafficSign``, ``Bridge``,
  ``Static`` -> manmade in Occ3D (nuScenes ``static.manmade`` lists walls, guard rails, fences,
  poles, signs, lights, hydrants). In KITTI: GuardRail -> fence (crash barriers), TrafficLight ->
  traffic-sign (no light class), Wall and Bridge -> other-structure, Static/Dynamic/Other ->
  other-object.
* SemanticKITTI's learning map drops other-structure and other-object to 0; we follow it, so
  Wall/Bridge/Static/Dynamic/Other become 0 there (as they do in real SemanticKITTI labels).
* ``Dynamic`` (movable props: bins, carts, strollers) and ``Other`` -> Occ3D ``others``.
* ``Rider`` -> pedestrian (Occ3D), person (SSCBench, which would otherwise erase bicyclists to
  empty), bicyclist (SemanticKITTI), Person (benchmark15).
* ``Train`` (trams, trains) -> Occ3D ``others`` (nuScenes has no rail vehicle), KITTI
  other-vehicle (on-rails); ``Bus``, ``Train``, ``Motorcycle``, ``Bicycle`` -> OtherVehicle.
* ``Vegetation`` includes tree trunks: SemanticKITTI ``trunk`` is never produced.
* Occ3D barrier, construction_vehicle, traffic_cone, trailer and KITTI parking have no CARLA
  class-level counterpart and are never produced.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

TAXONOMY_VERSION: str = "carla-ue5-0.10/1"

IGNORE: int = 255
"""Target id for classes that are not evaluated (benchmark15 has no free/empty class)."""

Kind = Literal["stuff", "thing"]
Motion = Literal["static", "dynamic"]
RGB = tuple[int, int, int]

# Source: Occ3D-nuScenes class list (occ3d class_names, as in the Occ3D / SparseOcc code).
OCC3D_NUSCENES_NAMES: tuple[str, ...] = (
    "others", "barrier", "bicycle", "bus", "car", "construction_vehicle", "motorcycle",
    "pedestrian", "traffic_cone", "trailer", "truck", "driveable_surface", "other_flat",
    "sidewalk", "terrain", "manmade", "vegetation", "free",
)  # fmt: skip
# Source: ai4ce/SSCBench dataset/configs/kitti360.yaml (learning_map_inv, nbr_classes: 19).
SSCBENCH_KITTI360_NAMES: tuple[str, ...] = (
    "unlabeled", "car", "bicycle", "motorcycle", "truck", "other-vehicle", "person", "road",
    "parking", "sidewalk", "other-ground", "building", "fence", "vegetation", "terrain", "pole",
    "traffic-sign", "other-structure", "other-object",
)  # fmt: skip
# Source: SemanticKITTI semantic-kitti.yaml (learning_map_inv + labels).
SEMANTICKITTI_NAMES: tuple[str, ...] = (
    "unlabeled", "car", "bicycle", "motorcycle", "truck", "other-vehicle", "person", "bicyclist",
    "motorcyclist", "road", "parking", "sidewalk", "other-ground", "building", "fence",
    "vegetation", "trunk", "terrain", "pole", "traffic-sign",
)  # fmt: skip
# Source: the per-class table of the CarlaOcc paper (column order = id).
BENCHMARK15_NAMES: tuple[str, ...] = (
    "Road", "Sidewalk", "Building", "Wall", "Fence", "Pole", "TrafficLight", "TrafficSign",
    "Vegetation", "Ground", "Person", "Car", "Truck", "OtherVehicle", "Other",
)  # fmt: skip

# Source: OpenDriveLab/OccNet ray_metrics.py and MCG-NJU/SparseOcc's openocc config (OpenOcc v2,
# the CVPR-2024 occupancy-and-flow track): the nuScenes classes in another order, free = 16.
OPENOCC_V2_NAMES: tuple[str, ...] = (
    "car", "truck", "trailer", "bus", "construction_vehicle", "bicycle", "motorcycle", "pedestrian",
    "traffic_cone", "barrier", "driveable_surface", "other_flat", "sidewalk", "terrain", "manmade",
    "vegetation", "free",
)  # fmt: skip
# Source: tasl-lab/UniOcc uniocc_viz.py (0-10; 11-19 reserved).
UNIOCC_NAMES: tuple[str, ...] = (
    "other", "car", "bicycle", "motorcycle", "pedestrian", "traffic_cone", "vegetation", "road",
    "terrain", "building", "free",
)  # fmt: skip

TARGETS: dict[str, tuple[str, ...]] = {
    "occ3d_nuscenes": OCC3D_NUSCENES_NAMES,
    "sscbench_kitti360": SSCBENCH_KITTI360_NAMES,
    "semantickitti": SEMANTICKITTI_NAMES,
    "benchmark15": BENCHMARK15_NAMES,
    "openocc_v2": OPENOCC_V2_NAMES,
    "uniocc": UNIOCC_NAMES,
}

# OpenOcc v2 ids follow from a class's Occ3D-nuScenes id by name (the same nuScenes classes);
# Occ3D's "others" has no OpenOcc class and becomes manmade (a structure or prop, not free).
_OCC3D_TO_OPENOCC_V2: tuple[int, ...] = tuple(
    OPENOCC_V2_NAMES.index("manmade" if n == "others" else n) for n in OCC3D_NUSCENES_NAMES
)
# UniOcc ids from our class names: its road covers the paved flat ground (it has no sidewalk),
# terrain the unpaved, building the walls too; poles, signs, fences and props are "other".
_UNIOCC_OF_CLASS: dict[str, str] = {
    "None": "free", "Sky": "free", "Road": "road", "RoadLine": "road", "Sidewalk": "road", "Ground": "road",
    "RailTrack": "road", "Terrain": "terrain", "Rock": "terrain", "Water": "terrain", "Building": "building",
    "Wall": "building", "Bridge": "building", "Vegetation": "vegetation", "Pedestrian": "pedestrian",
    "Rider": "pedestrian", "Car": "car", "Truck": "car", "Bus": "car", "Train": "car", "Motorcycle": "motorcycle",
    "Bicycle": "bicycle",
}  # fmt: skip
DERIVED_TARGETS = {
    "openocc_v2": lambda c: _OCC3D_TO_OPENOCC_V2[c.occ3d_nuscenes],
    "uniocc": lambda c: UNIOCC_NAMES.index(_UNIOCC_OF_CLASS.get(c.name, "other")),
}


class SemanticClass(BaseModel):
    """One CarlaOcc semantic class and its ids in the target label sets."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    id: int = Field(ge=0, le=29)
    name: str
    color: tuple[int, int, int]
    kind: Kind
    motion: Motion
    subclasses: tuple[str, ...]
    occ3d_nuscenes: int = Field(ge=0, le=len(OCC3D_NUSCENES_NAMES) - 1)
    sscbench_kitti360: int = Field(ge=0, le=len(SSCBENCH_KITTI360_NAMES) - 1)
    semantickitti: int = Field(ge=0, le=len(SEMANTICKITTI_NAMES) - 1)
    benchmark15: int  # 0..14, or IGNORE


# Column order: id, name, colour (CARLA UE5 CityScapesPalette.h), kind, motion,
#               occ3d_nuscenes, sscbench_kitti360, semantickitti, benchmark15, subclasses.
#
# These rows are the ``carlaocc-v1`` label table. Its things (instance ids) are the eight road
# users, as in the Cityscapes and SemanticKITTI /
# KITTI-360 panoptic conventions (PaSCo) that CarlaOcc is compared against, plus Building: the
# paper counts buildings among its annotated instances ("vehicles and buildings constitute the
# majority of annotated instances"), so each building is a static thing. Pole, TrafficLight and
# TrafficSign stay stuff: they are static infrastructure, their meshes are fused (head on pole,
# sign on pole) so per-object boundaries are ill-defined, and KITTI panoptic treats pole and
# traffic-sign as stuff. Motion "dynamic" marks exactly the movable road users; CARLA's "Dynamic"
# label is for movable *props* (bins, carts) that are placed, not driven, so its motion is static.
_T = "thing"
_S = "stuff"
_ST = "static"
_DY = "dynamic"
_X = IGNORE


def _row(
    id: int, name: str, color: RGB, kind: Kind, motion: Motion,
    occ3d: int, ssc360: int, skitti: int, b15: int, subclasses: tuple[str, ...],
) -> SemanticClass:  # fmt: skip
    return SemanticClass(
        id=id, name=name, color=color, kind=kind, motion=motion, subclasses=subclasses,
        occ3d_nuscenes=occ3d, sscbench_kitti360=ssc360, semantickitti=skitti, benchmark15=b15,
    )  # fmt: skip


# One row per class, one line each (deliberately wider than the usual line length).
# fmt: off
CARLAOCC_V1_CLASSES: tuple[SemanticClass, ...] = (
    _row(0,  "None",         (0, 0, 0),       _S, _ST, 17,  0,  0, _X, ()),
    _row(1,  "Road",         (128, 64, 128),  _S, _ST, 11,  7,  9,  0, ("lane", "intersection", "crosswalk", "parking", "driveway", "roundabout")),
    _row(2,  "Sidewalk",     (244, 35, 232),  _S, _ST, 13,  9, 11,  1, ("walkway", "curb", "traffic_island", "plaza", "ramp")),
    _row(3,  "Building",     (70, 70, 70),    _T, _ST, 15, 11, 13,  2, ("residential", "house", "apartment", "office", "tower", "commercial", "industrial", "warehouse", "garage", "gas_station", "religious", "public")),
    _row(4,  "Wall",         (102, 102, 156), _S, _ST, 15, 17,  0,  3, ("retaining_wall", "boundary_wall", "garden_wall", "noise_barrier")),
    _row(5,  "Fence",        (190, 153, 153), _S, _ST, 15, 12, 14,  4, ("metal_fence", "wooden_fence", "chain_link", "railing", "gate")),
    _row(6,  "Pole",         (153, 153, 153), _S, _ST, 15, 15, 18,  5, ("street_light", "utility_pole", "sign_pole", "traffic_light_pole", "flagpole")),
    _row(7,  "TrafficLight", (250, 170, 30),  _S, _ST, 15, 16, 19,  6, ("vehicle_signal", "pedestrian_signal", "overhead_signal")),
    _row(8,  "TrafficSign",  (220, 220, 0),   _S, _ST, 15, 16, 19,  7, ("stop", "yield", "speed_limit", "no_entry", "one_way", "pedestrian_crossing", "warning", "direction", "parking")),
    _row(9,  "Vegetation",   (107, 142, 35),  _S, _ST, 16, 13, 15,  8, ("tree", "palm", "conifer", "bush", "hedge")),
    _row(10, "Terrain",      (152, 251, 152), _S, _ST, 14, 14, 17,  9, ("grass", "soil", "sand", "gravel")),
    _row(11, "Sky",          (70, 130, 180),  _S, _ST, 17,  0,  0, _X, ()),
    _row(12, "Pedestrian",   (220, 20, 60),   _T, _DY,  7,  6,  6, 10, ("adult", "child")),
    _row(13, "Rider",        (255, 0, 0),     _T, _DY,  7,  6,  7, 10, ("cyclist", "motorcyclist")),
    _row(14, "Car",          (0, 0, 142),     _T, _DY,  4,  1,  1, 11, ("sedan", "suv", "hatchback", "coupe", "convertible", "wagon", "van", "minivan", "pickup", "taxi", "police")),
    _row(15, "Truck",        (0, 0, 70),      _T, _DY, 10,  4,  4, 12, ("box_truck", "fire_truck", "tanker", "semi_truck", "garbage_truck", "tow_truck", "cement_mixer", "dump_truck")),
    _row(16, "Bus",          (0, 60, 100),    _T, _DY,  3,  5,  5, 13, ("city_bus", "coach", "school_bus", "double_decker", "minibus")),
    _row(17, "Train",        (0, 80, 100),    _T, _DY,  0,  5,  5, 13, ("tram", "train", "metro")),
    _row(18, "Motorcycle",   (0, 0, 230),     _T, _DY,  6,  3,  3, 13, ("sport", "cruiser", "scooter", "moped")),
    _row(19, "Bicycle",      (119, 11, 32),   _T, _DY,  2,  2,  2, 13, ("road_bike", "mountain_bike", "city_bike", "cargo_bike")),
    _row(20, "Static",       (110, 190, 160), _S, _ST, 15, 18,  0, 14, ("bench", "bin", "hydrant", "bus_stop", "mailbox", "kiosk", "bollard", "planter", "barrier", "traffic_cone", "billboard", "vending_machine", "phone_booth")),
    _row(21, "Dynamic",      (170, 120, 50),  _S, _ST,  0, 18,  0, 14, ("movable_bin", "shopping_cart", "stroller", "wheelchair", "luggage", "box", "animal")),
    _row(22, "Other",        (55, 90, 80),    _S, _ST,  0, 18,  0, 14, ()),
    _row(23, "Water",        (45, 60, 150),   _S, _ST, 12, 10, 12,  9, ("river", "lake", "pond", "sea", "fountain")),
    _row(24, "RoadLine",     (157, 234, 50),  _S, _ST, 11,  7,  9,  0, ("lane_marking", "stop_line", "crosswalk_marking", "arrow", "text")),
    _row(25, "Ground",       (81, 0, 81),     _S, _ST, 12, 10, 12,  9, ("shared_space", "flat_roundabout", "pavement", "dirt_path")),
    _row(26, "Bridge",       (150, 100, 100), _S, _ST, 15, 17,  0, 14, ("overpass", "footbridge", "viaduct")),
    _row(27, "RailTrack",    (230, 150, 140), _S, _ST, 12, 10, 12,  9, ("rail", "tram_track")),
    _row(28, "GuardRail",    (180, 165, 180), _S, _ST, 15, 12, 14,  4, ("w_beam", "concrete_barrier", "cable_barrier")),
    _row(29, "Rock",         (180, 130, 70),  _S, _ST, 14, 14, 17,  9, ("boulder", "rock_formation", "cliff")),
)
# fmt: on

# The official release's label table, transcribed from ``utils/labels.py`` of fengyi233/carlaocc
# (commit de6a21c): name, id, is_instance, colour, nuscenes_id (Occ3D-nuScenes, 0-17),
# kitti360_id (SSCBench-KITTI-360, 0-18). Facts only; the other columns are ours.
# fmt: off
RELEASE_LABELS: tuple[tuple[str, int, bool, RGB, int, int], ...] = (
    ("None",         0,  False, (0, 0, 0),       17,  0),
    ("Road",         1,  False, (128, 64, 128),  11,  7),
    ("Sidewalk",     2,  False, (244, 35, 232),  13,  9),
    ("Building",     3,  False, (70, 70, 70),    15, 11),
    ("Wall",         4,  False, (102, 102, 156), 15, 17),
    ("Fence",        5,  False, (190, 153, 153),  1, 12),
    ("Pole",         6,  True,  (153, 153, 153), 15, 15),
    ("TrafficLight", 7,  True,  (250, 170, 30),   0, 16),
    ("TrafficSign",  8,  True,  (220, 220, 0),    0, 16),
    ("Vegetation",   9,  False, (107, 142, 35),  16, 13),
    ("Terrain",      10, False, (152, 251, 152), 14, 14),
    ("Sky",          11, False, (70, 130, 180),  17,  0),
    ("Pedestrian",   12, True,  (220, 20, 60),    7,  6),
    ("Rider",        13, True,  (255, 0, 0),      7,  6),
    ("Car",          14, True,  (0, 0, 142),      4,  1),
    ("Truck",        15, True,  (0, 0, 70),      10,  4),
    ("Bus",          16, True,  (0, 60, 100),     3,  5),
    ("Train",        17, True,  (0, 80, 100),     9,  5),
    ("Motorcycle",   18, True,  (0, 0, 230),      6,  3),
    ("Bicycle",      19, True,  (119, 11, 32),    2,  2),
    ("Static",       20, False, (110, 190, 160),  0, 18),
    ("Dynamic",      21, False, (170, 120, 50),   0, 18),
    ("Other",        22, False, (55, 90, 80),     0, 18),
    ("Water",        23, False, (45, 60, 150),   12, 10),
    ("RoadLine",     24, False, (157, 234, 50),  11,  7),
    ("Ground",       25, False, (81, 0, 81),     14, 10),
    ("Bridge",       26, False, (150, 100, 100), 15, 17),
    ("RailTrack",    27, False, (230, 150, 140), 12, 10),
    ("GuardRail",    28, False, (180, 165, 180),  1, 12),
    ("Rock",         29, False, (180, 130, 70),  14, 14),
)
# fmt: on


def _release_classes() -> tuple[SemanticClass, ...]:
    """The ``carlaocc-v1`` rows with the release's kind and Occ3D / KITTI-360 ids."""
    out = []
    for c, (name, i, is_instance, color, nus, k360) in zip(CARLAOCC_V1_CLASSES, RELEASE_LABELS, strict=True):
        if (name, i, color) != (c.name, c.id, c.color):
            raise RuntimeError(f"release label row {i} ({name}) does not line up with the class table")
        out.append(c.model_copy(update={"kind": _T if is_instance else _S, "occ3d_nuscenes": nus,
                                        "sscbench_kitti360": k360}))
    return tuple(out)


RELEASE_CLASSES: tuple[SemanticClass, ...] = _release_classes()

LabelTableName = Literal["release", "carlaocc-v1"]
DEFAULT_LABEL_TABLE: str = "release"


class LabelTable(BaseModel):
    """A named label table: the 30 classes with one choice of things and target ids.

    Which table a dataset was built with is recorded with it (``label_table`` in every occupancy
    and sensor array's attributes, ``taxonomy`` in the config): exports, evaluation and the
    statistics read that table, never a default.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    source: str
    classes: tuple[SemanticClass, ...]

    @property
    def version(self) -> str:
        """Class ids and this table: ``carla-ue5-0.10/1+release``."""
        return f"{TAXONOMY_VERSION}+{self.name}"

    def by_id(self, i: int) -> SemanticClass:
        """The class with id ``i`` (0-29) in this table; ``KeyError`` otherwise."""
        return self.classes[by_id(i).id]

    def thing_ids(self) -> tuple[int, ...]:
        """Ids of the classes that carry instance ids in this table."""
        return tuple(c.id for c in self.classes if c.kind == "thing")

    def stuff_ids(self) -> tuple[int, ...]:
        """Ids of the classes whose voxels have instance 0 in this table."""
        return tuple(c.id for c in self.classes if c.kind == "stuff")

    def mapping(self, target: str) -> tuple[int, ...]:
        """Lookup table of length 30: class id -> ``target`` id (see :data:`TARGETS`)."""
        if target not in TARGETS:
            raise ValueError(f"unknown target {target!r}; valid targets: {', '.join(TARGETS)}")
        if target in DERIVED_TARGETS:
            return tuple(DERIVED_TARGETS[target](c) for c in self.classes)
        return tuple(getattr(c, target) for c in self.classes)

    def table_rows(self) -> list[dict[str, object]]:
        """The table as plain dicts (tuples as lists) for Parquet or printing, in id order."""
        rows: list[dict[str, object]] = []
        for c in self.classes:
            row = c.model_dump()
            row["color"] = list(c.color)
            row["subclasses"] = list(c.subclasses)
            rows.append(row)
        return rows


LABEL_TABLES: dict[str, LabelTable] = {
    "release": LabelTable(name="release", classes=RELEASE_CLASSES,
                          source="the official CarlaOcc release, utils/labels.py of fengyi233/carlaocc"),
    "carlaocc-v1": LabelTable(name="carlaocc-v1", classes=CARLAOCC_V1_CLASSES,
                              source="carlaocc's first table: Building a thing; Pole, TrafficLight, TrafficSign stuff"),
}


def label_table(name: str | LabelTable | None = None) -> LabelTable:
    """The label table called ``name`` (None: :data:`DEFAULT_LABEL_TABLE`); ``ValueError`` naming
    the valid ones otherwise. A :class:`LabelTable` is returned as it is."""
    if isinstance(name, LabelTable):
        return name
    try:
        return LABEL_TABLES[DEFAULT_LABEL_TABLE if name is None else str(name)]
    except KeyError:
        raise ValueError(f"unknown label table {name!r}; valid: {', '.join(LABEL_TABLES)}") from None


CLASSES: tuple[SemanticClass, ...] = RELEASE_CLASSES
"""The classes of the default table. Names, colours, motion, sub-classes, SemanticKITTI and
benchmark15 ids are the same in every table; kind and the Occ3D / KITTI-360 ids are not: ask
:func:`label_table` for those."""

# Other spellings accepted by by_name: CARLA's Python enum names (carla.CityObjectLabel).
_ALIASES: dict[str, int] = {
    "unlabeled": 0, "roads": 1, "sidewalks": 2, "buildings": 3, "walls": 4, "fences": 5,
    "poles": 6, "trafficsigns": 8, "pedestrians": 12, "roadlines": 24,
}  # fmt: skip


def _key(name: str) -> str:
    """Normalise a class name: lower case, no separators ("Traffic_Light" -> "trafficlight")."""
    return re.sub(r"[^0-9a-z]", "", name.lower())


def _check_table(classes: tuple[SemanticClass, ...]) -> None:
    """Fail at import if a table is inconsistent (order, uniqueness, target ranges)."""
    if [c.id for c in classes] != list(range(30)):
        raise RuntimeError("taxonomy ids must be 0..29 in order")
    if len({_key(c.name) for c in classes}) != len(classes):
        raise RuntimeError("taxonomy names must be unique")
    if len({c.color for c in classes}) != len(classes):
        raise RuntimeError("taxonomy colours must be unique")
    for c in classes:
        if not all(0 <= v <= 255 for v in c.color):
            raise RuntimeError(f"{c.name}: colour out of range")
        if not (0 <= c.benchmark15 < len(BENCHMARK15_NAMES) or c.benchmark15 == IGNORE):
            raise RuntimeError(f"{c.name}: benchmark15 id out of range")


for _table in LABEL_TABLES.values():
    _check_table(_table.classes)

_BY_KEY: dict[str, SemanticClass] = {_key(c.name): c for c in CLASSES} | {
    k: CLASSES[i] for k, i in _ALIASES.items()
}


def by_id(i: int) -> SemanticClass:
    """The class with id ``i`` (0-29) in the default table; ``KeyError`` otherwise."""
    if isinstance(i, bool) or not 0 <= int(i) < len(CLASSES):
        raise KeyError(f"no semantic class with id {i!r}; ids are 0..{len(CLASSES) - 1}")
    return CLASSES[int(i)]


def by_name(name: str) -> SemanticClass:
    """The class called ``name``, case- and separator-insensitive (CARLA enum spellings too),
    in the default table."""
    found = _BY_KEY.get(_key(name))
    if found is None:
        valid = ", ".join(c.name for c in CLASSES)
        raise KeyError(f"unknown semantic class {name!r}; valid names: {valid}")
    return found


def thing_ids(table: str | LabelTable | None = None) -> tuple[int, ...]:
    """Ids of the thing classes (they carry instance ids) of ``table`` (None: the default)."""
    return label_table(table).thing_ids()


def stuff_ids(table: str | LabelTable | None = None) -> tuple[int, ...]:
    """Ids of the stuff classes (instance id 0) of ``table`` (None: the default)."""
    return label_table(table).stuff_ids()


def dynamic_ids() -> tuple[int, ...]:
    """Ids of the classes that move (the road users; the same in every table)."""
    return tuple(c.id for c in CLASSES if c.motion == "dynamic")


def mapping(target: str, table: str | LabelTable | None = None) -> tuple[int, ...]:
    """Lookup table of length 30: class id -> ``target`` id (see :data:`TARGETS`) in ``table``
    (None: the default)."""
    return label_table(table).mapping(target)


def palette() -> tuple[RGB, ...]:
    """RGB colour of every class, indexed by class id."""
    return tuple(c.color for c in CLASSES)


def table_rows(table: str | LabelTable | None = None) -> list[dict[str, object]]:
    """The table as plain dicts (tuples as lists) for Parquet or printing, in id order."""
    return label_table(table).table_rows()
