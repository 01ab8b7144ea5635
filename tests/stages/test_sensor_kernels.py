"""The sensors stage's compiled per-pixel kernels against the code they replace: D2NT normals
against the ``d2nt`` package itself (bit for bit), RGB shading against the numpy shading."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from carlaocc.stages.sensors.normals import VERSIONS, depth_normals, reference_normals, to_float16
from tests.raster_ties import agree_with_the_caster


def _depth(seed: int, H: int, W: int) -> np.ndarray:
    """A depth map with what D2NT's branches meet: tilted planes, depth steps, noise, holes,
    equal neighbours (flat runs) and the void along whole rows or columns."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:H, 0:W]
    d = rng.uniform(0.5, 80.0) + rng.normal(0, 0.05) * u + rng.normal(0, 0.05) * v
    d = d + rng.uniform(0, 20.0) * (u > rng.integers(0, W + 1)) + rng.normal(0, 0.02, (H, W)) * rng.integers(0, 2)
    d = np.round(d, int(rng.integers(1, 4))) if rng.random() < 0.3 else d  # flat runs: exact ties
    d = np.maximum(d, 0.1).astype(np.float32)
    d[rng.random((H, W)) < rng.uniform(0, 0.2)] = 0.0
    if rng.random() < 0.2:
        d[: rng.integers(0, H + 1)] = 0.0
    return d


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.integers(1, 24), st.integers(1, 24))
def test_d2nt_kernel_equals_the_d2nt_package(seed, H, W):
    depth = _depth(seed, H, W)
    rng = np.random.default_rng(seed + 1)
    f = rng.uniform(50, 1500)
    K = np.array([[f, 0, rng.uniform(0, W)], [0, f * rng.uniform(0.8, 1.2), rng.uniform(0, H)], [0, 0, 1]])
    for version in VERSIONS:
        ours, ref = depth_normals(depth, K, version), reference_normals(depth, K, version)
        assert ours.dtype == np.float32 and ours.shape == (H, W, 3)
        # the same float32 operations in the same order: the same bits
        assert np.array_equal(ours.view(np.uint32), ref.view(np.uint32)), version


def test_d2nt_kernel_equals_the_package_on_a_camera_image():
    # a full rig image (1408 x 376): the borders, the soft-min's padding and v3's argmin at scale
    from carlaocc.schemas.rig import RigConfig

    cam = RigConfig().cameras[0]
    depth = _depth(7, cam.height, cam.width)
    for version in VERSIONS:
        assert np.array_equal(depth_normals(depth, cam.intrinsics, version), reference_normals(depth, cam.intrinsics, version))


# -- RGB shading -------------------------------------------------------------------------------------
def _random_scene(seed: int):
    """A ground, random boxes (some glass, some textured) and random triangles around a small
    camera, with the camera's rays and clean + raw maps."""
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.schemas.rig import CameraSpec
    from carlaocc.stages.scenes.assembly import flatten
    from carlaocc.stages.sensors.raycast import RayScene, camera_ray_bundle, render_camera

    rng = np.random.default_rng(seed)
    meshes = [SceneMesh(np.array([[-80, -80, -1.7], [80, -80, -1.7], [80, 80, -1.7], [-80, 80, -1.7]], float),
                        np.array([[0, 1, 2], [0, 2, 3]]), 1, 0, True, False, name="road")]
    image = rng.integers(0, 256, (4, 3, 3), dtype=np.uint8)
    for k in range(int(rng.integers(1, 8))):
        lo = rng.uniform([2, -10, -1.7], [30, 10, 2])
        V = lo + rng.uniform(0.2, 6, 3) * np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
        F = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # fmt: skip
        textured = rng.random() < 0.3
        extra = dict(corner_uv=rng.uniform(-1, 2, (12, 3, 2)).astype(np.float32), image=image) if textured else {}
        meshes.append(SceneMesh(V, F, int(rng.choice([3, 14, 20])), k + 1, False, True, name=f"b{k}",
                                transparent=bool(rng.random() < 0.3), color=tuple(int(c) for c in rng.integers(0, 256, 3)),
                                **extra))
    tris = rng.uniform([1, -15, -2], [40, 15, 8], (int(rng.integers(0, 40)), 3, 3))
    if len(tris):
        meshes.append(SceneMesh(tris.reshape(-1, 3), np.arange(3 * len(tris)).reshape(-1, 3), 20, 99, False, True,
                                name="tris"))
    rs = RayScene(flatten(meshes))
    cam = CameraSpec(name="c", x=0.0, y=0.0, z=0.0, width=int(rng.integers(8, 96)), height=int(rng.integers(8, 64)))
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # OpenCV optical frame looking along +x
    clean, raw = render_camera(rs, cam, pose, raw=True)
    origin, dirs = camera_ray_bundle(cam, pose)
    sun = rng.normal(size=3)
    sun[2] = abs(sun[2]) + 0.1
    return rs, origin, dirs, clean, raw, sun / np.linalg.norm(sun), float(rng.uniform(0, 1))


