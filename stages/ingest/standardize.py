"""Standardization and validation of a source asset into an ADMesh asset.

Input: a :class:`stages.ingest.raw.RawAsset` (triangle parts in the source's frame and units, with
what the source declares about them). Output: a :class:`StandardizedAsset` (records + geometry in
the asset frame) or a :class:`stages.ingest.raw.Rejection` (quarantine). Bad data never raises.

Steps, in order:

1. **Labels and licence.** ``category`` None (or the empty class ``None``) -> ``"no category"``;
   a name the taxonomy does not know -> ``"unknown category 'X'"``; ``licence_required`` without a
   licence -> ``"missing licence"``. A sub-class outside the taxonomy's vocabulary is kept and
   recorded in :attr:`StandardizedAsset.notes` (never rejected). A part's ``semantic_id`` None
   means the asset's class.
2. **Arrays.** Faces must be ``(M, 3)`` integer triangles indexing the part's vertices
   (``"not triangles"``, ``"face index out of range"``); vertices finite
   (``"non-finite vertices"``); some faces at all (``"empty mesh"``).
3. **Cleaning, per part.** Degenerate faces (a repeated index, or zero area: twice the area below
   ``1e-12`` of the squared bounding-box diagonal) and duplicate faces (same vertex set, whatever
   the order or winding; the first is kept) are removed, then unreferenced vertices dropped. Parts
   left without faces are dropped; when none is left: ``"all faces degenerate"``. Vertices are not
   welded: the source adapters index their meshes.
4. **Frame.** A proper rotation (det +1) maps the declared ``forward`` axis to +X and ``up`` to +Z
   (the source's left, ``up x forward``, goes to +Y); ``up`` and ``forward`` must be perpendicular
   (``"axes not perpendicular"``).
5. **Scale** (source units -> metres), first rule that applies:
   ``target_length`` (longest horizontal extent := target) > ``normalized`` (the measured dimension
   := the sub-class's typical size) > declared units (m, cm, mm, in: fixed factor) > ``unknown``:
   try factors 1, 0.01, 0.001, 0.0254, 0.3048 and keep one that lands the measured dimension
   inside the sub-class's [min, max] (1 when it fits, else the one closest to the typical size in
   log scale); none fits -> scale to the typical size (rule says ``"fallback"``) when the size is
   within ``FALLBACK_MAX_RATIO`` (100x) of the typical size (game units), else ``"absurd size"``.
   The measured dimension is ``"length"`` (longest horizontal extent, max of x and y) or
   ``"height"`` (z extent), per :func:`size_range`.
6. **Origin** at the bottom centre of the bounding box (x, y centred, z from 0); vertices rounded
   to 0.1 um so float noise never reaches hashes or files.
7. **Plausibility.** The measured dimension outside ``[min / 3, max * 3]`` -> ``"absurd size"``
   (the hint names the size, the range and the scale rule).
8. **Watertightness, per part** with :func:`stages.geometry.is_watertight`. A part that is closed
   (every undirected edge shared by exactly two faces) but inconsistently wound is re-wound by a
   breadth-first walk over its faces; closed bodies whose signed volume is negative (inside out)
   are flipped unless they lie inside another body of the part (an inner shell of a hollow solid
   is meant to face inward). Both repairs are recorded in the notes.

Identity: ``asset_id`` = first 16 hex digits of SHA-256 over ``category|subclass|geometry_hash|
part semantic ids``; the same standardized geometry and labels from two files give the same id.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from carlaocc.schemas import taxonomy
from carlaocc.schemas.records import AssetRecord, PartRecord
from carlaocc.stages.geometry import (AssetGeometry, MeshPart, geometry_hash, is_watertight, signed_volume,
                             surface_area)
from carlaocc.stages.ingest.raw import RawAsset, RawPart, Rejection

__all__ = [
    "StandardizedAsset", "standardize", "SIZE_RANGES", "SUBCLASS_SIZE_RANGES", "size_range",
    "DECLARED_UNITS", "INFERENCE_FACTORS", "rotation_to_asset_frame",
]  # fmt: skip

# unknown units: beyond this ratio to the typical size no rescaling is attempted
FALLBACK_MAX_RATIO = 100.0
# vertices closer than this fraction of the asset's bounding-box diagonal are one vertex
WELD_REL = 1e-9
# classes whose length runs along their forward axis: lying sideways (y > 1.1 x) is corrected
LONG_ALONG_X = frozenset({"Car", "Truck", "Bus", "Train", "Motorcycle", "Bicycle"})
SIDEWAYS_RATIO = 1.1

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

DEGENERATE_REL = 1e-12
"""A face is degenerate when twice its area is below this times the squared bbox diagonal."""

_AXES: dict[str, np.ndarray] = {
    f"{s}{a}": sign * np.eye(3)[i] for i, a in enumerate("xyz") for s, sign in (("+", 1.0), ("-", -1.0))
}


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


def _range_label(category: str, subclass: str) -> str:
    """Which table row :func:`size_range` used: ``Car/sedan`` or ``Car``."""
    return f"{category}/{subclass}" if (category, subclass) in SUBCLASS_SIZE_RANGES else category


# --------------------------------------------------------------------------------------------
# result type
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StandardizedAsset:
    """A standardized asset: its record (``mesh_path`` empty, no aliases), one record per part and
    the geometry in the asset frame (metres, +X forward, Z up, origin at the bottom centre).

    ``notes`` says what cleaning and repair did and what was kept despite doubts (removed faces,
    re-wound parts, a sub-class outside the taxonomy); the records have no field for it."""

    asset: AssetRecord
    parts: list[PartRecord]
    geometry: AssetGeometry
    notes: tuple[str, ...] = ()


# --------------------------------------------------------------------------------------------
# frame
# --------------------------------------------------------------------------------------------


def rotation_to_asset_frame(up: str, forward: str) -> np.ndarray | None:
    """3x3 proper rotation mapping the source's ``forward`` axis to +X and ``up`` to +Z (and
    ``up x forward``, the source's left, to +Y); None when the axes are not perpendicular.
    ``KeyError`` for an axis name other than ``+x``, ``-x``, ..., ``-z``."""
    u, f = _AXES[up], _AXES[forward]
    if abs(float(u @ f)) > 0.0:
        return None
    # rows: the source vectors that become +X, +Y, +Z; orthonormal with det +1 by construction
    return np.stack([f, np.cross(u, f), u])


# --------------------------------------------------------------------------------------------
# cleaning
# --------------------------------------------------------------------------------------------


@dataclass
class _Clean:
    vertices: np.ndarray
    faces: np.ndarray
    degenerate: int
    duplicates: int
    unreferenced: int


def _check_arrays(k: int, part: RawPart) -> tuple[np.ndarray, np.ndarray] | Rejection:
    """The part's arrays as float64 (N, 3) and int64 (M, 3), or why they cannot be used."""
    name = part.name or f"part {k}"
    try:
        v = np.asarray(part.vertices, dtype=np.float64)
    except (TypeError, ValueError):
        return Rejection("bad vertices", f"{name}: vertices must be an (N, 3) array of numbers")
    f = np.asarray(part.faces)
    if v.size == 0:
        v = v.reshape(0, 3)
    if f.size == 0:
        f = f.reshape(0, 3)
    if v.ndim != 2 or v.shape[1] != 3:
        return Rejection("bad vertices", f"{name}: vertices have shape {v.shape}, expected (N, 3)")
    if f.ndim != 2 or f.shape[1] != 3:
        return Rejection("not triangles", f"{name}: faces have shape {f.shape}, expected (M, 3): "
                         "triangulate polygons in the source adapter")
    if not np.issubdtype(f.dtype, np.integer):
        ok = np.issubdtype(f.dtype, np.floating) and np.all(np.isfinite(f)) and np.all(f == np.round(f))
        if not ok:
            return Rejection("not triangles", f"{name}: face indices must be integers, got {f.dtype}")
    f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        bad = int(np.count_nonzero((f < 0) | (f >= len(v))))
        return Rejection("face index out of range",
                         f"{name}: {bad} face indices outside 0..{len(v) - 1} ({len(v)} vertices): "
                         "the source file is corrupt or its index buffers were mis-read")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(v), axis=1)))
        return Rejection("non-finite vertices",
                         f"{name}: {bad} of {len(v)} vertices are NaN or infinite: repair or "
                         "re-export the mesh")
    return v, f


