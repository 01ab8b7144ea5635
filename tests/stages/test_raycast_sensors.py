"""Ray-cast sensors, the simulator artifact model and the instance-guided rectification, on
synthetic frames: glass in front of a wall, a car with windows, unlabelled terrain."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.schemas.configs import SensorsConfig, SimulatorArtifacts
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.rig import CameraSpec, LidarSpec, RigConfig
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors import (SKY, UNLABELLED, CameraMaps, RayScene, camera_poses, camera_ray_bundle, compact_mesh,
                            covered_pixels,
                            depth_normals, lidar_scan, rectify, render_camera, simulate_frame, unlabelled_meshes)
from carlaocc.stages.sensors.artifacts import asset_fraction

BUILDING, TERRAIN, CAR, STATIC = 3, 10, 14, 20


def box(lo, hi, semantic, instance=0, transparent=False, stuff=False, name="", asset_id=""):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi - lo)
    m.apply_translation((lo + hi) / 2)
    return SceneMesh(m.vertices, m.faces, semantic, instance, stuff, not stuff, name=name or f"box{semantic}",
                     transparent=transparent, asset_id=asset_id or name or f"a{semantic}_{instance}")


def quad(x, y0, y1, z0, z1, semantic, instance=0, transparent=False, stuff=False, name="quad"):
    """A vertical rectangle facing -x at ``x`` (LiDAR frame)."""
    V = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    return SceneMesh(V, F, semantic, instance, stuff, False, name=name, transparent=transparent, asset_id=name)


def street_scene():
    """The LiDAR frame scene the tests look at (camera_00 looks along +x from (0.8, 0.3, -0.18))."""
    return [
        # unlabelled terrain under everything (the artifact model's default class)
        quad_ground := SceneMesh(np.array([[-60, -60, -1.73], [60, -60, -1.73], [60, 60, -1.73], [-60, 60, -1.73]]),
                                 np.array([[0, 1, 2], [0, 2, 3]]), TERRAIN, 0, True, False, name="terrain",
                                 asset_id="town/terrain"),
        # a building wall at 20 m with a glass shop window 8 m in front of it
        box([20, -30, -1.73], [22, 30, 5], BUILDING, 5, name="building"),
        quad(12.0, -4.0, 2.0, -1.5, 2.5, BUILDING, 5, transparent=True, name="building/window"),
        # a car at 6 m: opaque body, transparent cabin (its windows) with an opaque seat inside
        box([5, 1.5, -1.73], [9, 3.3, -0.9], CAR, 7, name="car/body"),
        box([5.8, 1.7, -0.9], [8.2, 3.1, -0.2], CAR, 7, transparent=True, name="car/windows"),
        box([6.6, 2.0, -0.9], [7.2, 2.8, -0.5], CAR, 7, name="car/seat"),
    ]


def front_rig(width=176, height=47):
    """The reference rig's front camera at a smaller image size (same 103.7 degree FOV)."""
    cam = CameraSpec(name="camera_00", x=0.8, y=-0.3, z=1.55, width=width, height=height)
    return RigConfig(cameras=(cam,), lidar=LidarSpec(points_per_second=20 * 32 * 90))


CFG = SensorsConfig(artifacts=SimulatorArtifacts(unlabelled_classes=("Terrain",), unlabelled_fraction=0.0))


def test_camera_rays_give_planar_depth_of_a_wall():
    # a wall perpendicular to the optical axis: every pixel's depth is the same planar distance
    rig = front_rig()
    cam = rig.cameras[0]
    pose = camera_poses(rig)[cam.name]
    wall = quad(30.0, -100, 100, -50, 50, BUILDING, 5)
    clean, _ = render_camera(RayScene(flatten([wall])), cam, pose)
    assert np.allclose(clean.depth, 30.0 - pose[0, 3], atol=1e-4)
    assert (clean.semantic == BUILDING).all() and (clean.instance == 5).all()
    # the ray bundle's directions have unit optical-axis component
    origin, d = camera_ray_bundle(cam, pose)
    assert np.allclose((d @ pose[:3, :3])[:, 2], 1.0)


