"""How big things are: the size table per class and sub-class, and the choice of the scale from
source units to metres.

Standardization measures an asset in the asset frame (after the frame step) by its ``"length"``
(longest horizontal extent) or ``"height"`` (z extent), per :func:`size_range`, and
:func:`choose_scale` picks the scale by the first rule that applies (``target_length``,
``normalized``, declared units, inferred units, fallback); a standardized size outside
``[min / ABSURD_FACTOR, max * ABSURD_FACTOR]`` is absurd (quarantined). Sizes in metres.

Degenerate extents (:func:`min_extent`), per the class (the same whichever label table says
which classes carry instance ids):

* **Solid objects** (:data:`SOLID_CLASSES`: Building and the road users) are filled when closed:
  no axis of their bounding box may be zero (``"flat mesh"``, checked
  before the scale: zero is zero in any units), and after the scale every axis must be at least
  the (sub-)class's minimum measured size / :data:`THIN_FACTOR` (``"too thin"``): Car 3.5 m ->
  0.175 m, Pedestrian 0.8 m -> 0.04 m, Building 2.5 m -> 0.125 m, Bicycle 1.0 m -> 0.05 m.
* **Everything else** may be flat on an axis (a sign plate is a plane): ground-like surfaces (Road, RoadLine, Ground, Sidewalk,
  Terrain, Water, RailTrack) and thin sheets (Fence, Wall, GuardRail, sign plates, billboards,
  foliage cards) are routinely single planes, and stuff is voxelized as a surface. Only its
  measured dimension is checked (zero height for a class measured by height is ``"absurd
  size"``; a mesh with no area on two axes has only degenerate faces and never gets here).
"""

from __future__ import annotations

import math

import numpy as np

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import SourceAsset
from carlaocc.stages.ingest.checks import Rejection

# unknown units: beyond this ratio to the typical size no rescaling is attempted
FALLBACK_MAX_RATIO = 100.0

SizeRange = tuple[str, float, float, float]  # (dimension, min, typical, max), metres

# --------------------------------------------------------------------------------------------
# the size table: per class, the measured dimension and its (min, typical, max) in metres
# --------------------------------------------------------------------------------------------
# "length" = longest horizontal extent (after the frame is standardized), "height" = z extent.
# Things with a clear footprint (vehicles) are measured by length, upright objects (buildings,
# poles, people, trees) by height; ground-like stuff by length with generous ranges (a road tile
# is 1 m or a 2 km road). Sky and None are never real assets; they get wide ranges so the table
# covers every class. The plausibility check rejects outside [min / 3, max * 3].
# fmt: off
SIZE_RANGES: dict[str, SizeRange] = {
    "None":         ("length", 0.05,  1.0,  1000.0),
    "Road":         ("length", 1.0,  20.0,  5000.0),
    "Sidewalk":     ("length", 0.5,  10.0,  5000.0),
    "Building":     ("height", 2.5,  10.0,   400.0),
    "Wall":         ("height", 0.3,   2.0,    15.0),
    "Fence":        ("height", 0.3,   1.5,     5.0),
    "Pole":         ("height", 1.0,   6.0,    40.0),
    "TrafficLight": ("height", 0.3,   3.5,    12.0),   # a signal head alone, or on its pole/mast
    "TrafficSign":  ("height", 0.3,   2.5,     8.0),   # a plate alone, or on its pole
    "Vegetation":   ("height", 0.2,   6.0,    80.0),
    "Terrain":      ("length", 0.5,  20.0,  5000.0),
    "Sky":          ("length", 1.0, 1000.0, 100000.0),
    "Pedestrian":   ("height", 0.8,   1.7,     2.2),
    "Rider":        ("height", 0.9,   1.6,     2.3),   # seated person, with or without the bike
    "Car":          ("length", 3.5,   4.5,     5.5),
    "Truck":        ("length", 4.5,   8.0,    25.0),
    "Bus":          ("length", 5.0,  12.0,    25.0),
    "Train":        ("length", 8.0,  25.0,   400.0),   # one car or a whole train
    "Motorcycle":   ("length", 1.2,   2.1,     2.8),
    "Bicycle":      ("length", 1.0,   1.75,    2.8),
    "Static":       ("height", 0.1,   1.0,    15.0),   # street furniture, from bollard to billboard
    "Dynamic":      ("length", 0.2,   1.0,     4.0),   # movable props
    "Other":        ("length", 0.05,  1.0,   100.0),
    "Water":        ("length", 0.5,  50.0, 10000.0),
    "RoadLine":     ("length", 0.1,   3.0,  5000.0),
    "Ground":       ("length", 0.5,  20.0,  5000.0),
    "Bridge":       ("length", 5.0,  50.0,  3000.0),
    "RailTrack":    ("length", 1.0,  25.0,  5000.0),
    "GuardRail":    ("length", 1.0,   4.0,   500.0),
    "Rock":         ("length", 0.2,   1.5,   200.0),
}

