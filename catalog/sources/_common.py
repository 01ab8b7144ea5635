"""Shared reading helpers of the source adapters: mesh files to :class:`SourcePart` s, licence
files, taxonomy look-ups.

Mesh files (:func:`load_parts`)
    ``.glb``/``.gltf``/``.obj``/``.ply``/``.stl``/``.off`` load with trimesh
    (``force="scene"``); every geometry node of the scene graph becomes one part with the node's
    world transform applied (a mirroring transform also reverses the triangle winding, so outward
    normals stay outward). ``.dae`` loads with :mod:`carlaocc.catalog.sources._collada` (trimesh needs the
    optional pycollada for it). Non-indexed triangles (every corner its own vertex) are indexed by
    welding bit-identical positions; indexed meshes are kept as they are.

Materials
    glTF: the JSON is read next to trimesh to recover what trimesh drops. A part is transparent
    when its material's ``alphaMode`` is ``BLEND`` or its ``baseColorFactor`` alpha is < 1, or it
    uses ``KHR_materials_transmission`` with a factor > 0 (glass authored physically).
    ``MASK`` (cut-outs) is not transparent. Trimesh materials are matched to the glTF materials by
    name, ties broken by colour factor and alpha mode.
    OBJ: the MTL is parsed here (:func:`carlaocc.catalog.sources.obj.parse_mtl`): ``d < 1`` or ``Tr > 0``.

Texture references (``SourcePart.texture``)
    Kept by reference, never decoded: the image path relative to the mesh file's directory
    (glTF image ``uri``, MTL ``map_Kd``, COLLADA ``init_from``); an image embedded in a GLB
    buffer is ``"<file name>#images/<index>"``; ``""`` when the material has no base colour
    texture.

Missing side files (:func:`missing_file_notes`)
    An OBJ's ``mtllib`` that does not exist, or a texture a part references by a path that does
    not exist (relative to the mesh file's directory), does not stop the read: the geometry is
    whole. Each becomes a note on the :class:`~carlaocc.schemas.meshes.SourceAsset` (and so on the
    asset record's ``notes``), e.g. ``"car.obj: material library 'car.mtl' not found (materials
    default: no transparency or texture)"``, queryable in SQL.

Every read problem becomes :class:`SourceError`: a missing file ``"missing mesh"``, anything
unparsable or truncated ``"unreadable file"``.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import struct
from urllib.parse import unquote

import numpy as np

# the appearance of a part (material colour, texture image and corner coordinates), re-exported
from carlaocc.catalog.sources._appearance import (MAX_TEXTURE_SIDE, gltf_materials, match_gltf,  # noqa: F401
                                                  obj_appearance, read_texture, texture_image,
                                                  trimesh_appearance, trimesh_material_info)
from carlaocc.catalog.sources._collada import ColladaError, read_dae
from carlaocc.catalog.sources.obj import missing_mtl_libraries, mtl_files, obj_materials
from carlaocc.catalog.sources.base import SourceError
from carlaocc.schemas.meshes import Axis, SourcePart
from carlaocc.schemas.taxonomy import SemanticClass, by_id, by_name

MESH_EXTS: tuple[str, ...] = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".dae")
AXES: tuple[str, ...] = ("+x", "-x", "+y", "-y", "+z", "-z")
UNITS: tuple[str, ...] = ("m", "cm", "mm", "in", "unknown")

_DAE_AXES: dict[str, tuple[Axis, Axis]] = {
    "Y_UP": ("+y", "+z"),
    "Z_UP": ("+z", "+x"),
    "X_UP": ("+x", "+z"),
}


def ext_of(path: str) -> str:
    return os.path.splitext(path)[1].lower()


def is_mesh_file(path: str) -> bool:
    return ext_of(path) in MESH_EXTS


def check_axes(up: str, forward: str) -> str | None:
    """Why (up, forward) is not a valid axis pair, or None."""
    if up not in AXES:
        return f"up {up!r} is not one of {', '.join(AXES)}"
    if forward not in AXES:
        return f"forward {forward!r} is not one of {', '.join(AXES)}"
    if up[1] == forward[1]:
        return f"up {up} and forward {forward} are the same axis"
    return None


def dae_up_axis(path: str) -> str:
    """The ``<up_axis>`` of a COLLADA file ("Y_UP" when absent), read from its first 64 kB."""
    try:
        with open(path, "rb") as f:
            head = f.read(65536).decode("utf-8", errors="replace")
    except OSError:
        return "Y_UP"
    m = re.search(r"<up_axis>\s*([XYZ]_UP)\s*</up_axis>", head)
    return m.group(1) if m else "Y_UP"


def default_axes(path: str) -> tuple[Axis, Axis]:
    """(up, forward) a mesh file's format implies.

    glTF: the spec fixes +Y up and the asset front facing +Z. COLLADA: from ``<up_axis>``
    (Y_UP: +y/+z like glTF; Z_UP: +z/+x; X_UP: +x/+z). Other formats carry no frame: our own
    convention, +z up and +x forward, unless the caller says otherwise."""
    ext = ext_of(path)
    if ext in (".glb", ".gltf"):
        return "+y", "+z"
    if ext == ".dae":
        return _DAE_AXES[dae_up_axis(path)]
    return "+z", "+x"


# -- excluded sub-trees ------------------------------------------------------------------------


def is_excluded(path: str, exclude) -> bool:
    """Whether ``path`` is one of the directories ``exclude`` or lies inside one (real paths
    compared, links resolved; a dataset root inside a source folder is excluded this way)."""
    if not exclude:
        return False
    p = os.path.realpath(path)
    for ex in exclude:
        e = os.path.realpath(ex)
        if p == e or p.startswith(e.rstrip(os.sep) + os.sep):
            return True
    return False


def drop_excluded(items: list, exclude) -> list:
    """The items whose primary file (``files[0]``) is not inside an excluded directory."""
    if not exclude:
        return items
    return [it for it in items if not (it.files and is_excluded(it.files[0], exclude))]


# -- licences --------------------------------------------------------------------------------

_LICENCE_LINE = re.compile(r"^\s*(?:SPDX-License-Identifier|Licen[cs]e)\s*:\s*(.+?)\s*$", re.I)


def licence_text(path: str) -> str:
    """The licence a licence file states: its ``License: ...`` (or SPDX) line when it has one
    (brackets stripped: Kenney writes ``License: (Creative Commons Zero, CC0)``), else its first
    non-blank line."""
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = f.read(65536).splitlines()
    except OSError:
        return ""
    for line in lines:
        m = _LICENCE_LINE.match(line)
        if m:
            return m.group(1).strip().strip("()").strip()
    for line in lines:
        if line.strip():
            return line.strip()
    return ""


def find_licence_file(path: str, root: str) -> str | None:
    """The first ``LICENSE*.txt`` / ``LICENCE*.txt`` (any case) in the file's directory or a
    parent directory up to ``root`` (inclusive); several in one directory: the first by name."""
    root = os.path.abspath(root)
    d = os.path.dirname(os.path.abspath(path))
    while True:
        try:
            names = sorted(os.listdir(d))
        except OSError:
            names = []
        for n in names:
            low = n.lower()
            if low.startswith(("license", "licence")) and low.endswith(".txt"):
                if os.path.isfile(os.path.join(d, n)):
                    return os.path.join(d, n)
        if d == root or os.path.dirname(d) == d or not d.startswith(root):
            return None
        d = os.path.dirname(d)


# -- taxonomy --------------------------------------------------------------------------------


def semantic_class(tag) -> SemanticClass:
    """A taxonomy class from a name (any case/separators, CARLA enum spellings) or an id (int or
    digit string). KeyError otherwise."""
    if isinstance(tag, bool):
        raise KeyError(f"not a class: {tag!r}")
    if isinstance(tag, int):
        return by_id(tag)
    if isinstance(tag, float) and tag.is_integer():
        return by_id(int(tag))
    if isinstance(tag, str):
        s = tag.strip()
        if s.isdigit():
            return by_id(int(s))
        return by_name(s)
    raise KeyError(f"not a class: {tag!r}")


def default_subclass(cls: SemanticClass) -> str:
    """The sub-class used when a source names none: the first of the class vocabulary."""
    return cls.subclasses[0] if cls.subclasses else ""


def check_subclass(cls: SemanticClass, subclass: str) -> str | None:
    """Why ``subclass`` is not in the class vocabulary, or None."""
    if subclass in cls.subclasses or (not cls.subclasses and subclass == ""):
        return None
    vocab = ", ".join(cls.subclasses) or "(none)"
    return f"sub-class {subclass!r} is not one of {cls.name}'s: {vocab}"


# -- meshes ----------------------------------------------------------------------------------


def _unique(name: str, taken: set[str]) -> str:
    out, k = name, 1
    while out in taken:
        out = f"{name}_{k}"
        k += 1
    taken.add(out)
    return out


def weld_unindexed(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index a non-indexed triangle soup (faces == arange) by welding identical positions."""
    n = len(vertices)
    if n == 0 or faces.size != n or not np.array_equal(faces.ravel(), np.arange(n)):
        return vertices, faces
    uniq, inv = np.unique(vertices, axis=0, return_inverse=True)
    return uniq, inv.reshape(-1, 3).astype(np.int64)


