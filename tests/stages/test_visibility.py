"""Camera/LiDAR visibility masks by 3D DDA (stages/voxelize/visibility.py).

The reference is an exact slab test of the ray segment against every voxel's box (voxel units,
grid origin 0, voxel size 1). A voxel whose *open* box the segment crosses before the first
occupied voxel must be marked; a marked voxel must at least touch the segment (closed box) no
later than that first hit. Voxels the ray only grazes (touches at a face, edge or corner) are
the tolerance band between the two, where the DDA's tie rule decides.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from carlaocc.schemas.grid import GridSpec
from carlaocc.schemas.rig import CameraSpec, RigConfig
from carlaocc.stages.voxelize import visibility as vis
from carlaocc.stages.voxelize.visibility import (
    Fans,
    camera_fans,
    camera_rays,
    fan_mask,
    lidar_directions,
    lidar_fans,
    ray_mask,
    sensor_to_lidar,
    visibility_masks,
)

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
EPS = 1e-7


@pytest.fixture(scope="module", autouse=True)
def _jit():
    vis.warmup()


def _unit_grid(shape) -> GridSpec:
    return GridSpec(region_min=(0.0, 0.0, 0.0), region_max=tuple(float(n) for n in shape), voxel_size=1.0)


# ------------------------------------------------------------------------------------------------
# brute-force reference
# ------------------------------------------------------------------------------------------------


def _reference(occ: np.ndarray, o, d, t_end):
    """(must, may) boolean volumes for one ray (voxel units, grid at the origin, unit voxels).

    must: open box crossed before the first hit (and the first occupied voxel crossed);
    may: closed box touched no later than the first hit. When the ray grazes an occupied voxel
    before its first proper hit, ``must`` is cut at the graze (the DDA may stop there)."""
    o = np.asarray(o, float)
    d = np.asarray(d, float) / np.linalg.norm(d)
    idx = np.indices(occ.shape).reshape(3, -1).T.astype(float)  # (V, 3) lower corners
    tin = np.zeros(len(idx))
    tout = np.full(len(idx), float(t_end))
    open_ok = np.ones(len(idx), bool)
    closed_ok = np.ones(len(idx), bool)
    for a in range(3):
        lo, hi = idx[:, a], idx[:, a] + 1.0
        if d[a] == 0.0:
            closed_ok &= (lo <= o[a]) & (o[a] <= hi)
            open_ok &= (lo + EPS < o[a]) & (o[a] < hi - EPS)
        else:
            with np.errstate(over="ignore"):  # subnormal components: +-inf is the right answer
                ta, tb = (lo - o[a]) / d[a], (hi - o[a]) / d[a]
            tin = np.maximum(tin, np.minimum(ta, tb))
            tout = np.minimum(tout, np.maximum(ta, tb))
    closed = closed_ok & (tin <= tout + EPS)
    opened = open_ok & (tin < tout - EPS)
    flat_occ = occ.reshape(-1) != 0
    hits = opened & flat_occ
    t_hit = tin[hits].min() if hits.any() else np.inf
    grazes = closed & ~opened & flat_occ
    t_graze = tin[grazes].min() if grazes.any() else np.inf
    must = opened & (tin < min(t_hit, t_graze) - EPS)
    if t_hit < t_graze - EPS:
        first = hits & (np.abs(tin - t_hit) <= EPS)
        if first.sum() == 1:  # a unique first occupied voxel must be marked
            must |= first
    may = closed & (tin <= t_hit + EPS)
    return must.reshape(occ.shape), may.reshape(occ.shape), tin.reshape(occ.shape)


@st.composite
def _scene(draw):
    shape = tuple(draw(st.integers(1, 6)) for _ in range(3))
    density = draw(st.sampled_from([0.0, 0.05, 0.2, 0.5]))
    seed = draw(st.integers(0, 2**31 - 1))
    occ = np.random.default_rng(seed).random(shape) < density
    o = [draw(st.floats(-3.0, n + 3.0, allow_nan=False)) for n in shape]
    d = [draw(st.floats(-1.0, 1.0, allow_nan=False)) for _ in range(3)]
    assume(np.linalg.norm(d) > 1e-3)
    t_end = draw(st.floats(0.0, 20.0))
    return occ, np.array(o), np.array(d), t_end


# ------------------------------------------------------------------------------------------------
# property tests against the reference
# ------------------------------------------------------------------------------------------------


@SETTINGS
@given(_scene())
def test_agrees_with_brute_force_reference(scene):
    occ, o, d, t_end = scene
    m = ray_mask(occ, _unit_grid(occ.shape), o, d[None], t_end).astype(bool)
    must, may, _ = _reference(occ, o, d, t_end)
    assert not (must & ~m).any(), "a voxel the ray crosses before the first hit is not marked"
    assert not (m & ~may).any(), "a marked voxel is off the ray or behind the first hit"


@SETTINGS
@given(_scene())
def test_marks_stop_at_first_occupied(scene):
    occ, o, d, t_end = scene
    m = ray_mask(occ, _unit_grid(occ.shape), o, d[None], t_end).astype(bool)
    _, _, tin = _reference(occ, o, d, t_end)
    marked_occ = m & occ
    # at most one occupied voxel is marked, and nothing beyond it
    assert marked_occ.sum() <= 1
    if marked_occ.any():
        assert tin[m].max() <= tin[marked_occ][0] + EPS


@SETTINGS
@given(_scene(), st.tuples(st.integers(-4, 4), st.integers(-4, 4), st.integers(-4, 4)),
       st.sampled_from([0.25, 0.5, 1.0]))
def test_translation_by_whole_voxels_commutes(scene, shift, voxel_size):
    occ, o, d, t_end = scene
    # dyadic coordinates: metres <-> voxel units is exact, so the results must be identical
    o = np.round(o * 64) / 64
    d = np.round(d * 64) / 64
    assume(np.abs(d).sum() > 0)
    base = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=tuple(n * voxel_size for n in occ.shape), voxel_size=voxel_size)
    s = np.array(shift, float) * voxel_size
    moved = GridSpec(region_min=tuple(s), region_max=tuple(s + np.array(occ.shape) * voxel_size), voxel_size=voxel_size)
    a = ray_mask(occ, base, o * voxel_size, d[None], t_end * voxel_size)
    b = ray_mask(occ, moved, o * voxel_size + s, d[None], t_end * voxel_size)
    np.testing.assert_array_equal(a, b)


def test_many_rays_serial_equals_parallel_and_union(monkeypatch):
    rng = np.random.default_rng(0)
    occ = rng.random((9, 7, 5)) < 0.1
    grid = GridSpec(region_min=(-1.0, -2.0, 0.5), region_max=(3.5, 1.5, 3.0), voxel_size=0.5)
    O = rng.uniform(-3, 4, size=(300, 3))
    D = rng.normal(size=(300, 3))
    D[::7, 1] = 0.0  # zero components
    D[5] = np.nan  # skipped
    union = np.zeros(grid.shape, np.uint8)
    for r in range(len(D)):
        ray_mask(occ, grid, O[r], D[r:r + 1], 6.0, out=union)
    monkeypatch.setattr(vis, "PARALLEL_MIN_RAYS", 10**9)
    serial = ray_mask(occ, grid, O, D, 6.0)
    monkeypatch.setattr(vis, "PARALLEL_MIN_RAYS", 1)
    parallel = ray_mask(occ, grid, O, D, 6.0)
    np.testing.assert_array_equal(serial, union)
    np.testing.assert_array_equal(parallel, union)
    assert serial.dtype == np.uint8 and set(np.unique(serial)) <= {0, 1}


# ------------------------------------------------------------------------------------------------
# known answers
# ------------------------------------------------------------------------------------------------


def test_wall_in_front_of_the_lidar():
    grid = GridSpec(voxel_size=0.5)
    occ = np.zeros(grid.shape, bool)
    iw = int((10.0 - grid.origin[0]) // grid.voxel_size)  # the voxel slab containing x = 10 m
    occ[iw] = True
    cam, lid = visibility_masks(occ, grid, RigConfig(), camera_stride=4)
    for m in (cam, lid):
        assert not m[iw + 1:].any(), "something behind the wall is marked"
        assert m[iw].any(), "no wall voxel is marked"
    # the forward beam closest to horizontal: the voxels between the LiDAR and the wall are marked,
    # and so is the wall voxel it hits
    e = np.radians(min(RigConfig().lidar.beam_elevations_deg, key=abs))
    for x in np.arange(0.25, 9.8, 0.25):
        i, j, k = ((np.array([x, 0.0, x * np.tan(e)]) - grid.origin) // grid.voxel_size).astype(int)
        assert lid[i, j, k] == 1
    hit = ((np.array([10.0, 0.0, 10.0 * np.tan(e)]) - grid.origin) // grid.voxel_size).astype(int)
    assert lid[tuple(hit)] == 1
    # the front camera's view of the free space ahead is marked too
    assert cam[int((5.0 - grid.origin[0]) // 0.5), int((0.3 - grid.origin[1]) // 0.5), int((-0.18 - grid.origin[2]) // 0.5)]


def test_ray_from_outside_enters_the_grid():
    grid = GridSpec(voxel_size=0.5)
    occ = np.zeros(grid.shape, bool)
    m = ray_mask(occ, grid, np.array([-40.0, 0.1, 0.1]), np.array([[1.0, 0.0, 0.0]]), 200.0)
    j, k = ((np.array([0.1, 0.1]) - grid.origin[1:]) // 0.5).astype(int)
    assert m[:, j, k].all() and m.sum() == grid.shape[0]
    # a ray that misses the grid does nothing; a ray too short to reach it neither
    assert not ray_mask(occ, grid, np.array([-40.0, 0.1, 0.1]), np.array([[-1.0, 0.0, 0.0]]), 200.0).any()
    assert not ray_mask(occ, grid, np.array([-40.0, 0.1, 0.1]), np.array([[1.0, 0.0, 0.0]]), 10.0).any()


def test_ray_stops_at_max_range():
    grid = GridSpec(voxel_size=0.5)
    occ = np.zeros(grid.shape, bool)
    i0, j, k = ((np.array([0.25, 0.25, 0.25]) - grid.origin) // 0.5).astype(int)
    m = ray_mask(occ, grid, np.array([0.25, 0.25, 0.25]), np.array([[2.0, 0.0, 0.0]]), 3.0)
    # 3 m from a voxel centre along x ends at the centre of the 6th voxel ahead
    assert np.argwhere(m).tolist() == [[i, j, k] for i in range(i0, i0 + 7)]


def test_origin_in_occupied_voxel_marks_only_it():
    grid = _unit_grid((4, 4, 4))
    occ = np.zeros(grid.shape, bool)
    occ[1, 2, 3] = True
    m = ray_mask(occ, grid, np.array([1.5, 2.5, 3.5]), np.array([[1.0, -1.0, 0.3], [0.0, 0.0, -1.0]]), 10.0)
    assert np.argwhere(m).tolist() == [[1, 2, 3]]


def test_out_accumulates_and_is_checked():
    grid = _unit_grid((4, 3, 2))
    occ = np.zeros(grid.shape, np.uint32)
    out = np.zeros(grid.shape, np.uint8)
    out[3, 2, 1] = 1
    res = ray_mask(occ, grid, np.array([0.5, 0.5, 0.5]), np.array([[1.0, 0.0, 0.0]]), 100.0, out=out)
    assert res is out and out[:, 0, 0].all() and out[3, 2, 1] == 1 and out.sum() == 5
    with pytest.raises(ValueError):
        ray_mask(occ, grid, np.zeros(3), np.array([[1.0, 0, 0]]), 1.0, out=np.zeros((4, 3, 2), np.int32))
    with pytest.raises(ValueError):
        ray_mask(np.zeros((2, 2, 2)), grid, np.zeros(3), np.array([[1.0, 0, 0]]), 1.0)


# ------------------------------------------------------------------------------------------------
# sensors
# ------------------------------------------------------------------------------------------------


def test_lidar_directions():
    lidar = RigConfig().lidar
    D = lidar_directions(lidar)
    steps = lidar.points_per_frame // lidar.channels
    assert D.shape == (lidar.channels * steps, 3)
    np.testing.assert_allclose(np.linalg.norm(D, axis=1), 1.0)
    e0 = np.radians(lidar.beam_elevations_deg[0])
    np.testing.assert_allclose(D[0], [np.cos(e0), 0.0, np.sin(e0)], atol=1e-12)
    assert D[1, 1] > 0  # counter-clockwise: the second azimuth turns towards +y
    np.testing.assert_allclose(np.degrees(np.arcsin(D[::steps, 2])), lidar.beam_elevations_deg, atol=1e-9)


def test_camera_rays_point_where_the_cameras_look():
    rig = RigConfig()
    poses = sensor_to_lidar(rig)
    np.testing.assert_allclose(poses[rig.lidar.name], np.eye(4), atol=1e-12)
    o, d = camera_rays(rig.cameras[0], poses["camera_00"], stride=8)
    np.testing.assert_allclose(o, [0.8, 0.3, 1.55 - 1.73], atol=1e-12)  # CARLA y=-0.3 is our left
    assert (d[:, 0] > 0).all() and len(d) == len(range(0, 376, 8)) * len(range(0, 1408, 8))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    _, d_rear = camera_rays(rig.cameras[4], poses["camera_04"], stride=8)
    assert (d_rear[:, 0] < 0).all()
    # odd image size: the middle pixel centre is the principal point, its ray the optical axis
    cam = CameraSpec(name="c", x=0.0, y=0.46, z=1.55, yaw_deg=90.0, width=5, height=3, hfov_deg=60.0)
    T = np.linalg.inv(np.asarray(rig.lidar.sensor_to_ego())) @ np.asarray(cam.camera_to_ego())
    _, d = camera_rays(cam, T)
    np.testing.assert_allclose(d[1 * 5 + 2], T[:3, 2], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)  # CARLA yaw +90 = right = -y
    # top-left pixel looks up-left of the axis (optical x right, y down)
    assert d[0] @ T[:3, 0] < 0 and d[0] @ T[:3, 1] < 0


# ------------------------------------------------------------------------------------------------
# vertical fans (algorithm 2) against the reference and against the 3D DDA
# ------------------------------------------------------------------------------------------------


@st.composite
def _fan_scene(draw):
    shape = tuple(draw(st.integers(1, 9)) for _ in range(3))
    density = draw(st.sampled_from([0.0, 0.05, 0.2]))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < density
    if draw(st.booleans()):  # a floor: most fans hit it
        occ[:, :, 0] = True
    n = draw(st.integers(1, 40))
    if draw(st.booleans()):
        # near: origins in or around the grid, rays from much less than a voxel apart (the
        # "dense" path) to far apart
        o = np.array([draw(st.floats(-3.0, k + 3.0, allow_nan=False)) for k in shape])
        a = round(draw(st.floats(0.0, 2 * np.pi)), 6)
        spread = draw(st.sampled_from([0.01, 0.2, 2.0]))
        slopes = np.sort(draw(st.floats(-1.5, 1.5)) + spread * (rng.random(n) - 0.5))
    else:
        # far: fans arriving from 10-40 voxels away, their rays 0.3-3 voxels apart in the grid
        # (where the dense and the per-ray paths meet)
        dist = draw(st.floats(10.0, 40.0))
        a = round(draw(st.floats(-0.6, 0.6)), 6)
        o = np.array([-dist * np.cos(a), shape[1] / 2 - dist * np.sin(a), draw(st.floats(0.0, shape[2]))])
        gap = draw(st.floats(0.3, 3.0)) / dist
        slopes = np.sort(gap * (np.arange(n) - n / 2) + rng.normal(0, 1e-3 * gap, n))
    t_end = draw(st.floats(0.0, 60.0))
    # (angles on a 1e-6 rad lattice: a heading component of 1e-24, whose drift rounds away in the
    # origin's coordinate, is a tie the reference's tolerance in t does not see)
    return occ, o, np.array([np.cos(a), np.sin(a)]), slopes, t_end


@SETTINGS
@given(_fan_scene())
def test_fans_agree_with_brute_force_reference(scene):
    occ, o, h, slopes, t_end = scene
    fans = Fans(origins=o[None], headings=h[None], slopes=slopes[None])
    m = fan_mask(occ, _unit_grid(occ.shape), fans, t_end).astype(bool)
    must = np.zeros(occ.shape, bool)
    may = np.zeros(occ.shape, bool)
    for d in fans.directions():
        mu, ma, _ = _reference(occ, o, d, t_end)
        must |= mu
        may |= ma
    assert not (must & ~m).any(), "a voxel a ray crosses before its first hit is not marked"
    assert not (m & ~may).any(), "a marked voxel is off every ray or behind its first hit"


def test_fans_equal_the_3d_dda_off_ties():
    # random (non-lattice) origins and slopes: no ray passes exactly through a voxel edge, so the
    # two algorithms must mark the very same voxels, near and far, on a floor, walls and clutter
    rng = np.random.default_rng(7)
    occ = rng.random((60, 50, 20)) < 0.01
    occ[:, :, 0] = True
    occ[45:47, :, :12] = True
    grid = GridSpec(region_min=(-3.0, -2.5, -0.5), region_max=(3.0, 2.5, 1.5), voxel_size=0.1)
    F = 40
    O = np.column_stack([rng.uniform(-2.9, 2.9, F), rng.uniform(-2.4, 2.4, F), rng.uniform(-0.3, 1.2, F)])
    a = rng.uniform(0, 2 * np.pi, F)
    base = np.sort(rng.uniform(-0.8, 0.8, (F, 1)) + np.linspace(-0.3, 0.3, 90)[None] + rng.normal(0, 1e-4, (F, 90)),
                   axis=1)
    fans = Fans(origins=O, headings=np.column_stack([np.cos(a), np.sin(a)]), slopes=base)
    got = fan_mask(occ, grid, fans, 5.0)
    want = np.zeros(grid.shape, np.uint8)
    D = fans.directions().reshape(F, -1, 3)
    for f in range(F):
        ray_mask(occ, grid, O[f], D[f], 5.0, out=want)
    assert want.sum() > 3000
    np.testing.assert_array_equal(got, want)


def test_fans_serial_equals_parallel(monkeypatch):
    rng = np.random.default_rng(1)
    occ = rng.random((30, 20, 10)) < 0.05
    grid = _unit_grid(occ.shape)
    F = 100
    a = rng.uniform(0, 2 * np.pi, F)
    fans = Fans(origins=rng.uniform(-2, 25, (F, 3)), headings=np.column_stack([np.cos(a), np.sin(a)]),
                slopes=np.sort(rng.normal(0, 0.3, (F, 12)), axis=1))
    monkeypatch.setattr(vis, "PARALLEL_MIN_FANS", 10**9)
    serial = fan_mask(occ, grid, fans, 40.0)
    monkeypatch.setattr(vis, "PARALLEL_MIN_FANS", 1)
    parallel = fan_mask(occ, grid, fans, 40.0)
    assert serial.any()
    np.testing.assert_array_equal(serial, parallel)


def test_fans_are_checked():
    with pytest.raises(ValueError, match="ascending"):
        Fans(origins=np.zeros((1, 3)), headings=[[1.0, 0.0]], slopes=[[0.2, 0.1]])
    with pytest.raises(ValueError, match="unit"):
        Fans(origins=np.zeros((1, 3)), headings=[[2.0, 0.0]], slopes=[[0.1]])
    with pytest.raises(ValueError, match="finite"):
        Fans(origins=np.zeros((1, 3)), headings=[[1.0, 0.0]], slopes=[[np.nan]])
    with pytest.raises(ValueError, match="fans need"):
        Fans(origins=np.zeros((2, 3)), headings=[[1.0, 0.0]], slopes=[[0.1]])


def _same_rays(a: np.ndarray, b: np.ndarray) -> None:
    assert a.shape == b.shape
    # the same set of unit vectors (sorted on rounded values: float noise must not reorder them)
    ka, kb = np.round(a, 9), np.round(b, 9)
    np.testing.assert_allclose(a[np.lexsort(ka.T)], b[np.lexsort(kb.T)], atol=1e-12)


def test_camera_fans_are_the_camera_rays():
    rig = RigConfig()
    poses = sensor_to_lidar(rig)
    for cam in rig.cameras:
        fans = camera_fans(cam, poses[cam.name], stride=4)
        o, d = camera_rays(cam, poses[cam.name], stride=4)
        assert fans is not None and len(fans) == len(range(0, cam.width, 4))
        np.testing.assert_allclose(fans.origins, np.broadcast_to(o, fans.origins.shape))
        _same_rays(fans.directions(), d)
    # a pitched camera's image columns are not vertical planes: no fans (traced ray by ray)
    T = poses["camera_00"].copy()
    c, s_ = np.cos(0.2), np.sin(0.2)
    T[:3, :3] = np.array([[c, 0, s_], [0, 1, 0], [-s_, 0, c]]) @ T[:3, :3]
    assert camera_fans(rig.cameras[0], T) is None


def test_lidar_fans_are_the_lidar_beams():
    lidar = RigConfig().lidar
    fans, vertical = lidar_fans(lidar)
    assert len(vertical) == 0 and len(fans) == lidar.points_per_frame // lidar.channels
    _same_rays(fans.directions(), lidar_directions(lidar))
    # beams straight up/down belong to no fan: traced on their own
    steep = lidar.model_copy(update={"upper_fov_deg": 90.0, "lower_fov_deg": -90.0, "channels": 5})
    fans, vertical = lidar_fans(steep)
    np.testing.assert_allclose(vertical, [[0, 0, 1.0], [0, 0, -1.0]])
    assert fans.slopes.shape[1] == 3


def test_rig_masks_by_fans_equal_the_rays_almost_everywhere():
    # the default rig on a street (floor, walls, a car): fans against the pixel and beam rays
    # one by one; they differ only where a ray passes exactly through a voxel edge (the camera
    # centres sit on lattice planes of a 0.2 m grid, so such ties exist)
    grid = GridSpec(voxel_size=0.2)
    occ = np.zeros(grid.shape, bool)
    k0 = int((-1.73 - grid.origin[2]) // 0.2)
    occ[:, :, k0] = True
    occ[:, :20, :] = True
    occ[:, -20:, :] = True
    occ[150:170, 110:140, k0:k0 + 8] = True
    rig = RigConfig()
    cam, lid = visibility_masks(occ, grid, rig, camera_stride=4)
    packed = vis.pack_occupancy(occ, grid)
    mask = packed.new_mask()
    poses = sensor_to_lidar(rig)
    maxr = float(np.linalg.norm(np.asarray(grid.shape) * 0.2))
    for c in rig.cameras:
        packed.trace(mask, *camera_rays(c, poses[c.name], 4), maxr)
    cam_rays = packed.or_into(mask, np.zeros(grid.shape, np.uint8))
    mask = packed.new_mask()
    packed.trace(mask, np.zeros(3), lidar_directions(rig.lidar), rig.lidar.range_m)
    lid_rays = packed.or_into(mask, np.zeros(grid.shape, np.uint8))
    for a, b in ((cam, cam_rays), (lid, lid_rays)):
        assert b.sum() > 10000
        assert (a != b).sum() <= 1e-3 * b.sum()


def test_slabs_and_packing_by_slabs_equal_the_whole():
    rng = np.random.default_rng(4)
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(3.0, 2.0, 7.0), voxel_size=0.1)  # 30x20x70
    occ = rng.random(grid.shape) < 0.02
    whole = vis.pack_occupancy(occ, grid)
    words = whole.words.copy()
    parts = vis.pack_occupancy(None, grid)
    for x0 in range(0, 30, 8):
        parts.pack_slab(x0, occ[x0:x0 + 8])
    np.testing.assert_array_equal(parts.words, words)
    with pytest.raises(ValueError, match="does not fit"):
        parts.pack_slab(25, occ[:8])
    mask = parts.new_mask()
    parts.trace(mask, np.array([0.05, 1.0, 3.5]), rng.normal(size=(500, 3)), 10.0)
    full = parts.or_into(mask, np.zeros(grid.shape, np.uint8))
    assert full.any() and (full <= 1).all()
    for x0 in range(0, 30, 7):  # x-slabs: blocks of every column of a few x
        slab = parts.block(mask, x0, 0, min(7, 30 - x0), grid.shape[1])
        want = full[x0:x0 + 7]
        np.testing.assert_array_equal(np.zeros_like(want) if slab is None else slab, want)


def test_a_packed_volume_keeps_its_bits_unless_it_reuses_the_thread_buffers():
    g = GridSpec(region_min=(0, 0, 0), region_max=(8, 8, 8), voxel_size=1.0)
    wall = np.zeros(g.shape, bool)
    wall[3] = True
    p = vis.pack_occupancy(wall, g)
    m = p.new_mask()
    # other volumes and masks of the same thread come and go in between
    ray_mask(np.zeros(g.shape, bool), g, np.array([0.5, 0.5, 0.5]), np.array([[1.0, 0, 0]]), 1.0)
    vis.warmup()
    p.trace(m, np.array([0.5, 4.5, 4.5]), np.array([[1.0, 0, 0]]), 100.0)
    p.trace(p.new_mask(), np.array([0.5, 1.5, 1.5]), np.array([[1.0, 0, 0]]), 100.0)
    np.testing.assert_array_equal(p.or_into(m, np.zeros(g.shape, np.uint8))[:, 4, 4], [1, 1, 1, 1, 0, 0, 0, 0])
    # a reusing volume shares the thread's buffers (what the pipeline wants, frame after frame)
    a = vis.pack_occupancy(wall, g, reuse=True)
    b = vis.pack_occupancy(np.zeros(g.shape, bool), g, reuse=True)
    assert np.shares_memory(a.words, b.words) and np.shares_memory(a.new_mask("x"), b.new_mask("x"))


def test_steep_fans_far_away_do_not_overflow():
    g = GridSpec(region_min=(0, 0, 0), region_max=(4, 4, 70), voxel_size=1.0)
    occ = np.zeros(g.shape, bool)
    for z, m in ((2.2, -1e20), (69.5, 1e20), (2.2, 1e30), (2.2, -1e300)):
        f = Fans(origins=[[1.3, 1.6, z]], headings=[[1.0, 0.0]], slopes=[[m]])
        np.testing.assert_array_equal(fan_mask(occ, g, f, np.inf), ray_mask(occ, g, f.origins[0], f.directions(), np.inf))


def test_zero_range_marks_the_origin_voxel_like_the_dda():
    g = _unit_grid((4, 4, 4))
    occ = np.zeros(g.shape, bool)
    f = Fans(origins=[[1.3, 1.6, 2.2]], headings=[[1.0, 0.0]], slopes=[[-0.4, 0.1]])
    got = fan_mask(occ, g, f, 0.0)
    np.testing.assert_array_equal(got, ray_mask(occ, g, f.origins[0], f.directions(), 0.0))
    assert np.argwhere(got).tolist() == [[1, 1, 2]]


def test_a_block_unpacks_every_byte_of_bits_to_its_eight_voxels():
    # one column of 2048 voxels whose bits, read as bytes, are 0, 1, ..., 255: every pattern of
    # eight voxels the unpacking meets, checked against numpy's unpackbits
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(1.0, 1.0, 2048.0), voxel_size=1.0)
    packed = vis.pack_occupancy(np.zeros(grid.shape, bool), grid)
    mask = np.arange(256, dtype=np.uint8).view(np.uint64).copy()
    got = packed.block(mask, 0, 0, 1, 1)
    want = np.unpackbits(np.arange(256, dtype=np.uint8), bitorder="little")
    np.testing.assert_array_equal(got.reshape(-1), want)


def test_blocks_of_a_mask_equal_the_whole_and_say_when_empty():
    rng = np.random.default_rng(9)
    for nz in (70, 72):  # bytes one by one, and four at a time
        grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(2.0, 1.7, nz / 10), voxel_size=0.1)
        occ = rng.random(grid.shape) < 0.02
        packed = vis.pack_occupancy(occ, grid)
        mask = packed.new_mask()
        packed.trace(mask, np.array([0.05, 0.05, 3.0]), rng.normal(size=(300, 3)) * (1, 1, 0.2) + (1, 1, 0), 2.0)
        full = packed.or_into(mask, np.zeros(grid.shape, np.uint8))
        assert full.any()
        for i0, j0, bx, by in ((0, 0, 20, 17), (3, 5, 7, 4), (19, 16, 1, 1), (0, 0, 0, 0)):
            b = packed.block(mask, i0, j0, bx, by)
            want = full[i0:i0 + bx, j0:j0 + by]
            if want.any():
                np.testing.assert_array_equal(b, want)
            else:
                assert b is None
        with pytest.raises(ValueError, match="outside"):
            packed.block(mask, 15, 0, 6, 1)


def _brute_words(occ: np.ndarray) -> np.ndarray:
    """Column bits of a (nx, ny, nz) volume, bit by bit: word (i * ny + j) * W + k // 64, bit k % 64."""
    nx, ny, nz = occ.shape
    W = (nz + 63) // 64
    words = np.zeros(nx * ny * W, np.uint64)
    for (i, j, k) in np.argwhere(occ != 0):
        words[(i * ny + j) * W + k // 64] |= np.uint64(1) << np.uint64(k % 64)
    return words


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 5), st.integers(1, 5), st.integers(1, 200), st.integers(0, 2**32 - 1), st.integers(1, 5))
def test_packing_through_the_bit_stream_equals_bit_by_bit(nx, ny, nz, seed, slab):
    # any nz (column starts at any bit of the stream), labels other than 1, packed whole or by slabs
    rng = np.random.default_rng(seed)
    occ = (rng.random((nx, ny, nz)) < rng.random()) * rng.integers(1, 256, (nx, ny, nz))
    occ = occ.astype(np.uint8)
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(nx, ny, nz), voxel_size=1.0)
    want = _brute_words(occ)
    np.testing.assert_array_equal(vis.pack_occupancy(occ, grid).words, want)
    parts = vis.pack_occupancy(None, grid)
    for x0 in range(0, nx, slab):
        parts.pack_slab(x0, occ[x0:x0 + slab])
    np.testing.assert_array_equal(parts.words, want)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 6), st.integers(1, 6), st.integers(1, 200), st.integers(0, 2**32 - 1),
       st.tuples(st.integers(0, 5), st.integers(0, 5), st.integers(0, 6), st.integers(0, 6)))
