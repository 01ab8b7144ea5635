"""The appearance of a source part, as ADMesh keeps it: the material's base colour (RGBA
0-255), and when the source references a base-colour texture that reads, the image (RGB uint8,
long side at most :data:`MAX_TEXTURE_SIDE`) with the texture coordinates of each triangle
corner; and the glTF materials a trimesh material came from (name, alpha mode, transparency,
texture reference). From our OBJ reader's parts (:func:`obj_appearance`) and trimesh geometries
(:func:`trimesh_appearance`); shared by every source reader."""

from __future__ import annotations

import os
import posixpath
from urllib.parse import unquote

import numpy as np
from PIL import Image, UnidentifiedImageError


MAX_TEXTURE_SIDE = 1024
"""Texture images are kept at most this many pixels on their long side (box-filtered down):
a camera never sees more of one asset's texture, and the ADMesh library stays small."""


def texture_image(img) -> np.ndarray:
    """An (H, W, 3) uint8 RGB array of a PIL image (palette, grey and alpha images converted),
    its long side at most :data:`MAX_TEXTURE_SIDE`."""

    if img.mode in ("P", "PA", "LA", "RGBA", "La"):
        img = img.convert("RGBA")  # palette and alpha images: through RGBA (no warning, no surprise)
    img = img.convert("RGB")
    w, h = img.size
    if max(w, h) > MAX_TEXTURE_SIDE:
        k = MAX_TEXTURE_SIDE / max(w, h)
        img = img.resize((max(1, round(w * k)), max(1, round(h * k))), Image.Resampling.BOX)
    return np.ascontiguousarray(np.asarray(img, dtype=np.uint8))


def read_texture(path: str) -> np.ndarray | None:
    """The image file at ``path`` as :func:`texture_image` gives it; None when it is missing or
    unreadable (the part keeps its texture by reference and its material colour)."""

    try:
        with Image.open(path) as img:
            return texture_image(img)
    except (OSError, UnidentifiedImageError, ValueError):
        return None


def obj_appearance(data, material, uv_index, mesh_dir: str, reversed_: bool = False):
    """``(color, corner_uv, image)`` of an OBJ part read by our reader (``data`` its ObjData,
    ``material`` its MtlMaterial or None, ``uv_index`` its triangles' ``vt`` corners): the MTL
    ``Kd``, and the ``map_Kd`` image (relative to ``mesh_dir``) with the corners' coordinates
    when the file reads and every corner has a ``vt``; ``reversed_``: the caller re-wound the
    triangles (a, b, c) -> (c, b, a), so the corners reverse too."""
    if material is None:
        return None, None, None
    if not material.texture:
        return material.color, None, None
    image = read_texture(os.path.join(mesh_dir, material.texture))
    corner_uv = data.corner_uv(uv_index) if image is not None else None
    if corner_uv is None:
        return material.color, None, None
    return material.color, np.ascontiguousarray(corner_uv[:, ::-1] if reversed_ else corner_uv), image


def _colour(value) -> tuple[int, int, int, int] | None:
    """An RGBA 0-255 tuple of a trimesh colour (uint8 RGB or RGBA), None when there is none."""
    if value is None:
        return None
    c = np.asarray(value).reshape(-1)
    if c.size not in (3, 4) or not np.all(np.isfinite(c)):
        return None
    if c.dtype.kind == "f" and c.max() <= 1.0:
        c = c * 255.0
    c = np.clip(np.rint(c), 0, 255).astype(int)
    return (int(c[0]), int(c[1]), int(c[2]), int(c[3]) if c.size == 4 else 255)


