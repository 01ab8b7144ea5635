"""The built-in procedural ADMesh source: parametric road-scene assets made from closed primitives.

The catalogue (:data:`CATALOGUE`) covers every *thing* class of the taxonomy (Pedestrian, Rider,
Car, Truck, Bus, Train, Motorcycle, Bicycle, Building) and the street-scene stuff props (poles,
street lights, traffic lights, signs, trees and other plants, benches, bins and other furniture,
a few movable props), with several sub-classes each: 87 sub-classes, so the default
``variants_per_subclass`` (3) gives 261 distinct assets. Every sub-class name is one of its
class's taxonomy sub-classes.

Every asset is a list of parts (:class:`stages.geometry.MeshPart`) in the **asset frame**: metres,
+X forward, +Y left, Z up, origin at the bottom centre of the asset's axis-aligned bounding box.
Each part is built from ``trimesh.creation`` primitives (box, cylinder, icosphere, capsule, cone)
or convex extruded prisms (:func:`_extrude`) and is closed and consistently wound (outward) on its
own; a part made of several primitives uses *disjoint* pieces only (touching at most), so a closed
part stays a valid solid for interior fill. Pieces of one asset that overlap (a wheel inside a
wheel arch, a window half sunk into a wall, a column under a canopy) are separate parts.

Transparent parts (vehicle windows and windscreens, building glazing, bus-shelter and phone-booth
panes, vending-machine fronts) are parts of their own with ``transparent=True``, material
``"glass"`` and the asset's class as semantic id.

Conventions the scene builder relies on (documented here, derived from the asset extent):

* Vehicles (Car, Truck, Bus, Train, Motorcycle, Bicycle, Rider) drive along +X; wheels touch z = 0.
* Buildings: the entrance facade faces +X; ``extent[0]`` is the depth, ``extent[1]`` the frontage.
* ``Pole/street_light``: the pole stands at the -X end (``x = -extent[0]/2 + r``, ``y = 0``);
  the arm and lamp reach forward along +X (over the road when +X points at it).
* ``Pole/utility_pole`` and ``Pole/flagpole``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``
  (a transformer or the flag, when present, is on its +X side).
* ``TrafficLight/vehicle_signal`` and ``TrafficLight/pedestrian_signal``: the pole is at
  ``x = -extent[0]/2 + r``, ``y = 0``; the lenses face +X (towards the traffic they control).
* ``TrafficLight/overhead_signal``: the pole is at ``x = -extent[0]/2 + r``,
  ``y = +extent[1]/2 - r``; the mast arm reaches along -Y and the head's lenses face +X.
* ``TrafficSign/*``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``; the plate faces +X.
* ``Static/bench``, ``Static/bus_stop``, ``Static/kiosk``, ``Static/vending_machine``,
  ``Static/phone_booth``, ``Static/billboard``, ``Static/mailbox``: the usable side (seat, open
  side, service window, front panel, door, board face, slot) faces +X.

``r`` is the pole radius (0.04-0.14 m, within 5 cm of the town's assumed 0.09 m). Sizes are seeded
uniform draws inside realistic ranges (a sub-class's variants also draw styles and colours), so the
``variants_per_subclass`` variants of one sub-class differ in size and proportions; the same seed
gives byte-identical vertex arrays and records. Colours (``MeshPart.color``) are cosmetic: they go
into GLB files and previews, never into ids or hashes.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import trimesh

from carlaocc.schemas import taxonomy
from carlaocc.schemas.configs import IngestConfig
from carlaocc.schemas.records import AssetRecord, PartRecord
from carlaocc.stages.geometry import (AssetGeometry, MeshPart, concatenate, geometry_hash, is_watertight,
                             signed_volume, surface_area)

__all__ = ["IngestResult", "ingest_procedural", "asset_id_for", "SOURCE", "LICENCE", "CATALOGUE"]

SOURCE = "procedural"
LICENCE = "CC0-1.0 (generated)"

# class ids, looked up once from the taxonomy table
_ID = {name: taxonomy.by_name(name).id for name in (
    "Building", "Pole", "TrafficLight", "TrafficSign", "Vegetation", "Pedestrian", "Rider", "Car",
    "Truck", "Bus", "Train", "Motorcycle", "Bicycle", "Static", "Dynamic",
)}  # fmt: skip

RGBA = tuple[int, int, int, int]

# default display colour (RGBA) of each material; purely cosmetic (GLB export, previews)
_COLOURS: dict[str, RGBA] = {
    "paint": (170, 30, 40, 255),
    "glass": (140, 180, 210, 110),
    "rubber": (25, 25, 25, 255),
    "metal": (120, 120, 125, 255),
    "plastic": (60, 60, 60, 255),
    "concrete": (170, 165, 160, 255),
    "brick": (160, 80, 60, 255),
    "plaster": (215, 205, 185, 255),
    "stone": (190, 180, 160, 255),
    "roof_tile": (120, 50, 40, 255),
    "wood": (110, 75, 45, 255),
    "bark": (90, 60, 40, 255),
    "foliage": (60, 120, 40, 255),
    "lamp": (250, 240, 200, 255),
    "lens": (240, 200, 60, 255),
    "sign_face": (220, 220, 220, 255),
    "skin": (220, 180, 150, 255),
    "cloth": (60, 70, 120, 255),
    "leather": (70, 45, 35, 255),
    "cardboard": (180, 140, 90, 255),
}

# cosmetic palettes the variants draw from
_WHITE, _BLACK, _RED, _YELLOW = (235, 235, 232, 255), (28, 28, 30, 255), (190, 25, 30, 255), (240, 185, 20, 255)
_BLUE, _GREEN, _ORANGE, _DARK = (30, 75, 165, 255), (25, 105, 60, 255), (235, 110, 20, 255), (45, 45, 50, 255)
_PAINTS: tuple[RGBA, ...] = (
    (230, 230, 228, 255), (25, 25, 28, 255), (165, 168, 172, 255), (95, 98, 104, 255), (150, 22, 28, 255),
    (28, 58, 130, 255), (18, 32, 68, 255), (42, 84, 56, 255), (205, 160, 40, 255), (110, 70, 45, 255),
    (200, 85, 25, 255), (120, 150, 180, 255),
)  # fmt: skip
_CLOTHES: tuple[RGBA, ...] = (
    (40, 45, 90, 255), (30, 30, 35, 255), (120, 30, 35, 255), (70, 100, 60, 255), (200, 190, 170, 255),
    (90, 90, 95, 255), (170, 120, 60, 255), (60, 110, 160, 255), (150, 80, 130, 255), (220, 220, 215, 255),
)  # fmt: skip
_SKINS: tuple[RGBA, ...] = (
    (240, 205, 180, 255), (220, 180, 150, 255), (180, 130, 95, 255), (120, 80, 55, 255), (85, 60, 45, 255),
)  # fmt: skip
_HAIR: tuple[RGBA, ...] = ((30, 25, 20, 255), (90, 60, 35, 255), (200, 170, 110, 255), (140, 140, 140, 255))
_FACADES: dict[str, tuple[RGBA, ...]] = {
    "plaster": ((215, 205, 185, 255), (232, 226, 212, 255), (205, 180, 150, 255), (190, 198, 204, 255)),
    "brick": ((160, 80, 60, 255), (140, 65, 50, 255), (175, 110, 80, 255)),
    "concrete": ((170, 165, 160, 255), (150, 150, 150, 255), (190, 185, 175, 255)),
    "metal": ((150, 155, 160, 255), (90, 110, 140, 255), (110, 130, 100, 255), (190, 190, 185, 255)),
}

Mesh = tuple[np.ndarray, np.ndarray]  # (vertices (N, 3) float64 m, faces (M, 3) int64)


@dataclass(frozen=True)
class IngestResult:
    """What the procedural source produces: one record per asset and per part, and the geometry
    keyed by asset id (parts in the asset frame). ``AssetRecord.mesh_path`` is left empty: the
    pipeline fills in the store path when it writes the mesh."""

    assets: list[AssetRecord]
    parts: list[PartRecord]
    geometry: dict[str, AssetGeometry]


# --------------------------------------------------------------------------------------------
# primitives: small pure functions returning (vertices, faces) in metres
# --------------------------------------------------------------------------------------------


def _tm(mesh: trimesh.Trimesh) -> Mesh:
    """(vertices, faces) copies of a trimesh primitive."""
    return np.array(mesh.vertices, dtype=np.float64), np.array(mesh.faces, dtype=np.int64)


def _box(lo, hi) -> Mesh:
    """Axis-aligned box between corners ``lo`` and ``hi`` (m)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v, f = _tm(trimesh.creation.box(extents=hi - lo))
    return v + (lo + hi) / 2.0, f


def _frustum(lo, hi, top_lo_xy, top_hi_xy) -> Mesh:
    """A box whose top face is moved to the rectangle ``top_lo_xy .. top_hi_xy`` (a tapered
    greenhouse or hip roof); still 8 vertices, closed and convex when the top lies over the
    bottom."""
    v, f = _box(lo, hi)
    top = v[:, 2] > (lo[2] + hi[2]) / 2.0
    # remap each top vertex from the bottom rectangle to the top rectangle, axis by axis
    for axis in (0, 1):
        at_hi = v[:, axis] > (lo[axis] + hi[axis]) / 2.0
        v[top & at_hi, axis] = top_hi_xy[axis]
        v[top & ~at_hi, axis] = top_lo_xy[axis]
    return v, f


def _chamfer_front_top(mesh: Mesh, dx: float, dz: float) -> Mesh:
    """Move the box's front-top edge (max x, max z) back by ``dx`` and down by ``dz`` (a hood
    slope); the mesh stays closed and convex."""
    v, f = mesh[0].copy(), mesh[1]
    xmax, zmax = v[:, 0].max(), v[:, 2].max()
    edge = (v[:, 0] == xmax) & (v[:, 2] == zmax)
    v[edge, 0] -= dx
    v[edge, 2] -= dz
    return v, f


def _cylinder(radius: float, p0, p1, sections: int = 16) -> Mesh:
    """Closed cylinder of ``radius`` with its axis from point ``p0`` to ``p1`` (m)."""
    return _tm(trimesh.creation.cylinder(radius=radius, segment=[p0, p1], sections=sections))


def _capsule(radius: float, p0, p1, count: int = 8) -> Mesh:
    """Closed capsule whose hemisphere centres are ``p0`` and ``p1`` (it extends ``radius``
    beyond both)."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    v, f = _tm(trimesh.creation.capsule(height=length, radius=radius, count=[count, count]))
    # rotate the +Z axis of the primitive onto the segment, then move it to the midpoint
    R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / length)[:3, :3]
    return v @ R.T + (p0 + p1) / 2.0, f


def _ellipsoid(centre, radii, subdivisions: int = 1) -> Mesh:
    """Closed ellipsoid (a scaled icosphere) at ``centre`` with semi-axes ``radii`` (m)."""
    v, f = _tm(trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0))
    return v * np.asarray(radii, dtype=np.float64) + np.asarray(centre, dtype=np.float64), f


def _cone(radius: float, height: float, base_centre, sections: int = 12) -> Mesh:
    """Closed upright cone with its base disc at ``base_centre`` (m)."""
    v, f = _tm(trimesh.creation.cone(radius=radius, height=height, sections=sections))
    return v + np.asarray(base_centre, dtype=np.float64), f


def _cone_between(radius: float, base, tip, sections: int = 16) -> Mesh:
    """Closed cone with its base disc (``radius``) centred on ``base`` and its apex at ``tip``."""
    base, tip = np.asarray(base, dtype=np.float64), np.asarray(tip, dtype=np.float64)
    d = tip - base
    height = float(np.linalg.norm(d))
    v, f = _tm(trimesh.creation.cone(radius=radius, height=height, sections=sections))
    R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / height)[:3, :3]
    return v @ R.T + base, f


def _pyramid(half: float, height: float, base_centre) -> Mesh:
    """Closed square pyramid: base ``2 half`` by ``2 half`` (edges along X and Y) centred on
    ``base_centre``, apex ``height`` above it (a 4-section cone turned by 45 degrees)."""
    v, f = _tm(trimesh.creation.cone(radius=half * np.sqrt(2.0), height=height, sections=4))
    return _rotate((v, f), _rz(np.pi / 4), base_centre)


def _beam(p0, p1, width: float, height: float) -> Mesh:
    """Box beam of square-ish section ``width`` (across, y) x ``height`` from ``p0`` to ``p1``."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    v, f = _box((-length / 2, -width / 2, -height / 2), (length / 2, width / 2, height / 2))
    # the box's +X becomes the beam direction
    R = trimesh.geometry.align_vectors([1.0, 0.0, 0.0], d / length)[:3, :3]
    return v @ R.T + (p0 + p1) / 2.0, f


def _plate_x(radius: float, thickness: float, centre, sections: int, spin: float) -> Mesh:
    """Regular polygon plate facing +X (disc normal along X) with ``sections`` corners on
    ``radius``, ``thickness`` along X, centred on ``centre``. With ``spin`` 0 a corner points
    down (-Z); ``spin`` (rad) turns the polygon in the Y-Z plane."""
    v, f = _tm(trimesh.creation.cylinder(radius=radius, height=thickness, sections=sections))
    # spin about the primitive's axis, then turn that axis (Z) onto +X: (x, y, z) -> (z, y, -x)
    c, s = np.cos(spin), np.sin(spin)
    v = v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    v = np.column_stack([v[:, 2], v[:, 1], -v[:, 0]])
    return v + np.asarray(centre, dtype=np.float64), f


def _prism_gable(lo, hi) -> Mesh:
    """Triangular prism filling the box ``lo .. hi`` with its ridge along Y at the top (a gable
    roof): a 3-section cylinder turned so its axis runs along Y and one corner points up."""
    v, f = _tm(trimesh.creation.cylinder(radius=1.0, height=1.0, sections=3))
    # proper rotation x -> z, y -> x, z -> y (a corner of the triangle at +x goes to the top)
    v = v[:, [1, 2, 0]]
    return _fit((v, f), lo, hi)


def _extrude(profile, a: float, b: float, axis: str = "y") -> Mesh:
    """Closed prism: the convex polygon ``profile`` ((K, 2) points, either winding) extruded from
    ``a`` to ``b`` along ``axis``. The profile lies in the (x, z) plane for ``axis="y"``, (y, z) for
    ``"x"`` and (x, y) for ``"z"``. The faces are wound outward whatever the profile's winding."""
    P = np.asarray(profile, dtype=np.float64)
    K = len(P)
    # (u, v) = the profile coordinates, w = the extrusion coordinate
    uvw = np.vstack([np.column_stack([P, np.full(K, a)]), np.column_stack([P, np.full(K, b)])])
    faces = [(0, i + 1, i) for i in range(1, K - 1)] + [(K, K + i, K + i + 1) for i in range(1, K - 1)]
    for i in range(K):
        j = (i + 1) % K
        faces += [(i, j, K + j), (i, K + j, K + i)]
    u, v_, w = uvw[:, 0], uvw[:, 1], uvw[:, 2]
    xyz = {"y": (u, w, v_), "x": (w, u, v_), "z": (u, v_, w)}[axis]
    V, F = np.column_stack(xyz), np.asarray(faces, dtype=np.int64)
    if signed_volume(V, F) < 0:  # inward (the profile winding and the axis map disagree): flip
        F = F[:, ::-1].copy()
    return V, F


