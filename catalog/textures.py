"""The textures of an ADMesh asset's parts: one ``.npz`` per textured asset, beside its GLB.

Per textured part ``k`` (its index in the asset's part order) two members: ``uv_<k>``, the
texture coordinates of every triangle corner, (M, 3, 2) float32 (u right, v up from the image's
bottom-left corner, repeating outside [0, 1]), and ``image_<k>``, the base colour texture,
(H, W, 3) uint8 RGB -- or, when part ``j`` before it has the same image, ``same_<k>`` = ``j``
(an atlas shared by the parts is stored once, and loaded as one array). Written
deterministically (fixed zip timestamps), so the same textures give the same bytes.
"""

from __future__ import annotations

import io
import typing

import numpy as np

from carlaocc.catalog.formats.carlaocc_npz import npz_bytes
from carlaocc.catalog.store import Store, StoreError
from carlaocc.schemas.meshes import MeshPart

__all__ = ["TextureStore", "has_texture", "texture_arrays", "textures_from_npz"]

Texture = tuple[np.ndarray, np.ndarray]  # (corner uv (M, 3, 2) float32, image (H, W, 3) uint8)


def has_texture(parts: typing.Sequence[MeshPart]) -> bool:
    """Whether any of ``parts`` carries a texture."""
    return any(p.image is not None for p in parts)


def texture_arrays(parts: typing.Sequence[MeshPart]) -> dict[str, np.ndarray]:
    """The npz members of the textured ``parts`` (see the module doc)."""
    out: dict[str, np.ndarray] = {}
    stored: list[tuple[int, np.ndarray]] = []  # (part, image) written so far
    for k, p in enumerate(parts):
        if p.image is not None:
            out[f"uv_{k}"] = np.asarray(p.corner_uv, dtype=np.float32)
            image = np.asarray(p.image, dtype=np.uint8)
            same = next((j for j, im in stored if im is image or (im.shape == image.shape and np.array_equal(im, image))),
                        None)
            if same is None:
                out[f"image_{k}"] = image
                stored.append((k, image))
            else:
                out[f"same_{k}"] = np.asarray(same, dtype=np.int64)
    return out


def textures_from_npz(data: bytes, where: str = "textures") -> dict[int, Texture]:
    """``part index -> (corner uv, image)`` of a texture file's bytes (``where`` names it in errors)."""
    out: dict[int, Texture] = {}
    images: dict[int, np.ndarray] = {}  # part -> its image array (shared by the parts that share it)
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        names = set(z.files)
        for name in sorted(names):
            if not name.startswith("uv_"):
                continue
            k = name[3:]
            if not k.isdigit() or (f"image_{k}" not in names and f"same_{k}" not in names):
                raise StoreError(f"{where}: member {name} has no image_{k}")
            if f"image_{k}" in names:
                image = z[f"image_{k}"]
            else:
                j = int(z[f"same_{k}"])
                if f"image_{j}" not in names:
                    raise StoreError(f"{where}: part {k} shares the image of part {j}, which has none")
                image = images.setdefault(j, z[f"image_{j}"])
            uv = z[name]
            if uv.ndim != 3 or uv.shape[1:] != (3, 2) or image.ndim != 3 or image.shape[2] != 3:
                raise StoreError(f"{where}: part {k} has coordinates {uv.shape} and image {image.shape}, "
                                 "expected (M, 3, 2) and (H, W, 3)")
            image = images.setdefault(int(k), image.astype(np.uint8, copy=False))
            out[int(k)] = (uv.astype(np.float32), image)
    return out


class TextureStore:
    """Asset textures in a store, addressed by store-relative path."""

    def __init__(self, store: Store):
        self.store = store

    def save(self, rel: str, parts: typing.Sequence[MeshPart]) -> str:
        arrays = texture_arrays(parts)
        if not arrays:
            raise ValueError(f"{rel}: none of the parts has a texture")
        return self.store.write_bytes(rel, npz_bytes(arrays, level=6))

    def exists(self, rel: str) -> bool:
        return self.store.exists(rel)

    def load(self, rel: str) -> dict[int, Texture]:
        try:
            return textures_from_npz(self.store.read_bytes(rel), f"{self.store.url}/{rel}")
        except StoreError:
            raise
        except Exception as exc:
            raise StoreError(f"cannot read textures {rel} in {self.store.url}: {exc}") from None