def test_blocks_through_the_bit_stream_equal_bit_by_bit(nx, ny, nz, seed, box):
    # a random mask (sparse, dense or empty) read back a block at a time against its bits one by one
    rng = np.random.default_rng(seed)
    want = rng.random((nx, ny, nz)) < rng.choice([0.0, 0.001, 0.3, 1.0])
    grid = GridSpec(region_min=(0.0, 0.0, 0.0), region_max=(nx, ny, nz), voxel_size=1.0)
    packed = vis.pack_occupancy(None, grid)
    mask = _brute_words(want)
    i0, j0 = min(box[0], nx - 1), min(box[1], ny - 1)
    bx, by = min(box[2], nx - i0), min(box[3], ny - j0)
    got = packed.block(mask, i0, j0, bx, by)
    part = want[i0:i0 + bx, j0:j0 + by]
    if part.any():
        assert got.dtype == np.uint8 and got.shape == part.shape
        np.testing.assert_array_equal(got, part.astype(np.uint8))
    else:
        assert got is None


# ------------------------------------------------------------------------------------------------
# the sparse part of a fan (rays at least a voxel apart: cells kept per ray, refreshed only when
# they change) against every ray traced in every column, exactly
# ------------------------------------------------------------------------------------------------


def _floor_cell(z: float) -> int:
    return int(np.floor(min(max(z, -2.0), 1099511627776.0)))


