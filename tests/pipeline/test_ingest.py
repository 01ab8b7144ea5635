"""`carlaocc ingest`: one task per source item, bad items quarantined with their reason while the
batch goes on, unchanged items skipped, a changed file re-ingested alone, vanished items pruned,
duplicates stored once as aliases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from carlaocc.catalog.sql import query
from carlaocc.catalog.store import Store
from carlaocc.pipeline.cli import app
from shared_data import require, shared_path

cli = CliRunner()


def _glb(mesh: trimesh.Trimesh) -> bytes:
    return trimesh.Scene([mesh]).export(file_type="glb")


def _car(length=4.5) -> trimesh.Trimesh:
    # glTF: +Y up, the front faces +Z; so width along x, height along y, length along z
    return trimesh.creation.box((1.9, 1.5, length))


@pytest.fixture
def source(tmp_path):
    src = tmp_path / "src"
    (src / "cars").mkdir(parents=True)
    (src / "cars" / "a.glb").write_bytes(_glb(_car(4.5)))
    # the same geometry under another node name: other bytes, one asset
    (src / "cars" / "a_copy.glb").write_bytes(trimesh.Scene({"other_name": _car(4.5)}).export(file_type="glb"))
    (src / "cars" / "b.glb").write_bytes(_glb(_car(4.1)))
    (src / "cars" / "huge.glb").write_bytes(_glb(trimesh.creation.box((1.9, 1.5, 10_000.0))))  # a 10 km "car"
    (src / "cars" / "broken.glb").write_bytes(_glb(_car())[:100])  # truncated
    nan = _car()
    nan.vertices[0] = [np.nan, 0, 0]
    (src / "cars" / "nan.obj").write_text(nan.export(file_type="obj"))
    (src / "cars" / "empty.obj").write_text("# no geometry\nv 0 0 0\n")
    (src / "misc").mkdir()
    (src / "misc" / "thing.stl").write_bytes(trimesh.creation.box((1, 1, 1)).export(file_type="stl"))
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\ncars/*.glb,Car,sedan\ncars/*.obj,Car,sedan\n")
    return src, cmap


def _ingest(src, cmap, root, *extra):
    return cli.invoke(app, ["ingest", "folder", str(src), "--category-map", str(cmap), "--root", str(root),
                            "--scheduler", "synchronous", *extra])


def test_batch_quarantines_bad_items_and_keeps_going(source, tmp_path):
    src, cmap = source
    root = Store(str(tmp_path / "data"))
    r = _ingest(src, cmap, root.url)
    assert r.exit_code == 0, r.output
    _, rows = query(root, "SELECT source_path, reason, hint FROM quarantine ORDER BY source_path")
    reasons = {p.split("/")[-1].split("#")[0]: reason for p, reason, _ in rows}
    assert set(reasons) == {"huge.glb", "broken.glb", "nan.obj", "empty.obj", "thing.stl"}
    assert "absurd size" in reasons["huge.glb"]
    assert "unreadable" in reasons["broken.glb"]
    assert "finite" in reasons["nan.obj"]
    assert "empty" in reasons["empty.obj"]
    assert reasons["thing.stl"] == "no category"
    assert all(hint for _, _, hint in rows)
    # the good ones: a and its copy are one asset with an alias
    _, rows = query(root, "SELECT source_path, aliases, category, round(extent[1], 2) FROM assets ORDER BY extent[1]")
    assert len(rows) == 2
    assert rows[1][0].endswith("a.glb") and [p.split("/")[-1] for p in rows[1][1]] == ["a_copy.glb"]
    assert rows[0][3] == pytest.approx(4.1, abs=0.01) and rows[1][3] == pytest.approx(4.5, abs=0.01)
    _, rows = query(root, "SELECT count(*) FROM parts")
    assert rows[0][0] == 2


def test_rerun_skips_unchanged_and_reingests_changed_and_prunes(source, tmp_path):
    src, cmap = source
    root = Store(str(tmp_path / "data"))
    assert _ingest(src, cmap, root.url).exit_code == 0
    r = _ingest(src, cmap, root.url)
    assert "0 ingested now, 8 unchanged" in r.output
    # one file changes: only it is re-ingested
    (src / "cars" / "b.glb").write_bytes(_glb(_car(3.9)))
    r = _ingest(src, cmap, root.url)
    assert "1 ingested now, 7 unchanged" in r.output
    _, rows = query(root, "SELECT round(extent[1], 2) FROM assets ORDER BY 1")
    assert rows[0][0] == pytest.approx(3.9, abs=0.01)
    # a bad file fixed leaves quarantine; a removed file leaves the library
    (src / "cars" / "nan.obj").write_text(_car(4.0).export(file_type="obj"))
    (src / "cars" / "b.glb").unlink()
    r = _ingest(src, cmap, root.url)
    assert r.exit_code == 0 and "pruned" in r.output
    _, rows = query(root, "SELECT source_path FROM quarantine")
    assert not any("nan.obj" in p for (p,) in rows)
    _, rows = query(root, "SELECT source_path FROM assets")
    names = sorted(p.split("/")[-1] for (p,) in rows)
    assert names == ["a.glb", "nan.obj"]
    # no standardized mesh is left that no asset references (b's old GLB, nan's none)
    _, rows = query(root, "SELECT mesh_path FROM assets")
    on_disk = sorted(root.glob("admesh/meshes", ".glb"))
    assert on_disk == sorted(p for (p,) in rows)


def test_odd_files_are_quarantined_or_skipped_never_fatal(tmp_path):
    import os

    src = tmp_path / "odd"
    src.mkdir()
    (src / "good car ü.glb").write_bytes(_glb(_car(4.5)))  # spaces and unicode
    (src / "flat.obj").write_text("v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n")  # 2-component vertices
    os.symlink(src / "loop_b.obj", src / "loop_a.obj")
    os.symlink(src / "loop_a.obj", src / "loop_b.obj")
    os.mkfifo(src / "pipe.obj")  # would block a reader forever
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\n*,Car,sedan\n")
    root = Store(str(tmp_path / "data"))
    r = _ingest(src, cmap, root.url)
    assert r.exit_code == 0, r.output
    _, rows = query(root, "SELECT source_path FROM assets")
    assert [p.split("/")[-1] for (p,) in rows] == ["good car ü.glb"]
    _, rows = query(root, "SELECT source_path, reason FROM quarantine ORDER BY 1")
    got = {p.split("/")[-1]: reason for p, reason in rows}
    assert set(got) == {"flat.obj", "loop_a.obj", "loop_b.obj"}  # the FIFO is never opened


def test_category_map_edits_reingest_only_the_items_they_touch(source, tmp_path):
    src, cmap = source
    root = Store(str(tmp_path / "data"))
    assert _ingest(src, cmap, root.url).exit_code == 0
    # a comment-free append of an unrelated row: no item's matched row changes
    cmap.write_text(cmap.read_text() + "misc/*.ply,Static,bench\n")
    assert "0 ingested now" in _ingest(src, cmap, root.url).output
    # the .stl row now matches: only thing.stl is re-ingested
    cmap.write_text(cmap.read_text() + "misc/*.stl,Static,bollard\n")
    r = _ingest(src, cmap, root.url)
    assert "1 ingested now" in r.output, r.output


def test_unusable_sources_exit_2(source, tmp_path):
    src, cmap = source
    bad = tmp_path / "bad.csv"
    bad.write_text("glob,category\ncars/*.glb,Car\n")
    for args in (["folder", str(tmp_path / "nope")], ["nosuchkind", str(src)],
                 ["folder", str(src), "--category-map", str(bad)],
                 ["folder", str(src), "--category-map", str(tmp_path / "missing.csv")]):
        r = cli.invoke(app, ["ingest", *args, "--root", str(tmp_path / "data")])
        assert r.exit_code == 2, (args, r.output)
        assert r.output.startswith("error:") and "Traceback" not in r.output
    assert not (tmp_path / "data").exists()


def test_carla_export_through_the_cli(tmp_path):
    """The documented CARLA export (made here by the adapter's example writer) assembles
    hierarchically, converts once to our frame, and keeps part-level classes."""
    from carlaocc.catalog.sources.carla import write_example_export

    export = write_example_export(str(tmp_path / "export"))
    root = Store(str(tmp_path / "data"))
    r = cli.invoke(app, ["ingest", "carla", export, "--root", root.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    _, rows = query(root, "SELECT a.category, p.name, c.name, p.transparent FROM parts p JOIN assets a USING (asset_id) "
                          "JOIN classes c ON c.id = p.semantic_id ORDER BY 1, 2")
    parts = {(cat, name): (cls, tr) for cat, name, cls, tr in rows}
    assert parts[("TrafficLight", "pole")][0] == "Pole"  # a part's class may differ from its asset's
    assert parts[("TrafficLight", "head")][0] == "TrafficLight"
    assert parts[("Car", "windshield")][1] is True
    _, rows = query(root, "SELECT category, round(extent[3], 2), scale_rule FROM assets WHERE category = 'TrafficLight'")
    (cat, height, rule), = rows
    assert height > 3.5 and "declared units m" in rule  # converted once from Unreal centimetres


def test_meshfleet_rows_without_mesh_are_reported_not_fatal(tmp_path):
    import csv as csvlib
    import os

    csv = str(require(shared_path("meshfleet/meshfleet_with_vehicle_categories_df.csv")))
    with open(csv, newline="") as fh:
        first = next(csvlib.DictReader(fh))
    meshes = tmp_path / "meshfleet"
    meshes.mkdir()
    sha = first["sha256"]
    (meshes / f"{sha}.glb").write_bytes(_glb(_car(4.4)))
    os.symlink(csv, meshes / "meshfleet.csv")
    root = Store(str(tmp_path / "data"))
    r = cli.invoke(app, ["ingest", "meshfleet", str(meshes), "--root", root.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    _, rows = query(root, "SELECT reason, count(*) FROM quarantine GROUP BY 1")
    counts = dict(rows)
    assert counts.get("missing mesh", 0) >= 1000
    _, rows = query(root, "SELECT count(*), min(licence) FROM assets")
    assert rows[0][0] == 1 and rows[0][1] == first["license"] if "license" in first else rows[0][0] == 1


def test_shapenet_model_in_its_own_frame_comes_out_upright_and_forward(tmp_path):
    """ShapeNetCore v2 models are normalized, +Y up, front facing -Z: the BMW hull (ours: +X
    forward, +Z up) written in that frame must come back long along X, upright, at car size."""
    import json

    from carlaocc.stages.ingest.standardize import rotation_to_asset_frame

    hull = str(require(shared_path("meshes/scenic/bmwx5_hull.obj")))
    car = trimesh.load(hull, force="mesh")
    R = rotation_to_asset_frame("+y", "-z")  # ShapeNet -> ours; its transpose: ours -> ShapeNet
    v = (car.vertices - car.vertices.mean(axis=0)) @ R  # row vectors: v @ R == (R.T @ v.T).T
    v /= np.linalg.norm(v.max(axis=0) - v.min(axis=0))  # normalized: unit bounding-box diagonal
    root = tmp_path / "ShapeNetCore.v2"
    d = root / "02958343" / "bmw0001" / "models"
    d.mkdir(parents=True)
    (d / "model_normalized.obj").write_text(trimesh.Trimesh(v, car.faces, process=False).export(file_type="obj"))
    (root / "taxonomy.json").write_text(json.dumps([{"synsetId": "02958343", "name": "car,auto", "children": []}]))
    store = Store(str(tmp_path / "data"))
    r = cli.invoke(app, ["ingest", "shapenet", str(root), "--root", store.url, "--scheduler", "synchronous"])
    assert r.exit_code == 0, r.output
    _, rows = query(store, "SELECT extent, scale_rule, notes FROM assets")
    (extent, rule, notes), = rows
    assert rule.startswith("normalized")
    assert extent[0] > extent[1] and extent[0] > extent[2]  # long along X
    assert extent[0] == pytest.approx(4.5, rel=0.15)  # a plausible car length
    assert extent[2] == pytest.approx(4.5 * 1.835 / 4.853, rel=0.05)  # upright: its height on Z
    assert "quarter" not in notes  # no correction needed: the declared frame was right


def test_textures_come_through_ingest_and_colour_the_cameras(tmp_path):
    """A Kenney house (glTF with an external colormap texture) and a milk truck (texture embedded
    in the GLB): each asset's texture is stored beside its mesh, comes back with the geometry the
    scenes use, and under flat light every camera pixel of the house is a colour of its texture."""
    import shutil

    from carlaocc.catalog.textures import TextureStore
    from carlaocc.pipeline.tasks.frame import load_geometry
    from carlaocc.schemas import taxonomy
    from carlaocc.schemas.meshes import SceneMesh
    from carlaocc.stages.scenes.assembly import flatten
    from carlaocc.stages.sensors.raycast import RayScene, camera_ray_bundle, render_camera
    from carlaocc.stages.sensors.shading import render_rgb

    house = require(shared_path("meshes/kenney-suburban/building-type-a.glb"))
    atlas = require(shared_path("meshes/kenney-suburban/Textures/colormap.png"))
    truck = require(shared_path("meshes/cesium/CesiumMilkTruck.glb"))
    src = tmp_path / "src"
    (src / "houses" / "Textures").mkdir(parents=True)
    (src / "trucks").mkdir()
    shutil.copy(house, src / "houses" / house.name)
    shutil.copy(atlas, src / "houses" / "Textures" / atlas.name)
    shutil.copy(truck, src / "trucks" / truck.name)
    cmap = tmp_path / "map.csv"
    cmap.write_text("glob,category,subclass\nhouses/*.glb,Building,house\ntrucks/*.glb,Truck,box_truck\n")
    root = Store(str(tmp_path / "data"))
    r = _ingest(src, cmap, root.url)
    assert r.exit_code == 0, r.output
    _, rows = query(root, "SELECT asset_id, category, texture_path FROM assets ORDER BY category")
    assert [c for _, c, _ in rows] == ["Building", "Truck"] and all(t for _, _, t in rows), rows
    for aid, _, rel in rows:
        assert rel == f"admesh/textures/{aid}.npz" and root.exists(rel)
    house_id, truck_id = rows[0][0], rows[1][0]
    # the truck's texture was embedded in its GLB; its two untextured parts keep their colours
    truck_tex = TextureStore(root).load(rows[1][2])
    _, parts = query(root, f"SELECT part_index, color FROM parts WHERE asset_id = '{truck_id}' ORDER BY 1")
    untextured = [k for k, _ in parts if k not in truck_tex]
    assert truck_tex and untextured and all(list(c) != [200, 200, 200, 255] for k, c in parts if k in untextured)

    geometry = load_geometry(root, {house_id}, [])
    (part,) = geometry[house_id].parts
    atlas_rgb = np.asarray(__import__("PIL.Image", fromlist=["Image"]).open(atlas).convert("RGBA").convert("RGB"))
    assert part.image is not None and np.array_equal(part.image, atlas_rgb)
    assert part.corner_uv.shape == (len(part.faces), 3, 2)

    # the house 14 m ahead of the front camera, under flat light (ambient 1: colour = texel)
    from carlaocc.schemas.rig import RigConfig
    from carlaocc.stages.sensors import camera_poses

    V = part.vertices + [14.0, 0.0, -1.7]
    rs = RayScene(flatten([SceneMesh(V, part.faces, taxonomy.by_name("Building").id, 0, True, True,
                                     color=part.color[:3], corner_uv=part.corner_uv, image=part.image)]))
    rig = RigConfig()
    spec = next(c for c in rig.cameras if c.name == "camera_00")
    pose = camera_poses(rig)[spec.name]
    clean, _ = render_camera(rs, spec, pose, raw=False)
    origin, dirs = camera_ray_bundle(spec, pose)
    rgb = render_rgb(rs, origin, dirs, clean, None, np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0]), 1.0)
    seen = rgb[clean.face >= 0].reshape(-1, 3)
    assert len(seen) > 1000
    palette = {tuple(c) for c in atlas_rgb.reshape(-1, 3)}
    colours = {tuple(int(v) for v in c) for c in np.unique(seen, axis=0)}
    assert colours <= palette and len(colours) >= 4, (len(colours), colours - palette)

    # the truck's three textured parts share one atlas: stored once, loaded as one array
    import zipfile

    members = zipfile.ZipFile(root.path(rows[1][2])).namelist()
    assert sum(m.startswith("image_") for m in members) == 1 and sum(m.startswith("same_") for m in members) == 2
    truck_parts = load_geometry(root, {truck_id}, [])[truck_id].parts
    images = [p.image for p in truck_parts if p.image is not None]
    assert len(images) == 3 and all(im is images[0] for im in images)

    # a texture is part of the item: changed, the item is ingested again, as another asset (same
    # geometry, another look); a copy of the house with the original atlas is a third asset
    inverted = 255 - atlas_rgb
    __import__("PIL.Image", fromlist=["Image"]).fromarray(inverted).save(src / "houses" / "Textures" / atlas.name)
    r = _ingest(src, cmap, root.url)
    assert "1 ingested now, 1 unchanged" in r.output, r.output
    _, rows2 = query(root, "SELECT asset_id, texture_path FROM assets WHERE category = 'Building'")
    (new_id, new_rel), = rows2
    assert new_id != house_id and np.array_equal(TextureStore(root).load(new_rel)[0][1], inverted)
    assert not root.exists(rows[0][2])  # the old texture left with its asset

    # the item removed: its mesh and texture leave the library
    (src / "houses" / house.name).unlink()
    assert _ingest(src, cmap, root.url).exit_code == 0
    assert sorted(root.glob("admesh/textures", ".npz")) == [rows[1][2]]