def _weld(v: np.ndarray, f: np.ndarray, quantum: float) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices at the same position (to ``quantum``): exporters split vertices along
    seams (normals, UVs), which would make every closed mesh look open. First occurrence wins."""
    if len(v) == 0 or quantum <= 0:
        return v, f
    keys = np.round(v / quantum).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    # keep the welded vertices in their original order
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return v[first[order]], rank[inverse.reshape(-1)][f]


def _clean(v: np.ndarray, f: np.ndarray, tol2: float, quantum: float = 0.0) -> _Clean:
    """Weld coincident vertices, drop degenerate then duplicate faces, then unreferenced
    vertices (order kept)."""
    v, f = _weld(v, f, quantum)
    n_in = len(f)
    # repeated index, or (twice the) area below the tolerance
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 2] == f[:, 0])
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flat = np.einsum("ij,ij->i", cross, cross) <= tol2 * tol2
    f = f[~(repeated | flat)]
    degenerate = n_in - len(f)
    # duplicates: same sorted vertex triple; the first occurrence wins
    if len(f):
        _, first = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        keep = np.sort(first)
        duplicates = len(f) - len(keep)
        f = f[keep]
    else:
        duplicates = 0
    # unreferenced vertices: renumber the used ones in their original order
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    remap = np.cumsum(used) - 1
    return _Clean(v[used], remap[f].reshape(-1, 3).astype(np.int64), degenerate, duplicates,
                  int(len(v) - used.sum()))


# --------------------------------------------------------------------------------------------
# winding
# --------------------------------------------------------------------------------------------


def _edges(f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed edges (a -> b) of every face, and the face each belongs to (3M each)."""
    a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
    b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
    return a, b, np.tile(np.arange(len(f)), 3)