def compact(vertices: np.ndarray, faces) -> tuple[np.ndarray, np.ndarray]:
    """The vertices ``faces`` use (in their original order), faces re-indexed into them."""
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    used, inv = np.unique(f.ravel(), return_inverse=True)
    return np.asarray(vertices, dtype=np.float64)[used], inv.reshape(-1, 3).astype(np.int64)


def make_part(name, vertices, faces, *, material="default", transparent=False, texture="",
              semantic_id=None, color=None, corner_uv=None, image=None) -> SourcePart:  # fmt: skip
    v = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    v, f = weld_unindexed(v, f)  # faces keep their order: corner coordinates stay valid
    return SourcePart(name=name, vertices=v, faces=f, material=material or "default",
                      transparent=bool(transparent), texture=texture, semantic_id=semantic_id,
                      color=color, corner_uv=corner_uv, image=image)  # fmt: skip


def read_json_object(path: str, reason: str, missing_reason: str | None = None) -> dict:
    """A JSON file whose top level is an object; any failure is a SourceError with ``reason``
    (``missing_reason`` when the file does not exist)."""
    try:
        with open(path, encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise SourceError(missing_reason or reason, f"{path} does not exist") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SourceError(reason, f"{path}: bad JSON: {e}") from None
    if not isinstance(doc, dict):
        raise SourceError(reason, f"{path}: expected a JSON object")
    return doc


def _unreadable(path: str, why: str) -> SourceError:
    return SourceError("unreadable file", f"{path}: {why}")


def check_glb(path: str) -> dict:
    """Validate a GLB container (header length, chunk bounds) and return its JSON."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise SourceError("missing mesh", f"{path} does not exist") from None
    except OSError as e:
        raise _unreadable(path, str(e)) from None
    if len(data) < 20:
        raise _unreadable(path, f"{len(data)} bytes: too short for a GLB (truncated or empty)")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise _unreadable(path, "no glTF magic: not a binary glTF file")
    if version != 2:
        raise _unreadable(path, f"glTF container version {version}; only 2 is read")
    if length != len(data):
        raise _unreadable(path, f"header says {length} bytes, file has {len(data)} (truncated?)")
    off, chunks = 12, []
    while off < len(data):
        if off + 8 > len(data):
            raise _unreadable(path, f"chunk header cut at byte {off} (truncated?)")
        clen, ctype = struct.unpack_from("<II", data, off)
        if off + 8 + clen > len(data):
            raise _unreadable(path, f"chunk at byte {off} runs past the end (truncated?)")
        chunks.append((ctype, data[off + 8 : off + 8 + clen]))
        off += 8 + clen
    if not chunks or chunks[0][0] != 0x4E4F534A:  # "JSON"
        raise _unreadable(path, "first chunk is not JSON")
    try:
        doc = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise _unreadable(path, f"bad JSON chunk: {e}") from None
    check_accessors(path, doc)
    return doc


_COMPONENT_BYTES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
# an accessor without a buffer view is zero-filled by readers: bound what it may claim
MAX_ACCESSOR_ELEMENTS = 50_000_000


def check_accessors(path: str, doc: dict) -> None:
    """Refuse accessors that claim more elements than their buffer view holds (or, without a
    buffer view, more than MAX_ACCESSOR_ELEMENTS): a 500-byte file must not allocate gigabytes."""
    views = doc.get("bufferViews") or []
    for i, acc in enumerate(doc.get("accessors") or []):
        try:
            count = int(acc.get("count", 0))
            size = _COMPONENT_BYTES.get(acc.get("componentType"), 4) * _COMPONENTS.get(acc.get("type"), 1)
            if count < 0 or count > MAX_ACCESSOR_ELEMENTS:
                raise _unreadable(path, f"accessor {i} claims {count} elements")
            if acc.get("bufferView") is None or count == 0:
                continue
            view = views[int(acc["bufferView"])]
            stride = int(view.get("byteStride") or size)
            need = int(acc.get("byteOffset", 0)) + (count - 1) * stride + size
            if need > int(view.get("byteLength", 0)):
                raise _unreadable(path, f"accessor {i} needs {need} bytes, its buffer view has "
                                        f"{view.get('byteLength', 0)} (corrupt or truncated)")
        except (TypeError, ValueError, IndexError, KeyError, AttributeError):
            raise _unreadable(path, f"accessor {i} is malformed") from None


def _gltf_json(path: str) -> dict:
    if ext_of(path) == ".glb":
        return check_glb(path)
    doc = read_json_object(path, "unreadable file", missing_reason="missing mesh")
    base = os.path.dirname(path)
    for b in doc.get("buffers", []) or []:
        uri = b.get("uri", "") if isinstance(b, dict) else ""
        if uri and not uri.startswith("data:"):
            bp = os.path.join(base, unquote(uri))
            if not os.path.isfile(bp):
                raise _unreadable(path, f"buffer {uri!r} not found next to the .gltf")
            if isinstance(b.get("byteLength"), int) and os.path.getsize(bp) < b["byteLength"]:
                raise _unreadable(path, f"buffer {uri!r} shorter than its byteLength (truncated?)")
    check_accessors(path, doc)
    return doc


def _check_compression(path: str, doc: dict) -> None:
    """Compressed geometry trimesh cannot decode here would load as placeholder zeros."""
    used = set(doc.get("extensionsUsed", []) or []) | set(doc.get("extensionsRequired", []) or [])
    if "KHR_draco_mesh_compression" in used and importlib.util.find_spec("DracoPy") is None:
        raise _unreadable(path, "Draco-compressed geometry and no DracoPy to decode it; "
                                "decompress it (e.g. gltf-transform copy) or install DracoPy")  # fmt: skip
    for ext in ("EXT_meshopt_compression", "KHR_meshopt_compression"):
        if ext in used:
            raise _unreadable(path, f"{ext} geometry is not decoded here; decompress it first "
                                    "(e.g. gltf-transform copy)")  # fmt: skip


def texture_files(path: str) -> list[str]:
    """Absolute paths of the existing texture files a mesh file references (an OBJ's MTL
    ``map_Kd``; a glTF/GLB's external image URIs): their pixels are stored with the asset, so
    they belong to the item's files (a changed or deleted texture re-ingests the item)."""
    ext = ext_of(path)
    base = os.path.dirname(os.path.abspath(path))
    refs: list[str] = []
    if ext == ".obj":
        try:
            refs = [m.texture for m in obj_materials(path).values() if m.texture]
        except OSError:
            return []
    elif ext in (".gltf", ".glb"):
        try:
            doc = _gltf_json(path)
        except (SourceError, OSError, ValueError):
            return []  # an unreadable file is reported by the reader, not here
        for img in (doc.get("images", []) if isinstance(doc, dict) else []) or []:
            uri = img.get("uri", "") if isinstance(img, dict) else ""
            if isinstance(uri, str) and uri and not uri.startswith("data:"):
                refs.append(unquote(uri))
    out: list[str] = []
    for ref in refs:
        p = os.path.normpath(os.path.join(base, ref.replace("\\", "/")))
        if os.path.isfile(p) and p not in out:
            out.append(p)
    return out


def sidecar_files(path: str) -> list[str]:
    """Files besides ``path`` whose bytes define the asset (for fingerprints): an OBJ's MTL
    libraries, a .gltf's external buffers, and the textures either references."""
    ext = ext_of(path)
    out: list[str] = []
    if ext == ".obj":
        out = [p for p in mtl_files(path) if p != path]
    elif ext == ".gltf":
        try:
            with open(path, encoding="utf-8") as f:
                doc = json.load(f)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            doc = {}
        base = os.path.dirname(os.path.abspath(path))
        for b in (doc.get("buffers", []) if isinstance(doc, dict) else []) or []:
            uri = b.get("uri", "") if isinstance(b, dict) else ""
            if uri and not uri.startswith("data:"):
                bp = os.path.normpath(os.path.join(base, unquote(uri)))
                if os.path.isfile(bp) and bp not in out:
                    out.append(bp)
    return out + [t for t in texture_files(path) if t not in out and t != path]


def _load_trimesh(path: str, ext: str) -> list[SourcePart]:
    import trimesh  # 1.0 s to import (python -X importtime): paid only when a mesh file is read

    infos: list[dict] = []
    mtl: dict = {}
    node_names: set[str] | None = None
    if ext in (".glb", ".gltf"):
        doc = _gltf_json(path)
        _check_compression(path, doc)
        infos = gltf_materials(doc, os.path.basename(path))
        nodes = doc.get("nodes", []) or []
        node_names = {str(i) for i in range(len(nodes))}
        node_names |= {n["name"] for n in nodes if isinstance(n, dict) and isinstance(n.get("name"), str)}
    elif ext == ".obj":
        try:
            mtl = obj_materials(path)
        except OSError:
            mtl = {}
    if not os.path.isfile(path):
        raise SourceError("missing mesh", f"{path} does not exist")
    try:
        scene = trimesh.load(path, force="scene", process=False)  # read as is: no cleaning here
    except FileNotFoundError as e:
        raise SourceError("missing mesh", f"{path}: {e}") from None
    except Exception as e:  # trimesh raises anything from IndexError to JSONDecodeError
        raise _unreadable(path, f"{type(e).__name__}: {e}") from None

    parts: list[SourcePart] = []
    taken: set[str] = set()
    for node in scene.graph.nodes_geometry:
        transform, gname = scene.graph[node]
        geom = scene.geometry.get(gname)
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue  # point clouds, paths: no triangles
        T = np.asarray(transform, dtype=np.float64)
        v = np.asarray(geom.vertices, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]
        f = np.asarray(geom.faces, dtype=np.int64)
        if np.linalg.det(T[:3, :3]) < 0:
            f = f[:, ::-1]  # (the corners' coordinates below follow the reversed order)
        material = getattr(geom.visual, "material", None)
        name, transparent = trimesh_material_info(material)
        texture = ""
        if infos:
            info = match_gltf(material, infos)
            if info is not None:
                transparent, texture = info["transparent"], info["texture"]
        elif mtl and name in mtl:
            transparent, texture = mtl[name].transparent, mtl[name].texture
        # glTF nodes keep their names; trimesh's own per-primitive nodes carry a random suffix,
        # so those parts are named after their (deterministic) geometry name instead
        label = str(node) if node_names is None or str(node) in node_names else str(gname)
        color, corner_uv, image = trimesh_appearance(geom, f, texture)
        if ext == ".obj":  # trimesh invents a grey Kd where the MTL states none (or is missing): ours
            color = mtl[name].color if name in mtl else None
        parts.append(make_part(_unique(label, taken), v, f, material=name, transparent=transparent,
                               texture=texture, color=color, corner_uv=corner_uv, image=image))  # fmt: skip
    return parts


def _load_dae(path: str) -> list[SourcePart]:
    try:
        doc = read_dae(path)
    except FileNotFoundError:
        raise SourceError("missing mesh", f"{path} does not exist") from None
    except (OSError, ColladaError) as e:
        raise _unreadable(path, str(e)) from None
    base = os.path.dirname(os.path.abspath(path))
    taken: set[str] = set()
    out = []
    for p in doc.parts:
        tex = p.texture
        if tex.startswith("file://"):
            tex = tex[len("file://") :]
        if tex and os.path.isabs(tex):
            tex = os.path.relpath(tex, base).replace(os.sep, "/")
        out.append(make_part(_unique(p.name, taken), p.vertices, p.faces, material=p.material,
                             transparent=p.transparent, texture=tex))  # fmt: skip
    return out


def _check_stl(path: str) -> None:
    """A truncated STL loads as an empty or partial mesh in trimesh: check its framing."""
    try:
        size = os.path.getsize(path)
        with open(path, "rb") as f:
            head = f.read(84)
            f.seek(max(0, size - 1024))
            tail = f.read()
    except OSError as e:
        raise _unreadable(path, str(e)) from None
    ascii_ = head.lstrip().lower().startswith(b"solid")
    if ascii_ and b"endsolid" in tail.lower():
        return  # a complete ASCII STL
    n = struct.unpack_from("<I", head, 80)[0] if len(head) >= 84 else None
    if n is not None and size >= 84 + 50 * n:
        return  # a binary STL with all its triangles (binary headers may start with "solid" too)
    if ascii_:
        raise _unreadable(path, "ASCII STL without 'endsolid' (truncated?)")
    if n is None:
        raise _unreadable(path, f"{size} bytes: too short for a binary STL (truncated?)")
    raise _unreadable(path, f"binary STL of {n} triangles needs {84 + 50 * n} bytes, "
                            f"file has {size} (truncated?)")  # fmt: skip


def missing_file_notes(path: str, parts, mtllibs: list[str] | None = None) -> list[str]:
    """Notes for the side files a mesh file references but that do not exist: an OBJ's material
    libraries (``mtllibs`` as written, else read from the OBJ's header) and the texture files
    ``parts`` reference by path (relative to the mesh file's directory; images embedded in the
    file, ``data:`` and other URIs are not files and are not checked)."""
    name = os.path.basename(path)
    base = os.path.dirname(os.path.abspath(path))
    notes = []
    if ext_of(path) == ".obj":
        for lib in missing_mtl_libraries(path, mtllibs):
            notes.append(f"{name}: material library {lib!r} not found (materials default: no "
                         "transparency or texture)")
    seen: set[str] = set()
    for part in parts:
        tex = part.texture
        if not tex or tex in seen or "#" in tex or re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", tex):
            continue  # none, embedded (file#images/k), or a URI (data:, http:, C: drive too)
        seen.add(tex)
        if not os.path.isfile(os.path.join(base, tex)):
            notes.append(f"{name}: texture {tex!r} not found (kept by reference)")
    return notes


def load_parts(path: str) -> list[SourcePart]:
    """One part per geometry node (per material) of a mesh file, node transforms applied, in the
    file's own frame and units. A readable file without triangles gives no parts (the
    standardizer quarantines it as an empty mesh). Raises SourceError ("missing mesh",
    "unreadable file")."""
    ext = ext_of(path)
    if ext not in MESH_EXTS:
        raise _unreadable(path, f"{ext or 'no extension'}: not a mesh format read here "
                                f"({', '.join(MESH_EXTS)}); convert it (e.g. to .glb)")  # fmt: skip
    if not os.path.exists(path):
        raise SourceError("missing mesh", f"{path} does not exist")
    if ext == ".stl":
        _check_stl(path)
    return _load_dae(path) if ext == ".dae" else _load_trimesh(path, ext)
