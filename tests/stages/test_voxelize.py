"""Voxelization kernels and elevation-ordered composition (stages/voxelize).

Coordinates in the property tests are dyadic (multiples of 1/64 m with power-of-two voxel sizes),
so the metres -> voxel-units map is exact and shifts by whole voxels are exact too.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.stages.voxelize import elevation_order, fill_interior, surface_voxels, voxelize_scene
from carlaocc.stages.voxelize.compose import composition_plan
from carlaocc.stages.voxelize.kernels import to_voxel_units, warmup

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module", autouse=True)
def _jit():
    warmup()  # compile / load the numba cache once, outside hypothesis' timing


# ------------------------------------------------------------------------------------------------
# brute-force reference: the same separating-axis test, vectorized over every voxel of the grid
# ------------------------------------------------------------------------------------------------


def _ref_surface_one(tri: np.ndarray, shape) -> np.ndarray:
    """Linear indices of the voxels (closed unit boxes, voxel units) a triangle (3, 3) touches.

    Plain per-voxel 13-axis test, no culling, evaluated in the frame the kernel documents."""
    nx, ny, nz = shape
    I, J, K = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    c = np.stack([I.ravel() + 0.5, J.ravel() + 0.5, K.ravel() + 0.5], axis=1)  # (N, 3) centres
    h = 0.5
    # the kernel's frame: cyclic axis order ending with the normal's dominant axis (x wins ties)
    a, b, cc = tri
    n = [
        (b[1] - a[1]) * (cc[2] - b[2]) - (b[2] - a[2]) * (cc[1] - b[1]),
        (b[2] - a[2]) * (cc[0] - b[0]) - (b[0] - a[0]) * (cc[2] - b[2]),
        (b[0] - a[0]) * (cc[1] - b[1]) - (b[1] - a[1]) * (cc[0] - b[0]),
    ]
    an = np.abs(n)
    d = 0 if (an[0] >= an[1] and an[0] >= an[2]) else (1 if an[1] >= an[2] else 2)
    perm = [[1, 2, 0], [2, 0, 1], [0, 1, 2]][d]
    tri, c = tri[:, perm], c[:, perm]
    v0, v1, v2 = tri[0] - c, tri[1] - c, tri[2] - c  # box centred at the origin

    def separated(p0, p1, p2, r):
        return (np.minimum(p0, np.minimum(p1, p2)) > r) | (np.maximum(p0, np.maximum(p1, p2)) < -r)

    sep = np.zeros(len(c), dtype=bool)
    for a in range(3):  # box axes
        sep |= separated(v0[:, a], v1[:, a], v2[:, a], h)
    # edges and normal from the absolute vertices, every vertex projected on every axis
    e0, e1, e2 = tri[1] - tri[0], tri[2] - tri[1], tri[0] - tri[2]
    nx_ = e0[1] * e1[2] - e0[2] * e1[1]
    ny_ = e0[2] * e1[0] - e0[0] * e1[2]
    nz_ = e0[0] * e1[1] - e0[1] * e1[0]
    r = h * (abs(nx_) + abs(ny_) + abs(nz_))
    proj = [nx_ * v[:, 0] + ny_ * v[:, 1] + nz_ * v[:, 2] for v in (v0, v1, v2)]
    sep |= separated(*proj, r)  # triangle normal
    for e in (e0, e1, e2):  # edge x box axis
        ex, ey, ez = e[0], e[1], e[2]
        x0, y0, z0 = v0[:, 0], v0[:, 1], v0[:, 2]
        x1, y1, z1 = v1[:, 0], v1[:, 1], v1[:, 2]
        x2, y2, z2 = v2[:, 0], v2[:, 1], v2[:, 2]
        r = h * (np.abs(ez) + np.abs(ey))
        sep |= separated(-ez * y0 + ey * z0, -ez * y1 + ey * z1, -ez * y2 + ey * z2, r)
        r = h * (np.abs(ez) + np.abs(ex))
        sep |= separated(ez * x0 - ex * z0, ez * x1 - ex * z1, ez * x2 - ex * z2, r)
        r = h * (np.abs(ey) + np.abs(ex))
        sep |= separated(-ey * x0 + ex * y0, -ey * x1 + ex * y1, -ey * x2 + ex * y2, r)
    return np.flatnonzero(~sep)


def _ref_surface(V, F, origin, voxel_size, shape) -> np.ndarray:
    P = to_voxel_units(V, origin, voxel_size)
    hits = [_ref_surface_one(P[f], shape) for f in np.asarray(F)]
    return np.unique(np.concatenate(hits)) if hits else np.zeros(0, dtype=np.int64)


# ------------------------------------------------------------------------------------------------
# strategies
# ------------------------------------------------------------------------------------------------

SHAPE = (7, 6, 5)
ORIGIN = (-0.5, 0.25, -1.0)
VS = 0.5


def dyadic(lo: float, hi: float):
    """Multiples of 1/64 in [lo, hi] (small integers so ties and degeneracies are common)."""
    return st.integers(int(lo * 64), int(hi * 64)).map(lambda n: n / 64.0)


def coarse(lo: float, hi: float):
    """Multiples of 1/4: lands on voxel faces, edges and corners, and makes collinear triangles."""
    return st.integers(int(lo * 4), int(hi * 4)).map(lambda n: n / 4.0)


def point(coord):
    # span the grid ([-0.5, 3.0] x [0.25, 3.25] x [-1, 1.5] m) and a margin beyond it
    return st.tuples(coord(-1.5, 4.0), coord(-0.75, 4.25), coord(-2.0, 2.5))


def triangles(coord, max_tris=6):
    return st.lists(st.tuples(point(coord), point(coord), point(coord)), min_size=1, max_size=max_tris).map(
        lambda tris: (np.asarray(tris, dtype=np.float64).reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3))
    )


any_triangles = st.one_of(triangles(dyadic), triangles(coarse))


# ------------------------------------------------------------------------------------------------
# surface kernel
# ------------------------------------------------------------------------------------------------


@SETTINGS
@given(mesh=any_triangles)
def test_surface_matches_bruteforce_sat(mesh):
    V, F = mesh
    got = surface_voxels(V, F, ORIGIN, VS, SHAPE)
    assert got.dtype == np.int64
    assert np.all(np.diff(got) > 0)  # sorted, unique
    np.testing.assert_array_equal(got, _ref_surface(V, F, ORIGIN, VS, SHAPE))


@settings(max_examples=40, deadline=None)
@given(
    tri=st.lists(st.floats(-3.0, 6.0, allow_nan=False), min_size=9, max_size=9),
    voxel_size=st.floats(0.11, 0.9),
    ox=st.floats(-1.0, 1.0),
)
def test_surface_matches_bruteforce_on_arbitrary_floats(tri, voxel_size, ox):
    V = np.asarray(tri).reshape(3, 3)
    F = np.array([[0, 1, 2]])
    origin = (ox, -0.3 * ox, 0.1)
    shape = (9, 8, 7)
    np.testing.assert_array_equal(surface_voxels(V, F, origin, voxel_size, shape), _ref_surface(V, F, origin, voxel_size, shape))


@SETTINGS
@given(mesh=any_triangles, shift=st.tuples(st.integers(-3, 3), st.integers(-3, 3), st.integers(-3, 3)))
def test_surface_translation_invariance(mesh, shift):
    V, F = mesh
    # a grid so large the mesh never reaches its border, before or after the shift
    shape = (40, 40, 40)
    origin = (-10.0, -10.0, -10.0)
    a = np.array(np.unravel_index(surface_voxels(V, F, origin, VS, shape), shape)).T
    b = np.array(np.unravel_index(surface_voxels(V + np.array(shift) * VS, F, origin, VS, shape), shape)).T
    np.testing.assert_array_equal(a + np.array(shift), b)


@SETTINGS
@given(mesh=any_triangles)
def test_surface_covers_vertices_and_centroids(mesh):
    V, F = mesh
    marked = set(surface_voxels(V, F, ORIGIN, VS, SHAPE).tolist())
    P = to_voxel_units(V, ORIGIN, VS)
    n = np.array(SHAPE)

    def voxel_of(p):
        ijk = np.floor(p).astype(int)
        return int(np.ravel_multi_index(tuple(ijk), SHAPE)) if np.all((ijk >= 0) & (ijk < n)) else None

    for f in F:
        for p in list(P[f]) + [P[f].mean(axis=0)]:  # the corners, then the centroid
            lin = voxel_of(p)
            if lin is not None:
                assert lin in marked


def test_surface_degenerate_triangles_mark_their_point_and_segment():
    shape = (4, 4, 4)
    # a point in the middle of voxel (1, 2, 3)
    pt = np.array([[1.5, 2.5, 3.5]] * 3)
    assert surface_voxels(pt, [[0, 1, 2]], (0, 0, 0), 1.0, shape).tolist() == [
        int(np.ravel_multi_index((1, 2, 3), shape))
    ]
    # a segment along x through voxel centres of row (j, k) = (2, 1), from x = 0.5 to 2.5
    seg = np.array([[0.5, 2.5, 1.5], [2.5, 2.5, 1.5], [1.5, 2.5, 1.5]])
    got = surface_voxels(seg, [[0, 1, 2]], (0, 0, 0), 1.0, shape)
    want = [int(np.ravel_multi_index((i, 2, 1), shape)) for i in range(3)]
    assert got.tolist() == want
    # a diagonal segment agrees with the brute force
    seg = np.array([[0.2, 0.3, 0.1], [3.7, 2.9, 3.3], [1.95, 1.6, 1.7]])
    np.testing.assert_array_equal(
        surface_voxels(seg, [[0, 1, 2]], (0, 0, 0), 1.0, shape), _ref_surface(seg, [[0, 1, 2]], (0, 0, 0), 1.0, shape)
    )


def test_surface_face_on_voxel_boundary_marks_both_sides():
    # a square at z = 2 exactly (a voxel face): closed boxes on both sides touch it
    V = np.array([[0.5, 0.5, 2.0], [2.5, 0.5, 2.0], [2.5, 2.5, 2.0], [0.5, 2.5, 2.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    k = np.unravel_index(surface_voxels(V, F, (0, 0, 0), 1.0, (4, 4, 4)), (4, 4, 4))[2]
    assert set(k.tolist()) == {1, 2}


def test_surface_outside_grid_and_empty():
    V = np.array([[10.0, 10.0, 10.0], [11.0, 10.0, 10.0], [10.0, 11.0, 10.0]])
    assert len(surface_voxels(V, [[0, 1, 2]], (0, 0, 0), 1.0, (4, 4, 4))) == 0
    assert len(surface_voxels(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), (0, 0, 0), 1.0, (4, 4, 4))) == 0
    # a NaN triangle is dropped, not propagated
    V = np.array([[np.nan, 0.5, 0.5], [1.5, 0.5, 0.5], [0.5, 1.5, 0.5]])
    assert len(surface_voxels(V, [[0, 1, 2]], (0, 0, 0), 1.0, (4, 4, 4))) == 0
    with pytest.raises(ValueError):
        surface_voxels(V, [[0, 1, 3]], (0, 0, 0), 1.0, (4, 4, 4))


def test_surface_large_triangle_crossing_the_grid_is_clipped():
    # one huge slanted triangle through a small grid: the clipped sweep equals the brute force
    V = np.array([[-40.0, -35.0, -3.0], [60.0, -20.0, 9.0], [-10.0, 70.0, 4.0]])
    np.testing.assert_array_equal(
        surface_voxels(V, [[0, 1, 2]], (0, 0, 0), 0.5, (12, 10, 8)), _ref_surface(V, [[0, 1, 2]], (0, 0, 0), 0.5, (12, 10, 8))
    )


# ------------------------------------------------------------------------------------------------
# fill kernel
# ------------------------------------------------------------------------------------------------


def _box_mesh(lo, hi):
    """Axis-aligned closed box with corners exactly lo / hi (trimesh's triangulation, outward)."""
    unit = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    V = np.where(unit.vertices > 0, np.asarray(hi, float), np.asarray(lo, float))
    return V, np.asarray(unit.faces)


def _centres_in(lo, hi, n, closed_low: bool):
    """Count of centres c + 0.5 (c in [0, n)) in [lo, hi) (closed_low) or (lo, hi]."""
    c = np.arange(n) + 0.5
    return int(np.sum((c >= lo) & (c < hi))) if closed_low else int(np.sum((c > lo) & (c <= hi)))


@SETTINGS
@given(a=st.one_of(point(dyadic), point(coarse)), b=st.one_of(point(dyadic), point(coarse)))
def test_fill_box_equals_analytic_centre_count(a, b):
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    V, F = _box_mesh(lo, hi)
    got = fill_interior(V, F, ORIGIN, VS, SHAPE)
    assert np.all(np.diff(got) > 0)
    plo, phi = to_voxel_units(np.array([lo, hi]), ORIGIN, VS)
    # documented ties: column perturbed to (x - eps^2, y + eps) -> x in (lo, hi], y in [lo, hi);
    # along z, z0 <= zc < z1
    want = (
        _centres_in(plo[0], phi[0], SHAPE[0], closed_low=False)
        * _centres_in(plo[1], phi[1], SHAPE[1], closed_low=True)
        * _centres_in(plo[2], phi[2], SHAPE[2], closed_low=True)
    )
    assert len(got) == want


@settings(max_examples=10, deadline=None)
@given(
    rot=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
    centre=st.tuples(st.floats(1.8, 2.2), st.floats(1.8, 2.2), st.floats(1.8, 2.2)),
)
def test_fill_icosphere_close_to_volume_and_exact_away_from_surface(rot, centre):
    r = 1.5
    voxel_size = 0.1
    m = trimesh.creation.icosphere(subdivisions=3, radius=r)
    q = np.asarray(rot) / np.linalg.norm(rot)
    R = trimesh.transformations.quaternion_matrix(q)[:3, :3]
    V = m.vertices @ R.T + np.asarray(centre)
    shape = (40, 40, 40)
    got = fill_interior(V, m.faces, (0, 0, 0), voxel_size, shape)
    # volume: the voxel count approximates the mesh's volume, and the sphere's 4/3 pi r^3
    assert abs(len(got) * voxel_size**3 - m.volume) / m.volume < 0.02
    assert abs(len(got) * voxel_size**3 - 4 / 3 * math.pi * r**3) / (4 / 3 * math.pi * r**3) < 0.03
    # exact away from the surface: icosphere lies between radius r*cos(max facet angle) and r
    ijk = np.array(np.unravel_index(np.arange(np.prod(shape)), shape)).T
    dist = np.linalg.norm((ijk + 0.5) * voxel_size - np.asarray(centre), axis=1)
    inside = np.zeros(np.prod(shape), dtype=bool)
    inside[got] = True
    assert inside[dist < 0.97 * r].all()
    assert not inside[dist > r].any()


def test_fill_columns_through_vertices_and_edges():
    # octahedron whose apexes sit exactly on a column centre, and whose equatorial edges pass
    # exactly over column centres: shared vertices/edges must be counted once
    c = np.array([2.5, 2.5, 2.5])
    r = 2.0
    V = np.array([c + d for d in ([r, 0, 0], [-r, 0, 0], [0, r, 0], [0, -r, 0], [0, 0, r], [0, 0, -r])])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    got = fill_interior(V, F, (0, 0, 0), 1.0, (5, 5, 5))
    ijk = np.array(np.unravel_index(got, (5, 5, 5))).T
    l1 = np.abs(ijk + 0.5 - c).sum(axis=1)
    assert (l1 <= r).all()
    # every centre strictly inside is found (the apex column included)
    allc = np.array(np.unravel_index(np.arange(125), (5, 5, 5))).T
    strict = allc[np.abs(allc + 0.5 - c).sum(axis=1) < r]
    assert {tuple(x) for x in strict} <= {tuple(x) for x in ijk}
    assert (2, 2, 2) in {tuple(x) for x in ijk}


def test_fill_mesh_beyond_grid_and_outside():
    # a box far taller than the grid: crossings outside the grid still set the parity inside it
    V, F = _box_mesh((0.2, 0.2, -50.0), (1.8, 1.8, 50.0))
    got = fill_interior(V, F, (0, 0, 0), 1.0, (3, 3, 3))
    assert len(got) == 2 * 2 * 3  # columns x, y in {0.5, 1.5}, every z
    # a box entirely outside fills nothing
    V, F = _box_mesh((5.0, 5.0, 5.0), (6.0, 6.0, 6.0))
    assert len(fill_interior(V, F, (0, 0, 0), 1.0, (3, 3, 3))) == 0
    assert len(fill_interior(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), (0, 0, 0), 1.0, (3, 3, 3))) == 0