SUBCLASS_SIZE_RANGES: dict[tuple[str, str], SizeRange] = {
    # buildings: height
    ("Building", "house"):            ("height", 4.0,   7.0,  15.0),
    ("Building", "residential"):      ("height", 4.0,   9.0,  40.0),
    ("Building", "apartment"):        ("height", 8.0,  20.0, 120.0),
    ("Building", "office"):           ("height", 6.0,  25.0, 300.0),
    ("Building", "tower"):            ("height", 30.0, 100.0, 830.0),
    ("Building", "commercial"):       ("height", 3.5,   8.0,  60.0),
    ("Building", "industrial"):       ("height", 4.0,  10.0,  40.0),
    ("Building", "warehouse"):        ("height", 4.0,   9.0,  30.0),
    ("Building", "garage"):           ("height", 2.2,   3.0,   8.0),
    ("Building", "gas_station"):      ("height", 3.0,   5.0,  12.0),
    ("Building", "religious"):        ("height", 5.0,  15.0, 160.0),
    ("Building", "public"):           ("height", 4.0,  12.0,  60.0),
    # walls, fences
    ("Wall", "garden_wall"):          ("height", 0.3,   1.2,   3.0),
    ("Wall", "noise_barrier"):        ("height", 1.5,   4.0,  10.0),
    ("Fence", "gate"):                ("height", 0.5,   1.8,   5.0),
    # poles
    ("Pole", "street_light"):         ("height", 3.0,   8.0,  20.0),
    ("Pole", "utility_pole"):         ("height", 5.0,  10.0,  25.0),
    ("Pole", "sign_pole"):            ("height", 1.5,   3.0,   6.0),
    ("Pole", "traffic_light_pole"):   ("height", 2.5,   5.0,  12.0),
    ("Pole", "flagpole"):             ("height", 3.0,   8.0,  30.0),
    # traffic lights and signs
    ("TrafficLight", "vehicle_signal"):    ("height", 0.3, 3.5,  8.0),
    ("TrafficLight", "pedestrian_signal"): ("height", 0.3, 2.8,  5.0),
    ("TrafficLight", "overhead_signal"):   ("height", 3.0, 6.5, 12.0),
    ("TrafficSign", "direction"):          ("height", 0.5, 4.0, 12.0),
    # vegetation
    ("Vegetation", "tree"):           ("height", 2.0,   8.0,  60.0),
    ("Vegetation", "palm"):           ("height", 3.0,  10.0,  30.0),
    ("Vegetation", "conifer"):        ("height", 2.0,  12.0,  80.0),
    ("Vegetation", "bush"):           ("height", 0.2,   1.0,   4.0),
    ("Vegetation", "hedge"):          ("height", 0.3,   1.2,   4.0),
    # people
    ("Pedestrian", "adult"):          ("height", 1.4,   1.75,  2.2),
    ("Pedestrian", "child"):          ("height", 0.8,   1.2,   1.6),
    # cars: length (the "a car 3.5-5.5 m long" is the category default)
    ("Car", "sedan"):                 ("length", 3.5,   4.5,   5.5),
    ("Car", "suv"):                   ("length", 4.0,   4.8,   5.5),
    ("Car", "hatchback"):             ("length", 2.5,   4.0,   4.6),
    ("Car", "coupe"):                 ("length", 3.5,   4.5,   5.0),
    ("Car", "convertible"):           ("length", 3.0,   4.4,   5.0),
    ("Car", "wagon"):                 ("length", 4.0,   4.7,   5.3),
    ("Car", "van"):                   ("length", 4.0,   5.2,   7.0),
    ("Car", "minivan"):               ("length", 4.2,   5.0,   5.5),
    ("Car", "pickup"):                ("length", 4.5,   5.5,   6.5),
    ("Car", "taxi"):                  ("length", 4.0,   4.8,   5.5),
    ("Car", "police"):                ("length", 4.0,   4.9,   5.5),
    # trucks
    ("Truck", "box_truck"):           ("length", 4.5,   7.5,  12.0),
    ("Truck", "fire_truck"):          ("length", 6.5,  10.0,  15.0),
    ("Truck", "tanker"):              ("length", 7.0,  12.0,  22.0),
    ("Truck", "semi_truck"):          ("length", 5.5,  16.0,  25.0),  # tractor alone or with trailer
    ("Truck", "garbage_truck"):       ("length", 6.0,   9.0,  12.0),
    ("Truck", "tow_truck"):           ("length", 5.0,   7.0,  12.0),
    ("Truck", "cement_mixer"):        ("length", 6.5,   9.0,  12.0),
    ("Truck", "dump_truck"):          ("length", 6.0,   8.5,  12.0),
    # buses
    ("Bus", "city_bus"):              ("length", 9.0,  12.0,  25.0),
    ("Bus", "coach"):                 ("length", 10.0, 13.0,  15.0),
    ("Bus", "school_bus"):            ("length", 6.0,  11.0,  14.0),
    ("Bus", "double_decker"):         ("length", 9.0,  11.0,  15.0),
    ("Bus", "minibus"):               ("length", 5.0,   7.0,   9.0),
    # trains
    ("Train", "tram"):                ("length", 8.0,  30.0,  75.0),
    ("Train", "metro"):               ("length", 10.0, 20.0, 200.0),
    # two-wheelers
    ("Motorcycle", "sport"):          ("length", 1.8,   2.05,  2.4),
    ("Motorcycle", "cruiser"):        ("length", 2.0,   2.4,   2.8),
    ("Motorcycle", "scooter"):        ("length", 1.2,   1.8,   2.3),
    ("Motorcycle", "moped"):          ("length", 1.2,   1.7,   2.1),
    ("Bicycle", "cargo_bike"):        ("length", 1.8,   2.4,   3.0),
    # street furniture
    ("Static", "bench"):              ("length", 1.0,   1.8,   3.5),
    ("Static", "bin"):                ("height", 0.5,   1.0,   1.6),
    ("Static", "hydrant"):            ("height", 0.4,   0.8,   1.2),
    ("Static", "bus_stop"):           ("length", 2.0,   4.0,  12.0),
    ("Static", "mailbox"):            ("height", 0.8,   1.2,   1.8),
    ("Static", "kiosk"):              ("height", 2.0,   2.8,   5.0),
    ("Static", "bollard"):            ("height", 0.3,   0.9,   1.5),
    ("Static", "planter"):            ("length", 0.4,   1.2,   4.0),
    ("Static", "barrier"):            ("length", 0.8,   2.0,   6.0),
    ("Static", "traffic_cone"):       ("height", 0.3,   0.7,   1.1),
    ("Static", "billboard"):          ("height", 2.0,   6.0,  15.0),
    ("Static", "vending_machine"):    ("height", 1.5,   1.8,   2.2),
    ("Static", "phone_booth"):        ("height", 2.0,   2.4,   3.0),
    # movable props
    ("Dynamic", "movable_bin"):       ("height", 0.8,   1.1,   1.5),
    ("Dynamic", "shopping_cart"):     ("length", 0.7,   0.95,  1.3),
    ("Dynamic", "stroller"):          ("length", 0.6,   0.9,   1.2),
    ("Dynamic", "wheelchair"):        ("length", 0.8,   1.05,  1.4),
    ("Dynamic", "luggage"):           ("height", 0.3,   0.65,  1.0),
    ("Dynamic", "box"):               ("length", 0.2,   0.6,   2.0),
    ("Dynamic", "animal"):            ("length", 0.2,   0.8,   3.0),
    # big stuff
    ("Bridge", "footbridge"):         ("length", 4.0,  25.0, 200.0),
    ("Rock", "boulder"):              ("length", 0.3,   1.5,   8.0),
    ("Rock", "rock_formation"):       ("length", 2.0,  10.0, 100.0),
    ("Rock", "cliff"):                ("length", 5.0,  50.0, 500.0),
}
# fmt: on

