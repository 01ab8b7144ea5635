"""The built-in procedural ADMesh source: parametric road-scene assets made from closed primitives.

Every asset is a list of parts (:class:`stages.geometry.MeshPart`) in the **asset frame**: metres,
+X forward, +Y left, Z up, origin at the bottom centre of the asset's axis-aligned bounding box.
Each part is built from ``trimesh.creation`` primitives (box, cylinder, icosphere, capsule, cone)
and is closed and consistently wound on its own; a part made of several primitives uses
*disjoint* pieces only (touching at most), so a closed part stays a valid solid for interior fill.
Pieces of one asset that overlap (a wheel inside a wheel arch, a window half sunk into a wall) are
separate parts.

Transparent parts (vehicle windows, building glazing) are parts of their own with
``transparent=True``, material ``"glass"`` and the asset's class as semantic id.

Conventions the scene builder relies on (documented here, derived from the asset extent):

* Buildings: the entrance facade faces +X; ``extent[0]`` is the depth, ``extent[1]`` the frontage.
* ``Pole/street_light``: the pole stands at the -X end (``x = -extent[0]/2 + r``, ``y = 0``);
  the arm and lamp reach forward along +X (over the road when +X points at it).
* ``TrafficLight/vehicle_signal``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``; the lenses
  face +X (towards the traffic they control).
* ``TrafficLight/overhead_signal``: the pole is at ``x = -extent[0]/2 + r``,
  ``y = +extent[1]/2 - r``; the mast arm reaches along -Y and the head's lenses face +X.
* ``TrafficSign/*``: the pole is at ``x = -extent[0]/2 + r``, ``y = 0``; the plate faces +X.
* ``Static/bench``: the seat faces +X, the backrest is at -X.

``r`` is the pole radius (0.04-0.11 m). Sizes are seeded uniform draws inside realistic ranges, so
``variants_per_subclass`` variants of one sub-class differ in size and proportions; the same seed
gives byte-identical vertex arrays and records.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import trimesh

from schemas import taxonomy
from schemas.configs import IngestConfig
from schemas.records import AssetRecord, PartRecord
from stages.geometry import (AssetGeometry, MeshPart, concatenate, geometry_hash, is_watertight,
                             signed_volume, surface_area)

__all__ = ["IngestResult", "ingest_procedural", "asset_id_for", "SOURCE", "LICENCE"]

SOURCE = "procedural"
LICENCE = "CC0-1.0 (generated)"

# class ids, looked up once from the taxonomy table
_ID = {name: taxonomy.by_name(name).id for name in (
    "Building", "Pole", "TrafficLight", "TrafficSign", "Vegetation", "Pedestrian", "Rider", "Car",
    "Truck", "Bus", "Motorcycle", "Bicycle", "Static",
)}  # fmt: skip

# display colour (RGBA) of each material; purely cosmetic (GLB export, previews)
_COLOURS: dict[str, tuple[int, int, int, int]] = {
    "paint": (170, 30, 40, 255),
    "glass": (140, 180, 210, 110),
    "rubber": (25, 25, 25, 255),
    "metal": (120, 120, 125, 255),
    "plastic": (60, 60, 60, 255),
    "concrete": (170, 165, 160, 255),
    "brick": (160, 80, 60, 255),
    "plaster": (215, 205, 185, 255),
    "roof_tile": (120, 50, 40, 255),
    "wood": (110, 75, 45, 255),
    "bark": (90, 60, 40, 255),
    "foliage": (60, 120, 40, 255),
    "lamp": (250, 240, 200, 255),
    "lens": (240, 200, 60, 255),
    "sign_face": (220, 220, 220, 255),
    "skin": (220, 180, 150, 255),
    "cloth": (60, 70, 120, 255),
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


def _fit(mesh: Mesh, lo, hi) -> Mesh:
    """Scale (positive, per axis) and move a mesh so its bounding box is ``lo .. hi``."""
    v, f = mesh
    vmin, vmax = v.min(axis=0), v.max(axis=0)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return (v - vmin) / (vmax - vmin) * (hi - lo) + lo, f


def _union(*meshes: Mesh) -> Mesh:
    """Disjoint pieces as one mesh (each piece stays closed, so the union is closed)."""
    return concatenate(list(meshes))


def _part(name: str, mesh: Mesh, semantic: str, material: str, transparent: bool = False) -> MeshPart:
    """A :class:`MeshPart` of class ``semantic`` (taxonomy name) and ``material``."""
    return MeshPart(
        name=name, vertices=mesh[0], faces=mesh[1], semantic_id=_ID[semantic], material=material,
        transparent=transparent, color=_COLOURS[material],
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# builders: one function per sub-class family; each draws its sizes from ``rng``
# --------------------------------------------------------------------------------------------


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One uniform draw in [lo, hi) as a Python float."""
    return float(rng.uniform(lo, hi))


