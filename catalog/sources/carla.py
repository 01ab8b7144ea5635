"""Simulator (CARLA / Unreal Engine) asset exports: the one place Unreal's frame is converted.

Export format ("carlaocc-ue-export/1")
======================================

A directory::

    <export>/
        meshes/<mesh>.obj       component meshes (+ optional .mtl libraries next to them)
        objects/<object>.json   one file per scene object (actor / blueprint)

Component meshes (``meshes/*.obj``)
    Wavefront OBJ holding the component's static mesh in **Unreal's local frame**: left-handed,
    x forward, y right, z up, **centimetres**, relative to the component's pivot. Coordinates
    are the raw ``FVector`` numbers, no axis swap. Triangles are wound so that
    ``(b - a) x (c - a)``, evaluated on the stored numbers, points out of the surface. ``usemtl``
    names a material; a material of an ``mtllib`` with ``d < 1`` or ``Tr > 0`` is transparent.

Object files (``objects/*.json``)::

    {
      "format": "carlaocc-ue-export/1",            optional
      "name": "traffic_light_01",                  optional (default: file stem)
      "semantic_tag": "TrafficLight",              CARLA CityObjectLabel name or id (0-29)
      "subclass": "vehicle_signal",                optional (default: the class's first)
      "licence": "CC-BY-4.0 (CARLA assets)",       optional (default "")
      "components": [
        {
          "name": "pole",                          unique within the object
          "mesh": "meshes/pole.obj",               relative to the export directory
          "parent": null,                          null (object root) or a component name
          "location": [0, 0, 0],                   cm, in the parent's frame (default 0)
          "rotation": [0, 0, 0],                   [pitch, yaw, roll] degrees, FRotator (default 0)
          "scale": [1, 1, 1],                      (default 1)
          "semantic_tag": "Pole"                   optional per-component label
        }
      ]
    }

Semantics (Unreal's): a component's local transform is ``T(location) * R(rotation) *
S(scale)`` (scale first, then rotation, then translation); its world transform is the parent's
world transform times its local one, up the parent chain to the object root. ``R`` is Unreal's
``FRotationMatrix``: with ``SP, CP`` the sine/cosine of pitch, ``SY, CY`` of yaw, ``SR, CR`` of
roll, the images of the local x, y, z axes are::

    x -> ( CP*CY,              CP*SY,              SP    )
    y -> ( SR*SP*CY - CR*SY,   SR*SP*SY + CR*CY,  -SR*CP )
    z -> (-(CR*SP*CY + SR*SY), CY*SR - CR*SP*SY,   CR*CP )

i.e. positive yaw turns x toward +y (to the right, seen from above), positive pitch raises x
toward +z, positive roll turns y toward -z. Transforms compose as full 4x4 matrices (exact for
any scale; Unreal's ``FTransform`` approximates a rotated child under a non-uniformly scaled
parent, which this format does not reproduce).

Conversion (here, once)
    After composing in Unreal's frame: ``(x, y, z)_ours = (x, -y, z)_unreal / 100``, a mirror
    (left- to right-handed: y right -> y left) and centimetres -> metres. A mirror reverses the
    apparent winding, so every triangle is re-wound (and re-wound again under a negative-scale
    transform) to keep normals outward. The asset is declared ``units="m"``, ``up="+z"``,
    ``forward="+x"``: standardization has nothing left to convert.

Labels
    ``semantic_tag`` is a CARLA ``CityObjectLabel``: a name (``"TrafficLight"``, the Python enum
    spellings ``"Poles"``... too, any case) or an id of CARLA UE5 0.10, whose ids are our
    taxonomy's (``carlaocc.schemas.taxonomy``). CARLA 0.9.x numbered its labels differently: write names
    for exports from it.

Reading
    One item per ``objects/*.json`` (key = file stem); its files are the JSON and every mesh and
    MTL it references. Category = the object's ``semantic_tag`` (missing: ``"no category"``;
    unknown: ``"bad metadata"``). One :class:`SourcePart` per component (per material when a
    component mesh has several), named after the component, ``semantic_id`` from the component's
    tag. A referenced mesh that does not exist: ``"missing mesh"``; malformed JSON, unknown parent,
    parent cycle, bad vectors: ``"bad metadata"``.

:func:`write_example_export` writes a small export (a traffic light, a car) built from trimesh
primitives, for tests and documentation.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from carlaocc.catalog.sources._common import (
    check_subclass,
    compact,
    default_subclass,
    drop_excluded,
    make_part,
    missing_file_notes,
    obj_appearance,
    read_json_object,
    semantic_class,
    texture_files,
)
from carlaocc.catalog.sources.obj import ObjError, mtl_files, obj_materials, read_obj
from carlaocc.catalog.sources.base import SourceError, SourceItem
from carlaocc.schemas.meshes import SourceAsset

FORMAT = "carlaocc-ue-export/1"
UE_TO_OURS = np.diag([0.01, -0.01, 0.01])  # mirror y, centimetres -> metres


def rotator_matrix(pitch: float, yaw: float, roll: float) -> np.ndarray:
    """3x3 rotation of an Unreal ``FRotator`` (degrees) for column vectors (columns = images of
    the local axes), as Unreal's ``FRotationMatrix``."""
    p, y, r = (math.radians(a) for a in (pitch, yaw, roll))
    SP, CP, SY, CY, SR, CR = math.sin(p), math.cos(p), math.sin(y), math.cos(y), math.sin(r), math.cos(r)
    rows = np.array([  # Unreal's row-vector matrix M: row i = image of axis i
        [CP * CY, CP * SY, SP],
        [SR * SP * CY - CR * SY, SR * SP * SY + CR * CY, -SR * CP],
        [-(CR * SP * CY + SR * SY), CY * SR - CR * SP * SY, CR * CP],
    ])  # fmt: skip
    return rows.T