def _is_closed(f: np.ndarray) -> bool:
    """Every undirected edge shared by exactly two faces (orientation not considered)."""
    if len(f) == 0:
        return False
    a, b, _ = _edges(f)
    n = int(f.max()) + 1
    _, counts = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    return bool(np.all(counts == 2))


def _flip(f: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = f.copy()
    out[mask] = out[mask][:, ::-1]
    return out


def _rewind(f: np.ndarray) -> tuple[np.ndarray, int]:
    """Make a closed (edge-manifold) mesh consistently wound: breadth-first over the faces of each
    connected body, keeping each body's first face as it is. Returns the faces and how many were
    flipped. A non-orientable surface stays inconsistent (the caller re-checks)."""
    m = len(f)
    a, b, face = _edges(f)
    n = int(f.max()) + 1
    key = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(key, kind="stable")
    # closed: sorted keys come in pairs (i, j) sharing one undirected edge
    i, j = order[0::2], order[1::2]
    fi, fj = face[i], face[j]
    # the two faces agree when they walk the shared edge in opposite directions
    rel = (a[i] == a[j]).astype(np.int8)  # 1: one of them must be flipped relative to the other
    pair = np.minimum(fi, fj).astype(np.int64) * m + np.maximum(fi, fj)
    pair, first = np.unique(pair, return_index=True)
    fi, fj, rel = pair // m, pair % m, rel[first]
    # a virtual root (index m) linked to one face of every body, so one BFS covers all bodies
    adj = sparse.coo_matrix((np.ones(len(fi)), (fi, fj)), shape=(m + 1, m + 1)).tocsr()
    _, body = csgraph.connected_components(adj[:m, :m], directed=False)
    _, seeds = np.unique(body, return_index=True)
    rows = np.concatenate([fi, fj, seeds, np.full(len(seeds), m)])
    cols = np.concatenate([fj, fi, np.full(len(seeds), m), seeds])
    vals = np.concatenate([rel, rel, np.zeros(2 * len(seeds), np.int8)]).astype(np.float64) + 1.0
    graph = sparse.csr_matrix((vals, (rows, cols)), shape=(m + 1, m + 1))
    _, pred = csgraph.breadth_first_order(graph, m, directed=False, return_predecessors=True)
    # parity of every face relative to its body's seed, by pointer jumping up the BFS tree
    ptr = np.where(pred < 0, np.arange(m + 1), pred)
    ptr[m] = m
    nodes = np.arange(m + 1)
    parity = (np.asarray(graph[nodes, ptr]).ravel() - 1.0).clip(0).astype(np.int8)
    parity[m] = 0
    parity[seeds] = 0
    ptr[seeds] = m
    while np.any(ptr != m):
        parity = parity ^ parity[ptr]
        ptr = ptr[ptr]
    flip = parity[:m].astype(bool)
    return _flip(f, flip), int(flip.sum())


def _fix_inverted(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, int]:
    """Flip the closed bodies of a consistently wound part whose signed volume is negative,
    unless the body lies inside another body's bounding box (an inner shell of a hollow solid).
    Returns the faces and how many bodies were flipped."""
    n = len(v)
    adj = sparse.coo_matrix((np.ones(2 * len(f)), (np.r_[f[:, 0], f[:, 1]], np.r_[f[:, 1], f[:, 2]])), shape=(n, n))
    count, label = csgraph.connected_components(adj, directed=False)
    body = label[f[:, 0]]
    tri = v[f]
    vol = np.bincount(body, weights=np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])),
                      minlength=count) / 6.0
    negative = np.flatnonzero(vol < 0.0)
    if len(negative) == 0:
        return f, 0
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, label, v)
    np.maximum.at(hi, label, v)
    flip_bodies = []
    for c in negative:
        inside = np.all(lo <= lo[c], axis=1) & np.all(hi >= hi[c], axis=1)
        inside[c] = False
        if not inside.any():
            flip_bodies.append(c)
    if not flip_bodies:
        return f, 0
    return _flip(f, np.isin(body, flip_bodies)), len(flip_bodies)


