"""Shared pieces of the procedural builders: class ids, materials and palettes, closed mesh
primitives, parts, and the builders' random draws.

A mesh here is ``(vertices (N, 3) float64 m, faces (M, 3) int64)`` in the asset frame (+X forward,
+Y left, Z up). Every primitive is closed and wound outward; the builders combine disjoint pieces
into parts (:func:`part`, :func:`glass_part`). Colours are cosmetic (GLB files, previews).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import trimesh

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.geometry import concatenate, signed_volume


# class ids, looked up once from the taxonomy table
ID = {name: taxonomy.by_name(name).id for name in (
    "Building", "Pole", "TrafficLight", "TrafficSign", "Vegetation", "Pedestrian", "Rider", "Car",
    "Truck", "Bus", "Train", "Motorcycle", "Bicycle", "Static", "Dynamic",
)}  # fmt: skip

RGBA = tuple[int, int, int, int]

# default display colour (RGBA) of each material; purely cosmetic (GLB export, previews)
COLOURS: dict[str, RGBA] = {
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
WHITE, BLACK, RED, YELLOW = (235, 235, 232, 255), (28, 28, 30, 255), (190, 25, 30, 255), (240, 185, 20, 255)
BLUE, GREEN, ORANGE, DARK = (30, 75, 165, 255), (25, 105, 60, 255), (235, 110, 20, 255), (45, 45, 50, 255)
PAINTS: tuple[RGBA, ...] = (
    (230, 230, 228, 255), (25, 25, 28, 255), (165, 168, 172, 255), (95, 98, 104, 255), (150, 22, 28, 255),
    (28, 58, 130, 255), (18, 32, 68, 255), (42, 84, 56, 255), (205, 160, 40, 255), (110, 70, 45, 255),
    (200, 85, 25, 255), (120, 150, 180, 255),
)  # fmt: skip
CLOTHES: tuple[RGBA, ...] = (
    (40, 45, 90, 255), (30, 30, 35, 255), (120, 30, 35, 255), (70, 100, 60, 255), (200, 190, 170, 255),
    (90, 90, 95, 255), (170, 120, 60, 255), (60, 110, 160, 255), (150, 80, 130, 255), (220, 220, 215, 255),
)  # fmt: skip
SKINS: tuple[RGBA, ...] = (
    (240, 205, 180, 255), (220, 180, 150, 255), (180, 130, 95, 255), (120, 80, 55, 255), (85, 60, 45, 255),
)  # fmt: skip
HAIR: tuple[RGBA, ...] = ((30, 25, 20, 255), (90, 60, 35, 255), (200, 170, 110, 255), (140, 140, 140, 255))
FACADES: dict[str, tuple[RGBA, ...]] = {
    "plaster": ((215, 205, 185, 255), (232, 226, 212, 255), (205, 180, 150, 255), (190, 198, 204, 255)),
    "brick": ((160, 80, 60, 255), (140, 65, 50, 255), (175, 110, 80, 255)),
    "concrete": ((170, 165, 160, 255), (150, 150, 150, 255), (190, 185, 175, 255)),
    "metal": ((150, 155, 160, 255), (90, 110, 140, 255), (110, 130, 100, 255), (190, 190, 185, 255)),
}

Mesh = tuple[np.ndarray, np.ndarray]  # (vertices (N, 3) float64 m, faces (M, 3) int64)


# --------------------------------------------------------------------------------------------
# primitives: small pure functions returning (vertices, faces) in metres
# --------------------------------------------------------------------------------------------


def _tm(mesh: trimesh.Trimesh) -> Mesh:
    """(vertices, faces) copies of a trimesh primitive."""
    return np.array(mesh.vertices, dtype=np.float64), np.array(mesh.faces, dtype=np.int64)


def box(lo, hi) -> Mesh:
    """Axis-aligned box between corners ``lo`` and ``hi`` (m)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v, f = _tm(trimesh.creation.box(extents=hi - lo))
    return v + (lo + hi) / 2.0, f


