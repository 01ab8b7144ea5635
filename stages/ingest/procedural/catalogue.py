"""The procedural catalogue and its driver: which builder makes each (category, sub-class), and
:func:`ingest_procedural`, which runs every builder with its own seeded generator, moves the parts
into the asset frame (origin at the bottom centre of the bounding box), derives content ids and
describes the assets as records (fill figures included: :func:`carlaocc.stages.voxelize.breakdown.asset_fill`).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, replace

import numpy as np

from carlaocc.schemas.configs import IngestConfig
from carlaocc.schemas.meshes import AssetGeometry, MeshPart
from carlaocc.schemas.records import AssetRecord, PartRecord
from carlaocc.stages.geometry import geometry_hash, is_watertight, signed_volume, surface_area
from carlaocc.stages.ingest.procedural.buildings import (
    apartment, commercial, garage, gas_station, house, industrial, office, public, religious,
    residential, tower, warehouse,
)
from carlaocc.stages.ingest.procedural.furniture import (
    barrier, bench, billboard, litter_bin, bollard, boxes, bus_stop, hydrant, kiosk, luggage, mailbox,
    movable_bin, phone_booth, planter, traffic_cone, vending_machine,
)
from carlaocc.stages.ingest.procedural.people import pedestrian, rider
from carlaocc.stages.ingest.procedural.poles import (
    flagpole, overhead_signal, pedestrian_signal, sign, street_light, utility_pole, vehicle_signal,
)
from carlaocc.stages.ingest.procedural.primitives import ID, Builder
from carlaocc.stages.ingest.procedural.two_wheelers import parked
from carlaocc.stages.ingest.procedural.vegetation import bush, conifer, hedge, palm, tree
from carlaocc.stages.ingest.procedural.vehicles import (
    bus, car, convertible, double_decker, locomotive, metro, pickup, school_bus, tram, truck,
)
from carlaocc.stages.voxelize.breakdown import asset_fill


SOURCE = "procedural"
LICENCE = "CC0-1.0 (generated)"


@dataclass(frozen=True)
class IngestResult:
    """What the procedural source produces: one record per asset and per part, and the geometry
    keyed by asset id (parts in the asset frame). ``AssetRecord.mesh_path`` is left empty: the
    pipeline fills in the store path when it writes the mesh."""

    assets: list[AssetRecord]
    parts: list[PartRecord]
    geometry: dict[str, AssetGeometry]


# (category, sub-class, builder) of every procedural sub-class, in output order
CATALOGUE: tuple[tuple[str, str, Builder], ...] = (
    ("Building", "house", house),
    ("Building", "residential", residential),
    ("Building", "apartment", apartment),
    ("Building", "office", office),
    ("Building", "tower", tower),
    ("Building", "commercial", commercial),
    ("Building", "industrial", industrial),
    ("Building", "warehouse", warehouse),
    ("Building", "garage", garage),
    ("Building", "gas_station", gas_station),
    ("Building", "religious", religious),
    ("Building", "public", public),
    ("Pole", "street_light", street_light),
    ("Pole", "utility_pole", utility_pole),
    ("Pole", "flagpole", flagpole),
    ("TrafficLight", "vehicle_signal", vehicle_signal),
    ("TrafficLight", "pedestrian_signal", pedestrian_signal),
    ("TrafficLight", "overhead_signal", overhead_signal),
    ("TrafficSign", "stop", sign("stop")),
    ("TrafficSign", "speed_limit", sign("speed_limit")),
    ("TrafficSign", "yield", sign("yield")),
    ("TrafficSign", "warning", sign("warning")),
    ("TrafficSign", "direction", sign("direction")),
    ("TrafficSign", "no_entry", sign("no_entry")),
    ("TrafficSign", "one_way", sign("one_way")),
    ("TrafficSign", "pedestrian_crossing", sign("pedestrian_crossing")),
    ("TrafficSign", "parking", sign("parking")),
    ("Vegetation", "tree", tree),
    ("Vegetation", "conifer", conifer),
    ("Vegetation", "bush", bush),
    ("Vegetation", "palm", palm),
    ("Vegetation", "hedge", hedge),
    ("Pedestrian", "adult", pedestrian("adult")),
    ("Pedestrian", "child", pedestrian("child")),
    ("Rider", "cyclist", rider("bicycle")),
    ("Rider", "motorcyclist", rider("motorcycle")),
    ("Car", "sedan", car("sedan")),
    ("Car", "hatchback", car("hatchback")),
    ("Car", "suv", car("suv")),
    ("Car", "van", car("van")),
    ("Car", "coupe", car("coupe")),
    ("Car", "wagon", car("wagon")),
    ("Car", "minivan", car("minivan")),
    ("Car", "taxi", car("taxi")),
    ("Car", "police", car("police")),
    ("Car", "convertible", convertible),
    ("Car", "pickup", pickup),
    ("Truck", "box_truck", truck("box_truck")),
    ("Truck", "tanker", truck("tanker")),
    ("Truck", "fire_truck", truck("fire_truck")),
    ("Truck", "semi_truck", truck("semi_truck")),
    ("Truck", "garbage_truck", truck("garbage_truck")),
    ("Truck", "tow_truck", truck("tow_truck")),
    ("Truck", "cement_mixer", truck("cement_mixer")),
    ("Truck", "dump_truck", truck("dump_truck")),
    ("Bus", "city_bus", bus("city_bus")),
    ("Bus", "minibus", bus("minibus")),
    ("Bus", "coach", bus("coach")),
    ("Bus", "school_bus", school_bus),
    ("Bus", "double_decker", double_decker),
    ("Train", "tram", tram),
    ("Train", "metro", metro),
    ("Train", "train", locomotive),
    ("Motorcycle", "sport", parked("sport")),
    ("Motorcycle", "cruiser", parked("cruiser")),
    ("Motorcycle", "scooter", parked("scooter")),
    ("Motorcycle", "moped", parked("moped")),
    ("Bicycle", "city_bike", parked("city_bike")),
    ("Bicycle", "road_bike", parked("road_bike")),
    ("Bicycle", "mountain_bike", parked("mountain_bike")),
    ("Bicycle", "cargo_bike", parked("cargo_bike")),
    ("Static", "bench", bench),
    ("Static", "bin", litter_bin),
    ("Static", "hydrant", hydrant),
    ("Static", "bus_stop", bus_stop),
    ("Static", "mailbox", mailbox),
    ("Static", "kiosk", kiosk),
    ("Static", "bollard", bollard),
    ("Static", "planter", planter),
    ("Static", "barrier", barrier),
    ("Static", "traffic_cone", traffic_cone),
    ("Static", "billboard", billboard),
    ("Static", "vending_machine", vending_machine),
    ("Static", "phone_booth", phone_booth),
    ("Dynamic", "movable_bin", movable_bin),
    ("Dynamic", "box", boxes),
    ("Dynamic", "luggage", luggage),
)


# --------------------------------------------------------------------------------------------
# standardization, identity, records
# --------------------------------------------------------------------------------------------


def _recentre(parts: list[MeshPart]) -> tuple[list[MeshPart], np.ndarray]:
    """Move all parts so the asset's bounding box has its bottom centre at the origin; returns
    the moved parts and the extent (x, y, z) in metres."""
    allv = np.concatenate([p.vertices for p in parts])
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    shift = np.array([-(lo[0] + hi[0]) / 2, -(lo[1] + hi[1]) / 2, -lo[2]])
    # round to 0.1 um so float noise of the primitives never leaks into ids or files
    moved = [replace(p, vertices=np.round(p.vertices + shift, 7) + 0.0) for p in parts]
    return moved, hi - lo


def asset_id_for(category: str, subclass: str, parts: list[MeshPart]) -> str:
    """Content-derived asset id: the first 16 hex digits of a SHA-256 over the category, the
    sub-class and, per part, its name, class, material, transparency and its vertices (rounded
    to 0.1 mm, little-endian float64) and faces (little-endian int64). Same geometry, same id."""
    h = hashlib.sha256()
    h.update(f"{category}\x00{subclass}\x00".encode())
    for p in parts:
        h.update(f"{p.name}\x00{p.semantic_id}\x00{p.material}\x00{int(p.transparent)}\x00".encode())
        h.update((np.round(p.vertices, 4) + 0.0).astype("<f8").tobytes())
        h.update(np.asarray(p.faces).astype("<i8").tobytes())
    return h.hexdigest()[:16]


def _variant_rng(seed: int, category: str, subclass: str, variant: int) -> np.random.Generator:
    """Independent generator per (seed, category, sub-class, variant): adding a sub-class never
    changes the others' draws."""
    key = int.from_bytes(hashlib.sha256(f"{category}/{subclass}".encode()).digest()[:8], "little")
    return np.random.default_rng(np.random.SeedSequence([seed & 0xFFFFFFFFFFFFFFFF, key, variant]))


