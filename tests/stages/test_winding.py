"""Solid fill of meshes that are not watertight: generalized winding numbers (stages/voxelize).

Every volume is checked against a reference written here, independent of the code under test:

* the closed form (voxel centres strictly inside a box, per axis, multiplied), or
* column parity (``fill_interior``) of the same shape closed, or
* exact winding numbers by direct solid-angle sums (Van Oosterom and Strackee 1983) at voxel
  centres, vectorized numpy, chunked over the queries: :func:`solid_angle_winding`.

``winding_interior`` returns the voxels *not* touched by the mesh's surface (not in
``surface_voxels``) whose centre is inside; the solid the voxelizer writes is the union of the two.
So every comparison with a reference is between solids -- the interior with the surface voxels
added on both sides (:func:`solid`) -- or, equivalently, between interiors with the surface voxels
removed on both sides.

Frames and units: meshes and grids in metres in one frame (the grid frame, z up); voxel ``(i, j, k)``
has its centre at ``origin + (i, j, k) * voxel_size + voxel_size / 2`` and the C-order linear index
``(i * ny + j) * nz + k``. Grid origins are offset from every mesh lattice by a non-lattice amount,
so no voxel centre lies on a face (where the winding number is undefined).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import trimesh
from carlaocc.catalog.voxel_file import load_voxels
from carlaocc.pipeline.cli import app
from carlaocc.schemas import taxonomy
from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import AssetGeometry, MeshPart, SceneMesh
from carlaocc.stages.voxelize.breakdown import (
    FILL_REFERENCE_VOXEL,
    asset_fill,
    fill_breakdown,
)
from carlaocc.stages.voxelize.compose import voxelize_scene
from carlaocc.stages.voxelize.fill import fill_method, fills
from carlaocc.stages.voxelize.kernels import fill_interior, surface_voxels
from carlaocc.stages.voxelize.winding import (
    warmup,
    winding_interior,
    winding_numbers,
    winding_tree,
)
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from shared_data import require, shared_path
from typer.testing import CliRunner

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MESHES = shared_path("meshes")
BUILDING = taxonomy.by_name("Building").id
CAR = taxonomy.by_name("Car").id
ROAD = taxonomy.by_name("Road").id


@pytest.fixture(scope="module", autouse=True)
def _jit():
    warmup()  # compile / load the numba cache once, outside hypothesis' timing


# ------------------------------------------------------------------------------------------------
# references
# ------------------------------------------------------------------------------------------------


def solid_angle_winding(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                        pairs_per_chunk: int = 1 << 15) -> np.ndarray:
    """Exact generalized winding numbers (Q,) at ``points`` (Q, 3): the sum over every triangle of
    its signed solid angle seen from the point (Van Oosterom and Strackee), divided by 4 pi.

    Same units and frame for mesh and points (any: the result is invariant). 1 inside and 0
    outside a closed outward-oriented (counter-clockwise seen from outside) mesh.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    Q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(Q))
    if len(F) == 0:
        return out
    # corner coordinates as (1, M) rows: ax, ay, az, bx, ..., cz
    T = [V[F[:, m], d][None, :] for m in range(3) for d in range(3)]
    step = max(1, pairs_per_chunk // len(F))
    for s in range(0, len(Q), step):
        # corners relative to the query points: (n, M) per coordinate
        qx, qy, qz = (Q[s:s + step, d][:, None] for d in range(3))
        ax, ay, az = T[0] - qx, T[1] - qy, T[2] - qz
        bx, by, bz = T[3] - qx, T[4] - qy, T[5] - qz
        cx, cy, cz = T[6] - qx, T[7] - qy, T[8] - qz
        la = np.sqrt(ax * ax + ay * ay + az * az)
        lb = np.sqrt(bx * bx + by * by + bz * bz)
        lc = np.sqrt(cx * cx + cy * cy + cz * cz)
        # tan(omega / 2) = a . (b x c) / (|a||b||c| + (a.b)|c| + (b.c)|a| + (c.a)|b|)
        det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (bx * cx + by * cy + bz * cz) * la
               + (cx * ax + cy * ay + cz * az) * lb)
        # w = sum of omega / (4 pi) = sum of 2 atan2 / (4 pi)
        out[s:s + step] = np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi)
    return out


def centres(idx: np.ndarray, origin, voxel_size: float, shape) -> np.ndarray:
    """Voxel centres (K, 3) metres of linear C-order indices ``idx``."""
    ijk = np.stack(np.unravel_index(np.asarray(idx, dtype=np.int64), tuple(shape)), axis=1)
    return np.asarray(origin, dtype=np.float64) + (ijk + 0.5) * voxel_size