def _ceil_cell(z: float) -> int:
    return int(np.ceil(min(max(z, -2.0), 1099511627776.0)))


def _fan_columns(o, h, shape):
    """The fan's columns as Algorithm 2 steps through them: (i, j, r_in, r_out) with the same float
    operations as the kernel's 2D DDA (``dda.slab``, ``dda.axis_setup``), ending at the footprint's end."""
    from carlaocc.stages.voxelize.dda import axis_setup, clamp_floor, slab
    nx, ny, _ = shape
    r0, r1 = slab(o[0], h[0], nx, 0.0, np.inf)
    r0, r1 = slab(o[1], h[1], ny, r0, r1)
    if not r0 <= r1:
        return []
    i, j = clamp_floor(o[0] + r0 * h[0], nx), clamp_floor(o[1] + r0 * h[1], ny)
    tmx, tdx, sx, lx = axis_setup(o[0], h[0], i, nx)
    tmy, tdy, sy, ly = axis_setup(o[1], h[1], j, ny)
    out, r_in = [], r0
    while True:
        out.append((i, j, r_in, max(min(tmx, tmy, r1), r_in)))
        if tmx <= tmy:
            if tmx >= r1 or lx == 0:
                return out
            lx, r_in, tmx, i = lx - 1, max(r_in, tmx), tmx + tdx, i + sx
        else:
            if tmy >= r1 or ly == 0:
                return out
            ly, r_in, tmy, j = ly - 1, max(r_in, tmy), tmy + tdy, j + sy