@settings(max_examples=12, deadline=None)
@given(st.integers(0, 2**31))
def test_rgb_kernels_equal_the_numpy_shading(seed):
    from carlaocc.stages.sensors.shading import reference_rgb, render_rgb

    rs, origin, dirs, clean, raw, sun, ambient = _random_scene(seed)
    up = np.array([0.0, 0.0, 1.0])
    ours = render_rgb(rs, origin, dirs, clean, raw, sun, up, ambient)
    ref = reference_rgb(rs, origin, dirs, clean, raw, sun, up, ambient)
    assert ours.dtype == np.uint8 and ours.shape == ref.shape
    # the same float32 operations, but for the Lambert term's dot product n . sun, which the
    # reference leaves to BLAS (its order of summation, or a fused multiply-add, may change the
    # last bit): a byte may then differ by one where a colour sits on a rounding boundary
    diff = np.abs(ours.astype(np.int16) - ref.astype(np.int16))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3
    # the float colours agree to a few float32 ulps, with either ray parameter type
    from carlaocc.stages.sensors.shading import face_normals, reference_shade, shade

    n = face_normals(rs.mesh.vertices, rs.mesh.faces)
    face = raw.face.reshape(-1)
    for t in (raw.depth.reshape(-1), raw.depth.reshape(-1).astype(np.float64)):
        a = shade(rs, origin, dirs, t, face, sun, up, ambient, n)
        b = reference_shade(rs, origin, dirs, t, face, sun, up, ambient, n)
        assert a.dtype == np.float32 and np.allclose(a, b, rtol=4e-7, atol=0)


# -- primary visibility by rasterization --------------------------------------------------------------
@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31))
def test_rasterized_first_hits_equal_the_caster_but_on_ties(seed):
    rs, origin, dirs, clean, raw, sun, ambient = _random_scene(seed)
    from carlaocc.schemas.rig import CameraSpec

    rng = np.random.default_rng(seed)
    cam = CameraSpec(name="c", x=0.0, y=0.0, z=0.0, width=int(rng.integers(8, 96)), height=int(rng.integers(8, 64)))
    # the camera turned a little (rays not on the axes), at a random place among the boxes
    pose = np.eye(4)
    yaw = rng.uniform(-0.5, 0.5)
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pose[:3, :3] = Rz @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    pose[:3, 3] = rng.uniform([-2, -3, -1], [4, 3, 2])
    agree_with_the_caster(rs, cam, pose)