def _rz(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about +Z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _ry(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about +Y (positive ``a`` tips +X down towards -Z)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rotate(mesh: Mesh, R: np.ndarray, t=(0.0, 0.0, 0.0)) -> Mesh:
    """Rotate a mesh by the proper rotation ``R`` about the origin, then move it by ``t``."""
    return mesh[0] @ np.asarray(R).T + np.asarray(t, dtype=np.float64), mesh[1]


def _fit(mesh: Mesh, lo, hi) -> Mesh:
    """Scale (positive, per axis) and move a mesh so its bounding box is ``lo .. hi``."""
    v, f = mesh
    vmin, vmax = v.min(axis=0), v.max(axis=0)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return (v - vmin) / (vmax - vmin) * (hi - lo) + lo, f


def _union(*meshes: Mesh) -> Mesh:
    """Disjoint pieces as one mesh (each piece stays closed, so the union is closed)."""
    return concatenate(list(meshes))


def _part(
    name: str, mesh: Mesh, semantic: str, material: str, transparent: bool = False, color: RGBA | None = None
) -> MeshPart:
    """A :class:`MeshPart` of class ``semantic`` (taxonomy name) and ``material``, coloured
    ``color`` or the material's default colour."""
    return MeshPart(
        name=name, vertices=mesh[0], faces=mesh[1], semantic_id=_ID[semantic], material=material,
        transparent=transparent, color=color if color is not None else _COLOURS[material],
    )  # fmt: skip


def _glass(name: str, mesh: Mesh, semantic: str) -> MeshPart:
    """A transparent glass part of class ``semantic``."""
    return _part(name, mesh, semantic, "glass", transparent=True)


# --------------------------------------------------------------------------------------------
# builders: one function per sub-class family; each draws its sizes (and style) from ``rng``
# --------------------------------------------------------------------------------------------

Builder = Callable[[np.random.Generator], list[MeshPart]]


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One uniform draw in [lo, hi) as a Python float."""
    return float(rng.uniform(lo, hi))


def _pick(rng: np.random.Generator, options: Sequence):
    """One uniformly drawn element of ``options``."""
    return options[int(rng.integers(len(options)))]


def _wheels(
    xs, half_track: float, radius: float, width: float, semantic: str, sections: int = 16
) -> list[MeshPart]:
    """One wheel part per axle position in ``xs`` and side (axis along Y, touching z = 0)."""
    out = []
    for k, x in enumerate(xs):
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y = sy * half_track
            mesh = _cylinder(radius, (x, y - width / 2, radius), (x, y + width / 2, radius), sections)
            out.append(_part(f"wheel_{k}_{side}", mesh, semantic, "rubber"))
    return out


def _greenhouse_vehicle(
    L: float, W: float, H: float, *, semantic: str, clearance: float, belt: float,
    gh_rear: float, gh_front: float, top_rear: float, top_front: float, top_side: float,
    hood: tuple[float, float], wheel_r: float, wheel_w: float, axles: list[float],
    paint: RGBA | None = None,
) -> list[MeshPart]:  # fmt: skip
    """Body box (with a hood chamfer) up to the belt line, a tapered glass greenhouse above it, a
    thin roof, and wheels. ``gh_rear``/``gh_front`` are greenhouse x limits (m); ``top_*`` are the
    insets of its top face (windshield rake, side tumblehome)."""
    roof_t = 0.06
    body = _chamfer_front_top(_box((-L / 2, -W / 2, clearance), (L / 2, W / 2, belt)), *hood)
    gy = W / 2 - 0.04
    glass_top = H - roof_t
    glass = _frustum(
        (gh_rear, -gy, belt), (gh_front, gy, glass_top),
        (gh_rear + top_rear, -gy + top_side), (gh_front - top_front, gy - top_side),
    )  # fmt: skip
    roof = _box((gh_rear + top_rear, -gy + top_side, glass_top), (gh_front - top_front, gy - top_side, H))
    parts = [
        _part("body", body, semantic, "paint", color=paint),
        _glass("windows", glass, semantic),
        _part("roof", roof, semantic, "paint", color=paint),
    ]
    return parts + _wheels(axles, W / 2 - wheel_w / 2 - 0.03, wheel_r, wheel_w, semantic)


# sub-class -> ranges of length, width, height (m) and shape fractions; ``extra`` adds roof
# equipment, ``paints`` restricts the body colours
_SEDAN = dict(L=(4.3, 4.9), W=(1.75, 1.9), H=(1.40, 1.50), r=(0.31, 0.34), clear=0.17, belt=0.52,
              gh=(-0.30, 0.17), top=(0.38, 0.55), hood=(0.25, 0.10))  # fmt: skip
_CAR_SPECS: dict[str, dict] = {
    "sedan": _SEDAN,
    "hatchback": dict(L=(3.8, 4.3), W=(1.68, 1.80), H=(1.42, 1.55), r=(0.30, 0.33), clear=0.16,
                      belt=0.50, gh=(-0.47, 0.16), top=(0.12, 0.55), hood=(0.22, 0.10)),
    "suv": dict(L=(4.5, 5.0), W=(1.85, 2.0), H=(1.65, 1.85), r=(0.36, 0.40), clear=0.24,
                belt=0.55, gh=(-0.46, 0.19), top=(0.10, 0.50), hood=(0.20, 0.08)),
    "van": dict(L=(4.8, 5.4), W=(1.90, 2.05), H=(1.95, 2.30), r=(0.33, 0.36), clear=0.20,
                belt=0.45, gh=(-0.48, 0.33), top=(0.03, 0.38), hood=(0.30, 0.15)),
    "coupe": dict(L=(4.2, 4.7), W=(1.78, 1.90), H=(1.28, 1.38), r=(0.31, 0.34), clear=0.14,
                  belt=0.55, gh=(-0.27, 0.12), top=(0.60, 0.52), hood=(0.28, 0.10)),
    "wagon": dict(L=(4.6, 5.0), W=(1.78, 1.90), H=(1.45, 1.55), r=(0.31, 0.34), clear=0.16,
                  belt=0.52, gh=(-0.47, 0.17), top=(0.08, 0.55), hood=(0.25, 0.10)),
    "minivan": dict(L=(4.8, 5.2), W=(1.90, 2.00), H=(1.70, 1.80), r=(0.33, 0.35), clear=0.17,
                    belt=0.45, gh=(-0.47, 0.30), top=(0.06, 0.65), hood=(0.30, 0.14)),
    "taxi": dict(_SEDAN, extra="taxi_sign", paints=(_YELLOW, _BLACK)),
    "police": dict(_SEDAN, H=(1.42, 1.52), extra="light_bar", paints=(_WHITE, _BLACK, (20, 35, 80, 255))),
}  # fmt: skip


def _car(subclass: str) -> Builder:
    """Builder of a Car sub-class from :data:`_CAR_SPECS`: a greenhouse vehicle, plus a roof
    sign (taxi) or light bar (police)."""
    spec = _CAR_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *spec["L"]), _u(rng, *spec["W"]), _u(rng, *spec["H"])
        r = _u(rng, *spec["r"])
        paint = _pick(rng, spec.get("paints", _PAINTS))
        belt = spec["clear"] + (H - spec["clear"]) * spec["belt"]
        # axles: overhangs of about 19 % (front) and 21 % (rear) of the length
        axles = [L / 2 - 0.19 * L, -L / 2 + 0.21 * L]
        gh_rear, gh_front = spec["gh"][0] * L, spec["gh"][1] * L
        parts = _greenhouse_vehicle(
            L, W, H, semantic="Car", clearance=spec["clear"], belt=belt, gh_rear=gh_rear,
            gh_front=gh_front, top_rear=spec["top"][0], top_front=spec["top"][1], top_side=0.10,
            hood=spec["hood"], wheel_r=r, wheel_w=0.22, axles=axles, paint=paint,
        )  # fmt: skip
        # roof equipment centred on the roof panel
        xc = (gh_rear + spec["top"][0] + gh_front - spec["top"][1]) / 2
        if spec.get("extra") == "taxi_sign":
            sign = _frustum((xc - 0.15, -0.40, H), (xc + 0.15, 0.40, H + 0.22), (xc - 0.12, -0.38), (xc + 0.12, 0.38))
            parts.append(_part("taxi_sign", sign, "Car", "plastic", color=(250, 220, 60, 255)))
        elif spec.get("extra") == "light_bar":
            bar = _box((xc - 0.14, -0.55, H), (xc + 0.14, 0.55, H + 0.11))
            parts.append(_part("light_bar", bar, "Car", "lens", color=_pick(rng, (_BLUE, _RED))))
        return parts

    return build


def _convertible(rng: np.random.Generator) -> list[MeshPart]:
    """Open two-seater (4.0-4.6 m): a low body, a raked windscreen, two seats sticking out of the
    cockpit, an optional folded hood behind them."""
    L, W, H_body = _u(rng, 4.0, 4.6), _u(rng, 1.75, 1.88), _u(rng, 0.92, 1.0)
    r, clear = _u(rng, 0.31, 0.34), 0.14
    paint = _pick(rng, _PAINTS)
    body = _chamfer_front_top(_box((-L / 2, -W / 2, clear), (L / 2, W / 2, H_body)), 0.30, 0.12)
    # windscreen: a thin slab leaning back 0.35 m over its 0.42 m height
    xw, gy = 0.16 * L, W / 2 - 0.08
    screen = _extrude([(xw, H_body), (xw + 0.05, H_body), (xw - 0.30, H_body + 0.42), (xw - 0.35, H_body + 0.42)],
                      -gy, gy)  # fmt: skip
    seat_x = -0.12 * L
    seats = _union(*[
        _box((seat_x - 0.12, sy * 0.42 - 0.24, H_body - 0.3), (seat_x + 0.0, sy * 0.42 + 0.24, H_body + 0.32))
        for sy in (-1.0, 1.0)
    ])  # fmt: skip
    parts = [
        _part("body", body, "Car", "paint", color=paint),
        _glass("windscreen", screen, "Car"),
        _part("seats", seats, "Car", "leather"),
    ]
    if rng.uniform() < 0.5:
        hood = _box((seat_x - 0.75, -W / 2 + 0.12, H_body), (seat_x - 0.25, W / 2 - 0.12, H_body + 0.18))
        parts.append(_part("folded_hood", hood, "Car", "cloth", color=_DARK))
    return parts + _wheels([L / 2 - 0.19 * L, -L / 2 + 0.21 * L], W / 2 - 0.14, r, 0.22, "Car")


def _pickup(rng: np.random.Generator) -> list[MeshPart]:
    """Pickup truck (5.0-5.5 m): a cab greenhouse over the front, an open bed behind it (floor,
    side walls, tailgate)."""
    L, W, H = _u(rng, 5.0, 5.5), _u(rng, 1.90, 2.03), _u(rng, 1.78, 1.92)
    r, clear = _u(rng, 0.38, 0.41), 0.25
    paint = _pick(rng, _PAINTS)
    belt = _u(rng, 1.05, 1.12)
    bed = _u(rng, 0.33, 0.38) * L
    x_bed = -L / 2 + bed  # front wall of the bed
    front = _chamfer_front_top(_box((x_bed, -W / 2, clear), (L / 2, W / 2, belt)), 0.15, 0.06)
    floor_top = belt - 0.45
    bed_floor = _box((-L / 2, -W / 2, clear + 0.1), (x_bed - 0.01, W / 2, floor_top))
    walls = _union(
        _box((-L / 2 + 0.07, W / 2 - 0.06, floor_top + 0.01), (x_bed - 0.01, W / 2, belt)),
        _box((-L / 2 + 0.07, -W / 2, floor_top + 0.01), (x_bed - 0.01, -W / 2 + 0.06, belt)),
        _box((-L / 2, -W / 2, floor_top + 0.01), (-L / 2 + 0.06, W / 2, belt - 0.02)),
    )
    gy = W / 2 - 0.05
    gh_rear, gh_front = x_bed + 0.02, 0.17 * L
    glass = _frustum(
        (gh_rear, -gy, belt), (gh_front, gy, H - 0.06), (gh_rear + 0.06, -gy + 0.1), (gh_front - 0.5, gy - 0.1)
    )
    roof = _box((gh_rear + 0.06, -gy + 0.1, H - 0.06), (gh_front - 0.5, gy - 0.1, H))
    parts = [
        _part("body", _union(front, bed_floor), "Car", "paint", color=paint),
        _part("bed_walls", walls, "Car", "paint", color=paint),
        _glass("windows", glass, "Car"),
        _part("roof", roof, "Car", "paint", color=paint),
    ]
    return parts + _wheels([L / 2 - 0.18 * L, -L / 2 + 0.22 * L], W / 2 - 0.16, r, 0.26, "Car")


def _truck_cab(
    xf: float, W: float, cab_len: float, cab_h: float, paint: RGBA, *, floor: float = 0.70,
    belt: float = 1.65, glass_top: float | None = None,
) -> tuple[list[MeshPart], float]:  # fmt: skip
    """A truck cab whose front is at ``xf``: lower cab (hood chamfer), a raked glass greenhouse, a
    thin roof (or, with ``glass_top`` below the cab height, a tapered roof fairing of a sleeper cab)
    and the cab's back wall. Returns the parts and the cab's rear x."""
    cab_x0 = xf - cab_len
    gy = W / 2 - 0.05
    top = cab_h - 0.08 if glass_top is None else glass_top
    cab = _chamfer_front_top(_box((cab_x0, -W / 2, floor), (xf, W / 2, belt)), 0.08, 0.05)
    glass = _frustum(
        (cab_x0 + 0.3, -gy, belt), (xf - 0.05, gy, top), (cab_x0 + 0.3, -gy + 0.05), (xf - 0.30, gy - 0.05)
    )
    if glass_top is None:
        roof = _box((cab_x0 + 0.3, -gy + 0.05, top), (xf - 0.30, gy - 0.05, cab_h))
    else:
        roof = _frustum((cab_x0, -gy, top), (xf - 0.30, gy, cab_h), (cab_x0, -gy + 0.12), (xf - 0.9, gy - 0.12))
    back = _box((cab_x0, -gy, belt), (cab_x0 + 0.3, gy, top))
    return [
        _part("cab", cab, "Truck", "paint", color=paint),
        _glass("cab_windows", glass, "Truck"),
        _part("cab_roof", roof, "Truck", "paint", color=paint),
        _part("cab_back", back, "Truck", "paint", color=paint),
    ], cab_x0


def _chassis(x0: float, x1: float, z0: float = 0.55, z1: float = 1.0, half: float = 0.55) -> MeshPart:
    """Truck chassis beam from ``x0`` to ``x1``."""
    return _part("chassis", _box((x0, -half, z0), (x1, half, z1)), "Truck", "metal", color=_DARK)


_BODY_COLOURS = (_WHITE, (200, 200, 195, 255), (150, 155, 160, 255), (30, 75, 165, 255), (200, 85, 25, 255))


def _truck(subclass: str) -> Builder:
    """Trucks: a cab with its own windows at the front, a body behind it (cargo box, tank, fire
    equipment body with a ladder, semi-trailer, refuse compactor, flatbed, mixer drum, tipper),
    a chassis beam and 4-12 wheels."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        paint = _pick(rng, _PAINTS)
        r, wheel_w = 0.50, 0.32
        if subclass in ("box_truck", "tanker"):
            L = _u(rng, 6.5, 9.0) if subclass == "box_truck" else _u(rng, 8.0, 10.0)
            W, H = _u(rng, 2.30, 2.50), _u(rng, 3.0, 3.6)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.0, 2.3), _u(rng, 2.6, 2.9), paint)
            parts.append(_chassis(-L / 2 + 0.3, cab_x0 - 0.15))
            cargo_x0, cargo_x1 = -L / 2, cab_x0 - 0.15
            if subclass == "box_truck":
                box = _box((cargo_x0, -W / 2, 1.0), (cargo_x1, W / 2, H))
                parts.append(_part("cargo_box", box, "Truck", "paint", color=_pick(rng, _BODY_COLOURS)))
            else:
                tr = min((H - 1.0) / 2, W / 2 - 0.02)
                tank = _cylinder(tr, (cargo_x0, 0.0, 1.0 + tr), (cargo_x1, 0.0, 1.0 + tr), 20)
                parts.append(_part("tank", tank, "Truck", "metal", color=(190, 192, 195, 255)))
            axles = [xf - 1.2, -L / 2 + 1.6 + 1.35, -L / 2 + 1.6]
        elif subclass == "fire_truck":
            L, W = _u(rng, 8.5, 10.5), _u(rng, 2.45, 2.55)
            xf, cab_h, body_h = L / 2, _u(rng, 2.9, 3.1), _u(rng, 2.8, 3.1)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.7, 3.1), cab_h, _RED)
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.1),
                _part("equipment_body", _box((-L / 2, -W / 2, 0.9), (cab_x0 - 0.1, W / 2, body_h)), "Truck", "paint",
                      color=_RED),
            ]  # fmt: skip
            # a ladder lying on top, reaching over the cab; rungs between (not touching) the rails
            zl, x0, x1 = max(body_h, cab_h) + 0.25, -L / 2 + 0.2, xf - 0.6
            rails = _union(_box((x0, 0.30, zl), (x1, 0.36, zl + 0.15)), _box((x0, -0.36, zl), (x1, -0.30, zl + 0.15)))
            n = int((x1 - x0) // 0.9)
            rung_x = [x0 + 0.45 + 0.9 * k for k in range(n)]
            rungs = _union(*[_box((x - 0.03, -0.29, zl + 0.05), (x + 0.03, 0.29, zl + 0.09)) for x in rung_x])
            turntable = _cylinder(0.6, (-L / 2 + 1.3, 0.0, body_h), (-L / 2 + 1.3, 0.0, zl - 0.01), 16)
            light = _box((xf - 1.3, -0.6, cab_h), (xf - 1.0, 0.6, cab_h + 0.12))
            parts += [
                _part("ladder_rails", rails, "Truck", "metal"),
                _part("ladder_rungs", rungs, "Truck", "metal"),
                _part("turntable", turntable, "Truck", "metal"),
                _part("light_bar", light, "Truck", "lens", color=_RED),
            ]
            axles = [xf - 1.5, -L / 2 + 2.2]
        elif subclass == "semi_truck":
            L, W = _u(rng, 15.0, 16.5), _u(rng, 2.45, 2.55)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.3, 2.6), _u(rng, 3.6, 3.9), paint, belt=1.75, glass_top=2.75)
            trailer_x1 = cab_x0 - 0.7
            xg = trailer_x1 - 4.5  # landing gear, clear of the tractor's rear wheels
            tanks = _union(*[_cylinder(0.30, (cab_x0 - 1.6, sy * 0.9, 0.75), (cab_x0 - 0.4, sy * 0.9, 0.75), 12)
                             for sy in (-1.0, 1.0)])  # fmt: skip
            parts += [
                _chassis(xf - 6.4, cab_x0 - 0.05, 0.6, 1.05, 0.5),
                _part("fifth_wheel", _box((xf - 5.8, -0.5, 1.06), (xf - 4.6, 0.5, 1.15)), "Truck", "metal"),
                _part("fuel_tanks", tanks, "Truck", "metal", color=(200, 200, 205, 255)),
                _part("trailer", _box((-L / 2, -W / 2, 1.25), (trailer_x1, W / 2, _u(rng, 3.9, 4.05))), "Truck",
                      "paint", color=_pick(rng, _BODY_COLOURS)),
                _part("landing_gear", _union(*[_box((xg, sy * 0.9 - 0.06, 0.3), (xg + 0.12, sy * 0.9 + 0.06, 1.24))
                                                for sy in (-1.0, 1.0)]), "Truck", "metal"),
            ]  # fmt: skip
            axles = [xf - 1.3, xf - 4.9, xf - 6.2, -L / 2 + 1.3, -L / 2 + 2.6, -L / 2 + 3.9]
        elif subclass == "garbage_truck":
            L, W, H = _u(rng, 8.0, 10.0), _u(rng, 2.45, 2.55), _u(rng, 3.4, 3.7)
            xf = L / 2
            colour = _pick(rng, (_WHITE, (60, 130, 60, 255), _ORANGE, (150, 155, 160, 255)))
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.2, 2.5), _u(rng, 2.7, 2.9), colour)
            xh = -L / 2 + 1.4  # the rear hopper, tapered, behind the compactor body
            hopper = _extrude([(xh - 0.01, 0.9), (xh - 0.01, H - 0.05), (-L / 2 + 0.5, H - 0.35), (-L / 2, 1.9),
                               (-L / 2 + 0.3, 0.9)], -W / 2 + 0.05, W / 2 - 0.05)  # fmt: skip
            parts += [
                _chassis(-L / 2 + 0.5, cab_x0 - 0.15),
                _part("compactor_body", _box((xh, -W / 2, 1.0), (cab_x0 - 0.15, W / 2, H)), "Truck", "paint",
                      color=colour),
                _part("hopper", hopper, "Truck", "paint", color=colour),
            ]  # fmt: skip
            axles = [xf - 1.3, -L / 2 + 2.4, -L / 2 + 3.7]
        elif subclass == "tow_truck":
            L, W = _u(rng, 6.5, 8.0), _u(rng, 2.30, 2.45)
            xf, cab_h = L / 2, _u(rng, 2.6, 2.8)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.1, 2.3), cab_h, paint)
            xd = cab_x0 - 0.3
            parts += [
                _chassis(-L / 2 + 0.4, cab_x0 - 0.1),
                _part("deck", _box((-L / 2, -W / 2, 1.01), (xd, W / 2, 1.16)), "Truck", "metal"),
                _part("headboard", _box((xd + 0.01, -W / 2 + 0.1, 1.01), (xd + 0.14, W / 2 - 0.1, 2.3)), "Truck",
                      "metal"),
                _part("light_bar", _box((xf - 1.2, -0.6, cab_h), (xf - 0.9, 0.6, cab_h + 0.12)), "Truck", "lens",
                      color=_ORANGE),
            ]  # fmt: skip
            axles = [xf - 1.2, -L / 2 + 1.8]
        elif subclass == "cement_mixer":
            L, W = _u(rng, 8.0, 9.5), _u(rng, 2.45, 2.50)
            xf = L / 2
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.2, 2.4), _u(rng, 2.7, 2.9), paint)
            R = _u(rng, 1.05, 1.15)
            pf, pr = np.array([cab_x0 - 1.0, 0.0, 2.05]), np.array([-L / 2 + 1.3, 0.0, 2.55])
            d = (pr - pf) / np.linalg.norm(pr - pf)
            colour = _pick(rng, (_WHITE, _ORANGE, _BLUE, (200, 200, 195, 255)))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                _part("drum", _cylinder(R, pf, pr, 16), "Truck", "paint", color=colour),
                _part("drum_front", _cone_between(R, pf, pf - 0.8 * d, 16), "Truck", "paint", color=colour),
                _part("drum_rear", _cone_between(R, pr, pr + 1.0 * d, 16), "Truck", "paint", color=colour),
            ]
            axles = [xf - 1.3, -L / 2 + 1.6, -L / 2 + 2.95]
        elif subclass == "dump_truck":
            L, W = _u(rng, 7.0, 8.8), _u(rng, 2.45, 2.55)
            xf, cab_h, Ht = L / 2, _u(rng, 2.8, 3.0), _u(rng, 2.5, 2.9)
            parts, cab_x0 = _truck_cab(xf, W, _u(rng, 2.1, 2.4), cab_h, paint)
            profile = [(-W / 2 + 0.15, 1.1), (W / 2 - 0.15, 1.1), (W / 2, Ht), (-W / 2, Ht)]  # flared sides
            tipper = _extrude(profile, -L / 2, cab_x0 - 0.2, "x")
            zg = max(Ht, cab_h) + 0.02
            guard = _box((cab_x0 - 0.19, -W / 2 + 0.1, zg), (cab_x0 + 0.9, W / 2 - 0.1, zg + 0.1))
            colour = _pick(rng, (_YELLOW, _ORANGE, (150, 155, 160, 255), _RED))
            parts += [
                _chassis(-L / 2 + 0.3, cab_x0 - 0.15),
                _part("tipper", tipper, "Truck", "metal", color=colour),
                _part("cab_guard", guard, "Truck", "metal", color=colour),
            ]
            axles = [xf - 1.3, -L / 2 + 1.6, -L / 2 + 2.95]
        else:  # pragma: no cover - the catalogue only names the sub-classes above
            raise ValueError(subclass)
        return parts + _wheels(axles, W / 2 - 0.18, r, wheel_w, "Truck")

    return build