def test_hits_beyond_the_maximum_depth_are_no_surface():
    # a wall at planar depth d: within max_depth it is seen, beyond it every map says "no
    # surface" (depth 0, the sky's label, instance 0, face -1), in the clean and the raw maps
    rig = front_rig()
    cam = rig.cameras[0]
    pose = camera_poses(rig)[cam.name]
    scene = RayScene(flatten([quad(30.0, -100, 100, -50, 50, BUILDING, 5)]))
    d = 30.0 - pose[0, 3]
    for max_depth, seen in ((d + 1.0, True), (d - 1.0, False)):
        for maps in render_camera(scene, cam, pose, max_depth=max_depth, raw=True):
            if seen:
                assert np.allclose(maps.depth, d, atol=1e-4) and (maps.face >= 0).all()
                assert (maps.semantic == BUILDING).all() and (maps.instance == 5).all()
            else:
                assert (maps.depth == 0).all() and (maps.face == -1).all()
                assert (maps.semantic == SKY).all() and (maps.instance == 0).all()


def test_rig_camera_rays_are_the_bundle_computed_once():
    from carlaocc.stages.sensors.raycast import rig_camera_rays

    rig = front_rig()
    cam = rig.cameras[0]
    pose = camera_poses(rig)[cam.name]
    origin, d = rig_camera_rays(cam, pose)
    want_origin, want_d = camera_ray_bundle(cam, pose)
    np.testing.assert_array_equal(origin, want_origin)
    np.testing.assert_array_equal(d, want_d)
    # the same read-only arrays frame after frame; another pose gets its own
    again = rig_camera_rays(cam, pose.copy())
    assert again[1] is d and not d.flags.writeable
    moved = pose.copy()
    moved[0, 3] += 1.0
    np.testing.assert_array_equal(rig_camera_rays(cam, moved)[0], want_origin + [1.0, 0.0, 0.0])


def test_miss_is_sky_with_zero_depth_and_max_depth_cuts():
    rig = front_rig()
    cam = rig.cameras[0]
    pose = camera_poses(rig)[cam.name]
    clean, _ = render_camera(RayScene(flatten([quad(30.0, -100, 100, -50, 50, BUILDING, 5)])), cam, pose,
                             max_depth=10.0)
    assert (clean.depth == 0).all() and (clean.semantic == SKY).all() and (clean.instance == 0).all()
    empty, _ = render_camera(RayScene(flatten([])), cam, pose)
    assert (empty.depth == 0).all() and (empty.semantic == SKY).all()


def test_raw_model_sees_through_glass_and_drops_unlabelled_labels():
    rig = front_rig()
    cam = rig.cameras[0]
    scene = street_scene()
    flags = unlabelled_meshes(scene, CFG.artifacts)
    assert flags.tolist() == [True, False, False, False, False, False]
    counts = [len(m.faces) for m in scene]
    full = RayScene(flatten(scene), unlabelled=np.repeat(flags, counts))
    clean, raw = render_camera(full, cam, camera_poses(rig)[cam.name], raw=True)
    glass = clean.depth < raw.depth - 1e-3
    assert glass.sum() > 100  # the shop window and the car's windows cover pixels
    # behind the shop window raw pixels see the wall or the (unlabelled) ground in front of it
    behind = raw.semantic[(clean.semantic == BUILDING) & glass]
    assert set(np.unique(behind)) == {BUILDING, UNLABELLED} and (behind == BUILDING).sum() > 50
    # terrain keeps its depth in the raw map but loses its label
    terrain = clean.semantic == TERRAIN
    assert terrain.sum() > 100
    assert (raw.semantic[terrain] == UNLABELLED).all() and (raw.depth[terrain] == clean.depth[terrain]).all()
    # without the translucency artifact raw depth equals clean depth everywhere
    _, raw2 = render_camera(full, cam, camera_poses(rig)[cam.name], raw=True, see_through=False)
    assert (raw2.depth == clean.depth).all()


@pytest.mark.parametrize("fraction", [0.0, 1.0])
def test_rectified_maps_equal_clean_maps_where_the_model_says(fraction):
    rig = front_rig()
    cfg = CFG.model_copy(update={"artifacts": CFG.artifacts.model_copy(update={"unlabelled_fraction": fraction})})
    scene = street_scene()
    frame = simulate_frame(scene, rig, cfg)
    (cf,) = frame.cameras.values()
    # the clean maps again, independently
    full = RayScene(flatten(scene))
    clean, _ = render_camera(full, cf.camera, camera_poses(rig)[cf.camera.name])
    rect, raw = cf.maps, cf.raw
    assert (raw.semantic != clean.semantic).sum() > 200  # the artifacts are there...
    # ... and depth is repaired everywhere (M holds every surface a raw ray skipped)
    assert np.allclose(rect.depth, clean.depth, rtol=0, atol=1e-4)
    # labels: everywhere except glass closer than epsilon to the surface behind it
    d_raw = np.where(raw.depth > 0, raw.depth, np.inf)
    ambiguous = (clean.depth < d_raw) & (d_raw - clean.depth < cfg.epsilon)
    ok = ~ambiguous
    assert (rect.semantic[ok] == clean.semantic[ok]).all()
    assert (rect.instance[ok] == clean.instance[ok]).all()
    assert cf.stats.semantic_mismatch == int((rect.semantic != clean.semantic).sum())
    if fraction == 1.0:  # every thing unlabelled: the car and building come back from M
        assert (raw.semantic == CAR).sum() == 0 and (rect.semantic == CAR).sum() > 50
    # untouched pixels (outside the error region, depth unchanged) are byte-identical to raw
    r = cf.rectification
    untouched = ~r.error_region & ~r.depth_changed
    assert untouched.sum() > 0
    for a, b in [(rect.depth, raw.depth), (rect.semantic, raw.semantic), (rect.instance, raw.instance)]:
        assert a[untouched].tobytes() == b[untouched].tobytes()