def _fan_rays_one_by_one(occ, o, h, slopes, t_range):
    """Every ray of one fan in every column it reaches: its cells ``floor(lower end) ..
    ceil(upper end) - 1`` (clipped to the grid), in the ray's order, up to its first occupied one;
    a ray leaves the fan when it hits, ends or has left the grid vertically moving away."""
    nz = occ.shape[2]
    mask = np.zeros(occ.shape, bool)
    cols = _fan_columns(o, h, occ.shape)
    R = [t_range / (np.sqrt(1.0 + abs(m) * abs(m)) if abs(m) < 1e150 else abs(m)) for m in slopes]
    alive = [bool(cols) and R[v] >= cols[0][2] for v in range(len(slopes))]
    for i, j, r_in, r_out in cols:
        for v, m in enumerate(slopes):
            if not alive[v]:
                continue
            r_end, dead = (R[v], True) if R[v] <= r_out else (r_out, False)
            za, zb = o[2] + m * r_in, o[2] + m * r_end
            lo = _floor_cell(min(za, zb))
            hi = max(_ceil_cell(max(za, zb)) - 1, lo)
            if hi < 0:
                dead = dead or m <= 0.0
            elif lo >= nz:
                dead = dead or m >= 0.0
            else:
                cells = range(max(lo, 0), min(hi, nz - 1) + 1)
                for k in (cells if m >= 0.0 else reversed(cells)):
                    mask[i, j, k] = True
                    if occ[i, j, k]:
                        dead = True
                        break
            alive[v] = not dead
        if not any(alive):
            break
    return mask