def asset_records(
    category: str, subclass: str, variant: int, parts: list[MeshPart]
) -> tuple[AssetRecord, list[PartRecord], AssetGeometry]:
    """Standardize one asset's parts and describe them as records."""
    parts, extent = _recentre(parts)
    aid = asset_id_for(category, subclass, parts)
    closed = tuple(is_watertight(p.faces) for p in parts)
    geometry = AssetGeometry(asset_id=aid, parts=tuple(parts), part_closed=closed)
    # how the voxelizer fills it, and how much of its volume hole handling recovers
    fill = asset_fill(geometry)
    asset = AssetRecord(
        asset_id=aid, source=SOURCE, source_path=f"procedural://{category}/{subclass}/{variant}",
        licence=LICENCE, category_id=ID[category], category=category, subclass=subclass,
        extent=[float(e) for e in extent],
        vertex_count=int(sum(len(p.vertices) for p in parts)), face_count=int(sum(len(p.faces) for p in parts)),
        part_count=len(parts), transparent_part_count=sum(p.transparent for p in parts),
        surface_area=sum(surface_area(p.vertices, p.faces) for p in parts),
        volume=sum(signed_volume(p.vertices, p.faces) for p in parts) if all(closed) else None,
        watertight=all(closed), **fill.record_fields(), scale_applied=1.0, scale_rule="metric by construction",
        geometry_hash=geometry_hash([(p.vertices, p.faces) for p in parts]), mesh_path="",
    )  # fmt: skip
    part_records = [
        PartRecord(
            asset_id=aid, part_index=k, name=p.name, material=p.material, transparent=p.transparent,
            semantic_id=p.semantic_id, face_count=int(len(p.faces)), watertight=c, color=[int(v) for v in p.color],
        )  # fmt: skip
        for k, (p, c) in enumerate(zip(parts, closed))
    ]
    return asset, part_records, geometry