# sub-class -> length, width, height ranges, wheel radius, clearance, belt height, front and rear
# axle distances from the ends (a second rear distance: tandem axle)
_BUS_SPECS: dict[str, dict] = {
    "city_bus": dict(L=(10.5, 12.5), W=(2.50, 2.55), H=(3.0, 3.2), r=0.50, clear=0.30, belt=1.15,
                     front=2.7, rear=(3.0,), top_front=0.15),
    "minibus": dict(L=(6.5, 7.8), W=(2.10, 2.30), H=(2.6, 2.9), r=0.40, clear=0.30, belt=1.0,
                    front=1.4, rear=(1.5,), top_front=0.15),
    "coach": dict(L=(12.0, 13.8), W=(2.50, 2.55), H=(3.5, 3.8), r=0.52, clear=0.35, belt=1.80,
                  front=2.6, rear=(3.2, 4.6), top_front=0.25),
}  # fmt: skip


def _bus(subclass: str) -> Builder:
    """City bus (10.5-12.5 m), minibus (6.5-7.8 m) or coach (12-13.8 m, high window band, tandem
    rear axle): a full-length window band over the body."""
    spec = _BUS_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *spec["L"]), _u(rng, *spec["W"]), _u(rng, *spec["H"])
        paint = _pick(rng, _PAINTS)
        axles = [L / 2 - spec["front"]] + [-L / 2 + d for d in spec["rear"]]
        return _greenhouse_vehicle(
            L, W, H, semantic="Bus", clearance=spec["clear"], belt=spec["belt"],
            gh_rear=-L / 2 + 0.05, gh_front=L / 2 - 0.05, top_rear=0.05, top_front=spec["top_front"],
            top_side=0.03, hood=(0.05, 0.02), wheel_r=spec["r"], wheel_w=0.30, axles=axles, paint=paint,
        )  # fmt: skip

    return build


def _school_bus(rng: np.random.Generator) -> list[MeshPart]:
    """Conventional (bonneted) school bus, 9.5-12 m, yellow: an engine bonnet in front of the
    passenger box, a window band and roof."""
    L, W, H = _u(rng, 9.5, 12.0), _u(rng, 2.40, 2.50), _u(rng, 3.0, 3.2)
    bonnet_len = _u(rng, 1.4, 1.7)
    xb = L / 2 - bonnet_len  # the front of the passenger box
    gy, belt, glass_top = W / 2 - 0.04, 1.55, H - 0.3
    bonnet = _chamfer_front_top(_box((xb + 0.01, -W / 2 + 0.25, 0.45), (L / 2, W / 2 - 0.25, 1.55)), 0.25, 0.12)
    body = _box((-L / 2, -W / 2, 0.35), (xb, W / 2, belt))
    glass = _frustum((-L / 2 + 0.05, -gy, belt), (xb - 0.02, gy, glass_top), (-L / 2 + 0.05, -gy + 0.03),
                     (xb - 0.25, gy - 0.03))  # fmt: skip
    roof = _box((-L / 2, -W / 2, glass_top), (xb - 0.2, W / 2, H))
    return [
        _part("bonnet", bonnet, "Bus", "paint", color=_YELLOW),
        _part("body", body, "Bus", "paint", color=_YELLOW),
        _glass("windows", glass, "Bus"),
        _part("roof", roof, "Bus", "paint", color=_YELLOW),
    ] + _wheels([L / 2 - bonnet_len + 0.3, -L / 2 + 3.0], W / 2 - 0.18, 0.48, 0.30, "Bus")


def _double_decker(rng: np.random.Generator) -> list[MeshPart]:
    """Double-decker bus, 10-11.5 m long and 4.2-4.4 m tall: two window bands separated by a
    body band."""
    L, W, H = _u(rng, 10.0, 11.5), _u(rng, 2.50, 2.55), _u(rng, 4.2, 4.4)
    paint = _pick(rng, (_RED, _RED, _PAINTS[0], _BLUE, _GREEN))
    gy = W / 2 - 0.03
    lower = _box((-L / 2, -W / 2, 0.30), (L / 2, W / 2, 1.0))
    mid = _box((-L / 2, -W / 2, 2.05), (L / 2, W / 2, 2.45))
    roof = _box((-L / 2 + 0.05, -W / 2 + 0.03, H - 0.22), (L / 2 - 0.05, W / 2 - 0.03, H))
    glass = _union(
        _box((-L / 2 + 0.05, -gy, 1.01), (L / 2 - 0.05, gy, 2.04)),
        _box((-L / 2 + 0.05, -gy, 2.46), (L / 2 - 0.05, gy, H - 0.23)),
    )
    return [
        _part("body", _union(lower, mid), "Bus", "paint", color=paint),
        _glass("windows", glass, "Bus"),
        _part("roof", roof, "Bus", "paint", color=paint),
    ] + _wheels([L / 2 - 2.4, -L / 2 + 2.8], W / 2 - 0.18, 0.50, 0.30, "Bus")


def _rail_wheels(centres, spacing: float, per_bogie: int, radius: float) -> list[MeshPart]:
    """Rail wheels (standard gauge) of ``per_bogie`` axles ``spacing`` apart on each bogie."""
    xs = [c + (k - (per_bogie - 1) / 2) * spacing for c in centres for k in range(per_bogie)]
    return _wheels(xs, 0.72, radius, 0.14, "Train", 12)


def _doors(xs, half_w: float, y: float, z0: float, z1: float, colour: RGBA) -> MeshPart:
    """Door leaves on both sides of a rail car: thin boxes straddling the side walls at ``y``."""
    leaves = [_box((x - half_w, sy * y - 0.03, z0), (x + half_w, sy * y + 0.03, z1)) for x in xs for sy in (-1.0, 1.0)]
    return _part("doors", _union(*leaves), "Train", "metal", color=colour)