def trimesh_appearance(geom, faces: np.ndarray, texture: str) -> tuple[tuple | None, np.ndarray | None, np.ndarray | None]:
    """``(color, corner_uv, image)`` of a trimesh geometry: its material's base colour (glTF
    ``baseColorFactor``, MTL ``Kd``), and, when the source references a base colour texture
    (``texture`` non-empty) that trimesh could read, the image and the coordinates of each corner
    of ``faces`` (the geometry's faces in the order the part keeps them; trimesh's coordinates
    have v up from the bottom-left corner for glTF and OBJ alike)."""
    visual = getattr(geom, "visual", None)
    material = getattr(visual, "material", None)
    color = None
    if material is not None:
        color = _colour(getattr(material, "baseColorFactor", None))
        if color is None and not hasattr(material, "baseColorFactor"):
            color = _colour(getattr(material, "diffuse", None))  # SimpleMaterial (MTL Kd)
    elif visual is not None and getattr(visual, "kind", None) == "face":
        color = _colour(np.asarray(visual.face_colors)[0]) if len(visual.face_colors) else None
    uv = getattr(visual, "uv", None)
    img = None
    if material is not None and texture:
        img = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    if img is None or uv is None or len(uv) != len(geom.vertices) or not np.all(np.isfinite(uv)):
        return color, None, None
    corner = np.asarray(uv, dtype=np.float32)[np.asarray(faces, dtype=np.int64)]
    return color, np.ascontiguousarray(corner), texture_image(img)


def gltf_materials(doc: dict, file_name: str) -> list[dict]:
    """Per glTF material: name, alphaMode, alpha, transmission, texture reference."""
    images = doc.get("images", []) or []
    textures = doc.get("textures", []) or []
    out = []
    for mat in doc.get("materials", []) or []:
        if not isinstance(mat, dict):
            mat = {}
        pbr = mat.get("pbrMetallicRoughness", {}) or {}
        factor = pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])
        try:
            alpha = float(factor[3])
        except (TypeError, IndexError, ValueError):
            alpha = 1.0
        ext = (mat.get("extensions", {}) or {}).get("KHR_materials_transmission", {}) or {}
        try:
            transmission = float(ext.get("transmissionFactor", 0.0))
        except (TypeError, ValueError):
            transmission = 0.0
        texture = ""
        tinfo = pbr.get("baseColorTexture")
        if isinstance(tinfo, dict) and isinstance(tinfo.get("index"), int):
            ti = tinfo["index"]
            tex = textures[ti] if 0 <= ti < len(textures) and isinstance(textures[ti], dict) else {}
            src = tex.get("source")
            for e in (tex.get("extensions", {}) or {}).values():  # KHR_texture_basisu, EXT_texture_webp
                if isinstance(e, dict) and isinstance(e.get("source"), int):
                    src = e["source"] if src is None else src
            if isinstance(src, int) and 0 <= src < len(images) and isinstance(images[src], dict):
                uri = images[src].get("uri", "")
                if uri and not uri.startswith("data:"):
                    texture = posixpath.normpath(unquote(uri).replace("\\", "/"))
                else:
                    texture = f"{file_name}#images/{src}"
        mode = mat.get("alphaMode", "OPAQUE")
        transparent = mode == "BLEND" or alpha < 1.0 or transmission > 0.0
        colour = [float(x) for x in factor] if isinstance(factor, list) else [1.0] * 4
        out.append({"name": mat.get("name"), "mode": mode, "colour": colour,
                    "transparent": transparent, "texture": texture})  # fmt: skip
    return out


def match_gltf(material, infos: list[dict]) -> dict | None:
    """The glTF material a trimesh PBRMaterial came from (by name, then colour and mode)."""
    name = getattr(material, "name", None)
    cands = [m for m in infos if m["name"] == name]
    if len(cands) <= 1:
        return cands[0] if cands else None
    mode = getattr(material, "alphaMode", None) or "OPAQUE"
    factor = getattr(material, "baseColorFactor", None)
    colour = None if factor is None else np.asarray(factor, dtype=np.float64) / 255.0
    best = [m for m in cands if m["mode"] == mode]
    if colour is not None:
        close = [m for m in best if np.allclose(m["colour"][: len(colour)], colour, atol=1 / 255)]
        best = close or best
    return (best or cands)[0]


def trimesh_material_info(material) -> tuple[str, bool]:
    """(name, transparent) from a trimesh material alone (no glTF JSON match)."""
    if material is None:
        return "default", False
    name = getattr(material, "name", None) or "default"
    mode = getattr(material, "alphaMode", None)
    factor = getattr(material, "baseColorFactor", None)
    alpha_lt_1 = factor is not None and len(factor) > 3 and int(np.asarray(factor)[3]) < 255
    return name, mode == "BLEND" or bool(alpha_lt_1)