def _wheels(xs, half_track: float, radius: float, width: float, semantic: str) -> list[MeshPart]:
    """One wheel part per axle position in ``xs`` and side (axis along Y, touching z = 0)."""
    out = []
    for k, x in enumerate(xs):
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y = sy * half_track
            mesh = _cylinder(radius, (x, y - width / 2, radius), (x, y + width / 2, radius), 16)
            out.append(_part(f"wheel_{k}_{side}", mesh, semantic, "rubber"))
    return out


def _greenhouse_vehicle(
    L: float, W: float, H: float, *, semantic: str, clearance: float, belt: float,
    gh_rear: float, gh_front: float, top_rear: float, top_front: float, top_side: float,
    hood: tuple[float, float], wheel_r: float, wheel_w: float, axles: list[float],
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
        _part("body", body, semantic, "paint"),
        _part("windows", glass, semantic, "glass", transparent=True),
        _part("roof", roof, semantic, "paint"),
    ]
    return parts + _wheels(axles, W / 2 - wheel_w / 2 - 0.03, wheel_r, wheel_w, semantic)


# sub-class -> ranges of length, width, height (m) and shape fractions
_CAR_SPECS: dict[str, dict] = {
    "sedan": dict(L=(4.3, 4.9), W=(1.75, 1.9), H=(1.40, 1.50), r=(0.31, 0.34), clear=0.17,
                  belt=0.52, gh=(-0.30, 0.17), top=(0.38, 0.55), hood=(0.25, 0.10)),
    "hatchback": dict(L=(3.8, 4.3), W=(1.68, 1.80), H=(1.42, 1.55), r=(0.30, 0.33), clear=0.16,
                      belt=0.50, gh=(-0.47, 0.16), top=(0.12, 0.55), hood=(0.22, 0.10)),
    "suv": dict(L=(4.5, 5.0), W=(1.85, 2.0), H=(1.65, 1.85), r=(0.36, 0.40), clear=0.24,
                belt=0.55, gh=(-0.46, 0.19), top=(0.10, 0.50), hood=(0.20, 0.08)),
    "van": dict(L=(4.8, 5.4), W=(1.90, 2.05), H=(1.95, 2.30), r=(0.33, 0.36), clear=0.20,
                belt=0.45, gh=(-0.48, 0.33), top=(0.03, 0.38), hood=(0.30, 0.15)),
}  # fmt: skip