def bbox_voxels(vertices: np.ndarray, origin, voxel_size: float, shape) -> np.ndarray:
    """Sorted linear indices of every voxel whose centre lies in the vertices' (closed) bounding box."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    axes = []
    for d in range(3):
        c = origin[d] + (np.arange(shape[d]) + 0.5) * voxel_size
        axes.append(np.flatnonzero((c >= lo[d]) & (c <= hi[d])))
    I, J, K = np.meshgrid(*axes, indexing="ij")
    return np.sort(((I * shape[1] + J) * shape[2] + K).ravel())


def reference_interior(vertices, faces, origin, voxel_size, shape) -> np.ndarray:
    """Sorted linear indices of the voxels in the mesh's bounding box whose centre has an exact
    winding number above 0.5 (a solid-angle sum at every one of them)."""
    idx = bbox_voxels(vertices, origin, voxel_size, shape)
    w = solid_angle_winding(vertices, faces, centres(idx, origin, voxel_size, shape))
    return idx[w > 0.5]


def box_centres(lo, hi, origin, voxel_size, shape) -> np.ndarray:
    """Closed form: sorted linear indices of the voxels whose centre is strictly inside the
    axis-aligned box [lo, hi] (metres)."""
    axes = []
    for d in range(3):
        c = origin[d] + (np.arange(shape[d]) + 0.5) * voxel_size
        axes.append(np.flatnonzero((c > lo[d]) & (c < hi[d])))
    I, J, K = np.meshgrid(*axes, indexing="ij")
    return np.sort(((I * shape[1] + J) * shape[2] + K).ravel())


def solid(interior: np.ndarray, vertices: np.ndarray, faces: np.ndarray, origin, voxel_size: float,
          shape) -> np.ndarray:
    """Sorted linear indices of the solid a voxelizer writes: the mesh's surface voxels (metres,
    grid frame) and ``interior``."""
    return np.union1d(surface_voxels(vertices, faces, origin, voxel_size, shape), interior)


def iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two index sets."""
    union = len(np.union1d(a, b))
    return len(np.intersect1d(a, b)) / union if union else 1.0


# ------------------------------------------------------------------------------------------------
# meshes built in the tests
# ------------------------------------------------------------------------------------------------


