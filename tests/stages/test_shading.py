"""Camera RGB shading (stages/sensors/shading.py) on small hand-made scenes: colours follow the
materials the semantic map says a pixel sees, shadows fall away from the sun, glass tints, the
sky brightens towards the horizon, and the same scene gives the same bytes."""

from __future__ import annotations

import numpy as np
import pytest

from carlaocc.schemas import taxonomy
from carlaocc.schemas.meshes import SceneMesh
from carlaocc.schemas.rig import RigConfig
from carlaocc.stages.scenes.assembly import flatten
from carlaocc.stages.sensors.raycast import RayScene, camera_ray_bundle, render_camera
from carlaocc.stages.sensors.shading import CLASS_BASE, face_normals, render_rgb, shade, sun_direction

ROAD, CAR, BUILDING = (taxonomy.by_name(n).id for n in ("Road", "Car", "Building"))
BOX_F = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])  # fmt: skip


def box(lo, hi):
    V = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], float)
    return V, BOX_F.copy()


def ground(z=-1.73, half=60.0):
    V = np.array([[-half, -half, z], [half, -half, z], [-half, half, z], [half, half, z]], float)
    return V, np.array([[0, 1, 3], [0, 3, 2]])


def scene(glass=False):
    """A road (default grey: asphalt), a red car box 10 m ahead, a building block to the left."""
    meshes = [SceneMesh(*ground(), ROAD, 0, True, False, name="road"),
              SceneMesh(*box([8, -1, -1.73], [12, 1, -0.23]), CAR, 7, False, True, name="car", color=(200, 30, 30)),
              SceneMesh(*box([5, 6, -1.73], [20, 12, 8]), BUILDING, 0, True, True, name="house", color=(90, 160, 90))]
    if glass:  # a window pane between the camera and the car
        meshes.append(SceneMesh(*box([4, -2, -1.5], [4.05, 2, 0.5]), CAR, 9, False, True, name="glass",
                                transparent=True, color=(200, 200, 255)))
    return RayScene(flatten(meshes))


def _render(rs, sun=(0.0, 0.0, 1.0), cam="camera_00"):
    from carlaocc.stages.sensors import camera_poses

    rig = RigConfig()
    spec = next(c for c in rig.cameras if c.name == cam)
    pose = camera_poses(rig)[cam]
    clean, raw = render_camera(rs, spec, pose, raw=True)
    origin, dirs = camera_ray_bundle(spec, pose)
    s = np.asarray(sun, float) / np.linalg.norm(sun)
    return render_rgb(rs, origin, dirs, clean, raw, s, np.array([0.0, 0.0, 1.0]), 0.35), clean


def test_pixels_take_the_material_the_semantic_map_sees():
    rgb, clean = _render(scene(), sun=(0.3, -0.2, 1.0))
    pix = rgb.reshape(-1, 3).astype(float)
    sem = clean.semantic.reshape(-1)
    for cls, base in ((CAR, (200, 30, 30)), (BUILDING, (90, 160, 90)), (ROAD, CLASS_BASE["Road"])):
        seen = pix[sem == cls]
        assert len(seen) > 100, cls
        # shading scales the base colour: the same chromaticity up to rounding
        want = np.asarray(base, float) / np.sum(base)
        got = seen / seen.sum(axis=1, keepdims=True)
        assert np.abs(got - want).max() < 0.02, (cls, got.mean(axis=0), want)
    # no surface: the sky, blue above
    sky = pix[sem == taxonomy.by_name("Sky").id]
    assert len(sky) and (sky[:, 2] > sky[:, 0]).all()