@st.composite
def _sparse_fan_scene(draw):
    # columns of 63-65 / 127-129 cells (ranges ending on and across word boundaries), walls, a
    # floor and clutter; fans from 8-60 voxels away (outside the grid: entering at its edges) or
    # above / below it, their rays 1-4 voxels apart where they enter; dyadic origins and slopes
    # put many ray ends exactly on cell faces (ties)
    shape = (draw(st.integers(1, 12)), draw(st.integers(1, 12)), draw(st.sampled_from([1, 5, 63, 64, 65, 127, 128, 129])))
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    occ = rng.random(shape) < draw(st.sampled_from([0.0, 0.01, 0.05, 0.3]))
    if draw(st.booleans()):
        occ[:, :, : draw(st.integers(1, 3))] = True
    if draw(st.booleans()):
        occ[draw(st.integers(0, shape[0] - 1))] = True
    dist = draw(st.floats(8.0, 60.0))
    a = round(draw(st.floats(-0.7, 0.7)), 6)
    oz = draw(st.sampled_from([0.0, 32.0, 63.5, 64.0, -5.0, float(shape[2]) + 4.0])) + draw(st.sampled_from([0.0, 0.25, 0.5]))
    o = np.array([-dist * np.cos(a), shape[1] / 2 - dist * np.sin(a), oz])
    if draw(st.booleans()):
        o[:2] = np.round(o[:2] * 64) / 64
    n = draw(st.integers(1, 40))
    gap = draw(st.floats(1.0, 4.0)) / dist
    centre = draw(st.floats(-1.0, 1.0))
    slopes = centre + gap * (np.arange(n) - n / 2)
    if draw(st.booleans()):
        slopes = np.round(slopes * 64) / 64
    slopes = np.unique(slopes)
    t_range = draw(st.sampled_from([np.inf, draw(st.floats(0.0, 120.0))]))
    return occ, o, np.array([np.cos(a), np.sin(a)]), slopes, t_range


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(_sparse_fan_scene())
def test_sparse_fans_equal_every_ray_in_every_column(scene):
    occ, o, h, slopes, t_range = scene
    cols = _fan_columns(o, h, occ.shape)
    # the kernel keeps cells per ray only where the rays are at least a voxel apart (elsewhere a
    # run of free rays is marked as one interval): only such fans compare bit for bit here
    assume(cols and len(slopes) > 1 and np.diff(slopes).max() * cols[0][3] >= 1.0)
    fans = Fans(origins=o[None], headings=h[None], slopes=slopes[None])
    got = fan_mask(occ, _unit_grid(occ.shape), fans, t_range).astype(bool)
    want = _fan_rays_one_by_one(occ, o, h, slopes, t_range)
    np.testing.assert_array_equal(got, want)