def cell_shell(occupied: np.ndarray, cell: float, lo=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The closed, outward-oriented boundary of a union of lattice cells (``occupied`` (nx, ny, nz)
    bool; cell ``(i, j, k)`` is ``lo + [i, i+1] x [j, j+1] x [k, k+1] * cell``, metres): two
    triangles per exposed cell face, vertices shared on the lattice (watertight)."""
    occ = np.pad(np.asarray(occupied, dtype=bool), 1)
    corners, tris = [], []
    for d in range(3):
        u, v = (d + 1) % 3, (d + 2) % 3
        eu, ev = np.eye(3, dtype=np.int64)[u], np.eye(3, dtype=np.int64)[v]
        for sign in (1, -1):
            # 1. exposed faces: an occupied cell whose neighbour along sign * d is empty
            exposed = occ & ~np.roll(occ, -sign, axis=d)
            cells = np.argwhere(exposed) - 1  # back to unpadded cell indices
            base = cells + (sign > 0) * np.eye(3, dtype=np.int64)[d]
            # 2. the face's lattice corners, counter-clockwise seen from its outside (+d: u, v)
            quad = np.stack([base, base + eu, base + eu + ev, base + ev], axis=1)
            if sign < 0:
                quad = quad[:, ::-1]
            corners.append(quad.reshape(-1, 3))
            n0 = sum(len(c) for c in corners[:-1])
            q = n0 + 4 * np.arange(len(cells))[:, None]
            tris.append(np.concatenate([q + [0, 1, 2], q + [0, 2, 3]]))
    # 3. weld the corners by their lattice coordinates
    lattice, inverse = np.unique(np.concatenate(corners), axis=0, return_inverse=True)
    F = inverse.reshape(-1)[np.concatenate(tris)]
    return np.asarray(lo, dtype=np.float64) + lattice * cell, F


def face_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Unit normals (M, 3) of counter-clockwise faces."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def open_box(lo, hi, cells, drop: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An axis-aligned box [lo, hi] (metres) tessellated into ``cells`` (3,) per side, closed,
    and with the side ``drop`` (``"+x"``, ``"-z"``, ...) removed: (V, F_closed, F_open)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    V, F = cell_shell(np.ones(cells, dtype=bool), 1.0)
    V = lo + V / np.asarray(cells) * (hi - lo)
    axis, sign = "xyz".index(drop[1]), 1.0 if drop[0] == "+" else -1.0
    keep = face_normals(V, F)[:, axis] * sign < 0.5
    return V, F, F[keep]


def car_shell(cell: float = 0.1):
    """A car-like closed shell (metres, x forward, z up, wheels on z = 0): a 4.4 x 1.8 x 0.7 m
    body from z = 0.3 m and a 2.2 x 1.6 x 0.6 m cabin on it whose front and back slope inwards
    (windscreens), tessellated at ``cell``; and the same shell with four open wheel arches (side
    and bottom triangles around each wheel removed). Returns (V, F_closed, F_open)."""
    def n(metres: float) -> int:
        return round(metres / cell)  # metres to cells

    occ = np.zeros((n(4.4), n(1.8), n(1.3)), dtype=bool)
    occ[:, :, : n(0.7)] = True  # body
    occ[n(1.1): n(3.3), n(0.1): n(1.7), n(0.7):] = True  # cabin
    V, F = cell_shell(occ, cell, lo=(0.0, 0.0, 0.3))
    # slope the cabin: x shrinks towards its middle with the height above the body (up to 35 %)
    t = np.clip((V[:, 2] - 1.0) / 0.6, 0.0, 1.0)
    V[:, 0] = 2.2 + (V[:, 0] - 2.2) * (1.0 - 0.35 * t)
    # wheel arches: wheels of radius 0.38 m at x = 0.85 and 3.55 m, axle at z = 0.3 m, 0.3 m wide
    c = V[F].mean(axis=1)
    nrm = face_normals(V, F)
    arch = np.zeros(len(F), dtype=bool)
    for xw in (0.85, 3.55):
        side = (np.abs(nrm[:, 1]) > 0.9) & ((c[:, 0] - xw) ** 2 + (c[:, 2] - 0.3) ** 2 < 0.38 ** 2)
        bottom = (nrm[:, 2] < -0.9) & (np.abs(c[:, 0] - xw) < 0.38) & ((c[:, 1] < 0.3) | (c[:, 1] > 1.5))
        arch |= side | bottom
    return V, F, F[~arch]


def random_hull(seed: int, n_removed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random convex polyhedron (outward faces) around the unit cube's centre and the same with
    ``n_removed`` random faces deleted: (V, F_closed, F_open)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0.0, 1.0, (int(rng.integers(6, 30)), 3)) * rng.uniform(0.4, 1.5, 3)
    hull = trimesh.convex.convex_hull(pts)
    F = np.asarray(hull.faces, dtype=np.int64)
    keep = np.ones(len(F), dtype=bool)
    keep[rng.choice(len(F), size=min(n_removed, len(F) - 2), replace=False)] = False
    return np.asarray(hull.vertices, dtype=np.float64), F, F[keep]


def far_from_surface(V, F, points, margin: float = 1e-3) -> np.ndarray:
    """Mask of the points at least ``margin`` (same units) from every triangle."""
    T = V[F]
    P = np.repeat(points, len(F), axis=0)
    closest = trimesh.triangles.closest_point(np.tile(T, (len(points), 1, 1)), P)
    dist = np.linalg.norm(closest - P, axis=1).reshape(len(points), len(F))
    return dist.min(axis=1) >= margin


def welded(path) -> tuple[np.ndarray, np.ndarray]:
    """A mesh file as loaded by the standalone voxelizer: one mesh, coincident vertices welded."""
    m = trimesh.load(str(path), force="mesh", process=False)
    V = np.asarray(m.vertices, dtype=np.float64)
    F = np.asarray(m.faces, dtype=np.int64)
    uniq, inverse = np.unique(V, axis=0, return_inverse=True)
    return uniq, inverse.reshape(-1)[F]


def grid_around(V: np.ndarray, voxel_size: float, margin: int = 2, offset: float = 0.37):
    """(origin, shape) of a grid holding the vertices with ``margin`` voxels each side, its lattice
    offset from the vertices' minimum by ``offset`` voxel."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    origin = lo - (margin + offset) * voxel_size
    shape = tuple(int(s) for s in np.ceil((hi - origin) / voxel_size) + margin)
    return tuple(float(o) for o in origin), shape


# ------------------------------------------------------------------------------------------------
# known volumes
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("drop", ["+x", "-x", "+y", "-y", "+z", "-z"])
def test_cube_with_one_face_missing_fills_the_full_cube(drop):
    lo, hi = (0.13, 0.27, 0.31), (1.13, 1.27, 1.31)
    V, F_closed, F_open = open_box(lo, hi, (1, 1, 1), drop)
    assert len(F_open) == 10
    origin, voxel_size, shape = (0.0, 0.0, 0.0), 0.05, (30, 32, 34)
    want = box_centres(lo, hi, origin, voxel_size, shape)
    assert len(want) == 20 ** 3
    got = winding_interior(V, F_open, origin, voxel_size, shape)
    # the box's voxel centres but the ones the five faces' surface voxels already hold
    surf = surface_voxels(V, F_open, origin, voxel_size, shape)
    assert len(np.intersect1d(got, surf)) == 0
    assert len(np.intersect1d(want, surf)) > 0  # the layers under the faces at 1.13, 1.27, 1.31 m
    np.testing.assert_array_equal(got, np.setdiff1d(want, surf))
    # the very solid column parity gives the closed cube
    np.testing.assert_array_equal(solid(got, V, F_closed, origin, voxel_size, shape),
                                  solid(fill_interior(V, F_closed, origin, voxel_size, shape), V, F_closed, origin, voxel_size, shape))


def test_box_building_without_floor_is_the_full_box():
    lo, hi = (2.1, 1.3, 0.0), (14.1, 9.3, 9.0)  # 12 x 8 x 9 m, standing on z = 0
    V, F_closed, F_open = open_box(lo, hi, (12, 8, 9), "-z")
    grid = GridSpec(region_min=(0.07, -0.41, -1.13), region_max=(16.07, 11.59, 10.87), voxel_size=0.25)
    floorless = SceneMesh(V, F_open, BUILDING, 4, False, closed=False, name="building")
    closed = SceneMesh(V, F_closed, BUILDING, 4, False, closed=True, name="building")
    sem, inst = voxelize_scene([floorless], grid)  # auto: a building is filled, open -> winding
    # closed form: the box's voxel centres, plus the surface voxels of the walls and roof
    inside = box_centres(lo, hi, grid.origin, grid.voxel_size, grid.shape)
    assert len(inside) == 48 * 32 * 36
    walls = surface_voxels(V, F_open, grid.origin, grid.voxel_size, grid.shape)
    np.testing.assert_array_equal(np.flatnonzero(sem), np.union1d(walls, inside))
    assert (inst[sem > 0] == 4).all() and (sem[sem > 0] == BUILDING).all()
    # the watertight box by column parity: the same grid but for the floor's own surface voxels
    sem_closed = voxelize_scene([closed], grid)[0]
    floor = surface_voxels(V, F_closed[face_normals(V, F_closed)[:, 2] < -0.5], grid.origin, grid.voxel_size,
                           grid.shape)
    np.testing.assert_array_equal(np.setdiff1d(np.flatnonzero(sem_closed), floor),
                                  np.setdiff1d(np.flatnonzero(sem), floor))
    # the kernel alone: exactly the box's voxel centres off the walls and roof
    np.testing.assert_array_equal(winding_interior(V, F_open, grid.origin, grid.voxel_size, grid.shape),
                                  np.setdiff1d(inside, walls))


def test_car_shell_with_open_wheel_arches_keeps_its_volume():
    V, F_closed, F_open = car_shell()
    assert len(F_closed) - len(F_open) > 50  # four real holes
    origin, voxel_size, shape = (-0.313, -0.271, 0.157), 0.05, (94, 42, 36)
    closed = fill_interior(V, F_closed, origin, voxel_size, shape)
    # closed shell: parity agrees with the closed form of the untapered volume minus the slopes
    assert len(closed) * voxel_size ** 3 == pytest.approx(4.4 * 1.8 * 0.7 + 1.6 * 0.6 * 2.2 * (1 - 0.35 / 2), rel=0.02)
    # through the composer: a Car not known to be closed (winding) against the closed one (parity)
    grid = GridSpec(region_min=origin, region_max=tuple(o + n * voxel_size for o, n in zip(origin, shape)), voxel_size=voxel_size)
    sem_open, _ = voxelize_scene([SceneMesh(V, F_open, CAR, 1, False, closed=False)], grid)
    sem_closed, _ = voxelize_scene([SceneMesh(V, F_closed, CAR, 1, False, closed=True)], grid)
    n_open, n_closed = np.count_nonzero(sem_open), np.count_nonzero(sem_closed)
    assert abs(n_open - n_closed) <= 0.03 * n_closed
    # nothing out of the body: every occupied voxel is inside the closed shell or on its surface
    assert not (sem_open.astype(bool) & ~sem_closed.astype(bool)).any()
    # the kernel alone: the solid (with the open shell's surface voxels) within 3 % of the closed
    # shell's (with its own), and inside it
    got = solid(winding_interior(V, F_open, origin, voxel_size, shape), V, F_open, origin, voxel_size, shape)
    want = solid(closed, V, F_closed, origin, voxel_size, shape)
    assert abs(len(got) - len(want)) <= 0.03 * len(want)
    assert len(np.setdiff1d(got, want)) == 0
    # and the composer writes that solid
    np.testing.assert_array_equal(np.flatnonzero(sem_open), got)


@pytest.mark.parametrize("which", ["closed", "open"])
def test_a_grid_or_tile_cutting_the_mesh_fills_what_it_holds(which):
    V, F_closed, F_open = car_shell()
    F = F_closed if which == "closed" else F_open
    origin, voxel_size, shape = np.array((-0.313, -0.271, 0.157)), 0.05, (94, 42, 36)
    whole = winding_interior(V, F, origin, voxel_size, shape)
    # a grid on the same lattice holding the middle of the car only (x 1.19 - 3.19 m, y 0.13 -
    # 1.38 m, z 0.66 - 1.26 m: through the body and the cabin on every side): its interior is the
    # big grid's in it
    cut0, cut_shape = np.array([30, 8, 10]), (40, 25, 12)
    cut = winding_interior(V, F, origin + cut0 * voxel_size, voxel_size, cut_shape)
    ijk = np.stack(np.unravel_index(whole, shape), axis=1) - cut0
    held = ((ijk >= 0) & (ijk < cut_shape)).all(axis=1)
    assert held.sum() > 0.5 * np.prod(cut_shape)
    np.testing.assert_array_equal(cut, np.sort(np.ravel_multi_index(ijk[held].T, cut_shape)))
    # the composer's x-slabs (each a grid cutting the car) write what one slab does
    grid = GridSpec(region_min=tuple(origin), region_max=tuple(origin + np.asarray(shape) * voxel_size), voxel_size=voxel_size)
    mesh = SceneMesh(V, F, CAR, 1, False, closed=False)  # not known closed: winding either way
    slabs, one = voxelize_scene([mesh], grid, tile_x=9)[0], voxelize_scene([mesh], grid, tile_x=shape[0])[0]
    np.testing.assert_array_equal(slabs, one)
    np.testing.assert_array_equal(np.flatnonzero(one), solid(whole, V, F, tuple(origin), voxel_size, shape))


KENNEY = ["kenney-suburban/building-type-a.glb", "kenney-retro-urban/detail-bench.glb",
          "kenney-retro-urban/detail-light-single.glb", "kenney-retro-urban/detail-light-traffic.glb",
          "kenney-roads/construction-cone.glb", "kenney-roads/light-square.glb",
          "kenney-roads/road-crossroad.glb", "kenney-roads/road-straight.glb",
          "kenney-roads/sign-highway.glb", "cesium/CesiumMilkTruck.glb"]


@pytest.mark.parametrize("name", KENNEY)
def test_models_match_exact_winding_numbers_at_every_voxel_centre(name):
    V, F = welded(require(MESHES / name))
    # the model at a voxel size where its longest side spans 32 voxels and its thinnest 4 (the
    # same as scaling a tiny model up: winding numbers do not change under a uniform scale)
    extent = V.max(axis=0) - V.min(axis=0)
    voxel_size = float(min(extent.max() / 32, extent.min() / 4))
    origin, shape = grid_around(V, voxel_size)
    surf = surface_voxels(V, F, origin, voxel_size, shape)
    got = winding_interior(V, F, origin, voxel_size, shape)
    assert len(np.intersect1d(got, surf)) == 0  # the interior leaves the surface voxels out
    want = reference_interior(V, F, origin, voxel_size, shape)
    assert len(want) > 100
    # the solids: the surface voxels plus the interior on both sides
    got, want = np.union1d(got, surf), np.union1d(want, surf)
    assert iou(got, want) >= 0.95, (voxel_size, len(got), len(want), iou(got, want))


# ------------------------------------------------------------------------------------------------
# no leak
# ------------------------------------------------------------------------------------------------


def open_cup(radius=0.5, height=0.8, segments=48, rings=8):
    """A cylinder (metres) with a bottom at z = 0 and no top, outward faces: (V, F_open, F_closed)
    where the closed one has a lid at the rim."""
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    z = np.linspace(0.0, height, rings + 1)
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)
    V = np.concatenate([np.column_stack([ring, np.full(segments, zk)]) for zk in z]
                       + [[[0.0, 0.0, 0.0], [0.0, 0.0, height]]])
    bottom_c, top_c = len(V) - 2, len(V) - 1
    s = np.arange(segments)
    t = (s + 1) % segments
    walls = [np.concatenate([np.column_stack([r * segments + s, r * segments + t, (r + 1) * segments + t]),
                             np.column_stack([r * segments + s, (r + 1) * segments + t, (r + 1) * segments + s])])
             for r in range(rings)]
    bottom = np.column_stack([np.full(segments, bottom_c), t, s])  # normal -z
    lid = np.column_stack([np.full(segments, top_c), rings * segments + s, rings * segments + t])  # +z
    F_open = np.concatenate(walls + [bottom])
    return V, F_open, np.concatenate([F_open, lid])