DECLARED_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
"""Source units -> metres, for the units a source can declare."""

INFERENCE_FACTORS: tuple[tuple[float, str], ...] = (
    (1.0, "m"), (0.01, "cm"), (0.001, "mm"), (0.0254, "in"), (0.3048, "ft"),
)  # fmt: skip
"""Candidate scales tried when a source's units are unknown (metres first: it wins ties)."""

ABSURD_FACTOR = 3.0
"""A measured size outside [min / 3, max * 3] of its range is absurd (quarantined)."""

THIN_FACTOR = 20.0
"""A thing's thinnest axis must be at least its range's minimum measured size / 20."""


def _check_size_tables() -> None:
    """Fail at import if the size table misses a class or is inconsistent."""
    names = {c.name for c in taxonomy.CLASSES}
    if set(SIZE_RANGES) != names:
        raise RuntimeError(f"SIZE_RANGES must cover exactly the taxonomy classes: {sorted(names ^ set(SIZE_RANGES))}")
    for key, (dim, lo, typ, hi) in [*SIZE_RANGES.items(), *SUBCLASS_SIZE_RANGES.items()]:
        if dim not in ("length", "height") or not 0.0 < lo <= typ <= hi:
            raise RuntimeError(f"size range {key}: bad entry {(dim, lo, typ, hi)}")
    for cat, sub in SUBCLASS_SIZE_RANGES:
        if cat not in names or sub not in taxonomy.by_name(cat).subclasses:
            raise RuntimeError(f"size range for unknown sub-class {cat}/{sub}")