# ------------------------------------------------------------------------------------------------
# composition
# ------------------------------------------------------------------------------------------------

ROAD, BUILDING, FENCE, TERRAIN, CAR = 1, 3, 5, 10, 14


def _grid(voxel_size=0.25):
    return GridSpec(region_min=(-4.0, -4.0, -1.0), region_max=(4.0, 4.0, 3.0), voxel_size=voxel_size)


def _plane(z, half=3.5, sub=2):
    """Open horizontal square at height z (metres), subdivided."""
    m = trimesh.creation.box(extents=(2 * half, 2 * half, 0.0))
    top = m.vertices[:, 2] >= 0
    V = m.vertices.copy()
    V[:, 2] = z
    F = np.asarray([f for f in m.faces if top[f].all()])
    V, F = trimesh.remesh.subdivide_to_size(V, F, max_edge=2 * half / sub)
    return np.asarray(V), np.asarray(F)


def _box(lo, hi, sem, inst, stuff=False):
    V, F = _box_mesh(lo, hi)
    return SceneMesh(V, F, semantic_id=sem, instance_id=inst, is_stuff=stuff, closed=True)


def _stuff(V, F, sem):
    return SceneMesh(V, F, semantic_id=sem, instance_id=0, is_stuff=True, closed=False)


def test_empty_scene_is_all_free():
    grid = _grid()
    sem, inst = voxelize_scene([], grid)
    assert sem.shape == inst.shape == grid.shape
    assert sem.dtype == np.uint8 and inst.dtype == np.uint32
    assert not sem.any() and not inst.any()