def test_open_cup_fills_up_to_its_rim_and_not_beyond_its_wall():
    V, F_open, F_closed = open_cup()
    origin, voxel_size = (-0.6137, -0.6071, -0.0913), 0.04
    shape = (31, 31, 27)
    got = winding_interior(V, F_open, origin, voxel_size, shape)
    c = centres(got, origin, voxel_size, shape)
    assert c[:, 2].max() <= 0.8  # nothing above the rim
    assert c[:, 2].min() >= 0.0  # nor below the bottom
    assert np.hypot(c[:, 0], c[:, 1]).max() <= 0.5 + voxel_size  # nor beyond the wall (one voxel)
    # and the cup is full: within 3 % of the closed cup by column parity, both without the closed
    # cup's surface voxels (the open one has no lid's)
    surf = surface_voxels(V, F_closed, origin, voxel_size, shape)
    closed = np.setdiff1d(fill_interior(V, F_closed, origin, voxel_size, shape), surf)
    assert len(np.intersect1d(got, closed)) >= 0.97 * len(closed)


def square_sheet(half=1.0, n=20, height=lambda x, y: 0.0 * x):
    """A subdivided square [-half, half]^2 (metres) at z = ``height(x, y)``, faces up (+z)."""
    g = np.linspace(-half, half, n + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    V = np.column_stack([X.ravel(), Y.ravel(), height(X, Y).ravel()])
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + (n + 1), a + (n + 2), a + 1
    return V, np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


@pytest.mark.parametrize("tilt", [0.0, 0.3, 1.1])
def test_flat_plane_fills_nothing(tilt):
    V, F = square_sheet()
    V = V @ Rotation.from_rotvec([tilt, 0.4 * tilt, 0.0]).as_matrix().T + (0.0, 0.0, 0.2037)
    origin, voxel_size = (-1.5313, -1.5171, -1.3119), 0.05
    assert len(winding_interior(V, F, origin, voxel_size, (62, 62, 62))) == 0
    assert len(winding_interior(V, F[:, ::-1], origin, voxel_size, (62, 62, 62))) == 0  # either side up


def test_terrain_sheet_with_a_bump_fills_nothing_outside_its_bounding_box():
    V, F = square_sheet(2.0, 40, lambda x, y: 0.9 * np.exp(-(x ** 2 + y ** 2) / 0.35) + 0.05 * np.sin(2 * x))
    voxel_size = 0.05
    origin, shape = grid_around(V, voxel_size, margin=4)
    for faces in (F, F[:, ::-1]):  # faces up (inside below) and down
        got = winding_interior(V, faces, origin, voxel_size, shape)
        c = centres(got, origin, voxel_size, shape)
        assert ((c >= V.min(axis=0)) & (c <= V.max(axis=0))).all()
    # faces up: under the bump the sheet wraps the centres (w > 0.5 there), inside the box
    assert len(winding_interior(V, F, origin, voxel_size, shape)) > 1000


# ------------------------------------------------------------------------------------------------
# kernels: properties
# ------------------------------------------------------------------------------------------------


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n_removed=st.integers(0, 4))
def test_winding_numbers_agree_with_solid_angle_sums(seed, n_removed):
    V, _, F = random_hull(seed, n_removed)
    rng = np.random.default_rng(seed + 1)
    lo, hi = V.min(axis=0), V.max(axis=0)
    pts = rng.uniform(lo - 0.5, hi + 0.5, (60, 3))
    pts = pts[far_from_surface(V, F, pts)]
    want = solid_angle_winding(V, F, pts)
    tree = winding_tree(V, F)
    np.testing.assert_allclose(winding_numbers(tree, pts), want, atol=0.02)
    np.testing.assert_allclose(winding_numbers(tree, pts, beta=np.inf), want, atol=1e-9)
    # shift: the winding number at points + shift
    s = rng.normal(size=3) * 0.1
    np.testing.assert_allclose(winding_numbers(tree, pts - s, shift=s, beta=np.inf), want, atol=1e-9)