_check_size_tables()


def size_range(category: str, subclass: str) -> SizeRange:
    """``(dimension, min, typical, max)`` in metres for a class (any spelling ``by_name`` accepts)
    and sub-class: the sub-class override when there is one, else the class's range.
    ``KeyError`` for a class the taxonomy does not know."""
    name = taxonomy.by_name(category).name
    return SUBCLASS_SIZE_RANGES.get((name, subclass), SIZE_RANGES[name])


SOLID_CLASSES: frozenset[str] = frozenset(
    ("Building", "Pedestrian", "Rider", "Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle"))
"""Classes whose assets are solid objects, never flat."""


def min_extent(category: str, subclass: str) -> float:
    """The smallest extent any axis of a standardized asset of the class may have, in metres:
    the (sub-)class's minimum measured size / :data:`THIN_FACTOR` for a solid object
    (:data:`SOLID_CLASSES`), 0 for the rest (which may be flat). ``KeyError`` for a class the
    taxonomy does not know."""
    if taxonomy.by_name(category).name not in SOLID_CLASSES:
        return 0.0
    return size_range(category, subclass)[1] / THIN_FACTOR


def range_label(category: str, subclass: str) -> str:
    """Which table row :func:`size_range` used: ``Car/sedan`` or ``Car``."""
    return f"{category}/{subclass}" if (category, subclass) in SUBCLASS_SIZE_RANGES else category


def measured_size(extent: np.ndarray, dim: str) -> float:
    """The size a range is about: ``"height"`` the z extent, ``"length"`` the longest horizontal
    extent (max of x and y), from an (x, y, z) extent in the asset frame."""
    return float(extent[2]) if dim == "height" else float(max(extent[0], extent[1]))


def choose_scale(raw: SourceAsset, category: str, extent: np.ndarray) -> tuple[float, str] | Rejection:
    """(scale source units -> metres, rule) from the extent in the asset frame (source units)."""
    sub = raw.subclass
    dim, lo, typ, hi = size_range(category, sub)
    label = range_label(category, sub)
    if raw.target_length is not None:
        t = raw.target_length
        if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
            return Rejection("bad target length", f"target_length {t!r} must be a positive number of "
                             "metres: fix the category map or the source's metadata")
        return t / float(max(extent[0], extent[1])), f"target_length {t:g} m from category map"
    size = measured_size(extent, dim)
    if size <= 0.0:
        return Rejection("absurd size", f"{label} is measured by its {dim}, which is 0: a flat mesh "
                         f"cannot be a {label}; check the category or the up axis ({raw.up})")
    if raw.normalized:
        return typ / size, f"normalized: scaled to typical {dim} {typ:g} m of {label}"
    if raw.units != "unknown":
        if raw.units not in DECLARED_UNITS:
            return Rejection("unknown units", f"units {raw.units!r}; declare one of "
                             f"{', '.join(DECLARED_UNITS)} or 'unknown' to infer them")
        return DECLARED_UNITS[raw.units], f"declared units {raw.units}"
    fits = [(k, u) for k, u in INFERENCE_FACTORS if lo <= size * k <= hi]
    if fits:
        # metres when they fit, else the candidate closest to the typical size (log scale)
        k, u = fits[0] if fits[0][0] == 1.0 else min(fits, key=lambda c: abs(math.log(size * c[0] / typ)))
        return k, f"inferred: {label} {dim} {size:.4g} -> {size * k:.3g} m (x{k:g}, {u})"
    # game units (a 1-unit house) are rescaled; a size no unit explains and far from any
    # plausible one (a 10 km car) is not a unit problem but a broken or mislabelled asset
    if not (1.0 / FALLBACK_MAX_RATIO <= size / typ <= FALLBACK_MAX_RATIO):
        return Rejection("absurd size", f"{label} {dim} {size:.4g} in unknown units: no unit "
                         f"({', '.join(u for _, u in INFERENCE_FACTORS)}) puts it inside {lo:g}-{hi:g} m and it is "
                         f"more than {FALLBACK_MAX_RATIO:g}x from the typical {typ:g} m; check the category, "
                         f"or give length_m in the category map")
    return typ / size, (f"fallback: no unit puts {label} {dim} {size:.4g} inside {lo:g}-{hi:g} m; "
                        f"scaled to typical {typ:g} m")