def test_mesh_outside_grid_marks_nothing():
    grid = _grid()
    far = _box((20.0, 20.0, 0.0), (21.0, 21.0, 1.0), CAR, 5)
    sem, inst = voxelize_scene([far], grid)
    assert not sem.any() and not inst.any()
    assert elevation_order([far], grid) == []


def test_car_on_road_overwrites_the_shared_voxels():
    grid = _grid()
    road = _stuff(*_plane(0.0), ROAD)
    car = _box((-1.0, -0.5, 0.0), (1.0, 0.5, 1.5), CAR, 7)
    for meshes in ([road, car], [car, road]):  # input order does not matter
        sem, inst = voxelize_scene(meshes, grid)
        # z = 0 m is the voxel face between k = 3 and k = 4 (origin -1 m, 0.25 m voxels)
        P = to_voxel_units(np.array([[-1.0, -0.5, 0.0], [1.0, 0.5, 1.5]]), grid.origin, grid.voxel_size)
        (i0, j0, _), (i1, j1, k1) = P.astype(int)
        # under the car, the road layer is the car's (surface + filled interior)
        assert (sem[i0 + 1 : i1 - 1, j0 + 1 : j1 - 1, 3:k1] == CAR).all()
        assert (inst[i0 + 1 : i1 - 1, j0 + 1 : j1 - 1, 3:k1] == 7).all()
        # away from the car the road remains, as stuff (instance 0)
        assert (sem[0:i0 - 1, :, 3:5][sem[0:i0 - 1, :, 3:5] > 0] == ROAD).all()
        assert sem[2, 2, 3] == ROAD and inst[2, 2, 3] == 0
    assert elevation_order([road, car], grid) == [0, 1]
    assert elevation_order([car, road], grid) == [1, 0]


