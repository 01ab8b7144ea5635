"""Panoptic meshes as GLB (catalog.panoptic): exact round trip, opens in trimesh, layering."""

from __future__ import annotations

import ast
import io
import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from carlaocc.catalog import panoptic
from carlaocc.catalog.panoptic import TRANSPARENT_ALPHA, load_panoptic_glb, panoptic_glb_bytes
from carlaocc.schemas import taxonomy

ROOT = Path(__file__).resolve().parents[2]


def mesh(seed=0, n_faces=300, n_vertices=200):
    """A random mesh with shared vertices across groups and interleaved groups of faces."""
    rng = np.random.default_rng(seed)
    V = rng.uniform(-80, 80, (n_vertices, 3))
    F = np.stack([rng.choice(n_vertices, 3, replace=False) for _ in range(n_faces)])
    labels = [(1, 0, False), (14, 7, False), (14, 7, True), (3, 2**31 + 5, False), (24, 0, False), (12, 123456, True)]
    pick = rng.integers(0, len(labels), n_faces)
    sem = np.array([labels[k][0] for k in pick], dtype=np.uint8)
    inst = np.array([labels[k][1] for k in pick], dtype=np.uint32)
    transp = np.array([labels[k][2] for k in pick], dtype=bool)
    return V, F, sem, inst, transp


def grouped(sem, inst, transp) -> np.ndarray:
    """Reference face order of the file: groups by first face, faces stable within a group."""
    keys = list(zip(sem.tolist(), inst.tolist(), transp.tolist()))
    first = {}
    for k in keys:
        first.setdefault(k, len(first))
    return np.array(sorted(range(len(keys)), key=lambda i: (first[keys[i]], i)))


def test_round_trip_exact():
    V, F, sem, inst, transp = mesh()
    data = panoptic_glb_bytes(V, F, sem, inst, transp)
    V2, F2, sem2, inst2, transp2 = load_panoptic_glb(data)
    order = grouped(sem, inst, transp)
    assert (V2.dtype, F2.dtype, sem2.dtype, inst2.dtype, transp2.dtype) == (np.float64, np.int64, np.uint8, np.uint32, bool)
    np.testing.assert_array_equal(sem2, sem[order])
    np.testing.assert_array_equal(inst2, inst[order])  # 2**31 + 5 survives: exact uint32
    np.testing.assert_array_equal(transp2, transp[order])
    # every triangle's corners exactly as float32 rounding of the input
    np.testing.assert_array_equal(V2[F2], V.astype(np.float32).astype(np.float64)[F[order]])
    # vertices are unshared across groups: a vertex belongs to one (semantic, instance, transparent)
    owner = {}
    for f, key in zip(F2, zip(sem2, inst2, transp2)):
        for v in f:
            assert owner.setdefault(int(v), key) == key
    assert len(V2) > len(np.unique(F))  # some vertices were shared by groups, hence duplicated


def test_already_grouped_input_keeps_face_order_and_is_deterministic():
    V, F, sem, inst, transp = mesh(seed=1)
    order = grouped(sem, inst, transp)
    args = (V, F[order], sem[order], inst[order], transp[order])
    data = panoptic_glb_bytes(*args)
    assert data == panoptic_glb_bytes(*args)
    V2, F2, sem2, inst2, _ = load_panoptic_glb(data)
    np.testing.assert_array_equal(sem2, args[2])
    np.testing.assert_array_equal(inst2, args[3])
    np.testing.assert_allclose(V2[F2], V[F[order]], atol=1e-4)


def test_trimesh_opens_it_y_up_with_ids():
    V, F, sem, inst, transp = mesh(seed=2)
    data = panoptic_glb_bytes(V, F, sem, inst, transp)
    scene = trimesh.load(io.BytesIO(data), file_type="glb")
    assert isinstance(scene, trimesh.Scene)
    groups = set(zip(sem.tolist(), inst.tolist(), transp.tolist()))
    assert len(scene.geometry) == len(groups)
    assert sum(len(g.faces) for g in scene.geometry.values()) == len(F)
    seen = set()
    for g in scene.geometry.values():
        md = g.metadata
        key = (md["semantic_id"], md["instance_id"], md["transparent"])
        seen.add(key)
        assert md["class"] == taxonomy.by_id(key[0]).name
        # the custom attributes, one value per vertex (float32: exact below 2**24)
        np.testing.assert_array_equal(g.vertex_attributes["_SEMANTIC"], key[0])
        if key[1] < 2**24:
            np.testing.assert_array_equal(g.vertex_attributes["_INSTANCE"], key[1])
        # glTF is Y-up: (x, y, z) -> (x, z, -y)
        mine = (sem == key[0]) & (inst == key[1]) & (transp == key[2])
        z_up = V[np.unique(F[mine])]
        np.testing.assert_allclose(g.vertices, np.stack([z_up[:, 0], z_up[:, 2], -z_up[:, 1]], axis=1), atol=1e-4)
    assert seen == groups