def test_winding_numbers_of_a_closed_mesh_are_0_and_1_many_queries():
    # enough queries for the threaded evaluator, with a tree many levels deep
    m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    rng = np.random.default_rng(7)
    pts = rng.uniform(-1.6, 1.6, (6000, 3))
    r = np.linalg.norm(pts, axis=1)
    pts = pts[np.abs(r - 1.0) > 0.05]
    w = winding_numbers(winding_tree(m.vertices, m.faces), pts)
    want = (np.linalg.norm(pts, axis=1) < 1.0).astype(float)
    np.testing.assert_allclose(w, want, atol=0.02)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n_removed=st.integers(0, 3))
def test_winding_numbers_invariant_under_rigid_motion(seed, n_removed):
    V, _, F = random_hull(seed, n_removed)
    rng = np.random.default_rng(seed + 2)
    pts = rng.uniform(V.min(axis=0) - 0.3, V.max(axis=0) + 0.3, (40, 3))
    pts = pts[far_from_surface(V, F, pts)]
    R = Rotation.random(random_state=seed % (2**31)).as_matrix()
    t = rng.normal(size=3) * 3.0

    def moved(X):
        return X @ R.T + t  # the rigid motion

    before, after = winding_tree(V, F), winding_tree(moved(V), F)
    np.testing.assert_allclose(winding_numbers(after, moved(pts), beta=np.inf),
                               winding_numbers(before, pts, beta=np.inf), atol=1e-9)
    # the approximations differ (another tree) but each is within 0.02 of the exact value
    np.testing.assert_allclose(winding_numbers(after, moved(pts)), winding_numbers(before, pts), atol=0.04)


