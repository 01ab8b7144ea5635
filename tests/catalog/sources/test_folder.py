"""FolderAdapter over the real test meshes (read-only) and small files written to tmp_path."""

from __future__ import annotations

import os
import shutil

import numpy as np
import pytest
import trimesh

from carlaocc.catalog.sources.base import SourceError
from carlaocc.catalog.sources.folder import FolderAdapter
from carlaocc.schemas.meshes import SourceAsset, SourcePart
from carlaocc.stages.ingest.standardize import StandardizedAsset, standardize
from shared_data import needs, shared_path

MESHES = str(shared_path("meshes"))
pytestmark = needs(MESHES)

MAP = """glob,category,subclass,length_m
kenney-roads/road-*.glb,Road,lane,
kenney-suburban/building-*.glb,building,house,
kenney-retro-urban/detail-light-traffic.glb,traffic_light,,
cesium/CesiumMilkTruck.glb,Truck,box_truck,5.5
trimesh-models/no_indices_3storybuilding.glb,Building,apartment,
trimesh-models/comments.off,Static,bollard,
scenic/*.obj,Car,suv,4.9
"""


@pytest.fixture
def adapter(tmp_path):
    path = tmp_path / "map.csv"
    path.write_text(MAP)
    return FolderAdapter(category_map=str(path))


@pytest.fixture
def items(adapter):
    return {it.key: it for it in adapter.list_items(MESHES)}


def test_lists_every_mesh_file_sorted(adapter, items):
    keys = list(items)
    assert keys == sorted(keys)
    assert "kenney-roads/road-straight.glb" in items
    assert "trimesh-models/unit_cube.STL" in items  # extension case-insensitive
    assert "trimesh-models/chair_model.binvox" not in items
    assert not any(k.endswith((".png", ".txt")) for k in keys)
    # the licence file is part of what defines the item
    assert items["kenney-roads/road-straight.glb"].files[-1].endswith("LICENSE.txt")


def test_kenney_glb_declared_y_up_unknown_units_with_licence(adapter, items):
    a = adapter.read(MESHES, items["kenney-roads/road-straight.glb"])
    assert (a.up, a.forward, a.units) == ("+y", "+z", "unknown")
    assert (a.category, a.subclass, a.source) == ("Road", "lane", "folder")
    assert a.licence == "Creative Commons Zero, CC0"
    assert a.parts[0].texture == "Textures/colormap.png"
    # adapters do not re-orient: the tile is flat in the source's x-z plane (y up)
    ext = np.ptp(a.parts[0].vertices, axis=0)
    assert ext[1] < 0.05 < ext[0]


def test_reads_the_schema_contract_that_standardize_accepts(adapter, items):
    """Adapters return ``carlaocc.schemas.meshes.SourceAsset`` itself; standardization takes it as is."""
    a = adapter.read(MESHES, items["kenney-suburban/building-type-a.glb"])
    assert type(a) is SourceAsset and all(type(p) is SourcePart for p in a.parts)
    assert isinstance(standardize(a), StandardizedAsset)


def test_empty_subclass_defaults_to_first_of_class(adapter, items):
    a = adapter.read(MESHES, items["kenney-retro-urban/detail-light-traffic.glb"])
    assert (a.category, a.subclass) == ("TrafficLight", "vehicle_signal")


def test_cesium_milk_truck_parts_and_textures(adapter, items):
    a = adapter.read(MESHES, items["cesium/CesiumMilkTruck.glb"])
    assert len(a.parts) >= 4
    assert a.target_length == 5.5
    textured = [p for p in a.parts if p.texture]
    assert len(textured) >= 2
    assert all(p.texture == "CesiumMilkTruck.glb#images/0" for p in textured)
    assert {p.material for p in a.parts} >= {"truck", "glass", "wheels"}
    names = [p.name for p in a.parts]
    assert len(set(names)) == len(names)
    for p in a.parts:
        assert p.vertices.dtype == np.float64 and p.faces.dtype == np.int64
        assert p.faces.min() >= 0 and p.faces.max() < len(p.vertices)
    # both wheel nodes instance one mesh: the node transforms are applied
    wheels = [p for p in a.parts if p.material == "wheels"]
    assert len(wheels) == 2
    assert abs(wheels[0].vertices[:, 0].mean() - wheels[1].vertices[:, 0].mean()) > 1.0