def _car(subclass: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """Builder of a Car sub-class from :data:`_CAR_SPECS`."""
    spec = _CAR_SPECS[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *spec["L"]), _u(rng, *spec["W"]), _u(rng, *spec["H"])
        r = _u(rng, *spec["r"])
        belt = spec["clear"] + (H - spec["clear"]) * spec["belt"]
        # axles: overhangs of about 19 % (front) and 21 % (rear) of the length
        axles = [L / 2 - 0.19 * L, -L / 2 + 0.21 * L]
        return _greenhouse_vehicle(
            L, W, H, semantic="Car", clearance=spec["clear"], belt=belt,
            gh_rear=spec["gh"][0] * L, gh_front=spec["gh"][1] * L, top_rear=spec["top"][0],
            top_front=spec["top"][1], top_side=0.10, hood=spec["hood"], wheel_r=r, wheel_w=0.22,
            axles=axles,
        )  # fmt: skip

    return build


def _bus(subclass: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """City bus (10.5-12.5 m) or minibus (6.5-7.8 m): full-length window band."""
    L_range, W_range, H_range = {
        "city_bus": ((10.5, 12.5), (2.50, 2.55), (3.0, 3.2)),
        "minibus": ((6.5, 7.8), (2.10, 2.30), (2.6, 2.9)),
    }[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L, W, H = _u(rng, *L_range), _u(rng, *W_range), _u(rng, *H_range)
        r = 0.50 if subclass == "city_bus" else 0.40
        front, rear = (2.6, 3.2) if subclass == "city_bus" else (1.3, 1.6)
        return _greenhouse_vehicle(
            L, W, H, semantic="Bus", clearance=0.30, belt=1.15 if subclass == "city_bus" else 1.0,
            gh_rear=-L / 2 + 0.05, gh_front=L / 2 - 0.05, top_rear=0.05, top_front=0.15,
            top_side=0.03, hood=(0.05, 0.02), wheel_r=r, wheel_w=0.30,
            axles=[L / 2 - front, -L / 2 + rear],
        )  # fmt: skip

    return build


def _truck(subclass: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """Box truck or tanker: a cab with its own windows at the front, a cargo box or tank behind,
    a chassis beam and six wheels (dual rear axles)."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        L = _u(rng, 6.5, 9.0) if subclass == "box_truck" else _u(rng, 8.0, 10.0)
        W, H = _u(rng, 2.30, 2.50), _u(rng, 3.0, 3.6)
        cab_len, cab_h, r = _u(rng, 2.0, 2.3), _u(rng, 2.6, 2.9), 0.50
        xf = L / 2
        cab_x0 = xf - cab_len
        cab = _chamfer_front_top(_box((cab_x0, -W / 2, 0.70), (xf, W / 2, 1.65)), 0.08, 0.05)
        gy = W / 2 - 0.05
        glass = _frustum((cab_x0 + 0.3, -gy, 1.65), (xf - 0.05, gy, cab_h - 0.08),
                         (cab_x0 + 0.3, -gy + 0.05), (xf - 0.30, gy - 0.05))  # fmt: skip
        cab_roof = _box((cab_x0 + 0.3, -gy + 0.05, cab_h - 0.08), (xf - 0.30, gy - 0.05, cab_h))
        # the cab's back wall below the roof behind the glass
        cab_back = _box((cab_x0, -gy, 1.65), (cab_x0 + 0.3, gy, cab_h))
        chassis = _box((-L / 2 + 0.3, -0.55, 0.55), (cab_x0 - 0.15, 0.55, 1.0))
        parts = [
            _part("cab", cab, "Truck", "paint"),
            _part("cab_windows", glass, "Truck", "glass", transparent=True),
            _part("cab_roof", cab_roof, "Truck", "paint"),
            _part("cab_back", cab_back, "Truck", "paint"),
            _part("chassis", chassis, "Truck", "metal"),
        ]
        cargo_x0, cargo_x1 = -L / 2, cab_x0 - 0.15
        if subclass == "box_truck":
            parts.append(_part("cargo_box", _box((cargo_x0, -W / 2, 1.0), (cargo_x1, W / 2, H)), "Truck", "paint"))
        else:
            tr = min((H - 1.0) / 2, W / 2 - 0.02)
            tank = _cylinder(tr, (cargo_x0, 0.0, 1.0 + tr), (cargo_x1, 0.0, 1.0 + tr), 20)
            parts.append(_part("tank", tank, "Truck", "metal"))
        axles = [xf - 1.2, -L / 2 + 1.6 + 1.35, -L / 2 + 1.6]
        return parts + _wheels(axles, W / 2 - 0.18, r, 0.32, "Truck")

    return build


def _two_wheeler(rng: np.random.Generator, kind: str) -> tuple[list[MeshPart], dict[str, np.ndarray]]:
    """Bicycle or motorcycle parts (class Bicycle/Motorcycle) and the rider anchor points
    (``seat``, ``bar``, ``pedal``: hip, hands and feet of a rider)."""
    sem = "Bicycle" if kind == "bicycle" else "Motorcycle"
    if kind == "bicycle":
        r, tw, wb = _u(rng, 0.33, 0.35), 0.04, _u(rng, 1.02, 1.10)
        seat_z, bar_z, bar_w = _u(rng, 0.85, 0.95), _u(rng, 0.95, 1.05), _u(rng, 0.50, 0.60)
    else:
        r, tw, wb = _u(rng, 0.29, 0.32), 0.13, _u(rng, 1.35, 1.50)
        seat_z, bar_z, bar_w = _u(rng, 0.78, 0.85), _u(rng, 1.00, 1.10), _u(rng, 0.70, 0.80)
    xf, xr = wb / 2, -wb / 2
    parts = [
        _part("wheel_front", _cylinder(r, (xf, -tw / 2, r), (xf, tw / 2, r), 20), sem, "rubber"),
        _part("wheel_rear", _cylinder(r, (xr, -tw / 2, r), (xr, tw / 2, r), 20), sem, "rubber"),
    ]
    seat = np.array([xr + 0.30, 0.0, seat_z])
    bar = np.array([xf - 0.12, 0.0, bar_z])
    pedal = np.array([0.0, 0.0, 0.30])
    if kind == "bicycle":
        t = 0.035
        parts += [
            _part("top_tube", _beam(seat + (0.05, 0, -0.08), bar + (-0.05, 0, -0.12), t, t), sem, "metal"),
            _part("down_tube", _beam(pedal, bar + (-0.03, 0, -0.18), t, t), sem, "metal"),
            _part("seat_tube", _beam(pedal + (0.0, 0, 0.02), seat + (0.0, 0, -0.04), t, t), sem, "metal"),
            _part("chain_stay", _beam(pedal + (-0.02, 0, 0.0), (xr + 0.02, 0.0, r), t, t), sem, "metal"),
            _part("fork", _beam(bar + (-0.02, 0, -0.10), (xf - 0.01, 0.0, r + 0.02), t, t), sem, "metal"),
            _part("saddle", _box(seat + (-0.12, -0.07, -0.02), seat + (0.12, 0.07, 0.04)), sem, "plastic"),
        ]
    else:
        parts += [
            _part("engine", _frustum((xr + 0.35, -0.20, 0.28), (xf - 0.35, 0.20, 0.62),
                                     (xr + 0.30, -0.17), (xf - 0.40, 0.17)), sem, "metal"),  # fmt: skip
            _part("tank", _box((0.0, -0.17, 0.62), (xf - 0.25, 0.17, bar_z - 0.18)), sem, "paint"),
            _part("seat", _box((xr + 0.05, -0.15, 0.62), (-0.02, 0.15, seat_z)), sem, "plastic"),
            _part("fork", _beam(bar + (-0.03, 0, -0.06), (xf - 0.02, 0.0, r + 0.05), 0.08, 0.08), sem, "metal"),
            _part("windscreen", _beam(bar + (-0.02, 0, 0.02), bar + (0.10, 0, 0.30), 0.36, 0.01), sem,
                  "glass", transparent=True),  # fmt: skip
        ]
    handlebar = _box(bar + (-0.02, -bar_w / 2, -0.02), bar + (0.02, bar_w / 2, 0.02))
    parts.append(_part("handlebar", handlebar, sem, "metal"))
    return parts, {"seat": seat, "bar": bar, "pedal": pedal}


def _bicycle(rng: np.random.Generator) -> list[MeshPart]:
    """A parked city bicycle (1.7-1.8 m)."""
    return _two_wheeler(rng, "bicycle")[0]


def _motorcycle(rng: np.random.Generator) -> list[MeshPart]:
    """A sport motorcycle (about 2.0-2.2 m) with a small transparent windscreen."""
    return _two_wheeler(rng, "motorcycle")[0]


def _rider(kind: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """A rider (class Rider) on a bicycle or motorcycle (that vehicle's class)."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        parts, a = _two_wheeler(rng, kind)
        H = _u(rng, 1.60, 1.90)  # standing height of the rider
        hip = a["seat"] + (0.0, 0.0, 0.10)
        shoulder = hip + (0.30, 0.0, 0.30 * H)
        tr, ar, lr = 0.085 * H * 0.9, 0.028 * H, 0.045 * H
        head_r = 0.065 * H
        hands_y = 0.20
        parts += [
            _part("rider_torso", _capsule(tr, hip + (0.02, 0, tr * 0.6), shoulder - (0.03, 0, 0.05)), "Rider", "cloth"),
            _part("rider_head", _ellipsoid(shoulder + (0.10, 0.0, 0.06 + 1.6 * head_r), (head_r,) * 3),
                  "Rider", "skin"),
        ]  # fmt: skip
        for side, sy in (("left", 1.0), ("right", -1.0)):
            sh = shoulder + (0.0, sy * (tr + ar), -0.05)
            hand = a["bar"] + (0.0, sy * hands_y, 0.03)
            foot = a["pedal"] + (0.05, sy * 0.16, 0.0)
            knee = (hip + foot) / 2 + (0.22, sy * 0.10, 0.12)
            parts += [
                _part(f"rider_arm_{side}", _capsule(ar, sh, hand), "Rider", "cloth"),
                _part(f"rider_thigh_{side}", _capsule(lr, hip + (0.0, sy * 0.09, 0.0), knee), "Rider", "cloth"),
                _part(f"rider_shin_{side}", _capsule(lr * 0.85, knee + (0.0, 0.0, -0.02), foot), "Rider", "cloth"),
            ]  # fmt: skip
        return parts

    return build


def _pedestrian(subclass: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """Standing person (adult 1.55-1.95 m, child 1.0-1.4 m): head, torso, two arms, two legs."""
    h_range, head_frac = {"adult": ((1.55, 1.95), 0.065), "child": ((1.00, 1.40), 0.080)}[subclass]

    def build(rng: np.random.Generator) -> list[MeshPart]:
        H = _u(rng, *h_range)
        head_r = head_frac * H
        leg_r, arm_r, torso_r = 0.042 * H, 0.028 * H, 0.085 * H
        hip_z = 0.50 * H
        torso_top = H - 2 * head_r - torso_r * 0.6
        parts = [
            _part("head", _ellipsoid((0.0, 0.0, H - head_r), (head_r, head_r * 0.9, head_r)), "Pedestrian", "skin"),
        ]
        torso = _capsule(torso_r, (0.0, 0.0, hip_z + 0.2 * torso_r), (0.0, 0.0, torso_top))
        torso = (torso[0] * (0.8, 1.15, 1.0), torso[1])  # flatter front-to-back than side-to-side
        parts.append(_part("torso", torso, "Pedestrian", "cloth"))
        for side, sy in (("left", 1.0), ("right", -1.0)):
            y_leg = sy * 0.055 * H
            y_arm = sy * (torso_r * 1.15 + arm_r + 0.01)
            parts += [
                _part(f"leg_{side}", _capsule(leg_r, (0.0, y_leg, hip_z), (0.0, y_leg, leg_r)), "Pedestrian", "cloth"),
                _part(f"arm_{side}", _capsule(arm_r, (0.0, y_arm, torso_top - 0.02 * H), (0.02 * H, y_arm, 0.46 * H)),
                      "Pedestrian", "skin"),
            ]  # fmt: skip
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
        _part("walls", walls, "Building", "plaster"),
        _part("roof", roof, "Building", "roof_tile"),
        _part("glazing", glazing, "Building", "glass", transparent=True),
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
        _part("walls", walls, "Building", "brick"),
        _part("glazing", _union(glazing, ground), "Building", "glass", transparent=True),
        _part("entrance", door, "Building", "glass", transparent=True),
        _part("roof_plant", plant, "Building", "concrete"),
    ]


def _office(rng: np.random.Generator) -> list[MeshPart]:
    """Office tower, 8-13 floors of 3.6 m over a 4.5 m lobby: a concrete core, a glass curtain
    wall on every facade, floor-slab edges projecting 0.15 m at every floor, a roof plant room."""
    D, F = _u(rng, 18.0, 28.0), _u(rng, 18.0, 30.0)
    floors = int(rng.integers(8, 14))
    lobby = 4.5
    H = lobby + 3.6 * floors
    core = _box((-D / 2 + 0.15, -F / 2 + 0.15, 0.0), (D / 2 - 0.15, F / 2 - 0.15, H))
    # curtain walls: front/back span the full frontage, the sides fit between them
    t = 0.15
    curtain = _union(
        _box((D / 2 - t, -F / 2, 0.0), (D / 2, F / 2, H - 0.6)),
        _box((-D / 2, -F / 2, 0.0), (-D / 2 + t, F / 2, H - 0.6)),
        _box((-D / 2 + t, F / 2 - t, 0.0), (D / 2 - t, F / 2, H - 0.6)),
        _box((-D / 2 + t, -F / 2, 0.0), (D / 2 - t, -F / 2 + t, H - 0.6)),
    )
    slabs = _union(*[
        _box((-D / 2 - 0.15, -F / 2 - 0.15, z - 0.3), (D / 2 + 0.15, F / 2 + 0.15, z))
        for z in [lobby + 3.6 * k for k in range(floors)]
    ] + [_box((-D / 2 - 0.15, -F / 2 - 0.15, H - 0.6), (D / 2 + 0.15, F / 2 + 0.15, H))])  # fmt: skip
    plant = _box((-D / 5, -F / 5, H), (D / 5, F / 5, H + _u(rng, 2.5, 4.0)))
    return [
        _part("core", core, "Building", "concrete"),
        _part("curtain_wall", curtain, "Building", "glass", transparent=True),
        _part("floor_slabs", slabs, "Building", "concrete"),
        _part("roof_plant", plant, "Building", "concrete"),
    ]


def _tree(rng: np.random.Generator) -> list[MeshPart]:
    """Street tree: trunk and an ellipsoid crown pruned high (crown base 3.8-4.5 m, so trucks and
    buses pass under branches that overhang the road)."""
    crown_base = _u(rng, 3.8, 4.5)
    rx, rz = _u(rng, 1.5, 2.8), _u(rng, 1.4, 2.4)
    trunk_r = _u(rng, 0.12, 0.22)
    trunk = _cylinder(trunk_r, (0.0, 0.0, 0.0), (0.0, 0.0, crown_base + rz), 8)
    crown = _ellipsoid((0.0, 0.0, crown_base + rz), (rx, rx * _u(rng, 0.85, 1.0), rz), 1)
    return [_part("trunk", trunk, "Vegetation", "bark"), _part("crown", crown, "Vegetation", "foliage")]


def _conifer(rng: np.random.Generator) -> list[MeshPart]:
    """Conifer: trunk and a cone crown starting 1-2 m above ground, 6-12 m tall."""
    base, height, radius = _u(rng, 1.0, 2.0), _u(rng, 5.0, 10.0), _u(rng, 1.2, 2.2)
    trunk = _cylinder(_u(rng, 0.12, 0.20), (0.0, 0.0, 0.0), (0.0, 0.0, base + 0.5), 8)
    crown = _cone(radius, height, (0.0, 0.0, base), 12)
    return [_part("trunk", trunk, "Vegetation", "bark"), _part("crown", crown, "Vegetation", "foliage")]


def _bush(rng: np.random.Generator) -> list[MeshPart]:
    """Bush: a flattened ellipsoid on the ground, 0.8-1.6 m high."""
    h, rx = _u(rng, 0.8, 1.6), _u(rng, 0.6, 1.3)
    crown = _ellipsoid((0.0, 0.0, h / 2), (rx, rx * _u(rng, 0.7, 1.0), h / 2), 1)
    return [_part("crown", crown, "Vegetation", "foliage")]


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


def _signal_head(x_back: float, y: float, z_top: float) -> tuple[Mesh, Mesh]:
    """A three-lens signal head with its back at ``x_back``, centred on ``y``, top at ``z_top``;
    returns (housing, lenses) with the lenses facing +X."""
    depth, width, height = 0.25, 0.35, 0.95
    housing = _box((x_back, y - width / 2, z_top - height), (x_back + depth, y + width / 2, z_top))
    lenses = _union(*[
        _plate_x(0.10, 0.04, (x_back + depth + 0.02, y, z_top - 0.17 - 0.30 * k), 12, 0.0) for k in range(3)
    ])  # fmt: skip
    return housing, lenses


def _vehicle_signal(rng: np.random.Generator) -> list[MeshPart]:
    """Post-mounted vehicle signal: a 3.0-3.6 m pole with a signal head on its front (+X)."""
    h, r = _u(rng, 3.0, 3.6), _u(rng, 0.07, 0.09)
    housing, lenses = _signal_head(r, 0.0, h)
    return [
        _part("pole", _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 12), "Pole", "metal"),
        _part("head", housing, "TrafficLight", "metal"),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


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
        _part("head", housing, "TrafficLight", "metal"),
        _part("lenses", lenses, "TrafficLight", "lens"),
    ]


def _sign(subclass: str) -> Callable[[np.random.Generator], list[MeshPart]]:
    """Traffic sign on a thin pole; the plate faces +X: stop (octagon), speed_limit (disc),
    yield (triangle, point down), warning (triangle, point up), direction (rectangle)."""

    def build(rng: np.random.Generator) -> list[MeshPart]:
        r = 0.045
        plate_centre_z = _u(rng, 2.3, 2.7)
        x = r + 0.015 + 0.01  # plate just in front of the pole
        if subclass == "stop":
            plate = _plate_x(_u(rng, 0.36, 0.40), 0.03, (x, 0.0, plate_centre_z), 8, np.pi / 8)
        elif subclass == "speed_limit":
            plate = _plate_x(_u(rng, 0.28, 0.32), 0.03, (x, 0.0, plate_centre_z), 20, 0.0)
        elif subclass in ("yield", "warning"):
            # the primitive's corner at spin 0 ends at -Z after the turn: point down for yield
            spin = 0.0 if subclass == "yield" else np.pi
            plate = _plate_x(_u(rng, 0.42, 0.48), 0.03, (x, 0.0, plate_centre_z), 3, spin)
        else:
            w, hgt = _u(rng, 0.6, 1.0), _u(rng, 0.4, 0.7)
            plate = _box((x - 0.015, -w / 2, plate_centre_z - hgt / 2), (x + 0.015, w / 2, plate_centre_z + hgt / 2))
        top = float(plate[0][:, 2].max())
        pole = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, top - 0.05), 8)
        return [_part("pole", pole, "Pole", "metal"), _part("plate", plate, "TrafficSign", "sign_face")]

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
    body = _cylinder(r, (0.0, 0.0, 0.0), (0.0, 0.0, h), 16)
    lid = _cylinder(r + 0.02, (0.0, 0.0, h), (0.0, 0.0, h + 0.05), 16)
    return [_part("body", body, "Static", "plastic"), _part("lid", lid, "Static", "plastic")]


# (category, sub-class, builder) of every procedural sub-class, in output order
CATALOGUE: tuple[tuple[str, str, Callable[[np.random.Generator], list[MeshPart]]], ...] = (
    ("Building", "house", _house),
    ("Building", "residential", _residential),
    ("Building", "office", _office),
    ("Pole", "street_light", _street_light),
    ("TrafficLight", "vehicle_signal", _vehicle_signal),
    ("TrafficLight", "overhead_signal", _overhead_signal),
    ("TrafficSign", "stop", _sign("stop")),
    ("TrafficSign", "speed_limit", _sign("speed_limit")),
    ("TrafficSign", "yield", _sign("yield")),
    ("TrafficSign", "warning", _sign("warning")),
    ("TrafficSign", "direction", _sign("direction")),
    ("Vegetation", "tree", _tree),
    ("Vegetation", "conifer", _conifer),
    ("Vegetation", "bush", _bush),
    ("Pedestrian", "adult", _pedestrian("adult")),
    ("Pedestrian", "child", _pedestrian("child")),
    ("Rider", "cyclist", _rider("bicycle")),
    ("Rider", "motorcyclist", _rider("motorcycle")),
    ("Car", "sedan", _car("sedan")),
    ("Car", "hatchback", _car("hatchback")),
    ("Car", "suv", _car("suv")),
    ("Car", "van", _car("van")),
    ("Truck", "box_truck", _truck("box_truck")),
    ("Truck", "tanker", _truck("tanker")),
    ("Bus", "city_bus", _bus("city_bus")),
    ("Bus", "minibus", _bus("minibus")),
    ("Motorcycle", "sport", _motorcycle),
    ("Bicycle", "city_bike", _bicycle),
    ("Static", "bench", _bench),
    ("Static", "bin", _bin),
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