def test_shadows_fall_away_from_the_sun():
    rs = scene()
    normals = face_normals(rs.mesh.vertices, rs.mesh.faces)
    # rays straight down onto the road along y = 0, either side of the car (x 8..12)
    xs = np.array([6.0, 7.5, 12.5, 14.0])
    origins = np.column_stack([xs, np.zeros(4), np.full(4, 5.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (4, 1))
    t, face = rs.cast(origins, dirs)
    sun = sun_direction(0.0, 30.0, np.eye(3))  # low in the +x sky: shadows towards -x
    up = np.array([0.0, 0.0, 1.0])
    out = np.stack([shade(rs, origins[k], dirs[k:k + 1], t[k:k + 1].astype(float), face[k:k + 1], sun, up, 0.35,
                          normals)[0] for k in range(4)])
    assert (rs.labels(face)[0] == ROAD).all()
    lum = out.sum(axis=1)
    # just behind the car (-x side) is in its shadow: ambient only; the sun side and far away are lit
    assert lum[1] == pytest.approx(0.35 * sum(CLASS_BASE["Road"]))
    assert lum[2] > lum[1] * 1.5 and lum[3] > lum[1] * 1.5
    # the sun on the other side moves the shadow to the other side
    sun2 = sun_direction(180.0, 30.0, np.eye(3))
    out2 = np.stack([shade(rs, origins[k], dirs[k:k + 1], t[k:k + 1].astype(float), face[k:k + 1], sun2, up, 0.35,
                           normals)[0] for k in range(4)])
    assert out2[2].sum() == pytest.approx(0.35 * sum(CLASS_BASE["Road"])) and out2[1].sum() > out2[2].sum() * 1.5


def test_glass_tints_and_does_not_cast_shadows():
    a, clean = _render(scene(), sun=(0.0, 0.0, 1.0))
    b, clean_g = _render(scene(glass=True), sun=(0.0, 0.0, 1.0))
    behind = clean_g.face >= 0
    behind &= np.isin(clean_g.face, np.flatnonzero(scene(glass=True).mesh.transparent))
    assert behind.sum() > 100
    # the pane changes the pixels it covers (tinted), not the others
    assert (a[behind] != b[behind]).any(axis=1).mean() > 0.9
    assert np.array_equal(a[~behind], b[~behind])


def test_same_scene_same_bytes_and_sun_in_the_scene_frame():
    a, _ = _render(scene(), sun=(0.5, 0.5, 1.0))
    b, _ = _render(scene(), sun=(0.5, 0.5, 1.0))
    assert a.tobytes() == b.tobytes()
    # the sun's world direction turned into a yawed frame
    R = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # world -> scene, a quarter turn
    assert np.allclose(sun_direction(90.0, 0.0, R), [1.0, 0.0, 0.0])
    assert np.allclose(sun_direction(0.0, 90.0, np.eye(3)), [0.0, 0.0, 1.0])


# --------------------------------------------------------------------------------------------
# textures
# --------------------------------------------------------------------------------------------

QUADRANTS = np.array([[[220, 30, 30], [30, 200, 40]],      # top row of the image: red, green
                      [[30, 60, 220], [230, 210, 40]]], np.uint8)  # bottom row: blue, yellow  # fmt: skip


def textured_wall(x=10.0, y=3.0, z0=-1.0, z1=3.0):
    """A wall facing the camera (-x), u from left (+y) to right (-y), v from bottom to top, with
    the 2x2 :data:`QUADRANTS` texture: its top-left texel should appear top-left in the image."""
    V = np.array([[x, y, z0], [x, -y, z0], [x, -y, z1], [x, y, z1]], float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)[F]
    return SceneMesh(V, F, BUILDING, 0, True, False, name="wall", color=(255, 255, 255), corner_uv=uv,
                     image=QUADRANTS)


def test_textures_appear_the_right_way_round_and_up():
    rs = RayScene(flatten([SceneMesh(*ground(), ROAD, 0, True, False, name="road"), textured_wall(x=25.0)]))
    rgb, clean = _render(rs, sun=(-1.0, 0.0, 0.3))
    wall = clean.semantic == BUILDING
    rows, cols = np.nonzero(wall)
    # the whole wall in view (a plane facing the camera maps its middle to the image's middle)
    assert rows.min() > 0 and cols.min() > 0 and rows.max() < wall.shape[0] - 1 and cols.max() < wall.shape[1] - 1
    rm, cm = (rows.min() + rows.max()) / 2, (cols.min() + cols.max()) / 2
    for (top, left), texel in (((True, True), QUADRANTS[0, 0]), ((True, False), QUADRANTS[0, 1]),
                               ((False, True), QUADRANTS[1, 0]), ((False, False), QUADRANTS[1, 1])):
        # (the pixels within 2 of a midline may see either texel)
        r = np.arange(wall.shape[0])[:, None] - rm
        c = np.arange(wall.shape[1])[None, :] - cm
        sel = wall & ((r < -2) if top else (r > 2)) & ((c < -2) if left else (c > 2))
        seen = rgb[sel].astype(float)
        assert len(seen) > 50
        # lit evenly (one plane): the texel's colour times one light factor, up to rounding
        want = texel / texel.sum()
        got = seen / seen.sum(axis=1, keepdims=True)
        assert np.abs(got - want).max() < 0.02, (top, left, got.mean(axis=0), want)


def test_texture_times_material_colour_and_untextured_meshes_unchanged():
    plain = [SceneMesh(*ground(), ROAD, 0, True, False, name="road"),
             SceneMesh(*box([8, -1, -1.73], [12, 1, -0.23]), CAR, 7, False, True, name="car", color=(200, 30, 30))]
    a, _ = _render(RayScene(flatten(plain)), sun=(0.3, -0.2, 1.0))
    # a textured mesh off camera: nothing else changes
    far = textured_wall(x=-50.0)
    b, _ = _render(RayScene(flatten(plain + [far])), sun=(0.3, -0.2, 1.0))
    assert np.array_equal(a, b)
    # the material colour multiplies the texture (a half-grey factor halves it)
    white = textured_wall()
    half = SceneMesh(white.vertices, white.faces, BUILDING, 0, True, False, name="wall", color=(128, 128, 128),
                     corner_uv=white.corner_uv, image=white.image)
    c, clean = _render(RayScene(flatten([white])), sun=(-1.0, 0.0, 0.3))
    d, _ = _render(RayScene(flatten([half])), sun=(-1.0, 0.0, 0.3))
    wall = clean.semantic == BUILDING
    ratio = d[wall].astype(float).sum() / c[wall].astype(float).sum()
    assert ratio == pytest.approx(128 / 255, abs=0.01)


def test_barycentric_recovers_the_weights_and_sampling_repeats():
    from carlaocc.stages.sensors.shading import barycentric, sample_texture

    rng = np.random.default_rng(3)
    tri = rng.normal(size=(200, 3, 3)) * 5.0
    w = rng.dirichlet([1.0, 1.0, 1.0], size=200)
    p = np.einsum("nk,nkj->nj", w, tri)
    np.testing.assert_allclose(barycentric(tri, p), w, atol=1e-6)
    # outside the triangle: clipped onto it, weights still sum to 1
    out = barycentric(tri, p + np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))  # off the plane
    np.testing.assert_allclose(out.sum(axis=1), 1.0)
    np.testing.assert_allclose(out, w, atol=1e-6)  # the plane's projection is the same point
    # u right, v up; u 1.25 repeats to 0.25
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.25, 0.25], [0.75, 0.25], [1.25, -0.25]])
    got = sample_texture(QUADRANTS, uv)
    np.testing.assert_array_equal(got[:4], QUADRANTS.reshape(4, 3))
    np.testing.assert_array_equal(got[4], QUADRANTS[0, 0])  # v -0.25 repeats to 0.75: the top row