@pytest.mark.parametrize("tile", [1, 3, 64])
def test_higher_stuff_takes_a_things_voxels_with_instance_zero(tile):
    # a stuff plane above a car's floor is written after the car: where it crosses the car, its
    # voxels are stuff with instance 0, in every tile (stuff writes no instance ids into a tile
    # no thing has painted, and must where one has); tiles without the car hold no instance at all
    grid = _grid()
    car = _box((-1.0, -0.5, 0.0), (1.0, 0.5, 1.5), CAR, 7)
    shelf = _stuff(*_plane(0.55), ROAD)  # z = 0.55 m: inside voxel layer k = 6 (origin -1 m, 0.25 m)
    sem, inst = voxelize_scene([shelf, car], grid, tile_x=tile)
    assert elevation_order([shelf, car], grid) == [1, 0]
    P = to_voxel_units(np.array([[-1.0, -0.5, 0.0]]), grid.origin, grid.voxel_size)
    i0, j0, _ = P[0].astype(int)
    inside = (slice(i0 + 1, i0 + 7), slice(j0 + 1, j0 + 3), 6)  # the shelf's layer within the car
    assert (sem[inside] == ROAD).all() and (inst[inside] == 0).all()
    assert (sem[i0 + 1:i0 + 7, j0 + 1:j0 + 3, 7] == CAR).all()  # the car's interior above the shelf
    assert (inst[sem == CAR] == 7).all() and (inst[sem != CAR] == 0).all()