def frustum(lo, hi, top_lo_xy, top_hi_xy) -> Mesh:
    """A box whose top face is moved to the rectangle ``top_lo_xy .. top_hi_xy`` (a tapered
    greenhouse or hip roof); still 8 vertices, closed and convex when the top lies over the
    bottom."""
    v, f = box(lo, hi)
    top = v[:, 2] > (lo[2] + hi[2]) / 2.0
    # remap each top vertex from the bottom rectangle to the top rectangle, axis by axis
    for axis in (0, 1):
        at_hi = v[:, axis] > (lo[axis] + hi[axis]) / 2.0
        v[top & at_hi, axis] = top_hi_xy[axis]
        v[top & ~at_hi, axis] = top_lo_xy[axis]
    return v, f


def chamfer_front_top(mesh: Mesh, dx: float, dz: float) -> Mesh:
    """Move the box's front-top edge (max x, max z) back by ``dx`` and down by ``dz`` (a hood
    slope); the mesh stays closed and convex."""
    v, f = mesh[0].copy(), mesh[1]
    xmax, zmax = v[:, 0].max(), v[:, 2].max()
    edge = (v[:, 0] == xmax) & (v[:, 2] == zmax)
    v[edge, 0] -= dx
    v[edge, 2] -= dz
    return v, f


def cylinder(radius: float, p0, p1, sections: int = 16) -> Mesh:
    """Closed cylinder of ``radius`` with its axis from point ``p0`` to ``p1`` (m)."""
    return _tm(trimesh.creation.cylinder(radius=radius, segment=[p0, p1], sections=sections))


def capsule(radius: float, p0, p1, count: int = 8) -> Mesh:
    """Closed capsule whose hemisphere centres are ``p0`` and ``p1`` (it extends ``radius``
    beyond both)."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    v, f = _tm(trimesh.creation.capsule(height=length, radius=radius, count=[count, count]))
    # rotate the +Z axis of the primitive onto the segment, then move it to the midpoint
    R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / length)[:3, :3]
    return v @ R.T + (p0 + p1) / 2.0, f


def ellipsoid(centre, radii, subdivisions: int = 1) -> Mesh:
    """Closed ellipsoid (a scaled icosphere) at ``centre`` with semi-axes ``radii`` (m)."""
    v, f = _tm(trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0))
    return v * np.asarray(radii, dtype=np.float64) + np.asarray(centre, dtype=np.float64), f


def cone(radius: float, height: float, base_centre, sections: int = 12) -> Mesh:
    """Closed upright cone with its base disc at ``base_centre`` (m)."""
    v, f = _tm(trimesh.creation.cone(radius=radius, height=height, sections=sections))
    return v + np.asarray(base_centre, dtype=np.float64), f


def cone_between(radius: float, base, tip, sections: int = 16) -> Mesh:
    """Closed cone with its base disc (``radius``) centred on ``base`` and its apex at ``tip``."""
    base, tip = np.asarray(base, dtype=np.float64), np.asarray(tip, dtype=np.float64)
    d = tip - base
    height = float(np.linalg.norm(d))
    v, f = _tm(trimesh.creation.cone(radius=radius, height=height, sections=sections))
    R = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d / height)[:3, :3]
    return v @ R.T + base, f


def pyramid(half: float, height: float, base_centre) -> Mesh:
    """Closed square pyramid: base ``2 half`` by ``2 half`` (edges along X and Y) centred on
    ``base_centre``, apex ``height`` above it (a 4-section cone turned by 45 degrees)."""
    v, f = _tm(trimesh.creation.cone(radius=half * np.sqrt(2.0), height=height, sections=4))
    return rotate((v, f), rot_z(np.pi / 4), base_centre)


def beam(p0, p1, width: float, height: float) -> Mesh:
    """Box beam of square-ish section ``width`` (across, y) x ``height`` from ``p0`` to ``p1``."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    d = p1 - p0
    length = float(np.linalg.norm(d))
    v, f = box((-length / 2, -width / 2, -height / 2), (length / 2, width / 2, height / 2))
    # the box's +X becomes the beam direction
    R = trimesh.geometry.align_vectors([1.0, 0.0, 0.0], d / length)[:3, :3]
    return v @ R.T + (p0 + p1) / 2.0, f