def test_non_indexed_glb_is_indexed(adapter, items):
    a = adapter.read(MESHES, items["trimesh-models/no_indices_3storybuilding.glb"])
    assert len(a.parts) == 3
    for p in a.parts:
        assert len(p.vertices) < 3 * len(p.faces)  # welded
    top = max(p.vertices[:, 1].max() for p in a.parts)
    assert top == pytest.approx(9.0)  # node transforms stack the floors


def test_off_with_comments_loads(adapter, items):
    a = adapter.read(MESHES, items["trimesh-models/comments.off"])
    assert (a.up, a.forward) == ("+z", "+x")
    assert sum(len(p.faces) for p in a.parts) == 12


def test_obj_declared_z_up(adapter, items):
    a = adapter.read(MESHES, items["scenic/bmwx5_hull.obj"])
    assert (a.category, a.subclass, a.up, a.forward, a.target_length) == ("Car", "suv", "+z", "+x", 4.9)


def test_unmatched_file_raises_no_category(adapter, items):
    with pytest.raises(SourceError) as e:
        adapter.read(MESHES, items["kenney-roads/sign-highway.glb"])
    assert e.value.reason == "no category"
    assert "add a row to the category map" in e.value.hint


def test_no_map_means_no_category(tmp_path):
    a = FolderAdapter()
    item = next(it for it in a.list_items(MESHES) if it.key.endswith("road-straight.glb"))
    with pytest.raises(SourceError) as e:
        a.read(MESHES, item)
    assert e.value.reason == "no category"


@pytest.mark.parametrize(
    "text, where",
    [
        ("glob,category\nx.glb,Road\n", "line 1"),  # missing column
        ("glob,category,subclass,length_m\nx.glb,Road,lane,long\n", "line 2"),  # bad length
        ("glob,category,subclass\nx.glb,Road,lane\ny.glb,Spaceship,\n", "line 3"),  # unknown class
        ("glob,category,subclass\nx.glb,Road,skyscraper\n", "line 2"),  # not a Road sub-class
        ("glob,category,subclass,lenght_m\nx.glb,Road,lane,3\n", "line 1"),  # unknown column
        ("glob,category,subclass,up,forward\nx.glb,Road,lane,+y,+y\n", "line 2"),  # same axis
        ("", "line 1"),
    ],
)
def test_bad_category_map(tmp_path, text, where):
    path = tmp_path / "map.csv"
    path.write_text(text)
    with pytest.raises(SourceError) as e:
        FolderAdapter(category_map=str(path)).list_items(MESHES)
    assert e.value.reason == "bad category map"
    assert where in e.value.hint


def test_missing_map_file(tmp_path):
    with pytest.raises(SourceError) as e:
        FolderAdapter(category_map=str(tmp_path / "nope.csv")).list_items(MESHES)
    assert e.value.reason == "bad category map"


def _folder(tmp_path, map_text):
    root = tmp_path / "root"
    root.mkdir()
    (root / "map.csv").write_text(map_text)
    return root, FolderAdapter(category_map="map.csv")  # relative to root


