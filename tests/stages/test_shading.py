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