def _tram(rng: np.random.Generator) -> list[MeshPart]:
    """Low-floor articulated tram, 20-32 m: a window band with raked windscreens at both ends,
    side doors, skirted bogies and a roof pantograph."""
    L, W, H = _u(rng, 20.0, 32.0), _u(rng, 2.30, 2.65), _u(rng, 3.3, 3.5)
    paint = _pick(rng, (_WHITE, _RED, _YELLOW, (30, 120, 160, 255), _GREEN))
    floor, belt, glass_top = 0.35, 1.0, _u(rng, 2.45, 2.6)
    gy = W / 2 - 0.04
    body = _box((-L / 2, -W / 2, floor), (L / 2, W / 2, belt))
    glass = _frustum((-L / 2 + 0.05, -gy, belt), (L / 2 - 0.05, gy, glass_top), (-L / 2 + 0.5, -gy + 0.03),
                     (L / 2 - 0.5, gy - 0.03))  # fmt: skip
    roof = _box((-L / 2 + 0.5, -gy + 0.03, glass_top), (L / 2 - 0.5, gy - 0.03, H))
    n_bogie = 2 + int(L > 26.0)
    centres = [(-L / 2 + 2.6) + k * (L - 5.2) / (n_bogie - 1) for k in range(n_bogie)]
    bogies = _union(*[_box((c - 1.2, -W / 2 + 0.12, 0.0), (c + 1.2, W / 2 - 0.12, floor - 0.01)) for c in centres])
    n_doors = int(L // 6.5)
    doors = [(-L / 2 + 2.0) + (k + 0.5) * (L - 4.0) / n_doors for k in range(n_doors)]
    xp = float(centres[0] + centres[-1]) / 2 + 2.0
    return [
        _part("body", body, "Train", "paint", color=paint),
        _glass("windows", glass, "Train"),
        _part("roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _doors(doors, 0.65, W / 2, floor + 0.05, glass_top - 0.1, _DARK),
        _part("pantograph_base", _box((xp - 0.6, -0.4, H), (xp + 0.6, 0.4, H + 0.12)), "Train", "metal"),
        _part("pantograph_arm", _beam((xp - 0.5, 0.0, H + 0.1), (xp + 0.2, 0.0, H + 0.57), 0.06, 0.06), "Train",
              "metal"),
        _part("pantograph_bow", _box((xp + 0.15, -0.75, H + 0.55), (xp + 0.25, 0.75, H + 0.6)), "Train", "metal"),
    ]


def _metro(rng: np.random.Generator) -> list[MeshPart]:
    """Metro / subway car, 18-20.5 m: flat ends with windscreens, a window band, three doors a
    side, two bogies of two axles."""
    L, W, H = _u(rng, 18.0, 20.5), _u(rng, 2.80, 3.05), _u(rng, 3.5, 3.8)
    paint = _pick(rng, (_PAINTS[2], _WHITE, _BLUE, (200, 200, 195, 255)))
    gy = W / 2 - 0.04
    body = _box((-L / 2, -W / 2, 0.95), (L / 2, W / 2, 1.9))
    glass = _frustum(
        (-L / 2 + 0.03, -gy, 1.9), (L / 2 - 0.03, gy, 2.9), (-L / 2 + 0.15, -gy + 0.02), (L / 2 - 0.15, gy - 0.02)
    )
    roof = _box((-L / 2 + 0.15, -gy + 0.02, 2.9), (L / 2 - 0.15, gy - 0.02, H))
    centres = [-L / 2 + 2.6, L / 2 - 2.6]
    bogies = _union(*[_box((c - 1.3, -W / 2 + 0.35, 0.35), (c + 1.3, W / 2 - 0.35, 0.94)) for c in centres])
    return [
        _part("body", body, "Train", "paint", color=paint),
        _glass("windows", glass, "Train"),
        _part("roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _doors([-L / 4, 0.0, L / 4], 0.7, W / 2, 1.0, 2.8, _pick(rng, (_RED, _YELLOW, _DARK))),
    ] + _rail_wheels(centres, 1.8, 2, 0.43)


def _locomotive(rng: np.random.Generator) -> list[MeshPart]:
    """Diesel locomotive (taxonomy sub-class ``train``), 16.5-21 m: a frame, a narrow hood, a
    full-width cab with windows near the front, a short nose, two three-axle bogies, a fuel tank."""
    L, W, H = _u(rng, 16.5, 21.0), _u(rng, 2.90, 3.10), _u(rng, 4.0, 4.3)
    paint = _pick(rng, (_RED, _BLUE, _YELLOW, _GREEN, _ORANGE, _DARK))
    gy = W / 2 - 0.05
    xc0, xc1 = L / 2 - 3.4, L / 2 - 0.6  # the cab
    frame = _box((-L / 2, -W / 2, 1.05), (L / 2, W / 2, 1.45))
    hood = _box((-L / 2 + 0.4, -W / 2 + 0.35, 1.46), (xc0 - 0.01, W / 2 - 0.35, H - 0.35))
    cab = _box((xc0, -W / 2, 1.46), (xc1, W / 2, 2.6))
    glass = _frustum((xc0, -gy, 2.6), (xc1, gy, H - 0.2), (xc0, -gy + 0.05), (xc1 - 0.25, gy - 0.05))
    roof = _box((xc0, -gy + 0.05, H - 0.2), (xc1 - 0.25, gy - 0.05, H))
    nose = _chamfer_front_top(_box((xc1 + 0.01, -W / 2 + 0.3, 1.46), (L / 2, W / 2 - 0.3, 2.5)), 0.2, 0.2)
    centres = [-(L / 2 - 3.8), L / 2 - 3.8]
    bogies = _union(*[_box((c - 1.9, -W / 2 + 0.4, 0.45), (c + 1.9, W / 2 - 0.4, 1.04)) for c in centres])
    tank = _box((-(L / 2 - 6.0), -W / 2 + 0.5, 0.5), (L / 2 - 6.0, W / 2 - 0.5, 1.04))
    return [
        _part("frame", frame, "Train", "metal", color=_DARK),
        _part("hood", _union(hood, nose), "Train", "paint", color=paint),
        _part("cab", cab, "Train", "paint", color=paint),
        _glass("cab_windows", glass, "Train"),
        _part("cab_roof", roof, "Train", "paint", color=paint),
        _part("bogies", bogies, "Train", "metal", color=_DARK),
        _part("fuel_tank", tank, "Train", "metal", color=_DARK),
    ] + _rail_wheels(centres, 1.4, 3, 0.52)


# two-wheeler kind -> wheel radius, tyre width, wheelbase, seat and handlebar heights, handlebar
# width (m); bicycles also their tube size, motorcycles their foot-peg (x, z)
_BIKES: dict[str, dict] = {
    "city_bike": dict(r=(0.33, 0.35), tw=0.04, wb=(1.02, 1.10), seat=(0.85, 0.95), bar=(0.98, 1.06),
                      bar_w=(0.50, 0.60), tube=0.035),
    "road_bike": dict(r=(0.34, 0.35), tw=0.025, wb=(0.97, 1.02), seat=(0.92, 1.00), bar=(0.88, 0.95),
                      bar_w=(0.40, 0.44), tube=0.03),
    "mountain_bike": dict(r=(0.35, 0.37), tw=0.06, wb=(1.10, 1.20), seat=(0.85, 0.95), bar=(0.98, 1.05),
                          bar_w=(0.70, 0.78), tube=0.045),
    "cargo_bike": dict(r=(0.33, 0.35), tw=0.045, wb=(1.90, 2.10), seat=(0.88, 0.95), bar=(1.00, 1.06),
                       bar_w=(0.55, 0.62), tube=0.04),
}  # fmt: skip
_MOTOS: dict[str, dict] = {
    "sport": dict(r=(0.29, 0.32), tw=0.13, wb=(1.35, 1.50), seat=(0.78, 0.85), bar=(1.00, 1.10),
                  bar_w=(0.70, 0.80), peg=(0.0, 0.30)),
    "cruiser": dict(r=(0.31, 0.34), tw=0.15, wb=(1.55, 1.75), seat=(0.66, 0.72), bar=(1.05, 1.15),
                    bar_w=(0.85, 0.95), peg=(0.30, 0.32)),
    "scooter": dict(r=(0.20, 0.24), tw=0.11, wb=(1.25, 1.35), seat=(0.76, 0.82), bar=(1.00, 1.06),
                    bar_w=(0.62, 0.70), peg=(0.10, 0.37)),
    "moped": dict(r=(0.27, 0.30), tw=0.08, wb=(1.15, 1.25), seat=(0.80, 0.86), bar=(1.00, 1.08),
                  bar_w=(0.60, 0.66), peg=(0.0, 0.30)),
}  # fmt: skip


def _bicycle_parts(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Bicycle parts (class Bicycle) of ``kind`` (:data:`_BIKES`) and the rider anchor points."""
    s = _BIKES[kind]
    r, tw, wb = _u(rng, *s["r"]), s["tw"], _u(rng, *s["wb"])
    seat_z, bar_z, bar_w, t = _u(rng, *s["seat"]), _u(rng, *s["bar"]), _u(rng, *s["bar_w"]), s["tube"]
    frame_c = _pick(rng, _PAINTS)
    xf, xr = wb / 2, -wb / 2
    cargo = kind == "cargo_bike"
    rf = 0.25 if cargo else r  # a long-john cargo bike has a small front wheel
    seat = np.array([xr + 0.30, 0.0, seat_z])
    pedal = np.array([xr + 0.55, 0.0, 0.30]) if cargo else np.array([0.0, 0.0, 0.30])
    bar = np.array([xr + 0.85, 0.0, bar_z]) if cargo else np.array([xf - 0.12, 0.0, bar_z])

    def tube(name: str, p0, p1, size: float = t) -> MeshPart:
        return _part(name, _beam(p0, p1, size, size), "Bicycle", "metal", color=frame_c)

    parts = [
        _part("wheel_front", _cylinder(rf, (xf, -tw / 2, rf), (xf, tw / 2, rf), 20), "Bicycle", "rubber"),
        _part("wheel_rear", _cylinder(r, (xr, -tw / 2, r), (xr, tw / 2, r), 20), "Bicycle", "rubber"),
        tube("top_tube", seat + (0.05, 0, -0.08), bar + (-0.05, 0, -0.12)),
        tube("down_tube", pedal, bar + (-0.03, 0, -0.18)),
        tube("seat_tube", pedal + (0.0, 0, 0.02), seat + (0.0, 0, -0.04)),
        tube("chain_stay", pedal + (-0.02, 0, 0.0), (xr + 0.02, 0.0, r)),
        _part("saddle", _box(seat + (-0.12, -0.07, -0.02), seat + (0.12, 0.07, 0.04)), "Bicycle", "leather"),
        _part("handlebar", _box(bar + (-0.02, -bar_w / 2, -0.02), bar + (0.02, bar_w / 2, 0.02)), "Bicycle", "metal"),
    ]
    if cargo:
        parts += [
            tube("cargo_beam", pedal + (0.02, 0, 0.0), (xf - 0.12, 0.0, 0.30)),
            tube("fork", (xf - 0.12, 0.0, 0.33), (xf - 0.01, 0.0, rf + 0.02)),
            _part("cargo_box", _box((bar[0] + 0.12, -0.33, 0.36), (xf - 0.30, 0.33, 0.85)), "Bicycle", "wood"),
        ]
    else:
        fork_t = t * 1.6 if kind == "mountain_bike" else t
        parts.append(tube("fork", bar + (-0.02, 0, -0.10), (xf - 0.01, 0.0, r + 0.02), fork_t))
    if kind == "city_bike":
        parts.append(_part("rack", _box((xr - 0.15, -0.08, 2 * r + 0.05), (xr + 0.22, 0.08, 2 * r + 0.08)), "Bicycle",
                           "metal"))  # fmt: skip
        if rng.uniform() < 0.5:
            basket = _box((bar[0] + 0.06, -0.18, bar_z - 0.33), (bar[0] + 0.40, 0.18, bar_z - 0.06))
            parts.append(_part("basket", basket, "Bicycle", "wood"))
    elif kind == "road_bike":
        drops = _union(*[_beam(bar + (0.0, sy * (bar_w / 2 - 0.02), 0.0), bar + (0.09, sy * (bar_w / 2 - 0.02), -0.13),
                               0.025, 0.025) for sy in (-1.0, 1.0)])  # fmt: skip
        parts.append(_part("drops", drops, "Bicycle", "metal"))
    return parts, {"seat": seat, "bar": bar, "pedal": pedal}


def _motorcycle_parts(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Motorcycle / scooter / moped parts (class Motorcycle) of ``kind`` (:data:`_MOTOS`) and the
    rider anchor points."""
    s = _MOTOS[kind]
    r, tw, wb = _u(rng, *s["r"]), s["tw"], _u(rng, *s["wb"])
    seat_z, bar_z, bar_w = _u(rng, *s["seat"]), _u(rng, *s["bar"]), _u(rng, *s["bar_w"])
    paint = _pick(rng, _PAINTS)
    sem = "Motorcycle"
    xf, xr = wb / 2, -wb / 2
    seat = np.array([xr + (0.45 if kind == "cruiser" else 0.35 if kind == "scooter" else 0.30), 0.0, seat_z])
    bar = np.array([xf - 0.12, 0.0, bar_z])
    peg = np.array([s["peg"][0], 0.0, s["peg"][1]])
    parts = [
        _part("wheel_front", _cylinder(r, (xf, -tw / 2, r), (xf, tw / 2, r), 20), sem, "rubber"),
        _part("wheel_rear", _cylinder(r, (xr, -tw / 2, r), (xr, tw / 2, r), 20), sem, "rubber"),
        _part("fork", _beam(bar + (-0.03, 0, -0.06), (xf - 0.02, 0.0, r + 0.05), 0.07, 0.07), sem, "metal"),
        _part("handlebar", _box(bar + (-0.02, -bar_w / 2, -0.02), bar + (0.02, bar_w / 2, 0.02)), sem, "metal"),
    ]
    windscreen = kind == "sport" or rng.uniform() < 0.35
    if kind == "sport":
        parts += [
            _part("engine", _frustum((xr + 0.35, -0.20, 0.28), (xf - 0.35, 0.20, 0.62),
                                     (xr + 0.30, -0.17), (xf - 0.40, 0.17)), sem, "metal"),  # fmt: skip
            _part("tank", _box((0.0, -0.17, 0.62), (xf - 0.25, 0.17, bar_z - 0.18)), sem, "paint", color=paint),
            _part("seat", _box((xr + 0.05, -0.15, 0.62), (-0.02, 0.15, seat_z)), sem, "leather"),
        ]
    elif kind == "cruiser":
        xt = (0.05 + xf - 0.35) / 2
        parts += [
            _part("engine", _frustum((xr + 0.45, -0.22, 0.24), (xf - 0.45, 0.22, 0.62),
                                     (xr + 0.40, -0.18), (xf - 0.50, 0.18)), sem, "metal"),  # fmt: skip
            _part("tank", _ellipsoid((xt, 0.0, bar_z - 0.30), ((xf - 0.35 - 0.05) / 2, 0.16, 0.11)), sem, "paint",
                  color=paint),  # fmt: skip
            _part("seat", _box((xr + 0.20, -0.17, 0.55), (0.0, 0.17, seat_z)), sem, "leather"),
            _part("exhaust", _cylinder(0.05, (xr + 0.05, -0.26, 0.36), (0.35, -0.26, 0.30), 10), sem, "metal",
                  color=(200, 200, 205, 255)),  # fmt: skip
        ]
    elif kind == "scooter":
        parts += [
            _part("floorboard", _box((xr + 0.45, -0.15, 0.22), (xf - 0.36, 0.15, 0.32)), sem, "plastic"),
            _part("legshield", _extrude([(xf - 0.34, 0.22), (xf - 0.22, 0.22), (xf - 0.13, 0.95), (xf - 0.25, 0.95)],
                                        -0.21, 0.21), sem, "paint", color=paint),  # fmt: skip
            _part("rear_body", _ellipsoid((xr + 0.33, 0.0, 0.50), (0.42, 0.19, 0.22)), sem, "paint", color=paint),
            _part("seat", _box((xr + 0.08, -0.14, 0.66), (xr + 0.68, 0.14, seat_z)), sem, "leather"),
        ]
    else:  # moped: a light frame with a small engine and tank
        parts += [
            _part("frame", _beam((xr + 0.30, 0.0, 0.62), bar + (-0.05, 0, -0.15), 0.05, 0.05), sem, "metal",
                  color=paint),
            _part("engine", _box((-0.25, -0.12, 0.20), (0.15, 0.12, 0.45)), sem, "metal"),
            _part("tank", _box((xr + 0.05, -0.13, 0.50), (xr + 0.55, 0.13, 0.62)), sem, "paint", color=paint),
            _part("seat", _box((xr + 0.10, -0.13, 0.64), (xr + 0.60, 0.13, seat_z)), sem, "leather"),
        ]
    if windscreen:
        screen = _beam(bar + (-0.02, 0, 0.02), bar + (0.10, 0, 0.30), 0.36, 0.01)
        parts.append(_glass("windscreen", screen, sem))
    return parts, {"seat": seat, "bar": bar, "pedal": peg}


def _two_wheeler(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Bicycle or motorcycle parts of ``kind`` and the rider anchor points (``seat``, ``bar``,
    ``pedal``: hip, hands and feet of a rider)."""
    return _bicycle_parts(rng, kind) if kind in _BIKES else _motorcycle_parts(rng, kind)


def _parked(kind: str) -> Builder:
    """A parked bicycle or motorcycle of ``kind`` (no rider)."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        return _two_wheeler(rng, kind)[0]

    return build


def _rider(family: str) -> Builder:
    """A rider (class Rider) on a bicycle (city, road or mountain bike) or a motorcycle (sport,
    cruiser or scooter) of that vehicle's class; motorcyclists always wear a helmet, cyclists
    half of the time."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        kinds = ("city_bike", "road_bike", "mountain_bike") if family == "bicycle" else ("sport", "cruiser", "scooter")
        kind = _pick(rng, kinds)
        parts, a = _two_wheeler(rng, kind)
        H = _u(rng, 1.60, 1.90)  # standing height of the rider
        cloth, skin = _pick(rng, _CLOTHES), _pick(rng, _SKINS)
        helmet = family == "motorcycle" or rng.uniform() < 0.5
        leans = {"road_bike": (0.42, 0.26), "cruiser": (0.12, 0.32), "scooter": (0.12, 0.32)}  # forward, up (x H)
        lean_x, lean_z = leans.get(kind, (0.30, 0.30))
        hip = a["seat"] + (0.0, 0.0, 0.10)
        shoulder = hip + (lean_x, 0.0, lean_z * H)
        tr, ar, lr = 0.085 * H * 0.9, 0.028 * H, 0.045 * H
        head_r = 0.065 * H * (1.15 if helmet else 1.0)
        head = _ellipsoid(shoulder + (0.10, 0.0, 0.06 + 1.6 * 0.065 * H), (head_r,) * 3)
        parts += [
            _part("rider_torso", _capsule(tr, hip + (0.02, 0, tr * 0.6), shoulder - (0.03, 0, 0.05)), "Rider", "cloth",
                  color=cloth),
            _part("rider_head", head, "Rider", "plastic" if helmet else "skin",
                  color=_pick(rng, _PAINTS) if helmet else skin),
        ]  # fmt: skip
        hands_y = 0.20
        for side, sy in (("left", 1.0), ("right", -1.0)):
            sh = shoulder + (0.0, sy * (tr + ar), -0.05)
            hand = a["bar"] + (0.0, sy * hands_y, 0.03)
            foot = a["pedal"] + (0.05, sy * 0.16, 0.0)
            knee = (hip + foot) / 2 + (0.22, sy * 0.10, 0.12)
            parts += [
                _part(f"rider_arm_{side}", _capsule(ar, sh, hand), "Rider", "cloth", color=cloth),
                _part(f"rider_thigh_{side}", _capsule(lr, hip + (0.0, sy * 0.09, 0.0), knee), "Rider", "cloth",
                      color=cloth),
                _part(f"rider_shin_{side}", _capsule(lr * 0.85, knee + (0.0, 0.0, -0.02), foot), "Rider", "cloth",
                      color=cloth),
            ]  # fmt: skip
        return parts

    return build


def _pedestrian(subclass: str) -> Builder:
    """Standing or walking person (adult 1.55-1.95 m, child 1.0-1.4 m): head, optional hair,
    torso, two arms, two legs; varied girth, stride, arm swing, clothes and skin colours, and a
    style (trousers, skirt, backpack or hand bag)."""
    h_range, head_frac = {"adult": ((1.55, 1.95), 0.065), "child": ((1.00, 1.40), 0.080)}[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        H = _u(rng, *h_range)
        girth = _u(rng, 0.9, 1.15)
        skin, top, bottom = _pick(rng, _SKINS), _pick(rng, _CLOTHES), _pick(rng, _CLOTHES)
        style = _pick(rng, ("trousers", "trousers", "skirt", "backpack", "bag"))
        stride, swing = _u(rng, 0.0, 0.12) * H, _u(rng, -0.35, 0.35)
        sleeves = rng.uniform() < 0.5
        head_r = head_frac * H
        leg_r, arm_r, torso_r = 0.042 * H * girth, 0.028 * H, 0.085 * H * girth
        hip_z = 0.50 * H
        torso_top = H - 2 * head_r - torso_r * 0.6
        parts = [
            _part("head", _ellipsoid((0.0, 0.0, H - head_r), (head_r, head_r * 0.9, head_r)), "Pedestrian", "skin",
                  color=skin),
        ]  # fmt: skip
        if rng.uniform() < 0.7:
            hair = _ellipsoid((-0.1 * head_r, 0.0, H - 0.85 * head_r), (head_r * 1.02, head_r * 0.94, head_r * 0.8))
            parts.append(_part("hair", hair, "Pedestrian", "cloth", color=_pick(rng, _HAIR)))
        torso = _capsule(torso_r, (0.0, 0.0, hip_z + 0.2 * torso_r), (0.0, 0.0, torso_top))
        torso = (torso[0] * (0.8, 1.15, 1.0), torso[1])  # flatter front-to-back than side-to-side
        parts.append(_part("torso", torso, "Pedestrian", "cloth", color=top))
        arm_len = torso_top - 0.02 * H - 0.46 * H
        hands = {}
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y_leg = sy * 0.055 * H
            y_arm = sy * (torso_r * 1.15 + arm_r + 0.01)
            foot_x = sy * stride / 2  # the left foot forward, the right back (or the reverse)
            sw = -sy * swing  # each arm swings against its leg
            sh = np.array([0.0, y_arm, torso_top - 0.02 * H])
            hands[side] = sh + arm_len * np.array([np.sin(sw), 0.0, -np.cos(sw)])
            parts += [
                _part(f"leg_{side}", _capsule(leg_r, (0.0, y_leg, hip_z), (foot_x, y_leg, leg_r)), "Pedestrian",
                      "cloth", color=bottom),
                _part(f"arm_{side}", _capsule(arm_r, sh, hands[side]), "Pedestrian", "cloth" if sleeves else "skin",
                      color=top if sleeves else skin),
            ]  # fmt: skip
        if style == "skirt":
            skirt = _cone(0.115 * H * girth, 0.30 * H, (0.0, 0.0, 0.30 * H), 12)
            parts.append(_part("skirt", skirt, "Pedestrian", "cloth", color=bottom))
        elif style == "backpack":
            zb = hip_z + 0.15 * H
            pack = _box((-0.8 * torso_r - 0.17, -0.14, zb), (-0.8 * torso_r - 0.01, 0.14, min(zb + 0.4, torso_top)))
            parts.append(_part("backpack", pack, "Pedestrian", "cloth", color=_pick(rng, _CLOTHES)))
        elif style == "bag":
            h = hands["right"]
            bag = _box((h[0] - 0.06, h[1] - 0.16, h[2] - 0.30), (h[0] + 0.06, h[1] + 0.10, h[2] - 0.04))
            parts.append(_part("bag", bag, "Pedestrian", "leather"))
        return parts

    return build


def _windows_on_facades(
    D: float, F: float, rows: list[tuple[float, float]], spans: dict[str, list[tuple[float, float]]]
) -> Mesh:
    """Glass panes straddling the walls of a ``D`` (x) by ``F`` (y) block: for every ``(z0, z1)``
    row and every facade (``"front"`` +X, ``"back"`` -X, ``"left"`` +Y, ``"right"`` -Y), one pane
    per ``(a, b)`` span along that facade (y spans on front/back, x spans on the sides).
    Panes are 0.10 m thick, half inside the wall, and never touch each other."""
    t = 0.05
    panes: list[Mesh] = []
    for z0, z1 in rows:
        for facade, facade_spans in spans.items():
            for a, b in facade_spans:
                if facade in ("front", "back"):
                    x = D / 2 if facade == "front" else -D / 2
                    panes.append(_box((x - t, a, z0), (x + t, b, z1)))
                else:
                    y = F / 2 if facade == "left" else -F / 2
                    panes.append(_box((a, y - t, z0), (b, y + t, z1)))
    return _union(*panes)


def _bays(lo: float, hi: float, n: int, width: float) -> list[tuple[float, float]]:
    """``n`` spans of ``width`` centred in ``n`` equal bays between ``lo`` and ``hi``."""
    step = (hi - lo) / n
    return [(lo + (k + 0.5) * step - width / 2, lo + (k + 0.5) * step + width / 2) for k in range(n)]


def _shift(mesh: Mesh, d) -> Mesh:
    """A mesh moved by ``d`` (m)."""
    return mesh[0] + np.asarray(d, dtype=np.float64), mesh[1]


_ROOF_COLOURS = ((120, 50, 40, 255), (70, 72, 80, 255), (150, 95, 60, 255), (95, 45, 35, 255))


def _house(rng: np.random.Generator) -> list[MeshPart]:
    """Detached house, 1-2 storeys, gable or hip roof, door on the +X facade, 4-9 m wide windows."""
    D, F = _u(rng, 8.0, 12.0), _u(rng, 9.0, 14.0)
    storeys = int(rng.integers(1, 3))
    wall_h = 2.9 * storeys + 0.3
    roof_h = _u(rng, 1.8, 3.5)
    eave = 0.35
    walls = _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h))
    roof_lo, roof_hi = (-D / 2 - eave, -F / 2 - eave, wall_h), (D / 2 + eave, F / 2 + eave, wall_h + roof_h)
    if rng.uniform() < 0.5:
        roof = _prism_gable(roof_lo, roof_hi)
    else:
        ridge = 0.15 + 0.25 * F  # hip roof: the top face shrinks to a short ridge along Y
        roof = _frustum(roof_lo, roof_hi, (-0.08, -ridge / 2), (0.08, ridge / 2))
    rows = [(0.9 + 2.9 * k, 2.2 + 2.9 * k) for k in range(storeys)]
    ys = [(-F / 4 - 0.6, -F / 4 + 0.6), (F / 4 - 0.6, F / 4 + 0.6)]
    xs = [(-0.6, 0.6)]
    glazing = _windows_on_facades(D, F, rows, {"front": ys, "back": ys, "left": xs, "right": xs})
    door = _box((D / 2 - 0.06, -0.45, 0.0), (D / 2 + 0.06, 0.45, 2.1))
    return [
        _part("walls", walls, "Building", "plaster", color=_pick(rng, _FACADES["plaster"])),
        _part("roof", roof, "Building", "roof_tile", color=_pick(rng, _ROOF_COLOURS)),
        _glass("glazing", glazing, "Building"),
        _part("door", door, "Building", "wood"),
    ]


def _residential(rng: np.random.Generator) -> list[MeshPart]:
    """Apartment block, 3-8 floors of 3 m, ribbon windows on every facade and floor, an entrance
    on the +X facade and a plant room on the flat roof."""
    D, F = _u(rng, 10.0, 16.0), _u(rng, 16.0, 30.0)
    floors = int(rng.integers(3, 9))
    H = 3.0 * floors + 0.4
    walls = _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H))
    rows = [(3.0 * k + 0.9, 3.0 * k + 2.3) for k in range(1, floors)]
    along_y = [(-F / 2 + 0.6, F / 2 - 0.6)]
    along_x = [(-D / 2 + 0.6, D / 2 - 0.6)]
    glazing = _windows_on_facades(D, F, rows, {"front": along_y, "back": along_y, "left": along_x, "right": along_x})
    # ground floor: shop windows beside the entrance at the front, ribbons on the other facades
    ground = _windows_on_facades(
        D, F, [(0.5, 2.5)],
        {"front": [(-F / 2 + 0.6, -1.2), (1.2, F / 2 - 0.6)], "back": along_y, "left": along_x, "right": along_x},
    )  # fmt: skip
    door = _box((D / 2 - 0.06, -0.9, 0.0), (D / 2 + 0.06, 0.9, 2.4))
    plant = _box((-D / 4, -F / 6, H), (D / 4, F / 6, H + _u(rng, 1.5, 2.5)))
    return [
        _part("walls", walls, "Building", "brick", color=_pick(rng, _FACADES["brick"])),
        _glass("glazing", _union(glazing, ground), "Building"),
        _glass("entrance", door, "Building"),
        _part("roof_plant", plant, "Building", "concrete"),
    ]


def _apartment(rng: np.random.Generator) -> list[MeshPart]:
    """Apartment slab, 4-10 floors of 2.9 m: vertical window strips in 4 m bays on every facade,
    balconies with glass railings on every upper floor of the +X facade, a glazed entrance and a
    ground floor of windows on the front."""
    D, F = _u(rng, 12.0, 18.0), _u(rng, 18.0, 36.0)
    floors, fh = int(rng.integers(4, 11)), 2.9
    H = fh * floors + 0.6
    nb, ns = max(2, int(F // 4.0)), max(1, int(D // 4.0))
    ys, xs = _bays(-F / 2, F / 2, nb, 1.4), _bays(-D / 2, D / 2, ns, 1.4)
    strips = _windows_on_facades(D, F, [(fh + 0.8, H - 1.2)], {"front": ys, "back": ys, "left": xs, "right": xs})
    ground = _windows_on_facades(D, F, [(0.8, 2.2)], {"front": [s for s in ys if min(abs(s[0]), abs(s[1])) > 1.4]})
    slabs, rails = [], []
    for k in range(1, floors):
        z = fh * k
        slabs.append(_box((D / 2 + 0.06, -F / 2 + 1.0, z - 0.15), (D / 2 + 1.3, F / 2 - 1.0, z)))
        rails.append(_box((D / 2 + 1.24, -F / 2 + 1.0, z + 0.01), (D / 2 + 1.30, F / 2 - 1.0, z + 1.0)))
    door = _box((D / 2 - 0.06, -1.0, 0.0), (D / 2 + 0.06, 1.0, 2.4))
    plant = _box((-D / 4, -F / 8, H), (D / 4, F / 8, H + _u(rng, 1.5, 2.5)))
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", "plaster",
              color=_pick(rng, _FACADES["plaster"])),
        _glass("glazing", _union(strips, ground), "Building"),
        _glass("entrance", door, "Building"),
        _part("balconies", _union(*slabs), "Building", "concrete"),
        _glass("balcony_railings", _union(*rails), "Building"),
        _part("roof_plant", plant, "Building", "concrete"),
    ]  # fmt: skip


def _curtain_block(D: float, F: float, z0: float, z1: float, t: float = 0.15) -> tuple[Mesh, Mesh]:
    """A glass-clad block: a core inset by ``t`` and four ``t`` thick curtain walls around it (the
    front/back walls span the full frontage, the sides fit between them), from ``z0`` to ``z1``."""
    core = _box((-D / 2 + t, -F / 2 + t, z0), (D / 2 - t, F / 2 - t, z1))
    curtain = _union(
        _box((D / 2 - t, -F / 2, z0), (D / 2, F / 2, z1)),
        _box((-D / 2, -F / 2, z0), (-D / 2 + t, F / 2, z1)),
        _box((-D / 2 + t, F / 2 - t, z0), (D / 2 - t, F / 2, z1)),
        _box((-D / 2 + t, -F / 2, z0), (D / 2 - t, -F / 2 + t, z1)),
    )
    return core, curtain


def _office(rng: np.random.Generator) -> list[MeshPart]:
    """Office tower, 8-13 floors of 3.6 m over a 4.5 m lobby: a concrete core, a glass curtain
    wall on every facade, floor-slab edges projecting 0.15 m at every floor, a roof plant room."""
    D, F = _u(rng, 18.0, 28.0), _u(rng, 18.0, 30.0)
    floors = int(rng.integers(8, 14))
    lobby = 4.5
    H = lobby + 3.6 * floors
    core, _ = _curtain_block(D, F, 0.0, H)
    _, curtain = _curtain_block(D, F, 0.0, H - 0.6)
    slabs = _union(*[
        _box((-D / 2 - 0.15, -F / 2 - 0.15, z - 0.3), (D / 2 + 0.15, F / 2 + 0.15, z))
        for z in [lobby + 3.6 * k for k in range(floors)]
    ] + [_box((-D / 2 - 0.15, -F / 2 - 0.15, H - 0.6), (D / 2 + 0.15, F / 2 + 0.15, H))])  # fmt: skip
    plant = _box((-D / 5, -F / 5, H), (D / 5, F / 5, H + _u(rng, 2.5, 4.0)))
    return [
        _part("core", core, "Building", "concrete"),
        _glass("curtain_wall", curtain, "Building"),
        _part("floor_slabs", slabs, "Building", "concrete"),
        _part("roof_plant", plant, "Building", "concrete"),
    ]


def _tower(rng: np.random.Generator) -> list[MeshPart]:
    """High-rise, 18-31 floors of 3.7 m over a 5 m lobby (75-125 m): a glass-clad shaft, a narrower
    glass-clad top of 3-6 floors set back above it, slab bands every third floor, a crown and,
    on half of them, an antenna mast."""
    D, F = _u(rng, 22.0, 34.0), _u(rng, 22.0, 34.0)
    floors, n_up, fh, lobby = int(rng.integers(18, 32)), int(rng.integers(3, 7)), 3.7, 5.0
    s = _u(rng, 0.6, 0.8)
    H_mid, H1 = lobby + fh * (floors - n_up), lobby + fh * floors
    d, f = D * s, F * s
    core_lo, curtain_lo = _curtain_block(D, F, 0.0, H_mid)
    core_up, curtain_up = _curtain_block(d, f, H_mid + 0.01, H1)
    bands = [_box((-D / 2 - 0.15, -F / 2 - 0.15, z - 0.3), (D / 2 + 0.15, F / 2 + 0.15, z))
             for z in np.arange(lobby, H_mid - 0.5, 3 * fh)]  # fmt: skip
    bands.append(_box((-D / 2 - 0.15, -F / 2 - 0.15, H_mid - 0.3), (D / 2 + 0.15, F / 2 + 0.15, H_mid)))
    bands.append(_box((-d / 2 - 0.15, -f / 2 - 0.15, H1 - 0.3), (d / 2 + 0.15, f / 2 + 0.15, H1)))
    crown_top = H1 + _u(rng, 3.0, 6.0)
    parts = [
        _part("core", _union(core_lo, core_up), "Building", "concrete"),
        _glass("curtain_wall", _union(curtain_lo, curtain_up), "Building"),
        _part("floor_bands", _union(*bands), "Building", "concrete"),
        _part("crown", _box((-d * 0.35, -f * 0.35, H1), (d * 0.35, f * 0.35, crown_top)), "Building", "concrete"),
    ]
    if rng.uniform() < 0.5:
        mast = _cylinder(0.3, (0.0, 0.0, crown_top), (0.0, 0.0, crown_top + _u(rng, 6.0, 15.0)), 8)
        parts.append(_part("antenna", mast, "Building", "metal"))
    return parts


def _commercial(rng: np.random.Generator) -> list[MeshPart]:
    """Retail building, 1-2 storeys: shop windows either side of a glazed entrance on the +X
    facade, a canopy and a sign band above them, ribbon windows upstairs, roof-top units."""
    D, F = _u(rng, 14.0, 24.0), _u(rng, 20.0, 40.0)
    storeys = int(rng.integers(1, 3))
    H = 4.6 + 3.8 * (storeys - 1) + 0.6
    material = _pick(rng, ("plaster", "brick", "concrete"))
    shop = _windows_on_facades(D, F, [(0.3, 3.4)], {"front": [(-F / 2 + 0.8, -1.9), (1.9, F / 2 - 0.8)]})
    glazing = [shop]
    if storeys == 2:
        glazing.append(_windows_on_facades(D, F, [(5.4, 7.2)], {
            "front": [(-F / 2 + 0.8, F / 2 - 0.8)], "back": [(-F / 2 + 0.8, F / 2 - 0.8)],
            "left": [(-D / 2 + 0.8, D / 2 - 0.8)], "right": [(-D / 2 + 0.8, D / 2 - 0.8)],
        }))  # fmt: skip
    n = int(rng.integers(1, 4))
    centres = [-F / 2 + (k + 1) * F / (n + 1) for k in range(n)]
    units = [_box((-2.0, yc - 1.2, H), (1.0, yc + 1.2, H + 1.5)) for yc in centres]
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", material,
              color=_pick(rng, _FACADES[material])),
        _glass("glazing", _union(*glazing), "Building"),
        _glass("entrance", _box((D / 2 - 0.06, -1.6, 0.0), (D / 2 + 0.06, 1.6, 3.0)), "Building"),
        _part("canopy", _box((D / 2 + 0.06, -F / 2 + 0.5, 3.55), (D / 2 + 1.8, F / 2 - 0.5, 3.75)), "Building", "metal",
              color=_pick(rng, _PAINTS)),
        _part("sign_band", _box((D / 2 - 0.02, -F * 0.3, 3.85), (D / 2 + 0.2, F * 0.3, 4.45)), "Building", "sign_face",
              color=_pick(rng, _PAINTS)),
        _part("roof_units", _union(*units), "Building", "metal"),
    ]  # fmt: skip


def _industrial(rng: np.random.Generator) -> list[MeshPart]:
    """Factory hall with a north-light sawtooth roof (glazed vertical faces), high ribbon
    windows, 1-3 loading doors on the +X facade and a brick chimney."""
    D, F, wall_h = _u(rng, 25.0, 45.0), _u(rng, 20.0, 40.0), _u(rng, 6.5, 9.5)
    material = _pick(rng, ("concrete", "metal"))
    n = max(3, int(D // 8.0))
    d, th = D / n, _u(rng, 2.5, 3.5)
    x0s = [-D / 2 + k * d for k in range(n)]
    teeth = _union(*[_extrude([(x0, wall_h), (x0 + d - 0.01, wall_h), (x0, wall_h + th)], -F / 2, F / 2) for x0 in x0s])
    roof_glass = _union(*[_box((x0 - 0.05, -F / 2 + 0.5, wall_h + 0.3), (x0 + 0.05, F / 2 - 0.5, wall_h + th - 0.3))
                          for x0 in x0s])  # fmt: skip
    ribbons = _windows_on_facades(D, F, [(wall_h - 2.6, wall_h - 1.2)], {
        "front": [(-F / 2 + 1.0, -F / 4), (F / 4, F / 2 - 1.0)],
        "left": [(-D / 2 + 1.0, D / 2 - 1.0)], "right": [(-D / 2 + 1.0, D / 2 - 1.0)],
    })  # fmt: skip
    nd = int(rng.integers(1, 4))
    w = min(4.0, F / 2 / nd - 0.4)
    doors = _union(*[_box((D / 2 - 0.05, a, 0.0), (D / 2 + 0.08, b, 4.5)) for a, b in _bays(-F / 4, F / 4, nd, w)])
    chimney_r, chimney_h = _u(rng, 0.6, 1.0), _u(rng, 14.0, 22.0)
    chimney = _cylinder(chimney_r, (-D / 2 + 3.0, F / 2 - 3.0, 0.0), (-D / 2 + 3.0, F / 2 - 3.0, chimney_h))
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", material,
              color=_pick(rng, _FACADES[material])),
        _part("sawtooth_roof", teeth, "Building", "metal", color=(110, 115, 120, 255)),
        _glass("glazing", _union(roof_glass, ribbons), "Building"),
        _glass("entrance", _box((D / 2 - 0.06, F / 2 - 4.0, 0.0), (D / 2 + 0.06, F / 2 - 2.5, 2.4)), "Building"),
        _part("loading_doors", doors, "Building", "metal", color=_DARK),
        _part("chimney", chimney, "Building", "brick"),
    ]  # fmt: skip


def _warehouse(rng: np.random.Generator) -> list[MeshPart]:
    """Logistics warehouse: a long clad box under a low-pitched roof, a loading dock along the +X
    facade with 2-5 roller doors, high ribbon windows on the other facades."""
    D, F, wall_h = _u(rng, 30.0, 60.0), _u(rng, 20.0, 40.0), _u(rng, 7.0, 11.0)
    pitch = np.tan(np.radians(_u(rng, 4.0, 8.0)))
    roof = _extrude([(-F / 2 - 0.3, wall_h), (F / 2 + 0.3, wall_h), (0.0, wall_h + (F / 2 + 0.3) * pitch)],
                    -D / 2 - 0.3, D / 2 + 0.3, "x")  # fmt: skip
    nd = int(rng.integers(2, 6))
    spacing = (F - 4.0) / nd
    doors = _union(*[_box((D / 2 - 0.04, a, 1.21), (D / 2 + 0.06, b, 5.2))
                     for a, b in _bays(-F / 2 + 2.0, F / 2 - 2.0, nd, min(3.5, spacing - 0.8))])  # fmt: skip
    along_y, along_x = [(-F / 2 + 1.0, F / 2 - 1.0)], [(-D / 2 + 1.0, D / 2 - 1.0)]
    high = [(wall_h - 1.8, wall_h - 0.8)]
    ribbons = _windows_on_facades(D, F, high, {"back": along_y, "left": along_x, "right": along_x})
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", "metal",
              color=_pick(rng, _FACADES["metal"])),
        _part("roof", roof, "Building", "metal", color=(95, 100, 105, 255)),
        _part("dock", _box((D / 2 + 0.01, -F / 2 + 1.0, 0.0), (D / 2 + 2.5, F / 2 - 1.0, 1.2)), "Building", "concrete"),
        _part("roller_doors", doors, "Building", "metal", color=_DARK),
        _glass("glazing", ribbons, "Building"),
        _glass("entrance", _box((D / 2 - 4.0, F / 2 - 0.06, 0.0), (D / 2 - 2.5, F / 2 + 0.06, 2.4)), "Building"),
    ]  # fmt: skip


def _garage(rng: np.random.Generator) -> list[MeshPart]:
    """Detached single or double garage under a mono-pitch roof: up-and-over doors on the +X
    facade, a small side window."""
    D = _u(rng, 5.5, 7.0)
    bays = 2 if rng.uniform() < 0.5 else 1
    F = _u(rng, 5.8, 6.6) if bays == 2 else _u(rng, 3.0, 3.6)
    Hf = _u(rng, 2.4, 2.7)
    roof = _extrude([(-D / 2 - 0.2, Hf), (D / 2 + 0.3, Hf), (D / 2 + 0.3, Hf + 0.15), (-D / 2 - 0.2, Hf + 0.5)],
                    -F / 2 - 0.2, F / 2 + 0.2)  # fmt: skip
    spans = _bays(-F / 2, F / 2, bays, F / bays - 0.7)
    doors = _union(*[_box((D / 2 - 0.04, a, 0.0), (D / 2 + 0.05, b, 2.1)) for a, b in spans])
    material = _pick(rng, ("plaster", "brick"))
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, Hf)), "Building", material,
              color=_pick(rng, _FACADES[material])),
        _part("roof", roof, "Building", "roof_tile", color=_pick(rng, _ROOF_COLOURS)),
        _part("doors", doors, "Building", "metal", color=_pick(rng, (_WHITE, _DARK, (120, 80, 50, 255)))),
        _glass("glazing", _box((-0.5, F / 2 - 0.05, 1.2), (0.5, F / 2 + 0.05, 1.8)), "Building"),
    ]  # fmt: skip


def _gas_station(rng: np.random.Generator) -> list[MeshPart]:
    """Filling station: a shop with a glazed front at the back, a canopy on columns over 2-3 pump
    islands in front of it (+X), a price pylon at the front corner."""
    Ds, Fs, Hs = _u(rng, 8.0, 12.0), _u(rng, 10.0, 16.0), _u(rng, 3.8, 4.5)
    Dc, Fc, Hc = _u(rng, 10.0, 14.0), _u(rng, 14.0, 22.0), _u(rng, 4.8, 5.5)
    x0 = Ds + _u(rng, 3.0, 5.0)  # the canopy's back edge (the shop spans x 0 .. Ds)
    colour = _pick(rng, (_RED, _BLUE, _GREEN, _YELLOW))
    shop_front = {"front": [(-Fs / 2 + 0.6, -1.2), (1.2, Fs / 2 - 0.6)]}
    shop_glass = _shift(_windows_on_facades(Ds, Fs, [(0.4, 2.8)], shop_front), (Ds / 2, 0.0, 0.0))
    n_isl = 3 if Fc > 18.0 else 2
    ys = [-Fc / 2 + (k + 0.5) * Fc / n_isl for k in range(n_isl)]
    islands = _union(*[_box((x0 + 2.0, y - 0.6, 0.0), (x0 + Dc - 2.0, y + 0.6, 0.15)) for y in ys])
    xs = (x0 + 2.4, x0 + Dc - 2.4)
    columns = _union(*[_cylinder(0.25, (x, y, 0.16), (x, y, Hc - 0.01), 12) for y in ys for x in xs])
    pumps = _union(*[_box((x0 + Dc / 2 - 0.3, y - 0.45, 0.16), (x0 + Dc / 2 + 0.3, y + 0.45, 1.9)) for y in ys])
    pylon = _box((x0 + Dc + 1.0, Fc / 2 - 2.0, 0.0), (x0 + Dc + 1.4, Fc / 2, _u(rng, 6.0, 8.0)))
    return [
        _part("shop", _box((0.0, -Fs / 2, 0.0), (Ds, Fs / 2, Hs)), "Building", "plaster",
              color=_pick(rng, _FACADES["plaster"])),
        _glass("glazing", shop_glass, "Building"),
        _glass("entrance", _box((Ds - 0.06, -1.0, 0.0), (Ds + 0.06, 1.0, 2.5)), "Building"),
        _part("canopy", _box((x0, -Fc / 2, Hc), (x0 + Dc, Fc / 2, Hc + 0.9)), "Building", "metal", color=_WHITE),
        _part("columns", columns, "Building", "metal", color=colour),
        _part("islands", islands, "Building", "concrete"),
        _part("pumps", pumps, "Building", "metal", color=colour),
        _part("price_sign", pylon, "Building", "sign_face", color=colour),
    ]  # fmt: skip


def _religious(rng: np.random.Generator) -> list[MeshPart]:
    """Place of worship, one of two styles: a church (nave under a steep roof with tall windows, a
    west tower with a spire and the door on its +X face) or a domed hall (a drum and dome on a
    square hall, a slender tower with a conical cap beside it)."""
    stone = _pick(rng, ((190, 180, 160, 255), (200, 195, 185, 255), (165, 150, 130, 255), (210, 200, 175, 255)))
    if rng.uniform() < 0.6:
        D, Fw, wall_h = _u(rng, 20.0, 32.0), _u(rng, 10.0, 15.0), _u(rng, 7.0, 10.0)
        T, Ht = _u(rng, 4.5, 6.5), _u(rng, 18.0, 28.0)
        gable = [(-Fw / 2 - 0.4, wall_h), (Fw / 2 + 0.4, wall_h), (0.0, wall_h + 0.6 * Fw)]
        roof = _extrude(gable, -D / 2 - 0.3, D / 2 + 0.3, "x")  # ridge along X
        bays = _bays(-D / 2, D / 2, int(D // 4.0), 1.2)
        nave_glass = _windows_on_facades(D, Fw, [(2.5, wall_h - 1.0)], {"left": bays, "right": bays})
        xt = D / 2 + T / 2
        belfry = _union(
            _box((D / 2 + T - 0.05, -0.6, Ht - 4.0), (D / 2 + T + 0.05, 0.6, Ht - 1.5)),
            *[_box((xt - 0.6, sy * T / 2 - 0.05, Ht - 4.0), (xt + 0.6, sy * T / 2 + 0.05, Ht - 1.5))
              for sy in (-1.0, 1.0)],
        )  # fmt: skip
        return [
            _part("nave", _box((-D / 2, -Fw / 2, 0.0), (D / 2, Fw / 2, wall_h)), "Building", "stone", color=stone),
            _part("roof", roof, "Building", "roof_tile", color=(70, 75, 85, 255)),
            _part("tower", _box((D / 2, -T / 2, 0.0), (D / 2 + T, T / 2, Ht)), "Building", "stone", color=stone),
            _part("spire", _pyramid(T / 2 + 0.2, _u(rng, 8.0, 14.0), (xt, 0.0, Ht)), "Building", "roof_tile",
                  color=(70, 75, 85, 255)),
            _glass("glazing", _union(nave_glass, belfry), "Building"),
            _part("door", _box((D / 2 + T - 0.06, -1.0, 0.0), (D / 2 + T + 0.06, 1.0, 3.6)), "Building", "wood"),
        ]  # fmt: skip
    D = _u(rng, 16.0, 26.0)
    F, wall_h = D * _u(rng, 0.9, 1.1), _u(rng, 8.0, 12.0)
    r = 0.3 * min(D, F)
    drum_top = wall_h + _u(rng, 2.0, 4.0)
    yt, Ht = F / 2 + 2.0, _u(rng, 20.0, 30.0)
    glass = _windows_on_facades(D, F, [(3.0, wall_h - 2.0)], {
        "front": [(-F / 3 - 0.75, -F / 3 + 0.75), (F / 3 - 0.75, F / 3 + 0.75)], "back": _bays(-F / 2, F / 2, 3, 1.5),
        "left": _bays(-D / 2, D / 2, 3, 1.5), "right": _bays(-D / 2, D / 2, 3, 1.5),
    })  # fmt: skip
    return [
        _part("hall", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, wall_h)), "Building", "stone", color=stone),
        _part("drum", _cylinder(r, (0.0, 0.0, wall_h), (0.0, 0.0, drum_top), 16), "Building", "stone", color=stone),
        _part("dome", _ellipsoid((0.0, 0.0, drum_top), (r, r, r * _u(rng, 0.8, 1.1)), 2), "Building", "metal",
              color=_pick(rng, ((60, 120, 110, 255), (200, 170, 80, 255), (90, 100, 140, 255)))),
        _part("tower", _cylinder(1.2, (D / 2 - 2.0, yt, 0.0), (D / 2 - 2.0, yt, Ht), 12), "Building", "stone",
              color=stone),
        _part("tower_cap", _cone(1.5, 3.0, (D / 2 - 2.0, yt, Ht), 12), "Building", "metal"),
        _glass("glazing", glass, "Building"),
        _part("door", _box((D / 2 - 0.06, -1.2, 0.0), (D / 2 + 0.06, 1.2, 4.0)), "Building", "wood"),
    ]  # fmt: skip


def _public(rng: np.random.Generator) -> list[MeshPart]:
    """Civic building (town hall, school, library), 2-3 storeys of 3.8 m: ribbon windows, a
    columned portico with steps, an entablature and a pediment in front of the +X entrance."""
    D, F = _u(rng, 14.0, 22.0), _u(rng, 30.0, 50.0)
    floors, fh = int(rng.integers(2, 4)), 3.8
    H = fh * floors + 0.8
    n_col = int(rng.integers(4, 7))
    Wp = (n_col - 1) * 2.6
    material = _pick(rng, ("stone", "plaster"))
    colour = _pick(rng, _FACADES["plaster"]) if material == "plaster" else _COLOURS["stone"]
    rows = [(fh * k + 1.0, fh * k + 2.8) for k in range(floors)]
    glazing = _windows_on_facades(D, F, rows, {
        "front": [(-F / 2 + 1.0, -Wp / 2 - 1.7), (Wp / 2 + 1.7, F / 2 - 1.0)], "back": [(-F / 2 + 1.0, F / 2 - 1.0)],
        "left": [(-D / 2 + 1.0, D / 2 - 1.0)], "right": [(-D / 2 + 1.0, D / 2 - 1.0)],
    })  # fmt: skip
    xc = D / 2 + 2.2
    columns = _union(*[_cylinder(0.35, (xc, -Wp / 2 + 2.6 * k, 1.01), (xc, -Wp / 2 + 2.6 * k, H - 1.61), 12)
                       for k in range(n_col)])  # fmt: skip
    half = Wp / 2 + 1.2
    entablature = _box((D / 2, -half, H - 1.6), (D / 2 + 2.8, half, H - 0.9))
    gable = [(-half, H - 0.89), (half, H - 0.89), (0.0, H - 0.89 + _u(rng, 1.5, 2.2))]
    pediment = _extrude(gable, D / 2 - 0.2, D / 2 + 2.8, "x")
    return [
        _part("walls", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H)), "Building", material, color=colour),
        _glass("glazing", glazing, "Building"),
        _glass("entrance", _box((D / 2 - 0.06, -1.3, 1.0), (D / 2 + 0.06, 1.3, 4.2)), "Building"),
        _part("steps", _box((D / 2, -Wp / 2 - 1.5, 0.0), (D / 2 + 3.8, Wp / 2 + 1.5, 1.0)), "Building", "concrete"),
        _part("columns", columns, "Building", "stone"),
        _part("portico_roof", _union(entablature, pediment), "Building", "stone", color=colour),
    ]


def _tree(rng: np.random.Generator) -> list[MeshPart]:
    """Street tree: trunk and an ellipsoid crown pruned high (crown base 3.8-4.5 m, so trucks and
    buses pass under branches that overhang the road)."""
    crown_base = _u(rng, 3.8, 4.5)
    rx, rz = _u(rng, 1.5, 2.8), _u(rng, 1.4, 2.4)
    trunk_r = _u(rng, 0.12, 0.22)
    trunk = _cylinder(trunk_r, (0.0, 0.0, 0.0), (0.0, 0.0, crown_base + rz), 8)
    crown = _ellipsoid((0.0, 0.0, crown_base + rz), (rx, rx * _u(rng, 0.85, 1.0), rz), 1)
    green = _pick(rng, ((60, 120, 40, 255), (75, 130, 50, 255), (50, 100, 45, 255), (95, 125, 45, 255)))
    return [_part("trunk", trunk, "Vegetation", "bark"), _part("crown", crown, "Vegetation", "foliage", color=green)]


def _conifer(rng: np.random.Generator) -> list[MeshPart]:
    """Conifer: trunk and a cone crown starting 1-2 m above ground, 6-12 m tall."""
    base, height, radius = _u(rng, 1.0, 2.0), _u(rng, 5.0, 10.0), _u(rng, 1.2, 2.2)
    trunk = _cylinder(_u(rng, 0.12, 0.20), (0.0, 0.0, 0.0), (0.0, 0.0, base + 0.5), 8)
    crown = _cone(radius, height, (0.0, 0.0, base), 12)
    return [_part("trunk", trunk, "Vegetation", "bark"),
            _part("crown", crown, "Vegetation", "foliage", color=(35, 85, 45, 255))]  # fmt: skip


def _bush(rng: np.random.Generator) -> list[MeshPart]:
    """Bush: a flattened ellipsoid on the ground, 0.8-1.6 m high."""
    h, rx = _u(rng, 0.8, 1.6), _u(rng, 0.6, 1.3)
    crown = _ellipsoid((0.0, 0.0, h / 2), (rx, rx * _u(rng, 0.7, 1.0), h / 2), 1)
    return [_part("crown", crown, "Vegetation", "foliage")]


def _palm(rng: np.random.Generator) -> list[MeshPart]:
    """Palm: a slim, slightly leaning 6-11 m trunk, a crown head and 6-8 drooping fronds (one
    part each: the fronds overlap at the head)."""
    h, lean = _u(rng, 6.0, 11.0), _u(rng, 0.0, 0.5)
    heading = _u(rng, 0.0, 2 * np.pi)
    top = np.array([lean * np.cos(heading), lean * np.sin(heading), h])
    parts = [
        _part("trunk", _cylinder(_u(rng, 0.15, 0.22), (0.0, 0.0, 0.0), top, 8), "Vegetation", "bark"),
        _part("crown_head", _ellipsoid(top, (0.35, 0.35, 0.45), 1), "Vegetation", "foliage"),
    ]
    n = int(rng.integers(6, 9))
    for k in range(n):
        length, droop = _u(rng, 2.0, 3.0), _u(rng, 0.2, 0.6)
        R = _rz(2 * np.pi * k / n + _u(rng, -0.2, 0.2)) @ _ry(droop)
        frond = _rotate(_ellipsoid((length / 2, 0.0, 0.0), (length / 2, 0.35, 0.06), 1), R, top + (0.0, 0.0, 0.15))
        parts.append(_part(f"frond_{k}", frond, "Vegetation", "foliage", color=(80, 130, 45, 255)))
    return parts


def _hedge(rng: np.random.Generator) -> list[MeshPart]:
    """Clipped hedge, 2-6 m long, 0.6-1.0 m wide, 0.8-1.8 m high, with bevelled top edges."""
    L, w, h = _u(rng, 2.0, 6.0), _u(rng, 0.6, 1.0), _u(rng, 0.8, 1.8)
    b = 0.15
    profile = [(-w / 2, 0.0), (w / 2, 0.0), (w / 2, h - b), (w / 2 - b, h), (-w / 2 + b, h), (-w / 2, h - b)]
    return [_part("hedge", _extrude(profile, -L / 2, L / 2, "x"), "Vegetation", "foliage", color=(45, 95, 40, 255))]


def _street_light(rng: np.random.Generator) -> list[MeshPart]:
    """Street light: 7-9 m pole, an arm of 1.5-2.5 m along +X, a lamp head at its end."""
    h, arm, r = _u(rng, 7.0, 9.0), _u(rng, 1.5, 2.5), _u(rng, 0.08, 0.11)
    pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = _box((r, -0.04, h - 0.20), (arm, 0.04, h - 0.10))
    lamp = _box((arm, -0.15, h - 0.30), (arm + 0.6, 0.15, h - 0.08))
    return [
        _part("pole", pole, "Pole", "metal"),
        _part("arm", arm_mesh, "Pole", "metal"),
        _part("lamp", lamp, "Pole", "lamp"),
    ]


def _utility_pole(rng: np.random.Generator) -> list[MeshPart]:
    """Wooden utility pole, 9-12 m: a cross-arm near the top with four insulators, and on half of
    them a pole-mounted transformer on the +X side."""
    h, r, a = _u(rng, 9.0, 12.0), _u(rng, 0.11, 0.14), _u(rng, 0.9, 1.2)
    ys = (-a + 0.1, -a / 2, a / 2, a - 0.1)
    insulators = _union(*[_cylinder(0.05, (0.0, y, h - 0.48), (0.0, y, h - 0.28), 8) for y in ys])
    parts = [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "wood"),
        _part("crossarm", _box((-0.05, -a, h - 0.6), (0.05, a, h - 0.48)), "Pole", "wood"),
        _part("insulators", insulators, "Pole", "plastic", color=(150, 170, 160, 255)),
    ]
    if rng.uniform() < 0.5:
        tr = _cylinder(0.3, (r + 0.32, 0.0, h - 3.5), (r + 0.32, 0.0, h - 2.5), 12)
        parts.append(_part("transformer", tr, "Pole", "metal"))
    return parts


def _flagpole(rng: np.random.Generator) -> list[MeshPart]:
    """Flagpole, 6-10 m, with a finial no wider than the pole and a flag (class Static) flying
    along +X."""
    h, r = _u(rng, 6.0, 10.0), _u(rng, 0.04, 0.06)
    fw, fh = _u(rng, 1.2, 2.0), _u(rng, 0.8, 1.3)
    flag = _box((r + 0.01, -0.01, h - 0.1 - fh), (r + 0.01 + fw, 0.01, h - 0.1))
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 10), "Pole", "metal"),
        _part("finial", _ellipsoid((0.0, 0.0, h + 0.04), (r, r, 0.08), 1), "Pole", "metal"),
        _part("flag", flag, "Static", "cloth", color=_pick(rng, _PAINTS)),
    ]


def _signal_head(x_back: float, y: float, z_top: float, lenses: int = 3) -> tuple[Mesh, Mesh]:
    """A signal head of ``lenses`` lenses with its back at ``x_back``, centred on ``y``, top at
    ``z_top``; returns (housing, lenses) with the lenses facing +X."""
    depth, width, height = 0.25, 0.35, 0.30 * lenses + 0.05
    housing = _box((x_back, y - width / 2, z_top - height), (x_back + depth, y + width / 2, z_top))
    lens_mesh = _union(*[
        _plate_x(0.10, 0.04, (x_back + depth + 0.02, y, z_top - 0.17 - 0.30 * k), 12, 0.0) for k in range(lenses)
    ])  # fmt: skip
    return housing, lens_mesh


def _vehicle_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Post-mounted vehicle signal: a 3.0-3.6 m pole with a signal head on its front (+X)."""
    h, r = _u(rng, 3.0, 3.6), _u(rng, 0.07, 0.09)
    housing, lenses = _signal_head(r, 0.0, h)
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


def _pedestrian_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Pedestrian signal: a 2.3-2.8 m pole, a two-lens head on its front (+X) and a push-button
    box below it."""
    h, r = _u(rng, 2.3, 2.8), _u(rng, 0.06, 0.08)
    housing, lenses = _signal_head(r, 0.0, h, lenses=2)
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens", color=(230, 235, 230, 255)),
        _part("button", _box((r + 0.005, -0.05, 1.0), (r + 0.10, 0.05, 1.2)), "TrafficLight", "plastic",
              color=_YELLOW),
    ]  # fmt: skip


def _overhead_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Mast-arm signal: a 5.8-6.8 m pole, an arm of 3.5-6 m reaching along -Y, a signal head
    hanging in front of the arm's end (its bottom at least 4.4 m above ground)."""
    h, arm, r = _u(rng, 5.8, 6.8), _u(rng, 3.5, 6.0), _u(rng, 0.10, 0.11)
    pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12)
    arm_mesh = _box((-0.06, -arm, h - 0.45), (0.06, -r, h - 0.30))
    housing, lenses = _signal_head(0.06, -arm + 0.5, h - 0.45)
    return [
        _part("pole", pole, "Pole", "metal"),
        _part("arm", arm_mesh, "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal", color=_DARK),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


def _sign(subclass: str) -> Builder:
    """Traffic sign on a thin pole; the plate faces +X: stop (red octagon), speed_limit (white
    disc in a red ring), no_entry (red disc, white bar), yield (triangle, point down), warning
    (triangle, point up), one_way (blue oblong, white arrow), pedestrian_crossing and parking (blue
    squares with a white symbol), direction (green or blue rectangle). Symbols and rings are parts
    of class TrafficSign just in front of (or behind) the plate."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        r = 0.045
        zc = _u(rng, 2.3, 2.7)  # plate centre height
        x = r + 0.015 + 0.01  # plate centre: just in front of the pole
        xs = x + 0.02  # symbol centre: on the plate's face
        extra: list[tuple[str, Mesh, RGBA]] = []
        if subclass == "stop":
            plate, colour = _plate_x(_u(rng, 0.36, 0.40), 0.03, (x, 0.0, zc), 8, np.pi / 8), _RED
            extra.append(("symbol", _box((xs - 0.005, -0.22, zc - 0.05), (xs + 0.005, 0.22, zc + 0.05)), _WHITE))
        elif subclass == "speed_limit":
            R = _u(rng, 0.28, 0.32)
            plate, colour = _plate_x(0.8 * R, 0.03, (xs - 0.005, 0.0, zc), 20, 0.0), _WHITE
            extra.append(("ring", _plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), _RED))
        elif subclass == "no_entry":
            R = _u(rng, 0.28, 0.32)
            plate, colour = _plate_x(R, 0.03, (x, 0.0, zc), 20, 0.0), _RED
            bar = _box((xs - 0.005, -0.65 * R, zc - 0.1 * R), (xs + 0.005, 0.65 * R, zc + 0.1 * R))
            extra.append(("symbol", bar, _WHITE))
        elif subclass in ("yield", "warning"):
            # the primitive's corner at spin 0 ends at -Z after the turn: point down for yield
            spin = 0.0 if subclass == "yield" else np.pi
            plate = _plate_x(_u(rng, 0.42, 0.48), 0.03, (x, 0.0, zc), 3, spin)
            colour = _WHITE if subclass == "yield" else _YELLOW
        elif subclass == "one_way":
            w, hgt = _u(rng, 0.8, 1.0), _u(rng, 0.25, 0.32)
            plate = _box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = _BLUE
            side = _pick(rng, (-1.0, 1.0))  # the arrow points left (+Y) or right (-Y)
            y_tail, y_base, y_tip = -0.3 * w * side, (0.4 * w - 0.12) * side, 0.4 * w * side
            shaft = _box((xs - 0.005, min(y_tail, y_base - 0.005 * side), zc - 0.03),
                         (xs + 0.005, max(y_tail, y_base - 0.005 * side), zc + 0.03))  # fmt: skip
            head = _extrude([(y_base, -0.1), (y_tip, 0.0), (y_base, 0.1)], xs - 0.005, xs + 0.005, "x")
            extra.append(("symbol", _union(shaft, _shift(head, (0.0, 0.0, zc))), _WHITE))
        elif subclass in ("pedestrian_crossing", "parking"):
            a = _u(rng, 0.55, 0.65)
            plate, colour = _box((x - 0.015, -a / 2, zc - a / 2), (x + 0.015, a / 2, zc + a / 2)), _BLUE
            if subclass == "pedestrian_crossing":
                triangle = [(-0.3 * a, -0.25 * a), (0.3 * a, -0.25 * a), (0.0, 0.3 * a)]
                sym = _extrude(triangle, xs - 0.005, xs + 0.005, "x")
                sym = _shift(sym, (0.0, 0.0, zc))
            else:  # a blocky "P": stem and bowl
                sym = _union(
                    _box((xs - 0.005, -0.18 * a, zc - 0.3 * a), (xs + 0.005, -0.08 * a, zc + 0.3 * a)),
                    _box((xs - 0.005, -0.07 * a, zc + 0.02 * a), (xs + 0.005, 0.18 * a, zc + 0.3 * a)),
                )
            extra.append(("symbol", sym, _WHITE))
        else:  # direction
            w, hgt = _u(rng, 0.6, 1.0), _u(rng, 0.4, 0.7)
            plate = _box((x - 0.015, -w / 2, zc - hgt / 2), (x + 0.015, w / 2, zc + hgt / 2))
            colour = _pick(rng, (_GREEN, _BLUE))
        top = max([float(plate[0][:, 2].max())] + [float(m[0][:, 2].max()) for _, m, _ in extra])
        pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, top - 0.05), 8)
        parts = [_part("pole", pole, "Pole", "metal"), _part("plate", plate, "TrafficSign", "sign_face", color=colour)]
        return parts + [_part(name, mesh, "TrafficSign", "sign_face", color=c) for name, mesh, c in extra]

    return build


def _bench(rng: np.random.Generator) -> list[MeshPart]:
    """Park bench, 1.5-1.8 m long: seat, backrest at -X, two leg frames."""
    L = _u(rng, 1.5, 1.8)
    seat = _box((-0.22, -L / 2, 0.42), (0.22, L / 2, 0.47))
    back = _box((-0.30, -L / 2, 0.50), (-0.25, L / 2, 0.85))
    legs = _union(
        _box((-0.25, -L / 2 + 0.10, 0.0), (0.20, -L / 2 + 0.16, 0.42)),
        _box((-0.25, L / 2 - 0.16, 0.0), (0.20, L / 2 - 0.10, 0.42)),
    )
    supports = _union(
        _box((-0.30, -L / 2 + 0.10, 0.42), (-0.25, -L / 2 + 0.16, 0.50)),
        _box((-0.30, L / 2 - 0.16, 0.42), (-0.25, L / 2 - 0.10, 0.50)),
    )
    return [
        _part("seat", seat, "Static", "wood"),
        _part("backrest", back, "Static", "wood"),
        _part("legs", legs, "Static", "metal"),
        _part("back_supports", supports, "Static", "metal"),
    ]


def _bin(rng: np.random.Generator) -> list[MeshPart]:
    """Litter bin: a 0.8-1.0 m cylinder with a lid."""
    r, h = _u(rng, 0.22, 0.30), _u(rng, 0.8, 1.0)
    colour = _pick(rng, (_DARK, _GREEN, (60, 60, 60, 255), (150, 155, 160, 255)))
    body = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 16)
    lid = _cylinder(r + 0.02, (0.0, 0.0, h), (0.0, 0.0, h + 0.05), 16)
    return [
        _part("body", body, "Static", "plastic", color=colour),
        _part("lid", lid, "Static", "plastic", color=colour),
    ]


def _hydrant(rng: np.random.Generator) -> list[MeshPart]:
    """Fire hydrant, 0.6-0.8 m: a base flange, a barrel, a domed cap and side outlets."""
    h, r = _u(rng, 0.5, 0.65), _u(rng, 0.10, 0.13)
    colour = _pick(rng, (_RED, _YELLOW, (200, 200, 195, 255)))
    zo = 0.06 + 0.7 * h  # outlet height
    return [
        _part("base", _cylinder(r + 0.04, (0.0, 0.0, 0.0), (0.0, 0.0, 0.06), 12), "Static", "metal", color=colour),
        _part("barrel", _cylinder(r, (0.0, 0.0, 0.06), (0.0, 0.0, 0.06 + h), 12), "Static", "metal", color=colour),
        _part("cap", _ellipsoid((0.0, 0.0, 0.06 + h), (r + 0.01, r + 0.01, 0.09), 1), "Static", "metal", color=colour),
        _part("outlets", _cylinder(0.045, (0.0, -r - 0.08, zo), (0.0, r + 0.08, zo), 10), "Static", "metal",
              color=colour),
    ]  # fmt: skip


def _bus_stop(rng: np.random.Generator) -> list[MeshPart]:
    """Bus shelter, 3.5-6 m long: a roof on four posts, a glass back wall at -X and a glass side
    panel, a bench; the open side faces +X."""
    L, H = _u(rng, 3.5, 6.0), _u(rng, 2.5, 2.8)
    corners = [(sx * 0.65, sy * (L / 2 - 0.1)) for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)]
    posts = _union(*[_cylinder(0.04, (x, y, 0.0), (x, y, H - 0.11), 10) for x, y in corners])
    glass = _union(
        _box((-0.72, -L / 2 + 0.15, 0.10), (-0.68, L / 2 - 0.15, H - 0.2)),
        _box((-0.60, L / 2 - 0.12, 0.10), (0.40, L / 2 - 0.08, H - 0.2)),
    )
    return [
        _part("roof", _box((-0.8, -L / 2, H - 0.1), (0.8, L / 2, H)), "Static", "metal"),
        _part("posts", posts, "Static", "metal"),
        _glass("panels", glass, "Static"),
        _part("bench", _box((-0.62, -L / 3, 0.42), (-0.25, L / 3, 0.47)), "Static", "wood"),
        _part("bench_legs", _union(*[_box((-0.5, y - 0.03, 0.0), (-0.4, y + 0.03, 0.41)) for y in (-L / 4, L / 4)]),
              "Static", "metal"),
    ]  # fmt: skip


def _mailbox(rng: np.random.Generator) -> list[MeshPart]:
    """Post box: a round pillar box with a domed cap, or a box on a post; the slot faces +X."""
    colour = _pick(rng, (_RED, _YELLOW, _BLUE, _GREEN))
    if rng.uniform() < 0.5:
        r, h = _u(rng, 0.22, 0.28), _u(rng, 1.1, 1.4)
        return [
            _part("body", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 16), "Static", "metal", color=colour),
            _part("cap", _ellipsoid((0.0, 0.0, h), (r + 0.02, r + 0.02, 0.12), 1), "Static", "metal", color=colour),
            _part("slot", _box((r - 0.02, -0.1, h - 0.25), (r + 0.01, 0.1, h - 0.21)), "Static", "plastic",
                  color=_BLACK),
        ]  # fmt: skip
    w, hb = _u(rng, 0.35, 0.45), _u(rng, 0.45, 0.6)
    return [
        _part("post", _box((-0.04, -0.04, 0.0), (0.04, 0.04, 0.8)), "Static", "metal"),
        _part("body", _box((-0.15, -w / 2, 0.81), (0.15, w / 2, 0.81 + hb)), "Static", "metal", color=colour),
        _part("slot", _box((0.14, -0.1, 0.81 + hb - 0.12), (0.16, 0.1, 0.81 + hb - 0.09)), "Static", "plastic",
              color=_BLACK),
    ]  # fmt: skip


def _kiosk(rng: np.random.Generator) -> list[MeshPart]:
    """Street kiosk, 2.2-3 m deep: a hut with an overhanging roof, a glazed service window and a
    counter on the +X side."""
    D, F, H = _u(rng, 2.2, 3.0), _u(rng, 2.5, 4.0), _u(rng, 2.6, 3.0)
    return [
        _part("body", _box((-D / 2, -F / 2, 0.0), (D / 2, F / 2, H - 0.16)), "Static", "wood",
              color=_pick(rng, (_GREEN, (110, 75, 45, 255), _BLUE, (200, 200, 195, 255)))),
        _part("roof", _box((-D / 2 - 0.3, -F / 2 - 0.3, H - 0.15), (D / 2 + 0.4, F / 2 + 0.3, H)), "Static", "metal"),
        _glass("window", _box((D / 2 - 0.05, -F / 3, 1.0), (D / 2 + 0.05, F / 3, 2.1)), "Static"),
        _part("counter", _box((D / 2 + 0.06, -F / 3, 0.95), (D / 2 + 0.35, F / 3, 1.0)), "Static", "wood"),
    ]  # fmt: skip


def _bollard(rng: np.random.Generator) -> list[MeshPart]:
    """Bollard, 0.8-1.0 m: a post with a reflective band near its top."""
    r, h = _u(rng, 0.08, 0.12), _u(rng, 0.8, 1.0)
    return [
        _part("post", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Static", "metal",
              color=_pick(rng, (_DARK, (150, 155, 160, 255), _RED))),
        _part("band", _cylinder(r + 0.005, (0.0, 0.0, h - 0.15), (0.0, 0.0, h - 0.08), 12), "Static", "plastic",
              color=_WHITE),
    ]  # fmt: skip


def _planter(rng: np.random.Generator) -> list[MeshPart]:
    """Concrete planter box with a shrub (class Vegetation) growing out of it."""
    L, w, h = _u(rng, 1.0, 2.0), _u(rng, 0.6, 1.0), _u(rng, 0.5, 0.8)
    shrub = _ellipsoid((0.0, 0.0, h), (0.4 * L, 0.4 * w, _u(rng, 0.3, 0.6)), 1)
    return [
        _part("box", _box((-L / 2, -w / 2, 0.0), (L / 2, w / 2, h)), "Static", "concrete"),
        _part("shrub", shrub, "Vegetation", "foliage"),
    ]


def _barrier(rng: np.random.Generator) -> list[MeshPart]:
    """Jersey barrier, 2-4 m long and 0.81 m high, in concrete or red/white plastic."""
    L = _u(rng, 2.0, 4.0)
    profile = [(-0.3, 0.0), (0.3, 0.0), (0.3, 0.08), (0.1, 0.81), (-0.1, 0.81), (-0.3, 0.08)]
    if rng.uniform() < 0.6:
        return [_part("barrier", _extrude(profile, -L / 2, L / 2, "x"), "Static", "concrete")]
    colour = _pick(rng, (_RED, _WHITE))
    return [_part("barrier", _extrude(profile, -L / 2, L / 2, "x"), "Static", "plastic", color=colour)]


def _traffic_cone(rng: np.random.Generator) -> list[MeshPart]:
    """Traffic cone, 0.5-0.75 m, on a square base."""
    h, r = _u(rng, 0.45, 0.70), _u(rng, 0.13, 0.16)
    return [
        _part("base", _box((-0.19, -0.19, 0.0), (0.19, 0.19, 0.03)), "Static", "rubber"),
        _part("cone", _cone(r, h, (0.0, 0.0, 0.03), 12), "Static", "plastic", color=_ORANGE),
    ]


def _billboard(rng: np.random.Generator) -> list[MeshPart]:
    """Billboard: a 3-6 m by 2-3 m board 2.5-4.5 m up on one or two posts behind it; the face
    looks +X."""
    W, Hb, Hh = _u(rng, 3.0, 6.0), _u(rng, 2.5, 4.5), _u(rng, 2.0, 3.0)
    ys = (0.0,) if W < 4.0 else (-W / 4, W / 4)
    posts = _union(*[_cylinder(0.15, (-0.2, y, 0.0), (-0.2, y, Hb + Hh - 0.3), 12) for y in ys])
    return [
        _part("posts", posts, "Static", "metal"),
        _part("board", _box((-0.04, -W / 2, Hb), (0.2, W / 2, Hb + Hh)), "Static", "sign_face",
              color=_pick(rng, _PAINTS)),
    ]


def _vending_machine(rng: np.random.Generator) -> list[MeshPart]:
    """Vending machine, 1.8-1.95 m: a cabinet with a glazed display on its +X front and a
    delivery slot."""
    W, H = _u(rng, 0.9, 1.2), _u(rng, 1.8, 1.95)
    return [
        _part("cabinet", _box((-0.4, -W / 2, 0.0), (0.4, W / 2, H)), "Static", "metal", color=_pick(rng, _PAINTS)),
        _glass("display", _box((0.38, -W / 2 + 0.08, 0.7), (0.42, W / 4, H - 0.15)), "Static"),
        _part("slot", _box((0.38, -W / 2 + 0.1, 0.15), (0.42, W / 4, 0.35)), "Static", "plastic", color=_BLACK),
    ]


def _phone_booth(rng: np.random.Generator) -> list[MeshPart]:
    """Phone booth, about 1 m square and 2.4-2.6 m tall: a base, four corner posts, glass panes on
    every side (the door at +X) and a roof."""
    a, H = _u(rng, 0.9, 1.05), _u(rng, 2.4, 2.6)
    colour = _pick(rng, (_RED, (150, 155, 160, 255), _BLUE))
    h = a / 2
    posts = _union(*[_box((sx * h - 0.04 * (sx > 0), sy * h - 0.04 * (sy > 0), 0.11),
                          (sx * h + 0.04 * (sx < 0), sy * h + 0.04 * (sy < 0), H - 0.21))
                     for sx in (-1.0, 1.0) for sy in (-1.0, 1.0)])  # fmt: skip
    panes = _union(
        _box((h - 0.03, -h + 0.05, 0.2), (h - 0.01, h - 0.05, H - 0.3)),
        _box((-h + 0.01, -h + 0.05, 0.2), (-h + 0.03, h - 0.05, H - 0.3)),
        _box((-h + 0.05, h - 0.03, 0.2), (h - 0.05, h - 0.01, H - 0.3)),
        _box((-h + 0.05, -h + 0.01, 0.2), (h - 0.05, -h + 0.03, H - 0.3)),
    )
    return [
        _part("base", _box((-h, -h, 0.0), (h, h, 0.1)), "Static", "metal", color=colour),
        _part("posts", posts, "Static", "metal", color=colour),
        _glass("panes", panes, "Static"),
        _part("roof", _box((-h - 0.03, -h - 0.03, H - 0.2), (h + 0.03, h + 0.03, H)), "Static", "metal", color=colour),
    ]


def _movable_bin(rng: np.random.Generator) -> list[MeshPart]:
    """Wheelie bin, 1.0-1.1 m: a tapered body, a lid, two wheels and a handle at -X."""
    h = _u(rng, 0.95, 1.05)
    colour = _pick(rng, (_GREEN, _DARK, _BLUE, (110, 80, 50, 255), (150, 155, 160, 255)))
    body = _frustum((-0.28, -0.25, 0.05), (0.28, 0.25, h), (-0.31, -0.29), (0.31, 0.29))
    wheels = _union(*[_cylinder(0.1, (-0.24, sy * 0.26 - 0.025, 0.1), (-0.24, sy * 0.26 + 0.025, 0.1), 12)
                      for sy in (-1.0, 1.0)])  # fmt: skip
    return [
        _part("body", body, "Dynamic", "plastic", color=colour),
        _part("lid", _box((-0.33, -0.31, h + 0.001), (0.33, 0.31, h + 0.05)), "Dynamic", "plastic", color=colour),
        _part("wheels", wheels, "Dynamic", "rubber"),
        _part("handle", _box((-0.37, -0.2, h - 0.12), (-0.335, 0.2, h - 0.08)), "Dynamic", "plastic", color=colour),
    ]


def _boxes(rng: np.random.Generator) -> list[MeshPart]:
    """A stack of 1-3 cardboard boxes (0.3-0.8 m), each a part of its own."""
    parts, z = [], 0.0
    for k in range(int(rng.integers(1, 4))):
        a, b, c = _u(rng, 0.3, 0.8), _u(rng, 0.3, 0.8), _u(rng, 0.25, 0.6)
        dx, dy = _u(rng, -0.05, 0.05), _u(rng, -0.05, 0.05)
        parts.append(_part(f"box_{k}", _box((dx - a / 2, dy - b / 2, z), (dx + a / 2, dy + b / 2, z + c)), "Dynamic",
                           "cardboard"))  # fmt: skip
        z += c
    return parts


def _luggage(rng: np.random.Generator) -> list[MeshPart]:
    """Upright suitcase, 0.55-0.75 m, with an extended telescopic handle and two wheels."""
    d, w, h = _u(rng, 0.22, 0.30), _u(rng, 0.38, 0.50), _u(rng, 0.55, 0.75)
    hh = _u(rng, 0.3, 0.45)
    rods = _union(*[_box((-d / 2 + 0.02, y - 0.01, h + 0.05), (-d / 2 + 0.04, y + 0.01, h + 0.05 + hh))
                    for y in (-0.12, 0.12)])  # fmt: skip
    yw = w / 2 - 0.05  # wheel centres at +-yw
    xw = -d / 2 + 0.04
    wheels = _union(*[_cylinder(0.03, (xw, y - 0.015, 0.03), (xw, y + 0.015, 0.03), 10) for y in (-yw, yw)])
    return [
        _part("case", _box((-d / 2, -w / 2, 0.05), (d / 2, w / 2, h + 0.05)), "Dynamic", "plastic",
              color=_pick(rng, _PAINTS)),
        _part("handle_rods", rods, "Dynamic", "metal"),
        _part("grip", _box((-d / 2 + 0.01, -0.14, h + 0.06 + hh), (-d / 2 + 0.05, 0.14, h + 0.09 + hh)), "Dynamic",
              "plastic", color=_BLACK),
        _part("wheels", wheels, "Dynamic", "rubber"),
    ]  # fmt: skip


# (category, sub-class, builder) of every procedural sub-class, in output order
CATALOGUE: tuple[tuple[str, str, Builder], ...] = (
    ("Building", "house", _house),
    ("Building", "residential", _residential),
    ("Building", "apartment", _apartment),
    ("Building", "office", _office),
    ("Building", "tower", _tower),
    ("Building", "commercial", _commercial),
    ("Building", "industrial", _industrial),
    ("Building", "warehouse", _warehouse),
    ("Building", "garage", _garage),
    ("Building", "gas_station", _gas_station),
    ("Building", "religious", _religious),
    ("Building", "public", _public),
    ("Pole", "street_light", _street_light),
    ("Pole", "utility_pole", _utility_pole),
    ("Pole", "flagpole", _flagpole),
    ("TrafficLight", "vehicle_signal", _vehicle_signal),
    ("TrafficLight", "pedestrian_signal", _pedestrian_signal),
    ("TrafficLight", "overhead_signal", _overhead_signal),
    ("TrafficSign", "stop", _sign("stop")),
    ("TrafficSign", "speed_limit", _sign("speed_limit")),
    ("TrafficSign", "yield", _sign("yield")),
    ("TrafficSign", "warning", _sign("warning")),
    ("TrafficSign", "direction", _sign("direction")),
    ("TrafficSign", "no_entry", _sign("no_entry")),
    ("TrafficSign", "one_way", _sign("one_way")),
    ("TrafficSign", "pedestrian_crossing", _sign("pedestrian_crossing")),
    ("TrafficSign", "parking", _sign("parking")),
    ("Vegetation", "tree", _tree),
    ("Vegetation", "conifer", _conifer),
    ("Vegetation", "bush", _bush),
    ("Vegetation", "palm", _palm),
    ("Vegetation", "hedge", _hedge),
    ("Pedestrian", "adult", _pedestrian("adult")),
    ("Pedestrian", "child", _pedestrian("child")),
    ("Rider", "cyclist", _rider("bicycle")),
    ("Rider", "motorcyclist", _rider("motorcycle")),
    ("Car", "sedan", _car("sedan")),
    ("Car", "hatchback", _car("hatchback")),
    ("Car", "suv", _car("suv")),
    ("Car", "van", _car("van")),
    ("Car", "coupe", _car("coupe")),
    ("Car", "wagon", _car("wagon")),
    ("Car", "minivan", _car("minivan")),
    ("Car", "taxi", _car("taxi")),
    ("Car", "police", _car("police")),
    ("Car", "convertible", _convertible),
    ("Car", "pickup", _pickup),
    ("Truck", "box_truck", _truck("box_truck")),
    ("Truck", "tanker", _truck("tanker")),
    ("Truck", "fire_truck", _truck("fire_truck")),
    ("Truck", "semi_truck", _truck("semi_truck")),
    ("Truck", "garbage_truck", _truck("garbage_truck")),
    ("Truck", "tow_truck", _truck("tow_truck")),
    ("Truck", "cement_mixer", _truck("cement_mixer")),
    ("Truck", "dump_truck", _truck("dump_truck")),
    ("Bus", "city_bus", _bus("city_bus")),
    ("Bus", "minibus", _bus("minibus")),
    ("Bus", "coach", _bus("coach")),
    ("Bus", "school_bus", _school_bus),
    ("Bus", "double_decker", _double_decker),
    ("Train", "tram", _tram),
    ("Train", "metro", _metro),
    ("Train", "train", _locomotive),
    ("Motorcycle", "sport", _parked("sport")),
    ("Motorcycle", "cruiser", _parked("cruiser")),
    ("Motorcycle", "scooter", _parked("scooter")),
    ("Motorcycle", "moped", _parked("moped")),
    ("Bicycle", "city_bike", _parked("city_bike")),
    ("Bicycle", "road_bike", _parked("road_bike")),
    ("Bicycle", "mountain_bike", _parked("mountain_bike")),
    ("Bicycle", "cargo_bike", _parked("cargo_bike")),
    ("Static", "bench", _bench),
    ("Static", "bin", _bin),
    ("Static", "hydrant", _hydrant),
    ("Static", "bus_stop", _bus_stop),
    ("Static", "mailbox", _mailbox),
    ("Static", "kiosk", _kiosk),
    ("Static", "bollard", _bollard),
    ("Static", "planter", _planter),
    ("Static", "barrier", _barrier),
    ("Static", "traffic_cone", _traffic_cone),
    ("Static", "billboard", _billboard),
    ("Static", "vending_machine", _vending_machine),
    ("Static", "phone_booth", _phone_booth),
    ("Dynamic", "movable_bin", _movable_bin),
    ("Dynamic", "box", _boxes),
    ("Dynamic", "luggage", _luggage),
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


def _records(
    category: str, subclass: str, variant: int, parts: list[MeshPart]
) -> tuple[AssetRecord, list[PartRecord], AssetGeometry]:
    """Standardize one asset's parts and describe them as records."""
    parts, extent = _recentre(parts)
    aid = asset_id_for(category, subclass, parts)
    closed = tuple(is_watertight(p.faces) for p in parts)
    asset = AssetRecord(
        asset_id=aid, source=SOURCE, source_path=f"procedural://{category}/{subclass}/{variant}",
        licence=LICENCE, category_id=_ID[category], category=category, subclass=subclass,
        extent=[float(e) for e in extent],
        vertex_count=int(sum(len(p.vertices) for p in parts)), face_count=int(sum(len(p.faces) for p in parts)),
        part_count=len(parts), transparent_part_count=sum(p.transparent for p in parts),
        surface_area=sum(surface_area(p.vertices, p.faces) for p in parts),
        volume=sum(signed_volume(p.vertices, p.faces) for p in parts) if all(closed) else None,
        watertight=all(closed), scale_applied=1.0, scale_rule="metric by construction",
        geometry_hash=geometry_hash([(p.vertices, p.faces) for p in parts]), mesh_path="",
    )  # fmt: skip
    part_records = [
        PartRecord(
            asset_id=aid, part_index=k, name=p.name, material=p.material, transparent=p.transparent,
            semantic_id=p.semantic_id, face_count=int(len(p.faces)), watertight=c,
        )  # fmt: skip
        for k, (p, c) in enumerate(zip(parts, closed))
    ]
    return asset, part_records, AssetGeometry(asset_id=aid, parts=tuple(parts), part_closed=closed)


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
            asset, part_records, geom = _records(category, subclass, variant, build(rng))
            if asset.asset_id in geometry:  # identical draws cannot happen with continuous ranges
                raise ValueError(f"procedural asset {category}/{subclass}/{variant} duplicates {asset.asset_id}")
            assets.append(asset)
            parts.extend(part_records)
            geometry[asset.asset_id] = geom
    return IngestResult(assets=assets, parts=parts, geometry=geometry)