def test_building_wins_over_terrain():
    grid = _grid()
    Vt, Ft = _plane(0.0)
    Vt[:, 2] += 0.3 * np.sin(Vt[:, 0])  # gently hilly terrain around z = 0
    terrain = _stuff(Vt, Ft, TERRAIN)
    building = _box((0.0, 0.0, 0.0), (2.0, 2.0, 2.5), BUILDING, 0, stuff=True)
    sem, _ = voxelize_scene([building, terrain], grid)
    P = to_voxel_units(np.array([[0.0, 0.0, 0.0], [2.0, 2.0, 2.5]]), grid.origin, grid.voxel_size)
    (i0, j0, k0), (i1, j1, k1) = P.astype(int)
    # the building's walls win over the terrain wherever they meet
    assert (sem[i0, j0 : j1 + 1, k0 : k1 + 1] == BUILDING).all()
    assert elevation_order([building, terrain], grid) == [1, 0]
    # Building is a volumetric class: filled even when given as stuff
    assert sem[i0 + 3, j0 + 3, k0 + 4] == BUILDING
    # a fence (a thin/open class) given as the same closed box stays a surface under auto
    fence = _box((0.0, 0.0, 0.0), (2.0, 2.0, 2.5), FENCE, 0, stuff=True)
    sem, _ = voxelize_scene([fence, terrain], grid)
    assert sem[i0 + 3, j0 + 3, k0 + 4] == 0 and sem[i0, j0 + 3, k0 + 4] == FENCE


def test_stuff_of_one_class_is_fused_and_things_are_not():
    grid = _grid()
    road_a = _stuff(*_plane(0.0, half=1.0), ROAD)
    road_b = SceneMesh(*_plane(0.5, half=1.0), semantic_id=ROAD, instance_id=99, is_stuff=True, closed=False)
    car = _box((-1.0, -0.5, 0.0), (1.0, 0.5, 1.5), CAR, 7)
    plan = composition_plan([road_a, car, road_b], grid)
    assert [p.sources for p in plan] == [(0, 2), (1,)]
    assert plan[0].instance_id == 0 and not plan[0].fill and plan[1].fill
    assert len(plan[0].faces) == len(road_a.faces) + len(road_b.faces)
    assert elevation_order([road_a, car, road_b], grid) == [0, 2, 1]
    sem, inst = voxelize_scene([road_a, road_b], grid)
    assert (inst[sem == ROAD] == 0).all()


def test_single_mesh_surface_parity_and_winding():
    grid = _grid()
    m = trimesh.creation.icosphere(subdivisions=2, radius=1.3)
    mesh = SceneMesh(m.vertices, m.faces, semantic_id=20, instance_id=3, is_stuff=False, closed=False)
    sem, inst = voxelize_scene([mesh], grid, fill="surface")
    want = surface_voxels(m.vertices, m.faces, grid.origin, grid.voxel_size, grid.shape)
    np.testing.assert_array_equal(np.flatnonzero(sem), want)
    assert (inst.reshape(-1)[want] == 3).all()
    # closed: surface plus the inside by column parity
    closed = SceneMesh(m.vertices, m.faces, semantic_id=20, instance_id=3, is_stuff=False, closed=True)
    sem2, _ = voxelize_scene([closed], grid)
    fill = fill_interior(m.vertices, m.faces, grid.origin, grid.voxel_size, grid.shape)
    np.testing.assert_array_equal(np.flatnonzero(sem2), np.union1d(want, fill))
    # not known to be closed: the inside by winding numbers, the same voxels on a closed sphere
    sem3, _ = voxelize_scene([mesh], grid)
    np.testing.assert_array_equal(sem3, sem2)


def test_culling_keeps_stuff_inside_region_only_and_sets_its_elevation():
    grid = _grid()
    # a road that dips to -20 m far outside the region: after culling its key is the local height
    V, F = _plane(0.0, half=30.0, sub=30)
    V[np.abs(V[:, 0]) > 10, 2] = -20.0
    road = _stuff(V, F, ROAD)
    (p,) = composition_plan([road], grid)
    assert p.key[0] > -1.0 and len(p.faces) < len(F)