def local_matrix(location, rotation, scale) -> np.ndarray:
    """4x4 ``T * R * S`` of an Unreal relative transform (cm, FRotator degrees, scale)."""
    m = np.eye(4)
    m[:3, :3] = rotator_matrix(*rotation) @ np.diag(np.asarray(scale, dtype=np.float64))
    m[:3, 3] = location
    return m


def _vec(comp: dict, key: str, default: float, where: str) -> list[float]:
    v = comp.get(key)
    if v is None:
        return [default] * 3
    numbers = isinstance(v, list) and all(
        isinstance(x, (int, float)) and not isinstance(x, bool) for x in v
    )
    if not (numbers and len(v) == 3):
        raise SourceError("bad metadata", f"{where}: {key} must be a list of 3 numbers, got {v!r}")
    if not all(math.isfinite(x) for x in v):
        raise SourceError("bad metadata", f"{where}: {key} has a non-finite value")
    return [float(x) for x in v]


def _load_object(path: str) -> dict:
    doc = read_json_object(path, "bad metadata")
    fmt = doc.get("format", FORMAT)
    if fmt != FORMAT:
        raise SourceError("bad metadata", f"{path}: format {fmt!r}, this reader reads {FORMAT!r}")
    comps = doc.get("components")
    if not isinstance(comps, list) or not comps or not all(isinstance(c, dict) for c in comps):
        raise SourceError("bad metadata", f"{path}: 'components' must be a non-empty list of objects")
    names = [c.get("name") for c in comps]
    if not all(isinstance(n, str) and n for n in names):
        raise SourceError("bad metadata", f"{path}: every component needs a non-empty 'name'")
    if len(set(names)) != len(names):
        raise SourceError("bad metadata", f"{path}: component names are not unique")
    for c in comps:
        if not isinstance(c.get("mesh"), str) or not c["mesh"]:
            raise SourceError("bad metadata", f"{path}: component {c['name']!r} has no 'mesh'")
    return doc


def world_matrices(doc: dict, where: str) -> dict[str, np.ndarray]:
    """Component name -> 4x4 world matrix (Unreal frame, cm), through the parent chains."""
    comps = {c["name"]: c for c in doc["components"]}
    local = {
        n: local_matrix(_vec(c, "location", 0.0, f"{where}: {n}"),
                        _vec(c, "rotation", 0.0, f"{where}: {n}"),
                        _vec(c, "scale", 1.0, f"{where}: {n}"))
        for n, c in comps.items()
    }  # fmt: skip
    world: dict[str, np.ndarray] = {}

    def resolve(name: str, stack: tuple[str, ...]) -> np.ndarray:
        if name in world:
            return world[name]
        if name in stack:
            raise SourceError("bad metadata", f"{where}: parent cycle {' -> '.join(stack + (name,))}")
        parent = comps[name].get("parent")
        if parent is None:
            m = local[name]
        elif not isinstance(parent, str) or parent not in comps:
            raise SourceError("bad metadata", f"{where}: component {name!r} has unknown parent {parent!r}")
        else:
            m = resolve(parent, stack + (name,)) @ local[name]
        world[name] = m
        return m

    for n in comps:
        resolve(n, ())
    return world