def test_the_tie_rule_lower_triangle_index_and_no_crack_on_a_shared_edge():
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.schemas.rig import CameraSpec
    from carlaocc.stages.scenes.assembly import flatten
    from carlaocc.stages.sensors.raycast import RayScene

    # camera frame = scene frame, looking along +z; pixel column 8's rays have x = 0 exactly
    # (principal point at 17 / 2 = 8 + 0.5)
    cam = CameraSpec(name="c", width=17, height=12, hfov_deg=60.0)
    pose = np.eye(4)
    # a quad at z = 10 split along x = 0 (the shared edge), and a copy of its left half (coplanar)
    left = np.array([[-20, -20, 10], [0, -20, 10], [0, 20, 10], [-20, 20, 10]], float)
    right = left + [20, 0, 0]
    for order in ((left, right), (right, left)):
        meshes = [SceneMesh(q, np.array([[0, 1, 2], [0, 2, 3]]), 3, k + 1, False, True, name=f"q{k}")
                  for k, q in enumerate(order)]
        meshes.append(SceneMesh(left, np.array([[0, 1, 2], [0, 2, 3]]), 3, 9, False, True, name="copy"))
        rs = RayScene(flatten(meshes))
        t, face = rs.first_hits(cam, pose)
        face = face.reshape(cam.height, cam.width)
        # every pixel sees the quad at depth 10 (no crack along the edge or the diagonals)
        assert (face >= 0).all() and np.allclose(t, 10.0)
        # the column through the shared edge: both halves hit at equal depth, the lower index
        # kept whichever half it is
        assert (face[:, 8] < 2).all()
        assert (face[:, :8] < 2).all() == (order[0] is left) and (face[:, 9:] < 2).all() == (order[0] is right)
        # the left half and its copy (triangles 4, 5) coincide: the lower index (the original) is kept
        assert not np.isin(face, [4, 5]).any()


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**31))
def test_raw_maps_through_glass_are_the_casters_but_on_ties(seed):
    # the raw maps continue rays on glass from the caster's own hit: with the caster alone
    # (first_hits cast too) the raw maps are the same wherever the clean triangle is
    import pytest

    from carlaocc.stages.sensors import raycast

    rs, _, _, _, _, _, _ = _random_scene(seed)
    from carlaocc.schemas.rig import CameraSpec

    cam = CameraSpec(name="c", x=0.0, y=0.0, z=0.0, width=64, height=40)
    pose = np.eye(4)
    pose[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    clean, raw = raycast.render_camera(rs, cam, pose, raw=True)

    def cast_first_hits(self, camera, camera_to_scene):
        origin, dirs = raycast.rig_camera_rays(camera, camera_to_scene)
        return self.cast(origin, dirs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(raycast.RayScene, "first_hits", cast_first_hits)
        clean_ref, raw_ref = raycast.render_camera(rs, cam, pose, raw=True)
    same = clean.face == clean_ref.face
    for a, b in ((raw.face, raw_ref.face), (raw.semantic, raw_ref.semantic), (raw.instance, raw_ref.instance)):
        assert np.array_equal(a[same], b[same])
    glass = same & rs.transparent(clean.face.reshape(-1)).reshape(clean.face.shape)
    assert np.array_equal(raw.depth[glass], raw_ref.depth[glass])  # the caster's depths behind glass


# float32 values where float16 rounding has its cases: ties at both ends of the significand,
# the subnormal range and its underflow, overflow, infinities, NaNs with payloads, signed zeros
_HALF_EDGES = np.array([0x00000000, 0x80000000, 0x33000000, 0x33000001, 0x337FFFFF, 0x38000000, 0x387FE000,
                        0x387FF000, 0x387FF001, 0x3F801000, 0x3F803000, 0x3F801001, 0x477FEFFF, 0x477FF000,
                        0x47800000, 0x7F800000, 0xFF800000, 0x7F800001, 0x7FC00000, 0xFF802000, 0x7F801FFF],
                       dtype=np.uint32)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=200), st.integers(0, 2**32 - 1))