def test_parallel_and_serial_kernels_agree(monkeypatch):
    import carlaocc.stages.voxelize.kernels as K

    m = trimesh.creation.icosphere(subdivisions=4, radius=1.7)
    V = m.vertices + np.array([2.1, 2.0, 1.9])
    shape = (40, 41, 42)
    monkeypatch.setattr(K, "PARALLEL_MIN_TRIANGLES", 10**9)
    monkeypatch.setattr(K, "PARALLEL_MIN_VOXELS", 10**12)
    serial = surface_voxels(V, m.faces, (0, 0, 0), 0.1, shape)
    monkeypatch.setattr(K, "PARALLEL_MIN_TRIANGLES", 0)
    monkeypatch.setattr(K, "PARALLEL_MIN_VOXELS", 0)
    parallel = surface_voxels(V, m.faces, (0, 0, 0), 0.1, shape)
    np.testing.assert_array_equal(serial, parallel)
    assert len(serial) > 1000


# ------------------------------------------------------------------------------------------------
# known answers, tiles, fill modes, rotated frames
# ------------------------------------------------------------------------------------------------

from shared_data import require, shared_path  # noqa: E402

TESTDATA_MESHES = shared_path("meshes")


def _unit_cube(closed=True, stuff=False):
    m = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    return SceneMesh(m.vertices, m.faces, semantic_id=ROAD if stuff else CAR, instance_id=0 if stuff else 1,
                     is_stuff=stuff, closed=closed)


def test_unit_cube_known_answer_602_surface_1331_filled():
    # the known answer: 1 m cube at the origin, 0.1 m voxels, grid origin (-0.55,)*3
    grid = GridSpec(region_min=(-0.55,) * 3, region_max=(0.75,) * 3, voxel_size=0.1)
    assert grid.shape == (13, 13, 13)
    sem, _ = voxelize_scene([_unit_cube(closed=False)], grid, fill="surface")
    assert np.count_nonzero(sem) == 602
    # filled: by parity when known closed, by winding numbers otherwise -- the same 1331
    assert np.count_nonzero(voxelize_scene([_unit_cube(closed=False)], grid)[0]) == 1331
    sem, inst = voxelize_scene([_unit_cube(closed=True)], grid)
    assert np.count_nonzero(sem) == 1331 and (inst[sem > 0] == 1).all()
    assert np.count_nonzero(voxelize_scene([_unit_cube(closed=True)], grid, fill="surface")[0]) == 602


def test_fill_modes_solid_fills_every_class_auto_only_volumetric_ones():
    grid = GridSpec(region_min=(-0.55,) * 3, region_max=(0.75,) * 3, voxel_size=0.1)
    cube = _unit_cube(closed=True, stuff=True)  # a Road cube: a surface class
    assert np.count_nonzero(voxelize_scene([cube], grid, fill="auto")[0]) == 602
    sem, inst = voxelize_scene([cube], grid, fill="solid")
    assert np.count_nonzero(sem) == 1331 and not inst.any()
    # solid fills open meshes too (winding numbers); surface fills nothing
    assert np.count_nonzero(voxelize_scene([_unit_cube(closed=False, stuff=True)], grid, fill="solid")[0]) == 1331
    assert np.count_nonzero(voxelize_scene([_unit_cube(closed=True)], grid, fill="surface")[0]) == 602
    with pytest.raises(ValueError, match="fill mode"):
        voxelize_scene([cube], grid, fill="hollow")


def _random_scene(rng, n_things=4):
    meshes = [_stuff(*_plane(0.0), ROAD)]
    Vt, Ft = _plane(0.1, sub=3)
    Vt[:, 2] += 0.4 * np.sin(1.3 * Vt[:, 0]) * np.cos(0.7 * Vt[:, 1])
    meshes.append(_stuff(Vt, Ft, TERRAIN))
    for k in range(n_things):
        c = rng.uniform(-3.5, 3.5, 3) * (1, 1, 0.3)
        m = trimesh.creation.box(extents=rng.uniform(0.3, 2.0, 3))
        m.apply_transform(trimesh.transformations.rotation_matrix(rng.uniform(0, 6.3), rng.normal(size=3)))
        m.apply_translation(c)
        meshes.append(SceneMesh(m.vertices, m.faces, semantic_id=CAR + (k % 2), instance_id=k + 1,
                                is_stuff=False, closed=bool(k % 3)))
    return meshes


@SETTINGS
@given(seed=st.integers(0, 2**31 - 1), tile=st.integers(1, 40))
def test_tiles_agree_with_the_whole_grid(seed, tile):
    rng = np.random.default_rng(seed)
    grid = GridSpec(region_min=(-4.0, -4.0, -1.0), region_max=(4.0, 4.0, 3.0), voxel_size=0.2)
    meshes = _random_scene(rng)
    whole = voxelize_scene(meshes, grid, tile_x=grid.shape[0])
    tiled = voxelize_scene(meshes, grid, tile_x=tile)
    np.testing.assert_array_equal(whole[0], tiled[0])
    np.testing.assert_array_equal(whole[1], tiled[1])