def ingest_procedural(config: IngestConfig) -> IngestResult:
    """Generate the procedural asset library: ``config.variants_per_subclass`` seeded variants of
    every sub-class of :data:`CATALOGUE`, standardized to the asset frame (metres, +X forward,
    Z up, origin at the bottom centre). Deterministic: the same ``config.seed`` gives identical
    records and vertex arrays. Records come in catalogue order, then variant order."""
    if config.variants_per_subclass < 1:
        raise ValueError(f"variants_per_subclass must be >= 1, got {config.variants_per_subclass}")
    assets: list[AssetRecord] = []
    parts: list[PartRecord] = []
    geometry: dict[str, AssetGeometry] = {}
    for category, subclass, build in CATALOGUE:
        for variant in range(config.variants_per_subclass):
            # draw this variant's sizes, build its parts, standardize and describe them
            rng = _variant_rng(config.seed, category, subclass, variant)
            asset, part_records, geom = asset_records(category, subclass, variant, build(rng))
            if asset.asset_id in geometry:  # identical draws cannot happen with continuous ranges
                raise ValueError(f"procedural asset {category}/{subclass}/{variant} duplicates {asset.asset_id}")
            assets.append(asset)
            parts.extend(part_records)
            geometry[asset.asset_id] = geom
    return IngestResult(assets=assets, parts=parts, geometry=geometry)
