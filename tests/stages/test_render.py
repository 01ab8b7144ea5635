"""Headless preview rendering: framing, colours, transparency, determinism; the asset and camera
sheets (titles, keys, the pixels inside their panels)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from carlaocc.schemas.meshes import MeshPart
from carlaocc.stages.render.assets import render_asset

WHITE = np.array([255, 255, 255], dtype=np.uint8)


def _part(mesh: trimesh.Trimesh, color=(200, 30, 30, 255), transparent=False, name="p") -> MeshPart:
    return MeshPart(name=name, vertices=mesh.vertices, faces=mesh.faces, semantic_id=14, color=color,
                    transparent=transparent)  # fmt: skip


def _box(extents, centre=(0.0, 0.0, 0.0), **kw) -> MeshPart:
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(np.asarray(centre) + (0.0, 0.0, extents[2] / 2))
    return _part(m, **kw)


def _foreground(img: np.ndarray, background=WHITE) -> np.ndarray:
    return np.any(img != background, axis=2)


def test_red_box_is_red_in_the_middle_and_background_at_the_corners():
    img = render_asset([_box((1.0, 1.0, 1.0), color=(220, 20, 20, 255))], size=(96, 128))
    assert img.shape == (96, 128, 3) and img.dtype == np.uint8
    r, g, b = (int(v) for v in img[48, 64])
    assert r > 90 and r > g + 60 and r > b + 60
    for y, x in ((0, 0), (0, -1), (-1, 0), (-1, -1)):
        assert (img[y, x] == WHITE).all()
    # the box fills a good part of the frame (it is fitted to the image with a margin)
    fg = _foreground(img)
    assert 0.15 < fg.mean() < 0.9
    assert not fg[:3].any() and not fg[:, :3].any()


def test_background_colour_and_empty_input():
    bg = (10, 20, 30)
    img = render_asset([_box((1.0, 2.0, 0.5))], size=64, background=bg)
    assert (img[0, 0] == bg).all()
    empty = render_asset([], size=(8, 12), background=bg)
    assert empty.shape == (8, 12, 3) and (empty == np.array(bg, dtype=np.uint8)).all()


def test_rendering_is_deterministic():
    parts = [_box((4.0, 1.8, 1.2), color=(30, 60, 160, 255)),
             _box((2.0, 1.6, 0.5), centre=(0.0, 0.0, 1.2), color=(140, 180, 210, 110), transparent=True)]  # fmt: skip
    a = render_asset(parts, size=(64, 80))
    b = render_asset(parts, size=(64, 80))
    assert a.tobytes() == b.tobytes()
    assert render_asset(parts, size=(64, 80), azimuth_deg=40.0).tobytes() != a.tobytes()


def test_tall_pole_renders_taller_than_wide():
    pole = trimesh.creation.cylinder(radius=0.1, height=8.0, sections=12)
    pole.apply_translation((0.0, 0.0, 4.0))
    img = render_asset([_part(pole, color=(120, 120, 125, 255))], size=(128, 128), shadow=False)
    ys, xs = np.nonzero(_foreground(img))
    height, width = ys.max() - ys.min() + 1, xs.max() - xs.min() + 1
    assert height > 4 * width
    assert height > 0.8 * 128  # it is framed to fill the image height


def test_shading_differs_between_faces_and_shadow_darkens_the_ground():
    img = render_asset([_box((1.0, 1.0, 1.0), color=(200, 200, 200, 255))], size=(128, 128), shadow=True)
    greys = {tuple(int(v) for v in img[y, x]) for y, x in zip(*np.nonzero(_foreground(img)))}
    assert len(greys) >= 3  # the top and two side faces are lit differently (plus edges, shadow)
    no_shadow = render_asset([_box((1.0, 1.0, 1.0), color=(200, 200, 200, 255))], size=(128, 128), shadow=False)
    assert _foreground(img).sum() > _foreground(no_shadow).sum()


def test_transparent_parts_are_blended():
    glass = dict(color=(60, 90, 200, 110), transparent=True)
    solid = dict(color=(60, 90, 200, 255), transparent=False)
    see_through = render_asset([_box((1.0, 1.0, 1.0), **glass)], size=64, shadow=False)
    opaque = render_asset([_box((1.0, 1.0, 1.0), **solid)], size=64, shadow=False)
    c = (32, 32)
    assert (see_through[c] != WHITE).any()
    assert int(see_through[c].astype(int).sum()) > int(opaque[c].astype(int).sum())  # lighter: background shows
    # glass in front of a red box lets the red through
    red = _box((1.0, 1.0, 1.0), color=(220, 20, 20, 255))
    front = _box((0.2, 1.4, 1.4), centre=(1.0, 0.0, -0.2), **glass)
    behind = render_asset([red, front], size=64, azimuth_deg=0.0, elevation_deg=5.0, shadow=False)
    r, g, b = (int(v) for v in behind[32, 32])
    assert r > b - 40 and (r, g, b) != tuple(int(v) for v in opaque[c])


def test_twenty_thousand_triangles_render():
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=1.0)  # 20 480 triangles
    assert len(sphere.faces) >= 20_000
    img = render_asset([_part(sphere, color=(90, 160, 90, 255))], size=(256, 256))
    fg = _foreground(img)
    assert fg[128, 128] and fg.mean() > 0.3


def test_asset_sheet_titles_and_class_key():
    from carlaocc.schemas.taxonomy import by_name, palette
    from carlaocc.stages.render.assets import asset_sheet

    car, glass = by_name("Car").id, by_name("Pole").id
    images = [np.full((30, 40, 3), v, np.uint8) for v in (10, 60, 110, 160, 210)]
    labels = [f"Car/high_seq {k}" for k in range(5)]
    sheet = asset_sheet(images, labels, {car, glass, 999}, columns=3, translucent=True)
    assert sheet.titles == labels  # text as given ("high_seq" in a real font)
    (key,) = sheet.keys  # one key, on the first row
    assert key.labels == ["Pole", "Car", "translucent: glass (drawn see-through)"]
    assert key.entries[1].colours == (tuple(palette()[car]),)
    # three panels on the first row, two on the second, each image drawn as it is
    assert [b[0] for b in sheet.boxes] == [sheet.boxes[0][0]] * 3 + [sheet.boxes[3][0]] * 2
    for (r0, r1, c0, c1), im in zip(sheet.boxes, images):
        assert (sheet.image[r0:r1, c0:c1] == im).all()
    with pytest.raises(ValueError, match="labels"):
        asset_sheet(images, labels[:2], {car})


def test_project_skeletons_and_draw():
    from carlaocc.stages.render.sensors import draw_skeletons, project_skeletons

    K = [[100.0, 0.0, 50.0], [0.0, 100.0, 20.0], [0.0, 0.0, 1.0]]
    depth = np.full((40, 100), 10.0, dtype=np.float32)
    depth[:, :30] = 2.0  # a wall in front of the left part of the image
    # one walker: a joint straight ahead at 5 m, one to the left (behind the wall), one behind the camera
    joints = np.array([[[0.0, 0.0, 5.0], [-1.5, 0.0, 5.0], [0.0, 0.0, -1.0]]])
    uv, visible = project_skeletons(joints, K, depth)
    np.testing.assert_allclose(uv[0, 0], [50.0, 20.0])
    np.testing.assert_allclose(uv[0, 1], [20.0, 20.0])
    assert np.isnan(uv[0, 2]).all()
    assert visible[0].tolist() == [True, False, False]
    image = np.zeros((40, 100, 3), dtype=np.uint8)
    out = draw_skeletons(image, uv, visible, [(0, 1), (1, 2)], step=1)
    assert tuple(out[20, 50]) == (255, 255, 255)  # the visible joint
    assert tuple(out[20, 20]) == (140, 140, 140)  # the hidden one, grey
    assert tuple(out[20, 35]) == (140, 140, 140)  # the bone between them (one end hidden): grey
    assert not image.any()  # the input is left as it is


def _camera_views():
    """Two 40 x 60 cameras: a road (class Road) under a car (instance 7) at 5 m, sky above (no
    surface), normals facing the camera."""
    from carlaocc.schemas.taxonomy import by_name
    from carlaocc.stages.render.sensors import CameraView

    road, car = by_name("Road").id, by_name("Car").id
    depth = np.zeros((40, 60), np.float32)
    depth[20:] = 2.0
    depth[10:30, 20:40] = 5.0
    sem = np.zeros((40, 60), np.uint8)
    sem[20:] = road
    sem[10:30, 20:40] = car
    inst = np.where(sem == car, 7, 0).astype(np.uint32)
    normal = np.zeros((40, 60, 3), np.float32)
    normal[depth > 0] = (0.0, 0.0, -1.0)
    return [CameraView(name, depth, sem, inst, normal, direction=d)
            for name, d in (("camera_00", "front, stereo left (with camera_01)"), ("camera_03", "right"))]


def test_sensor_sheet_titles_keys_and_pixels():
    from carlaocc.schemas.taxonomy import by_name, palette
    from carlaocc.stages.render.colours import instance_colors
    from carlaocc.stages.render.sensors import depth_image, sensor_sheet

    views = _camera_views()
    sheet = sensor_sheet(views, step=1)
    # every panel names its camera and the direction it faces
    assert sheet.titles[:2] == ["camera_00 (front, stereo left (with camera_01)): depth", "camera_03 (right): depth"]
    assert [t.split(": ")[-1] for t in sheet.titles] == ["depth"] * 2 + ["normal"] * 2 + ["semantic"] * 2 + ["instance"] * 2
    depth, normal, semantic, instance = sheet.keys
    # depth: a scale in metres whose tick positions follow the ramp sqrt(1 m / depth)
    ticks = dict((label, pos) for pos, label in depth.scale.ticks)
    assert ticks["5"] == pytest.approx(np.sqrt(1 / 5)) and ticks["80"] == pytest.approx(np.sqrt(1 / 80))
    # the scale's colour at 5 m is the colour the depth map draws at 5 m
    k = int(round(np.sqrt(1 / 5) * 63))
    assert np.abs(depth.scale.colours[k].astype(int) - depth_image(np.array([[1 / (k / 63) ** 2]]))[0, 0]).max() <= 1
    assert ("no surface", ((0, 0, 0),)) in [(e.label, e.colours) for e in depth.entries]
    # normals: a surface facing the camera is (128, 128, 255), as the maps draw it
    assert normal.entries[0].label == "faces the camera" and normal.entries[0].colours == ((128, 128, 255),)
    assert [e.label for e in semantic.entries] == ["Road", "Car"]
    car = by_name("Car").id
    assert semantic.entries[1].colours == (tuple(palette()[car]),)
    assert instance.entries[0].kind == "instances" and instance.entries[0].colours == (tuple(int(v) for v in instance_colors(7)),)
    # pixels inside the panels are the maps' colours, one sheet pixel per map pixel
    r0, r1, c0, c1 = sheet.boxes[0]
    assert (r1 - r0, c1 - c0) == (40, 60)
    assert (sheet.image[r0 + 20, c0 + 30] == depth_image(np.array([[5.0]]))[0, 0]).all()
    assert (sheet.image[r0 + 2, c0 + 2] == 0).all()
    r0, r1, c0, c1 = sheet.boxes[5]  # camera_03 semantic
    assert (sheet.image[r0 + 35, c0 + 5] == palette()[by_name("Road").id]).all()
    r0, r1, c0, c1 = sheet.boxes[7]  # camera_03 instance: the car in its instance colour
    assert (sheet.image[r0 + 20, c0 + 30] == instance_colors(7)).all()


def test_sensor_sheet_rgb_row_and_repair_tints():
    import dataclasses

    from carlaocc.stages.render.sensors import OMISSION_TINT, sensor_sheet

    rgb = np.zeros((40, 60, 3), np.uint8)
    rgb[:, :, 1] = 200
    views = [dataclasses.replace(v, rgb=rgb, depth_raw=v.depth, semantic_raw=v.semantic) for v in _camera_views()]
    sheet = sensor_sheet(views, step=2)
    assert sheet.titles[0] == "camera_00 (front, stereo left (with camera_01)): rgb"
    r0, r1, c0, c1 = sheet.boxes[0]
    assert (r1 - r0, c1 - c0) == (20, 30) and (sheet.image[r0:r1, c0:c1] == rgb[::2, ::2]).all()
    keys = {t.split(": ")[-1]: k for t, k in zip(sheet.titles[::2], sheet.keys)}
    assert set(keys) == {"rgb", "depth", "normal", "semantic", "instance", "raw depth", "rectified depth",
                         "raw semantic", "rectified semantic"}
    assert ("omission region (no raw label)", (OMISSION_TINT,)) in [(e.label, e.colours) for e in keys["raw semantic"].entries]