def test_rectify_formula_on_hand_made_pixels():
    # four pixels: glass in front (Omega_t), glass within epsilon, omission, sky behind glass
    raw = CameraMaps(np.array([[10.0, 5.01, 7.0, 0.0]], np.float32), np.array([[3, 3, 0, SKY]], np.uint8),
                     np.array([[5, 5, 0, 0]], np.uint32))
    cast = CameraMaps(np.array([[4.0, 5.0, 7.0, 9.0]], np.float32), np.array([[14, 14, 10, 14]], np.uint8),
                      np.array([[7, 7, 0, 8]], np.uint32))
    r = rectify(raw, cast, epsilon=0.05)
    assert r.maps.depth.tolist() == [[4.0, 5.0, 7.0, 9.0]]
    assert r.transparency.tolist() == [[True, False, False, True]]
    assert r.omission.tolist() == [[False, False, True, False]]
    assert r.maps.semantic.tolist() == [[14, 3, 10, 14]]
    assert r.maps.instance.tolist() == [[7, 5, 0, 8]]
    # an omission pixel M does not cover keeps its raw label; no instance map in, none out
    r2 = rectify(CameraMaps(raw.depth, raw.semantic, None),
                 CameraMaps(np.zeros((1, 4), np.float32), cast.semantic, cast.instance), 0.05)
    assert r2.maps.semantic.tolist() == [[3, 3, 0, SKY]] and r2.maps.instance is None
    with pytest.raises(ValueError, match="epsilon"):
        rectify(raw, cast, 0.0)
    with pytest.raises(ValueError, match="differ in size"):
        rectify(raw, CameraMaps(np.zeros((2, 2), np.float32), np.zeros((2, 2), np.uint8), None), 0.05)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31), st.floats(0.01, 1.0))
def test_rectify_properties(seed, eps):
    rng = np.random.default_rng(seed)
    shape = (7, 9)
    d_raw = np.where(rng.random(shape) < 0.2, 0, rng.uniform(1, 50, shape)).astype(np.float32)
    d_rc = np.where(rng.random(shape) < 0.5, 0, rng.uniform(1, 50, shape)).astype(np.float32)
    raw = CameraMaps(d_raw, rng.integers(0, 30, shape).astype(np.uint8), rng.integers(0, 9, shape).astype(np.uint32))
    cast = CameraMaps(d_rc, rng.integers(1, 30, shape).astype(np.uint8), rng.integers(0, 9, shape).astype(np.uint32))
    r = rectify(raw, cast, eps)
    inf = lambda d: np.where(d > 0, d, np.inf)  # noqa: E731
    # depth is the pointwise minimum, never farther than either input
    assert np.array_equal(inf(r.maps.depth), np.minimum(inf(d_raw), inf(d_rc)))
    # labels change only inside the error region, and there only to the ray-cast ones
    changed = (r.maps.semantic != raw.semantic) | (r.maps.instance != raw.instance)
    assert not (changed & ~r.error_region).any()
    assert (r.maps.semantic[changed] == cast.semantic[changed]).all()
    # rectifying the rectified maps again changes nothing more (idempotent on depth)
    r2 = rectify(r.maps, cast, eps)
    assert np.array_equal(r2.maps.depth, r.maps.depth)


def test_compact_mesh_holds_only_glass_and_unlabelled():
    scene = street_scene()
    flags = unlabelled_meshes(scene, CFG.artifacts)
    m = compact_mesh(scene, flags)
    expected = sum(len(s.faces) for s, f in zip(scene, flags) if f or s.transparent)
    assert len(m.faces) == expected and m.transparent.sum() == 2 + 12
    with pytest.raises(ValueError, match="flags"):
        compact_mesh(scene, flags[:2])