@SETTINGS
@given(seed=st.integers(0, 2**32 - 1), n_removed=st.integers(0, 3),
       shift=st.tuples(*[st.integers(-6, 6)] * 3))
def test_winding_interior_invariant_under_integer_voxel_shifts(seed, n_removed, shift):
    V, _, F = random_hull(seed, n_removed)
    voxel_size, shape = 0.0625, (60, 60, 60)
    origin = np.array([-0.9, -0.85, -0.8])
    t = np.asarray(shift)
    base = winding_interior(V, F, origin, voxel_size, shape)
    # mesh and grid origin moved together: the same voxels
    np.testing.assert_array_equal(winding_interior(V + t * voxel_size, F, origin + t * voxel_size, voxel_size, shape), base)
    # the mesh alone moved: the voxels move by the shift
    moved = winding_interior(V + t * voxel_size, F, origin, voxel_size, shape)
    ijk = np.stack(np.unravel_index(base, shape), axis=1) + t
    np.testing.assert_array_equal(moved, np.sort(np.ravel_multi_index(ijk.T, shape)))
    assert len(np.intersect1d(base, surface_voxels(V, F, origin, voxel_size, shape))) == 0
    if n_removed == 0:  # closed: the very solid of column parity
        np.testing.assert_array_equal(solid(base, V, F, origin, voxel_size, shape),
                                      solid(fill_interior(V, F, origin, voxel_size, shape), V, F, origin, voxel_size, shape))


