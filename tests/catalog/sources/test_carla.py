"""CarlaAdapter: Unreal's left-handed centimetre frame converted once into ours."""

from __future__ import annotations

import json

import numpy as np
import pytest

from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.carla import CarlaAdapter, rotator_matrix, write_example_export
from carlaocc.schemas.taxonomy import by_name


def signed_volume(v, f):
    return float(np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6.0)


@pytest.fixture
def export(tmp_path):
    return write_example_export(str(tmp_path / "export"))


@pytest.fixture
def assets(export):
    a = CarlaAdapter()
    return {it.key: a.read(export, it) for it in a.list_items(export)}


def test_items_and_files(export):
    items = CarlaAdapter().list_items(export)
    assert [it.key for it in items] == ["car", "traffic_light"]
    car = items[0]
    assert car.files[0].endswith("car.json")
    assert sum(f.endswith("wheel.obj") for f in car.files) == 1
    assert any(f.endswith("windshield.mtl") for f in car.files)


def test_declared_in_our_frame(assets):
    for a in assets.values():
        assert (a.units, a.up, a.forward, a.normalized) == ("m", "+z", "+x", False)
    tl = assets["traffic_light"]
    assert (tl.category, tl.subclass, tl.licence) == ("TrafficLight", "vehicle_signal", "CC0-1.0 (carlaocc example)")
    assert (assets["car"].category, assets["car"].subclass) == ("Car", "sedan")  # tag given as id 14


def test_traffic_light_geometry(assets):
    parts = {p.name: p for p in assets["traffic_light"].parts}
    pole, head, arm = parts["pole"].vertices, parts["head"].vertices, parts["arm"].vertices
    # the pole stands upright: 4 m tall, 0.2 m wide, from the ground
    assert pole[:, 2].min() == pytest.approx(0.0) and pole[:, 2].max() == pytest.approx(4.0)
    assert np.ptp(pole[:, 0]) == pytest.approx(0.2, abs=1e-6) and np.ptp(pole[:, 1]) <= 0.2 + 1e-6
    # the head hangs at 2.85..3.75 m, centred 1 m to Unreal's right (+y) = our -y
    centre = (head.min(0) + head.max(0)) / 2
    assert centre == pytest.approx([0.0, -1.0, 3.3], abs=1e-9)
    assert head[:, 2].min() == pytest.approx(2.85) and head[:, 2].max() == pytest.approx(3.75)
    assert np.ptp(head, axis=0) == pytest.approx([0.3, 0.3, 0.9])  # yaw +90 then -90: unturned
    # the arm (yaw 90 about the pole top) reaches from the pole to the head along our -y
    assert arm[:, 1].min() == pytest.approx(-1.0) and arm[:, 1].max() == pytest.approx(0.0)
    assert parts["pole"].semantic_id == parts["arm"].semantic_id == by_name("Pole").id
    assert parts["head"].semantic_id is None


def test_car_geometry(assets):
    parts = {p.name: p for p in assets["car"].parts}
    body = parts["body"].vertices
    assert body.min(0) == pytest.approx([-2.25, -0.9, 0.3]) and body.max(0) == pytest.approx([2.25, 0.9, 1.5])
    # wheel_fl sits at Unreal y = -80 cm (left): ours +0.8 m; rolled 90: axle along y
    fl = parts["wheel_fl"].vertices
    assert (fl.min(0) + fl.max(0)) / 2 == pytest.approx([1.4, 0.8, 0.35], abs=1e-9)
    assert np.ptp(fl, axis=0) == pytest.approx([0.7, 0.22, 0.7], abs=0.01)
    assert parts["windshield"].transparent and parts["windshield"].material == "glass"
    assert not parts["body"].transparent


def test_winding_stays_outward(assets):
    for asset in assets.values():
        for p in asset.parts:
            assert signed_volume(p.vertices, p.faces) > 0, p.name


def test_negative_scale_keeps_outward(export):
    path = f"{export}/objects/traffic_light.json"
    doc = json.load(open(path))
    doc["components"][0]["scale"] = [1, -1, 1]  # a mirrored component
    json.dump(doc, open(path, "w"))
    a = CarlaAdapter()
    item = next(it for it in a.list_items(export) if it.key == "traffic_light")
    for p in a.read(export, item).parts:
        assert signed_volume(p.vertices, p.faces) > 0, p.name