@st.composite
def _edge_fan_scene(draw):
    # fans that start dense (rays less than a voxel apart) and turn sparse inside the grid, from
    # origins in, beside, above or below the grid; columns of 63-65 / 127-129 cells (ranges ending
    # on and across word boundaries); columns occupied only below or only above the fan's rays
    # (their occupied runs outside a run's range: the free-run shortcut, step 3 of Algorithm 2),
    # walls at the grid's edges; dyadic origins and slopes put ray ends exactly on cell faces
    shape = (draw(st.integers(1, 14)), draw(st.integers(1, 14)), draw(st.sampled_from([1, 5, 63, 64, 65, 127, 128, 129])))
    nx, ny, nz = shape
    rng = np.random.default_rng(draw(st.integers(0, 2**31 - 1)))
    occ = np.zeros(shape, bool)
    band = draw(st.sampled_from(["none", "below", "above", "both", "random", "edges"]))
    k = draw(st.integers(0, nz))
    if band in ("below", "both"):
        occ[:, :, :k] = rng.random((nx, ny, 1)) < 0.7
    if band in ("above", "both"):
        occ[:, :, max(k, nz - draw(st.integers(1, 8))):] = rng.random((nx, ny, 1)) < 0.7
    if band == "random":
        occ = rng.random(shape) < draw(st.sampled_from([0.01, 0.05]))
    if band == "edges":
        occ[[0, -1]] = True
        occ[:, [0, -1]] = True
    where = draw(st.sampled_from(["inside", "beside", "above", "below"]))
    a = round(draw(st.floats(0.0, 2 * np.pi)), 6)
    if where == "inside":
        o = np.array([draw(st.floats(0.0, nx)), draw(st.floats(0.0, ny)), draw(st.floats(0.0, nz))])
    else:
        dist = draw(st.floats(1.0, 20.0))
        o = np.array([nx / 2 - dist * np.cos(a), ny / 2 - dist * np.sin(a), draw(st.floats(0.0, nz))])
        o[2] = {"beside": o[2], "above": nz + draw(st.floats(0.0, 6.0)), "below": -draw(st.floats(0.0, 6.0))}[where]
    if draw(st.booleans()):
        o = np.round(o * 16) / 16
    n = draw(st.integers(2, 60))
    # neighbouring rays a voxel apart somewhere between 0.5 and 20 voxels from the origin
    gap = 1.0 / draw(st.floats(0.5, 20.0))
    slopes = draw(st.floats(-1.5, 1.5)) + gap * (np.arange(n) - n / 2) + rng.normal(0, 0.1 * gap, n) * draw(st.booleans())
    if draw(st.booleans()):
        slopes = np.round(slopes * 64) / 64
    slopes = np.unique(slopes)
    t_range = draw(st.sampled_from([np.inf, draw(st.floats(0.0, 40.0))]))
    return occ, o, np.array([np.cos(a), np.sin(a)]), slopes, t_range


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_edge_fan_scene())
def test_fans_from_dense_to_sparse_equal_every_ray_in_every_column(scene):
    # the union of every ray's cells in every column, exactly: the dense part's intervals, the
    # free-run shortcut and the sparse part's carried-over cells all give the rays' own cells
    occ, o, h, slopes, t_range = scene
    fans = Fans(origins=o[None], headings=h[None], slopes=slopes[None])
    got = fan_mask(occ, _unit_grid(occ.shape), fans, t_range).astype(bool)
    want = _fan_rays_one_by_one(occ, o, h, slopes, t_range)
    np.testing.assert_array_equal(got, want)