# --------------------------------------------------------------------------------------------
# scale
# --------------------------------------------------------------------------------------------


def _measure(extent: np.ndarray, dim: str) -> float:
    return float(extent[2]) if dim == "height" else float(max(extent[0], extent[1]))


def _choose_scale(raw: RawAsset, category: str, extent: np.ndarray) -> tuple[float, str] | Rejection:
    """(scale source units -> metres, rule) from the extent in the asset frame (source units)."""
    sub = raw.subclass
    dim, lo, typ, hi = size_range(category, sub)
    label = _range_label(category, sub)
    if raw.target_length is not None:
        t = raw.target_length
        if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
            return Rejection("bad target length", f"target_length {t!r} must be a positive number of "
                             "metres: fix the category map or the source's metadata")
        return t / float(max(extent[0], extent[1])), f"target_length {t:g} m from category map"
    size = _measure(extent, dim)
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


# --------------------------------------------------------------------------------------------
# standardize
# --------------------------------------------------------------------------------------------


def _category(raw: RawAsset) -> taxonomy.SemanticClass | Rejection:
    if raw.category is None or not str(raw.category).strip():
        return Rejection("no category", "the source gives no class for this object: add it to the "
                         "source's category map (categories are never guessed)")
    try:
        cls = taxonomy.by_name(str(raw.category))
    except KeyError:
        valid = ", ".join(c.name for c in taxonomy.CLASSES if c.id != 0)
        return Rejection(f"unknown category '{raw.category}'",
                         f"map it to one of the taxonomy classes: {valid}")
    if cls.id == 0:
        return Rejection("no category", f"class {raw.category!r} is the empty label (id 0): map the "
                         "object to a real class")
    return cls