def test_materials_colours_and_alpha():
    V, F, sem, inst, transp = mesh(seed=3)
    gltf, _ = panoptic._unpack(panoptic_glb_bytes(V, F, sem, inst, transp, palette={1: (1, 2, 3)}))
    assert gltf["asset"]["version"] == "2.0"
    assert gltf["scenes"][0]["extras"]["format"] == "carlaocc-panoptic"
    for m in gltf["meshes"]:
        ex = m["primitives"][0]["extras"]
        mat = gltf["materials"][m["primitives"][0]["material"]]
        rgb = (1, 2, 3) if ex["semantic_id"] == 1 else taxonomy.by_id(ex["semantic_id"]).color
        np.testing.assert_allclose(mat["pbrMetallicRoughness"]["baseColorFactor"],
                                   [c / 255 for c in rgb] + [TRANSPARENT_ALPHA if ex["transparent"] else 1.0])  # fmt: skip
        assert mat["alphaMode"] == ("BLEND" if ex["transparent"] else "OPAQUE")
        # spec: no UNSIGNED_INT vertex attributes; every view 4-byte aligned
        for name, acc in m["primitives"][0]["attributes"].items():
            assert gltf["accessors"][acc]["componentType"] != 5125, name
    assert all(v["byteOffset"] % 4 == 0 for v in gltf["bufferViews"])
    # one material per (class, transparent)
    assert len(gltf["materials"]) == len(set(zip(sem.tolist(), transp.tolist())))


def test_ids_from_attributes_when_extras_are_missing():
    V, F, sem, inst, transp = mesh(seed=4)
    inst = np.where(inst > 2**24, 99, inst).astype(np.uint32)  # float32 attributes are exact below 2**24
    gltf, blob = panoptic._unpack(panoptic_glb_bytes(V, F, sem, inst, transp))
    for group in (gltf["nodes"], gltf["meshes"], [p for m in gltf["meshes"] for p in m["primitives"]]):
        for item in group:
            item.pop("extras")
    V2, F2, sem2, inst2, _ = load_panoptic_glb(panoptic._pack(gltf, blob))
    order = grouped(sem, inst, transp)
    np.testing.assert_array_equal(sem2, sem[order])
    np.testing.assert_array_equal(inst2, inst[order])
    np.testing.assert_allclose(V2[F2], V[F[order]], atol=1e-4)


def test_empty_mesh_and_bad_input():
    z = np.zeros((0, 3))
    V, F, sem, inst, transp = load_panoptic_glb(panoptic_glb_bytes(z, z.astype(int), [], [], []))
    assert V.shape == (0, 3) and F.shape == (0, 3) and len(sem) == len(inst) == len(transp) == 0
    V, F, sem, inst, transp = mesh(n_faces=4)
    with pytest.raises(ValueError, match="semantic"):
        panoptic_glb_bytes(V, F, np.array([1, 2, 300, 4]), inst, transp)
    with pytest.raises(ValueError, match="face index"):
        panoptic_glb_bytes(V[:2], F, sem, inst, transp)
    with pytest.raises(ValueError, match="instance has 3"):
        panoptic_glb_bytes(V, F, sem, inst[:3], transp)
    with pytest.raises(ValueError, match="not a GLB"):
        load_panoptic_glb(b"PK\x03\x04 not a gltf at all")


def test_glb_container_is_well_formed():
    data = panoptic_glb_bytes(*mesh(seed=5))
    magic, version, length = data[:4], *struct.unpack_from("<II", data, 4)
    assert (magic, version, length) == (b"glTF", 2, len(data)) and len(data) % 4 == 0
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_len % 4 == 0
    gltf = json.loads(data[20 : 20 + json_len])
    bin_len, bin_type = struct.unpack_from("<II", data, 20 + json_len)
    assert bin_type == 0x004E4942 and bin_len >= gltf["buffers"][0]["byteLength"]


def test_catalog_panoptic_imports_no_stages():
    tree = ast.parse((ROOT / "catalog" / "panoptic.py").read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module]
    mods = {m.removeprefix("carlaocc.").split(".")[0] for m in names}
    assert not mods & {"stages", "pipeline", "dask", "distributed", "typer"}