# ------------------------------------------------------------------------------------------------
# the fill rule and the breakdown
# ------------------------------------------------------------------------------------------------


def test_fill_rule_and_method():
    veg = taxonomy.by_name("Vegetation").id
    assert fills(CAR) and fills(BUILDING) and fills(taxonomy.by_name("Pole").id)
    assert not fills(ROAD) and not fills(taxonomy.by_name("Terrain").id) and not fills(veg, "crown")
    assert fills(veg, "Trunk_01") and not fills(CAR, fill="surface") and fills(ROAD, fill="solid")
    with pytest.raises(ValueError, match="fill mode"):
        fills(CAR, fill="hollow")
    assert [fill_method(False, True), fill_method(True, True), fill_method(True, False)] == \
        ["surface", "parity", "winding"]


def _box_scene(closed: bool):
    lo, hi = (0.3, 0.2, 0.0), (3.3, 2.2, 2.5)
    V, F_closed, F_open = open_box(lo, hi, (6, 4, 5), "-z")
    grid = GridSpec(region_min=(-0.13, -0.27, -0.41), region_max=(3.87, 2.73, 3.09), voxel_size=0.1)
    mesh = SceneMesh(V, F_closed if closed else F_open, BUILDING, 1, False, closed=closed)
    return mesh, grid, len(box_centres(lo, hi, grid.origin, grid.voxel_size, grid.shape))