def plate_x(radius: float, thickness: float, centre, sections: int, spin: float) -> Mesh:
    """Regular polygon plate facing +X (disc normal along X) with ``sections`` corners on
    ``radius``, ``thickness`` along X, centred on ``centre``. With ``spin`` 0 a corner points
    down (-Z); ``spin`` (rad) turns the polygon in the Y-Z plane."""
    v, f = _tm(trimesh.creation.cylinder(radius=radius, height=thickness, sections=sections))
    # spin about the primitive's axis, then turn that axis (Z) onto +X: (x, y, z) -> (z, y, -x)
    c, s = np.cos(spin), np.sin(spin)
    v = v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    v = np.column_stack([v[:, 2], v[:, 1], -v[:, 0]])
    return v + np.asarray(centre, dtype=np.float64), f


def prism_gable(lo, hi) -> Mesh:
    """Triangular prism filling the box ``lo .. hi`` with its ridge along Y at the top (a gable
    roof): a 3-section cylinder turned so its axis runs along Y and one corner points up."""
    v, f = _tm(trimesh.creation.cylinder(radius=1.0, height=1.0, sections=3))
    # proper rotation x -> z, y -> x, z -> y (a corner of the triangle at +x goes to the top)
    v = v[:, [1, 2, 0]]
    return _fit((v, f), lo, hi)


def extrude(profile, a: float, b: float, axis: str = "y") -> Mesh:
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


def rot_z(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about +Z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_y(a: float) -> np.ndarray:
    """Rotation by ``a`` rad about +Y (positive ``a`` tips +X down towards -Z)."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rotate(mesh: Mesh, R: np.ndarray, t=(0.0, 0.0, 0.0)) -> Mesh:
    """Rotate a mesh by the proper rotation ``R`` about the origin, then move it by ``t``."""
    return mesh[0] @ np.asarray(R).T + np.asarray(t, dtype=np.float64), mesh[1]


def _fit(mesh: Mesh, lo, hi) -> Mesh:
    """Scale (positive, per axis) and move a mesh so its bounding box is ``lo .. hi``."""
    v, f = mesh
    vmin, vmax = v.min(axis=0), v.max(axis=0)
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    return (v - vmin) / (vmax - vmin) * (hi - lo) + lo, f


def union(*meshes: Mesh) -> Mesh:
    """Disjoint pieces as one mesh (each piece stays closed, so the union is closed)."""
    return concatenate(list(meshes))


def shift(mesh: Mesh, d) -> Mesh:
    """A mesh moved by ``d`` (m)."""
    return mesh[0] + np.asarray(d, dtype=np.float64), mesh[1]


def part(
    name: str, mesh: Mesh, semantic: str, material: str, transparent: bool = False, color: RGBA | None = None
) -> MeshPart:
    """A :class:`MeshPart` of class ``semantic`` (taxonomy name) and ``material``, coloured
    ``color`` or the material's default colour."""
    return MeshPart(
        name=name, vertices=mesh[0], faces=mesh[1], semantic_id=ID[semantic], material=material,
        transparent=transparent, color=color if color is not None else COLOURS[material],
    )  # fmt: skip


def glass_part(name: str, mesh: Mesh, semantic: str) -> MeshPart:
    """A transparent glass part of class ``semantic``."""
    return part(name, mesh, semantic, "glass", transparent=True)


# --------------------------------------------------------------------------------------------
# builders: one function per sub-class family; each draws its sizes (and style) from ``rng``
# --------------------------------------------------------------------------------------------

Builder = Callable[[np.random.Generator], list[MeshPart]]


def uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    """One uniform draw in [lo, hi) as a Python float."""
    return float(rng.uniform(lo, hi))


def pick(rng: np.random.Generator, options: Sequence):
    """One uniformly drawn element of ``options``."""
    return options[int(rng.integers(len(options)))]