def test_rotator_conventions():
    x, y, z = np.eye(3)
    assert rotator_matrix(0, 90, 0) @ x == pytest.approx(y)  # yaw turns x toward +y
    assert rotator_matrix(90, 0, 0) @ x == pytest.approx(z)  # pitch raises x
    assert rotator_matrix(0, 0, 90) @ y == pytest.approx(-z)  # roll turns y toward -z
    r = rotator_matrix(10, 20, 30)
    assert r.T @ r == pytest.approx(np.eye(3)) and np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize(
    "change, reason",
    [
        (lambda d: d.pop("semantic_tag"), "no category"),
        (lambda d: d.update(semantic_tag="Spaceship"), "bad metadata"),
        (lambda d: d.update(subclass="tanker"), "bad metadata"),
        (lambda d: d["components"][2].update(parent="nobody"), "bad metadata"),
        (lambda d: d["components"][0].update(parent="head"), "bad metadata"),  # cycle
        (lambda d: d["components"][1].update(location=[1, 2]), "bad metadata"),
        (lambda d: d["components"][1].update(mesh="meshes/gone.obj"), "missing mesh"),
        (lambda d: d["components"][1].update(semantic_tag=99), "bad metadata"),
    ],
)
def test_bad_objects(export, change, reason):
    path = f"{export}/objects/traffic_light.json"
    doc = json.load(open(path))
    change(doc)
    json.dump(doc, open(path, "w"))
    a = CarlaAdapter()
    item = next(it for it in a.list_items(export) if it.key == "traffic_light")
    with pytest.raises(SourceError) as e:
        a.read(export, item)
    assert e.value.reason == reason


def test_malformed_json_is_listed_then_reported(export):
    with open(f"{export}/objects/broken.json", "w") as f:
        f.write("{")
    a = CarlaAdapter()
    items = {it.key: it for it in a.list_items(export)}
    assert "broken" in items
    with pytest.raises(SourceError) as e:
        a.read(export, items["broken"])
    assert e.value.reason == "bad metadata"


def test_not_an_export(tmp_path):
    with pytest.raises(SourceError):
        CarlaAdapter().list_items(str(tmp_path))


def test_textures_and_material_colours_come_with_their_corners(export):
    """An OBJ with ``vt`` corners and an MTL ``map_Kd``: each triangle corner keeps the texture
    coordinates of its own vertex through the frame change (which re-winds every triangle)."""
    from PIL import Image

    import trimesh

    mesh = trimesh.creation.box(extents=(450.0, 180.0, 120.0))
    v, f = np.asarray(mesh.vertices) + (0, 0, 90), np.asarray(mesh.faces)
    u = (v[:, 0] + 225.0) / 450.0  # along the car, in Unreal's x
    w = (v[:, 2] - 30.0) / 120.0  # up
    lines = ["mtllib body.mtl", "usemtl paint"]
    lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in zip(u, w)]
    lines += [f"f {i + 1}/{i + 1} {j + 1}/{j + 1} {k + 1}/{k + 1}" for i, j, k in f]
    (open(f"{export}/meshes/body.obj", "w")).write("\n".join(lines) + "\n")
    open(f"{export}/meshes/body.mtl", "w").write("newmtl paint\nKd 1 1 1\nmap_Kd tex/paint.png\n")
    import os

    os.makedirs(f"{export}/meshes/tex")
    Image.fromarray(np.array([[[200, 0, 0], [0, 0, 200]]], np.uint8)).save(f"{export}/meshes/tex/paint.png")
    a = CarlaAdapter()
    car = a.read(export, next(it for it in a.list_items(export) if it.key == "car"))
    body = next(p for p in car.parts if p.name == "body")
    assert body.texture == "tex/paint.png" and body.color == (255, 255, 255, 255)
    assert body.image.shape == (1, 2, 3) and body.corner_uv.shape == (len(body.faces), 3, 2)
    corners = body.vertices[body.faces]  # ours: metres, y mirrored; x and z as Unreal's / 100
    np.testing.assert_allclose(body.corner_uv[..., 0], (corners[..., 0] * 100 + 225.0) / 450.0, atol=1e-5)
    np.testing.assert_allclose(body.corner_uv[..., 1], (corners[..., 2] * 100 - 30.0) / 120.0, atol=1e-5)
    assert signed_volume(body.vertices, body.faces) > 0  # still outward
    # the windshield's MTL colour (Kd 0.6 0.7 0.8), no texture
    shield = next(p for p in car.parts if p.name == "windshield")
    assert shield.color == (153, 178, 204, 255) and shield.image is None
    # a texture file that is missing: kept by reference, no image, no coordinates
    os.remove(f"{export}/meshes/tex/paint.png")
    body = next(p for p in a.read(export, next(it for it in a.list_items(export) if it.key == "car")).parts
                if p.name == "body")
    assert body.texture == "tex/paint.png" and body.image is None and body.corner_uv is None