def test_voxel_size_that_does_not_divide_the_region_grows_it():
    # 0.5 m on the default 76.8 m x range: 154 voxels, the region grows to 77.0 m, origin kept
    grid = GridSpec(voxel_size=0.5)
    assert grid.shape == (154, 103, 26) and grid.grown
    ground = _stuff(*_plane(-1.73, half=60.0, sub=4), ROAD)
    sem, _ = voxelize_scene([ground], grid)
    k = int((-1.73 - grid.origin[2]) // 0.5)
    assert (sem[:, :, k] == ROAD).all()  # the grown last column is covered too


@pytest.mark.parametrize("voxel_size", [0.02, 1.0])
def test_extreme_voxel_sizes(voxel_size):
    grid = GridSpec(region_min=(-0.6, -0.6, -0.6), region_max=(0.6, 0.6, 0.6), voxel_size=voxel_size)
    sem, _ = voxelize_scene([_unit_cube(closed=True)], grid)
    n = np.count_nonzero(sem)
    # 0.02 m: the faces lie on voxel faces (voxel units 5 and 55) and mark both sides: 52 per axis
    assert n == (52**3 if voxel_size == 0.02 else 8)


def test_chair_matches_binvox_loosely():
    from scipy import ndimage

    root = TESTDATA_MESHES / "trimesh-models"
    require(root / "chair_model.binvox")
    ref_grid = trimesh.load(root / "chair_model.binvox")
    chair = trimesh.load(root / "chair_model.obj", force="mesh")
    T = ref_grid.transform
    pitch = float(T[0, 0])
    # trimesh's binvox transform maps indices to voxel centres: our origin is half a voxel lower
    origin = T[:3, 3] - 0.5 * pitch
    idx = surface_voxels(chair.vertices, chair.faces, origin, pitch, (32, 32, 32))
    ours = np.zeros(32**3, dtype=bool)
    ours[idx] = True
    ours = ours.reshape(32, 32, 32)
    ref = ref_grid.matrix
    iou = (ours & ref).sum() / (ours | ref).sum()
    assert iou > 0.75  # binvox fills closed parts; ours is the exact surface (measured 0.82)
    near = np.ones((3, 3, 3), dtype=bool)
    assert (ref <= ndimage.binary_dilation(ours, near)).all()  # every binvox voxel within 1 voxel
    assert (ours <= ndimage.binary_dilation(ref, near)).all()


def _yaw(deg, t=(0.0, 0.0, 0.0)):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0, t[0]], [s, c, 0, t[1]], [0, 0, 1, t[2]], [0, 0, 0, 1.0]])


def _in_frame(meshes, world_to_lidar):
    R, t = world_to_lidar[:3, :3], world_to_lidar[:3, 3]
    return [SceneMesh(m.vertices @ R.T + t, m.faces, m.semantic_id, m.instance_id, m.is_stuff, m.closed)
            for m in meshes]


def _centres_world(sem, grid, lidar_to_world):
    ijk = np.argwhere(sem > 0)
    p = np.asarray(grid.origin) + (ijk + 0.5) * grid.voxel_size
    return p @ lidar_to_world[:3, :3].T + lidar_to_world[:3, 3], sem[tuple(ijk.T)]


def _to_grid_index(p_world, grid, lidar_to_world):
    inv = np.linalg.inv(lidar_to_world)
    p = p_world @ inv[:3, :3].T + inv[:3, 3]
    return np.floor((p - np.asarray(grid.origin)) / grid.voxel_size).astype(int)


def test_rotated_ego_headings_see_the_same_world_occupancy():
    """The same static scene voxelized from two ego headings gives the same world occupancy up to
    the voxel-boundary tolerance; re-binning one frame's voxel centres into the other (the public
    shortcut) loses and duplicates voxels."""
    from scipy import ndimage

    rng = np.random.default_rng(7)
    world = _random_scene(rng, n_things=6)
    grid = GridSpec(region_min=(-2.5, -2.5, -1.0), region_max=(2.5, 2.5, 2.0), voxel_size=0.1)
    poses = [_yaw(0.0, (0.3, -0.2, 0.0)), _yaw(20.0, (0.3, -0.2, 0.0))]  # lidar-to-world
    sems = [voxelize_scene(_in_frame(world, np.linalg.inv(T)), grid)[0] for T in poses]
    # map B's occupied voxel centres into A's grid: each must land within one voxel of A's
    pB, labB = _centres_world(sems[1], grid, poses[1])
    idx = _to_grid_index(pB, grid, poses[0])
    inside = np.all((idx >= 1) & (idx < np.array(grid.shape) - 1), axis=1)
    dil = ndimage.grey_dilation(sems[0] > 0, size=(3, 3, 3))
    hit = dil[tuple(idx[inside].T)]
    assert hit.mean() > 0.995
    # the same amount of surface in the common disc (radius 2.2 m), within 5 %
    def in_disc(sem, T):
        p, _ = _centres_world(sem, grid, T)
        return int((np.hypot(p[:, 0] - 0.3, p[:, 1] + 0.2) < 2.2).sum())
    a, b = in_disc(sems[0], poses[0]), in_disc(sems[1], poses[1])
    assert abs(a - b) / a < 0.05
    # the ground is continuous: every column of B's grid inside the disc has an occupied voxel
    ij = np.argwhere(np.ones(grid.shape[:2], dtype=bool))
    cxy = np.asarray(grid.origin[:2]) + (ij + 0.5) * grid.voxel_size
    cw = cxy @ poses[1][:2, :2].T + poses[1][:2, 3]
    disc = np.zeros(grid.shape[:2], dtype=bool)
    disc[tuple(ij[np.hypot(cw[:, 0] - 0.3, cw[:, 1] + 0.2) < 2.2].T)] = True
    assert sems[1].any(axis=2)[disc].all()
    # the re-binning shortcut (A's voxel centres binned into B's grid) loses and merges voxels
    pA, _ = _centres_world(sems[0], grid, poses[0])
    idxA = _to_grid_index(pA, grid, poses[1])
    ok = np.all((idxA >= 0) & (idxA < np.array(grid.shape)), axis=1)
    lin = np.ravel_multi_index(tuple(idxA[ok].T), grid.shape)
    rebinned = np.zeros(grid.shape, dtype=bool)
    rebinned.reshape(-1)[lin] = True
    in_disc = sems[1].astype(bool) & disc[:, :, None]
    lost = (in_disc & ~rebinned).sum() / in_disc.sum()
    merged = 1.0 - len(np.unique(lin)) / len(lin)
    assert lost > 0.01 and merged > 0.01, (lost, merged)