def test_breakdown_watertight_box_has_no_hole_fill_floorless_box_does():
    closed, grid, inside = _box_scene(True)
    b = fill_breakdown([closed], grid)
    assert b.from_holes == 0 and b.filled > 0.8 * inside
    floorless, _, _ = _box_scene(False)
    h = fill_breakdown([floorless], grid)
    # the same voxels (the floor's layer is surface in one, filled in the other), but every
    # filled voxel was reached through the open floor
    assert h.total == b.total and h.from_holes == h.filled > b.filled
    assert h.surface < b.surface  # no floor voxels


def test_breakdown_counts_add_up_with_the_composer():
    floorless, grid, _ = _box_scene(False)
    V, F_open, _ = open_cup(radius=0.4, height=0.6)
    cup = SceneMesh(V + (1.8, 1.2, 2.6), F_open, taxonomy.by_name("Static").id, 0, True, closed=False)
    road = SceneMesh(*square_sheet(2.0, 8), ROAD, 0, True, closed=False)
    meshes = [floorless, cup, road]
    for fill in ("auto", "solid", "surface"):
        b = fill_breakdown(meshes, grid, fill)
        surface = np.count_nonzero(voxelize_scene(meshes, grid, fill="surface")[0])
        total = np.count_nonzero(voxelize_scene(meshes, grid, fill=fill)[0])
        assert b.surface == surface and b.total == total
        assert 0 <= b.from_holes <= b.filled
        assert (b.filled == 0) == (fill == "surface")


def test_asset_fill_methods_and_hole_voxels():
    lo, hi = (-1.0, -1.0, 0.0), (1.0, 1.0, 1.6)
    V, F_closed, F_open = open_box(lo, hi, (4, 4, 4), "-z")

    def asset(F, closed):
        return AssetGeometry("box", (MeshPart("body", V, F, BUILDING),), (closed,))

    watertight, floorless = asset_fill(asset(F_closed, True)), asset_fill(asset(F_open, False))
    assert watertight.method == "parity" and watertight.from_holes == 0
    assert floorless.method == "winding" and floorless.from_holes == floorless.filled > 0
    voxel_size = FILL_REFERENCE_VOXEL  # the 2 m box spans far fewer than FILL_REFERENCE_MAX_EDGE voxels
    assert watertight.voxel_size == floorless.voxel_size == voxel_size
    # the asset's grid is snapped to its bottom (z = 0): the floor on a lattice plane also marks
    # the layer under it, of which the open box keeps only the walls' rim (two voxels each side
    # of the wall planes, also on the lattice): (2 m / vs - 2)^2 voxels less
    n = round(2.0 / voxel_size) - 2
    assert watertight.voxels - floorless.voxels == n * n
    road = AssetGeometry("road", (MeshPart("road", V, F_open, ROAD),), (False,))
    assert asset_fill(road).method == "surface" and asset_fill(road).filled == 0


# ------------------------------------------------------------------------------------------------
# CLI
# ------------------------------------------------------------------------------------------------

SUMMARY = re.compile(r"voxels: ([\d,]+) surface, ([\d,]+) filled \(([^)]*)\), ([\d,]+) of them from hole handling")


def test_cli_voxelize_open_building_auto_and_solid_fill_its_interior(tmp_path):
    glb = require(MESHES / "kenney-suburban/building-type-a.glb")
    cli = CliRunner()
    counts, lines = {}, {}
    for fill in ("surface", "auto", "solid"):
        out = tmp_path / f"{fill}.npz"
        r = cli.invoke(app, ["voxelize", str(glb), "--class", "Building", "--voxel-size", "0.05", "--fill", fill,
                              "--out", str(out)])
        assert r.exit_code == 0, r.output
        counts[fill] = len(load_voxels(out))  # the occupied voxels
        m = SUMMARY.search(r.output)
        assert m, r.output
        lines[fill] = [int(g.replace(",", "")) for g in m.group(1, 2, 4)] + [m.group(3)]
    surface, filled, holes, how = lines["surface"]
    assert counts["surface"] == surface and filled == holes == 0 and how == "no mesh filled"
    for fill in ("auto", "solid"):
        surface, filled, holes, how = lines[fill]
        assert counts[fill] > counts["surface"] and counts[fill] == surface + filled
        assert how == "1 by winding" and 0 <= holes <= filled  # the model is not watertight
    assert counts["auto"] == counts["solid"]
