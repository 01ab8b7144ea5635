"""Panoptic meshes (triangles with per-face semantic and instance ids) as GLB files.

Used to inspect a frame's assembled scene (LiDAR frame) and the whole town's static mesh (world
frame). Plain arrays in and out, so this module knows nothing of ``stages``.

Layout (glTF 2.0 binary, written here without a glTF library so that every byte is ours):

* One node -> one mesh -> one triangle primitive per **group** of faces sharing
  ``(semantic, instance, transparent)``. Groups come in order of their first face; a group's
  faces keep their input order. A group's vertices are the input vertices its faces use (in
  ascending input index), so a vertex used by two groups is written twice and every vertex of a
  primitive carries its faces' ids.
* Primitive, mesh and node ``extras``: ``{"semantic_id", "instance_id", "class",
  "transparent"}`` -- the exact ids, authoritative when reading back.
* Custom vertex attributes ``_SEMANTIC`` and ``_INSTANCE``, **float32 scalars** (for shaders and
  viewers: trimesh loads them into ``vertex_attributes``, three.js into ``geometry.attributes``).
  glTF forbids UNSIGNED_INT for vertex attributes (it is for indices only) and requires 4-byte
  aligned attribute elements, so float32 is the portable choice: it represents every id below
  2**24 exactly; larger instance ids are rounded there and exact only in ``extras``.
* One material per (class, transparent) pair: the taxonomy colour (or ``palette``), opaque, or
  alpha :data:`TRANSPARENT_ALPHA` with ``alphaMode: BLEND`` for transparent parts; double-sided
  (stuff is open surfaces).
* Axes: our frames are Z-up, glTF is Y-up: positions are stored as ``(x, z, -y)`` exactly as
  :mod:`carlaocc.catalog.meshes` does and converted back on load. Positions are float32 (glTF has no
  float64), so a round trip changes a vertex by float32 rounding only; ids are exact.
* Scene ``extras``: ``{"format": "carlaocc-panoptic", "version": 1, "taxonomy_version", "faces"}``.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping

import numpy as np

from carlaocc.catalog.meshes import from_gltf_axes, to_gltf_axes
from carlaocc.schemas import taxonomy

__all__ = ["FORMAT", "TRANSPARENT_ALPHA", "load_panoptic_glb", "panoptic_glb_bytes"]

FORMAT = "carlaocc-panoptic"
FORMAT_VERSION = 1
TRANSPARENT_ALPHA = 0.35

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_FLOAT, _UINT, _USHORT, _UBYTE = 5126, 5125, 5123, 5121
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_TRIANGLES = 4
_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}

Arrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def _check(vertices, faces, semantic, instance, transparent) -> Arrays:
    """Validated copies: (N, 3) float64, (M, 3) int64, (M,) uint8 / uint32 / bool."""
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    m = len(F)
    out = []
    for name, a, dtype, top in (("semantic", semantic, np.uint8, 255), ("instance", instance, np.uint32, 2**32 - 1)):
        a = np.asarray(a).reshape(-1)
        if len(a) != m:
            raise ValueError(f"{name} has {len(a)} entries for {m} faces")
        if m and (a.min() < 0 or a.max() > top):
            raise ValueError(f"{name} ids must lie in [0, {top}]")
        out.append(a.astype(dtype))
    T = np.asarray(transparent, dtype=bool).reshape(-1)
    if len(T) != m:
        raise ValueError(f"transparent has {len(T)} entries for {m} faces")
    if m and (F.min() < 0 or F.max() >= len(V)):
        raise ValueError(f"face index outside [0, {len(V)})")
    if not np.isfinite(V).all():
        raise ValueError("vertices must be finite")
    return V, F, out[0], out[1], T


def _class_name(semantic_id: int) -> str:
    try:
        return taxonomy.by_id(semantic_id).name
    except KeyError:
        return f"class_{semantic_id}"


def _colour(semantic_id: int, palette: Mapping[int, tuple[int, int, int]] | None) -> tuple[int, int, int]:
    if palette is not None and semantic_id in palette:
        return tuple(int(c) for c in palette[semantic_id])  # type: ignore[return-value]
    try:
        return taxonomy.by_id(semantic_id).color
    except KeyError:
        return (128, 128, 128)


def _groups(semantic: np.ndarray, instance: np.ndarray, transparent: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(order, starts)``: faces ordered by group (groups by first face, faces stable inside a
    group) and the start of each group in that order (plus the end)."""
    key = (semantic.astype(np.uint64) << np.uint64(33)) | (instance.astype(np.uint64) << np.uint64(1)) | transparent.astype(np.uint64)
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    face_rank = rank[inverse.reshape(-1)]
    order = np.argsort(face_rank, kind="stable")
    starts = np.searchsorted(face_rank[order], np.arange(len(first) + 1))
    return order, starts


