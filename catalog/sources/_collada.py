"""A small COLLADA (.dae) reader: triangle geometry, node transforms, materials.

trimesh reads COLLADA only through the optional ``pycollada`` package, which this project does
not depend on; this reader covers what mesh libraries ship (SketchUp, Blender, 3ds Max exports):

* ``<triangles>``, ``<polylist>`` and ``<polygons>`` primitives (polygons fan-triangulated,
  ``<ph>`` holes ignored); ``<lines>`` and the rest are skipped;
* the node tree of the instantiated visual scene, with ``<matrix>``, ``<translate>``,
  ``<rotate>`` and ``<scale>`` composed in document order, ``<instance_node>`` and
  ``<instance_geometry>`` with ``<bind_material>``;
* per material: the effect's opacity (``<transparent>`` with its ``opaque`` mode times
  ``<transparency>``; without ``<transparent>`` the material is opaque) and the diffuse texture's
  image path (``init_from``, COLLADA 1.4 and 1.5).

``asset/up_axis`` and ``asset/unit`` are reported, never applied (adapters only describe).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from urllib.parse import unquote

import numpy as np


class ColladaError(ValueError):
    """The document is not usable COLLADA; the message says why."""


@dataclass(frozen=True)
class DaePart:
    name: str
    vertices: np.ndarray  # (N, 3) float64, node transforms applied
    faces: np.ndarray  # (M, 3) int64
    material: str
    transparent: bool
    texture: str  # image path as written in the document ("" if none)


@dataclass(frozen=True)
class DaeDocument:
    parts: list[DaePart]
    up_axis: str  # "X_UP", "Y_UP" (the COLLADA default) or "Z_UP"
    unit_m: float  # metres per unit (1.0 when absent)


def _tag(el: ET.Element) -> str:
    return el.tag.rsplit("}", 1)[-1]


def _children(el: ET.Element, name: str) -> list[ET.Element]:
    return [c for c in el if _tag(c) == name]


def _child(el: ET.Element, name: str) -> ET.Element | None:
    for c in el:
        if _tag(c) == name:
            return c
    return None


def _floats(text: str | None) -> np.ndarray:
    return np.array((text or "").split(), dtype=np.float64)


def _ints(text: str | None) -> np.ndarray:
    return np.array((text or "").split(), dtype=np.int64)


def _ref(url: str | None) -> str:
    return unquote((url or "").lstrip("#"))


def _rotation(axis: np.ndarray, deg: float) -> np.ndarray:
    n = float(np.linalg.norm(axis))
    m = np.eye(4)
    if n == 0.0:
        return m
    x, y, z = axis / n
    a = math.radians(deg)
    c, s, t = math.cos(a), math.sin(a), 1.0 - math.cos(a)
    m[:3, :3] = [
        [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
        [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
        [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
    ]
    return m


def _node_matrix(node: ET.Element) -> np.ndarray:
    m = np.eye(4)
    for el in node:
        kind = _tag(el)
        if kind == "matrix":
            v = _floats(el.text)
            if v.size == 16:
                m = m @ v.reshape(4, 4)  # row-major in the document
        elif kind == "translate":
            v = _floats(el.text)
            if v.size == 3:
                t = np.eye(4)
                t[:3, 3] = v
                m = m @ t
        elif kind == "rotate":
            v = _floats(el.text)
            if v.size == 4:
                m = m @ _rotation(v[:3], v[3])
        elif kind == "scale":
            v = _floats(el.text)
            if v.size == 3:
                m = m @ np.diag([*v, 1.0])
    return m


def _luminance(rgb) -> float:
    return 0.212671 * rgb[0] + 0.715160 * rgb[1] + 0.072169 * rgb[2]


class _Reader:
    def __init__(self, root: ET.Element):
        self.root = root
        self.ids: dict[str, ET.Element] = {}
        for el in root.iter():
            i = el.get("id")
            if i is not None:
                self.ids.setdefault(i, el)
        self._materials: dict[str, tuple[str, bool, str]] = {}
        self._geoms: dict[str, list[tuple[str, np.ndarray, np.ndarray]]] = {}

    # -- materials ---------------------------------------------------------------------------
    def _image_path(self, image_id: str) -> str:
        img = self.ids.get(image_id)
        if img is None or _tag(img) != "image":
            return ""
        init = _child(img, "init_from")
        if init is None:
            return ""
        ref = _child(init, "ref")  # COLLADA 1.5
        text = (ref.text if ref is not None else init.text) or ""
        return unquote(text.strip()).replace("\\", "/")

    def _texture_image(self, effect: ET.Element, sampler: str) -> str:
        params = {p.get("sid"): p for p in effect.iter() if _tag(p) == "newparam"}
        p = params.get(sampler)
        if p is None:  # some exporters point straight at the image
            return self._image_path(sampler)
        s2d = _child(p, "sampler2D")
        if s2d is None:
            return ""
        inst = _child(s2d, "instance_image")  # COLLADA 1.5
        if inst is not None:
            return self._image_path(_ref(inst.get("url")))
        src = _child(s2d, "source")
        if src is None or not src.text:
            return ""
        surf = params.get(src.text.strip())
        surface = _child(surf, "surface") if surf is not None else None
        init = _child(surface, "init_from") if surface is not None else None
        return self._image_path((init.text or "").strip()) if init is not None else ""

    def material(self, mat_id: str) -> tuple[str, bool, str]:
        """(name, transparent, texture) of a material id."""
        if mat_id in self._materials:
            return self._materials[mat_id]
        mat = self.ids.get(mat_id)
        name, transparent, texture = mat_id or "default", False, ""
        if mat is not None and _tag(mat) == "material":
            name = mat.get("name") or mat_id
            inst = _child(mat, "instance_effect")
            effect = self.ids.get(_ref(inst.get("url"))) if inst is not None else None
            if effect is not None:
                for tech in effect.iter():
                    if _tag(tech) not in ("phong", "lambert", "blinn", "constant"):
                        continue
                    diffuse = _child(tech, "diffuse")
                    tex = _child(diffuse, "texture") if diffuse is not None else None
                    if tex is not None:
                        texture = self._texture_image(effect, tex.get("texture", ""))
                    transparent = self._transparent(tech)
                    break
        self._materials[mat_id] = (name, transparent, texture)
        return self._materials[mat_id]

    @staticmethod
    def _transparent(tech: ET.Element) -> bool:
        tr = _child(tech, "transparent")
        if tr is None:
            return False
        ty = _child(tech, "transparency")
        f = _child(ty, "float") if ty is not None else None
        factor = float(f.text) if f is not None and f.text else 1.0
        color = _child(tr, "color")
        if color is None:  # an alpha texture (cut-outs, foliage): not glass
            return False
        c = _floats(color.text)
        if c.size < 4:
            c = np.concatenate([c, np.ones(4 - c.size)])
        mode = tr.get("opaque", "A_ONE")
        if mode == "A_ONE":
            opacity = c[3] * factor
        elif mode == "A_ZERO":
            opacity = 1.0 - c[3] * factor
        elif mode == "RGB_ZERO":
            opacity = 1.0 - _luminance(c) * factor
        else:  # RGB_ONE
            opacity = _luminance(c) * factor
        return opacity < 1.0 - 1e-6

    # -- geometry ----------------------------------------------------------------------------
    def geometry(self, geom_id: str) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """[(material symbol, positions, triangles)] of a geometry id."""
        if geom_id in self._geoms:
            return self._geoms[geom_id]
        geom = self.ids.get(geom_id)
        out: list[tuple[str, np.ndarray, np.ndarray]] = []
        mesh = _child(geom, "mesh") if geom is not None else None
        if mesh is not None:
            for prim in mesh:
                kind = _tag(prim)
                if kind not in ("triangles", "polylist", "polygons"):
                    continue
                out.append(self._primitive(mesh, prim, kind))
        self._geoms[geom_id] = out
        return out

    def _positions(self, mesh: ET.Element, source_id: str) -> np.ndarray:
        el = self.ids.get(source_id)
        if el is not None and _tag(el) == "vertices":
            for inp in _children(el, "input"):
                if inp.get("semantic") == "POSITION":
                    return self._positions(mesh, _ref(inp.get("source")))
            raise ColladaError(f"vertices {source_id!r} has no POSITION input")
        if el is None or _tag(el) != "source":
            raise ColladaError(f"source {source_id!r} not found")
        arr = _child(el, "float_array")
        data = _floats(arr.text if arr is not None else "")
        stride = 3
        tc = _child(el, "technique_common")
        acc = _child(tc, "accessor") if tc is not None else None
        if acc is not None:
            stride = int(acc.get("stride", "3"))
        if stride < 3 or data.size % stride:
            raise ColladaError(f"source {source_id!r}: {data.size} floats, stride {stride}")
        return data.reshape(-1, stride)[:, :3]

    def _primitive(self, mesh, prim, kind) -> tuple[str, np.ndarray, np.ndarray]:
        inputs = _children(prim, "input")
        if not inputs:
            raise ColladaError(f"<{kind}> without inputs")
        stride = max(int(i.get("offset", "0")) for i in inputs) + 1
        vin = [i for i in inputs if i.get("semantic") == "VERTEX"]
        if not vin:
            raise ColladaError(f"<{kind}> without a VERTEX input")
        offset = int(vin[0].get("offset", "0"))
        positions = self._positions(mesh, _ref(vin[0].get("source")))
        tris: list[np.ndarray] = []
        if kind == "triangles":
            p = _ints(" ".join(x.text or "" for x in _children(prim, "p")))
            idx = p.reshape(-1, stride)[:, offset] if p.size % stride == 0 else None
            if idx is None or idx.size % 3:
                raise ColladaError("<triangles>: index count is not a multiple of 3 corners")
            tris.append(idx.reshape(-1, 3))
        else:
            if kind == "polylist":
                vcount = _ints(_child(prim, "vcount").text if _child(prim, "vcount") is not None else "")
                p = _ints(_child(prim, "p").text if _child(prim, "p") is not None else "")
                if p.size != int(vcount.sum()) * stride:
                    raise ColladaError("<polylist>: <p> does not match <vcount>")
                corners = p.reshape(-1, stride)[:, offset]
                starts = np.concatenate([[0], np.cumsum(vcount)[:-1]]).astype(np.int64)
                polys = [corners[s : s + n] for s, n in zip(starts, vcount)]
            else:
                polys = []
                for pe in _children(prim, "p"):
                    p = _ints(pe.text)
                    if p.size % stride:
                        raise ColladaError("<polygons>: a <p> is not whole corners")
                    polys.append(p.reshape(-1, stride)[:, offset])
            for poly in polys:
                if len(poly) >= 3:
                    k = np.arange(1, len(poly) - 1)
                    tris.append(np.stack([np.full_like(k, poly[0]), poly[k], poly[k + 1]], axis=1))
        faces = np.concatenate(tris).astype(np.int64) if tris else np.zeros((0, 3), np.int64)
        if faces.size and (faces.min() < 0 or faces.max() >= len(positions)):
            raise ColladaError("vertex index out of range")
        return prim.get("material", ""), positions, faces

    # -- scene -------------------------------------------------------------------------------
    def parts(self) -> list[DaePart]:
        scene = _child(self.root, "scene")
        inst = _child(scene, "instance_visual_scene") if scene is not None else None
        vs = self.ids.get(_ref(inst.get("url"))) if inst is not None else None
        if vs is None:  # no <scene>: the first visual scene
            vss = [e for e in self.root.iter() if _tag(e) == "visual_scene"]
            vs = vss[0] if vss else None
        out: list[DaePart] = []
        if vs is None:
            return out
        for node in _children(vs, "node"):
            self._walk(node, np.eye(4), out, depth=0)
        return out

    def _walk(self, node, parent: np.ndarray, out: list[DaePart], depth: int) -> None:
        if depth > 256:
            raise ColladaError("node hierarchy too deep (instance_node cycle?)")
        m = parent @ _node_matrix(node)
        label = node.get("name") or node.get("id") or "node"
        for el in node:
            kind = _tag(el)
            if kind == "node":
                self._walk(el, m, out, depth + 1)
            elif kind == "instance_node":
                target = self.ids.get(_ref(el.get("url")))
                if target is not None:
                    self._walk(target, m, out, depth + 1)
            elif kind == "instance_geometry":
                binding = {}
                for im in el.iter():
                    if _tag(im) == "instance_material":
                        binding[im.get("symbol", "")] = _ref(im.get("target"))
                gid = _ref(el.get("url"))
                for i, (symbol, pos, faces) in enumerate(self.geometry(gid)):
                    if not len(faces):
                        continue
                    used, inv = np.unique(faces.ravel(), return_inverse=True)
                    v = pos[used] @ m[:3, :3].T + m[:3, 3]
                    f = inv.reshape(-1, 3).astype(np.int64)
                    if np.linalg.det(m[:3, :3]) < 0:
                        f = f[:, ::-1].copy()
                    name, transparent, texture = self.material(binding.get(symbol, symbol))
                    out.append(DaePart(f"{label}/{gid}#{i}", v, f, name, transparent, texture))


def read_dae(path: str) -> DaeDocument:
    """Parse a COLLADA file. Raises ColladaError (or OSError) when it cannot be read."""
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as e:
        raise ColladaError(f"not well-formed XML: {e}") from None
    if _tag(root) != "COLLADA":
        raise ColladaError(f"root element is <{_tag(root)}>, not <COLLADA>")
    up, unit = "Y_UP", 1.0
    asset = _child(root, "asset")
    if asset is not None:
        u = _child(asset, "up_axis")
        if u is not None and (u.text or "").strip() in ("X_UP", "Y_UP", "Z_UP"):
            up = u.text.strip()
        un = _child(asset, "unit")
        if un is not None:
            try:
                unit = float(un.get("meter", "1"))
            except ValueError:
                pass
    try:
        parts = _Reader(root).parts()
    except (ValueError, TypeError, AttributeError) as e:
        if isinstance(e, ColladaError):
            raise
        raise ColladaError(f"malformed geometry: {e}") from None
    return DaeDocument(parts, up, unit)