def standardize(raw: RawAsset) -> StandardizedAsset | Rejection:
    """Standardize one source asset (frame, units, cleaning, validation; see the module doc).
    Returns the records and geometry, or a :class:`Rejection` for data that cannot be used."""
    cls = _category(raw)
    if isinstance(cls, Rejection):
        return cls
    category = cls.name
    if raw.licence_required and not (raw.licence or "").strip():
        return Rejection("missing licence", f"source '{raw.source}' requires a licence per object "
                         "and this one has none: add it to the source's metadata or drop the object")
    try:
        R = rotation_to_asset_frame(raw.up, raw.forward)
    except KeyError:
        return Rejection("bad axis", f"up {raw.up!r} / forward {raw.forward!r}: axes are one of "
                         f"{', '.join(_AXES)}")
    if R is None:
        return Rejection("axes not perpendicular", f"up {raw.up} and forward {raw.forward} must be "
                         "perpendicular axes: fix the source adapter's frame declaration")
    if not raw.parts:
        return Rejection("empty mesh", "the object has no mesh parts: check the source file")

    # arrays and part classes
    checked: list[tuple[RawPart, np.ndarray, np.ndarray, int]] = []
    for k, part in enumerate(raw.parts):
        arrays = _check_arrays(k, part)
        if isinstance(arrays, Rejection):
            return arrays
        sid = cls.id if part.semantic_id is None else part.semantic_id
        try:
            sid = taxonomy.by_id(sid).id
        except (KeyError, TypeError, ValueError):
            return Rejection("unknown part class", f"part {k} ({part.name}) has semantic id "
                             f"{part.semantic_id!r}; ids are 0..{len(taxonomy.CLASSES) - 1}")
        checked.append((part, arrays[0], arrays[1], sid))
    n_faces_in = sum(len(f) for _, _, f, _ in checked)
    if n_faces_in == 0:
        return Rejection("empty mesh", "the object's parts have no faces: check the source file")

    # cleaning, with a tolerance relative to the asset's size
    referenced = [v[np.unique(f)] for _, v, f, _ in checked if len(f)]
    allv = np.concatenate(referenced)
    diag = float(np.linalg.norm(allv.max(axis=0) - allv.min(axis=0)))
    tol2 = DEGENERATE_REL * diag * diag
    notes: list[str] = []
    cleaned: list[tuple[RawPart, _Clean, int]] = []
    for k, (part, v, f, sid) in enumerate(checked):
        c = _clean(v, f, tol2, quantum=WELD_REL * diag)
        label = f"part {k} '{part.name}'"
        if c.degenerate or c.duplicates or c.unreferenced:
            notes.append(f"{label}: removed {c.degenerate} degenerate and {c.duplicates} duplicate "
                         f"faces, {c.unreferenced} unreferenced vertices")
        if len(c.faces) == 0:
            notes.append(f"{label}: dropped (no faces left)")
            continue
        cleaned.append((part, c, sid))
    if not cleaned:
        return Rejection("all faces degenerate", f"all {n_faces_in} faces have zero area, repeat a "
                         "vertex or duplicate another: nothing is left after cleaning")

    # frame, scale, origin
    rotated = [c.vertices @ R.T for _, c, _ in cleaned]
    allv = np.concatenate(rotated)
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    # a vehicle is longer than wide: one lying sideways had its forward axis mis-declared, so its
    # long side is turned to +X (a quarter turn about +Z; front and back stay ambiguous)
    if category in LONG_ALONG_X and (hi[1] - lo[1]) > SIDEWAYS_RATIO * (hi[0] - lo[0]):
        quarter = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +Y -> +X
        rotated = [v @ quarter.T for v in rotated]
        allv = np.concatenate(rotated)
        lo, hi = allv.min(axis=0), allv.max(axis=0)
        notes.append(f"turned a quarter about +Z: its long side lay along Y (declared forward "
                     f"{raw.forward} is sideways)")
    chosen = _choose_scale(raw, category, hi - lo)
    if isinstance(chosen, Rejection):
        return chosen
    scale, rule = chosen
    shift = -np.array([(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0, lo[2]]) * scale
    placed = [np.round(v * scale + shift, 7) + 0.0 for v in rotated]
    allv = np.concatenate(placed)
    extent = allv.max(axis=0) - allv.min(axis=0)
    dim, rmin, _, rmax = size_range(category, raw.subclass)
    size = _measure(extent, dim)
    if not (rmin / ABSURD_FACTOR <= size <= rmax * ABSURD_FACTOR):
        return Rejection("absurd size", f"{_range_label(category, raw.subclass)} {dim} {size:.4g} m "
                         f"after standardization is outside {rmin / ABSURD_FACTOR:.3g}-"
                         f"{rmax * ABSURD_FACTOR:.3g} m (range {rmin:g}-{rmax:g} m, scale x{scale:.6g}: "
                         f"{rule}): declare the units, fix the up axis or the category")

    if raw.subclass not in cls.subclasses and (raw.subclass or cls.subclasses):
        known = ", ".join(cls.subclasses) or "none"
        notes.append(f"sub-class {raw.subclass!r} is not in the taxonomy's {category} sub-classes "
                     f"({known}); kept as given")

    # watertightness and winding, per part
    mesh_parts: list[MeshPart] = []
    closed: list[bool] = []
    for k, ((part, c, sid), v) in enumerate(zip(cleaned, placed)):
        f = c.faces
        label = f"part {k} '{part.name}'"
        tight = is_watertight(f)
        if not tight and _is_closed(f):
            f2, flipped = _rewind(f)
            if is_watertight(f2):
                f, tight = f2, True
                notes.append(f"{label}: closed but inconsistently wound; winding fixed ({flipped} faces flipped)")
            else:
                notes.append(f"{label}: closed but not orientable; winding left as is")
        if tight:
            f2, bodies = _fix_inverted(v, f)
            if bodies:
                f = f2
                notes.append(f"{label}: {bodies} inside-out bodies flipped outward")
        r, g, b = taxonomy.by_id(sid).color
        mesh_parts.append(MeshPart(
            name=part.name or f"part_{k}", vertices=v, faces=f, semantic_id=sid,
            material=part.material, transparent=bool(part.transparent),
            color=(r, g, b, 110 if part.transparent else 255),
        ))  # fmt: skip
        closed.append(tight)

    ghash = geometry_hash([(p.vertices, p.faces) for p in mesh_parts])
    # labels and surface properties are part of identity: two files are one asset only when
    # they agree on geometry, classes, materials and transparency
    ids = ",".join(f"{p.semantic_id}:{p.material}:{int(p.transparent)}" for p in mesh_parts)
    aid = hashlib.sha256(f"{category}|{raw.subclass}|{ghash}|{ids}".encode()).hexdigest()[:16]
    watertight = all(closed)
    asset = AssetRecord(
        asset_id=aid, source=raw.source, source_path=raw.source_path, licence=raw.licence or "",
        category_id=cls.id, category=category, subclass=raw.subclass,
        extent=[float(e) for e in extent],
        vertex_count=int(sum(len(p.vertices) for p in mesh_parts)),
        face_count=int(sum(len(p.faces) for p in mesh_parts)),
        part_count=len(mesh_parts), transparent_part_count=sum(p.transparent for p in mesh_parts),
        surface_area=float(sum(surface_area(p.vertices, p.faces) for p in mesh_parts)),
        volume=float(sum(signed_volume(p.vertices, p.faces) for p in mesh_parts)) if watertight else None,
        watertight=watertight, scale_applied=float(scale), scale_rule=rule, geometry_hash=ghash,
        aliases=[], notes="; ".join(notes), mesh_path="",
    )  # fmt: skip
    part_records = [
        PartRecord(
            asset_id=aid, part_index=k, name=p.name, material=p.material, transparent=p.transparent,
            semantic_id=p.semantic_id, face_count=int(len(p.faces)), watertight=t, texture=part.texture or "",
        )  # fmt: skip
        for k, (p, t, (part, _, _)) in enumerate(zip(mesh_parts, closed, cleaned))
    ]
    geometry = AssetGeometry(asset_id=aid, parts=tuple(mesh_parts), part_closed=tuple(closed))
    return StandardizedAsset(asset=asset, parts=part_records, geometry=geometry, notes=tuple(notes))