class _Buffer:
    """The GLB binary chunk under construction, with its bufferViews and accessors."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(self, data: np.ndarray, component: int, kind: str, target: int, minmax: bool = False) -> int:
        data = np.ascontiguousarray(data, dtype=_DTYPES[component]).astype(np.dtype(_DTYPES[component]).newbyteorder("<"))
        self.blob.extend(b"\0" * (-len(self.blob) % 4))  # every view starts 4-byte aligned
        self.views.append({"buffer": 0, "byteOffset": len(self.blob), "byteLength": data.nbytes, "target": target})
        self.blob.extend(data.tobytes())
        acc = {"bufferView": len(self.views) - 1, "componentType": component, "count": len(data), "type": kind}
        if minmax:
            flat = data.reshape(len(data), -1)
            acc["min"] = [float(v) for v in flat.min(axis=0)]
            acc["max"] = [float(v) for v in flat.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def panoptic_glb_bytes(
    vertices,
    faces,
    semantic,
    instance,
    transparent,
    palette: dict[int, tuple[int, int, int]] | None = None,
) -> bytes:
    """Serialize a panoptic mesh (Z-up, metres; per-face ``semantic`` 0-255, ``instance`` uint32,
    ``transparent`` bool) into GLB bytes; see the module docstring for the layout. ``palette``
    overrides taxonomy colours per class id. Deterministic: equal inputs give equal bytes."""
    V, F, sem, inst, transp = _check(vertices, faces, semantic, instance, transparent)
    Vy = to_gltf_axes(V).astype(np.float32)
    buf = _Buffer()
    materials: list[dict] = []
    material_of: dict[tuple[int, bool], int] = {}
    meshes: list[dict] = []
    nodes: list[dict] = []
    order, starts = _groups(sem, inst, transp)
    for g in range(len(starts) - 1):
        members = order[starts[g] : starts[g + 1]]
        s, i, t = int(sem[members[0]]), int(inst[members[0]]), bool(transp[members[0]])
        used, local = np.unique(F[members], return_inverse=True)
        n = len(used)
        if (s, t) not in material_of:
            r, gr, b = _colour(s, palette)
            materials.append({
                "name": _class_name(s) + ("_transparent" if t else ""),
                "pbrMetallicRoughness": {
                    "baseColorFactor": [r / 255.0, gr / 255.0, b / 255.0, TRANSPARENT_ALPHA if t else 1.0],
                    "metallicFactor": 0.0, "roughnessFactor": 1.0,
                },
                "alphaMode": "BLEND" if t else "OPAQUE",
                "doubleSided": True,
            })  # fmt: skip
            material_of[(s, t)] = len(materials) - 1
        extras = {"semantic_id": s, "instance_id": i, "class": _class_name(s), "transparent": t}
        attributes = {
            "POSITION": buf.add(Vy[used], _FLOAT, "VEC3", _ARRAY_BUFFER, minmax=True),
            "_SEMANTIC": buf.add(np.full(n, s, np.float32), _FLOAT, "SCALAR", _ARRAY_BUFFER),
            "_INSTANCE": buf.add(np.full(n, i, np.float32), _FLOAT, "SCALAR", _ARRAY_BUFFER),
        }
        indices = buf.add(local.reshape(-1).astype(np.uint32), _UINT, "SCALAR", _ELEMENT_ARRAY_BUFFER)
        name = f"{_class_name(s)}_{i}" + ("_transparent" if t else "")
        meshes.append({
            "name": name, "extras": extras,
            "primitives": [{"attributes": attributes, "indices": indices, "material": material_of[(s, t)],
                            "mode": _TRIANGLES, "extras": extras}],
        })  # fmt: skip
        nodes.append({"name": name, "mesh": len(meshes) - 1, "extras": extras})

    scene: dict = {"name": FORMAT, "extras": {
        "format": FORMAT, "version": FORMAT_VERSION, "taxonomy_version": taxonomy.TAXONOMY_VERSION, "faces": len(F),
    }}  # fmt: skip
    gltf: dict = {"asset": {"version": "2.0", "generator": "carlaocc catalog.panoptic"}, "scene": 0, "scenes": [scene]}
    if nodes:  # glTF arrays, when present, must not be empty
        scene["nodes"] = list(range(len(nodes)))
        gltf |= {"nodes": nodes, "meshes": meshes, "materials": materials, "accessors": buf.accessors,
                 "bufferViews": buf.views, "buffers": [{"byteLength": len(buf.blob)}]}  # fmt: skip
    return _pack(gltf, bytes(buf.blob))


def _pack(gltf: dict, blob: bytes) -> bytes:
    """GLB container: 12-byte header, a JSON chunk padded with spaces, a BIN chunk padded with
    zeros (omitted when empty)."""
    js = json.dumps(gltf, separators=(",", ":"), sort_keys=True).encode("utf-8")
    js += b" " * (-len(js) % 4)
    chunks = struct.pack("<II", len(js), _CHUNK_JSON) + js
    if blob:
        blob += b"\0" * (-len(blob) % 4)
        chunks += struct.pack("<II", len(blob), _CHUNK_BIN) + blob
    return _GLB_MAGIC + struct.pack("<II", 2, 12 + len(chunks)) + chunks


def _unpack(data: bytes) -> tuple[dict, bytes]:
    """(glTF JSON, BIN chunk) of GLB bytes; ``ValueError`` for anything else."""
    if len(data) < 20 or data[:4] != _GLB_MAGIC:
        raise ValueError("not a GLB file (no glTF magic)")
    version, total = struct.unpack_from("<II", data, 4)
    if version != 2 or total > len(data):
        raise ValueError(f"unsupported or truncated GLB (version {version}, length {total} of {len(data)} bytes)")
    gltf, blob, pos = None, b"", 12
    while pos + 8 <= total:
        length, kind = struct.unpack_from("<II", data, pos)
        body = data[pos + 8 : pos + 8 + length]
        if kind == _CHUNK_JSON and gltf is None:
            gltf = json.loads(body.decode("utf-8"))
        elif kind == _CHUNK_BIN and not blob:
            blob = bytes(body)
        pos += 8 + length
    if gltf is None:
        raise ValueError("GLB has no JSON chunk")
    return gltf, blob


def _read(gltf: dict, blob: bytes, index: int) -> np.ndarray:
    """The data of accessor ``index`` as an array of shape (count,) or (count, components)."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = np.dtype(_DTYPES[acc["componentType"]]).newbyteorder("<")
    ncomp, count = _NCOMP[acc["type"]], int(acc["count"])
    start = int(view.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    stride = int(view.get("byteStride", 0)) or dtype.itemsize * ncomp
    if stride == dtype.itemsize * ncomp:
        out = np.frombuffer(blob, dtype=dtype, count=count * ncomp, offset=start)
    else:  # interleaved: gather element by element through a strided view
        raw = np.frombuffer(blob, dtype=np.uint8, count=stride * (count - 1) + dtype.itemsize * ncomp, offset=start)
        out = np.lib.stride_tricks.as_strided(raw, (count, dtype.itemsize * ncomp), (stride, 1)).copy().view(dtype)
    out = out.astype(dtype.newbyteorder("="))
    return out.reshape(count, ncomp) if ncomp > 1 else out.reshape(count)


def load_panoptic_glb(data: bytes) -> Arrays:
    """``(vertices, faces, semantic, instance, transparent)`` of a GLB written by
    :func:`panoptic_glb_bytes`: vertices (N, 3) float64 back in the Z-up frame, faces (M, 3)
    int64, per-face semantic uint8, instance uint32, transparent bool. Faces come grouped (see
    the module docstring); ids are read from the primitives' ``extras`` (exact), falling back to
    the ``_SEMANTIC`` / ``_INSTANCE`` attributes for files without them."""
    gltf, blob = _unpack(bytes(data))
    scenes = gltf.get("scenes") or [{}]
    node_ids = scenes[int(gltf.get("scene", 0))].get("nodes", [])
    verts, faces, sem, inst, transp = [], [], [], [], []
    offset = 0
    for n in node_ids:
        node = gltf["nodes"][n]
        if "mesh" not in node:
            continue
        mesh = gltf["meshes"][node["mesh"]]
        for prim in mesh["primitives"]:
            if prim.get("mode", _TRIANGLES) != _TRIANGLES:
                raise ValueError(f"mesh {mesh.get('name', node['mesh'])!r}: only triangle primitives are supported")
            attrs = prim["attributes"]
            V = from_gltf_axes(_read(gltf, blob, attrs["POSITION"]))
            idx = _read(gltf, blob, prim["indices"]) if "indices" in prim else np.arange(len(V))
            F = idx.astype(np.int64).reshape(-1, 3)
            extras = prim.get("extras") or mesh.get("extras") or node.get("extras") or {}
            m = len(F)
            if "semantic_id" in extras:
                s = np.full(m, int(extras["semantic_id"]), np.uint8)
                i = np.full(m, int(extras["instance_id"]), np.uint32)
                t = np.full(m, bool(extras.get("transparent", False)))
            elif "_SEMANTIC" in attrs and "_INSTANCE" in attrs:  # per vertex: a face takes its first corner's
                s = np.rint(_read(gltf, blob, attrs["_SEMANTIC"])[F[:, 0]]).astype(np.uint8)
                i = np.rint(_read(gltf, blob, attrs["_INSTANCE"])[F[:, 0]].astype(np.float64)).astype(np.uint32)
                t = np.zeros(m, dtype=bool)
            else:
                raise ValueError(f"mesh {mesh.get('name', node['mesh'])!r} carries no panoptic ids")
            verts.append(V)
            faces.append(F + offset)
            sem.append(s)
            inst.append(i)
            transp.append(t)
            offset += len(V)
    if not faces:
        return (np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.uint8),
                np.zeros(0, np.uint32), np.zeros(0, bool))  # fmt: skip
    return (np.concatenate(verts), np.concatenate(faces), np.concatenate(sem),
            np.concatenate(inst), np.concatenate(transp))  # fmt: skip