def test_float16_rounding_equals_numpys(bits, seed):
    # bit for bit numpy's astype (all 2**32 float32 patterns were compared once, see the
    # docstring's benchmark note); here the edges, random patterns and a dense random sample
    rng = np.random.default_rng(seed)
    x = np.concatenate([_HALF_EDGES, np.array(bits, np.uint32), rng.integers(0, 2**32, 4096, dtype=np.uint32)])
    f = x.view(np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        want = f.astype(np.float16)
    got = to_float16(f.reshape(-1, 1))
    assert got.dtype == np.float16 and got.shape == (len(x), 1)
    assert np.array_equal(got.reshape(-1).view(np.uint16), want.view(np.uint16))


def _exact_first_hits(V, F, rays):
    # every pixel against every triangle, the rasterizer's float64 test in the same order of
    # operations, no screen spans: nearest t > 0, the lower index on equal t
    o = rays[0, :3].astype(np.float64)
    r = rays[:, 3:].astype(np.float64)
    best_t, best_f = np.full(len(r), np.inf), np.full(len(r), -1)
    for f, (ia, ib, ic) in enumerate(F):
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = V[ia] - o, V[ib] - o, V[ic] - o
        n0 = (b1 - a1) * (c2 - a2) - (b2 - a2) * (c1 - a1)
        n1 = (b2 - a2) * (c0 - a0) - (b0 - a0) * (c2 - a2)
        n2 = (b0 - a0) * (c1 - a1) - (b1 - a1) * (c0 - a0)
        if n0 == 0.0 and n1 == 0.0 and n2 == 0.0:
            continue
        na = n0 * a0 + n1 * a1 + n2 * a2
        s0 = (a1 * b2 - a2 * b1) * r[:, 0] + (a2 * b0 - a0 * b2) * r[:, 1] + (a0 * b1 - a1 * b0) * r[:, 2]
        s1 = (b1 * c2 - b2 * c1) * r[:, 0] + (b2 * c0 - b0 * c2) * r[:, 1] + (b0 * c1 - b1 * c0) * r[:, 2]
        s2 = (c1 * a2 - c2 * a1) * r[:, 0] + (c2 * a0 - c0 * a2) * r[:, 1] + (c0 * a1 - c1 * a0) * r[:, 2]
        den = n0 * r[:, 0] + n1 * r[:, 1] + n2 * r[:, 2]
        inside = (((s0 >= 0) & (s1 >= 0) & (s2 >= 0)) | ((s0 <= 0) & (s1 <= 0) & (s2 <= 0))) & (den != 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = na / den
        win = inside & (t > 0) & (t < best_t)
        best_t[win], best_f[win] = t[win], f
    return best_t.astype(np.float32), best_f


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31))
def test_rasterized_screen_spans_miss_no_pixel_of_slivers_and_specks(seed):
    # the screen spans only pick the pixels the exact test sees: on slivers (nearly flat or
    # nearly vertical edges, corners a hair apart), sub-pixel specks, triangles through the
    # camera plane and coplanar copies, the rasterizer equals every pixel tested against every
    # triangle, bit for bit
    from carlaocc.schemas.rig import CameraSpec
    from carlaocc.stages.sensors.raycast import rasterize_first_hits, rig_camera_rays

    rng = np.random.default_rng(seed)
    cam = CameraSpec(name="c", width=int(rng.integers(4, 48)), height=int(rng.integers(4, 32)),
                     hfov_deg=float(rng.uniform(40, 120)))
    pose = np.eye(4)
    yaw, pitch = rng.uniform(-0.3, 0.3, 2)
    Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(pitch), 0, np.sin(pitch)], [0, 1, 0], [-np.sin(pitch), 0, np.cos(pitch)]])
    pose[:3, :3] = Rz @ Ry @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)
    pose[:3, 3] = rng.uniform(-3, 3, 3)
    tris = []
    for _ in range(int(rng.integers(1, 12))):
        # a point in front of the camera (scene frame), then a triangle of one kind around it
        depth = rng.uniform(0.5, 30.0)
        c = pose[:3, 3] + pose[:3, :3] @ np.array([rng.uniform(-1, 1) * depth, rng.uniform(-0.6, 0.6) * depth, depth])
        kind = rng.integers(0, 5)
        if kind == 0:  # a sliver: a long edge and a third corner a hair off it
            d = rng.normal(size=3)
            tris.append([c - d, c + d, c + 1e-4 * rng.normal(size=3)])
        elif kind == 1:  # a speck well under a pixel
            tris.append([c, c + 1e-3 * rng.normal(size=3), c + 1e-3 * rng.normal(size=3)])
        elif kind == 2:  # through the camera plane
            tris.append([c, pose[:3, 3] - pose[:3, :3] @ [0, 0, rng.uniform(0.1, 2)] + rng.normal(size=3),
                         c + rng.normal(size=3)])
        else:
            tris.append([c + rng.normal(size=3) * depth / 4 for _ in range(3)])
        if rng.random() < 0.2:
            tris.append(tris[-1])  # a coplanar copy: the lower index keeps every pixel
    V = np.asarray(tris, np.float64).reshape(-1, 3).astype(np.float32).astype(np.float64)
    F = np.arange(len(V), dtype=np.int64).reshape(-1, 3)
    origin, dirs = rig_camera_rays(cam, pose)
    rays = np.empty((len(dirs), 6), np.float32)
    rays[:, :3], rays[:, 3:] = origin, dirs
    t, f = rasterize_first_hits(V, F, cam, pose, rays)
    t_ref, f_ref = _exact_first_hits(V, F, rays)
    assert np.array_equal(f, f_ref), np.flatnonzero(f != f_ref)[:10]
    assert np.array_equal(t.view(np.uint32), t_ref.view(np.uint32))