def test_unlabelled_fraction_is_stable_per_asset():
    scene = [box([0, 0, 0], [1, 1, 1], CAR, i, asset_id=f"car_{i % 40}") for i in range(200)]
    model = SimulatorArtifacts(unlabelled_classes=(), unlabelled_fraction=0.3, seed=4)
    flags = unlabelled_meshes(scene, model)
    # the same asset is flagged the same way everywhere, and roughly the configured share of assets
    by_asset = {}
    for m, f in zip(scene, flags):
        assert by_asset.setdefault(m.asset_id, f) == f
    share = np.mean(list(by_asset.values()))
    assert 0.1 <= share <= 0.55
    assert all(f == (asset_fraction(m.asset_id, 4) < 0.3) for m, f in zip(scene, flags))
    # stuff is only flagged by class
    stuff = [quad(5, 0, 1, 0, 1, 1, stuff=True, name="road")]
    assert not unlabelled_meshes(stuff, SimulatorArtifacts(unlabelled_classes=(), unlabelled_fraction=1.0)).any()


def test_lidar_scan_hits_a_wall_at_its_range():
    rig = front_rig()
    wall = quad(15.0, -100, 100, -50, 50, BUILDING, 5)
    pts = lidar_scan(RayScene(flatten([wall])), rig.lidar)
    assert len(pts["x"]) > 0
    assert np.allclose(pts["x"], 15.0, atol=1e-3)
    r = np.sqrt(pts["x"] ** 2 + pts["y"] ** 2 + pts["z"] ** 2)
    assert np.allclose(r, pts["distance"], atol=1e-3)
    assert (pts["semantic"] == BUILDING).all() and (pts["instance"] == 5).all()
    # every channel that points at the wall returns, none beyond range
    assert set(np.unique(pts["channel"])) == set(range(rig.lidar.channels))
    far = lidar_scan(RayScene(flatten([quad(100.0, -500, 500, -500, 500, BUILDING, 5)])), rig.lidar)
    assert len(far["x"]) == 0
    assert {k: v.dtype.name for k, v in pts.items()} == {
        "x": "float32", "y": "float32", "z": "float32", "distance": "float32", "semantic": "uint8",
        "instance": "uint32", "channel": "uint8"}


def test_normals_of_a_tilted_plane_match_the_analytic_normal():
    cam = CameraSpec(name="c", width=160, height=90)
    K = np.asarray(cam.intrinsics)
    # plane n . X = -c in the camera frame; depth along each pixel ray
    n = np.array([0.3, -0.5, -1.0])
    n /= np.linalg.norm(n)
    u = np.arange(cam.width) + 0.5
    v = np.arange(cam.height) + 0.5
    x = (u[None, :] - K[0, 2]) / K[0, 0]
    y = (v[:, None] - K[1, 2]) / K[1, 1]
    depth = (10.0 / -(n[0] * x + n[1] * y + n[2])).astype(np.float32)
    depth[:5, :5] = 0  # a patch without a surface
    for version in ("d2nt_basic", "d2nt_v2", "d2nt_v3"):
        N = depth_normals(depth, K, version)
        inner = N[10:-10, 10:-10].reshape(-1, 3)
        assert np.allclose(inner, n, atol=2e-3), version
        assert (N[:6, :6] == 0).all()
    with pytest.raises(ValueError, match="version"):
        depth_normals(depth, K, "d2nt_v9")


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31))
def test_covered_pixels_hold_every_hit(seed):
    # random triangles around the camera, some straddling its plane or behind it: every pixel
    # whose ray hits one lies in the covered set, so culled casting equals full casting
    rng = np.random.default_rng(seed)
    rig = front_rig(96, 32)
    cam = rig.cameras[0]
    pose = camera_poses(rig)[cam.name]
    centre = rng.uniform([-3, -6, -3], [15, 6, 3], size=(12, 1, 3)) + pose[:3, 3]
    V = (centre + rng.normal(scale=rng.uniform(0.2, 4.0), size=(12, 3, 3))).reshape(-1, 3)
    mesh = SceneMesh(V, np.arange(36).reshape(12, 3), CAR, 3, False, False)
    scene = RayScene(flatten([mesh]))
    full, _ = render_camera(scene, cam, pose)
    covered = covered_pixels(flatten([mesh]), cam, pose)
    assert not ((full.depth > 0) & ~covered).any()
    culled, _ = render_camera(scene, cam, pose, pixels=covered)
    assert culled.depth.tobytes() == full.depth.tobytes()
    assert culled.semantic.tobytes() == full.semantic.tobytes()