@SETTINGS
@given(seed=st.integers(0, 2**31 - 1), tile=st.integers(1, 40))
def test_tile_thing_boxes_hold_every_voxel_of_their_instance(seed, tile):
    # Tile.things is what the pipeline reads instead of scanning instance tiles (chunks it never
    # reaches are not read; flow looks for an actor's voxels only inside its boxes)
    from carlaocc.stages.voxelize import voxelize_tiles

    rng = np.random.default_rng(seed)
    grid = GridSpec(region_min=(-4.0, -4.0, -1.0), region_max=(4.0, 4.0, 3.0), voxel_size=0.2)
    meshes = _random_scene(rng, n_things=6)
    for t in voxelize_tiles(meshes, grid, tile):
        assert t.things.dtype == np.int64 and t.things.shape[1] == 7
        covered = np.zeros(t.instance.shape, bool)
        for ident, i0, i1, j0, j1, k0, k1 in t.things:
            assert 0 <= i0 <= i1 <= t.instance.shape[0] and 0 <= j0 <= j1 <= grid.shape[1]
            box = np.zeros_like(covered)
            box[i0:i1, j0:j1, k0:k1] = True
            # every voxel of the instance in this tile is inside one of its boxes
            covered |= box & (t.instance == ident)
        assert (covered == (t.instance != 0)).all()


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), tile=st.integers(1, 40))
def test_tile_instance_buffer_is_clean_scene_after_scene(seed, tile):
    # the thread's instance buffer is zeroed only inside the boxes things were painted into: scene
    # after scene (one abandoned after its first tile), the same grids as in a fresh thread
    from concurrent.futures import ThreadPoolExecutor

    from carlaocc.stages.voxelize import voxelize_tiles

    rng = np.random.default_rng(seed)
    grid = GridSpec(region_min=(-4.0, -4.0, -1.0), region_max=(4.0, 4.0, 3.0), voxel_size=0.2)
    scenes = [_random_scene(rng, n_things=6) for _ in range(3)]

    def fresh(meshes):
        with ThreadPoolExecutor(1) as ex:
            return ex.submit(voxelize_scene, meshes, grid, "auto", tile).result()

    want = [fresh(m) for m in scenes]
    next(iter(voxelize_tiles(scenes[0], grid, tile)))
    for meshes, (sem, inst) in zip(scenes[::-1], want[::-1]):
        got_sem, got_inst = voxelize_scene(meshes, grid, "auto", tile)
        np.testing.assert_array_equal(got_sem, sem)
        np.testing.assert_array_equal(got_inst, inst)


def test_elevation_order_follows_the_worlds_up_in_a_tilted_grid():
    # world: a road at z = 0 over x in [-20, 15], a car standing beyond it at x in [18, 20]
    Vr, Fr = _plane(0.0, half=1.0)
    Vr[:, 0] = np.interp(Vr[:, 0], [-1.0, 1.0], [-20.0, 15.0])
    Vc, Fc = _box_mesh((18.0, -0.5, 0.0), (20.0, 0.5, 1.5))
    # the grid frame is pitched by 0.2 rad (an ego on a slope): world -> grid rotation Q
    th = 0.2
    Q = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0], [-np.sin(th), 0.0, np.cos(th)]])
    road = _stuff(Vr @ Q.T, Fr, ROAD)
    car = SceneMesh(Vc @ Q.T, Fc, semantic_id=CAR, instance_id=7, is_stuff=False, closed=True)
    # along the grid's z the car's far end is lower than the road's: the road would be written last
    assert elevation_order([road, car]) == [1, 0]
    # along the world's up (Q e_z in the grid frame) both start at 0 and the car reaches higher
    assert elevation_order([road, car], up=Q @ [0.0, 0.0, 1.0]) == [0, 1]
    # the grid's own z given explicitly is the default; a zero vector is refused
    assert elevation_order([road, car], up=(0.0, 0.0, 2.0)) == [1, 0]
    with pytest.raises(ValueError, match="up"):
        elevation_order([road, car], up=(0.0, 0.0, 0.0))