def to_ours(vertices_cm: np.ndarray, faces: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unreal-local vertices (cm) through a world matrix, then into our frame (m, right-handed),
    triangles re-wound so outward normals stay outward."""
    v = vertices_cm @ world[:3, :3].T + world[:3, 3]
    v = v @ UE_TO_OURS.T
    flip = np.linalg.det(world[:3, :3]) > 0  # the mirror flips once; a negative det flips back
    f = faces[:, ::-1] if flip else faces
    return v, np.ascontiguousarray(f, dtype=np.int64)


class CarlaAdapter:
    """Unreal/CARLA export directories (see the module docstring)."""

    kind = "carla"

    def list_items(self, root: str, exclude: tuple[str, ...] = ()) -> list[SourceItem]:
        root = os.path.abspath(root)
        odir = os.path.join(root, "objects")
        if not os.path.isdir(odir):
            raise SourceError("bad metadata", f"{odir} not found: an export holds objects/*.json "
                                              "and meshes/*.obj")  # fmt: skip
        items = []
        for name in sorted(os.listdir(odir)):
            if not name.lower().endswith(".json"):
                continue
            path = os.path.join(odir, name)
            files = [path]
            # a malformed object is still listed (with just its JSON as input): read() reports it
            try:
                components = _load_object(path)["components"]
            except SourceError:
                components = []
            for c in components:
                mesh = os.path.abspath(os.path.join(root, c["mesh"]))
                if mesh not in files:
                    files.append(mesh)
                    files += [m for m in (*mtl_files(mesh), *texture_files(mesh)) if m not in files]
            items.append(SourceItem(key=os.path.splitext(name)[0], files=tuple(files), meta={}))
        items.sort(key=lambda it: it.key)
        return drop_excluded(items, exclude)

    def read(self, root: str, item: SourceItem) -> SourceAsset:
        root = os.path.abspath(root)
        path = os.path.join(root, "objects", item.key + ".json")
        doc = _load_object(path)
        tag = doc.get("semantic_tag")
        if tag is None:
            raise SourceError("no category", f"{path}: no semantic_tag (a CARLA label name or id)")
        try:
            cls = semantic_class(tag)
        except KeyError as e:
            raise SourceError("bad metadata", f"{path}: {e.args[0]}") from None
        subclass = doc.get("subclass") or default_subclass(cls)
        why = check_subclass(cls, str(subclass))
        if why:
            raise SourceError("bad metadata", f"{path}: {why}")
        world = world_matrices(doc, path)

        meshes: dict[str, tuple] = {}
        parts, notes = [], []
        for comp in doc["components"]:
            name = comp["name"]
            semantic_id = None
            if comp.get("semantic_tag") is not None:
                try:
                    semantic_id = semantic_class(comp["semantic_tag"]).id
                except KeyError as e:
                    raise SourceError("bad metadata", f"{path}: component {name!r}: {e.args[0]}") from None
            mesh_path = os.path.abspath(os.path.join(root, comp["mesh"]))
            if mesh_path not in meshes:
                if not os.path.isfile(mesh_path):
                    raise SourceError("missing mesh", f"{mesh_path} (component {name!r} of {path})")
                try:
                    data = read_obj(mesh_path)
                except (OSError, ObjError) as e:
                    raise SourceError("unreadable file", f"{mesh_path}: {e}") from None
                meshes[mesh_path] = (data, obj_materials(mesh_path, data.mtllibs))
                used = [meshes[mesh_path][1][g.material] for g in data.groups if g.material in meshes[mesh_path][1]]
                notes += [n for n in missing_file_notes(mesh_path, used, data.mtllibs) if n not in notes]
            data, mtl = meshes[mesh_path]
            by_mat: dict[str, tuple[list, list]] = {}
            for g in data.groups:
                faces, uv_index = by_mat.setdefault(g.material, ([], []))
                faces.extend(g.faces)
                uv_index.extend(g.uv_index)
            for mat_name, (faces, uv_index) in by_mat.items():
                v, f = compact(data.vertices, faces)
                v, f = to_ours(v, f, world[name])
                m = mtl.get(mat_name)
                # to_ours re-winds the triangles when the world matrix keeps handedness: so are their corners
                color, corner_uv, image = obj_appearance(data, m, uv_index, os.path.dirname(mesh_path),
                                                         reversed_=np.linalg.det(world[name][:3, :3]) > 0)
                parts.append(make_part(
                    name if len(by_mat) == 1 else f"{name}/{mat_name or 'default'}", v, f,
                    material=mat_name or "default",
                    transparent=m.transparent if m else False,
                    texture=m.texture if m else "",  # relative to the mesh's directory
                    semantic_id=semantic_id, color=color, corner_uv=corner_uv, image=image,
                ))  # fmt: skip
        return SourceAsset(
            source=self.kind,
            source_path=path,
            licence=str(doc.get("licence", doc.get("license", "")) or ""),
            category=cls.name,
            subclass=str(subclass),
            parts=tuple(parts),
            up="+z",
            forward="+x",
            units="m",
            normalized=False,
            target_length=None,
            licence_required=False,
            notes=tuple(notes),
        )


# -- example export --------------------------------------------------------------------------


def _write_obj(path: str, vertices: np.ndarray, faces: np.ndarray, material: str = "",
               mtllib: str = "") -> None:  # fmt: skip
    lines = ["# carlaocc example export: Unreal local frame (x fwd, y right, z up), cm"]
    if mtllib:
        lines.append(f"mtllib {mtllib}")
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    if material:
        lines.append(f"usemtl {material}")
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")


def write_example_export(directory: str) -> str:
    """Write a small export into ``directory`` (created) and return it.

    * ``objects/traffic_light.json`` (TrafficLight/vehicle_signal): a 4 m ``pole`` (Pole), an
      ``arm`` attached to the pole top turned by yaw 90 so it reaches 1 m to Unreal's +y (the
      right), and a ``head`` attached to the arm's end 0.5 m lower, turned back by yaw -90.
      The head's centre ends at Unreal (0, 100, 330) cm = ours (0, -1.0, 3.3) m.
    * ``objects/car.json`` (Car/sedan): a ``body`` box (4.5 x 1.8 x 1.2 m, 0.3 m off the
      ground), a transparent ``windshield`` (MTL ``d 0.35``), and four wheels attached to the
      body at (+-140, +-80, 35) cm, rolled 90 degrees so their axles lie along y.
    """
    import trimesh  # 1.0 s to import (python -X importtime): paid only when a CARLA model is built

    mdir = os.path.join(directory, "meshes")
    odir = os.path.join(directory, "objects")
    os.makedirs(mdir, exist_ok=True)
    os.makedirs(odir, exist_ok=True)

    def prim(mesh, offset=(0.0, 0.0, 0.0)):
        return np.asarray(mesh.vertices) + np.asarray(offset), np.asarray(mesh.faces)

    pole = prim(trimesh.creation.cylinder(radius=10.0, height=400.0, sections=16), (0, 0, 200))
    arm = prim(trimesh.creation.box(extents=(100.0, 8.0, 8.0)), (50, 0, 0))  # along local +x
    head = prim(trimesh.creation.box(extents=(30.0, 30.0, 90.0)))  # pivot at its centre
    body = prim(trimesh.creation.box(extents=(450.0, 180.0, 120.0)), (0, 0, 90))
    shield = prim(trimesh.creation.box(extents=(4.0, 150.0, 50.0)))
    wheel = prim(trimesh.creation.cylinder(radius=35.0, height=22.0, sections=20))  # axle along z

    for name, (v, f) in {"pole": pole, "arm": arm, "head": head, "body": body, "wheel": wheel}.items():
        _write_obj(os.path.join(mdir, f"{name}.obj"), v, f)
    _write_obj(os.path.join(mdir, "windshield.obj"), *shield, material="glass", mtllib="windshield.mtl")
    with open(os.path.join(mdir, "windshield.mtl"), "w", encoding="utf-8") as f:
        f.write("newmtl glass\nKd 0.6 0.7 0.8\nd 0.35\n")

    light = {
        "format": FORMAT,
        "name": "traffic_light",
        "semantic_tag": "TrafficLight",
        "subclass": "vehicle_signal",
        "licence": "CC0-1.0 (carlaocc example)",
        "components": [
            {"name": "pole", "mesh": "meshes/pole.obj", "parent": None,
             "location": [0, 0, 0], "rotation": [0, 0, 0], "scale": [1, 1, 1], "semantic_tag": "Pole"},
            {"name": "arm", "mesh": "meshes/arm.obj", "parent": "pole",
             "location": [0, 0, 380], "rotation": [0, 90, 0], "scale": [1, 1, 1], "semantic_tag": "Pole"},
            {"name": "head", "mesh": "meshes/head.obj", "parent": "arm",
             "location": [100, 0, -50], "rotation": [0, -90, 0], "scale": [1, 1, 1]},
        ],
    }  # fmt: skip
    wheels = [
        {"name": f"wheel_{tag}", "mesh": "meshes/wheel.obj", "parent": "body",
         "location": [x, y, 35], "rotation": [0, 0, 90], "scale": [1, 1, 1]}
        for tag, x, y in (("fl", 140, -80), ("fr", 140, 80), ("rl", -140, -80), ("rr", -140, 80))
    ]  # fmt: skip
    car = {
        "format": FORMAT,
        "name": "car",
        "semantic_tag": 14,
        "subclass": "sedan",
        "licence": "CC0-1.0 (carlaocc example)",
        "components": [
            {"name": "body", "mesh": "meshes/body.obj", "parent": None},
            {"name": "windshield", "mesh": "meshes/windshield.obj", "parent": "body",
             "location": [80, 0, 170], "rotation": [-30, 0, 0]},
            *wheels,
        ],
    }  # fmt: skip
    for name, doc in (("traffic_light", light), ("car", car)):
        with open(os.path.join(odir, f"{name}.json"), "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=2)
            f.write("\n")
    return directory