def test_truncated_glb_is_unreadable(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*.glb,Truck,box_truck\n")
    data = open(os.path.join(MESHES, "cesium/CesiumMilkTruck.glb"), "rb").read()
    (root / "truncated.glb").write_bytes(data[: len(data) // 2])  # JSON intact, buffer cut
    (root / "header_only.glb").write_bytes(data[:10])
    (root / "empty.glb").write_bytes(b"")
    items = a.list_items(str(root))
    assert [it.key for it in items] == ["empty.glb", "header_only.glb", "truncated.glb"]
    for it in items:
        with pytest.raises(SourceError) as e:
            a.read(str(root), it)
        assert e.value.reason == "unreadable file", it.key


def test_garbage_files_are_unreadable(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bollard\n")
    (root / "bad.ply").write_bytes(b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n1 2")
    (root / "bad.stl").write_bytes(b"solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0")
    (root / "bad.dae").write_text("<COLLADA><library_geometries>")
    (root / "bad.gltf").write_text("{not json")
    for it in a.list_items(str(root)):
        with pytest.raises(SourceError) as e:
            a.read(str(root), it)
        assert e.value.reason == "unreadable file", it.key


def test_missing_file_is_missing_mesh(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bollard\n")
    (root / "gone.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    items = a.list_items(str(root))
    os.remove(root / "gone.obj")
    with pytest.raises(SourceError) as e:
        a.read(str(root), items[0])
    assert e.value.reason == "missing mesh"


def test_first_match_wins_and_map_overrides_axes(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass,up,forward,units\n"
                                "sub/special*.obj,Pole,flagpole,+y,-z,cm\n"
                                "*.obj,Static,bench,,,\n")  # fmt: skip
    (root / "sub").mkdir()
    for name in ("sub/special1.obj", "sub/other.obj"):
        (root / name).write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3 4\n")
    got = {it.key: a.read(str(root), it) for it in a.list_items(str(root))}
    s, o = got["sub/special1.obj"], got["sub/other.obj"]
    assert (s.category, s.subclass, s.up, s.forward, s.units) == ("Pole", "flagpole", "+y", "-z", "cm")
    assert (o.category, o.subclass, o.up, o.forward, o.units) == ("Static", "bench", "+z", "+x", "unknown")
    assert len(o.parts[0].faces) == 2  # quad fan-triangulated


def test_obj_mtl_transparency_and_texture(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Building,house\n")
    (root / "house.obj").write_text(
        "mtllib house.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\n"
        "usemtl brick\nf 1 2 3\nf 1 3 4\nusemtl glass\nf 1 2 5\nusemtl tinted\nf 2 3 5\n"
    )
    (root / "house.mtl").write_text(
        "newmtl brick\nKd 1 0 0\nmap_Kd -s 1 1 1 tex/brick.png\n"
        "newmtl glass\nd 0.3\nnewmtl tinted\nTr 0.2\n"
    )
    [item] = a.list_items(str(root))
    assert any(f.endswith("house.mtl") for f in item.files)
    parts = {p.material: p for p in a.read(str(root), item).parts}
    assert not parts["brick"].transparent and parts["brick"].texture == "tex/brick.png"
    assert parts["glass"].transparent and parts["tinted"].transparent


def test_gltf_blend_and_alpha_are_transparent(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Building,office\n")
    scene = trimesh.Scene()
    for name, kw in {
        "opaque": {"baseColorFactor": [200, 200, 200, 255]},
        "blend": {"alphaMode": "BLEND", "baseColorFactor": [200, 200, 255, 255]},
        "alpha": {"baseColorFactor": [200, 200, 255, 100]},
    }.items():
        box = trimesh.creation.box()
        box.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.PBRMaterial(name=name, **kw))
        scene.add_geometry(box, geom_name=name, node_name=name)
    (root / "glass.glb").write_bytes(scene.export(file_type="glb"))
    [item] = a.list_items(str(root))
    parts = {p.material: p for p in a.read(str(root), item).parts}
    assert not parts["opaque"].transparent
    assert parts["blend"].transparent and parts["alpha"].transparent


def _glb(doc: dict, bin_: bytes = b"") -> bytes:
    import json
    import struct

    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js
    if bin_:
        bin_ += b"\0" * (-len(bin_) % 4)
        body += struct.pack("<II", len(bin_), 0x004E4942) + bin_
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_compressed_geometry_is_not_read_as_zeros(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bench\n")
    for ext in ("EXT_meshopt_compression",) + (("KHR_draco_mesh_compression",) if _no_draco() else ()):
        (root / f"{ext}.glb").write_bytes(_glb({"asset": {"version": "2.0"}, "extensionsUsed": [ext]}))
    for it in a.list_items(str(root)):
        with pytest.raises(SourceError) as e:
            a.read(str(root), it)
        assert e.value.reason == "unreadable file" and "compress" in e.value.hint


def _no_draco() -> bool:
    import importlib.util

    return importlib.util.find_spec("DracoPy") is None


def test_gltf_with_external_buffer(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*.gltf,Static,bench\n")
    box = trimesh.creation.box()
    files = trimesh.Scene(box).export(file_type="gltf")  # {"model.gltf": ..., "gltf_buffer_0.bin": ...}
    for name, data in files.items():
        (root / name).write_bytes(data)
    [item] = a.list_items(str(root))
    assert any(f.endswith(".bin") for f in item.files)
    asset = a.read(str(root), item)
    assert (asset.up, asset.forward) == ("+y", "+z") and len(asset.parts[0].faces) == 12
    for f in item.files[1:]:
        os.remove(f)
    with pytest.raises(SourceError) as e:
        a.read(str(root), item)
    assert e.value.reason == "unreadable file"


def test_licence_from_parent_directory(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bench\n")
    (root / "kit" / "deep").mkdir(parents=True)
    (root / "kit" / "LICENCE-assets.txt").write_text("\n  SPDX-License-Identifier: CC-BY-4.0\n")
    shutil.copy(os.path.join(MESHES, "trimesh-models/comments.off"), root / "kit" / "deep" / "c.off")
    shutil.copy(os.path.join(MESHES, "trimesh-models/comments.off"), root / "top.off")
    got = {it.key: a.read(str(root), it) for it in a.list_items(str(root))}
    assert got["kit/deep/c.off"].licence == "CC-BY-4.0"
    assert got["top.off"].licence == ""


def test_collada_reader(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bench\n")
    (root / "quad.dae").write_text(DAE)
    [item] = a.list_items(str(root))
    asset = a.read(str(root), item)
    assert (asset.up, asset.forward) == ("+z", "+x")  # <up_axis>Z_UP</up_axis>
    parts = {p.material: p for p in asset.parts}
    assert set(parts) == {"Glass", "Wood"}
    assert parts["Glass"].transparent and not parts["Wood"].transparent
    assert parts["Wood"].texture == "textures/wood.jpg"
    # node: translate (10, 0, 0) then scale 2: quad corners at x = 10 .. 12
    wood = parts["Wood"].vertices
    assert wood[:, 0].min() == pytest.approx(10.0) and wood[:, 0].max() == pytest.approx(12.0)
    assert len(parts["Wood"].faces) == 2  # polylist quad fan-triangulated


DAE = """<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit meter="0.0254" name="inch"/><up_axis>Z_UP</up_axis></asset>
  <library_images><image id="img"><init_from>textures/wood.jpg</init_from></image></library_images>
  <library_effects>
    <effect id="wood-fx"><profile_COMMON>
      <newparam sid="surf"><surface type="2D"><init_from>img</init_from></surface></newparam>
      <newparam sid="samp"><sampler2D><source>surf</source></sampler2D></newparam>
      <technique sid="c"><lambert><diffuse><texture texture="samp" texcoord="uv"/></diffuse></lambert></technique>
    </profile_COMMON></effect>
    <effect id="glass-fx"><profile_COMMON><technique sid="c"><phong>
      <diffuse><color>0.5 0.6 0.9 1</color></diffuse>
      <transparent opaque="A_ONE"><color>1 1 1 0.4</color></transparent>
      <transparency><float>1</float></transparency>
    </phong></technique></profile_COMMON></effect>
  </library_effects>
  <library_materials>
    <material id="wood-mat" name="Wood"><instance_effect url="#wood-fx"/></material>
    <material id="glass-mat" name="Glass"><instance_effect url="#glass-fx"/></material>
  </library_materials>
  <library_geometries><geometry id="quad"><mesh>
    <source id="pos"><float_array id="pos-a" count="12">0 0 0 1 0 0 1 1 0 0 1 0</float_array>
      <technique_common><accessor source="#pos-a" count="4" stride="3"/></technique_common></source>
    <vertices id="verts"><input semantic="POSITION" source="#pos"/></vertices>
    <polylist material="woodsym" count="1"><input semantic="VERTEX" source="#verts" offset="0"/>
      <vcount>4</vcount><p>0 1 2 3</p></polylist>
    <triangles material="glasssym" count="1"><input semantic="VERTEX" source="#verts" offset="0"/>
      <input semantic="NORMAL" source="#verts" offset="1"/><p>0 0 1 0 2 0</p></triangles>
  </mesh></geometry></library_geometries>
  <library_visual_scenes><visual_scene id="scene">
    <node id="n" name="quad"><translate>10 0 0</translate><scale>2 2 2</scale>
      <instance_geometry url="#quad"><bind_material><technique_common>
        <instance_material symbol="woodsym" target="#wood-mat"/>
        <instance_material symbol="glasssym" target="#glass-mat"/>
      </technique_common></bind_material></instance_geometry>
    </node>
  </visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#scene"/></scene>
</COLLADA>
"""


# -- issue 17: missing side files are noted, a dataset root inside the folder is skipped ------

_TETRA = "v 0 0 0\nv 4 0 0\nv 0 2 0\nv 0 0 1.5\nusemtl paint\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def test_missing_mtl_and_texture_are_noted_not_fatal(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*.obj,Car,sedan\n")
    (root / "no_mtl.obj").write_text("mtllib no_mtl.mtl\n" + _TETRA)
    (root / "no_tex.obj").write_text("mtllib no_tex.mtl\n" + _TETRA)
    (root / "no_tex.mtl").write_text("newmtl paint\nKd 1 0 0\nmap_Kd tex/paint.png\n")
    (root / "whole.obj").write_text("mtllib whole.mtl\n" + _TETRA)
    (root / "whole.mtl").write_text("newmtl paint\nKd 1 0 0\nmap_Kd paint.png\n")
    (root / "paint.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (root / "plain.obj").write_text(_TETRA)  # names no library: nothing is missing
    got = {it.key: a.read(str(root), it) for it in a.list_items(str(root))}
    assert got["no_mtl.obj"].notes == (
        "no_mtl.obj: material library 'no_mtl.mtl' not found (materials default: no transparency or texture)",)
    assert got["no_tex.obj"].notes == ("no_tex.obj: texture 'tex/paint.png' not found (kept by reference)",)
    assert got["whole.obj"].notes == () and got["plain.obj"].notes == ()
    # the geometry is whole: standardized, with the note on the asset record
    s = standardize(got["no_mtl.obj"])
    assert isinstance(s, StandardizedAsset) and "material library 'no_mtl.mtl' not found" in s.asset.notes


def test_missing_gltf_texture_is_noted(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*.glb,Static,bench\n")
    shutil.copy(os.path.join(MESHES, "kenney-retro-urban/detail-bench.glb"), root / "bench.glb")  # no Textures/
    [item] = a.list_items(str(root))
    notes = a.read(str(root), item).notes
    assert notes == ("bench.glb: texture 'Textures/metal.png' not found (kept by reference)",
                     "bench.glb: texture 'Textures/planks.png' not found (kept by reference)")


def test_excluded_directories_are_not_listed(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bollard\n")
    for rel in ("a.obj", "sub/b.obj", "data/admesh/meshes/0123.glb", "data/x.obj", "database/c.obj"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(_TETRA)
    keys = lambda **kw: [it.key for it in a.list_items(str(root), **kw)]  # noqa: E731
    assert "data/x.obj" in keys()
    # the excluded tree goes, a sibling whose name merely starts the same stays
    assert keys(exclude=(str(root / "data"),)) == ["a.obj", "database/c.obj", "sub/b.obj"]
    assert keys(exclude=(str(root),)) == []  # the dataset root is the source itself
    assert keys(exclude=(str(tmp_path / "elsewhere"),)) == keys()


def test_excluded_directory_reached_through_a_link_is_still_excluded(tmp_path):
    root, a = _folder(tmp_path, "glob,category,subclass\n*,Static,bollard\n")
    (root / "data").mkdir()
    (root / "data" / "x.obj").write_text(_TETRA)
    (root / "a.obj").write_text(_TETRA)
    link = tmp_path / "link"
    link.symlink_to(root)  # the source given through a link, the root by its real path
    assert [it.key for it in a.list_items(str(link), exclude=(str(root / "data"),))] == ["a.obj"]


def test_obj_colours_are_the_mtl_kd_or_none():
    """trimesh invents a grey diffuse for OBJ materials without Kd (or without an MTL): parts
    carry the MTL's Kd, else no colour (the cameras then shade them in their class colour)."""
    from carlaocc.catalog.sources._common import load_parts
    from shared_data import require, shared_path

    chair = require(shared_path("meshes/trimesh-models/chair_model.obj"))  # its MTL is missing
    assert all(p.color is None for p in load_parts(str(chair)))
